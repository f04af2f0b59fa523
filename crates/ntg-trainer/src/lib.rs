//! The `ntg` application: wires the environments of this repository and the
//! training library (ntg-train) together, and holds the `ntg` command-line
//! tool.
//!
//! What is here, in layers (each module uses only those above it):
//! - ntg-train's modules, re-exported under their own names ([`fit`],
//!   [`dataset`], [`run_dir`], [`stats`], [`symmetry`], [`video`],
//!   [`evaluate`], [`provenance`], [`events`]); [`spec`] adds profiles, the device and
//!   the command line's parsers to ntg-train's;
//! - [`method`]: ntg-train's methods (NTG, the Flat Policy) and this
//!   repository's block-stacking baselines (NTP, NTP Flat, NTP
//!   (Detector)), in one registry;
//! - [`domain`]: this repository's domains, one file each (block stacking,
//!   object collection, object sorting) behind ntg-train's `Domain` trait;
//!   [`jigsaws`]: the JIGSAWS cross-task experiment, scored by NLL;
//!   [`export`]: a trained run's weights as safetensors for PyTorch
//!   (`ntg export`, and the model zoo's entries); [`lerobot`]: demos and
//!   rollouts as datasets in LeRobot's layout (`ntg blocks demos`, `ntg
//!   trace`);
//! - [`experiment`]: the paper's figures as experiment files
//!   (`experiments/*.toml`), run and drawn ([`figure`], [`svg`]), and a
//!   run's training curves ([`curves`], `ntg plot`);
//!   [`reproduce`] runs them all, [`slurm`] as job arrays; [`record`] keeps the paper profile's
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

pub mod allocator;
pub mod block_world;
pub mod carry;
pub mod cli;
pub mod curves;
pub mod domain;
pub mod experiment;
pub mod export;
pub mod figure;
pub mod jigsaws;
pub mod lerobot;
pub mod method;
pub mod record;
pub mod reproduce;
pub mod slurm;
pub mod spec;
pub mod svg;
pub mod trace;

pub use ntg_train::{dataset, evaluate, events, fit, provenance, run_dir, stats, symmetry, video};

pub use domain::{blocks, collect};
