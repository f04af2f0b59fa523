//! Fuzzes what `NtgModel::load` reads from a checkpoint folder: the first
//! byte picks the file, the rest is its contents.
//!
//! - `0`: `config.json` (serde, then `NtgConfig::validate`);
//! - `1`: `model.bpk` (burn's burnpack header and tensors) beside a valid
//!   small `config.json`;
//! - `2`: an optimizer state file (`load_optimizer`).
//!
//! No checksum sidecars are written, so the bytes reach the decoders (as
//! they do for files saved before sidecars existed). Any input may be
//! refused, none may panic (weights that load are finite: the loader
//! refuses NaN and infinity).
//!
//! Seeds: `cargo run -p ntg-model --example fuzz_seeds -- DIR`, then
//! `cargo +nightly fuzz run checkpoint CORPUS DIR -- -max_total_time=600`.
#![no_main]

use std::sync::OnceLock;

use burn::optim::{AdamConfig, ModuleOptimizer};
use libfuzzer_sys::fuzz_target;
use ntg_model::{NtgConfig, NtgModel, cpu_device, load_optimizer};

include!("../small_config.rs");

/// The small model the `model.bpk` inputs are loaded into.
fn config() -> &'static NtgConfig {
    static CONFIG: OnceLock<NtgConfig> = OnceLock::new();
    CONFIG.get_or_init(small_config)
}

fuzz_target!(|data: &[u8]| {
    let Some((&which, bytes)) = data.split_first() else {
        return;
    };
    let dir = tempfile::tempdir().expect("a temporary folder");
    match which % 3 {
        0 => {
            std::fs::write(dir.path().join("config.json"), bytes).unwrap();
            let _ = NtgModel::load_config(dir.path());
        }
        1 => {
            let json = serde_json::to_string(config()).unwrap();
            std::fs::write(dir.path().join("config.json"), json).unwrap();
            std::fs::write(dir.path().join("model.bpk"), bytes).unwrap();
            let _ = NtgModel::load(dir.path(), &cpu_device());
        }
        _ => {
            let path = dir.path().join("optimizer.bpk");
            std::fs::write(&path, bytes).unwrap();
            let fresh: ModuleOptimizer = AdamConfig::new().init();
            let _ = load_optimizer(fresh, &path);
        }
    }
});
