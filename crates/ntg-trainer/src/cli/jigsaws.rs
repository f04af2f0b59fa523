//! `ntg jigsaws ...`: the env-jigsaws commands.
//!
//! Not built yet: every subcommand here reports that it is unavailable and
//! exits non-zero.

use clap::Subcommand;

/// Subcommands of `ntg jigsaws`.
#[derive(Debug, Subcommand)]
pub enum JigsawsCommand {
    /// Not available yet.
    Unavailable,
}

/// Runs an `ntg jigsaws` subcommand.
pub fn run(_command: JigsawsCommand) -> anyhow::Result<()> {
    anyhow::bail!("`ntg jigsaws` is not available yet (env-jigsaws is not built)")
}
