//! The paper's figures as experiment configs: each figure is a TOML file in
//! `crates/ntg-trainer/experiments/` that lists, per profile, the runs it
//! trains (domain, method, observation, recipe, scale, seed, and any field
//! of the run configuration set by name) and how they are plotted. The
//! files are compiled in as the defaults; `ntg reproduce --experiments DIR`
//! reads edited copies from `DIR` instead.
//!
//! One module per figure turns its file into runs through the shared
//! training and evaluation code ([`crate::fit`], [`crate::domain`]) and
//! draws the result: [`ntp_exp`] (block stacking, success vs training
//! tasks), [`ablation`] (block stacking, NTG without each part; runs in
//! `ntp_exp`'s form) and [`thor_all`] (object collection, success vs
//! objects); fig.
//! "jigsaws" reads `jigsaws.toml` through
//! [`crate::jigsaws::JigsawsConfig::for_profile`].
//!
//! The prose of each figure's report section is a template in
//! `crates/ntg-trainer/experiments/report/`, compiled in and filled from
//! the figure's results ([`template`]).

use std::path::Path;

use anyhow::{Context, bail};
use serde::de::DeserializeOwned;
use serde::{Deserialize, Serialize};
use serde_json::Value;

use crate::spec::Profile;

pub mod ablation;
pub mod ntp_exp;
pub mod qualitative;
pub mod structure;
pub mod template;
pub mod thor_all;
pub mod zoo;

/// The experiment files compiled in: `(name, contents)`.
pub const BUILT_IN: [(&str, &str); 6] = [
    ("ntp_exp", include_str!("../../experiments/ntp_exp.toml")),
    ("ablation", include_str!("../../experiments/ablation.toml")),
    (
        "structure",
        include_str!("../../experiments/structure.toml"),
    ),
    (
        "ablation_b",
        include_str!("../../experiments/ablation_b.toml"),
    ),
    ("thor_all", include_str!("../../experiments/thor_all.toml")),
    ("jigsaws", include_str!("../../experiments/jigsaws.toml")),
];

/// How `ntg reproduce` treats the runs of a figure: where their folders
/// are, how many train at once, which ones, and the committed run records
/// ([`crate::record`]) it restores and writes.
#[derive(Debug)]
pub struct Plan<'a> {
    /// The folder of the run folders.
    pub runs: &'a Path,
    /// Places for the runs trained at once (each on its share of the cores), shared by
    /// every figure of the invocation.
    pub slots: Slots,
    /// Only these run folders (`--only`); `None`: every run.
    pub only: Option<&'a [String]>,
    /// Where run records are kept: a finished run's record is written there
    /// if none is; with `restore`, a missing run folder whose record is
    /// there (of the same configuration) is restored from it instead of
    /// trained.
    pub records: Option<&'a Path>,
    /// See `records`.
    pub restore: bool,
    /// Whether runs neither finished nor recorded are trained (`false`:
    /// they are left out and listed in `missing`).
    pub train: bool,
    /// The runs left out (neither finished nor recorded, and `train` off).
    pub missing: std::sync::Mutex<Vec<String>>,
}

impl<'a> Plan<'a> {
    /// Every run in `runs`, trained where needed, `jobs` at a time; no
    /// records.
    pub fn train_all(runs: &'a Path, jobs: usize) -> Self {
        Plan {
            runs,
            slots: Slots::new(jobs),
            only: None,
            records: None,
            restore: false,
            train: true,
            missing: Default::default(),
        }
    }

    /// Whether the run folder `name` is among `only`.
    pub(crate) fn selected(&self, name: &str) -> bool {
        self.only
            .is_none_or(|names| names.iter().any(|n| n == name))
    }

    /// Gets the run folder `name` (of `config`) ready for its figure: if
    /// it is missing and a record of the same configuration is kept,
    /// restores it from there; else, when training, if a run of the same
    /// configuration begun on another machine is carried in the
    /// `in-progress/` folder beside the records
    /// ([`crate::record::in_progress_dir`]), copies it in to resume it.
    /// Returns the folder, or `None` (the run noted in `missing`) when
    /// training is off and the run has no evaluation `eval/<eval_file>`.
    pub(crate) fn prepare(
        &self,
        name: &str,
        config: &impl Serialize,
        eval_file: &str,
    ) -> anyhow::Result<Option<std::path::PathBuf>> {
        let dir = self.runs.join(name);
        if let (Some(records), true, false) = (self.records, self.restore, dir.exists()) {
            let path = crate::record::path(records, name);
            if path.is_file() {
                let record = crate::record::RunRecord::read(&path)?;
                let written = as_written(config)?;
                if record.config() == Some(&written) {
                    eprintln!(
                        "  [{name}] finished earlier: restored from {}",
                        path.display()
                    );
                    record.restore(&dir, &path)?;
                } else {
                    eprintln!(
                        "  [{name}] {} records another configuration: not used",
                        path.display()
                    );
                }
            }
        }
        // Resumed also under `--only` (which restores no record): a
        // carried run is unfinished, so there is nothing to check it against.
        let carried = self
            .records
            .map(|records| crate::record::in_progress_dir(records, name));
        if let Some(carried) = carried.as_deref().filter(|_| self.train && !dir.exists()) {
            // A carry killed while it swapped copies leaves the copy parked
            // beside its place: put back first.
            crate::run_dir::recover_dir(carried)?;
        }
        if let Some(carried) = carried.filter(|c| self.train && !dir.exists() && c.is_dir()) {
            let written = as_written(config)?;
            let theirs: Value = crate::run_dir::RunDir::read_json(&carried.join("config.json"))?;
            if theirs == written {
                eprintln!(
                    "  [{name}] begun on another machine: resumed from a copy of {}",
                    carried.display()
                );
                crate::run_dir::copy_tree(&carried, &dir)?;
            } else {
                eprintln!(
                    "  [{name}] {} holds another configuration: not used",
                    carried.display()
                );
            }
        }
        let evaluated = dir.join("eval").join(eval_file).is_file();
        if self.train && !evaluated && crate::record::is_restored(&dir) {
            bail!(
                "{} was restored from its record, which holds no eval/{eval_file} (and a record holds no weights to make it): move the folder away to train the run again",
                dir.display()
            );
        }
        if !self.train && !evaluated {
            self.missing
                .lock()
                .unwrap_or_else(|e| e.into_inner())
                .push(name.to_owned());
            return Ok(None);
        }
        Ok(Some(dir))
    }

