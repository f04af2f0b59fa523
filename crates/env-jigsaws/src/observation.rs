//! NTG observations: kinematics windows, one per CTG node of a trial.
//!
//! # The convention, exactly
//!
//! A trial with segments `s_0 .. s_{n-1}` becomes a
//! [`Demonstration<Vec<f32>>`](ctg_graph::Demonstration) over
//! [`gesture_vocabulary`] with **one step per
//! segment**: `actions[i] = s_i.gesture` (consecutive segments with the same
//! gesture stay separate steps). It has `n + 1` observations:
//!
//! - observation `i < n` is anchored at row `a_i = max(start_row(s_i) − 1, 0)`,
//!   the last kinematics row *before* segment `i` starts (so it shows the end
//!   of the previous gesture, i.e. the CTG node the observation sits at);
//! - observation `n` is anchored at `a_n = end_row(s_{n−1})`, the last row of
//!   the last segment (node = last gesture, next action `<end>`).
//!
//! The window of anchor `a` is the `W` rows `a − (W−1−j)·stride` for
//! `j = 0 .. W` (oldest first), i.e. the kinematics downsampled from 30 Hz by
//! `stride` (default 6, giving 5 Hz) over the `(W−1)·stride / 30` seconds up
//! to the anchor; row indices below 0 are clamped to row 0 (edge padding).
//! Each row's 76 values are normalised column by column,
//! `(x − mean_c) / std_c`, with [`ColumnStats`] (use
//! [`ColumnStats::identity`] for raw values), and the window is flattened
//! row-major: value `(j, c)` is at index `j·76 + c`, length `W·76`.

use ctg_graph::Demonstration;

use crate::dataset::Trial;
use crate::error::{JigsawsError, Result};
use crate::gesture::gesture_vocabulary;
use crate::kinematics::{KINEMATICS_COLUMNS, Kinematics};

/// Default window length `W` in (downsampled) rows: 10 rows at 5 Hz, 1.8 s.
pub const DEFAULT_WINDOW: usize = 10;
/// Default downsampling stride: every 6th row of 30 Hz kinematics (5 Hz).
pub const DEFAULT_STRIDE: usize = 6;

/// Window length and downsampling of observations.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct ObservationConfig {
    /// `W`: rows per window (after downsampling), at least 1.
    pub window: usize,
    /// Rows of 30 Hz kinematics between consecutive window rows, at least 1
    /// (6 gives 5 Hz).
    pub stride: usize,
}

impl Default for ObservationConfig {
    fn default() -> Self {
        ObservationConfig {
            window: DEFAULT_WINDOW,
            stride: DEFAULT_STRIDE,
        }
    }
}

impl ObservationConfig {
    /// Length of one flattened observation: `window × 76`.
    pub fn observation_dim(&self) -> usize {
        self.window * KINEMATICS_COLUMNS
    }

    /// Sampling rate of window rows in Hz (`30 / stride`).
    pub fn sample_rate_hz(&self) -> f64 {
        crate::FRAME_RATE / self.stride as f64
    }

    fn validate(&self) -> Result<()> {
        if self.window == 0 {
            return Err(JigsawsError::Config("window must be at least 1".into()));
        }
        if self.stride == 0 {
            return Err(JigsawsError::Config("stride must be at least 1".into()));
        }
        Ok(())
    }
}

/// Per-column mean and standard deviation of kinematics, for normalising
/// observations.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct ColumnStats {
    /// Mean of each of the 76 columns.
    pub mean: Vec<f32>,
    /// Standard deviation of each column (population), replaced by 1 where
    /// it is below `1e-8` (a constant column is only centred).
    pub std: Vec<f32>,
}

impl ColumnStats {
    /// Mean 0, std 1: observations are the raw values.
    pub fn identity() -> ColumnStats {
        ColumnStats {
            mean: vec![0.0; KINEMATICS_COLUMNS],
            std: vec![1.0; KINEMATICS_COLUMNS],
        }
    }

