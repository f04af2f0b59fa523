//! An object-collection run's validation episodes, scored per number of
//! objects: success, goals met and the demos its interpreter transcribed
//! exactly, for the run's selected epoch (else its last). These are the
//! held-out train-side tasks the run validated on (`validation_tasks_per_n`
//! per N of its training numbers and of its `validation_objects`), never
//! test episodes, so designs can be compared on them, on N = 6 too.
//!
//! With `SHOW_FAILED=K` it also prints the first K failed episodes of each
//! N: the demo's actions, the interpreter's transcription and the actions
//! the policy executed, and counts the failures by how they ended (`<end>`
//! chosen with goals left, or the step limit).
//!
//! ```text
//! cargo run --release -p ntg-trainer --example collect_validation -- RUN
//! ```

use anyhow::Context;
use ntg_trainer::collect::{CollectDomain, CollectRunConfig, load_model, validation_episodes};
use ntg_trainer::run_dir::RunDir;

fn main() -> anyhow::Result<()> {
    let usage = "usage: collect_validation RUN";
    let args: Vec<String> = std::env::args().skip(1).collect();
    let run = RunDir::open(std::path::Path::new(args.first().context(usage)?))?;
    let config: CollectRunConfig = RunDir::read_json(&run.config_path())?;
    let episodes = validation_episodes(&config)?;
    anyhow::ensure!(
        !episodes.is_empty(),
        "{} has no validation episodes (validation_tasks_per_n is 0)",
        run.root().display()
    );
    let model = load_model(&run, &config)?;
    let domain = CollectDomain::for_run(&config);
    let records = ntg_train::domain::evaluate(&domain, model.as_ref(), &episodes)?;
    let mut groups: Vec<usize> = records.iter().map(|r| r.group).collect();
    groups.sort_unstable();
    groups.dedup();
    println!("N | episodes | success | goals met | transcribed exactly");
    let show: usize = std::env::var("SHOW_FAILED")
        .ok()
        .map(|k| k.parse())
        .transpose()
        .context("SHOW_FAILED must be a number of episodes")?
        .unwrap_or(0);
    for &n in &groups {
        let failed: Vec<_> = records
            .iter()
            .filter(|r| r.group == n && !r.success)
            .collect();
        if show == 0 || failed.is_empty() {
            continue;
        }
        let ended = failed
            .iter()
            .filter(|r| {
                r.trace
                    .last()
                    .is_some_and(|a| a == ctg_graph::Vocabulary::END_NAME)
            })
            .count();
        println!(
            "N = {n}: {} failed, {ended} by `<end>` with goals left, {} at the step limit",
            failed.len(),
            failed.len() - ended
        );
        for r in failed.iter().take(show) {
            println!(
                "  goals {}/{}\n    demo    {}\n    read    {}\n    did     {}",
                r.goals_met,
                r.goals,
                r.demo_actions.join(" "),
                r.transcription.join(" "),
                r.trace.join(" ")
            );
        }
    }
    for n in groups {
        let of_n: Vec<_> = records.iter().filter(|r| r.group == n).cloned().collect();
        let success = ntg_train::domain::success_rate(&of_n);
        let goals = ntg_train::domain::mean_goal_fraction(&of_n);
        let exact: Vec<bool> = of_n
            .iter()
            .filter_map(|r| r.transcription_exact())
            .collect();
        println!(
            "{n} | {} | {:.3} | {goals:.3} | {}/{}",
            of_n.len(),
            success.rate,
            exact.iter().filter(|&&x| x).count(),
            exact.len()
        );
    }
    Ok(())
}
