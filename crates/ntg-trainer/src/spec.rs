//! The words a run is specified in, shared by every domain, method and
//! figure: the observation kind and the experiment scale (profile).
//!
//! Architecture invariant: this module imports nothing else of the crate,
//! so every other module may use it without forming a cycle.

use clap::ValueEnum;
use serde::{Deserialize, Serialize};

/// What the networks see.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, ValueEnum)]
#[serde(rename_all = "lowercase")]
pub enum ObsKind {
    /// The domain's symbolic state vector (block stacking: the 26-number
    /// state, cube positions relative to the gripper and a gripper one-hot).
    State,
    /// The rendered 64×64 RGB frame.
    Vid,
}

impl ObsKind {
    /// Name in run folders and files (`state`, `vid`).
    pub fn name(self) -> &'static str {
        match self {
            ObsKind::State => "state",
            ObsKind::Vid => "vid",
        }
    }
}

/// Experiment scale.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, ValueEnum)]
#[serde(rename_all = "lowercase")]
pub enum Profile {
    /// Seconds per figure: for tests and CI.
    Smoke,
    /// Every figure at reduced scale: minutes on 2 CPU cores.
    Quick,
    /// The paper's scale (100 demos per task, up to 1000 tasks): hours.
    Paper,
}

impl Profile {
    /// Name in run folders (`smoke`, `quick`, `paper`).
    pub fn name(self) -> &'static str {
        match self {
            Profile::Smoke => "smoke",
            Profile::Quick => "quick",
            Profile::Paper => "paper",
        }
    }
}

/// Command-line parsers that refuse out-of-range numbers at parse time, so
/// that clap's error names the flag and nothing is written.
pub mod parse {
    fn number<T: std::str::FromStr>(s: &str) -> Result<T, String>
    where
        T::Err: std::fmt::Display,
    {
        s.trim().parse().map_err(|e| format!("{e}"))
    }

    /// A whole number of at least 1.
    pub fn positive(s: &str) -> Result<usize, String> {
        match number::<usize>(s)? {
            0 => Err("must be at least 1".into()),
            n => Ok(n),
        }
    }

    /// A finite number above 0.
    pub fn positive_real(s: &str) -> Result<f64, String> {
        let v: f64 = number(s)?;
        if v.is_finite() && v > 0.0 {
            Ok(v)
        } else {
            Err(format!("must be a finite number above 0, got {v}"))
        }
    }

    /// A finite number of at least 0.
    pub fn non_negative(s: &str) -> Result<f32, String> {
        let v: f32 = number(s)?;
        if v.is_finite() && v >= 0.0 {
            Ok(v)
        } else {
            Err(format!("must be a finite number of at least 0, got {v}"))
        }
    }

    /// A fraction: a number in `[0, 1]`.
    pub fn fraction(s: &str) -> Result<f64, String> {
        let v: f64 = number(s)?;
        if (0.0..=1.0).contains(&v) {
            Ok(v)
        } else {
            Err(format!("must be in [0, 1], got {v}"))
        }
    }

    /// A probability below 1: a number in `[0, 1)`.
    pub fn rate(s: &str) -> Result<f32, String> {
        let v: f32 = number(s)?;
        if (0.0..1.0).contains(&v) {
            Ok(v)
        } else {
            Err(format!("must be in [0, 1), got {v}"))
        }
    }

    /// A number in `[0, 1]`.
    pub fn unit(s: &str) -> Result<f32, String> {
        let v: f32 = number(s)?;
        if (0.0..=1.0).contains(&v) {
            Ok(v)
        } else {
            Err(format!("must be in [0, 1], got {v}"))
        }
    }

    /// Any finite number.
    pub fn finite(s: &str) -> Result<f32, String> {
        let v: f32 = number(s)?;
        if v.is_finite() {
            Ok(v)
        } else {
            Err(format!("must be a finite number, got {v}"))
        }
    }
}
