//! Wires the environments and networks of ntg-rs together, and holds the
//! `ntg` command-line tool.
//!
//! Built so far: the `ntg` CLI ([`cli`]) with `ntg graph`, which builds the
//! union conjugate task graph of demonstrated action sequences. Dataset
//! building, training, evaluation and figures come with the trainer issue.
//!
//! **Architecture invariant:** this is the only crate that knows every other
//! crate (environments and networks); no other crate depends on it except
//! `xtask`. Experiments are data (configs) run through one code path, not
//! code copied per figure.

pub mod cli;
