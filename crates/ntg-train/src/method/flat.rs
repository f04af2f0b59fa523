//! The Flat Policy (Duan et al. 2017) as a training method: each example
//! imitates one demonstration conditioned on another demonstration of the
//! same task (drawn from the epoch's generator), as in the paper's
//! baseline.

use std::collections::BTreeMap;

use anyhow::bail;
use burn::module::Module;
use burn::tensor::Device;
use ctg_graph::{ActionId, Vocabulary};
use ntg_model::{
    ConditionedFlatPolicy, EdgeCounts, FlatBatch, FlatExample, FlatPolicy, executed_actions,
};
use rand::seq::IndexedRandom;
use serde::{Deserialize, Serialize};

use crate::dataset::DemoDataset;
use crate::fit::{StepContext, StepReport, TrainStep};
use crate::method::input::{Demos, EpochLog, EpochReport, TrainInput, fit_model};
use crate::method::{Agent, Model, TrainedPolicy};

/// Metrics of one Flat Policy epoch, as logged to `metrics.jsonl`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FlatEpochMetrics {
    /// Epoch index (from 0).
    pub epoch: usize,
    /// Mean cross-entropy of the next action.
    pub loss: f32,
    /// Fraction of steps whose next action it picks.
    pub step_accuracy: f32,
    /// Wall-clock seconds of the epoch.
    pub seconds: f32,
}

impl EpochLog for FlatEpochMetrics {
    fn epoch(&self) -> usize {
        self.epoch
    }
    fn log_line(&self) -> String {
        FlatEpochMetrics::log_line(self)
    }
}

impl FlatEpochMetrics {
    /// One human-readable log line.
    pub fn log_line(&self) -> String {
        format!(
            "epoch {:>3}: loss {:.3} | steps {:.3} | {:.1}s",
            self.epoch, self.loss, self.step_accuracy, self.seconds
        )
    }
}

/// What the Flat Policy's training imitates besides the next actions.
#[derive(Debug, Clone, Copy, Default)]
pub struct FlatTraining {
    /// Also imitate the final `<end>` decision.
    pub learn_end: bool,
    /// The attention query also reads the set of actions taken so far
    /// ([`ntg_model::executed_actions`]).
    pub memory: bool,
}

/// The Flat Policy's options, read from a run's configuration (see
/// [`crate::method::input::options_of`]); absent keys are off.
#[derive(Debug, Clone, Default, PartialEq, Deserialize)]
pub struct FlatOptions {
    /// Also imitate the final `<end>` decision.
    #[serde(default)]
    pub learn_end: bool,
    /// The attention query also reads the set of actions taken so far.
    #[serde(default)]
    pub memory: bool,
}

/// Trains the Flat Policy on `input` with `options` (behind the frozen
/// frame encoder when the demos come with one).
pub fn train(
    input: TrainInput<'_>,
    options: &FlatOptions,
    on_epoch: &mut dyn FnMut(&EpochReport),
) -> anyhow::Result<Model> {
    let Demos { dataset, frames } = input.load_demos()?;
    let n = input.vocabulary.len();
    let policy = ntg_model::FlatPolicyConfig::new(n, input.encoders.sequence.clone())
        .with_seed(input.model_seed)
        .with_memory_dim(options.memory.then_some(n))
        .init(input.device)?;
    let training = FlatTraining {
        learn_end: options.learn_end,
        memory: options.memory,
    };
    let step = FlatStep::new(&policy, &dataset, training, input.device)?;
    fit_model(policy, step, frames, &input, input.validation, on_epoch)
}

/// The Flat Policy's [`TrainStep`] on a dataset of demonstrations.
pub struct FlatStep<'a> {
    dataset: &'a DemoDataset,
    by_task: BTreeMap<usize, Vec<usize>>,
    training: FlatTraining,
    device: Device,
}

impl<'a> FlatStep<'a> {
    /// The step for `policy`'s vocabulary on `dataset`; every task needs at
    /// least two demonstrations.
    pub fn new(
        policy: &FlatPolicy,
        dataset: &'a DemoDataset,
        training: FlatTraining,
        device: &Device,
    ) -> anyhow::Result<Self> {
        dataset.check_num_nodes(policy.num_nodes(), "policy")?;
        let mut by_task: BTreeMap<usize, Vec<usize>> = BTreeMap::new();
        for (i, d) in dataset.demos().iter().enumerate() {
            by_task.entry(d.task).or_default().push(i);
        }
        if let Some((task, _)) = by_task.iter().find(|(_, v)| v.len() < 2) {
            bail!(
                "task {task} has a single demonstration; training pairs a demo with another of its task"
            );
        }
        Ok(FlatStep {
            dataset,
            by_task,
            training,
            device: device.clone(),
        })
    }

    fn rows(&self, i: usize) -> Vec<Vec<f32>> {
        let d = &self.dataset.demos()[i];
        d.rows().map(|r| self.dataset.row(r)).collect()
    }
}

