//! Errors of task files, generators and demo output.

/// What can go wrong reading task files or generating tasks and demos.
///
/// Environment stepping uses `ctg_graph::CtgError` (the trait's error type).
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum BlocksError {
    /// A file could not be read or written.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: String,
        /// The I/O error.
        source: std::io::Error,
    },
    /// A file is not valid JSON of the expected shape.
    #[error("{path}:{line}:{column}: {message}")]
    Json {
        /// The file.
        path: String,
        /// 1-based line of the problem.
        line: usize,
        /// 1-based column of the problem.
        column: usize,
        /// What serde_json reported.
        message: String,
    },
    /// A task in a task file is invalid.
    #[error("{path}: task {index} (`{id}`): {message}")]
    Task {
        /// The file.
        path: String,
        /// 0-based position of the task in the file.
        index: usize,
        /// The task's id.
        id: String,
        /// What is wrong.
        message: String,
    },
    /// A generator could not produce what was asked.
    #[error("generator: {0}")]
    Generator(String),
    /// An invalid configuration or request.
    #[error("invalid: {0}")]
    Invalid(String),
    /// An environment or expert error.
    #[error(transparent)]
    Ctg(#[from] ctg_graph::CtgError),
    /// An image could not be encoded or written.
    #[error("{path}: {message}")]
    Image {
        /// The file.
        path: String,
        /// What went wrong.
        message: String,
    },
}
