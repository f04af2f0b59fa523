//! The JIGSAWS cross-task experiment (the paper's fig. "jigsaws"): train NTG
//! on Knot Tying and Suturing, build a policy from one Needle Passing
//! demonstration, and score how well it explains every other Needle
//! Passing demonstration by the mean per-step negative log-likelihood (NLL)
//! of the expert's gestures.
//!
//! # Data
//!
//! By default the data is the **synthetic stand-in** of
//! [`env_jigsaws::synth`] (generated in memory with a seed; it is the same
//! content `ntg jigsaws synth` writes and the reader reads back); with a
//! root folder ([`DataSource::Root`]) the same code reads a real copy with
//! [`env_jigsaws::Dataset::load`]. Each trial becomes one demonstration
//! with **one step per gesture segment** over the `G1`–`G15` vocabulary;
//! its observations are kinematics windows ([`ObservationEncoder`]: `W`
//! rows at 5 Hz, each column standardised with statistics fitted on the
//! two **training** tasks only, so nothing of Needle Passing leaks into
//! training). The networks read them with
//! [`EncoderConfig::kinematics`]. Training demonstrations are stored in a
//! [`DemoDataset`] with task index 0 = Suturing, 1 = Knot Tying (the
//! ground-truth task graph of each is the union of its demos' paths) and
//! the trial's position in its task as the entry's `seed`.
//!
//! # Methods
//!
//! - **uniform**: `π(a|o) = 1/|A|` over the `|A| = 16` actions an expert can
//!   take (`G1`–`G15` and `<end>`; `<start>` is never an action), so its NLL
//!   is `ln 16 ≈ 2.773` whatever the data.
//! - **no graph**: NTG without a task graph. The policy is still
//!   `π(a|o) ∝ Σ_n ε(a|n,o) ℓ(n|o)`, but over the fully connected graph
//!   (the "no demo interpreter" initial graph) and without graph
//!   completion: the edge classifier gets the GCN's task-independent
//!   initial node embeddings `N⁰` instead of `NE_gcn`. It therefore sees
//!   the current observation but nothing of the demonstration. It is
//!   trained as its own model, as it is used: NTG's training step with this
//!   ablation ([`crate::method::ntg::NtgStep`]) trains the node localizer
//!   and the edge classifier (with `N⁰`) on every training step, the edge
//!   classifier's softmax over every action the fully connected graph
//!   allows, so it is not a network handicapped at test time (masked to the
//!   training tasks' graphs, the logits of every other transition would
//!   stay untrained).
//! - **full NTG, own head** ([`Method::FullOwnHead`], the paper's
//!   wiring): demo interpreter → path CTG → GCN completion → the policy over
//!   the completed graph ([`NtgPolicy::from_demo`]) with the full model's
//!   own node localizer and edge classifier, which reads the GCN's
//!   embeddings `NE_gcn`, and with **soft edges** ([`NtgConfig::soft_edges`],
//!   [`JigsawsConfig::soft_edges`]): each row of the edge classifier is
//!   weighted by the GCN's edge probabilities, `ε(a|n,o) ∝ C_na ·
//!   exp(s(a|n,o))` (the transcribed path's edges at weight 1, every weight
//!   at least [`ntg_model::SOFT_EDGE_FLOOR`]), instead of being cut to the
//!   graph thresholded at 0.5. It is trained as it is used: the GCN reads
//!   **another** demo of the same task than the one the edge classifier
//!   imitates ([`OptimConfig::gcn_from_other_demo`]), and the edge
//!   classifier's logits get the same `ln C` of that completed graph, with
//!   a softmax over every node.
//!
//!   Why soft edges and the other demo (measured on the quick profile,
//!   seeds 0): with the hard mask and the GCN reading the imitated demo
//!   itself, this method scored 0.970 on Needle Passing against 0.725 for
//!   no graph, and 0.978 against 0.584 on the held-out training-task demos.
//!   The GCN embeddings of the demo's own path told the edge classifier
//!   where that demo retries and ends, so it was overconfident on retries
//!   and endings of other demos (GCN from another demo: 0.835); and a hard
//!   0.5 threshold made an edge the GCN was unsure of cost `ln(16/ε)` while
//!   the classifier had never been trained on logits outside the training
//!   tasks' graphs (soft edges alone: 0.690; both: 0.653).
//! - **full NTG** ([`Method::Full`], the figure's "NTG (full)"; **a
//!   deviation from the paper**): the same trained full model's demo
//!   interpreter and GCN give the graph, and the graph is a **prior on the
//!   no-graph model's node localizer and edge classifier** ([`GraphPrior`]):
//!   `π(a|o) ∝ Σ_n ℓ₀(n|o) ε_τ(a|n,o)`, `ε_τ(a|n,o) ∝ C_na^τ · ε₀(a|n,o)`,
//!   with `ℓ₀`, `ε₀` the no-graph model's and `C` the soft-edge weights
//!   above. Full NTG and no graph therefore differ **only by the graph**.
//!   The prior's weight `τ` is chosen from
//!   [`JigsawsConfig::prior_weights`] (0, ¼, ½, ¾, 1; 0 is the no-graph
//!   policy, 1 the soft-edge policy on the no-graph head) on the held-out
//!   training-task demos, together with the full model's epoch
//!   ([`train_method`]); the chosen `τ` is in the report. The full model is
//!   trained exactly as for the own-head method (one run serves both, each
//!   with its own epoch selection); the thresholded graph remains what the
//!   figure of the predicted graph shows.
//!
//! # Why full NTG was fragile, and the validation protocol
//!
//! With the own-head method, the order full < no graph held at the default
//! seeds (0.653 vs 0.725) but not when one seed changed: full was lower in
//! 2 of 8 settings, and model seed 2 gave 1.649 (table below; before soft
//! edges and the GCN reading another demo, full scored 0.94–1.13 on the
//! five of these measured). The graph's real contribution here is small
//! (it removes the other tasks' gestures: `G12` after `G1`, `G9`/`G10`
//! after `G6`), while the edge classifiers' reading of Needle Passing
//! kinematics, which they never saw, varies with the seed by as much (no
//! graph alone spans 0.569–0.725). Diagnosed by scoring, per setting, the
//! own-head policy with the true transcription, the own head without the
//! graph's weights, and the no-graph head under the same graph (a one-off
//! diagnostic, not kept in the code):
//!
//! - **The own edge classifier on unseen kinematics** (model seed 2): 1.649
//!   with the interpreter's transcriptions, 1.604 with the true ones, 1.767
//!   without the graph's weights at all, but 0.637 for the no-graph head
//!   under the same graph (no graph: 0.661). The excess sits on the common
//!   steps `G3 → G6` and `G2 → G3`: this classifier, trained only with the
//!   graph's `ln C` removing every off-graph gesture, reads Needle Passing
//!   kinematics badly, and the no-graph classifier of the same seed does
//!   not. Hence the shared head: the edge classifier and localizer are
//!   trained once, as the no-graph model trains them, and the graph only
//!   reweighs them.
//! - **Transcription errors** (data seed 1): the interpreter writes
//!   Suturing's `G9` after `G6` into Needle Passing transcriptions, and the
//!   GCN then gives the true `G6 → G4` only 0.18, so every `G6 → G4` step
//!   pays for it (own head 0.807, 0.537 with the true transcriptions; the
//!   no-graph head under the interpreter's graph 0.810, under the true
//!   path's 0.582). With the shared head the interpreter and GCN are
//!   selected for the graph they give, not for the own head's score, and
//!   were selected at later epochs (20–40 instead of 8–16), and the
//!   graph's weight can be turned down.
//! - **The graph at full weight is overconfident even within a task**: on
//!   the held-out Suturing demos, the no-graph head under the full-weight
//!   graph of one other Suturing demo scored worse than without it in all
//!   8 settings (e.g. 0.747 vs 0.634 at data seed 1); on Knot Tying it
//!   helped (0.393 vs 0.440 at the defaults). A single demo does not show
//!   every retry, and the GCN's probabilities for the missing ones are
//!   small. Hence a tempered prior whose weight is chosen on validation.
//!
//! **Validation protocol.** Every choice is made on the held-out
//! demonstrations of the training tasks (every 5th trial of Suturing and of
//! Knot Tying: 7 + 7 demos, never trained on), each task's group scored
//! leave-one-out within itself exactly as Needle Passing is, and the
//! conditioning demos' scores averaged: each model's epoch, and the prior
//! weight `τ`. The candidates of `τ` were fixed before any run. Needle
//! Passing is scored once, after. Leaving a whole training task out (train
//! on Suturing, score on Knot Tying, and the reverse) was considered and not
//! used: the two tasks share only `G1` and `G11`, so a model trained on one
//! has never produced 4 (Knot Tying) or 8 (Suturing) of the other's
//! gestures, and the score would be dominated by those steps whatever the
//! method; Needle Passing's gestures are all Suturing's, which makes the
//! within-task held-out demos the closer proxy for what the graph must do.
//! What the protocol cannot show is unfamiliar kinematics; that failure is
//! addressed by the design (one shared head), not by a tuned number.
//! Disclosure: the diagnostics above (step 1 of the work) scored two
//! shared-head variants on Needle Passing (the no-graph head under the
//! graph at weight 1 and ½, with the own head's epoch selection) before the
//! method was fixed; the method itself (shared head, `τ` and the epoch
//! chosen on validation among the candidates above) was then run once over
//! the settings below, unchanged.
//!
//! # Seed sensitivity (measured, quick profile)
//!
//! `ntg jigsaws nll --seed-table` (and `ntg reproduce` at the paper
//! profile) repeats the experiment with one seed changed at a time
//! ([`seed_table`]: synthetic-data seeds 1–3, model seeds 1–5; model seed 5
//! was added to the issue's eight settings before any run of the method).
//! Mean NLL over the 28 conditioning demos (the spread over conditioning
//! demos is 0.005–0.007 for no graph and full, up to 0.21 for the own
//! head); τ is the selected prior weight. Measured with this code, quick
//! profile (release, `RAYON_NUM_THREADS=1`, 1 min 50 s for all nine on
//! two busy cores):
//!
//! | setting | no graph | own head | full | τ | full < no graph |
//! |---|---|---|---|---|---|
//! | default | 0.725 | 0.653 | 0.686 | 1 | yes |
//! | data 1 | 0.634 | 0.807 | 0.616 | ¼ | yes |
//! | data 2 | 0.689 | 0.614 | 0.651 | ½ | yes |
//! | data 3 | 0.679 | 0.712 | 0.639 | ¾ | yes |
//! | model 1 | 0.569 | 0.602 | 0.536 | 1 | yes |
//! | model 2 | 0.661 | 1.649 | 0.626 | 1 | yes |
//! | model 3 | 0.688 | 0.710 | 0.654 | 1 | yes |
//! | model 4 | 0.574 | 0.612 | 0.542 | 1 | yes |
//! | model 5 | 0.643 | 0.631 | 0.591 | 1 | yes |
//! | mean | 0.651 | 0.777 | 0.616 | | 9 of 9 |
//!
//! Uniform is `ln 16 ≈ 2.773` throughout, so full < no graph < uniform in
//! all nine settings and in the mean. The own-head column is the previous
//! method (its numbers are unchanged: same training, same selection); it
//! beats no graph in 3 of 9. Full NTG's margin over no graph is small
//! (0.018–0.052 nats, mean 0.036), smaller than the seed-to-seed spread
//! of either method (no graph 0.569–0.725), which is what the graph can
//! add on this data (see above); at the default seeds the own head is
//! lower still (0.653), but not robustly. No graph's numbers are those of
//! the same no-graph model as before. The selected τ is below 1 exactly in
//! the three data-seed settings.
//!
//! **Fresh settings, run once after the above was committed** (not in the
//! table's code, which stays at the nine settings fixed beforehand): data
//! seed 4: no graph 0.580, own head 0.531, full 0.583 (τ = ¾; full
//! **higher**); data 5: 0.618, 0.602, 0.575; model 6: 0.571, 0.596, 0.533;
//! model 7: 0.732, 0.843, 0.696. So full < no graph in 12 of 13 settings
//! measured. The failure at data seed 4 is a third failure mode, seen only
//! there: for 2 of the 28 conditioning demos (`D003`, `B004`) the demo
//! interpreter transcribes a Knot Tying sequence (`G1 G12 G13 G14 G15 …
//! G11`), the GCN completes the Knot Tying graph, and every true Needle
//! Passing edge gets a weight below 0.005; those two policies score 1.19
//! while the other 26 lie in 0.52–0.55 (below no graph's 0.58). Held-out
//! training-task demos never show this (their task is one the interpreter
//! knows), so the validation protocol cannot guard against it; it is left
//! as found (a method that also keeps the transitions the node localizer
//! reads in the demo would address it, but it would be chosen on Needle
//! Passing).
//!
//! Tried before and not kept (own-head method): the length-independent
//! "stepping" interpreter of object collection (full above no graph for
//! all eight settings, 0.934 for the defaults) and decoder token dropout
//! 0.5 (full lower in 3 of 8, 0.934 for the defaults).
//!
//! # Scoring
//!
//! For conditioning demo `d` and every other demo `e`, each of `e`'s
//! `n + 1` steps (observation `i`, the expert's next gesture, and `<end>`
//! after the last one) is scored by `−ln π̃(a|o)`, where
//!
//! ```text
//! π̃(a|o) = (1 − ε) π(a|o) + ε / |A|,   ε = smoothing (default 0.01)
//! ```
//!
//! A task graph gives probability exactly 0 to a transition it lacks; the
//! smoothing mixes in 1% of the uniform policy so such a step costs at most
//! `ln(|A|/ε) ≈ 7.38` nats instead of an infinite NLL, and every such step
//! is **counted** ([`MethodResult::zero_probability_steps`]) and reported.
//! The same smoothing is applied to every method (it leaves uniform
//! unchanged). The score of `d` is the mean over all steps of all `e ≠ d`
//! (pooled, so long demos weigh more); the figure shows the mean over the
//! conditioning demos with the standard deviation as the error bar.
//!
//! # Training and model selection
//!
//! Every `validation_every`-th trial of each training task (5: positions
//! 4, 9, …) is held out. Two models are trained, each for up to
//! `optim.epochs` epochs: the no-graph model first, then the full model.
//! Every `eval_every` epochs each method's policy is scored with the same
//! leave-one-out protocol on the held-out demos of each training task,
//! within the task, and each method keeps the model (and, for full NTG, the
//! prior weight) with the lowest such validation NLL ([`train_method`]):
//! no graph its model; the own-head method and full NTG each their epoch
//! of the one full-model run (full NTG scored with the selected no-graph
//! model as its head). Needle Passing plays no part in choosing anything.
//!
//! Everything is seeded: the synthetic data by its seed, the weights by
//! `model_seed`, the shuffling by the optimiser's seed; the same config
//! gives the same numbers.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use anyhow::{Context, bail, ensure};
use burn::module::Module;
use burn::tensor::Device;
use ctg_graph::{ActionId, Ctg, Demonstration, Vocabulary};
use env_jigsaws::{
    ColumnStats, Dataset, ObservationConfig, ObservationEncoder, SynthConfig, Task, Trial,
    gesture_vocabulary,
};
use ntg_model::{AblationConfig, EncoderConfig, NtgConfig, NtgModel, NtgPolicy};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::dataset::{DemoDataset, ObsDtype};
use crate::fit::OptimConfig;
use crate::method::ntg::{EpochMetrics, TrainExtras, train_with};
use crate::run_dir::RunDir;
use crate::spec::Profile;

