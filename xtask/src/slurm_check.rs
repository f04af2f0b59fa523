//! `cargo xtask slurm-check`: the smoke profile through a real Slurm.
//!
//! 1. Installs Slurm and munge from the distribution's packages where their
//!    daemons are missing (`apt-get`, as root).
//! 2. Starts a one-node cluster on localhost inside the working folder: its
//!    own munge key and socket, `slurm.conf`, state and spool folders, on
//!    ports free at the time; nothing under /etc is touched.
//! 3. Runs `ntg reproduce --profile smoke` locally, for reference.
//! 4. Writes the submit script (`ntg cluster slurm --profile smoke`),
//!    submits it, and requeues one video task as soon as it runs
//!    (`scontrol requeue`): its log must show an attempt cut short and a
//!    second one that finished. Then waits for every job.
//! 5. Compares the cluster's figures, `results.json` and `REPORT.md` with
//!    the local run's: equal byte for byte once the run folders' paths and
//!    the clock readings (training seconds, the report's times, its
//!    paragraphs on the invocation's compute) are set aside.
//! 6. Stops every daemon it started, whatever happened.

use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use anyhow::{Context, bail};

/// Options of `cargo xtask slurm-check`.
#[derive(Debug, Clone)]
pub struct SlurmCheck {
    /// The ntg binary (built in release mode when not given).
    pub ntg: Option<PathBuf>,
    /// The working folder (replaced).
    pub work: PathBuf,
    /// How long to wait for the jobs.
    pub timeout: Duration,
}

/// The daemons started, stopped on drop.
struct Daemons {
    pid_files: Vec<PathBuf>,
    children: Vec<Child>,
    slurm_conf: Option<PathBuf>,
}

impl Drop for Daemons {
    fn drop(&mut self) {
        if let Some(conf) = &self.slurm_conf {
            // Jobs first, so no task outlives the check.
            let _ = Command::new("scancel")
                .args(["--user", "root"])
                .env("SLURM_CONF", conf)
                .stderr(Stdio::null())
                .status();
        }
        for child in &mut self.children {
            let _ = child.kill();
            let _ = child.wait();
        }
        let mut pids = Vec::new();
        for file in &self.pid_files {
            if let Ok(pid) = std::fs::read_to_string(file) {
                let pid = pid.trim().to_owned();
                let _ = Command::new("kill").arg(&pid).status();
                pids.push(pid);
            }
        }
        // They save their state on SIGTERM: wait (10 s at most) until they
        // are gone, so that the check ends with none of them running.
        let alive = |pid: &String| {
            Command::new("kill")
                .args(["-0", pid])
                .stderr(Stdio::null())
                .status()
                .is_ok_and(|s| s.success())
        };
        let until = Instant::now() + Duration::from_secs(10);
        while pids.iter().any(alive) && Instant::now() < until {
            std::thread::sleep(Duration::from_millis(100));
        }
        match pids.iter().filter(|p| alive(p)).count() {
            0 => eprintln!("slurm-check: daemons stopped"),
            n => eprintln!("slurm-check: {n} daemons still running 10 s after SIGTERM"),
        }
    }
}

fn have(program: &str) -> bool {
    Command::new("sh")
        .args(["-c", &format!("command -v {program}")])
        .stdout(Stdio::null())
        .status()
        .is_ok_and(|s| s.success())
}

fn run(command: &mut Command, what: &str) -> anyhow::Result<String> {
    let out = command
        .output()
        .with_context(|| format!("could not start {what}"))?;
    if !out.status.success() {
        bail!(
            "{what} failed ({}): {}{}",
            out.status,
            String::from_utf8_lossy(&out.stdout),
            String::from_utf8_lossy(&out.stderr)
        );
    }
    Ok(String::from_utf8_lossy(&out.stdout).into_owned())
}

