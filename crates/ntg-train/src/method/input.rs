//! What a domain gives a method to train on: [`TrainInput`], the one value a
//! method sees (never the domain's type), as [`crate::domain::Domain`] is
//! what evaluation sees.
//!
//! A domain builds it once per run from its configuration (vocabulary,
//! demos, the encoders' input, object symmetry, a validator) and hands it,
//! with the run's configuration, to the method the configuration names
//! ([`super::Method::train`]); the method reads its own options from that
//! configuration and trains.

use std::any::Any;

use burn::module::ModuleDisplay;
use burn::tensor::Device;
use ctg_graph::Vocabulary;
use ntg_model::{EncoderConfig, FrameStageNet};

use crate::dataset::DemoDataset;
use crate::fit::{OptimConfig, Selection, TrainStep, TrainedModel, ValidationScore, Validator};
use crate::method::on_frames::{EmbeddingReader, OnFrames, OnFramesStep};
use crate::method::{Model, TrainedPolicy};
use crate::run_dir::RunDir;
use crate::symmetry::{ObjectSymmetry, RenamingFilter};

/// A run's training demonstrations.
pub struct Demos {
    /// The demos: observation rows, or (with `frames`) the embeddings of
    /// their frames.
    pub dataset: DemoDataset,
    /// The frozen frame encoder (the first stage of a run from demo
    /// videos, [`crate::video`]) whose embeddings the rows are; `None` on
    /// rows a network reads directly.
    pub frames: Option<FrameStageNet>,
}

/// The encoders a domain's rows are read through.
#[derive(Debug, Clone)]
pub struct RowEncoders {
    /// For a network that reads a demo as a sequence (NTG's demo
    /// interpreter, the Flat Policy).
    pub sequence: EncoderConfig,
    /// For a network that judges one observation on its own (NTG's node
    /// localizer and edge classifier), which must see relations between
    /// objects in the row itself.
    pub observation: EncoderConfig,
}

impl RowEncoders {
    /// The same encoder for every network.
    pub fn same(encoder: EncoderConfig) -> Self {
        RowEncoders {
            sequence: encoder.clone(),
            observation: encoder,
        }
    }
}

/// Renaming the objects of training demos (a symmetry of the domain).
#[derive(Clone, Copy)]
pub struct Renaming<'a> {
    /// How objects appear in rows and actions.
    pub symmetry: &'a ObjectSymmetry,
    /// Which renamings of a demo of dataset task `task` may be trained on;
    /// `None` accepts every one.
    pub accept: Option<RenamingFilter<'a>>,
}

/// Scores a trained model on a domain's validation episodes.
pub type ScoreFn<'a> = dyn Fn(&dyn TrainedPolicy) -> anyhow::Result<ValidationScore> + Sync + 'a;

/// Epoch selection on validation episodes.
#[derive(Clone, Copy)]
pub struct Validation<'a> {
    /// The score of a model.
    pub score: &'a ScoreFn<'a>,
    /// Score after every this many epochs (and after the last); 0 and 1
    /// mean every epoch.
    pub every: usize,
}

/// One finished training epoch, as a method reports it.
#[derive(Debug, Clone, PartialEq)]
pub struct EpochReport {
    /// The epoch, from 0.
    pub epoch: usize,
    /// Its metrics in one line (the method's `log_line`).
    pub line: String,
}

/// A method's metrics of one epoch, as it reports them.
pub trait EpochLog {
    /// The epoch, from 0.
    fn epoch(&self) -> usize;
    /// The metrics in one line.
    fn log_line(&self) -> String;
}

impl EpochReport {
    /// The report of `metrics`.
    pub fn of(metrics: &impl EpochLog) -> Self {
        EpochReport {
            epoch: metrics.epoch(),
            line: metrics.log_line(),
        }
    }
}

impl std::fmt::Display for EpochReport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.line)
    }
}

/// What a method trains on: everything a domain provides, in one value.
pub struct TrainInput<'a> {
    /// The domain's action vocabulary.
    pub vocabulary: &'a Vocabulary,
    /// Builds the training demos, or reads them from the run folder's
    /// cache (called once, by a method that trains on them).
    pub demos: &'a dyn Fn() -> anyhow::Result<Demos>,
    /// The encoders of rows read directly; a run on frames gets encoders of
    /// its frame embeddings.
    pub encoders: RowEncoders,
    /// Object renaming in training, if the run asks for it.
    pub renaming: Option<Renaming<'a>>,
    /// Epoch selection, if the run validates.
    pub validation: Option<Validation<'a>>,
    /// Every imitated demo is conditioned on another demo of its task drawn
    /// from the epoch's generator, and NTG sums its losses with the GCN's
    /// last (object collection's runs were trained so, and reproduce bit
    /// for bit). Otherwise a method pairs demos as its options say.
    pub other_demo_each_epoch: bool,
    /// Seed of the initial weights.
    pub model_seed: u64,
    /// Optimisation.
    pub optim: &'a OptimConfig,
    /// The run folder: checkpoints, metrics, caches.
    pub run: &'a RunDir,
    /// An autodiff device.
    pub device: &'a Device,
    /// What the domain provides beyond this for an application's methods
    /// (each downcasts to a type its own file defines, such as NTP's
    /// primitive-level episodes); `None` when it provides nothing more.
    pub extension: Option<&'a (dyn Any + Send + Sync)>,
}

