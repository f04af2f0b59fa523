//! A module saved with its configuration: `config.json` (serde) beside
//! `model.bpk` (burn's burnpack). Shared by [`crate::NtgModel`] and
//! [`crate::FlatPolicy`]; every failure is a [`ModelError::File`] naming
//! the file.
//!
//! Every file saved here (and the optimizer state of
//! [`crate::save_optimizer`]) gets a sidecar `FILE.sha256` with its SHA-256,
//! written after it and checked before it is read: a file changed or
//! damaged after it was saved is an error that says so, not a confusing
//! failure deep in the decoder. Files saved before the sidecars existed
//! load unchecked.

use std::path::Path;

use burn::module::Module;
use serde::Serialize;
use serde::de::DeserializeOwned;

use crate::model::{CONFIG_FILE, WEIGHTS_FILE};
use crate::{ModelError, Result};

/// Writes `config` to `dir/config.json` and the weights of `module` to
/// `dir/model.bpk`, creating `dir` if needed.
pub(crate) fn save<M: Module, C: Serialize>(module: &M, config: &C, dir: &Path) -> Result<()> {
    std::fs::create_dir_all(dir).map_err(|e| ModelError::file(dir, e))?;
    let config_path = dir.join(CONFIG_FILE);
    let json =
        serde_json::to_string_pretty(config).map_err(|e| ModelError::file(&config_path, e))?;
    std::fs::write(&config_path, json).map_err(|e| ModelError::file(&config_path, e))?;
    seal(&config_path)?;
    let weights = dir.join(WEIGHTS_FILE);
    module
        .clone()
        .save_file(&weights)
        .map_err(|e| ModelError::file(&weights, e))?;
    seal(&weights)
}

/// The sidecar that holds `path`'s checksum: `path` with `.sha256` added.
fn sidecar(path: &Path) -> std::path::PathBuf {
    let mut name = path.as_os_str().to_owned();
    name.push(".sha256");
    name.into()
}

fn sha256_hex(path: &Path) -> Result<String> {
    use sha2::Digest;
    let bytes = std::fs::read(path).map_err(|e| ModelError::file(path, e))?;
    let digest = sha2::Sha256::digest(&bytes);
    Ok(digest.iter().map(|b| format!("{b:02x}")).collect())
}

/// Writes the checksum of the file `path` beside it (`path.sha256`).
pub(crate) fn seal(path: &Path) -> Result<()> {
    let side = sidecar(path);
    std::fs::write(&side, sha256_hex(path)? + "\n").map_err(|e| ModelError::file(&side, e))
}

/// Checks the file `path` against its checksum, when it has one.
pub(crate) fn verify(path: &Path) -> Result<()> {
    let side = sidecar(path);
    let expected = match std::fs::read_to_string(&side) {
        Ok(text) => text.trim().to_owned(),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(()),
        Err(e) => return Err(ModelError::file(&side, e)),
    };
    let found = sha256_hex(path)?;
    if found != expected {
        return Err(ModelError::file(
            path,
            format!(
                "checksum mismatch: the file changed or was damaged after it was saved (SHA-256 {found}, {} says {expected})",
                side.display()
            ),
        ));
    }
    Ok(())
}

/// Reads `dir/config.json` and checks it with `validate`.
pub(crate) fn load_config<C: DeserializeOwned>(
    dir: &Path,
    validate: impl FnOnce(&C) -> Result<()>,
) -> Result<C> {
    let path = dir.join(CONFIG_FILE);
    let text = std::fs::read_to_string(&path).map_err(|e| ModelError::file(&path, e))?;
    verify(&path)?;
    let config: C = serde_json::from_str(&text).map_err(|e| ModelError::file(&path, e))?;
    validate(&config).map_err(|e| ModelError::file(&path, e))?;
    Ok(config)
}

/// Loads `dir/model.bpk` into `module` (freshly built from the saved
/// configuration), or, in a folder without one, `dir/model.safetensors`
/// (a model zoo entry); a missing file or a mismatched record is an error.
pub(crate) fn load_weights<M: Module>(module: M, dir: &Path) -> Result<M> {
    let mut weights = dir.join(WEIGHTS_FILE);
    let safetensors = dir.join(crate::export::SAFETENSORS_WEIGHTS_FILE);
    let module = if !weights.is_file() && safetensors.is_file() {
        // A model zoo entry: the weights in PyTorch's layout.
        weights = safetensors;
        verify(&weights)?;
        decode(&weights, || {
            crate::export::load_safetensors(module, &weights)
        })?
    } else {
        if !weights.is_file() {
            return Err(ModelError::file(&weights, "no such file"));
        }
        verify(&weights)?;
        decode(&weights, || {
            module
                .try_load_file(&weights)
                .map_err(|e| ModelError::file(&weights, e))
        })?
    };
    let mut check = NonFinite::default();
    module.visit(&mut check);
    if check.tensors > 0 {
        return Err(ModelError::file(
            &weights,
            format!(
                "{} of its weight tensors hold NaN or infinite values (the run that saved them diverged); use an earlier checkpoint or retrain with a lower learning rate",
                check.tensors
            ),
        ));
    }
    Ok(module)
}

/// Runs `load`, burn's decoder of the file `path`, turning a panic inside
/// it into an error naming the file: burn panics on some malformed records
/// (e.g. an optimizer record without parameter ids, found by the
/// `checkpoint` fuzz target) instead of returning an error. The panic hook
/// is silenced meanwhile, so the user sees the error alone; files are
/// loaded before training starts its worker threads.
pub(crate) fn decode<T>(path: &Path, load: impl FnOnce() -> Result<T>) -> Result<T> {
    quietly(load).unwrap_or_else(|why| {
        Err(ModelError::file(
            path,
            format!("not a valid checkpoint file ({why}); use another checkpoint or retrain"),
        ))
    })
}

/// Runs `f`, returning the message of a panic inside it (burn's) as an
/// error instead of unwinding further; the panic hook is silenced
/// meanwhile, so nothing is printed.
pub(crate) fn quietly<T>(f: impl FnOnce() -> T) -> std::result::Result<T, String> {
    let hook = std::panic::take_hook();
    std::panic::set_hook(Box::new(|_| {}));
    let outcome = std::panic::catch_unwind(std::panic::AssertUnwindSafe(f));
    std::panic::set_hook(hook);
    outcome.map_err(|payload| {
        payload
            .downcast_ref::<&str>()
            .map(|s| (*s).to_owned())
            .or_else(|| payload.downcast_ref::<String>().cloned())
            .unwrap_or_else(|| "a panic without a message".into())
    })
}

/// Counts the float parameters that hold a NaN or an infinity.
#[derive(Default)]
struct NonFinite {
    tensors: usize,
}

impl burn::module::ModuleVisitor for NonFinite {
    fn visit_float<const D: usize>(
        &mut self,
        param: &burn::module::Param<burn::tensor::Tensor<D>>,
    ) {
        // Read back as f32 (converted from whatever the backend stores):
        // GPU backends keep booleans as integers, so reading a bool tensor
        // with `try_to_vec::<bool>` fails there (it counted every tensor of
        // a wgpu run as non-finite).
        let finite = param.val().is_finite().all().float().into_data();
        if finite
            .try_to_vec_as::<f32>()
            .map_or(true, |v| v.contains(&0.0))
        {
            self.tensors += 1;
        }
    }
}
