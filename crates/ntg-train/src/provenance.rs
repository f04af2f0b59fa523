//! Where and with what each stretch of a run's training ran: the run
//! folder's `sessions.jsonl`, one [`Session`] line per stretch, written by
//! [`crate::fit::fit`] when training starts or resumes. Results are
//! deterministic per machine, not across CPUs, so a run says where each of
//! its epochs was trained.

use crate::run_dir::RunDir;
use serde::{Deserialize, Serialize};

/// One stretch of training of a run (a line of its `sessions.jsonl`):
/// results are deterministic per machine, not across CPUs (README), so a
/// record says where each epoch was trained.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Session {
    /// The first epoch (from 0) trained in it.
    pub from_epoch: usize,
    /// The commit the binary was built from (see [`commit`]).
    pub commit: String,
    /// The CPU and thread count.
    pub machine: String,
    /// Whether the process flushed subnormal floats to zero
    /// (`ntg_model::float_mode`); absent in lines written before the
    /// mode existed, whose binaries kept them.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub flush_subnormals: Option<bool>,
    /// The threads the run computed on (its rayon pool); absent in lines
    /// written before it was noted, whose runs computed on one thread
    /// (`ntg reproduce`'s share of 2 cores at 2 runs at a time) unless the
    /// record's notes say otherwise.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub compute_threads: Option<usize>,
}

impl Session {
    /// Whether this stretch flushed subnormals (absent: it did not).
    pub fn flushed_subnormals(&self) -> bool {
        self.flush_subnormals.unwrap_or(false)
    }
}

/// Notes in `run`'s `sessions.jsonl` that training starts (or resumes) at
/// epoch `from_epoch` here, warning on stderr when earlier stretches ran
/// in another float mode ([`mixed_float_mode_warning`]).
pub fn note_session(run: &RunDir, from_epoch: usize) -> anyhow::Result<()> {
    if let Some(warning) = mixed_float_mode_warning(run, ntg_model::flushes_subnormals())? {
        eprintln!("warning: {warning}");
    }
    RunDir::append_jsonl(
        &run.root().join("sessions.jsonl"),
        &Session {
            from_epoch,
            commit: commit(),
            machine: machine(),
            flush_subnormals: Some(ntg_model::flushes_subnormals()),
            compute_threads: Some(rayon::current_num_threads()),
        },
    )
}

/// What to tell a user who resumes `run` in float mode `flushing`
/// (`ntg_model::float_mode`) when stretches before ran in the other: the
/// run will mix them, and no single-mode rerun can repeat it.
pub fn mixed_float_mode_warning(run: &RunDir, flushing: bool) -> anyhow::Result<Option<String>> {
    let path = run.root().join("sessions.jsonl");
    if !path.is_file() {
        return Ok(None);
    }
    let sessions: Vec<Session> = crate::run_dir::read_jsonl(&path)?;
    let other = sessions
        .iter()
        .filter(|s| s.flushed_subnormals() != flushing)
        .count();
    Ok((other > 0).then(|| {
        let (then, now, value) = if flushing {
            ("kept", "flushes", "0")
        } else {
            ("flushed", "keeps", "1")
        };
        format!(
            "{}: {other} earlier training stretch(es) {then} subnormal floats and this process {now} \
             them, so the run mixes the two modes; NTG_FLUSH_SUBNORMALS={value} resumes it in its \
             earlier mode",
            run.root().display()
        )
    }))
}

/// The commit this binary was built from (`build.rs`): `-dirty` if the
/// workspace's code had uncommitted changes then, `unknown` if it was not
/// built in a git checkout.
pub fn commit() -> String {
    env!("NTG_BUILD_COMMIT").to_owned()
}

/// The machine this process runs on, in words: the CPU's model name and
/// the threads it offers ("Intel(R) Xeon(R) Processor, 2 threads").
pub fn machine() -> String {
    let cpu = std::fs::read_to_string("/proc/cpuinfo")
        .ok()
        .and_then(|info| {
            info.lines()
                .find(|l| l.starts_with("model name"))
                .and_then(|l| l.split(':').nth(1))
                .map(|m| m.trim().to_owned())
        })
        .unwrap_or_else(|| std::env::consts::ARCH.to_owned());
    let threads = std::thread::available_parallelism().map_or(1, |n| n.get());
    format!("{cpu}, {threads} threads")
}
