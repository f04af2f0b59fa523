//! Neural Task Programming (NTP) and NTP Flat, the block-stacking
//! figure's baselines (`docs/BASELINES.md`), as training
//! methods: the network is [`ntg_model::NtpNet`], its program stack
//! [`ntg_model::ProgramStack`], its training signal the expert's
//! primitive-level episodes with NTP's call trees
//! ([`env_blocks::record_ntp_demo`]).
//!
//! Our choices, where the paper and NTP's authors leave them open:
//! - **Specification demo**: each training episode is imitated conditioned
//!   on *another* demo of its task (as for the Flat Policy and NTG's GCN),
//!   so the network cannot find its own observations in the demo; a task
//!   with a single demo (the quick figure's video panel) is imitated
//!   conditioned on that demo itself, as NTG then is. NTP
//!   reads the demo at its own action level: one row per primitive (the
//!   observation before it) and the last observation.
//! - **Scopes across two demos**: a `pick_place` of the imitated episode
//!   reads the spec's `pick_place` that moves the same cube onto the same
//!   target (the k-th such call for the k-th, the last one when the spec has
//!   fewer), its `pick` the spec call's last `pick`, its `place` the
//!   spec's `place`. A call with no counterpart in the spec (a cube only
//!   this episode had to clear) gets no scope target and reads its
//!   caller's scope.
//! - **NTP Flat**: the same network and demos; the root calls the
//!   primitives directly and nothing has a scope.
//! - **Step limit**: 80 primitives, as NTG's 40 flat actions (a flat
//!   action is at most two primitives).

use std::collections::BTreeMap;
use std::path::Path;

use anyhow::Context;
use burn::module::Module;
use burn::tensor::Device;
use ctg_graph::{ActionId, Vocabulary};
use env_blocks::world::{NUM_OBJECTS, Target};
use env_blocks::{BlocksTask, EnvConfig, NtpCall, NtpProgram, StackTask};
use ntg_model::{
    ConditionedNtp, EdgeCounts, NtpConfig, NtpDecisionCheck, NtpExample, NtpNet, ProgramCall,
    ProgramStack, StackStep,
};
use rand::seq::IndexedRandom;
use serde::{Deserialize, Serialize};

use crate::evaluate::in_parallel;
use crate::fit::ValidationScore;
use crate::fit::{StepContext, StepReport, TrainStep, TrainedModel};
use crate::method::input::{EpochLog, Validation, fit_model};
use crate::method::{Agent, EpochReport, Model, TrainInput, TrainedPolicy};
use crate::run_dir::RunDir;
use crate::spec::ObsKind;
use crate::symmetry::{ObjectSymmetry, RenamingFilter};

/// Programs the stack may nest: root, `pick_place`, `pick`/`place`.
const MAX_DEPTH: usize = 3;

/// Which NTP is trained: the hierarchy with scopes, or the root calling
/// primitives.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum NtpKind {
    /// NTP with its program hierarchy and scopes.
    Hierarchical,
    /// NTP Flat: the lowest level only.
    Flat,
}

/// The argument index of a `move` target: cubes first, then bins.
pub fn argument_index(target: Target) -> usize {
    match target {
        Target::Object(i) => i,
        Target::Bin(b) => NUM_OBJECTS + b,
    }
}

/// The `move` target of argument index `index` (see [`argument_index`]).
pub fn argument_target(index: usize) -> Target {
    if index < NUM_OBJECTS {
        Target::Object(index)
    } else {
        Target::Bin(index - NUM_OBJECTS)
    }
}

/// NTP's network for block stacking on `encoder`'s observations: its 7
/// programs and a `move` argument per cube; on state rows (`objects`) the
/// argument is also read off the demo's cube positions (see
/// [`NtpConfig::object_arguments`]).
/// With `core` [`NtpCoreKind::Gru`], its core is the recurrent variant
/// ([`NtpConfig::recurrent_core`]).
pub fn ntp_config(
    encoder: ntg_model::EncoderConfig,
    objects: bool,
    core: NtpCoreKind,
    seed: u64,
) -> NtpConfig {
    NtpConfig::new(NtpProgram::ALL.len(), NUM_OBJECTS, encoder)
        .with_object_arguments(objects.then_some(NUM_OBJECTS))
        .with_recurrent_core((core == NtpCoreKind::Gru).then_some(true))
        .with_seed(seed)
}

/// The core network of NTP, NTP Flat and NTP (Detector) (`--ntp-core`).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "kebab-case")]
pub enum NtpCoreKind {
    /// Feed-forward: each decision reads the current observation, the
    /// program and its scope of the demo only (the design's default).
    #[default]
    Reactive,
    /// Recurrent: a GRU state carried through each program call's
    /// decisions, so a program knows what it has done in this call (the
    /// original NTP's variant, `docs/BASELINES.md`).
    Gru,
}

impl NtpCoreKind {
    /// Whether this is the reactive default.
    pub fn is_reactive(&self) -> bool {
        *self == NtpCoreKind::Reactive
    }

    /// The value's name in a run configuration (`ntp_core`) and on the
    /// command line (`--ntp-core`).
    pub fn name(&self) -> &'static str {
        match self {
            NtpCoreKind::Reactive => "reactive",
            NtpCoreKind::Gru => "gru",
        }
    }

    /// What a figure's legend adds to the method's name: nothing for the
    /// reactive default.
    pub fn legend_suffix(&self) -> &'static str {
        match self {
            NtpCoreKind::Reactive => "",
            NtpCoreKind::Gru => ", GRU core",
        }
    }
}

/// One training episode: its task (index into the run's tasks), its
/// observation rows (before each primitive, and the last) and its call
/// tree.
#[derive(Debug, Clone)]
pub struct NtpEpisode {
    /// Index of its task.
    pub task: usize,
    /// Observation rows, one more than primitives.
    pub rows: Vec<Vec<f32>>,
    /// NTP's call tree of the episode.
    pub trace: NtpCall,
}

/// The training episodes of an NTP run.
#[derive(Debug, Clone)]
pub struct NtpDataset {
    episodes: Vec<NtpEpisode>,
    by_task: BTreeMap<usize, Vec<usize>>,
}

impl NtpDataset {
    /// Records `demos_per_task` expert episodes of each of `tasks` at the
    /// primitive level in parallel (episode `j` of task `t` with seed
    /// `seed_base + 1000 t + j`, as NTG's demos), featurised by `featurize`.
    pub fn record(
        tasks: &[StackTask],
        demos_per_task: usize,
        seed_base: u64,
        env: EnvConfig,
        featurize: impl Fn(&env_blocks::BlocksObservation) -> Vec<f32> + Sync + Send,
    ) -> anyhow::Result<Self> {
        let pairs = Self::pairs(tasks.len(), demos_per_task, seed_base);
        let episodes = in_parallel(&pairs, "NTP demos", |_, &(t, seed)| {
            let task = BlocksTask::Stack(tasks[t].clone());
            let demo = env_blocks::record_ntp_demo(&task, env, seed)
                .with_context(|| format!("NTP demo of task {} (seed {seed})", tasks[t].id))?;
            Ok(NtpEpisode {
                task: t,
                rows: demo.observations.iter().map(&featurize).collect(),
                trace: demo.root,
            })
        })?;
        Ok(Self::new(episodes))
    }

