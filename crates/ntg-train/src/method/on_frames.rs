//! Any method on frames: the frozen shared frame encoder (stage A of
//! [`crate::video`]) in front of a model trained over its embeddings
//! (stage B), as a model every domain can condition and roll out. NTG on
//! frames is [`VideoNtgModel`], the Flat Policy on the same frames
//! [`VideoFlatModel`].

use std::path::Path;

use burn::module::{Module, ModuleDisplay};
use burn::tensor::Device;
use ctg_graph::{ActionId, Vocabulary};
use ntg_model::{EdgeCounts, FlatPolicy, FrameStageNet, NtgModel, rows_tensor};

use crate::fit::{StepContext, StepReport, TrainStep, TrainedModel};
use crate::method::{Agent, Model, TrainedPolicy};
use crate::spec::ObsKind;

/// Folder of the frozen encoder inside a saved [`OnFrames`] model.
pub const ENCODER_DIR: &str = "frame_encoder";

impl TrainedModel for FrameStageNet {
    fn save_to(&self, dir: &Path) -> anyhow::Result<()> {
        Ok(self.save(dir)?)
    }
    fn load_from(dir: &Path, device: &Device) -> anyhow::Result<Self> {
        Ok(FrameStageNet::load(dir, device)?)
    }
}

/// A model over frame embeddings: how many values its observation rows
/// have.
pub trait EmbeddingReader {
    /// Values per observation row the model reads.
    fn row_dim(&self) -> usize;
}

impl EmbeddingReader for NtgModel {
    fn row_dim(&self) -> usize {
        self.obs_dim()
    }
}

impl EmbeddingReader for ntg_model::NtpNet {
    fn row_dim(&self) -> usize {
        self.obs_dim()
    }
}

impl EmbeddingReader for FlatPolicy {
    fn row_dim(&self) -> usize {
        self.obs_dim()
    }
}

/// A method on videos: the frozen stage A network (whose encoder the model
/// reads every frame through) and the model over its embeddings.
#[derive(Module, Debug)]
pub struct OnFrames<M: Module + ModuleDisplay> {
    /// Stage A's network; only its encoder is used, frozen.
    pub frames: FrameStageNet,
    /// The method's networks over `Enc(o)` rows.
    pub policy: M,
}

/// NTG on frames.
pub type VideoNtgModel = OnFrames<NtgModel>;
/// The Flat Policy on frames.
pub type VideoFlatModel = OnFrames<FlatPolicy>;

impl<M: Module + ModuleDisplay + EmbeddingReader> OnFrames<M> {
    /// Joins a trained stage A network (frozen here) and a model over its
    /// embeddings.
    pub fn new(frames: FrameStageNet, policy: M) -> anyhow::Result<Self> {
        let h = frames.encoder.out_dim();
        anyhow::ensure!(
            policy.row_dim() == h,
            "the model reads rows of {} values, the frame encoder gives {h}",
            policy.row_dim()
        );
        Ok(OnFrames {
            frames: frames.no_grad(),
            policy,
        })
    }
}

impl<M: Module + ModuleDisplay> OnFrames<M> {
    /// `Enc(o)` of frame rows, in batches of 256.
    pub fn encode_rows(&self, rows: &[Vec<f32>]) -> anyhow::Result<Vec<Vec<f32>>> {
        encode_rows(&self.frames, rows)
    }
}

/// `Enc(o)` of frame rows with `net`'s encoder, in batches of 256.
pub fn encode_rows(net: &FrameStageNet, rows: &[Vec<f32>]) -> anyhow::Result<Vec<Vec<f32>>> {
    let device = net.loc_nodes.val().device();
    let dim = net.encoder.input_dim();
    let h = net.encoder.out_dim();
    let mut out = Vec::with_capacity(rows.len());
    for chunk in rows.chunks(256) {
        let encoded = net.encode(rows_tensor(chunk, dim, &device)?)?;
        let values = ntg_model::nn::to_vec(encoded)?;
        out.extend(values.chunks_exact(h).map(<[f32]>::to_vec));
    }
    Ok(out)
}

impl<M: TrainedModel + ModuleDisplay + EmbeddingReader> TrainedModel for OnFrames<M> {
    fn save_to(&self, dir: &Path) -> anyhow::Result<()> {
        self.policy.save_to(dir)?;
        Ok(self.frames.save(dir.join(ENCODER_DIR))?)
    }
    fn load_from(dir: &Path, device: &Device) -> anyhow::Result<Self> {
        let frames = FrameStageNet::load(dir.join(ENCODER_DIR), device)?;
        OnFrames::new(frames, M::load_from(dir, device)?)
    }
}

/// Whether `dir` holds a saved [`OnFrames`] model (rather than a model on
/// state rows).
pub fn is_video_model(dir: &Path) -> bool {
    dir.join(ENCODER_DIR).is_dir()
}

