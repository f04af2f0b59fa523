//! Run folders: where a training run keeps its config, dataset cache,
//! metrics and checkpoints.
//!
//! ```text
//! runs/NAME/
//!   config.json      the run's configuration (written once, checked on resume)
//!   dataset/         the demonstration cache (see `dataset`)
//!   metrics.jsonl    one JSON object per epoch, appended as training goes:
//!                    the method's fields, `seconds` (wall time of the
//!                    epoch's steps) and, where the run had its process to
//!                    itself (Linux), `cpu_seconds` (the process's CPU time
//!                    over those steps, every thread)
//!   events.out.tfevents.*
//!                    the same, and the validation scores, as TensorBoard
//!                    event files: one per training session (`events`)
//!   checkpoint/      latest weights, optimiser state and progress
//!   validation.jsonl per epoch, the score on the validation tasks (if any)
//!   best/            the weights of the epoch that scored best on them,
//!                    and `selection.json` saying which epoch that was
//!   eval/            evaluation results
//!   train.lock       while a process writes the run (trains or evaluates
//!                    it): its process id, the file held with an OS lock
//!   stage_a/, detector_stage/
//!                    a stage trained before the run's model (a video
//!                    run's frame encoder, NTP (Detector)'s detector): a
//!                    run folder of its own
//! ```
//!
//! Nothing the user wrote is overwritten: creating a run in a non-empty
//! folder is an error unless the caller resumes it. A run has one writer at
//! a time: training and evaluation hold [`RunDir::lock`], and a second
//! process that tries is told which process holds it. The lock is the OS's
//! (`flock` on Unix) on `train.lock`, so the kernel releases it when its
//! process dies, however it dies: a killed run's file is taken over by the
//! next writer, with no guessing from process ids.

use std::fs::{self, OpenOptions};
use std::io::Write;
use std::path::{Path, PathBuf};

use anyhow::{Context, bail};
use serde::Serialize;
use serde::de::DeserializeOwned;

/// The file a run folder restored from a committed record holds instead of
/// weights (the record's path): its training is finished, elsewhere.
pub const RESTORED_MARKER: &str = "restored-from-record.txt";

/// Whether the run folder `dir` was restored from a record (it has no
/// weights).
pub fn is_restored(dir: &Path) -> bool {
    dir.join(RESTORED_MARKER).is_file()
}

/// Fills the new folder `to` with the files of `from` (recursively),
/// hard-linked where the file system allows and copied where not; built
/// under a temporary name and renamed at the end, so a kill leaves `to`
/// absent or whole.
pub fn link_or_copy_tree(from: &Path, to: &Path) -> anyhow::Result<()> {
    fill_tree(from, to, true)
}

/// Copies the folder `from` to `to` (which must not exist), file by file,
/// never linking: for a tree whose copy will be written to while the
/// original must stay as it is (a run carried between machines in
/// `docs/figures/in-progress/`). Like [`link_or_copy_tree`], through
/// `to.partial`.
pub fn copy_tree(from: &Path, to: &Path) -> anyhow::Result<()> {
    fill_tree(from, to, false)
}

fn fill_tree(from: &Path, to: &Path, link: bool) -> anyhow::Result<()> {
    fn fill(from: &Path, to: &Path, link: bool) -> anyhow::Result<()> {
        fs::create_dir_all(to).with_context(|| format!("creating {}", to.display()))?;
        for entry in fs::read_dir(from).with_context(|| format!("reading {}", from.display()))? {
            let entry = entry?;
            let (source, target) = (entry.path(), to.join(entry.file_name()));
            if entry.file_name() == LOCK_FILE {
                // The lock of whoever writes `from`, not part of its run.
                continue;
            }
            if entry.file_type()?.is_dir() {
                fill(&source, &target, link)?;
            } else if !link || fs::hard_link(&source, &target).is_err() {
                fs::copy(&source, &target).with_context(|| {
                    format!("copying {} to {}", source.display(), target.display())
                })?;
            }
        }
        Ok(())
    }
    // Appended, not `with_extension`: a run name may hold a dot
    // (`x-0.5` would stage in `x-0.partial`, shared with `x-0.7`).
    let name = to.file_name().map(|n| n.to_string_lossy().into_owned());
    let partial = to.with_file_name(format!("{}.partial", name.unwrap_or_default()));
    if partial.exists() {
        fs::remove_dir_all(&partial)
            .with_context(|| format!("removing the unfinished {}", partial.display()))?;
    }
    fill(from, &partial, link)?;
    fs::rename(&partial, to)
        .with_context(|| format!("renaming {} to {}", partial.display(), to.display()))
}

/// Name of a run's per-epoch metrics file.
const METRICS_FILE: &str = "metrics.jsonl";

/// The writer lock's file name in a run folder.
pub const LOCK_FILE: &str = "train.lock";

/// A held run-folder lock ([`RunDir::lock`]); dropping the last guard of
/// a folder releases it.
#[derive(Debug)]
pub struct RunLock {
    path: PathBuf,
}

/// One run-folder lock this process holds: the lock file's path, its open
/// file (holding the OS lock), the thread that took it and how many of its
/// guards are alive.
struct HeldLock {
    path: PathBuf,
    file: fs::File,
    thread: std::thread::ThreadId,
    guards: usize,
}

/// The run-folder locks this process holds. A thread that holds a folder's
/// lock may take it again (a run's training holds it from its first cache
/// to its last epoch, and the epoch loop takes it too); any other thread is
/// refused, as another process is.
static HELD_LOCKS: std::sync::Mutex<Vec<HeldLock>> = std::sync::Mutex::new(Vec::new());

fn held_locks() -> std::sync::MutexGuard<'static, Vec<HeldLock>> {
    HELD_LOCKS.lock().unwrap_or_else(|e| e.into_inner())
}