mod graph;
mod prior;
mod report;
mod scoring;
mod seeds;
mod training;

pub use graph::*;
pub use prior::*;
pub use report::*;
pub use scoring::*;
pub use seeds::*;
pub use training::*;

/// The default smoothing `ε` (see the module docs).
pub const DEFAULT_SMOOTHING: f64 = 0.01;

/// The training tasks, in their [`DemoDataset`] task-index order.
pub const TRAIN_TASKS: [Task; 2] = [Task::Suturing, Task::KnotTying];
/// The unseen task the policies are built for and scored on.
pub const TEST_TASK: Task = Task::NeedlePassing;

/// Where the trials come from.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum DataSource {
    /// The synthetic stand-in, generated in memory.
    Synthetic {
        /// Seed of the generator.
        seed: u64,
        /// Duration multiplier (1 is realistic).
        duration_scale: f64,
    },
    /// A JIGSAWS copy on disk (real or written by `ntg jigsaws synth`).
    Root {
        /// The dataset root (task folders are searched for below it).
        path: PathBuf,
    },
}

impl DataSource {
    /// Part of the run-folder names: `synth<seed>` or `root`.
    pub fn run_tag(&self) -> String {
        match self {
            DataSource::Synthetic { seed, .. } => format!("synth{seed}"),
            DataSource::Root { .. } => "root".to_owned(),
        }
    }

