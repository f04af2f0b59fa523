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
//!   trained as its own model, as it is used ([`NoGraphTrainer`]): node
//!   localizer and edge classifier (with `N⁰`) on every training step, the
//!   edge classifier's softmax over every action the fully connected graph
//!   allows, so it is not a network handicapped at test time. (The shared
//!   trainer would mask the edge loss to the training tasks' graphs, leaving
//!   the logits of every other transition untrained.)
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
use crate::reproduce::Profile;
use crate::run_dir::RunDir;
use crate::train::{EpochMetrics, OptimConfig, train};

use burn::optim::{AdamConfig, GradientsParams, ModuleOptimizer};
use ntg_model::{ids_tensor, rows_tensor, successor_mask};
use rand::SeedableRng;
use rand::seq::SliceRandom;
use rand_chacha::ChaCha8Rng;

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
    /// The configuration of `profile` on `source`.
    ///
    /// Budgets (release build, 2 quiet CPU cores): smoke about 30 s, quick
    /// about 2 minutes, paper longer.
    pub fn for_profile(profile: Profile, source: DataSource) -> JigsawsConfig {
        let (epochs, eval_every) = match profile {
            Profile::Smoke => (2, 1),
            Profile::Quick => (40, 4),
            Profile::Paper => (100, 5),
        };
        JigsawsConfig {
            source,
            observation: ObservationConfig::default(),
            model_seed: 0,
            optim: OptimConfig {
                epochs,
                batch_size: 8,
                learning_rate: 3e-3,
                seed: 0,
                token_dropout: 0.0,
                cosine_decay: false,
                gcn_from_other_demo: true,
            },
            smoothing: DEFAULT_SMOOTHING,
            validation_every: 5,
            eval_every,
            soft_edges: true,
            prior_weights: default_prior_weights(),
        }
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

/// Number of actions an expert can take in a vocabulary: every real action
/// plus `<end>`.
pub fn num_choices(vocab: &Vocabulary) -> usize {
    vocab.num_actions() + 1
}

/// `−ln π̃` of one step, with `π̃ = (1 − ε)·exp(log_p) + ε/choices`
/// (`log_p = −∞` is probability 0). Returns the NLL and whether the
/// unsmoothed probability was 0.
pub fn smoothed_nll(log_p: f64, smoothing: f64, choices: usize) -> (f64, bool) {
    let p = if log_p.is_nan() { 0.0 } else { log_p.exp() };
    let mixed = (1.0 - smoothing) * p + smoothing / choices as f64;
    (-mixed.ln(), p == 0.0)
}

/// Per-step NLLs of one demonstration under a policy given as a function
/// from an observation to `ln π(·|o)` over every node, and the number of
/// steps the policy gave probability 0.
pub fn demo_step_nlls(
    demo: &Demonstration<Vec<f32>>,
    mut log_probabilities: impl FnMut(&[f32]) -> anyhow::Result<Vec<f32>>,
    smoothing: f64,
    choices: usize,
) -> anyhow::Result<(Vec<f64>, usize)> {
    let mut nlls = Vec::with_capacity(demo.len() + 1);
    let mut zeros = 0;
    for (o, a) in demo.observations().iter().zip(demo.next_actions()) {
        let logs = log_probabilities(o)?;
        let log_p = logs
            .get(a.index())
            .copied()
            .with_context(|| format!("the policy scored {} actions", logs.len()))?;
        let (nll, zero) = smoothed_nll(f64::from(log_p), smoothing, choices);
        nlls.push(nll);
        zeros += usize::from(zero);
    }
    Ok((nlls, zeros))
}

/// The score of one conditioning demonstration.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct DemoScore {
    /// The conditioning trial.
    pub trial: String,
    /// Mean per-step NLL over the steps of every other test demo.
    pub nll: f64,
    /// Steps scored.
    pub steps: usize,
    /// Of those, steps the unsmoothed policy gave probability 0.
    pub zero_probability_steps: usize,
}

/// One method's result.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct MethodResult {
    /// The method.
    pub method: Method,
    /// Mean over conditioning demos of their mean per-step NLL (nats).
    pub mean_nll: f64,
    /// Standard deviation over conditioning demos (population).
    pub std_nll: f64,
    /// Lowest conditioning demo's NLL.
    pub min_nll: f64,
    /// Highest conditioning demo's NLL.
    pub max_nll: f64,
    /// Steps scored, summed over conditioning demos.
    pub steps: usize,
    /// Of those, steps with unsmoothed probability 0.
    pub zero_probability_steps: usize,
    /// Per conditioning demo.
    pub per_demo: Vec<DemoScore>,
}

impl MethodResult {
    /// Aggregates per-demo scores.
    pub fn from_scores(method: Method, per_demo: Vec<DemoScore>) -> MethodResult {
        let n = per_demo.len().max(1) as f64;
        let mean = per_demo.iter().map(|d| d.nll).sum::<f64>() / n;
        let var = per_demo.iter().map(|d| (d.nll - mean).powi(2)).sum::<f64>() / n;
        MethodResult {
            method,
            mean_nll: mean,
            std_nll: var.sqrt(),
            min_nll: per_demo.iter().map(|d| d.nll).fold(f64::INFINITY, f64::min),
            max_nll: per_demo
                .iter()
                .map(|d| d.nll)
                .fold(f64::NEG_INFINITY, f64::max),
            steps: per_demo.iter().map(|d| d.steps).sum(),
            zero_probability_steps: per_demo.iter().map(|d| d.zero_probability_steps).sum(),
            per_demo,
        }
    }
}

/// Scores of every conditioning demo `d`: `nlls(d, e)` gives the per-step
/// NLLs of demo `e` under the policy built from `d` and how many of its
/// steps had probability 0 (it is never called with `e == d`).
pub fn leave_one_out<'a>(
    test: &[TestDemo],
    nlls: impl Fn(usize, usize) -> (&'a [f64], usize),
) -> Vec<DemoScore> {
    (0..test.len())
        .map(|d| {
            let (mut sum, mut steps, mut zeros) = (0.0, 0, 0);
            for e in (0..test.len()).filter(|&e| e != d) {
                let (v, z) = nlls(d, e);
                sum += v.iter().sum::<f64>();
                steps += v.len();
                zeros += z;
            }
            DemoScore {
                trial: test[d].trial.clone(),
                nll: sum / steps.max(1) as f64,
                steps,
                zero_probability_steps: zeros,
            }
        })
        .collect()
}

fn policy_nlls(
    policy: &NtgPolicy,
    demo: &Demonstration<Vec<f32>>,
    smoothing: f64,
    choices: usize,
) -> anyhow::Result<(Vec<f64>, usize)> {
    demo_step_nlls(
        demo,
        |o| Ok(policy.log_probabilities(o)?),
        smoothing,
        choices,
    )
}

/// What scores a method's policies: the model(s) behind it.
#[derive(Debug, Clone, Copy)]
pub enum Scorer<'a> {
    /// The uniform policy.
    Uniform,
    /// A model's own NTG policy, with the method's ablation switches
    /// ([`Method::NoGraph`], [`Method::FullOwnHead`]).
    Own(Method, &'a NtgModel),
    /// [`Method::Full`]: the graph prior of `graph` (its demo interpreter
    /// and GCN) raised to `weight`, on the node localizer and edge
    /// classifier of `head` (the no-graph model); see [`GraphPrior`].
    GraphPrior {
        /// The no-graph model.
        head: &'a NtgModel,
        /// The full model.
        graph: &'a NtgModel,
        /// The prior weight `τ`.
        weight: f64,
    },
}

/// Scores `scorer`'s policies on the test demos, as `method`.
pub fn score(
    method: Method,
    scorer: Scorer<'_>,
    data: &JigsawsData,
    smoothing: f64,
) -> anyhow::Result<MethodResult> {
    let per_demo = score_demos(scorer, &data.vocab, &data.test, smoothing)?;
    Ok(MethodResult::from_scores(method, per_demo))
}