impl Drop for RunLock {
    fn drop(&mut self) {
        let mut held = held_locks();
        let Some(i) = held.iter().position(|h| h.path == self.path) else {
            return;
        };
        held[i].guards -= 1;
        if held[i].guards == 0 {
            let last = held.swap_remove(i);
            // Removed while still locked, then unlocked by closing: a
            // process that opened the file meanwhile finds, once it has
            // the lock, that the path no longer names its file, and opens
            // it again ([`RunDir::lock`]).
            // (Off Unix the file stays: there a file's identity is not
            // checked after locking, so a removed file could get two
            // holders.)
            if cfg!(unix) {
                let _ = fs::remove_file(&last.path);
            }
            drop(last.file);
        }
    }
}

/// What a lock file holds after this process's id: it was written by an
/// `ntg` that holds OS locks (a file without it is from an older one).
const OS_LOCK_TAG: &str = "os-lock";

/// The command line of process `pid`, if it is a live process other than
/// this one (on Linux, from `/proc`: a process, not a thread of one, and
/// not a zombie; elsewhere not known, `None`).
fn another_live_process(pid: u32) -> Option<String> {
    if !cfg!(target_os = "linux") || pid == std::process::id() {
        return None;
    }
    let status = fs::read_to_string(format!("/proc/{pid}/status")).ok()?;
    let field = |name: &str| {
        status
            .lines()
            .find_map(|l| l.strip_prefix(name))
            .map(str::trim)
    };
    if field("Tgid:") != Some(pid.to_string().as_str())
        || field("State:").is_some_and(|s| s.starts_with('Z'))
    {
        return None;
    }
    let cmdline = fs::read(format!("/proc/{pid}/cmdline")).unwrap_or_default();
    Some(
        String::from_utf8_lossy(&cmdline)
            .split('\0')
            .filter(|a| !a.is_empty())
            .collect::<Vec<_>>()
            .join(" "),
    )
}

/// Whether `path` still names the open `file` (it was not removed or
/// replaced since it was opened). Where file identities are not known
/// (not Unix), assumed.
fn names_file(path: &Path, file: &fs::File) -> bool {
    #[cfg(unix)]
    {
        use std::os::unix::fs::MetadataExt;
        match (fs::metadata(path), file.metadata()) {
            (Ok(a), Ok(b)) => a.dev() == b.dev() && a.ino() == b.ino(),
            _ => false,
        }
    }
    #[cfg(not(unix))]
    {
        let _ = (path, file);
        true
    }
}

/// A run folder.
#[derive(Debug, Clone)]
pub struct RunDir {
    root: PathBuf,
}

impl RunDir {
    /// Creates a new run folder at `root`; errors if it exists and is not empty.
    pub fn create(root: &Path) -> anyhow::Result<Self> {
        if root.exists() {
            let mut entries =
                fs::read_dir(root).with_context(|| format!("reading {}", root.display()))?;
            if entries.next().is_some() {
                bail!(
                    "{} already exists and is not empty; pass --resume to continue that run, or choose another --out",
                    root.display()
                );
            }
        }
        fs::create_dir_all(root).with_context(|| format!("creating {}", root.display()))?;
        Ok(RunDir {
            root: root.to_path_buf(),
        })
    }

    /// Opens an existing run folder (it must hold a `config.json`).
    pub fn open(root: &Path) -> anyhow::Result<Self> {
        if root.exists() && !root.is_dir() {
            bail!(
                "{} is not a run folder (it is a file; a run folder holds config.json)",
                root.display()
            );
        }
        if !root.is_dir() {
            bail!("{} is not a run folder (it does not exist)", root.display());
        }
        let dir = RunDir {
            root: root.to_path_buf(),
        };
        if !dir.config_path().is_file() {
            bail!(
                "{} is not a run folder: {} is missing",
                root.display(),
                dir.config_path().display()
            );
        }
        Ok(dir)
    }

    /// What `ntg train` does with `--out root`: with `resume`, opens the
    /// run there after checking it was started with `config` (else an
    /// error that shows the saved configuration, followed by `hint`);
    /// without, creates the folder and saves `config` as its
    /// `config.json`.
    pub fn start_or_resume<C>(
        root: &Path,
        config: &C,
        resume: bool,
        hint: &str,
    ) -> anyhow::Result<Self>
    where
        C: Serialize + DeserializeOwned + PartialEq,
    {
        if resume {
            let run = RunDir::open(root)?;
            let saved: C = RunDir::read_json(&run.config_path())?;
            // Compared as saved: a setting whose values are written alike
            // (shards 0 and 1: "one shard", not written) is the same.
            if serde_json::to_value(&saved)? != serde_json::to_value(config)? {
                let (old, new) = (serde_json::to_value(&saved)?, serde_json::to_value(config)?);
                let differences = config_differences(&old, &new);
                if differences.len() == 1 && differences[0].starts_with("optim.epochs:") {
                    // More epochs for the same run: allowed where the run
                    // so extended equals one trained that long from the
                    // start (see `extension_refusal`).
                    if let Some(why) = extension_refusal(&old, &new) {
                        bail!(
                            "{}: cannot extend the run to --epochs {}: {why}; start a new run in another --out",
                            run.config_path().display(),
                            new["optim"]["epochs"]
                        );
                    }
                    RunDir::write_json(&run.config_path(), config)?;
                    return Ok(run);
                }
                bail!(
                    "{} was started with a different configuration ({}); resume it with the same arguments as the original run ({hint}or start a new run in another --out)",
                    run.config_path().display(),
                    differences.join("; ")
                );
            }
            Ok(run)
        } else {
            let run = RunDir::create(root)?;
            RunDir::write_json(&run.config_path(), config)?;
            Ok(run)
        }
    }