impl TrainStep<FlatPolicy> for FlatStep<'_> {
    type Metrics = FlatEpochMetrics;

    fn num_examples(&self) -> usize {
        self.dataset.demos().len()
    }

    fn step(
        &self,
        policy: &FlatPolicy,
        chunk: &[usize],
        ctx: StepContext<'_>,
    ) -> anyhow::Result<StepReport> {
        let n = policy.num_nodes();
        let FlatTraining { learn_end, memory } = self.training;
        let owned: Vec<_> = chunk
            .iter()
            .map(|&i| {
                let entry = &self.dataset.demos()[i];
                let mut next = entry.actions.clone();
                // The policy acts at the keyframes (every row of a demo
                // without video) and attends over every row of the other.
                let rows = self.rows(i);
                let mut queries: Vec<Vec<f32>> =
                    entry.keyframes().iter().map(|&k| rows[k].clone()).collect();
                if learn_end {
                    next.push(Vocabulary::END);
                } else {
                    queries.pop();
                }
                let others: Vec<usize> = self.by_task[&entry.task]
                    .iter()
                    .copied()
                    .filter(|&j| j != i)
                    .collect();
                let cond = *others.choose(ctx.rng).unwrap_or(&i);
                (self.rows(cond), queries, next)
            })
            .collect();
        let examples: Vec<FlatExample<'_, Vec<f32>>> = owned
            .iter()
            .map(|(d, q, t)| (&d[..], &q[..], &t[..]))
            .collect();
        let mut batch = FlatBatch::new(&examples, self.dataset.obs_dim(), n, &self.device)?;
        if memory {
            // Before query `t` the agent has taken the first `t` actions.
            let memories: Vec<Vec<Vec<f32>>> = owned
                .iter()
                .map(|(_, q, t)| (0..q.len()).map(|k| executed_actions(n, &t[..k])).collect())
                .collect();
            batch = batch.with_memory(&memories, n)?;
        }
        let out = policy.loss(&batch)?;
        StepReport::scored(out.loss, &[out.accuracy])
    }

    fn epoch_metrics(
        &self,
        epoch: usize,
        means: &[f32],
        _: &EdgeCounts,
        seconds: f32,
    ) -> FlatEpochMetrics {
        FlatEpochMetrics {
            epoch,
            loss: means[0],
            step_accuracy: means[1],
            seconds,
        }
    }
}

/// The Flat Policy in the method registry.
pub struct Flat;

impl crate::method::Method for Flat {
    fn name(&self) -> &'static str {
        "flat"
    }
    fn legend(&self) -> &'static str {
        "Flat Policy"
    }
    fn load(&self, dir: &std::path::Path, device: &Device) -> anyhow::Result<Model> {
        super::on_frames::load_either::<FlatPolicy>(dir, device)
    }
    fn train(
        &self,
        input: TrainInput<'_>,
        config: &serde_json::Value,
        on_epoch: &mut dyn FnMut(&EpochReport),
    ) -> anyhow::Result<Model> {
        let options: FlatOptions = crate::method::input::options_of(self.legend(), config)?;
        self.check(config)?;
        train(input, &options, on_epoch)
    }
    fn options(&self) -> &'static [&'static str] {
        &["learn_end", "memory"]
    }
    fn check(&self, config: &serde_json::Value) -> anyhow::Result<()> {
        if let Some(prior) = config.get("location_step_prior").filter(|v| !v.is_null()) {
            bail!(
                "--location-step-prior {prior}: a location step prior is NTG's stepping interpreter's; the Flat Policy has no location-aware attention"
            );
        }
        Ok(())
    }
}

impl TrainedPolicy for FlatPolicy {
    fn for_inference(&self) -> Model {
        Box::new(self.valid())
    }
    fn condition(
        &self,
        demo: &[Vec<f32>],
        _: &ctg_graph::Vocabulary,
    ) -> anyhow::Result<Box<dyn Agent>> {
        Ok(Box::new(FlatAgent {
            policy: FlatPolicy::condition(self, demo)?,
            memory: self.memory_dim() > 0,
            num_nodes: self.num_nodes(),
        }))
    }
    fn as_any(&self) -> &dyn std::any::Any {
        self
    }
    fn export_safetensors(
        &self,
        dir: &std::path::Path,
    ) -> anyhow::Result<Vec<crate::method::ExportedFile>> {
        Ok(vec![crate::method::export_network(self, dir, "")?])
    }
}

/// The Flat Policy conditioned on a demo.
struct FlatAgent {
    policy: ConditionedFlatPolicy,
    /// Whether it reads the actions taken so far.
    memory: bool,
    num_nodes: usize,
}

impl Agent for FlatAgent {
    fn act(
        &self,
        row: &[f32],
        executed: &[ActionId],
        _: &mut crate::method::Ties,
    ) -> anyhow::Result<ActionId> {
        let m = self
            .memory
            .then(|| executed_actions(self.num_nodes, executed));
        Ok(self.policy.next_action_with_memory(row, m.as_deref())?)
    }
}
