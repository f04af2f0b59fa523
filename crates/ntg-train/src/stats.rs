//! Success rates with confidence intervals, and summaries over seeds.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

/// A success rate over independent trials, with its 95% Wilson score interval.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct SuccessRate {
    /// Number of successful trials.
    pub successes: usize,
    /// Number of trials.
    pub trials: usize,
    /// `successes / trials` (0 when there were no trials).
    pub rate: f64,
    /// Lower end of the 95% Wilson interval.
    pub ci_low: f64,
    /// Upper end of the 95% Wilson interval.
    pub ci_high: f64,
}

impl SuccessRate {
    /// The rate of `successes` out of `trials`.
    pub fn new(successes: usize, trials: usize) -> Self {
        if trials == 0 {
            return SuccessRate {
                successes,
                trials,
                rate: 0.0,
                ci_low: 0.0,
                ci_high: 1.0,
            };
        }
        let n = trials as f64;
        let p = successes as f64 / n;
        let z = 1.959_963_984_540_054_f64;
        let denom = 1.0 + z * z / n;
        let centre = (p + z * z / (2.0 * n)) / denom;
        let half = z * ((p * (1.0 - p) + z * z / (4.0 * n)) / n).sqrt() / denom;
        SuccessRate {
            successes,
            trials,
            rate: p,
            ci_low: (centre - half).max(0.0),
            ci_high: (centre + half).min(1.0),
        }
    }

    /// The rate of the `true`s in `outcomes`.
    pub fn from_outcomes(outcomes: impl IntoIterator<Item = bool>) -> Self {
        let (mut s, mut n) = (0, 0);
        for ok in outcomes {
            n += 1;
            s += usize::from(ok);
        }
        SuccessRate::new(s, n)
    }
}

impl std::fmt::Display for SuccessRate {
    /// `0.850 (0.767-0.907, 85/100)`: the rate, its 95% interval and counts.
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{:.3} ({:.3}-{:.3}, {}/{})",
            self.rate, self.ci_low, self.ci_high, self.successes, self.trials
        )
    }
}

/// The mean rate of `rates` (one per seed of a point; 0 for none).
pub fn mean_rate(rates: &[SuccessRate]) -> f64 {
    rates.iter().map(|r| r.rate).sum::<f64>() / rates.len().max(1) as f64
}

/// The lowest interval end and the highest of `rates` (one per seed of a
/// point): "above" between two points asks the one's lowest above the
/// other's highest.
pub fn interval_span(rates: &[SuccessRate]) -> (f64, f64) {
    rates.iter().fold((f64::INFINITY, 0.0f64), |(lo, hi), r| {
        (lo.min(r.ci_low), hi.max(r.ci_high))
    })
}

/// `"0.080 (mean of 2 seeds: 0.010, 0.150)"`: one point's seeds in a
/// report.
pub fn seeds_text(rates: &[SuccessRate]) -> String {
    let each: Vec<String> = rates.iter().map(|r| format!("{:.3}", r.rate)).collect();
    format!(
        "{:.3} (mean of {} seeds: {})",
        mean_rate(rates),
        rates.len(),
        each.join(", ")
    )
}

/// Mean and 95% interval (normal approximation, t-free) of a few values,
/// e.g. one metric over seeds.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Summary {
    /// Number of values.
    pub n: usize,
    /// Arithmetic mean.
    pub mean: f64,
    /// Sample standard deviation (0 for a single value).
    pub std: f64,
    /// `mean - 1.96 * std / sqrt(n)`.
    pub ci_low: f64,
    /// `mean + 1.96 * std / sqrt(n)`.
    pub ci_high: f64,
}

impl Summary {
    /// Summarises `values` (`None` when empty).
    pub fn of(values: &[f64]) -> Option<Self> {
        if values.is_empty() {
            return None;
        }
        let n = values.len() as f64;
        let mean = values.iter().sum::<f64>() / n;
        let std = if values.len() > 1 {
            (values.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (n - 1.0)).sqrt()
        } else {
            0.0
        };
        let half = 1.96 * std / n.sqrt();
        Some(Summary {
            n: values.len(),
            mean,
            std,
            ci_low: mean - half,
            ci_high: mean + half,
        })
    }
}

