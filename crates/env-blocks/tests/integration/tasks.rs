//! Task files, statistics, the generator and the standard split.

use std::path::{Path, PathBuf};

use env_blocks::task::{
    NTP_GOALS_PER_TASK, NTP_TALLEST_TOWER, NTP_TOWERS_PER_TASK, STANDARD_SEED, TRAIN_SIZES,
};
use env_blocks::{
    BlocksError, Goal, StackTask, TaskStats, generate_stack_tasks, parse_ntp_tasks, read_ntp_tasks,
    standard_split, standard_tasks, write_ntp_tasks,
};

fn fixture() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/ntp_small.json")
}

#[test]
fn reads_the_ntp_fixture() {
    let tasks = read_ntp_tasks(&fixture()).unwrap();
    assert_eq!(tasks.len(), 3);
    assert_eq!(tasks[0].id, "stack_0");
    assert_eq!(tasks[0].goals[0], Goal { src: 2, target: 6 });
    assert_eq!(tasks[0].towers(), vec![vec![6, 2], vec![1, 7, 3]]);
    assert_eq!(tasks[0].describe(), "C>G H>B D>H");
    let stats = TaskStats::of(&tasks);
    assert_eq!(
        stats.goals_per_task.into_iter().collect::<Vec<_>>(),
        [(1, 1), (3, 1), (4, 1)]
    );
    assert_eq!(
        stats.towers_per_task.into_iter().collect::<Vec<_>>(),
        [(1, 1), (2, 2)]
    );
    assert_eq!(
        stats.tallest_tower.into_iter().collect::<Vec<_>>(),
        [(2, 1), (3, 1), (4, 1)]
    );
    assert_eq!(stats.bottom_up_tower_order, 3);
    assert_eq!(stats.distinct, 3);
}

#[test]
fn write_then_read_round_trips() {
    let tasks = read_ntp_tasks(&fixture()).unwrap();
    let text = write_ntp_tasks(&tasks);
    assert_eq!(parse_ntp_tasks(&text, "mem").unwrap(), tasks);
}

fn task_error(text: &str) -> String {
    parse_ntp_tasks(text, "f.json").unwrap_err().to_string()
}

#[test]
fn malformed_files_are_typed_errors_naming_the_place() {
    let e = parse_ntp_tasks("{\"tasks\": [\n{\"id\": 3}]}", "bad.json").unwrap_err();
    assert!(matches!(e, BlocksError::Json { line: 2, .. }), "{e}");
    assert!(e.to_string().starts_with("bad.json:2:"), "{e}");

    let goal = |n: &str, s: &str, t: &str| {
        format!("{{\"name\":\"{n}\",\"src\":\"{s}\",\"target\":\"{t}\"}}")
    };
    let file = |goals: &[String]| {
        format!(
            "{{\"tasks\":[{{\"id\":\"t\",\"goals\":[{}]}}]}}",
            goals.join(",")
        )
    };
    let e = task_error(&file(&[goal("pick_place", "cube_9", "cube_1")]));
    assert!(
        e.contains("f.json: task 0 (`t`)") && e.contains("cube_9"),
        "{e}"
    );
    let e = task_error(&file(&[goal("push", "cube_0", "cube_1")]));
    assert!(e.contains("unknown goal `push`"), "{e}");
    let e = task_error(&file(&[goal("pick_place", "cube_0", "cube_0")]));
    assert!(e.contains("on itself"), "{e}");
    let e = task_error(&file(&[
        goal("pick_place", "cube_0", "cube_1"),
        goal("pick_place", "cube_1", "cube_0"),
    ]));
    assert!(e.contains("cycle"), "{e}");
    let e = task_error(&file(&[]));
    assert!(e.contains("at least one goal"), "{e}");
    let e = task_error(
        "{\"tasks\":[{\"id\":\"t\",\"goals\":[{\"name\":\"pick_place\",\"src\":\"cube_0\",\"target\":\"cube_1\"}],\
         \"end_constraints\":[{\"type\":\"on_top\",\"src\":\"cube_2\",\"target\":\"cube_1\"}]}]}",
    );
    assert!(e.contains("end constraints differ"), "{e}");
    let e = read_ntp_tasks(Path::new("/nonexistent/tasks.json")).unwrap_err();
    assert!(e.to_string().starts_with("/nonexistent/tasks.json:"), "{e}");
}

#[test]
fn stack_task_validation() {
    assert!(
        StackTask::new(
            "x",
            vec![Goal { src: 0, target: 1 }, Goal { src: 2, target: 1 }]
        )
        .is_err()
    );
    assert!(
        StackTask::new(
            "x",
            vec![Goal { src: 0, target: 1 }, Goal { src: 0, target: 2 }]
        )
        .is_err()
    );
    assert!(StackTask::new("x", vec![Goal { src: 0, target: 8 }]).is_err());
    let t = StackTask::new(
        "x",
        vec![Goal { src: 2, target: 1 }, Goal { src: 1, target: 0 }],
    )
    .unwrap();
    assert_eq!(t.towers(), vec![vec![0, 1, 2]]);
    // Bottom-up regrouping reorders a top-down task.
    assert_eq!(
        t.goals_by_tower().concat(),
        vec![Goal { src: 1, target: 0 }, Goal { src: 2, target: 1 }]
    );
}

