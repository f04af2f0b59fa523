//! Choosing the device (and so the backend) the networks run on.
//!
//! burn 0.22 has no backend type parameter: the backend is a property of
//! the runtime [`Device`]. The CPU default is burn's `flex` backend;
//! burn-ndarray (feature `ndarray`, deprecated upstream, much slower on
//! convolutions) and the GPU backends (features `wgpu`, `cuda`) are opt-in.
//! Always pick the device explicitly: `Device::default()` depends on which
//! features happen to be unified into the build.
//!
//! CI type-checks the GPU features only when a file that names a backend
//! (this one, the `backend_extension` kernels, ...: `.ci/gpu-inputs`) or
//! the lock file changed since `cargo xtask check-gpu` last checked them:
//! run it after changing such a file and commit `.ci/gpu-checked`.

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

impl BackendKind {
    /// The backend's inference device after checking that it works: a
    /// tiny computation runs on it and is read back. A missing feature, or
    /// a GPU backend that finds no device (burn panics there), is an
    /// error that says so.
    pub fn working_device(self) -> Result<Device> {
        let device = self.device()?;
        let probe = device.clone();
        crate::checkpoint::quietly(move || {
            let sum = burn::tensor::Tensor::<1>::ones([4], &probe)
                .sum()
                .into_data();
            sum.try_to_vec::<f32>()
                .map(|_| ())
                .map_err(|e| format!("{e:?}"))
        })
        .and_then(|read| read)
        .map_err(|why| {
            ModelError::Config(format!(
                "backend `{}` found no usable device ({why})",
                self.name()
            ))
        })?;
        Ok(device)
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_cpu_backend_passes_its_probe_and_missing_features_are_named() {
        assert!(BackendKind::Flex.working_device().is_ok());
        for kind in BackendKind::ALL {
            if !kind.is_available() {
                let err = kind.working_device().unwrap_err().to_string();
                assert!(
                    err.contains(&format!("--features {}", kind.name())),
                    "{err}"
                );
            }
        }
    }
}
