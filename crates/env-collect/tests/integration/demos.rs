//! Expert demonstrations: conformance, determinism, variety across seeds,
//! parallel = sequential, the written files, and the expert's invariants.

use ctg_graph::{Environment, check_environment, record_demonstration};
use env_collect::export::{DEMO_FORMAT, write_demo};
use env_collect::{
    Action, CollectConfig, CollectEnv, CollectExpert, DemoJob, Split, TaskSplitter, generate_demos,
    generate_demos_sequential, jobs_for_tasks, record_demo, vocabulary,
};
use proptest::prelude::*;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

fn sample_task(n: usize, seed: u64) -> env_collect::Task {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    TaskSplitter::default().sample(n, None, &mut rng).unwrap()
}

#[test]
fn passes_the_conformance_check_for_every_n() {
    // N = 6 too: validation on demos longer than every test episode's.
    for n in env_collect::domain::MIN_OBJECTS..=env_collect::domain::MAX_OBJECTS {
        for render in [true, false] {
            let task = sample_task(n, n as u64);
            let config = CollectConfig {
                render,
                ..CollectConfig::default()
            };
            let report = check_environment(
                || CollectEnv::new(task.clone(), config).unwrap(),
                &mut CollectExpert,
                &[0, 1, 2, 17],
            )
            .unwrap_or_else(|e| panic!("N = {n}, render = {render}: {e}"));
            assert_eq!(report.seeds_checked, 4);
            assert!(report.seeds_vary_initial_observation || !render);
            assert!(report.longest_demonstration >= 3 * n);
            assert!(report.longest_demonstration <= 3 * n + 3);
        }
    }
}

#[test]
fn same_seed_same_demo_different_seeds_different_demos() {
    let config = CollectConfig::default();
    let task = sample_task(3, 11);
    let a = record_demo(&task, 42, &config).unwrap();
    let b = record_demo(&task, 42, &config).unwrap();
    assert_eq!(a, b);

    // Other seeds give other scenes: frames always differ, and the action
    // sequences (where the targets are found, hence the order) vary.
    let demos: Vec<_> = (0..12)
        .map(|s| record_demo(&task, s, &config).unwrap())
        .collect();
    let mut sequences: Vec<_> = demos.iter().map(|d| d.actions().to_vec()).collect();
    sequences.sort();
    sequences.dedup();
    assert!(
        sequences.len() >= 6,
        "only {} distinct sequences",
        sequences.len()
    );
    for (i, x) in demos.iter().enumerate() {
        for y in &demos[i + 1..] {
            assert_ne!(x.observations()[1], y.observations()[1]);
        }
    }

    // The same seed in two tasks gives unrelated scenes.
    let other = sample_task(3, 12);
    assert_ne!(task, other);
    let mut e1 = CollectEnv::new(task, config).unwrap();
    let mut e2 = CollectEnv::new(other, config).unwrap();
    e1.reset(5).unwrap();
    e2.reset(5).unwrap();
    assert_ne!(e1.scene().unwrap().locations, e2.scene().unwrap().locations);
}

#[test]
fn parallel_generation_equals_sequential() {
    let splitter = TaskSplitter::default();
    let mut tasks = splitter
        .sample_distinct(2, 6, Some(Split::Train), 1)
        .unwrap();
    tasks.extend(
        splitter
            .sample_distinct(4, 6, Some(Split::Train), 2)
            .unwrap(),
    );
    let jobs = jobs_for_tasks(&tasks, 3, 99);
    assert_eq!(jobs.len(), 36);
    let config = CollectConfig::default();
    let sequential = generate_demos_sequential(&jobs, &config).unwrap();
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(4)
        .build()
        .unwrap();
    let parallel = pool.install(|| generate_demos(&jobs, &config)).unwrap();
    assert_eq!(parallel, sequential);
    assert_eq!(jobs, jobs_for_tasks(&tasks, 3, 99));
    assert_ne!(jobs, jobs_for_tasks(&tasks, 3, 100));
}

