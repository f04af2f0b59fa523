//! Tests of the JIGSAWS experiment.

use super::*;

fn small_synthetic(trials: usize, seed: u64) -> Dataset {
    let config = SynthConfig {
        max_trials_per_task: Some(trials),
        duration_scale: 0.3,
        ..SynthConfig::new(seed)
    };
    env_jigsaws::generate(&config).unwrap().dataset
}

#[test]
fn trials_become_one_step_per_segment_with_held_out_demos() {
    let dataset = small_synthetic(6, 3);
    let data = build_data(&dataset, ObservationConfig::default(), 3, "test").unwrap();
    // 6 trials per task, positions 2 and 5 held out.
    assert_eq!(data.train.demos().len(), 8);
    assert_eq!(data.validation.len(), 2);
    assert!(data.validation.iter().all(|g| g.len() == 2));
    assert_eq!(data.test.len(), 6);
    assert_eq!(data.train.obs_dim(), 10 * 76);
    let suturing = dataset.trials(Task::Suturing);
    let kept: Vec<&Trial> = suturing
        .iter()
        .enumerate()
        .filter(|(i, _)| i % 3 != 2)
        .map(|(_, t)| t)
        .collect();
    for (entry, trial) in data.train.demos().iter().zip(&kept) {
        assert_eq!(entry.task, 0);
        let ids: Vec<ActionId> = trial.gestures().iter().map(|g| g.action_id()).collect();
        assert_eq!(entry.actions, ids, "{}", trial.id());
        assert_eq!(entry.rows().len(), trial.segments.len() + 1);
    }
    assert_eq!(data.validation[0][0].trial, suturing[2].id().to_string());
    let last = data.train.demos().last().unwrap();
    assert_eq!(last.task, 1);
    let np = dataset.trials(TEST_TASK);
    assert_eq!(data.test[0].trial, np[0].id().to_string());
    assert_eq!(data.test[0].demo.len(), np[0].segments.len());
    // Deterministic.
    let again = build_data(&small_synthetic(6, 3), ObservationConfig::default(), 3, "t").unwrap();
    assert_eq!(again.train, data.train);
    assert_eq!(again.test, data.test);
}

#[test]
fn leave_one_out_pools_the_steps_of_the_other_demos() {
    let data = build_data(&small_synthetic(3, 1), ObservationConfig::default(), 0, "t").unwrap();
    let test = &data.test[..3];
    // nlls(d, e) = [e + 1; e + 1]: demo e has e + 1 steps of NLL e + 1.
    let table: Vec<Vec<f64>> = (0..3).map(|e| vec![(e + 1) as f64; e + 1]).collect();
    let scores = leave_one_out(test, |_, e| (&table[e], usize::from(e == 2)));
    // d = 0: steps 2·2 + 3·3 = 13 over 5 steps.
    assert!((scores[0].nll - 13.0 / 5.0).abs() < 1e-12);
    assert_eq!((scores[0].steps, scores[0].zero_probability_steps), (5, 1));
    // d = 2: 1 + 2·2 = 5 over 3 steps, no zero.
    assert!((scores[2].nll - 5.0 / 3.0).abs() < 1e-12);
    assert_eq!(scores[2].zero_probability_steps, 0);
    let r = MethodResult::from_scores(Method::Full, scores);
    assert!(r.min_nll <= r.mean_nll && r.mean_nll <= r.max_nll);
    assert_eq!(r.steps, 5 + 4 + 3);
}

#[test]
fn uniform_scores_ln_16_and_models_are_required() {
    let data = build_data(&small_synthetic(3, 2), ObservationConfig::default(), 0, "t").unwrap();
    let r = score(Method::Uniform, Scorer::Uniform, &data, DEFAULT_SMOOTHING).unwrap();
    assert_eq!(num_choices(&data.vocab), 16);
    for d in &r.per_demo {
        assert!((d.nll - 16f64.ln()).abs() < 1e-6, "{d:?}");
    }
    let err = score_demos(Scorer::Uniform, &data.vocab, &data.test[..1], 0.0).unwrap_err();
    assert!(err.to_string().contains("at least 2"), "{err}");
}

