//! Per-step negative log-likelihood of expert gestures under a policy, and leave-one-out scoring of demos.

use super::*;

/// Number of actions an expert can take in a vocabulary: every real action
/// plus `<end>`.
pub fn num_choices(vocab: &Vocabulary) -> usize {
    vocab.num_actions() + 1
}

/// `−ln π̃` of one step, with `π̃ = (1 − ε)·exp(log_p) + ε/choices`
/// (`log_p = −∞` is probability 0). Returns the NLL and whether the
/// unsmoothed probability was 0.
pub fn smoothed_nll(log_p: f64, smoothing: f64, choices: usize) -> (f64, bool) {
    let p = if log_p.is_nan() { 0.0 } else { log_p.exp() };
    let mixed = (1.0 - smoothing) * p + smoothing / choices as f64;
    (-mixed.ln(), p == 0.0)
}

/// Per-step NLLs of one demonstration under a policy given as a function
/// from an observation to `ln π(·|o)` over every node, and the number of
/// steps the policy gave probability 0.
pub fn demo_step_nlls(
    demo: &Demonstration<Vec<f32>>,
    mut log_probabilities: impl FnMut(&[f32]) -> anyhow::Result<Vec<f32>>,
    smoothing: f64,
    choices: usize,
) -> anyhow::Result<(Vec<f64>, usize)> {
    let mut nlls = Vec::with_capacity(demo.len() + 1);
    let mut zeros = 0;
    for (o, a) in demo.observations().iter().zip(demo.next_actions()) {
        let logs = log_probabilities(o)?;
        let log_p = logs
            .get(a.index())
            .copied()
            .with_context(|| format!("the policy scored {} actions", logs.len()))?;
        let (nll, zero) = smoothed_nll(f64::from(log_p), smoothing, choices);
        nlls.push(nll);
        zeros += usize::from(zero);
    }
    Ok((nlls, zeros))
}

/// The score of one conditioning demonstration.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct DemoScore {
    /// The conditioning trial.
    pub trial: String,
    /// Mean per-step NLL over the steps of every other test demo.
    pub nll: f64,
    /// Steps scored.
    pub steps: usize,
    /// Of those, steps the unsmoothed policy gave probability 0.
    pub zero_probability_steps: usize,
}

/// One method's result.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct MethodResult {
    /// The method.
    pub method: Method,
    /// Mean over conditioning demos of their mean per-step NLL (nats).
    pub mean_nll: f64,
    /// Standard deviation over conditioning demos (population).
    pub std_nll: f64,
    /// Lowest conditioning demo's NLL.
    pub min_nll: f64,
    /// Highest conditioning demo's NLL.
    pub max_nll: f64,
    /// Steps scored, summed over conditioning demos.
    pub steps: usize,
    /// Of those, steps with unsmoothed probability 0.
    pub zero_probability_steps: usize,
    /// Per conditioning demo.
    pub per_demo: Vec<DemoScore>,
}

impl MethodResult {
    /// Aggregates per-demo scores.
    pub fn from_scores(method: Method, per_demo: Vec<DemoScore>) -> MethodResult {
        let n = per_demo.len().max(1) as f64;
        let mean = per_demo.iter().map(|d| d.nll).sum::<f64>() / n;
        let var = per_demo.iter().map(|d| (d.nll - mean).powi(2)).sum::<f64>() / n;
        MethodResult {
            method,
            mean_nll: mean,
            std_nll: var.sqrt(),
            min_nll: per_demo.iter().map(|d| d.nll).fold(f64::INFINITY, f64::min),
            max_nll: per_demo
                .iter()
                .map(|d| d.nll)
                .fold(f64::NEG_INFINITY, f64::max),
            steps: per_demo.iter().map(|d| d.steps).sum(),
            zero_probability_steps: per_demo.iter().map(|d| d.zero_probability_steps).sum(),
            per_demo,
        }
    }
}

/// Scores of every conditioning demo `d`: `nlls(d, e)` gives the per-step
/// NLLs of demo `e` under the policy built from `d` and how many of its
/// steps had probability 0 (it is never called with `e == d`).
pub fn leave_one_out<'a>(
    test: &[TestDemo],
    nlls: impl Fn(usize, usize) -> (&'a [f64], usize),
) -> Vec<DemoScore> {
    (0..test.len())
        .map(|d| {
            let (mut sum, mut steps, mut zeros) = (0.0, 0, 0);
            for e in (0..test.len()).filter(|&e| e != d) {
                let (v, z) = nlls(d, e);
                sum += v.iter().sum::<f64>();
                steps += v.len();
                zeros += z;
            }
            DemoScore {
                trial: test[d].trial.clone(),
                nll: sum / steps.max(1) as f64,
                steps,
                zero_probability_steps: zeros,
            }
        })
        .collect()
}

