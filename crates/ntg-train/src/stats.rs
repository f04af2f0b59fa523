//! Success rates with confidence intervals, and summaries over seeds.

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
}
