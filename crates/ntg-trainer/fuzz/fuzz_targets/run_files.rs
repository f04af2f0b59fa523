//! Fuzzes the readers of a run folder's files, as `ntg train --resume`,
//! `ntg eval` and `ntg reproduce` call them. The first byte picks the
//! file, the rest is its contents:
//!
//! - `0`: `config.json`: which domain owns it, the domain's run
//!   configuration and its checks, and the differences against a valid
//!   configuration (the `--resume` message);
//! - `1`: `metrics.jsonl`: the epoch seconds and the lines a resume drops
//!   (after which no kept line may be past the checkpoint);
//! - `2`: `best/selection.json`: the selected epoch;
//! - `3`: `train.lock`: taking the writer lock.
//!
//! Any input may be refused, none may panic.
//!
//! `cargo +nightly fuzz run run_files CORPUS seeds -- -max_total_time=600`
#![no_main]

use libfuzzer_sys::fuzz_target;
use ntg_trainer::domain::DomainId;
use ntg_trainer::run_dir::{RunDir, config_differences, drop_lines_from_epoch, read_jsonl};
use ntg_trainer::method::MethodId;
use ntg_trainer::spec::ObsKind;
use ntg_trainer::{blocks, collect};

fuzz_target!(|data: &[u8]| {
    let Some((&which, bytes)) = data.split_first() else {
        return;
    };
    let dir = tempfile::tempdir().expect("a temporary folder");
    let root = dir.path();
    let valid = serde_json::to_value(collect::CollectRunConfig::new(
        MethodId::Ntg,
        ObsKind::State,
        vec![2, 4],
        10,
        5,
        3,
        0,
    )).unwrap();
    std::fs::write(root.join("config.json"), serde_json::to_vec(&valid).unwrap()).unwrap();
    match which % 4 {
        0 => {
            std::fs::write(root.join("config.json"), bytes).unwrap();
            let run = RunDir::open(root).unwrap();
            if let Ok(value) = RunDir::read_json::<serde_json::Value>(&run.config_path()) {
                let _ = DomainId::of_run(&value);
                let _ = config_differences(&value, &valid);
                let _ = config_differences(&valid, &value);
            }
            let _ = RunDir::read_json::<blocks::BlocksRunConfig>(&run.config_path());
            if let Ok(config) = RunDir::read_json::<collect::CollectRunConfig>(&run.config_path()) {
                let _ = config.validate();
            }
        }
        1 => {
            let run = RunDir::open(root).unwrap();
            std::fs::write(run.metrics_path(), bytes).unwrap();
            let _ = run.epoch_seconds();
            let done = bytes.len() % 7;
            if drop_lines_from_epoch(&run.metrics_path(), done).is_ok() {
                let kept: Vec<serde_json::Value> = read_jsonl(&run.metrics_path())
                    .expect("the lines a resume keeps still parse");
                assert!(kept.iter().all(|line| {
                    line.get("epoch")
                        .and_then(serde_json::Value::as_u64)
                        .is_none_or(|e| e < done as u64)
                }));
            }
        }
        2 => {
            let run = RunDir::open(root).unwrap();
            std::fs::create_dir_all(run.best_dir()).unwrap();
            std::fs::write(run.best_dir().join("selection.json"), bytes).unwrap();
            let _ = ntg_trainer::fit::selected_epoch(&run);
        }
        _ => {
            let run = RunDir::open(root).unwrap();
            std::fs::write(root.join(ntg_trainer::run_dir::LOCK_FILE), bytes).unwrap();
            let _ = run.lock();
        }
    }
});
