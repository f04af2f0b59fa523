//! The integration tests of `env-jigsaws`, the JIGSAWS dataset reader: malformed input, the miniature copy, properties, synthetic data: one test binary
//! for the crate (one module per former test file), so that a test
//! build links the crate and its dependencies once, not once per file.
//! `cargo test -p env-jigsaws --test integration MODULE::` runs one module.

mod malformed;
mod miniature;
mod properties;
mod synthetic;
