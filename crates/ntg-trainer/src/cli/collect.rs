//! `ntg collect ...`: the env-collect commands.
//!
//! Not built yet: every subcommand here reports that it is unavailable and
//! exits non-zero.

use clap::Subcommand;

/// Subcommands of `ntg collect`.
#[derive(Debug, Subcommand)]
pub enum CollectCommand {
    /// Not available yet.
    Unavailable,
}

/// Runs an `ntg collect` subcommand.
pub fn run(_command: CollectCommand) -> anyhow::Result<()> {
    anyhow::bail!("`ntg collect` is not available yet (env-collect is not built)")
}
