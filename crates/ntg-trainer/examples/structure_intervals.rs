//! Success of structure-benchmark evaluations per structure, with the
//! two-level bootstrap interval over structures and tasks
//! (`ntg_train::stats::clustered_bootstrap`, 10,000 resamples, seed 0).
//! Each argument is an `ntg eval` result file of a run on `--task-set
//! structure` (`eval/full-N.json` for the test structures,
//! `eval/taller-full-N.json` for the taller ones, `eval/validation-…`);
//! several files of one split (one per seed, on the same tasks) are
//! averaged.
//!
//! ```text
//! cargo run --release -p ntg-trainer --example structure_intervals -- FILE [FILE ...]
//! ```

use anyhow::{Context, ensure};
use env_blocks::structure::StructureSet;
use ntg_trainer::blocks::{EvalResult, outcomes_by_structure};

fn main() -> anyhow::Result<()> {
    let files: Vec<String> = std::env::args().skip(1).collect();
    ensure!(
        !files.is_empty(),
        "usage: structure_intervals FILE [FILE ...]"
    );
    // outcomes[seed][structure][task], structures in key order.
    let mut outcomes: Vec<Vec<Vec<bool>>> = Vec::new();
    let mut names: Vec<String> = Vec::new();
    for file in &files {
        let text = std::fs::read_to_string(file).with_context(|| format!("reading {file}"))?;
        let eval: EvalResult =
            serde_json::from_str(&text).with_context(|| format!("parsing {file}"))?;
        let first = eval
            .tasks
            .first()
            .map(|r| r.task.as_str())
            .with_context(|| format!("{file}: no task"))?;
        let set = StructureSet::ALL
            .into_iter()
            .find(|s| first.starts_with(&format!("{}_", s.name())))
            .with_context(|| format!("{file}: {first} is not a structure-benchmark task"))?;
        let grouped = outcomes_by_structure(set, &eval.tasks).with_context(|| file.clone())?;
        if names.is_empty() {
            names = grouped.iter().map(|(towers, _)| towers.clone()).collect();
        }
        outcomes.push(grouped.into_iter().map(|(_, o)| o).collect());
    }
    let rate =
        ntg_train::stats::clustered_bootstrap(&outcomes, 10_000, 0).map_err(anyhow::Error::msg)?;
    println!(
        "{} files: success {:.3} (two-level bootstrap 95%: {:.3}-{:.3}) over {} structures, {} tasks",
        files.len(),
        rate.rate,
        rate.ci_low,
        rate.ci_high,
        rate.clusters,
        rate.tasks
    );
    for (i, name) in names.iter().enumerate() {
        let (ok, n) = outcomes.iter().fold((0, 0), |(ok, n), seed| {
            (
                ok + seed[i].iter().filter(|&&s| s).count(),
                n + seed[i].len(),
            )
        });
        println!(
            "  towers of {name} cubes: {ok}/{n} = {:.3}",
            ok as f64 / n as f64
        );
    }
    Ok(())
}