    /// A one-line description for reports.
    pub fn describe(&self) -> String {
        match self {
            DataSource::Synthetic {
                seed,
                duration_scale,
            } => format!(
                "synthetic stand-in (seed {seed}, duration scale {duration_scale}; generated, not real surgical data)"
            ),
            DataSource::Root { path } => format!("JIGSAWS copy at {}", path.display()),
        }
    }
}

/// Everything that defines one JIGSAWS experiment (saved as each run's
/// `config.json`; a finished run with the same config is reused).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct JigsawsConfig {
    /// The trials.
    pub source: DataSource,
    /// Kinematics windows.
    pub observation: ObservationConfig,
    /// Seed of the initial weights of both trained models.
    pub model_seed: u64,
    /// Optimisation (both trained models).
    pub optim: OptimConfig,
    /// The smoothing `ε` of the scores, in `[0, 1)`.
    pub smoothing: f64,
    /// Every `k`-th trial of each training task (positions `k−1, 2k−1, …`
    /// in id order) is held out for model selection, not trained on; 0
    /// holds out nothing (the last epoch is used).
    pub validation_every: usize,
    /// Validation after every this many epochs (and after the last); the
    /// epoch with the lowest validation NLL gives each method's model.
    pub eval_every: usize,
    /// The full model's policy weighs edges by the GCN's probabilities
    /// ([`NtgConfig::soft_edges`]) instead of masking them to the
    /// thresholded graph.
    #[serde(default)]
    pub soft_edges: bool,
    /// The candidate weights `τ` of [`Method::Full`]'s graph prior
    /// ([`GraphPrior`]); the one with the lowest validation NLL is used.
    #[serde(default = "default_prior_weights")]
    pub prior_weights: Vec<f64>,
}

