//! `ntg plot`: a run's training curves as a PNG (see [`crate::curves`]).

use std::path::PathBuf;

use clap::Args;

/// Arguments of `ntg plot`.
#[derive(Debug, Args)]
pub struct PlotArgs {
    /// The run folder (`ntg train --out`, a paper-profile run).
    #[arg(value_name = "RUN")]
    pub run: PathBuf,
    /// The PNG to write (an SVG is written beside it). Default:
    /// `RUN/curves.png`, redrawn on every call; a file given here that
    /// exists is replaced only with --force.
    #[arg(long, value_name = "FILE")]
    pub out: Option<PathBuf>,
    /// Replace an existing --out file.
    #[arg(long, requires = "out")]
    pub force: bool,
}

/// Runs `ntg plot`.
pub fn run(args: &PlotArgs) -> anyhow::Result<()> {
    let png = match &args.out {
        Some(out) => {
            if out.extension().is_none_or(|e| e != "png") {
                anyhow::bail!("--out {}: give a file name ending in .png", out.display());
            }
            if out.exists() && !args.force {
                anyhow::bail!(
                    "--out {}: exists; pass --force to replace it, or choose another file",
                    out.display()
                );
            }
            out.clone()
        }
        None => args.run.join("curves.png"),
    };
    let panels = crate::curves::plot_run(&args.run, &png)?;
    println!(
        "{} panels of training curves written to {} (and {})",
        panels,
        png.display(),
        png.with_extension("svg").display()
    );
    Ok(())
}
