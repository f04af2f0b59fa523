//! Where a block-stacking NTG run's node localizer, reading the frame,
//! departs from the agent's own record of what it did: the first TASKS
//! validation tasks (never test tasks), rolled out as `ntg eval --split
//! validation --variant localizer-node` rolls them out (same seeds, the
//! localizer choosing the node even in a run trained to take it from the
//! record).
//!
//! At every decision the node the localizer finds most likely is compared
//! with the last action the agent executed (`<start>` before the first),
//! the node the executed-node variant would use. Each disagreement is
//! counted by kind: one behind (the action before the last), further
//! behind (an older executed action), ahead (an action not executed yet),
//! and whether the last action had failed in the environment (a slip or an
//! off-centre drop, so the scene still shows the step before). Then, per
//! episode, success with and without a disagreement, and the failed
//! episodes by their first fault and whether the demo was read exactly,
//! then both by the task's tallest tower (a structure-benchmark run's
//! validation set holds towers taller than its training ones).
//!
//! ```text
//! cargo run --release -p ntg-trainer --example localizer_rollouts -- RUN [TASKS]
//! ```

use anyhow::Context;
use ntg_trainer::blocks::{self, BlocksDomain, BlocksRunConfig, Seeds, TrainedBlocks, Variant};
use ntg_trainer::domain::Episode;
use ntg_trainer::method::TrainedPolicy;
use ntg_trainer::run_dir::RunDir;

/// One decision as the example records it.
struct Seen {
    action: String,
    localized: Option<String>,
    /// The agent's explanation (the localizer's two most likely nodes).
    explanation: String,
    /// The environment's failure of this action (its kind), if any.
    failure: Option<String>,
}

