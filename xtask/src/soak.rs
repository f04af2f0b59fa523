//! `cargo xtask soak`: kill a small training run with SIGKILL again and
//! again, resume it to the end, and check that it ends exactly where an
//! uninterrupted run with the same seed ends. With `--array`, the run is a
//! job array task (`ntg reproduce --profile quick --array-index I`), stopped
//! with SIGTERM and SIGKILL in turn as Slurm stops a preempted task, and
//! its test evaluation is compared too.
//!
//! Both runs are `ntg train --domain blocks` at a tiny scale (state input,
//! validation on, so `best/` is exercised too). The soaked run is started,
//! killed after a seeded random delay, resumed with `--resume`, killed
//! again, ... `kills` times, then resumed without a kill until it finishes.
//! Every resume must start cleanly (a resume that exits with an error, not
//! by the kill, fails the soak). At the end the soaked run's final
//! weights, optimizer state, selected weights and metrics (times aside)
//! must equal the uninterrupted run's byte for byte (burn's random
//! parameter ids aside, see [`without_param_ids`]), and no temporary file,
//! staging folder or lock may be left in it.

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use anyhow::{Context, bail};

/// Settings of one soak.
pub struct Soak {
    /// How many times to kill the run.
    pub kills: usize,
    /// Seed of the kill delays.
    pub seed: u64,
    /// Shortest delay before a kill.
    pub min_delay: Duration,
    /// Longest delay before a kill.
    pub max_delay: Duration,
    /// Use the release build of `ntg` (else the dev build).
    pub release: bool,
    /// Soak this `ntg` binary instead of building one.
    pub ntg: Option<PathBuf>,
    /// Soak a job array task instead (`ntg reproduce --profile quick
    /// --array-index I` of the quick profile's run [`ARRAY_RUN`]), killed
    /// with SIGTERM and SIGKILL in turn, as Slurm stops a preempted task.
    pub array: bool,
}

/// The run an array-task soak trains: the quick profile's NTG on object
/// collection (state input; 7 epochs, the last of which validation scores
/// perfectly, about 11 s of training in a release build on this project's
/// machine, then 5000 test episodes), long enough for about 10 kills of at
/// most 0.9 s. Its early stop on a perfect validation score is resumed too.
pub const ARRAY_RUN: &str = "thor_all-ntg";

/// What the soak starts: `ntg train` into a run folder, or an array task
/// into a runs folder (its run folder `RUNS/quick/ARRAY_RUN`).
#[derive(Clone)]
enum Target {
    Train { epochs: usize },
    ArrayTask { index: usize },
}

impl Target {
    /// The arguments of one start into `out` (`resume`: a training run
    /// that has started before).
    fn args(&self, out: &Path, resume: bool) -> Vec<String> {
        match self {
            Target::Train { epochs } => {
                let mut args = train_args(out, *epochs);
                if resume {
                    args.push("--resume".into());
                }
                args
            }
            Target::ArrayTask { index } => [
                "reproduce",
                "--profile",
                "quick",
                "--jobs",
                "1",
                "--runs",
                &out.display().to_string(),
                "--out",
                &out.join("report").display().to_string(),
                "--array-index",
                &index.to_string(),
            ]
            .map(String::from)
            .to_vec(),
        }
    }

    /// The run folder the start trains in.
    fn run_dir(&self, out: &Path) -> PathBuf {
        match self {
            Target::Train { .. } => out.to_path_buf(),
            Target::ArrayTask { .. } => out.join("quick").join(ARRAY_RUN),
        }
    }
}

/// The index of [`ARRAY_RUN`] in `ntg reproduce --profile quick --list`.
fn array_index(ntg: &Path) -> anyhow::Result<usize> {
    let out = Command::new(ntg)
        .args(["reproduce", "--profile", "quick", "--list", "--json"])
        .output()
        .context("could not start ntg")?;
    if !out.status.success() {
        bail!("ntg reproduce --list failed ({})", out.status);
    }
    let list: serde_json::Value = serde_json::from_slice(&out.stdout)?;
    list.as_array()
        .and_then(|runs| runs.iter().position(|r| r["name"] == ARRAY_RUN))
        .with_context(|| format!("{ARRAY_RUN} is not in the quick profile's list"))
}

/// A small seeded generator (xorshift64*) for the kill delays: xtask stays
/// light (no `rand`).
struct Delays(u64);

