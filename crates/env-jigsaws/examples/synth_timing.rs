//! Times generating, writing and reading the full synthetic dataset.
use std::time::Instant;

use env_jigsaws::{Dataset, SynthConfig, write_synthetic};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let out = std::env::args()
        .nth(1)
        .ok_or("usage: synth_timing OUT_DIR")?;
    let t = Instant::now();
    let synth = write_synthetic(&SynthConfig::new(7), out.as_ref())?;
    println!("generate+write: {:.2?}", t.elapsed());
    let t = Instant::now();
    let loaded = Dataset::load(out.as_ref())?;
    println!("load: {:.2?}", t.elapsed());
    println!("same content: {}", loaded.dataset == synth.dataset);
    for s in loaded.dataset.stats().tasks {
        println!("{}: {} trials, {} frames", s.task, s.trials, s.frames);
    }
    Ok(())
}
