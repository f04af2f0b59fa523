//! Watching training: the TensorBoard event files `fit` writes beside
//! `metrics.jsonl`, and `ntg plot`.
//!
//! Where `NTG_PYTHON` (default `python3`) has the `tensorboard` package,
//! its own event reader (`EventAccumulator`) reads the run's events back;
//! without it that half prints "skipped:" to stderr.

use std::path::Path;
use std::process::{Command, Stdio};

use crate::common::ntg;

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

fn python() -> String {
    std::env::var("NTG_PYTHON").unwrap_or_else(|_| "python3".to_owned())
}

#[test]
fn events_and_plot() {
    let tmp = tempfile::tempdir().unwrap();
    let run = tmp.path().join("run");
    let (code, _, err) = ntg(&[
        "train",
        "--domain",
        "blocks",
        "--train-tasks",
        "3",
        "--demos-per-task",
        "2",
        "--epochs",
        "2",
        "--validation-tasks",
        "2",
        "--out",
        s(&run),
    ]);
    assert_eq!(code, 0, "{err}");

    // One event file (one session), with every metrics field per epoch
    // and the validation scores under the names the log prints.
    let files = ntg_trainer::events::event_files(&run).unwrap();
    assert_eq!(files.len(), 1, "{files:?}");
    let events = ntg_trainer::events::read_events(&files[0]).unwrap();
    let mut tags: Vec<(i64, String)> = Vec::new();
    for event in &events {
        if let Some(ntg_trainer::events::What::Summary(summary)) = &event.what {
            tags.extend(summary.value.iter().map(|v| (event.step, v.tag.clone())));
        }
    }
    for step in [1, 2] {
        for tag in [
            "train/loss",
            "train/token_accuracy",
            "validation/success",
            "validation/goals_met",
        ] {
            assert!(
                tags.contains(&(step, tag.to_owned())),
                "no {tag} at step {step}: {tags:?}"
            );
        }
    }

    // TensorBoard's own reader.
    let python = python();
    let has_tensorboard = Command::new(&python)
        .args(["-c", "import tensorboard"])
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .status()
        .is_ok_and(|s| s.success());
    if has_tensorboard {
        let script = "import sys\n\
            from tensorboard.backend.event_processing.event_accumulator import EventAccumulator\n\
            ea = EventAccumulator(sys.argv[1]); ea.Reload()\n\
            loss = [(e.step, e.value) for e in ea.Scalars('train/loss')]\n\
            success = [(e.step, e.value) for e in ea.Scalars('validation/success')]\n\
            print(len(loss), len(success), loss[0][0], loss[-1][0])\n";
        let out = Command::new(&python)
            .args(["-c", script, s(&run)])
            .output()
            .unwrap();
        let stdout = String::from_utf8_lossy(&out.stdout);
        assert!(
            out.status.success(),
            "{stdout}{}",
            String::from_utf8_lossy(&out.stderr)
        );
        assert_eq!(stdout.trim(), "2 2 1 2", "TensorBoard read {stdout}");
    } else {
        eprintln!(
            "skipped: TensorBoard's event reader (`{python} -c \"import tensorboard\"` failed; point NTG_PYTHON at a Python with it)"
        );
    }

    // ntg plot: the default file in the run folder, redrawn on each call.
    for _ in 0..2 {
        let (code, stdout, err) = ntg(&["plot", s(&run)]);
        assert_eq!(code, 0, "{err}");
        assert!(stdout.contains("curves.png"), "{stdout}");
    }
    let png = image::open(run.join("curves.png")).unwrap();
    assert!(png.width() > 400 && png.height() > 300);
    // An --out that exists is replaced only with --force.
    let out = tmp.path().join("mine.png");
    std::fs::write(&out, "mine").unwrap();
    let (code, _, err) = ntg(&["plot", s(&run), "--out", s(&out)]);
    assert_eq!(code, 1);
    assert!(err.contains("--force") && err.contains("mine.png"), "{err}");
    assert_eq!(std::fs::read_to_string(&out).unwrap(), "mine");
    let (code, _, err) = ntg(&["plot", s(&run), "--out", s(&out), "--force"]);
    assert_eq!(code, 0, "{err}");
    assert!(image::open(&out).is_ok());
    // Not a run folder; a run folder with no epochs logged.
    let empty = tmp.path().join("empty");
    std::fs::create_dir(&empty).unwrap();
    let (code, _, err) = ntg(&["plot", s(&empty)]);
    assert_eq!(code, 1);
    assert!(err.contains("config.json is missing"), "{err}");
    std::fs::copy(run.join("config.json"), empty.join("config.json")).unwrap();
    let (code, _, err) = ntg(&["plot", s(&empty)]);
    assert_eq!(code, 1);
    assert!(err.contains("no training epochs logged"), "{err}");
}