/// The leave-one-out scores of `scorer`'s policies on `test` (each demo
/// conditions a policy scored on all the others).
pub fn score_demos(
    scorer: Scorer<'_>,
    vocab: &Vocabulary,
    test: &[TestDemo],
    smoothing: f64,
) -> anyhow::Result<Vec<DemoScore>> {
    ensure!(
        test.len() >= 2,
        "scoring needs at least 2 demonstrations, got {}",
        test.len()
    );
    let choices = num_choices(vocab);
    let per_demo = match scorer {
        Scorer::Uniform => {
            let uniform = vec![-(choices as f32).ln(); vocab.len()];
            let rows: Vec<(Vec<f64>, usize)> = test
                .iter()
                .map(|t| demo_step_nlls(&t.demo, |_| Ok(uniform.clone()), smoothing, choices))
                .collect::<anyhow::Result<_>>()?;
            leave_one_out(test, |_, e| (&rows[e].0, rows[e].1))
        }
        Scorer::GraphPrior {
            head,
            graph,
            weight,
        } => graph_prior_scores(head, graph, vocab, test, smoothing, &[weight])?
            .pop()
            .context("no scores")?,
        Scorer::Own(method, model) => {
            let ablation = method
                .ablation()
                .with_context(|| format!("method {} has no model", method.name()))?;
            let mut model = model.valid();
            model.config.ablation = ablation;
            if method == Method::NoGraph {
                // The policy does not depend on the demonstration: build it
                // once and score every demo once.
                let first = &test[0].demo;
                let rows: Vec<(Vec<f64>, usize)> = test
                    .par_iter()
                    .map(|t| {
                        let policy = NtgPolicy::from_demo(&model, first.observations(), vocab)?;
                        policy_nlls(&policy, &t.demo, smoothing, choices)
                    })
                    .collect::<anyhow::Result<_>>()?;
                leave_one_out(test, |_, e| (&rows[e].0, rows[e].1))
            } else {
                let table: Vec<Vec<(Vec<f64>, usize)>> = test
                    .par_iter()
                    .map(|d| {
                        let policy = NtgPolicy::from_demo(&model, d.demo.observations(), vocab)
                            .with_context(|| format!("policy from {}", d.trial))?;
                        test.iter()
                            .map(|e| {
                                if std::ptr::eq(e, d) {
                                    Ok((Vec::new(), 0))
                                } else {
                                    policy_nlls(&policy, &e.demo, smoothing, choices)
                                }
                            })
                            .collect()
                    })
                    .collect::<anyhow::Result<_>>()?;
                leave_one_out(test, |d, e| (&table[d][e].0, table[d][e].1))
            }
        }
    };
    Ok(per_demo)
}

/// The policy of [`Method::Full`]: the demo's completed graph as a prior on
/// a demo-independent policy head.
///
/// `π(a|o) ∝ Σ_n ℓ(n|o) ε_τ(a|n,o)` with
/// `ε_τ(a|n,o) ∝ C_na^τ · ε₀(a|n,o)`, where `ℓ` and `ε₀` (a softmax over
/// every action of the fully connected graph) are the no-graph model's node
/// localizer and edge classifier, `C` the soft-edge weights of the graph the
/// full model's demo interpreter and GCN build from the demo
/// ([`NtgModel::edge_weights`]: the transcribed path's edges at 1, the
/// GCN's probabilities elsewhere, at least [`ntg_model::SOFT_EDGE_FLOOR`]),
/// and `τ ∈ [0, 1]` the prior's weight: 1 is the soft-edge policy
/// `ε ∝ C·exp(s)` on the no-graph head, 0 the no-graph policy itself.
#[derive(Debug, Clone, PartialEq)]
pub struct GraphPrior {
    /// `C`, row-major `N × N`.
    weights: Vec<f64>,
    num_nodes: usize,
}

impl GraphPrior {
    /// The prior the full model `graph` builds from one demonstration.
    pub fn from_demo(
        graph: &NtgModel,
        demo_observations: &[Vec<f32>],
    ) -> anyhow::Result<GraphPrior> {
        let mut model = graph.valid();
        model.config.ablation = AblationConfig::new();
        let (_, initial) = model.initial_graph(demo_observations)?;
        let completed = model.complete_graph(&initial)?;
        let c = model.edge_weights(&initial, &completed.probabilities)?;
        Ok(GraphPrior {
            weights: c.adjacency().iter().map(|&w| f64::from(w)).collect(),
            num_nodes: c.num_nodes(),
        })
    }

    /// `ln π(·|o)` over every node for a head's node probabilities `ℓ`
    /// (`[N]`) and edge rows `ε₀` (`[N × N]`, row = current node), with
    /// the prior raised to `weight` (`-inf` where the probability is 0).
    pub fn log_probabilities(
        &self,
        node: &[f32],
        edge: &[f32],
        weight: f64,
    ) -> anyhow::Result<Vec<f32>> {
        let n = self.num_nodes;
        ensure!(
            node.len() == n && edge.len() == n * n,
            "a graph prior over {n} nodes got {} node and {} edge probabilities",
            node.len(),
            edge.len()
        );
        ensure!(
            weight.is_finite() && weight >= 0.0,
            "the prior weight must be a non-negative number, got {weight}"
        );
        let mut out = vec![0f64; n];
        let mut row = vec![0f64; n];
        for from in 0..n {
            let l = f64::from(node[from]);
            if l <= 0.0 {
                continue;
            }
            for (a, r) in row.iter_mut().enumerate() {
                let c = self.weights[from * n + a];
                *r = if c > 0.0 {
                    f64::from(edge[from * n + a]) * c.powf(weight)
                } else {
                    0.0
                };
            }
            let z: f64 = row.iter().sum();
            if z > 0.0 {
                for (o, r) in out.iter_mut().zip(&row) {
                    *o += l * r / z;
                }
            }
        }
        let total: f64 = out.iter().sum();
        Ok(out
            .iter()
            .map(|&p| {
                if total > 0.0 {
                    (p / total).ln() as f32
                } else {
                    f32::NEG_INFINITY
                }
            })
            .collect())
    }
}

/// One demo's step NLLs and its number of probability-0 steps.
type StepNlls = (Vec<f64>, usize);

/// The no-graph head's `(ℓ(·|o), ε₀(·|·,o))` for every observation of a
/// demo (see [`GraphPrior`]).
fn head_outputs(
    head: &NtgPolicy,
    demo: &Demonstration<Vec<f32>>,
) -> anyhow::Result<Vec<(Vec<f32>, Vec<f32>)>> {
    let full = Ctg::fully_connected(head.graph().num_nodes());
    demo.observations()
        .iter()
        .map(|o| {
            Ok((
                head.node_probabilities(o)?,
                head.edge_probabilities_for(&full, o)?,
            ))
        })
        .collect()
}

/// Leave-one-out scores of [`Method::Full`] on `test` for every prior
/// weight in `weights` (one list of scores per weight, in order): the
/// head's outputs are computed once per demo, the prior once per
/// conditioning demo.
pub fn graph_prior_scores(
    head: &NtgModel,
    graph: &NtgModel,
    vocab: &Vocabulary,
    test: &[TestDemo],
    smoothing: f64,
    weights: &[f64],
) -> anyhow::Result<Vec<Vec<DemoScore>>> {
    ensure!(
        test.len() >= 2,
        "scoring needs at least 2 demonstrations, got {}",
        test.len()
    );
    let choices = num_choices(vocab);
    let mut head = head.valid();
    head.config.ablation = Method::NoGraph
        .ablation()
        .context("the no-graph method has ablation switches")?;
    head.config.soft_edges = None;
    let head_policy = NtgPolicy::from_demo(&head, test[0].demo.observations(), vocab)?;
    let outputs: Vec<Vec<(Vec<f32>, Vec<f32>)>> = test
        .iter()
        .map(|t| head_outputs(&head_policy, &t.demo))
        .collect::<anyhow::Result<_>>()?;
    // table[d][w][e]: the step NLLs of e under d's prior at weight w.
    let table: Vec<Vec<Vec<StepNlls>>> = test
        .par_iter()
        .map(|d| {
            let prior = GraphPrior::from_demo(graph, d.demo.observations())
                .with_context(|| format!("graph prior from {}", d.trial))?;
            weights
                .iter()
                .map(|&w| {
                    test.iter()
                        .zip(&outputs)
                        .map(|(e, out)| {
                            if std::ptr::eq(e, d) {
                                return Ok((Vec::new(), 0));
                            }
                            let mut step = out.iter();
                            demo_step_nlls(
                                &e.demo,
                                |_| {
                                    let (node, edge) =
                                        step.next().context("one head output per step")?;
                                    prior.log_probabilities(node, edge, w)
                                },
                                smoothing,
                                choices,
                            )
                        })
                        .collect()
                })
                .collect()
        })
        .collect::<anyhow::Result<_>>()?;
    Ok((0..weights.len())
        .map(|w| leave_one_out(test, |d, e| (&table[d][w][e].0, table[d][w][e].1)))
        .collect())
}

/// The full model's predicted graph for one Needle Passing demonstration.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PredictedGraph {
    /// The conditioning trial.
    pub trial: String,
    /// The expert's gestures in it.
    pub demo_gestures: Vec<String>,
    /// The demo interpreter's transcription of it.
    pub transcription: Vec<String>,
    /// Edges of the transcription's path graph.
    pub path_edges: usize,
    /// Edges of the completed, thresholded graph the policy executes.
    pub graph_edges: usize,
    /// Edges the GCN added (in the graph, not in the path), as `from -> to`.
    pub added_edges: Vec<String>,
    /// Edges of the ground-truth Needle Passing graph (union of all its
    /// demos' paths).
    pub truth_edges: usize,
    /// Edges of the graph that are in the ground truth.
    pub correct_edges: usize,
    /// The graph as DOT: path edges solid, added edges dashed with their
    /// GCN probability.
    pub dot: String,
}