    /// The (task index, seed) of each of `demos_per_task` episodes of
    /// `tasks` tasks that [`Self::record`] records: episode `j` of task
    /// `t` has seed `seed_base + 1000 t + j`.
    pub fn pairs(tasks: usize, demos_per_task: usize, seed_base: u64) -> Vec<(usize, u64)> {
        (0..tasks)
            .flat_map(|t| {
                (0..demos_per_task).map(move |j| (t, seed_base + 1000 * t as u64 + j as u64))
            })
            .collect()
    }

    /// A dataset of `episodes`.
    pub fn new(episodes: Vec<NtpEpisode>) -> Self {
        let mut by_task: BTreeMap<usize, Vec<usize>> = BTreeMap::new();
        for (i, e) in episodes.iter().enumerate() {
            by_task.entry(e.task).or_default().push(i);
        }
        NtpDataset { episodes, by_task }
    }

    /// The episodes.
    pub fn episodes(&self) -> &[NtpEpisode] {
        &self.episodes
    }

    /// The dataset cached in `dir` when it was built with the same
    /// `encoder_probe` (what the encoder that produced its rows gives for a
    /// fixed input: a cache from another encoder is rebuilt, not read);
    /// otherwise `build`'s, saved there first. A cache is written whole or
    /// not at all, so a killed run rebuilds it.
    pub fn load_or_build(
        dir: &Path,
        encoder_probe: &[f32],
        build: impl FnOnce() -> anyhow::Result<Self>,
    ) -> anyhow::Result<Self> {
        if dir.join(EPISODES_FILE).is_file() {
            match Self::load(dir, encoder_probe)? {
                Some(cached) => return Ok(cached),
                None => eprintln!(
                    "  {}: encoded by another frame encoder; encoding again",
                    dir.display()
                ),
            }
        }
        let dataset = build()?;
        dataset.save(dir, encoder_probe)?;
        Ok(dataset)
    }

    /// Like [`Self::load_or_build`] for the episodes of `pairs` (task index,
    /// seed), in that order, whose build is long (100,000 episodes' frames
    /// rendered and encoded): built `part_len` pairs at a time by
    /// `build_part`, each part saved as it is done in `DIR.parts/NNNNN/`
    /// (with the probe; a part of another encoder is built again), so a
    /// killed build resumes after its last whole part. The whole is then
    /// saved in `dir` and the parts removed. `build_part` of a slice gives
    /// the same episodes whatever the slices. Up to `part_len` pairs are
    /// built in one go, with no parts.
    pub fn load_or_build_in_parts(
        dir: &Path,
        encoder_probe: &[f32],
        pairs: &[(usize, u64)],
        part_len: usize,
        mut build_part: impl FnMut(&[(usize, u64)], &str) -> anyhow::Result<Self>,
    ) -> anyhow::Result<Self> {
        anyhow::ensure!(
            part_len > 0,
            "parts of a dataset must hold at least one episode"
        );
        if pairs.len() <= part_len {
            return Self::load_or_build(dir, encoder_probe, || build_part(pairs, ""));
        }
        let parts_dir = dir.with_extension("parts");
        if dir.join(EPISODES_FILE).is_file() {
            match Self::load(dir, encoder_probe)? {
                Some(cached) => {
                    // Parts a kill left after the whole was saved.
                    if parts_dir.exists() {
                        std::fs::remove_dir_all(&parts_dir)
                            .with_context(|| format!("removing {}", parts_dir.display()))?;
                    }
                    return Ok(cached);
                }
                None => eprintln!(
                    "  {}: encoded by another frame encoder; encoding again",
                    dir.display()
                ),
            }
        }
        let parts = crate::dataset::build_in_parts(
            &parts_dir,
            pairs,
            part_len,
            |part_dir| {
                Ok(match part_dir.join(EPISODES_FILE).is_file() {
                    true => Self::load(part_dir, encoder_probe)?,
                    false => None,
                })
            },
            |part: &Self, part_pairs| {
                part.episodes
                    .iter()
                    .map(|e| e.task)
                    .eq(part_pairs.iter().map(|&(t, _)| t))
            },
            &mut build_part,
            |part, part_dir| part.save(part_dir, encoder_probe),
        )?;
        let episodes = parts.into_iter().flat_map(|p| p.episodes).collect();
        let whole = Self::new(episodes);
        whole.save(dir, encoder_probe)?;
        std::fs::remove_dir_all(&parts_dir)
            .with_context(|| format!("removing {}", parts_dir.display()))?;
        Ok(whole)
    }

    /// Writes the episodes to `dir` (`episodes.json`, `rows.bin` of
    /// little-endian `f32`), through a sibling `.partial` folder renamed
    /// into place.
    pub fn save(&self, dir: &Path, encoder_probe: &[f32]) -> anyhow::Result<()> {
        use std::io::Write;
        let row_dim = self
            .episodes
            .first()
            .and_then(|e| e.rows.first())
            .map_or(0, Vec::len);
        let partial = dir.with_extension("partial");
        if partial.exists() {
            std::fs::remove_dir_all(&partial)
                .with_context(|| format!("removing {}", partial.display()))?;
        }
        std::fs::create_dir_all(&partial)
            .with_context(|| format!("creating {}", partial.display()))?;
        let bin = partial.join(ROWS_FILE);
        let mut out = std::io::BufWriter::new(
            std::fs::File::create(&bin).with_context(|| format!("writing {}", bin.display()))?,
        );
        for row in self.episodes.iter().flat_map(|e| &e.rows) {
            anyhow::ensure!(row.len() == row_dim, "rows of unequal length");
            for v in row {
                out.write_all(&v.to_le_bytes())?;
            }
        }
        out.flush()
            .with_context(|| format!("writing {}", bin.display()))?;
        let index = EpisodesIndex {
            format: EPISODES_FORMAT.into(),
            row_dim,
            encoder_probe: encoder_probe.to_vec(),
            episodes: self
                .episodes
                .iter()
                .map(|e| EpisodeEntry {
                    task: e.task,
                    rows: e.rows.len(),
                    trace: e.trace.clone(),
                })
                .collect(),
        };
        let json = partial.join(EPISODES_FILE);
        std::fs::write(&json, serde_json::to_vec(&index)?)
            .with_context(|| format!("writing {}", json.display()))?;
        if dir.exists() {
            std::fs::remove_dir_all(dir).with_context(|| format!("removing {}", dir.display()))?;
        }
        std::fs::rename(&partial, dir)
            .with_context(|| format!("renaming {} to {}", partial.display(), dir.display()))
    }

