//! `ntg blocks ...`: the env-blocks commands.
//!
//! Not built yet: every subcommand here reports that it is unavailable and
//! exits non-zero.

use clap::Subcommand;

/// Subcommands of `ntg blocks`.
#[derive(Debug, Subcommand)]
pub enum BlocksCommand {
    /// Not available yet.
    Unavailable,
}

/// Runs an `ntg blocks` subcommand.
pub fn run(_command: BlocksCommand) -> anyhow::Result<()> {
    anyhow::bail!("`ntg blocks` is not available yet (env-blocks is not built)")
}
