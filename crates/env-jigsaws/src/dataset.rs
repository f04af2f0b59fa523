//! Trials and datasets: loading the real layout (nested task folders,
//! missing partner files) and writing it.

use std::collections::{BTreeMap, BTreeSet};
use std::fmt;
use std::fs;
use std::path::{Path, PathBuf};

use crate::error::{JigsawsError, Problem, Result};
use crate::kinematics::Kinematics;
use crate::transcription::{
    MetaRecord, Segment, format_meta_file, format_transcription, overlapping_segments,
    parse_meta_file, parse_transcription, segment_lines,
};
use crate::{Gesture, Task, TrialId};

/// One trial: its meta row, gesture segments and kinematics (and the paths
/// of its videos, which are listed but never decoded).
#[derive(Debug, Clone, PartialEq)]
pub struct Trial {
    /// The meta-file row (its `trial` field is this trial's id).
    pub meta: MetaRecord,
    /// The labelled segments, in order, non-overlapping, within the
    /// kinematics.
    pub segments: Vec<Segment>,
    /// The kinematics, 30 Hz.
    pub kinematics: Kinematics,
    /// Video files of this trial found in `video/` (`..._capture1.avi`,
    /// `..._capture2.avi`), sorted; empty for the synthetic dataset.
    pub videos: Vec<PathBuf>,
}

impl Trial {
    /// A trial, checked: at least one segment, `end >= start >= 1`, each
    /// segment starting after the previous one starts, and every segment
    /// within the kinematics rows. (Overlapping segments are allowed; see
    /// [`crate::overlapping_segments`].)
    pub fn new(meta: MetaRecord, segments: Vec<Segment>, kinematics: Kinematics) -> Result<Trial> {
        let trial = meta.trial;
        let invalid = |problem| JigsawsError::InvalidTrial { trial, problem };
        if segments.is_empty() {
            return Err(invalid(Problem::SegmentFields { got: 0 }));
        }
        let mut prev: Option<&Segment> = None;
        for s in &segments {
            if s.start_frame == 0 {
                return Err(invalid(Problem::FrameZero));
            }
            if s.end_frame < s.start_frame {
                return Err(invalid(Problem::EndBeforeStart {
                    start: s.start_frame,
                    end: s.end_frame,
                }));
            }
            if let Some(p) = prev
                && s.start_frame <= p.start_frame
            {
                return Err(invalid(Problem::OutOfOrder {
                    start: s.start_frame,
                    previous_start: p.start_frame,
                }));
            }
            if s.end_frame as usize > kinematics.num_rows() {
                return Err(invalid(Problem::SegmentPastEnd {
                    end: s.end_frame,
                    rows: kinematics.num_rows(),
                }));
            }
            prev = Some(s);
        }
        Ok(Trial {
            meta,
            segments,
            kinematics,
            videos: Vec::new(),
        })
    }

    /// The trial id.
    pub fn id(&self) -> TrialId {
        self.meta.trial
    }

    /// The gesture of each segment, in order.
    pub fn gestures(&self) -> Vec<Gesture> {
        self.segments.iter().map(|s| s.gesture).collect()
    }

    /// The gesture label of every kinematics row (`None` for unlabelled
    /// frames; where segments overlap, the later segment's gesture).
    pub fn frame_labels(&self) -> Vec<Option<Gesture>> {
        let mut labels = vec![None; self.kinematics.num_rows()];
        for s in &self.segments {
            let end = (s.end_row() + 1).min(labels.len());
            for l in labels.iter_mut().take(end).skip(s.start_row()) {
                *l = Some(s.gesture);
            }
        }
        labels
    }

    /// Number of labelled frames (frames inside at least one segment).
    pub fn labelled_frames(&self) -> usize {
        self.frame_labels().iter().filter(|l| l.is_some()).count()
    }
}

/// A set of trials grouped by task (only the tasks that were found or
/// generated appear). Trials are sorted by id.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Dataset {
    tasks: BTreeMap<Task, Vec<Trial>>,
}