#[test]
fn missing_tasks_and_bad_roots_are_clear_errors() {
    let full = small_synthetic(3, 0);
    let only = |tasks: &[Task], np: usize| {
        let trials = full
            .all_trials()
            .filter(|t| tasks.contains(&t.id().task))
            .filter(|t| {
                t.id().task != TEST_TASK || {
                    let i = full.trials(TEST_TASK).iter().position(|x| x.id() == t.id());
                    i.is_some_and(|i| i < np)
                }
            })
            .cloned()
            .collect();
        Dataset::from_trials(tasks, trials)
    };
    let err = build_data(
        &only(&[Task::Suturing, TEST_TASK], 3),
        ObservationConfig::default(),
        0,
        "root X",
    )
    .unwrap_err()
    .to_string();
    assert!(
        err.contains("root X") && err.contains("Knot_Tying"),
        "{err}"
    );
    let err = build_data(
        &only(&Task::ALL, 1),
        ObservationConfig::default(),
        0,
        "root X",
    )
    .unwrap_err()
    .to_string();
    assert!(
        err.contains("1 usable Needle_Passing") && err.contains("at least 2"),
        "{err}"
    );
    let err = build_data(&full, ObservationConfig::default(), 1, "root X")
        .unwrap_err()
        .to_string();
    assert!(err.contains("no Suturing trials left to train on"), "{err}");

    let dir = tempfile::tempdir().unwrap();
    let missing = DataSource::Root {
        path: dir.path().join("nope"),
    };
    let err = load_source(&missing).unwrap_err().to_string();
    assert!(
        err.contains("nope") && err.contains("no such folder"),
        "{err}"
    );
    let empty = DataSource::Root {
        path: dir.path().to_owned(),
    };
    let err = format!("{:#}", load_source(&empty).unwrap_err());
    assert!(err.contains("no JIGSAWS task folder"), "{err}");

    let mut config = JigsawsConfig::for_profile(Profile::Smoke, empty, Default::default()).unwrap();
    config.smoothing = 1.0;
    let err = run_experiment(&config, dir.path(), |_| {}).unwrap_err();
    assert!(err.to_string().contains("smoothing"), "{err}");
    config.smoothing = DEFAULT_SMOOTHING;
    for bad in [vec![], vec![0.5, 1.5], vec![f64::NAN]] {
        config.prior_weights = bad;
        let err = run_experiment(&config, dir.path(), |_| {}).unwrap_err();
        assert!(err.to_string().contains("prior weights"), "{err}");
    }
}

/// The no-graph model learns (NTG's step with the demo interpreter and the
/// GCN ablated): on a small synthetic set, a few epochs
/// bring the held-out NLL of the training tasks far below uniform's, and
/// the same seed gives the same model.
#[test]
fn no_graph_model_learns_the_next_gesture() {
    let data = build_data(&small_synthetic(8, 5), ObservationConfig::default(), 4, "t").unwrap();
    let device = ntg_model::cpu_device().autodiff();
    let optim = OptimConfig {
        epochs: 6,
        batch_size: 4,
        learning_rate: 3e-3,
        seed: 0,
        token_dropout: 0.0,
        cosine_decay: false,
        shards: 1,
        gcn_from_other_demo: false,
    };
    let train = || {
        let mut config = NtgConfig::for_domain(data.vocab.len(), EncoderConfig::kinematics(10));
        config.ablation = Method::NoGraph.ablation().unwrap();
        let model = NtgModel::new(config, &device).unwrap();
        let before = validation_nll(Scorer::Own(Method::NoGraph, &model), &data, 0.01)
            .unwrap()
            .unwrap();
        let tmp = tempfile::tempdir().unwrap();
        let run = RunDir::create(tmp.path()).unwrap();
        let model = crate::method::ntg::train_with(
            model,
            &data.train,
            &optim,
            &run,
            &device,
            |_| {},
            Default::default(),
        )
        .unwrap();
        let after = validation_nll(Scorer::Own(Method::NoGraph, &model), &data, 0.01)
            .unwrap()
            .unwrap();
        (before, after)
    };
    let (before, after) = train();
    let uniform = 16f64.ln();
    assert!(
        after < 0.5 * uniform,
        "held-out NLL {after:.3} (uniform {uniform:.3})"
    );
    assert!(after < before - 0.5, "before {before:.3}, after {after:.3}");
    assert_eq!(train(), (before, after));
}

