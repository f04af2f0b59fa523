//! Training's optional parts (`TrainExtras`): model selection on validation
//! tasks (the epoch a validator scores best is kept in `best/`, returned by
//! training and loaded by evaluation), and keeping the edge classifier's
//! loss out of the GCN.

use burn::module::Module;
use ntg_model::NtgModel;
use ntg_trainer::blocks::{BlocksRunConfig, ObsKind, Recipe, build_dataset, new_model};
use ntg_trainer::fit::{OptimConfig, ValidationRecord, ValidationScore, selected_epoch};
use ntg_trainer::method::ntg::{NtgTraining, TrainExtras, train_with};
use ntg_trainer::run_dir::RunDir;

/// A tiny run of the paper's recipe, without failures or validation.
fn config() -> BlocksRunConfig {
    let paper = Recipe::Paper.config(ObsKind::State, 3, 2, 4, 5);
    BlocksRunConfig {
        failures: false,
        model_seed: 3,
        validation_tasks: 0,
        validate_every: 0,
        optim: OptimConfig {
            batch_size: 2,
            learning_rate: 1e-2,
            ..paper.optim
        },
        ..paper
    }
}

fn params<M: Module>(module: &M) -> Vec<Vec<f32>> {
    struct Collect(Vec<Vec<f32>>);
    impl burn::module::ModuleVisitor for Collect {
        fn visit_float<const D: usize>(
            &mut self,
            param: &burn::module::Param<burn::tensor::Tensor<D>>,
        ) {
            self.0
                .push(param.val().into_data().try_to_vec::<f32>().unwrap());
        }
    }
    let mut c = Collect(Vec::new());
    module.visit(&mut c);
    c.0
}

/// Trains a fresh model of `config` on its blocks dataset into `run`.
fn train_tiny(config: &BlocksRunConfig, run: &RunDir, extras: TrainExtras<'_>) -> NtgModel {
    let device = ntg_model::cpu_device().autodiff();
    let split = env_blocks::standard_split().unwrap();
    let dataset = build_dataset(config, split.train(config.train_tasks).unwrap()).unwrap();
    train_with(
        new_model(config, &device).unwrap(),
        &dataset,
        &config.optim,
        run,
        &device,
        |_| {},
        extras,
    )
    .unwrap()
}

#[test]
fn the_best_scored_epoch_is_kept_and_returned() {
    let tmp = tempfile::tempdir().unwrap();
    let config = config();
    let run = RunDir::create(&tmp.path().join("run")).unwrap();

    // Scores by epoch: epoch 1 is best; epoch 3 ties it on success but
    // meets fewer goals.
    let scores = [(0.1, 0.5), (0.4, 0.6), (0.2, 0.9), (0.4, 0.3)];
    let mut seen = Vec::new();
    let mut validator = |model: &NtgModel| -> anyhow::Result<ValidationScore> {
        seen.push(params(model));
        let (success, goal_fraction) = scores[seen.len() - 1];
        Ok(ValidationScore {
            success,
            goal_fraction,
        })
    };
    let returned = train_tiny(
        &config,
        &run,
        TrainExtras {
            validator: Some(&mut validator),
            validate_every: 1,
            ..TrainExtras::default()
        },
    );
    assert_eq!(seen.len(), 4, "every epoch is validated once");
    assert_eq!(
        selected_epoch(&run).unwrap(),
        Some(ValidationRecord {
            epoch: 1,
            score: ValidationScore {
                success: 0.4,
                goal_fraction: 0.6
            }
        })
    );
    assert_eq!(params(&returned), seen[1], "training returns epoch 1");
    assert_ne!(seen[1], seen[3], "the last epoch differs from the best");
    let loaded = NtgModel::load(run.best_dir(), &ntg_model::cpu_device()).unwrap();
    assert_eq!(params(&loaded), seen[1], "best/ holds epoch 1");
    let last = NtgModel::load(run.checkpoint_dir(), &ntg_model::cpu_device()).unwrap();
    assert_eq!(params(&last), seen[3], "checkpoint/ holds the last epoch");
    let lines = std::fs::read_to_string(run.validation_path()).unwrap();
    assert_eq!(lines.lines().count(), 4);
}

#[test]
fn without_a_validator_nothing_is_selected() {
    let tmp = tempfile::tempdir().unwrap();
    let mut config = config();
    config.optim.epochs = 1;
    let run = RunDir::create(&tmp.path().join("run")).unwrap();
    train_tiny(&config, &run, TrainExtras::default());
    assert_eq!(selected_epoch(&run).unwrap(), None);
    assert!(!run.validation_path().exists());
}

#[test]
fn validate_every_skips_epochs_but_always_scores_the_last() {
    let tmp = tempfile::tempdir().unwrap();
    let mut config = config();
    config.optim.epochs = 5;
    let run = RunDir::create(&tmp.path().join("run")).unwrap();
    let mut calls = 0;
    let mut validator = |_: &NtgModel| -> anyhow::Result<ValidationScore> {
        calls += 1;
        Ok(ValidationScore {
            success: 0.0,
            goal_fraction: 0.0,
        })
    };
    train_tiny(
        &config,
        &run,
        TrainExtras {
            validator: Some(&mut validator),
            validate_every: 2,
            ..TrainExtras::default()
        },
    );
    assert_eq!(calls, 3);
    let epochs: Vec<usize> = std::fs::read_to_string(run.validation_path())
        .unwrap()
        .lines()
        .map(|l| serde_json::from_str::<ValidationRecord>(l).unwrap().epoch)
        .collect();
    assert_eq!(epochs, [1, 3, 4]);
    assert_eq!(selected_epoch(&run).unwrap().unwrap().epoch, 1);
}

