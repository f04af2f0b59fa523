//! The Neural Task Graph networks, in burn 0.22.
//!
//! **Not built yet.** This crate will hold the observation encoders, the
//! `DemoInterpreter`, the `GraphCompletionNet`, the `NodeLocalizer`, the
//! `EdgeClassifier` and the `NtgPolicy` that plugs them into
//! `ctg_graph`'s executor (see `docs/ARCHITECTURE.md`). Nothing here works yet.
//!
//! Must never depend on an environment crate: it sees observations as tensors.
