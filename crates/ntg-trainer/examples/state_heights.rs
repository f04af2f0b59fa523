//! The range of heights a block-stacking state encoder reads, on the
//! structure benchmark's sets: the largest gripper-relative cube height
//! `|z|` and the largest height difference between two cubes `|z_i − z_j|`
//! over the expert demos of the first tasks of each set (the training
//! pool's demos are what a run trains on). A height clamp
//! (`StateEncoderConfig::height_clamp`) at or above the training pool's
//! values is the identity on every training state.
//!
//! `cargo run --release -p ntg-trainer --example state_heights -- [TASKS] [DEMOS]`
//! (defaults: 1000 tasks of each set, 20 demos per task, seeded as
//! training seeds them).

use anyhow::Context;
use env_blocks::structure::StructureSet;
use env_blocks::world::NUM_OBJECTS;
use env_blocks::{BlocksTask, EnvConfig};
use ntg_trainer::blocks::{TRAIN_SEED_BASE, task_set_tasks};

fn main() -> anyhow::Result<()> {
    let usage = "usage: state_heights [TASKS] [DEMOS]";
    let args: Vec<String> = std::env::args().skip(1).collect();
    let tasks: usize = args
        .first()
        .map_or(Ok(1000), |t| t.parse())
        .context(usage)?;
    let demos: usize = args.get(1).map_or(Ok(20), |t| t.parse()).context(usage)?;
    let config = EnvConfig::state_only();
    for set in StructureSet::ALL {
        let (mut height, mut difference) = (0.0f32, 0.0f32);
        let (mut rows, mut failed) = (0usize, 0usize);
        for (t, task) in task_set_tasks(set, tasks)?.into_iter().enumerate() {
            let task = BlocksTask::Stack(task);
            for j in 0..demos {
                let seed = TRAIN_SEED_BASE + 1000 * t as u64 + j as u64;
                // The expert's step limit is set for the standard heights:
                // a taller tower's demo may not fit it (counted, skipped).
                let Ok(demo) = env_blocks::expert_demo(&task, config, seed) else {
                    failed += 1;
                    continue;
                };
                for observation in demo.observations() {
                    let s = observation.state();
                    let z: Vec<f32> = (0..NUM_OBJECTS).map(|i| s[3 * i + 2]).collect();
                    for (i, &zi) in z.iter().enumerate() {
                        height = height.max(zi.abs());
                        for &zj in &z[i + 1..] {
                            difference = difference.max((zi - zj).abs());
                        }
                    }
                    rows += 1;
                }
            }
        }
        println!(
            "{}: {tasks} tasks x {demos} demos ({failed} not finished by the expert), {rows} states: max |z| {height:.4}, max |z_i - z_j| {difference:.4}",
            set.name()
        );
    }
    Ok(())
}
