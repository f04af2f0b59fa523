//! Training runs of the experiment's models, their validation NLL and the saved selections.

use super::*;

/// The saved configuration of one trained model's run.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
struct RunConfig {
    experiment: JigsawsConfig,
    /// The methods whose models the run selects.
    methods: Vec<Method>,
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
    let run = RunDir::open_or_create(
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
        for &mark in &marks {
            // `train_with` resumes from the run's checkpoint, so training in
            // stages takes exactly the steps of one long run. The no-graph
            // model's ablation (no demo interpreter, no GCN) makes NTG's
            // step train only the localizer and the edge classifier, the
            // latter over the fully connected graph with `N⁰`.
            let optim = OptimConfig {
                epochs: mark,
                ..config.optim.clone()
            };
            let model = train_with(
                fresh.clone(),
                &data.train,
                &optim,
                &run,
                device,
                &mut on_epoch,
                TrainExtras::default(),
            )?;
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
    let metrics: Vec<EpochMetrics> = crate::run_dir::read_jsonl(&run.metrics_path())?;
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
