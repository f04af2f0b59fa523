//! NTP (Detector), the video panel's baseline that gets extra supervision
//! (`docs/BASELINES.md`): an NTP network
//! ([`crate::method::ntp`]) fed the states a separately trained frame →
//! state regressor ([`ntg_model::Detector`], [`crate::method::detector`])
//! estimates, for the demo's frames and for every observed frame. Our
//! choice: NTP trains on the detector's estimates of its training episodes'
//! frames (`DetectorSettings::ntp_on_estimates`; chosen on validation
//! tasks over true states, `docs/results/ntp-2026-11-25.md`).
//!
//! Our choice: the demo NTP reads is the demo video's frame before each
//! primitive and its last frame (NTP reads its specification one row per
//! primitive; [`crate::blocks::BlocksDomain::at_primitive_level`]). So the
//! baseline is told where the video's primitives start, which NTG (Vid),
//! reading every frame of the video, is not: a help to the baseline, not a
//! handicap.

use std::path::Path;

use anyhow::Context;
use burn::module::Module;
use burn::tensor::Device;
use ctg_graph::{ActionId, Vocabulary};
use ntg_model::Detector;

use crate::fit::TrainedModel;
use crate::method::input::fit_on;
use crate::method::ntp::NtpModel;
use crate::method::ntp::{
    NtpKind, NtpOptions, NtpStep, ntp_config, primitive_level, primitive_validation,
};
use crate::method::on_frames::FrozenFront;
use crate::method::{Agent, EpochReport, Model, TrainInput, TrainedPolicy};
use crate::spec::ObsKind;

/// Folder of the detector inside a saved [`NtpOnDetector`].
pub const DETECTOR_DIR: &str = "detector";

/// The NTP (Detector) model: the frozen detector in front of NTP.
#[derive(Module, Debug)]
pub struct NtpOnDetector {
    /// Frame → estimated state row; frozen.
    pub detector: Detector,
    /// NTP on state rows.
    pub ntp: NtpModel,
}

impl NtpOnDetector {
    /// Joins a trained detector (frozen here) and NTP on the state rows it
    /// estimates.
    pub fn new(detector: Detector, ntp: NtpModel) -> anyhow::Result<Self> {
        anyhow::ensure!(
            detector.config.row_dim() == ntp.net.obs_dim(),
            "the detector estimates rows of {} values, NTP reads {}",
            detector.config.row_dim(),
            ntp.net.obs_dim()
        );
        Ok(NtpOnDetector {
            detector: detector.no_grad(),
            ntp,
        })
    }
}

impl FrozenFront for NtpOnDetector {
    type Behind = NtpModel;
    fn behind(&self) -> &NtpModel {
        &self.ntp
    }
}

impl TrainedModel for NtpOnDetector {
    fn save_to(&self, dir: &Path) -> anyhow::Result<()> {
        self.ntp.save_to(dir)?;
        Ok(self.detector.save(dir.join(DETECTOR_DIR))?)
    }
    fn load_from(dir: &Path, device: &Device) -> anyhow::Result<Self> {
        let detector = Detector::load(dir.join(DETECTOR_DIR), device)?;
        NtpOnDetector::new(detector, NtpModel::load_from(dir, device)?)
    }
}

/// NTP (Detector) in the method registry.
pub struct NtpDetector;

impl crate::method::Method for NtpDetector {
    fn name(&self) -> &'static str {
        "ntp-detector"
    }
    fn legend(&self) -> &'static str {
        "NTP (Detector)"
    }
    fn load(&self, dir: &Path, device: &Device) -> anyhow::Result<Model> {
        Ok(Box::new(NtpOnDetector::load_from(dir, device)?))
    }
    /// Its detector stage, and cube renaming of the state rows its NTP
    /// reads, which the detector estimates from frames.
    fn options(&self) -> &'static [&'static str] {
        &["detector", "permute_objects", "ntp_core"]
    }
    fn check(&self, config: &serde_json::Value) -> anyhow::Result<()> {
        let options: NtpOptions = crate::method::input::options_of(self.legend(), config)?;
        options.check_whole(self.name())?;
        if config.get("obs").and_then(serde_json::Value::as_str) != Some(ObsKind::Vid.name()) {
            anyhow::bail!(
                "--method ntp-detector is the video baseline: it needs --obs vid (NTP on true states is --method ntp)"
            );
        }
        if !options.encoder_labels().is_flat() {
            anyhow::bail!(
                "--encoder-labels primitive trains the frame encoder of NTP and NTP Flat; NTP (Detector) reads frames through its detector"
            );
        }
        Ok(())
    }
    fn train(
        &self,
        input: TrainInput<'_>,
        config: &serde_json::Value,
        on_epoch: &mut dyn FnMut(&EpochReport),
    ) -> anyhow::Result<Model> {
        self.check(config)?;
        let options = crate::method::input::options_of(self.legend(), config)?;
        train(input, &options, on_epoch)
    }
}

