//! Block stacking and object sorting: the world, tasks, expert and renderer.
//!
//! **Not built yet.** See `docs/ARCHITECTURE.md`. Nothing here works yet.
//!
//! Must never depend on `ntg-model`, burn, or another environment crate.