#[test]
fn a_bad_job_is_reported_not_panicked() {
    // A step limit too short for the expert: recording fails cleanly.
    let config = CollectConfig {
        max_steps: Some(2),
        ..CollectConfig::default()
    };
    let jobs = vec![DemoJob {
        task: sample_task(2, 0),
        seed: 0,
    }];
    let err = generate_demos(&jobs, &config).unwrap_err();
    assert!(err.to_string().contains("step limit"), "{err}");
}

#[test]
fn write_demo_writes_json_frames_and_a_contact_sheet() {
    let dir = tempfile::tempdir().unwrap();
    let task = sample_task(2, 3);
    let written = write_demo(dir.path(), &task, 8, &CollectConfig::default()).unwrap();
    assert_eq!(written.frames.len(), written.demo.len() + 1);
    for frame in &written.frames {
        let img = image::open(frame).unwrap().to_rgb8();
        assert_eq!(img.dimensions(), (64, 64));
    }
    let first = image::open(&written.frames[1]).unwrap().to_rgb8();
    assert_eq!(Some(&first), written.demo.observations()[1].frame.as_ref());
    let sheet = image::open(written.contact_sheet.as_ref().unwrap()).unwrap();
    assert!(sheet.width() > 128 && sheet.height() > 128);

    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&written.json).unwrap()).unwrap();
    assert_eq!(json["format"], DEMO_FORMAT);
    assert_eq!(json["seed"], 8);
    assert_eq!(json["num_objects"], 2);
    let actions = json["actions"].as_array().unwrap();
    assert_eq!(actions.len(), written.demo.len());
    let names: Vec<String> = written
        .demo
        .actions()
        .iter()
        .map(|&a| vocabulary().name(a).unwrap().to_owned())
        .collect();
    assert_eq!(actions, &names);
    assert_eq!(
        json["steps"].as_array().unwrap().len(),
        written.demo.len() + 1
    );
    assert_eq!(json["steps"][0]["node"], "<start>");
    assert_eq!(json["steps"][written.demo.len()]["next_action"], "<end>");
    let task_back: env_collect::Task = serde_json::from_value(json["task"].clone()).unwrap();
    assert_eq!(task_back, task);
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(64))]

    /// The expert always succeeds within 3N + 3 actions: N pickups, each
    /// followed by the drop-off at the target's receptacle, and at most M
    /// searches; the recorded states line up with the replay.
    #[test]
    fn the_expert_always_succeeds(n in 1usize..=5, task_seed in any::<u64>(), seed in any::<u64>()) {
        let task = sample_task(n, task_seed);
        let config = CollectConfig { render: false, ..CollectConfig::default() };
        let mut env = CollectEnv::new(task.clone(), config).unwrap();
        let demo = record_demonstration(&mut env, &mut CollectExpert, seed).unwrap();
        prop_assert!(env.is_success());
        prop_assert!(demo.len() >= 3 * n && demo.len() <= 3 * n + 3, "{}", demo.len());
        let actions: Vec<Action> = demo.actions().iter().map(|&a| Action::from_id(a).unwrap()).collect();
        let searches = actions.iter().filter(|&&a| a == Action::Search).count();
        prop_assert!(searches <= task.num_locations());
        let mut picked = Vec::new();
        for pair in actions.windows(2) {
            if let Action::Pickup(c) = pair[0] {
                prop_assert_eq!(pair[1], Action::Dropoff(task.receptacle_of(c).unwrap()));
                picked.push(c);
            }
        }
        picked.sort();
        let targets: Vec<_> = task.targets().iter().map(|t| t.category).collect();
        prop_assert_eq!(picked, targets);
        // Every demonstration starts by searching.
        prop_assert_eq!(actions[0], Action::Search);
        // The environment is reproducible from the seed.
        let (first, _) = env.reset(seed).unwrap();
        prop_assert_eq!(&first, &demo.observations()[0]);
    }
}