/// The default candidates of [`JigsawsConfig::prior_weights`]: from no
/// prior (0, the no-graph policy) to the full soft-edge prior (1) in
/// quarters.
pub fn default_prior_weights() -> Vec<f64> {
    vec![0.0, 0.25, 0.5, 0.75, 1.0]
}

impl JigsawsConfig {
    /// The configuration of `profile` on `source`, from the experiment
    /// file `experiments/jigsaws.toml` (built in, or read from `DIR` with
    /// `--experiments DIR`).
    pub fn for_profile(
        profile: Profile,
        source: DataSource,
        experiments: crate::experiment::Source<'_>,
    ) -> anyhow::Result<JigsawsConfig> {
        #[derive(Deserialize)]
        #[serde(deny_unknown_fields)]
        struct File {
            config: toml::Table,
            profiles: crate::experiment::Profiles<crate::experiment::ProfileOverrides>,
        }
        let (file, origin): (File, String) = crate::experiment::load("jigsaws", experiments)?;
        let mut base = serde_json::to_value(&file.config)?;
        let object = base
            .as_object_mut()
            .with_context(|| format!("{origin}: [config] is not a table"))?;
        object.insert("source".into(), serde_json::to_value(&source)?);
        object.insert(
            "observation".into(),
            serde_json::to_value(ObservationConfig::default())?,
        );
        let base: JigsawsConfig =
            serde_json::from_value(base).context("experiments/jigsaws.toml: invalid [config]")?;
        crate::experiment::with_overrides(
            &base,
            &file.profiles.get(profile).overrides,
            "experiments/jigsaws.toml",
        )
    }

