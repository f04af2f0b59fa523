//! Fig. "ntp_exp": block stacking, success on unseen tasks against the
//! number of seen training tasks, (a) state and (b) video input, for NTG
//! and the NTP baselines a panel lists (`methods`; NTP and NTP Flat on
//! state input so far). The runs are listed in `experiments/ntp_exp.toml`.
//! Every method of a point trains on the same tasks, demos and seeds, with
//! the same epochs (so the same optimisation steps over the same episodes)
//! and the same validation schedule, and is scored on the same test tasks.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use anyhow::Context;
use serde::{Deserialize, Serialize};

use crate::blocks::{self, BlocksRunConfig, Recipe, Variant};
use crate::domain::{DomainId, TranscriptionSplit};
use crate::experiment::template::NTP_EXP;
use crate::experiment::{Plan, share_part};
use crate::figure::{Dash, Panel, Point, Series, method_look};
use crate::method::MethodId;
use crate::method::ntp::NtpCoreKind;
use crate::run_dir::RunDir;
use crate::spec::{ObsKind, Profile};
use crate::stats::SuccessRate;

/// The figure's experiment file (`experiments/ntp_exp.toml`).
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct NtpExpExperiment {
    /// Always block stacking.
    pub domain: DomainId,
    /// The method of panels that list no `methods` (NTG).
    pub method: MethodId,
    /// The training recipe every run starts from.
    pub recipe: Recipe,
    /// Seed of every run's weights and shuffling.
    pub seed: u64,
    /// Validations per run (the best-scoring epoch is evaluated).
    pub validations_per_run: usize,
    /// Fields of the run configuration set in every run.
    #[serde(default)]
    pub overrides: toml::Table,
    /// The scale of each profile.
    pub profiles: crate::experiment::Profiles<NtpExpProfile>,
    /// Where the file was read from (for messages).
    #[serde(skip)]
    pub origin: String,
    /// The file's name (`ntp_exp`, `ablation`): the prefix of its run
    /// folders.
    #[serde(skip)]
    pub name: String,
}

/// The figure at one profile.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct NtpExpProfile {
    /// Fields of the run configuration set in this profile's runs (after
    /// the experiment's).
    #[serde(default)]
    pub overrides: toml::Table,
    /// The panels, each a curve over numbers of training tasks.
    pub panels: Vec<PanelScale>,
}

/// The scale of one panel of fig. "ntp_exp".
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PanelScale {
    /// Observation kind of the panel.
    pub obs: ObsKind,
    /// x values: numbers of training tasks.
    pub train_tasks: Vec<usize>,
    /// Demonstrations per training task.
    pub demos_per_task: usize,
    /// Training epochs (at least).
    pub epochs: usize,
    /// At least this many optimisation steps: small training sets get more
    /// epochs so that every point is trained, not just the large ones. 0 =
    /// exactly `epochs`.
    pub min_steps: usize,
    /// Unseen test tasks evaluated per point.
    pub test_tasks: usize,
    /// Fields of the run configuration set in this panel's runs (after the
    /// profile's), e.g. the video panel's `video.encoder`.
    #[serde(default)]
    pub overrides: toml::Table,
    /// The methods trained at every point (default: the experiment's
    /// `method`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub methods: Option<Vec<MethodId>>,
    /// The recipe of this panel's runs (default: the experiment's
    /// `recipe`). Two panels of one input with different recipes are two
    /// curves of one plot (item 4b of the figure's issue: NTG both as the
    /// paper describes it and with ntg-rs's additions).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub recipe: Option<Recipe>,
    /// The detector's settings of the panel's NTP (Detector) runs, over
    /// [`DetectorSettings::default`](crate::method::detector::DetectorSettings::default).
    #[serde(default)]
    pub detector: toml::Table,
    /// NTG trained whole and without each of these parts at every point
    /// (fig. "ablation" (a); default: whole only). Other methods are
    /// trained whole.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub ablations: Option<Vec<Variant>>,
    /// The seed of this panel's runs (weights and shuffling; default: the
    /// experiment's `seed`). More seeds of a point are more panels, one
    /// per seed, whose runs go to `...-seedS` folders and which the figure
    /// and report combine.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub seed: Option<u64>,
    /// A word added to the run folders' names after the input
    /// (`ntp_exp-vid-TAG-...`), so that a panel of another protocol (its
    /// overrides: another perception, say) keeps its runs and records
    /// apart from the earlier protocol's. Lowercase letters and digits.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub tag: Option<String>,
    /// The tag of another panel (video, the same seed) whose NTG runs this
    /// panel's NTG runs take their finished stage A and embeddings from,
    /// point by point, rather than computing them again: for a candidate
    /// that differs from that panel only in what stage B alone reads
    /// (the demo interpreter, its location step prior, the `<end>` rule;
    /// see `same_but_stage_b`). Linked only where the two runs'
    /// configurations differ in nothing else and the source's stage is
    /// finished; otherwise the run computes its own. A baseline's run
    /// (NTP, NTP Flat) of such a panel links only the stage A of NTG's run
    /// there (its frame encoder; it encodes its own episodes).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub stages_from: Option<String>,
}

impl PanelScale {
    /// Epochs for `train_tasks` tasks: `epochs`, or more to reach `min_steps`.
    pub fn epochs_for(&self, train_tasks: usize, batch_size: usize) -> usize {
        let demos = train_tasks * self.demos_per_task;
        let steps_per_epoch = demos.div_ceil(batch_size.max(1)).max(1);
        self.epochs.max(self.min_steps.div_ceil(steps_per_epoch))
    }
}

impl NtpExpExperiment {
    /// Reads `ntp_exp.toml` from `source`.
    pub fn load(source: crate::experiment::Source<'_>) -> anyhow::Result<Self> {
        Self::load_named("ntp_exp", source)
    }

    /// Reads `name.toml` from `source`: a figure of block-stacking runs in
    /// this file's form (`ntp_exp`, `ablation`).
    pub fn load_named(name: &str, source: crate::experiment::Source<'_>) -> anyhow::Result<Self> {
        let (mut experiment, origin): (Self, String) = crate::experiment::load(name, source)?;
        experiment.origin = origin;
        experiment.name = name.to_owned();
        Ok(experiment)
    }

    /// The methods of `panel`, in order.
    pub fn methods_of(&self, panel: &PanelScale) -> Vec<MethodId> {
        panel.methods.clone().unwrap_or_else(|| vec![self.method])
    }

    /// The runs of `panel` at one point, in order: each method (NTG whole
    /// and without each part the panel ablates), with its ablation.
    pub fn runs_of(&self, panel: &PanelScale) -> Vec<(MethodId, Variant)> {
        let ablations = panel.ablations.clone().unwrap_or(vec![Variant::Full]);
        self.methods_of(panel)
            .into_iter()
            .flat_map(|method| match method {
                MethodId::Ntg => ablations.iter().map(|&a| (method, a)).collect(),
                _ => vec![(method, Variant::Full)],
            })
            .collect()
    }

    /// What the figure's runs change in their recipe at `profile`, in
    /// words (Markdown): the file's and the profile's overrides (panels
    /// may add their own, named in the file).
    pub fn recipe_note(&self, profile: Profile) -> String {
        let profile = &self.profiles.get(profile).overrides;
        NTP_EXP.fill(
            "recipe_note",
            &[
                ("recipe", &self.recipe.name()),
                ("file", &self.name),
                (
                    "overrides",
                    &crate::experiment::overrides_text(&self.overrides),
                ),
                (
                    "profile_overrides",
                    &crate::experiment::overrides_text(profile),
                ),
            ],
        )
    }

    /// The seed of `panel`'s runs.
    pub fn seed_of(&self, panel: &PanelScale) -> u64 {
        panel.seed.unwrap_or(self.seed)
    }

    /// The recipe of `panel`'s runs.
    pub fn recipe_of(&self, panel: &PanelScale) -> Recipe {
        panel.recipe.unwrap_or(self.recipe)
    }

    /// The run folder's name of `method` (`ablation`: NTG without a part)
    /// at the point with `train_tasks` tasks of `panel`. NTG's folders name
    /// no method (the names of the committed records); a panel with
    /// another recipe than the experiment's adds the recipe's name, an
    /// ablation its own.
    pub fn run_name(
        &self,
        panel: &PanelScale,
        run: (MethodId, Variant),
        train_tasks: usize,
    ) -> String {
        self.run_name_with_core(panel, run, train_tasks, panel_ntp_core(panel))
    }

    /// [`Self::run_name`] of NTG's run of the same point in a panel of the
    /// other node source (the executed node or the localizer): the run
    /// whose stage A it may link (the node source is read after it).
    fn run_name_of_other_node_source(&self, panel: &PanelScale, train_tasks: usize) -> String {
        let mut other = panel.clone();
        let executed = panel_executed_node(panel)
            .unwrap_or_else(|| recipe_executed_node(self.recipe_of(panel)));
        let video = other
            .overrides
            .entry("video")
            .or_insert_with(|| toml::Value::Table(Default::default()));
        if let toml::Value::Table(video) = video {
            video.insert("executed_node".into(), toml::Value::Boolean(!executed));
        }
        self.run_name(&other, (MethodId::Ntg, Variant::Full), train_tasks)
    }

    /// [`Self::run_name`] of NTG's run of the same point in the panel that
    /// `panel` takes its stages from ([`PanelScale::stages_from`]), if any.
    fn run_name_of_stage_source(&self, panel: &PanelScale, train_tasks: usize) -> Option<String> {
        let tag = panel.stages_from.as_ref()?;
        let mut source = panel.clone();
        source.tag = Some(tag.clone());
        source.stages_from = None;
        // The node source names NTG's runs (`...-localizer-N`): the source
        // panel's, which a candidate may change (stage A does not read it).
        let profiles = [
            &self.profiles.smoke,
            &self.profiles.quick,
            &self.profiles.paper,
        ];
        let named = profiles
            .iter()
            .flat_map(|p| &p.panels)
            .find(|p| p.tag.as_ref() == Some(tag) && p.obs == panel.obs && p.seed == panel.seed);
        if let Some(executed) = named.and_then(panel_executed_node) {
            let video = source
                .overrides
                .entry("video")
                .or_insert_with(|| toml::Value::Table(toml::Table::new()));
            if let toml::Value::Table(video) = video {
                video.insert("executed_node".into(), toml::Value::Boolean(executed));
            }
        } else if let Some(toml::Value::Table(video)) = source.overrides.get_mut("video") {
            video.remove("executed_node");
        }
        Some(self.run_name(&source, (MethodId::Ntg, Variant::Full), train_tasks))
    }

    /// [`Self::run_name`] of a baseline run with NTP's core `core` (`None`:
    /// reactive) in place of the panel's: the run of the same point in
    /// another panel, whose shared stages a run may link.
    fn run_name_with_core(
        &self,
        panel: &PanelScale,
        (method, ablation): (MethodId, Variant),
        train_tasks: usize,
        core: Option<NtpCoreKind>,
    ) -> String {
        let mut name = format!("{}-{}", self.name, panel.obs.name());
        if let Some(tag) = &panel.tag {
            name = format!("{name}-{tag}");
        }
        if !method.is_ntg() {
            name = format!("{name}-{}", method.name());
            if let Some(core) = core {
                name = format!("{name}-{}", core.name());
            }
        }
        if !ablation.is_full() {
            name = format!("{name}-{}", ablation.name());
        }
        let recipe = self.recipe_of(panel);
        if recipe != self.recipe {
            name = format!("{name}-{}", recipe.name());
        }
        // NTG's node source where the panel sets another than its recipe's.
        if method.is_ntg()
            && let Some(executed) = panel_executed_node(panel)
            && executed != recipe_executed_node(recipe)
        {
            name = format!("{name}-{}", if executed { "executed" } else { "localizer" });
        }
        crate::experiment::seeded_name(
            format!("{name}-{train_tasks}"),
            self.seed_of(panel),
            self.seed,
        )
    }

    /// The run folder names of the figure at `profile`, in order.
    pub fn run_names(&self, profile: Profile) -> Vec<String> {
        let mut names = Vec::new();
        for panel in &self.profiles.get(profile).panels {
            for run in self.runs_of(panel) {
                for &n in &panel.train_tasks {
                    names.push(self.run_name(panel, run, n));
                }
            }
        }
        names
    }

    /// Every run configuration of the figure at `profile`, checked.
    pub fn run_configs(&self, profile: Profile) -> anyhow::Result<Vec<BlocksRunConfig>> {
        Ok(self
            .named_run_configs(profile)?
            .into_iter()
            .map(|(_, config)| config)
            .collect())
    }

    /// Every run of the figure at `profile`: its folder name and its
    /// configuration, checked.
    pub fn named_run_configs(
        &self,
        profile: Profile,
    ) -> anyhow::Result<Vec<(String, BlocksRunConfig)>> {
        let mut configs = Vec::new();
        for panel in &self.profiles.get(profile).panels {
            for run in self.runs_of(panel) {
                for &n in &panel.train_tasks {
                    configs.push((
                        self.run_name(panel, run, n),
                        self.run_config(profile, panel, run, n)?,
                    ));
                }
            }
        }
        Ok(configs)
    }

    /// The run configuration of `method` (`ablation`: NTG without a part)
    /// at the point with `train_tasks` tasks of `panel` at `profile`: the
    /// recipe's, with the experiment's and the profile's overrides, at least
    /// `panel.min_steps` steps, and validated `validations_per_run` times.
    pub fn run_config(
        &self,
        profile: Profile,
        panel: &PanelScale,
        (method, ablation): (MethodId, Variant),
        train_tasks: usize,
    ) -> anyhow::Result<BlocksRunConfig> {
        anyhow::ensure!(
            self.domain == DomainId::Blocks,
            "{}: {} is a block-stacking figure (domain = \"blocks\")",
            self.origin,
            self.name
        );
        anyhow::ensure!(
            ablation.trains() && (ablation.is_full() || method.is_ntg()),
            "{}: ablations are NTG trained without one part (no-demo-interpreter, no-node-localizer, no-edge-classifier, no-gcn), not {} of {}",
            self.origin,
            ablation.name(),
            method.name()
        );
        if let Some(tag) = &panel.tag {
            anyhow::ensure!(
                !tag.is_empty()
                    && tag
                        .chars()
                        .all(|c| c.is_ascii_lowercase() || c.is_ascii_digit()),
                "{}: a panel's tag names its run folders: lowercase letters and digits, not {tag:?}",
                self.origin
            );
        }
        if let Some(from) = &panel.stages_from {
            let profile_panels = &self.profiles.get(profile).panels;
            anyhow::ensure!(
                panel.obs == ObsKind::Vid
                    && Some(from) != panel.tag.as_ref()
                    && profile_panels.iter().any(|p| {
                        p.tag.as_ref() == Some(from) && p.obs == panel.obs && p.seed == panel.seed
                    }),
                "{}: stages_from = {from:?} names the video panel of the same seed whose stage A and embeddings this panel's NTG runs take; no other such panel has tag {from:?}",
                self.origin
            );
        }
        let reads = |obs: ObsKind| panel.obs == obs;
        anyhow::ensure!(
            match method {
                MethodId::Ntg => true,
                MethodId::Ntp | MethodId::NtpFlat => true,
                MethodId::NtpDetector => reads(ObsKind::Vid),
                MethodId::Flat => false,
            },
            "{}: ntp_exp trains NTG, NTP and NTP Flat, and NTP (Detector) on video (the {:?} panel lists {})",
            self.origin,
            panel.obs,
            method.name()
        );
        let recipe = self.recipe_of(panel);
        let base = recipe.config(
            panel.obs,
            train_tasks,
            panel.demos_per_task,
            1,
            self.seed_of(panel),
        );
        let what = self.origin.as_str();
        let config = crate::experiment::with_overrides(&base, &self.overrides, what)?;
        let config = crate::experiment::with_overrides(
            &config,
            &self.profiles.get(profile).overrides,
            what,
        )?;
        let config = crate::experiment::with_overrides(&config, &panel.overrides, what)?;
        let mut config = recipe.for_method(config, method);
        config.ablation = ablation;
        // NTP's core names the panel's baseline runs (`run_name`), so it is
        // set where the name is read from: the panel's overrides.
        let panel_core = panel_ntp_core(panel).unwrap_or_default();
        anyhow::ensure!(
            config.ntp_core == panel_core,
            "{}: ntp_core = {:?} belongs in a panel's overrides, where it names the panel's baseline runs (`...-ntp-gru-N`), not in the file's or a profile's",
            self.origin,
            config.ntp_core.name()
        );
        // The node source names NTG's runs where a panel sets it.
        for (table, whose) in [
            (&self.overrides, "the file's"),
            (&self.profiles.get(profile).overrides, "a profile's"),
        ] {
            anyhow::ensure!(
                table
                    .get("video")
                    .and_then(|v| v.get("executed_node"))
                    .is_none(),
                "{}: video.executed_node belongs in a panel's overrides, where it names the panel's NTG runs (`...-localizer-N`), not in {whose}",
                self.origin
            );
        }
        anyhow::ensure!(
            panel_core.is_reactive() || !method.is_ntg(),
            "{}: a panel with ntp_core = {:?} sets NTP's core network, and NTG has none: list only the baselines in its `methods`",
            self.origin,
            panel_core.name()
        );
        if let Some(detector) = config.detector.as_mut() {
            *detector = crate::experiment::with_overrides(
                &*detector,
                &panel.detector,
                &format!("{what} (detector)"),
            )?;
        }
        let epochs = panel.epochs_for(train_tasks, config.optim.batch_size);
        config.optim.epochs = epochs;
        config.validate_every = epochs.div_ceil(self.validations_per_run.max(1));
        Ok(config)
    }
}

/// The core network a panel's overrides give its NTP runs, where not the
/// reactive default (`ntp_core = "gru"`): their run folders add its name.
fn panel_ntp_core(panel: &PanelScale) -> Option<NtpCoreKind> {
    let core: NtpCoreKind = panel.overrides.get("ntp_core")?.clone().try_into().ok()?;
    (!core.is_reactive()).then_some(core)
}

/// The node source a panel's overrides give its NTG runs
/// (`video.executed_node`), where they set one.
fn panel_executed_node(panel: &PanelScale) -> Option<bool> {
    panel
        .overrides
        .get("video")?
        .get("executed_node")?
        .as_bool()
}

/// Whether `recipe`'s NTG on video takes its node from the executed
/// actions (the recommended recipe) rather than the localizer (the
/// paper's).
fn recipe_executed_node(recipe: Recipe) -> bool {
    recipe
        .config(ObsKind::Vid, 1, 1, 1, 0)
        .video
        .is_some_and(|v| v.executed_node)
}