    /// Reads the episodes [`Self::save`] wrote to `dir`; `None` when they
    /// were encoded by an encoder whose probe differs from `encoder_probe`.
    pub fn load(dir: &Path, encoder_probe: &[f32]) -> anyhow::Result<Option<Self>> {
        let json = dir.join(EPISODES_FILE);
        let text = std::fs::read(&json).with_context(|| format!("reading {}", json.display()))?;
        let index: EpisodesIndex = serde_json::from_slice(&text)
            .with_context(|| format!("{}: not an NTP episode index", json.display()))?;
        anyhow::ensure!(
            index.format == EPISODES_FORMAT,
            "{}: format `{}`, expected `{EPISODES_FORMAT}`",
            json.display(),
            index.format
        );
        if index.encoder_probe != encoder_probe {
            return Ok(None);
        }
        let bin = dir.join(ROWS_FILE);
        let bytes = std::fs::read(&bin).with_context(|| format!("reading {}", bin.display()))?;
        let rows: usize = index.episodes.iter().map(|e| e.rows).sum();
        anyhow::ensure!(
            bytes.len() == rows * index.row_dim * 4,
            "{}: {} bytes, but {} says {rows} rows of {} values",
            bin.display(),
            bytes.len(),
            json.display(),
            index.row_dim
        );
        let mut values = bytes
            .chunks_exact(4)
            .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]));
        let episodes = index
            .episodes
            .into_iter()
            .map(|e| NtpEpisode {
                task: e.task,
                rows: (0..e.rows)
                    .map(|_| values.by_ref().take(index.row_dim).collect())
                    .collect(),
                trace: e.trace,
            })
            .collect();
        Ok(Some(Self::new(episodes)))
    }
}

/// Folder of a video NTP run's encoded training episodes (see
/// [`NtpDataset::load_or_build`]).
pub const NTP_FRAMES_DIR: &str = "ntp_frames";
/// Episodes per saved part of a video NTP run's episode cache
/// ([`NtpDataset::load_or_build_in_parts`]).
pub const NTP_PART_EPISODES: usize = 8192;
const EPISODES_FILE: &str = "episodes.json";
const ROWS_FILE: &str = "rows.bin";
const EPISODES_FORMAT: &str = "ntg-rs ntp episodes v1";

/// What `episodes.json` of an [`NtpDataset`] cache holds.
#[derive(Serialize, Deserialize)]
struct EpisodesIndex {
    format: String,
    row_dim: usize,
    encoder_probe: Vec<f32>,
    episodes: Vec<EpisodeEntry>,
}

/// One episode in `episodes.json`: its task, how many rows it has in
/// `rows.bin` and its call tree.
#[derive(Serialize, Deserialize)]
struct EpisodeEntry {
    task: usize,
    rows: usize,
    trace: NtpCall,
}

/// What a `pick_place` call does: the cube it picks and where it puts it.
type PickPlaceKey = (Option<Target>, Option<Target>);

/// The `(picked cube, place target)` of a `pick_place` call: the `move` of
/// its last `pick` and of its `place`.
fn pick_place_key(call: &NtpCall) -> PickPlaceKey {
    let move_of = |c: &NtpCall| {
        c.children
            .iter()
            .find(|p| p.program == NtpProgram::Move)
            .and_then(|p| p.argument)
    };
    let picked = call
        .children
        .iter()
        .rev()
        .find(|c| c.program == NtpProgram::Pick)
        .and_then(move_of);
    let placed = call
        .children
        .iter()
        .find(|c| c.program == NtpProgram::Place)
        .and_then(move_of);
    (picked, placed)
}

/// `call` in the network's indices, without scopes.
fn unscoped(call: &NtpCall) -> ProgramCall {
    ProgramCall {
        program: call.program.index(),
        argument: call.argument.map(argument_index),
        start: call.start,
        end: call.end,
        scope: None,
        children: call.children.iter().map(unscoped).collect(),
    }
}

/// The training trace of `episode` conditioned on the demo `spec` (see the
/// module docs for how scopes are aligned); NTP Flat's is the flattened
/// tree without scopes.
pub fn training_trace(episode: &NtpCall, spec: &NtpCall, kind: NtpKind) -> ProgramCall {
    if kind == NtpKind::Flat {
        return unscoped(&episode.flattened());
    }
    let rows = |c: &NtpCall| Some((c.start, c.end));
    let mut seen: Vec<(PickPlaceKey, usize)> = Vec::new();
    let mut root = unscoped(episode);
    for (pp, call) in episode.children.iter().zip(&mut root.children) {
        let key = pick_place_key(pp);
        let k = match seen.iter().position(|(seen_key, _)| *seen_key == key) {
            Some(p) => &mut seen[p].1,
            None => {
                seen.push((key, 0));
                &mut seen.last_mut().expect("just pushed").1
            }
        };
        let matches: Vec<&NtpCall> = spec
            .children
            .iter()
            .filter(|s| pick_place_key(s) == key)
            .collect();
        let Some(matched) = matches.get(*k).or(matches.last()).copied() else {
            continue;
        };
        *k += 1;
        call.scope = rows(matched);
        let spec_pick = matched
            .children
            .iter()
            .rev()
            .find(|c| c.program == NtpProgram::Pick);
        let spec_place = matched
            .children
            .iter()
            .find(|c| c.program == NtpProgram::Place);
        for child in &mut call.children {
            let counterpart = match NtpProgram::from_index(child.program) {
                Some(NtpProgram::Pick) => spec_pick,
                Some(NtpProgram::Place) => spec_place,
                _ => None,
            };
            child.scope = counterpart.and_then(rows);
        }
    }
    root
}

/// Metrics of one NTP epoch, as logged to `metrics.jsonl`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct NtpEpochMetrics {
    /// Epoch index (from 0).
    pub epoch: usize,
    /// Mean of the summed losses.
    pub loss: f32,
    /// End-of-program decisions right.
    pub eop_accuracy: f32,
    /// Sub-program calls right.
    pub program_accuracy: f32,
    /// `move` arguments right.
    pub argument_accuracy: f32,
    /// Scope row labels right.
    pub scope_accuracy: f32,
    /// Wall-clock seconds of the epoch.
    pub seconds: f32,
}

impl EpochLog for NtpEpochMetrics {
    fn epoch(&self) -> usize {
        self.epoch
    }
    fn log_line(&self) -> String {
        NtpEpochMetrics::log_line(self)
    }
}

impl NtpEpochMetrics {
    /// One human-readable log line.
    pub fn log_line(&self) -> String {
        format!(
            "epoch {:>3}: loss {:.3} | eop {:.3} | program {:.3} | argument {:.3} | scope {:.3} | {:.1}s",
            self.epoch,
            self.loss,
            self.eop_accuracy,
            self.program_accuracy,
            self.argument_accuracy,
            self.scope_accuracy,
            self.seconds
        )
    }
}

/// Cube renaming for NTP's training (not in the paper; NTG's recommended
/// recipe has it, so the baseline gets it too): each example's two demos
/// get one random renaming of the cubes, in their observation columns and
/// in `move`'s arguments.
pub struct NtpRenaming<'a> {
    /// Where each cube's columns are (no action families: NTP's arguments
    /// are renamed directly).
    pub symmetry: ObjectSymmetry,
    /// Renamings a task may not be trained under (e.g. into a held-out
    /// task); drawn again.
    pub accept: Option<RenamingFilter<'a>>,
}

/// NTP's [`TrainStep`]: each episode of the batch is imitated conditioned
/// on another demo of its task (itself if it is the only one), drawn from
/// the epoch's generator.
pub struct NtpStep<'a> {
    dataset: &'a NtpDataset,
    kind: NtpKind,
    renaming: Option<NtpRenaming<'a>>,
    device: Device,
}

