//! `ntg train` and `ntg eval`.

use std::path::PathBuf;

use anyhow::{Context, bail};
use clap::{Args, ValueEnum};
use ntg_model::NtgModel;

use crate::blocks::{self, BlocksRunConfig, ObsKind, Recipe, Variant};
use crate::fit::OptimConfig;
use crate::run_dir::RunDir;

/// Task domains `ntg train` knows.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum Domain {
    /// Block stacking (the paper's main experiment).
    Blocks,
    /// Object collection (fig. "thor_all"): NTG or the Flat Policy.
    Collect,
}

/// Arguments of `ntg train`.
#[derive(Debug, Args)]
pub struct TrainArgs {
    /// Task domain.
    #[arg(long, value_enum, default_value_t = Domain::Blocks)]
    pub domain: Domain,
    /// Block stacking: the training recipe the other options add to.
    #[arg(long, value_enum, default_value_t = Recipe::Recommended)]
    pub recipe: Recipe,
    /// Observation kind.
    #[arg(long, value_enum, default_value_t = ObsKind::State)]
    pub obs: ObsKind,
    /// Training tasks (blocks: a prefix of the standard 1000-task pool;
    /// collect: distinct training tasks per number of objects).
    #[arg(long, default_value_t = 100)]
    pub train_tasks: usize,
    /// Options only `--domain collect` reads.
    #[command(flatten)]
    pub collect: super::collect::CollectTrainArgs,
    /// Expert demonstrations per training task.
    #[arg(long, default_value_t = 20)]
    pub demos_per_task: usize,
    /// Passes over the demonstrations.
    #[arg(long, default_value_t = 20)]
    pub epochs: usize,
    /// Demonstrations per optimisation step.
    #[arg(long, default_value_t = 32)]
    pub batch_size: usize,
    /// Adam learning rate [default: 3e-3 with --recipe recommended, else
    /// 1e-3].
    #[arg(long)]
    pub lr: Option<f64>,
    /// Seed of the weights and the shuffling.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Train the edge classifier on GCN embeddings of another demo of the
    /// same task than the one it imitates.
    #[arg(long)]
    pub gcn_from_other_demo: bool,
    /// Decay the learning rate along a half cosine to a tenth of --lr.
    #[arg(long)]
    pub cosine_decay: bool,
    /// Probability that the demo interpreter's decoder reads `<start>`
    /// instead of the previous action in training (0 = plain teacher forcing).
    #[arg(long, default_value_t = 0.0)]
    pub token_dropout: f32,
    /// The localizer's and edge classifier's state encoders also read every
    /// pairwise difference of cube positions.
    #[arg(long)]
    pub pairwise: bool,
    /// Hidden layers of the localizer's and edge classifier's state encoder
    /// MLPs (state observations only; the demo interpreter keeps one)
    /// [default: 3 with --recipe recommended, else 1].
    #[arg(long)]
    pub state_hidden_layers: Option<usize>,
    /// Held-out validation tasks scored after every epoch; the epoch that
    /// scores best is the run's result (`best/`). 0 = keep the last epoch.
    #[arg(long, default_value_t = 100)]
    pub validation_tasks: usize,
    /// Score the validation tasks after every this many epochs (and after
    /// the last).
    #[arg(long, default_value_t = 1)]
    pub validate_every: usize,
    /// Train on demos whose cubes are renamed by a random permutation per
    /// demo and step (block stacking, state observations; not in the paper).
    #[arg(long)]
    pub permute_objects: bool,
    /// Hidden width of a fusion layer between the edge classifier's inputs
    /// and its query (0 = the paper's linear W; not in the paper)
    /// [default: 256 with --recipe recommended, else 0].
    #[arg(long)]
    pub edge_fusion_hidden: Option<usize>,
    /// Weight of recovery steps (the next action repeats one already taken)
    /// in the edge classifier's loss (1 = unweighted; not in the paper).
    #[arg(long, default_value_t = 1.0)]
    pub retry_weight: f32,
    /// Keep the edge classifier's loss out of the GCN, which then learns
    /// only to complete task graphs (not in the paper).
    #[arg(long)]
    pub detach_gcn_from_edges: bool,
    /// Weigh edges by the completed graph's probabilities instead of
    /// cutting them to the graph thresholded at 0.5 (trained the same way).
    #[arg(long)]
    pub soft_edges: bool,
    /// Turn stochastic grasp/drop failures off (they are on by default).
    #[arg(long)]
    pub no_failures: bool,
    /// Run folder to create (or, with --resume, to continue).
    #[arg(long)]
    pub out: PathBuf,
    /// Continue the run in --out from its last checkpoint.
    #[arg(long)]
    pub resume: bool,
}