fn install_slurm() -> anyhow::Result<()> {
    let daemons = [
        "slurmctld",
        "slurmd",
        "munged",
        "sbatch",
        "scontrol",
        "squeue",
    ];
    if daemons.iter().all(|d| have(d)) {
        return Ok(());
    }
    eprintln!("slurm-check: installing slurmctld, slurmd, slurm-client and munge (apt-get)");
    run(
        Command::new("apt-get").arg("update").stdout(Stdio::null()),
        "apt-get update",
    )?;
    run(
        Command::new("apt-get")
            .args([
                "install",
                "-y",
                "--no-install-recommends",
                "slurmctld",
                "slurmd",
                "slurm-client",
                "munge",
            ])
            .env("DEBIAN_FRONTEND", "noninteractive")
            .stdout(Stdio::null()),
        "apt-get install",
    )?;
    Ok(())
}

/// A TCP port free on 127.0.0.1 now.
fn free_port() -> anyhow::Result<u16> {
    let listener = std::net::TcpListener::bind("127.0.0.1:0")?;
    Ok(listener.local_addr()?.port())
}

fn s(p: &Path) -> &str {
    p.to_str().expect("paths of the check are UTF-8")
}

/// Starts munge and a one-node Slurm in `dir`; returns the daemons and
/// the path of `slurm.conf`.
fn start_cluster(dir: &Path) -> anyhow::Result<(Daemons, PathBuf)> {
    let munge = dir.join("munge");
    for sub in ["munge", "state", "spool", "log"] {
        std::fs::create_dir_all(dir.join(sub))?;
    }
    let key = munge.join("munge.key");
    run(
        Command::new("mungekey").args(["--create", "--keyfile", s(&key)]),
        "mungekey",
    )?;
    let socket = munge.join("munge.socket");
    let mut daemons = Daemons {
        pid_files: Vec::new(),
        children: Vec::new(),
        slurm_conf: None,
    };
    run(
        Command::new("munged").args([
            "--force",
            &format!("--key-file={}", s(&key)),
            &format!("--socket={}", s(&socket)),
            &format!("--pid-file={}", s(&munge.join("munged.pid"))),
            &format!("--log-file={}", s(&munge.join("munged.log"))),
            &format!("--seed-file={}", s(&munge.join("munged.seed"))),
        ]),
        "munged",
    )?;
    daemons.pid_files.push(munge.join("munged.pid"));

    let memory_mb = std::fs::read_to_string("/proc/meminfo")?
        .lines()
        .find_map(|l| l.strip_prefix("MemTotal:"))
        .and_then(|v| v.split_whitespace().next()?.parse::<u64>().ok())
        .map(|kb| kb / 1024 * 8 / 10)
        .context("reading MemTotal from /proc/meminfo")?;
    let cpus = std::thread::available_parallelism().map_or(1, |n| n.get());
    let conf = dir.join("slurm.conf");
    let d = |sub: &str| dir.join(sub).to_str().unwrap().to_owned();
    std::fs::write(
        &conf,
        format!(
            "ClusterName=ntgcheck\n\
             SlurmctldHost=localhost\n\
             SlurmUser=root\n\
             SlurmctldPort={ctld}\n\
             SlurmdPort={slurmd}\n\
             AuthType=auth/munge\n\
             AuthInfo=socket={socket}\n\
             CredType=cred/munge\n\
             StateSaveLocation={state}\n\
             SlurmdSpoolDir={spool}\n\
             SlurmctldPidFile={log}/slurmctld.pid\n\
             SlurmdPidFile={log}/slurmd.pid\n\
             SlurmctldLogFile={log}/slurmctld.log\n\
             SlurmdLogFile={log}/slurmd.log\n\
             ProctrackType=proctrack/linuxproc\n\
             TaskPlugin=task/none\n\
             SelectType=select/cons_tres\n\
             SelectTypeParameters=CR_CPU_Memory\n\
             JobAcctGatherType=jobacct_gather/none\n\
             AccountingStorageType=accounting_storage/none\n\
             MpiDefault=none\n\
             ReturnToService=2\n\
             JobRequeue=1\n\
             NodeName=localhost CPUs={cpus} RealMemory={memory_mb} State=UNKNOWN\n\
             PartitionName=check Nodes=localhost Default=YES MaxTime=INFINITE State=UP\n",
            ctld = free_port()?,
            slurmd = free_port()?,
            socket = s(&socket),
            state = d("state"),
            spool = d("spool"),
            log = d("log"),
        ),
    )?;
    daemons.slurm_conf = Some(conf.clone());
    run(
        Command::new("slurmctld").args(["-f", s(&conf)]),
        "slurmctld",
    )?;
    daemons.pid_files.push(dir.join("log/slurmctld.pid"));
    run(
        Command::new("slurmd").args(["-f", s(&conf), "-N", "localhost"]),
        "slurmd",
    )?;
    daemons.pid_files.push(dir.join("log/slurmd.pid"));
    // The node up and idle.
    let started = Instant::now();
    loop {
        let state = Command::new("sinfo")
            .args(["-h", "-o", "%T"])
            .env("SLURM_CONF", &conf)
            .output()
            .map(|o| String::from_utf8_lossy(&o.stdout).trim().to_owned())
            .unwrap_or_default();
        if state == "idle" {
            break;
        }
        if started.elapsed() > Duration::from_secs(60) {
            bail!(
                "the Slurm node did not come up in 60 s (sinfo: {state:?}); see {}",
                dir.join("log").display()
            );
        }
        std::thread::sleep(Duration::from_millis(500));
    }
    Ok((daemons, conf))
}