    fn validate(&self) -> anyhow::Result<()> {
        ensure!(
            (0.0..1.0).contains(&self.smoothing),
            "the smoothing must be in [0, 1), got {}",
            self.smoothing
        );
        ensure!(self.eval_every > 0, "eval_every must be positive");
        ensure!(
            !self.prior_weights.is_empty()
                && self
                    .prior_weights
                    .iter()
                    .all(|w| w.is_finite() && (0.0..=1.0).contains(w)),
            "the prior weights must be numbers in [0, 1] (at least one), got {:?}",
            self.prior_weights
        );
        if let DataSource::Synthetic { duration_scale, .. } = self.source {
            ensure!(
                duration_scale.is_finite() && duration_scale > 0.0,
                "the duration scale must be a positive number, got {duration_scale}"
            );
        }
        Ok(())
    }
}

/// Loads the trials of `source`, returning the dataset and the reader's
/// warnings (skipped trials, stray files) as text.
pub fn load_source(source: &DataSource) -> anyhow::Result<(Dataset, Vec<String>)> {
    match source {
        DataSource::Synthetic {
            seed,
            duration_scale,
        } => {
            let config = SynthConfig {
                duration_scale: *duration_scale,
                ..SynthConfig::new(*seed)
            };
            let synth = env_jigsaws::generate(&config)
                .context("generating the synthetic JIGSAWS stand-in")?;
            Ok((synth.dataset, Vec::new()))
        }
        DataSource::Root { path } => {
            if !path.is_dir() {
                bail!(
                    "--jigsaws-root {}: no such folder (pass the folder that holds Suturing/, Knot_Tying/ and Needle_Passing/)",
                    path.display()
                );
            }
            let loaded = Dataset::load(path)
                .with_context(|| format!("reading JIGSAWS from {}", path.display()))?;
            let warnings = loaded
                .report
                .warnings
                .iter()
                .map(ToString::to_string)
                .collect();
            Ok((loaded.dataset, warnings))
        }
    }
}