/// Something the loader skipped or could not use; loading went on.
#[derive(Debug, Clone, PartialEq)]
pub enum LoadWarning {
    /// No folder for this task was found under the root.
    MissingTask {
        /// The task.
        task: Task,
    },
    /// The task folder has no meta file, so none of its trials can be used.
    MissingMetaFile {
        /// The expected meta-file path.
        path: PathBuf,
    },
    /// A trial with some but not all of transcription, kinematics and meta
    /// row; it was skipped.
    IncompleteTrial {
        /// The trial.
        trial: TrialId,
        /// One of the files that exists (or the meta file).
        path: PathBuf,
        /// What is missing: `"transcription"`, `"kinematics"`, `"meta row"`.
        missing: Vec<&'static str>,
    },
    /// A file whose name is not `<Task>_<Surgeon><NNN>.txt` of this task; it
    /// was ignored.
    UnrecognisedFile {
        /// The file.
        path: PathBuf,
    },
    /// A segment that starts before the previous one ends; it was kept (its
    /// frames are labelled with the later gesture).
    OverlappingSegment {
        /// The transcription.
        path: PathBuf,
        /// 1-based line of the segment.
        line: usize,
        /// Its start frame.
        start: u32,
        /// The previous segment's end frame.
        previous_end: u32,
    },
}

impl fmt::Display for LoadWarning {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            LoadWarning::MissingTask { task } => write!(f, "no {task} folder found; task skipped"),
            LoadWarning::MissingMetaFile { path } => write!(
                f,
                "{}: meta file missing; every trial of this task skipped",
                path.display()
            ),
            LoadWarning::IncompleteTrial {
                trial,
                path,
                missing,
            } => write!(
                f,
                "{}: trial {trial} skipped: no {}",
                path.display(),
                missing.join(", no ")
            ),
            LoadWarning::UnrecognisedFile { path } => write!(
                f,
                "{}: not named like a trial of this task; ignored",
                path.display()
            ),
            LoadWarning::OverlappingSegment {
                path,
                line,
                start,
                previous_end,
            } => write!(
                f,
                "{}:{line}: segment starting at frame {start} overlaps the previous one (ends at frame {previous_end}); kept",
                path.display()
            ),
        }
    }
}

/// What the loader found besides the trials.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct LoadReport {
    /// The folder used for each task found.
    pub task_folders: BTreeMap<Task, PathBuf>,
    /// Everything skipped, in the order met.
    pub warnings: Vec<LoadWarning>,
}

/// A loaded dataset and its report.
#[derive(Debug, Clone, PartialEq)]
pub struct LoadedDataset {
    /// The usable trials.
    pub dataset: Dataset,
    /// Task folders used and warnings.
    pub report: LoadReport,
}

/// How deep below the root [`find_task_folder`] looks.
pub const MAX_SEARCH_DEPTH: usize = 4;

impl Dataset {
    /// A dataset of the given trials (grouped by task, sorted by id). Every
    /// task of `tasks` is present, possibly with no trials.
    pub fn from_trials(tasks: &[Task], trials: Vec<Trial>) -> Dataset {
        let mut map: BTreeMap<Task, Vec<Trial>> = tasks.iter().map(|&t| (t, Vec::new())).collect();
        for t in trials {
            map.entry(t.id().task).or_default().push(t);
        }
        for v in map.values_mut() {
            v.sort_by_key(Trial::id);
        }
        Dataset { tasks: map }
    }

    /// Loads every task found under `root` (see [`find_task_folder`]): a
    /// trial is used when it has a transcription, a kinematics file and a
    /// meta row; anything less is skipped with a warning in the report.
    /// Malformed files are errors naming the file and line. Errors if no
    /// task folder is found at all.
    pub fn load(root: &Path) -> Result<LoadedDataset> {
        let mut report = LoadReport::default();
        let mut dataset = Dataset::default();
        for task in Task::ALL {
            match find_task_folder(root, task)? {
                Some(folder) => {
                    let trials = load_task(&folder, task, &mut report.warnings)?;
                    dataset.tasks.insert(task, trials);
                    report.task_folders.insert(task, folder);
                }
                None => report.warnings.push(LoadWarning::MissingTask { task }),
            }
        }
        if report.task_folders.is_empty() {
            return Err(JigsawsError::NoTaskFolders {
                root: root.to_owned(),
            });
        }
        Ok(LoadedDataset { dataset, report })
    }

    /// Loads one task folder (the folder holding `meta_file_<Task>.txt`,
    /// `transcriptions/` and `kinematics/`).
    pub fn load_task_folder(folder: &Path, task: Task) -> Result<LoadedDataset> {
        let mut report = LoadReport::default();
        let trials = load_task(folder, task, &mut report.warnings)?;
        report.task_folders.insert(task, folder.to_owned());
        Ok(LoadedDataset {
            dataset: Dataset::from_trials(&[task], trials),
            report,
        })
    }

