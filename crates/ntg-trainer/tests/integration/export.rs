//! `ntg export` end to end: a tiny trained run's weights as safetensors,
//! checked against the run's own weights here, and, where PyTorch is
//! installed, loaded by the PyTorch twin
//! (`crates/ntg-model/benches/pytorch/twin.py`), which must compute the
//! trained model's outputs, losses and gradients within 1e-4.
//!
//! ```text
//! NTG_PYTHON=/path/to/venv/bin/python cargo test -p ntg-trainer --test integration export:: -- --nocapture
//! ```
//!
//! The interpreter is `NTG_PYTHON` (default `python3`); it needs torch,
//! numpy and safetensors. Without them the PyTorch half prints "skipped:"
//! to stderr and the rest still runs.

use std::path::Path;
use std::process::{Command, Stdio};

use crate::common::{ntg, train_tiny_run};

#[path = "../../../ntg-model/examples/twin_export.rs"]
#[allow(dead_code)] // the example's `main` and constants
mod twin_export;

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

fn python() -> String {
    std::env::var("NTG_PYTHON").unwrap_or_else(|_| "python3".to_owned())
}

fn has_modules(python: &str, modules: &str) -> bool {
    Command::new(python)
        .args(["-c", &format!("import {modules}")])
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .status()
        .is_ok_and(|s| s.success())
}

/// The header of a safetensors file: name → (dtype, shape, byte range).
fn safetensors_header(path: &Path) -> serde_json::Map<String, serde_json::Value> {
    let bytes = std::fs::read(path).unwrap();
    let n = u64::from_le_bytes(bytes[..8].try_into().unwrap()) as usize;
    let header: serde_json::Value = serde_json::from_slice(&bytes[8..8 + n]).unwrap();
    let serde_json::Value::Object(mut map) = header else {
        panic!("{}: the header is not an object", path.display())
    };
    map.remove("__metadata__");
    map
}

/// The f32 values of tensor `name` of a safetensors file.
fn safetensors_values(path: &Path, name: &str) -> Vec<f32> {
    let bytes = std::fs::read(path).unwrap();
    let n = u64::from_le_bytes(bytes[..8].try_into().unwrap()) as usize;
    let header = safetensors_header(path);
    let offsets = &header[name]["data_offsets"];
    let (start, end) = (
        offsets[0].as_u64().unwrap() as usize,
        offsets[1].as_u64().unwrap() as usize,
    );
    bytes[8 + n + start..8 + n + end]
        .chunks_exact(4)
        .map(|c| f32::from_le_bytes(c.try_into().unwrap()))
        .collect()
}