/// The two full methods share one trained model, each with its own
/// selection. The own-head model's policy weighs edges by the GCN's
/// probabilities and logs the GCN's edge F1 (the no-graph model logs
/// none). The graph-prior method's selection covers every candidate
/// weight, picks the lowest, and at weight 0 reproduces the no-graph
/// policy's validation NLL; both fall far below uniform's.
#[test]
fn full_methods_share_one_run_and_select_the_prior_weight() {
    let data = build_data(&small_synthetic(8, 5), ObservationConfig::default(), 4, "t").unwrap();
    let mut config = JigsawsConfig::for_profile(
        Profile::Smoke,
        DataSource::Synthetic {
            seed: 5,
            duration_scale: 0.3,
        },
        Default::default(),
    )
    .unwrap();
    assert!(config.soft_edges && config.optim.gcn_from_other_demo);
    config.optim.epochs = 6;
    config.eval_every = 3;
    let dir = tempfile::tempdir().unwrap();
    let device = ntg_model::cpu_device().autodiff();
    let fit = |methods: &[Method],
               run: &Path,
               head: Option<&NtgModel>,
               on_epoch: &mut dyn FnMut(&EpochMetrics)| {
        train_method(methods, &data, &config, run, head, &device, on_epoch)
    };
    let (head, head_run) = fit(
        &[Method::NoGraph],
        &dir.path().join("no-graph"),
        None,
        &mut |m: &EpochMetrics| assert_eq!(m.edge_f1, None),
    )
    .unwrap()
    .pop()
    .unwrap();
    assert!(!head.config().uses_soft_edges());
    let err = fit(
        &[Method::Full],
        &dir.path().join("bad"),
        None,
        &mut |_: &EpochMetrics| {},
    )
    .unwrap_err();
    assert!(
        err.to_string().contains("needs the no-graph model"),
        "{err}"
    );
    let err = fit(
        &[Method::NoGraph, Method::Full],
        &dir.path().join("bad"),
        Some(&head),
        &mut |_: &EpochMetrics| {},
    )
    .unwrap_err();
    assert!(err.to_string().contains("do not share"), "{err}");

    let mut logged = Vec::new();
    let full_dir = dir.path().join("full");
    let mut trained = fit(
        &[Method::FullOwnHead, Method::Full],
        &full_dir,
        Some(&head),
        &mut |m: &EpochMetrics| logged.push(m.clone()),
    )
    .unwrap();
    assert_eq!(logged.len(), 6);
    assert!(logged.iter().all(|m| m.edge_f1.is_some()), "{logged:?}");
    let (graph, graph_run) = trained.pop().unwrap();
    let (own, own_run) = trained.pop().unwrap();
    assert_eq!(
        (own_run.method, graph_run.method),
        (Method::FullOwnHead, Method::Full)
    );
    assert!(own.config().uses_soft_edges());
    let policy =
        NtgPolicy::from_demo(&own.valid(), data.test[0].demo.observations(), &data.vocab).unwrap();
    assert!(policy.edge_weights().is_some());
    assert_eq!(own_run.selection.prior_weight, None);

    let uniform = 16f64.ln();
    let sel = &graph_run.selection;
    assert_eq!(sel.validation.len(), 2);
    let weights: Vec<f64> = sel.by_prior_weight.iter().map(|&(w, _)| w).collect();
    assert_eq!(weights, config.prior_weights);
    let (best_w, best_v) = sel
        .by_prior_weight
        .iter()
        .copied()
        .min_by(|a, b| a.1.total_cmp(&b.1))
        .unwrap();
    assert_eq!(sel.prior_weight, Some(best_w));
    assert!(sel.validation.contains(&(sel.epochs, best_v)), "{sel:?}");
    assert!(best_v < 0.5 * uniform, "held-out NLL {best_v:.3}");
    // Weight 0: the no-graph policy, whatever the graph.
    let at_zero = validation_by_weight(&head, &graph, &data, DEFAULT_SMOOTHING, &[0.0])
        .unwrap()
        .unwrap()[0];
    let own_head = validation_nll(
        Scorer::Own(Method::NoGraph, &head),
        &data,
        DEFAULT_SMOOTHING,
    )
    .unwrap()
    .unwrap();
    assert!((at_zero - own_head).abs() < 1e-4, "{at_zero} vs {own_head}");
    let head_best = head_run
        .selection
        .validation
        .iter()
        .map(|v| v.1)
        .fold(f64::MAX, f64::min);
    assert!((own_head - head_best).abs() < 1e-9);

    // A run folder of the older one-method format is refused clearly.
    let old_format = dir.path().join("old");
    std::fs::create_dir_all(&old_format).unwrap();
    std::fs::write(
        old_format.join("config.json"),
        serde_json::json!({ "experiment": config, "method": "full" }).to_string(),
    )
    .unwrap();
    let err = fit(
        &[Method::NoGraph],
        &old_format,
        None,
        &mut |_: &EpochMetrics| {},
    )
    .unwrap_err()
    .to_string();
    assert!(
        err.contains("another configuration") && err.contains("older format"),
        "{err}"
    );

    // A finished run is reused as it was selected.
    let again = fit(
        &[Method::FullOwnHead, Method::Full],
        &full_dir,
        Some(&head),
        &mut |_: &EpochMetrics| panic!("a finished run trained again"),
    )
    .unwrap();
    let reused = &again[1].1.selection;
    assert_eq!(
        (reused.epochs, reused.prior_weight),
        (sel.epochs, sel.prior_weight)
    );
    for (a, b) in reused.by_prior_weight.iter().zip(&sel.by_prior_weight) {
        // JSON keeps the values to the last bit or so.
        assert!(a.0 == b.0 && (a.1 - b.1).abs() < 1e-12, "{a:?} vs {b:?}");
    }
    let scored = |model: &NtgModel| {
        score(
            Method::Full,
            Scorer::GraphPrior {
                head: &head,
                graph: model,
                weight: best_w,
            },
            &data,
            DEFAULT_SMOOTHING,
        )
        .unwrap()
    };
    assert_eq!(scored(&again[1].0), scored(&graph));
}

