//! The `ntg` command-line tool. All logic lives in [`ntg_trainer::cli`].

fn main() -> std::process::ExitCode {
    ntg_trainer::cli::main()
}