    /// What `ntg reproduce` does with a figure's run folder: opens the
    /// run at `root` if it holds `config` (to reuse or resume it), creates
    /// it if absent, and errors if it holds another configuration (or one
    /// of an older format).
    pub fn open_or_create<C>(root: &Path, config: &C) -> anyhow::Result<Self>
    where
        C: Serialize + DeserializeOwned + PartialEq,
    {
        if root.join("config.json").is_file() {
            let run = RunDir::open(root)?;
            let saved: Option<C> = RunDir::read_json(&run.config_path()).ok();
            // Compared as written (see `start_or_resume`).
            let same = match &saved {
                Some(saved) => serde_json::to_value(saved)? == serde_json::to_value(config)?,
                None => false,
            };
            if !same {
                bail!(
                    "{} holds a run with another configuration{}; move it away or delete it",
                    root.display(),
                    if saved.is_none() {
                        " (or of an older format)"
                    } else {
                        ""
                    }
                );
            }
            Ok(run)
        } else {
            let run = RunDir::create(root)?;
            RunDir::write_json(&run.config_path(), config)?;
            Ok(run)
        }
    }

    /// The evaluation saved as `eval/NAME`, if it was written after the
    /// run's last checkpoint (so it belongs to the final weights);
    /// otherwise `evaluate` runs and its result is saved there.
    pub fn cached_eval<T>(
        &self,
        name: &str,
        evaluate: impl FnOnce() -> anyhow::Result<T>,
    ) -> anyhow::Result<T>
    where
        T: Serialize + DeserializeOwned,
    {
        let path = self.eval_dir().join(name);
        let modified = |p: &Path| fs::metadata(p).and_then(|m| m.modified()).ok();
        let checkpoint = self.checkpoint_dir().join("progress.json");
        if let (Some(eval), Some(ckpt)) = (modified(&path), modified(&checkpoint))
            && eval >= ckpt
        {
            return RunDir::read_json(&path);
        }
        let result = evaluate()?;
        fs::create_dir_all(self.eval_dir())
            .with_context(|| format!("creating {}", self.eval_dir().display()))?;
        RunDir::write_json(&path, &result)?;
        Ok(result)
    }

    /// Seconds spent in training epochs: the sum of the `seconds` of every
    /// line of `metrics.jsonl`, the run's own and its stages' (each
    /// subfolder that has one: a video run's frame encoder, NTP
    /// (Detector)'s detector), so a reused run reports its original cost.
    pub fn epoch_seconds(&self) -> anyhow::Result<f64> {
        #[derive(serde::Deserialize)]
        struct Seconds {
            seconds: f64,
        }
        let mut total = 0.0;
        for file in self.metrics_files()? {
            let lines: Vec<Seconds> = read_jsonl(&file)?;
            total += lines.iter().map(|l| l.seconds).sum::<f64>();
        }
        Ok(total)
    }

    /// Over the run's training epochs that recorded their CPU time
    /// (`cpu_seconds`, see [`crate::fit`]; every stage's `metrics.jsonl`,
    /// as [`RunDir::epoch_seconds`]): `(CPU seconds, wall seconds)` of
    /// those epochs, or `None` if no epoch recorded it.
    pub fn recorded_cpu_seconds(&self) -> anyhow::Result<Option<(f64, f64)>> {
        #[derive(serde::Deserialize)]
        struct Line {
            seconds: f64,
            cpu_seconds: Option<f64>,
        }
        let (mut cpu, mut wall, mut lines) = (0.0, 0.0, 0);
        for file in self.metrics_files()? {
            for line in read_jsonl::<Line>(&file)? {
                if let Some(c) = line.cpu_seconds {
                    cpu += c;
                    wall += line.seconds;
                    lines += 1;
                }
            }
        }
        Ok((lines > 0).then_some((cpu, wall)))
    }

    /// Core-seconds of the run's training epochs (every stage's
    /// `metrics.jsonl`, as [`RunDir::epoch_seconds`]): each epoch's CPU
    /// time where it recorded one (`cpu_seconds`: the run alone in its
    /// process), else its wall time (`seconds`; a run of `ntg reproduce`
    /// trains on one thread, so its wall time is its core time unless
    /// something else shared the core). What the reports give as a run's
    /// training time: wall time alone overstates runs that shared their
    /// core with other work (the paper profile's lanes, at a low priority,
    /// beside builds and tests).
    pub fn epoch_compute_seconds(&self) -> anyhow::Result<f64> {
        #[derive(serde::Deserialize)]
        struct Line {
            seconds: f64,
            cpu_seconds: Option<f64>,
        }
        let mut total = 0.0;
        for file in self.metrics_files()? {
            for line in read_jsonl::<Line>(&file)? {
                total += line.cpu_seconds.unwrap_or(line.seconds);
            }
        }
        Ok(total)
    }

    /// Per stage of the run: `(stage, epochs, seconds)` of the epochs in
    /// its `metrics.jsonl` (as [`Self::epoch_compute_seconds`] counts
    /// them), the run's own first (stage `""`), then each stage folder's
    /// by name (`stage_a`, `detector_stage`).
    pub fn stage_compute_seconds(&self) -> anyhow::Result<Vec<(String, usize, f64)>> {
        #[derive(serde::Deserialize)]
        struct Line {
            seconds: f64,
            cpu_seconds: Option<f64>,
        }
        let mut files = self.metrics_files()?;
        files[1..].sort();
        let mut stages = Vec::new();
        for file in files {
            if !file.is_file() {
                continue;
            }
            let lines = read_jsonl::<Line>(&file)?;
            let stage = match file.parent() {
                Some(dir) if dir != self.root => dir
                    .file_name()
                    .map_or_else(String::new, |n| n.to_string_lossy().into_owned()),
                _ => String::new(),
            };
            let seconds = lines
                .iter()
                .map(|l| l.cpu_seconds.unwrap_or(l.seconds))
                .sum();
            stages.push((stage, lines.len(), seconds));
        }
        Ok(stages)
    }

