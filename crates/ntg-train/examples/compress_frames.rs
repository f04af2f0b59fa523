//! Measures a frame cache stored compressed against the same cache stored
//! plainly: writes a compressed copy of the dataset in `DIR` (a stage A
//! `dataset` folder or one of its parts) to `OUT`, checks that every row
//! reads back the same, and prints both sizes, the time the compression
//! took, and the median time to read a row from each.
//!
//! `cargo run --release -p ntg-train --example compress_frames -- DIR OUT`
//! (`OUT` must not exist: nothing is overwritten).

use std::path::PathBuf;
use std::time::Instant;

use anyhow::{Context, bail, ensure};
use ntg_train::dataset::DemoDataset;

fn folder_bytes(dir: &std::path::Path) -> anyhow::Result<u64> {
    let mut total = 0;
    for entry in std::fs::read_dir(dir).with_context(|| format!("reading {}", dir.display()))? {
        total += entry?.metadata()?.len();
    }
    Ok(total)
}

/// Median seconds to read one of `rows` rows, over `n` rows spread evenly.
fn median_row_seconds(dataset: &DemoDataset, rows: usize, n: usize) -> f64 {
    let mut times: Vec<f64> = (0..n)
        .map(|k| {
            let row = k * rows / n;
            let start = Instant::now();
            std::hint::black_box(dataset.row(row));
            start.elapsed().as_secs_f64()
        })
        .collect();
    times.sort_by(f64::total_cmp);
    times[n / 2]
}

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let [dir, out] = args.as_slice() else {
        bail!(
            "usage: compress_frames DIR OUT (a dataset folder, and a folder to write that does not exist)"
        );
    };
    let (dir, out) = (PathBuf::from(dir), PathBuf::from(out));
    ensure!(
        !out.exists(),
        "{}: exists; choose a new folder",
        out.display()
    );
    let plain = DemoDataset::load_mapped(&dir)?;
    let rows = plain.num_rows();
    let start = Instant::now();
    plain.save_compressed(&out)?;
    let compress_seconds = start.elapsed().as_secs_f64();
    let packed = DemoDataset::load_mapped(&out)?;
    ensure!(packed.num_rows() == rows, "row counts differ");
    for row in 0..rows {
        ensure!(packed.row(row) == plain.row(row), "row {row} differs");
    }
    let (before, after) = (folder_bytes(&dir)?, folder_bytes(&out)?);
    let n = rows.min(2000);
    println!(
        "{rows} rows of {} values: {:.2} GB -> {:.3} GB ({:.0}x smaller), compressed in {compress_seconds:.0} s",
        plain.obs_dim(),
        before as f64 / 1e9,
        after as f64 / 1e9,
        before as f64 / after.max(1) as f64
    );
    println!(
        "median time to read a row: {:.3} ms plain (mapped), {:.3} ms compressed ({n} rows)",
        1e3 * median_row_seconds(&plain, rows, n),
        1e3 * median_row_seconds(&packed, rows, n)
    );
    Ok(())
}