#[test]
fn detached_gcn_learns_only_from_its_own_loss() {
    // Soft edges change only the edge classifier's loss (its mask and the
    // `ln C` added to its logits), so with the GCN detached from that loss
    // the GCN ends with the same weights either way; attached, it does not.
    let gcn_after = |soft_edges: bool, detach_gcn_from_edges: bool| {
        let tmp = tempfile::tempdir().unwrap();
        let config = BlocksRunConfig {
            soft_edges,
            detach_gcn_from_edges,
            ..config()
        };
        let run = RunDir::create(&tmp.path().join("run")).unwrap();
        let model = train_tiny(
            &config,
            &run,
            TrainExtras {
                training: NtgTraining {
                    detach_gcn_from_edges,
                    ..NtgTraining::default()
                },
                ..TrainExtras::default()
            },
        );
        (params(&model.gcn), params(&model.edges))
    };
    let (detached_hard, edges_hard) = gcn_after(false, true);
    let (detached_soft, edges_soft) = gcn_after(true, true);
    assert_eq!(detached_hard, detached_soft);
    assert_ne!(
        edges_hard, edges_soft,
        "soft edges change the edge classifier"
    );
    let (attached_hard, _) = gcn_after(false, false);
    let (attached_soft, _) = gcn_after(true, false);
    assert_ne!(attached_hard, attached_soft);
    assert_ne!(attached_hard, detached_hard);
}

#[test]
fn the_renaming_filter_is_consulted_for_every_renamed_demo() {
    // A filter that accepts nothing stops training with a clear error; one
    // that accepts everything trains as if there were none.
    let tmp = tempfile::tempdir().unwrap();
    let config = BlocksRunConfig {
        permute_objects: true,
        ..config()
    };
    let device = ntg_model::cpu_device().autodiff();
    let split = env_blocks::standard_split().unwrap();
    let dataset = build_dataset(&config, split.train(config.train_tasks).unwrap()).unwrap();
    let symmetry = ntg_trainer::blocks::object_symmetry();
    let refuse_all = |_: usize, _: &[usize]| false;
    let err = train_with(
        new_model(&config, &device).unwrap(),
        &dataset,
        &config.optim,
        &RunDir::create(&tmp.path().join("refused")).unwrap(),
        &device,
        |_| {},
        TrainExtras {
            training: NtgTraining {
                permute_objects: Some(&symmetry),
                accept_renaming: Some(&refuse_all),
                ..NtgTraining::default()
            },
            ..TrainExtras::default()
        },
    )
    .unwrap_err();
    assert!(
        format!("{err:#}").contains("no acceptable renaming"),
        "{err:#}"
    );

    let accept_all = |_: usize, _: &[usize]| true;
    let run = |name: &str, accept: Option<ntg_trainer::symmetry::RenamingFilter<'_>>| {
        let model = train_with(
            new_model(&config, &device).unwrap(),
            &dataset,
            &config.optim,
            &RunDir::create(&tmp.path().join(name)).unwrap(),
            &device,
            |_| {},
            TrainExtras {
                training: NtgTraining {
                    permute_objects: Some(&symmetry),
                    accept_renaming: accept,
                    ..NtgTraining::default()
                },
                ..TrainExtras::default()
            },
        )
        .unwrap();
        params(&model.edges)
    };
    assert_eq!(run("all", Some(&accept_all)), run("none", None));
}

#[test]
fn an_ablation_is_trained_without_its_part_and_keeps_it_off() {
    use ntg_trainer::blocks::Variant;
    let device = ntg_model::cpu_device().autodiff();
    let trained = |ablation: Variant| {
        let tmp = tempfile::tempdir().unwrap();
        let config = BlocksRunConfig {
            ablation,
            ..config()
        };
        let run = RunDir::create(&tmp.path().join("run")).unwrap();
        let untrained = new_model(&config, &device).unwrap();
        let model = train_tiny(&config, &run, TrainExtras::default());
        (untrained, model)
    };
    // Without the edge classifier its weights get no gradient; the GCN
    // still learns to complete graphs.
    let (before, after) = trained(Variant::NoEdgeClassifier);
    assert_eq!(params(&before.edges), params(&after.edges));
    assert_ne!(params(&before.gcn), params(&after.gcn));
    assert!(!after.config.ablation.edge_classifier);
    // Without the GCN its message passing is never trained (only its
    // initial node embeddings N⁰, the edge classifier's input), and the
    // switch stays in the model: evaluating the run as "full" keeps it off.
    let (before, after) = trained(Variant::NoGcn);
    let initial = |m: &NtgModel| m.gcn.nodes.val().into_data().try_to_vec::<f32>().unwrap();
    let passing = |m: &NtgModel| {
        let mut p = params(&m.gcn);
        p.retain(|t| *t != initial(m));
        p
    };
    assert_eq!(passing(&before), passing(&after));
    assert_eq!(passing(&before).len() + 1, params(&before.gcn).len());
    assert_ne!(initial(&before), initial(&after));
    assert_ne!(params(&before.edges), params(&after.edges));
    assert!(!Variant::Full.ablation_of(&after.config.ablation).gcn);
    // The full model trains every part.
    let (before, after) = trained(Variant::Full);
    assert_ne!(params(&before.gcn), params(&after.gcn));
    assert_ne!(params(&before.edges), params(&after.edges));
    // The configuration records the ablation only where there is one.
    let json = serde_json::to_value(BlocksRunConfig {
        ablation: Variant::NoDemoInterpreter,
        ..config()
    })
    .unwrap();
    assert_eq!(json["ablation"], "no-demo-interpreter");
    assert!(
        serde_json::to_value(config())
            .unwrap()
            .get("ablation")
            .is_none()
    );
}
