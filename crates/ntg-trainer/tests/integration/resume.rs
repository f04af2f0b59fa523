//! Killing a training run and resuming it gives the same final weights as an
//! uninterrupted run with the same seed (smoke scale).

use std::panic::{AssertUnwindSafe, catch_unwind};

use burn::module::Module;
use ntg_model::NtgModel;
use ntg_trainer::blocks::{BlocksRunConfig, ObsKind, train_run};
use ntg_trainer::fit::OptimConfig;
use ntg_trainer::run_dir::RunDir;

fn config() -> BlocksRunConfig {
    BlocksRunConfig {
        obs: ObsKind::State,
        train_tasks: 4,
        demos_per_task: 2,
        failures: true,
        model_seed: 7,
        state_hidden_layers: 1,
        pairwise: false,
        validation_tasks: 5,
        validate_every: 0,
        permute_objects: true,
        exclude_held_out_renamings: true,
        edge_fusion_hidden: 0,
        retry_weight: 3.0,
        detach_gcn_from_edges: true,
        soft_edges: true,
        ablation: Default::default(),
        video: None,
        method: ntg_trainer::method::MethodId::Ntg,
        detector: None,
        ntp_core: Default::default(),
        tasks: None,
        structure_benchmark: false,
        executed_node: false,
        state_height_clamp: None,
        memory: false,
        end_after_demo: false,
        interpreter: None,
        location_step_prior: None,
        optim: OptimConfig {
            epochs: 3,
            batch_size: 3,
            learning_rate: 3e-3,
            seed: 11,
            token_dropout: 0.3,
            cosine_decay: true,
            gcn_from_other_demo: true,
            shards: 2,
        },
    }
}

fn metrics_without_time(run: &RunDir) -> Vec<serde_json::Value> {
    std::fs::read_to_string(run.metrics_path())
        .unwrap()
        .lines()
        .map(|l| {
            let mut v: serde_json::Value = serde_json::from_str(l).unwrap();
            let fields = v.as_object_mut().unwrap();
            fields.remove("seconds");
            fields.remove("cpu_seconds");
            v
        })
        .collect()
}

/// Trains `config` in `run`, killed (a panic) after epoch 1, then resumed
/// to the end.
fn train_killed_then_resumed(run: &RunDir, config: &BlocksRunConfig) {
    let device = ntg_model::cpu_device().autodiff();
    let outcome = catch_unwind(AssertUnwindSafe(|| {
        train_run(run, config, &device, |m| {
            if m.epoch == 1 {
                panic!("simulated kill after epoch 1");
            }
        })
    }));
    assert!(
        outcome.is_err(),
        "the simulated kill must interrupt training"
    );
    assert_eq!(metrics_without_time(run).len(), 2);
    train_run(run, config, &device, |_| {}).unwrap();
}

/// Every float parameter of the NTG model saved in `dir`, in visiting
/// order (the checkpoint file itself may carry per-save metadata).
fn weights(dir: std::path::PathBuf) -> Vec<Vec<f32>> {
    let model = NtgModel::load(dir, &ntg_model::cpu_device()).unwrap();
    let mut collector = ParamCollector(Vec::new());
    model.visit(&mut collector);
    collector.0
}

#[test]
fn killed_and_resumed_run_matches_uninterrupted_run() {
    let tmp = tempfile::tempdir().unwrap();
    let device = ntg_model::cpu_device().autodiff();

    let straight = RunDir::create(&tmp.path().join("straight")).unwrap();
    train_run(&straight, &config(), &device, |_| {}).unwrap();

    let killed = RunDir::create(&tmp.path().join("killed")).unwrap();
    train_killed_then_resumed(&killed, &config());

    assert_eq!(
        metrics_without_time(&killed),
        metrics_without_time(&straight)
    );
    // Every epoch was scored on the validation tasks, once, and both runs
    // selected the same epoch.
    let validation = |run: &RunDir| std::fs::read_to_string(run.validation_path()).unwrap();
    assert_eq!(validation(&straight).lines().count(), 3);
    assert_eq!(validation(&killed), validation(&straight));
    let selected = |run: &RunDir| ntg_trainer::fit::selected_epoch(run).unwrap().unwrap();
    assert_eq!(selected(&killed), selected(&straight));
    // Compare the final and the selected weights parameter by parameter.
    for (a, b) in [
        (
            weights(killed.checkpoint_dir()),
            weights(straight.checkpoint_dir()),
        ),
        (weights(killed.best_dir()), weights(straight.best_dir())),
    ] {
        assert!(!a.is_empty());
        assert_eq!(a.len(), b.len());
        for (i, (x, y)) in a.iter().zip(&b).enumerate() {
            assert!(
                x == y,
                "parameter {i} differs between the resumed and the uninterrupted run"
            );
        }
    }
}