/// `text` with every `*seconds*` field of a JSON value removed and the
/// folder `root` written as `ROOT`.
fn without_clocks_json(text: &str, root: &Path) -> anyhow::Result<serde_json::Value> {
    fn strip(value: &mut serde_json::Value) {
        match value {
            serde_json::Value::Object(map) => {
                map.retain(|k, _| !k.contains("seconds"));
                map.values_mut().for_each(strip);
            }
            serde_json::Value::Array(items) => items.iter_mut().for_each(strip),
            _ => {}
        }
    }
    let mut value: serde_json::Value = serde_json::from_str(&text.replace(s(root), "ROOT"))?;
    strip(&mut value);
    Ok(value)
}

/// A Markdown report with its clock readings (`12 s`, `0.5 core-hours`,
/// `69.1 hours`) written as `#`, `root` as `ROOT`, and without the two
/// paragraphs about the invocation and its compute (how long it took, on
/// how many threads, and which runs recorded their CPU time: a run records
/// it where it had its process alone, as every array task does).
fn without_clocks_text(text: &str, root: &Path) -> String {
    let text: String = text
        .replace(s(root), "ROOT")
        .lines()
        .filter(|l| !(l.starts_with("Profile `") || l.starts_with("**Compute.**")))
        .map(|l| format!("{l}\n"))
        .collect();
    let mut out = String::with_capacity(text.len());
    let words: Vec<&str> = text.split(' ').collect();
    for (i, word) in words.iter().enumerate() {
        let next = words.get(i + 1).copied().unwrap_or("");
        let unit = [
            "s",
            "s)",
            "s;",
            "s,",
            "s.",
            "core-hours",
            "hours",
            "CPU",
            "min",
        ]
        .iter()
        .any(|u| next.starts_with(u) && next.len() <= u.len() + 1);
        let number = !word.is_empty()
            && word
                .chars()
                .all(|c| c.is_ascii_digit() || c == '.' || c == ',');
        if i > 0 {
            out.push(' ');
        }
        out.push_str(if number && unit { "#" } else { word });
    }
    out
}

/// Files under `dir`, relative, sorted (folders descended).
fn files(dir: &Path) -> anyhow::Result<Vec<PathBuf>> {
    let mut found = Vec::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        for entry in std::fs::read_dir(&d).with_context(|| format!("reading {}", d.display()))? {
            let path = entry?.path();
            if path.is_dir() {
                if path.file_name().is_some_and(|n| n == "slurm-logs") {
                    continue;
                }
                stack.push(path);
            } else {
                found.push(path.strip_prefix(dir)?.to_path_buf());
            }
        }
    }
    found.sort();
    Ok(found)
}

