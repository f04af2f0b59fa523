//! The cluster interface: `ntg reproduce --list`, `--array-index` (and
//! `SLURM_ARRAY_TASK_ID`), `ntg cluster slurm`. `cargo xtask slurm-check`
//! runs the script on a real Slurm.

use std::path::Path;
use std::process::Command;

use crate::common::ntg;

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

#[test]
fn an_array_task_trains_its_run_of_the_list_as_only_would() {
    let (code, stdout, err) = ntg(&["reproduce", "--profile", "smoke", "--list", "--json"]);
    assert_eq!(code, 0, "{err}");
    let list: serde_json::Value = serde_json::from_str(&stdout).unwrap();
    let list = list.as_array().unwrap();
    assert!(list.len() > 10, "{list:?}");
    let first = list[0]["name"].as_str().unwrap().to_owned();
    let (code, text, err) = ntg(&["reproduce", "--profile", "smoke", "--list"]);
    assert_eq!(code, 0, "{err}");
    assert_eq!(text.lines().count(), list.len());
    assert!(text.lines().next().unwrap().contains(&first), "{text}");

    // Index from SLURM_ARRAY_TASK_ID; the run lands where --only puts it.
    let tmp = tempfile::tempdir().unwrap();
    let runs = tmp.path().join("runs");
    let out = tmp.path().join("out");
    let task = Command::new(env!("CARGO_BIN_EXE_ntg"))
        .args([
            "reproduce",
            "--profile",
            "smoke",
            "--runs",
            s(&runs),
            "--out",
            s(&out),
        ])
        .arg("--array-index")
        .env("SLURM_ARRAY_TASK_ID", "0")
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&task.stderr);
    assert!(task.status.success(), "{err}");
    assert!(err.contains(&format!("array task 0: {first}")), "{err}");
    assert!(
        runs.join("smoke")
            .join(&first)
            .join("config.json")
            .is_file()
    );
    // The same index again reuses the finished run.
    let (code, again, err) = ntg(&[
        "reproduce",
        "--profile",
        "smoke",
        "--runs",
        s(&runs),
        "--out",
        s(&out),
        "--array-index",
        "0",
    ]);
    assert_eq!(code, 0, "{err}");
    assert!(again.contains(&first), "{again}");
}

#[test]
fn the_slurm_script_submits_every_run_and_the_report() {
    let tmp = tempfile::tempdir().unwrap();
    let script = tmp.path().join("submit.sh");
    let (code, stdout, err) = ntg(&[
        "cluster",
        "slurm",
        "--profile",
        "smoke",
        "--runs",
        s(&tmp.path().join("runs")),
        "--script",
        s(&script),
    ]);
    assert_eq!(code, 0, "{err}");
    assert!(stdout.contains("submit with `bash"), "{stdout}");
    let text = std::fs::read_to_string(&script).unwrap();
    let syntax = Command::new("bash")
        .arg("-n")
        .arg(&script)
        .output()
        .unwrap();
    assert!(
        syntax.status.success(),
        "{}",
        String::from_utf8_lossy(&syntax.stderr)
    );
    assert!(text.contains("--array-index"), "{text}");
    assert!(text.contains("--requeue"), "{text}");
    assert!(text.contains("--job-name=\"ntg-smoke-report\""), "{text}");
    // Refused over an existing file without --force.
    let (code, _, err) = ntg(&[
        "cluster",
        "slurm",
        "--profile",
        "smoke",
        "--runs",
        "r",
        "--script",
        s(&script),
    ]);
    assert_eq!(code, 1, "{err}");
    assert!(err.contains("--force"), "{err}");
}

#[test]
fn a_missing_or_bad_task_index_is_named() {
    let run = |env: Option<&str>| {
        let mut command = Command::new(env!("CARGO_BIN_EXE_ntg"));
        command.args([
            "reproduce",
            "--profile",
            "smoke",
            "--runs",
            "/nonexistent",
            "--array-index",
        ]);
        command.env_remove("SLURM_ARRAY_TASK_ID");
        if let Some(value) = env {
            command.env("SLURM_ARRAY_TASK_ID", value);
        }
        let out = command.output().unwrap();
        (
            out.status.code(),
            String::from_utf8_lossy(&out.stderr).into_owned(),
        )
    };
    let (code, err) = run(None);
    assert_eq!(code, Some(1), "{err}");
    assert!(
        err.contains("SLURM_ARRAY_TASK_ID, which is not set"),
        "{err}"
    );
    let (code, err) = run(Some("a7"));
    assert_eq!(code, Some(1), "{err}");
    assert!(
        err.contains("SLURM_ARRAY_TASK_ID=\"a7\" is not a run index"),
        "{err}"
    );
}
