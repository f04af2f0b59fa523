//! `ntg trace`: one unseen test task executed by a trained run, written out
//! step by step (see [`crate::trace`]).

use std::path::PathBuf;

use clap::Args;

use crate::blocks::BlocksRunConfig;
use crate::run_dir::RunDir;

/// Arguments of `ntg trace`.
#[derive(Debug, Args)]
pub struct TraceArgs {
    /// Run folder written by `ntg train`.
    #[arg(long)]
    pub run: PathBuf,
    /// The test task: an index into the standard test set (0-999) or a task
    /// id such as `stack_1003`.
    #[arg(long)]
    pub task: String,
    /// Folder to write the trace into (must not exist, or be empty).
    #[arg(long)]
    pub out: PathBuf,
    /// Keep GCN edges with probability at least this (default: the
    /// model's configured threshold).
    #[arg(long)]
    pub edge_threshold: Option<f32>,
}

/// Runs `ntg trace`.
pub fn run(args: &TraceArgs) -> anyhow::Result<()> {
    let (run, domain) = crate::domain::open_run(&args.run)?;
    if domain != crate::domain::DomainId::Blocks {
        anyhow::bail!(
            "{}: ntg trace replays block-stacking runs; this is a run of --domain {} (ntg eval evaluates it)",
            run.root().display(),
            domain.name()
        );
    }
    let config: BlocksRunConfig = RunDir::read_json(&run.config_path())?;
    let device = crate::spec::device();
    if config.method.is_ntp() {
        if args.edge_threshold.is_some() {
            anyhow::bail!(
                "--edge-threshold chooses NTG's edges; {} is a {} run",
                run.root().display(),
                config.method.legend()
            );
        }
        let model = crate::blocks::load_baseline(&run, &config, &device)?;
        let index = crate::trace::resolve_test_task(config.task_source(), &args.task)?;
        let trace = crate::trace::trace_baseline(model.as_ref(), &config, index, &args.out)?;
        print!("{}", crate::trace::baseline_table(&trace));
        println!("trace written to {}", args.out.display());
        return Ok(());
    }
    let crate::blocks::TrainedBlocks::State(model) =
        crate::blocks::load_trained(&run, args.edge_threshold, &device)?
    else {
        anyhow::bail!(
            "{}: ntg trace replays state-input runs; this run is on video (--obs vid)",
            run.root().display()
        );
    };
    let tasks = config.task_source();
    let index = crate::trace::resolve_test_task(tasks, &args.task)?;
    let trace =
        crate::trace::trace_task(&model, tasks, config.obs, config.failures, index, &args.out)?;
    print!("{}", crate::trace::trace_table(&trace));
    println!("trace written to {}", args.out.display());
    Ok(())
}