/// One measured point.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct NtpExpPoint {
    /// The method trained (results written before baselines existed are
    /// NTG's).
    #[serde(default, skip_serializing_if = "MethodId::is_ntg")]
    pub method: MethodId,
    /// The part NTG was trained without (fig. "ablation" (a)); `full` for
    /// the whole model and every other method.
    #[serde(default, skip_serializing_if = "Variant::is_full")]
    pub ablation: Variant,
    /// The recipe it was trained with (results written before recipes per
    /// panel are the paper's).
    #[serde(default = "paper_recipe", skip_serializing_if = "is_paper_recipe")]
    pub recipe: Recipe,
    /// Observation kind of the panel.
    pub obs: ObsKind,
    /// Seed of the run's weights and shuffling (results written before
    /// seeds per panel: 0).
    #[serde(default, skip_serializing_if = "is_zero")]
    pub seed: u64,
    /// Training tasks.
    pub train_tasks: usize,
    /// Demonstrations per task.
    pub demos_per_task: usize,
    /// Epochs.
    pub epochs: usize,
    /// The epoch (from 0) that scored best on the validation tasks and was
    /// evaluated; `None` = the last.
    #[serde(default)]
    pub selected_epoch: Option<usize>,
    /// Whether training renamed cubes at random (not in the paper).
    #[serde(default)]
    pub permute_objects: bool,
    /// What the run adds to the paper's recipe, as its row names it, read
    /// from its whole configuration ([`blocks::additions`]); empty for a
    /// run of the paper's recipe.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub additions: Vec<String>,
    /// Where the run's recommended recipe differs from the recipe as it is
    /// now ([`blocks::recipe_changes`]), as its row names it: a run trained
    /// before the recipe changed. Empty for the paper's recipe.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub recipe_changes: Vec<String>,
    /// Every setting of the run's configuration, named
    /// ([`blocks::named_settings`]): what [`name_apart`] compares.
    #[serde(skip)]
    pub settings: Vec<(String, String)>,
    /// The settings that tell this point's curve apart from another curve
    /// of the same method, recipe and input (another panel that trained
    /// differently), named after the method ([`name_apart`]); empty where
    /// no other curve shares the name.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub distinction: Vec<String>,
    /// Video runs: the side in pixels of the camera's frames (the run's
    /// `video.camera`), shown in the row's input cell; `None` on state.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub camera: Option<u32>,
    /// Video runs whose stage A trained on another number of demo videos
    /// than the recipe's (`video.encoder.demos`): that number, a curve of
    /// its own (results written before it: none).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub stage_a_videos: Option<usize>,
    /// The panel's tag (`PanelScale::tag`, in the run folder's name), where
    /// it has one (results written before it: none).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub tag: Option<String>,
    /// NTP's core network (the run's `ntp_core`): a curve of its own
    /// beside the reactive default's. Reactive for NTG.
    #[serde(default, skip_serializing_if = "NtpCoreKind::is_reactive")]
    pub ntp_core: NtpCoreKind,
    /// NTG on video: whether its policy took the current node from the
    /// actions it executed (`video.executed_node`) rather than from the
    /// node localizer reading the frame: a curve of its own.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub executed_node: bool,
    /// Success on unseen tasks.
    pub success: SuccessRate,
    /// Mean fraction of each unseen task's goal constraints met at the end.
    #[serde(default)]
    pub goal_fraction: f64,
    /// A reduced profile: the same test tasks scored by the run's model at
    /// the weights its training started from (`initial/`), the value the
    /// point must beat to show learning; absent at the paper profile and
    /// where the run kept no initial weights.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub untrained: Option<Untrained>,
    /// Core-seconds of training epochs
    /// ([`crate::run_dir::RunDir::epoch_compute_seconds`]: CPU time where
    /// recorded, else wall time; from the run's metrics, so a reused run
    /// reports its original cost).
    pub train_seconds: f64,
    /// Video runs: the compute of each stage, and of encoding the training
    /// videos where the run noted it (results written before it: none).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub stage_times: Option<StageTimes>,
    /// NTG: the test demos its interpreter transcribed exactly, and success
    /// on those and on the others (absent where the evaluation did not
    /// keep it: runs restored from records written before it).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub transcription: Option<TranscriptionSplit>,
    /// Success on the run's own training tasks (new demos and scenes),
    /// where it was evaluated there (`ntg eval --split seen`): whether a
    /// method does what it was trained on. The largest such evaluation.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub seen: Option<SuccessRate>,
    /// NTP (Detector): its detector's score on held-out frames
    /// (`detector_stage/held_out.json`), where the run has a detector.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub detector: Option<crate::method::detector::DetectorHeldOut>,
    /// NTP baselines: its decisions checked along the expert's traces of
    /// test tasks (`ntg eval --decisions`, `eval/decisions-N.json`), where
    /// they were: where the method goes wrong. The largest such check.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub decisions: Option<crate::method::ntp::DecisionReport>,
    /// How its training went: validation success per validated epoch and
    /// the last epoch's training accuracies (absent where the run folder
    /// has no validation scores).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub curve: Option<TrainingCurve>,
    /// Run folder.
    pub run: PathBuf,
}

/// Where a video run's training compute went: each stage's epochs (core
/// seconds: CPU time where recorded, else wall time, as the training time
/// column), and stage B's encoding of the training videos through the
/// frozen frame encoder.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct StageTimes {
    /// Each stage with epochs: `stage_a` (the frame encoder),
    /// `detector_stage`, then the method's own training (`stage B`).
    pub stages: Vec<StageTime>,
    /// Encoding the training videos, where the run noted it
    /// (`encoding.jsonl`; runs before it: none).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub encoding: Option<EncodingTime>,
}

/// One stage's epochs and their core seconds.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct StageTime {
    /// Its folder in the run (`stage_a`, `detector_stage`), or `stage B`.
    pub stage: String,
    /// Epochs trained.
    pub epochs: usize,
    /// Their core seconds.
    pub seconds: f64,
}

/// Stage B's encoding of the training videos.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct EncodingTime {
    /// Videos encoded (a part encoded again after a kill counted again).
    pub videos: usize,
    /// Core seconds: CPU time where the part's process ran nothing else,
    /// else wall time.
    pub seconds: f64,
}

impl StageTimes {
    /// The stage times `run`'s files record.
    pub fn of(run: &RunDir) -> anyhow::Result<StageTimes> {
        let mut stages: Vec<StageTime> = run
            .stage_compute_seconds()?
            .into_iter()
            .map(|(stage, epochs, seconds)| StageTime {
                stage: if stage.is_empty() {
                    "stage B".to_owned()
                } else {
                    stage
                },
                epochs,
                seconds,
            })
            .collect();
        // The method's own training last: the order the stages ran in.
        stages.sort_by_key(|s| s.stage == "stage B");
        let times = run.root().join(crate::video::ENCODING_TIMES);
        let encoding = if times.is_file() {
            let parts: Vec<crate::video::EncodedPart> = crate::run_dir::read_jsonl(&times)?;
            Some(EncodingTime {
                videos: parts.iter().map(|p| p.videos).sum(),
                seconds: parts
                    .iter()
                    .map(|p| p.cpu_seconds.unwrap_or(p.seconds))
                    .sum(),
            })
        } else {
            None
        };
        Ok(StageTimes { stages, encoding })
    }

    /// `stage_a 3 epochs 2710 s; encoding 100000 videos 5040 s; stage B 30
    /// epochs 4300 s` (Markdown-free).
    pub fn text(&self) -> String {
        let mut parts: Vec<String> = Vec::new();
        for stage in &self.stages {
            if stage.stage == "stage B" {
                parts.push(match &self.encoding {
                    Some(e) => NTP_EXP.fill(
                        "stage_time_encoding",
                        &[
                            ("videos", &e.videos),
                            ("seconds", &format!("{:.0}", e.seconds)),
                        ],
                    ),
                    None => NTP_EXP.text("stage_time_no_encoding"),
                });
            }
            parts.push(NTP_EXP.fill(
                "stage_time",
                &[
                    ("stage", &stage.stage),
                    ("epochs", &stage.epochs),
                    ("seconds", &format!("{:.0}", stage.seconds)),
                ],
            ));
        }
        parts.join("; ")
    }
}

/// A point's score before training ([`NtpExpPoint::untrained`]).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Untrained {
    /// Success on the point's test tasks.
    pub success: SuccessRate,
    /// Mean fraction of goal constraints met there.
    pub goal_fraction: f64,
}

/// A run's training curve as the report shows it: whether the method was
/// still improving when its training stopped (issue 16's under-training
/// check of a baseline far below the paper).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TrainingCurve {
    /// Its scores on the validation tasks, in epoch order.
    pub validation: Vec<crate::fit::ValidationRecord>,
    /// The last epoch's training accuracies: every `*_accuracy` value of
    /// the last line of `metrics.jsonl`, named without the suffix.
    pub last_accuracies: std::collections::BTreeMap<String, f64>,
    /// Epochs the run trained.
    pub epochs_trained: usize,
}

impl TrainingCurve {
    /// The curve of `run` (trained with `method`), from its
    /// `validation.jsonl` and `metrics.jsonl`; `None` without validation
    /// scores. Heads a method does not train are left out (NTP Flat logs
    /// a scope accuracy of 0: it has no scopes).
    pub fn of(run: &RunDir, method: MethodId) -> anyhow::Result<Option<TrainingCurve>> {
        let path = run.validation_path();
        if !path.is_file() {
            return Ok(None);
        }
        let mut validation: Vec<crate::fit::ValidationRecord> = crate::run_dir::read_jsonl(&path)?;
        if validation.is_empty() {
            return Ok(None);
        }
        validation.sort_by_key(|r| r.epoch);
        let metrics: Vec<serde_json::Value> = if run.metrics_path().is_file() {
            crate::run_dir::read_jsonl(&run.metrics_path())?
        } else {
            Vec::new()
        };
        let last_accuracies = metrics
            .last()
            .and_then(|m| m.as_object())
            .map(|m| {
                m.iter()
                    .filter_map(|(k, v)| {
                        Some((k.strip_suffix("_accuracy")?.to_owned(), v.as_f64()?))
                    })
                    .filter(|(head, _)| !(method == MethodId::NtpFlat && head == "scope"))
                    .collect()
            })
            .unwrap_or_default();
        Ok(Some(TrainingCurve {
            validation,
            last_accuracies,
            epochs_trained: metrics.len(),
        }))
    }

    /// The best validation score's epoch, as training selects it (success,
    /// then goals met; the first of equals).
    pub fn best_epoch(&self) -> usize {
        let mut best = self.validation[0];
        for r in &self.validation[1..] {
            if r.score.beats(&best.score) {
                best = *r;
            }
        }
        best.epoch
    }

    /// Mean validation success over the last third of the validated epochs
    /// and over the third before it (`None` with fewer than two scores):
    /// a curve still rising when training stopped has the first clearly
    /// above the second.
    pub fn last_thirds(&self) -> Option<(f64, f64)> {
        let n = self.validation.len();
        let w = n / 3;
        if w == 0 {
            return None;
        }
        let mean = |rs: &[crate::fit::ValidationRecord]| {
            rs.iter().map(|r| r.score.success).sum::<f64>() / rs.len() as f64
        };
        Some((
            mean(&self.validation[n - w..]),
            mean(&self.validation[n - 2 * w..n - w]),
        ))
    }

    /// One line of the report: validation success by epoch (from 1), the
    /// best epoch, the last two thirds' means, and the last epoch's
    /// training accuracies.
    pub fn describe(&self) -> String {
        let scores = self
            .validation
            .iter()
            .map(|r| format!("{}: {:.2}", r.epoch + 1, r.score.success))
            .collect::<Vec<_>>()
            .join(", ");
        let mut line = format!(
            "validation success by epoch {scores}; best at epoch {}",
            self.best_epoch() + 1
        );
        if self
            .validation
            .last()
            .is_some_and(|r| r.epoch == self.best_epoch())
        {
            line.push_str(", the last validated");
        }
        if let Some((last, before)) = self.last_thirds() {
            let w = self.validation.len() / 3;
            let _ = write!(
                line,
                "; mean of the last {w} scores {last:.3}, of the {w} before {before:.3}"
            );
        }
        let accuracies = self
            .last_accuracies
            .iter()
            .map(|(name, a)| format!("{} {a:.3}", name.replace('_', " ")))
            .collect::<Vec<_>>()
            .join(", ");
        if !accuracies.is_empty() {
            let _ = write!(
                line,
                "; training accuracy at its last epoch ({}): {accuracies}",
                self.epochs_trained
            );
        }
        line
    }
}

fn is_zero(seed: &u64) -> bool {
    *seed == 0
}

fn paper_recipe() -> Recipe {
    Recipe::Paper
}

fn is_paper_recipe(recipe: &Recipe) -> bool {
    *recipe == Recipe::Paper
}

/// Trains (or reuses, or resumes) and evaluates every point of the figure
/// at `profile` (or only the run folders named in `only`), with run folders
/// under `runs`, `jobs` runs at a time, in the file's order (the results:
/// state input first). The video baselines that may reuse a frame encoder
/// (NTP and NTP Flat: NTG's, or one of their own labels which they share)
/// start after every other run has finished, and each point's first such
/// baseline before the others of its point, so that each encoder and each
/// point's encoded episodes are made once.
pub fn run(
    experiment: &NtpExpExperiment,
    profile: Profile,
    plan: &Plan<'_>,
) -> anyhow::Result<Vec<NtpExpPoint>> {
    let [first, second, third] = waves(experiment, profile, |name| plan.selected(name));
    let mut points = Vec::new();
    for wave in [first, second, third] {
        let wave: Vec<crate::experiment::Job<'_, Option<(usize, NtpExpPoint)>>> = wave
            .into_iter()
            .map(|(order, scale, method, n)| {
                Box::new(move || {
                    run_point(experiment, profile, scale, method, n, plan)
                        .map(|point| point.map(|point| (order, point)))
                }) as crate::experiment::Job<'_, _>
            })
            .collect();
        points.extend(
            crate::experiment::in_parallel(&experiment.name, &plan.slots, wave)?
                .into_iter()
                .flatten(),
        );
    }
    // State input first, then each input in the file's order (a long run
    // may be listed first so that it starts first).
    points.sort_by_key(|(order, point)| (point.obs == ObsKind::Vid, *order));
    let mut points: Vec<NtpExpPoint> = points.into_iter().map(|(_, point)| point).collect();
    name_apart(&mut points);
    Ok(points)
}

/// Names apart the curves that would share a name: two panels (two tags)
/// of one method, recipe, input and perception whose runs trained
/// differently. Each such curve's points get, as their
/// [`NtpExpPoint::distinction`], every setting in which its first run
/// differs from the first run of another of them (in key order); a curve
/// that differs in no named setting is named by its panel's tag.
pub fn name_apart(points: &mut [NtpExpPoint]) {
    let base = |p: &NtpExpPoint| CurveId {
        tag: None,
        distinction: Vec::new(),
        ..p.curve_id()
    };
    let mut curves: Vec<(CurveId, Option<String>, usize)> = Vec::new();
    for (i, p) in points.iter().enumerate() {
        if !curves
            .iter()
            .any(|(b, tag, _)| *b == base(p) && *tag == p.tag)
        {
            curves.push((base(p), p.tag.clone(), i));
        }
    }
    for (b, tag, first) in &curves {
        let others: Vec<usize> = curves
            .iter()
            .filter(|(ob, otag, _)| ob == b && otag != tag)
            .map(|&(_, _, i)| i)
            .collect();
        if others.is_empty() {
            continue;
        }
        let own = &points[*first].settings;
        let mut distinction: Vec<String> = own
            .iter()
            .filter(|(key, name)| {
                others.iter().any(|&o| {
                    points[o]
                        .settings
                        .iter()
                        .find(|(k, _)| k == key)
                        .is_none_or(|(_, n)| n != name)
                })
            })
            .map(|(_, name)| name.clone())
            .collect();
        if distinction.is_empty() {
            distinction.extend(tag.iter().map(|t| format!("panel {t}")));
        }
        for p in points.iter_mut().filter(|p| base(p) == *b && p.tag == *tag) {
            p.distinction = distinction.clone();
        }
    }
}

/// One run of a wave: its place in the file's order, panel, method and
/// training tasks.
type Scheduled<'a> = (usize, &'a PanelScale, (MethodId, Variant), usize);

/// The figure's runs at `profile` (those `selected`) in the three waves
/// [`run`] trains them in: every run but the video baselines that may
/// reuse a frame encoder, then each point's first such baseline, then the
/// others of its point (so that each encoder and each point's encoded
/// episodes are made once).
fn waves<'a>(
    experiment: &'a NtpExpExperiment,
    profile: Profile,
    selected: impl Fn(&str) -> bool,
) -> [Vec<Scheduled<'a>>; 3] {
    let (mut first, mut second, mut third) = (Vec::new(), Vec::new(), Vec::new());
    // The points (by NTG's run name) whose first sharing baseline is in
    // the second wave.
    let mut shared_points: Vec<String> = Vec::new();
    for scale in &experiment.profiles.get(profile).panels {
        for method in experiment.runs_of(scale) {
            for &n in &scale.train_tasks {
                if !selected(&experiment.run_name(scale, method, n)) {
                    continue;
                }
                let order = first.len() + second.len() + third.len();
                let wave = if reuses_stage_a(scale.obs, method.0) {
                    let point = experiment.run_name(scale, (MethodId::Ntg, Variant::Full), n);
                    if shared_points.contains(&point) {
                        &mut third
                    } else {
                        shared_points.push(point);
                        &mut second
                    }
                } else {
                    &mut first
                };
                wave.push((order, scale, method, n));
            }
        }
    }
    [first, second, third]
}

/// A run of the figure as a scheduler sees it ([`schedule`]).
#[derive(Debug, Clone, PartialEq, Eq, serde::Serialize)]
pub struct ScheduledRun {
    /// The run folder's name.
    pub name: String,
    /// Its wave (0, 1 or 2): a run of a later wave may link the finished
    /// stages of its point's runs of earlier waves.
    pub wave: usize,
    /// The runs whose finished stages (frame encoder, encoded episodes) it
    /// links when they are done, else trains itself: of earlier waves, or
    /// (NTG's run of the other node source) of its own, which
    /// [`crate::reproduce::run_list`] moves it after.
    pub after: Vec<String>,
    /// Whether it trains on demo videos.
    pub video: bool,
}

/// Every run of the figure at `profile`, wave by wave, in the order
/// [`run`] starts them.
pub fn schedule(experiment: &NtpExpExperiment, profile: Profile) -> Vec<ScheduledRun> {
    let waves = waves(experiment, profile, |_| true);
    let names = experiment.run_names(profile);
    let mut listed: Vec<ScheduledRun> = Vec::new();
    // The point (NTG's run name) of each listed run.
    let mut points: Vec<String> = Vec::new();
    for (wave, runs) in waves.iter().enumerate() {
        for &(_, scale, method, n) in runs {
            let name = experiment.run_name(scale, method, n);
            let point = experiment.run_name(scale, (MethodId::Ntg, Variant::Full), n);
            let mut after = Vec::new();
            if wave > 0 {
                // NTG's run of the point, then the point's runs of earlier
                // waves, where the figure has them.
                for (earlier, its_point) in listed.iter().zip(&points) {
                    let of_point = *its_point == point;
                    if (earlier.name == point || of_point && earlier.wave > 0)
                        && earlier.wave < wave
                        && !after.contains(&earlier.name)
                    {
                        after.push(earlier.name.clone());
                    }
                }
            }
            // NTG's run of the other node source than its recipe's links
            // the stage A and embeddings of the recipe's run of its point.
            if scale.obs == ObsKind::Vid
                && method == (MethodId::Ntg, Variant::Full)
                && panel_executed_node(scale)
                    .is_some_and(|e| e != recipe_executed_node(experiment.recipe_of(scale)))
            {
                let other = experiment.run_name_of_other_node_source(scale, n);
                if names.contains(&other) {
                    after.push(other);
                }
            }
            // A panel's run that takes its stages from another panel's
            // (NTG's run of the point there).
            if method.1.is_full()
                && (method.0 == MethodId::Ntg || reuses_stage_a(scale.obs, method.0))
                && let Some(source) = experiment.run_name_of_stage_source(scale, n)
                && names.contains(&source)
                && !after.contains(&source)
            {
                after.push(source);
            }
            points.push(point);
            listed.push(ScheduledRun {
                name,
                wave,
                after,
                video: scale.obs == ObsKind::Vid,
            });
        }
    }
    listed
}

/// Whether `method` on `obs` starts from NTG's frame encoder of its point.
fn reuses_stage_a(obs: ObsKind, method: MethodId) -> bool {
    obs == ObsKind::Vid && matches!(method, MethodId::Ntp | MethodId::NtpFlat)
}

