//! `ntg carry`: saves unfinished paper-profile runs to resume them on
//! another machine (see [`crate::carry`]).

use std::path::PathBuf;

use clap::Args;

/// Arguments of `ntg carry`.
#[derive(Debug, Args)]
pub struct CarryArgs {
    /// The paper-profile runs to save, by folder name (as `ntg reproduce
    /// --only` takes them), e.g. `ntp_exp-vid-ntp-1000`.
    #[arg(required = true, value_name = "RUN", value_delimiter = ',')]
    pub names: Vec<String>,
    /// The `--runs` folder `ntg reproduce` trained them in (its `paper/`
    /// holds the paper profile's run folders).
    #[arg(long, default_value = "runs/figures")]
    pub runs: PathBuf,
    /// The `--out` folder of `ntg reproduce --profile paper`: the runs are
    /// saved into its `in-progress/`, beside its `records/`.
    #[arg(long, default_value = "docs/figures")]
    pub out: PathBuf,
}

/// Runs `ntg carry`: saves each run, or fails naming the first that could
/// not be (the runs before it are saved).
pub fn run(args: &CarryArgs) -> anyhow::Result<()> {
    let runs = args.runs.join("paper");
    let records = args.out.join("records");
    for name in &args.names {
        let carried = crate::carry::carry_run(&runs, &records, name)?;
        let mut checkpoints: Vec<String> = carried
            .checkpoints
            .iter()
            .map(|(stage, epochs)| match stage.as_os_str().is_empty() {
                true => format!("{epochs} epochs"),
                false => format!("{}: {epochs} epochs", stage.display()),
            })
            .collect();
        checkpoints.sort();
        if checkpoints.is_empty() {
            checkpoints.push("no checkpoint yet".to_owned());
        }
        println!(
            "{name}: carried to {} ({} files, {:.1} MB; {}); commit it, and `ntg reproduce \
             --profile paper` resumes it on the next machine",
            carried.to.display(),
            carried.files,
            carried.bytes as f64 / 1e6,
            checkpoints.join(", ")
        );
    }
    Ok(())
}
