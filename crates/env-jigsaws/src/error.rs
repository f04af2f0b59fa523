//! The crate's error type: every failure names the file (and, for malformed
//! content, the 1-based line).

use std::path::PathBuf;

use crate::{Task, TrialId};

/// What is wrong with one line of a JIGSAWS file.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum Problem {
    /// A kinematics row with fewer values than expected.
    #[error("short row: expected {expected} values, found {got}")]
    ShortRow {
        /// Values expected (76).
        expected: usize,
        /// Values found.
        got: usize,
    },
    /// A kinematics row with more values than expected.
    #[error("long row: expected {expected} values, found {got}")]
    LongRow {
        /// Values expected (76).
        expected: usize,
        /// Values found.
        got: usize,
    },
    /// A token that does not parse as a number.
    #[error("column {column}: `{token}` is not a number")]
    NotANumber {
        /// 1-based column.
        column: usize,
        /// The offending token.
        token: String,
    },
    /// A number that is NaN or infinite.
    #[error("column {column}: `{token}` is not a finite number")]
    NotFinite {
        /// 1-based column.
        column: usize,
        /// The offending token.
        token: String,
    },
    /// A transcription line without exactly three fields.
    #[error("a segment needs 3 fields `<start_frame> <end_frame> G<k>`, found {got}")]
    SegmentFields {
        /// Fields found.
        got: usize,
    },
    /// A frame number that is not a positive integer.
    #[error("`{token}` is not a frame number (a positive integer)")]
    BadFrame {
        /// The offending token.
        token: String,
    },
    /// Frame 0 (frames are 1-based).
    #[error("frame numbers are 1-based; 0 is not a frame")]
    FrameZero,
    /// A segment that ends before it starts.
    #[error("segment ends at frame {end}, before it starts at frame {start}")]
    EndBeforeStart {
        /// Start frame.
        start: u32,
        /// End frame.
        end: u32,
    },
    /// A gesture label outside `G1`..`G15`.
    #[error("unknown gesture `{token}` (expected G1 to G15)")]
    UnknownGesture {
        /// The offending token.
        token: String,
    },
    /// A segment that does not start after the previous one starts
    /// (segments must be in order).
    #[error(
        "segment starting at frame {start} is out of order: the previous segment starts at frame {previous_start}"
    )]
    OutOfOrder {
        /// Start frame of this segment.
        start: u32,
        /// Start frame of the previous segment.
        previous_start: u32,
    },
    /// A segment past the last kinematics row of its trial.
    #[error("segment ends at frame {end}, but the kinematics file has only {rows} rows")]
    SegmentPastEnd {
        /// End frame of the segment.
        end: u32,
        /// Rows in the kinematics file.
        rows: usize,
    },
    /// A meta row without the expected number of non-empty fields.
    #[error(
        "a meta row needs 9 non-empty fields (trial id, skill, GRS total, six sub-scores), found {got}"
    )]
    MetaFields {
        /// Non-empty fields found.
        got: usize,
    },
    /// A trial id that does not parse.
    #[error("`{token}` is not a trial id `<Task>_<Surgeon><NNN>`")]
    BadTrialId {
        /// The offending token.
        token: String,
    },
    /// A meta row of another task's trial.
    #[error("trial `{trial}` belongs to another task than {expected}")]
    WrongTask {
        /// The trial.
        trial: TrialId,
        /// The task of the file.
        expected: Task,
    },
    /// A skill letter other than N, I, E.
    #[error("`{token}` is not a skill level (N, I or E)")]
    BadSkill {
        /// The offending token.
        token: String,
    },
    /// A score outside its range.
    #[error("{field}: `{token}` is not an integer from {min} to {max}")]
    BadScore {
        /// Which score.
        field: &'static str,
        /// The offending token.
        token: String,
        /// Smallest allowed.
        min: u8,
        /// Largest allowed.
        max: u8,
    },
    /// A trial listed twice in a meta file.
    #[error("trial `{trial}` is listed twice (first on line {first_line})")]
    DuplicateTrial {
        /// The trial.
        trial: TrialId,
        /// Line of its first row.
        first_line: usize,
    },
    /// Bytes that are not UTF-8.
    #[error("not valid UTF-8 text")]
    InvalidUtf8,
}

/// Everything that can go wrong reading, writing or converting JIGSAWS data.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum JigsawsError {
    /// A file or folder could not be read or written.
    #[error("{}: {source}", path.display())]
    Io {
        /// The file or folder.
        path: PathBuf,
        /// The I/O error.
        source: std::io::Error,
    },
    /// A malformed line.
    #[error("{}:{line}: {problem}", path.display())]
    Parse {
        /// The file.
        path: PathBuf,
        /// 1-based line number.
        line: usize,
        /// What is wrong.
        problem: Problem,
    },
    /// A file with no data lines.
    #[error("{}: {what} file has no data", path.display())]
    Empty {
        /// The file.
        path: PathBuf,
        /// Which kind of file (`transcription`, `kinematics`).
        what: &'static str,
    },
    /// No task folder anywhere under the root.
    #[error(
        "{}: no JIGSAWS task folder (Suturing, Needle_Passing or Knot_Tying with transcriptions/ or kinematics/) found",
        root.display()
    )]
    NoTaskFolders {
        /// The searched root.
        root: PathBuf,
    },
    /// The output folder of the generator already holds a task folder.
    #[error("{}: already exists; write the synthetic dataset into an empty folder", path.display())]
    OutputExists {
        /// The existing task folder.
        path: PathBuf,
    },
    /// An invalid observation configuration.
    #[error("observation config: {0}")]
    Config(String),
    /// Column statistics were fitted on no rows.
    #[error("cannot fit column statistics on zero kinematics rows")]
    NoRows,
    /// A trial could not be turned into a demonstration.
    #[error("trial {trial}: {source}")]
    Demonstration {
        /// The trial.
        trial: TrialId,
        /// Why.
        source: ctg_graph::CtgError,
    },
    /// A trial whose in-memory content is inconsistent (built by hand, not
    /// read from files).
    #[error("trial {trial}: {problem}")]
    InvalidTrial {
        /// The trial.
        trial: TrialId,
        /// What is wrong.
        problem: Problem,
    },
}

/// Shorthand for `Result<T, JigsawsError>`.
pub type Result<T, E = JigsawsError> = std::result::Result<T, E>;