impl Delays {
    fn next_unit(&mut self) -> f64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        let x = self.0.wrapping_mul(0x2545_f491_4f6c_dd1d);
        (x >> 11) as f64 / (1u64 << 53) as f64
    }
}

/// The run's arguments: `epochs` epochs of a tiny block-stacking run.
fn train_args(out: &Path, epochs: usize) -> Vec<String> {
    [
        "train",
        "--domain",
        "blocks",
        "--train-tasks",
        "6",
        "--demos-per-task",
        "3",
        "--batch-size",
        "4",
        "--validation-tasks",
        "3",
        "--seed",
        "5",
    ]
    .iter()
    .map(|s| s.to_string())
    .chain([
        "--epochs".to_owned(),
        epochs.to_string(),
        "--out".to_owned(),
        out.display().to_string(),
    ])
    .collect()
}

pub fn build_ntg(root: &Path, release: bool) -> anyhow::Result<PathBuf> {
    let mut args = vec!["build", "--quiet", "-p", "ntg-trainer", "--bin", "ntg"];
    if release {
        args.push("--release");
    }
    let status = Command::new(env!("CARGO"))
        .args(&args)
        .current_dir(root)
        .status()
        .context("could not start cargo")?;
    if !status.success() {
        bail!("building ntg failed ({status})");
    }
    let profile = if release { "release" } else { "debug" };
    let target = std::env::var_os("CARGO_TARGET_DIR")
        .map(PathBuf::from)
        .unwrap_or_else(|| root.join("target"));
    Ok(target.join(profile).join("ntg"))
}

/// Files and folders under `dir`, relative, sorted.
fn listing(dir: &Path) -> anyhow::Result<Vec<PathBuf>> {
    let mut out = Vec::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        for entry in std::fs::read_dir(&d).with_context(|| format!("reading {}", d.display()))? {
            let path = entry?.path();
            out.push(path.strip_prefix(dir)?.to_path_buf());
            if path.is_dir() {
                stack.push(path);
            }
        }
    }
    out.sort();
    Ok(out)
}

/// A burnpack file with its parameter ids zeroed. burn draws a random id
/// for every parameter it creates (the optimizer keys its state by them),
/// so two runs with the same seed differ in these ids and nowhere else:
/// the tensors, their names and their order are the same bytes. (The
/// optimizer's own file is keyed, and ordered, by those ids, so it is not
/// compared as bytes; its state shows in every later step instead: the
/// final weights and every epoch's losses match only if each resume
/// restored it exactly.)
fn without_param_ids(mut bytes: Vec<u8>) -> Vec<u8> {
    const KEY: &[u8] = b"param_id";
    let mut i = 0;
    while let Some(at) = bytes[i..].windows(KEY.len()).position(|w| w == KEY) {
        let head = i + at + KEY.len();
        // A CBOR unsigned integer: 0x18..=0x1b, then 1, 2, 4 or 8 bytes.
        let len = match bytes.get(head) {
            Some(0x18) => 1,
            Some(0x19) => 2,
            Some(0x1a) => 4,
            Some(0x1b) => 8,
            _ => 0,
        };
        let end = (head + 1 + len).min(bytes.len());
        bytes[(head + 1).min(end)..end].fill(0);
        i = head;
    }
    bytes
}

/// The JSON lines of a `metrics.jsonl`-style file with their clock fields
/// (`seconds`, wall; `cpu_seconds`, process CPU) removed: the only fields a
/// killed-and-resumed run may differ in.
fn without_clock_fields(path: &Path) -> anyhow::Result<Vec<serde_json::Value>> {
    let text =
        std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
    text.lines()
        .enumerate()
        .map(|(i, line)| {
            let mut value: serde_json::Value = serde_json::from_str(line)
                .with_context(|| format!("{} line {}: not JSON", path.display(), i + 1))?;
            if let Some(fields) = value.as_object_mut() {
                fields.remove("seconds");
                fields.remove("cpu_seconds");
            }
            Ok(value)
        })
        .collect()
}

/// Wall time of one `ntg train` run of `epochs` epochs into `out`.
fn timed_run(ntg: &Path, out: &Path, epochs: usize) -> anyhow::Result<Duration> {
    let started = Instant::now();
    let status = Command::new(ntg)
        .args(train_args(out, epochs))
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .status()
        .context("could not start ntg")?;
    if !status.success() {
        bail!("the probe run of {epochs} epochs failed ({status})");
    }
    Ok(started.elapsed())
}

