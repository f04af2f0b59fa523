//! Helpers shared by the CLI integration tests.

use std::path::{Path, PathBuf};
use std::process::Command;

/// Runs the `ntg` binary with `args`: exit code (-1 if killed by a signal),
/// stdout and stderr.
pub fn ntg(args: &[&str]) -> (i32, String, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_ntg"))
        .args(args)
        .output()
        .expect("the ntg binary runs");
    (
        out.status.code().unwrap_or(-1),
        String::from_utf8_lossy(&out.stdout).into_owned(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

/// The `ntg train` flags of the tiny fixture run (state input, 1 epoch).
pub const TINY_RUN: &[&str] = &[
    "train",
    "--domain",
    "blocks",
    "--train-tasks",
    "2",
    "--demos-per-task",
    "2",
    "--epochs",
    "1",
    "--validation-tasks",
    "0",
];

/// A tiny trained block-stacking run in `dir/run` ([`TINY_RUN`]).
pub fn train_tiny_run(dir: &Path) -> PathBuf {
    let run = dir.join("run");
    let args = [TINY_RUN, &["--out", run.to_str().unwrap()]].concat();
    let (code, _, err) = ntg(&args);
    assert_eq!(code, 0, "training the fixture run failed: {err}");
    run
}
