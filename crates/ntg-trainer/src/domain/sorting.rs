//! Object sorting (fig. "ablation" (b)): eight objects of four categories go
//! into the bins their categories map to (`env_blocks::sorting`), state
//! input. NTG is trained on demos of whole sortings; each test scene starts
//! with some objects already in their bins (a half-done task, as after a
//! recovery), so the order it needs differs from the conditioning demo's:
//! the executor must leave the demo's path, which only the GCN's added
//! edges allow and only the edge classifier can choose among.
//!
//! The 256 sorting tasks (every category → bin map, `standard_sort_tasks`)
//! split by map: the first [`TRAIN_POOL`] train (a run takes a prefix),
//! the next [`VALIDATION_TASKS`] select epochs, the last [`TEST_TASKS`] are
//! the unseen test maps.

use anyhow::{Context, bail};
use burn::tensor::Device;
use ctg_graph::{ActionId, Vocabulary};
use env_blocks::{BlocksEnv, BlocksExpert, BlocksObservation, EnvConfig, SortTask};
use serde::{Deserialize, Serialize};

use crate::domain::{
    Domain, DomainFlags, DomainRuns, Episode, EpisodeRecord, EvalFlags, TrainFlags,
};
use crate::fit::{OptimConfig, ValidationScore};
use crate::method::MethodId;
use crate::method::input::Validation;
use crate::method::ntg::{Ntg, Variant};
use crate::method::{Demos, EpochReport, Method, TrainInput, TrainedPolicy};
use crate::run_dir::RunDir;
use crate::spec::ObsKind;
use crate::stats::SuccessRate;
use ntg_model::NtgModel;

/// Sorting tasks a run may train on (a prefix of the standard list).
pub const TRAIN_POOL: usize = 200;
/// Sorting tasks held out for epoch selection (after the pool).
pub const VALIDATION_TASKS: usize = 16;
/// Unseen test sorting tasks (the last of the standard list).
pub const TEST_TASKS: usize = 40;
/// Step limit of an episode in new runs: 16 actions sort the eight
/// objects; grasp slips and missed drops add retries (block stacking's
/// limit of 40 cut expert demos short; 64 cut one of the paper profile's
/// 20,000, which turned out to be a livelock of the bins, since fixed in
/// env-blocks' `World::move_point`).
pub const STEP_LIMIT: usize = 128;

/// The step limit of runs saved before it was in their configuration.
fn first_step_limit() -> usize {
    64
}
/// Seed base of training demos (demo `j` of task `t`: `+ 1000 t + j`).
const TRAIN_SEED_BASE: u64 = 5_000_000;
/// Seed bases of the validation episodes: conditioning demo, rollout
/// scene, and which objects start sorted.
pub const VALIDATION_SEEDS: [u64; 3] = [6_000_000, 6_500_000, 6_700_000];
/// Seed bases of the test episodes (as [`VALIDATION_SEEDS`]).
pub const TEST_SEEDS: [u64; 3] = [7_000_000, 7_500_000, 7_700_000];

/// Everything that defines a sorting run (`config.json`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SortingRunConfig {
    /// Always `"sorting"` (tells `ntg eval` which domain a run is).
    pub domain: String,
    /// Training tasks (a prefix of the [`TRAIN_POOL`]).
    pub train_tasks: usize,
    /// Expert demonstrations per training task (each sorts every object,
    /// in an order of its own).
    pub demos_per_task: usize,
    /// Stochastic grasp and drop failures in demos and rollouts.
    pub failures: bool,
    /// Seed of the model's initial weights.
    pub model_seed: u64,
    /// Hidden layers of the localizer's and edge classifier's state
    /// encoders (the demo interpreter keeps one).
    pub state_hidden_layers: usize,
    /// Those encoders also read every pairwise object-position difference.
    pub pairwise: bool,
    /// Validation episodes scored to select the epoch (0 = the last).
    pub validation_episodes: usize,
    /// Validate after every this many epochs (and after the last).
    pub validate_every: usize,
    /// The part of NTG trained and evaluated without (`full` = none).
    #[serde(default, skip_serializing_if = "Variant::is_full")]
    pub ablation: Variant,
    /// Step limit of every demo and rollout ([`STEP_LIMIT`] in new runs;
    /// runs saved before it: 64).
    #[serde(default = "first_step_limit")]
    pub step_limit: usize,
    /// Optimisation.
    pub optim: OptimConfig,
}

