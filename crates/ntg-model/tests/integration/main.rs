//! The integration tests of `ntg-model`, the networks: learning at small scale and the PyTorch twin cross-check: one test binary
//! for the crate (one module per former test file), so that a test
//! build links the crate and its dependencies once, not once per file.
//! `cargo test -p ntg-model --test integration MODULE::` runs one module.

mod learning;
mod pytorch_twin;