/// Checks that the model saved in `dir` reads the observations `obs` that
/// the run configuration `config` (its path, for the message) says; a
/// mismatch means the run folder was changed by hand.
pub fn check_model_obs(dir: &Path, obs: ObsKind, config: &Path) -> anyhow::Result<()> {
    let saved = if is_video_model(dir) {
        ObsKind::Vid
    } else {
        ObsKind::State
    };
    anyhow::ensure!(
        saved == obs,
        "{} says \"obs\": \"{}\", but the model in {} reads {} observations: the run folder was changed by hand; restore the run's config.json or train a new run",
        config.display(),
        obs.name(),
        dir.display(),
        saved.name()
    );
    Ok(())
}

/// Loads the model saved in `dir`: on frames if it holds a frame encoder,
/// else on state rows.
pub fn load_either<M>(dir: &Path, device: &Device) -> anyhow::Result<Model>
where
    M: TrainedModel + ModuleDisplay + TrainedPolicy + EmbeddingReader + 'static,
    OnFrames<M>: TrainedPolicy,
{
    Ok(if is_video_model(dir) {
        Box::new(OnFrames::<M>::load_from(dir, device)?)
    } else {
        Box::new(M::load_from(dir, device)?)
    })
}

impl<M> TrainedPolicy for OnFrames<M>
where
    M: Module + ModuleDisplay + TrainedPolicy + 'static,
    OnFrames<M>: Send + Sync,
{
    fn for_inference(&self) -> Model {
        Box::new(self.valid())
    }
    fn condition(
        &self,
        demo: &[Vec<f32>],
        vocabulary: &Vocabulary,
    ) -> anyhow::Result<Box<dyn Agent>> {
        let embedded = self.encode_rows(demo)?;
        Ok(Box::new(FramesAgent {
            frames: self.frames.clone(),
            agent: self.policy.condition(&embedded, vocabulary)?,
        }))
    }
    fn as_any(&self) -> &dyn std::any::Any {
        self
    }
    fn export_safetensors(&self, dir: &Path) -> anyhow::Result<Vec<crate::method::ExportedFile>> {
        let mut files = self.policy.export_safetensors(dir)?;
        files.push(crate::method::export_network(
            &self.frames,
            dir,
            ENCODER_DIR,
        )?);
        Ok(files)
    }
}

/// An agent on frames: each observed frame is encoded once, then the
/// method's agent acts on its embedding.
pub struct FramesAgent {
    frames: FrameStageNet,
    agent: Box<dyn Agent>,
}

impl Agent for FramesAgent {
    fn act(
        &self,
        row: &[f32],
        executed: &[ActionId],
        ties: &mut crate::method::Ties,
    ) -> anyhow::Result<ActionId> {
        let embedded = encode_rows(&self.frames, &[row.to_vec()])?;
        self.agent.act(&embedded[0], executed, ties)
    }
    fn transcription(&self) -> &[ActionId] {
        self.agent.transcription()
    }
    fn explain(&self) -> Option<String> {
        self.agent.explain()
    }
}

/// A model whose trained part sits behind a frozen front that reads the
/// frames (stage A's encoder, NTP (Detector)'s detector).
pub trait FrozenFront {
    /// The part trained behind the front.
    type Behind;
    /// That part.
    fn behind(&self) -> &Self::Behind;
}

impl<M: Module + ModuleDisplay> FrozenFront for OnFrames<M> {
    type Behind = M;
    fn behind(&self) -> &M {
        &self.policy
    }
}

/// Stage B's step for any method: the method's own step on the model
/// behind the frozen front (the dataset's rows are what the front gives:
/// embeddings, or states).
pub struct OnFramesStep<S>(pub S);

impl<W, S> TrainStep<W> for OnFramesStep<S>
where
    W: FrozenFront,
    S: TrainStep<W::Behind>,
{
    type Metrics = S::Metrics;
    fn num_examples(&self) -> usize {
        self.0.num_examples()
    }
    fn step(&self, model: &W, batch: &[usize], ctx: StepContext<'_>) -> anyhow::Result<StepReport> {
        self.0.step(model.behind(), batch, ctx)
    }
    fn epoch_metrics(
        &self,
        epoch: usize,
        means: &[f32],
        edges: &EdgeCounts,
        seconds: f32,
    ) -> Self::Metrics {
        self.0.epoch_metrics(epoch, means, edges, seconds)
    }
}

/// A trained model built around an [`NtgModel`]: NTG on state rows, or on
/// frames through the frozen encoder. Evaluation switches its ablation
/// variant and edge threshold through [`NtgBased::ntg_mut`].
pub trait NtgBased: TrainedPolicy + Clone {
    /// The NTG networks.
    fn ntg(&self) -> &NtgModel;
    /// The NTG networks, to change their evaluation settings.
    fn ntg_mut(&mut self) -> &mut NtgModel;
}

impl NtgBased for NtgModel {
    fn ntg(&self) -> &NtgModel {
        self
    }
    fn ntg_mut(&mut self) -> &mut NtgModel {
        self
    }
}

impl NtgBased for VideoNtgModel {
    fn ntg(&self) -> &NtgModel {
        &self.policy
    }
    fn ntg_mut(&mut self) -> &mut NtgModel {
        &mut self.policy
    }
}
