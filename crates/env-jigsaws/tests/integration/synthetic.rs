//! The synthetic stand-in: written → read gives the same content, the same
//! seed gives the same data, the inventory and gesture sets match DATA.md,
//! and the kinematics are physically consistent with the gestures.

use std::collections::BTreeMap;

use env_jigsaws::{
    Arm, Dataset, FRAME_RATE, Gesture, LoadWarning, SynthConfig, Task, Trial, TrialId, generate,
    synth, write_synthetic,
};

fn small(seed: u64) -> SynthConfig {
    SynthConfig {
        seed,
        tasks: Task::ALL.to_vec(),
        max_trials_per_task: Some(2),
        duration_scale: 0.4,
    }
}

#[test]
fn written_then_read_is_the_same_content() {
    let dir = tempfile::tempdir().unwrap();
    let synth = write_synthetic(&small(11), dir.path()).unwrap();
    assert_eq!(synth.dataset.num_trials(), 6);
    let loaded = Dataset::load(dir.path()).unwrap();
    assert!(
        loaded.report.warnings.is_empty(),
        "{:?}",
        loaded.report.warnings
    );
    assert_eq!(loaded.dataset, synth.dataset);
    // Writing again into the same folder is refused.
    let again = write_synthetic(&small(11), dir.path()).unwrap_err();
    assert!(again.to_string().contains("already exists"), "{again}");
}

#[test]
fn full_inventory_written_and_read_with_the_kinematics_only_trial() {
    // Whole inventory, but short trials to keep the test fast.
    let config = SynthConfig {
        duration_scale: 0.1,
        ..SynthConfig::new(3)
    };
    let dir = tempfile::tempdir().unwrap();
    let synth = write_synthetic(&config, dir.path()).unwrap();
    let loaded = Dataset::load(dir.path()).unwrap();
    assert_eq!(loaded.dataset, synth.dataset);
    let h002 = TrialId::new(Task::Suturing, 'H', 2);
    assert_eq!(
        loaded.report.warnings,
        [LoadWarning::IncompleteTrial {
            trial: h002,
            path: dir
                .path()
                .join("Suturing/kinematics/AllGestures/Suturing_H002.txt"),
            missing: vec!["transcription", "meta row"],
        }]
    );
    let stats = loaded.dataset.stats();
    let counts: Vec<(Task, usize)> = stats.tasks.iter().map(|t| (t.task, t.trials)).collect();
    assert_eq!(
        counts,
        [
            (Task::Suturing, 39),
            (Task::NeedlePassing, 28),
            (Task::KnotTying, 36)
        ]
    );
}

#[test]
fn full_set_has_the_data_md_gesture_sets_and_skill_effects() {
    let synth = generate(&SynthConfig::new(2019)).unwrap();
    let stats = synth.dataset.stats();
    for task in Task::ALL {
        let t = stats.task(task).unwrap();
        assert_eq!(t.gesture_set(), task.gestures(), "{task}");
        assert_eq!(t.trials, task.inventory().len());
        assert!(t.labelled_frames < t.frames, "{task} has unlabelled frames");
        let per_trial = t.frames as f64 / t.trials as f64 / FRAME_RATE;
        assert!(
            (15.0..200.0).contains(&per_trial),
            "{task}: {per_trial} s per trial"
        );
    }
    // Needle Passing retries go back to G8 ("orienting needle").
    let np = stats.task(Task::NeedlePassing).unwrap();
    let count = |from: &str, to: &str| {
        np.transitions
            .iter()
            .find(|t| t.from == from && t.to == to)
            .map_or(0, |t| t.count)
    };
    assert!(count("G2", "G8") + count("G3", "G8") > 0);

    // Novices are slower and retry more than experts (Suturing).
    let mean = |skill: env_jigsaws::Skill, f: &dyn Fn(&Trial) -> f64| {
        let v: Vec<f64> = synth
            .dataset
            .trials(Task::Suturing)
            .iter()
            .filter(|t| t.meta.skill == skill)
            .map(f)
            .collect();
        v.iter().sum::<f64>() / v.len() as f64
    };
    let retries = |t: &Trial| {
        t.segments
            .windows(2)
            .filter(|w| {
                matches!(
                    (w[0].gesture.number(), w[1].gesture.number()),
                    (2, 8) | (2, 2) | (3, 2) | (3, 8)
                )
            })
            .count() as f64
    };
    let seconds_per_segment =
        |t: &Trial| t.labelled_frames() as f64 / t.segments.len() as f64 / 30.0;
    use env_jigsaws::Skill::{Expert, Novice};
    assert!(mean(Novice, &retries) > mean(Expert, &retries));
    assert!(mean(Novice, &seconds_per_segment) > mean(Expert, &seconds_per_segment) * 1.3);
    // The GRS total is the sum of the sub-scores.
    for t in synth.dataset.all_trials() {
        assert_eq!(
            u32::from(t.meta.grs_total),
            t.meta.grs.iter().map(|&g| u32::from(g)).sum::<u32>()
        );
    }
}