impl TrainArgs {
    /// The block-stacking run configuration these arguments describe: the
    /// recipe, with the boolean flags added and the numbers overridden.
    pub fn config(&self) -> BlocksRunConfig {
        let base = self.recipe.config(
            self.obs,
            self.train_tasks,
            self.demos_per_task,
            self.epochs,
            self.seed,
        );
        BlocksRunConfig {
            failures: !self.no_failures,
            state_hidden_layers: self.state_hidden_layers.unwrap_or(base.state_hidden_layers),
            pairwise: base.pairwise || self.pairwise,
            validation_tasks: self.validation_tasks,
            validate_every: self.validate_every,
            permute_objects: base.permute_objects || self.permute_objects,
            // Renamed demos never show a held-out task (new runs always).
            exclude_held_out_renamings: base.permute_objects || self.permute_objects,
            edge_fusion_hidden: self.edge_fusion_hidden.unwrap_or(base.edge_fusion_hidden),
            retry_weight: self.retry_weight,
            detach_gcn_from_edges: base.detach_gcn_from_edges || self.detach_gcn_from_edges,
            soft_edges: base.soft_edges || self.soft_edges,
            optim: OptimConfig {
                batch_size: self.batch_size,
                learning_rate: self.lr.unwrap_or(base.optim.learning_rate),
                token_dropout: self.token_dropout,
                cosine_decay: base.optim.cosine_decay || self.cosine_decay,
                gcn_from_other_demo: base.optim.gcn_from_other_demo || self.gcn_from_other_demo,
                ..base.optim
            },
            ..base
        }
    }
}

/// Runs `ntg train`.
pub fn run_train(args: &TrainArgs) -> anyhow::Result<()> {
    if args.domain == Domain::Collect {
        return train_collect(args);
    }
    let config = args.config();
    if !args.resume {
        if config.train_tasks == 0 || config.demos_per_task == 0 {
            bail!("--train-tasks and --demos-per-task must be positive");
        }
        if config.permute_objects && config.obs != ObsKind::State {
            bail!(
                "--permute-objects renames cubes in state observations; it does not apply to --obs vid"
            );
        }
        if !(0.0..1.0).contains(&config.optim.token_dropout) {
            bail!(
                "--token-dropout must be in [0, 1), got {}",
                config.optim.token_dropout
            );
        }
    }
    let run = RunDir::start_or_resume(
        &args.out,
        &config,
        args.resume,
        "runs started before --recipe existed need --recipe paper; ",
    )?;
    let device = ntg_model::cpu_device().autodiff();
    eprintln!(
        "training NTG ({:?} observations) on {} tasks x {} demos for {} epochs -> {}",
        config.obs,
        config.train_tasks,
        config.demos_per_task,
        config.optim.epochs,
        run.root().display()
    );
    blocks::train_run(&run, &config, &device, |m| eprintln!("{}", m.log_line()))?;
    match crate::fit::selected_epoch(&run)? {
        Some(best) => eprintln!(
            "done: epoch {} scored best on the validation tasks (success {:.3}, goals met {:.3}); its weights are in {}",
            best.epoch,
            best.score.success,
            best.score.goal_fraction,
            run.best_dir().display()
        ),
        None => eprintln!("done: weights in {}", run.checkpoint_dir().display()),
    }
    Ok(())
}

/// `ntg train --domain collect`: trains NTG or the Flat Policy on tasks
/// with `--objects` targets (`--train-tasks` distinct tasks per N).
fn train_collect(args: &TrainArgs) -> anyhow::Result<()> {
    let c = &args.collect;
    let mut config = crate::collect::CollectRunConfig::new(
        c.method,
        args.obs,
        c.objects.clone(),
        args.train_tasks,
        args.demos_per_task,
        args.epochs,
        args.seed,
    );
    config.segments = !c.no_segments;
    config.learn_end = c.learn_end;
    config.memory = c.memory;
    config.interpreter = c.interpreter;
    config.location_step_prior = c.location_step_prior();
    config.optim.batch_size = args.batch_size;
    config.optim.learning_rate = args.lr.unwrap_or(crate::fit::PAPER_LEARNING_RATE);
    config.optim.cosine_decay = args.cosine_decay;
    config.validate()?;
    let run = RunDir::start_or_resume(&args.out, &config, args.resume, "")?;
    eprintln!(
        "training {} ({:?} observations) on N = {:?}, {} tasks per N x {} demos, {} epochs -> {}",
        config.method.name(),
        config.obs,
        config.train_objects,
        config.tasks_per_n,
        config.demos_per_task,
        config.optim.epochs,
        run.root().display()
    );
    let device = ntg_model::cpu_device().autodiff();
    crate::collect::train_run(&run, &config, &device, |line| eprintln!("{line}"))?;
    eprintln!("done: weights in {}", run.checkpoint_dir().display());
    Ok(())
}