impl<'a> NtpStep<'a> {
    /// The step of `kind` on `dataset`, with cubes renamed when `renaming`
    /// is given.
    pub fn new(
        dataset: &'a NtpDataset,
        kind: NtpKind,
        renaming: Option<NtpRenaming<'a>>,
        device: &Device,
    ) -> anyhow::Result<Self> {
        Ok(NtpStep {
            dataset,
            kind,
            renaming,
            device: device.clone(),
        })
    }
}

/// `call` with every argument (a cube) renamed by `perm`.
fn renamed_call(call: &mut ProgramCall, perm: &[usize]) {
    if let Some(a) = call.argument.as_mut()
        && let Some(&to) = perm.get(*a)
    {
        *a = to;
    }
    for c in &mut call.children {
        renamed_call(c, perm);
    }
}

impl TrainStep<NtpModel> for NtpStep<'_> {
    type Metrics = NtpEpochMetrics;

    fn num_examples(&self) -> usize {
        self.dataset.episodes.len()
    }

    fn step(
        &self,
        model: &NtpModel,
        chunk: &[usize],
        ctx: StepContext<'_>,
    ) -> anyhow::Result<StepReport> {
        let net = &model.net;
        let episodes = &self.dataset.episodes;
        // Per example: the spec's rows, the episode's rows, the trace.
        type Owned = (Vec<Vec<f32>>, Vec<Vec<f32>>, ProgramCall);
        let mut owned: Vec<Owned> = Vec::new();
        for &i in chunk {
            let e = &episodes[i];
            let others: Vec<usize> = self.dataset.by_task[&e.task]
                .iter()
                .copied()
                .filter(|&j| j != i)
                .collect();
            let spec = &episodes[*others.choose(ctx.rng).unwrap_or(&i)];
            let mut trace = training_trace(&e.trace, &spec.trace, self.kind);
            let (mut spec_rows, mut rows) = (spec.rows.clone(), e.rows.clone());
            if let Some(r) = &self.renaming {
                let relabeling = r.symmetry.random_accepted(0, ctx.rng, |perm| {
                    r.accept.is_none_or(|accept| accept(e.task, perm))
                })?;
                for row in spec_rows.iter_mut().chain(rows.iter_mut()) {
                    *row = r.symmetry.apply_to_row(&relabeling, row);
                }
                renamed_call(&mut trace, relabeling.perm());
            }
            owned.push((spec_rows, rows, trace));
        }
        let examples: Vec<NtpExample<'_, Vec<f32>>> = owned
            .iter()
            .map(|(spec, rows, trace)| (&spec[..], &rows[..], trace))
            .collect();
        let batch = net.batch(&examples, &self.device)?;
        let out = net.loss(&batch)?;
        StepReport::scored(
            out.loss,
            &[
                out.eop_accuracy,
                out.program_accuracy,
                out.argument_accuracy,
                out.scope_accuracy,
            ],
        )
    }

    fn epoch_metrics(
        &self,
        epoch: usize,
        means: &[f32],
        _: &EdgeCounts,
        seconds: f32,
    ) -> NtpEpochMetrics {
        NtpEpochMetrics {
            epoch,
            loss: means[0],
            eop_accuracy: means[1],
            program_accuracy: means[2],
            argument_accuracy: means[3],
            scope_accuracy: means[4],
            seconds,
        }
    }
}

/// An NTP network as a trained method of block stacking: what `fit` trains
/// and checkpoints (the network's own files) and the policy whose programs
/// act in block stacking's vocabulary. (The network is ntg-model's and the
/// method traits ntg-train's, so the method is this wrapper.)
#[derive(Module, Debug)]
pub struct NtpModel {
    /// The network.
    pub net: NtpNet,
}

impl NtpModel {
    /// A freshly initialised model of `config`.
    pub fn init(config: &NtpConfig, device: &Device) -> anyhow::Result<Self> {
        Ok(NtpModel {
            net: config.init(device)?,
        })
    }
}

impl TrainedModel for NtpModel {
    fn save_to(&self, dir: &Path) -> anyhow::Result<()> {
        Ok(self.net.save(dir)?)
    }
    fn load_from(dir: &Path, device: &Device) -> anyhow::Result<Self> {
        Ok(NtpModel {
            net: NtpNet::load(dir, device)?,
        })
    }
}

impl crate::method::on_frames::EmbeddingReader for NtpModel {
    fn row_dim(&self) -> usize {
        self.net.obs_dim()
    }
}

/// How an NTP network decides along expert traces it is shown step by
/// step (teacher forcing; `ntg eval --decisions`): per step of the program
/// hierarchy, how often it decides as the trace does, and which head is
/// wrong where it does not.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct DecisionReport {
    /// Episodes (traces) checked.
    pub episodes: usize,
    /// Episodes in which every decision was the trace's.
    pub episodes_right: usize,
    /// Episodes in which every decision was the trace's but perhaps for
    /// the scopes given to callees (a scope off by a row may still serve).
    pub episodes_right_but_scopes: usize,
    /// Decisions checked.
    pub decisions: usize,
    /// Decisions the program stack would take exactly as the trace does.
    pub right: usize,
    /// Per step (caller, what the trace does there), in first-seen order.
    pub steps: Vec<StepTally>,
}

/// The decisions of one step of the program hierarchy: a caller calling
/// one sub-program, or returning.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct StepTally {
    /// The deciding program (`stack`, `pick_place`, `pick`, `place`).
    pub program: String,
    /// What the trace does: the sub-program it calls, or `return`.
    pub step: String,
    /// Decisions of this step checked.
    pub decisions: usize,
    /// Taken exactly as the trace does.
    pub right: usize,
    /// Wrong about returning (returns where the trace calls, or calls
    /// where it returns).
    pub eop_wrong: usize,
    /// Calls the wrong sub-program (end-of-program right).
    pub program_wrong: usize,
    /// Gives the wrong argument (a cube).
    pub argument_wrong: usize,
    /// Gives the callee a scope other than the trace's.
    pub scope_wrong: usize,
}

impl DecisionReport {
    /// Tallies `checks` ([`ntg_model::NtpNet::check_decisions`], of whole
    /// episodes told apart by their `demo` index) into the report.
    pub fn add(&mut self, checks: &[NtpDecisionCheck]) {
        let name = |p: usize| NtpProgram::from_index(p).map_or("?", NtpProgram::name);
        let mut episode_right: BTreeMap<usize, (bool, bool)> = BTreeMap::new();
        for c in checks {
            let right = c.right();
            let but_scope = NtpDecisionCheck {
                scope_right: None,
                ..*c
            }
            .right();
            let episode = episode_right.entry(c.demo).or_insert((true, true));
            episode.0 &= right;
            episode.1 &= but_scope;
            let step = if c.returns {
                "return"
            } else {
                name(c.next_program)
            };
            let at = match self
                .steps
                .iter()
                .position(|t| t.program == name(c.program) && t.step == step)
            {
                Some(at) => at,
                None => {
                    self.steps.push(StepTally {
                        program: name(c.program).to_owned(),
                        step: step.to_owned(),
                        decisions: 0,
                        right: 0,
                        eop_wrong: 0,
                        program_wrong: 0,
                        argument_wrong: 0,
                        scope_wrong: 0,
                    });
                    self.steps.len() - 1
                }
            };
            let tally = &mut self.steps[at];
            tally.decisions += 1;
            tally.right += usize::from(right);
            if !c.eop_right {
                tally.eop_wrong += 1;
            } else if !c.returns {
                tally.program_wrong += usize::from(c.program_right == Some(false));
                tally.argument_wrong += usize::from(c.argument_right == Some(false));
                tally.scope_wrong += usize::from(c.scope_right == Some(false));
            }
            self.decisions += 1;
            self.right += usize::from(right);
        }
        self.episodes += episode_right.len();
        self.episodes_right += episode_right.values().filter(|r| r.0).count();
        self.episodes_right_but_scopes += episode_right.values().filter(|r| r.1).count();
    }

