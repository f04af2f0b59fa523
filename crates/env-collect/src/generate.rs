//! Recording expert demonstrations, one at a time or in parallel.

use ctg_graph::{Demonstration, record_demonstration};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::env::{CollectConfig, CollectEnv, CollectObservation};
use crate::{CollectError, CollectExpert, Task, splitmix64};

/// One demonstration to record: a task and the reset seed of its scene.
#[derive(Debug, Clone, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub struct DemoJob {
    /// The task.
    pub task: Task,
    /// The episode seed.
    pub seed: u64,
}

/// Records the expert's demonstration of `task` in the scene of `seed`.
pub fn record_demo(
    task: &Task,
    seed: u64,
    config: &CollectConfig,
) -> Result<Demonstration<CollectObservation>, CollectError> {
    let mut env = CollectEnv::new(task.clone(), *config)?;
    Ok(record_demonstration(&mut env, &mut CollectExpert, seed)?)
}

/// Records every job in parallel on rayon's current pool. The result is in
/// job order and equal to [`generate_demos_sequential`]'s: each job depends
/// only on its own task and seed. The first error (in job order) is returned.
pub fn generate_demos(
    jobs: &[DemoJob],
    config: &CollectConfig,
) -> Result<Vec<Demonstration<CollectObservation>>, CollectError> {
    jobs.par_iter()
        .map(|job| record_demo(&job.task, job.seed, config))
        .collect()
}

/// Records every job, one after the other.
pub fn generate_demos_sequential(
    jobs: &[DemoJob],
    config: &CollectConfig,
) -> Result<Vec<Demonstration<CollectObservation>>, CollectError> {
    jobs.iter()
        .map(|job| record_demo(&job.task, job.seed, config))
        .collect()
}

/// `seeds_per_task` jobs for each task, with episode seeds derived from
/// `base_seed`, the task's position and the repetition (distinct with
/// overwhelming probability, and reproducible).
pub fn jobs_for_tasks(tasks: &[Task], seeds_per_task: usize, base_seed: u64) -> Vec<DemoJob> {
    tasks
        .iter()
        .enumerate()
        .flat_map(|(i, task)| {
            (0..seeds_per_task).map(move |k| DemoJob {
                task: task.clone(),
                seed: splitmix64(base_seed ^ splitmix64(((i as u64) << 20) ^ k as u64)),
            })
        })
        .collect()
}
