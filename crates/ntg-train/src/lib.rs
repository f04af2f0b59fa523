//! The training library of ntg-rs: what it takes to train Neural Task
//! Graphs (and the Flat Policy baseline) on a domain of one's own, and to
//! evaluate it on tasks it never trained on.
//!
//! What is here, in layers (each module uses only those above it):
//! - [`spec`] (observation kinds, named settings), [`run_dir`] (run
//!   folders), [`provenance`] (where each stretch of training ran),
//!   [`dataset`] (demo datasets generated in parallel and cached on disk),
//!   [`events`] (the training log as TensorBoard event files),
//!   [`stats`], [`symmetry`] (object renaming), [`evaluate`] (parallel
//!   loops with a progress bar);
//! - [`fit`]: the one epoch loop (checkpoints, exact resume, validation and
//!   best-epoch selection) that every method trains through;
//! - [`method`]: methods, one file each (NTG, the Flat Policy): a training
//!   step and a model that can be conditioned on a demo; [`video`]: a
//!   method from demo videos, trained in stages (the shared frame encoder
//!   on single frames, then the rest on its cached embeddings);
//! - [`domain`]: the [`Domain`] trait a domain implements over ctg-graph's
//!   `Environment` and `Expert`, [`record_demos`] and the one evaluation
//!   loop, [`evaluate`](domain::evaluate).
//!
//! **Architecture invariant:** this crate depends on `ctg-graph`,
//! `ntg-model` and small crates only: no environment crate, no command-line
//! parser, no plotting library, no allocator (`cargo tree -p ntg-train -e
//! normal` shows it). It parses no command line and reads no process-wide
//! device: every function that builds networks takes its device.

pub mod dataset;
pub mod domain;
pub mod evaluate;
pub mod events;
pub mod fit;
pub mod method;
pub mod provenance;
pub mod run_dir;
pub mod spec;
pub mod stats;
pub mod symmetry;
pub mod video;

pub use domain::{Domain, Episode, EpisodeRecord, RowDomain, record_demos};
pub use spec::ObsKind;

/// The error type every fallible function of the library returns: a user's
/// [`Domain`] names it as `ntg_train::anyhow::Result`.
pub use anyhow;
