//! Object collection: a partially observed search-and-collect world.
//!
//! **Not built yet.** See `docs/ARCHITECTURE.md`. Nothing here works yet.
//!
//! Must never depend on `ntg-model`, burn, or another environment crate.
