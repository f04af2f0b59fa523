//! Wires the environments and networks of ntg-rs together, and holds the
//! `ntg` command-line tool.
//!
//! What is here, in layers (each module uses only those above it):
//! - [`spec`] (observation kinds, profiles), [`run_dir`] (run folders),
//!   [`dataset`] (demo datasets generated in parallel and cached on disk),
//!   [`stats`], [`symmetry`] (object renaming);
//! - [`fit`]: the one epoch loop (checkpoints, exact resume, validation
//!   and best-epoch selection) that every method trains through;
//! - [`method`]: methods, one file each (NTG, the Flat Policy): a training
//!   step and a model that can be conditioned on a demo; [`video`]: NTG
//!   from demo videos, trained in stages (the shared frame encoder on
//!   single frames, then the rest on its cached embeddings);
//! - [`domain`]: domains, one file each (block stacking, object
//!   collection) behind one trait, and the one evaluation loop;
//!   [`jigsaws`]: the JIGSAWS cross-task experiment, scored by NLL;
//! - [`experiment`]: the paper's figures as experiment files
//!   (`experiments/*.toml`), run and drawn ([`figure`], [`svg`]);
//!   [`reproduce`] runs them all; [`record`] keeps the paper profile's
//!   finished runs as small committed records and [`carry`] its unfinished
//!   ones carried between machines; [`trace`] executes one test task step
//!   by step;
//! - [`cli`]: the `ntg` command line, which parses arguments into run
//!   configurations and calls the library.
//!
//! **Architecture invariant:** this is the only crate that knows every other
//! crate (environments and networks); no other crate depends on it except
//! `xtask`. Experiments are data (configs) run through one code path, not
//! code copied per figure.

pub mod carry;
pub mod cli;
pub mod dataset;
pub mod domain;
pub mod evaluate;
pub mod experiment;
pub mod figure;
pub mod fit;
pub mod jigsaws;
pub mod method;
pub mod record;
pub mod reproduce;
pub mod run_dir;
pub mod spec;
pub mod stats;
pub mod svg;
pub mod symmetry;
pub mod trace;
pub mod video;

pub use domain::{blocks, collect};