fn policy_nlls(
    policy: &NtgPolicy,
    demo: &Demonstration<Vec<f32>>,
    smoothing: f64,
    choices: usize,
) -> anyhow::Result<(Vec<f64>, usize)> {
    demo_step_nlls(
        demo,
        |o| Ok(policy.log_probabilities(o)?),
        smoothing,
        choices,
    )
}

/// What scores a method's policies: the model(s) behind it.
#[derive(Debug, Clone, Copy)]
pub enum Scorer<'a> {
    /// The uniform policy.
    Uniform,
    /// A model's own NTG policy, with the method's ablation switches
    /// ([`Method::NoGraph`], [`Method::FullOwnHead`]).
    Own(Method, &'a NtgModel),
    /// [`Method::Full`]: the graph prior of `graph` (its demo interpreter
    /// and GCN) raised to `weight`, on the node localizer and edge
    /// classifier of `head` (the no-graph model); see [`GraphPrior`].
    GraphPrior {
        /// The no-graph model.
        head: &'a NtgModel,
        /// The full model.
        graph: &'a NtgModel,
        /// The prior weight `τ`.
        weight: f64,
    },
}

/// Scores `scorer`'s policies on the test demos, as `method`.
pub fn score(
    method: Method,
    scorer: Scorer<'_>,
    data: &JigsawsData,
    smoothing: f64,
) -> anyhow::Result<MethodResult> {
    let per_demo = score_demos(scorer, &data.vocab, &data.test, smoothing)?;
    Ok(MethodResult::from_scores(method, per_demo))
}

/// The leave-one-out scores of `scorer`'s policies on `test` (each demo
/// conditions a policy scored on all the others).
pub fn score_demos(
    scorer: Scorer<'_>,
    vocab: &Vocabulary,
    test: &[TestDemo],
    smoothing: f64,
) -> anyhow::Result<Vec<DemoScore>> {
    ensure!(
        test.len() >= 2,
        "scoring needs at least 2 demonstrations, got {}",
        test.len()
    );
    let choices = num_choices(vocab);
    let per_demo = match scorer {
        Scorer::Uniform => {
            let uniform = vec![-(choices as f32).ln(); vocab.len()];
            let rows: Vec<(Vec<f64>, usize)> = test
                .iter()
                .map(|t| demo_step_nlls(&t.demo, |_| Ok(uniform.clone()), smoothing, choices))
                .collect::<anyhow::Result<_>>()?;
            leave_one_out(test, |_, e| (&rows[e].0, rows[e].1))
        }
        Scorer::GraphPrior {
            head,
            graph,
            weight,
        } => graph_prior_scores(head, graph, vocab, test, smoothing, &[weight])?
            .pop()
            .context("no scores")?,
        Scorer::Own(method, model) => {
            let ablation = method
                .ablation()
                .with_context(|| format!("method {} has no model", method.name()))?;
            let mut model = model.valid();
            model.config.ablation = ablation;
            if method == Method::NoGraph {
                // The policy does not depend on the demonstration: build it
                // once and score every demo once.
                let first = &test[0].demo;
                let rows: Vec<(Vec<f64>, usize)> = test
                    .par_iter()
                    .map(|t| {
                        let policy = NtgPolicy::from_demo(&model, first.observations(), vocab)?;
                        policy_nlls(&policy, &t.demo, smoothing, choices)
                    })
                    .collect::<anyhow::Result<_>>()?;
                leave_one_out(test, |_, e| (&rows[e].0, rows[e].1))
            } else {
                let table: Vec<Vec<(Vec<f64>, usize)>> = test
                    .par_iter()
                    .map(|d| {
                        let policy = NtgPolicy::from_demo(&model, d.demo.observations(), vocab)
                            .with_context(|| format!("policy from {}", d.trial))?;
                        test.iter()
                            .map(|e| {
                                if std::ptr::eq(e, d) {
                                    Ok((Vec::new(), 0))
                                } else {
                                    policy_nlls(&policy, &e.demo, smoothing, choices)
                                }
                            })
                            .collect()
                    })
                    .collect::<anyhow::Result<_>>()?;
                leave_one_out(test, |d, e| (&table[d][e].0, table[d][e].1))
            }
        }
    };
    Ok(per_demo)
}
