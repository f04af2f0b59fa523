//! The one evaluation loop: rollouts of independent episodes in parallel
//! (rayon), in order, with a progress bar. Every domain's test and
//! validation evaluation runs through [`in_parallel`]; each job builds its
//! own environment from its seeds, so the results do not depend on the
//! number of threads or their schedule.

use rayon::prelude::*;

use crate::dataset::progress_bar;

/// `run(i, &jobs[i])` for every job, in parallel; the results in job
/// order, or the first error.
pub fn in_parallel<J, R>(
    jobs: &[J],
    what: &str,
    run: impl Fn(usize, &J) -> anyhow::Result<R> + Sync + Send,
) -> anyhow::Result<Vec<R>>
where
    J: Sync,
    R: Send,
{
    let bar = progress_bar(jobs.len() as u64, what);
    let results = jobs
        .par_iter()
        .enumerate()
        .map(|(i, job)| {
            let r = run(i, job);
            bar.inc(1);
            r
        })
        .collect::<anyhow::Result<Vec<R>>>()?;
    bar.finish_and_clear();
    Ok(results)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn results_keep_the_job_order_and_errors_surface() {
        let jobs: Vec<u64> = (0..100).collect();
        let out = in_parallel(&jobs, "jobs", |i, &j| Ok((i as u64) * 1000 + j)).unwrap();
        assert_eq!(out, (0..100).map(|j| j * 1001).collect::<Vec<_>>());
        let err = in_parallel(&jobs, "jobs", |_, &j| {
            anyhow::ensure!(j != 42, "job {j} failed");
            Ok(j)
        })
        .unwrap_err();
        assert_eq!(err.to_string(), "job 42 failed");
    }
}
