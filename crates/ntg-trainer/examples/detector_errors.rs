//! Where a trained NTP (Detector) detector errs, on held-out validation
//! frames: the error per axis, the part of the error all cubes of a frame
//! share (an error in where the gripper is: the rows are relative to it)
//! and the rest, and the error by cube height. A diagnostic for choosing
//! the detector's design on validation frames, never on test tasks.
//!
//! ```text
//! cargo run --release -p ntg-trainer --example detector_errors -- RUN [TASKS]
//! ```
//!
//! `RUN` is a run folder with a `detector_stage` (an `ntg train --method
//! ntp-detector` run or a `detector_heldout` output); the selected detector
//! is scored on one episode of each of the `TASKS` (default 50) validation
//! tasks after the ones that selected it: the frames of `held_out.json`.

use anyhow::Context;
use ntg_model::Detector;
use ntg_trainer::blocks::{self, BlocksRunConfig, VALIDATION_DEMO_SEED_BASE};
use ntg_trainer::method::detector::{DETECTOR_STAGE_DIR, DetectorDataset};
use ntg_trainer::run_dir::RunDir;
use ntg_trainer::spec::ObsKind;

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let run = std::path::PathBuf::from(args.first().context("usage: detector_errors RUN [TASKS]")?);
    let tasks: usize = args.get(1).map_or(Ok(50), |v| v.parse()).context("TASKS")?;
    let stage = run.join(DETECTOR_STAGE_DIR);
    let config: serde_json::Value = RunDir::read_json(&stage.join("config.json"))?;
    let select = config["settings"]["validation_tasks"]
        .as_u64()
        .context("the stage's config.json has no settings.validation_tasks")?
        as usize;
    let device = ntg_model::cpu_device();
    let detector = Detector::load(stage.join("best"), &device)?;
    let scale = detector.config.position_scale.unwrap_or(1.0);
    let validation = env_blocks::validation_tasks(select + tasks)?;
    let failures = RunDir::read_json::<BlocksRunConfig>(&run.join("config.json"))
        .map(|c| c.failures)
        .unwrap_or(true);
    let frames = DetectorDataset::record(
        &validation[select..],
        1,
        VALIDATION_DEMO_SEED_BASE + 1,
        blocks::env_config(ObsKind::Vid, failures),
    )?;
    let k = detector.config.num_objects;
    let (mut axis, mut common, mut rest, mut total) = ([0.0f64; 3], 0.0f64, 0.0f64, 0.0f64);
    // Error by the cube's height above the gripper's, in bins of 0.05.
    let mut by_height: std::collections::BTreeMap<i64, (f64, usize)> = Default::default();
    let all: Vec<usize> = (0..frames.len()).collect();
    for chunk in all.chunks(256) {
        let (x, rows) = frames.tensors(chunk, &device);
        let out = ntg_model::nn::to_vec(detector.forward(x)?)?;
        let rows = ntg_model::nn::to_vec(rows)?;
        let (w_out, w_row) = (out.len() / chunk.len(), rows.len() / chunk.len());
        for i in 0..chunk.len() {
            let diff: Vec<[f64; 3]> = (0..k)
                .map(|c| {
                    std::array::from_fn(|a| {
                        f64::from(out[i * w_out + 3 * c + a] * scale)
                            - f64::from(rows[i * w_row + 3 * c + a])
                    })
                })
                .collect();
            let mean: [f64; 3] =
                std::array::from_fn(|a| diff.iter().map(|d| d[a]).sum::<f64>() / k as f64);
            common += mean.iter().map(|m| m * m).sum::<f64>().sqrt();
            for (c, d) in diff.iter().enumerate() {
                let norm = |v: [f64; 3]| v.iter().map(|x| x * x).sum::<f64>().sqrt();
                let e = norm(*d);
                total += e / k as f64;
                rest += norm(std::array::from_fn(|a| d[a] - mean[a])) / k as f64;
                for a in 0..3 {
                    axis[a] += d[a].abs() / k as f64;
                }
                let z = f64::from(rows[i * w_row + 3 * c + 2]);
                let bin = by_height.entry((z / 0.05).floor() as i64).or_default();
                bin.0 += e;
                bin.1 += 1;
            }
        }
    }
    let n = frames.len() as f64;
    println!(
        "{} frames: position error {:.4}; |x| {:.4} |y| {:.4} |z| {:.4}; shared by the frame's cubes {:.4}, the rest {:.4}",
        frames.len(),
        total / n,
        axis[0] / n,
        axis[1] / n,
        axis[2] / n,
        common / n,
        rest / n
    );
    for (bin, (sum, count)) in by_height {
        println!(
            "  cube z - gripper z in [{:.2}, {:.2}): {count} cubes, error {:.4}",
            bin as f64 * 0.05,
            (bin + 1) as f64 * 0.05,
            sum / count as f64
        );
    }
    Ok(())
}