    /// Fits on every row (30 Hz, labelled or not) of the given trials, e.g.
    /// the training tasks only. Errors if there are no rows.
    pub fn fit<'a>(trials: impl IntoIterator<Item = &'a Trial>) -> Result<ColumnStats> {
        let mut n = 0usize;
        let mut sum = [0f64; KINEMATICS_COLUMNS];
        let mut sum_sq = [0f64; KINEMATICS_COLUMNS];
        for trial in trials {
            for row in trial.kinematics.rows() {
                n += 1;
                for (c, &v) in row.iter().enumerate() {
                    sum[c] += f64::from(v);
                    sum_sq[c] += f64::from(v) * f64::from(v);
                }
            }
        }
        if n == 0 {
            return Err(JigsawsError::NoRows);
        }
        let n = n as f64;
        let mean: Vec<f32> = sum.iter().map(|s| (s / n) as f32).collect();
        let std = sum
            .iter()
            .zip(&sum_sq)
            .map(|(s, q)| {
                let m = s / n;
                let sd = (q / n - m * m).max(0.0).sqrt();
                if sd < 1e-8 { 1.0 } else { sd as f32 }
            })
            .collect();
        Ok(ColumnStats { mean, std })
    }

    fn normalise_into(&self, row: &[f32], out: &mut Vec<f32>) {
        out.extend(
            row.iter()
                .zip(self.mean.iter().zip(&self.std))
                .map(|(x, (m, s))| (x - m) / s),
        );
    }
}

/// Turns trials into NTG demonstrations (see the module docs for the exact
/// convention).
#[derive(Debug, Clone, PartialEq)]
pub struct ObservationEncoder {
    config: ObservationConfig,
    stats: ColumnStats,
}

impl ObservationEncoder {
    /// An encoder; errors on a zero window or stride, or statistics that do
    /// not have 76 columns or have a non-positive or non-finite std.
    pub fn new(config: ObservationConfig, stats: ColumnStats) -> Result<ObservationEncoder> {
        config.validate()?;
        if stats.mean.len() != KINEMATICS_COLUMNS || stats.std.len() != KINEMATICS_COLUMNS {
            return Err(JigsawsError::Config(format!(
                "column statistics need {KINEMATICS_COLUMNS} columns, got {} means and {} stds",
                stats.mean.len(),
                stats.std.len()
            )));
        }
        if stats.mean.iter().any(|m| !m.is_finite())
            || stats.std.iter().any(|s| !s.is_finite() || *s <= 0.0)
        {
            return Err(JigsawsError::Config(
                "column means must be finite and stds finite and positive".into(),
            ));
        }
        Ok(ObservationEncoder { config, stats })
    }

    /// The configuration (`window` is `W`).
    pub fn config(&self) -> ObservationConfig {
        self.config
    }

    /// The normalisation statistics.
    pub fn stats(&self) -> &ColumnStats {
        &self.stats
    }

    /// Length of one observation, `W × 76`.
    pub fn observation_dim(&self) -> usize {
        self.config.observation_dim()
    }

    /// The anchor rows of a trial's `n + 1` observations.
    pub fn anchor_rows(trial: &Trial) -> Vec<usize> {
        let mut anchors: Vec<usize> = trial
            .segments
            .iter()
            .map(|s| s.start_row().saturating_sub(1))
            .collect();
        if let Some(last) = trial.segments.last() {
            anchors.push(last.end_row());
        }
        anchors
    }

    /// The normalised, flattened window ending at row `anchor` (clamped to
    /// the last row). Empty kinematics give an empty vector.
    pub fn window(&self, kinematics: &Kinematics, anchor: usize) -> Vec<f32> {
        let rows = kinematics.num_rows();
        let mut out = Vec::with_capacity(self.observation_dim());
        if rows == 0 {
            return out;
        }
        let anchor = anchor.min(rows - 1);
        for j in 0..self.config.window {
            let back = (self.config.window - 1 - j) * self.config.stride;
            let r = anchor.saturating_sub(back);
            if let Some(row) = kinematics.row(r) {
                self.stats.normalise_into(row, &mut out);
            }
        }
        out
    }

    /// The trial as a demonstration over the G1–G15 vocabulary.
    pub fn demonstration(&self, trial: &Trial) -> Result<Demonstration<Vec<f32>>> {
        let vocab = gesture_vocabulary();
        let observations = Self::anchor_rows(trial)
            .into_iter()
            .map(|a| self.window(&trial.kinematics, a))
            .collect();
        let actions = trial
            .segments
            .iter()
            .map(|s| s.gesture.action_id())
            .collect();
        Demonstration::new(observations, actions, &vocab).map_err(|source| {
            JigsawsError::Demonstration {
                trial: trial.id(),
                source,
            }
        })
    }

