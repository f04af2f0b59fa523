//! NTG on frames: the frozen shared frame encoder and the NTG model over
//! its embeddings (trained in stages by [`crate::video`]), as a model
//! every domain can condition and roll out.

use std::path::Path;

use burn::module::Module;
use burn::tensor::Device;
use ctg_graph::{ActionId, Vocabulary};
use ntg_model::{FrameStageNet, NtgModel, NtgPolicy, rows_tensor};

use crate::fit::TrainedModel;
use crate::method::{Agent, Model, TrainedPolicy};

/// Folder of the frozen encoder inside a saved [`VideoNtgModel`].
pub const ENCODER_DIR: &str = "frame_encoder";

impl TrainedModel for FrameStageNet {
    fn save_to(&self, dir: &Path) -> anyhow::Result<()> {
        Ok(self.save(dir)?)
    }
    fn load_from(dir: &Path, device: &Device) -> anyhow::Result<Self> {
        Ok(FrameStageNet::load(dir, device)?)
    }
}

/// NTG on videos: the frozen stage A network (whose encoder every network
/// reads) and the NTG model over its embeddings.
#[derive(Module, Debug)]
pub struct VideoNtgModel {
    /// Stage A's network; only its encoder is used, frozen.
    pub frames: FrameStageNet,
    /// The four networks over `Enc(o)` rows.
    pub ntg: NtgModel,
}

impl VideoNtgModel {
    /// Joins a trained stage A network (frozen here) and an NTG model over
    /// its embeddings.
    pub fn new(frames: FrameStageNet, ntg: NtgModel) -> anyhow::Result<Self> {
        let h = frames.encoder.out_dim();
        anyhow::ensure!(
            ntg.obs_dim() == h,
            "the NTG model reads rows of {} values, the frame encoder gives {h}",
            ntg.obs_dim()
        );
        Ok(VideoNtgModel {
            frames: frames.no_grad(),
            ntg,
        })
    }

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

impl TrainedModel for VideoNtgModel {
    fn save_to(&self, dir: &Path) -> anyhow::Result<()> {
        self.ntg.save(dir)?;
        Ok(self.frames.save(dir.join(ENCODER_DIR))?)
    }
    fn load_from(dir: &Path, device: &Device) -> anyhow::Result<Self> {
        let frames = FrameStageNet::load(dir.join(ENCODER_DIR), device)?;
        VideoNtgModel::new(frames, NtgModel::load(dir, device)?)
    }
}

/// Whether `dir` holds a saved [`VideoNtgModel`] (rather than a plain NTG
/// model).
pub fn is_video_model(dir: &Path) -> bool {
    dir.join(ENCODER_DIR).is_dir()
}

impl TrainedPolicy for VideoNtgModel {
    fn for_inference(&self) -> Model {
        Box::new(self.valid())
    }
    fn condition(
        &self,
        demo: &[Vec<f32>],
        vocabulary: &Vocabulary,
    ) -> anyhow::Result<Box<dyn Agent>> {
        let embedded = self.encode_rows(demo)?;
        Ok(Box::new(VideoAgent {
            frames: self.frames.clone(),
            policy: NtgPolicy::from_demo(&self.ntg, &embedded, vocabulary)?,
        }))
    }
    fn as_any(&self) -> &dyn std::any::Any {
        self
    }
}

/// NTG's agent on frames: each observed frame is encoded once, then the
/// graph executor acts on its embedding.
pub struct VideoAgent {
    frames: FrameStageNet,
    policy: NtgPolicy,
}

impl VideoAgent {
    /// The graph executor over the embeddings.
    pub fn policy(&self) -> &NtgPolicy {
        &self.policy
    }
}

impl Agent for VideoAgent {
    fn act(&self, row: &[f32], executed: &[ActionId]) -> anyhow::Result<ActionId> {
        let embedded = encode_rows(&self.frames, &[row.to_vec()])?;
        self.policy.act(&embedded[0], executed)
    }
    fn transcription(&self) -> &[ActionId] {
        self.policy.demo_actions()
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
        &self.ntg
    }
    fn ntg_mut(&mut self) -> &mut NtgModel {
        &mut self.ntg
    }
}
