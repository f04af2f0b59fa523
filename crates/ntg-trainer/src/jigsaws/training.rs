//! Training runs of the experiment's models, their validation NLL and the saved selections.

use super::*;

/// The saved configuration of one trained model's run.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
struct RunConfig {
    experiment: JigsawsConfig,
    /// The methods whose models the run selects.
    methods: Vec<Method>,
}

fn open_run(dir: &Path, config: &RunConfig) -> anyhow::Result<RunDir> {
    if dir.join("config.json").is_file() {
        let run = RunDir::open(dir)?;
        // A run of an older format (e.g. one method per run) is another
        // configuration too.
        let saved: Option<RunConfig> = RunDir::read_json(&run.config_path()).ok();
        if saved.as_ref() != Some(config) {
            bail!(
                "{} holds a run with another configuration{}; move it away or delete it",
                dir.display(),
                if saved.is_none() {
                    " (or of an older format)"
                } else {
                    ""
                }
            );
        }
        Ok(run)
    } else {
        let run = RunDir::create(dir)?;
        RunDir::write_json(&run.config_path(), config)?;
        Ok(run)
    }
}

fn read_metrics(run: &RunDir) -> anyhow::Result<Vec<EpochMetrics>> {
    let path = run.metrics_path();
    let text =
        std::fs::read_to_string(&path).with_context(|| format!("reading {}", path.display()))?;
    text.lines()
        .filter(|l| !l.trim().is_empty())
        .map(|l| {
            serde_json::from_str(l).with_context(|| format!("{}: invalid line", path.display()))
        })
        .collect()
}

/// The "no graph" model's trainer: the node localizer on every
/// observation's node, and the edge classifier, given `N⁰` (the GCN's
/// task-independent initial embeddings, trained along), on every
/// observation's next action with a softmax over every successor in the
/// **fully connected** graph, as its policy uses it. No demo interpreter
/// and no graph completion are trained (their metrics are logged as 0).
/// Adam; demos shuffled per epoch with a generator seeded by
/// `(seed, epoch)` as in [`train`]. It trains in memory (seconds); the
/// selected model is saved by [`train_method`].
pub struct NoGraphTrainer {
    model: NtgModel,
    optimizer: ModuleOptimizer,
    demos: Vec<Demonstration<Vec<f32>>>,
    dim: usize,
    epochs_done: usize,
}

impl NoGraphTrainer {
    /// A trainer for `model` (on an autodiff device) on `dataset`.
    pub fn new(model: NtgModel, dataset: &DemoDataset) -> anyhow::Result<NoGraphTrainer> {
        ensure!(
            !dataset.demos().is_empty(),
            "the dataset has no demonstrations"
        );
        let demos = (0..dataset.demos().len())
            .map(|i| dataset.demonstration(i))
            .collect::<anyhow::Result<_>>()?;
        Ok(NoGraphTrainer {
            model,
            optimizer: AdamConfig::new().init(),
            demos,
            dim: dataset.obs_dim(),
            epochs_done: 0,
        })
    }

    /// The model as trained so far.
    pub fn model(&self) -> &NtgModel {
        &self.model
    }