    /// The run's `metrics.jsonl` and those of its stages (subfolders).
    fn metrics_files(&self) -> anyhow::Result<Vec<PathBuf>> {
        let mut files = vec![self.metrics_path()];
        let entries = std::fs::read_dir(&self.root)
            .with_context(|| format!("reading {}", self.root.display()))?;
        for entry in entries {
            let stage = entry?.path().join(METRICS_FILE);
            if stage.is_file() {
                files.push(stage);
            }
        }
        Ok(files)
    }

    /// Takes the run's writer lock until the returned guard is dropped:
    /// the OS's exclusive lock on `train.lock` (which then holds this
    /// process's id, for the message another process gets). Errors, naming
    /// the holder, if another process holds it, or another thread of this
    /// one. A lock file left by a process that died (killed, or a power
    /// cut) is taken over: the OS released its lock. The thread that holds
    /// it may take it again (the guards nest: the last one dropped
    /// releases it). A file whose OS lock is free but which names another
    /// live process is refused too: a process of an `ntg` from before OS
    /// locks may hold it.
    pub fn lock(&self) -> anyhow::Result<RunLock> {
        let root = fs::canonicalize(&self.root).unwrap_or_else(|_| self.root.clone());
        let path = root.join(LOCK_FILE);
        let mut held = held_locks();
        if let Some(entry) = held.iter_mut().find(|h| h.path == path) {
            if entry.thread != std::thread::current().id() {
                bail!(
                    "{} is being written by another thread of this process ({}); a run folder has one writer",
                    self.root.display(),
                    path.display()
                );
            }
            entry.guards += 1;
            return Ok(RunLock { path });
        }
        let refused = |text: &str, unlocked: Option<&str>| {
            anyhow::anyhow!(
                "{} is being written by another process ({}: {}); wait for it to finish{}",
                self.root.display(),
                path.display(),
                match text.split_whitespace().next().map(str::parse::<u32>) {
                    Some(Ok(pid)) => format!("process {pid}"),
                    _ => format!("{:?}", text.trim()),
                },
                unlocked.map_or_else(String::new, |cmdline| format!(
                    " (it holds no OS lock on the file, as an ntg from before OS locks would; that process runs `{cmdline}`: if it is not an ntg, delete the file)"
                ))
            )
        };
        // Retried while the file the lock was taken on is no longer the
        // one at `path` (its holder removed it on release meanwhile).
        for _ in 0..100 {
            let mut file = OpenOptions::new()
                .read(true)
                .write(true)
                .create(true)
                .truncate(false)
                .open(&path)
                .with_context(|| format!("opening {}", path.display()))?;
            match file.try_lock() {
                Ok(()) => {}
                Err(fs::TryLockError::WouldBlock) => {
                    return Err(refused(
                        &fs::read_to_string(&path).unwrap_or_default(),
                        None,
                    ));
                }
                Err(fs::TryLockError::Error(e)) => {
                    return Err(e).with_context(|| {
                        format!(
                            "locking {} (a run folder needs a file system with file locks: put the runs folder on a local disk)",
                            path.display()
                        )
                    });
                }
            }
            if !names_file(&path, &file) {
                continue;
            }
            // A bare process id: written by an ntg from before OS locks,
            // which may still run and write without one.
            let text = fs::read_to_string(&path).unwrap_or_default();
            if let Some(cmdline) = text
                .trim()
                .parse::<u32>()
                .ok()
                .and_then(another_live_process)
            {
                return Err(refused(&text, Some(&cmdline)));
            }
            file.set_len(0)
                .and_then(|()| write!(file, "{} {OS_LOCK_TAG}", std::process::id()))
                .with_context(|| format!("writing {}", path.display()))?;
            held.push(HeldLock {
                path: path.clone(),
                file,
                thread: std::thread::current().id(),
                guards: 1,
            });
            return Ok(RunLock { path });
        }
        bail!(
            "could not take {}: it was replaced 100 times in a row",
            path.display()
        )
    }

    /// The folder itself.
    pub fn root(&self) -> &Path {
        &self.root
    }

    /// `config.json`.
    pub fn config_path(&self) -> PathBuf {
        self.root.join("config.json")
    }

    /// The dataset cache folder.
    pub fn dataset_dir(&self) -> PathBuf {
        self.root.join("dataset")
    }

    /// The checkpoint folder.
    pub fn checkpoint_dir(&self) -> PathBuf {
        self.root.join("checkpoint")
    }

    /// The folder of the checkpoint selected on validation tasks.
    pub fn best_dir(&self) -> PathBuf {
        self.root.join("best")
    }

    /// The weights training started from, saved by [`crate::fit::fit`]
    /// before a run's first epoch (a video run's with its frozen frame
    /// encoder): the untrained model a reduced profile scores to show that
    /// a series learned something. Runs begun before it existed have none.
    pub fn initial_dir(&self) -> PathBuf {
        self.root.join("initial")
    }

    /// `validation.jsonl`.
    pub fn validation_path(&self) -> PathBuf {
        self.root.join("validation.jsonl")
    }

    /// The evaluation folder.
    pub fn eval_dir(&self) -> PathBuf {
        self.root.join("eval")
    }

    /// `metrics.jsonl`.
    pub fn metrics_path(&self) -> PathBuf {
        self.root.join(METRICS_FILE)
    }

