//! The words a run is specified in, shared by every domain and method: the
//! observation kind, and [`Choice`], how a setting with a fixed set of
//! values is named in files and on command lines.
//!
//! Architecture invariant: this module imports nothing else of the crate,
//! so every other module may use it without forming a cycle.

use serde::{Deserialize, Serialize};

/// A setting with a fixed set of values, each with a name (as serialised
/// and as an application's command line spells it) and a line of help.
/// The library parses no command lines: an application builds its parsers
/// from [`Choice::ALL`].
pub trait Choice: Copy + PartialEq + Send + Sync + 'static {
    /// Every value, in the order help lists them.
    const ALL: &'static [Self];
    /// Its name in files and on command lines.
    fn name(self) -> &'static str;
    /// One line on what it means.
    fn help(self) -> &'static str;
    /// The value named `name`, if any.
    fn from_name(name: &str) -> Option<Self> {
        Self::ALL.iter().copied().find(|c| c.name() == name)
    }
}

/// What the networks see.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum ObsKind {
    /// The domain's symbolic state vector (block stacking: the 26-number
    /// state, cube positions relative to the gripper and a gripper one-hot).
    State,
    /// The rendered RGB frame.
    Vid,
}

impl ObsKind {
    /// Name in run folders and files (`state`, `vid`).
    pub fn name(self) -> &'static str {
        Choice::name(self)
    }
}

impl Choice for ObsKind {
    const ALL: &'static [Self] = &[ObsKind::State, ObsKind::Vid];

    fn name(self) -> &'static str {
        match self {
            ObsKind::State => "state",
            ObsKind::Vid => "vid",
        }
    }

    fn help(self) -> &'static str {
        match self {
            ObsKind::State => "The domain's symbolic state vector",
            ObsKind::Vid => "The rendered RGB frame",
        }
    }
}

impl std::fmt::Display for ObsKind {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn observation_kinds_are_named_as_they_are_serialised() {
        for &kind in ObsKind::ALL {
            let serialised = serde_json::to_value(kind).unwrap();
            assert_eq!(serialised.as_str(), Some(kind.name()));
            assert_eq!(ObsKind::from_name(kind.name()), Some(kind));
        }
        assert_eq!(ObsKind::from_name("video"), None);
    }
}
