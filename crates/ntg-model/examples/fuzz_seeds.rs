//! Writes seed inputs for the `checkpoint` fuzz target (`fuzz/`): a small
//! model's `config.json`, `model.bpk` and Adam state, each prefixed with
//! the byte that makes the target read it as that file.
//!
//! `cargo run -p ntg-model --example fuzz_seeds -- DIR`

use burn::optim::{AdamConfig, GradientsParams, ModuleOptimizer};
use ntg_model::{NtgModel, cpu_device};

include!("../fuzz/small_config.rs");

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let out = std::env::args_os()
        .nth(1)
        .ok_or("usage: fuzz_seeds DIR (the folder to write the seeds to)")?;
    let out = std::path::PathBuf::from(out);
    std::fs::create_dir_all(&out)?;
    let config = small_config();
    let device = cpu_device().autodiff();
    let model = NtgModel::new(config, &device)?;
    let saved = tempfile::tempdir()?;
    model.save(saved.path())?;
    let mut optimizer: ModuleOptimizer = AdamConfig::new().init();
    let grads = GradientsParams::from_grads(model.localizer.nodes.val().sum().backward(), &model);
    let _ = optimizer.step(1e-3, model, grads);
    ntg_model::save_optimizer(&optimizer, saved.path().join("optimizer.bpk"))?;
    for (byte, file) in [(0u8, "config.json"), (1, "model.bpk"), (2, "optimizer.bpk")] {
        let mut bytes = vec![byte];
        bytes.extend(std::fs::read(saved.path().join(file))?);
        std::fs::write(out.join(file), bytes)?;
    }
    println!("wrote 3 seeds to {}", out.display());
    Ok(())
}