/// One Needle Passing demonstration, ready for scoring.
#[derive(Debug, Clone, PartialEq)]
pub struct TestDemo {
    /// The trial id, e.g. `Needle_Passing_B001`.
    pub trial: String,
    /// Its observations (kinematics windows) and gestures.
    pub demo: Demonstration<Vec<f32>>,
}

/// The experiment's data: training demos of the two seen tasks, test demos
/// of Needle Passing, and the encoder that made them.
#[derive(Debug, Clone)]
pub struct JigsawsData {
    /// The gesture vocabulary (`<start>`, `<end>`, `G1`–`G15`).
    pub vocab: Vocabulary,
    /// The observation encoder (fitted on the training tasks).
    pub encoder: ObservationEncoder,
    /// Suturing (task 0) and Knot Tying (task 1) demonstrations trained on.
    pub train: DemoDataset,
    /// Held-out demonstrations of the training tasks, one group per task
    /// with at least 2 (model selection scores each group leave-one-out).
    pub validation: Vec<Vec<TestDemo>>,
    /// Needle Passing demonstrations, sorted by trial id.
    pub test: Vec<TestDemo>,
}

/// Builds the experiment's data from a dataset, holding out every
/// `validation_every`-th trial of each training task (0: none). Errors,
/// naming `what` (the source), if a training task has no trials to train on
/// or Needle Passing has fewer than two (a policy needs one demo and the
/// score at least one other).
pub fn build_data(
    dataset: &Dataset,
    observation: ObservationConfig,
    validation_every: usize,
    what: &str,
) -> anyhow::Result<JigsawsData> {
    for task in TRAIN_TASKS {
        if dataset.trials(task).is_empty() {
            bail!(
                "{what}: no usable {task} trials (the experiment trains on {} and {})",
                TRAIN_TASKS[0],
                TRAIN_TASKS[1]
            );
        }
    }
    let test_trials = dataset.trials(TEST_TASK);
    if test_trials.len() < 2 {
        bail!(
            "{what}: {} usable {TEST_TASK} trial(s); the experiment needs at least 2 (one to build the policy from, others to score)",
            test_trials.len()
        );
    }
    let train_trials = || TRAIN_TASKS.iter().flat_map(|&t| dataset.trials(t));
    let stats = ColumnStats::fit(train_trials())
        .with_context(|| format!("{what}: fitting the kinematics statistics"))?;
    let encoder = ObservationEncoder::new(observation, stats)?;
    let vocab = gesture_vocabulary();
    let held_out = |i: usize| validation_every > 0 && i % validation_every == validation_every - 1;
    let mut demos = Vec::new();
    let mut validation = Vec::new();
    for (task_index, &task) in TRAIN_TASKS.iter().enumerate() {
        let mut group = Vec::new();
        for (i, trial) in dataset.trials(task).iter().enumerate() {
            let demo = encode(&encoder, trial, what)?;
            if held_out(i) {
                group.push(TestDemo {
                    trial: trial.id().to_string(),
                    demo,
                });
            } else {
                demos.push((task_index, i as u64, demo));
            }
        }
        if !demos.iter().any(|(t, _, _)| *t == task_index) {
            bail!(
                "{what}: no {task} trials left to train on after holding out every {validation_every}-th"
            );
        }
        if group.len() >= 2 {
            validation.push(group);
        }
    }
    let train = DemoDataset::from_demos(
        vocab.clone(),
        encoder.observation_dim(),
        ObsDtype::F32,
        demos,
    )?;
    let test = test_trials
        .iter()
        .map(|t| {
            Ok(TestDemo {
                trial: t.id().to_string(),
                demo: encode(&encoder, t, what)?,
            })
        })
        .collect::<anyhow::Result<_>>()?;
    Ok(JigsawsData {
        vocab,
        encoder,
        train,
        validation,
        test,
    })
}