/// Trains (or reuses, or resumes) and evaluates one point of one method.
fn run_point(
    experiment: &NtpExpExperiment,
    profile: Profile,
    scale: &PanelScale,
    (method, ablation): (MethodId, Variant),
    n: usize,
    plan: &Plan<'_>,
) -> anyhow::Result<Option<NtpExpPoint>> {
    let config = experiment.run_config(profile, scale, (method, ablation), n)?;
    let obs = scale.obs;
    let epochs = config.optim.epochs;
    let recipe = experiment.recipe_of(scale);
    let name = experiment.run_name(scale, (method, ablation), n);
    let runs = plan.runs;
    let dir = runs.join(&name);
    if !dir.exists()
        && let Some(twin) = finished_twin(runs, &config)?
    {
        eprintln!(
            "  [{name}] the same run, finished, is {}: reused",
            twin.display()
        );
        crate::run_dir::link_or_copy_tree(&twin, &dir)?;
    }
    let eval_file = test_eval_file(method, scale.test_tasks);
    let Some(dir) = plan.prepare(&name, &config, &eval_file)? else {
        return Ok(None);
    };
    let run = RunDir::open_or_create(&dir, &config)?;
    // One writer for the whole point: the stages it shares in, its caches,
    // training and evaluation (another `ntg reproduce --only` of the same
    // run is refused here, not only once the epochs start).
    let _writer = run.lock()?;
    if reuses_stage_a(obs, method) {
        let sibling = match method {
            MethodId::Ntp => MethodId::NtpFlat,
            _ => MethodId::Ntp,
        };
        // The baselines of the point whose stages this run may share: its
        // sibling with the same core, then (a run of another core's panel)
        // both with the reactive core.
        let mut siblings = vec![experiment.run_name(scale, (sibling, Variant::Full), n)];
        if panel_ntp_core(scale).is_some() {
            for m in [method, sibling] {
                siblings.push(experiment.run_name_with_core(scale, (m, Variant::Full), n, None));
            }
        }
        // The panel it takes its stages from first (NTG's run of the point
        // there: only its stage A, which does not read the method; NTP
        // encodes its own episodes), then NTG's run of its own point; a
        // baseline's where NTG's holds no weights (a folder restored from
        // its record).
        let mut linked = false;
        if let Some(source) = experiment.run_name_of_stage_source(scale, n) {
            let same = same_but_stage_b_and_method(&config);
            linked = share_stage_a(&runs.join(source), &run, &config, &same)?;
        }
        let ntg_run = experiment.run_name(scale, (MethodId::Ntg, Variant::Full), n);
        let same = same_but_method(&config);
        for source in std::iter::once(&ntg_run).chain(&siblings) {
            if linked || share_stage_a(&runs.join(source), &run, &config, &same)? {
                break;
            }
        }
        for source in &siblings {
            if share_ntp_frames(&runs.join(source), &run, &config)? {
                break;
            }
        }
    } else if obs == ObsKind::Vid && method.is_ntg() && ablation.is_full() {
        // NTG trains the point's frame encoder first in a whole figure;
        // run on its own (`--only`) after a baseline of its point finished
        // the same stage A, it links that one instead of training it again.
        // So does NTG's run of the other node source (which stage A does
        // not read), and then its embeddings too: the same frozen encoder
        // over the same videos, which training does not read the node
        // source from either (only the policy's rollouts do).
        // A panel taking its stages from another ([`PanelScale::stages_from`])
        // links that panel's run of the point first: its stage A and
        // embeddings, where the two differ only in what stage B reads.
        let from = experiment.run_name_of_stage_source(scale, n);
        let linked = match &from {
            Some(source) => {
                let same = same_but_stage_b(&config);
                let linked = share_stage_a(&runs.join(source), &run, &config, &same)?;
                if linked {
                    share_embeddings(&runs.join(source), &run, &same)?;
                }
                linked
            }
            None => false,
        };
        let sources = [MethodId::Ntp, MethodId::NtpFlat]
            .map(|sibling| experiment.run_name(scale, (sibling, Variant::Full), n));
        let other = experiment.run_name_of_other_node_source(scale, n);
        let same = same_but_method(&config);
        for source in sources.iter().chain([&other]).filter(|_| !linked) {
            if share_stage_a(&runs.join(source), &run, &config, &same)? {
                if source == &other {
                    share_embeddings(&runs.join(source), &run, &same)?;
                }
                break;
            }
        }
    }
    eprintln!(
        "{} ({}{}, {} recipe, {obs:?}, {n} tasks x {} demos, {epochs} epochs): training -> {}",
        experiment.name,
        method.legend(),
        if ablation.is_full() {
            String::new()
        } else {
            format!(" without {}", ablation_part(ablation))
        },
        recipe.name(),
        scale.demos_per_task,
        dir.display()
    );
    let device = crate::spec::device().autodiff();
    // Trained (or its finished training loaded) only when the evaluation
    // is not saved yet.
    let result = run.cached_eval(&eval_file, || {
        if method.is_ntg() {
            let model = blocks::train_run(&run, &config, &device, |r| eprintln!("  [{name}] {r}"))?;
            model.evaluate(
                config.task_source(),
                config.failures,
                config.camera(),
                scale.test_tasks,
                Variant::Full,
            )
        } else {
            let model =
                blocks::train_model(&run, &config, &device, |r| eprintln!("  [{name}] {r}"))?;
            blocks::evaluate_ntp(
                model.as_ref(),
                config.task_source(),
                obs,
                config.failures,
                config.camera(),
                scale.test_tasks,
            )
        }
    })?;
    // A reduced profile shows that each series learned: the same test
    // tasks scored at the run's initial weights.
    let untrained = crate::experiment::untrained_eval(&run, profile, &eval_file, || {
        blocks::evaluate_untrained(&run, &config, scale.test_tasks, &device)
    })?
    .map(|u| Untrained {
        success: u.success,
        goal_fraction: u.mean_goal_fraction,
    });
    plan.finish(&dir)?;
    let train_seconds = run.epoch_compute_seconds()?;
    eprintln!(
        "  [{name}] success on {} unseen tasks: {:.3} ({:.3}-{:.3}); goals met {:.3}{}",
        scale.test_tasks,
        result.success.rate,
        result.success.ci_low,
        result.success.ci_high,
        result.mean_goal_fraction,
        result.transcribed_note()
    );
    Ok(Some(NtpExpPoint {
        method,
        ablation,
        recipe,
        obs,
        seed: experiment.seed_of(scale),
        train_tasks: n,
        demos_per_task: scale.demos_per_task,
        epochs,
        selected_epoch: crate::fit::selected_epoch(&run)?.map(|r| r.epoch),
        permute_objects: config.permute_objects,
        additions: blocks::additions(&config),
        recipe_changes: blocks::recipe_changes(&config, recipe),
        settings: blocks::named_settings(&config),
        distinction: Vec::new(),
        camera: (obs == ObsKind::Vid).then(|| config.camera().size),
        stage_a_videos: config
            .video
            .as_ref()
            .map(|v| v.encoder.demos)
            .filter(|&n| n != blocks::BlocksVideo::new(false).encoder.demos),
        tag: scale.tag.clone(),
        ntp_core: config.ntp_core,
        executed_node: method.is_ntg()
            && (config.executed_node || config.video.as_ref().is_some_and(|v| v.executed_node)),
        success: result.success,
        goal_fraction: result.mean_goal_fraction,
        untrained,
        train_seconds,
        stage_times: (obs == ObsKind::Vid)
            .then(|| StageTimes::of(&run))
            .transpose()?,
        transcription: TranscriptionSplit::of(&result.tasks),
        seen: seen_success(&run, method)?,
        detector: detector_held_out(&run)?,
        decisions: decisions_report(&run)?,
        curve: TrainingCurve::of(&run, method)?,
        run: dir,
    }))
}

/// The index in `points` of each curve's point with the most training
/// tasks (a curve: method, recipe, input and seed; the whole model only),
/// in the order the curves first appear.
pub(crate) fn largest_of_each_curve(points: &[NtpExpPoint]) -> Vec<usize> {
    let mut largest: Vec<usize> = Vec::new();
    for (i, p) in points
        .iter()
        .enumerate()
        .filter(|(_, p)| p.ablation.is_full())
    {
        let curve = |q: &NtpExpPoint| (q.curve_id(), q.seed);
        match largest.iter().position(|&j| curve(&points[j]) == curve(p)) {
            Some(k) if points[largest[k]].train_tasks < p.train_tasks => largest[k] = i,
            Some(_) => {}
            None => largest.push(i),
        }
    }
    largest
}

/// Training tasks from which a baseline's largest point is also scored on
/// its own training tasks ([`check_baselines`]): the paper's largest, where
/// issue 16 compares the baselines with the paper's values.
pub const SEEN_CHECK_TRAIN_TASKS: usize = 1000;

/// Training tasks scored by [`check_baselines`] (at most the run's own).
pub const SEEN_CHECK_TASKS: usize = 200;

/// Test tasks along whose expert traces [`check_baselines`] checks a
/// baseline's decisions.
pub const DECISION_CHECK_TASKS: usize = 200;

/// Checks each baseline curve's largest point (every seed) with at least
/// `min_train_tasks` training tasks: whether a baseline far below the
/// paper does what it was trained on, and where it goes wrong.
///
/// - Scores it on [`SEEN_CHECK_TASKS`] of its own training tasks, with
///   demos and scenes it never trained on (`ntg eval --split seen`, cached
///   in `eval/seen-METHOD-N.json`), unless it has such a score.
/// - Checks its decisions along the expert's traces of the first
///   [`DECISION_CHECK_TASKS`] test tasks, or as many as the point was
///   scored on if fewer (`ntg eval --decisions`, cached in
///   `eval/decisions-N.json`), unless it has such a check.
///
/// Both are added to the run's record. A run restored from its record
/// without them has no weights and is left out.
pub fn check_baselines(
    points: &mut [NtpExpPoint],
    plan: &Plan<'_>,
    min_train_tasks: usize,
) -> anyhow::Result<()> {
    for i in largest_of_each_curve(points) {
        let p = &points[i];
        if p.method.is_ntg() || p.train_tasks < min_train_tasks {
            continue;
        }
        if p.seen.is_none() {
            seen_check(points, i, plan)?;
        }
        let p = &points[i];
        if p.decisions.is_none() && !crate::record::is_restored(&p.run) {
            decision_check(points, i, plan)?;
        }
    }
    Ok(())
}

/// [`check_baselines`]' seen-task score of `points[i]`.
fn seen_check(points: &mut [NtpExpPoint], i: usize, plan: &Plan<'_>) -> anyhow::Result<()> {
    let p = &points[i];
    let n = SEEN_CHECK_TASKS.min(p.train_tasks);
    let Some(result) = evaluate_point(p, crate::domain::EvalSplit::Seen, n, plan)? else {
        return Ok(());
    };
    eprintln!(
        "seen tasks [{}]: success {:.3} ({:.3}-{:.3}) on {n} of its training tasks (unseen: {:.3})",
        p.run.display(),
        result.success.rate,
        result.success.ci_low,
        result.success.ci_high,
        p.success.rate
    );
    points[i].seen = Some(result.success);
    Ok(())
}

/// [`check_baselines`]' decision check of `points[i]`.
fn decision_check(points: &mut [NtpExpPoint], i: usize, plan: &Plan<'_>) -> anyhow::Result<()> {
    let p = &points[i];
    let run = RunDir::open(&p.run)?;
    let _writer = run.lock()?;
    let config: BlocksRunConfig = RunDir::read_json(&run.config_path())?;
    let split = blocks::task_split(config.task_source())?;
    // No more tasks than the point was scored on: cheap where it was.
    let n = DECISION_CHECK_TASKS
        .min(p.success.trials)
        .min(split.test.len());
    let report = run.cached_eval(&format!("decisions-{n}.json"), || {
        let device = crate::spec::device();
        let model = blocks::load_baseline(&run, &config, &device)?;
        blocks::ntp_decisions(
            model.as_ref(),
            &config,
            &split.test[..n],
            blocks::Seeds::TEST,
            &device,
        )
    })?;
    eprintln!(
        "decisions [{}]: {}/{} right along {} test traces",
        p.run.display(),
        report.right,
        report.decisions,
        report.episodes
    );
    plan.finish(&p.run)?;
    points[i].decisions = Some(report);
    Ok(())
}

/// The largest decision check of `run` (`eval/decisions-N.json`, written
/// by `ntg eval --decisions` on the test split), if any.
fn decisions_report(run: &RunDir) -> anyhow::Result<Option<crate::method::ntp::DecisionReport>> {
    largest_eval(
        run,
        "decisions-",
        |r: &crate::method::ntp::DecisionReport| r.episodes,
    )
}

/// The largest (by `size`) of `run`'s evaluations `eval/PREFIX{N}.json`
/// (N a number), if any.
fn largest_eval<T: serde::de::DeserializeOwned>(
    run: &RunDir,
    prefix: &str,
    size: impl Fn(&T) -> usize,
) -> anyhow::Result<Option<T>> {
    let dir = run.eval_dir();
    if !dir.is_dir() {
        return Ok(None);
    }
    let mut best: Option<T> = None;
    for entry in std::fs::read_dir(&dir).with_context(|| format!("reading {}", dir.display()))? {
        let path = entry?.path();
        let name = path
            .file_name()
            .and_then(|n| n.to_str())
            .unwrap_or_default();
        let matches = name
            .strip_prefix(prefix)
            .and_then(|rest| rest.strip_suffix(".json"))
            .is_some_and(|n| n.parse::<usize>().is_ok());
        if matches {
            let found: T = RunDir::read_json(&path)?;
            if best.as_ref().is_none_or(|b| size(&found) > size(b)) {
                best = Some(found);
            }
        }
    }
    Ok(best)
}

/// The file in a run's `eval/` where a point of `method` keeps its score
/// on `n` test tasks: `full-N.json` for NTG (the whole model), `METHOD-N.json`
/// for the others; other splits prefix it with theirs (`taller-full-N.json`).
pub(crate) fn test_eval_file(method: MethodId, n: usize) -> String {
    let who = if method.is_ntg() {
        "full"
    } else {
        method.name()
    };
    format!("{who}-{n}.json")
}

/// Scores `p`'s run on `n` tasks of `split` (what `ntg eval --split`
/// computes), cached in `eval/{split}-{full|METHOD}-{n}.json` and added to
/// the run's record; `None` for a run restored from its record without
/// that evaluation (it has no weights), saying so.
pub(crate) fn evaluate_point(
    p: &NtpExpPoint,
    split: crate::domain::EvalSplit,
    n: usize,
    plan: &Plan<'_>,
) -> anyhow::Result<Option<blocks::EvalResult>> {
    let run = RunDir::open(&p.run)?;
    let name = split.name();
    let file = format!("{name}-{}", test_eval_file(p.method, n));
    if crate::record::is_restored(&p.run) && !run.eval_dir().join(&file).is_file() {
        eprintln!(
            "{name} split [{}]: not in its record, and it has no weights: left out",
            p.run.display()
        );
        return Ok(None);
    }
    let flags = crate::domain::EvalFlags::of_run(&p.run, n, split);
    let _writer = run.lock()?;
    let result = run.cached_eval(&file, || {
        blocks::evaluate_run(&run, &flags).map(|(_, result)| result)
    })?;
    plan.finish(&p.run)?;
    Ok(Some(result))
}

/// The score of `run`'s detector on held-out frames, where it has one.
fn detector_held_out(
    run: &RunDir,
) -> anyhow::Result<Option<crate::method::detector::DetectorHeldOut>> {
    let path = run
        .root()
        .join(crate::method::detector::DETECTOR_STAGE_DIR)
        .join("held_out.json");
    path.is_file().then(|| RunDir::read_json(&path)).transpose()
}

/// The success rate of `run`'s largest evaluation on its own training
/// tasks (`eval/seen-{full|METHOD}-N.json`, written by `ntg eval --split
/// seen`), if any.
fn seen_success(run: &RunDir, method: MethodId) -> anyhow::Result<Option<SuccessRate>> {
    let prefix = if method.is_ntg() {
        "seen-full-".to_owned()
    } else {
        format!("seen-{}-", method.name())
    };
    Ok(largest_eval(run, &prefix, |r: &blocks::EvalResult| r.success.trials)?.map(|r| r.success))
}

/// A finished run folder under `runs` with exactly `config` (another
/// figure's run of the same configuration, e.g. the whole model of fig.
/// "ablation" and fig. "ntp_exp"'s point at the same scale), if any: a run
/// is its configuration, so it is trained once and its folder (evaluations
/// included) is linked for the other figure. Folders that cannot be read
/// as block-stacking runs are passed over.
fn finished_twin(runs: &Path, config: &BlocksRunConfig) -> anyhow::Result<Option<PathBuf>> {
    let Ok(entries) = std::fs::read_dir(runs) else {
        return Ok(None);
    };
    let mut folders: Vec<PathBuf> = entries
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.is_dir() && p.extension().is_none())
        .collect();
    folders.sort();
    for folder in folders {
        let same = RunDir::read_json::<BlocksRunConfig>(&folder.join("config.json"))
            .is_ok_and(|c| c == *config);
        let done = crate::fit::training_finished(&folder, config.optim.epochs).unwrap_or(false);
        if same && done {
            return Ok(Some(folder));
        }
    }
    Ok(None)
}

/// Stage A (the frame encoder) of a video point is the same for NTG, NTP
/// and NTP Flat: their run configurations differ only in the method, and
/// stage A reads the same videos with the same settings and seed. So a
/// baseline's run starts from another run's (`source_run`: NTG's, or the
/// other baseline's) finished stage A, linked into its folder, rather than
/// training it again; its compute still counts those epochs. Nothing is
/// linked (false) unless the configurations match but for the method and
/// that stage A finished with its weights there.
fn share_stage_a(
    source_run: &Path,
    run: &RunDir,
    config: &BlocksRunConfig,
    same: &dyn Fn(&BlocksRunConfig) -> bool,
) -> anyhow::Result<bool> {
    let Some(video) = &config.video else {
        return Ok(false);
    };
    share_part(
        (source_run, crate::video::STAGE_A_DIR),
        run,
        |stage_a| crate::video::stage_a_finished(stage_a, &video.encoder),
        same,
        "stage A: the frame encoder",
    )
}

/// Stage B's embeddings (every training video through the frozen frame
/// encoder) of NTG's run of the other node source (`source_run`), linked
/// into `run` once its stage A was linked from the same run: the same
/// encoder over the same videos. Only complete caches (their `index.json`
/// written) are linked.
fn share_embeddings(
    source_run: &Path,
    run: &RunDir,
    same: &dyn Fn(&BlocksRunConfig) -> bool,
) -> anyhow::Result<bool> {
    share_part(
        (source_run, crate::video::EMBEDDINGS_DIR),
        run,
        |embeddings: &Path| Ok(embeddings.join("index.json").is_file()),
        same,
        "stage B's embeddings of the training videos",
    )
}

/// Accepts a run configuration equal to `config` but for what stage B
/// alone reads among the settings a [`PanelScale::stages_from`] candidate
/// changes: the demo interpreter and its location step prior (stage A
/// trains the frame encoder with the localizer's and edge classifier's
/// heads, and encoding runs that encoder only), the `<end>` rule and the
/// policy's node source (rollouts only; stage A scores frames, not
/// rollouts; the node source is also what runs of the other node source
/// share stage A across, [`same_but_method`]), and whether the localizer
/// reads the previous frame (stage B's localizer; stage A records only its
/// encoder stage and seed, as fig. ntp_exp's `cam128lr1prev` shares
/// `cam128lr1`'s).
fn same_but_stage_b(config: &BlocksRunConfig) -> impl Fn(&BlocksRunConfig) -> bool + '_ {
    move |theirs| {
        let mut same = config.clone();
        same.interpreter = theirs.interpreter;
        same.location_step_prior = theirs.location_step_prior;
        same.end_after_demo = theirs.end_after_demo;
        if let (Some(mine), Some(theirs)) = (same.video.as_mut(), theirs.video.as_ref()) {
            mine.executed_node = theirs.executed_node;
            mine.localizer_previous_frame = theirs.localizer_previous_frame;
        }
        *theirs == same
    }
}

/// Accepts a run configuration equal to `config` but for what stage B alone
/// reads ([`same_but_stage_b`]) and the method ([`same_but_method`]): a
/// baseline's panel taking its stages from another panel links the stage A
/// of NTG's run there, which trained the same frame encoder.
fn same_but_stage_b_and_method(config: &BlocksRunConfig) -> impl Fn(&BlocksRunConfig) -> bool + '_ {
    move |theirs| {
        let mut mine = config.clone();
        mine.method = theirs.method;
        mine.ntp_core = theirs.ntp_core;
        same_but_stage_b(&mine)(theirs)
    }
}

/// NTP and NTP Flat on video encode the same primitive-level episodes with
/// the same (shared) frame encoder: a baseline's run links the encoded
/// episodes of its sibling's run (`sibling_run`) when those are complete
/// and the configurations match but for the method. The cache itself
/// checks, when read, that its frame encoder is this run's.
fn share_ntp_frames(
    sibling_run: &Path,
    run: &RunDir,
    config: &BlocksRunConfig,
) -> anyhow::Result<bool> {
    share_part(
        (sibling_run, crate::method::ntp::NTP_FRAMES_DIR),
        run,
        |source: &Path| Ok(source.is_dir()),
        same_but_method(config),
        "NTP's encoded training episodes",
    )
}

/// Accepts a run configuration equal to `config` but for the method,
/// NTP's core network and NTG's node source (which no shared stage reads:
/// stage A trains the frame encoder, the encoded episodes are its output).
fn same_but_method(config: &BlocksRunConfig) -> impl Fn(&BlocksRunConfig) -> bool + '_ {
    move |theirs| {
        let mut same = config.clone();
        same.method = theirs.method;
        same.ntp_core = theirs.ntp_core;
        if let (Some(mine), Some(theirs)) = (same.video.as_mut(), theirs.video.as_ref()) {
            mine.executed_node = theirs.executed_node;
            mine.localizer_previous_frame = theirs.localizer_previous_frame;
        }
        *theirs == same
    }
}

/// The part of NTG that `ablation` removes, in words ("the GCN").
pub fn ablation_part(ablation: Variant) -> &'static str {
    match ablation {
        Variant::NoDemoInterpreter => "the demo interpreter",
        Variant::NoNodeLocalizer => "the node localizer",
        Variant::NoEdgeClassifier => "the edge classifier",
        Variant::NoGcn => "the GCN",
        Variant::Full | Variant::ExecutedNode | Variant::LocalizerNode => "nothing",
    }
}