/// Collects every float parameter of a module, in visiting order.
struct ParamCollector(Vec<Vec<f32>>);

impl burn::module::ModuleVisitor for ParamCollector {
    fn visit_float<const D: usize>(
        &mut self,
        param: &burn::module::Param<burn::tensor::Tensor<D>>,
    ) {
        self.0
            .push(param.val().into_data().try_to_vec::<f32>().unwrap());
    }
}

/// The same on demo videos: stage A (the frame encoder, its own checkpoint
/// in `stage_a/`), the embedding cache, then stage B killed after its
/// epoch 1 and resumed: every stage's metrics and the final weights are
/// the uninterrupted run's.
#[test]
fn a_video_run_killed_in_stage_b_resumes_to_the_uninterrupted_run() {
    let mut video = ntg_trainer::blocks::BlocksVideo::new(false);
    video.encoder.demos = 6;
    video.encoder.epochs = 2;
    video.encoder.batch_size = 16;
    video.encoder.frame_fraction = 0.5;
    let config = BlocksRunConfig {
        obs: ObsKind::Vid,
        train_tasks: 3,
        permute_objects: false,
        exclude_held_out_renamings: false,
        validation_tasks: 2,
        video: Some(video),
        ..config()
    };
    let tmp = tempfile::tempdir().unwrap();
    let device = ntg_model::cpu_device().autodiff();
    let straight = RunDir::create(&tmp.path().join("straight")).unwrap();
    train_run(&straight, &config, &device, |_| {}).unwrap();

    let killed = RunDir::create(&tmp.path().join("killed")).unwrap();
    train_killed_then_resumed(&killed, &config);

    assert_eq!(
        metrics_without_time(&killed),
        metrics_without_time(&straight)
    );
    let stage_a = |run: &RunDir| RunDir::open(&run.root().join("stage_a")).unwrap();
    assert_eq!(
        metrics_without_time(&stage_a(&killed)),
        metrics_without_time(&stage_a(&straight))
    );
    // A finished stage A keeps its encoder, not its training frames.
    for run in [&killed, &straight] {
        assert!(stage_a(run).checkpoint_dir().is_dir());
        assert!(!stage_a(run).dataset_dir().exists());
    }
    let (a, b) = (
        weights(killed.checkpoint_dir()),
        weights(straight.checkpoint_dir()),
    );
    assert!(!a.is_empty());
    assert!(a == b, "the resumed video run's weights differ");
}