/// Builds the full model's graph for test demo `index` and compares it with
/// the ground-truth Needle Passing graph.
pub fn predicted_graph(
    model: &NtgModel,
    data: &JigsawsData,
    index: usize,
) -> anyhow::Result<PredictedGraph> {
    let vocab = &data.vocab;
    let test = data
        .test
        .get(index)
        .with_context(|| format!("no test demo {index}"))?;
    let mut model = model.valid();
    model.config.ablation = AblationConfig::new();
    let policy = NtgPolicy::from_demo(&model, test.demo.observations(), vocab)?;
    let n = vocab.len();
    let path = Ctg::from_path(n, policy.demo_actions())?;
    let graph = policy.graph();
    let mut truth = Ctg::empty(n);
    for t in &data.test {
        truth.add_path(t.demo.actions())?;
    }
    let mut shown = path.clone();
    let mut added = Vec::new();
    for edge in graph.edges() {
        if !path.has_edge(edge.from, edge.to) {
            let p = policy.edge_probabilities().weight(edge.from, edge.to);
            // Below 1 so `to_dot` draws it dashed with its probability.
            shown.set_weight(edge.from, edge.to, p.min(0.99))?;
            added.push(format!(
                "{} -> {}",
                name(vocab, edge.from),
                name(vocab, edge.to)
            ));
        }
    }
    let names = |ids: &[ActionId]| ids.iter().map(|&a| name(vocab, a)).collect();
    Ok(PredictedGraph {
        trial: test.trial.clone(),
        demo_gestures: names(test.demo.actions()),
        transcription: names(policy.demo_actions()),
        path_edges: path.num_edges(),
        graph_edges: graph.num_edges(),
        added_edges: added,
        truth_edges: truth.num_edges(),
        correct_edges: graph
            .edges()
            .filter(|e| truth.has_edge(e.from, e.to))
            .count(),
        dot: shown.to_dot(vocab)?,
    })
}

fn name(vocab: &Vocabulary, id: ActionId) -> String {
    vocab.name(id).unwrap_or("?").to_owned()
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

/// The saved configuration of one trained model's run.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
struct RunConfig {
    experiment: JigsawsConfig,
    /// The methods whose models the run selects.
    methods: Vec<Method>,
}

fn open_run(dir: &Path, config: &RunConfig) -> anyhow::Result<RunDir> {
    if dir.join("config.json").is_file() {
        let run = RunDir::open(dir)?;
        // A run of an older format (e.g. one method per run) is another
        // configuration too.
        let saved: Option<RunConfig> = RunDir::read_json(&run.config_path()).ok();
        if saved.as_ref() != Some(config) {
            bail!(
                "{} holds a run with another configuration{}; move it away or delete it",
                dir.display(),
                if saved.is_none() {
                    " (or of an older format)"
                } else {
                    ""
                }
            );
        }
        Ok(run)
    } else {
        let run = RunDir::create(dir)?;
        RunDir::write_json(&run.config_path(), config)?;
        Ok(run)
    }
}

fn read_metrics(run: &RunDir) -> anyhow::Result<Vec<EpochMetrics>> {
    let path = run.metrics_path();
    let text =
        std::fs::read_to_string(&path).with_context(|| format!("reading {}", path.display()))?;
    text.lines()
        .filter(|l| !l.trim().is_empty())
        .map(|l| {
            serde_json::from_str(l).with_context(|| format!("{}: invalid line", path.display()))
        })
        .collect()
}

/// The "no graph" model's trainer: the node localizer on every
/// observation's node, and the edge classifier, given `N⁰` (the GCN's
/// task-independent initial embeddings, trained along), on every
/// observation's next action with a softmax over every successor in the
/// **fully connected** graph, as its policy uses it. No demo interpreter
/// and no graph completion are trained (their metrics are logged as 0).
/// Adam; demos shuffled per epoch with a generator seeded by
/// `(seed, epoch)` as in [`train`]. It trains in memory (seconds); the
/// selected model is saved by [`train_method`].
pub struct NoGraphTrainer {
    model: NtgModel,
    optimizer: ModuleOptimizer,
    demos: Vec<Demonstration<Vec<f32>>>,
    dim: usize,
    epochs_done: usize,
}

impl NoGraphTrainer {
    /// A trainer for `model` (on an autodiff device) on `dataset`.
    pub fn new(model: NtgModel, dataset: &DemoDataset) -> anyhow::Result<NoGraphTrainer> {
        ensure!(
            !dataset.demos().is_empty(),
            "the dataset has no demonstrations"
        );
        let demos = (0..dataset.demos().len())
            .map(|i| dataset.demonstration(i))
            .collect::<anyhow::Result<_>>()?;
        Ok(NoGraphTrainer {
            model,
            optimizer: AdamConfig::new().init(),
            demos,
            dim: dataset.obs_dim(),
            epochs_done: 0,
        })
    }

    /// The model as trained so far.
    pub fn model(&self) -> &NtgModel {
        &self.model
    }

    /// Trains until `epochs` epochs are done, calling `on_epoch` after each.
    pub fn train_to(
        &mut self,
        epochs: usize,
        optim: &OptimConfig,
        device: &Device,
        mut on_epoch: impl FnMut(&EpochMetrics) -> anyhow::Result<()>,
    ) -> anyhow::Result<()> {
        ensure!(optim.batch_size > 0, "batch size must be positive");
        let n = self.model.num_nodes();
        let full = Ctg::fully_connected(n);
        for epoch in self.epochs_done..epochs {
            let started = std::time::Instant::now();
            let mut order: Vec<usize> = (0..self.demos.len()).collect();
            let mut rng = ChaCha8Rng::seed_from_u64(
                optim.seed ^ (epoch as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15),
            );
            order.shuffle(&mut rng);
            let mut sums = [0.0f32; 5];
            let mut steps = 0;
            for chunk in order.chunks(optim.batch_size) {
                let mut rows: Vec<&[f32]> = Vec::new();
                let mut nodes = Vec::new();
                let mut next = Vec::new();
                for &i in chunk {
                    let d = &self.demos[i];
                    rows.extend(d.observations().iter().map(Vec::as_slice));
                    nodes.extend(d.node_labels());
                    next.extend(d.next_actions());
                }
                let model = &self.model;
                let obs = rows_tensor(&rows, self.dim, device)?;
                let node_ids = ids_tensor(&nodes, n, device)?;
                let next_ids = ids_tensor(&next, n, device)?;
                let loc = model
                    .localizer
                    .loss(model.localizer.forward(obs.clone())?, node_ids.clone())?;
                let graphs = vec![&full; rows.len()];
                let mask = successor_mask(&graphs, &nodes, Some(&next), n, device)?;
                let logits = model.edges.forward(
                    obs,
                    node_ids,
                    model.gcn.initial_embeddings(rows.len()),
                    model.localizer.node_embeddings(),
                    mask,
                )?;
                let edge = model.edges.loss(logits, next_ids)?;
                let total = loc.loss.clone() + edge.loss.clone();
                let values = [
                    first(total.clone())?,
                    first(loc.loss)?,
                    loc.accuracy,
                    first(edge.loss)?,
                    edge.accuracy,
                ];
                let grads = GradientsParams::from_grads(total.backward(), model);
                self.model = self
                    .optimizer
                    .step(optim.learning_rate, self.model.clone(), grads);
                for (s, v) in sums.iter_mut().zip(values) {
                    *s += v;
                }
                steps += 1;
            }
            let mean = |i: usize| sums[i] / steps as f32;
            let metrics = EpochMetrics {
                epoch,
                loss: mean(0),
                interpreter_loss: 0.0,
                token_accuracy: 0.0,
                gcn_loss: 0.0,
                edge_f1: None,
                localizer_loss: mean(1),
                localizer_accuracy: mean(2),
                edge_loss: mean(3),
                step_accuracy: mean(4),
                seconds: started.elapsed().as_secs_f32(),
            };
            ensure!(
                metrics.loss.is_finite(),
                "training diverged at epoch {epoch} (loss {})",
                metrics.loss
            );
            self.epochs_done = epoch + 1;
            on_epoch(&metrics)?;
        }
        Ok(())
    }
}

fn first(t: burn::tensor::Tensor<1>) -> anyhow::Result<f32> {
    Ok(ntg_model::nn::to_vec(t)?
        .first()
        .copied()
        .unwrap_or(f32::NAN))
}

/// Mean validation NLL of `scorer`'s policies: each held-out group scored
/// leave-one-out within itself, the conditioning demos' scores averaged
/// over all groups. `None` without validation groups.
pub fn validation_nll(
    scorer: Scorer<'_>,
    data: &JigsawsData,
    smoothing: f64,
) -> anyhow::Result<Option<f64>> {
    let mut scores = Vec::new();
    for group in &data.validation {
        scores.extend(score_demos(scorer, &data.vocab, group, smoothing)?);
    }
    Ok(mean_nll(&scores))
}

fn mean_nll(scores: &[DemoScore]) -> Option<f64> {
    (!scores.is_empty()).then(|| scores.iter().map(|d| d.nll).sum::<f64>() / scores.len() as f64)
}

/// The validation NLL of [`Method::Full`] for every prior weight in
/// `weights` (as [`validation_nll`]); `None` without validation groups.
pub fn validation_by_weight(
    head: &NtgModel,
    graph: &NtgModel,
    data: &JigsawsData,
    smoothing: f64,
    weights: &[f64],
) -> anyhow::Result<Option<Vec<f64>>> {
    let mut by_weight = vec![Vec::new(); weights.len()];
    for group in &data.validation {
        let scores = graph_prior_scores(head, graph, &data.vocab, group, smoothing, weights)?;
        for (all, s) in by_weight.iter_mut().zip(scores) {
            all.extend(s);
        }
    }
    Ok(by_weight.iter().map(|s| mean_nll(s)).collect())
}

/// Where [`train_method`] keeps `method`'s selected model inside a run
/// folder.
pub fn selected_dir(run: &Path, method: Method) -> PathBuf {
    run.join(format!("selected-{}", method.name()))
}
const SELECTION_FILE: &str = "selection.json";

/// How a method's model was chosen.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Selection {
    /// Epochs trained when the selected model was taken (1-based count).
    pub epochs: usize,
    /// `(epochs trained, validation NLL)` at every evaluation (for
    /// [`Method::Full`], at the best prior weight of that evaluation).
    pub validation: Vec<(usize, f64)>,
    /// [`Method::Full`]: the selected prior weight `τ`.
    #[serde(default)]
    pub prior_weight: Option<f64>,
    /// [`Method::Full`]: `(τ, validation NLL)` of the selected epoch for
    /// every candidate weight.
    #[serde(default)]
    pub by_prior_weight: Vec<(f64, f64)>,
}

