//! Wires the environments and networks of ntg-rs together, and holds the
//! `ntg` command-line tool.
//!
//! Built so far: the `ntg` CLI ([`cli`]) with `ntg graph`, which builds the
//! union conjugate task graph of demonstrated action sequences; success-rate
//! statistics ([`stats`]); figures as SVG + PNG ([`figure`]); task graphs
//! rendered to SVG in-process ([`svg`]). Dataset building, training and
//! evaluation come with the trainer issue.
//!
//! **Architecture invariant:** this is the only crate that knows every other
//! crate (environments and networks); no other crate depends on it except
//! `xtask`. Experiments are data (configs) run through one code path, not
//! code copied per figure.

pub mod blocks;
pub mod cli;
pub mod collect;
pub mod dataset;
pub mod figure;
pub mod reproduce;
pub mod run_dir;
pub mod stats;
pub mod svg;
pub mod train;