/// Writes the figure as `stem.svg` and `stem.png`: success on unseen tasks
/// against training tasks, one panel per input (state, then video per frame
/// side), one line per curve: its method's colour and marker, a dash per
/// variant (recipe, core network, node source) the same in every panel, the
/// mean over seeds with its interval as a band. The same panels of goals
/// met (partial progress, which shows what a model learned where whole
/// tasks rarely succeed) go to `stem-goals.svg` and `.png`.
pub fn write_figure(points: &[NtpExpPoint], stem: &Path) -> anyhow::Result<()> {
    let name = stem
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    let (success, goals) = figure_panels(points);
    crate::figure::write_figure(&success, stem)?;
    crate::figure::write_figure(&goals, &stem.with_file_name(format!("{name}-goals")))
}

/// The dash of each of a panel's `curves`, which tells apart the curves of
/// one method: the same in every panel by what the curve adds (NTP's GRU
/// core long-dashed, NTG's executed node dotted, the recommended recipe
/// dashed, the paper's solid), unless two curves of one method would get
/// the same; then the method's curves are dashed in turn.
fn panel_dashes(curves: &[CurveId]) -> Vec<Dash> {
    let by_addition: Vec<Dash> = curves
        .iter()
        .map(|c| {
            if c.ntp_core != NtpCoreKind::Reactive {
                Dash::LongDashed
            } else if c.executed_node {
                Dash::Dotted
            } else if c.recipe == Recipe::Recommended || !c.ablation.is_full() {
                Dash::Dashed
            } else {
                Dash::Solid
            }
        })
        .collect();
    let clash = curves
        .iter()
        .zip(&by_addition)
        .enumerate()
        .any(|(i, (a, da))| {
            curves[..i]
                .iter()
                .zip(&by_addition)
                .any(|(b, db)| a.method == b.method && da == db)
        });
    if !clash {
        return by_addition;
    }
    curves
        .iter()
        .enumerate()
        .map(|(i, c)| {
            let nth = curves[..i].iter().filter(|b| b.method == c.method).count();
            Dash::ALL[nth % Dash::ALL.len()]
        })
        .collect()
}

/// The figure's panels: success, and goals met ([`write_figure`]).
pub(crate) fn figure_panels(points: &[NtpExpPoint]) -> (Vec<Panel>, Vec<Panel>) {
    let mut curves: Vec<CurveId> = Vec::new();
    for p in points {
        if !curves.contains(&p.curve_id()) {
            curves.push(p.curve_id());
        }
    }
    // The inputs, state first, then video by frame side (the standard
    // camera first) and by stage A's number of videos (the recipe's
    // first): a panel per protocol of perception, so that its curves
    // are told apart by method and recipe, not by a long legend.
    // NTP (Detector) trains no frame encoder: it joins the panel of the
    // other methods of its tag (the same camera and demos).
    let panel_videos = |c: &CurveId| {
        if c.method != MethodId::NtpDetector {
            return c.stage_a_videos;
        }
        curves
            .iter()
            .find(|o| {
                o.method != MethodId::NtpDetector
                    && (o.obs, o.camera, &o.tag) == (c.obs, c.camera, &c.tag)
            })
            .map_or(c.stage_a_videos, |o| o.stage_a_videos)
    };
    type Input = (ObsKind, Option<u32>, Option<usize>);
    let mut inputs: Vec<Input> = curves
        .iter()
        .map(|c| (c.obs, c.camera, panel_videos(c)))
        .collect();
    inputs.sort_by_key(|&(obs, camera, videos)| (obs != ObsKind::State, camera, videos));
    inputs.dedup();
    let letters = "abcdefghijklmnopqrstuvwxyz";
    let panel = |(i, &(obs, camera, videos)): (usize, &Input), goals: bool| {
        let mut input = match (obs, camera) {
            (ObsKind::State, _) => "state input".to_owned(),
            (ObsKind::Vid, None) => "video input".to_owned(),
            (ObsKind::Vid, Some(side)) => format!("video input, {side}×{side} frames"),
        };
        if let Some(videos) = videos {
            input.push_str(&format!(", stage A on up to {videos} videos"));
        }
        let of_panel: Vec<CurveId> = curves
            .iter()
            .filter(|c| c.obs == obs && c.camera == camera && panel_videos(c) == videos)
            .cloned()
            .collect();
        let dashes = panel_dashes(&of_panel);
        let series = of_panel
            .iter()
            .zip(dashes)
            .map(|(curve, dash)| {
                let look = method_look(curve.method.legend(), dash);
                let groups = by_point(points.iter().filter(|p| &p.curve_id() == curve));
                let points = groups
                    .iter()
                    .map(|g| {
                        if goals {
                            Point::exact(g.train_tasks as f64, g.mean(|p| p.goal_fraction))
                        } else {
                            g.success_point()
                        }
                    })
                    .collect();
                Series {
                    // The panel's title names the input and stage A.
                    name: curve.method_name(),
                    points,
                    look: Some(look),
                }
            })
            .filter(|series| !series.points.is_empty())
            .collect();
        Panel {
            title: format!("({}) {input}", &letters[i % 26..i % 26 + 1]),
            x_label: "seen training tasks".into(),
            y_label: if goals {
                "unseen tasks: goals met".into()
            } else {
                "unseen tasks: success rate".into()
            },
            x_log: true,
            x_ticks_at_points: false,
            y_range: (0.0, 1.0),
            series,
        }
    };
    let panels = |goals: bool| inputs.iter().enumerate().map(|i| panel(i, goals)).collect();
    (panels(false), panels(true))
}

/// The seeds of one point of one curve.
pub(crate) struct SeedGroup<'a> {
    /// Training tasks of the point.
    pub train_tasks: usize,
    /// One point per seed, in the order given.
    pub seeds: Vec<&'a NtpExpPoint>,
}

impl SeedGroup<'_> {
    /// The mean of `value` over the seeds.
    pub fn mean(&self, value: impl Fn(&NtpExpPoint) -> f64) -> f64 {
        self.seeds.iter().map(|p| value(p)).sum::<f64>() / self.seeds.len().max(1) as f64
    }

    /// The figure's success point: one seed's rate with its Wilson
    /// interval, or the mean over seeds with a bar from the lowest seed's
    /// interval end to the highest's.
    pub fn success_point(&self) -> Point {
        match self.seeds.as_slice() {
            [one] => Point::success(self.train_tasks as f64, &one.success),
            many => Point {
                x: self.train_tasks as f64,
                y: self.mean(|p| p.success.rate),
                lo: many.iter().map(|p| p.success.ci_low).fold(1.0, f64::min),
                hi: many.iter().map(|p| p.success.ci_high).fold(0.0, f64::max),
            },
        }
    }
}

/// `points` (of one curve) grouped by training tasks, in order of first
/// appearance.
pub(crate) fn by_point<'a>(points: impl Iterator<Item = &'a NtpExpPoint>) -> Vec<SeedGroup<'a>> {
    let mut groups: Vec<SeedGroup<'a>> = Vec::new();
    for p in points {
        match groups.iter_mut().find(|g| g.train_tasks == p.train_tasks) {
            Some(g) => g.seeds.push(p),
            None => groups.push(SeedGroup {
                train_tasks: p.train_tasks,
                seeds: vec![p],
            }),
        }
    }
    groups
}

/// The report's lines on points trained with more than one seed: mean and
/// range of success over the seeds (each seed's row, with its Wilson
/// interval, is in the table).
pub(crate) fn seed_spread(points: &[NtpExpPoint]) -> Vec<String> {
    let mut curves: Vec<CurveId> = Vec::new();
    for p in points {
        if !curves.contains(&p.curve_id()) {
            curves.push(p.curve_id());
        }
    }
    let mut lines = Vec::new();
    for curve in curves {
        let of = points.iter().filter(|p| p.curve_id() == curve);
        for g in by_point(of).iter().filter(|g| g.seeds.len() > 1) {
            let rates: Vec<f64> = g.seeds.iter().map(|p| p.success.rate).collect();
            let seeds: Vec<String> = g.seeds.iter().map(|p| p.seed.to_string()).collect();
            lines.push(NTP_EXP.fill(
                "seeds_line",
                &[
                    ("curve", &curve.method_name()),
                    ("obs", &curve.input()),
                    ("tasks", &g.train_tasks),
                    ("mean", &format!("{:.3}", g.mean(|p| p.success.rate))),
                    ("seeds", &seeds.join(", ")),
                    (
                        "lowest",
                        &format!("{:.3}", rates.iter().copied().fold(1.0, f64::min)),
                    ),
                    (
                        "highest",
                        &format!("{:.3}", rates.iter().copied().fold(0.0, f64::max)),
                    ),
                ],
            ));
        }
    }
    lines
}

/// A point's name in the report: its curve's, and its seed if not 0.
pub(crate) fn row_name(p: &NtpExpPoint) -> String {
    let name = p.curve_id().method_name();
    match p.seed {
        0 => name,
        seed => format!("{name}, seed {seed}"),
    }
}

/// The legend of `method` trained with `recipe` (and without a part, for
/// an ablation): the paper's recipe is the figure's default and goes
/// unnamed.
pub fn curve_name(method: MethodId, recipe: Recipe, ablation: Variant) -> String {
    let mut name = method.legend().to_owned();
    if !ablation.is_full() {
        name = format!("{name} without {}", ablation_part(ablation));
    }
    match recipe {
        Recipe::Paper => name,
        Recipe::Recommended => format!("{name}, recommended recipe"),
    }
}

/// A point's report cell naming what its run adds to the paper's recipe.
pub(crate) fn additions_cell(p: &NtpExpPoint) -> String {
    match p.additions.is_empty() {
        true => "none".into(),
        false => p.additions.join("; "),
    }
}

impl NtpExpPoint {
    /// The side of the point's frames where it is not the standard
    /// camera's (64): a curve of its own beside the standard frames'.
    pub fn other_camera(&self) -> Option<u32> {
        self.camera.filter(|&side| side != env_blocks::FRAME_SIZE)
    }

    /// The curve the point belongs to.
    pub fn curve_id(&self) -> CurveId {
        CurveId {
            method: self.method,
            recipe: self.recipe,
            ablation: self.ablation,
            obs: self.obs,
            camera: self.other_camera(),
            stage_a_videos: self.stage_a_videos,
            ntp_core: self.ntp_core,
            executed_node: self.executed_node,
            end_after_demo: self.additions.iter().any(|a| a == END_AFTER_DEMO),
            tag: self.tag.clone(),
            recipe_changes: self.recipe_changes.clone(),
            distinction: self.distinction.clone(),
        }
    }
}

/// What a name adds for NTG's node taken from the executed actions.
fn executed_node_suffix(executed_node: bool) -> &'static str {
    if executed_node { ", executed node" } else { "" }
}

/// The name of NTG's `<end>` rule (`end_after_demo`), as the run's
/// additions name it ([`blocks::additions`]) and as a curve's name gives it.
const END_AFTER_DEMO: &str = "ends only after the demo's actions";

/// One curve of the figure: the points drawn, and reported, as one line.
/// The seeds of a point are combined within a curve and never across
/// curves (a run of another camera or core network, or of a panel with
/// another tag, is another protocol).
#[derive(Debug, Clone, PartialEq)]
pub struct CurveId {
    /// The method trained.
    pub method: MethodId,
    /// Its recipe.
    pub recipe: Recipe,
    /// The part NTG is trained without (`full`: none).
    pub ablation: Variant,
    /// The input.
    pub obs: ObsKind,
    /// The frame side where not the standard camera's.
    pub camera: Option<u32>,
    /// Stage A's demo videos where not the recipe's number.
    pub stage_a_videos: Option<usize>,
    /// NTP's core network (reactive for NTG).
    pub ntp_core: NtpCoreKind,
    /// NTG on video: the node from the executed actions, not the localizer.
    pub executed_node: bool,
    /// NTG's policy chooses `<end>` only once the demo's actions are
    /// executed (`end_after_demo`, a symbolic rule).
    pub end_after_demo: bool,
    /// The panel's tag (`PanelScale::tag`): two panels of one method and
    /// recipe are two curves.
    pub tag: Option<String>,
    /// Where the run's recommended recipe differs from the recipe as it is
    /// now (`NtpExpPoint::recipe_changes`), named after the method.
    pub recipe_changes: Vec<String>,
    /// What tells the curve apart from another of the same name
    /// (`NtpExpPoint::distinction`), named after the method.
    pub distinction: Vec<String>,
}

impl CurveId {
    /// The curve's name in the figure's legend: the method and recipe
    /// ([`curve_name`]), its core network where not reactive and its frame
    /// side where not the standard camera's.
    pub fn legend(&self) -> String {
        let mut name = self.method_name();
        if let Some(side) = self.camera {
            name = format!("{name}, {side}×{side} frames");
        }
        if let Some(videos) = self.stage_a_videos {
            name = format!("{name}, stage A on up to {videos} videos");
        }
        name
    }

    /// The method and what it was trained with, without the input: the
    /// method and recipe ([`curve_name`]), its core network where not
    /// reactive and NTG's node source where executed.
    pub fn method_name(&self) -> String {
        let mut name = format!(
            "{}{}{}",
            curve_name(self.method, self.recipe, self.ablation),
            self.ntp_core.legend_suffix(),
            executed_node_suffix(self.executed_node)
        );
        if self.end_after_demo {
            name.push_str(&format!(", {END_AFTER_DEMO}"));
        }
        for change in self.recipe_changes.iter().chain(&self.distinction) {
            name.push_str(&format!(", {change}"));
        }
        name
    }

    /// The curve's input in words: `State`, `Vid`, or `Vid, 128×128` for
    /// frames of another camera (`, stage A on up to 5000 videos` where stage A
    /// read another number of videos than the recipe's).
    pub fn input(&self) -> String {
        let mut input = match self.camera {
            Some(side) => format!("{:?}, {side}×{side}", self.obs),
            None => format!("{:?}", self.obs),
        };
        if let Some(videos) = self.stage_a_videos {
            input.push_str(&format!(", stage A on up to {videos} videos"));
        }
        input
    }
}

/// A row's input cell: `State`, or `Vid` with its frames' side.
pub(crate) fn input_cell(obs: ObsKind, camera: Option<u32>) -> String {
    match camera {
        Some(side) if obs == ObsKind::Vid => format!("Vid ({side}×{side})"),
        _ => format!("{obs:?}"),
    }
}

/// A point's report cells `input | training tasks | demos/task | epochs
/// (selected)`; a run that stopped early at a perfect validation score
/// shows the epochs it trained of its planned ones.
pub(crate) fn scale_cells(p: &NtpExpPoint) -> String {
    let epochs = match &p.curve {
        Some(c) if c.epochs_trained > 0 && c.epochs_trained < p.epochs => {
            format!("{} of {}", c.epochs_trained, p.epochs)
        }
        _ => p.epochs.to_string(),
    };
    format!(
        "{} | {} | {} | {} ({})",
        input_cell(p.obs, p.camera),
        p.train_tasks,
        p.demos_per_task,
        epochs,
        p.selected_epoch
            .map_or_else(|| "last".to_owned(), |e| (e + 1).to_string())
    )
}

/// What the paper's text says of a method's success at 1000 tasks (it
/// gives its figure only as an image).
fn paper_at_1000(method: MethodId, obs: ObsKind, recipe: Recipe) -> &'static str {
    match (method, obs) {
        _ if recipe != Recipe::Paper => "not in the paper",
        (MethodId::Ntg, ObsKind::Vid) => "≈ 0.9 (≈ 30 points above NTP (Vid))",
        (MethodId::Ntg, _) => "≈ 0.9",
        (MethodId::Ntp, ObsKind::Vid) => "≈ 0.62",
        (MethodId::Ntp, _) => "≈ NTG (Vid)",
        _ => "below NTG",
    }
}

/// The headline table (README's "Results", `results-table.md`): every
/// curve of the whole model with a point at `train_tasks`, its success on
/// unseen tasks there (the mean over seeds with their range, or one seed's
/// 95% interval) beside what the paper's text says; curves in the order of
/// their first point in `points`.
pub fn headline_table(points: &[NtpExpPoint], train_tasks: usize) -> String {
    let mut curves: Vec<(CurveId, Vec<&NtpExpPoint>)> = Vec::new();
    for p in points
        .iter()
        .filter(|p| p.train_tasks == train_tasks && p.ablation.is_full())
    {
        let id = p.curve_id();
        match curves.iter_mut().find(|(c, _)| *c == id) {
            Some((_, seeds)) => seeds.push(p),
            None => curves.push((id, vec![p])),
        }
    }
    let trials = curves
        .first()
        .map_or(0, |(_, seeds)| seeds[0].success.trials);
    let mut s = format!(
        "| method | input | paper (its text) | ours, success on {trials} unseen tasks | seeds |\n|---|---|---|---|---|\n"
    );
    for (id, seeds) in &curves {
        let ours = match seeds.as_slice() {
            [one] => format!(
                "{:.3} ({:.3}–{:.3})",
                one.success.rate, one.success.ci_low, one.success.ci_high
            ),
            many => {
                let rates: Vec<f64> = many.iter().map(|p| p.success.rate).collect();
                let (lo, hi) = rates
                    .iter()
                    .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), &r| {
                        (lo.min(r), hi.max(r))
                    });
                format!(
                    "{:.3} ({lo:.3}–{hi:.3})",
                    rates.iter().sum::<f64>() / rates.len() as f64
                )
            }
        };
        let _ = writeln!(
            s,
            "| {} | {} | {} | {ours} | {} |",
            id.method_name(),
            id.input(),
            paper_at_1000(id.method, id.obs, id.recipe),
            seeds.len()
        );
    }
    s
}

/// A point's report cells `training time | test tasks | success (95% CI) |
/// goals met`.
pub(crate) fn outcome_cells(p: &NtpExpPoint) -> String {
    format!(
        "{:.0} s | {} | {:.3} ({:.3}–{:.3}) | {:.3}",
        p.train_seconds,
        p.success.trials,
        p.success.rate,
        p.success.ci_low,
        p.success.ci_high,
        p.goal_fraction
    )
}

/// The report section of fig. "ntp_exp" (Markdown); `recipe_note` says
/// what the file changes in the recipes ([`NtpExpExperiment::recipe_note`]).
pub fn report_section(points: &[NtpExpPoint], recipe_note: &str) -> String {
    let mut s = String::new();
    let _ = writeln!(s, "{}\n", NTP_EXP.text("head"));
    let _ = writeln!(s, "{}", NTP_EXP.text("table_head"));
    for p in points {
        let paper = match (p.method, p.obs, p.train_tasks) {
            _ if p.recipe != Recipe::Paper => "not in the paper (our additions)",
            (MethodId::Ntg, _, 50) => "≈ 0.1 (NTG, 50 tasks)",
            (MethodId::Ntg, _, 1000) => "≈ 0.9 (NTG, 1000 tasks, 100 demos/task)",
            (MethodId::Ntg, _, _) => "rising with tasks",
            (MethodId::Ntp, ObsKind::State, 50) => "above NTG (50 tasks)",
            (MethodId::Ntp, ObsKind::State, 1000) => "≈ NTG (Vid) (1000 tasks)",
            (_, _, n) if n >= 100 => "below NTG",
            _ => "not stated",
        };
        let _ = writeln!(
            s,
            "| {} | {} | {} | {} | {paper} |",
            row_name(p),
            scale_cells(p),
            additions_cell(p),
            outcome_cells(p)
        );
    }
    let notes = NTP_EXP.fill(
        "notes",
        &[
            ("recipe_note", &recipe_note),
            ("paper_learning_rate", &crate::fit::PAPER_LEARNING_RATE),
        ],
    );
    let _ = writeln!(s, "\n{notes}\n");
    bullet_list(
        &mut s,
        &NTP_EXP.text("relations_title"),
        trend_checks(points),
    );
    bullet_list(
        &mut s,
        &NTP_EXP.text("transcription_title"),
        transcription_lines(points),
    );
    bullet_list(
        &mut s,
        &NTP_EXP.text("learning_title"),
        learning_lines(points),
    );
    bullet_list(&mut s, &NTP_EXP.text("seen_title"), seen_lines(points));
    bullet_list(
        &mut s,
        &NTP_EXP.text("curves_title"),
        baseline_curve_lines(points),
    );
    bullet_list(
        &mut s,
        &NTP_EXP.text("decisions_title"),
        decision_lines(points),
    );
    bullet_list(
        &mut s,
        &NTP_EXP.text("detector_title"),
        detector_lines(points),
    );
    bullet_list(
        &mut s,
        &NTP_EXP.text("compute_title"),
        compute_lines(points),
    );
    bullet_list(
        &mut s,
        &NTP_EXP.text("stage_times_title"),
        stage_time_lines(points),
    );
    bullet_list(&mut s, &NTP_EXP.text("seeds_title"), seed_spread(points));
    s
}

/// One line per video run: where its training compute went, stage by
/// stage ([`StageTimes`]).
pub(crate) fn stage_time_lines(points: &[NtpExpPoint]) -> Vec<String> {
    points
        .iter()
        .filter_map(|p| {
            let times = p.stage_times.as_ref()?;
            Some(NTP_EXP.fill(
                "stage_times_line",
                &[
                    ("run", &row_name(p)),
                    ("obs", &p.curve_id().input()),
                    ("tasks", &p.train_tasks),
                    ("stages", &times.text()),
                ],
            ))
        })
        .collect()
}