    /// After a run's evaluations: writes its record where records are kept,
    /// unless the run was restored from one. A record already there is
    /// replaced only by one that extends it (the same outcomes, and more
    /// evaluations); one that holds evaluations this run lacks (`ntg
    /// reproduce --only` reruns a point's main one) is kept, and one that
    /// differs is kept, a line saying so either way. Once the run is
    /// recorded (or restored from its record), its copy carried in
    /// `in-progress/` (if any) is removed.
    pub(crate) fn finish(&self, dir: &Path) -> anyhow::Result<()> {
        use crate::record::{Comparison, RunRecord};
        let Some(records) = self.records else {
            return Ok(());
        };
        let discard_carried = |run: &str, config: Option<&Value>| -> anyhow::Result<()> {
            // Recorded: a copy of the run carried from another machine is
            // done with.
            if let Some(removed) = crate::carry::discard_carried(records, run, config)? {
                eprintln!(
                    "  [{run}] recorded: removed its carried copy {}",
                    removed.display()
                );
            }
            Ok(())
        };
        if crate::record::is_restored(dir) {
            let run = dir
                .file_name()
                .map_or_else(String::new, |n| n.to_string_lossy().into_owned());
            let path = crate::record::path(records, &run);
            if path.is_file() {
                let kept = RunRecord::read(&path)?;
                discard_carried(&run, kept.config())?;
            }
            return Ok(());
        }
        let record = RunRecord::of_run(dir)?;
        let path = crate::record::path(records, &record.run);
        if path.is_file() {
            let kept = RunRecord::read(&path)?;
            match kept.compare(&record) {
                Comparison::Same => {}
                Comparison::Extends => record.write(&path)?,
                Comparison::Within { common: 0, .. } => eprintln!(
                    "  [{}] has no evaluation in common with its record {}: nothing compared; the record is kept",
                    record.run,
                    path.display()
                ),
                Comparison::Within { missing, adds, .. } => {
                    eprintln!(
                        "  [{}] matches its record {} on every evaluation both hold; the record is kept{}{}",
                        record.run,
                        path.display(),
                        if missing.is_empty() {
                            String::new()
                        } else {
                            format!(" (it also holds {})", missing.join(", "))
                        },
                        if adds.is_empty() {
                            String::new()
                        } else {
                            format!(", with this run's {} added", adds.join(", "))
                        }
                    );
                    if !adds.is_empty() {
                        kept.with_evaluations_of(&record, &adds).write(&path)?;
                    }
                }
                Comparison::Differs => {
                    eprintln!(
                        "  [{}] differs from its record {} (kept; delete it to replace it): {}",
                        record.run,
                        path.display(),
                        record.summary()
                    );
                    return Ok(());
                }
            }
        } else {
            record.write(&path)?;
        }
        // A 1000-task run's selected weights beside the records; not
        // keeping them (another configuration's there) leaves the record
        // as written, and says so.
        match crate::carry::keep_selected_weights(
            records,
            &record.run,
            dir,
            &crate::export::keep_in_zoo,
        ) {
            Ok(Some(kept)) => eprintln!(
                "  [{}] selected weights kept in {} ({} files, {:.1} MB)",
                record.run,
                kept.to.display(),
                kept.files,
                kept.bytes as f64 / 1e6
            ),
            Ok(None) => {}
            Err(e) => eprintln!("  [{}] selected weights not kept: {e:#}", record.run),
        }
        discard_carried(&record.run, record.config())
    }
}

/// `config` as a run folder's `config.json` holds it: through text, so
/// that an f32 reads back as the number the file holds.
pub(crate) fn as_written(config: &impl Serialize) -> anyhow::Result<Value> {
    Ok(serde_json::from_str(&serde_json::to_string(config)?)?)
}

/// A run folder's name: `base`, with `-seedS` unless `seed` is the
/// figure's `default` seed (so single-seed folders keep their names).
pub(crate) fn seeded_name(base: String, seed: u64, default: u64) -> String {
    if seed == default {
        base
    } else {
        format!("{base}-seed{seed}")
    }
}

/// Links `part` of the finished run folder `source_run` into `run` (hard
/// links, or copies where the file system has none), so that `run` does not
/// compute it again: only when `run` has no `part` yet, `ready` says the
/// source's `part` is complete, and `same` accepts the source's
/// `config.json` (the settings that decide `part` are equal). Says so on
/// stderr, naming `what`; returns whether it linked.
pub(crate) fn share_part<C: DeserializeOwned>(
    (source_run, part): (&Path, &str),
    run: &crate::run_dir::RunDir,
    ready: impl Fn(&Path) -> anyhow::Result<bool>,
    same: impl Fn(&C) -> bool,
    what: &str,
) -> anyhow::Result<bool> {
    let target = run.root().join(part);
    let source = source_run.join(part);
    if target.exists() || !source.exists() || !ready(&source)? {
        return Ok(false);
    }
    let theirs: C = crate::run_dir::RunDir::read_json(&source_run.join("config.json"))?;
    if !same(&theirs) {
        return Ok(false);
    }
    eprintln!(
        "  [{}] {what} of {} (the same videos and settings)",
        run.root().file_name().unwrap_or_default().to_string_lossy(),
        source_run.display()
    );
    crate::run_dir::link_or_copy_tree(&source, &target)?;
    Ok(true)
}