    /// Demonstrations of several trials, in order.
    pub fn demonstrations<'a>(
        &self,
        trials: impl IntoIterator<Item = &'a Trial>,
    ) -> Result<Vec<Demonstration<Vec<f32>>>> {
        trials.into_iter().map(|t| self.demonstration(t)).collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::transcription::{MetaRecord, Segment};
    use crate::{Gesture, Skill, Task, TrialId};
    use ctg_graph::Vocabulary;

    /// A trial whose row r has every value equal to r.
    fn ramp_trial(rows: usize, segments: &[(u32, u32, Gesture)]) -> Trial {
        let data = (0..rows)
            .flat_map(|r| std::iter::repeat_n(r as f32, 76))
            .collect();
        let meta = MetaRecord {
            trial: TrialId::new(Task::NeedlePassing, 'B', 1),
            skill: Skill::Novice,
            grs_total: 12,
            grs: [2; 6],
        };
        let segments = segments
            .iter()
            .map(|&(s, e, g)| Segment {
                start_frame: s,
                end_frame: e,
                gesture: g,
            })
            .collect();
        Trial::new(meta, segments, Kinematics::from_flat(data).unwrap()).unwrap()
    }

    #[test]
    fn anchors_and_windows_follow_the_documented_convention() {
        let trial = ramp_trial(
            100,
            &[
                (1, 20, Gesture::G1),
                (31, 60, Gesture::G5),
                (61, 90, Gesture::G8),
            ],
        );
        assert_eq!(ObservationEncoder::anchor_rows(&trial), [0, 29, 59, 89]);
        let enc = ObservationEncoder::new(
            ObservationConfig {
                window: 3,
                stride: 6,
            },
            ColumnStats::identity(),
        )
        .unwrap();
        let demo = enc.demonstration(&trial).unwrap();
        assert_eq!(demo.len(), 3);
        let obs = demo.observations();
        assert_eq!(obs[1].len(), 3 * 76);
        // Rows 17, 23, 29, oldest first, row-major.
        assert_eq!(obs[1][0], 17.0);
        assert_eq!(obs[1][75], 17.0);
        assert_eq!(obs[1][76], 23.0);
        assert_eq!(obs[1][2 * 76], 29.0);
        // Edge padding before row 0.
        assert!(obs[0].iter().all(|&v| v == 0.0));
        assert_eq!(obs[3][2 * 76], 89.0);
        let g = |g: Gesture| g.action_id();
        assert_eq!(
            demo.actions(),
            [g(Gesture::G1), g(Gesture::G5), g(Gesture::G8)]
        );
        assert_eq!(demo.node_labels()[0], Vocabulary::START);
        assert_eq!(demo.next_actions()[3], Vocabulary::END);
    }

    #[test]
    fn normalisation_uses_fitted_stats() {
        let trial = ramp_trial(5, &[(1, 5, Gesture::G1)]);
        let stats = ColumnStats::fit([&trial]).unwrap();
        assert!((stats.mean[0] - 2.0).abs() < 1e-6);
        assert!((stats.std[0] - 2f32.sqrt()).abs() < 1e-6);
        let enc = ObservationEncoder::new(
            ObservationConfig {
                window: 1,
                stride: 1,
            },
            stats,
        )
        .unwrap();
        let w = enc.window(&trial.kinematics, 4);
        assert!((w[0] - 2.0 / 2f32.sqrt()).abs() < 1e-6);
        assert!(ColumnStats::fit(std::iter::empty()).is_err());
    }

    #[test]
    fn rejects_bad_configs() {
        let bad = |w, s| {
            ObservationEncoder::new(
                ObservationConfig {
                    window: w,
                    stride: s,
                },
                ColumnStats::identity(),
            )
            .is_err()
        };
        assert!(bad(0, 6));
        assert!(bad(3, 0));
        assert!(!bad(1, 1));
        let mut stats = ColumnStats::identity();
        stats.std[3] = 0.0;
        assert!(ObservationEncoder::new(ObservationConfig::default(), stats).is_err());
    }
}