    /// Writes `value` as pretty JSON to `path` atomically (temp file + rename).
    pub fn write_json(path: &Path, value: &impl Serialize) -> anyhow::Result<()> {
        // Named for this process: two writers of one file (two `ntg eval`s)
        // never write into each other's temporary file.
        let tmp = path.with_extension(format!("json.{}.tmp", std::process::id()));
        fs::write(&tmp, serde_json::to_vec_pretty(value)?)
            .with_context(|| format!("writing {}", tmp.display()))?;
        fs::rename(&tmp, path).with_context(|| format!("writing {}", path.display()))?;
        Ok(())
    }

    /// Reads JSON from `path`, naming the file and (for a value of the
    /// wrong shape) the field in any error.
    pub fn read_json<T: DeserializeOwned>(path: &Path) -> anyhow::Result<T> {
        let text =
            fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
        let mut json = serde_json::Deserializer::from_str(&text);
        let value: T = serde_path_to_error::deserialize(&mut json).map_err(|e| {
            let field = e.path().to_string();
            let at = if field == "." {
                String::new()
            } else {
                format!(" field `{field}`:")
            };
            anyhow::anyhow!("{}:{at} {}", path.display(), e.into_inner())
        })?;
        json.end()
            .with_context(|| format!("{}: invalid contents", path.display()))?;
        Ok(value)
    }

    /// Appends one line to `metrics.jsonl`.
    pub fn append_metrics(&self, record: &impl Serialize) -> anyhow::Result<()> {
        Self::append_jsonl(&self.metrics_path(), record)
    }

    /// Appends `record` as one JSON line to `path`.
    pub fn append_jsonl(path: &Path, record: &impl Serialize) -> anyhow::Result<()> {
        let mut file = OpenOptions::new()
            .create(true)
            .append(true)
            .open(path)
            .with_context(|| format!("opening {}", path.display()))?;
        let mut line = serde_json::to_vec(record)?;
        line.push(b'\n');
        file.write_all(&line)
            .with_context(|| format!("writing {}", path.display()))?;
        Ok(())
    }
}

/// Why a run saved with configuration `old` cannot be extended to `new`,
/// which differs from it in `optim.epochs` alone, so that the extended
/// run equals one trained for `new`'s epochs from the start; `None` when
/// it can. It cannot when the new count is not larger, when the learning
/// rate decays over the whole schedule (`optim.cosine_decay`: every
/// epoch's rate depends on the total), or when the old count is not a
/// multiple of `validate_every` (the old run scored its last epoch on the
/// validation tasks, which the longer run would not have, so their
/// selected epochs could differ).
pub fn extension_refusal(old: &serde_json::Value, new: &serde_json::Value) -> Option<String> {
    let epochs = |c: &serde_json::Value| c["optim"]["epochs"].as_u64().unwrap_or(0);
    let (from, to) = (epochs(old), epochs(new));
    if to <= from {
        return Some(format!(
            "it was started with --epochs {from}; only more epochs extend it"
        ));
    }
    if old["optim"]["cosine_decay"].as_bool() == Some(true) {
        return Some(
            "its learning rate follows a cosine decay over all its epochs, so every epoch's rate would change"
                .into(),
        );
    }
    let every = old["validate_every"].as_u64().unwrap_or(1).max(1);
    if from % every != 0 {
        return Some(format!(
            "it scored its last epoch ({from}) on the validation tasks, which a run of {to} epochs validated every {every} would not"
        ));
    }
    None
}

/// The fields in which two configurations differ, as `name: saved S, now N`
/// (nested fields as `optim.epochs`).
pub fn config_differences(saved: &serde_json::Value, now: &serde_json::Value) -> Vec<String> {
    fn walk(path: &str, saved: &serde_json::Value, now: &serde_json::Value, out: &mut Vec<String>) {
        match (saved, now) {
            (serde_json::Value::Object(a), serde_json::Value::Object(b)) => {
                let mut keys: Vec<&String> = a.keys().chain(b.keys()).collect();
                keys.sort();
                keys.dedup();
                for key in keys {
                    let name = if path.is_empty() {
                        key.clone()
                    } else {
                        format!("{path}.{key}")
                    };
                    let null = serde_json::Value::Null;
                    walk(
                        &name,
                        a.get(key).unwrap_or(&null),
                        b.get(key).unwrap_or(&null),
                        out,
                    );
                }
            }
            _ if saved != now => out.push(format!("{path}: saved {saved}, now {now}")),
            _ => {}
        }
    }
    let mut out = Vec::new();
    walk("", saved, now, &mut out);
    out
}

/// `DIR.next` and `DIR.old` beside `dir`.
fn staging(dir: &Path) -> (PathBuf, PathBuf) {
    let name = dir.file_name().map(|n| n.to_string_lossy().into_owned());
    let name = name.unwrap_or_default();
    (
        dir.with_file_name(format!("{name}.next")),
        dir.with_file_name(format!("{name}.old")),
    )
}

/// Replaces the folder `dir` by the one `write` fills, so that a kill at
/// any moment leaves the old folder or the new one, complete, never a mix:
/// `write` fills `DIR.next`, which then takes `DIR`'s place by renames
/// (the old one parked as `DIR.old` in between). [`recover_dir`] finishes
/// or undoes an interrupted replacement.
pub fn replace_dir(
    dir: &Path,
    write: impl FnOnce(&Path) -> anyhow::Result<()>,
) -> anyhow::Result<()> {
    let (next, old) = staging(dir);
    let rename = |from: &Path, to: &Path| {
        fs::rename(from, to)
            .with_context(|| format!("renaming {} to {}", from.display(), to.display()))
    };
    if next.exists() {
        fs::remove_dir_all(&next).with_context(|| format!("removing {}", next.display()))?;
    }
    fs::create_dir_all(&next).with_context(|| format!("creating {}", next.display()))?;
    write(&next)?;
    if dir.exists() {
        rename(dir, &old)?;
    }
    rename(&next, dir)?;
    if old.exists() {
        fs::remove_dir_all(&old).with_context(|| format!("removing {}", old.display()))?;
    }
    Ok(())
}

