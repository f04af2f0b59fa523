//! Each kind of malformed input, planted in a copy of the miniature, is an
//! error from `Dataset::load` that names the file and the line.

use std::fs;
use std::path::{Path, PathBuf};

use env_jigsaws::{Dataset, JigsawsError, Problem};

fn copy_dir(from: &Path, to: &Path) {
    fs::create_dir_all(to).unwrap();
    for entry in fs::read_dir(from).unwrap() {
        let entry = entry.unwrap();
        let target = to.join(entry.file_name());
        if entry.path().is_dir() {
            copy_dir(&entry.path(), &target);
        } else {
            fs::copy(entry.path(), target).unwrap();
        }
    }
}

/// A fresh copy of the miniature; returns (tempdir guard, Suturing folder).
fn copy() -> (tempfile::TempDir, PathBuf) {
    let dir = tempfile::tempdir().unwrap();
    copy_dir(
        &Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/miniature"),
        dir.path(),
    );
    let suturing = dir.path().join("JIGSAWS/Suturing/Suturing");
    (dir, suturing)
}

/// Loads after `edit` and returns (file name, line, problem) of the error.
fn load_error(edit: impl FnOnce(&Path)) -> (String, usize, Problem, String) {
    let (dir, suturing) = copy();
    edit(&suturing);
    match Dataset::load(dir.path()) {
        Err(err @ JigsawsError::Parse { .. }) => {
            let message = err.to_string();
            let JigsawsError::Parse {
                path,
                line,
                problem,
            } = err
            else {
                unreachable!()
            };
            (
                path.file_name().unwrap().to_string_lossy().into_owned(),
                line,
                problem,
                message,
            )
        }
        other => panic!("expected a parse error, got {other:?}"),
    }
}

fn transcription(s: &Path) -> PathBuf {
    s.join("transcriptions/Suturing_B001.txt")
}

fn kinematics(s: &Path) -> PathBuf {
    s.join("kinematics/AllGestures/Suturing_B001.txt")
}

fn edit_line(path: &Path, line: usize, f: impl FnOnce(&str) -> String) {
    let text = fs::read_to_string(path).unwrap();
    let mut lines: Vec<String> = text.lines().map(str::to_owned).collect();
    lines[line - 1] = f(&lines[line - 1]);
    fs::write(path, lines.join("\n") + "\n").unwrap();
}

#[test]
fn short_kinematics_row() {
    let (file, line, problem, message) = load_error(|s| {
        edit_line(&kinematics(s), 7, |l| {
            l.split_whitespace().take(75).collect::<Vec<_>>().join(" ")
        })
    });
    assert_eq!((file.as_str(), line), ("Suturing_B001.txt", 7));
    assert_eq!(
        problem,
        Problem::ShortRow {
            expected: 76,
            got: 75
        }
    );
    assert!(
        message.ends_with(
            "kinematics/AllGestures/Suturing_B001.txt:7: short row: expected 76 values, found 75"
        ),
        "{message}"
    );
}

#[test]
fn non_number_in_kinematics() {
    let (file, line, problem, _) = load_error(|s| {
        edit_line(&kinematics(s), 3, |l| {
            let mut t: Vec<&str> = l.split_whitespace().collect();
            t[40] = "0.0x1";
            t.join("  ")
        })
    });
    assert_eq!((file.as_str(), line), ("Suturing_B001.txt", 3));
    assert_eq!(
        problem,
        Problem::NotANumber {
            column: 41,
            token: "0.0x1".into()
        }
    );
}

#[test]
fn segment_end_before_start() {
    let (_, line, problem, message) =
        load_error(|s| edit_line(&transcription(s), 2, |_| "12 8 G5 ".into()));
    assert_eq!(line, 2);
    assert_eq!(problem, Problem::EndBeforeStart { start: 12, end: 8 });
    assert!(
        message.contains("transcriptions/Suturing_B001.txt:2: segment ends at frame 8"),
        "{message}"
    );
}

#[test]
fn unknown_gesture() {
    let (_, line, problem, _) =
        load_error(|s| edit_line(&transcription(s), 3, |_| "15 19 G18 ".into()));
    assert_eq!(line, 3);
    assert_eq!(
        problem,
        Problem::UnknownGesture {
            token: "G18".into()
        }
    );
}

#[test]
fn segment_past_the_kinematics() {
    let (file, line, problem, _) =
        load_error(|s| edit_line(&transcription(s), 3, |_| "15 21 G8 ".into()));
    assert_eq!((file.as_str(), line), ("Suturing_B001.txt", 3));
    assert_eq!(problem, Problem::SegmentPastEnd { end: 21, rows: 20 });
}

#[test]
fn out_of_order_segment() {
    let (_, line, problem, _) =
        load_error(|s| edit_line(&transcription(s), 3, |_| "8 19 G8 ".into()));
    assert_eq!(line, 3);
    assert_eq!(
        problem,
        Problem::OutOfOrder {
            start: 8,
            previous_start: 8
        }
    );
}

#[test]
fn overlapping_segment_is_kept_with_a_warning() {
    let (dir, suturing) = copy();
    edit_line(&transcription(&suturing), 3, |_| "12 19 G8 ".into());
    let loaded = Dataset::load(dir.path()).unwrap();
    let warning = loaded
        .report
        .warnings
        .iter()
        .find(|w| matches!(w, env_jigsaws::LoadWarning::OverlappingSegment { .. }))
        .expect("an overlap warning")
        .to_string();
    assert!(
        warning.ends_with("transcriptions/Suturing_B001.txt:3: segment starting at frame 12 overlaps the previous one (ends at frame 12); kept"),
        "{warning}"
    );
    let id = env_jigsaws::TrialId::new(env_jigsaws::Task::Suturing, 'B', 1);
    assert_eq!(loaded.dataset.trial(id).unwrap().segments.len(), 3);
}

#[test]
fn bad_meta_row() {
    let (file, line, problem, _) = load_error(|s| {
        edit_line(&s.join("meta_file_Suturing.txt"), 3, |l| {
            l.replace("\tE\t", "\tX\t")
        })
    });
    assert_eq!((file.as_str(), line), ("meta_file_Suturing.txt", 3));
    assert_eq!(problem, Problem::BadSkill { token: "X".into() });
}

#[test]
fn invalid_utf8_names_the_line() {
    let (_, line, problem, _) = load_error(|s| {
        let mut bytes = fs::read(transcription(s)).unwrap();
        bytes.extend_from_slice(b"20 20 G\xff\n");
        fs::write(transcription(s), bytes).unwrap();
    });
    assert_eq!((line, problem), (4, Problem::InvalidUtf8));
}

#[test]
fn empty_transcription_is_an_error() {
    let (dir, suturing) = copy();
    fs::write(transcription(&suturing), "\n\n").unwrap();
    let err = Dataset::load(dir.path()).unwrap_err();
    assert!(
        matches!(&err, JigsawsError::Empty { path, what: "transcription" } if path.ends_with("Suturing_B001.txt")),
        "{err}"
    );
}

#[test]
fn a_root_without_task_folders_is_an_error() {
    let dir = tempfile::tempdir().unwrap();
    fs::create_dir_all(dir.path().join("Suturing/empty")).unwrap();
    let err = Dataset::load(dir.path()).unwrap_err();
    assert!(matches!(err, JigsawsError::NoTaskFolders { .. }), "{err}");
    let missing = Dataset::load(&dir.path().join("nope")).unwrap_err();
    assert!(matches!(missing, JigsawsError::Io { .. }), "{missing}");
}
