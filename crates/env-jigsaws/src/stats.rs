//! Per-task statistics: trials, gestures, frames, transitions.

use std::collections::BTreeMap;

use ctg_graph::Vocabulary;

use crate::dataset::Dataset;
use crate::{FRAME_RATE, Gesture, Skill, Task};

/// How often one gesture follows another (or `<start>` / `<end>`).
#[derive(Debug, Clone, PartialEq, Eq, serde::Serialize)]
pub struct TransitionCount {
    /// The earlier gesture, or `<start>`.
    pub from: String,
    /// The later gesture, or `<end>`.
    pub to: String,
    /// Number of times, over all trials.
    pub count: usize,
}

/// How often a gesture occurs.
#[derive(Debug, Clone, PartialEq, Eq, serde::Serialize)]
pub struct GestureCount {
    /// The gesture.
    pub gesture: Gesture,
    /// Segments labelled with it.
    pub segments: usize,
    /// Frames labelled with it.
    pub frames: usize,
}

/// Statistics of one task.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct TaskStats {
    /// The task.
    pub task: Task,
    /// Number of trials.
    pub trials: usize,
    /// Trials per self-rated skill level.
    pub trials_by_skill: BTreeMap<Skill, usize>,
    /// Number of segments (steps).
    pub segments: usize,
    /// Kinematics rows (30 Hz frames) over all trials.
    pub frames: usize,
    /// Frames inside a segment.
    pub labelled_frames: usize,
    /// Total duration in seconds (`frames / 30`).
    pub duration_s: f64,
    /// The gestures that occur, in order of number, with counts.
    pub gestures: Vec<GestureCount>,
    /// Consecutive-segment transitions, `<start>` → first and last →
    /// `<end>` included, sorted by `from` then `to` in vocabulary order.
    pub transitions: Vec<TransitionCount>,
}

impl TaskStats {
    /// Just the gestures that occur, in order.
    pub fn gesture_set(&self) -> Vec<Gesture> {
        self.gestures.iter().map(|g| g.gesture).collect()
    }
}

/// Statistics of every task of a dataset.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct DatasetStats {
    /// One entry per task present, in [`Task::ALL`] order.
    pub tasks: Vec<TaskStats>,
}

impl DatasetStats {
    /// The entry of `task`, if present.
    pub fn task(&self, task: Task) -> Option<&TaskStats> {
        self.tasks.iter().find(|t| t.task == task)
    }
}

impl Dataset {
    /// Computes per-task statistics.
    pub fn stats(&self) -> DatasetStats {
        let vocab = crate::gesture_vocabulary();
        let tasks = self
            .tasks()
            .map(|task| {
                let trials = self.trials(task);
                let mut by_skill = BTreeMap::new();
                let mut per_gesture: BTreeMap<Gesture, (usize, usize)> = BTreeMap::new();
                let mut transitions: BTreeMap<(usize, usize), usize> = BTreeMap::new();
                let (mut segments, mut frames, mut labelled) = (0, 0, 0);
                for t in trials {
                    *by_skill.entry(t.meta.skill).or_insert(0) += 1;
                    segments += t.segments.len();
                    frames += t.kinematics.num_rows();
                    labelled += t.labelled_frames();
                    for s in &t.segments {
                        let e = per_gesture.entry(s.gesture).or_insert((0, 0));
                        e.0 += 1;
                        e.1 += s.num_frames();
                    }
                    let path: Vec<usize> = std::iter::once(Vocabulary::START.index())
                        .chain(t.segments.iter().map(|s| s.gesture.action_id().index()))
                        .chain(std::iter::once(Vocabulary::END.index()))
                        .collect();
                    for w in path.windows(2) {
                        *transitions.entry((w[0], w[1])).or_insert(0) += 1;
                    }
                }
                let name = |i: usize| {
                    vocab
                        .name(ctg_graph::ActionId::new(i))
                        .unwrap_or("?")
                        .to_owned()
                };
                TaskStats {
                    task,
                    trials: trials.len(),
                    trials_by_skill: by_skill,
                    segments,
                    frames,
                    labelled_frames: labelled,
                    duration_s: frames as f64 / FRAME_RATE,
                    gestures: per_gesture
                        .into_iter()
                        .map(|(gesture, (segments, frames))| GestureCount {
                            gesture,
                            segments,
                            frames,
                        })
                        .collect(),
                    transitions: transitions
                        .into_iter()
                        .map(|((a, b), count)| TransitionCount {
                            from: name(a),
                            to: name(b),
                            count,
                        })
                        .collect(),
                }
            })
            .collect();
        DatasetStats { tasks }
    }
}