    /// The tasks present, in [`Task::ALL`] order.
    pub fn tasks(&self) -> impl Iterator<Item = Task> + '_ {
        self.tasks.keys().copied()
    }

    /// The trials of `task`, sorted by id (empty if the task is absent).
    pub fn trials(&self, task: Task) -> &[Trial] {
        self.tasks.get(&task).map_or(&[], Vec::as_slice)
    }

    /// Every trial, task by task.
    pub fn all_trials(&self) -> impl Iterator<Item = &Trial> {
        self.tasks.values().flatten()
    }

    /// The trial with this id.
    pub fn trial(&self, id: TrialId) -> Option<&Trial> {
        self.trials(id.task).iter().find(|t| t.id() == id)
    }

    /// Total number of trials.
    pub fn num_trials(&self) -> usize {
        self.tasks.values().map(Vec::len).sum()
    }

    /// Keeps only the trials for which `keep` is true.
    pub fn retain(&mut self, mut keep: impl FnMut(&Trial) -> bool) {
        for v in self.tasks.values_mut() {
            v.retain(&mut keep);
        }
    }

    /// Writes the dataset in the real layout under `root`:
    /// `<root>/<Task>/meta_file_<Task>.txt`,
    /// `<root>/<Task>/transcriptions/<id>.txt` and
    /// `<root>/<Task>/kinematics/AllGestures/<id>.txt` (no videos). Existing
    /// files are overwritten.
    pub fn write(&self, root: &Path) -> Result<()> {
        for (&task, trials) in &self.tasks {
            let folder = root.join(task.folder_name());
            let records: Vec<MetaRecord> = trials.iter().map(|t| t.meta).collect();
            write_file(
                &folder.join(format!("meta_file_{}.txt", task.folder_name())),
                format_meta_file(&records).as_bytes(),
            )?;
            for t in trials {
                write_file(
                    &transcription_path(&folder, t.id()),
                    format_transcription(&t.segments).as_bytes(),
                )?;
                write_file(
                    &kinematics_path(&folder, t.id()),
                    t.kinematics.to_text().as_bytes(),
                )?;
            }
        }
        Ok(())
    }
}

/// `<folder>/transcriptions/<id>.txt`.
pub fn transcription_path(task_folder: &Path, id: TrialId) -> PathBuf {
    task_folder.join("transcriptions").join(format!("{id}.txt"))
}

/// `<folder>/kinematics/AllGestures/<id>.txt`.
pub fn kinematics_path(task_folder: &Path, id: TrialId) -> PathBuf {
    task_folder
        .join("kinematics")
        .join("AllGestures")
        .join(format!("{id}.txt"))
}

/// Writes `bytes` to `path`, creating parent folders.
pub(crate) fn write_file(path: &Path, bytes: &[u8]) -> Result<()> {
    let io = |source| JigsawsError::Io {
        path: path.to_owned(),
        source,
    };
    if let Some(parent) = path.parent() {
        fs::create_dir_all(parent).map_err(|source| JigsawsError::Io {
            path: parent.to_owned(),
            source,
        })?;
    }
    fs::write(path, bytes).map_err(io)
}

/// Reads a text file; invalid UTF-8 is an error naming the line of the first
/// bad byte.
pub fn read_text(path: &Path) -> Result<String> {
    let bytes = fs::read(path).map_err(|source| JigsawsError::Io {
        path: path.to_owned(),
        source,
    })?;
    String::from_utf8(bytes).map_err(|e| {
        let valid = &e.as_bytes()[..e.utf8_error().valid_up_to()];
        JigsawsError::Parse {
            path: path.to_owned(),
            line: valid.iter().filter(|&&b| b == b'\n').count() + 1,
            problem: Problem::InvalidUtf8,
        }
    })
}

/// Whether `dir` looks like a task folder: it has a `transcriptions` or
/// `kinematics` subfolder or the task's meta file.
fn is_task_folder(dir: &Path, task: Task) -> bool {
    dir.join("transcriptions").is_dir()
        || dir.join("kinematics").is_dir()
        || dir
            .join(format!("meta_file_{}.txt", task.folder_name()))
            .is_file()
}

