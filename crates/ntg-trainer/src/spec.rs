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