fn main() -> anyhow::Result<()> {
    let usage = "usage: localizer_rollouts RUN [TASKS]";
    let args: Vec<String> = std::env::args().skip(1).collect();
    let run = RunDir::open(std::path::Path::new(args.first().context(usage)?))?;
    let count: usize = args.get(1).map_or(Ok(100), |t| t.parse()).context(usage)?;
    let config: BlocksRunConfig = RunDir::read_json(&run.config_path())?;
    let mut model = blocks::load_trained(&run, None, &ntg_model::cpu_device())?;
    let ablation = Variant::LocalizerNode.ablation_of(&model.ntg().config.ablation);
    model.ntg_mut().config.ablation = ablation;
    let policy: &dyn TrainedPolicy = match &model {
        TrainedBlocks::State(m) => m,
        TrainedBlocks::Video(m) => m,
    };
    let policy = policy.for_inference();
    let domain = BlocksDomain::new(config.obs, config.failures).with_camera(config.camera());
    let tasks = blocks::validation_tasks_of(config.task_source(), count)?;

    let mut kinds = Kinds::default();
    let (mut episodes_ok, mut episodes_disagree, mut ok_disagree) = (0usize, 0usize, 0usize);
    let mut first_kinds = Kinds::default();
    // Decisions after each kind of failed action: [agree, disagree].
    let mut after_failure: std::collections::BTreeMap<String, [usize; 2]> =
        std::collections::BTreeMap::new();
    // Failed episodes by the first thing that went wrong in them.
    let mut first_fault: std::collections::BTreeMap<(&'static str, &'static str), usize> =
        std::collections::BTreeMap::new();
    // By the task's tallest tower (cubes): [episodes, successes], and the
    // failed episodes' first faults.
    let mut by_height: std::collections::BTreeMap<usize, [usize; 2]> =
        std::collections::BTreeMap::new();
    let mut fault_by_height: std::collections::BTreeMap<(usize, &'static str), usize> =
        std::collections::BTreeMap::new();
    for (i, task) in tasks.iter().enumerate() {
        let episode = Episode {
            group: 0,
            index: i,
            task: task.clone(),
            demo_seed: Seeds::VALIDATION.demo + i as u64,
            rollout_seed: Seeds::VALIDATION.rollout + i as u64,
        };
        let mut seen = Vec::new();
        let record =
            ntg_trainer::domain::run_episode_observed(&domain, policy.as_ref(), &episode, |d| {
                let localized = d.explanation.as_deref().and_then(|e| {
                    e.strip_prefix("localized ")
                        .and_then(|rest| rest.split(' ').next())
                        .map(str::to_owned)
                });
                seen.push(Seen {
                    explanation: d.explanation.clone().unwrap_or_default(),
                    action: domain_name(d.action),
                    localized,
                    failure: d.step.info.failure.as_ref().map(|f| {
                        let debug = format!("{f:?}");
                        debug
                            .split([' ', '{', '('])
                            .next()
                            .unwrap_or_default()
                            .to_owned()
                    }),
                });
                Ok(())
            })?;
        let mut disagreed = false;
        for t in 0..seen.len() {
            let Some(localized) = seen[t].localized.as_deref() else {
                anyhow::bail!("the agent did not say which node it localized (not an NTG run?)");
            };
            let last = if t == 0 {
                "<start>"
            } else {
                seen[t - 1].action.as_str()
            };
            let last_failure = if t == 0 {
                None
            } else {
                seen[t - 1].failure.as_deref()
            };
            let last_failed = last_failure.is_some();
            if let Some(f) = last_failure {
                let entry = after_failure.entry(f.to_owned()).or_insert([0usize; 2]);
                entry[usize::from(localized != last)] += 1;
            }
            let kind = if localized == last {
                Kind::Agree
            } else if t >= 2 && localized == seen[t - 2].action {
                Kind::OneBehind
            } else if (t == 1 && localized == "<start>")
                || seen[..t.saturating_sub(2)]
                    .iter()
                    .any(|s| s.action == localized)
            {
                Kind::FurtherBehind
            } else {
                Kind::Ahead
            };
            kinds.add(kind, last_failed);
            if kind != Kind::Agree && !disagreed {
                disagreed = true;
                first_kinds.add(kind, last_failed);
            }
        }
        let tallest = task.towers().iter().map(Vec::len).max().unwrap_or(0);
        let entry = by_height.entry(tallest).or_insert([0; 2]);
        entry[0] += 1;
        entry[1] += usize::from(record.success);
        if !record.success {
            *fault_by_height
                .entry((tallest, first_fault_of(&seen)))
                .or_insert(0) += 1;
        }
        if !record.success {
            let exact = if record.transcribed_exactly == Some(true) {
                "demo read exactly"
            } else {
                "demo misread"
            };
            *first_fault
                .entry((first_fault_of(&seen), exact))
                .or_insert(0) += 1;
        }
        episodes_ok += usize::from(record.success);
        episodes_disagree += usize::from(disagreed);
        ok_disagree += usize::from(record.success && disagreed);
        if std::env::var_os("SHOW").is_some() && !record.success {
            println!(
                "{} ({}): demo {}",
                record.task,
                i,
                record.demo_actions.join(" ")
            );
            for (t, s) in seen.iter().enumerate() {
                println!(
                    "  {t:2} {:<40} -> {:<10}{}",
                    s.explanation,
                    s.action,
                    s.failure
                        .as_deref()
                        .map(|f| format!(" ({f})"))
                        .unwrap_or_default()
                );
            }
        }
    }
    println!(
        "{} validation tasks of {}",
        tasks.len(),
        run.root().display()
    );
    println!(
        "success {}/{} = {:.3}; episodes with a disagreement {} (success {}), without {} (success {})",
        episodes_ok,
        tasks.len(),
        episodes_ok as f64 / tasks.len() as f64,
        episodes_disagree,
        ok_disagree,
        tasks.len() - episodes_disagree,
        episodes_ok - ok_disagree
    );
    println!("\ndecisions (after a failed action / otherwise):");
    kinds.print();
    println!("\ndecisions after a failed action, by its failure (agree / disagree):");
    for (failure, [agree, disagree]) in &after_failure {
        println!("  {failure:<15} {agree:6} / {disagree:6}");
    }
    println!("\nfirst disagreement of each episode:");
    first_kinds.print();
    println!("\nfailed episodes by their first fault:");
    for ((fault, exact), n) in &first_fault {
        println!("  {fault:<45} {exact:<18} {n:4}");
    }
    println!(
        "\nby the task's tallest tower (cubes): success, then failed episodes by first fault:"
    );
    for (height, [episodes, ok]) in &by_height {
        println!("  {height}: {ok}/{episodes}");
        for ((h, fault), n) in &fault_by_height {
            if h == height {
                println!("      {fault:<45} {n:4}");
            }
        }
    }
    Ok(())
}

/// The first thing that went wrong in a failed episode: the localizer
/// disagreeing with the record, or (while it agreed) an action the
/// environment refused, or `<end>` chosen too early; otherwise the
/// episode ran into the step limit after only slips and missed drops.
fn first_fault_of(seen: &[Seen]) -> &'static str {
    for (t, s) in seen.iter().enumerate() {
        let last = if t == 0 {
            "<start>"
        } else {
            seen[t - 1].action.as_str()
        };
        if s.localized.as_deref() != Some(last) {
            let after_refused = t > 0
                && seen[t - 1]
                    .failure
                    .as_deref()
                    .is_some_and(|f| f != "Slipped" && f != "Missed");
            return if after_refused {
                "localizer, after an action the env refused"
            } else if t > 0 && seen[t - 1].failure.is_some() {
                "localizer, after a slip or missed drop"
            } else {
                "localizer, after a successful action"
            };
        }
        if s.failure
            .as_deref()
            .is_some_and(|f| f != "Slipped" && f != "Missed")
        {
            return "an action the env refused (localizer right)";
        }
        if s.action == "<end>" {
            return "<end> too early (localizer right)";
        }
    }
    "step limit (localizer right throughout)"
}

fn domain_name(action: ctg_graph::ActionId) -> String {
    env_blocks::vocabulary(false, env_blocks::ActionLevel::Flat)
        .name(action)
        .unwrap_or("?")
        .to_owned()
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Kind {
    Agree,
    OneBehind,
    FurtherBehind,
    Ahead,
}

/// Counts per kind, after a failed action and otherwise.
#[derive(Default)]
struct Kinds([[usize; 2]; 4]);

impl Kinds {
    fn add(&mut self, kind: Kind, after_failure: bool) {
        self.0[kind as usize][usize::from(!after_failure)] += 1;
    }
    fn print(&self) {
        let names = ["agree", "one behind", "further behind", "ahead"];
        for (name, [failed, ok]) in names.iter().zip(self.0) {
            println!("  {name:<15} {failed:6} / {ok:6}");
        }
    }
}
