//! `ntg train` → `ntg trace` end to end on a tiny run: the trace folder's
//! files, agreement with `ntg eval`'s rollout of the same task, and the
//! errors for a missing run, an unknown task and an occupied folder; a
//! video run whose interpreter reads pooled frames (`--interpreter-frame-pool`).

use std::path::Path;

use crate::common;
use common::ntg;

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

#[test]
fn trace_writes_frames_graph_and_steps_consistent_with_eval() {
    let tmp = tempfile::tempdir().unwrap();
    let run = tmp.path().join("run");
    let (code, _, err) = ntg(&[
        "train",
        "--train-tasks",
        "3",
        "--demos-per-task",
        "2",
        "--epochs",
        "1",
        "--out",
        s(&run),
    ]);
    assert_eq!(code, 0, "{err}");
    let (code, _, err) = ntg(&["eval", "--run", s(&run), "--test-tasks", "2"]);
    assert_eq!(code, 0, "{err}");
    let eval: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(run.join("eval/full-2.json")).unwrap())
            .unwrap();

    let out = tmp.path().join("trace");
    let (code, stdout, err) = ntg(&[
        "trace",
        "--run",
        s(&run),
        "--task",
        "stack_1001",
        "--out",
        s(&out),
    ]);
    assert_eq!(code, 0, "{err}");
    assert!(stdout.contains("localised node"), "{stdout}");
    for file in [
        "trace.json",
        "trace.txt",
        "ctg.dot",
        "ctg.svg",
        "demo.txt",
        "contact-sheet.png",
        "rollout.gif",
        "frames/step_000.png",
    ] {
        assert!(out.join(file).is_file(), "missing {file}");
    }
    // The animation has a frame per observation.
    let gif = std::fs::File::open(out.join("rollout.gif")).unwrap();
    let decoder = image::codecs::gif::GifDecoder::new(std::io::BufReader::new(gif)).unwrap();
    let animated = image::AnimationDecoder::into_frames(decoder).count();
    let pngs = std::fs::read_dir(out.join("frames")).unwrap().count();
    assert_eq!(animated, pngs, "rollout.gif frames vs frames/*.png");
    // The rollout as a LeRobot dataset: one row a frame, ending in <end>.
    let rows =
        crate::lerobot::read_episode(&out.join("lerobot/data/chunk-000/episode_000000.parquet"));
    assert_eq!(rows.len(), pngs, "lerobot rows vs frames/*.png");
    assert_eq!(rows.last().unwrap().action_name, "<end>");
    let dot = std::fs::read_to_string(out.join("ctg.dot")).unwrap();
    assert!(dot.starts_with("digraph"), "{dot}");
    let svg = std::fs::read_to_string(out.join("ctg.svg")).unwrap();
    assert!(svg.contains("<svg"), "{svg}");

    // The traced rollout is the one `ntg eval` scored for test task 1.
    let trace: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("trace.json")).unwrap()).unwrap();
    let record = &eval["tasks"][1];
    assert_eq!(trace["task"], record["task"]);
    assert_eq!(trace["success"], record["success"]);
    let chosen: Vec<&serde_json::Value> = trace["steps"]
        .as_array()
        .unwrap()
        .iter()
        .map(|st| &st["chosen"]["name"])
        .collect();
    let evaluated: Vec<&serde_json::Value> = record["trace"].as_array().unwrap().iter().collect();
    assert_eq!(chosen, evaluated);
    // One frame per decision plus the final observation.
    let frames = std::fs::read_dir(out.join("frames")).unwrap().count();
    assert_eq!(frames, chosen.len() + 1);

    // An occupied folder is refused and left as it was.
    let before = std::fs::read_to_string(out.join("trace.txt")).unwrap();
    let (code, _, err) = ntg(&["trace", "--run", s(&run), "--task", "0", "--out", s(&out)]);
    assert_ne!(code, 0);
    assert!(err.contains("not empty"), "{err}");
    assert_eq!(
        std::fs::read_to_string(out.join("trace.txt")).unwrap(),
        before
    );

    // Unknown task ids and out-of-range indices name the problem.
    for task in ["stack_1", "5000"] {
        let (code, _, err) = ntg(&[
            "trace",
            "--run",
            s(&run),
            "--task",
            task,
            "--out",
            s(&tmp.path().join("t2")),
        ]);
        assert_ne!(code, 0);
        assert_eq!(err.lines().count(), 1, "{err}");
        assert!(err.contains("test task"), "{err}");
    }
}

#[test]
fn trace_of_a_missing_run_is_a_one_line_error() {
    let tmp = tempfile::tempdir().unwrap();
    let (code, _, err) = ntg(&[
        "trace",
        "--run",
        "/nonexistent/run",
        "--task",
        "0",
        "--out",
        s(&tmp.path().join("t")),
    ]);
    assert_ne!(code, 0);
    assert_eq!(err.lines().count(), 1, "{err}");
    assert!(err.contains("/nonexistent/run"), "{err}");
}

/// `ntg train --obs vid` on 2 tasks x 1 demo into `out`, with `extra` flags.
fn train_tiny_video_run(out: &Path, extra: &[&str]) -> (i32, String, String) {
    let mut args = vec![
        "train",
        "--obs",
        "vid",
        "--train-tasks",
        "2",
        "--demos-per-task",
        "1",
        "--out",
        s(out),
    ];
    args.extend_from_slice(extra);
    ntg(&args)
}

#[test]
fn renaming_cubes_of_video_runs_is_refused_before_anything_is_written() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("run");
    let (code, _, err) = train_tiny_video_run(&out, &["--permute-objects"]);
    assert_ne!(code, 0);
    assert!(err.contains("--permute-objects"), "{err}");
    assert!(!out.exists(), "no run folder is created");
}

#[test]
fn the_interpreter_reads_pooled_frames_when_asked() {
    let tmp = tempfile::tempdir().unwrap();
    let run = tmp.path().join("run");
    let (code, _, err) = train_tiny_video_run(
        &run,
        &[
            "--epochs",
            "1",
            "--encoder-demos",
            "2",
            "--encoder-epochs",
            "1",
            "--validation-tasks",
            "0",
            "--interpreter-frame-pool",
            "3",
        ],
    );
    assert_eq!(code, 0, "{err}");
    let read = |p: &Path| -> serde_json::Value {
        serde_json::from_str(&std::fs::read_to_string(p).unwrap()).unwrap()
    };
    let config = read(&run.join("config.json"));
    assert_eq!(config["video"]["interpreter_frame_pool"], 3, "{config}");
    let model = read(&run.join("checkpoint/config.json"));
    assert_eq!(model["interpreter"]["frame_pool"], 3, "{model}");
    let (code, stdout, err) = ntg(&["eval", "--run", s(&run), "--test-tasks", "1"]);
    assert_eq!(code, 0, "{err}");
    assert!(stdout.contains("success"), "{stdout}");
}