/// Ctrl-C (SIGINT) during `ntg train`: exit status 130 and a message with
/// the command that resumes the run, which then finishes it.
#[cfg(unix)]
#[test]
fn ctrl_c_says_how_to_resume() {
    use std::io::Read;
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("run");
    let mut child = std::process::Command::new(env!("CARGO_BIN_EXE_ntg"))
        .args([
            "train",
            "--domain",
            "blocks",
            "--train-tasks",
            "20",
            "--demos-per-task",
            "4",
            "--epochs",
            "400",
            "--validation-tasks",
            "0",
            "--out",
            out.to_str().unwrap(),
        ])
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    // Interrupted once training has started (the first epoch logged).
    let started = std::time::Instant::now();
    while !out.join("metrics.jsonl").is_file() {
        assert!(
            started.elapsed().as_secs() < 120,
            "no epoch logged in 2 minutes"
        );
        std::thread::sleep(std::time::Duration::from_millis(50));
    }
    let killed = std::process::Command::new("kill")
        .args(["-INT", &child.id().to_string()])
        .status()
        .unwrap();
    assert!(killed.success());
    let status = child.wait().unwrap();
    let mut stderr = String::new();
    child
        .stderr
        .take()
        .unwrap()
        .read_to_string(&mut stderr)
        .unwrap();
    assert_eq!(status.code(), Some(130), "{stderr}");
    let hint = stderr
        .lines()
        .find(|l| l.starts_with("interrupted: "))
        .unwrap_or_else(|| panic!("no resume hint: {stderr}"));
    assert!(hint.contains("train --resume --domain blocks"), "{hint}");
    // The command it names parses as `ntg train --resume` of this run
    // (resuming 400 epochs is left out: minutes).
    let command = hint.split('`').nth(1).unwrap_or_else(|| panic!("{hint}"));
    let words: Vec<&str> = command.split_whitespace().collect();
    let cli = ntg_trainer::cli::parse_from(words).unwrap_or_else(|e| panic!("{command}: {e}"));
    let ntg_trainer::cli::Command::Train(args) = cli.command else {
        panic!("{command}: not ntg train");
    };
    assert!(args.flags.resume, "{command}");
    assert_eq!(args.flags.out, out);
}

/// `ntg train --resume --epochs N` on a finished run of fewer epochs
/// trains the rest: the same metrics, validation scores and weights as a
/// run of N epochs from the start. Where that cannot hold (a cosine
/// decay over the whole run) it is refused, saying why.
#[test]
fn resume_with_more_epochs_extends_a_finished_run() {
    let tmp = tempfile::tempdir().unwrap();
    let train = |out: &std::path::Path, epochs: &str, resume: bool, recipe: &str| {
        let mut args = vec![
            "train",
            "--domain",
            "blocks",
            "--recipe",
            recipe,
            "--train-tasks",
            "3",
            "--demos-per-task",
            "2",
            "--validation-tasks",
            "2",
            "--epochs",
            epochs,
            "--out",
            out.to_str().unwrap(),
        ];
        if resume {
            args.push("--resume");
        }
        crate::common::ntg(&args)
    };
    let straight = tmp.path().join("straight");
    let extended = tmp.path().join("extended");
    let (code, _, err) = train(&straight, "4", false, "paper");
    assert_eq!(code, 0, "{err}");
    let (code, _, err) = train(&extended, "2", false, "paper");
    assert_eq!(code, 0, "{err}");
    let (code, _, err) = train(&extended, "4", true, "paper");
    assert_eq!(code, 0, "{err}");
    let (a, b) = (
        RunDir::open(&straight).unwrap(),
        RunDir::open(&extended).unwrap(),
    );
    assert_eq!(metrics_without_time(&a), metrics_without_time(&b));
    assert_eq!(
        std::fs::read_to_string(a.validation_path()).unwrap(),
        std::fs::read_to_string(b.validation_path()).unwrap()
    );
    assert!(weights(a.checkpoint_dir()) == weights(b.checkpoint_dir()));
    assert!(weights(a.best_dir()) == weights(b.best_dir()));

    // Fewer epochs, and a cosine decay (the recommended recipe's), are
    // refused, naming the reason; the run is left as it was.
    let (code, _, err) = train(&extended, "3", true, "paper");
    assert_eq!(code, 1);
    assert!(err.contains("only more epochs extend it"), "{err}");
    let cosine = tmp.path().join("cosine");
    let (code, _, err) = train(&cosine, "1", false, "recommended");
    assert_eq!(code, 0, "{err}");
    let config = std::fs::read_to_string(cosine.join("config.json")).unwrap();
    let (code, _, err) = train(&cosine, "2", true, "recommended");
    assert_eq!(code, 1);
    assert!(err.contains("cosine decay"), "{err}");
    assert_eq!(
        std::fs::read_to_string(cosine.join("config.json")).unwrap(),
        config
    );
}
