//! The integration tests of `env-collect`, the object-collection environment: actions, demos, demo videos: one test binary
//! for the crate (one module per former test file), so that a test
//! build links the crate and its dependencies once, not once per file.
//! `cargo test -p env-collect --test integration MODULE::` runs one module.

mod actions;
mod demos;
mod video;
