//! The JIGSAWS surgical dataset for NTG: a reader for the real layout, a
//! seeded synthetic stand-in written in the same layout, and NTG
//! observations (kinematics windows, one step per gesture segment).
//!
//! - [`Dataset::load`] finds the task folders under a root (nested
//!   `Suturing/Suturing/...` included, see [`find_task_folder`]) and reads
//!   meta files ([`parse_meta_file`]), transcriptions
//!   ([`parse_transcription`]) and 76-column kinematics
//!   ([`Kinematics::parse`], typed per arm with [`Kinematics::arm`]). A
//!   trial missing its transcription, kinematics or meta row is skipped and
//!   reported in [`LoadReport::warnings`]; malformed content is a
//!   [`JigsawsError::Parse`] naming the file and line. Videos are listed,
//!   never decoded.
//! - [`synth`] generates a **synthetic stand-in** (the real data is not
//!   available here) with the real trial inventory, and writes it in the
//!   real layout.
//! - [`ObservationEncoder`] turns a [`Trial`] into a
//!   [`ctg_graph::Demonstration<Vec<f32>>`] over [`gesture_vocabulary`]
//!   (`G1`–`G15`): see [`observation`] for the exact window convention.
//! - [`Dataset::stats`]: trials, gestures, frames and transitions per task.
//!
//! ```no_run
//! use env_jigsaws::{ColumnStats, Dataset, ObservationConfig, ObservationEncoder, Task};
//! # fn main() -> env_jigsaws::Result<()> {
//! let loaded = Dataset::load("data/jigsaws".as_ref())?;
//! for warning in &loaded.report.warnings {
//!     eprintln!("warning: {warning}");
//! }
//! let data = loaded.dataset;
//! let train = data.trials(Task::Suturing).iter().chain(data.trials(Task::KnotTying));
//! let encoder = ObservationEncoder::new(ObservationConfig::default(), ColumnStats::fit(train)?)?;
//! let test_demos = encoder.demonstrations(data.trials(Task::NeedlePassing))?;
//! # let _ = test_demos;
//! # Ok(())
//! # }
//! ```
//!
//! **Architecture invariant:** depends on `ctg-graph`, rand, serde and
//! thiserror only. It must never depend on `ntg-model`, burn, or another
//! environment crate.

mod dataset;
mod error;
mod gesture;
mod kinematics;
pub mod observation;
mod stats;
pub mod synth;
mod transcription;

pub use dataset::{
    Dataset, LoadReport, LoadWarning, LoadedDataset, MAX_SEARCH_DEPTH, Trial, find_task_folder,
    kinematics_path, read_text, transcription_path,
};
pub use error::{JigsawsError, Problem, Result};
pub use gesture::{Gesture, Skill, Task, TrialId, gesture_vocabulary};
pub use kinematics::{
    ARM_COLUMNS, Arm, ArmState, FRAME_RATE, KINEMATICS_COLUMNS, Kinematics, group,
};
pub use observation::{
    ColumnStats, DEFAULT_STRIDE, DEFAULT_WINDOW, ObservationConfig, ObservationEncoder,
};
pub use stats::{DatasetStats, GestureCount, TaskStats, TransitionCount};
pub use synth::{SynthConfig, SyntheticJigsaws, generate, write_synthetic};
pub use transcription::{
    GRS_ITEMS, MetaRecord, Segment, format_meta_file, format_transcription, overlapping_segments,
    parse_meta_file, parse_transcription, segment_lines,
};
