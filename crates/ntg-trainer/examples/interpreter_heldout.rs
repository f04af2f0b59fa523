//! How well a block-stacking video run's demo interpreter transcribes demo
//! videos it never saw: one video of each of the first TASKS validation
//! tasks (never test tasks), recorded as `ntg eval --split validation`
//! records its demos (same seeds, failures as the run), encoded by the
//! run's frozen stage A encoder and decoded greedily by the interpreter of
//! the run's selected epoch.
//!
//! Prints the token accuracy (tokens equal at the same position, over the
//! longer of the two sequences, summed over videos), the fraction of
//! videos transcribed exactly, and what the errors are: each wrong video is
//! aligned with its true actions by edit distance, and every edit is
//! counted as a wrong cube (`pick(A)` for `pick(B)`), a wrong verb, a
//! missing or an extra action, and as next to a repeated action (a retry of
//! a failed grasp or drop) or not.
//!
//! ```text
//! cargo run --release -p ntg-trainer --example interpreter_heldout -- RUN [TASKS]
//! ```

use anyhow::{Context, ensure};
use ctg_graph::ActionId;
use ntg_trainer::blocks::{self, BlocksRunConfig};
use ntg_trainer::fit::TrainedModel;
use ntg_trainer::method::on_frames::VideoNtgModel;
use ntg_trainer::run_dir::RunDir;

fn main() -> anyhow::Result<()> {
    let usage = "usage: interpreter_heldout RUN [TASKS]";
    let args: Vec<String> = std::env::args().skip(1).collect();
    let run = RunDir::open(std::path::Path::new(args.first().context(usage)?))?;
    let tasks: usize = args.get(1).map_or(Ok(200), |t| t.parse()).context(usage)?;
    let config: BlocksRunConfig = RunDir::read_json(&run.config_path())?;
    let video = config
        .video
        .as_ref()
        .with_context(|| format!("{} is not a video run", run.root().display()))?;
    let dir = match ntg_trainer::fit::selected_epoch(&run)? {
        Some(_) => run.best_dir(),
        None => run.checkpoint_dir(),
    };
    let model = VideoNtgModel::load_from(&dir, &ntg_model::cpu_device())?;

    let validation = env_blocks::validation_tasks(tasks)?;
    let (mut equal, mut total, mut exact) = (0usize, 0usize, 0usize);
    let mut frames_per_video = Vec::with_capacity(tasks);
    let vocabulary = env_blocks::vocabulary(false, env_blocks::ActionLevel::Flat);
    let mut edits = EditCounts::default();
    // Videos without / with a repeated action (a retry), and how many of
    // them are transcribed exactly.
    let (mut with_retry, mut exact_with_retry) = ([0usize; 2], [0usize; 2]);
    for (i, seed) in blocks::validation_video_pairs(tasks) {
        let demo = blocks::record_video(
            validation[i].clone(),
            config.failures,
            video.camera,
            &video.frames,
            seed,
        )?;
        let embedded = model.encode_rows(demo.frames())?;
        let decoded: Vec<ActionId> = model.policy.interpreter.decode(&embedded)?;
        let truth = demo.actions();
        equal += decoded.iter().zip(truth).filter(|(a, b)| a == b).count();
        total += truth.len().max(decoded.len());
        exact += usize::from(decoded.as_slice() == truth);
        let retried = truth.windows(2).any(|w| w[0] == w[1]);
        with_retry[usize::from(retried)] += 1;
        exact_with_retry[usize::from(retried)] += usize::from(decoded.as_slice() == truth);
        if decoded.as_slice() != truth {
            if std::env::var_os("SHOW_WRONG").is_some() {
                let names = |a: &[ActionId]| {
                    a.iter()
                        .map(|&x| vocabulary.name(x).unwrap_or("?"))
                        .collect::<Vec<_>>()
                        .join(" ")
                };
                println!("truth   {}\ndecoded {}\n", names(truth), names(&decoded));
            }
            edits.add(&vocabulary, truth, &decoded);
        }
        frames_per_video.push(demo.num_frames());
    }
    ensure!(total > 0, "no validation videos");
    frames_per_video.sort_unstable();
    println!(
        "{tasks} held-out validation videos ({} to {} frames, median {}): token accuracy {:.4} ({equal}/{total}), transcribed exactly {exact}/{tasks} = {:.3}",
        frames_per_video[0],
        frames_per_video[tasks - 1],
        frames_per_video[tasks / 2],
        equal as f64 / total as f64,
        exact as f64 / tasks as f64,
    );
    println!(
        "edits in the {} wrong transcriptions: wrong cube {}, wrong verb {}, missing action {}, extra action {}; \
         of them next to a repeated true action (a retry) {}; wrong videos with a retry {}",
        tasks - exact,
        edits.wrong_cube,
        edits.wrong_verb,
        edits.missing,
        edits.extra,
        edits.near_retry,
        edits.videos_with_retry,
    );
    println!(
        "transcribed exactly: {}/{} videos without a retry, {}/{} with one",
        exact_with_retry[0], with_retry[0], exact_with_retry[1], with_retry[1],
    );
    Ok(())
}

/// Edits between true and decoded action sequences, by kind.
#[derive(Default)]
struct EditCounts {
    wrong_cube: usize,
    wrong_verb: usize,
    missing: usize,
    extra: usize,
    near_retry: usize,
    videos_with_retry: usize,
}

impl EditCounts {
    /// Aligns `decoded` with `truth` (Levenshtein, unit costs) and counts
    /// each edit of one alignment.
    fn add(
        &mut self,
        vocabulary: &ctg_graph::Vocabulary,
        truth: &[ActionId],
        decoded: &[ActionId],
    ) {
        let (n, m) = (truth.len(), decoded.len());
        let mut d = vec![vec![0usize; m + 1]; n + 1];
        for (i, row) in d.iter_mut().enumerate() {
            row[0] = i;
        }
        for (j, cell) in d[0].iter_mut().enumerate() {
            *cell = j;
        }
        for i in 1..=n {
            for j in 1..=m {
                let sub = d[i - 1][j - 1] + usize::from(truth[i - 1] != decoded[j - 1]);
                d[i][j] = sub.min(d[i - 1][j] + 1).min(d[i][j - 1] + 1);
            }
        }
        let repeated = |i: usize| {
            (i > 0 && truth[i - 1] == truth[i]) || (i + 1 < n && truth[i + 1] == truth[i])
        };
        self.videos_with_retry += usize::from(truth.windows(2).any(|w| w[0] == w[1]));
        let verb = |a: ActionId| {
            let name = vocabulary.name(a).unwrap_or("?");
            name.split('(').next().unwrap_or(name).to_owned()
        };
        let (mut i, mut j) = (n, m);
        while i > 0 || j > 0 {
            if i > 0
                && j > 0
                && d[i][j] == d[i - 1][j - 1] + usize::from(truth[i - 1] != decoded[j - 1])
            {
                if truth[i - 1] != decoded[j - 1] {
                    if verb(truth[i - 1]) == verb(decoded[j - 1]) {
                        self.wrong_cube += 1;
                    } else {
                        self.wrong_verb += 1;
                    }
                    self.near_retry += usize::from(repeated(i - 1));
                }
                i -= 1;
                j -= 1;
            } else if i > 0 && d[i][j] == d[i - 1][j] + 1 {
                self.missing += 1;
                self.near_retry += usize::from(repeated(i - 1));
                i -= 1;
            } else {
                self.extra += 1;
                self.near_retry += usize::from(i > 0 && repeated(i - 1));
                j -= 1;
            }
        }
    }
}
