//! A module saved with its configuration: `config.json` (serde) beside
//! `model.bpk` (burn's burnpack). Shared by [`crate::NtgModel`] and
//! [`crate::FlatPolicy`]; every failure is a [`ModelError::File`] naming
//! the file.

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
    let weights = dir.join(WEIGHTS_FILE);
    module
        .clone()
        .save_file(&weights)
        .map_err(|e| ModelError::file(&weights, e))
}

/// Reads `dir/config.json` and checks it with `validate`.
pub(crate) fn load_config<C: DeserializeOwned>(
    dir: &Path,
    validate: impl FnOnce(&C) -> Result<()>,
) -> Result<C> {
    let path = dir.join(CONFIG_FILE);
    let text = std::fs::read_to_string(&path).map_err(|e| ModelError::file(&path, e))?;
    let config: C = serde_json::from_str(&text).map_err(|e| ModelError::file(&path, e))?;
    validate(&config).map_err(|e| ModelError::file(&path, e))?;
    Ok(config)
}

/// Loads `dir/model.bpk` into `module` (freshly built from the saved
/// configuration); a missing file or a mismatched record is an error.
pub(crate) fn load_weights<M: Module>(module: M, dir: &Path) -> Result<M> {
    let weights = dir.join(WEIGHTS_FILE);
    if !weights.is_file() {
        return Err(ModelError::file(&weights, "no such file"));
    }
    module
        .try_load_file(&weights)
        .map_err(|e| ModelError::file(&weights, e))
}