/// Finds the folder of `task` under `root`: a folder named like the task
/// (`Suturing`, `Needle_Passing`, `Knot_Tying`) that holds `transcriptions/`,
/// `kinematics/` or the meta file, at most [`MAX_SEARCH_DEPTH`] levels below
/// `root` (`root` itself counts). Archives that nest the task folder twice
/// (`Suturing/Suturing/...`) are handled because the outer folder does not
/// qualify. The shallowest match wins, ties broken by path order.
pub fn find_task_folder(root: &Path, task: Task) -> Result<Option<PathBuf>> {
    let mut level = vec![root.to_owned()];
    for depth in 0..=MAX_SEARCH_DEPTH {
        let mut matches: Vec<PathBuf> = level
            .iter()
            .filter(|d| {
                d.file_name().and_then(|n| n.to_str()) == Some(task.folder_name())
                    && is_task_folder(d, task)
            })
            .cloned()
            .collect();
        if !matches.is_empty() {
            matches.sort();
            return Ok(matches.into_iter().next());
        }
        if depth == MAX_SEARCH_DEPTH {
            break;
        }
        let mut next = Vec::new();
        for dir in &level {
            let entries = match fs::read_dir(dir) {
                Ok(e) => e,
                Err(source) if dir == root => {
                    return Err(JigsawsError::Io {
                        path: dir.clone(),
                        source,
                    });
                }
                Err(_) => continue, // an unreadable subfolder cannot hold the task
            };
            for entry in entries.flatten() {
                let path = entry.path();
                let hidden = entry.file_name().to_string_lossy().starts_with('.');
                if !hidden && path.is_dir() {
                    next.push(path);
                }
            }
        }
        next.sort();
        level = next;
    }
    Ok(None)
}

/// Files of `dir` named `<id>.txt` for a trial of `task`; other visible
/// files are reported. A missing folder gives no files.
fn trial_files(
    dir: &Path,
    task: Task,
    warnings: &mut Vec<LoadWarning>,
) -> Result<BTreeMap<TrialId, PathBuf>> {
    let mut out = BTreeMap::new();
    if !dir.is_dir() {
        return Ok(out);
    }
    for path in sorted_files(dir)? {
        let name = path.file_name().and_then(|n| n.to_str()).unwrap_or("");
        if name.starts_with('.') {
            continue;
        }
        match name
            .strip_suffix(".txt")
            .and_then(TrialId::parse)
            .filter(|id| id.task == task)
        {
            Some(id) => {
                out.insert(id, path);
            }
            None => warnings.push(LoadWarning::UnrecognisedFile { path }),
        }
    }
    Ok(out)
}

fn sorted_files(dir: &Path) -> Result<Vec<PathBuf>> {
    let io = |source| JigsawsError::Io {
        path: dir.to_owned(),
        source,
    };
    let mut files = Vec::new();
    for entry in fs::read_dir(dir).map_err(io)? {
        let path = entry.map_err(io)?.path();
        if path.is_file() {
            files.push(path);
        }
    }
    files.sort();
    Ok(files)
}