/// How many epochs the run needs so that it is still training when the
/// last kill lands, measured on this machine: every attempt trains for at
/// most `max_delay` before its kill, so `kills * max_delay` of epoch time
/// is the most the kills can get through. A fixed count is too short on a
/// fast machine (CI's soak once finished after 4 of 5 kills). The epoch
/// time is the difference of a 1-epoch and a 5-epoch probe run (start-up
/// and data generation cancel), and the count is twice what the kills
/// could get through, never under 20.
fn epochs_outlasting_kills(ntg: &Path, work: &Path, soak: &Soak) -> anyhow::Result<usize> {
    let short = timed_run(ntg, &work.join("probe-1"), 1)?;
    let long = timed_run(ntg, &work.join("probe-5"), 5)?;
    for probe in ["probe-1", "probe-5"] {
        let dir = work.join(probe);
        std::fs::remove_dir_all(&dir).with_context(|| format!("removing {}", dir.display()))?;
    }
    let per_epoch = (long.saturating_sub(short).as_secs_f64() / 4.0).max(1e-3);
    let reachable = soak.kills as f64 * soak.max_delay.as_secs_f64() / per_epoch;
    Ok(((2.0 * reachable).ceil() as usize).max(20))
}

/// Runs the soak in `work` (created afresh) and prints its report.
pub fn run(root: &Path, work: &Path, soak: &Soak) -> anyhow::Result<()> {
    let ntg = match &soak.ntg {
        Some(path) if path.is_file() => path.clone(),
        Some(path) => bail!("--ntg {}: no such file (build it first)", path.display()),
        None => build_ntg(root, soak.release)?,
    };
    if work.exists() {
        std::fs::remove_dir_all(work).with_context(|| format!("removing {}", work.display()))?;
    }
    std::fs::create_dir_all(work).with_context(|| format!("creating {}", work.display()))?;
    let straight_out = work.join("straight");
    let soaked_out = work.join("soaked");
    let target = if soak.array {
        Target::ArrayTask {
            index: array_index(&ntg)?,
        }
    } else {
        Target::Train {
            epochs: epochs_outlasting_kills(&ntg, work, soak)?,
        }
    };
    let (straight, soaked) = (target.run_dir(&straight_out), target.run_dir(&soaked_out));

    let started = Instant::now();
    let status = Command::new(&ntg)
        .args(target.args(&straight_out, false))
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .status()
        .context("could not start ntg")?;
    if !status.success() {
        bail!("the uninterrupted run failed ({status})");
    }
    let straight_time = started.elapsed();

    let mut delays = Delays(soak.seed.wrapping_mul(0x9e37_79b9_7f4a_7c15) | 1);
    let mut killed = 0usize;
    let started = Instant::now();
    let mut terminated = 0usize;
    for k in 0..soak.kills {
        let args = target.args(&soaked_out, soaked.join("config.json").is_file());
        let mut child = Command::new(&ntg)
            .args(&args)
            .stdout(Stdio::null())
            .stderr(Stdio::piped())
            .spawn()
            .context("could not start ntg")?;
        let span = soak.max_delay.saturating_sub(soak.min_delay);
        let delay = soak.min_delay + span.mul_f64(delays.next_unit());
        let deadline = Instant::now() + delay;
        let exited = loop {
            if let Some(status) = child.try_wait()? {
                break Some(status);
            }
            if Instant::now() >= deadline {
                break None;
            }
            std::thread::sleep(Duration::from_millis(5));
        };
        match exited {
            // An array task is stopped as Slurm stops one: SIGTERM (ntg
            // exits at once, status 130), every second time SIGKILL.
            None if soak.array && k % 2 == 0 => {
                let sent = Command::new("kill")
                    .args(["-TERM", &child.id().to_string()])
                    .status()?;
                let status = child.wait()?;
                if !sent.success() || !(status.code() == Some(130) || status.code().is_none()) {
                    bail!("SIGTERM {k}: ntg ended with {status}, not 130");
                }
                killed += 1;
                terminated += 1;
            }
            None => {
                child.kill().context("killing ntg")?;
                child.wait()?;
                killed += 1;
            }
            Some(status) if status.success() => {
                bail!(
                    "the run finished after {killed} kills, before kill {}: the soak needs a longer run",
                    k + 1
                );
            }
            Some(status) => {
                let mut err = String::new();
                if let Some(mut pipe) = child.stderr.take() {
                    use std::io::Read;
                    let _ = pipe.read_to_string(&mut err);
                }
                bail!("resume {k} failed ({status}) after {killed} kills:\n{err}");
            }
        }
    }
    let args = target.args(&soaked_out, soaked.join("config.json").is_file());
    let output = Command::new(&ntg)
        .args(&args)
        .output()
        .context("could not start ntg")?;
    if !output.status.success() {
        bail!(
            "the final resume failed ({}):\n{}",
            output.status,
            String::from_utf8_lossy(&output.stderr)
        );
    }
    let soak_time = started.elapsed();

    let mut problems = Vec::new();
    for file in [
        "checkpoint/model.bpk",
        "checkpoint/config.json",
        "best/model.bpk",
        "best/selection.json",
    ] {
        let (a, b) = (straight.join(file), soaked.join(file));
        let (a, b) = (
            std::fs::read(&a).with_context(|| format!("reading {}", a.display()))?,
            std::fs::read(&b).with_context(|| format!("reading {}", b.display()))?,
        );
        if without_param_ids(a) != without_param_ids(b) {
            problems.push(format!("{file} differs from the uninterrupted run's"));
        }
    }
    let mut logs = vec!["metrics.jsonl".to_owned(), "validation.jsonl".to_owned()];
    if soak.array {
        // The test evaluation (every episode's outcome), as `eval/*.json`.
        for entry in std::fs::read_dir(straight.join("eval"))? {
            let name = entry?.file_name().to_string_lossy().into_owned();
            logs.push(format!("eval/{name}"));
        }
    }
    for file in &logs {
        let read = |dir: &Path| -> anyhow::Result<Vec<serde_json::Value>> {
            if file.starts_with("eval/") {
                let text = std::fs::read_to_string(dir.join(file))
                    .with_context(|| format!("reading {}", dir.join(file).display()))?;
                let mut value: serde_json::Value = serde_json::from_str(&text)?;
                if let Some(fields) = value.as_object_mut() {
                    fields.retain(|k, _| !k.contains("seconds"));
                }
                Ok(vec![value])
            } else {
                without_clock_fields(&dir.join(file))
            }
        };
        if read(&straight)? != read(&soaked)? {
            problems.push(format!(
                "{file} differs (times aside) from the uninterrupted run's"
            ));
        }
    }
    let stray: Vec<PathBuf> = listing(&soaked)?
        .into_iter()
        .filter(|p| {
            let name = p.to_string_lossy();
            name.ends_with(".tmp")
                || name.ends_with(".next")
                || name.ends_with(".old")
                || name.contains(".tmp")
                || name.ends_with("train.lock")
        })
        .collect();
    if !stray.is_empty() {
        problems.push(format!("stray files left: {stray:?}"));
    }
    // TensorBoard's event files: one per training session, named by its
    // start time, so the soaked run has one per resume (TensorBoard merges
    // them; their encoding is tested in ntg-train's `events`). Compared by
    // presence, the rest by name.
    let is_events = |p: &PathBuf| p.to_string_lossy().contains("events.out.tfevents.");
    let (straight_files, soaked_files) = (listing(&straight)?, listing(&soaked)?);
    if !straight_files.iter().any(is_events) || !soaked_files.iter().any(is_events) {
        problems.push("a run folder has no TensorBoard event file".into());
    }
    let others = |files: Vec<PathBuf>| -> Vec<PathBuf> {
        files.into_iter().filter(|p| !is_events(p)).collect()
    };
    if others(straight_files) != others(soaked_files) {
        problems.push("the two run folders hold different files".into());
    }

    match &target {
        Target::Train { epochs } => {
            println!("soak: {killed} kills during a {epochs}-epoch run, then resumed to the end")
        }
        Target::ArrayTask { index } => println!(
            "soak: {killed} stops ({terminated} SIGTERM, the others SIGKILL) of array task {index} ({ARRAY_RUN}, profile quick), then run to the end"
        ),
    }
    println!(
        "time: uninterrupted run {:.1}s; soak {:.1}s",
        straight_time.as_secs_f64(),
        soak_time.as_secs_f64()
    );
    if problems.is_empty() {
        println!(
            "ok: every resume started cleanly; the final weights, the selected weights and every epoch's metrics{} equal the uninterrupted run's; no stray files",
            if soak.array {
                " and the test evaluation's episodes"
            } else {
                ""
            }
        );
        Ok(())
    } else {
        bail!("soak failed:\n- {}", problems.join("\n- "))
    }
}
