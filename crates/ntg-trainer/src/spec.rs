//! The words a run is specified in, shared by every domain, method and
//! figure: the observation kind (ntg-train's, re-exported), the experiment
//! scale (profile), the device the networks run on, and the command line's
//! parsers of numbers and [`Choice`]s.
//!
//! Architecture invariant: this module imports nothing else of the crate,
//! so every other module may use it without forming a cycle.

use clap::ValueEnum;
use serde::{Deserialize, Serialize};

pub use ntg_train::spec::*;

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

/// Where the networks run (`ntg train|eval|reproduce --device`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, ValueEnum)]
pub enum DeviceKind {
    /// burn's `flex` CPU backend (every build).
    #[default]
    Cpu,
    /// WebGPU (a build with `--features wgpu`).
    Wgpu,
    /// CUDA device 0 (a build with `--features cuda`).
    Cuda,
}

static DEVICE: std::sync::OnceLock<burn::tensor::Device> = std::sync::OnceLock::new();

/// Makes `kind` the device every network of this process runs on (see
/// [`device`]); once, before any training or evaluation. Errors, saying
/// how to get it, if this build lacks the backend or it finds no device.
pub fn select_device(kind: DeviceKind) -> anyhow::Result<()> {
    let backend = match kind {
        DeviceKind::Cpu => ntg_model::BackendKind::Flex,
        DeviceKind::Wgpu => ntg_model::BackendKind::Wgpu,
        DeviceKind::Cuda => ntg_model::BackendKind::Cuda,
    };
    if !backend.is_available() {
        anyhow::bail!(
            "--device {0}: this ntg was built without the {0} backend; rebuild it with `cargo build --release -p ntg-trainer --features {0}`",
            backend.name()
        );
    }
    let device = backend.working_device()?;
    if let Some(chosen) = DEVICE.get() {
        anyhow::ensure!(
            *chosen == device,
            "the device was already chosen ({chosen:?})"
        );
        return Ok(());
    }
    let _ = DEVICE.set(device);
    Ok(())
}

/// The device networks are built on: the one [`select_device`] chose, or
/// the CPU (`flex`). Training adds `.autodiff()`.
pub fn device() -> burn::tensor::Device {
    DEVICE.get().cloned().unwrap_or_else(ntg_model::cpu_device)
}

/// Command-line parsers that refuse out-of-range numbers at parse time, so
/// that clap's error names the flag and nothing is written.
pub mod parse {
    use ntg_train::spec::Choice;

    /// The parser of a [`Choice`] flag: its values by name, each with its
    /// help, as clap's `value_enum` lists them.
    pub fn choice<T: Choice + Clone>() -> impl clap::builder::TypedValueParser<Value = T> {
        use clap::builder::{PossibleValue, PossibleValuesParser, TypedValueParser};
        PossibleValuesParser::new(
            T::ALL
                .iter()
                .map(|c| PossibleValue::new(c.name()).help(c.help())),
        )
        .map(|name| T::from_name(&name).expect("clap accepts only the possible values"))
    }

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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_cpu_is_the_default_device_and_gpu_backends_need_their_feature() {
        assert_eq!(device(), ntg_model::cpu_device());
        select_device(DeviceKind::Cpu).unwrap();
        assert_eq!(device(), ntg_model::cpu_device());
        if !cfg!(feature = "cuda") {
            let err = select_device(DeviceKind::Cuda).unwrap_err().to_string();
            assert!(err.contains("--features cuda"), "{err}");
        }
    }
}