    /// An empty report.
    pub fn new() -> Self {
        DecisionReport {
            episodes: 0,
            episodes_right: 0,
            episodes_right_but_scopes: 0,
            decisions: 0,
            right: 0,
            steps: Vec::new(),
        }
    }

    /// The fraction of episodes every decision of which would be right if
    /// each step's decisions were right independently at its measured
    /// rate: the product over steps of (its rate) to the power of (its
    /// decisions per episode).
    pub fn independent_episodes_right(&self) -> f64 {
        if self.episodes == 0 {
            return 0.0;
        }
        self.steps
            .iter()
            .map(|t| {
                let rate = t.right as f64 / t.decisions.max(1) as f64;
                rate.powf(t.decisions as f64 / self.episodes as f64)
            })
            .product()
    }

    /// The report as a table, one line per step, then the totals.
    pub fn table(&self) -> String {
        let mut out = format!(
            "{:<11} {:<11} {:>9} {:>8} {:>6} {:>8} {:>9} {:>6}\n",
            "program", "step", "decisions", "right", "eop", "program", "argument", "scope"
        );
        for t in &self.steps {
            out.push_str(&format!(
                "{:<11} {:<11} {:>9} {:>8.4} {:>6} {:>8} {:>9} {:>6}\n",
                t.program,
                t.step,
                t.decisions,
                t.right as f64 / t.decisions.max(1) as f64,
                t.eop_wrong,
                t.program_wrong,
                t.argument_wrong,
                t.scope_wrong
            ));
        }
        out.push_str(&format!(
            concat!(
                "(eop / program / argument / scope: decisions wrong by that head)\n",
                "decisions right {}/{} = {:.4}; {:.1} decisions per episode; ",
                "episodes with every decision right {}/{} = {:.3} ",
                "(if each step erred independently at its rate: {:.3}), but for scopes {}/{} = {:.3}\n",
            ),
            self.right,
            self.decisions,
            self.right as f64 / self.decisions.max(1) as f64,
            self.decisions as f64 / self.episodes.max(1) as f64,
            self.episodes_right,
            self.episodes,
            self.episodes_right as f64 / self.episodes.max(1) as f64,
            self.independent_episodes_right(),
            self.episodes_right_but_scopes,
            self.episodes,
            self.episodes_right_but_scopes as f64 / self.episodes.max(1) as f64
        ));
        out
    }
}

impl Default for DecisionReport {
    fn default() -> Self {
        Self::new()
    }
}

/// One episode to check: the specification demo's rows, the episode's
/// rows (both as the network reads them) and their call trees.
pub struct CheckedEpisode {
    /// The specification demo's rows.
    pub spec_rows: Vec<Vec<f32>>,
    /// Its call tree.
    pub spec: NtpCall,
    /// The executed episode's rows.
    pub rows: Vec<Vec<f32>>,
    /// Its call tree.
    pub trace: NtpCall,
}

/// Checks `net`'s decisions along `episodes`' traces (each conditioned on
/// its specification demo, the trace built as for training,
/// [`training_trace`]) and adds them to `report`.
pub fn check_episodes(
    net: &NtpNet,
    kind: NtpKind,
    episodes: &[CheckedEpisode],
    report: &mut DecisionReport,
    device: &Device,
) -> anyhow::Result<()> {
    let net = net.valid();
    for chunk in episodes.chunks(16) {
        let traces: Vec<ProgramCall> = chunk
            .iter()
            .map(|e| training_trace(&e.trace, &e.spec, kind))
            .collect();
        let examples: Vec<NtpExample<'_, Vec<f32>>> = chunk
            .iter()
            .zip(&traces)
            .map(|(e, t)| (&e.spec_rows[..], &e.rows[..], t))
            .collect();
        let batch = net.batch(&examples, device)?;
        report.add(&net.check_decisions(&batch)?);
    }
    Ok(())
}

impl NtpKind {
    /// The NTP that `method` trains: NTP Flat's lowest level only, or (NTP
    /// and NTP (Detector)) the hierarchy.
    pub fn of(method: &dyn crate::method::Method) -> Self {
        if method.name() == crate::method::Method::name(&NtpMethod(NtpKind::Flat)) {
            NtpKind::Flat
        } else {
            NtpKind::Hierarchical
        }
    }
}

/// What NTP and NTP Flat's frame encoder (stage A) is trained to tell
/// apart, on a run from demo videos: NTG's flat actions on every frame of
/// the demo videos (the encoder NTG's run of the same videos trains, so
/// they share it), or NTP's own lowest-level supervision on the frames NTP
/// acts on (the scene before each primitive and the last): the primitive
/// just taken and the next.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "kebab-case")]
pub enum FrameLabels {
    /// NTG's flat actions, on every frame of the demo videos (stage A as
    /// NTG's, shared with NTG's run of the point).
    #[default]
    Flat,
    /// NTP's primitives, on the frame before each primitive of its
    /// primitive-level episodes (NTP and NTP Flat on video only).
    Primitive,
}

impl FrameLabels {
    /// Whether these are NTG's flat labels (the default).
    pub fn is_flat(&self) -> bool {
        *self == FrameLabels::Flat
    }
}

/// Maps an episode's frame rows to the rows NTP reads (a frozen encoder's
/// embeddings, a detector's estimated states).
pub type EncodeRows<'a> = &'a dyn Fn(&[Vec<f32>]) -> anyhow::Result<Vec<Vec<f32>>>;

/// What a domain whose expert also acts at NTP's primitive level
/// (`move(X)`, `grasp`, `drop`) gives the NTP family to train on, in
/// [`TrainInput::extension`] as a [`PrimitiveInput`]. NTP's programs are
/// block stacking's, so block stacking is the one domain that provides it.
pub trait PrimitiveLevel: Send + Sync {
    /// What the run's networks see.
    fn obs(&self) -> ObsKind;
    /// NTP's encoder of true-state rows (`on_frames` false) or of frame
    /// embeddings.
    fn encoder(&self, on_frames: bool) -> ntg_model::EncoderConfig;
    /// The expert's primitive-level episodes of the training tasks on true
    /// states (the tasks and seeds of NTG's demos).
    fn state_episodes(&self) -> anyhow::Result<NtpDataset>;
    /// Cube renaming in training on states, if the run asks for it.
    fn renaming(&self) -> Option<NtpRenaming<'_>>;
    /// The frozen frame encoder, trained (or read from `run`) on the run's
    /// demo videos with `labels`.
    fn frame_encoder(
        &self,
        labels: FrameLabels,
        run: &RunDir,
        device: &Device,
    ) -> anyhow::Result<ntg_model::FrameStageNet>;
    /// The training episodes on frames (the run's demo videos' tasks and
    /// seeds, or without videos the training tasks'), each episode's frame
    /// rows mapped by `encode`, cached in parts in `run` (fingerprinted by
    /// what `encode` makes of a fixed frame); the progress bar says `what`.
    fn frame_episodes(
        &self,
        run: &RunDir,
        encode: EncodeRows<'_>,
        what: &str,
    ) -> anyhow::Result<NtpDataset>;
    /// The detector of NTP (Detector), trained (or read) in `run`'s detector
    /// stage with `settings`.
    fn detector(
        &self,
        settings: &crate::method::detector::DetectorSettings,
        run: &RunDir,
        device: &Device,
    ) -> anyhow::Result<ntg_model::Detector>;
    /// The score of a model acting at the primitive level on the run's
    /// validation tasks.
    fn score(&self, model: &dyn TrainedPolicy) -> anyhow::Result<ValidationScore>;
}