impl SortingRunConfig {
    /// Checks what serde cannot.
    pub fn validate(&self) -> anyhow::Result<()> {
        if self.domain != "sorting" {
            bail!("domain is {:?}, not \"sorting\"", self.domain);
        }
        if self.train_tasks == 0 || self.train_tasks > TRAIN_POOL {
            bail!(
                "--train-tasks {}: object sorting trains on 1 to {TRAIN_POOL} of its 256 tasks",
                self.train_tasks
            );
        }
        if !self.ablation.trains() {
            bail!(
                "ablation {}: a run is trained full or without one part",
                self.ablation.name()
            );
        }
        Ok(())
    }
}

/// The domain: sorting tasks seen through their state.
pub struct SortingDomain {
    env_config: EnvConfig,
    vocabulary: Vocabulary,
}

impl SortingDomain {
    /// Sorting, with stochastic failures on or off, episodes cut at
    /// `step_limit` actions.
    pub fn new(failures: bool, step_limit: usize) -> Self {
        let mut env_config = crate::block_world::env_config(ObsKind::State, failures);
        env_config.max_steps = Some(step_limit);
        SortingDomain {
            env_config,
            vocabulary: env_blocks::vocabulary(true, env_blocks::ActionLevel::Flat),
        }
    }
}

impl SortingDomain {
    /// The same domain with every observation's frame rendered (for
    /// figures; rendering draws no random numbers, so episodes are
    /// unchanged).
    pub fn rendering(failures: bool, step_limit: usize) -> Self {
        let mut domain = SortingDomain::new(failures, step_limit);
        domain.env_config.render = true;
        domain
    }
}

impl Domain for SortingDomain {
    type Task = SortTask;
    type Env = BlocksEnv;
    type Expert = BlocksExpert;

    fn vocabulary(&self) -> &Vocabulary {
        &self.vocabulary
    }
    fn env(&self, task: &SortTask) -> anyhow::Result<BlocksEnv> {
        Ok(BlocksEnv::sorting(task.clone(), self.env_config)?)
    }
    fn expert(&self) -> BlocksExpert {
        BlocksExpert::new()
    }
    fn obs_kind(&self) -> ObsKind {
        ObsKind::State
    }
    fn obs_dim(&self) -> usize {
        env_blocks::STATE_DIM
    }
    fn featurize(&self, observation: &BlocksObservation) -> Vec<f32> {
        observation.state().to_vec()
    }
    fn task_name(&self, task: &SortTask) -> String {
        match task.presorted.len() {
            0 => task.id.clone(),
            k => format!("{} ({k} presorted)", task.id),
        }
    }
    fn goals(&self, task: &SortTask, env: &BlocksEnv) -> (usize, usize) {
        let n = env_blocks::world::NUM_OBJECTS;
        let met = (0..n)
            .filter(|&o| env.world().in_bin(o, task.bin_of(o)))
            .count();
        (met, n)
    }
    /// The demo sorts the whole scene, whatever the rollout's scene has
    /// presorted: the order the policy needs differs from the demo's.
    fn record_demo(
        &self,
        _env: &mut BlocksEnv,
        task: &SortTask,
        seed: u64,
    ) -> anyhow::Result<(Vec<Vec<f32>>, Vec<ActionId>)> {
        let whole = SortTask {
            presorted: Vec::new(),
            ..task.clone()
        };
        crate::domain::record_keyframes(self, &mut self.env(&whole)?, seed)
    }
}

/// The three parts of the standard sorting tasks: training pool,
/// validation, test.
pub fn split() -> anyhow::Result<(Vec<SortTask>, Vec<SortTask>, Vec<SortTask>)> {
    let mut tasks = env_blocks::standard_sort_tasks()?;
    let test = tasks.split_off(tasks.len() - TEST_TASKS);
    let validation = tasks.split_off(TRAIN_POOL);
    anyhow::ensure!(
        validation.len() == VALIDATION_TASKS,
        "the standard sorting tasks changed size"
    );
    Ok((tasks, validation, test))
}

/// `count` evaluation episodes over `tasks` (cycling through them): each
/// rollout scene starts with 2 to 4 objects already in their bins (drawn
/// from the episode's seed), the conditioning demo sorts a whole scene.
pub fn episodes(tasks: &[SortTask], count: usize, seeds: [u64; 3]) -> Vec<Episode<SortTask>> {
    (0..count)
        .map(|i| {
            let task = &tasks[i % tasks.len()];
            Episode {
                group: 0,
                index: i,
                task: task.with_random_presorted(2 + i % 3, seeds[2] + i as u64),
                demo_seed: seeds[0] + i as u64,
                rollout_seed: seeds[1] + i as u64,
            }
        })
        .collect()
}

