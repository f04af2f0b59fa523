//! The JIGSAWS surgical dataset: reader, synthetic stand-in, NTG observations.
//!
//! **Not built yet.** See `docs/ARCHITECTURE.md`. Nothing here works yet.
//!
//! Must never depend on `ntg-model`, burn, or another environment crate.