fn encode(
    encoder: &ObservationEncoder,
    trial: &Trial,
    what: &str,
) -> anyhow::Result<Demonstration<Vec<f32>>> {
    encoder
        .demonstration(trial)
        .with_context(|| format!("{what}: trial {}", trial.id()))
}

/// The compared methods.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Method {
    /// Uniform over the 16 actions.
    Uniform,
    /// NTG without a task graph (see the module docs).
    NoGraph,
    /// The full NTG model with its own edge classifier, which reads the
    /// GCN's embeddings `NE_gcn` (the paper's wiring; see the module docs).
    FullOwnHead,
    /// The full NTG model as this crate runs it: the demo's completed graph
    /// as a prior on the no-graph model's node localizer and edge classifier
    /// (see the module docs).
    Full,
}

impl Method {
    /// Every method, in figure order.
    pub const ALL: [Method; 4] = [
        Method::Uniform,
        Method::NoGraph,
        Method::FullOwnHead,
        Method::Full,
    ];

    /// Name in files and reports.
    pub fn name(self) -> &'static str {
        match self {
            Method::Uniform => "uniform",
            Method::NoGraph => "no-graph",
            Method::FullOwnHead => "full-own-head",
            Method::Full => "full",
        }
    }

    /// Label in figures.
    pub fn label(self) -> &'static str {
        match self {
            Method::Uniform => "uniform",
            Method::NoGraph => "NTG, no graph",
            Method::FullOwnHead => "NTG, own head",
            Method::Full => "NTG (full)",
        }
    }

    /// The ablation switches of the trained model behind this method
    /// (`None` for uniform, which has none). Both full methods use the
    /// full model (for [`Method::Full`], its demo interpreter and GCN).
    pub fn ablation(self) -> Option<AblationConfig> {
        match self {
            Method::Uniform => None,
            Method::NoGraph => Some(
                AblationConfig::new()
                    .with_demo_interpreter(false)
                    .with_gcn(false),
            ),
            Method::FullOwnHead | Method::Full => Some(AblationConfig::new()),
        }
    }
}

/// One trained model's run.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TrainedRun {
    /// The method it serves.
    pub method: Method,
    /// Its run folder.
    pub run: PathBuf,
    /// Seconds of its training epochs (from `metrics.jsonl`, so a reused
    /// run reports its original cost).
    pub train_seconds: f64,
    /// Metrics of its last epoch.
    pub last_epoch: Option<EpochMetrics>,
    /// Which epoch's model was used.
    pub selection: Selection,
}

/// Everything the experiment measured.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct JigsawsResult {
    /// The configuration.
    pub config: JigsawsConfig,
    /// The data, in words.
    pub source: String,
    /// Warnings of the reader (a real copy's skipped trials).
    pub warnings: Vec<String>,
    /// Training demonstrations (Suturing + Knot Tying).
    pub train_demos: usize,
    /// Needle Passing demonstrations (each conditions one policy).
    pub test_demos: usize,
    /// One entry per method, in [`Method::ALL`] order.
    pub methods: Vec<MethodResult>,
    /// The two trained models.
    pub runs: Vec<TrainedRun>,
    /// The full model's graph for the first Needle Passing demo.
    pub graph: PredictedGraph,
    /// The same experiment with one seed changed at a time ([`seed_table`];
    /// not run at the smoke profile).
    #[serde(default)]
    pub seeds: Option<SeedTable>,
}

impl JigsawsResult {
    /// The result of `method`.
    pub fn method(&self, method: Method) -> Option<&MethodResult> {
        self.methods.iter().find(|m| m.method == method)
    }
}