/// The places for runs training at once, shared by the figures of one
/// `ntg reproduce`: figures that do not depend on each other's runs train
/// side by side, so a core left idle while one figure waits for its
/// longest run takes the next run of another. A run takes a place before
/// it starts and gives it back when it ends; after a failure no run gets
/// one.
#[derive(Debug)]
pub struct Slots {
    count: usize,
    state: std::sync::Mutex<SlotState>,
    changed: std::sync::Condvar,
}

#[derive(Debug)]
struct SlotState {
    free: usize,
    /// Whether a run ever took a place, or [`Slots::open`] was called.
    started: bool,
    /// A run failed: no more places are given.
    failed: bool,
}

impl Slots {
    /// `count` places (at least one).
    pub fn new(count: usize) -> Self {
        let count = count.max(1);
        Slots {
            count,
            state: std::sync::Mutex::new(SlotState {
                free: count,
                started: false,
                failed: false,
            }),
            changed: std::sync::Condvar::new(),
        }
    }

    /// How many runs train at once.
    pub fn count(&self) -> usize {
        self.count
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, SlotState> {
        self.state.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// Waits for a free place and takes it; `None` once a run has failed.
    fn take(&self) -> Option<SlotTaken<'_>> {
        let mut state = self.lock();
        while state.free == 0 && !state.failed {
            state = self.changed.wait(state).unwrap_or_else(|e| e.into_inner());
        }
        if state.failed {
            return None;
        }
        state.free -= 1;
        state.started = true;
        self.changed.notify_all();
        Some(SlotTaken(self))
    }

    /// Waits until some run has taken a place (or [`Slots::open`] was
    /// called): a figure started beside another calls it first, so that
    /// the other's first run (listed first because it is the longest)
    /// starts first.
    pub(crate) fn wait_for_a_start(&self) {
        let mut state = self.lock();
        while !state.started && !state.failed {
            state = self.changed.wait(state).unwrap_or_else(|e| e.into_inner());
        }
    }

    /// Lets [`Slots::wait_for_a_start`] return although no run started
    /// (the figure in front had none to train).
    pub(crate) fn open(&self) {
        self.lock().started = true;
        self.changed.notify_all();
    }

    /// No run gets a place from now on.
    pub(crate) fn fail(&self) {
        self.lock().failed = true;
        self.changed.notify_all();
    }
}

/// A place taken from [`Slots`]; given back when dropped.
struct SlotTaken<'a>(&'a Slots);

impl Drop for SlotTaken<'_> {
    fn drop(&mut self) {
        self.0.lock().free += 1;
        self.0.changed.notify_all();
    }
}

/// One run of a figure, to be started by [`in_parallel`].
pub(crate) type Job<'a, T> = Box<dyn FnOnce() -> anyhow::Result<T> + Send + 'a>;

/// Runs `jobs` (each a run of a figure: trained or reused, then evaluated)
/// in list order, each once it has a place in `slots` (so at most
/// `slots.count()` at once, this call's and other figures' together), and
/// returns their results in that order. A run's result does not depend on
/// which others run beside it (each is seeded on its own), only the wall
/// time does: the figures' runs train with `shards` unset, and each job
/// runs inside a rayon pool of its own with its share of the cores
/// (`current_num_threads / slots.count()`, at least one), so two at once
/// use both cores of a 2-core machine without contending for one pool (the
/// parallel kernels of two runs on one shared pool made each about 2.2x
/// slower). After a job fails no
/// new one starts (here or in another figure), and the first failure in
/// list order is returned. A line on stderr after each run says how many
/// of `what` are done, and the time left at the pace so far (a rough
/// guide: runs differ in size).
pub(crate) fn in_parallel<T: Send>(
    what: &str,
    slots: &Slots,
    jobs: Vec<Job<'_, T>>,
) -> anyhow::Result<Vec<T>> {
    use std::sync::Mutex;
    use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
    let count = jobs.len();
    let started = std::time::Instant::now();
    let finished = AtomicUsize::new(0);
    let queue = Mutex::new(jobs.into_iter().enumerate());
    let results: Mutex<Vec<Option<anyhow::Result<T>>>> =
        Mutex::new((0..count).map(|_| None).collect());
    let failed = AtomicBool::new(false);
    let threads_per_job = (rayon::current_num_threads() / slots.count()).max(1);
    std::thread::scope(|scope| {
        for _ in 0..slots.count().min(count) {
            scope.spawn(|| {
                ntg_model::apply_float_mode();
                let pool = ntg_model::compute_pool_builder(threads_per_job)
                    .thread_name(|i| format!("run-worker-{i}"))
                    .build();
                while !failed.load(Ordering::SeqCst) {
                    let Some(_slot) = slots.take() else { break };
                    let next = queue.lock().unwrap_or_else(|e| e.into_inner()).next();
                    let Some((index, job)) = next else { break };
                    let result = match &pool {
                        Ok(pool) => {
                            let _running = crate::fit::RunningJob::start();
                            pool.install(job)
                        }
                        Err(e) => Err(anyhow::anyhow!("could not start a run's threads: {e}")),
                    };
                    if result.is_err() {
                        failed.store(true, Ordering::SeqCst);
                        slots.fail();
                    }
                    let done = finished.fetch_add(1, Ordering::SeqCst) + 1;
                    let seconds = started.elapsed().as_secs_f64();
                    eprintln!(
                        "{what}: {done} of {count} runs done, {seconds:.0} s; about {:.0} s left at this pace",
                        seconds / done as f64 * (count - done) as f64
                    );
                    results.lock().unwrap_or_else(|e| e.into_inner())[index] = Some(result);
                }
            });
        }
    });
    let results = results.into_inner().unwrap_or_else(|e| e.into_inner());
    let mut done = Vec::with_capacity(count);
    for result in results {
        match result {
            Some(result) => done.push(result?),
            None => bail!("another run failed, so this one was not started"),
        }
    }
    Ok(done)
}

/// One table per profile.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Profiles<P> {
    /// `smoke`.
    pub smoke: P,
    /// `quick`.
    pub quick: P,
    /// `paper`.
    pub paper: P,
}