impl<'a> TrainInput<'a> {
    /// The input of a run on observation rows `dataset` (no renaming, no
    /// validation, each row encoded by an MLP over its values): what a
    /// domain of one's own needs at least.
    pub fn of_rows(
        dataset: &'a dyn Fn() -> anyhow::Result<Demos>,
        vocabulary: &'a Vocabulary,
        obs_dim: usize,
        optim: &'a OptimConfig,
        run: &'a RunDir,
        device: &'a Device,
    ) -> Self {
        TrainInput {
            vocabulary,
            demos: dataset,
            encoders: RowEncoders::same(EncoderConfig::state(obs_dim)),
            renaming: None,
            validation: None,
            other_demo_each_epoch: false,
            model_seed: optim.seed,
            optim,
            run,
            device,
            extension: None,
        }
    }

    /// Reads the demos and checks their vocabulary is the domain's.
    pub fn load_demos(&self) -> anyhow::Result<Demos> {
        let demos = (self.demos)()?;
        if demos.dataset.vocabulary() != self.vocabulary {
            anyhow::bail!(
                "the training demos are in a vocabulary of {} actions, the domain's has {}",
                demos.dataset.vocabulary().len(),
                self.vocabulary.len()
            );
        }
        Ok(demos)
    }
}

/// Reads a method's options from a run's configuration: the keys its
/// options type names, each absent one at its default.
pub fn options_of<T: serde::de::DeserializeOwned>(
    method: &str,
    config: &serde_json::Value,
) -> anyhow::Result<T> {
    T::deserialize(config)
        .map_err(|e| anyhow::anyhow!("the run configuration's options of {method}: {e}"))
}

/// [`crate::fit::fit`] of `model` with `step` on `input`'s optimisation,
/// run folder and device, the epoch selected by `validation` if given (a
/// method passes `input.validation`, or its own score on the same
/// episodes): the loop every method trains through.
pub fn fit_on<M, S>(
    model: M,
    step: &S,
    input: &TrainInput<'_>,
    validation: Option<Validation<'_>>,
    on_epoch: &mut dyn FnMut(&EpochReport),
) -> anyhow::Result<M>
where
    M: TrainedModel + TrainedPolicy + Send,
    S: TrainStep<M> + Sync,
    S::Metrics: EpochLog,
{
    let log = |m: &S::Metrics| on_epoch(&EpochReport::of(m));
    let Some(validation) = validation else {
        return crate::fit::fit(model, step, input.optim, input.run, input.device, None, log);
    };
    let mut validator = |m: &M| (validation.score)(m);
    let selection = Selection {
        validator: &mut validator as &mut dyn Validator<M>,
        every: validation.every,
        scores: crate::fit::ROLLOUT_SCORES,
    };
    crate::fit::fit(
        model,
        step,
        input.optim,
        input.run,
        input.device,
        Some(selection),
        log,
    )
}

/// [`fit_on`] of a model that reads rows: on the rows themselves, or, given
/// the frozen frame encoder whose embeddings they are, behind it (the
/// second stage of a run from demo videos).
pub fn fit_model<M, S>(
    model: M,
    step: S,
    frames: Option<FrameStageNet>,
    input: &TrainInput<'_>,
    validation: Option<Validation<'_>>,
    on_epoch: &mut dyn FnMut(&EpochReport),
) -> anyhow::Result<Model>
where
    M: TrainedModel + TrainedPolicy + ModuleDisplay + EmbeddingReader + Send + 'static,
    S: TrainStep<M> + Sync,
    S::Metrics: EpochLog,
    OnFrames<M>: TrainedPolicy,
{
    Ok(match frames {
        None => Box::new(fit_on(model, &step, input, validation, on_epoch)?),
        Some(frames) => {
            let model = OnFrames::new(frames, model)?;
            Box::new(fit_on(
                model,
                &OnFramesStep(step),
                input,
                validation,
                on_epoch,
            )?)
        }
    })
}