/// Runs the whole experiment: data, the two trained models (run folders
/// `<runs>/jigsaws-<tag>-full` and `<runs>/jigsaws-<tag>-no-graph`, tag
/// from [`DataSource::run_tag`], reused when finished with the same
/// config), the three methods' scores and the
/// predicted graph.
pub fn run_experiment(
    config: &JigsawsConfig,
    runs: &Path,
    mut log: impl FnMut(&str),
) -> anyhow::Result<JigsawsResult> {
    config.validate()?;
    let (dataset, warnings) = load_source(&config.source)?;
    for w in &warnings {
        log(&format!("warning: {w}"));
    }
    let data = build_data(
        &dataset,
        config.observation,
        config.validation_every,
        &config.source.describe(),
    )?;
    log(&format!(
        "jigsaws: {} training demos ({} + {}), {} held out for model selection, {} {TEST_TASK} demos",
        data.train.demos().len(),
        TRAIN_TASKS[0],
        TRAIN_TASKS[1],
        data.validation.iter().map(Vec::len).sum::<usize>(),
        data.test.len()
    ));
    let device = crate::spec::device().autodiff();
    let mut trained = Vec::new();
    let mut models: Vec<(Method, NtgModel)> = Vec::new();
    // The no-graph model first: the full method's head.
    for group in [
        &[Method::NoGraph][..],
        &[Method::FullOwnHead, Method::Full][..],
    ] {
        let dir = runs.join(format!(
            "jigsaws-{}-{}",
            config.source.run_tag(),
            if group[0] == Method::NoGraph {
                "no-graph"
            } else {
                "full"
            }
        ));
        log(&format!(
            "jigsaws ({}): training -> {}",
            group
                .iter()
                .map(|m| m.name())
                .collect::<Vec<_>>()
                .join(", "),
            dir.display()
        ));
        let head = models
            .iter()
            .find(|(m, _)| *m == Method::NoGraph)
            .map(|(_, model)| model);
        let selected = train_method(group, &data, config, &dir, head, &device, |m| {
            log(&format!(
                "  epoch {:>3}: loss {:.3}, tokens {:.3}, nodes {:.3}, steps {:.3}, edge F1 {}",
                m.epoch,
                m.loss,
                m.token_accuracy,
                m.localizer_accuracy,
                m.step_accuracy,
                m.edge_f1_text()
            ))
        })?;
        for (model, run) in selected {
            let curve: Vec<String> = run
                .selection
                .validation
                .iter()
                .map(|(e, v)| format!("{e}: {v:.3}"))
                .collect();
            log(&format!(
                "  {}: validation NLL by epochs trained [{}]; using the model after {} epochs{}",
                run.method.name(),
                curve.join(", "),
                run.selection.epochs,
                run.selection
                    .prior_weight
                    .map_or(String::new(), |w| format!(" and prior weight {w}"))
            ));
            models.push((run.method, model));
            trained.push(run);
        }
    }
    let model = |method: Method| {
        models
            .iter()
            .find(|(m, _)| *m == method)
            .map(|(_, model)| model)
            .with_context(|| format!("no model was trained for {}", method.name()))
    };
    let mut methods = Vec::new();
    for method in Method::ALL {
        let scorer = match method {
            Method::Uniform => Scorer::Uniform,
            Method::NoGraph | Method::FullOwnHead => Scorer::Own(method, model(method)?),
            Method::Full => Scorer::GraphPrior {
                head: model(Method::NoGraph)?,
                graph: model(Method::Full)?,
                weight: trained
                    .iter()
                    .find(|r| r.method == Method::Full)
                    .and_then(|r| r.selection.prior_weight)
                    .context("no prior weight was selected")?,
            },
        };
        let result = score(method, scorer, &data, config.smoothing)?;
        log(&format!(
            "  {}: NLL {:.3} ± {:.3} over {} conditioning demos ({} of {} steps at probability 0 before smoothing)",
            method.name(),
            result.mean_nll,
            result.std_nll,
            result.per_demo.len(),
            result.zero_probability_steps,
            result.steps
        ));
        methods.push(result);
    }
    let graph = predicted_graph(model(Method::Full)?, &data, 0)?;
    Ok(JigsawsResult {
        config: config.clone(),
        source: config.source.describe(),
        warnings,
        train_demos: data.train.demos().len(),
        test_demos: data.test.len(),
        methods,
        runs: trained,
        graph,
        seeds: None,
    })
}

#[cfg(test)]
mod tests;