impl<P> Profiles<P> {
    /// The table of `profile`.
    pub fn get(&self, profile: Profile) -> &P {
        match profile {
            Profile::Smoke => &self.smoke,
            Profile::Quick => &self.quick,
            Profile::Paper => &self.paper,
        }
    }
}

/// A profile's table that only sets fields of the run configuration.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ProfileOverrides {
    /// Fields of the run configuration set at this profile.
    #[serde(default)]
    pub overrides: toml::Table,
}

/// Where experiment files are read from.
#[derive(Debug, Clone, Copy, Default)]
pub enum Source<'a> {
    /// The copies compiled into the binary.
    #[default]
    BuiltIn,
    /// `DIR/NAME.toml`.
    Dir(&'a Path),
}

/// Reads and parses experiment `name` (e.g. `ntp_exp`) from `source`, and
/// says where it came from (for messages); errors name the file and the
/// problem.
pub fn load<T: DeserializeOwned>(name: &str, source: Source<'_>) -> anyhow::Result<(T, String)> {
    let (text, origin) = match source {
        Source::BuiltIn => {
            let text = BUILT_IN
                .iter()
                .find(|(n, _)| *n == name)
                .map(|(_, t)| (*t).to_owned())
                .with_context(|| format!("no built-in experiment named {name}"))?;
            (text, format!("experiments/{name}.toml (built in)"))
        }
        Source::Dir(dir) => {
            let path = dir.join(format!("{name}.toml"));
            let text = std::fs::read_to_string(&path)
                .with_context(|| format!("reading {}", path.display()))?;
            (text, path.display().to_string())
        }
    };
    let value = toml::from_str(&text).with_context(|| format!("{origin}: invalid experiment"))?;
    Ok((value, origin))
}

/// `base` with the fields named in `overrides` replaced (nested tables
/// replace nested fields). Every key must name a field of `C`, so a
/// misspelt key is an error, not a silently ignored setting. A field that
/// `base`'s serialisation leaves out (one skipped at its default, such as
/// `video.encoder_labels`) can be set too: a key `base` does not have is
/// added, and refused only if deserialising `C` ignores it.
pub fn with_overrides<C>(base: &C, overrides: &toml::Table, what: &str) -> anyhow::Result<C>
where
    C: Serialize + DeserializeOwned,
{
    let context = || format!("applying the overrides of {what}");
    let mut value = serde_json::to_value(base)?;
    let overrides = serde_json::to_value(overrides)?;
    let mut added = Vec::new();
    merge(&mut value, &overrides, "", &mut added).with_context(context)?;
    let mut ignored = Vec::new();
    // serde_ignored names an `Option`'s content `?` (`video.?.x`).
    let config = serde_ignored::deserialize(value, |path| {
        let path = path.to_string();
        let keys: Vec<&str> = path.split('.').filter(|key| *key != "?").collect();
        ignored.push(keys.join("."));
    })
    .with_context(context)?;
    let unread = |name: &str| {
        ignored
            .iter()
            .any(|path| path == name || path.starts_with(&format!("{name}.")))
    };
    if let Some(AddedKey { name, known }) = added.iter().find(|key| unread(&key.name)) {
        return Err(anyhow::anyhow!(
            "unknown setting `{name}` (known here: {known})"
        ))
        .with_context(context);
    }
    Ok(config)
}

/// A key of a figure's overrides that the base config's serialisation did
/// not have, and the keys it had at that level (for the error naming it).
struct AddedKey {
    name: String,
    known: String,
}

/// A reduced profile's score of `run`'s starting weights (`initial/`) on
/// the test set its trained model is scored on (`evaluate`), cached in
/// `eval/untrained-EVAL_FILE`: the value each point must beat to show that
/// it learned. `None` at the paper profile, which does not show it, and
/// where the run kept no starting weights (begun before they were kept, or
/// restored from its record).
pub(crate) fn untrained_eval<T: Serialize + DeserializeOwned>(
    run: &crate::run_dir::RunDir,
    profile: Profile,
    eval_file: &str,
    evaluate: impl FnOnce() -> anyhow::Result<T>,
) -> anyhow::Result<Option<T>> {
    if profile == Profile::Paper || !run.initial_dir().is_dir() {
        return Ok(None);
    }
    run.cached_eval(&format!("untrained-{eval_file}"), evaluate)
        .map(Some)
}

/// Whether `trained` is above `untrained`: its 95% interval's lower end
/// above the untrained rate (a margin of 1e-9 absorbs the rounding of a
/// lower end that is 0 in exact arithmetic).
pub(crate) fn above_untrained(
    trained: &crate::stats::SuccessRate,
    untrained: &crate::stats::SuccessRate,
) -> bool {
    trained.ci_low > untrained.rate + 1e-9
}

/// The report's word for [`above_untrained`].
pub(crate) fn learning_verdict(
    trained: &crate::stats::SuccessRate,
    untrained: &crate::stats::SuccessRate,
) -> &'static str {
    if above_untrained(trained, untrained) {
        "above"
    } else {
        "**not above**"
    }
}

/// The start of a figure's report section: `heading` (a Markdown heading
/// and any text under it) and a blank line. `Err` holds the whole section
/// when `trained` is false: the heading and a line saying no run of it has
/// trained yet at this profile.
pub(crate) fn open_section(heading: &str, trained: bool) -> Result<String, String> {
    let head = format!("{heading}\n\n");
    if trained {
        Ok(head)
    } else {
        Err(head + &template::REPORT.text("not_trained") + "\n\n")
    }
}

/// `overrides` as `a.b = value` settings separated by commas, in key
/// order ("none" when empty): how a report names what a figure's
/// file changes in its recipe.
pub fn overrides_text(overrides: &toml::Table) -> String {
    fn flatten(table: &toml::Table, path: &str, out: &mut Vec<String>) {
        for (key, value) in table {
            let name = if path.is_empty() {
                key.clone()
            } else {
                format!("{path}.{key}")
            };
            match value {
                toml::Value::Table(inner) => flatten(inner, &name, out),
                other => out.push(format!("`{name} = {other}`")),
            }
        }
    }
    let mut out = Vec::new();
    flatten(overrides, "", &mut out);
    if out.is_empty() {
        "none".to_owned()
    } else {
        out.join(", ")
    }
}

