//! How much do the observation windows say about the CTG node (the last
//! gesture) and the next gesture? Fits nearest-centroid classifiers on
//! Suturing + Knot Tying windows and scores them on Needle Passing, with a
//! majority-class baseline beside them. A sanity probe of the synthetic
//! stand-in (or of a real copy: pass its root), not a result of NTG.
//!
//! `cargo run --release -p env-jigsaws --example observation_probe [ROOT] [SEED]`

use std::collections::BTreeMap;

use ctg_graph::ActionId;
use env_jigsaws::{
    ColumnStats, Dataset, ObservationConfig, ObservationEncoder, SynthConfig, Task, generate,
};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let mut args = std::env::args().skip(1);
    let root = args.next();
    let seed: u64 = args.next().map_or(Ok(0), |s| s.parse())?;
    let data = match root {
        Some(r) if r != "-" => Dataset::load(r.as_ref())?.dataset,
        _ => generate(&SynthConfig::new(seed))?.dataset,
    };
    let train: Vec<_> = data
        .trials(Task::Suturing)
        .iter()
        .chain(data.trials(Task::KnotTying))
        .collect();
    let encoder = ObservationEncoder::new(
        ObservationConfig::default(),
        ColumnStats::fit(train.iter().copied())?,
    )?;
    let train_demos = encoder.demonstrations(train.iter().copied())?;
    let test_demos = encoder.demonstrations(data.trials(Task::NeedlePassing))?;
    for (what, label) in [("node (last gesture)", 0usize), ("next gesture", 1usize)] {
        let labels = |d: &ctg_graph::Demonstration<Vec<f32>>| -> Vec<ActionId> {
            if label == 0 {
                d.node_labels()
            } else {
                d.next_actions()
            }
        };
        let mut sums: BTreeMap<ActionId, (Vec<f64>, usize)> = BTreeMap::new();
        for d in &train_demos {
            for (o, l) in d.observations().iter().zip(labels(d)) {
                let e = sums.entry(l).or_insert_with(|| (vec![0.0; o.len()], 0));
                e.0.iter_mut().zip(o).for_each(|(s, v)| *s += f64::from(*v));
                e.1 += 1;
            }
        }
        let centroids: Vec<(ActionId, Vec<f64>)> = sums
            .into_iter()
            .map(|(l, (s, n))| (l, s.into_iter().map(|v| v / n as f64).collect()))
            .collect();
        let (mut correct, mut total) = (0, 0);
        let mut counts: BTreeMap<ActionId, usize> = BTreeMap::new();
        for d in &test_demos {
            for (o, l) in d.observations().iter().zip(labels(d)) {
                let best = centroids
                    .iter()
                    .map(|(c, m)| {
                        let dist: f64 = m
                            .iter()
                            .zip(o)
                            .map(|(a, b)| (a - f64::from(*b)).powi(2))
                            .sum();
                        (dist, *c)
                    })
                    .min_by(|a, b| a.0.total_cmp(&b.0))
                    .map(|(_, c)| c);
                correct += usize::from(best == Some(l));
                total += 1;
                *counts.entry(l).or_default() += 1;
            }
        }
        let majority = counts.values().max().copied().unwrap_or(0);
        println!(
            "{what}: nearest-centroid accuracy on Needle Passing {:.3} ({correct}/{total}); majority class {:.3}",
            correct as f64 / total as f64,
            majority as f64 / total as f64
        );
    }
    Ok(())
}
