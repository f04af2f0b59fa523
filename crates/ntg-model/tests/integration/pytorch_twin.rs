//! Cross-checks the burn NTG model against its PyTorch twin
//! (`benches/pytorch/twin.py`): exports a seeded model, batch and reference
//! outputs with the `twin_export` example's code, then runs the twin on
//! them, which fails if any output, loss or gradient differs by more than
//! 1e-4.
//!
//! ```text
//! NTG_PYTHON=/path/to/venv/bin/python cargo test -p ntg-model --test integration pytorch_twin -- --nocapture
//! ```
//!
//! The Python interpreter is `NTG_PYTHON` (default `python3`). Without
//! PyTorch there the export still runs, and the test prints
//! "skipped: PyTorch not installed" to stderr and passes.

use std::path::Path;
use std::process::{Command, Stdio};

#[path = "../../examples/twin_export.rs"]
#[allow(dead_code)] // the example's `main`
mod twin_export;

fn python() -> String {
    std::env::var("NTG_PYTHON").unwrap_or_else(|_| "python3".to_owned())
}

fn has_torch(python: &str) -> bool {
    Command::new(python)
        .args(["-c", "import torch"])
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .status()
        .is_ok_and(|s| s.success())
}

#[test]
fn the_pytorch_twin_computes_the_same_outputs_losses_and_gradients() {
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("ntg_twin.json");
    twin_export::export(&file).unwrap();
    assert!(file.metadata().unwrap().len() > 0);

    let python = python();
    if !has_torch(&python) {
        eprintln!(
            "skipped: PyTorch not installed (`{python} -c \"import torch\"` failed; \
             point NTG_PYTHON at a Python with torch and numpy)"
        );
        return;
    }
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("benches/pytorch/twin.py");
    let out = Command::new(&python)
        .arg(&script)
        .arg(&file)
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    let stderr = String::from_utf8_lossy(&out.stderr);
    println!("{stdout}");
    eprintln!("{stderr}");
    assert!(
        out.status.success(),
        "the PyTorch twin disagrees with the burn model ({}):\n{stdout}\n{stderr}",
        out.status
    );
}