/// Trains one model and selects, for each of `methods` it serves, the
/// model of the epoch with the lowest validation NLL of that method's
/// policy (and, for [`Method::Full`], the prior weight among
/// `config.prior_weights`; it needs the no-graph model as `head`).
///
/// Trains for up to `config.optim.epochs` epochs, evaluating every
/// `config.eval_every` epochs (and after the last); without validation
/// data the last epoch (and the largest prior weight) is used. Every method
/// must use the same trained model ([`Method::ablation`]). Each selected
/// model is saved under [`selected_dir`] with its [`Selection`]; a run
/// folder that has them for the same configuration is reused without
/// training.
pub fn train_method(
    methods: &[Method],
    data: &JigsawsData,
    config: &JigsawsConfig,
    dir: &Path,
    head: Option<&NtgModel>,
    device: &Device,
    mut on_epoch: impl FnMut(&EpochMetrics),
) -> anyhow::Result<Vec<(NtgModel, TrainedRun)>> {
    let first = *methods.first().context("no method to train for")?;
    let ablation = first
        .ablation()
        .with_context(|| format!("method {} has no model to train", first.name()))?;
    ensure!(
        methods
            .iter()
            .all(|m| m.ablation().as_ref() == Some(&ablation)),
        "the methods {:?} do not share one trained model",
        methods.iter().map(|m| m.name()).collect::<Vec<_>>()
    );
    let no_graph = ablation == Method::NoGraph.ablation().context("no-graph ablation")?;
    let weights = &config.prior_weights;
    if methods.contains(&Method::Full) {
        ensure!(head.is_some(), "the full method needs the no-graph model");
        ensure!(!weights.is_empty(), "the full method needs a prior weight");
    }
    let run = open_run(
        dir,
        &RunConfig {
            experiment: config.clone(),
            methods: methods.to_vec(),
        },
    )?;
    let finished = methods
        .iter()
        .all(|&m| selected_dir(dir, m).join(SELECTION_FILE).is_file());
    let selected: Vec<(NtgModel, Selection)> = if finished {
        methods
            .iter()
            .map(|&m| {
                let sel_dir = selected_dir(dir, m);
                let selection: Selection = RunDir::read_json(&sel_dir.join(SELECTION_FILE))?;
                let model = NtgModel::load(&sel_dir, device)
                    .with_context(|| format!("reusing {}", sel_dir.display()))?;
                Ok((model, selection))
            })
            .collect::<anyhow::Result<_>>()?
    } else {
        let encoder = EncoderConfig::kinematics(config.observation.window);
        let mut model_config = NtgConfig::for_domain(data.vocab.len(), encoder);
        model_config.seed = config.model_seed;
        model_config.ablation = ablation;
        model_config.soft_edges = Some(config.soft_edges && !no_graph);
        let fresh = NtgModel::new(model_config, device)?;
        let max = config.optim.epochs;
        let mut marks: Vec<usize> = (1..=max).filter(|e| e % config.eval_every == 0).collect();
        if marks.last() != Some(&max) {
            marks.push(max);
        }
        // Per method: (value, mark, model, weight index, values by weight).
        type Best = (f64, usize, NtgModel, usize, Vec<f64>);
        let mut best: Vec<Option<Best>> = vec![None; methods.len()];
        let mut curves = vec![Vec::new(); methods.len()];
        let mut trainer = if no_graph {
            // In-memory trainer: start the metrics log afresh.
            let _ = std::fs::remove_file(run.metrics_path());
            Some(NoGraphTrainer::new(fresh.clone(), &data.train)?)
        } else {
            None
        };
        for &mark in &marks {
            let model = match &mut trainer {
                Some(trainer) => {
                    trainer.train_to(mark, &config.optim, device, |m| {
                        on_epoch(m);
                        run.append_metrics(m)
                    })?;
                    trainer.model().clone()
                }
                None => {
                    // `train` resumes from the run's checkpoint, so training
                    // in stages takes exactly the steps of one long run.
                    let optim = OptimConfig {
                        epochs: mark,
                        ..config.optim.clone()
                    };
                    train(
                        fresh.clone(),
                        &data.train,
                        &optim,
                        &run,
                        device,
                        &mut on_epoch,
                    )?
                }
            };
            for (i, &method) in methods.iter().enumerate() {
                // (value, index of the best weight, value per weight).
                let value: Option<(f64, usize, Vec<f64>)> = match (method, head) {
                    (Method::Full, Some(head)) => {
                        validation_by_weight(head, &model, data, config.smoothing, weights)?.map(
                            |values| {
                                let (w, v) = values
                                    .iter()
                                    .enumerate()
                                    .min_by(|a, b| a.1.total_cmp(b.1))
                                    .map_or((0, f64::NAN), |(w, &v)| (w, v));
                                (v, w, values)
                            },
                        )
                    }
                    _ => validation_nll(Scorer::Own(method, &model), data, config.smoothing)?
                        .map(|v| (v, 0, Vec::new())),
                };
                if let Some((v, _, _)) = &value {
                    curves[i].push((mark, *v));
                }
                let better = match (&best[i], &value) {
                    (None, _) | (Some(_), None) => true,
                    (Some((b, ..)), Some((v, _, _))) => v < b,
                };
                if better {
                    best[i] = Some(match value {
                        Some((v, w, values)) => (v, mark, model.clone(), w, values),
                        // No validation data: the last epoch, the largest weight.
                        None => (
                            f64::NAN,
                            mark,
                            model.clone(),
                            weights.len().saturating_sub(1),
                            Vec::new(),
                        ),
                    });
                }
            }
        }
        methods
            .iter()
            .zip(best)
            .zip(curves)
            .map(|((&method, best), curve)| {
                let (_, epochs, model, w, values) =
                    best.context("no epochs to train (epochs is 0)")?;
                let full = method == Method::Full;
                let selection = Selection {
                    epochs,
                    validation: curve,
                    prior_weight: full.then(|| weights[w]),
                    by_prior_weight: if full {
                        weights.iter().copied().zip(values).collect()
                    } else {
                        Vec::new()
                    },
                };
                let sel_dir = selected_dir(dir, method);
                model.save(&sel_dir)?;
                RunDir::write_json(&sel_dir.join(SELECTION_FILE), &selection)?;
                Ok((model, selection))
            })
            .collect::<anyhow::Result<_>>()?
    };
    let metrics = read_metrics(&run)?;
    Ok(methods
        .iter()
        .zip(selected)
        .map(|(&method, (model, selection))| {
            (
                model,
                TrainedRun {
                    method,
                    run: dir.to_owned(),
                    train_seconds: metrics.iter().map(|m| f64::from(m.seconds)).sum(),
                    last_epoch: metrics.last().cloned(),
                    selection,
                },
            )
        })
        .collect())
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
    let device = ntg_model::cpu_device().autodiff();
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

/// One setting of the [`seed_table`]: the base configuration with at most
/// one seed changed.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum SeedSetting {
    /// The base configuration.
    Default,
    /// Another seed of the synthetic data.
    Data(u64),
    /// Another seed of both models' initial weights.
    Model(u64),
}