fn load_task(folder: &Path, task: Task, warnings: &mut Vec<LoadWarning>) -> Result<Vec<Trial>> {
    let meta_path = folder.join(format!("meta_file_{}.txt", task.folder_name()));
    let meta: BTreeMap<TrialId, MetaRecord> = if meta_path.is_file() {
        parse_meta_file(&read_text(&meta_path)?, task, &meta_path)?
            .into_iter()
            .map(|(_, r)| (r.trial, r))
            .collect()
    } else {
        warnings.push(LoadWarning::MissingMetaFile {
            path: meta_path.clone(),
        });
        BTreeMap::new()
    };
    let transcriptions = trial_files(&folder.join("transcriptions"), task, warnings)?;
    let kinematics = trial_files(
        &folder.join("kinematics").join("AllGestures"),
        task,
        warnings,
    )?;
    let videos = list_videos(&folder.join("video"))?;

    let ids: BTreeSet<TrialId> = transcriptions
        .keys()
        .chain(kinematics.keys())
        .chain(meta.keys())
        .copied()
        .collect();
    let mut trials = Vec::new();
    for id in ids {
        let (t, k, m) = (transcriptions.get(&id), kinematics.get(&id), meta.get(&id));
        let (Some(t_path), Some(k_path), Some(record)) = (t, k, m) else {
            let missing = [
                (t.is_none(), "transcription"),
                (k.is_none(), "kinematics"),
                (m.is_none(), "meta row"),
            ]
            .into_iter()
            .filter_map(|(gone, what)| gone.then_some(what))
            .collect();
            let path = k.or(t).cloned().unwrap_or_else(|| meta_path.clone());
            warnings.push(LoadWarning::IncompleteTrial {
                trial: id,
                path,
                missing,
            });
            continue;
        };
        let text = read_text(t_path)?;
        let segments = parse_transcription(&text, t_path)?;
        let lines = segment_lines(&text);
        let line_of = |i: usize| lines.get(i).copied().unwrap_or(i + 1);
        if segments.is_empty() {
            return Err(JigsawsError::Empty {
                path: t_path.clone(),
                what: "transcription",
            });
        }
        let kin = Kinematics::parse(&read_text(k_path)?, k_path)?;
        if kin.is_empty() {
            return Err(JigsawsError::Empty {
                path: k_path.clone(),
                what: "kinematics",
            });
        }
        if let Some((i, s)) = segments
            .iter()
            .enumerate()
            .find(|(_, s)| s.end_frame as usize > kin.num_rows())
        {
            return Err(JigsawsError::Parse {
                path: t_path.clone(),
                line: line_of(i),
                problem: Problem::SegmentPastEnd {
                    end: s.end_frame,
                    rows: kin.num_rows(),
                },
            });
        }
        for i in overlapping_segments(&segments) {
            warnings.push(LoadWarning::OverlappingSegment {
                path: t_path.clone(),
                line: line_of(i),
                start: segments[i].start_frame,
                previous_end: segments[i - 1].end_frame,
            });
        }
        let mut trial = Trial::new(*record, segments, kin)?;
        let prefix = format!("{id}_");
        trial.videos = videos
            .iter()
            .filter(|v| {
                v.file_name()
                    .and_then(|n| n.to_str())
                    .is_some_and(|n| n.starts_with(&prefix))
            })
            .cloned()
            .collect();
        trials.push(trial);
    }
    Ok(trials)
}

fn list_videos(dir: &Path) -> Result<Vec<PathBuf>> {
    if !dir.is_dir() {
        return Ok(Vec::new());
    }
    Ok(sorted_files(dir)?
        .into_iter()
        .filter(|p| {
            p.extension()
                .and_then(|e| e.to_str())
                .is_some_and(|e| e.eq_ignore_ascii_case("avi"))
        })
        .collect())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::Skill;

    fn meta(id: TrialId) -> MetaRecord {
        MetaRecord {
            trial: id,
            skill: Skill::Expert,
            grs_total: 24,
            grs: [4; 6],
        }
    }

    fn seg(start: u32, end: u32, g: Gesture) -> Segment {
        Segment {
            start_frame: start,
            end_frame: end,
            gesture: g,
        }
    }

    #[test]
    fn trial_new_validates_segments() {
        let id = TrialId::new(Task::Suturing, 'D', 1);
        let kin = Kinematics::from_flat(vec![0.0; 76 * 10]).unwrap();
        let ok = Trial::new(meta(id), vec![seg(2, 4, Gesture::G1)], kin.clone()).unwrap();
        assert_eq!(
            ok.frame_labels(),
            [
                None,
                Some(Gesture::G1),
                Some(Gesture::G1),
                Some(Gesture::G1),
                None,
                None,
                None,
                None,
                None,
                None
            ]
        );
        let err = Trial::new(meta(id), vec![seg(2, 11, Gesture::G1)], kin.clone()).unwrap_err();
        assert_eq!(
            err.to_string(),
            "trial Suturing_D001: segment ends at frame 11, but the kinematics file has only 10 rows"
        );
        assert!(Trial::new(meta(id), vec![], kin.clone()).is_err());
        assert!(
            Trial::new(
                meta(id),
                vec![seg(4, 4, Gesture::G1), seg(4, 5, Gesture::G2)],
                kin.clone()
            )
            .is_err()
        );
        // An overlap is allowed; the later gesture labels the shared frame.
        let overlap = Trial::new(
            meta(id),
            vec![seg(2, 4, Gesture::G1), seg(4, 5, Gesture::G2)],
            kin,
        )
        .unwrap();
        assert_eq!(overlap.frame_labels()[3], Some(Gesture::G2));
        assert_eq!(overlap.labelled_frames(), 4);
    }
}
