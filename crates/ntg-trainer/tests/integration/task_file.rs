//! `ntg train --domain blocks --tasks FILE`: training and evaluation on an
//! NTP task file instead of the generated stand-in set, split by the
//! standard rule (first 1000 tasks the training pool, the rest the test
//! tasks), with validation tasks drawn outside the file's configurations.

use crate::common;

use std::path::Path;

use common::ntg;
use env_blocks::StackTask;

/// An NTP task file of `count` tasks named `mine_<i>` (not the stand-in
/// set's tasks, nor its names).
fn write_task_file(path: &Path, count: usize) -> Vec<StackTask> {
    let tasks: Vec<StackTask> = env_blocks::generate_stack_tasks(777, count)
        .unwrap()
        .into_iter()
        .enumerate()
        .map(|(i, t)| StackTask::new(format!("mine_{i}"), t.goals).unwrap())
        .collect();
    std::fs::write(path, env_blocks::write_ntp_tasks(&tasks)).unwrap();
    tasks
}

#[test]
fn a_run_trains_and_is_evaluated_on_the_task_file_it_names() {
    let tmp = tempfile::tempdir().unwrap();
    let file = tmp.path().join("tasks.json");
    let tasks = write_task_file(&file, 1010);
    let run = tmp.path().join("run");
    let (code, _, err) = ntg(&[
        "train",
        "--domain",
        "blocks",
        "--tasks",
        file.to_str().unwrap(),
        "--train-tasks",
        "2",
        "--demos-per-task",
        "1",
        "--epochs",
        "1",
        "--validation-tasks",
        "2",
        "--out",
        run.to_str().unwrap(),
    ]);
    assert_eq!(code, 0, "{err}");
    let (code, _, err) = ntg(&["eval", "--run", run.to_str().unwrap(), "--test-tasks", "2"]);
    assert_eq!(code, 0, "{err}");
    let eval: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(run.join("eval/full-2.json")).unwrap())
            .unwrap();
    let names: Vec<&str> = eval["tasks"]
        .as_array()
        .unwrap()
        .iter()
        .map(|t| t["task"].as_str().unwrap())
        .collect();
    assert_eq!(names, ["mine_1000", "mine_1001"]);
    assert_eq!(tasks[1000].id, "mine_1000");
    // Taller towers are the structure benchmark's split, not a task file's.
    let (code, _, err) = ntg(&["eval", "--run", run.to_str().unwrap(), "--split", "taller"]);
    assert_ne!(code, 0);
    assert!(err.contains("--task-set structure"), "{err}");
    // A file the split cannot use is an error that names it, and no run
    // folder is made.
    let short = tmp.path().join("short.json");
    write_task_file(&short, 900);
    let refused = tmp.path().join("refused");
    let (code, _, err) = ntg(&[
        "train",
        "--domain",
        "blocks",
        "--tasks",
        short.to_str().unwrap(),
        "--train-tasks",
        "2",
        "--out",
        refused.to_str().unwrap(),
    ]);
    assert_ne!(code, 0);
    assert!(
        err.contains("short.json") && err.contains("900 tasks"),
        "{err}"
    );
    assert!(!refused.exists());
}

#[test]
fn validation_tasks_avoid_every_configuration_of_the_task_file() {
    let tmp = tempfile::tempdir().unwrap();
    let file = tmp.path().join("tasks.json");
    let tasks = write_task_file(&file, 1100);
    let split =
        ntg_trainer::blocks::task_split(ntg_trainer::blocks::TaskSource::File(&file)).unwrap();
    assert_eq!((split.train_pool.len(), split.test.len()), (1000, 100));
    assert_eq!(split.test[0], tasks[1000]);
    let validation =
        ntg_trainer::blocks::validation_tasks_of(ntg_trainer::blocks::TaskSource::File(&file), 300)
            .unwrap();
    let seen: std::collections::HashSet<_> =
        tasks.iter().map(StackTask::configuration_key).collect();
    assert!(
        validation
            .iter()
            .all(|t| !seen.contains(&t.configuration_key()))
    );
}

/// NTP's own task file, where `../shared/data` has it (never committed).
#[test]
fn ntps_own_task_file_splits_into_the_standard_sizes() {
    let file = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../../shared/data/ntp-block-stacking/stack_2000.json");
    if !file.is_file() {
        eprintln!("skipped: {} is not here", file.display());
        return;
    }
    let split =
        ntg_trainer::blocks::task_split(ntg_trainer::blocks::TaskSource::File(&file)).unwrap();
    assert_eq!((split.train_pool.len(), split.test.len()), (1000, 1000));
    assert_eq!(
        ntg_trainer::blocks::validation_tasks_of(ntg_trainer::blocks::TaskSource::File(&file), 100)
            .unwrap()
            .len(),
        100
    );
}

