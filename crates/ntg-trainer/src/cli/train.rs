//! `ntg train` and `ntg eval`: parsed into the shared flags and each
//! domain's own, then handed to the domain the run belongs to (the domain
//! registry, [`crate::domain::DomainId`]).

use std::path::PathBuf;

use clap::Args;

use crate::domain::{DomainFlags, DomainId, TrainFlags};

/// Arguments of `ntg train`.
#[derive(Debug, Args)]
pub struct TrainArgs {
    /// Task domain.
    #[arg(long, value_enum, default_value_t = DomainId::Blocks)]
    pub domain: DomainId,
    /// The flags every domain reads.
    #[command(flatten)]
    pub flags: TrainFlags,
    /// Each domain's own flags.
    #[command(flatten)]
    pub own: DomainFlags,
}

/// Runs `ntg train`.
pub fn run_train(args: &TrainArgs) -> anyhow::Result<()> {
    args.domain.runs().train(&args.flags, &args.own)
}

/// Arguments of `ntg eval`.
pub type EvalArgs = crate::domain::EvalFlags;

/// Runs `ntg eval` on the run in `--run`, with the domain it belongs to.
pub fn run_eval(args: &EvalArgs) -> anyhow::Result<()> {
    let (run, domain) = crate::domain::open_run(&args.run)?;
    // No lock: evaluation reads the trained model (replaced whole by
    // training, never half-written) and writes only its own records under
    // `eval/`, each in one rename; a run folder it cannot write to (a
    // read-only copy) is evaluated all the same.
    domain.runs().evaluate(&run, args)
}

/// Arguments of `ntg reproduce`.
#[derive(Debug, Args)]
pub struct ReproduceArgs {
    /// Where the networks run: the CPU, or a GPU backend compiled in with
    /// `--features wgpu` / `--features cuda`.
    #[arg(long, value_enum, default_value_t = crate::spec::DeviceKind::Cpu)]
    pub device: crate::spec::DeviceKind,
    /// Experiment scale.
    #[arg(long, value_enum, default_value_t = crate::spec::Profile::Quick)]
    pub profile: crate::spec::Profile,
    /// Where run folders go, in a subfolder per profile (`DIR/PROFILE/RUN`,
    /// e.g. `runs/figures/paper/ntp_exp-state-1000`); finished runs are
    /// reused.
    #[arg(long, value_name = "DIR", default_value = "runs/figures")]
    pub runs: PathBuf,
    /// Where figures, results.json and REPORT.md go (and, at the paper
    /// profile, the run records under `records/`). Default: `docs/figures`
    /// for the paper profile, `docs/figures/PROFILE` for the others.
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Run fig. "jigsaws" on this JIGSAWS copy instead of the synthetic
    /// stand-in.
    #[arg(long, value_name = "DIR")]
    pub jigsaws_root: Option<PathBuf>,
    /// Read the figures' experiment files (`ntp_exp.toml`,
    /// `thor_all.toml`) from this folder instead of the copies built in
    /// (`crates/ntg-trainer/experiments/`).
    #[arg(long, value_name = "DIR")]
    pub experiments: Option<PathBuf>,
    /// Runs trained at once. The figures' runs train on one thread each,
    /// so 2 keeps both cores of a 2-core machine busy; a run's result does
    /// not depend on it.
    #[arg(long, default_value_t = 2, value_parser = clap::value_parser!(u16).range(1..))]
    pub jobs: u16,
    /// Train (or reuse) and evaluate only these run folders of the rollout
    /// figures (e.g. `ntp_exp-state-1000,ablation_b-no-gcn`), and say of
    /// each whether it matches the result in `--out`'s results.json;
    /// writes no figure or report.
    #[arg(long, value_name = "RUN", value_delimiter = ',')]
    pub only: Vec<String>,
    /// Train nothing: draw the figures and write the report from the
    /// finished runs and (paper profile) the committed run records, and
    /// list the other runs as not trained yet.
    #[arg(long, conflicts_with = "only")]
    pub no_train: bool,
    /// Print the profile's runs, one per line, in an order a scheduler can
    /// follow (wave by wave, each with the runs whose finished stages it
    /// reuses), and exit: the list `--array-index` indexes.
    #[arg(long, conflicts_with_all = ["only", "no_train"])]
    pub list: bool,
    /// With --list: print JSON instead of text.
    #[arg(long, requires = "list")]
    pub json: bool,
    /// Train (or resume, or reuse) and evaluate the I-th run of --list, as
    /// --only would: one task of a job array. Without I, the index is read
    /// from SLURM_ARRAY_TASK_ID.
    #[arg(long, value_name = "I", num_args = 0..=1, conflicts_with_all = ["only", "no_train", "list"])]
    pub array_index: Option<Option<usize>>,
}