/// The prior on hand-made numbers: one node sure, a uniform head over
/// three actions, `C` = (0, 1, 0.25).
#[test]
fn graph_prior_weighs_the_head_by_c_to_the_weight() {
    let n = 3;
    let prior = GraphPrior {
        weights: vec![0.0, 1.0, 0.25, 0.0, 1.0, 1.0, 0.0, 0.0, 0.0],
        num_nodes: n,
    };
    let node = [1.0, 0.0, 0.0];
    let edge = [1.0 / 3.0; 9];
    let p = |w: f64| -> Vec<f64> {
        prior
            .log_probabilities(&node, &edge, w)
            .unwrap()
            .iter()
            .map(|&l| f64::from(l).exp())
            .collect()
    };
    let close = |a: &[f64], b: &[f64]| a.iter().zip(b).all(|(x, y)| (x - y).abs() < 1e-6);
    // Weight 1: ∝ C; 0.5: ∝ √C; 0: uniform over C's support.
    assert!(close(&p(1.0), &[0.0, 0.8, 0.2]), "{:?}", p(1.0));
    assert!(close(&p(0.5), &[0.0, 2.0 / 3.0, 1.0 / 3.0]), "{:?}", p(0.5));
    assert!(close(&p(0.0), &[0.0, 0.5, 0.5]), "{:?}", p(0.0));
    // The head's preferences count too, and node mass mixes rows; a
    // node without successors (row 2) is skipped.
    let edge = [0.0, 0.5, 0.5, 0.0, 0.9, 0.1, 0.0, 0.0, 0.0];
    let logs = prior
        .log_probabilities(&[0.5, 0.25, 0.25], &edge, 1.0)
        .unwrap();
    let got: Vec<f64> = logs.iter().map(|&l| f64::from(l).exp()).collect();
    // Row 0: (0.5, 0.125) / 0.625 = (0.8, 0.2); row 1: (0.9, 0.1).
    let want = [
        0.0,
        (0.5 * 0.8 + 0.25 * 0.9) / 0.75,
        (0.5 * 0.2 + 0.25 * 0.1) / 0.75,
    ];
    assert!(close(&got, &want), "{got:?}");
    assert_eq!(logs[0], f32::NEG_INFINITY);
    // Bad input.
    let err = prior.log_probabilities(&node, &edge[..8], 1.0).unwrap_err();
    assert!(err.to_string().contains("8 edge"), "{err}");
    let err = prior.log_probabilities(&node, &edge, -1.0).unwrap_err();
    assert!(err.to_string().contains("non-negative"), "{err}");
    let err = prior.log_probabilities(&[0.0; 3], &edge, 1.0).unwrap();
    assert!(err.iter().all(|&l| l == f32::NEG_INFINITY));
}

