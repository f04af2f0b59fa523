//! Choosing the device (and so the backend) the networks run on.
//!
//! burn 0.22 has no backend type parameter: the backend is a property of
//! the runtime [`Device`]. The CPU default is burn's `flex` backend;
//! burn-ndarray (feature `ndarray`, deprecated upstream, much slower on
//! convolutions) and the GPU backends (features `wgpu`, `cuda`) are opt-in.
//! Always pick the device explicitly: `Device::default()` depends on which
//! features happen to be unified into the build.

use std::fmt;
use std::str::FromStr;

use burn::tensor::Device;

use crate::{ModelError, Result};

/// A backend this build can run on.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum BackendKind {
    /// burn's pure-Rust `flex` CPU backend (the default).
    Flex,
    /// burn-ndarray (CPU; feature `ndarray`).
    NdArray,
    /// WebGPU through wgpu (feature `wgpu`).
    Wgpu,
    /// CUDA (feature `cuda`), device 0.
    Cuda,
}

impl BackendKind {
    /// Every backend, compiled in or not.
    pub const ALL: [BackendKind; 4] = [
        BackendKind::Flex,
        BackendKind::NdArray,
        BackendKind::Wgpu,
        BackendKind::Cuda,
    ];

    /// The backends compiled into this build.
    pub fn available() -> Vec<BackendKind> {
        Self::ALL.into_iter().filter(|b| b.is_available()).collect()
    }

    /// Whether this build has the backend's feature.
    pub fn is_available(self) -> bool {
        match self {
            BackendKind::Flex => true,
            BackendKind::NdArray => cfg!(feature = "ndarray"),
            BackendKind::Wgpu => cfg!(feature = "wgpu"),
            BackendKind::Cuda => cfg!(feature = "cuda"),
        }
    }

    /// The backend's name as written on command lines (`flex`, `ndarray`,
    /// `wgpu`, `cuda`).
    pub fn name(self) -> &'static str {
        match self {
            BackendKind::Flex => "flex",
            BackendKind::NdArray => "ndarray",
            BackendKind::Wgpu => "wgpu",
            BackendKind::Cuda => "cuda",
        }
    }

    /// The inference device of this backend (add `.autodiff()` to train),
    /// or an error if the feature is not compiled in.
    pub fn device(self) -> Result<Device> {
        match self {
            BackendKind::Flex => Ok(Device::flex()),
            #[cfg(feature = "ndarray")]
            #[allow(deprecated)]
            // burn-ndarray is deprecated upstream but still supported here
            BackendKind::NdArray => Ok(Device::ndarray()),
            #[cfg(feature = "wgpu")]
            BackendKind::Wgpu => Ok(Device::wgpu(Default::default())),
            #[cfg(feature = "cuda")]
            BackendKind::Cuda => Ok(Device::cuda(0)),
            #[allow(unreachable_patterns)]
            other => Err(ModelError::Config(format!(
                "backend `{}` is not compiled in; rebuild ntg-model with `--features {}`",
                other.name(),
                other.name()
            ))),
        }
    }
}

impl fmt::Display for BackendKind {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl FromStr for BackendKind {
    type Err = ModelError;
    fn from_str(s: &str) -> Result<Self> {
        Self::ALL
            .into_iter()
            .find(|b| b.name() == s)
            .ok_or_else(|| {
                ModelError::Config(format!(
                    "unknown backend `{s}`; expected one of flex, ndarray, wgpu, cuda"
                ))
            })
    }
}

/// The default CPU device: `flex`.
pub fn cpu_device() -> Device {
    Device::flex()
}
