//! The methods the `ntg` binary offers, registered in one list
//! ([`MethodId`]): NTG and the Flat Policy from ntg-train (re-exported here
//! with the method traits), and this repository's block-stacking baselines:
//! NTP and NTP Flat ([`ntp`]), NTP (Detector) ([`ntp_detector`]) and its
//! frame detector ([`detector`]).
//!
//! Adding a method: a new file (its model, step, options, [`Method`] with
//! `train`, [`TrainedPolicy`] and [`Agent`]), and one line in the
//! `methods!` list below. Every domain then trains it through the one
//! [`TrainInput`] it builds, with no arm per method.

use std::path::Path;

use burn::tensor::Device;
use clap::ValueEnum;
use serde::{Deserialize, Serialize};

pub use ntg_train::method::*;

pub mod detector;
pub mod ntp;
pub mod ntp_detector;

/// The registry: one line per method, `Identifier => value implementing
/// Method`; it makes [`MethodId`] (serialised and parsed lower-case).
macro_rules! methods {
    ($($(#[$doc:meta])* $id:ident => $method:expr,)*) => {
        /// The registered methods.
        #[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, ValueEnum)]
        #[serde(rename_all = "kebab-case")]
        pub enum MethodId {
            $($(#[$doc])* $id,)*
        }

        impl MethodId {
            /// Every registered method, in registry order.
            pub const ALL: &[MethodId] = &[$(MethodId::$id,)*];

            /// The method itself.
            pub fn method(self) -> &'static dyn Method {
                match self {
                    $(MethodId::$id => &$method,)*
                }
            }
        }
    };
}

methods! {
    /// Neural Task Graphs.
    Ntg => ntg::Ntg,
    /// The Flat Policy baseline (attention over the demo, then an MLP).
    Flat => flat::Flat,
    /// Neural Task Programming (Xu et al. 2018), block stacking.
    Ntp => ntp::NtpMethod(ntp::NtpKind::Hierarchical),
    /// NTP trained on the lowest level only, block stacking.
    NtpFlat => ntp::NtpMethod(ntp::NtpKind::Flat),
    /// NTP on the states a frame detector estimates (video input), block
    /// stacking.
    NtpDetector => ntp_detector::NtpDetector,
}

impl Default for MethodId {
    /// NTG, the method of runs saved before the field existed.
    fn default() -> Self {
        MethodId::Ntg
    }
}

impl MethodId {
    /// Whether it is NTG.
    pub fn is_ntg(&self) -> bool {
        *self == MethodId::Ntg
    }

    /// Whether it is one of the NTP baselines.
    pub fn is_ntp(&self) -> bool {
        matches!(
            self,
            MethodId::Ntp | MethodId::NtpFlat | MethodId::NtpDetector
        )
    }

    /// Name in files, run folders and on the command line.
    pub fn name(self) -> &'static str {
        self.method().name()
    }

    /// Name in figure legends and reports.
    pub fn legend(self) -> &'static str {
        self.method().legend()
    }

    /// Loads this method's model saved in `dir`.
    pub fn load(self, dir: &Path, device: &Device) -> anyhow::Result<Model> {
        self.method().load(dir, device)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_method_is_named_as_it_is_serialised() {
        for &id in MethodId::ALL {
            let serialised = serde_json::to_value(id).unwrap();
            assert_eq!(serialised.as_str(), Some(id.name()));
            let parsed: MethodId = serde_json::from_value(serialised).unwrap();
            assert_eq!(parsed, id);
            assert_eq!(
                MethodId::from_str(id.name(), false).unwrap(),
                id,
                "the command line accepts {}",
                id.name()
            );
        }
    }
}