/// `ntg eval` on a collect run: success per N = 1..5 on `--test-tasks`
/// unseen test episodes each; writes `eval/collect-<K>.json`.
fn eval_collect(
    run: &RunDir,
    config: &crate::collect::CollectRunConfig,
    args: &EvalArgs,
) -> anyhow::Result<()> {
    if args.split != EvalSplit::Test {
        anyhow::bail!(
            "--split validation is for block-stacking runs; object collection evaluates its test episodes"
        );
    }
    let model = crate::collect::load_model(run, config)?;
    let result = crate::collect::evaluate(
        model.as_ref(),
        config.method,
        config.obs,
        &crate::collect::EVAL_OBJECTS,
        args.test_tasks,
    )?;
    std::fs::create_dir_all(run.eval_dir())?;
    let path = run
        .eval_dir()
        .join(format!("collect-{}.json", args.test_tasks));
    RunDir::write_json(&path, &result)?;
    for p in &result.points {
        let s = p.success;
        println!(
            "{} N = {}: success {}/{} = {:.3} (95% CI {:.3}-{:.3})",
            config.method.name(),
            p.objects,
            s.successes,
            s.trials,
            s.rate,
            s.ci_low,
            s.ci_high
        );
    }
    println!("records in {}", path.display());
    Ok(())
}

/// Arguments of `ntg eval`.
#[derive(Debug, Args)]
pub struct EvalArgs {
    /// Run folder written by `ntg train`.
    #[arg(long)]
    pub run: PathBuf,
    /// Number of unseen test tasks (blocks: from the start of the standard
    /// test set; collect: test episodes per number of objects).
    #[arg(long, default_value_t = 100)]
    pub test_tasks: usize,
    /// Which policy to evaluate.
    #[arg(long, value_enum, default_value_t = Variant::Full)]
    pub variant: Variant,
    /// Keep GCN edges with probability at least this (default: the
    /// model's configured threshold, 0.5).
    #[arg(long)]
    pub edge_threshold: Option<f32>,
    /// Which tasks to evaluate on (blocks): the test set, or the held-out
    /// validation tasks, where settings such as --edge-threshold can be
    /// chosen without looking at the test set.
    #[arg(long, value_enum, default_value_t = EvalSplit::Test)]
    pub split: EvalSplit,
}

/// Task sets `ntg eval` can use.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum EvalSplit {
    /// The standard test set (the reported numbers).
    Test,
    /// The validation tasks (`env_blocks::validation_tasks`).
    Validation,
}

/// Loads the trained model of `run` (the epoch selected on validation
/// tasks if there is one, else the last checkpoint), with its edge
/// threshold overridden when `edge_threshold` is given (checked to lie in
/// [0, 1]).
pub fn load_trained(
    run: &RunDir,
    edge_threshold: Option<f32>,
    device: &burn::tensor::Device,
) -> anyhow::Result<NtgModel> {
    let dir = match crate::fit::selected_epoch(run)? {
        Some(_) => run.best_dir(),
        None => run.checkpoint_dir(),
    };
    let mut model = NtgModel::load(dir, device)
        .with_context(|| format!("loading the trained model of {}", run.root().display()))?;
    if let Some(t) = edge_threshold {
        if !(0.0..=1.0).contains(&t) {
            bail!("--edge-threshold must be in [0, 1], got {t}");
        }
        model.config.edge_threshold = t;
    }
    Ok(model)
}

