//! The integration tests of `ntg-trainer`, the trainer end to end: the `ntg` CLI, resumption, the smoke and video learning tests: one test binary
//! for the crate (one module per former test file), so that a test
//! build links the crate and its dependencies once, not once per file.
//! `cargo test -p ntg-trainer --test integration MODULE::` runs one module.

mod bad_inputs;
mod cli_baselines;
mod cli_graph;
mod cli_sorting;
mod cli_trace;
mod cluster;
mod common;
mod export;
mod lerobot;
mod module_cycles;
mod resume;
mod smoke;
mod task_file;
mod train_extras;
mod video;
mod watch;
