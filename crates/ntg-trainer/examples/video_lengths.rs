//! How long demo videos are: the distribution of frames per flat action,
//! and how much the videos of one task differ, for block stacking and
//! object collection with their default `VideoConfig`s, recorded exactly
//! as `ntg train --obs vid` records its training videos (same task splits,
//! same seeds, failures on).
//!
//! `cargo run --release -p ntg-trainer --example video_lengths -- [TASKS] [DEMOS]`
//! (default 50 tasks per domain, 5 demos each).

use anyhow::Context;
use ntg_trainer::blocks;
use ntg_trainer::collect::{self, CollectRunConfig};
use ntg_trainer::method::MethodId;
use ntg_trainer::spec::ObsKind;

/// Frames per action (the start segment left out) and video lengths of
/// `demos` videos of each of `tasks` tasks, per task.
fn summarise(name: &str, per_task: &[Vec<ctg_graph::VideoDemonstration<()>>]) {
    let mut per_action: Vec<usize> = per_task
        .iter()
        .flatten()
        .flat_map(|v| v.segment_lengths().into_iter().skip(1))
        .collect();
    per_action.sort_unstable();
    let quantile = |q: f64| per_action[((per_action.len() - 1) as f64 * q).round() as usize];
    let mut histogram = std::collections::BTreeMap::<usize, usize>::new();
    for &n in &per_action {
        *histogram.entry(n).or_default() += 1;
    }
    let varying = per_task
        .iter()
        .filter(|videos| {
            let lengths: std::collections::BTreeSet<usize> =
                videos.iter().map(|v| v.num_frames()).collect();
            lengths.len() > 1
        })
        .count();
    let spread: Vec<usize> = per_task
        .iter()
        .map(|videos| {
            let lengths = videos.iter().map(|v| v.num_frames());
            lengths.clone().max().unwrap_or(0) - lengths.min().unwrap_or(0)
        })
        .collect();
    println!(
        "{name}: {} videos, {} actions",
        per_task.iter().map(Vec::len).sum::<usize>(),
        per_action.len()
    );
    println!(
        "  frames per flat action: min {} | quartiles {} / {} / {} | max {}",
        per_action[0],
        quantile(0.25),
        quantile(0.5),
        quantile(0.75),
        per_action[per_action.len() - 1]
    );
    let shares: Vec<String> = histogram
        .iter()
        .map(|(n, c)| format!("{n}: {:.1}%", 100.0 * *c as f64 / per_action.len() as f64))
        .collect();
    println!("  histogram: {}", shares.join(", "));
    println!(
        "  tasks whose videos differ in length: {varying}/{} (longest minus shortest video of a task: median {} frames, max {})",
        per_task.len(),
        {
            let mut s = spread.clone();
            s.sort_unstable();
            s[s.len() / 2]
        },
        spread.iter().max().copied().unwrap_or(0)
    );
}

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let arg = |i: usize, default: usize| -> anyhow::Result<usize> {
        args.get(i).map_or(Ok(default), |v| {
            v.parse().with_context(|| format!("{v:?} is not a count"))
        })
    };
    let (tasks, demos) = (arg(0, 50)?, arg(1, 5)?);
    anyhow::ensure!(tasks > 0 && demos > 0, "TASKS and DEMOS must be positive");

    let frames = env_blocks::VideoConfig::default();
    let split = env_blocks::standard_split()?;
    let stack = split.train(tasks)?;
    let per_task = stack
        .iter()
        .enumerate()
        .map(|(t, task)| {
            (0..demos)
                .map(|j| {
                    let seed = blocks::TRAIN_SEED_BASE + 1000 * t as u64 + j as u64;
                    Ok(blocks::record_video(
                        task.clone(),
                        true,
                        env_blocks::Camera::default(),
                        &frames,
                        seed,
                    )?
                    .map_frames(|_| ()))
                })
                .collect::<anyhow::Result<Vec<_>>>()
        })
        .collect::<anyhow::Result<Vec<_>>>()?;
    summarise("block stacking", &per_task);

    let config = CollectRunConfig::new(MethodId::Ntg, ObsKind::Vid, vec![2, 4], tasks, demos, 1, 0);
    let video = config.video.clone().context("collect video settings")?;
    let per_task = collect::training_tasks(&config)?
        .into_iter()
        .enumerate()
        .map(|(t, task)| {
            (0..demos)
                .map(|j| {
                    let seed = collect::TRAIN_SEED_BASE + 1000 * t as u64 + j as u64;
                    let v = env_collect::record_video_demo(
                        task.clone(),
                        collect::env_config(ObsKind::Vid),
                        seed,
                        &video.frames,
                    )?;
                    Ok(v.map_frames(|_| ()))
                })
                .collect::<anyhow::Result<Vec<_>>>()
        })
        .collect::<anyhow::Result<Vec<_>>>()?;
    summarise("object collection (N = 2, 4)", &per_task);
    Ok(())
}