/// Runs `ntg eval`: prints the success rate and writes
/// `eval/<variant>-<K>.json` in the run folder.
pub fn run_eval(args: &EvalArgs) -> anyhow::Result<()> {
    let run = RunDir::open(&args.run)?;
    if let Ok(config) = RunDir::read_json::<crate::collect::CollectRunConfig>(&run.config_path()) {
        return eval_collect(&run, &config, args);
    }
    let config: BlocksRunConfig = RunDir::read_json(&run.config_path())?;
    let device = ntg_model::cpu_device();
    let model = load_trained(&run, args.edge_threshold, &device)?;
    let mut name = format!("{}-{}", args.variant.name(), args.test_tasks);
    if let Some(t) = args.edge_threshold {
        name.push_str(&format!("-threshold{t}"));
    }
    let result = match args.split {
        EvalSplit::Test => blocks::evaluate(
            &model,
            config.obs,
            config.failures,
            args.test_tasks,
            args.variant,
        )?,
        EvalSplit::Validation => {
            name.insert_str(0, "validation-");
            blocks::evaluate_tasks(
                &model,
                config.obs,
                config.failures,
                &env_blocks::validation_tasks(args.test_tasks)?,
                blocks::Seeds::VALIDATION,
                args.variant,
            )?
        }
    };
    std::fs::create_dir_all(run.eval_dir())?;
    let path = run.eval_dir().join(format!("{name}.json"));
    RunDir::write_json(&path, &result)?;
    let s = result.success;
    println!(
        "{}: success {}/{} = {:.3} (95% CI {:.3}-{:.3}); goals met {:.3}; records in {}",
        result.variant,
        s.successes,
        s.trials,
        s.rate,
        s.ci_low,
        s.ci_high,
        result.mean_goal_fraction,
        path.display()
    );
    Ok(())
}

/// Arguments of `ntg reproduce`.
#[derive(Debug, Args)]
pub struct ReproduceArgs {
    /// Experiment scale.
    #[arg(long, value_enum, default_value_t = crate::spec::Profile::Quick)]
    pub profile: crate::spec::Profile,
    /// Where run folders go (finished runs are reused).
    #[arg(long, default_value = "runs/figures")]
    pub runs: PathBuf,
    /// Where figures, results.json and REPORT.md go.
    #[arg(long, default_value = "docs/figures")]
    pub out: PathBuf,
    /// Run fig. "jigsaws" on this JIGSAWS copy instead of the synthetic
    /// stand-in.
    #[arg(long, value_name = "DIR")]
    pub jigsaws_root: Option<PathBuf>,
    /// Read the figures' experiment files (`ntp_exp.toml`,
    /// `thor_all.toml`) from this folder instead of the copies built in
    /// (`crates/ntg-trainer/experiments/`).
    #[arg(long, value_name = "DIR")]
    pub experiments: Option<PathBuf>,
}

/// Runs `ntg reproduce`.
pub fn run_reproduce(args: &ReproduceArgs) -> anyhow::Result<()> {
    let runs = args.runs.join(
        serde_json::to_value(args.profile)?
            .as_str()
            .unwrap_or("profile"),
    );
    let results = crate::reproduce::reproduce(
        args.profile,
        &runs,
        &args.out,
        args.jigsaws_root.as_deref(),
        match &args.experiments {
            Some(dir) => crate::experiment::Source::Dir(dir),
            None => crate::experiment::Source::BuiltIn,
        },
    )?;
    println!(
        "wrote {} (figure ntp_exp: {} points)",
        args.out.display(),
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

    use super::*;
    use crate::cli::{Cli, Command};

    fn config_of(args: &[&str]) -> BlocksRunConfig {
        let argv = ["ntg", "train", "--out", "run"].iter().chain(args);
        match Cli::try_parse_from(argv).unwrap().command {
            Command::Train(train) => train.config(),
            other => panic!("parsed as {other:?}"),
        }
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
        assert_eq!((c.edge_fusion_hidden, c.detach_gcn_from_edges), (256, true));
        assert!(c.soft_edges && c.exclude_held_out_renamings);
        assert_eq!(c.optim.learning_rate, 3e-3);
        assert!(c.optim.cosine_decay && c.optim.gcn_from_other_demo);
        let c = config_of(&["--edge-fusion-hidden", "0", "--state-hidden-layers", "2"]);
        assert_eq!((c.edge_fusion_hidden, c.state_hidden_layers), (0, 2));
        // Frames have no per-cube columns to rename.
        assert!(!config_of(&["--obs", "vid"]).permute_objects);
    }

    #[test]
    fn collect_location_step_prior_defaults_per_method_and_interpreter() {
        let prior = |args: &[&str]| {
            let argv = ["ntg", "train", "--domain", "collect", "--out", "run"]
                .iter()
                .chain(args);
            match Cli::try_parse_from(argv).unwrap().command {
                Command::Train(train) => train.collect.location_step_prior(),
                other => panic!("parsed as {other:?}"),
            }
        };
        assert_eq!(prior(&[]), Some(crate::collect::LOCATION_STEP_PRIOR));
        assert_eq!(prior(&["--method", "flat"]), None);
        assert_eq!(prior(&["--interpreter", "luong"]), None);
        assert_eq!(prior(&["--location-step-prior", "0.5"]), Some(0.5));
        // An explicit 0 is no prior: what runs saved before the option hold.
        assert_eq!(prior(&["--location-step-prior", "0"]), None);
    }
}