/// `overrides` written into `base`, key by key (tables into tables). A key
/// `base` lacks is added and listed in `added`: it may name a field that
/// `base`'s serialisation skipped, or be a typo ([`with_overrides`] tells
/// them apart).
fn merge(
    base: &mut Value,
    overrides: &Value,
    path: &str,
    added: &mut Vec<AddedKey>,
) -> anyhow::Result<()> {
    let (Value::Object(base), Value::Object(overrides)) = (base, overrides) else {
        bail!("{path} is not a table");
    };
    for (key, new) in overrides {
        let name = if path.is_empty() {
            key.clone()
        } else {
            format!("{path}.{key}")
        };
        match base.get_mut(key) {
            Some(old) if old.is_object() && new.is_object() => merge(old, new, &name, added)?,
            Some(old) => *old = new.clone(),
            None => {
                let known: Vec<&str> = base.keys().map(String::as_str).collect();
                added.push(AddedKey {
                    name,
                    known: known.join(", "),
                });
                base.insert(key.clone(), new.clone());
            }
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fit::OptimConfig;

    fn optim() -> OptimConfig {
        OptimConfig {
            epochs: 1,
            batch_size: 32,
            learning_rate: 1e-3,
            seed: 0,
            token_dropout: 0.0,
            gcn_from_other_demo: false,
            cosine_decay: false,
            shards: 1,
        }
    }

    #[test]
    fn a_run_carried_in_progress_is_resumed_from_a_copy() {
        let tmp = tempfile::tempdir().unwrap();
        let records = tmp.path().join("figures/records");
        let carried = crate::record::in_progress_dir(&records, "r");
        assert!(carried.ends_with("figures/in-progress/r"));
        std::fs::create_dir_all(carried.join("checkpoint")).unwrap();
        let config = serde_json::json!({"seed": 1, "method": "ntp"});
        std::fs::write(carried.join("config.json"), config.to_string()).unwrap();
        std::fs::write(carried.join("metrics.jsonl"), "{\"epoch\":0}\n").unwrap();
        std::fs::write(carried.join("checkpoint/progress.json"), "{}").unwrap();
        let runs = tmp.path().join("runs");
        let plan = |train: bool| Plan {
            records: Some(&records),
            restore: true,
            train,
            ..Plan::train_all(&runs, 1)
        };
        // Not when nothing is trained, nor for another configuration.
        assert_eq!(plan(false).prepare("r", &config, "e.json").unwrap(), None);
        assert!(!runs.join("r").exists());
        let other = serde_json::json!({"seed": 2, "method": "ntp"});
        plan(true).prepare("r", &other, "e.json").unwrap();
        assert!(!runs.join("r").exists());
        let dir = plan(true).prepare("r", &config, "e.json").unwrap().unwrap();
        assert_eq!(dir, runs.join("r"));
        assert!(dir.join("checkpoint/progress.json").is_file());
        // A copy: training appends to it, the carried folder stays.
        crate::run_dir::RunDir::append_jsonl(
            &dir.join("metrics.jsonl"),
            &serde_json::json!({"epoch": 1}),
        )
        .unwrap();
        let kept = std::fs::read_to_string(carried.join("metrics.jsonl")).unwrap();
        assert_eq!(kept.lines().count(), 1);
        // An existing folder is never replaced.
        std::fs::remove_file(dir.join("checkpoint/progress.json")).unwrap();
        plan(true).prepare("r", &config, "e.json").unwrap();
        assert!(!dir.join("checkpoint/progress.json").exists());
        // `--only` restores no record but resumes a carried run.
        std::fs::remove_dir_all(&dir).unwrap();
        let only = Plan {
            restore: false,
            ..plan(true)
        };
        only.prepare("r", &config, "e.json").unwrap();
        assert!(dir.join("checkpoint/progress.json").is_file());
        // Recorded: the carried copy is done with and removed.
        plan(true).finish(&dir).unwrap();
        assert!(crate::record::path(&records, "r").is_file());
        assert!(!carried.exists());
    }

    #[test]
    fn a_record_is_replaced_only_by_one_that_extends_it() {
        use crate::record::RunRecord;
        let tmp = tempfile::tempdir().unwrap();
        let records = tmp.path().join("figures/records");
        let runs = tmp.path().join("runs");
        let plan = Plan {
            records: Some(&records),
            restore: true,
            ..Plan::train_all(&runs, 1)
        };
        let dir = runs.join("r");
        std::fs::create_dir_all(dir.join("eval")).unwrap();
        let config = serde_json::json!({"seed": 1});
        std::fs::write(dir.join("config.json"), config.to_string()).unwrap();
        let eval = |name: &str, success: bool| {
            std::fs::write(
                dir.join("eval").join(name),
                serde_json::json!({"tasks": [{"success": success}]}).to_string(),
            )
            .unwrap()
        };
        let recorded = || RunRecord::read(&crate::record::path(&records, "r")).unwrap();
        eval("full-1.json", true);
        plan.finish(&dir).unwrap();
        assert_eq!(recorded().files.len(), 2);
        // More evaluations, the same outcomes: written.
        eval("structure-full-1.json", false);
        plan.finish(&dir).unwrap();
        assert!(recorded().files.contains_key("eval/structure-full-1.json"));
        // A rerun of the main evaluation alone (`--only` in a fresh
        // folder) matches on it and keeps the record whole; so does one
        // that a carried copy waits for, which is then removed.
        std::fs::remove_file(dir.join("eval/structure-full-1.json")).unwrap();
        let carried = crate::record::in_progress_dir(&records, "r");
        std::fs::create_dir_all(&carried).unwrap();
        std::fs::write(carried.join("config.json"), config.to_string()).unwrap();
        plan.finish(&dir).unwrap();
        assert!(recorded().files.contains_key("eval/structure-full-1.json"));
        assert!(!carried.exists());
        let kept = recorded();
        assert!(matches!(
            kept.compare(&RunRecord::of_run(&dir).unwrap()),
            crate::record::Comparison::Within { missing, .. } if missing == ["eval/structure-full-1.json"]
        ));
        // One that also brings an evaluation the record lacks: added to it.
        eval("seen-full-1.json", true);
        plan.finish(&dir).unwrap();
        let kept = recorded();
        assert!(kept.files.contains_key("eval/structure-full-1.json"));
        assert!(kept.files.contains_key("eval/seen-full-1.json"));
        // Other outcomes: the record is kept as it was.
        eval("full-1.json", false);
        eval("structure-full-1.json", false);
        eval("seen-full-1.json", false);
        plan.finish(&dir).unwrap();
        assert_eq!(recorded(), kept);
        // A folder restored from the record writes nothing, but a copy
        // carried before the run was recorded is done with.
        let restored = runs.join("again");
        std::fs::create_dir_all(&carried).unwrap();
        std::fs::write(carried.join("config.json"), config.to_string()).unwrap();
        let named = crate::record::path(&records, "again");
        std::fs::copy(crate::record::path(&records, "r"), &named).unwrap();
        let again = crate::record::in_progress_dir(&records, "again");
        std::fs::create_dir_all(&again).unwrap();
        std::fs::write(again.join("config.json"), config.to_string()).unwrap();
        kept.restore(&restored, &named).unwrap();
        plan.finish(&restored).unwrap();
        // Asked for an evaluation its record lacks: a clear error, not a
        // training that finds no weights.
        let err = plan
            .prepare("again", &config, "other-7.json")
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("restored from its record") && err.contains("eval/other-7.json"),
            "{err}"
        );
        assert!(!again.exists());
        assert!(carried.exists());
        assert_eq!(RunRecord::read(&named).unwrap(), kept);
    }

    #[test]
    fn share_part_links_a_finished_part_only_between_matching_runs() {
        use crate::run_dir::RunDir;
        let tmp = tempfile::tempdir().unwrap();
        let config = |seed: u64, method: &str| serde_json::json!({"seed": seed, "method": method});
        let source = RunDir::open_or_create(&tmp.path().join("a"), &config(0, "ntg")).unwrap();
        std::fs::create_dir_all(source.root().join("part")).unwrap();
        std::fs::write(source.root().join("part/data.bin"), b"encoder").unwrap();
        let same_seed = |mine: Value| move |theirs: &Value| theirs["seed"] == mine["seed"];
        let share = |run: &RunDir, ready: bool| {
            share_part(
                (source.root(), "part"),
                run,
                |_: &Path| Ok(ready),
                same_seed(config(run.root().ends_with("c") as u64, "")),
                "the part",
            )
            .unwrap()
        };
        let b = RunDir::open_or_create(&tmp.path().join("b"), &config(0, "flat")).unwrap();
        assert!(!share(&b, false), "not finished: nothing linked");
        assert!(!b.root().join("part").exists());
        assert!(share(&b, true));
        assert_eq!(
            std::fs::read(b.root().join("part/data.bin")).unwrap(),
            b"encoder"
        );
        assert!(!share(&b, true), "a part the run has is kept");
        let c = RunDir::open_or_create(&tmp.path().join("c"), &config(1, "flat")).unwrap();
        assert!(!share(&c, true), "another seed: nothing linked");
        assert!(!c.root().join("part").exists());
    }

    #[test]
    fn overrides_replace_named_fields_and_refuse_unknown_ones() {
        let table: toml::Table =
            toml::from_str("learning_rate = 3e-3\ncosine_decay = true").unwrap();
        let c = with_overrides(&optim(), &table, "test").unwrap();
        assert_eq!(c.learning_rate, 3e-3);
        assert!(c.cosine_decay);
        assert_eq!(c.batch_size, 32);
        let typo: toml::Table = toml::from_str("learning_rte = 3e-3").unwrap();
        let err = format!(
            "{:#}",
            with_overrides(&optim(), &typo, "x.toml").unwrap_err()
        );
        assert!(
            err.contains("x.toml") && err.contains("unknown setting `learning_rte`"),
            "{err}"
        );
        let wrong_type: toml::Table = toml::from_str("epochs = \"many\"").unwrap();
        assert!(with_overrides(&optim(), &wrong_type, "x.toml").is_err());
    }

    #[test]
    fn overrides_set_fields_their_base_leaves_out_at_the_default() {
        use crate::domain::blocks::{FrameLabels, ObsKind, Recipe};
        let base = Recipe::Paper.config(ObsKind::Vid, 4, 2, 1, 0);
        let json = serde_json::to_value(&base).unwrap();
        assert!(
            json["video"].get("encoder_labels").is_none(),
            "the field is left out at its default: {}",
            json["video"]
        );
        let table: toml::Table = toml::from_str("[video]\nencoder_labels = \"primitive\"").unwrap();
        let c = with_overrides(&base, &table, "fig.toml").unwrap();
        assert_eq!(
            c.video.as_ref().unwrap().encoder_labels,
            FrameLabels::Primitive
        );
        // A key the base leaves out and no field reads is still a typo.
        let typo: toml::Table = toml::from_str("[video]\nencoder_lables = \"primitive\"").unwrap();
        let err = format!(
            "{:#}",
            with_overrides(&base, &typo, "fig.toml").unwrap_err()
        );
        assert!(
            err.contains("fig.toml") && err.contains("unknown setting `video.encoder_lables`"),
            "{err}"
        );
    }

    #[test]
    fn parallel_jobs_keep_their_order_and_the_first_failure_wins() {
        let jobs: Vec<Job<'static, usize>> = (0..7_usize)
            .map(|i| {
                Box::new(move || {
                    std::thread::sleep(std::time::Duration::from_millis(7 - i as u64));
                    Ok(i * 10)
                }) as Job<'static, usize>
            })
            .collect();
        assert_eq!(
            in_parallel("test", &Slots::new(3), jobs).unwrap(),
            vec![0, 10, 20, 30, 40, 50, 60]
        );
        let jobs: Vec<Job<'static, usize>> = vec![
            Box::new(|| Ok(1)),
            Box::new(|| bail!("run two broke")),
            Box::new(|| bail!("run three broke")),
        ];
        let err = in_parallel("test", &Slots::new(1), jobs)
            .unwrap_err()
            .to_string();
        assert_eq!(err, "run two broke");
        assert!(
            in_parallel::<usize>("test", &Slots::new(2), Vec::new())
                .unwrap()
                .is_empty()
        );
    }

    #[test]
    fn each_job_computes_on_its_share_of_the_cores() {
        // Inside a 4-thread pool, 2 places: each job sees a pool of 2
        // threads of its own, not the caller's.
        let outer = rayon::ThreadPoolBuilder::new()
            .num_threads(4)
            .build()
            .unwrap();
        let job = || -> Job<'static, (usize, bool)> {
            Box::new(|| {
                let name = std::thread::current().name().map(str::to_owned);
                Ok((
                    rayon::current_num_threads(),
                    rayon::current_thread_index().is_some()
                        && name.is_some_and(|n| n.starts_with("run-worker-")),
                ))
            })
        };
        let seen = outer
            .install(|| in_parallel("test", &Slots::new(2), vec![job(), job(), job()]))
            .unwrap();
        assert_eq!(seen, vec![(2, true); 3]);
    }

    #[test]
    fn figures_side_by_side_share_the_places_and_a_failure_stops_both() {
        use std::sync::atomic::{AtomicUsize, Ordering};
        let slots = Slots::new(2);
        let (running, most) = (AtomicUsize::new(0), AtomicUsize::new(0));
        let job = |i: usize| {
            let (running, most) = (&running, &most);
            Box::new(move || {
                let now = running.fetch_add(1, Ordering::SeqCst) + 1;
                most.fetch_max(now, Ordering::SeqCst);
                std::thread::sleep(std::time::Duration::from_millis(3));
                running.fetch_sub(1, Ordering::SeqCst);
                Ok(i)
            }) as Job<'_, usize>
        };
        let (a, b) = std::thread::scope(|scope| {
            let b = scope.spawn(|| {
                slots.wait_for_a_start();
                in_parallel("b", &slots, (10..16).map(job).collect())
            });
            let a = in_parallel("a", &slots, (0..6).map(job).collect());
            (a, b.join().unwrap())
        });
        assert_eq!(a.unwrap(), (0..6).collect::<Vec<_>>());
        assert_eq!(b.unwrap(), (10..16).collect::<Vec<_>>());
        assert_eq!(most.load(Ordering::SeqCst), 2, "two places, both used");

        // Nothing to run in front: `open` lets the other figure go.
        let slots = Slots::new(2);
        std::thread::scope(|scope| {
            let b = scope.spawn(|| {
                slots.wait_for_a_start();
                in_parallel(
                    "b",
                    &slots,
                    vec![Box::new(|| Ok(1_usize)) as Job<'_, usize>],
                )
            });
            slots.open();
            assert_eq!(b.join().unwrap().unwrap(), vec![1]);
        });

        // A failure in one figure: the other starts no new run.
        let slots = Slots::new(1);
        let err = in_parallel::<usize>("a", &slots, vec![Box::new(|| bail!("broke"))]);
        assert_eq!(err.unwrap_err().to_string(), "broke");
        let err = in_parallel(
            "b",
            &slots,
            vec![Box::new(|| Ok(1_usize)) as Job<'_, usize>],
        );
        assert!(err.unwrap_err().to_string().contains("another run failed"));
    }

    #[test]
    fn overrides_are_named_as_flat_settings() {
        let table: toml::Table =
            toml::from_str("pairwise = true\noptim = { learning_rate = 0.003, epochs = 2 }")
                .unwrap();
        assert_eq!(
            overrides_text(&table),
            "`optim.epochs = 2`, `optim.learning_rate = 0.003`, `pairwise = true`"
        );
        assert_eq!(overrides_text(&toml::Table::new()), "none");
    }

    #[test]
    fn every_built_in_experiment_parses() {
        let e = ntp_exp::NtpExpExperiment::load(Source::BuiltIn).unwrap();
        assert_eq!(e.origin, "experiments/ntp_exp.toml (built in)");
        thor_all::ThorAllExperiment::load(Source::BuiltIn).unwrap();
        let err = format!(
            "{:#}",
            load::<ntp_exp::NtpExpExperiment>("nope", Source::BuiltIn).unwrap_err()
        );
        assert!(err.contains("nope"), "{err}");
    }

    #[test]
    fn experiment_files_from_a_folder_name_the_file_in_errors() {
        let dir = tempfile::tempdir().unwrap();
        std::fs::write(dir.path().join("ntp_exp.toml"), "domain = [").unwrap();
        let err = format!(
            "{:#}",
            load::<ntp_exp::NtpExpExperiment>("ntp_exp", Source::Dir(dir.path())).unwrap_err()
        );
        assert!(
            err.contains("ntp_exp.toml") && err.contains("invalid"),
            "{err}"
        );
        let err = format!(
            "{:#}",
            load::<ntp_exp::NtpExpExperiment>("thor_all", Source::Dir(dir.path())).unwrap_err()
        );
        assert!(err.contains("thor_all.toml"), "{err}");
    }

    #[test]
    fn a_misspelt_setting_in_an_edited_copy_is_an_error_naming_the_copy() {
        let dir = tempfile::tempdir().unwrap();
        let (_, built_in) = BUILT_IN.iter().find(|(n, _)| *n == "ntp_exp").unwrap();
        let edited = built_in.replace("pairwise = true", "pairwse = true");
        assert_ne!(&edited, built_in);
        std::fs::write(dir.path().join("ntp_exp.toml"), edited).unwrap();
        let experiment = ntp_exp::NtpExpExperiment::load(Source::Dir(dir.path())).unwrap();
        let err = format!("{:#}", experiment.run_configs(Profile::Quick).unwrap_err());
        assert!(
            err.contains("ntp_exp.toml") && err.contains("unknown setting `pairwse`"),
            "{err}"
        );
        assert!(!err.contains("built in"), "{err}");
    }

    /// Every run of the paper profile: folder name and configuration as
    /// its `config.json` would hold it.
    fn paper_runs() -> std::collections::BTreeMap<String, Value> {
        let mut runs = std::collections::BTreeMap::new();
        let paper = Profile::Paper;
        for figure in [
            ntp_exp::NtpExpExperiment::load(Source::BuiltIn).unwrap(),
            ablation::load(Source::BuiltIn).unwrap(),
            structure::load(Source::BuiltIn).unwrap(),
        ] {
            for (name, config) in figure.named_run_configs(paper).unwrap() {
                runs.insert(name, as_written(&config).unwrap());
            }
        }
        let sorting = ablation::AblationBExperiment::load(Source::BuiltIn).unwrap();
        for seed in sorting.seeds(paper) {
            for &variant in &sorting.ablations {
                let config = sorting.run_config(paper, variant, seed).unwrap();
                runs.insert(
                    sorting.run_name(variant, seed),
                    as_written(&config).unwrap(),
                );
            }
        }
        let thor_all = thor_all::ThorAllExperiment::load(Source::BuiltIn).unwrap();
        for run in thor_all.runs(paper) {
            let config = thor_all.run_config(paper, run).unwrap();
            runs.insert(thor_all.run_name(paper, run), as_written(&config).unwrap());
        }
        runs
    }

    /// The top-level fields in which two configurations differ.
    fn differing_fields(a: &Value, b: &Value) -> Vec<String> {
        let (Some(a), Some(b)) = (a.as_object(), b.as_object()) else {
            return vec!["(not both objects)".into()];
        };
        let mut keys: Vec<&String> = a.keys().chain(b.keys()).collect();
        keys.sort();
        keys.dedup();
        keys.into_iter()
            .filter(|k| a.get(*k) != b.get(*k))
            .map(|k| {
                let shown = |v: Option<&Value>| v.map_or("absent".to_string(), Value::to_string);
                format!("{k}: {} recorded, {} now", shown(a.get(k)), shown(b.get(k)))
            })
            .collect()
    }

    /// The committed paper-profile results (`docs/figures/records/`, days
    /// of CPU) and the carried unfinished runs (`docs/figures/in-progress/`)
    /// are reused only while they hold exactly the configuration the paper
    /// profile trains their run with. A change to a run configuration's
    /// fields (a new field that serialises where older files lack it) or to
    /// an experiment file that would make `ntg reproduce --profile paper`
    /// pass over a record ("records another configuration: not used") or a
    /// carried run fails here, at once, instead.
    #[test]
    fn committed_paper_records_hold_the_configurations_the_paper_profile_trains() {
        let figures = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../docs/figures");
        let records = figures.join("records");
        if !records.is_dir() {
            eprintln!(
                "skipped: no {} (not a checkout of the repository)",
                records.display()
            );
            return;
        }
        let planned = paper_runs();
        let mut checked = 0;
        let mut problems = Vec::new();
        for entry in std::fs::read_dir(&records).unwrap() {
            let path = entry.unwrap().path();
            let Some(name) = path.file_stem().and_then(|n| n.to_str()) else {
                continue;
            };
            let record = crate::record::RunRecord::read(&path).unwrap();
            match (planned.get(name), record.config()) {
                (None, _) => problems.push(format!(
                    "{name}: recorded, but no paper-profile run has this name"
                )),
                (Some(_), None) => {
                    problems.push(format!("{name}: its record holds no config.json"))
                }
                (Some(now), Some(recorded)) if now != recorded => problems.push(format!(
                    "{name}: another configuration: {}",
                    differing_fields(recorded, now).join("; ")
                )),
                _ => checked += 1,
            }
        }
        // The run folders under `folder` (beside its README), each with its
        // name and configuration.
        let run_copies = |folder: &str| -> Vec<(String, Value)> {
            let folder = figures.join(folder);
            if !folder.is_dir() {
                return Vec::new();
            }
            std::fs::read_dir(&folder)
                .unwrap()
                .map(|entry| entry.unwrap().path())
                .filter(|dir| dir.is_dir())
                .map(|dir| {
                    let name = dir.file_name().unwrap().to_string_lossy().into_owned();
                    let config = crate::run_dir::RunDir::read_json(&dir.join("config.json"));
                    (name, config.unwrap())
                })
                .collect()
        };
        for (name, config) in run_copies("in-progress") {
            match planned.get(&name) {
                None => problems.push(format!(
                    "in-progress/{name}: no paper-profile run has this name"
                )),
                Some(now) if *now != config => problems.push(format!(
                    "in-progress/{name}: another configuration: {}",
                    differing_fields(&config, now).join("; ")
                )),
                _ => checked += 1,
            }
        }
        // Kept selected weights belong to a recorded run of the same
        // configuration.
        for (name, config) in run_copies("weights") {
            let record = crate::record::path(&records, &name);
            if !record.is_file() {
                problems.push(format!("weights/{name}: no record of this run"));
                continue;
            }
            let recorded = crate::record::RunRecord::read(&record).unwrap();
            if recorded.config() != Some(&config) {
                problems.push(format!(
                    "weights/{name}: another configuration than its record's"
                ));
            }
            // As safetensors, with their name map (`export::keep_in_zoo`).
            let entry = figures.join("weights").join(&name);
            for needed in ["best/model.safetensors", crate::export::NAMES_FILE] {
                if !entry.join(needed).is_file() {
                    problems.push(format!("weights/{name}: no {needed}"));
                }
            }
        }
        assert!(problems.is_empty(), "{}", problems.join("\n"));
        assert!(checked > 0, "no record checked in {}", records.display());
    }
}