#[test]
fn seed_settings_change_one_seed_and_the_table_counts_wins() {
    let synth = DataSource::Synthetic {
        seed: 0,
        duration_scale: 1.0,
    };
    let base =
        JigsawsConfig::for_profile(Profile::Quick, synth.clone(), Default::default()).unwrap();
    let all = SeedSetting::all(&synth);
    assert_eq!(all.len(), 9);
    let names: Vec<String> = all.iter().map(|s| s.name()).collect();
    assert_eq!(names[..4], ["default", "data1", "data2", "data3"]);
    assert_eq!(names[8], "model5");
    let data2 = SeedSetting::Data(2).apply(&base).unwrap();
    assert_eq!(
        (data2.source.run_tag(), data2.model_seed),
        ("synth2".to_owned(), 0)
    );
    let model3 = SeedSetting::Model(3).apply(&base).unwrap();
    assert_eq!((model3.source.clone(), model3.model_seed), (synth, 3));
    assert_eq!(SeedSetting::Default.apply(&base).unwrap(), base);
    let root = DataSource::Root {
        path: PathBuf::from("/data/jigsaws"),
    };
    assert!(
        SeedSetting::all(&root)
            .iter()
            .all(|s| !matches!(s, SeedSetting::Data(_)))
    );
    let on_disk = JigsawsConfig::for_profile(Profile::Quick, root, Default::default()).unwrap();
    let err = SeedSetting::Data(1).apply(&on_disk).unwrap_err();
    assert!(err.to_string().contains("no data seed"), "{err}");

    let row = |setting, ng: f64, own: f64, full: f64| SeedRow {
        setting,
        nll: vec![
            (Method::Uniform, 16f64.ln()),
            (Method::NoGraph, ng),
            (Method::FullOwnHead, own),
            (Method::Full, full),
        ],
        prior_weight: Some(0.5),
    };
    let table = SeedTable {
        rows: vec![
            row(SeedSetting::Default, 0.7, 0.6, 0.65),
            row(SeedSetting::Data(1), 0.6, 0.8, 0.62),
            row(SeedSetting::Model(1), 0.5, 0.9, 0.4),
        ],
    };
    assert_eq!(table.wins(Method::Full, Method::NoGraph), 2);
    assert_eq!(table.wins(Method::FullOwnHead, Method::NoGraph), 1);
    assert!((table.mean(Method::Full) - (0.65 + 0.62 + 0.4) / 3.0).abs() < 1e-12);
    let md = seed_table_markdown(&table);
    assert!(
        md.contains("| data1 | 0.600 | 0.800 | 0.620 | 0.5 | **no** |"),
        "{md}"
    );
    assert!(md.contains("full lower in 2 of 3"), "{md}");
}

#[test]
fn smoothed_nll_of_known_distributions() {
    // Uniform over 16: ln 16 whatever the smoothing.
    let (nll, zero) = smoothed_nll(-(16f64.ln()), 0.01, 16);
    assert!((nll - 16f64.ln()).abs() < 1e-12);
    assert!(!zero);
    // p = 1/2 without smoothing: ln 2.
    assert!((smoothed_nll(0.5f64.ln(), 0.0, 16).0 - 2f64.ln()).abs() < 1e-12);
    // Probability 0: finite, ln(16 / ε), and flagged.
    let (nll, zero) = smoothed_nll(f64::NEG_INFINITY, 0.01, 16);
    assert!((nll - (1600f64).ln()).abs() < 1e-9, "{nll}");
    assert!(zero);
    // Certainty: −ln(1 − ε + ε/16).
    let (nll, _) = smoothed_nll(0.0, 0.01, 16);
    assert!((nll + (0.99 + 0.01 / 16.0f64).ln()).abs() < 1e-12);
}

/// The built-in `experiments/jigsaws.toml` gives the configurations the
/// figure was measured with.
#[test]
fn the_built_in_file_gives_the_configurations_the_figure_was_measured_with() {
    let source = DataSource::Synthetic {
        seed: 0,
        duration_scale: 1.0,
    };
    for (profile, epochs, eval_every) in [
        (Profile::Smoke, 2, 1),
        (Profile::Quick, 40, 4),
        (Profile::Paper, 100, 5),
    ] {
        let expected = JigsawsConfig {
            source: source.clone(),
            observation: ObservationConfig::default(),
            model_seed: 0,
            optim: OptimConfig {
                epochs,
                batch_size: 8,
                learning_rate: 3e-3,
                seed: 0,
                token_dropout: 0.0,
                cosine_decay: false,
                shards: 0, // unset in the file: one thread, as measured
                gcn_from_other_demo: true,
            },
            smoothing: DEFAULT_SMOOTHING,
            validation_every: 5,
            eval_every,
            soft_edges: true,
            prior_weights: default_prior_weights(),
        };
        let config =
            JigsawsConfig::for_profile(profile, source.clone(), Default::default()).unwrap();
        assert_eq!(config, expected, "{profile:?}");
    }
}
