//! `ntg train --method ntp|ntp-flat|ntp-detector` (states and videos) →
//! `ntg eval` → `ntg trace` end to end on tiny runs: each trains, is scored, and its trace is the
//! rollout `ntg eval` scored, with NTP's running programs at every step.

use std::path::Path;

use crate::common;
use common::ntg;

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

fn json(path: &Path) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap()
}

/// Trains `method` on `obs` with `extra` flags, evaluates 2 test tasks and
/// traces test task 1; checks the trace against the evaluation.
fn train_eval_trace(method: &str, obs: &str, extra: &[&str]) {
    let tmp = tempfile::tempdir().unwrap();
    let run = tmp.path().join("run");
    let mut args = vec![
        "train",
        "--method",
        method,
        "--obs",
        obs,
        "--train-tasks",
        "2",
        "--demos-per-task",
        "2",
        "--epochs",
        "1",
        "--validation-tasks",
        "2",
        "--out",
        s(&run),
    ];
    args.extend_from_slice(extra);
    let (code, _, err) = ntg(&args);
    assert_eq!(code, 0, "{method}: {err}");
    // Resumed when finished, a run reads its stages back (their frames
    // are not recorded again).
    args.push("--resume");
    let (code, _, resumed) = ntg(&args);
    assert_eq!(code, 0, "{method}: {resumed}");
    let stage_done = match (method, obs) {
        ("ntp-detector", _) => Some("detector: done"),
        (_, "vid") => Some("stage A: done"),
        _ => None,
    };
    if let Some(line) = stage_done {
        assert!(resumed.contains(line), "{method}: {resumed}");
    }
    // The recommended recipe renames the cubes of state rows (NTP
    // (Detector)'s NTP reads them too); on frames, stage A's videos.
    let config = json(&run.join("config.json"));
    let on_videos = obs == "vid" && method != "ntp-detector";
    assert_eq!(config["permute_objects"], !on_videos, "{method}: {config}");
    assert_eq!(
        config.get("video").is_some(),
        on_videos,
        "{method}: {config}"
    );
    assert_eq!(
        config.get("detector").is_some(),
        method == "ntp-detector",
        "{config}"
    );
    // Block stacking's stage A reads keypoints unless told not to.
    let keypoints = config["video"]["encoder"]["spatial_softmax"] == true;
    let keypoints_off = extra
        .windows(2)
        .any(|w| w == ["--encoder-keypoints", "false"]);
    assert_eq!(keypoints, on_videos && !keypoints_off, "{config}");
    let on_estimates = config["detector"]["ntp_on_estimates"] == true;
    assert_eq!(
        run.join("ntp_frames/episodes.json").is_file(),
        on_videos || on_estimates,
        "{method}: NTP's episodes are cached where they are frames' encodings or estimates"
    );
    assert_eq!(
        on_estimates,
        method == "ntp-detector" && !extra.contains(&"--ntp-on-true-states"),
        "{config}"
    );
    let (code, stdout, err) = ntg(&["eval", "--run", s(&run), "--test-tasks", "2"]);
    assert_eq!(code, 0, "{method}: {err}");
    assert!(stdout.contains("success"), "{stdout}");
    let eval = json(&run.join(format!("eval/{method}-2.json")));
    // Seen tasks, with demos and scenes it never trained on.
    let seen = |tasks: &str, extra: &[&str]| {
        let mut args = vec![
            "eval",
            "--run",
            s(&run),
            "--split",
            "seen",
            "--test-tasks",
            tasks,
        ];
        args.extend_from_slice(extra);
        ntg(&args)
    };
    let (code, _, err) = seen("2", &[]);
    assert_eq!(code, 0, "{method}: {err}");
    let seen_eval = json(&run.join(format!("eval/seen-{method}-2.json")));
    let split = env_blocks::standard_split().unwrap();
    let first = &split.train(1).unwrap()[0];
    assert_eq!(
        seen_eval["tasks"][0]["task"],
        first.id.as_str(),
        "{seen_eval}"
    );
    let (code, _, err) = seen("3", &[]);
    assert_ne!(code, 0);
    assert!(err.contains("trained on 2 tasks"), "{err}");
    // Tasks of structures the training pool lacks (a tall tower).
    let (code, _, err) = ntg(&[
        "eval",
        "--run",
        s(&run),
        "--split",
        "structure",
        "--test-tasks",
        "2",
    ]);
    assert_eq!(code, 0, "{method}: {err}");
    let structure = json(&run.join(format!("eval/structure-{method}-2.json")));
    assert_eq!(structure["tasks"][1]["task"], "struct_1", "{structure}");
    // Its decisions checked one by one along the expert's traces of two
    // seen tasks: every decision of both traces is tallied under the step
    // of the hierarchy it is.
    let (code, stdout, err) = seen("2", &["--decisions"]);
    assert_eq!(code, 0, "{method}: {err}");
    assert!(stdout.contains("decisions right"), "{stdout}");
    let report = json(&run.join("eval/seen-decisions-2.json"));
    assert_eq!(report["episodes"], 2, "{report}");
    let steps = report["steps"].as_array().unwrap();
    let total: u64 = steps.iter().map(|t| t["decisions"].as_u64().unwrap()).sum();
    assert_eq!(report["decisions"].as_u64(), Some(total), "{report}");
    let has = |program: &str, step: &str| {
        steps
            .iter()
            .any(|t| t["program"] == program && t["step"] == step)
    };
    if method == "ntp-flat" {
        assert!(
            has("stack", "drop") && !has("stack", "pick_place"),
            "{report}"
        );
    } else {
        assert!(
            has("stack", "pick_place") && has("place", "drop"),
            "{report}"
        );
        assert!(has("pick", "return") && has("stack", "return"), "{report}");
    }

    let out = tmp.path().join("trace");
    let (code, stdout, err) = ntg(&["trace", "--run", s(&run), "--task", "1", "--out", s(&out)]);
    assert_eq!(code, 0, "{method}: {err}");
    assert!(stdout.contains("running programs"), "{stdout}");
    for file in [
        "trace.json",
        "trace.txt",
        "demo.txt",
        "contact-sheet.png",
        "rollout.gif",
        "frames/step_000.png",
    ] {
        assert!(out.join(file).is_file(), "{method}: missing {file}");
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
    let trace = json(&out.join("trace.json"));
    let record = &eval["tasks"][1];
    assert_eq!(trace["task"], record["task"]);
    assert_eq!(trace["success"], record["success"]);
    let steps = trace["steps"].as_array().unwrap();
    let chosen: Vec<&serde_json::Value> = steps.iter().map(|st| &st["chosen"]).collect();
    let evaluated: Vec<&serde_json::Value> = record["trace"].as_array().unwrap().iter().collect();
    assert_eq!(
        chosen, evaluated,
        "{method}: the trace is the evaluated rollout"
    );
    // Every step says which programs ran, root first, with their scopes.
    for st in steps {
        let programs = st["programs"].as_str().unwrap_or_default();
        assert!(programs.starts_with("stack[0-"), "{method}: {programs:?}");
    }
    // One frame per decision plus the final observation.
    let frames = std::fs::read_dir(out.join("frames")).unwrap().count();
    assert_eq!(frames, steps.len() + 1);
    // NTG's graph options are refused for a baseline.
    let (code, _, err) = ntg(&["eval", "--run", s(&run), "--edge-threshold", "0.5"]);
    assert_ne!(code, 0);
    assert!(err.contains("--edge-threshold"), "{err}");
}

#[test]
fn ntp_trains_evaluates_and_traces_from_the_command_line() {
    train_eval_trace("ntp", "state", &[]);
}

#[test]
fn ntp_flat_trains_evaluates_and_traces_from_the_command_line() {
    train_eval_trace("ntp-flat", "state", &[]);
}

#[test]
fn ntp_on_demo_videos_trains_in_the_stages_of_ntg() {
    train_eval_trace(
        "ntp",
        "vid",
        &["--encoder-demos", "4", "--encoder-epochs", "1"],
    );
}

#[test]
fn ntp_on_demo_videos_trains_without_keypoints_when_asked() {
    train_eval_trace(
        "ntp",
        "vid",
        &[
            "--encoder-demos",
            "4",
            "--encoder-epochs",
            "1",
            "--encoder-keypoints",
            "false",
        ],
    );
}

#[test]
fn ntp_detector_trains_its_detector_then_ntp_on_video() {
    train_eval_trace(
        "ntp-detector",
        "vid",
        &["--detector-episodes", "4", "--detector-epochs", "1"],
    );
}

/// NTP (Detector) whose NTP trains on true states (by default on the
/// detector's estimates of its episodes' frames): recorded in the run's
/// configuration, and the run trains, evaluates and traces as the other.
#[test]
fn ntp_detector_trains_ntp_on_true_states_when_asked() {
    train_eval_trace(
        "ntp-detector",
        "vid",
        &[
            "--detector-episodes",
            "4",
            "--detector-epochs",
            "1",
            "--ntp-on-true-states",
        ],
    );
}
