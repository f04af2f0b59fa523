//! Object Collection: a partially observed search-and-collect world with
//! rendered 64×64 frames, the stand-in for the paper's AI2-THOR experiment.
//!
//! A [`Task`] is N ∈ [1, 6] target objects of distinct categories out of
//! C = 8 ([`Category`]), each with its designated drop-off receptacle among
//! K = 5 ([`Receptacle`]). Each episode (`reset(seed)` of [`CollectEnv`]) builds a
//! fresh scene from its seed: M = N + 3 search locations visited in a random
//! order, the targets hidden at distinct locations and 1–3 distractor
//! objects (non-target categories) anywhere, every object with its own
//! position, size, tint and shape variant, every place with its own tint and
//! texture phase. Actions ([`Action`], vocabulary [`vocabulary`]):
//!
//! - `search`: go to the next search location (cyclically);
//! - `pickup(category)`: fails (reported in [`CollectInfo::failure`], not an
//!   error) unless such an object is visible at the current place and the
//!   hand is empty;
//! - `dropoff(receptacle)`: go to the receptacle and put the held object in
//!   it (fails, after going there, if the hand is empty).
//!
//! Success: every target is in its designated receptacle when the episode
//! ends (by `<end>` or by the step limit). The agent sees only the current
//! place ([`CollectObservation`]): a frame with the objects there and a
//! "hand" inset showing what it holds, plus a symbolic state vector with the
//! same information ([`state_layout`]). [`CollectExpert`] searches until a
//! target is visible, picks it up, drops it off, and repeats;
//! [`generate_demos`] records many demonstrations in parallel (rayon), equal
//! to [`generate_demos_sequential`]. [`TaskSplitter`] splits all tasks into
//! disjoint train and test sets by task identity; [`export::write_demo`]
//! writes a demonstration as JSON, PNG frames and a contact sheet
//! (`ntg collect demo --objects 4 --seed 3 --out DIR` wrote
//! `docs/collect-contact-sheet.png`). [`frame_to_chw`] turns a frame into the
//! CHW `[0, 1]` features the frame encoder reads.
//!
//! [`video`] records demonstrations as videos
//! ([`ctg_graph::VideoDemonstration`]): several frames per action, of
//! seeded, varying number ([`VideoConfig`]), showing the motion (walking
//! pans, the arm reaching, the object lifting into the hand, the receptacle
//! opening and the object dropping in), each action's segment ending on the
//! very frame the environment observes ([`record_video_demo`],
//! [`VideoRecorder`] for any rollout, [`generate_video_demos`] in parallel;
//! [`export::video_contact_sheet`] draws one).
//!
//! Speed (criterion, `cargo bench -p env-collect`): see `benches/collect.rs`.
//!
//! **Architecture invariant:** depends on `ctg-graph`, `image`, `rand`,
//! `rayon`, `serde` and small utility crates only. It must never depend on
//! `ntg-model`, burn, or another environment crate.
//!
//! ```
//! use ctg_graph::record_demonstration;
//! use env_collect::{CollectConfig, CollectEnv, CollectExpert, TaskSplitter};
//! use rand::SeedableRng;
//!
//! let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(1);
//! let task = TaskSplitter::default().sample(2, None, &mut rng).unwrap();
//! let mut env = CollectEnv::new(task, CollectConfig::default()).unwrap();
//! let demo = record_demonstration(&mut env, &mut CollectExpert, 7).unwrap();
//! assert!(demo.len() >= 6); // at least search, pickup, dropoff per object
//! let frame = demo.observations()[0].frame.as_ref().unwrap();
//! assert_eq!(frame.dimensions(), (64, 64));
//! ```

pub mod domain;
mod env;
mod expert;
pub mod export;
mod generate;
pub mod render;
mod task;
pub mod video;

pub use domain::{Action, Category, Receptacle, Surface, vocabulary};
pub use env::{
    CollectConfig, CollectEnv, CollectInfo, CollectObservation, FRAME_DIM, Failure, Place,
    STATE_LEN, Scene, SceneLocation, SceneObject, frame_to_chw, state_layout,
};
pub use expert::CollectExpert;
pub use generate::{
    DemoJob, generate_demos, generate_demos_sequential, jobs_for_tasks, record_demo,
};
pub use task::{Split, Target, Task, TaskSplitter};
pub use video::{FrameRange, VideoConfig, VideoRecorder, generate_video_demos, record_video_demo};

/// Errors of this crate (environment-protocol errors are
/// [`ctg_graph::CtgError`], wrapped here where they meet the others).
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum CollectError {
    /// A task that breaks the rules (1–5 targets, distinct categories).
    #[error("invalid task: {0}")]
    InvalidTask(String),
    /// A configuration value out of range.
    #[error("invalid configuration: {0}")]
    InvalidConfig(String),
    /// An environment, expert or demonstration error.
    #[error(transparent)]
    Ctg(#[from] ctg_graph::CtgError),
    /// A file could not be written.
    #[error("{path}: {source}")]
    Io {
        /// The file or folder.
        path: std::path::PathBuf,
        /// What went wrong.
        source: std::io::Error,
    },
    /// A PNG could not be encoded or written.
    #[error("{path}: {source}")]
    Image {
        /// The file.
        path: std::path::PathBuf,
        /// What went wrong.
        source: image::ImageError,
    },
    /// JSON could not be encoded.
    #[error("json: {0}")]
    Json(#[from] serde_json::Error),
}

/// SplitMix64: a fast, well-mixed 64-bit hash, used to derive seeds and
/// texture noise deterministically.
pub(crate) fn splitmix64(x: u64) -> u64 {
    let mut z = x.wrapping_add(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}