/// The run `--array-index` names: `index`, or (none given) the one
/// `SLURM_ARRAY_TASK_ID` names.
fn array_run(
    index: Option<usize>,
    list: &[crate::reproduce::ListedRun],
) -> anyhow::Result<&crate::reproduce::ListedRun> {
    let index = match index {
        Some(i) => i,
        None => {
            let value = std::env::var("SLURM_ARRAY_TASK_ID").map_err(|_| {
                anyhow::anyhow!(
                    "--array-index without a value reads SLURM_ARRAY_TASK_ID, which is not set (give the index: --array-index I)"
                )
            })?;
            value.trim().parse().map_err(|_| {
                anyhow::anyhow!("SLURM_ARRAY_TASK_ID={value:?} is not a run index (0, 1, ...)")
            })?
        }
    };
    list.get(index).ok_or_else(|| {
        anyhow::anyhow!(
            "--array-index {index}: the profile has {} runs (indices 0 to {}; see --list)",
            list.len(),
            list.len().saturating_sub(1)
        )
    })
}

/// Runs `ntg reproduce`.
pub fn run_reproduce(args: &ReproduceArgs) -> anyhow::Result<()> {
    let profile_name = serde_json::to_value(args.profile)?
        .as_str()
        .unwrap_or("profile")
        .to_owned();
    let experiments = match &args.experiments {
        Some(dir) => crate::experiment::Source::Dir(dir),
        None => crate::experiment::Source::BuiltIn,
    };
    if args.list {
        let list = crate::reproduce::run_list(args.profile, experiments)?;
        let text = if args.json {
            serde_json::to_string_pretty(&list)? + "\n"
        } else {
            list.iter()
                .map(|run| crate::reproduce::list_line(run) + "\n")
                .collect()
        };
        // A reader that stops early (`| head`) is not an error.
        use std::io::Write as _;
        return match std::io::stdout().lock().write_all(text.as_bytes()) {
            Err(e) if e.kind() == std::io::ErrorKind::BrokenPipe => Ok(()),
            other => Ok(other?),
        };
    }
    let mut only = args.only.clone();
    if let Some(index) = args.array_index {
        let list = crate::reproduce::run_list(args.profile, experiments)?;
        let run = array_run(index, &list)?;
        eprintln!(
            "array task {}: {} (of {} runs of profile {profile_name})",
            run.index,
            run.name,
            list.len()
        );
        only = vec![run.name.clone()];
    }
    let runs = args.runs.join(&profile_name);
    let out = args
        .out
        .clone()
        .unwrap_or_else(|| crate::reproduce::default_out(args.profile));
    // The paper profile's runs take hours: each finished one is recorded
    // (committed with the figures), so the profile can be completed over
    // several sittings, from a fresh clone too.
    let records = out.join("records");
    let plan = crate::experiment::Plan {
        only: (!only.is_empty()).then_some(only.as_slice()),
        records: (args.profile == crate::spec::Profile::Paper).then_some(records.as_path()),
        restore: only.is_empty(),
        train: !args.no_train,
        ..crate::experiment::Plan::train_all(&runs, usize::from(args.jobs))
    };
    if !only.is_empty() {
        if args.jigsaws_root.is_some() {
            anyhow::bail!(
                "--only reruns runs of the rollout figures; fig. jigsaws (--jigsaws-root) is not one"
            );
        }
        for line in crate::reproduce::reproduce_only(args.profile, &plan, &out, experiments)? {
            println!("{line}");
        }
        for name in plan
            .missing
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .iter()
        {
            println!(
                "{name}: not evaluated in {} (--no-train trains nothing)",
                runs.display()
            );
        }
        return Ok(());
    }
    // The paper profile's committed results, shown beside another
    // profile's.
    let paper_results = PathBuf::from("docs/figures/results.json");
    let paper: Option<crate::reproduce::Results> =
        if args.profile != crate::spec::Profile::Paper && paper_results.is_file() {
            Some(crate::run_dir::RunDir::read_json(&paper_results)?)
        } else {
            None
        };
    let results = crate::reproduce::reproduce(
        args.profile,
        &plan,
        &out,
        args.jigsaws_root.as_deref(),
        experiments,
        paper
            .as_ref()
            .filter(|p| p.profile == crate::spec::Profile::Paper),
    )?;
    println!(
        "wrote {} (figure ntp_exp: {} points)",
        out.display(),
        results.ntp_exp.len()
    );
    for (what, why) in &results.not_yet {
        println!("not reproduced yet: {what} ({why})");
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use clap::Parser;

    use crate::blocks::{self, BlocksRunConfig};
    use crate::cli::{Cli, Command};

    fn config_of(args: &[&str]) -> BlocksRunConfig {
        let argv = ["ntg", "train", "--out", "run"].iter().chain(args);
        match Cli::try_parse_from(argv).unwrap().command {
            Command::Train(train) => blocks::train_config(&train.flags, &train.own.blocks),
            other => panic!("parsed as {other:?}"),
        }
    }

    #[test]
    fn block_stacking_takes_an_interpreter_and_its_step_prior() {
        use crate::method::ntg::InterpreterKind;
        // The recommended recipe's on states: the stepping interpreter
        // taught its alignment, with its step prior.
        let c = config_of(&[]);
        assert_eq!(
            (c.interpreter, c.location_step_prior),
            (
                Some(InterpreterKind::SteppingAligned),
                Some(crate::collect::LOCATION_STEP_PRIOR)
            )
        );
        let paper = config_of(&["--recipe", "paper"]);
        assert_eq!((paper.interpreter, paper.location_step_prior), (None, None));
        // `--interpreter luong` replaces it and its prior.
        let c = config_of(&["--interpreter", "luong"]);
        assert_eq!((c.interpreter, c.location_step_prior), (None, None));
        assert_eq!(serde_json::to_value(&c).unwrap().get("interpreter"), None);
        let c = config_of(&["--interpreter", "stepping"]);
        assert_eq!(
            (c.interpreter, c.location_step_prior),
            (
                Some(InterpreterKind::Stepping),
                Some(crate::collect::LOCATION_STEP_PRIOR)
            )
        );
        let c = config_of(&["--interpreter", "stepping", "--location-step-prior", "0"]);
        assert_eq!(c.location_step_prior, None);
        assert!(
            blocks::additions(&config_of(&[
                "--recipe",
                "paper",
                "--interpreter",
                "stepping"
            ]))
            .contains(&"stepping interpreter".to_owned())
        );
    }

    #[test]
    fn the_video_renaming_group_is_the_recipe_s_unless_set() {
        let group = |args: &[&str]| config_of(args).video.unwrap().demos_per_renaming;
        assert_eq!(group(&["--obs", "vid"]), 4);
        assert_eq!(group(&["--obs", "vid", "--recipe", "paper"]), 0);
        assert_eq!(group(&["--obs", "vid", "--video-renaming-group", "2"]), 2);
        assert_eq!(group(&["--obs", "vid", "--video-renaming-group", "0"]), 0);
    }

    #[test]
    fn the_node_source_is_the_recipe_s_unless_set_on_either_input() {
        let video = |args: &[&str]| {
            let v = config_of(args).video.unwrap();
            (v.executed_node, v.localizer_previous_frame)
        };
        // On video the recommended recipe takes the executed node, the
        // paper's the localizer; --node-source overrides either, so the
        // localizer can read the previous frame in the recommended recipe.
        assert_eq!(video(&["--obs", "vid"]), (true, false));
        assert_eq!(
            video(&["--obs", "vid", "--recipe", "paper"]),
            (false, false)
        );
        assert_eq!(
            video(&[
                "--obs",
                "vid",
                "--node-source",
                "localizer",
                "--localizer-previous-frame"
            ]),
            (false, true)
        );
        assert_eq!(
            video(&[
                "--obs",
                "vid",
                "--recipe",
                "paper",
                "--node-source",
                "executed"
            ]),
            (true, false)
        );
        let c = config_of(&["--obs", "vid", "--node-source", "localizer"]);
        assert!(
            !c.executed_node,
            "a video run's switch is video.executed_node"
        );
        // On states the switch is the run's own, and the recommended
        // recipe's is the executed node.
        assert!(config_of(&[]).executed_node);
        assert!(!config_of(&["--recipe", "paper"]).executed_node);
        assert!(!config_of(&["--node-source", "localizer"]).executed_node);
        assert!(config_of(&["--recipe", "paper", "--node-source", "executed"]).executed_node);
        assert!(config_of(&["--node-source", "localizer"]).video.is_none());
        assert!(
            blocks::additions(&config_of(&[
                "--obs",
                "vid",
                "--node-source",
                "localizer",
                "--localizer-previous-frame"
            ]))
            .contains(&"localizer reads the previous frame".to_owned())
        );
    }

    #[test]
    fn the_paper_recipe_adds_nothing() {
        let c = config_of(&["--recipe", "paper"]);
        assert_eq!(
            (c.state_hidden_layers, c.pairwise, c.permute_objects),
            (1, false, false)
        );
        assert_eq!((c.edge_fusion_hidden, c.detach_gcn_from_edges), (0, false));
        assert!(!c.soft_edges && !c.exclude_held_out_renamings);
        assert_eq!(c.optim.learning_rate, crate::fit::PAPER_LEARNING_RATE);
        assert!(!c.optim.cosine_decay && !c.optim.gcn_from_other_demo);
        // Flags add to the recipe.
        let c = config_of(&["--recipe", "paper", "--pairwise", "--lr", "0.01"]);
        assert!(c.pairwise);
        assert_eq!(c.optim.learning_rate, 0.01);
        // Renaming, from any recipe, never shows a held-out task.
        let c = config_of(&["--recipe", "paper", "--permute-objects"]);
        assert!(c.permute_objects && c.exclude_held_out_renamings);
    }

    #[test]
    fn the_recommended_recipe_is_the_default_and_numbers_override_it() {
        let c = config_of(&[]);
        assert_eq!(
            (c.state_hidden_layers, c.pairwise, c.permute_objects),
            (3, true, true)
        );
        // The GCN learns from the edge loss on states, not on video.
        assert_eq!(
            (c.edge_fusion_hidden, c.detach_gcn_from_edges),
            (256, false)
        );
        assert!(c.soft_edges && c.exclude_held_out_renamings);
        assert_eq!(c.optim.learning_rate, 3e-3);
        assert!(c.optim.cosine_decay && c.optim.gcn_from_other_demo);
        // On states the policy's node from the executed actions and the
        // `<end>` rule; `--end-after-demo false` turns the rule off.
        assert!(c.executed_node && c.end_after_demo);
        assert!(!config_of(&["--end-after-demo", "false"]).end_after_demo);
        assert!(config_of(&["--recipe", "paper", "--end-after-demo"]).end_after_demo);
        assert!(!config_of(&["--recipe", "paper"]).end_after_demo);
        let c = config_of(&["--edge-fusion-hidden", "0", "--state-hidden-layers", "2"]);
        assert_eq!((c.edge_fusion_hidden, c.state_hidden_layers), (0, 2));
        // Frames have no per-cube columns to rename; on video the GCN stays
        // out of the edge loss.
        let vid = config_of(&["--obs", "vid"]);
        assert!(!vid.permute_objects && vid.detach_gcn_from_edges);
        // The state choices of the recipe are NTG's, and only on states.
        assert!(!vid.executed_node && !vid.end_after_demo && vid.interpreter.is_none());
        let ntp = config_of(&["--method", "ntp"]);
        assert!(!ntp.executed_node && !ntp.end_after_demo);
        assert_eq!((ntp.interpreter, ntp.location_step_prior), (None, None));
    }

    #[test]
    fn unset_flags_write_the_recipe_s_values() {
        // A CLI run of a recipe is the recipe's run: the same configuration.
        for recipe in ["paper", "recommended"] {
            let c = config_of(&["--recipe", recipe]);
            assert_eq!(c.retry_weight, 0.0, "{recipe}");
            assert!(c.ntp_core.is_reactive(), "{recipe}");
        }
        let c = config_of(&[
            "--retry-weight",
            "2",
            "--method",
            "ntp",
            "--ntp-core",
            "gru",
        ]);
        assert_eq!(c.retry_weight, 2.0);
        assert_eq!(c.ntp_core, blocks::NtpCoreKind::Gru);
    }

    #[test]
    fn ntp_detector_takes_the_camera_and_stem_flags() {
        let c = config_of(&[
            "--obs",
            "vid",
            "--method",
            "ntp-detector",
            "--camera-size",
            "128",
            "--encoder-stem",
            "16",
        ]);
        assert!(c.video.is_none());
        assert_eq!(c.camera().size, 128);
        assert_eq!(c.detector.as_ref().unwrap().stem, Some(16));
        let standard = config_of(&["--obs", "vid", "--method", "ntp-detector"]);
        assert_eq!(standard.camera(), env_blocks::Camera::default());
        assert_eq!(standard.detector.unwrap().stem, None);
    }

    #[test]
    fn shards_default_to_two_and_reach_both_video_stages() {
        assert_eq!(config_of(&[]).optim.shards, 2);
        let c = config_of(&["--obs", "vid", "--shards", "3"]);
        assert_eq!(c.optim.shards, 3);
        assert_eq!(c.video.as_ref().unwrap().encoder.shards, 3);
        assert_eq!(c.video.unwrap().encoder.optim(0).shards, 3);
    }

    #[test]
    fn collect_location_step_prior_defaults_per_method_and_interpreter() {
        let prior = |args: &[&str]| {
            let argv = ["ntg", "train", "--domain", "collect", "--out", "run"]
                .iter()
                .chain(args);
            match Cli::try_parse_from(argv).unwrap().command {
                Command::Train(train) => crate::collect::location_step_prior_of(&train.flags),
                other => panic!("parsed as {other:?}"),
            }
        };
        assert_eq!(prior(&[]), Some(crate::collect::LOCATION_STEP_PRIOR));
        assert_eq!(prior(&["--method", "flat"]), None);
        assert_eq!(prior(&["--interpreter", "luong"]), None);
        // Demo videos take the stepping interpreter with the video
        // window, primed alike; the paper's interpreter has none.
        assert_eq!(
            prior(&["--obs", "vid"]),
            Some(crate::collect::LOCATION_STEP_PRIOR)
        );
        assert_eq!(prior(&["--obs", "vid", "--interpreter", "luong"]), None);
        assert_eq!(
            prior(&["--obs", "vid", "--interpreter", "stepping"]),
            Some(crate::collect::LOCATION_STEP_PRIOR)
        );
        assert_eq!(prior(&["--location-step-prior", "0.5"]), Some(0.5));
        // An explicit 0 is no prior: what runs saved before the option hold.
        assert_eq!(prior(&["--location-step-prior", "0"]), None);
    }

    #[test]
    fn out_of_range_numbers_are_refused_at_parse_time_naming_the_flag() {
        let refused = |args: &[&str]| {
            let argv = ["ntg"].iter().chain(args);
            Cli::try_parse_from(argv).unwrap_err().render().to_string()
        };
        for (args, flag) in [
            (&["train", "--out", "r", "--lr", "NaN"][..], "--lr"),
            (&["train", "--out", "r", "--lr", "inf"][..], "--lr"),
            (&["train", "--out", "r", "--lr=-1"][..], "--lr"),
            (&["train", "--out", "r", "--epochs", "0"][..], "--epochs"),
            (
                &["train", "--out", "r", "--batch-size", "0"][..],
                "--batch-size",
            ),
            (
                &["train", "--out", "r", "--train-tasks", "0"][..],
                "--train-tasks",
            ),
            (
                &["train", "--out", "r", "--retry-weight", "NaN"][..],
                "--retry-weight",
            ),
            (
                &["train", "--out", "r", "--token-dropout", "1"][..],
                "--token-dropout",
            ),
            (
                &["train", "--out", "r", "--location-step-prior", "inf"][..],
                "--location-step-prior",
            ),
            (
                &["eval", "--run", "r", "--test-tasks", "0"][..],
                "--test-tasks",
            ),
            (
                &["eval", "--run", "r", "--edge-threshold", "2"][..],
                "--edge-threshold",
            ),
            (
                &[
                    "blocks",
                    "demo",
                    "--task",
                    "1",
                    "--out",
                    "d",
                    "--columns",
                    "0",
                ][..],
                "--columns",
            ),
            (
                &[
                    "blocks", "demo", "--task", "1", "--out", "d", "--scale", "0",
                ][..],
                "--scale",
            ),
            (
                &["train", "--out", "r", "--obs", "vid", "--encoder-lr", "NaN"][..],
                "--encoder-lr",
            ),
        ] {
            let err = refused(args);
            assert!(err.contains(flag), "{args:?}: {err}");
        }
    }

    #[test]
    fn too_many_training_tasks_are_refused_before_the_run_folder_exists() {
        let tmp = tempfile::tempdir().unwrap();
        for domain in ["blocks", "collect"] {
            let out = tmp.path().join(domain);
            let out_arg = out.to_str().unwrap();
            let argv = [
                "ntg",
                "train",
                "--domain",
                domain,
                "--train-tasks",
                "5000",
                "--out",
                out_arg,
            ];
            let Command::Train(args) = Cli::try_parse_from(argv).unwrap().command else {
                panic!("not ntg train");
            };
            let err = format!("{:#}", super::run_train(&args).unwrap_err());
            assert!(err.contains("5000"), "{domain}: {err}");
            assert!(!out.exists(), "{domain}: the run folder was created");
        }
    }
}