impl SeedSetting {
    /// The settings of the table: the default, synthetic-data seeds 1–3
    /// (synthetic data only) and model seeds 1–5.
    pub fn all(source: &DataSource) -> Vec<SeedSetting> {
        let data: &[u64] = match source {
            DataSource::Synthetic { .. } => &[1, 2, 3],
            DataSource::Root { .. } => &[],
        };
        std::iter::once(SeedSetting::Default)
            .chain(data.iter().map(|&s| SeedSetting::Data(s)))
            .chain((1..=5).map(SeedSetting::Model))
            .collect()
    }

    /// Name in reports and run folders: `default`, `data1`, `model2`.
    pub fn name(self) -> String {
        match self {
            SeedSetting::Default => "default".to_owned(),
            SeedSetting::Data(s) => format!("data{s}"),
            SeedSetting::Model(s) => format!("model{s}"),
        }
    }

    /// `base` with this setting's seed. Errors for a data seed on a
    /// dataset read from disk.
    pub fn apply(self, base: &JigsawsConfig) -> anyhow::Result<JigsawsConfig> {
        let mut config = base.clone();
        match (self, &mut config.source) {
            (SeedSetting::Default, _) => {}
            (SeedSetting::Model(s), _) => config.model_seed = s,
            (SeedSetting::Data(s), DataSource::Synthetic { seed, .. }) => *seed = s,
            (SeedSetting::Data(_), DataSource::Root { path }) => bail!(
                "{}: a dataset on disk has no data seed to change",
                path.display()
            ),
        }
        Ok(config)
    }
}

/// One row of the [`seed_table`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SeedRow {
    /// The setting.
    pub setting: SeedSetting,
    /// Mean NLL over conditioning demos, per method in [`Method::ALL`]
    /// order.
    pub nll: Vec<(Method, f64)>,
    /// [`Method::Full`]'s selected prior weight.
    pub prior_weight: Option<f64>,
}

impl SeedRow {
    /// The mean NLL of `method`.
    pub fn nll(&self, method: Method) -> Option<f64> {
        self.nll.iter().find(|(m, _)| *m == method).map(|&(_, v)| v)
    }

    fn of(setting: SeedSetting, result: &JigsawsResult) -> SeedRow {
        SeedRow {
            setting,
            nll: result
                .methods
                .iter()
                .map(|m| (m.method, m.mean_nll))
                .collect(),
            prior_weight: result
                .runs
                .iter()
                .find(|r| r.method == Method::Full)
                .and_then(|r| r.selection.prior_weight),
        }
    }
}

/// The experiment repeated with one seed changed at a time
/// ([`SeedSetting::all`]): does full NTG beat no graph whatever the seeds?
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SeedTable {
    /// One row per setting.
    pub rows: Vec<SeedRow>,
}

impl SeedTable {
    /// Settings where `a` scored a lower NLL than `b`.
    pub fn wins(&self, a: Method, b: Method) -> usize {
        self.rows
            .iter()
            .filter(|r| matches!((r.nll(a), r.nll(b)), (Some(x), Some(y)) if x < y))
            .count()
    }

    /// Mean over settings of `method`'s NLL.
    pub fn mean(&self, method: Method) -> f64 {
        let v: Vec<f64> = self.rows.iter().filter_map(|r| r.nll(method)).collect();
        v.iter().sum::<f64>() / v.len().max(1) as f64
    }
}

/// Runs the experiment of `base` once per [`SeedSetting::all`] (run folders
/// under `<runs>/jigsaws-seeds/<setting>/`, reused when finished), taking
/// the default row from `done` when given (the result of `base` itself).
pub fn seed_table(
    base: &JigsawsConfig,
    done: Option<&JigsawsResult>,
    runs: &Path,
    mut log: impl FnMut(&str),
) -> anyhow::Result<SeedTable> {
    let mut rows = Vec::new();
    for setting in SeedSetting::all(&base.source) {
        let row = match (setting, done) {
            (SeedSetting::Default, Some(result)) => SeedRow::of(setting, result),
            _ => {
                let config = setting.apply(base)?;
                log(&format!("jigsaws seed table: {}", setting.name()));
                let dir = runs.join("jigsaws-seeds").join(setting.name());
                let result = run_experiment(&config, &dir, |line| {
                    if !line.starts_with("  epoch") {
                        log(line);
                    }
                })?;
                SeedRow::of(setting, &result)
            }
        };
        rows.push(row);
    }
    Ok(SeedTable { rows })
}

/// The seed table as Markdown (a table and a one-line summary).
pub fn seed_table_markdown(table: &SeedTable) -> String {
    let mut s = String::new();
    let _ = writeln!(
        s,
        "| setting | no graph | NTG, own head | NTG (full) | τ | full < no graph |"
    );
    let _ = writeln!(s, "|---|---|---|---|---|---|");
    let cell = |v: Option<f64>| v.map_or("–".to_owned(), |v| format!("{v:.3}"));
    for r in &table.rows {
        let (ng, full) = (r.nll(Method::NoGraph), r.nll(Method::Full));
        let _ = writeln!(
            s,
            "| {} | {} | {} | {} | {} | {} |",
            r.setting.name(),
            cell(ng),
            cell(r.nll(Method::FullOwnHead)),
            cell(full),
            r.prior_weight.map_or("–".to_owned(), |w| w.to_string()),
            match (full, ng) {
                (Some(f), Some(n)) if f < n => "yes",
                _ => "**no**",
            }
        );
    }
    let n = table.rows.len();
    let _ = writeln!(
        s,
        "| mean | {:.3} | {:.3} | {:.3} | | full lower in {} of {n}; own head lower than no graph in {} of {n} |",
        table.mean(Method::NoGraph),
        table.mean(Method::FullOwnHead),
        table.mean(Method::Full),
        table.wins(Method::Full, Method::NoGraph),
        table.wins(Method::FullOwnHead, Method::NoGraph),
    );
    s
}

/// Runs the experiment at `profile` (synthetic data, seed 0, unless `root`
/// names a JIGSAWS copy), and writes `<out>/jigsaws.{svg,png}` (the bar
/// chart), `<out>/jigsaws_graph.{dot,svg}` (the predicted Needle Passing
/// graph) and `<out>/jigsaws.json`.
pub fn reproduce(
    profile: Profile,
    root: Option<&Path>,
    runs: &Path,
    out: &Path,
) -> anyhow::Result<JigsawsResult> {
    let source = match root {
        Some(path) => DataSource::Root {
            path: path.to_owned(),
        },
        None => DataSource::Synthetic {
            seed: 0,
            duration_scale: 1.0,
        },
    };
    let config = JigsawsConfig::for_profile(profile, source);
    let mut result = run_experiment(&config, runs, |line| eprintln!("{line}"))?;
    // The table multiplies the experiment's cost by ten: the paper profile
    // runs it; at the quick profile (whose whole run must fit 15 minutes
    // with the build) it is `ntg jigsaws nll --seed-table`.
    if profile == Profile::Paper {
        result.seeds = Some(seed_table(&config, Some(&result), runs, |line| {
            eprintln!("{line}")
        })?);
    }
    write_outputs(&result, out)?;
    Ok(result)
}

/// Writes the figure, the graph, the report section (`jigsaws.md`) and the
/// JSON of `result` into `out`.
pub fn write_outputs(result: &JigsawsResult, out: &Path) -> anyhow::Result<()> {
    std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
    write_figure(result, &out.join("jigsaws"))?;
    let dot_path = out.join("jigsaws_graph.dot");
    std::fs::write(&dot_path, &result.graph.dot)
        .with_context(|| format!("writing {}", dot_path.display()))?;
    let svg = crate::svg::dot_to_svg(&result.graph.dot)?;
    let svg_path = out.join("jigsaws_graph.svg");
    std::fs::write(&svg_path, svg).with_context(|| format!("writing {}", svg_path.display()))?;
    let md_path = out.join("jigsaws.md");
    std::fs::write(&md_path, report_section(result))
        .with_context(|| format!("writing {}", md_path.display()))?;
    RunDir::write_json(&out.join("jigsaws.json"), result)
}