/// A [`PrimitiveLevel`], as a domain puts it in [`TrainInput::extension`].
pub struct PrimitiveInput(pub Box<dyn PrimitiveLevel>);

/// The primitive level `input` provides, or an error saying `method` needs
/// it.
pub fn primitive_level<'a>(
    input: &TrainInput<'a>,
    method: &str,
) -> anyhow::Result<&'a dyn PrimitiveLevel> {
    input
        .extension
        .and_then(|e| e.downcast_ref::<PrimitiveInput>())
        .map(|p| p.0.as_ref())
        .with_context(|| {
            format!(
                "--method {method}: NTP's programs act at block stacking's primitive level; this domain has none (--domain blocks)"
            )
        })
}

/// The NTP family's options, read from a run's configuration.
#[derive(Debug, Clone, Default, PartialEq, Deserialize)]
pub struct NtpOptions {
    /// NTP (Detector)'s detector stage.
    #[serde(default)]
    pub detector: Option<crate::method::detector::DetectorSettings>,
    /// The options runs from demo videos keep under `video`.
    #[serde(default)]
    pub video: Option<NtpVideoOptions>,
    /// NTG's ablations (refused here).
    #[serde(default)]
    pub ablation: crate::method::ntg::Variant,
    /// The core network.
    #[serde(default)]
    pub ntp_core: NtpCoreKind,
}

/// NTP's options under a video run configuration's `video`.
#[derive(Debug, Clone, Default, PartialEq, Deserialize)]
pub struct NtpVideoOptions {
    /// What the frame encoder is trained to tell apart.
    #[serde(default)]
    pub encoder_labels: FrameLabels,
}

impl NtpOptions {
    /// The frame encoder's labels (flat without video settings).
    pub fn encoder_labels(&self) -> FrameLabels {
        self.video
            .as_ref()
            .map(|v| v.encoder_labels)
            .unwrap_or_default()
    }

    /// Refuses what NTP and NTP Flat (`method`) cannot train, naming the
    /// flag.
    pub fn check(&self, method: &str) -> anyhow::Result<()> {
        self.check_whole(method)?;
        if self.detector.is_some() {
            anyhow::bail!(
                "--detector-episodes, --detector-epochs and --ntp-on-true-states train NTP (Detector): they need --method ntp-detector"
            );
        }
        Ok(())
    }

    /// Refuses an NTG ablation, naming the flag.
    pub fn check_whole(&self, method: &str) -> anyhow::Result<()> {
        if !self.ablation.is_full() {
            anyhow::bail!(
                "--ablation {}: the ablations are NTG's; {method} is trained whole",
                self.ablation.name()
            );
        }
        Ok(())
    }
}

/// Trains NTP or NTP Flat (`kind`) on `input`'s primitive level: on true
/// states with the run's cube renaming, or from demo videos in stages, the
/// frame encoder first, then NTP on the embeddings of the frames it acts
/// on, the same network as on states but for its encoder's input and the
/// argument read off cube positions, which frames do not have.
pub fn train(
    kind: NtpKind,
    input: TrainInput<'_>,
    options: &NtpOptions,
    on_epoch: &mut dyn FnMut(&EpochReport),
) -> anyhow::Result<Model> {
    let method = crate::method::Method::name(&NtpMethod(kind));
    options.check(method)?;
    let level = primitive_level(&input, method)?;
    let score = |m: &dyn TrainedPolicy| level.score(m);
    let validation = primitive_validation(&input, &score);
    let seed = input.model_seed;
    match level.obs() {
        ObsKind::State => {
            if !options.encoder_labels().is_flat() {
                anyhow::bail!("--encoder-labels sets the frame encoder: it needs --obs vid");
            }
            let dataset = level.state_episodes()?;
            let net = NtpModel::init(
                &ntp_config(level.encoder(false), true, options.ntp_core, seed),
                input.device,
            )?;
            let step = NtpStep::new(&dataset, kind, level.renaming(), input.device)?;
            fit_model(net, step, None, &input, validation, on_epoch)
        }
        ObsKind::Vid => {
            let frames = level.frame_encoder(options.encoder_labels(), input.run, input.device)?;
            let net = Module::valid(&frames);
            let encode = |rows: &[Vec<f32>]| crate::method::on_frames::encode_rows(&net, rows);
            let dataset = level.frame_episodes(input.run, &encode, "NTP frames")?;
            let ntp = NtpModel::init(
                &ntp_config(level.encoder(true), false, options.ntp_core, seed),
                input.device,
            )?;
            let step = NtpStep::new(&dataset, kind, None, input.device)?;
            fit_model(ntp, step, Some(frames), &input, validation, on_epoch)
        }
    }
}

/// `input`'s validation (if it validates) with the primitive level's
/// score in place of the domain's, which acts at the level of its demos.
pub fn primitive_validation<'a>(
    input: &TrainInput<'_>,
    score: &'a crate::method::input::ScoreFn<'a>,
) -> Option<Validation<'a>> {
    input.validation.map(|v| Validation {
        score,
        every: v.every,
    })
}

/// NTP or NTP Flat in the method registry.
pub struct NtpMethod(pub NtpKind);

impl crate::method::Method for NtpMethod {
    fn name(&self) -> &'static str {
        match self.0 {
            NtpKind::Hierarchical => "ntp",
            NtpKind::Flat => "ntp-flat",
        }
    }
    fn legend(&self) -> &'static str {
        match self.0 {
            NtpKind::Hierarchical => "NTP",
            NtpKind::Flat => "NTP Flat",
        }
    }
    fn load(&self, dir: &Path, device: &Device) -> anyhow::Result<Model> {
        crate::method::on_frames::load_either::<NtpModel>(dir, device)
    }
    fn options(&self) -> &'static [&'static str] {
        &["video.encoder_labels", "ntp_core"]
    }
    fn check(&self, config: &serde_json::Value) -> anyhow::Result<()> {
        crate::method::input::options_of::<NtpOptions>(self.legend(), config)?.check(self.name())
    }
    fn train(
        &self,
        input: TrainInput<'_>,
        config: &serde_json::Value,
        on_epoch: &mut dyn FnMut(&EpochReport),
    ) -> anyhow::Result<Model> {
        let options = crate::method::input::options_of(self.legend(), config)?;
        train(self.0, input, &options, on_epoch)
    }
}