/// Compares the cluster's report folder with the local one's.
fn compare(local: &Path, cluster: &Path) -> anyhow::Result<usize> {
    let (a, b) = (files(&local.join("out"))?, files(&cluster.join("out"))?);
    if a != b {
        bail!("the cluster wrote other files than the local run: {b:?} against {a:?}");
    }
    for file in &a {
        let (x, y) = (local.join("out").join(file), cluster.join("out").join(file));
        let name = file.to_string_lossy();
        let equal = if name.ends_with(".json") {
            without_clocks_json(&std::fs::read_to_string(&x)?, local)?
                == without_clocks_json(&std::fs::read_to_string(&y)?, cluster)?
        } else if name.ends_with(".md") {
            without_clocks_text(&std::fs::read_to_string(&x)?, local)
                == without_clocks_text(&std::fs::read_to_string(&y)?, cluster)
        } else {
            std::fs::read(&x)? == std::fs::read(&y)?
        };
        if !equal {
            bail!(
                "{name} differs between the local run ({}) and the cluster's ({}), clocks and paths aside",
                x.display(),
                y.display()
            );
        }
    }
    Ok(a.len())
}

fn squeue(conf: &Path, args: &[&str]) -> String {
    Command::new("squeue")
        .args(args)
        .env("SLURM_CONF", conf)
        .output()
        .map(|o| String::from_utf8_lossy(&o.stdout).into_owned())
        .unwrap_or_default()
}

