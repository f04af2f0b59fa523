//! The one error type of the crate.

use crate::ActionId;

/// Everything that can go wrong in `ctg-graph`, and in the environments built
/// on its traits.
///
/// Every fallible public function returns `Result<_, CtgError>`; nothing in
/// this crate panics on user input.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum CtgError {
    /// An action name was given twice when building a vocabulary.
    #[error("vocabulary: action `{0}` appears twice")]
    DuplicateAction(String),
    /// An action name was empty or all whitespace.
    #[error("vocabulary: action names must not be empty")]
    EmptyActionName,
    /// An action name collides with `<start>` or `<end>`.
    #[error("vocabulary: `{0}` is reserved for the graph's start/end node")]
    ReservedName(String),
    /// A name that is not in the vocabulary.
    #[error("unknown action `{0}`")]
    UnknownAction(String),
    /// An action id past the end of the vocabulary or graph.
    #[error("action id {id} is outside the {len} nodes of the vocabulary")]
    ActionOutOfRange {
        /// The offending id.
        id: usize,
        /// Number of nodes (reserved ones included).
        len: usize,
    },
    /// `<start>` or `<end>` used where only real actions are allowed (for
    /// example inside a demonstrated action sequence).
    #[error("`{0}` is a reserved node and cannot appear as an action here")]
    ReservedAction(&'static str),
    /// A demonstration with no actions.
    #[error("a demonstration needs at least one action")]
    EmptyDemonstration,
    /// A demonstration whose observation and action counts disagree.
    #[error(
        "a demonstration with {actions} actions needs {expected} observations \
         (one before the first action and one after each), got {observations}"
    )]
    ObservationCount {
        /// Number of actions.
        actions: usize,
        /// Number of observations given.
        observations: usize,
        /// Number of observations required (`actions + 1`).
        expected: usize,
    },
    /// A video demonstration whose frame segments do not match its actions:
    /// it needs one segment of frames before the first action and one per
    /// action, none empty.
    #[error(
        "a video demonstration with {actions} actions needs {expected} non-empty \
         frame segments (one before the first action and one per action): {problem}"
    )]
    VideoSegments {
        /// Number of actions.
        actions: usize,
        /// Number of segments required (`actions + 1`).
        expected: usize,
        /// What is wrong.
        problem: String,
    },
    /// Two graphs (or a graph and a vocabulary) of different sizes.
    #[error("size mismatch: {left} nodes vs {right} nodes")]
    SizeMismatch {
        /// Size of the first operand.
        left: usize,
        /// Size of the second operand.
        right: usize,
    },
    /// A flat adjacency matrix whose length is not `n * n`.
    #[error("adjacency matrix has {got} entries, expected {expected} ({n}x{n})")]
    AdjacencyShape {
        /// Entries given.
        got: usize,
        /// Entries expected.
        expected: usize,
        /// Number of nodes.
        n: usize,
    },
    /// A serialised graph that declares more nodes than may be read.
    #[error("graph declares {n} nodes, more than the {max} a graph may have")]
    TooManyNodes {
        /// Nodes declared.
        n: usize,
        /// The most allowed.
        max: usize,
    },
    /// A serialised graph that lists one edge twice.
    #[error("edge {from:?} -> {to:?} is listed twice")]
    DuplicateEdge {
        /// Source node.
        from: ActionId,
        /// Target node.
        to: ActionId,
    },
    /// A serialised graph in neither of the known layouts.
    #[error("malformed graph: {0}")]
    GraphFormat(String),
    /// An edge weight that is not a finite number in `[0, 1]`.
    #[error("edge weight {weight} on {from:?} -> {to:?} is not a number in [0, 1]")]
    InvalidWeight {
        /// Source node.
        from: ActionId,
        /// Target node.
        to: ActionId,
        /// The rejected weight.
        weight: f32,
    },
    /// A threshold that is NaN.
    #[error("threshold must be a number, got NaN")]
    InvalidThreshold,
    /// A scorer returned the wrong number of scores, or a negative or
    /// non-finite score.
    #[error("scorer output invalid: {0}")]
    InvalidScores(String),
    /// The executor found no action with positive probability among the CTG
    /// successors of the current nodes.
    #[error("no CTG successor of the current node has positive probability")]
    NoValidAction,
    /// An environment rejected an action (not applicable in this
    /// environment at all, e.g. `<start>`).
    #[error("invalid action `{action}`: {reason}")]
    InvalidAction {
        /// Name (or id) of the action.
        action: String,
        /// Why it was rejected.
        reason: String,
    },
    /// `step` was called before the first `reset`.
    #[error("the environment must be reset before it can step")]
    NotReset,
    /// `step` was called after the episode terminated or was truncated.
    #[error("the episode is over (terminated or truncated); call reset")]
    EpisodeOver,
    /// An expert could not finish its demonstration.
    #[error("expert failed: {0}")]
    ExpertFailed(String),
    /// An environment broke the contract that `check_environment` checks.
    #[error("environment conformance: {0}")]
    Conformance(String),
    /// Any other environment-specific failure.
    #[error("environment: {0}")]
    Environment(String),
}

/// Shorthand for `Result<T, CtgError>`.
pub type Result<T, E = CtgError> = std::result::Result<T, E>;