impl TrainedPolicy for NtpModel {
    fn for_inference(&self) -> Model {
        Box::new(self.valid())
    }
    fn condition(
        &self,
        demo: &[Vec<f32>],
        vocabulary: &Vocabulary,
    ) -> anyhow::Result<Box<dyn Agent>> {
        let net = &self.net;
        let actions = (0..net.num_programs())
            .map(|p| {
                (0..net.num_arguments())
                    .map(|a| {
                        let program = NtpProgram::from_index(p)?;
                        let action = program.action(Some(argument_target(a)))?;
                        vocabulary.id(&env_blocks::action_name(action))
                    })
                    .collect()
            })
            .collect();
        let primitives = (0..net.num_programs())
            .map(|p| NtpProgram::from_index(p).is_some_and(NtpProgram::is_primitive))
            .collect();
        Ok(Box::new(NtpAgent {
            stack: std::cell::RefCell::new(ProgramStack::new(
                NtpProgram::Root.index(),
                demo.len(),
                primitives,
                MAX_DEPTH,
            )),
            core: NtpNet::condition(net, demo)?,
            actions,
        }))
    }
    fn as_any(&self) -> &dyn std::any::Any {
        self
    }
    fn export_safetensors(
        &self,
        dir: &Path,
    ) -> anyhow::Result<Vec<ntg_train::method::ExportedFile>> {
        // The network as saved (`NtpNet::save`): its names carry no `net.`.
        Ok(vec![ntg_train::method::export_network(&self.net, dir, "")?])
    }
}

/// NTP conditioned on a demo, with its program stack.
struct NtpAgent {
    core: ConditionedNtp,
    stack: std::cell::RefCell<ProgramStack>,
    /// The environment action of each (program, argument); `None` where
    /// the program is not a primitive of the vocabulary.
    actions: Vec<Vec<Option<ActionId>>>,
}

impl Agent for NtpAgent {
    fn act(
        &self,
        row: &[f32],
        _: &[ActionId],
        _: &mut crate::method::Ties,
    ) -> anyhow::Result<ActionId> {
        let step = self.stack.borrow_mut().step(&self.core, row)?;
        Ok(match step {
            StackStep::Act { program, argument } => self
                .actions
                .get(program)
                .and_then(|a| a.get(argument).copied().flatten())
                .with_context(|| format!("NTP called program {program} with argument {argument}, not an action of the environment"))?,
            // A stalled stack gives up: the episode ends unfinished.
            StackStep::Done | StackStep::Stalled => Vocabulary::END,
        })
    }
    fn explain(&self) -> Option<String> {
        Some(call_stack(self.stack.borrow().frames()))
    }
}

