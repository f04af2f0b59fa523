//! Block stacking and object sorting: the world, tasks, expert and renderer
//! of the paper's main experiment (after NTP's block-stacking environment).
//!
//! - [`world`]: eight 5 cm cubes, bins and a gripper; NTP's primitives
//!   `move(i)`, `grasp`, `drop` with kinematic, support-aware physics
//!   (parry3d shape casts) and optional stochastic failures;
//! - [`render`]: deterministic 64×64 ray-cast frames from a fixed camera;
//! - [`task`]: NTP's task-file format, statistics, the seeded generator and
//!   the standard split (`datasets/blocks/`);
//! - [`structure`]: the structure benchmark: training, validation and test
//!   structures that share none, and taller towers than any trained on;
//! - [`sorting`]: object-sorting tasks (4 categories into 4 bins);
//! - [`env`](mod@env): [`BlocksEnv`], a `ctg_graph::Environment` at the flat level
//!   (`pick(X)`, `place(Y)`) or NTP's primitive level;
//! - [`expert`]: the scripted [`BlocksExpert`], NTP's hierarchical trace,
//!   rich demos and parallel demo generation;
//! - [`ntp`]: NTP's demonstrations, the expert's primitive-level episode
//!   with its program call tree (the baselines' training signal);
//! - [`video`]: demonstration videos, the expert's demo rendered along each
//!   primitive's motion (several frames per flat action, seeded lengths);
//! - [`sheet`]: contact sheets of frames and of videos.
//!
//! Must never depend on `ntg-model`, burn, or another environment crate.

pub mod env;
pub mod error;
pub mod expert;
pub mod ntp;
pub mod render;
pub mod sheet;
pub mod sorting;
pub mod structure;
pub mod task;
pub mod video;
pub mod world;

pub use env::{
    ActionLevel, BlocksAction, BlocksEnv, BlocksInfo, BlocksObservation, BlocksTask, EnvConfig,
    PrimitiveEvent, action_name, vocabulary,
};
pub use error::BlocksError;
pub use expert::{
    BlocksExpert, ReplayStats, RichDemo, StepRecord, TraceNode, expert_demo, expert_success,
    generate_demos, generate_demos_sequential, record_rich_demo,
};
pub use ntp::{NtpCall, NtpDemo, NtpProgram, record_ntp_demo};
pub use render::{Camera, FRAME_SIZE, Framing, Renderer};
pub use sorting::{SortTask, generate_sort_tasks, standard_sort_tasks};
pub use task::{
    Goal, STRUCTURE_SEED, StackTask, StandardSplit, TRAIN_POOL, TaskStats, cube_letter,
    generate_stack_tasks, parse_ntp_tasks, read_ntp_tasks, standard_split, standard_tasks,
    structure_test_tasks, validation_tasks, validation_tasks_avoiding, write_ntp_tasks,
};
pub use video::{
    FrameRange, VideoConfig, generate_video_demos, record_video_demo, video_segment_lengths,
};
pub use world::{Failure, FailureConfig, Outcome, Primitive, Support, Target, World};

/// Length of the state vector: 8 cubes × xyz relative to the gripper, plus
/// the gripper's open/closed one-hot.
pub const STATE_DIM: usize = 3 * world::NUM_OBJECTS + 2;