fn percent(count: usize, total: usize) -> f64 {
    100.0 * count as f64 / total as f64
}

fn assert_within_5pp(
    name: &str,
    got: &std::collections::BTreeMap<usize, usize>,
    want: &[usize],
    first: usize,
) {
    let total_want: usize = want.iter().sum();
    let total_got: usize = got.values().sum();
    for (k, &w) in want.iter().enumerate() {
        let g = got.get(&(k + first)).copied().unwrap_or(0);
        let (pg, pw) = (percent(g, total_got), percent(w, total_want));
        assert!(
            (pg - pw).abs() <= 5.0,
            "{name} {}: {pg:.1}% vs NTP {pw:.1}%",
            k + first
        );
    }
    for k in got.keys() {
        assert!(
            (first..first + want.len()).contains(k),
            "{name}: bin {k} absent from NTP's file"
        );
    }
}

#[test]
fn generator_matches_ntp_histograms_within_5_points() {
    let tasks = standard_tasks().unwrap();
    let stats = TaskStats::of(&tasks);
    assert_eq!(stats.tasks, 2000);
    assert_eq!(stats.distinct, 2000);
    assert_eq!(stats.bottom_up_tower_order, 2000);
    assert_within_5pp("goals", &stats.goals_per_task, &NTP_GOALS_PER_TASK, 1);
    assert_within_5pp("towers", &stats.towers_per_task, &NTP_TOWERS_PER_TASK, 1);
    assert_within_5pp("tallest", &stats.tallest_tower, &NTP_TALLEST_TOWER, 2);
    // Another seed also matches: the fit is not an accident of one draw.
    let other = TaskStats::of(&generate_stack_tasks(7, 2000).unwrap());
    assert_within_5pp(
        "tallest (seed 7)",
        &other.tallest_tower,
        &NTP_TALLEST_TOWER,
        2,
    );
}

#[test]
fn generator_is_deterministic_and_seeded() {
    let a = generate_stack_tasks(3, 50).unwrap();
    assert_eq!(a, generate_stack_tasks(3, 50).unwrap());
    assert_ne!(a, generate_stack_tasks(4, 50).unwrap());
    assert_eq!(a[7].id, "stack_7");
}

#[test]
fn standard_split_is_nested_and_disjoint() {
    let split = standard_split().unwrap();
    assert_eq!((split.train_pool.len(), split.test.len()), (1000, 1000));
    for n in TRAIN_SIZES {
        assert_eq!(split.train(n).unwrap(), &split.train_pool[..n]);
    }
    assert!(split.train(1001).is_err());
    let train: std::collections::HashSet<_> = split
        .train_pool
        .iter()
        .map(StackTask::configuration_key)
        .collect();
    assert!(
        split
            .test
            .iter()
            .all(|t| !train.contains(&t.configuration_key()))
    );
    assert_eq!(split.test[0].id, "stack_1000");
}

#[test]
fn committed_task_set_equals_the_regenerated_one() {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../datasets/blocks/stack_2000.json");
    let committed = read_ntp_tasks(&path).unwrap();
    assert_eq!(
        committed,
        standard_tasks().unwrap(),
        "regenerate with `ntg blocks tasks --write`"
    );
    let text = std::fs::read_to_string(&path).unwrap();
    assert_eq!(
        text,
        write_ntp_tasks(&committed),
        "the committed file is not in canonical form"
    );
    assert_eq!(STANDARD_SEED, 20_190_616);
}

#[test]
fn reproduces_the_ntp_readme_statistics_when_the_file_is_present() {
    let path = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../../shared/data/ntp-block-stacking/stack_2000.json");
    if !path.exists() {
        eprintln!(
            "skipping: {} is absent (reference data, not in the repository)",
            path.display()
        );
        return;
    }
    let stats = TaskStats::of(&read_ntp_tasks(&path).unwrap());
    let hist =
        |m: &std::collections::BTreeMap<usize, usize>| m.values().copied().collect::<Vec<_>>();
    assert_eq!(stats.tasks, 2000);
    assert_eq!(hist(&stats.goals_per_task), NTP_GOALS_PER_TASK);
    assert_eq!(hist(&stats.towers_per_task), NTP_TOWERS_PER_TASK);
    assert_eq!(hist(&stats.tallest_tower), NTP_TALLEST_TOWER);
    assert_eq!(stats.bottom_up_tower_order, 2000);
    assert_eq!(stats.distinct, 2000);
}