/// A success rate over test tasks that come in clusters (tasks of one
/// structure, say), over one or more seeds of a method scored on the same
/// tasks, with a 95% interval from a two-level bootstrap: each resample
/// draws as many clusters as there are, with replacement, then within each
/// drawn cluster as many of its tasks, with replacement, and takes the
/// mean success over the seeds on those tasks (the seeds are kept as they
/// are: their spread is in the point estimate's neighbours, not resampled).
/// Where tasks of a cluster succeed or fail together, a Wilson interval
/// over tasks treats them as independent and is too narrow; this one
/// widens with the clusters' disagreement, and with few clusters.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ClusteredRate {
    /// Mean over the seeds of each seed's success rate over all tasks.
    pub rate: f64,
    /// 2.5th percentile of the resampled rates.
    pub ci_low: f64,
    /// 97.5th percentile of the resampled rates.
    pub ci_high: f64,
    /// Clusters (structures).
    pub clusters: usize,
    /// Tasks per seed, over every cluster.
    pub tasks: usize,
    /// Seeds averaged.
    pub seeds: usize,
    /// Bootstrap resamples.
    pub resamples: usize,
    /// Seed of the resampling.
    pub bootstrap_seed: u64,
}

/// [`ClusteredRate`] of `outcomes[seed][cluster][task]` (every seed with
/// the same clusters and the same number of tasks in each), from
/// `resamples` resamples drawn from `bootstrap_seed`. Errors name what is
/// missing or uneven.
pub fn clustered_bootstrap(
    outcomes: &[Vec<Vec<bool>>],
    resamples: usize,
    bootstrap_seed: u64,
) -> Result<ClusteredRate, String> {
    let first = outcomes.first().ok_or("no seed's outcomes")?;
    if first.is_empty() {
        return Err("no cluster of tasks".into());
    }
    let sizes: Vec<usize> = first.iter().map(Vec::len).collect();
    if let Some(c) = sizes.iter().position(|&n| n == 0) {
        return Err(format!("cluster {c} has no task"));
    }
    for (s, seed) in outcomes.iter().enumerate() {
        let theirs: Vec<usize> = seed.iter().map(Vec::len).collect();
        if theirs != sizes {
            return Err(format!(
                "seed {s} has clusters of {theirs:?} tasks, seed 0 of {sizes:?}: every seed must be scored on the same tasks"
            ));
        }
    }
    if resamples < 2 {
        return Err(format!("at least 2 resamples are needed, got {resamples}"));
    }
    let seeds = outcomes.len() as f64;
    let tasks: usize = sizes.iter().sum();
    // Successes of every seed together, per task: the statistic only
    // needs their sum over the drawn tasks.
    let together: Vec<Vec<u32>> = (0..sizes.len())
        .map(|c| {
            (0..sizes[c])
                .map(|t| outcomes.iter().map(|seed| u32::from(seed[c][t])).sum())
                .collect()
        })
        .collect();
    let total: u64 = together.iter().flatten().map(|&k| u64::from(k)).sum();
    let rate = total as f64 / (seeds * tasks as f64);
    let mut rng = ChaCha8Rng::seed_from_u64(bootstrap_seed);
    let mut rates = Vec::with_capacity(resamples);
    for _ in 0..resamples {
        let (mut successes, mut drawn) = (0u64, 0usize);
        for _ in 0..sizes.len() {
            let cluster = &together[rng.random_range(0..sizes.len())];
            for _ in 0..cluster.len() {
                successes += u64::from(cluster[rng.random_range(0..cluster.len())]);
            }
            drawn += cluster.len();
        }
        rates.push(successes as f64 / (seeds * drawn as f64));
    }
    rates.sort_by(f64::total_cmp);
    let at = |q: f64| rates[((q * (resamples - 1) as f64).round() as usize).min(resamples - 1)];
    Ok(ClusteredRate {
        rate,
        ci_low: at(0.025),
        ci_high: at(0.975),
        clusters: sizes.len(),
        tasks,
        seeds: outcomes.len(),
        resamples,
        bootstrap_seed,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn wilson_interval_matches_known_values() {
        // 8/10: Wilson 95% interval is about [0.490, 0.943].
        let r = SuccessRate::new(8, 10);
        assert!((r.rate - 0.8).abs() < 1e-12);
        assert!((r.ci_low - 0.4902).abs() < 1e-3, "{r:?}");
        assert!((r.ci_high - 0.9433).abs() < 1e-3, "{r:?}");
        let all = SuccessRate::new(20, 20);
        assert_eq!(all.ci_high, 1.0);
        assert!(all.ci_low > 0.8 && all.ci_low < 0.85);
        let none = SuccessRate::new(0, 0);
        assert_eq!((none.ci_low, none.ci_high), (0.0, 1.0));
    }

    #[test]
    fn summary_of_values() {
        let s = Summary::of(&[1.0, 2.0, 3.0]).unwrap();
        assert!((s.mean - 2.0).abs() < 1e-12 && (s.std - 1.0).abs() < 1e-12);
        assert!(Summary::of(&[]).is_none());
        assert_eq!(Summary::of(&[5.0]).unwrap().std, 0.0);
    }
    /// Ten clusters of 100 tasks, each cluster all successes or all
    /// failures: the tasks are not independent, and the two-level interval
    /// is far wider than Wilson's over 1000 tasks; independent outcomes at
    /// the same rate keep it about Wilson's width.
    #[test]
    fn clustered_bootstrap_widens_with_the_clusters_disagreement() {
        let blocks: Vec<Vec<bool>> = (0..10).map(|c| vec![c < 5; 100]).collect();
        let r = clustered_bootstrap(&[blocks], 2000, 7).unwrap();
        assert!((r.rate - 0.5).abs() < 1e-12);
        let wilson = SuccessRate::new(500, 1000);
        assert!(
            r.ci_high - r.ci_low > 4.0 * (wilson.ci_high - wilson.ci_low),
            "{r:?}"
        );
        assert!(r.ci_low < 0.3 && r.ci_high > 0.7, "{r:?}");
        // Independent outcomes: every other task succeeds in a random order.
        let mut rng = ChaCha8Rng::seed_from_u64(1);
        let mixed: Vec<Vec<bool>> = (0..10)
            .map(|_| (0..100).map(|_| rng.random_bool(0.5)).collect())
            .collect();
        let m = clustered_bootstrap(std::slice::from_ref(&mixed), 2000, 7).unwrap();
        let width = m.ci_high - m.ci_low;
        assert!(width > 0.03 && width < 0.1, "{m:?}");
        assert!(m.ci_low <= m.rate && m.rate <= m.ci_high);
        // Seeded: the same seed, the same interval.
        assert_eq!(m, clustered_bootstrap(&[mixed], 2000, 7).unwrap());
    }

    #[test]
    fn clustered_bootstrap_averages_seeds_on_the_same_tasks_and_refuses_uneven_ones() {
        let all = vec![vec![true; 4], vec![true; 6]];
        let none = vec![vec![false; 4], vec![false; 6]];
        let r = clustered_bootstrap(&[all.clone(), none], 100, 0).unwrap();
        assert_eq!((r.rate, r.ci_low, r.ci_high), (0.5, 0.5, 0.5));
        assert_eq!((r.clusters, r.tasks, r.seeds), (2, 10, 2));
        let one = clustered_bootstrap(std::slice::from_ref(&all), 100, 0).unwrap();
        assert_eq!((one.rate, one.ci_low, one.ci_high), (1.0, 1.0, 1.0));
        let uneven = vec![vec![true; 4], vec![true; 5]];
        assert!(
            clustered_bootstrap(&[all.clone(), uneven], 100, 0)
                .unwrap_err()
                .contains("same tasks")
        );
        assert!(clustered_bootstrap(&[], 100, 0).is_err());
        assert!(clustered_bootstrap(&[vec![]], 100, 0).is_err());
        assert!(
            clustered_bootstrap(&[vec![vec![]]], 100, 0)
                .unwrap_err()
                .contains("cluster 0")
        );
        assert!(clustered_bootstrap(&[all], 1, 0).is_err());
    }
}
