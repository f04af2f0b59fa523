//! Wires the environments and networks of ntg-rs together, and holds the
//! `ntg` command-line tool.
//!
//! What is here: the `ntg` CLI ([`cli`]); demo datasets generated in
//! parallel and cached on disk ([`dataset`]); joint training of the four NTG
//! networks with checkpoints and exact resume ([`train`]); the block-stacking
//! experiment, evaluation on unseen tasks ([`blocks`]) and step-by-step
//! traces ([`trace`]); success-rate statistics ([`stats`]); the paper's
//! figures as experiment configs ([`reproduce`]), drawn as SVG + PNG
//! ([`figure`]); task graphs rendered to SVG in-process ([`svg`]).
//!
//! **Architecture invariant:** this is the only crate that knows every other
//! crate (environments and networks); no other crate depends on it except
//! `xtask`. Experiments are data (configs) run through one code path, not
//! code copied per figure.

pub mod cli;
pub mod dataset;
pub mod domain;
pub mod evaluate;
pub mod experiment;
pub mod figure;
pub mod fit;
pub mod jigsaws;
pub mod method;
pub mod reproduce;
pub mod run_dir;
pub mod spec;
pub mod stats;
pub mod svg;
pub mod symmetry;
pub mod trace;

pub use domain::{blocks, collect};