    /// Trains until `epochs` epochs are done, calling `on_epoch` after each.
    pub fn train_to(
        &mut self,
        epochs: usize,
        optim: &OptimConfig,
        device: &Device,
        mut on_epoch: impl FnMut(&EpochMetrics) -> anyhow::Result<()>,
    ) -> anyhow::Result<()> {
        ensure!(optim.batch_size > 0, "batch size must be positive");
        let n = self.model.num_nodes();
        let full = Ctg::fully_connected(n);
        for epoch in self.epochs_done..epochs {
            let started = std::time::Instant::now();
            let mut order: Vec<usize> = (0..self.demos.len()).collect();
            let mut rng = ChaCha8Rng::seed_from_u64(
                optim.seed ^ (epoch as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15),
            );
            order.shuffle(&mut rng);
            let mut sums = [0.0f32; 5];
            let mut steps = 0;
            for chunk in order.chunks(optim.batch_size) {
                let mut rows: Vec<&[f32]> = Vec::new();
                let mut nodes = Vec::new();
                let mut next = Vec::new();
                for &i in chunk {
                    let d = &self.demos[i];
                    rows.extend(d.observations().iter().map(Vec::as_slice));
                    nodes.extend(d.node_labels());
                    next.extend(d.next_actions());
                }
                let model = &self.model;
                let obs = rows_tensor(&rows, self.dim, device)?;
                let node_ids = ids_tensor(&nodes, n, device)?;
                let next_ids = ids_tensor(&next, n, device)?;
                let loc = model
                    .localizer
                    .loss(model.localizer.forward(obs.clone())?, node_ids.clone())?;
                let graphs = vec![&full; rows.len()];
                let mask = successor_mask(&graphs, &nodes, Some(&next), n, device)?;
                let logits = model.edges.forward(
                    obs,
                    node_ids,
                    model.gcn.initial_embeddings(rows.len()),
                    model.localizer.node_embeddings(),
                    mask,
                )?;
                let edge = model.edges.loss(logits, next_ids)?;
                let total = loc.loss.clone() + edge.loss.clone();
                let values = [
                    first(total.clone())?,
                    first(loc.loss)?,
                    loc.accuracy,
                    first(edge.loss)?,
                    edge.accuracy,
                ];
                let grads = GradientsParams::from_grads(total.backward(), model);
                self.model = self
                    .optimizer
                    .step(optim.learning_rate, self.model.clone(), grads);
                for (s, v) in sums.iter_mut().zip(values) {
                    *s += v;
                }
                steps += 1;
            }
            let mean = |i: usize| sums[i] / steps as f32;
            let metrics = EpochMetrics {
                epoch,
                loss: mean(0),
                interpreter_loss: 0.0,
                token_accuracy: 0.0,
                gcn_loss: 0.0,
                edge_f1: None,
                localizer_loss: mean(1),
                localizer_accuracy: mean(2),
                edge_loss: mean(3),
                step_accuracy: mean(4),
                seconds: started.elapsed().as_secs_f32(),
            };
            ensure!(
                metrics.loss.is_finite(),
                "training diverged at epoch {epoch} (loss {})",
                metrics.loss
            );
            self.epochs_done = epoch + 1;
            on_epoch(&metrics)?;
        }
        Ok(())
    }
}

fn first(t: burn::tensor::Tensor<1>) -> anyhow::Result<f32> {
    Ok(ntg_model::nn::to_vec(t)?
        .first()
        .copied()
        .unwrap_or(f32::NAN))
}

/// Mean validation NLL of `scorer`'s policies: each held-out group scored
/// leave-one-out within itself, the conditioning demos' scores averaged
/// over all groups. `None` without validation groups.
pub fn validation_nll(
    scorer: Scorer<'_>,
    data: &JigsawsData,
    smoothing: f64,
) -> anyhow::Result<Option<f64>> {
    let mut scores = Vec::new();
    for group in &data.validation {
        scores.extend(score_demos(scorer, &data.vocab, group, smoothing)?);
    }
    Ok(mean_nll(&scores))
}

fn mean_nll(scores: &[DemoScore]) -> Option<f64> {
    (!scores.is_empty()).then(|| scores.iter().map(|d| d.nll).sum::<f64>() / scores.len() as f64)
}

/// The validation NLL of [`Method::Full`] for every prior weight in
/// `weights` (as [`validation_nll`]); `None` without validation groups.
pub fn validation_by_weight(
    head: &NtgModel,
    graph: &NtgModel,
    data: &JigsawsData,
    smoothing: f64,
    weights: &[f64],
) -> anyhow::Result<Option<Vec<f64>>> {
    let mut by_weight = vec![Vec::new(); weights.len()];
    for group in &data.validation {
        let scores = graph_prior_scores(head, graph, &data.vocab, group, smoothing, weights)?;
        for (all, s) in by_weight.iter_mut().zip(scores) {
            all.extend(s);
        }
    }
    Ok(by_weight.iter().map(|s| mean_nll(s)).collect())
}

