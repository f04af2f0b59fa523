//! The block world that block stacking and object sorting share (both on
//! env-blocks' simulator): an observation's row, the networks' row encoder
//! and the environment configuration, per observation kind. It lives apart
//! from both domain files so that neither imports the other.

use env_blocks::{BlocksObservation, EnvConfig};
use ntg_model::EncoderConfig;

use crate::spec::ObsKind;
use crate::video::EncoderStage;

/// Values per observation row of `kind`.
pub fn obs_dim(kind: ObsKind) -> usize {
    match kind {
        ObsKind::State => env_blocks::STATE_DIM,
        ObsKind::Vid => 3 * 64 * 64,
    }
}

/// The encoder of the NTG networks for `kind` (`state_hidden_layers` and
/// `pairwise` apply to the state MLP: the relational input covers the 8
/// cube positions). On video the networks read the frozen frame encoder's
/// embeddings (see [`crate::video`]) through an MLP of
/// `state_hidden_layers` layers.
pub fn encoder(kind: ObsKind, state_hidden_layers: usize, pairwise: bool) -> EncoderConfig {
    match kind {
        ObsKind::Vid => EncoderConfig::State(
            ntg_model::StateEncoderConfig::new(EncoderStage::default().embedding_dim())
                .with_hidden_layers(state_hidden_layers),
        ),
        ObsKind::State => EncoderConfig::State(
            ntg_model::StateEncoderConfig::new(env_blocks::STATE_DIM)
                .with_hidden_layers(state_hidden_layers)
                .with_pairwise_objects(if pairwise {
                    env_blocks::world::NUM_OBJECTS
                } else {
                    0
                }),
        ),
    }
}

/// The observation as a flat row: the state, or the frame in CHW order
/// scaled to `[0, 1]` (the same layout as object collection's frames).
pub fn featurize(obs: &BlocksObservation, kind: ObsKind) -> Vec<f32> {
    match kind {
        ObsKind::State => obs.state().to_vec(),
        // Rendering is switched on for `Vid` by `env_config`; a missing
        // frame gives a wrong-length row, which the model rejects.
        ObsKind::Vid => obs
            .frame()
            .map(env_collect::frame_to_chw)
            .unwrap_or_default(),
    }
}

/// The environment configuration for `kind`, with stochastic failures on or off.
pub fn env_config(kind: ObsKind, failures: bool) -> EnvConfig {
    let config = match kind {
        ObsKind::State => EnvConfig::state_only(),
        ObsKind::Vid => EnvConfig::default(),
    };
    if failures {
        config
    } else {
        config.without_failures()
    }
}
