//! The reader on a hand-made miniature of the real layout (`tests/miniature`):
//! Suturing nested twice, Knot Tying once, Needle Passing absent; a
//! kinematics-only trial, a meta row without files, a stray file, videos,
//! unlabelled frames, CRLF line endings, runs of spaces and e-notation.

use std::path::{Path, PathBuf};

use ctg_graph::Vocabulary;
use env_jigsaws::{
    Arm, ColumnStats, Dataset, Gesture, LoadWarning, ObservationConfig, ObservationEncoder, Skill,
    Task, TrialId, find_task_folder,
};

fn root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/miniature")
}

#[test]
fn finds_nested_task_folders() {
    let r = root();
    assert_eq!(
        find_task_folder(&r, Task::Suturing).unwrap(),
        Some(r.join("JIGSAWS/Suturing/Suturing"))
    );
    assert_eq!(
        find_task_folder(&r, Task::KnotTying).unwrap(),
        Some(r.join("JIGSAWS/Knot_Tying"))
    );
    assert_eq!(find_task_folder(&r, Task::NeedlePassing).unwrap(), None);
    // The task folder itself can be given as the root.
    let kt = r.join("JIGSAWS/Knot_Tying");
    assert_eq!(find_task_folder(&kt, Task::KnotTying).unwrap(), Some(kt));
}

#[test]
fn loads_complete_trials_and_reports_the_rest() {
    let loaded = Dataset::load(&root()).unwrap();
    let data = &loaded.dataset;
    let ids: Vec<String> = data.all_trials().map(|t| t.id().to_string()).collect();
    assert_eq!(ids, ["Suturing_B001", "Suturing_D001", "Knot_Tying_B001"]);
    assert!(data.trials(Task::NeedlePassing).is_empty());

    let warnings: Vec<String> = loaded
        .report
        .warnings
        .iter()
        .map(ToString::to_string)
        .collect();
    assert_eq!(warnings.len(), 4, "{warnings:#?}");
    let w = &loaded.report.warnings;
    assert!(w.contains(&LoadWarning::MissingTask {
        task: Task::NeedlePassing
    }));
    assert!(w.iter().any(|w| matches!(w,
        LoadWarning::IncompleteTrial { trial, missing, path }
            if *trial == TrialId::new(Task::Suturing, 'H', 2)
            && missing == &["transcription", "meta row"]
            && path.ends_with("kinematics/AllGestures/Suturing_H002.txt"))));
    assert!(w.iter().any(|w| matches!(w,
        LoadWarning::IncompleteTrial { trial, missing, path }
            if *trial == TrialId::new(Task::Suturing, 'C', 2)
            && missing == &["transcription", "kinematics"]
            && path.ends_with("meta_file_Suturing.txt"))));
    assert!(w.iter().any(|w| matches!(w,
        LoadWarning::UnrecognisedFile { path } if path.ends_with("transcriptions/notes.md"))));
    assert!(
        warnings.iter().any(|s| s.ends_with(
            "Suturing_H002.txt: trial Suturing_H002 skipped: no transcription, no meta row"
        )),
        "{warnings:#?}"
    );
}

#[test]
fn trial_content_is_read_exactly() {
    let data = Dataset::load(&root()).unwrap().dataset;
    let b001 = data
        .trial(TrialId::new(Task::Suturing, 'B', 1))
        .expect("Suturing_B001");
    assert_eq!(b001.meta.skill, Skill::Novice);
    assert_eq!(
        (b001.meta.grs_total, b001.meta.grs),
        (13, [2, 2, 2, 3, 2, 2])
    );
    assert_eq!(b001.gestures(), [Gesture::G1, Gesture::G5, Gesture::G8]);
    assert_eq!(b001.kinematics.num_rows(), 20);
    assert_eq!(b001.labelled_frames(), 15);
    let labels = b001.frame_labels();
    // Frames 1-2, 13-14 and 20 are unlabelled; frame f is row f - 1.
    let unlabelled: Vec<usize> = (0..20).filter(|&r| labels[r].is_none()).collect();
    assert_eq!(unlabelled, [0, 1, 12, 13, 19]);
    assert_eq!(labels[2], Some(Gesture::G1));
    assert_eq!(labels[18], Some(Gesture::G8));

    let names: Vec<_> = b001
        .videos
        .iter()
        .map(|p| p.file_name().unwrap().to_str().unwrap().to_owned())
        .collect();
    assert_eq!(
        names,
        ["Suturing_B001_capture1.avi", "Suturing_B001_capture2.avi"]
    );
    assert!(
        data.trial(TrialId::new(Task::Suturing, 'D', 1))
            .unwrap()
            .videos
            .is_empty()
    );

    // Row 3 (frame 4), patient-side right arm (columns 58-76): see the
    // fixture's pattern: position 0.04 + 0.001·r + 0.0001·k·seed, identity
    // rotation, velocity 0.03, angular velocity -1.25e-5·k, gripper 0.9 - 0.05·r.
    let arm = b001.kinematics.arm(3, Arm::PatientRight).unwrap();
    assert_eq!(arm.position, [0.043, 0.0431, 0.0432]);
    assert_eq!(
        arm.rotation,
        [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]
    );
    assert_eq!(arm.linear_velocity, [0.03; 3]);
    assert_eq!(arm.angular_velocity, [-1.25e-5, -2.5e-5, -3.75e-5]);
    assert_eq!(arm.gripper_angle, 0.75);
    let master_left = b001.kinematics.arm(0, Arm::MasterLeft).unwrap();
    assert_eq!(master_left.position, [0.01, 0.0101, 0.0102]);

    // CRLF files read the same.
    let kt = data.trial(TrialId::new(Task::KnotTying, 'B', 1)).unwrap();
    assert_eq!(kt.gestures(), [Gesture::G1, Gesture::G12]);
    assert_eq!(kt.kinematics.num_rows(), 10);
}

#[test]
fn demonstrations_have_one_step_per_segment() {
    let data = Dataset::load(&root()).unwrap().dataset;
    let trial = data.trial(TrialId::new(Task::Suturing, 'B', 1)).unwrap();
    let config = ObservationConfig {
        window: 4,
        stride: 6,
    };
    let encoder =
        ObservationEncoder::new(config, ColumnStats::fit(data.all_trials()).unwrap()).unwrap();
    let demo = encoder.demonstration(trial).unwrap();
    let vocab = env_jigsaws::gesture_vocabulary();
    assert_eq!(vocab.format_sequence(demo.actions()), "G1 G5 G8");
    assert_eq!(demo.observations().len(), 4);
    assert!(
        demo.observations()
            .iter()
            .all(|o| o.len() == 4 * 76 && o.iter().all(|v| v.is_finite()))
    );
    assert_eq!(demo.next_actions().last(), Some(&Vocabulary::END));
    // Anchors: rows 1 (before frame 3), 6, 13, and 18 (end of the last segment).
    assert_eq!(ObservationEncoder::anchor_rows(trial), [1, 6, 13, 18]);
}