/// One line per point also evaluated on its own training tasks
/// ([`NtpExpPoint::seen`]): its success there beside its success on unseen
/// tasks.
fn seen_lines(points: &[NtpExpPoint]) -> Vec<String> {
    points
        .iter()
        .filter_map(|p| {
            let seen = p.seen?;
            Some(NTP_EXP.fill(
                "seen_line",
                &[
                    ("run", &row_name(p)),
                    ("obs", &p.curve_id().input()),
                    ("tasks", &p.train_tasks),
                    ("seen", &format!("{:.3}", seen.rate)),
                    ("successes", &seen.successes),
                    ("trials", &seen.trials),
                    ("unseen", &format!("{:.3}", p.success.rate)),
                ],
            ))
        })
        .collect()
}

/// One line per point whose untrained model was scored
/// ([`NtpExpPoint::untrained`]): its success and goals met beside the
/// untrained model's, and whether it is above.
pub(crate) fn learning_lines(points: &[NtpExpPoint]) -> Vec<String> {
    points
        .iter()
        .filter_map(|p| {
            let untrained = p.untrained.as_ref()?;
            let verdict = crate::experiment::learning_verdict(&p.success, &untrained.success);
            Some(NTP_EXP.fill(
                "learning_line",
                &[
                    ("run", &row_name(p)),
                    ("obs", &p.curve_id().input()),
                    ("tasks", &p.train_tasks),
                    ("success", &format!("{:.3}", p.success.rate)),
                    ("low", &format!("{:.3}", p.success.ci_low)),
                    ("high", &format!("{:.3}", p.success.ci_high)),
                    ("untrained", &format!("{:.3}", untrained.success.rate)),
                    ("goals", &format!("{:.3}", p.goal_fraction)),
                    (
                        "untrained_goals",
                        &format!("{:.3}", untrained.goal_fraction),
                    ),
                    ("verdict", &verdict),
                ],
            ))
        })
        .collect()
}

/// One line per NTP (Detector) point: its detector's held-out scores
/// ([`NtpExpPoint::detector`]).
fn detector_lines(points: &[NtpExpPoint]) -> Vec<String> {
    points
        .iter()
        .filter_map(|p| {
            let d = p.detector.as_ref()?;
            Some(NTP_EXP.fill(
                "detector_line",
                &[
                    ("run", &row_name(p)),
                    ("obs", &p.curve_id().input()),
                    ("tasks", &p.train_tasks),
                    ("error", &format!("{:.4}", d.detector.position_error)),
                    (
                        "edges",
                        &format!(
                            "{:.2}",
                            d.detector.position_error / f64::from(env_blocks::world::CUBE_SIZE)
                        ),
                    ),
                    ("frames", &d.detector.frames),
                    (
                        "mean_state_error",
                        &format!("{:.4}", d.mean_state_position_error),
                    ),
                    ("gripper", &format!("{:.3}", d.detector.gripper_accuracy)),
                ],
            ))
        })
        .collect()
}

/// One line per baseline point at its curve's largest number of training
/// tasks (every seed there): its [`TrainingCurve`].
pub(crate) fn baseline_curve_lines(points: &[NtpExpPoint]) -> Vec<String> {
    let largest = |p: &NtpExpPoint| {
        points
            .iter()
            .filter(|q| q.curve_id() == p.curve_id())
            .map(|q| q.train_tasks)
            .max()
    };
    points
        .iter()
        .filter(|p| !p.method.is_ntg() && largest(p) == Some(p.train_tasks))
        .filter_map(|p| {
            let curve = p.curve.as_ref()?;
            Some(format!(
                "{} ({}, {} tasks; test {:.3}): {}",
                row_name(p),
                p.curve_id().input(),
                p.train_tasks,
                p.success.rate,
                curve.describe()
            ))
        })
        .collect()
}

/// One line per point with a decision check ([`NtpExpPoint::decisions`]):
/// its totals and its three steps least often right, with the head that
/// erred most there.
pub(crate) fn decision_lines(points: &[NtpExpPoint]) -> Vec<String> {
    points
        .iter()
        .filter_map(|p| {
            let r = p.decisions.as_ref()?;
            let rate = |right: usize, of: usize| right as f64 / of.max(1) as f64;
            let mut steps: Vec<&crate::method::ntp::StepTally> = r.steps.iter().collect();
            steps.sort_by(|a, b| {
                rate(a.right, a.decisions)
                    .partial_cmp(&rate(b.right, b.decisions))
                    .unwrap_or(std::cmp::Ordering::Equal)
            });
            let worst: Vec<String> = steps
                .iter()
                .take(3)
                .map(|t| {
                    let heads = [
                        ("eop", t.eop_wrong),
                        ("program", t.program_wrong),
                        ("argument", t.argument_wrong),
                        ("scope", t.scope_wrong),
                    ];
                    let (head, wrong) = heads
                        .iter()
                        .copied()
                        .max_by_key(|&(_, n)| n)
                        .unwrap_or(("eop", 0));
                    NTP_EXP.fill(
                        "decision_step",
                        &[
                            ("program", &t.program),
                            ("step", &t.step),
                            ("right", &format!("{:.3}", rate(t.right, t.decisions))),
                            ("head", &head),
                            ("wrong", &wrong),
                            ("decisions", &t.decisions),
                        ],
                    )
                })
                .collect();
            let per_trace = r.decisions as f64 / r.episodes.max(1) as f64;
            let but_scopes = rate(r.episodes_right_but_scopes, r.episodes);
            Some(NTP_EXP.fill(
                "decision_line",
                &[
                    ("run", &row_name(p)),
                    ("obs", &p.curve_id().input()),
                    ("tasks", &p.train_tasks),
                    ("test", &format!("{:.3}", p.success.rate)),
                    ("right", &format!("{:.3}", rate(r.right, r.decisions))),
                    ("per_trace", &format!("{per_trace:.1}")),
                    (
                        "traces_right",
                        &format!("{:.3}", rate(r.episodes_right, r.episodes)),
                    ),
                    ("traces", &r.episodes),
                    ("traces_right_but_scopes", &format!("{but_scopes:.3}")),
                    ("least_right", &worst.join("; ")),
                ],
            ))
        })
        .collect()
}

/// The success rates of a point's `seeds`.
pub(crate) fn seed_rates(seeds: &[&NtpExpPoint]) -> Vec<SuccessRate> {
    seeds.iter().map(|p| p.success).collect()
}

/// Appends `title`, then `lines` as a Markdown list; nothing if there are
/// no lines.
pub(crate) fn bullet_list(s: &mut String, title: &str, lines: Vec<String>) {
    if lines.is_empty() {
        return;
    }
    let _ = writeln!(s, "{title}\n");
    for line in lines {
        let _ = writeln!(s, "- {line}");
    }
    let _ = writeln!(s);
}

/// One line per curve (method, input, recipe): its runs and their summed
/// training epochs (Markdown).
pub(crate) fn compute_lines(points: &[NtpExpPoint]) -> Vec<String> {
    let mut curves: Vec<(String, usize, f64)> = Vec::new();
    for p in points {
        let curve = p.curve_id();
        let name = format!("{} ({})", curve.method_name(), curve.input());
        match curves.iter_mut().find(|(n, _, _)| *n == name) {
            Some((_, runs, seconds)) => {
                *runs += 1;
                *seconds += p.train_seconds;
            }
            None => curves.push((name, 1, p.train_seconds)),
        }
    }
    curves
        .into_iter()
        .map(|(name, runs, seconds)| {
            let time = if seconds >= 3600.0 {
                format!("{:.2} core-hours", seconds / 3600.0)
            } else {
                format!("{:.1} core-minutes", seconds / 60.0)
            };
            format!(
                "{name}: {runs} run{}, {time}",
                if runs == 1 { "" } else { "s" }
            )
        })
        .collect()
}

/// One line per point with a [`TranscriptionSplit`] (Markdown).
pub(crate) fn transcription_lines(points: &[NtpExpPoint]) -> Vec<String> {
    let rate = |r: &SuccessRate| {
        if r.trials == 0 {
            NTP_EXP.text("transcription_none")
        } else {
            format!("{:.3} ({}/{})", r.rate, r.successes, r.trials)
        }
    };
    points
        .iter()
        .filter_map(|p| {
            let t = p.transcription.as_ref()?;
            Some(NTP_EXP.fill(
                "transcription_line",
                &[
                    ("run", &row_name(p)),
                    ("obs", &p.curve_id().input()),
                    ("tasks", &p.train_tasks),
                    ("exact", &rate(&t.exact)),
                    ("success_if_exact", &rate(&t.success_if_exact)),
                    ("success_otherwise", &rate(&t.success_otherwise)),
                ],
            ))
        })
        .collect()
}

/// The paper's stated relations between the methods of fig. ntp_exp,
/// each checked at every number of training tasks where both sides were
/// run (paper recipe, over every seed of each point: "above" needs every
/// seed's interval of one side above every seed's of the other, "on par"
/// any overlap; with one seed a side, its interval): Markdown lines saying
/// where each holds and where it does not, with the numbers. Relations
/// with no point on either side are left out. Where baselines were also
/// trained with the recommended recipe (issue 17, 4b: cube renaming, the
/// addition that applies to them), NTG against each of them with that
/// recipe on both sides follows, judged the same way. Runs of the
/// recommended recipe trained before it changed (`recipe_changes`) are left
/// out: the relations are between the recipes as they are.
pub fn trend_checks(points: &[NtpExpPoint]) -> Vec<String> {
    let of_recipe = |recipe: Recipe| -> Vec<&NtpExpPoint> {
        points
            .iter()
            .filter(|p| p.recipe == recipe && p.ablation.is_full() && p.recipe_changes.is_empty())
            .collect()
    };
    let (paper, recommended) = (of_recipe(Recipe::Paper), of_recipe(Recipe::Recommended));
    // Every seed of a point of one side, in seed order.
    fn find<'a>(set: &[&'a NtpExpPoint], side: Side, n: usize) -> Option<Vec<&'a NtpExpPoint>> {
        let mut seeds: Vec<&NtpExpPoint> = set
            .iter()
            .filter(|p| Side::of(p) == side && p.train_tasks == n)
            .copied()
            .collect();
        seeds.sort_by_key(|p| p.seed);
        (!seeds.is_empty()).then_some(seeds)
    }
    // A video protocol's name beyond its camera and stage A: what its NTG
    // curve is named apart by (`name_apart`), e.g. its learning rate.
    let labels: Vec<(u64, String)> = points
        .iter()
        .filter(|p| p.obs == ObsKind::Vid && !p.distinction.is_empty())
        .map(|p| (protocol_of(p), p.distinction.join(", ")))
        .collect();
    let input_of = |side: &Side| match labels.iter().find(|(h, _)| *h == side.protocol) {
        Some((_, label)) => format!("{}, {label}", side.input()),
        None => side.input(),
    };
    let name_of = |side: &Side| format!("{} ({})", side.legend(), input_of(side));
    let rate = |seeds: &[&NtpExpPoint]| {
        let name = name_of(&Side::of(seeds[0]));
        match seeds {
            [one] => format!("{name} {:.3}", one.success.rate),
            _ => format!("{name} {}", crate::stats::seeds_text(&seed_rates(seeds))),
        }
    };
    // (relation, [(where, a's seeds, b's seeds)]).
    type Pair<'a> = (String, Vec<&'a NtpExpPoint>, Vec<&'a NtpExpPoint>);
    type Judge = dyn Fn(&[&NtpExpPoint], &[&NtpExpPoint]) -> bool;
    let judge = |name: &str, pairs: Vec<Pair<'_>>, ok: &Judge| {
        if pairs.is_empty() {
            return None;
        }
        let (mut yes, mut no) = (Vec::new(), Vec::new());
        for (at, a, b) in pairs {
            let text = format!("{at}: {} vs {}", rate(&a), rate(&b));
            if ok(&a, &b) {
                yes.push(text);
            } else {
                no.push(text);
            }
        }
        let verdict = match (yes.is_empty(), no.is_empty()) {
            (false, true) => "**holds**",
            (true, false) => "**does not hold**",
            _ => "**holds in part**",
        };
        let mut line = format!("{name}: {verdict}");
        if !yes.is_empty() {
            line.push_str(&format!("; holds at {}", yes.join(", ")));
        }
        if !no.is_empty() {
            line.push_str(&format!("; does not hold at {}", no.join(", ")));
        }
        Some(line + ".")
    };
    // Over seeds: every interval of one side against every interval of
    // the other (with one seed each, the two intervals).
    fn low(s: &[&NtpExpPoint]) -> f64 {
        crate::stats::interval_span(&seed_rates(s)).0
    }
    fn high(s: &[&NtpExpPoint]) -> f64 {
        crate::stats::interval_span(&seed_rates(s)).1
    }
    fn above(a: &[&NtpExpPoint], b: &[&NtpExpPoint]) -> bool {
        low(a) > high(b)
    }
    fn on_par_or_above(a: &[&NtpExpPoint], b: &[&NtpExpPoint]) -> bool {
        high(a) >= low(b)
    }
    // Each number of training tasks from `from` on where `set` has both
    // sides.
    fn pairs<'a>(set: &[&'a NtpExpPoint], a: Side, b: Side, from: usize) -> Vec<Pair<'a>> {
        let mut sizes: Vec<usize> = set.iter().map(|p| p.train_tasks).collect();
        sizes.sort_unstable();
        sizes.dedup();
        sizes
            .into_iter()
            .filter(|&n| n >= from)
            .filter_map(|n| Some((format!("{n} tasks"), find(set, a, n)?, find(set, b, n)?)))
            .collect()
    }
    // The inputs: state, and video with each camera its points used (each
    // a protocol of its own: the paper's relations are checked within
    // one); and each baseline's core networks there.
    // A stage A on another number of videos is a protocol of its own too.
    // So is each video panel's tag (a protocol: `cam128a20klr1` trains
    // stage B at another learning rate than `cam128a20k`).
    type Input = (ObsKind, Option<u32>, Option<usize>, u64);
    let mut inputs: Vec<Input> = vec![(ObsKind::State, None, None, 0)];
    for p in points.iter().filter(|p| p.obs == ObsKind::Vid) {
        let input = (p.obs, p.other_camera(), p.stage_a_videos, protocol_of(p));
        if !inputs.contains(&input) {
            inputs.push(input);
        }
    }
    inputs[1..].sort_by_key(|&(_, camera, videos, _)| (camera, videos));
    let cores_of =
        |method: MethodId, (obs, camera, stage_a_videos, protocol): Input| -> Vec<Side> {
            [NtpCoreKind::Reactive, NtpCoreKind::Gru]
                .into_iter()
                .map(|core| Side {
                    method,
                    core,
                    executed_node: false,
                    obs,
                    camera,
                    stage_a_videos,
                    protocol,
                })
                .filter(|side| points.iter().any(|p| Side::of(p) == *side))
                .collect()
        };
    let side = |method: MethodId, (obs, camera, stage_a_videos, protocol): Input| Side {
        method,
        core: NtpCoreKind::Reactive,
        executed_node: false,
        obs,
        camera,
        stage_a_videos,
        protocol,
    };
    let state = (ObsKind::State, None, None, 0);
    let baselines = [MethodId::Ntp, MethodId::NtpFlat, MethodId::NtpDetector];
    let mut lines = Vec::new();
    for &input in inputs.iter().filter(|(obs, ..)| *obs == ObsKind::Vid) {
        for ntp_vid in cores_of(MethodId::Ntp, input) {
            let ntp_state = side(MethodId::Ntp, state);
            lines.extend(judge(
                &format!(
                    "{} clearly below {}",
                    name_of(&ntp_vid),
                    name_of(&ntp_state)
                ),
                pairs(&paper, ntp_state, ntp_vid, 0),
                &above,
            ));
        }
    }
    for &input in inputs.iter().filter(|(obs, ..)| *obs == ObsKind::Vid) {
        let (ntg_vid, ntp_state) = (side(MethodId::Ntg, input), side(MethodId::Ntp, state));
        lines.extend(judge(
            &format!(
                "NTG ({}) on par with {} or above",
                input_of(&ntg_vid),
                name_of(&ntp_state)
            ),
            pairs(&paper, ntg_vid, ntp_state, 0),
            &on_par_or_above,
        ));
    }
    for &input in &inputs {
        let ntg = side(MethodId::Ntg, input);
        for baseline in baselines.into_iter().flat_map(|m| cores_of(m, input)) {
            lines.extend(judge(
                &format!(
                    "NTG above {} from 100 tasks on ({} input)",
                    baseline.legend(),
                    input_of(&ntg)
                ),
                pairs(&paper, ntg, baseline, 100),
                &above,
            ));
        }
        for ntp in cores_of(MethodId::Ntp, input) {
            let flat = Side {
                method: MethodId::NtpFlat,
                ..ntp
            };
            lines.extend(judge(
                &format!(
                    "{} below {} ({} input)",
                    flat.legend(),
                    ntp.legend(),
                    input_of(&ntp)
                ),
                pairs(&paper, ntp, flat, 0),
                &above,
            ));
        }
    }
    for &input in &inputs {
        // NTG of the recommended recipe with each node source it was run
        // with on this input.
        let ntgs = [true, false].map(|executed_node| Side {
            executed_node,
            ..side(MethodId::Ntg, input)
        });
        for ntg in ntgs
            .into_iter()
            .filter(|ntg| recommended.iter().any(|p| Side::of(p) == *ntg))
        {
            for baseline in baselines.into_iter().flat_map(|m| cores_of(m, input)) {
                let ntg_name = match ntg.executed_node {
                    true => "NTG with the executed node",
                    false => "NTG",
                };
                lines.extend(judge(
                    &format!(
                        "Not in the paper: {ntg_name} above {} with the recommended recipe on both sides ({} input)",
                        baseline.legend(),
                        input_of(&ntg)
                    ),
                    pairs(&recommended, ntg, baseline, 0),
                    &above,
                ));
            }
        }
    }
    lines
}

/// One side of a relation [`trend_checks`] checks: a method (with NTP's
/// core network) on one input (with its camera).
#[derive(Debug, Clone, Copy, PartialEq)]
struct Side {
    method: MethodId,
    core: NtpCoreKind,
    /// NTG on video: the node from the executed actions.
    executed_node: bool,
    obs: ObsKind,
    /// The frame side where not the standard camera's.
    camera: Option<u32>,
    /// Stage A's demo videos where not the recipe's number.
    stage_a_videos: Option<usize>,
    /// The video panel's protocol ([`protocol_of`]).
    protocol: u64,
}

/// A video point's protocol, its panel's tag (hashed, to compare): the
/// paper's relations are checked within one. State points are all one.
fn protocol_of(p: &NtpExpPoint) -> u64 {
    use std::hash::{Hash, Hasher};
    if p.obs != ObsKind::Vid {
        return 0;
    }
    let mut hasher = std::collections::hash_map::DefaultHasher::new();
    p.tag.hash(&mut hasher);
    hasher.finish()
}

impl Side {
    fn of(p: &NtpExpPoint) -> Side {
        Side {
            method: p.method,
            core: p.ntp_core,
            executed_node: p.executed_node,
            obs: p.obs,
            camera: p.other_camera(),
            stage_a_videos: p.stage_a_videos,
            protocol: protocol_of(p),
        }
    }

    /// The method and its core or node source: `NTP, GRU core`.
    fn legend(&self) -> String {
        format!(
            "{}{}{}",
            self.method.legend(),
            self.core.legend_suffix(),
            executed_node_suffix(self.executed_node)
        )
    }