/// Trains NTP (Detector) on `input`'s primitive level: its detector first
/// (so a bad setting fails before NTP's episodes are recorded), then NTP
/// on the detector's estimates of its episodes' frames, the rows it will
/// be fed (or, with `ntp_on_estimates` off, on the true states), validated
/// through the detector on frames. The options are checked
/// ([`crate::method::Method::check`]).
pub fn train(
    input: TrainInput<'_>,
    options: &NtpOptions,
    on_epoch: &mut dyn FnMut(&EpochReport),
) -> anyhow::Result<Model> {
    let level = primitive_level(&input, "ntp-detector")?;
    let settings = options
        .detector
        .clone()
        .context("an NTP (Detector) run's configuration needs its `detector` settings")?;
    let detector = level.detector(&settings, input.run, input.device)?;
    let dataset = if settings.ntp_on_estimates {
        let valid = Module::valid(&detector);
        let estimate = |rows: &[Vec<f32>]| Ok(valid.predict_rows(rows)?);
        level.frame_episodes(input.run, &estimate, "NTP frames through the detector")?
    } else {
        level.state_episodes()?
    };
    let net = NtpModel::init(
        &ntp_config(
            level.encoder(false),
            true,
            options.ntp_core,
            input.model_seed,
        ),
        input.device,
    )?;
    let step = NtpStep::new(
        &dataset,
        NtpKind::Hierarchical,
        level.renaming(),
        input.device,
    )?;
    let model = NtpOnDetector::new(detector, net)?;
    let step = crate::method::on_frames::OnFramesStep(step);
    let score = |m: &dyn TrainedPolicy| level.score(m);
    let validation = primitive_validation(&input, &score);
    Ok(Box::new(fit_on(
        model, &step, &input, validation, on_epoch,
    )?))
}

impl TrainedPolicy for NtpOnDetector {
    fn for_inference(&self) -> Model {
        Box::new(self.valid())
    }
    fn condition(
        &self,
        demo: &[Vec<f32>],
        vocabulary: &Vocabulary,
    ) -> anyhow::Result<Box<dyn Agent>> {
        let rows = self
            .detector
            .predict_rows(demo)
            .context("the detector on the demo's frames")?;
        Ok(Box::new(DetectorAgent {
            detector: self.detector.clone(),
            agent: TrainedPolicy::condition(&self.ntp, &rows, vocabulary)?,
        }))
    }
    fn as_any(&self) -> &dyn std::any::Any {
        self
    }
    fn export_safetensors(
        &self,
        dir: &Path,
    ) -> anyhow::Result<Vec<ntg_train::method::ExportedFile>> {
        let mut files = self.ntp.export_safetensors(dir)?;
        files.push(ntg_train::method::export_network(
            &self.detector,
            dir,
            DETECTOR_DIR,
        )?);
        Ok(files)
    }
}

/// NTP acting on the state the detector estimates from each frame.
struct DetectorAgent {
    detector: Detector,
    agent: Box<dyn Agent>,
}

impl Agent for DetectorAgent {
    fn act(
        &self,
        row: &[f32],
        executed: &[ActionId],
        ties: &mut crate::method::Ties,
    ) -> anyhow::Result<ActionId> {
        let estimated = self
            .detector
            .predict_rows(&[row])
            .context("the detector on an observed frame")?;
        self.agent.act(&estimated[0], executed, ties)
    }
    fn explain(&self) -> Option<String> {
        self.agent.explain()
    }
}