/// Puts `dir` back in order after a kill during [`replace_dir`]: a
/// half-written `DIR.next` is removed, and a `DIR` parked as `DIR.old`
/// whose replacement never took its place is restored (the replacement is
/// dropped: what was logged after the old one is redone).
pub fn recover_dir(dir: &Path) -> anyhow::Result<()> {
    let (next, old) = staging(dir);
    if old.exists() {
        if dir.exists() {
            fs::remove_dir_all(&old).with_context(|| format!("removing {}", old.display()))?;
        } else {
            fs::rename(&old, dir)
                .with_context(|| format!("restoring {} from {}", dir.display(), old.display()))?;
        }
    }
    if next.exists() {
        fs::remove_dir_all(&next).with_context(|| format!("removing {}", next.display()))?;
    }
    Ok(())
}

/// Keeps the lines of the JSON-lines file `path` whose `"epoch"` is below
/// `epochs_done` (a run killed after logging an epoch but before its
/// checkpoint redoes that epoch) and returns how many lines it dropped;
/// errors if a line is further ahead than one epoch, which no kill leaves
/// (the checkpoint was removed or replaced by hand).
pub fn drop_lines_from_epoch(path: &Path, epochs_done: usize) -> anyhow::Result<usize> {
    if !path.is_file() {
        return Ok(0);
    }
    let lines: Vec<serde_json::Value> = read_jsonl(path)?;
    let epoch = |v: &serde_json::Value| v.get("epoch").and_then(serde_json::Value::as_u64);
    if let Some(e) = lines
        .iter()
        .filter_map(epoch)
        .find(|&e| e > epochs_done as u64)
    {
        bail!(
            "{} logs epoch {e} but the checkpoint holds {epochs_done} finished epochs; the checkpoint was removed or replaced: start a new run (another --out)",
            path.display()
        );
    }
    // The kept lines are written back as they were (not re-serialised,
    // which would reorder their keys).
    let original =
        fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
    let kept: Vec<&str> = original
        .lines()
        .filter(|l| !l.trim().is_empty())
        .zip(&lines)
        .filter(|(_, v)| epoch(v).is_none_or(|e| e < epochs_done as u64))
        .map(|(l, _)| l)
        .collect();
    let dropped = lines.len() - kept.len();
    if dropped > 0 {
        let mut text = String::new();
        for line in kept {
            text.push_str(line);
            text.push('\n');
        }
        let tmp = path.with_extension("jsonl.tmp");
        fs::write(&tmp, text).with_context(|| format!("writing {}", tmp.display()))?;
        fs::rename(&tmp, path).with_context(|| format!("writing {}", path.display()))?;
    }
    Ok(dropped)
}