#[test]
fn an_exported_run_holds_its_trained_weights_in_pytorch_layout() {
    let tmp = tempfile::tempdir().unwrap();
    let run = train_tiny_run(tmp.path());

    let out = tmp.path().join("export");
    let (code, stdout, err) = ntg(&["export", s(&run), "--out", s(&out)]);
    assert_eq!(code, 0, "{err}");
    assert!(
        stdout.contains("model.safetensors") && stdout.contains("the last checkpoint"),
        "{stdout}"
    );
    let names: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("names.json")).unwrap()).unwrap();
    assert_eq!(names["format"], "ntg-export/1");
    assert_eq!(names["method"], "ntg");
    assert_eq!(names["source"], "checkpoint");
    assert!(out.join("run.json").is_file() && out.join("model.config.json").is_file());
    let files = names["files"].as_array().unwrap();
    assert_eq!(files.len(), 1, "{names}");
    assert_eq!(files[0]["file"], "model.safetensors");

    // The name map lists exactly the file's tensors, with their shapes, and
    // marks every Linear weight (and nothing else) transposed.
    let file = out.join("model.safetensors");
    let header = safetensors_header(&file);
    let tensors = files[0]["tensors"].as_array().unwrap();
    assert_eq!(tensors.len(), header.len());
    for t in tensors {
        let name = t["name"].as_str().unwrap();
        assert_eq!(header[name]["shape"], t["shape"], "{name}");
        assert_eq!(header[name]["dtype"], "F32", "{name}");
        let linear_weight = t["module"] == "Linear" && name.ends_with(".weight");
        assert_eq!(t["transposed"], linear_weight, "{name}");
    }

    // The values are the trained weights: a Linear weight transposed, an
    // embedding table as it is.
    let device = ntg_model::cpu_device().autodiff();
    let model = ntg_model::NtgModel::load(run.join("checkpoint"), &device).unwrap();
    let burn_out = model.interpreter.out.weight.val(); // [in, out]
    let [d_in, d_out] = burn_out.dims();
    let burn_values = ntg_model::nn::to_vec(burn_out).unwrap();
    let file_values = safetensors_values(&file, "interpreter.out.weight"); // [out, in]
    assert_eq!(
        header["interpreter.out.weight"]["shape"],
        serde_json::json!([d_out, d_in])
    );
    for i in 0..d_in {
        for o in 0..d_out {
            assert_eq!(file_values[o * d_in + i], burn_values[i * d_out + o]);
        }
    }
    let tokens = ntg_model::nn::to_vec(model.interpreter.tokens.val()).unwrap();
    assert_eq!(safetensors_values(&file, "interpreter.tokens"), tokens);

    // An earlier export is replaced only with --force.
    let (code, _, err) = ntg(&["export", s(&run), "--out", s(&out)]);
    assert_ne!(code, 0);
    assert!(err.contains("--force"), "{err}");
    let (code, _, err) = ntg(&["export", s(&run), "--out", s(&out), "--force"]);
    assert_eq!(code, 0, "{err}");

    // As a run folder, the weights evaluate as the run's own do.
    let as_run = tmp.path().join("as-run");
    let (code, _, err) = ntg(&["export", s(&run), "--out", s(&as_run), "--run-folder"]);
    assert_eq!(code, 0, "{err}");
    assert!(as_run.join("checkpoint/model.safetensors").is_file());
    assert!(!as_run.join("checkpoint/model.bpk").exists());
    let eval = |dir: &Path| {
        let (code, out, err) = ntg(&["eval", "--run", s(dir), "--test-tasks", "4"]);
        assert_eq!(code, 0, "{err}");
        out.lines()
            .find(|l| l.contains("success"))
            .unwrap()
            .to_owned()
    };
    assert_eq!(
        eval(&as_run).replace(s(&as_run), ""),
        eval(&run).replace(s(&run), "")
    );
    // A folder it cannot write its records into is evaluated all the
    // same, and says so (here `eval` is a file; a read-only copy is the
    // real case).
    std::fs::remove_dir_all(as_run.join("eval")).unwrap();
    std::fs::write(as_run.join("eval"), "mine").unwrap();
    let (code, out, err) = ntg(&["eval", "--run", s(&as_run), "--test-tasks", "4"]);
    assert_eq!(code, 0, "{err}");
    assert!(
        out.contains("success") && out.contains("not recorded ("),
        "{out}"
    );
    assert_eq!(
        std::fs::read_to_string(as_run.join("eval")).unwrap(),
        "mine"
    );

    // Every committed weights entry (a video run: its policy and its frame
    // encoder) exports too.
    let zoo = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../docs/figures/weights");
    for entry in std::fs::read_dir(&zoo).unwrap() {
        let entry = entry.unwrap().path();
        if !entry.join("config.json").is_file() {
            continue;
        }
        let to = tmp.path().join(entry.file_name().unwrap());
        let (code, _, err) = ntg(&["export", s(&entry), "--out", s(&to)]);
        assert_eq!(code, 0, "{}: {err}", entry.display());
        let names: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(to.join("names.json")).unwrap()).unwrap();
        assert_eq!(names["source"], "best", "{}", entry.display());
        for f in names["files"].as_array().unwrap() {
            let file = to.join(f["file"].as_str().unwrap());
            assert_eq!(
                safetensors_header(&file).len(),
                f["tensors"].as_array().unwrap().len(),
                "{}",
                file.display()
            );
        }
    }

    // PyTorch: the twin loads the file and computes the trained model's
    // outputs, losses and gradients on the twin's batch.
    let python = python();
    if !has_modules(&python, "torch, numpy, safetensors") {
        eprintln!(
            "skipped: the PyTorch round trip (`{python} -c \"import torch, numpy, safetensors\"` \
             failed; point NTG_PYTHON at a Python with them)"
        );
        return;
    }
    let reference = tmp.path().join("trained_twin.json");
    twin_export::export_model(&model, &device, &reference).unwrap();
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("../ntg-model/benches/pytorch/twin.py");
    let result = Command::new(&python)
        .arg(&script)
        .arg(&reference)
        .arg("--weights")
        .arg(&file)
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&result.stdout);
    let stderr = String::from_utf8_lossy(&result.stderr);
    println!("{stdout}");
    assert!(
        result.status.success() && stdout.contains("all within tolerance"),
        "the PyTorch twin on the exported weights disagrees ({}):\n{stdout}\n{stderr}",
        result.status
    );
}