/// The bar chart: mean per-step NLL per method, ±1 standard deviation over
/// conditioning demos.
pub fn write_figure(result: &JigsawsResult, stem: &Path) -> anyhow::Result<()> {
    let bars = result
        .methods
        .iter()
        .map(|m| crate::figure::Bar {
            label: m.method.label().to_owned(),
            value: m.mean_nll,
            lo: m.mean_nll - m.std_nll,
            hi: m.mean_nll + m.std_nll,
        })
        .collect();
    crate::figure::write_bar_chart(
        &crate::figure::BarChart {
            title: format!(
                "{TEST_TASK} from one demo ({} demos, {})",
                result.test_demos,
                match result.config.source {
                    DataSource::Synthetic { .. } => "synthetic stand-in",
                    DataSource::Root { .. } => "JIGSAWS copy",
                }
            ),
            y_label: "NLL per step (nats, lower is better)".into(),
            bars,
        },
        stem,
    )
}

/// The report section (Markdown) of a result.
pub fn report_section(result: &JigsawsResult) -> String {
    let mut s = String::new();
    let selected: Vec<String> = result
        .runs
        .iter()
        .map(|r| {
            format!(
                "{} after {}{}",
                r.method.label(),
                r.selection.epochs,
                r.selection
                    .prior_weight
                    .map_or(String::new(), |w| format!(" (prior weight τ = {w})"))
            )
        })
        .collect();
    let _ = writeln!(
        s,
        "## Fig. jigsaws: cross-task NLL on {TEST_TASK}\n\n![jigsaws](jigsaws.png)\n\nData: {}. Trained on {} {} + {} demos for up to {} epochs; the model of each method is the one with the lowest NLL on held-out {} and {} demos (every {}-th trial), checked every {} epochs: {} epochs (the two full methods are one training run). Each of the {} {TEST_TASK} demos conditions one policy, scored on all the others. Per-step NLL in nats with ε = {} smoothing (a probability-0 step costs ln(16/ε); such steps are counted); ± is the standard deviation over conditioning demos. Definitions: module docs of `ntg_trainer::jigsaws`.\n",
        result.source,
        result.train_demos,
        TRAIN_TASKS[0],
        TRAIN_TASKS[1],
        result.config.optim.epochs,
        TRAIN_TASKS[0],
        TRAIN_TASKS[1],
        result.config.validation_every,
        result.config.eval_every,
        selected.join("; "),
        result.test_demos,
        result.config.smoothing
    );
    let _ = writeln!(
        s,
        "| method | NLL (mean ± std) | min–max over demos | steps at probability 0 | training time |"
    );
    let _ = writeln!(s, "|---|---|---|---|---|");
    for m in &result.methods {
        let time = result
            .runs
            .iter()
            .find(|r| r.method == m.method)
            .map_or("–".to_owned(), |r| format!("{:.0} s", r.train_seconds));
        let _ = writeln!(
            s,
            "| {} | {:.3} ± {:.3} | {:.3}–{:.3} | {} of {} | {time} |",
            m.method.label(),
            m.mean_nll,
            m.std_nll,
            m.min_nll,
            m.max_nll,
            m.zero_probability_steps,
            m.steps
        );
    }
    let nll = |m| result.method(m).map_or(f64::NAN, |r| r.mean_nll);
    let (u, ng, f) = (
        nll(Method::Uniform),
        nll(Method::NoGraph),
        nll(Method::Full),
    );
    let verdict = if f < ng && ng < u {
        "the same order here".to_owned()
    } else {
        format!("**not the order measured here** (full {f:.3}, no graph {ng:.3}, uniform {u:.3})")
    };
    let _ = writeln!(
        s,
        "\nPaper: uniform worst, no graph better, full NTG best (no numbers in the text): {verdict}. **Deviation from the paper:** \"NTG (full)\" uses the completed graph as a prior on the no-graph model's node localizer and edge classifier, `ε(a|n,o) ∝ C_na^τ · ε₀(a|n,o)`, with τ chosen on the held-out training-task demos; \"NTG, own head\" is the full model with the paper's wiring (an edge classifier reading the GCN's embeddings), shown for comparison.\n"
    );
    if let Some(table) = &result.seeds {
        let _ = writeln!(
            s,
            "**Seed sensitivity.** The same experiment with one seed changed at a time (synthetic data, or both models' initial weights); mean NLL over conditioning demos, τ the selected prior weight of NTG (full):\n\n{}",
            seed_table_markdown(table)
        );
    }
    let g = &result.graph;
    let short = |v: &[String]| {
        if v.len() > 30 {
            format!("{} … ({} gestures)", v[..30].join(" "), v.len())
        } else {
            v.join(" ")
        }
    };
    if result.seeds.is_none() {
        let _ = writeln!(
            s,
            "**Seed sensitivity.** Not run here: `ntg jigsaws nll --seed-table` repeats the experiment with one seed changed at a time (the paper profile of `ntg reproduce` includes it; the table measured at the quick profile is in the docs of `ntg_trainer::jigsaws`).\n"
        );
    }
    let _ = writeln!(
        s,
        "Predicted graph for {} ([SVG](jigsaws_graph.svg), [DOT](jigsaws_graph.dot); dashed: added by the GCN, with its probability): transcription `{}` (expert: `{}`); the path has {} edges, the completed graph {} ({} of them in the ground-truth {TEST_TASK} graph of {} edges, the union of all its demos); added by the GCN: {}.\n",
        g.trial,
        short(&g.transcription),
        short(&g.demo_gestures),
        g.path_edges,
        g.graph_edges,
        g.correct_edges,
        g.truth_edges,
        if g.added_edges.is_empty() {
            "none".to_owned()
        } else {
            g.added_edges.join(", ")
        }
    );
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    fn small_synthetic(trials: usize, seed: u64) -> Dataset {
        let config = SynthConfig {
            max_trials_per_task: Some(trials),
            duration_scale: 0.3,
            ..SynthConfig::new(seed)
        };
        env_jigsaws::generate(&config).unwrap().dataset
    }

    #[test]
    fn trials_become_one_step_per_segment_with_held_out_demos() {
        let dataset = small_synthetic(6, 3);
        let data = build_data(&dataset, ObservationConfig::default(), 3, "test").unwrap();
        // 6 trials per task, positions 2 and 5 held out.
        assert_eq!(data.train.demos().len(), 8);
        assert_eq!(data.validation.len(), 2);
        assert!(data.validation.iter().all(|g| g.len() == 2));
        assert_eq!(data.test.len(), 6);
        assert_eq!(data.train.obs_dim(), 10 * 76);
        let suturing = dataset.trials(Task::Suturing);
        let kept: Vec<&Trial> = suturing
            .iter()
            .enumerate()
            .filter(|(i, _)| i % 3 != 2)
            .map(|(_, t)| t)
            .collect();
        for (entry, trial) in data.train.demos().iter().zip(&kept) {
            assert_eq!(entry.task, 0);
            let ids: Vec<ActionId> = trial.gestures().iter().map(|g| g.action_id()).collect();
            assert_eq!(entry.actions, ids, "{}", trial.id());
            assert_eq!(entry.rows().len(), trial.segments.len() + 1);
        }
        assert_eq!(data.validation[0][0].trial, suturing[2].id().to_string());
        let last = data.train.demos().last().unwrap();
        assert_eq!(last.task, 1);
        let np = dataset.trials(TEST_TASK);
        assert_eq!(data.test[0].trial, np[0].id().to_string());
        assert_eq!(data.test[0].demo.len(), np[0].segments.len());
        // Deterministic.
        let again =
            build_data(&small_synthetic(6, 3), ObservationConfig::default(), 3, "t").unwrap();
        assert_eq!(again.train, data.train);
        assert_eq!(again.test, data.test);
    }

    #[test]
    fn leave_one_out_pools_the_steps_of_the_other_demos() {
        let data =
            build_data(&small_synthetic(3, 1), ObservationConfig::default(), 0, "t").unwrap();
        let test = &data.test[..3];
        // nlls(d, e) = [e + 1; e + 1]: demo e has e + 1 steps of NLL e + 1.
        let table: Vec<Vec<f64>> = (0..3).map(|e| vec![(e + 1) as f64; e + 1]).collect();
        let scores = leave_one_out(test, |_, e| (&table[e], usize::from(e == 2)));
        // d = 0: steps 2·2 + 3·3 = 13 over 5 steps.
        assert!((scores[0].nll - 13.0 / 5.0).abs() < 1e-12);
        assert_eq!((scores[0].steps, scores[0].zero_probability_steps), (5, 1));
        // d = 2: 1 + 2·2 = 5 over 3 steps, no zero.
        assert!((scores[2].nll - 5.0 / 3.0).abs() < 1e-12);
        assert_eq!(scores[2].zero_probability_steps, 0);
        let r = MethodResult::from_scores(Method::Full, scores);
        assert!(r.min_nll <= r.mean_nll && r.mean_nll <= r.max_nll);
        assert_eq!(r.steps, 5 + 4 + 3);
    }

    #[test]
    fn uniform_scores_ln_16_and_models_are_required() {
        let data =
            build_data(&small_synthetic(3, 2), ObservationConfig::default(), 0, "t").unwrap();
        let r = score(Method::Uniform, Scorer::Uniform, &data, DEFAULT_SMOOTHING).unwrap();
        assert_eq!(num_choices(&data.vocab), 16);
        for d in &r.per_demo {
            assert!((d.nll - 16f64.ln()).abs() < 1e-6, "{d:?}");
        }
        let err = score_demos(Scorer::Uniform, &data.vocab, &data.test[..1], 0.0).unwrap_err();
        assert!(err.to_string().contains("at least 2"), "{err}");
    }

    #[test]
    fn missing_tasks_and_bad_roots_are_clear_errors() {
        let full = small_synthetic(3, 0);
        let only = |tasks: &[Task], np: usize| {
            let trials = full
                .all_trials()
                .filter(|t| tasks.contains(&t.id().task))
                .filter(|t| {
                    t.id().task != TEST_TASK || {
                        let i = full.trials(TEST_TASK).iter().position(|x| x.id() == t.id());
                        i.is_some_and(|i| i < np)
                    }
                })
                .cloned()
                .collect();
            Dataset::from_trials(tasks, trials)
        };
        let err = build_data(
            &only(&[Task::Suturing, TEST_TASK], 3),
            ObservationConfig::default(),
            0,
            "root X",
        )
        .unwrap_err()
        .to_string();
        assert!(
            err.contains("root X") && err.contains("Knot_Tying"),
            "{err}"
        );
        let err = build_data(
            &only(&Task::ALL, 1),
            ObservationConfig::default(),
            0,
            "root X",
        )
        .unwrap_err()
        .to_string();
        assert!(
            err.contains("1 usable Needle_Passing") && err.contains("at least 2"),
            "{err}"
        );
        let err = build_data(&full, ObservationConfig::default(), 1, "root X")
            .unwrap_err()
            .to_string();
        assert!(err.contains("no Suturing trials left to train on"), "{err}");

        let dir = tempfile::tempdir().unwrap();
        let missing = DataSource::Root {
            path: dir.path().join("nope"),
        };
        let err = load_source(&missing).unwrap_err().to_string();
        assert!(
            err.contains("nope") && err.contains("no such folder"),
            "{err}"
        );
        let empty = DataSource::Root {
            path: dir.path().to_owned(),
        };
        let err = format!("{:#}", load_source(&empty).unwrap_err());
        assert!(err.contains("no JIGSAWS task folder"), "{err}");

        let mut config = JigsawsConfig::for_profile(Profile::Smoke, empty);
        config.smoothing = 1.0;
        let err = run_experiment(&config, dir.path(), |_| {}).unwrap_err();
        assert!(err.to_string().contains("smoothing"), "{err}");
        config.smoothing = DEFAULT_SMOOTHING;
        for bad in [vec![], vec![0.5, 1.5], vec![f64::NAN]] {
            config.prior_weights = bad;
            let err = run_experiment(&config, dir.path(), |_| {}).unwrap_err();
            assert!(err.to_string().contains("prior weights"), "{err}");
        }
    }

    /// The no-graph trainer learns: on a small synthetic set, a few epochs
    /// bring the held-out NLL of the training tasks far below uniform's, and
    /// the same seed gives the same model.
    #[test]
    fn no_graph_trainer_learns_the_next_gesture() {
        let data =
            build_data(&small_synthetic(8, 5), ObservationConfig::default(), 4, "t").unwrap();
        let device = ntg_model::cpu_device().autodiff();
        let optim = OptimConfig {
            epochs: 6,
            batch_size: 4,
            learning_rate: 3e-3,
            seed: 0,
            token_dropout: 0.0,
            cosine_decay: false,
            gcn_from_other_demo: false,
        };
        let train = || {
            let mut config = NtgConfig::for_domain(data.vocab.len(), EncoderConfig::kinematics(10));
            config.ablation = Method::NoGraph.ablation().unwrap();
            let model = NtgModel::new(config, &device).unwrap();
            let before = validation_nll(Scorer::Own(Method::NoGraph, &model), &data, 0.01)
                .unwrap()
                .unwrap();
            let mut trainer = NoGraphTrainer::new(model, &data.train).unwrap();
            trainer
                .train_to(optim.epochs, &optim, &device, |_| Ok(()))
                .unwrap();
            let after = validation_nll(Scorer::Own(Method::NoGraph, trainer.model()), &data, 0.01)
                .unwrap()
                .unwrap();
            (before, after)
        };
        let (before, after) = train();
        let uniform = 16f64.ln();
        assert!(
            after < 0.5 * uniform,
            "held-out NLL {after:.3} (uniform {uniform:.3})"
        );
        assert!(after < before - 0.5, "before {before:.3}, after {after:.3}");
        assert_eq!(train(), (before, after));
    }

    /// The two full methods share one trained model, each with its own
    /// selection. The own-head model's policy weighs edges by the GCN's
    /// probabilities and logs the GCN's edge F1 (the no-graph model logs
    /// none). The graph-prior method's selection covers every candidate
    /// weight, picks the lowest, and at weight 0 reproduces the no-graph
    /// policy's validation NLL; both fall far below uniform's.
    #[test]
    fn full_methods_share_one_run_and_select_the_prior_weight() {
        let data =
            build_data(&small_synthetic(8, 5), ObservationConfig::default(), 4, "t").unwrap();
        let mut config = JigsawsConfig::for_profile(
            Profile::Smoke,
            DataSource::Synthetic {
                seed: 5,
                duration_scale: 0.3,
            },
        );
        assert!(config.soft_edges && config.optim.gcn_from_other_demo);
        config.optim.epochs = 6;
        config.eval_every = 3;
        let dir = tempfile::tempdir().unwrap();
        let device = ntg_model::cpu_device().autodiff();
        let fit = |methods: &[Method],
                   run: &Path,
                   head: Option<&NtgModel>,
                   on_epoch: &mut dyn FnMut(&EpochMetrics)| {
            train_method(methods, &data, &config, run, head, &device, on_epoch)
        };
        let (head, head_run) = fit(
            &[Method::NoGraph],
            &dir.path().join("no-graph"),
            None,
            &mut |m: &EpochMetrics| assert_eq!(m.edge_f1, None),
        )
        .unwrap()
        .pop()
        .unwrap();
        assert!(!head.config().uses_soft_edges());
        let err = fit(
            &[Method::Full],
            &dir.path().join("bad"),
            None,
            &mut |_: &EpochMetrics| {},
        )
        .unwrap_err();
        assert!(
            err.to_string().contains("needs the no-graph model"),
            "{err}"
        );
        let err = fit(
            &[Method::NoGraph, Method::Full],
            &dir.path().join("bad"),
            Some(&head),
            &mut |_: &EpochMetrics| {},
        )
        .unwrap_err();
        assert!(err.to_string().contains("do not share"), "{err}");

        let mut logged = Vec::new();
        let full_dir = dir.path().join("full");
        let mut trained = fit(
            &[Method::FullOwnHead, Method::Full],
            &full_dir,
            Some(&head),
            &mut |m: &EpochMetrics| logged.push(m.clone()),
        )
        .unwrap();
        assert_eq!(logged.len(), 6);
        assert!(logged.iter().all(|m| m.edge_f1.is_some()), "{logged:?}");
        let (graph, graph_run) = trained.pop().unwrap();
        let (own, own_run) = trained.pop().unwrap();
        assert_eq!(
            (own_run.method, graph_run.method),
            (Method::FullOwnHead, Method::Full)
        );
        assert!(own.config().uses_soft_edges());
        let policy =
            NtgPolicy::from_demo(&own.valid(), data.test[0].demo.observations(), &data.vocab)
                .unwrap();
        assert!(policy.edge_weights().is_some());
        assert_eq!(own_run.selection.prior_weight, None);

        let uniform = 16f64.ln();
        let sel = &graph_run.selection;
        assert_eq!(sel.validation.len(), 2);
        let weights: Vec<f64> = sel.by_prior_weight.iter().map(|&(w, _)| w).collect();
        assert_eq!(weights, config.prior_weights);
        let (best_w, best_v) = sel
            .by_prior_weight
            .iter()
            .copied()
            .min_by(|a, b| a.1.total_cmp(&b.1))
            .unwrap();
        assert_eq!(sel.prior_weight, Some(best_w));
        assert!(sel.validation.contains(&(sel.epochs, best_v)), "{sel:?}");
        assert!(best_v < 0.5 * uniform, "held-out NLL {best_v:.3}");
        // Weight 0: the no-graph policy, whatever the graph.
        let at_zero = validation_by_weight(&head, &graph, &data, DEFAULT_SMOOTHING, &[0.0])
            .unwrap()
            .unwrap()[0];
        let own_head = validation_nll(
            Scorer::Own(Method::NoGraph, &head),
            &data,
            DEFAULT_SMOOTHING,
        )
        .unwrap()
        .unwrap();
        assert!((at_zero - own_head).abs() < 1e-4, "{at_zero} vs {own_head}");
        let head_best = head_run
            .selection
            .validation
            .iter()
            .map(|v| v.1)
            .fold(f64::MAX, f64::min);
        assert!((own_head - head_best).abs() < 1e-9);

        // A run folder of the older one-method format is refused clearly.
        let old_format = dir.path().join("old");
        std::fs::create_dir_all(&old_format).unwrap();
        std::fs::write(
            old_format.join("config.json"),
            serde_json::json!({ "experiment": config, "method": "full" }).to_string(),
        )
        .unwrap();
        let err = fit(
            &[Method::NoGraph],
            &old_format,
            None,
            &mut |_: &EpochMetrics| {},
        )
        .unwrap_err()
        .to_string();
        assert!(
            err.contains("another configuration") && err.contains("older format"),
            "{err}"
        );

        // A finished run is reused as it was selected.
        let again = fit(
            &[Method::FullOwnHead, Method::Full],
            &full_dir,
            Some(&head),
            &mut |_: &EpochMetrics| panic!("a finished run trained again"),
        )
        .unwrap();
        let reused = &again[1].1.selection;
        assert_eq!(
            (reused.epochs, reused.prior_weight),
            (sel.epochs, sel.prior_weight)
        );
        for (a, b) in reused.by_prior_weight.iter().zip(&sel.by_prior_weight) {
            // JSON keeps the values to the last bit or so.
            assert!(a.0 == b.0 && (a.1 - b.1).abs() < 1e-12, "{a:?} vs {b:?}");
        }
        let scored = |model: &NtgModel| {
            score(
                Method::Full,
                Scorer::GraphPrior {
                    head: &head,
                    graph: model,
                    weight: best_w,
                },
                &data,
                DEFAULT_SMOOTHING,
            )
            .unwrap()
        };
        assert_eq!(scored(&again[1].0), scored(&graph));
    }

    /// The prior on hand-made numbers: one node sure, a uniform head over
    /// three actions, `C` = (0, 1, 0.25).
    #[test]
    fn graph_prior_weighs_the_head_by_c_to_the_weight() {
        let n = 3;
        let prior = GraphPrior {
            weights: vec![0.0, 1.0, 0.25, 0.0, 1.0, 1.0, 0.0, 0.0, 0.0],
            num_nodes: n,
        };
        let node = [1.0, 0.0, 0.0];
        let edge = [1.0 / 3.0; 9];
        let p = |w: f64| -> Vec<f64> {
            prior
                .log_probabilities(&node, &edge, w)
                .unwrap()
                .iter()
                .map(|&l| f64::from(l).exp())
                .collect()
        };
        let close = |a: &[f64], b: &[f64]| a.iter().zip(b).all(|(x, y)| (x - y).abs() < 1e-6);
        // Weight 1: ∝ C; 0.5: ∝ √C; 0: uniform over C's support.
        assert!(close(&p(1.0), &[0.0, 0.8, 0.2]), "{:?}", p(1.0));
        assert!(close(&p(0.5), &[0.0, 2.0 / 3.0, 1.0 / 3.0]), "{:?}", p(0.5));
        assert!(close(&p(0.0), &[0.0, 0.5, 0.5]), "{:?}", p(0.0));
        // The head's preferences count too, and node mass mixes rows; a
        // node without successors (row 2) is skipped.
        let edge = [0.0, 0.5, 0.5, 0.0, 0.9, 0.1, 0.0, 0.0, 0.0];
        let logs = prior
            .log_probabilities(&[0.5, 0.25, 0.25], &edge, 1.0)
            .unwrap();
        let got: Vec<f64> = logs.iter().map(|&l| f64::from(l).exp()).collect();
        // Row 0: (0.5, 0.125) / 0.625 = (0.8, 0.2); row 1: (0.9, 0.1).
        let want = [
            0.0,
            (0.5 * 0.8 + 0.25 * 0.9) / 0.75,
            (0.5 * 0.2 + 0.25 * 0.1) / 0.75,
        ];
        assert!(close(&got, &want), "{got:?}");
        assert_eq!(logs[0], f32::NEG_INFINITY);
        // Bad input.
        let err = prior.log_probabilities(&node, &edge[..8], 1.0).unwrap_err();
        assert!(err.to_string().contains("8 edge"), "{err}");
        let err = prior.log_probabilities(&node, &edge, -1.0).unwrap_err();
        assert!(err.to_string().contains("non-negative"), "{err}");
        let err = prior.log_probabilities(&[0.0; 3], &edge, 1.0).unwrap();
        assert!(err.iter().all(|&l| l == f32::NEG_INFINITY));
    }

    #[test]
    fn seed_settings_change_one_seed_and_the_table_counts_wins() {
        let synth = DataSource::Synthetic {
            seed: 0,
            duration_scale: 1.0,
        };
        let base = JigsawsConfig::for_profile(Profile::Quick, synth.clone());
        let all = SeedSetting::all(&synth);
        assert_eq!(all.len(), 9);
        let names: Vec<String> = all.iter().map(|s| s.name()).collect();
        assert_eq!(names[..4], ["default", "data1", "data2", "data3"]);
        assert_eq!(names[8], "model5");
        let data2 = SeedSetting::Data(2).apply(&base).unwrap();
        assert_eq!(
            (data2.source.run_tag(), data2.model_seed),
            ("synth2".to_owned(), 0)
        );
        let model3 = SeedSetting::Model(3).apply(&base).unwrap();
        assert_eq!((model3.source.clone(), model3.model_seed), (synth, 3));
        assert_eq!(SeedSetting::Default.apply(&base).unwrap(), base);
        let root = DataSource::Root {
            path: PathBuf::from("/data/jigsaws"),
        };
        assert!(
            SeedSetting::all(&root)
                .iter()
                .all(|s| !matches!(s, SeedSetting::Data(_)))
        );
        let on_disk = JigsawsConfig::for_profile(Profile::Quick, root);
        let err = SeedSetting::Data(1).apply(&on_disk).unwrap_err();
        assert!(err.to_string().contains("no data seed"), "{err}");

        let row = |setting, ng: f64, own: f64, full: f64| SeedRow {
            setting,
            nll: vec![
                (Method::Uniform, 16f64.ln()),
                (Method::NoGraph, ng),
                (Method::FullOwnHead, own),
                (Method::Full, full),
            ],
            prior_weight: Some(0.5),
        };
        let table = SeedTable {
            rows: vec![
                row(SeedSetting::Default, 0.7, 0.6, 0.65),
                row(SeedSetting::Data(1), 0.6, 0.8, 0.62),
                row(SeedSetting::Model(1), 0.5, 0.9, 0.4),
            ],
        };
        assert_eq!(table.wins(Method::Full, Method::NoGraph), 2);
        assert_eq!(table.wins(Method::FullOwnHead, Method::NoGraph), 1);
        assert!((table.mean(Method::Full) - (0.65 + 0.62 + 0.4) / 3.0).abs() < 1e-12);
        let md = seed_table_markdown(&table);
        assert!(
            md.contains("| data1 | 0.600 | 0.800 | 0.620 | 0.5 | **no** |"),
            "{md}"
        );
        assert!(md.contains("full lower in 2 of 3"), "{md}");
    }

    #[test]
    fn smoothed_nll_of_known_distributions() {
        // Uniform over 16: ln 16 whatever the smoothing.
        let (nll, zero) = smoothed_nll(-(16f64.ln()), 0.01, 16);
        assert!((nll - 16f64.ln()).abs() < 1e-12);
        assert!(!zero);
        // p = 1/2 without smoothing: ln 2.
        assert!((smoothed_nll(0.5f64.ln(), 0.0, 16).0 - 2f64.ln()).abs() < 1e-12);
        // Probability 0: finite, ln(16 / ε), and flagged.
        let (nll, zero) = smoothed_nll(f64::NEG_INFINITY, 0.01, 16);
        assert!((nll - (1600f64).ln()).abs() < 1e-9, "{nll}");
        assert!(zero);
        // Certainty: −ln(1 − ε + ε/16).
        let (nll, _) = smoothed_nll(0.0, 0.01, 16);
        assert!((nll + (0.99 + 0.01 / 16.0f64).ln()).abs() < 1e-12);
    }
}
