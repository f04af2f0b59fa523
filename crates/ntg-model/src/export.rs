//! Weights as safetensors files that PyTorch loads (`ntg export`).
//!
//! [`save_safetensors`] writes every parameter of a module under its path
//! in the module (`interpreter.enc_gru.input.weight`, `mid.0.bias`; enum
//! variant names left out, as PyTorch names have none), in PyTorch's
//! layout: a burn `Linear` keeps its weight as `[in, out]` and computes
//! `x W + b`, PyTorch's `nn.Linear` as `[out, in]`, so every `Linear`
//! weight is transposed (burn-store's `BurnToPyTorchAdapter`); everything
//! else (convolutions `[out, in, kh, kw]`, biases, embedding tables) has
//! the same layout in both and is written as is. The returned
//! [`ExportedTensor`]s say which were transposed, for the name map that
//! `ntg export` writes beside the files. Each file gets a `.sha256`
//! sidecar, as checkpoints do.
//!
//! [`load_safetensors`] reads such a file back into a module (the model
//! zoo's entries hold their weights this way: a model folder with
//! `model.safetensors` instead of `model.bpk` loads like any checkpoint).

use std::collections::BTreeMap;
use std::path::Path;
use std::sync::{Arc, Mutex};

use burn::module::Module;
use burn::store::{
    BurnToPyTorchAdapter, ModuleAdapter, ModuleContext, ModuleSnapshot, PyTorchToBurnAdapter,
    SafetensorsStore,
};

use crate::{ModelError, Result};

/// One tensor of an exported file.
#[derive(Debug, Clone, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct ExportedTensor {
    /// Its key in the safetensors file: the parameter's path in the module.
    pub name: String,
    /// Its shape in the file (PyTorch's layout).
    pub shape: Vec<usize>,
    /// Its element type (`F32` for every network here).
    pub dtype: String,
    /// The module type that holds it (`Linear`, `Conv2d`, or the network
    /// for a bare parameter such as a node-embedding table).
    pub module: String,
    /// Whether the file holds the transpose of burn's tensor (a `Linear`
    /// weight: `[out, in]` in the file, `[in, out]` in burn).
    pub transposed: bool,
}

/// Wraps [`BurnToPyTorchAdapter`] and records, for every tensor it sees,
/// the module type that holds it and whether it was transposed.
#[derive(Clone, Default)]
struct Recording {
    seen: Arc<Mutex<Vec<ExportedTensor>>>,
}

impl ModuleAdapter for Recording {
    fn adapt(&self, tensor: burn_pack::Tensor, ctx: ModuleContext<'_>) -> burn_pack::Tensor {
        let module = ctx
            .module_type()
            .map(|t| t.split_once(':').map_or(t, |(_, name)| name).to_owned())
            .unwrap_or_default();
        let out = BurnToPyTorchAdapter.adapt(tensor, ctx);
        let shape = out.shape.to_vec();
        // The adapter's own rule: a Linear's 2-D `weight` is transposed.
        let transposed =
            module == "Linear" && out.name.rsplit('.').next() == Some("weight") && shape.len() == 2;
        if let Ok(mut seen) = self.seen.lock() {
            seen.push(ExportedTensor {
                name: out.name.clone(),
                shape,
                dtype: format!("{:?}", out.dtype).to_uppercase(),
                module,
                transposed,
            });
        }
        out
    }

    fn clone_box(&self) -> Box<dyn ModuleAdapter> {
        Box::new(self.clone())
    }
}

/// The weights file of a model folder saved as safetensors (the model
/// zoo's entries), read when the folder has no `model.bpk`.
pub const SAFETENSORS_WEIGHTS_FILE: &str = "model.safetensors";

/// Writes the parameters of `module` to the safetensors file `path` in
/// PyTorch's layout (see the module doc), with `metadata` in the file's
/// header beside burn-store's own (`format`, `producer`, `version`), and
/// its checksum beside it (`path.sha256`). Refuses an existing file.
/// Returns the tensors written, sorted by name.
pub fn save_safetensors<M: Module>(
    module: &M,
    path: &Path,
    metadata: &BTreeMap<String, String>,
) -> Result<Vec<ExportedTensor>> {
    if path.exists() {
        return Err(ModelError::file(path, "already exists; not overwritten"));
    }
    let recording = Recording::default();
    let mut store = SafetensorsStore::from_file(path)
        .with_to_adapter(recording.clone())
        .skip_enum_variants(true)
        .overwrite(false);
    for (key, value) in metadata {
        store = store.metadata(key.clone(), value.clone());
    }
    module
        .save_into(&mut store)
        .map_err(|e| ModelError::file(path, e))?;
    let mut seen = recording
        .seen
        .lock()
        .map(|s| s.clone())
        .map_err(|_| ModelError::file(path, "the exporter's record was poisoned"))?;
    seen.sort_by(|a, b| a.name.cmp(&b.name));
    seen.dedup_by(|a, b| a.name == b.name);
    if seen.is_empty() {
        return Err(ModelError::file(
            path,
            "the module has no parameters to export",
        ));
    }
    // burn-store writes through a scratch file created 0600; an exported
    // file is for others to read (a model zoo, a shared folder), as every
    // other file the project writes.
    #[cfg(unix)]
    {
        use std::os::unix::fs::PermissionsExt;
        std::fs::set_permissions(path, std::fs::Permissions::from_mode(0o644))
            .map_err(|e| ModelError::file(path, e))?;
    }
    crate::checkpoint::seal(path)?;
    Ok(seen)
}

/// Loads the safetensors file `path` (written by [`save_safetensors`]:
/// PyTorch's layout) into `module`, freshly built from the saved
/// configuration. Every parameter of the module must be in the file with
/// its shape, and the file must hold nothing else.
pub fn load_safetensors<M: Module>(mut module: M, path: &Path) -> Result<M> {
    let mut store = SafetensorsStore::from_file(path)
        .with_from_adapter(PyTorchToBurnAdapter)
        .skip_enum_variants(true);
    let applied = module
        .load_from(&mut store)
        .map_err(|e| ModelError::file(path, e))?;
    if !applied.missing.is_empty() || !applied.unused.is_empty() || !applied.errors.is_empty() {
        let missing: Vec<&str> = applied.missing.iter().map(|(p, _)| p.as_str()).collect();
        return Err(ModelError::file(
            path,
            format!(
                "does not match the network its config.json builds: missing {missing:?}, not used {:?}, errors {:?}",
                applied.unused, applied.errors
            ),
        ));
    }
    Ok(module)
}