/// The running programs, root first, each with its scope of the demo
/// (rows, inclusive): `stack[0-12] > pick_place[3-7] > pick[3-4]`.
pub fn call_stack(frames: &[ntg_model::StackFrame]) -> String {
    let names: Vec<String> = frames
        .iter()
        .map(|f| {
            let name = NtpProgram::from_index(f.program).map_or("?", NtpProgram::name);
            format!("{name}[{}-{}]", f.scope.0, f.scope.1)
        })
        .collect();
    names.join(" > ")
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tasks(n: usize) -> Vec<StackTask> {
        env_blocks::standard_split()
            .unwrap()
            .train(n)
            .unwrap()
            .to_vec()
    }

    fn demo(task: &StackTask, seed: u64, config: EnvConfig) -> env_blocks::NtpDemo {
        env_blocks::record_ntp_demo(&BlocksTask::Stack(task.clone()), config, seed).unwrap()
    }

    #[test]
    fn an_episode_cache_reads_back_what_was_saved_and_only_for_its_encoder() {
        let tasks = tasks(2);
        let config = EnvConfig::state_only();
        let dataset = NtpDataset::record(&tasks, 2, 40, config, |o| {
            crate::domain::blocks::featurize(o, crate::spec::ObsKind::State)
        })
        .unwrap();
        let dir = tempfile::tempdir().unwrap();
        let cache = dir.path().join(NTP_FRAMES_DIR);
        let probe = [0.25_f32, -1.0 / 3.0];
        let built = NtpDataset::load_or_build(&cache, &probe, || Ok(dataset.clone())).unwrap();
        let read = NtpDataset::load_or_build(&cache, &probe, || panic!("cached")).unwrap();
        for (a, b) in [&dataset, &built]
            .iter()
            .flat_map(|d| d.episodes().iter().zip(read.episodes()))
        {
            assert_eq!((a.task, &a.rows, &a.trace), (b.task, &b.rows, &b.trace));
        }
        assert_eq!(read.episodes().len(), 4);
        assert!(
            NtpDataset::load(&cache, &[0.25, 0.0]).unwrap().is_none(),
            "another encoder's cache is not read"
        );
        let rows = cache.join(ROWS_FILE);
        let bytes = std::fs::read(&rows).unwrap();
        std::fs::write(&rows, &bytes[..bytes.len() - 4]).unwrap();
        let err = NtpDataset::load(&cache, &probe).unwrap_err().to_string();
        assert!(err.contains("rows.bin") && err.contains("bytes"), "{err}");
    }

    #[test]
    fn an_episode_cache_built_in_parts_resumes_after_its_last_whole_part() {
        let tasks = tasks(3);
        let config = EnvConfig::state_only();
        let build = |pairs: &[(usize, u64)]| {
            NtpDataset::new(
                pairs
                    .iter()
                    .map(|&(t, seed)| {
                        let demo = demo(&tasks[t], seed, config);
                        NtpEpisode {
                            task: t,
                            rows: demo
                                .observations
                                .iter()
                                .map(|o| {
                                    crate::domain::blocks::featurize(o, crate::spec::ObsKind::State)
                                })
                                .collect(),
                            trace: demo.root,
                        }
                    })
                    .collect(),
            )
        };
        let pairs = NtpDataset::pairs(3, 2, 40);
        let whole = build(&pairs);
        let same = |a: &NtpDataset, b: &NtpDataset| {
            a.episodes().len() == b.episodes().len()
                && a.episodes()
                    .iter()
                    .zip(b.episodes())
                    .all(|(a, b)| (a.task, &a.rows, &a.trace) == (b.task, &b.rows, &b.trace))
        };
        let dir = tempfile::tempdir().unwrap();
        let cache = dir.path().join(NTP_FRAMES_DIR);
        let probe = [0.5_f32];
        // Killed while building its second part of three.
        let mut built = 0;
        let err = NtpDataset::load_or_build_in_parts(&cache, &probe, &pairs, 2, |part, _| {
            built += 1;
            anyhow::ensure!(built < 2, "killed");
            Ok(build(part))
        })
        .unwrap_err();
        assert_eq!(err.to_string(), "killed");
        let mut rebuilt = Vec::new();
        let resumed = NtpDataset::load_or_build_in_parts(&cache, &probe, &pairs, 2, |part, _| {
            rebuilt.push(part.to_vec());
            Ok(build(part))
        })
        .unwrap();
        assert_eq!(rebuilt, [pairs[2..4].to_vec(), pairs[4..].to_vec()]);
        assert!(same(&resumed, &whole), "the episodes built in one go");
        assert!(!cache.with_extension("parts").exists(), "parts removed");
        let read =
            NtpDataset::load_or_build_in_parts(&cache, &probe, &pairs, 2, |_, _| panic!("cached"))
                .unwrap();
        assert!(same(&read, &whole));
        // Parts of another encoder are built again, not read.
        let other = dir.path().join("other");
        build(&pairs[..2])
            .save(&other.with_extension("parts").join("00000"), &[0.0])
            .unwrap();
        let mut rebuilt = 0;
        let fresh = NtpDataset::load_or_build_in_parts(&other, &probe, &pairs, 2, |part, _| {
            rebuilt += 1;
            Ok(build(part))
        })
        .unwrap();
        assert_eq!(rebuilt, 3);
        assert!(same(&fresh, &whole));
    }

    #[test]
    fn a_decision_report_tallies_each_step_and_the_head_that_erred() {
        let (root, place, drop) = (
            NtpProgram::Root.index(),
            NtpProgram::Place.index(),
            NtpProgram::Drop.index(),
        );
        let check = |demo, program, returns, next, eop, scope| NtpDecisionCheck {
            demo,
            program,
            returns,
            next_program: next,
            eop_right: eop,
            program_right: (!returns).then_some(true),
            argument_right: None,
            scope_right: scope,
        };
        let mut report = DecisionReport::new();
        report.add(&[
            // Episode 0: place returns instead of dropping.
            check(0, place, false, drop, false, None),
            check(0, place, true, 0, true, None),
            // Episode 1: right but for a scope.
            check(1, place, false, drop, true, None),
            check(
                1,
                root,
                false,
                NtpProgram::PickPlace.index(),
                true,
                Some(false),
            ),
        ]);
        report.add(&[check(0, place, false, drop, true, None)]);
        assert_eq!(
            (
                report.episodes,
                report.episodes_right,
                report.episodes_right_but_scopes
            ),
            (3, 1, 2)
        );
        assert_eq!((report.decisions, report.right), (5, 3));
        let step = |program: &str, step: &str| {
            report
                .steps
                .iter()
                .find(|t| t.program == program && t.step == step)
                .unwrap()
                .clone()
        };
        let place_drop = step("place", "drop");
        assert_eq!(
            (place_drop.decisions, place_drop.right, place_drop.eop_wrong),
            (3, 2, 1)
        );
        let scoped = step("stack", "pick_place");
        assert_eq!(
            (scoped.right, scoped.scope_wrong, scoped.eop_wrong),
            (0, 1, 0)
        );
        assert_eq!(step("place", "return").right, 1);
        // place -> drop right 2/3, once per episode; stack -> pick_place
        // 0/1: no episode can be right.
        assert_eq!(report.independent_episodes_right(), 0.0);
        assert!(
            report
                .table()
                .contains("episodes with every decision right 1/3")
        );
    }

    #[test]
    fn scopes_point_at_the_spec_call_that_moves_the_same_cube() {
        let task = &tasks(3)[2];
        let config = EnvConfig::state_only().without_failures();
        let episode = demo(task, 1, config);
        let spec = demo(task, 2, config);
        let trace = training_trace(&episode.root, &spec.root, NtpKind::Hierarchical);
        assert_eq!(trace.scope, None);
        let mut scoped = 0;
        for (pp, call) in episode.root.children.iter().zip(&trace.children) {
            let Some((s, e)) = call.scope else { continue };
            scoped += 1;
            let spec_pp = spec
                .root
                .children
                .iter()
                .find(|c| (c.start, c.end) == (s, e))
                .expect("a scope is a spec pick_place's rows");
            assert_eq!(pick_place_key(spec_pp), pick_place_key(pp));
            // Its pick and place read slices of that scope.
            for child in &call.children {
                let (cs, ce) = child.scope.expect("pick and place have scopes");
                assert!(s <= cs && ce <= e && cs < ce);
            }
        }
        // Without failures, every goal's pick_place has a counterpart.
        assert!(scoped >= task.goals.len(), "{scoped} scoped calls");
        // NTP Flat: primitives under the root, no scopes.
        let flat = training_trace(&episode.root, &spec.root, NtpKind::Flat);
        assert_eq!(flat.children.len(), episode.actions.len());
        assert!(
            flat.children
                .iter()
                .all(|c| c.scope.is_none() && c.children.is_empty())
        );
    }

    /// Replays a recorded call tree's decisions in the order the stack asks
    /// for them: the oracle NTP.
    struct Oracle {
        decisions: std::cell::RefCell<std::collections::VecDeque<ntg_model::NtpDecision>>,
    }

    fn oracle_decisions(call: &ProgramCall, out: &mut Vec<ntg_model::NtpDecision>) {
        if call.children.is_empty() {
            return;
        }
        for c in &call.children {
            out.push(ntg_model::NtpDecision {
                end_of_program: false,
                program: c.program,
                argument: c.argument.unwrap_or(0),
                scope: c.scope.unwrap_or((0, 0)),
            });
            oracle_decisions(c, out);
        }
        out.push(ntg_model::NtpDecision {
            end_of_program: true,
            program: 0,
            argument: 0,
            scope: (0, 0),
        });
    }

    impl ntg_model::NtpCore for Oracle {
        fn decide(
            &self,
            _: &[f32],
            _: &ntg_model::StackFrame,
        ) -> ntg_model::Result<ntg_model::NtpDecision> {
            self.decisions
                .borrow_mut()
                .pop_front()
                .ok_or_else(|| ntg_model::ModelError::Input("the oracle's trace ran out".into()))
        }
    }

    /// The program stack, driven by the expert's own call tree, completes
    /// every task in the environment (failures on: the same seed gives the
    /// same slips and misses, which the tree already retries).
    #[test]
    fn the_program_stack_driven_by_the_oracle_trace_completes_every_task() {
        let config = EnvConfig::state_only();
        let primitive_env = EnvConfig {
            level: env_blocks::ActionLevel::Primitive,
            ..config
        };
        for (i, task) in tasks(20).iter().enumerate() {
            let seed = 500 + i as u64;
            let recorded = demo(task, seed, config);
            let trace = unscoped(&recorded.root);
            let mut decisions = Vec::new();
            oracle_decisions(&trace, &mut decisions);
            let oracle = Oracle {
                decisions: std::cell::RefCell::new(decisions.into()),
            };
            let mut env = env_blocks::BlocksEnv::stacking(task.clone(), primitive_env).unwrap();
            use ctg_graph::Environment;
            env.reset(seed).unwrap();
            let primitives = NtpProgram::ALL.iter().map(|p| p.is_primitive()).collect();
            let mut stack =
                ProgramStack::new(0, recorded.observations.len(), primitives, MAX_DEPTH);
            let mut steps = 0;
            loop {
                match stack.step(&oracle, &[]).unwrap() {
                    StackStep::Act { program, argument } => {
                        let action = NtpProgram::from_index(program)
                            .unwrap()
                            .action(Some(argument_target(argument)))
                            .unwrap();
                        env.step(env.encode(action).unwrap()).unwrap();
                        steps += 1;
                    }
                    StackStep::Done => break,
                    StackStep::Stalled => panic!("the oracle stalled"),
                }
            }
            assert_eq!(steps, recorded.actions.len());
            assert!(env.is_success(), "task {} seed {seed}", task.id);
        }
    }
}