/// Runs the check.
pub fn check(root: &Path, opts: &SlurmCheck) -> anyhow::Result<()> {
    let started = Instant::now();
    install_slurm()?;
    let ntg = match &opts.ntg {
        Some(p) => std::path::absolute(root.join(p))?,
        None => crate::soak::build_ntg(root, true)?,
    };
    let work = std::path::absolute(root.join(&opts.work))?;
    if work.exists() {
        std::fs::remove_dir_all(&work).with_context(|| format!("replacing {}", work.display()))?;
    }
    std::fs::create_dir_all(&work)?;
    let (daemons, conf) = start_cluster(&work.join("slurm"))?;
    eprintln!(
        "slurm-check: one-node cluster up ({:.0} s)",
        started.elapsed().as_secs_f64()
    );

    let local = work.join("local");
    let t = Instant::now();
    run(
        Command::new(&ntg)
            .args(["reproduce", "--profile", "smoke", "--runs"])
            .arg(local.join("runs"))
            .arg("--out")
            .arg(local.join("out")),
        "the local ntg reproduce --profile smoke",
    )?;
    let local_time = t.elapsed();

    let cluster = work.join("cluster");
    std::fs::create_dir_all(&cluster)?;
    let script = cluster.join("submit.sh");
    run(
        Command::new(&ntg)
            .args(["cluster", "slurm", "--profile", "smoke", "--runs"])
            .arg(cluster.join("runs"))
            .arg("--out")
            .arg(cluster.join("out"))
            .arg("--script")
            .arg(&script),
        "ntg cluster slurm",
    )?;
    let t = Instant::now();
    let submitted = run(
        Command::new("bash")
            .arg(&script)
            .env("SLURM_CONF", &conf)
            .env("STATE_MEM", "2G")
            .env("VIDEO_MEM", "3G")
            .env("REPORT_MEM", "3G")
            .env("STATE_TIME", "00:30:00")
            .env("VIDEO_TIME", "00:30:00")
            .env("REPORT_TIME", "00:30:00")
            .env("REQUEUE_BEFORE", "60"),
        "the submit script",
    )?;
    eprint!("{submitted}");
    // The video arrays' jobs: "wave W, video: job ID (array SPEC)".
    let video_jobs: Vec<(String, Vec<String>)> = submitted
        .lines()
        .filter(|l| l.contains(", video: job "))
        .filter_map(|l| {
            let rest = l.split(", video: job ").nth(1)?;
            let (id, spec) = rest.split_once(" (array ")?;
            let tasks = spec
                .trim_end_matches(')')
                .split(',')
                .flat_map(|part| match part.split_once('-') {
                    Some((a, b)) => {
                        let (a, b): (usize, usize) = (a.parse().ok()?, b.parse().ok()?);
                        Some((a..=b).map(|i| i.to_string()).collect::<Vec<_>>())
                    }
                    None => Some(vec![part.to_owned()]),
                })
                .flatten()
                .collect();
            Some((id.to_owned(), tasks))
        })
        .collect();
    if video_jobs.is_empty() {
        bail!("the submit script submitted no video array: {submitted}");
    }

    // The run folder of each list index.
    let listed: serde_json::Value = serde_json::from_str(&run(
        Command::new(&ntg).args(["reproduce", "--profile", "smoke", "--list", "--json"]),
        "ntg reproduce --list",
    )?)?;
    let run_name = |index: &str| -> Option<String> {
        let i: usize = index.parse().ok()?;
        Some(listed.get(i)?.get("name")?.as_str()?.to_owned())
    };
    // Requeue a video task mid-run: once it runs and its run folder exists
    // (training has begun), before it ends; the next one if it ended first.
    let mut requeued: Option<(String, String)> = None;
    let deadline = Instant::now() + opts.timeout;
    'tasks: for (job, tasks) in &video_jobs {
        for task in tasks {
            let id = format!("{job}_{task}");
            let name = run_name(task).context("an array index outside --list")?;
            let folder = cluster.join("runs/smoke").join(&name);
            while Instant::now() < deadline {
                let state = squeue(&conf, &["-h", "-j", &id, "-o", "%T"]);
                let state = state.trim();
                if state.is_empty() || state == "COMPLETED" {
                    break; // ended before it could be caught
                }
                if state == "RUNNING" && folder.join("config.json").exists() {
                    let done = Command::new("scontrol")
                        .args(["requeue", &id])
                        .env("SLURM_CONF", &conf)
                        .stderr(Stdio::null())
                        .status()?;
                    if done.success() {
                        eprintln!("slurm-check: requeued {id} ({name}) while it trained");
                        requeued = Some((id, name));
                        break 'tasks;
                    }
                    break;
                }
                std::thread::sleep(Duration::from_millis(20));
            }
        }
    }
    let Some((requeued, requeued_name)) = requeued else {
        bail!("no video task could be requeued mid-run (each ended before it was caught)");
    };
    // Every job done.
    loop {
        let left = squeue(&conf, &["-h", "-o", "%i %T"]);
        if left.trim().is_empty() {
            break;
        }
        if Instant::now() > deadline {
            bail!(
                "jobs still queued after {} s:\n{left}",
                opts.timeout.as_secs()
            );
        }
        std::thread::sleep(Duration::from_secs(1));
    }
    let cluster_time = t.elapsed();
    drop(daemons);

    // The requeued task's log: one attempt cut short, one finished.
    let (job, task) = requeued.split_once('_').expect("an array task id");
    let logs = cluster.join("out/slurm-logs");
    let log = std::fs::read_dir(&logs)?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .find(|p| {
            p.file_name()
                .is_some_and(|n| n.to_string_lossy().ends_with(&format!("_{job}_{task}.log")))
        })
        .with_context(|| format!("no log of {requeued} in {}", logs.display()))?;
    let text = std::fs::read_to_string(&log)?;
    // `ntg reproduce` says "N of N runs done" once a run has finished and
    // been evaluated: once, so the attempt that was requeued did not finish.
    let attempts = text.matches("array task ").count();
    let finished = text.matches(" runs done").count();
    eprintln!(
        "slurm-check: {} ({requeued_name}): {attempts} attempts logged, {finished} finished",
        log.display()
    );
    if finished != 1 {
        bail!(
            "{requeued} ({requeued_name}) finished {finished} times ({}): the requeue did not cut a run short",
            log.display()
        );
    }

    let compared = compare(&local, &cluster)?;
    println!(
        "slurm-check passed: {compared} files of the smoke profile's report equal the local run's (clocks and paths aside), with {requeued} requeued mid-run; local run {:.0} s, cluster {:.0} s, check {:.0} s in all",
        local_time.as_secs_f64(),
        cluster_time.as_secs_f64(),
        started.elapsed().as_secs_f64()
    );
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn clock_readings_are_masked_and_nothing_else() {
        let root = Path::new("/w/local");
        let a = without_clocks_text(
            "trained in 12 s on /w/local/runs, 0.5 core-hours; 3 tasks",
            root,
        );
        assert_eq!(a, "trained in # s on ROOT/runs, # core-hours; 3 tasks\n");
        let v = without_clocks_json(
            r#"{"train_seconds": 1.5, "run": "/w/local/runs/x", "success": 0.25}"#,
            root,
        )
        .unwrap();
        assert_eq!(
            v,
            serde_json::json!({"run": "ROOT/runs/x", "success": 0.25})
        );
    }
}
