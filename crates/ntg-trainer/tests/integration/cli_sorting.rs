//! `ntg train --domain sorting` → `ntg eval` end to end on a tiny run: an
//! ablated NTG trains on sorting demos, keeps its ablation in its saved
//! configuration, and is scored on part-sorted test scenes.

use crate::common;
use common::ntg;

#[test]
fn a_sorting_run_trains_and_is_scored_on_part_sorted_scenes() {
    let tmp = tempfile::tempdir().unwrap();
    let run = tmp.path().join("run");
    let run_arg = run.to_str().unwrap();
    let (code, _, err) = ntg(&[
        "train",
        "--domain",
        "sorting",
        "--ablation",
        "no-gcn",
        "--train-tasks",
        "2",
        "--demos-per-task",
        "2",
        "--epochs",
        "1",
        "--validation-episodes",
        "2",
        "--out",
        run_arg,
    ]);
    assert_eq!(code, 0, "{err}");
    let config: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(run.join("config.json")).unwrap()).unwrap();
    assert_eq!(config["domain"], "sorting");
    assert_eq!(config["ablation"], "no-gcn");
    let (code, out, err) = ntg(&["eval", "--run", run_arg, "--test-tasks", "3"]);
    assert_eq!(code, 0, "{err}");
    assert!(
        out.contains("scenes with 2-4 objects presorted") && out.contains("/3 = "),
        "{out}"
    );
    let records: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(run.join("eval").join("full-3.json")).unwrap(),
    )
    .unwrap();
    let episodes = records["episodes"].as_array().unwrap();
    assert_eq!(episodes.len(), 3);
    assert!(
        episodes[0]["task"]
            .as_str()
            .unwrap()
            .ends_with("(2 presorted)")
    );
}
