//! The `ntg` command-line tool. All logic lives in [`ntg_trainer::cli`].

/// mimalloc instead of the system allocator: burn's CPU backend allocates
/// for every tensor operation, and with the data-parallel shards two
/// threads allocate at once. `cargo xtask bench` measured the state training
/// step about 10% faster with it, on one thread and on two.
#[global_allocator]
static ALLOCATOR: mimalloc::MiMalloc = mimalloc::MiMalloc;

fn main() -> std::process::ExitCode {
    ntg_trainer::allocator::keep_freed_memory();
    ntg_trainer::cli::main()
}