/// Where [`train_method`] keeps `method`'s selected model inside a run
/// folder.
pub fn selected_dir(run: &Path, method: Method) -> PathBuf {
    run.join(format!("selected-{}", method.name()))
}
const SELECTION_FILE: &str = "selection.json";

/// How a method's model was chosen.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Selection {
    /// Epochs trained when the selected model was taken (1-based count).
    pub epochs: usize,
    /// `(epochs trained, validation NLL)` at every evaluation (for
    /// [`Method::Full`], at the best prior weight of that evaluation).
    pub validation: Vec<(usize, f64)>,
    /// [`Method::Full`]: the selected prior weight `τ`.
    #[serde(default)]
    pub prior_weight: Option<f64>,
    /// [`Method::Full`]: `(τ, validation NLL)` of the selected epoch for
    /// every candidate weight.
    #[serde(default)]
    pub by_prior_weight: Vec<(f64, f64)>,
}

/// Trains one model and selects, for each of `methods` it serves, the
/// model of the epoch with the lowest validation NLL of that method's
/// policy (and, for [`Method::Full`], the prior weight among
/// `config.prior_weights`; it needs the no-graph model as `head`).
///
/// Trains for up to `config.optim.epochs` epochs, evaluating every
/// `config.eval_every` epochs (and after the last); without validation
/// data the last epoch (and the largest prior weight) is used. Every method
/// must use the same trained model ([`Method::ablation`]). Each selected
/// model is saved under [`selected_dir`] with its [`Selection`]; a run
/// folder that has them for the same configuration is reused without
/// training.
pub fn train_method(
    methods: &[Method],
    data: &JigsawsData,
    config: &JigsawsConfig,
    dir: &Path,
    head: Option<&NtgModel>,
    device: &Device,
    mut on_epoch: impl FnMut(&EpochMetrics),
) -> anyhow::Result<Vec<(NtgModel, TrainedRun)>> {
    let first = *methods.first().context("no method to train for")?;
    let ablation = first
        .ablation()
        .with_context(|| format!("method {} has no model to train", first.name()))?;
    ensure!(
        methods
            .iter()
            .all(|m| m.ablation().as_ref() == Some(&ablation)),
        "the methods {:?} do not share one trained model",
        methods.iter().map(|m| m.name()).collect::<Vec<_>>()
    );
    let no_graph = ablation == Method::NoGraph.ablation().context("no-graph ablation")?;
    let weights = &config.prior_weights;
    if methods.contains(&Method::Full) {
        ensure!(head.is_some(), "the full method needs the no-graph model");
        ensure!(!weights.is_empty(), "the full method needs a prior weight");
    }
    let run = open_run(
        dir,
        &RunConfig {
            experiment: config.clone(),
            methods: methods.to_vec(),
        },
    )?;
    let finished = methods
        .iter()
        .all(|&m| selected_dir(dir, m).join(SELECTION_FILE).is_file());
    let selected: Vec<(NtgModel, Selection)> = if finished {
        methods
            .iter()
            .map(|&m| {
                let sel_dir = selected_dir(dir, m);
                let selection: Selection = RunDir::read_json(&sel_dir.join(SELECTION_FILE))?;
                let model = NtgModel::load(&sel_dir, device)
                    .with_context(|| format!("reusing {}", sel_dir.display()))?;
                Ok((model, selection))
            })
            .collect::<anyhow::Result<_>>()?
    } else {
        let encoder = EncoderConfig::kinematics(config.observation.window);
        let mut model_config = NtgConfig::for_domain(data.vocab.len(), encoder);
        model_config.seed = config.model_seed;
        model_config.ablation = ablation;
        model_config.soft_edges = Some(config.soft_edges && !no_graph);
        let fresh = NtgModel::new(model_config, device)?;
        let max = config.optim.epochs;
        let mut marks: Vec<usize> = (1..=max).filter(|e| e % config.eval_every == 0).collect();
        if marks.last() != Some(&max) {
            marks.push(max);
        }
        // Per method: (value, mark, model, weight index, values by weight).
        type Best = (f64, usize, NtgModel, usize, Vec<f64>);
        let mut best: Vec<Option<Best>> = vec![None; methods.len()];
        let mut curves = vec![Vec::new(); methods.len()];
        let mut trainer = if no_graph {
            // In-memory trainer: start the metrics log afresh.
            let _ = std::fs::remove_file(run.metrics_path());
            Some(NoGraphTrainer::new(fresh.clone(), &data.train)?)
        } else {
            None
        };
        for &mark in &marks {
            let model = match &mut trainer {
                Some(trainer) => {
                    trainer.train_to(mark, &config.optim, device, |m| {
                        on_epoch(m);
                        run.append_metrics(m)
                    })?;
                    trainer.model().clone()
                }
                None => {
                    // `train` resumes from the run's checkpoint, so training
                    // in stages takes exactly the steps of one long run.
                    let optim = OptimConfig {
                        epochs: mark,
                        ..config.optim.clone()
                    };
                    train(
                        fresh.clone(),
                        &data.train,
                        &optim,
                        &run,
                        device,
                        &mut on_epoch,
                    )?
                }
            };
            for (i, &method) in methods.iter().enumerate() {
                // (value, index of the best weight, value per weight).
                let value: Option<(f64, usize, Vec<f64>)> = match (method, head) {
                    (Method::Full, Some(head)) => {
                        validation_by_weight(head, &model, data, config.smoothing, weights)?.map(
                            |values| {
                                let (w, v) = values
                                    .iter()
                                    .enumerate()
                                    .min_by(|a, b| a.1.total_cmp(b.1))
                                    .map_or((0, f64::NAN), |(w, &v)| (w, v));
                                (v, w, values)
                            },
                        )
                    }
                    _ => validation_nll(Scorer::Own(method, &model), data, config.smoothing)?
                        .map(|v| (v, 0, Vec::new())),
                };
                if let Some((v, _, _)) = &value {
                    curves[i].push((mark, *v));
                }
                let better = match (&best[i], &value) {
                    (None, _) | (Some(_), None) => true,
                    (Some((b, ..)), Some((v, _, _))) => v < b,
                };
                if better {
                    best[i] = Some(match value {
                        Some((v, w, values)) => (v, mark, model.clone(), w, values),
                        // No validation data: the last epoch, the largest weight.
                        None => (
                            f64::NAN,
                            mark,
                            model.clone(),
                            weights.len().saturating_sub(1),
                            Vec::new(),
                        ),
                    });
                }
            }
        }
        methods
            .iter()
            .zip(best)
            .zip(curves)
            .map(|((&method, best), curve)| {
                let (_, epochs, model, w, values) =
                    best.context("no epochs to train (epochs is 0)")?;
                let full = method == Method::Full;
                let selection = Selection {
                    epochs,
                    validation: curve,
                    prior_weight: full.then(|| weights[w]),
                    by_prior_weight: if full {
                        weights.iter().copied().zip(values).collect()
                    } else {
                        Vec::new()
                    },
                };
                let sel_dir = selected_dir(dir, method);
                model.save(&sel_dir)?;
                RunDir::write_json(&sel_dir.join(SELECTION_FILE), &selection)?;
                Ok((model, selection))
            })
            .collect::<anyhow::Result<_>>()?
    };
    let metrics = read_metrics(&run)?;
    Ok(methods
        .iter()
        .zip(selected)
        .map(|(&method, (model, selection))| {
            (
                model,
                TrainedRun {
                    method,
                    run: dir.to_owned(),
                    train_seconds: metrics.iter().map(|m| f64::from(m.seconds)).sum(),
                    last_epoch: metrics.last().cloned(),
                    selection,
                },
            )
        })
        .collect())
}