/// Reads every line of a JSON-lines file, naming the file and line of the
/// first that does not parse.
pub fn read_jsonl<T: DeserializeOwned>(path: &Path) -> anyhow::Result<Vec<T>> {
    let text =
        std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
    text.lines()
        .enumerate()
        .filter(|(_, l)| !l.trim().is_empty())
        .map(|(i, l)| {
            serde_json::from_str(l)
                .with_context(|| format!("{}: line {} is not valid", path.display(), i + 1))
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn one_writer_at_a_time_and_stale_locks_are_taken_over() {
        let tmp = tempfile::tempdir().unwrap();
        let run = RunDir::create(&tmp.path().join("run")).unwrap();
        let lock_file = run.root().join(LOCK_FILE);
        let held = run.lock().unwrap();
        // The holding thread may take it again; the last guard releases it.
        let nested = run.lock().unwrap();
        drop(nested);
        assert!(lock_file.exists());
        // Another thread of this process is refused.
        let err = std::thread::scope(|s| s.spawn(|| run.lock().map(drop)).join().unwrap())
            .unwrap_err()
            .to_string();
        assert!(err.contains("another thread"), "{err}");
        // A copy of the folder does not take its writer's lock along.
        let copy = tmp.path().join("copy");
        link_or_copy_tree(run.root(), &copy).unwrap();
        assert!(!copy.join(LOCK_FILE).exists());
        drop(held);
        assert!(!lock_file.exists());

        // Another process's lock (here an OS lock this test takes on its
        // own handle, the file naming a process that does not exist).
        fs::write(&lock_file, "4194304999").unwrap();
        let outside = fs::File::open(&lock_file).unwrap();
        outside.try_lock().unwrap();
        let err = run.lock().unwrap_err().to_string();
        assert!(err.contains("process 4194304999"), "{err}");
        assert!(!err.contains("delete the file"), "{err}");
        // Its holder died: the OS released the lock, the file is taken over.
        drop(outside);
        let taken = run.lock().unwrap();
        assert_eq!(
            fs::read_to_string(&lock_file).unwrap(),
            format!("{} {OS_LOCK_TAG}", std::process::id())
        );
        drop(taken);
        // A file of this ntg naming a live process: its OS lock decides
        // (the process may be another one that reused a dead holder's id).
        fs::write(&lock_file, format!("1 {OS_LOCK_TAG}")).unwrap();
        drop(run.lock().unwrap());
        // So is a file left half-written, or naming this very process (a
        // killed run's id, reused by the process that resumes it).
        for left in ["", "someone", &std::process::id().to_string()] {
            fs::write(&lock_file, left).unwrap();
            drop(run.lock().unwrap());
            assert!(!lock_file.exists());
        }
        // A file without an OS lock that names another live process (an
        // ntg from before OS locks) is refused, saying how to clear it.
        if cfg!(target_os = "linux") {
            fs::write(&lock_file, "1").unwrap();
            let err = run.lock().unwrap_err().to_string();
            assert!(
                err.contains("process 1") && err.contains("delete the file"),
                "{err}"
            );
            // Not a thread of a process (this test's, alive while it is
            // checked), though `/proc/TID` answers for those too.
            let found = std::thread::scope(|s| {
                s.spawn(|| {
                    let me = fs::read_link("/proc/thread-self").unwrap();
                    let tid: u32 = me.file_name().unwrap().to_str().unwrap().parse().unwrap();
                    another_live_process(tid)
                })
                .join()
                .unwrap()
            });
            assert_eq!(found, None);
            assert!(another_live_process(1).is_some());
        }
    }

    #[test]
    fn a_lock_taken_on_a_file_replaced_meanwhile_is_not_held() {
        let tmp = tempfile::tempdir().unwrap();
        let path = tmp.path().join(LOCK_FILE);
        fs::write(&path, "").unwrap();
        let opened = fs::File::open(&path).unwrap();
        assert!(names_file(&path, &opened));
        // Its holder removed it on release, and another process made a new one.
        fs::remove_file(&path).unwrap();
        assert_eq!(names_file(&path, &opened), !cfg!(unix));
        fs::write(&path, "").unwrap();
        assert_eq!(names_file(&path, &opened), !cfg!(unix));
    }

    #[test]
    fn start_or_resume_checks_the_saved_configuration() {
        let tmp = tempfile::tempdir().unwrap();
        let root = tmp.path().join("run");
        let config = serde_json::json!({"epochs": 3});
        RunDir::start_or_resume(&root, &config, false, "").unwrap();
        let saved: serde_json::Value = RunDir::read_json(&root.join("config.json")).unwrap();
        assert_eq!(saved, config);
        // Starting again over it is refused; resuming with the same
        // configuration is not.
        assert!(RunDir::start_or_resume(&root, &config, false, "").is_err());
        RunDir::start_or_resume(&root, &config, true, "").unwrap();
        let other = serde_json::json!({"epochs": 4});
        let err = RunDir::start_or_resume(&root, &other, true, "try --x; ")
            .unwrap_err()
            .to_string();
        assert!(err.contains("different configuration"), "{err}");
        assert!(err.contains("(epochs: saved 3, now 4)"), "{err}");
        assert!(err.contains("(try --x; or start a new run"), "{err}");
        // Resuming where nothing was started names the folder.
        let missing = tmp.path().join("none");
        let err = RunDir::start_or_resume(&missing, &config, true, "")
            .unwrap_err()
            .to_string();
        assert!(err.contains("none"), "{err}");
        // One shard is not written, so it reads back as 0: a run started
        // with `--shards 1` resumes with `--shards 1`.
        let optim = crate::fit::OptimConfig {
            shards: 1,
            ..crate::fit::OptimConfig::stage(2, 4, 1e-3, 0, 1)
        };
        let root = tmp.path().join("one-shard");
        RunDir::start_or_resume(&root, &optim, false, "").unwrap();
        RunDir::start_or_resume(&root, &optim, true, "").unwrap();
    }

    #[test]
    fn refuses_to_overwrite_and_checks_open() {
        let tmp = tempfile::tempdir().unwrap();
        let root = tmp.path().join("run");
        let run = RunDir::create(&root).unwrap();
        RunDir::write_json(&run.config_path(), &serde_json::json!({"a": 1})).unwrap();
        let err = RunDir::create(&root).unwrap_err().to_string();
        assert!(err.contains("already exists"), "{err}");
        assert!(RunDir::open(&root).is_ok());
        let err = RunDir::open(&tmp.path().join("nope"))
            .unwrap_err()
            .to_string();
        assert!(err.contains("does not exist"), "{err}");
        fs::create_dir(tmp.path().join("empty")).unwrap();
        let err = RunDir::open(&tmp.path().join("empty"))
            .unwrap_err()
            .to_string();
        assert!(err.contains("config.json is missing"), "{err}");
    }

    #[test]
    fn metrics_append_lines_and_bad_json_names_the_file() {
        let tmp = tempfile::tempdir().unwrap();
        let run = RunDir::create(tmp.path()).unwrap();
        run.append_metrics(&serde_json::json!({"epoch": 0}))
            .unwrap();
        run.append_metrics(&serde_json::json!({"epoch": 1}))
            .unwrap();
        let text = fs::read_to_string(run.metrics_path()).unwrap();
        assert_eq!(text.lines().count(), 2);
        fs::write(run.config_path(), "{").unwrap();
        let err = format!(
            "{:#}",
            RunDir::read_json::<serde_json::Value>(&run.config_path()).unwrap_err()
        );
        assert!(err.contains("config.json"), "{err}");
    }

    #[test]
    fn epoch_seconds_sum_the_metrics_and_errors_name_the_file() {
        let dir = tempfile::tempdir().unwrap();
        let run = RunDir::create(dir.path()).unwrap();
        std::fs::write(run.metrics_path(), "{\"seconds\": 1.5}\nnot json\n").unwrap();
        let err = format!("{:#}", run.epoch_seconds().unwrap_err());
        assert!(
            err.contains("metrics.jsonl") && err.contains("line 2"),
            "{err}"
        );
        std::fs::write(run.metrics_path(), "{\"seconds\": 1.5}\n{\"seconds\": 2}\n").unwrap();
        assert_eq!(run.epoch_seconds().unwrap(), 3.5);
        assert_eq!(run.recorded_cpu_seconds().unwrap(), None);
        assert_eq!(run.epoch_compute_seconds().unwrap(), 3.5);
        std::fs::write(
            run.metrics_path(),
            "{\"seconds\": 1.5, \"cpu_seconds\": 1.25}\n{\"seconds\": 2, \"cpu_seconds\": 1}\n",
        )
        .unwrap();
        assert_eq!(run.recorded_cpu_seconds().unwrap(), Some((2.25, 3.5)));
        std::fs::create_dir(run.root().join("stage_a")).unwrap();
        std::fs::write(
            run.root().join("stage_a/metrics.jsonl"),
            "{\"seconds\": 4}\n",
        )
        .unwrap();
        assert_eq!(run.epoch_seconds().unwrap(), 7.5);
        // Only the epochs that recorded CPU time count for it.
        assert_eq!(run.recorded_cpu_seconds().unwrap(), Some((2.25, 3.5)));
        // Compute: CPU time where an epoch recorded it, else wall time.
        assert_eq!(run.epoch_compute_seconds().unwrap(), 2.25 + 4.0);
    }

    #[test]
    fn open_or_create_reuses_the_same_configuration_only() {
        let tmp = tempfile::tempdir().unwrap();
        let root = tmp.path().join("run");
        let config = serde_json::json!({"epochs": 3});
        RunDir::open_or_create(&root, &config).unwrap();
        RunDir::open_or_create(&root, &config).unwrap();
        let err = RunDir::open_or_create(&root, &serde_json::json!({"epochs": 4}))
            .unwrap_err()
            .to_string();
        assert!(err.contains("another configuration"), "{err}");
    }

    #[test]
    fn cached_evaluations_are_reused_until_the_next_checkpoint() {
        let tmp = tempfile::tempdir().unwrap();
        let run = RunDir::create(tmp.path()).unwrap();
        fs::create_dir_all(run.checkpoint_dir()).unwrap();
        RunDir::write_json(&run.checkpoint_dir().join("progress.json"), &1).unwrap();
        let first: u32 = run.cached_eval("e.json", || Ok(7)).unwrap();
        let again: u32 = run.cached_eval("e.json", || Ok(8)).unwrap();
        assert_eq!((first, again), (7, 7));
        // A newer checkpoint makes the saved evaluation stale.
        std::thread::sleep(std::time::Duration::from_millis(20));
        RunDir::write_json(&run.checkpoint_dir().join("progress.json"), &2).unwrap();
        let fresh: u32 = run.cached_eval("e.json", || Ok(9)).unwrap();
        assert_eq!(fresh, 9);
    }
    #[test]
    fn jsonl_errors_name_the_file_and_line() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("m.jsonl");
        std::fs::write(&path, "{\"epochs_done\": 1}\n\nnot json\n").unwrap();
        let err = format!("{:#}", read_jsonl::<serde_json::Value>(&path).unwrap_err());
        assert!(err.contains("m.jsonl") && err.contains("line 3"), "{err}");
        std::fs::write(&path, "{\"epochs_done\": 1}\n{\"epochs_done\": 2}\n").unwrap();
        assert_eq!(read_jsonl::<serde_json::Value>(&path).unwrap().len(), 2);
    }

    #[test]
    fn replacing_a_folder_leaves_old_or_new_and_recovery_finishes_a_killed_one() {
        let tmp = tempfile::tempdir().unwrap();
        let dir = tmp.path().join("checkpoint");
        let write = |n: u32| {
            move |d: &Path| -> anyhow::Result<()> {
                fs::write(d.join("n"), n.to_string())?;
                Ok(())
            }
        };
        let read = |d: &Path| fs::read_to_string(d.join("n")).unwrap();
        replace_dir(&dir, write(1)).unwrap();
        replace_dir(&dir, write(2)).unwrap();
        assert_eq!(read(&dir), "2");
        let (next, old) = staging(&dir);
        assert!(!next.exists() && !old.exists());
        // A failed write leaves the old folder in place.
        assert!(replace_dir(&dir, |_| anyhow::bail!("disk full")).is_err());
        assert_eq!(read(&dir), "2");
        recover_dir(&dir).unwrap();
        assert!(!next.exists());
        // Killed between the two renames: the old folder comes back.
        fs::rename(&dir, &old).unwrap();
        fs::create_dir_all(&next).unwrap();
        recover_dir(&dir).unwrap();
        assert_eq!(read(&dir), "2");
        assert!(!next.exists() && !old.exists());
        // Killed before removing the parked one: it goes.
        fs::create_dir_all(&old).unwrap();
        recover_dir(&dir).unwrap();
        assert!(!old.exists() && dir.exists());
    }

    #[test]
    fn lines_of_an_unfinished_epoch_are_dropped_and_lines_from_the_future_refused() {
        let tmp = tempfile::tempdir().unwrap();
        let path = tmp.path().join("metrics.jsonl");
        assert_eq!(drop_lines_from_epoch(&path, 3).unwrap(), 0);
        fs::write(
            &path,
            "{\"epoch\":0,\"success\":0.5,\"goal\":1}\n{\"epoch\":1}\n{\"epoch\":2}\n",
        )
        .unwrap();
        assert_eq!(drop_lines_from_epoch(&path, 3).unwrap(), 0);
        assert_eq!(drop_lines_from_epoch(&path, 2).unwrap(), 1);
        // The kept lines are the same text (keys not reordered), so a
        // resumed run's logs equal an uninterrupted run's byte for byte.
        assert_eq!(
            fs::read_to_string(&path).unwrap(),
            "{\"epoch\":0,\"success\":0.5,\"goal\":1}\n{\"epoch\":1}\n"
        );
        let err = drop_lines_from_epoch(&path, 0).unwrap_err().to_string();
        assert!(
            err.contains("logs epoch 1") && err.contains("metrics.jsonl"),
            "{err}"
        );
    }
}