/// The encoders of a sorting run's state rows: the demo interpreter's
/// plain, the localizer's and edge classifier's as the run says.
pub fn encoders(config: &SortingRunConfig) -> crate::method::RowEncoders {
    let state = |layers, pairwise| crate::block_world::encoder(ObsKind::State, layers, pairwise);
    crate::method::RowEncoders {
        sequence: state(1, false),
        observation: state(config.state_hidden_layers, config.pairwise),
    }
}

/// Success and goals met of `model` on `episodes` (its ablation as
/// trained, the policy variant `variant` on top).
pub fn evaluate(
    model: &NtgModel,
    config: &SortingRunConfig,
    episodes: &[Episode<SortTask>],
    variant: Variant,
) -> anyhow::Result<SortingResult> {
    let mut model = model.clone();
    model.config.ablation = variant.ablation_of(&model.config.ablation);
    let records = crate::domain::evaluate(
        &SortingDomain::new(config.failures, config.step_limit),
        &model,
        episodes,
    )?;
    Ok(SortingResult {
        variant: variant.name().to_owned(),
        success: crate::domain::success_rate(&records),
        goal_fraction: crate::domain::mean_goal_fraction(&records),
        episodes: records,
    })
}

/// One evaluation of a sorting run (`eval/*.json`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SortingResult {
    /// The policy variant evaluated.
    pub variant: String,
    /// Episodes whose every object ended in its bin.
    pub success: SuccessRate,
    /// Mean fraction of objects in their bins at the end.
    pub goal_fraction: f64,
    /// Every episode.
    pub episodes: Vec<EpisodeRecord>,
}

/// Trains (or resumes) a sorting run, selecting the epoch on validation
/// episodes (presorted scenes of the validation tasks).
pub fn train_run(
    run: &RunDir,
    config: &SortingRunConfig,
    device: &Device,
    mut on_epoch: impl FnMut(&EpochReport),
) -> anyhow::Result<NtgModel> {
    // One writer from the first cache this run builds (demos, frame
    // embeddings, stages) to its last epoch, not only during epochs.
    let _writer = run.lock()?;
    config.validate()?;
    let (pool, validation, _) = split()?;
    let tasks = &pool[..config.train_tasks];
    let domain = SortingDomain::new(config.failures, config.step_limit);
    let demos = || {
        let dataset = crate::dataset::DemoDataset::load_or_build(&run.dataset_dir(), || {
            crate::domain::record_demos(&domain, tasks, config.demos_per_task, TRAIN_SEED_BASE)
        })?;
        Ok(Demos {
            dataset,
            frames: None,
        })
    };
    let validation = episodes(&validation, config.validation_episodes, VALIDATION_SEEDS);
    let score = |model: &dyn TrainedPolicy| {
        let records = crate::domain::evaluate(&domain, model, &validation)?;
        Ok(ValidationScore {
            success: crate::domain::success_rate(&records).rate,
            goal_fraction: crate::domain::mean_goal_fraction(&records),
        })
    };
    let input = TrainInput {
        vocabulary: domain.vocabulary(),
        demos: &demos,
        encoders: encoders(config),
        renaming: None,
        validation: (!validation.is_empty()).then_some(Validation {
            score: &score,
            every: config.validate_every,
        }),
        other_demo_each_epoch: false,
        model_seed: config.model_seed,
        optim: &config.optim,
        run,
        device,
        extension: None,
    };
    let model = Ntg.train(input, &serde_json::to_value(config)?, &mut on_epoch)?;
    model
        .as_any()
        .downcast_ref::<NtgModel>()
        .cloned()
        .context("object sorting trains NTG on state rows")
}

/// The run's selected (or last) model.
pub fn load_model(run: &RunDir, device: &Device) -> anyhow::Result<NtgModel> {
    let dir = match crate::fit::selected_epoch(run)? {
        Some(_) => run.best_dir(),
        None => run.checkpoint_dir(),
    };
    NtgModel::load(&dir, device)
        .with_context(|| format!("loading the trained model of {}", run.root().display()))
}

/// Object sorting's own `ntg train` flags.
#[derive(Debug, Clone, clap::Args)]
#[command(next_help_heading = "Object sorting (--domain sorting)")]
pub struct SortingFlags {
    /// Validation episodes (presorted scenes of the 16 validation tasks)
    /// scored after every epoch; the best epoch is the run's result.
    #[arg(long, default_value_t = 48)]
    pub validation_episodes: usize,
}

