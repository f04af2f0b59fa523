//! Helpers shared by the CLI integration tests.

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