/// `ntg eval --tasks FILE`: a trained run evaluated on a user's task file,
/// its training tasks among them named as such.
#[test]
fn eval_reads_a_users_task_file_and_names_the_training_tasks_in_it() {
    let tmp = tempfile::tempdir().unwrap();
    let run = common::train_tiny_run(tmp.path());
    let split = env_blocks::standard_split().unwrap();
    // Two of the run's training tasks, renamed, then two test tasks.
    let mut mine: Vec<StackTask> = split.train_pool[..2]
        .iter()
        .chain(&split.test[..2])
        .enumerate()
        .map(|(i, t)| StackTask::new(format!("mine_{i}"), t.goals.clone()).unwrap())
        .collect();
    mine.truncate(4);
    let file = tmp.path().join("mine.json");
    std::fs::write(&file, env_blocks::write_ntp_tasks(&mine)).unwrap();
    let run_s = run.to_str().unwrap();
    let (code, out, err) = ntg(&["eval", "--run", run_s, "--tasks", file.to_str().unwrap()]);
    assert_eq!(code, 0, "{err}");
    assert!(
        out.contains("2 of its 4 tasks end as a training task of this run does, so they are not unseen: mine_0, mine_1"),
        "{out}"
    );
    assert!(out.contains("evaluating them all"), "{out}");
    let result: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(run.join("eval/tasks-mine-full-4.json")).unwrap(),
    )
    .unwrap();
    assert_eq!(result["success"]["trials"], 4, "{result}");
}

/// `--task-set structure`: a run trains on the structure benchmark's
/// training structures, validates on its validation structures, and is
/// scored on its test structures (`--split test`) and on taller towers
/// (`--split taller`); the standard set's runs refuse `--split taller`,
/// and a structure run refuses the earlier protocol's `--split structure`.
#[test]
fn a_structure_benchmark_run_is_scored_on_new_and_taller_structures() {
    use env_blocks::structure::{STRUCTURE_BENCHMARK_SEED, StructureBenchmark, StructureSet};
    let tmp = tempfile::tempdir().unwrap();
    let run = tmp.path().join("run");
    let (code, _, err) = ntg(&[
        "train",
        "--domain",
        "blocks",
        "--task-set",
        "structure",
        "--train-tasks",
        "3",
        "--demos-per-task",
        "1",
        "--epochs",
        "1",
        "--validation-tasks",
        "2",
        "--out",
        run.to_str().unwrap(),
    ]);
    assert_eq!(code, 0, "{err}");
    let config: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(run.join("config.json")).unwrap()).unwrap();
    assert_eq!(config["structure_benchmark"], true);
    // The tasks of each split are the benchmark's, by id and structure.
    let benchmark = StructureBenchmark::new(STRUCTURE_BENCHMARK_SEED);
    for (split, file, set) in [
        ("test", "full-3.json", StructureSet::Test),
        ("taller", "taller-full-3.json", StructureSet::Taller),
        (
            "validation",
            "validation-full-3.json",
            StructureSet::Validation,
        ),
    ] {
        let (code, _, err) = ntg(&[
            "eval",
            "--run",
            run.to_str().unwrap(),
            "--test-tasks",
            "3",
            "--split",
            split,
        ]);
        assert_eq!(code, 0, "--split {split}: {err}");
        let eval: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(run.join("eval").join(file)).unwrap())
                .unwrap();
        let names: Vec<String> = eval["tasks"]
            .as_array()
            .unwrap()
            .iter()
            .map(|t| t["task"].as_str().unwrap().to_owned())
            .collect();
        let expected: Vec<String> = (0..3).map(|i| format!("{}_{i}", set.name())).collect();
        assert_eq!(names, expected, "--split {split}");
        let drawn = ntg_trainer::blocks::task_set_tasks(set, 3).unwrap();
        for (task, name) in drawn.iter().zip(&names) {
            assert_eq!(&task.id, name);
            assert_eq!(benchmark.set_of(task), Some(set));
        }
    }
    // The earlier protocol's split of the standard set is refused here.
    let (code, _, err) = ntg(&[
        "eval",
        "--run",
        run.to_str().unwrap(),
        "--split",
        "structure",
    ]);
    assert_ne!(code, 0);
    assert!(err.contains("--split taller"), "{err}");
    // A task file and the benchmark are refused together.
    let (code, _, err) = ntg(&[
        "train",
        "--domain",
        "blocks",
        "--task-set",
        "structure",
        "--tasks",
        "x.json",
        "--out",
        tmp.path().join("both").to_str().unwrap(),
    ]);
    assert_ne!(code, 0);
    assert!(
        err.contains("--task-set") || err.contains("--tasks"),
        "{err}"
    );
    assert!(!tmp.path().join("both").exists());
}
