//! The crate's one error type.

use std::path::PathBuf;

/// Everything that can go wrong in `ntg-model`.
///
/// Bad input (tensors of the wrong shape, observations of the wrong length,
/// an inconsistent configuration, a missing or corrupt checkpoint) is
/// reported here instead of panicking.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum ModelError {
    /// A tensor or slice argument had the wrong shape.
    #[error("{what}: expected shape {expected}, got {got}")]
    Shape {
        /// Which argument.
        what: &'static str,
        /// The expected shape, in words (e.g. `[B, 26]`).
        expected: String,
        /// The shape received.
        got: String,
    },
    /// A configuration that cannot build a model.
    #[error("invalid configuration: {0}")]
    Config(String),
    /// Invalid non-shape input (an empty batch, an id out of range, ...).
    #[error("invalid input: {0}")]
    Input(String),
    /// Reading or writing a file failed.
    #[error("{path}: {message}")]
    File {
        /// The file concerned.
        path: PathBuf,
        /// What went wrong.
        message: String,
    },
    /// A task-graph operation failed.
    #[error("task graph: {0}")]
    Graph(#[from] ctg_graph::CtgError),
    /// Reading tensor values back from a device failed.
    #[error("reading tensor data: {0}")]
    Data(String),
}

impl ModelError {
    pub(crate) fn shape(
        what: &'static str,
        expected: impl Into<String>,
        got: impl std::fmt::Debug,
    ) -> Self {
        ModelError::Shape {
            what,
            expected: expected.into(),
            got: format!("{got:?}"),
        }
    }

    pub(crate) fn file(path: impl Into<PathBuf>, message: impl std::fmt::Display) -> Self {
        ModelError::File {
            path: path.into(),
            message: message.to_string(),
        }
    }
}

/// Shorthand for `Result<T, ModelError>`.
pub type Result<T, E = ModelError> = std::result::Result<T, E>;