    /// The input: `Vid` or `Vid, 128×128` (`, stage A on up to 5000 videos`).
    fn input(&self) -> String {
        let mut input = match self.camera {
            Some(side) => format!("{:?}, {side}×{side}", self.obs),
            None => format!("{:?}", self.obs),
        };
        if let Some(videos) = self.stage_a_videos {
            input.push_str(&format!(", stage A on up to {videos} videos"));
        }
        input
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// No success is never above an untrained 0 (the Wilson interval's
    /// lower end of 0/100 is 0 up to rounding); a few successes are; a
    /// point within the untrained rate's noise is not.
    #[test]
    fn above_untrained_needs_the_interval_above_the_untrained_rate() {
        let zero = SuccessRate::new(0, 100);
        use crate::experiment::above_untrained;
        assert!(!above_untrained(&SuccessRate::new(0, 100), &zero));
        assert!(above_untrained(&SuccessRate::new(5, 100), &zero));
        assert!(!above_untrained(
            &SuccessRate::new(12, 100),
            &SuccessRate::new(8, 100)
        ));
        assert!(above_untrained(
            &SuccessRate::new(40, 100),
            &SuccessRate::new(8, 100)
        ));
    }

    /// Every row of the committed report's block-stacking tables (fig.
    /// "ntp_exp", fig. "ablation" (a), the structure split) names every
    /// addition to the paper's recipe that its run's configuration (in its
    /// committed record) holds: the executed node, cube renaming and its
    /// groups, retry repeats, the progress head, frame pooling, ...
    #[test]
    fn every_committed_row_names_every_addition_its_run_configuration_holds() {
        let figures = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../docs/figures");
        if !figures.join("records").is_dir() {
            eprintln!(
                "skipped: no {} (not a checkout of the repository)",
                figures.display()
            );
            return;
        }
        let results: serde_json::Value = RunDir::read_json(&figures.join("results.json")).unwrap();
        let report = std::fs::read_to_string(figures.join("REPORT.md")).unwrap();
        let runs_of = |key: &str| -> Vec<String> {
            results[key]
                .as_array()
                .unwrap_or_else(|| panic!("results.json: no {key}"))
                .iter()
                .map(|p| {
                    std::path::Path::new(p["run"].as_str().unwrap())
                        .file_name()
                        .unwrap()
                        .to_string_lossy()
                        .into_owned()
                })
                .collect()
        };
        let mut named = 0;
        for (key, header) in [
            (
                "ntp_exp",
                "| method | input | training tasks | demos/task |",
            ),
            ("ablation", "| variant | input | training tasks |"),
            ("structure", "| method | input | training tasks | seed |"),
        ] {
            let start = report
                .find(header)
                .unwrap_or_else(|| panic!("the {key} table"));
            let rows: Vec<&str> = report[start..]
                .lines()
                .skip(2)
                .take_while(|l| l.starts_with('|'))
                .collect();
            let runs = runs_of(key);
            assert_eq!(rows.len(), runs.len(), "{key}: one row per point");
            for (row, run) in rows.iter().zip(&runs) {
                let record: serde_json::Value =
                    RunDir::read_json(&figures.join("records").join(format!("{run}.json")))
                        .unwrap();
                let config: BlocksRunConfig =
                    serde_json::from_value(record["files"]["config.json"].clone()).unwrap();
                let additions = blocks::additions(&config);
                if additions.is_empty() {
                    assert!(
                        row.contains("| none |"),
                        "{key}: {run} adds nothing, its row says otherwise: {row}"
                    );
                }
                for addition in additions {
                    assert!(
                        row.contains(&addition),
                        "{key}: {run}: its row does not name {addition:?}: {row}"
                    );
                    named += 1;
                }
            }
        }
        assert!(
            named > 0,
            "the recommended recipe's rows name their additions"
        );
    }

    #[test]
    fn additions_name_what_a_configuration_adds_to_the_paper_recipe() {
        let paper = Recipe::Paper.config(ObsKind::Vid, 50, 4, 2, 0);
        assert_eq!(blocks::additions(&paper), Vec::<String>::new());
        let mut ours = Recipe::Recommended.config(ObsKind::Vid, 50, 4, 2, 0);
        let additions = blocks::additions(&ours);
        for named in [
            "executed node (not the localizer)",
            "video cube renaming in groups of 4",
            "interpreter frame pooling 4",
        ] {
            assert!(
                additions.iter().any(|a| a == named),
                "{named}: {additions:?}"
            );
        }
        // A setting without a name of its own is named by its key.
        ours.video.as_mut().unwrap().encoder.kernel = 5;
        assert!(
            blocks::additions(&ours)
                .iter()
                .any(|a| a == "stage A kernel = 5")
        );
        ours.retry_weight = 2.0;
        assert!(
            blocks::additions(&ours)
                .iter()
                .any(|a| a == "retry weight 2.0")
        );
        // Perception: the camera and the encoder's stem.
        let video = ours.video.as_mut().unwrap();
        video.camera = env_blocks::Camera::of_size(128);
        video.encoder.stem = 16;
        let additions = blocks::additions(&ours);
        for named in ["camera 128x128 px", "encoder stem of 16 channels"] {
            assert!(
                additions.iter().any(|a| a == named),
                "{named}: {additions:?}"
            );
        }
    }

    #[test]
    fn recipe_changes_name_where_a_run_differs_from_the_recipe_as_it_is_now() {
        // The recipe as it is: nothing to name, on either input.
        for obs in [ObsKind::State, ObsKind::Vid] {
            let now = Recipe::Recommended.config(obs, 50, 4, 2, 0);
            assert_eq!(
                blocks::recipe_changes(&now, Recipe::Recommended),
                Vec::<String>::new()
            );
        }
        // A state run trained with the GCN detached (before the recipe's
        // re-choice on validation structures) says so ...
        let mut before = Recipe::Recommended.config(ObsKind::State, 50, 4, 2, 0);
        before.detach_gcn_from_edges = true;
        assert_eq!(
            blocks::recipe_changes(&before, Recipe::Recommended),
            vec!["GCN detached from the edge loss".to_owned()]
        );
        // ... so does one trained before the executed node, the `<end>`
        // rule and the taught stepping interpreter (the step prior goes
        // with the interpreter) ...
        let mut localizer = Recipe::Recommended.config(ObsKind::State, 50, 4, 2, 0);
        localizer.executed_node = false;
        localizer.end_after_demo = false;
        localizer.interpreter = None;
        localizer.location_step_prior = None;
        assert_eq!(
            blocks::recipe_changes(&localizer, Recipe::Recommended),
            vec![
                "may end before the demo's actions".to_owned(),
                "localizer choosing the node".to_owned(),
                "the paper's interpreter".to_owned(),
            ]
        );
        // ... a setting turned off is named as such ...
        before.pairwise = false;
        assert!(
            blocks::recipe_changes(&before, Recipe::Recommended)
                .contains(&"without pairwise cube offsets".to_owned())
        );
        // ... NTP has no GCN to detach, and the paper recipe's differences
        // are additions.
        let mut ntp = Recipe::Recommended.for_method(
            Recipe::Recommended.config(ObsKind::State, 50, 4, 2, 0),
            MethodId::Ntp,
        );
        ntp.detach_gcn_from_edges = true;
        assert_eq!(
            blocks::recipe_changes(&ntp, Recipe::Recommended),
            Vec::<String>::new()
        );
        assert_eq!(
            blocks::recipe_changes(&before, Recipe::Paper),
            Vec::<String>::new()
        );
    }

    #[test]
    fn a_panel_tag_keeps_its_runs_apart_and_must_be_a_plain_word() {
        let mut experiment = NtpExpExperiment::load(crate::experiment::Source::BuiltIn).unwrap();
        let mut panel = experiment.profiles.smoke.panels[1].clone();
        let untagged = experiment.run_name(&panel, (MethodId::Ntp, Variant::Full), 5);
        assert_eq!(untagged, "ntp_exp-vid-ntp-5");
        panel.tag = Some("cam128".into());
        let tagged = experiment.run_name(&panel, (MethodId::Ntp, Variant::Full), 5);
        assert_eq!(tagged, "ntp_exp-vid-cam128-ntp-5");
        panel.tag = Some("Cam 128".into());
        experiment.profiles.smoke.panels[1] = panel;
        let err = experiment.run_configs(Profile::Smoke).unwrap_err();
        assert!(
            err.to_string().contains("lowercase letters and digits"),
            "{err}"
        );
    }

    #[test]
    fn a_panel_takes_its_stages_from_the_panel_it_names_only_where_stage_b_alone_differs() {
        let experiment =
            NtpExpExperiment::load_named("structure", crate::experiment::Source::BuiltIn).unwrap();
        // The paper profile lists the `localign` run after `locend`'s run of
        // its seed, whose stage A and embeddings it links.
        let list = schedule(&experiment, Profile::Paper);
        let name = "structure-vid-localign-recommended-localizer-1000";
        let source = "structure-vid-locend-recommended-localizer-1000".to_owned();
        let run = list.iter().find(|r| r.name == name).unwrap();
        assert!(run.after.contains(&source), "{:?}", run.after);
        let at = |n: &str| list.iter().position(|r| r.name == n).unwrap();
        assert!(at(&source) < at(name));
        // The two configurations differ only in what stage B reads.
        let configs = experiment.named_run_configs(Profile::Paper).unwrap();
        let config = |name: &str| configs.iter().find(|(n, _)| n == name).unwrap().1.clone();
        let candidate = config("structure-vid-localign-recommended-localizer-1000");
        let source = config("structure-vid-locend-recommended-localizer-1000");
        assert!(same_but_stage_b(&candidate)(&source));
        assert!(!same_but_stage_b(&candidate)(&config(
            "structure-vid-recommended-localizer-1000-seed1"
        )));
        let mut other = source.clone();
        other.memory = false;
        assert!(
            !same_but_stage_b(&candidate)(&other),
            "a memory difference links nothing"
        );
        // A candidate of the other node source links the source panel's
        // run by that run's own name (`...-localizer-...`).
        let list_names: Vec<&str> = list.iter().map(|r| r.name.as_str()).collect();
        let name = "structure-vid-tallexecend-recommended-1000";
        let source = "structure-vid-tall-recommended-localizer-1000".to_owned();
        let run = list
            .iter()
            .find(|r| r.name == name)
            .unwrap_or_else(|| panic!("{list_names:?}"));
        assert!(run.after.contains(&source), "{:?}", run.after);
        assert!(same_but_stage_b(&config(name))(&config(&source)));
        // The tall camera's runs name their framing, the detector's too.
        for name in [
            "structure-vid-tall-recommended-localizer-1000",
            "structure-vid-tall-ntp-detector-1000",
        ] {
            let tall = config(name);
            assert_eq!(tall.camera().framing, env_blocks::Framing::Tall, "{name}");
            assert_eq!(tall.camera().size, 160, "{name}");
            let additions = blocks::additions(&tall);
            assert!(
                additions.iter().any(|a| a == "tall camera framing"),
                "{name}: {additions:?}"
            );
        }
        // A baseline's panel taking its stages from another links the
        // stage A of NTG's run there: the same frame encoder, whatever the
        // method and the localizer's inputs.
        let ntp_exp = NtpExpExperiment::load(crate::experiment::Source::BuiltIn).unwrap();
        let list = schedule(&ntp_exp, Profile::Paper);
        let name = "ntp_exp-vid-cam128a20klr1ntgenc-ntp-1000";
        let source = "ntp_exp-vid-cam128a20klr1prev-1000".to_owned();
        let run = list.iter().find(|r| r.name == name).unwrap();
        assert!(run.after.contains(&source), "{:?}", run.after);
        let configs = ntp_exp.named_run_configs(Profile::Paper).unwrap();
        let config = |name: &str| configs.iter().find(|(n, _)| n == name).unwrap().1.clone();
        let (baseline, ntg) = (config(name), config(&source));
        assert!(same_but_stage_b_and_method(&baseline)(&ntg));
        let mut other = ntg.clone();
        other.end_after_demo = !other.end_after_demo;
        assert!(same_but_stage_b_and_method(&baseline)(&other));
        assert!(
            !same_but_method(&baseline)(&other),
            "the <end> rule differs"
        );
        assert!(!same_but_stage_b_and_method(&baseline)(&config(
            "ntp_exp-vid-cam128a20klr1prev-1000-seed1"
        )));
        // A panel naming no such panel is refused.
        let mut broken = experiment.clone();
        let panel = broken
            .profiles
            .paper
            .panels
            .iter_mut()
            .find(|p| p.tag.as_deref() == Some("localign"))
            .unwrap();
        panel.stages_from = Some("nosuchtag".into());
        let err = broken.run_configs(Profile::Paper).unwrap_err().to_string();
        assert!(err.contains("stages_from = \"nosuchtag\""), "{err}");
    }

    #[test]
    fn a_panel_s_ntp_core_names_its_baseline_runs_and_belongs_to_the_panel() {
        let mut experiment = NtpExpExperiment::load(crate::experiment::Source::BuiltIn).unwrap();
        let mut panel = experiment.profiles.smoke.panels[1].clone();
        panel.tag = Some("cam128".into());
        panel
            .overrides
            .insert("ntp_core".into(), toml::Value::String("gru".into()));
        panel.methods = Some(vec![MethodId::Ntp, MethodId::NtpFlat]);
        let name = |experiment: &NtpExpExperiment, panel: &PanelScale, method| {
            experiment.run_name(panel, (method, Variant::Full), 5)
        };
        assert_eq!(
            name(&experiment, &panel, MethodId::Ntp),
            "ntp_exp-vid-cam128-ntp-gru-5"
        );
        assert_eq!(
            name(&experiment, &panel, MethodId::NtpFlat),
            "ntp_exp-vid-cam128-ntp-flat-gru-5"
        );
        // NTG of the same point, whose stage A the baselines link, keeps
        // its name.
        assert_eq!(
            name(&experiment, &panel, MethodId::Ntg),
            "ntp_exp-vid-cam128-5"
        );
        experiment.profiles.smoke.panels = vec![panel.clone()];
        let configs = experiment.run_configs(Profile::Smoke).unwrap();
        assert!(configs.iter().all(|c| c.ntp_core == NtpCoreKind::Gru));
        // NTG has no core network: a panel that sets one cannot list it.
        let mut with_ntg = panel.clone();
        with_ntg.methods = Some(vec![MethodId::Ntg, MethodId::Ntp]);
        experiment.profiles.smoke.panels = vec![with_ntg];
        let err = experiment.run_configs(Profile::Smoke).unwrap_err();
        assert!(err.to_string().contains("NTG has none"), "{err}");
        // Set for the whole file, it would not name the runs: refused.
        let mut reactive = panel.clone();
        reactive.overrides.remove("ntp_core");
        experiment.profiles.smoke.panels = vec![reactive];
        experiment
            .overrides
            .insert("ntp_core".into(), toml::Value::String("gru".into()));
        let err = experiment.run_configs(Profile::Smoke).unwrap_err();
        assert!(
            err.to_string().contains("belongs in a panel's overrides"),
            "{err}"
        );
    }

    #[test]
    fn a_panel_s_node_source_names_its_ntg_runs_where_it_is_not_the_recipe_s() {
        let mut experiment = NtpExpExperiment::load(crate::experiment::Source::BuiltIn).unwrap();
        let mut panel = experiment.profiles.smoke.panels[1].clone();
        panel.recipe = Some(Recipe::Recommended);
        panel.methods = Some(vec![MethodId::Ntg, MethodId::Ntp]);
        let set = |panel: &mut PanelScale, executed: bool| {
            let video = panel
                .overrides
                .get_mut("video")
                .unwrap()
                .as_table_mut()
                .unwrap();
            video.insert("executed_node".into(), toml::Value::Boolean(executed));
        };
        let ntg = |experiment: &NtpExpExperiment, panel: &PanelScale| {
            experiment.run_name(panel, (MethodId::Ntg, Variant::Full), 5)
        };
        assert_eq!(ntg(&experiment, &panel), "ntp_exp-vid-recommended-5");
        assert_eq!(
            experiment.run_name_of_other_node_source(&panel, 5),
            "ntp_exp-vid-recommended-localizer-5"
        );
        // The recipe's own value names nothing.
        set(&mut panel, true);
        assert_eq!(ntg(&experiment, &panel), "ntp_exp-vid-recommended-5");
        set(&mut panel, false);
        assert_eq!(
            ntg(&experiment, &panel),
            "ntp_exp-vid-recommended-localizer-5"
        );
        assert_eq!(
            experiment.run_name_of_other_node_source(&panel, 5),
            "ntp_exp-vid-recommended-5"
        );
        // Baselines have no node source: their names are the panel's.
        assert_eq!(
            experiment.run_name(&panel, (MethodId::Ntp, Variant::Full), 5),
            "ntp_exp-vid-ntp-recommended-5"
        );
        experiment.profiles.smoke.panels = vec![panel.clone()];
        let configs = experiment.run_configs(Profile::Smoke).unwrap();
        assert!(!configs[0].video.as_ref().unwrap().executed_node);
        // Set for a whole profile it would not name the runs: refused.
        let mut plain = panel.clone();
        plain
            .overrides
            .get_mut("video")
            .unwrap()
            .as_table_mut()
            .unwrap()
            .remove("executed_node");
        experiment.profiles.smoke.panels = vec![plain];
        let table: toml::Table = toml::from_str("[video]\nexecuted_node = false").unwrap();
        experiment.profiles.smoke.overrides.extend(table);
        let err = experiment.run_configs(Profile::Smoke).unwrap_err();
        assert!(
            err.to_string().contains("belongs in a panel's overrides"),
            "{err}"
        );
    }

    #[test]
    fn ntp_detector_of_a_panel_with_another_camera_renders_its_frames_with_it() {
        let experiment = NtpExpExperiment::load(crate::experiment::Source::BuiltIn).unwrap();
        let configs = experiment.named_run_configs(Profile::Paper).unwrap();
        let config = |name: &str| {
            configs
                .iter()
                .find(|(n, _)| n == name)
                .map(|(_, c)| c.clone())
                .unwrap_or_else(|| panic!("{name}"))
        };
        let cam128 = config("ntp_exp-vid-cam128-ntp-detector-1000");
        assert!(cam128.video.is_none());
        assert_eq!(cam128.camera().size, 128);
        assert_eq!(cam128.detector.as_ref().unwrap().stem, Some(16));
        let additions = blocks::additions(&cam128);
        for named in ["camera 128x128 px", "detector stem of 16 channels"] {
            assert!(additions.iter().any(|a| a == named), "{additions:?}");
        }
        // The earlier protocol's detector keeps the standard camera, and
        // its configuration (that of its committed records) is unchanged.
        let standard = config("ntp_exp-vid-ntp-detector-1000");
        assert_eq!(standard.camera(), env_blocks::Camera::default());
        let json = serde_json::to_string(&standard.detector).unwrap();
        assert!(!json.contains("camera") && !json.contains("stem"), "{json}");
    }

    #[test]
    fn small_training_sets_get_epochs_up_to_the_minimum_steps() {
        let scale = PanelScale {
            obs: ObsKind::State,
            train_tasks: vec![50, 1000],
            demos_per_task: 10,
            epochs: 6,
            min_steps: 1000,
            test_tasks: 10,
            overrides: toml::Table::new(),
            methods: None,
            recipe: None,
            detector: toml::Table::new(),
            ablations: None,
            seed: None,
            tag: None,
            stages_from: None,
        };
        // 500 demos = 16 steps per epoch -> 63 epochs to reach 1000 steps.
        assert_eq!(scale.epochs_for(50, 32), 63);
        // 10000 demos = 313 steps per epoch: 6 epochs already exceed it.
        assert_eq!(scale.epochs_for(1000, 32), 6);
        let exact = PanelScale {
            min_steps: 0,
            ..scale
        };
        assert_eq!(exact.epochs_for(50, 32), 6);
    }

    #[test]
    fn a_baseline_point_trains_and_scores_in_its_own_run_folder() {
        let dir = tempfile::tempdir().unwrap();
        let mut experiment = NtpExpExperiment::load(crate::experiment::Source::BuiltIn).unwrap();
        // The smoke profile lists the baselines; keep one tiny point of NTP.
        let smoke = &mut experiment.profiles.smoke;
        smoke.panels.truncate(1);
        let panel = &mut smoke.panels[0];
        assert_eq!(
            panel.methods.clone().unwrap_or_default(),
            vec![MethodId::Ntg, MethodId::Ntp, MethodId::NtpFlat]
        );
        panel.methods = Some(vec![MethodId::Ntp]);
        panel.train_tasks = vec![2];
        panel.epochs = 1;
        panel.test_tasks = 2;
        let runs = dir.path().join("runs");
        let points = run(&experiment, Profile::Smoke, &Plan::train_all(&runs, 1)).unwrap();
        assert_eq!(points.len(), 1);
        let p = &points[0];
        assert_eq!(
            (p.method, p.obs, p.train_tasks),
            (MethodId::Ntp, ObsKind::State, 2)
        );
        assert_eq!(p.success.trials, 2);
        assert!(p.run.ends_with("ntp_exp-state-ntp-2"));
        let config: BlocksRunConfig = RunDir::read_json(&p.run.join("config.json")).unwrap();
        assert_eq!(config.method, MethodId::Ntp);
        // A second pass reuses the run and its evaluation.
        assert_eq!(
            run(&experiment, Profile::Smoke, &Plan::train_all(&runs, 2)).unwrap(),
            points
        );
        // The seen-task check scores it on its own training tasks (at most
        // as many as it has), once.
        let mut checked = points.clone();
        check_baselines(&mut checked, &Plan::train_all(&runs, 1), 3).unwrap();
        assert_eq!(checked, points, "below the threshold: nothing scored");
        check_baselines(&mut checked, &Plan::train_all(&runs, 1), 2).unwrap();
        assert_eq!(checked[0].seen.unwrap().trials, 2);
        assert!(p.run.join("eval").join("seen-ntp-2.json").is_file());
        // Its decisions are checked along the expert's traces of test tasks.
        let report = checked[0].decisions.clone().unwrap();
        // As many tasks as the point was scored on (2), fewer than 200.
        assert_eq!(report.episodes, 2);
        assert!(
            report
                .steps
                .iter()
                .any(|t| t.program == "place" && t.step == "drop")
        );
        assert!(p.run.join("eval").join("decisions-2.json").is_file());
        let lines = decision_lines(&checked);
        assert_eq!(lines.len(), 1);
        assert!(lines[0].contains("least often right"), "{}", lines[0]);
        assert_eq!(
            run(&experiment, Profile::Smoke, &Plan::train_all(&runs, 1)).unwrap(),
            checked,
            "the point reads its seen score back"
        );
        // Methods the figure has not are refused before anything runs:
        // the Flat Policy, NTP (Detector) on states.
        let state = &experiment.profiles.smoke.panels[0];
        for method in [MethodId::Flat, MethodId::NtpDetector] {
            let err = experiment
                .run_config(Profile::Smoke, state, (method, Variant::Full), 2)
                .unwrap_err();
            assert!(format!("{err:#}").contains("ntp_exp trains"), "{err:#}");
        }
    }

    #[test]
    fn the_paper_profile_has_three_seeds_on_state_and_two_on_video_at_1000_tasks() {
        let experiment = NtpExpExperiment::load(crate::experiment::Source::BuiltIn).unwrap();
        let names = experiment.run_names(Profile::Paper);
        for method in ["", "ntp-", "ntp-flat-"] {
            for seed in ["", "-seed1", "-seed2"] {
                let name = format!("ntp_exp-state-{method}1000{seed}");
                assert!(names.contains(&name), "{name}");
            }
        }
        for method in ["", "ntp-", "ntp-flat-", "ntp-detector-"] {
            for seed in ["", "-seed1"] {
                let name = format!("ntp_exp-vid-{method}1000{seed}");
                assert!(names.contains(&name), "{name}");
            }
        }
        let paper = &experiment.profiles.paper.panels;
        let seeded = paper.iter().find(|p| p.seed == Some(2)).unwrap();
        let c = experiment
            .run_config(Profile::Paper, seeded, (MethodId::Ntp, Variant::Full), 1000)
            .unwrap();
        assert_eq!((c.model_seed, c.optim.seed), (2, 2));
        let ablation =
            crate::experiment::ablation::load(crate::experiment::Source::BuiltIn).unwrap();
        assert_eq!(
            ablation
                .run_names(Profile::Paper)
                .iter()
                .filter(|n| n.contains("no-gcn"))
                .count(),
            3
        );
    }

    #[test]
    fn a_baseline_s_training_curve_is_read_from_its_run_and_reported_at_its_largest_point() {
        let tmp = tempfile::tempdir().unwrap();
        let run = RunDir::create(&tmp.path().join("run")).unwrap();
        for (epoch, success) in [(1, 0.05), (3, 0.12), (5, 0.10)] {
            RunDir::append_jsonl(
                &run.validation_path(),
                &serde_json::json!({"epoch": epoch, "success": success, "goal_fraction": 0.3}),
            )
            .unwrap();
        }
        for epoch in 0..6 {
            run.append_metrics(&serde_json::json!({
                "epoch": epoch, "loss": 1.0, "seconds": 2.0,
                "program_accuracy": 0.5 + 0.08 * epoch as f64, "scope_accuracy": 0.25,
            }))
            .unwrap();
        }
        assert_eq!(
            TrainingCurve::of(&run, MethodId::NtpFlat)
                .unwrap()
                .unwrap()
                .last_accuracies
                .keys()
                .collect::<Vec<_>>(),
            ["program"]
        );
        let curve = TrainingCurve::of(&run, MethodId::Ntp).unwrap().unwrap();
        let scores: Vec<(usize, f64)> = curve
            .validation
            .iter()
            .map(|r| (r.epoch, r.score.success))
            .collect();
        assert_eq!(scores, [(1, 0.05), (3, 0.12), (5, 0.10)]);
        assert_eq!(curve.best_epoch(), 3);
        assert_eq!(curve.last_thirds(), Some((0.10, 0.12)));
        assert_eq!(curve.epochs_trained, 6);
        assert_eq!(
            curve.describe(),
            "validation success by epoch 2: 0.05, 4: 0.12, 6: 0.10; best at epoch 4; \
             mean of the last 1 scores 0.100, of the 1 before 0.120; \
             training accuracy at its last epoch (6): program 0.900, scope 0.250"
        );
        // Equal success: the one with more goals met is the better, as
        // training selects it; at the last validated epoch, the line says so.
        let mut tied = curve.clone();
        tied.validation[2].score.success = 0.12;
        tied.validation[2].score.goal_fraction = 0.4;
        assert_eq!(tied.best_epoch(), 5);
        assert!(
            tied.describe()
                .contains("best at epoch 6, the last validated;")
        );
        // No validation scores: no curve.
        let bare = RunDir::create(&tmp.path().join("bare")).unwrap();
        assert_eq!(TrainingCurve::of(&bare, MethodId::Ntp).unwrap(), None);

        // The report lists baselines at their curve's largest point only.
        let point = |method, n| NtpExpPoint {
            method,
            ablation: Variant::Full,
            recipe: Recipe::Paper,
            obs: ObsKind::Vid,
            seed: 0,
            train_tasks: n,
            demos_per_task: 100,
            epochs: 6,
            selected_epoch: None,
            permute_objects: false,
            additions: Vec::new(),
            recipe_changes: Vec::new(),
            settings: Vec::new(),
            distinction: Vec::new(),
            camera: None,
            stage_a_videos: None,
            tag: None,
            ntp_core: NtpCoreKind::Reactive,
            executed_node: false,
            success: SuccessRate::new(1, 10),
            goal_fraction: 0.5,
            untrained: None,
            train_seconds: 1.0,
            stage_times: None,
            transcription: None,
            seen: None,
            detector: None,
            decisions: None,
            curve: Some(curve.clone()),
            run: PathBuf::new(),
        };
        let points = [
            point(MethodId::Ntp, 100),
            point(MethodId::Ntp, 500),
            point(MethodId::Ntg, 500),
        ];
        let lines = baseline_curve_lines(&points);
        assert_eq!(lines.len(), 1);
        assert!(
            lines[0].starts_with(
                "NTP (Vid, 500 tasks; test 0.100): validation success by epoch 2: 0.05"
            )
        );
    }

    #[test]
    fn stage_times_come_from_the_run_files_in_the_order_the_stages_ran() {
        let dir = tempfile::tempdir().unwrap();
        let run = RunDir::open_or_create(dir.path(), &serde_json::json!({})).unwrap();
        let write = |path: &str, text: &str| {
            let path = dir.path().join(path);
            std::fs::create_dir_all(path.parent().unwrap()).unwrap();
            std::fs::write(path, text).unwrap();
        };
        write(
            "metrics.jsonl",
            "{\"epoch\":0,\"seconds\":10.0,\"cpu_seconds\":8.0}\n{\"epoch\":1,\"seconds\":12.0}\n",
        );
        write("stage_a/metrics.jsonl", "{\"epoch\":0,\"seconds\":100.0}\n");
        let times = StageTimes::of(&run).unwrap();
        let stages: Vec<(&str, usize, f64)> = times
            .stages
            .iter()
            .map(|s| (s.stage.as_str(), s.epochs, s.seconds))
            .collect();
        assert_eq!(stages, [("stage_a", 1, 100.0), ("stage B", 2, 20.0)]);
        assert_eq!(times.encoding, None);
        assert_eq!(
            times.text(),
            "stage_a 1 epochs 100 s; encoding not recorded; stage B 2 epochs 20 s"
        );
        // Two parts noted, the second without CPU time: its wall time.
        write(
            crate::video::ENCODING_TIMES,
            "{\"videos\":4096,\"frames\":9,\"seconds\":50.0,\"cpu_seconds\":40.0}\n{\"videos\":10,\"frames\":1,\"seconds\":2.0}\n",
        );
        let times = StageTimes::of(&run).unwrap();
        assert_eq!(
            times.encoding,
            Some(EncodingTime {
                videos: 4106,
                seconds: 42.0
            })
        );
        assert!(
            times
                .text()
                .contains("; encoding 4106 videos 42 s; stage B")
        );
    }

    #[test]
    fn transcription_lines_show_the_runs_that_kept_it() {
        let rate = |s, n| SuccessRate::new(s, n);
        let mut points = vec![NtpExpPoint {
            method: MethodId::Ntg,
            ablation: Variant::Full,
            recipe: Recipe::Paper,
            obs: ObsKind::State,
            seed: 1,
            train_tasks: 1000,
            demos_per_task: 100,
            epochs: 30,
            selected_epoch: None,
            permute_objects: false,
            additions: Vec::new(),
            recipe_changes: Vec::new(),
            settings: Vec::new(),
            distinction: Vec::new(),
            camera: None,
            stage_a_videos: None,
            tag: None,
            ntp_core: NtpCoreKind::Reactive,
            executed_node: false,
            success: rate(6, 10),
            goal_fraction: 0.5,
            untrained: None,
            train_seconds: 1.0,
            stage_times: None,
            transcription: Some(TranscriptionSplit {
                exact: rate(8, 10),
                success_if_exact: rate(6, 8),
                success_otherwise: rate(0, 2),
            }),
            seen: None,
            detector: None,
            decisions: None,
            curve: None,
            run: PathBuf::new(),
        }];
        points.push(NtpExpPoint {
            transcription: None,
            seen: None,
            ..points[0].clone()
        });
        assert_eq!(
            compute_lines(&points),
            ["NTG (ours) (State): 2 runs, 0.0 core-minutes"]
        );
        assert_eq!(
            transcription_lines(&points),
            [
                "NTG (ours), seed 1 (State, 1000 tasks): transcribed exactly 0.800 (8/10); success 0.750 (6/8) on those, 0.000 (0/2) on the others"
            ]
        );
    }

    #[test]
    fn the_papers_relations_are_checked_where_both_sides_were_run() {
        let point = |method, obs, n, seed, successes: usize| NtpExpPoint {
            method,
            ablation: Variant::Full,
            recipe: Recipe::Paper,
            obs,
            seed,
            train_tasks: n,
            demos_per_task: 100,
            epochs: 30,
            selected_epoch: None,
            permute_objects: false,
            additions: Vec::new(),
            recipe_changes: Vec::new(),
            settings: Vec::new(),
            distinction: Vec::new(),
            camera: None,
            stage_a_videos: None,
            tag: None,
            ntp_core: NtpCoreKind::Reactive,
            executed_node: false,
            success: SuccessRate::from_outcomes((0..200).map(|i| i < successes)),
            goal_fraction: 0.5,
            untrained: None,
            train_seconds: 1.0,
            stage_times: None,
            transcription: None,
            seen: None,
            detector: None,
            decisions: None,
            curve: None,
            run: PathBuf::new(),
        };
        let (state, vid) = (ObsKind::State, ObsKind::Vid);
        let points = vec![
            point(MethodId::Ntg, state, 50, 0, 10),
            point(MethodId::Ntg, state, 100, 0, 120),
            point(MethodId::Ntg, state, 100, 1, 0),
            point(MethodId::Ntp, state, 50, 0, 40),
            point(MethodId::Ntp, state, 100, 0, 100),
            point(MethodId::NtpFlat, state, 50, 0, 2),
            point(MethodId::NtpFlat, state, 100, 0, 100),
            point(MethodId::Ntp, vid, 100, 0, 20),
        ];
        let lines = trend_checks(&points);
        let line = |start: &str| {
            lines
                .iter()
                .find(|l| l.starts_with(start))
                .unwrap_or_else(|| panic!("{start}: {lines:?}"))
                .clone()
        };
        assert_eq!(
            line("NTP (Vid) clearly below"),
            "NTP (Vid) clearly below NTP (State): **holds**; holds at 100 tasks: NTP (State) 0.500 vs NTP (Vid) 0.100."
        );
        // From 100 tasks on only, over both seeds (seed 1 scored 0: seed
        // 0's 0.6 alone would not be clearly above 0.5 either).
        assert_eq!(
            line("NTG above NTP from 100"),
            "NTG above NTP from 100 tasks on (State input): **does not hold**; does not hold at 100 tasks: NTG (ours) (State) 0.300 (mean of 2 seeds: 0.600, 0.000) vs NTP (State) 0.500."
        );
        // Several seeds each, every interval of one side above the other's.
        let seeds = |method, successes: [usize; 2]| {
            [0, 1].map(|seed| point(method, state, 1000, seed, successes[seed as usize]))
        };
        let mut apart = seeds(MethodId::Ntg, [160, 180]).to_vec();
        apart.extend(seeds(MethodId::Ntp, [100, 120]));
        assert!(trend_checks(&apart)[0].contains("**holds**"), "{apart:?}");
        apart[0] = point(MethodId::Ntg, state, 1000, 0, 125);
        assert!(trend_checks(&apart)[0].contains("**does not hold**"));
        assert_eq!(
            line("NTP Flat below NTP (State"),
            "NTP Flat below NTP (State input): **holds in part**; \
             holds at 50 tasks: NTP (State) 0.200 vs NTP Flat (State) 0.010; \
             does not hold at 100 tasks: NTP (State) 0.500 vs NTP Flat (State) 0.500."
        );
        // No NTG on video: that relation is left out.
        assert!(!lines.iter().any(|l| l.starts_with("NTG (Vid)")));
        // No baseline with the recommended recipe: no such line.
        assert!(!lines.iter().any(|l| l.contains("recommended recipe")));
        // With it, NTG is judged against the baseline of the same recipe
        // only, not against the paper-recipe one.
        let recommended = |method, successes| NtpExpPoint {
            recipe: Recipe::Recommended,
            permute_objects: true,
            additions: Vec::new(),
            recipe_changes: Vec::new(),
            settings: Vec::new(),
            distinction: Vec::new(),
            camera: None,
            stage_a_videos: None,
            tag: None,
            ..point(method, state, 1000, 0, successes)
        };
        let mut both = points.clone();
        both.extend([
            recommended(MethodId::Ntg, 190),
            recommended(MethodId::Ntp, 150),
            point(MethodId::Ntp, state, 1000, 0, 195),
        ]);
        let lines = trend_checks(&both);
        let expected = "Not in the paper: NTG above NTP with the recommended recipe on both sides \
                        (State input): **holds**; holds at 1000 tasks: NTG (ours) (State) 0.950 vs NTP (State) 0.750.";
        assert!(lines.contains(&expected.to_owned()), "{lines:?}");
        assert!(
            !lines
                .iter()
                .any(|l| l.contains("NTP Flat with the recommended"))
        );
        // Another camera and another core network are protocols of their
        // own: checked apart, never combined with the standard points as
        // if they were more seeds.
        let mut protocols = points.clone();
        protocols.extend([
            NtpExpPoint {
                camera: Some(128),
                stage_a_videos: None,
                tag: None,
                ..point(MethodId::Ntp, vid, 100, 0, 60)
            },
            NtpExpPoint {
                camera: Some(128),
                stage_a_videos: None,
                tag: None,
                ntp_core: NtpCoreKind::Gru,
                ..point(MethodId::Ntp, vid, 100, 0, 190)
            },
            NtpExpPoint {
                camera: Some(128),
                stage_a_videos: None,
                tag: None,
                ..point(MethodId::Ntg, vid, 100, 0, 150)
            },
        ]);
        let lines = trend_checks(&protocols);
        let has = |expected: &str| {
            assert!(
                lines.contains(&expected.to_owned()),
                "{expected}\n{lines:#?}"
            );
        };
        has(
            "NTP (Vid) clearly below NTP (State): **holds**; holds at 100 tasks: NTP (State) 0.500 vs NTP (Vid) 0.100.",
        );
        has(
            "NTP (Vid, 128×128) clearly below NTP (State): **holds**; holds at 100 tasks: NTP (State) 0.500 vs NTP (Vid, 128×128) 0.300.",
        );
        has(
            "NTP, GRU core (Vid, 128×128) clearly below NTP (State): **does not hold**; does not hold at 100 tasks: NTP (State) 0.500 vs NTP, GRU core (Vid, 128×128) 0.950.",
        );
        has(
            "NTG (Vid, 128×128) on par with NTP (State) or above: **holds**; holds at 100 tasks: NTG (ours) (Vid, 128×128) 0.750 vs NTP (State) 0.500.",
        );
        has(
            "NTG above NTP from 100 tasks on (Vid, 128×128 input): **holds**; holds at 100 tasks: NTG (ours) (Vid, 128×128) 0.750 vs NTP (Vid, 128×128) 0.300.",
        );
        has(
            "NTG above NTP, GRU core from 100 tasks on (Vid, 128×128 input): **does not hold**; does not hold at 100 tasks: NTG (ours) (Vid, 128×128) 0.750 vs NTP, GRU core (Vid, 128×128) 0.950.",
        );
        // The standard camera's video has no NTG: no such line for it.
        assert!(
            !lines.iter().any(|l| l.starts_with("NTG (Vid)")),
            "{lines:#?}"
        );
        assert!(
            !lines
                .iter()
                .any(|l| l.contains("(Vid input)") && l.contains("GRU"))
        );
    }

    #[test]
    fn seeds_of_a_point_are_combined_in_the_figure_and_the_report() {
        let point = |seed: u64, successes: usize| NtpExpPoint {
            method: MethodId::Ntg,
            ablation: Variant::Full,
            recipe: Recipe::Paper,
            obs: ObsKind::State,
            seed,
            train_tasks: 1000,
            demos_per_task: 10,
            epochs: 6,
            selected_epoch: None,
            permute_objects: false,
            additions: Vec::new(),
            recipe_changes: Vec::new(),
            settings: Vec::new(),
            distinction: Vec::new(),
            camera: None,
            stage_a_videos: None,
            tag: None,
            ntp_core: NtpCoreKind::Reactive,
            executed_node: false,
            success: SuccessRate::from_outcomes((0..100).map(|i| i < successes)),
            goal_fraction: 0.5,
            untrained: None,
            train_seconds: 1.0,
            stage_times: None,
            transcription: None,
            seen: None,
            detector: None,
            decisions: None,
            curve: None,
            run: PathBuf::from(format!("run{seed}")),
        };
        let points = vec![point(0, 20), point(1, 40), point(2, 30)];
        let groups = by_point(points.iter());
        assert_eq!(groups.len(), 1);
        let p = groups[0].success_point();
        assert!((p.y - 0.3).abs() < 1e-12);
        assert_eq!(
            (p.lo, p.hi),
            (points[0].success.ci_low, points[1].success.ci_high)
        );
        let spread = seed_spread(&points);
        assert_eq!(
            spread,
            vec!["NTG (ours) (State, 1000 tasks): success 0.300 on average over seeds 0, 1, 2 (from 0.200 to 0.400)".to_owned()]
        );
        // A seed of another camera is a curve of its own, not a fourth seed.
        let mut cameras = points.clone();
        cameras.push(NtpExpPoint {
            obs: ObsKind::Vid,
            camera: Some(128),
            stage_a_videos: None,
            tag: None,
            ..point(1, 90)
        });
        cameras.iter_mut().for_each(|p| {
            p.obs = ObsKind::Vid;
            p.camera = p.camera.or(Some(64));
        });
        assert_eq!(
            seed_spread(&cameras),
            vec!["NTG (ours) (Vid, 1000 tasks): success 0.300 on average over seeds 0, 1, 2 (from 0.200 to 0.400)".to_owned()]
        );
        // A run trained before its recipe changed is a curve of its own,
        // named by the change, and stays out of the paper's relations; so
        // is another panel's (its tag) for the seeds.
        let mut tagged = points.clone();
        tagged.push(NtpExpPoint {
            tag: Some("nodetach".into()),
            ..point(0, 90)
        });
        assert_eq!(seed_spread(&tagged), spread);
        tagged[3].recipe_changes = vec!["GCN detached from the edge loss".into()];
        assert_eq!(
            row_name(&tagged[3]),
            "NTG (ours), GCN detached from the edge loss"
        );
        let ntp = NtpExpPoint {
            method: MethodId::Ntp,
            ..point(0, 10)
        };
        let untagged = [points.clone(), vec![ntp.clone()]].concat();
        tagged.push(ntp);
        let relations = trend_checks(&untagged);
        assert!(
            relations.iter().any(|l| l.contains("0.300")),
            "{relations:?}"
        );
        assert_eq!(trend_checks(&tagged), relations);
        // Two panels of one method and input that trained differently are
        // named apart by what differs; a curve alone keeps its name.
        let mut apart = points.clone();
        let setting = |lr: &str| {
            vec![(
                "optim.learning_rate".to_owned(),
                format!("learning rate {lr}"),
            )]
        };
        apart.iter_mut().for_each(|p| p.settings = setting("0.003"));
        apart.push(NtpExpPoint {
            tag: Some("lr1".into()),
            settings: setting("0.001"),
            ..point(0, 90)
        });
        name_apart(&mut apart);
        assert_eq!(row_name(&apart[0]), "NTG (ours), learning rate 0.003");
        assert_eq!(row_name(&apart[3]), "NTG (ours), learning rate 0.001");
        let mut alone = points.clone();
        name_apart(&mut alone);
        assert_eq!(row_name(&alone[0]), "NTG (ours)");
        // The `<end>` rule is in the name of a curve alone too.
        let mut ends = points.clone();
        ends.iter_mut()
            .for_each(|p| p.additions = vec![END_AFTER_DEMO.into()]);
        name_apart(&mut ends);
        assert_eq!(
            row_name(&ends[0]),
            "NTG (ours), ends only after the demo's actions"
        );
        // Two panels that differ in no named setting: the tag names them.
        apart[3].settings = setting("0.003");
        name_apart(&mut apart);
        assert_eq!(row_name(&apart[3]), "NTG (ours), panel lr1");
        // Two video panels (tags) of one camera are two protocols: the
        // relations pair NTG with the baselines of its own panel, and name
        // the protocol by what tells its NTG apart.
        let vid = |method: MethodId, tag: &str, lr: &str, successes: usize| {
            let mut p = NtpExpPoint {
                method,
                obs: ObsKind::Vid,
                camera: Some(128),
                tag: Some(tag.into()),
                settings: setting(lr),
                ..point(0, successes)
            };
            p.run = PathBuf::from(format!("{tag}-{}", method.legend()));
            p
        };
        let mut protocols = vec![
            vid(MethodId::Ntg, "old", "0.003", 30),
            vid(MethodId::Ntg, "new", "0.001", 90),
            vid(MethodId::Ntp, "new", "0.001", 10),
        ];
        name_apart(&mut protocols);
        let relations = trend_checks(&protocols);
        let line = relations
            .iter()
            .find(|l| l.starts_with("NTG above NTP from 100 tasks on"))
            .unwrap_or_else(|| panic!("{relations:?}"));
        assert!(
            line.contains("(Vid, 128×128, learning rate 0.001 input)"),
            "{line}"
        );
        assert!(line.contains("0.900 vs"), "{line}");
        assert!(!line.contains("mean of"), "{line}");
        // A panel per camera and number of stage A videos, named in its
        // title; its curves are named by method and recipe alone.
        let mut perception = protocols.clone();
        perception[0].stage_a_videos = Some(5000);
        perception[1].stage_a_videos = Some(20000);
        perception[2].stage_a_videos = Some(20000);
        perception.push(point(0, 50));
        // The detector, which has no stage A, joins its tag's panel.
        perception.push(vid(MethodId::NtpDetector, "old", "0.003", 20));
        let (panels, goals) = figure_panels(&perception);
        let titles: Vec<&str> = panels.iter().map(|p| p.title.as_str()).collect();
        assert_eq!(
            titles,
            [
                "(a) state input",
                "(b) video input, 128×128 frames, stage A on up to 5000 videos",
                "(c) video input, 128×128 frames, stage A on up to 20000 videos",
            ]
        );
        assert_eq!(goals.len(), 3);
        let names: Vec<&str> = panels[2].series.iter().map(|s| s.name.as_str()).collect();
        assert_eq!(names, ["NTG (ours), learning rate 0.001", "NTP"]);
        assert_eq!(panels[1].series.len(), 2, "NTG and the detector of tag old");
        let report = report_section(&points, "");
        assert!(report.contains("| NTG (ours), seed 1 |"), "{report}");
        assert!(report.contains("**Over seeds.**"), "{report}");
        // One seed: its own interval.
        let one = by_point(points[..1].iter());
        assert_eq!(
            one[0].success_point(),
            Point::success(1000.0, &points[0].success)
        );
    }

    #[test]
    fn another_figure_s_run_of_the_same_configuration_is_reused() {
        let dir = tempfile::tempdir().unwrap();
        let mut experiment = NtpExpExperiment::load(crate::experiment::Source::BuiltIn).unwrap();
        let smoke = &mut experiment.profiles.smoke;
        smoke.panels.truncate(1);
        let panel = &mut smoke.panels[0];
        panel.methods = Some(vec![MethodId::Ntg]);
        panel.train_tasks = vec![2];
        panel.epochs = 1;
        panel.test_tasks = 2;
        let runs = dir.path().join("runs");
        let first = run(&experiment, Profile::Smoke, &Plan::train_all(&runs, 1)).unwrap();
        std::fs::write(first[0].run.join("marker"), "trained here").unwrap();
        let mut other = experiment.clone();
        other.name = "other".into();
        let second = run(&other, Profile::Smoke, &Plan::train_all(&runs, 1)).unwrap();
        assert!(second[0].run.ends_with("other-state-2"));
        assert_eq!(
            std::fs::read_to_string(second[0].run.join("marker")).unwrap(),
            "trained here",
            "the finished folder is linked, not trained again"
        );
        assert_eq!(second[0].success, first[0].success);
        // Another configuration is trained in its own folder.
        other.name = "third".into();
        other.profiles.smoke.panels[0].epochs = 2;
        let third = run(&other, Profile::Smoke, &Plan::train_all(&runs, 1)).unwrap();
        assert!(!third[0].run.join("marker").exists());
    }

    /// On video, NTP reuses the NTG run's stage A of the same point
    /// (linked, not trained again) and trains over its embeddings.
    #[test]
    fn video_baselines_share_the_point_s_frame_encoder() {
        let dir = tempfile::tempdir().unwrap();
        let mut experiment = NtpExpExperiment::load(crate::experiment::Source::BuiltIn).unwrap();
        let smoke = &mut experiment.profiles.smoke;
        smoke.panels.remove(0);
        let panel = &mut smoke.panels[0];
        panel.methods = Some(vec![MethodId::Ntg, MethodId::Ntp, MethodId::NtpFlat]);
        panel.train_tasks = vec![2];
        panel.test_tasks = 1;
        let runs = dir.path().join("runs");
        // Two jobs: NTP Flat still starts after NTP has encoded its
        // episodes (the point's first baseline is a wave of its own).
        let points = run(&experiment, Profile::Smoke, &Plan::train_all(&runs, 2)).unwrap();
        assert_eq!(points.len(), 3);
        // NTP Flat reads NTP's encoded episodes (linked), on the same
        // stage A.
        let cached =
            |p: &NtpExpPoint, file: &str| p.run.join(crate::method::ntp::NTP_FRAMES_DIR).join(file);
        let episodes = |p: &NtpExpPoint| std::fs::read(cached(p, "episodes.json")).unwrap();
        assert!(points[2].run.ends_with("ntp_exp-vid-ntp-flat-2"));
        assert_eq!(episodes(&points[1]), episodes(&points[2]));
        #[cfg(unix)]
        {
            use std::os::unix::fs::MetadataExt;
            let inode = |p: &NtpExpPoint| std::fs::metadata(cached(p, "rows.bin")).unwrap().ino();
            assert_eq!(
                inode(&points[1]),
                inode(&points[2]),
                "linked, not encoded again"
            );
        }
        assert!(
            !points[0]
                .run
                .join(crate::method::ntp::NTP_FRAMES_DIR)
                .exists()
        );
        let stage = |p: &NtpExpPoint| p.run.join(crate::video::STAGE_A_DIR);
        let weights =
            |p: &NtpExpPoint| std::fs::read(stage(p).join("checkpoint/model.bpk")).unwrap();
        assert_eq!(weights(&points[0]), weights(&points[1]));
        assert_eq!(weights(&points[0]), weights(&points[2]));
        let metrics =
            |p: &NtpExpPoint| std::fs::read_to_string(stage(p).join("metrics.jsonl")).unwrap();
        assert_eq!(metrics(&points[0]), metrics(&points[1]), "trained once");
        assert!(points[1].run.ends_with("ntp_exp-vid-ntp-2"));
        assert_eq!(points[1].success.trials, 1);
        // NTG's point run on its own after its baselines (`--only`): it
        // links their finished stage A instead of training it again.
        std::fs::remove_dir_all(&points[0].run).unwrap();
        let only = ["ntp_exp-vid-2".to_owned()];
        let again = run(
            &experiment,
            Profile::Smoke,
            &Plan {
                only: Some(&only),
                ..Plan::train_all(&runs, 1)
            },
        )
        .unwrap();
        assert_eq!(again.len(), 1);
        assert_eq!(weights(&again[0]), weights(&points[1]));
        #[cfg(unix)]
        {
            use std::os::unix::fs::MetadataExt;
            let inode = |p: &NtpExpPoint| {
                std::fs::metadata(stage(p).join("metrics.jsonl"))
                    .unwrap()
                    .ino()
            };
            assert_eq!(
                inode(&again[0]),
                inode(&points[1]),
                "linked, not trained again"
            );
        }
        assert_eq!(again[0].success.trials, 1);
        // A panel of the same point with the GRU core: its NTP run links
        // the reactive runs' stage A and encoded episodes (the core is read
        // by neither), and is a curve of its own.
        let mut gru = experiment.clone();
        let panel = &mut gru.profiles.smoke.panels[0];
        panel.methods = Some(vec![MethodId::Ntp]);
        panel
            .overrides
            .insert("ntp_core".into(), toml::Value::String("gru".into()));
        let gru_points = run(&gru, Profile::Smoke, &Plan::train_all(&runs, 1)).unwrap();
        assert_eq!(gru_points.len(), 1);
        let gru_point = &gru_points[0];
        assert!(gru_point.run.ends_with("ntp_exp-vid-ntp-gru-2"));
        assert_eq!(gru_point.ntp_core, NtpCoreKind::Gru);
        assert_ne!(gru_point.curve_id(), points[1].curve_id());
        assert_eq!(weights(gru_point), weights(&points[1]));
        assert_eq!(
            metrics(gru_point),
            metrics(&points[1]),
            "stage A trained once"
        );
        assert_eq!(episodes(gru_point), episodes(&points[1]));
        #[cfg(unix)]
        {
            use std::os::unix::fs::MetadataExt;
            let inode = |p: &NtpExpPoint| std::fs::metadata(cached(p, "rows.bin")).unwrap().ino();
            assert_eq!(
                inode(gru_point),
                inode(&points[1]),
                "linked, not encoded again"
            );
        }
    }

    /// NTG's run of a panel with the other node source links the point's
    /// stage A and stage B's embeddings (neither reads the node source)
    /// and trains its own policy.
    #[test]
    fn ntg_of_the_other_node_source_links_stage_a_and_the_embeddings() {
        let dir = tempfile::tempdir().unwrap();
        let mut experiment = NtpExpExperiment::load(crate::experiment::Source::BuiltIn).unwrap();
        let smoke = &mut experiment.profiles.smoke;
        smoke.panels.remove(0);
        let panel = &mut smoke.panels[0];
        panel.methods = Some(vec![MethodId::Ntg]);
        panel.train_tasks = vec![2];
        panel.test_tasks = 1;
        let runs = dir.path().join("runs");
        let first = run(&experiment, Profile::Smoke, &Plan::train_all(&runs, 1)).unwrap();
        assert!(first[0].run.ends_with("ntp_exp-vid-2"));
        assert!(!first[0].executed_node);
        let mut executed = experiment.clone();
        let panel = &mut executed.profiles.smoke.panels[0];
        panel
            .overrides
            .entry("video")
            .or_insert_with(|| toml::Value::Table(Default::default()))
            .as_table_mut()
            .unwrap()
            .insert("executed_node".into(), toml::Value::Boolean(true));
        let second = run(&executed, Profile::Smoke, &Plan::train_all(&runs, 1)).unwrap();
        assert!(second[0].run.ends_with("ntp_exp-vid-executed-2"));
        assert!(second[0].executed_node);
        #[cfg(unix)]
        {
            use std::os::unix::fs::MetadataExt;
            let inode =
                |p: &NtpExpPoint, file: &str| std::fs::metadata(p.run.join(file)).unwrap().ino();
            for file in [
                "stage_a/metrics.jsonl",
                "embeddings/index.json",
                "embeddings/observations.bin",
            ] {
                assert_eq!(
                    inode(&second[0], file),
                    inode(&first[0], file),
                    "{file}: linked, not computed again"
                );
            }
            assert_ne!(
                inode(&second[0], "checkpoint/model.bpk"),
                inode(&first[0], "checkpoint/model.bpk"),
                "the policy is trained in its own folder"
            );
        }
    }

    /// NTP (Detector) trains its detector, then NTP on states, in one run
    /// folder, and is scored on frames.
    #[test]
    fn an_ntp_detector_point_trains_its_detector_then_ntp_and_acts_on_frames() {
        let dir = tempfile::tempdir().unwrap();
        let mut experiment = NtpExpExperiment::load(crate::experiment::Source::BuiltIn).unwrap();
        let smoke = &mut experiment.profiles.smoke;
        smoke.panels.remove(0);
        let panel = &mut smoke.panels[0];
        assert_eq!(panel.obs, ObsKind::Vid);
        assert!(
            panel
                .methods
                .clone()
                .unwrap_or_default()
                .contains(&MethodId::NtpDetector)
        );
        panel.methods = Some(vec![MethodId::NtpDetector]);
        panel.train_tasks = vec![2];
        panel.test_tasks = 2;
        let runs = dir.path().join("runs");
        let points = run(&experiment, Profile::Smoke, &Plan::train_all(&runs, 1)).unwrap();
        let p = &points[0];
        assert_eq!(
            (p.method, p.obs, p.train_tasks, p.success.trials),
            (MethodId::NtpDetector, ObsKind::Vid, 2, 2)
        );
        assert!(p.run.ends_with("ntp_exp-vid-ntp-detector-2"));
        let config: BlocksRunConfig = RunDir::read_json(&p.run.join("config.json")).unwrap();
        assert_eq!(config.video, None);
        let detector = config.detector.expect("detector settings");
        assert_eq!((detector.episodes, detector.epochs), (10, 1));
        // The detector's stage: its own metrics and held-out score; its
        // seconds count in the point's compute (compared as compute, CPU
        // seconds where recorded: wall seconds exceed them whenever other
        // processes share the cores, and then the stage's wall alone could
        // exceed the point's compute).
        let stage = p.run.join(crate::method::detector::DETECTOR_STAGE_DIR);
        let held_out: crate::method::detector::DetectorHeldOut =
            RunDir::read_json(&stage.join("held_out.json")).unwrap();
        assert!(held_out.detector.frames > 0 && held_out.detector.position_error.is_finite());
        // The report gives its error in cube edges too.
        let edges = held_out.detector.position_error / f64::from(env_blocks::world::CUBE_SIZE);
        let lines = detector_lines(&points);
        assert!(
            lines[0].contains(&format!("({edges:.2} cube edges)")),
            "{lines:?}"
        );
        let stage_seconds = RunDir::open(&stage)
            .unwrap()
            .epoch_compute_seconds()
            .unwrap();
        // At least the stage's: NTP's one epoch of two demos may record
        // no CPU time of its own on a loaded machine.
        assert!(
            stage_seconds > 0.0 && p.train_seconds >= stage_seconds,
            "stage {stage_seconds} s, point {} s",
            p.train_seconds
        );
        // The saved model is NTP with its detector; it loads by method.
        let model = MethodId::NtpDetector
            .load(&p.run.join("checkpoint"), &crate::spec::device())
            .unwrap();
        assert!(
            model
                .as_any()
                .downcast_ref::<crate::method::ntp_detector::NtpOnDetector>()
                .is_some()
        );
        assert_eq!(
            run(&experiment, Profile::Smoke, &Plan::train_all(&runs, 1)).unwrap(),
            points
        );
    }

    #[test]
    fn the_built_in_file_gives_the_configurations_the_figure_was_measured_with() {
        let experiment = NtpExpExperiment::load(crate::experiment::Source::BuiltIn).unwrap();
        let quick = experiment.profiles.get(Profile::Quick);
        // The configurations the figure's committed results were measured
        // with.
        let expected = |n: usize, epochs: usize, validation_tasks, cosine_decay| BlocksRunConfig {
            obs: ObsKind::State,
            train_tasks: n,
            demos_per_task: 10,
            failures: true,
            model_seed: 0,
            state_hidden_layers: 3,
            pairwise: true,
            validation_tasks,
            validate_every: epochs.div_ceil(16),
            permute_objects: false,
            exclude_held_out_renamings: false,
            edge_fusion_hidden: 0,
            retry_weight: 0.0,
            detach_gcn_from_edges: false,
            soft_edges: false,
            ablation: Variant::Full,
            video: None,
            method: crate::method::MethodId::Ntg,
            detector: None,
            ntp_core: crate::blocks::NtpCoreKind::Reactive,
            tasks: None,
            structure_benchmark: false,
            executed_node: false,
            state_height_clamp: None,
            memory: false,
            end_after_demo: false,
            interpreter: None,
            location_step_prior: None,
            optim: crate::fit::OptimConfig {
                epochs,
                batch_size: 32,
                learning_rate: 3e-3,
                seed: 0,
                token_dropout: 0.0,
                cosine_decay,
                shards: 0, // unset in the file: one thread, as measured
                gcn_from_other_demo: false,
            },
        };
        // NTP with the paper's recipe at 1000 tasks (about 1900 steps).
        let state = &quick.panels[2];
        let mut ntp_1000 = expected(1000, 6, 50, false);
        ntp_1000.method = MethodId::Ntp;
        assert_eq!(
            experiment
                .run_config(Profile::Quick, state, (MethodId::Ntp, Variant::Full), 1000)
                .unwrap(),
            ntp_1000
        );
        // NTG (and NTP) with the recommended recipe at 1000 tasks, and NTG
        // at 50 tasks with as many steps (1875: 118 epochs of 16 steps).
        let recommended = &quick.panels[1];
        let c = experiment
            .run_config(
                Profile::Quick,
                recommended,
                (MethodId::Ntg, Variant::Full),
                1000,
            )
            .unwrap();
        assert_eq!(
            (c.obs, c.demos_per_task, c.optim.epochs, c.permute_objects),
            (ObsKind::State, 10, 6, true)
        );
        let small = &quick.panels[3];
        let c = experiment
            .run_config(Profile::Quick, small, (MethodId::Ntg, Variant::Full), 50)
            .unwrap();
        assert_eq!(
            (c.obs, c.optim.epochs, c.permute_objects, c.validation_tasks),
            (ObsKind::State, 118, true, 50)
        );
        let quick_ntg_1000 = |panel| {
            experiment
                .run_config(Profile::Quick, panel, (MethodId::Ntg, Variant::Full), 1000)
                .unwrap()
        };
        let paper = &experiment.profiles.get(Profile::Paper).panels[0];
        let c = experiment
            .run_config(Profile::Paper, paper, (MethodId::Ntg, Variant::Full), 50)
            .unwrap();
        assert_eq!((c.validation_tasks, c.optim.cosine_decay), (100, true));
        let smoke = &experiment.profiles.get(Profile::Smoke).panels[1];
        let c = experiment
            .run_config(Profile::Smoke, smoke, (MethodId::Ntg, Variant::Full), 5)
            .unwrap();
        assert_eq!(
            (c.obs, c.validation_tasks, c.optim.epochs),
            (ObsKind::Vid, 0, 1)
        );
        // The video panel's own overrides reach its encoder stage only.
        let encoder = &c.video.as_ref().unwrap().encoder;
        assert_eq!((encoder.demos, encoder.epochs), (10, 1));
        assert_eq!(
            experiment.run_name(smoke, (MethodId::Ntp, Variant::Full), 5),
            "ntp_exp-vid-ntp-5"
        );
        // NTG with the recommended recipe on video: its own panel, folder
        // and configuration (the recipe's, at the panel's scale).
        let recommended = &quick.panels[0];
        assert_eq!(experiment.recipe_of(recommended), Recipe::Recommended);
        assert_eq!(
            experiment.run_name(recommended, (MethodId::Ntg, Variant::Full), 1000),
            "ntp_exp-vid-recommended-1000"
        );
        let c = quick_ntg_1000(recommended);
        // 4 demos per task, chosen on validation tasks.
        let mut expected = Recipe::Recommended.config(ObsKind::Vid, 1000, 4, 10, 0);
        expected.state_hidden_layers = 3;
        expected.pairwise = true;
        expected.validation_tasks = 50;
        expected.validate_every = 1;
        expected.optim.shards = 0; // unset in the file: one thread
        let video = expected.video.as_mut().unwrap();
        video.encoder.demos = 2000; // each task's first two videos
        video.encoder.epochs = 5; // chosen on validation tasks
        // The paper profile's perception: 128x128 frames, a 16-channel stem.
        video.camera.size = 128;
        video.encoder.stem = 16;
        assert_eq!(c, expected);
    }
}