#[test]
fn same_seed_same_data_other_seed_other_data() {
    let a = generate(&small(5)).unwrap();
    let b = generate(&small(5)).unwrap();
    let c = generate(&small(6)).unwrap();
    assert_eq!(a, b);
    assert_ne!(a.dataset, c.dataset);
    // A subset equals the same trials of a larger set.
    let larger = generate(&SynthConfig {
        max_trials_per_task: Some(3),
        ..small(5)
    })
    .unwrap();
    for t in a.dataset.all_trials() {
        assert_eq!(Some(t), larger.dataset.trial(t.id()));
    }
    assert_ne!(
        synth::trial_seed(5, TrialId::new(Task::Suturing, 'B', 1)),
        synth::trial_seed(5, TrialId::new(Task::KnotTying, 'B', 1))
    );
}

fn det(r: &[[f32; 3]; 3]) -> f64 {
    let m = |i: usize, j: usize| f64::from(r[i][j]);
    m(0, 0) * (m(1, 1) * m(2, 2) - m(1, 2) * m(2, 1))
        - m(0, 1) * (m(1, 0) * m(2, 2) - m(1, 2) * m(2, 0))
        + m(0, 2) * (m(1, 0) * m(2, 1) - m(1, 1) * m(2, 0))
}

#[test]
fn kinematics_are_physically_consistent() {
    let synth = generate(&SynthConfig {
        max_trials_per_task: Some(3),
        duration_scale: 1.0,
        ..small(8)
    })
    .unwrap();
    for trial in synth.dataset.all_trials() {
        let k = &trial.kinematics;
        let n = k.num_rows();
        for arm in Arm::ALL {
            for r in 0..n {
                let s = k.arm(r, arm).unwrap();
                // Rotation: orthonormal rows, determinant 1.
                for i in 0..3 {
                    for j in 0..3 {
                        let dot: f64 = (0..3)
                            .map(|c| f64::from(s.rotation[i][c]) * f64::from(s.rotation[j][c]))
                            .sum();
                        let want = if i == j { 1.0 } else { 0.0 };
                        assert!((dot - want).abs() < 1e-5, "{} row {r}: R·Rᵀ", trial.id());
                    }
                }
                assert!((det(&s.rotation) - 1.0).abs() < 1e-5);
                // Linear velocity = forward difference × 30.
                let (a, b) = if r + 1 < n { (r, r + 1) } else { (r - 1, r) };
                let (pa, pb) = (k.arm(a, arm).unwrap(), k.arm(b, arm).unwrap());
                for i in 0..3 {
                    let fd = (f64::from(pb.position[i]) - f64::from(pa.position[i])) * 30.0;
                    assert!(
                        (f64::from(s.linear_velocity[i]) - fd).abs() < 2e-6,
                        "{} {arm:?} row {r}: v {} vs fd {fd}",
                        trial.id(),
                        s.linear_velocity[i]
                    );
                }
                // Angular velocity ≈ small-angle forward difference of R × 30:
                // the skew part of R[b]·R[a]ᵀ.
                let rr = |i: usize, j: usize| -> f64 {
                    (0..3)
                        .map(|c| f64::from(pb.rotation[i][c]) * f64::from(pa.rotation[j][c]))
                        .sum()
                };
                let w = [
                    (rr(2, 1) - rr(1, 2)) / 2.0 * 30.0,
                    (rr(0, 2) - rr(2, 0)) / 2.0 * 30.0,
                    (rr(1, 0) - rr(0, 1)) / 2.0 * 30.0,
                ];
                for (got, want) in s.angular_velocity.iter().zip(w) {
                    let got = f64::from(*got);
                    assert!(
                        (got - want).abs() < 2e-3 + 0.01 * want.abs(),
                        "{} {arm:?} row {r}: ω {got} vs {want}",
                        trial.id(),
                    );
                }
            }
        }
    }
}

#[test]
fn gripper_angle_matches_grasping() {
    let synth = generate(&SynthConfig {
        max_trials_per_task: Some(4),
        duration_scale: 1.0,
        ..small(9)
    })
    .unwrap();
    let mut checked: BTreeMap<Gesture, usize> = BTreeMap::new();
    let grip = |t: &Trial, row: usize, arm: Arm| t.kinematics.arm(row, arm).unwrap().gripper_angle;
    for trial in synth.dataset.all_trials() {
        for s in &trial.segments {
            let end = s.end_row();
            let (left, right) = (
                grip(trial, end, Arm::PatientLeft),
                grip(trial, end, Arm::PatientRight),
            );
            let closed = |g: f32| g < 0.2;
            let open = |g: f32| g > 0.7;
            let ok = match s.gesture.number() {
                // Reaching with the right hand ends grasping.
                1 | 14 => closed(right),
                // Positioning, pushing, moving with the needle in the right grip.
                2 | 3 | 5 => closed(right),
                // Transfer left → right: right holds, left has let go.
                4 => closed(right) && open(left),
                // Pulling with the left hand: left holds, right has let go.
                6 => closed(left) && open(right),
                12 => closed(left),
                13 => closed(left) && open(right),
                15 => closed(left) && closed(right),
                // Dropping the suture: both open.
                11 => open(left) && open(right),
                _ => true,
            };
            assert!(
                ok,
                "{} {}: left {left}, right {right}",
                trial.id(),
                s.gesture
            );
            *checked.entry(s.gesture).or_default() += 1;
            // The master gripper follows the patient-side one.
            assert_eq!(right, grip(trial, end, Arm::MasterRight));
        }
    }
    assert!(checked.len() >= 10, "{checked:?}");
}
