//! The integration tests of `env-blocks`, the block-stacking environment: simulator, renderer, task sets, demo videos, world invariants: one test binary
//! for the crate (one module per former test file), so that a test
//! build links the crate and its dependencies once, not once per file.
//! `cargo test -p env-blocks --test integration MODULE::` runs one module.

mod env;
mod render;
mod tasks;
mod video;
mod world;
