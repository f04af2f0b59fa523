//! Where NTP (Detector) loses: a trained `--method ntp-detector` run's NTP
//! rolled out on validation tasks with each input either true or
//! estimated: the demo's state rows (true, or the detector's from its
//! frames) × the observed state rows (the same). Both true is NTP on
//! states with this run's weights; both estimated is NTP (Detector) as
//! `ntg eval` scores it. Also prints the detector's mean position error on
//! the demos' and the rollouts' frames. Validation tasks only.
//!
//! ```text
//! cargo run --release -p ntg-trainer --example ntp_detector_inputs -- RUN TASKS
//! ```

use anyhow::{Context, bail};
use ctg_graph::{Environment, record_demonstration};
use env_blocks::BlocksExpert;
use ntg_trainer::blocks::{self, BlocksDomain, Seeds};
use ntg_trainer::domain::Domain;
use ntg_trainer::method::TrainedPolicy;
use ntg_trainer::method::ntp_detector::NtpOnDetector;
use ntg_trainer::run_dir::RunDir;
use ntg_trainer::spec::ObsKind;

/// Mean over cubes of the distance between estimated and true positions.
fn position_error(estimated: &[f32], truth: &[f32]) -> f64 {
    let cubes = env_blocks::world::NUM_OBJECTS;
    (0..cubes)
        .map(|k| {
            (0..3)
                .map(|c| f64::from(estimated[3 * k + c] - truth[3 * k + c]).powi(2))
                .sum::<f64>()
                .sqrt()
        })
        .sum::<f64>()
        / cubes as f64
}

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let [run, tasks] = args.as_slice() else {
        bail!("usage: ntp_detector_inputs RUN TASKS");
    };
    let tasks: usize = tasks.parse().context("TASKS")?;
    let run = RunDir::open(std::path::Path::new(run))?;
    let config: blocks::BlocksRunConfig = RunDir::read_json(&run.config_path())?;
    let device = ntg_model::cpu_device();
    let model = blocks::load_baseline(&run, &config, &device)?;
    let model = model
        .as_any()
        .downcast_ref::<NtpOnDetector>()
        .context("not an NTP (Detector) run")?;
    let domain = BlocksDomain::new(ObsKind::Vid, config.failures).at_primitive_level();
    let validation = env_blocks::validation_tasks(tasks)?;
    let seeds = Seeds::VALIDATION;
    // [demo estimated][observation estimated] -> (successes, goal fraction sum)
    let mut outcome = [[(0usize, 0.0f64); 2]; 2];
    let (mut demo_error, mut demo_rows, mut rollout_error, mut rollout_rows) = (0.0, 0, 0.0, 0);
    for (i, task) in validation.iter().enumerate() {
        let mut env = domain.env(task)?;
        let demo = record_demonstration(&mut env, &mut BlocksExpert::new(), seeds.demo + i as u64)?;
        let true_demo: Vec<Vec<f32>> = demo
            .observations()
            .iter()
            .map(|o| o.state().to_vec())
            .collect();
        let frames: Vec<Vec<f32>> = demo
            .observations()
            .iter()
            .map(|o| blocks::featurize(o, ObsKind::Vid))
            .collect();
        let estimated_demo = model.detector.predict_rows(&frames)?;
        for (e, t) in estimated_demo.iter().zip(&true_demo) {
            demo_error += position_error(e, t);
            demo_rows += 1;
        }
        for (d, demo_rows) in [&true_demo, &estimated_demo].into_iter().enumerate() {
            for (o, slot) in outcome[d].iter_mut().enumerate() {
                let agent = TrainedPolicy::condition(&model.ntp, demo_rows, domain.vocabulary())?;
                let (mut observation, _) = env.reset(seeds.rollout + i as u64)?;
                let mut ties = ntg_trainer::method::Ties::for_episode(seeds.rollout + i as u64);
                let mut taken = Vec::new();
                loop {
                    let truth = observation.state().to_vec();
                    let row = if o == 1 {
                        let estimated = model
                            .detector
                            .predict_rows(&[blocks::featurize(&observation, ObsKind::Vid)])?
                            .remove(0);
                        rollout_error += position_error(&estimated, &truth);
                        rollout_rows += 1;
                        estimated
                    } else {
                        truth
                    };
                    let action = agent.act(&row, &taken, &mut ties)?;
                    taken.push(action);
                    let step = env.step(action)?;
                    let done = step.is_done();
                    observation = step.observation;
                    if done {
                        break;
                    }
                }
                let (met, goals) = domain.goals(task, &env);
                slot.0 += usize::from(env.is_success());
                slot.1 += met as f64 / goals.max(1) as f64;
            }
        }
    }
    println!(
        "{} ({} validation tasks; detector position error: demo frames {:.4}, rollout frames {:.4})",
        run.root().display(),
        validation.len(),
        demo_error / demo_rows.max(1) as f64,
        rollout_error / rollout_rows.max(1) as f64
    );
    println!("| demo rows | observed rows | success | goals met |\n|---|---|---|---|");
    for (d, demo) in ["true", "estimated"].iter().enumerate() {
        for (o, observed) in ["true", "estimated"].iter().enumerate() {
            let (successes, goals) = outcome[d][o];
            println!(
                "| {demo} | {observed} | {successes}/{} | {:.3} |",
                validation.len(),
                goals / validation.len().max(1) as f64
            );
        }
    }
    Ok(())
}