/// Object sorting in the domain registry (`ntg train --domain sorting`,
/// `ntg eval` on its runs).
pub struct Sorting;

impl DomainRuns for Sorting {
    fn name(&self) -> &'static str {
        "sorting"
    }

    fn train(&self, flags: &TrainFlags, own: &DomainFlags) -> anyhow::Result<()> {
        if flags.method != MethodId::Ntg || flags.obs != ObsKind::State {
            bail!("object sorting trains NTG on state input (--method ntg --obs state)");
        }
        flags.check_encoder_flags()?;
        if flags.interpreter.is_some() || flags.location_step_prior.is_some() {
            bail!(
                "--interpreter and --location-step-prior are block stacking's and object collection's; object sorting trains the paper's interpreter"
            );
        }
        if flags.memory {
            bail!(
                "--memory is block stacking's and object collection's; object sorting trains NTG without an execution memory"
            );
        }
        let own = &own.sorting;
        let config = SortingRunConfig {
            domain: "sorting".into(),
            train_tasks: flags.train_tasks,
            demos_per_task: flags.demos_per_task,
            failures: true,
            model_seed: flags.seed,
            state_hidden_layers: 3,
            pairwise: true,
            validation_episodes: own.validation_episodes,
            validate_every: 1,
            ablation: flags.ablation,
            step_limit: STEP_LIMIT,
            optim: OptimConfig {
                epochs: flags.epochs,
                batch_size: flags.batch_size,
                learning_rate: flags.lr.unwrap_or(3e-3),
                seed: flags.seed,
                token_dropout: 0.0,
                cosine_decay: flags.cosine_decay,
                shards: flags.shards,
                gcn_from_other_demo: false,
            },
        };
        config.validate()?;
        let run = RunDir::start_or_resume(&flags.out, &config, flags.resume, "")?;
        eprintln!(
            "training NTG{} on {} sorting tasks x {} demos for {} epochs -> {}",
            match config.ablation {
                Variant::Full => String::new(),
                a => format!(" ({})", a.name()),
            },
            config.train_tasks,
            config.demos_per_task,
            config.optim.epochs,
            run.root().display()
        );
        let device = crate::spec::device().autodiff();
        train_run(&run, &config, &device, |r| eprintln!("{r}"))?;
        println!("done: weights in {}", run.checkpoint_dir().display());
        Ok(())
    }

    fn owns(&self, config: &serde_json::Value) -> bool {
        config.get("domain").and_then(serde_json::Value::as_str) == Some("sorting")
    }

    fn evaluate(&self, run: &RunDir, flags: &EvalFlags) -> anyhow::Result<()> {
        let config: SortingRunConfig = RunDir::read_json(&run.config_path())?;
        if flags.edge_threshold.is_some()
            || matches!(
                flags.split,
                crate::domain::EvalSplit::Seen | crate::domain::EvalSplit::Structure
            )
        {
            bail!("object sorting evaluates --split test or validation, without --edge-threshold");
        }
        anyhow::ensure!(
            !flags.decisions,
            "--decisions checks an NTP baseline's decisions (block stacking); {} is not one",
            run.root().display()
        );
        anyhow::ensure!(
            flags.tasks.is_none(),
            "--tasks reads block-stacking tasks (NTP's format); {} is an object-sorting run",
            run.root().display()
        );
        let model = load_model(run, &crate::spec::device())?;
        let (_, validation, test) = split()?;
        let (tasks, seeds, split_name) = match flags.split {
            crate::domain::EvalSplit::Validation => (validation, VALIDATION_SEEDS, "validation"),
            _ => (test, TEST_SEEDS, "test"),
        };
        let result = evaluate(
            &model,
            &config,
            &episodes(&tasks, flags.test_tasks, seeds),
            flags.variant,
        )?;
        let name = match flags.split {
            crate::domain::EvalSplit::Validation => "validation-",
            _ => "",
        };
        let recorded = super::record_eval(
            run,
            &format!("{name}{}-{}.json", flags.variant.name(), flags.test_tasks),
            &result,
        );
        let s = result.success;
        println!(
            "{} ({split_name}, scenes with 2-4 objects presorted): success {}/{} = {:.3} (95% CI {:.3}-{:.3}); objects sorted {:.3}; {recorded}",
            flags.variant.name(),
            s.successes,
            s.trials,
            s.rate,
            s.ci_low,
            s.ci_high,
            result.goal_fraction,
        );
        Ok(())
    }
    fn trained(&self, run: &RunDir) -> anyhow::Result<super::TrainedRun> {
        let model = load_model(run, &crate::spec::device())?;
        Ok(super::TrainedRun {
            model: Box::new(model),
            dir: crate::fit::trained_dir(run)?,
            method: MethodId::Ntg.name(),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_split_is_disjoint_and_test_scenes_start_part_sorted() {
        let (pool, validation, test) = split().unwrap();
        assert_eq!(
            (pool.len(), validation.len(), test.len()),
            (TRAIN_POOL, VALIDATION_TASKS, TEST_TASKS)
        );
        let maps: std::collections::HashSet<_> = pool
            .iter()
            .chain(&validation)
            .chain(&test)
            .map(|t| t.bin_of_category)
            .collect();
        assert_eq!(maps.len(), 256, "every map once");
        let eps = episodes(&test, 6, TEST_SEEDS);
        assert_eq!(
            eps.iter()
                .map(|e| e.task.presorted.len())
                .collect::<Vec<_>>(),
            vec![2, 3, 4, 2, 3, 4]
        );
        assert_eq!(eps[0].task.bin_of_category, test[0].bin_of_category);
        assert_eq!(eps, episodes(&test, 6, TEST_SEEDS), "seeded");
    }

    #[test]
    fn the_expert_finishes_a_part_sorted_scene_in_another_order_than_its_demo() {
        // What the test episodes ask: the demo (a whole scene) and the
        // expert's own rollout of the presorted scene differ, and the
        // expert completes the latter.
        let domain = SortingDomain::new(false, STEP_LIMIT);
        let (_, _, test) = split().unwrap();
        let episode = &episodes(&test, 1, TEST_SEEDS)[0];
        let mut env = domain.env(&episode.task).unwrap();
        let (rows, demo) = domain
            .record_demo(&mut env, &episode.task, episode.demo_seed)
            .unwrap();
        assert_eq!(rows.len(), demo.len() + 1);
        assert_eq!(demo.len(), 16, "8 picks, 8 places (no failures)");
        let rollout = ctg_graph::record_demonstration(
            &mut domain.env(&episode.task).unwrap(),
            &mut domain.expert(),
            episode.rollout_seed,
        )
        .unwrap();
        assert_eq!(
            rollout.actions().len(),
            16 - 2 * episode.task.presorted.len()
        );
        let picks = |actions: &[ActionId]| -> Vec<ActionId> {
            actions.iter().copied().step_by(2).collect()
        };
        assert!(
            !picks(&demo).ends_with(&picks(rollout.actions())),
            "the expert's rollout is not the demo's tail"
        );
        let mut env = domain.env(&episode.task).unwrap();
        ctg_graph::Environment::reset(&mut env, episode.rollout_seed).unwrap();
        for &a in rollout.actions() {
            ctg_graph::Environment::step(&mut env, a).unwrap();
        }
        assert!(ctg_graph::Environment::is_success(&env));
        assert_eq!(domain.goals(&episode.task, &env), (8, 8));
    }

    #[test]
    fn a_tiny_run_trains_validates_and_evaluates_its_ablation() {
        let dir = tempfile::tempdir().unwrap();
        let config = SortingRunConfig {
            domain: "sorting".into(),
            train_tasks: 3,
            demos_per_task: 2,
            failures: true,
            model_seed: 0,
            state_hidden_layers: 1,
            pairwise: false,
            validation_episodes: 2,
            validate_every: 1,
            ablation: Variant::NoGcn,
            step_limit: STEP_LIMIT,
            optim: OptimConfig::stage(2, 4, 3e-3, 0, 1),
        };
        let run = RunDir::create(&dir.path().join("run")).unwrap();
        RunDir::write_json(&run.config_path(), &config).unwrap();
        let device = crate::spec::device().autodiff();
        train_run(&run, &config, &device, |_| {}).unwrap();
        let model = load_model(&run, &crate::spec::device()).unwrap();
        assert!(!model.config.ablation.gcn, "trained without the GCN");
        let (_, _, test) = split().unwrap();
        let result = evaluate(
            &model,
            &config,
            &episodes(&test, 3, TEST_SEEDS),
            Variant::Full,
        )
        .unwrap();
        assert_eq!(result.success.trials, 3);
        assert!(result.episodes.iter().all(|e| e.goals == 8));
        let wrong = SortingRunConfig {
            train_tasks: TRAIN_POOL + 1,
            ..config
        };
        assert!(
            wrong
                .validate()
                .unwrap_err()
                .to_string()
                .contains("1 to 200")
        );
    }
}
