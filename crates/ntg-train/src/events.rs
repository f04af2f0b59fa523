//! TensorBoard event files: the training log of [`crate::fit`] in the
//! format TensorBoard (and `tensorboard.backend.event_processing`, and
//! every viewer that reads `tfevents`) reads, beside `metrics.jsonl`.
//!
//! Each training session of a run folder (a fresh start or a resume)
//! appends to a file of its own, `events.out.tfevents.<unix seconds>.ntg.<epoch>`,
//! so `tensorboard --logdir runs/` shows every run, and a video run's
//! `stage_a/` as a run of its own. Per epoch, every number of the epoch's
//! `metrics.jsonl` line is a scalar `train/<field>`, and the validation
//! score, where the epoch was validated, `validation/<score name>` (the
//! names the method gives its two numbers: `success` and `goals_met` for
//! rollouts, stage A's held-out accuracies). The step is the number of
//! epochs done (the first epoch is step 1).
//!
//! A resumed session starts with a `SessionLog` START at its first step:
//! TensorBoard then drops what an earlier session logged from that step on
//! (an epoch logged before a kill and trained again), as it does for
//! TensorFlow's own restarts. The files are written, never read back by
//! training: `metrics.jsonl` stays the run's record.
//!
//! The format: TFRecord framing (a little-endian u64 length, its masked
//! CRC-32C, the bytes, their masked CRC-32C) around `tensorflow.Event`
//! protobuf messages; the few fields used are declared below with prost.

use std::fs::{File, OpenOptions};
use std::io::Write;
use std::path::{Path, PathBuf};
use std::time::{SystemTime, UNIX_EPOCH};

use anyhow::Context;

/// `tensorflow.Event` (tensorflow/core/util/event.proto): the fields used.
#[derive(Clone, PartialEq, prost::Message)]
pub struct Event {
    /// Seconds since the Unix epoch.
    #[prost(double, tag = "1")]
    pub wall_time: f64,
    /// The training step (here: epochs done).
    #[prost(int64, tag = "2")]
    pub step: i64,
    /// What the event carries.
    #[prost(oneof = "What", tags = "3, 5, 7")]
    pub what: Option<What>,
}

/// The payload of an [`Event`].
#[derive(Clone, PartialEq, prost::Oneof)]
pub enum What {
    /// The first event of a file: `brain.Event:2`.
    #[prost(string, tag = "3")]
    FileVersion(String),
    /// Scalars.
    #[prost(message, tag = "5")]
    Summary(Summary),
    /// A session's start.
    #[prost(message, tag = "7")]
    SessionLog(SessionLog),
}

/// `tensorflow.Summary`: the scalar values of one step.
#[derive(Clone, PartialEq, prost::Message)]
pub struct Summary {
    /// The values.
    #[prost(message, repeated, tag = "1")]
    pub value: Vec<SummaryValue>,
}

/// `tensorflow.Summary.Value` with a `simple_value`.
#[derive(Clone, PartialEq, prost::Message)]
pub struct SummaryValue {
    /// The series' name (`train/loss`).
    #[prost(string, tag = "1")]
    pub tag: String,
    /// The value: a member of the proto's `oneof value`, so that it is
    /// written even when it is 0 (a plain proto3 float would be left out,
    /// and TensorBoard would drop the value).
    #[prost(oneof = "Scalar", tags = "2")]
    pub value: Option<Scalar>,
}

impl SummaryValue {
    /// A scalar value.
    pub fn scalar(tag: impl Into<String>, value: f32) -> Self {
        SummaryValue {
            tag: tag.into(),
            value: Some(Scalar::SimpleValue(value)),
        }
    }

    /// The scalar, if it is one.
    pub fn simple_value(&self) -> Option<f32> {
        self.value.map(|Scalar::SimpleValue(v)| v)
    }
}

/// The `oneof value` of `tensorflow.Summary.Value` (scalars only).
#[derive(Clone, Copy, PartialEq, prost::Oneof)]
pub enum Scalar {
    /// `simple_value`.
    #[prost(float, tag = "2")]
    SimpleValue(f32),
}

/// `tensorflow.SessionLog` (status only).
#[derive(Clone, PartialEq, prost::Message)]
pub struct SessionLog {
    /// 1: START.
    #[prost(int32, tag = "1")]
    pub status: i32,
}

/// `SessionLog.START`.
const SESSION_START: i32 = 1;

/// The part of an event file's name that TensorBoard looks for.
pub const EVENTS_FILE_MARK: &str = "tfevents";

/// An event file being appended to by one training session.
#[derive(Debug)]
pub struct EventWriter {
    path: PathBuf,
    file: File,
}

impl EventWriter {
    /// Starts this session's event file in `dir` (a run folder), whose
    /// first epoch to train is `from_epoch` (0: a fresh run): the file's
    /// version, and for a resumed run the session start that supersedes
    /// what earlier sessions logged from step `from_epoch + 1` on.
    pub fn start_session(dir: &Path, from_epoch: usize) -> anyhow::Result<Self> {
        let seconds = SystemTime::now()
            .duration_since(UNIX_EPOCH)
            .map(|d| d.as_secs())
            .unwrap_or(0);
        let path = dir.join(format!(
            "events.out.{EVENTS_FILE_MARK}.{seconds:010}.ntg.{from_epoch}"
        ));
        let file = OpenOptions::new()
            .create(true)
            .append(true)
            .open(&path)
            .with_context(|| format!("opening {}", path.display()))?;
        let mut writer = EventWriter { path, file };
        writer.write(&Event {
            wall_time: now(),
            step: 0,
            what: Some(What::FileVersion("brain.Event:2".into())),
        })?;
        if from_epoch > 0 {
            writer.write(&Event {
                wall_time: now(),
                step: from_epoch as i64 + 1,
                what: Some(What::SessionLog(SessionLog {
                    status: SESSION_START,
                })),
            })?;
        }
        Ok(writer)
    }

    /// The file being written.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Appends the numbers of `record` (a JSON object; nested objects'
    /// numbers as `outer.inner`, non-numbers and `epoch` skipped) as the
    /// scalars `<prefix>/<field>` of `epoch` (0-based; step `epoch + 1`),
    /// and flushes them to the file.
    pub fn scalars(
        &mut self,
        prefix: &str,
        epoch: usize,
        record: &serde_json::Value,
    ) -> anyhow::Result<()> {
        let mut value = Vec::new();
        collect_numbers(prefix, record, &mut value);
        value.retain(|v| v.tag != format!("{prefix}/epoch"));
        if value.is_empty() {
            return Ok(());
        }
        self.write(&Event {
            wall_time: now(),
            step: epoch as i64 + 1,
            what: Some(What::Summary(Summary { value })),
        })
    }

    /// Appends `values` as the scalars `<prefix>/<name>` of `epoch`
    /// (0-based; step `epoch + 1`), in the order given (spaces in names
    /// as `_`), and flushes them to the file.
    pub fn named_scalars(
        &mut self,
        prefix: &str,
        epoch: usize,
        values: &[(&str, f64)],
    ) -> anyhow::Result<()> {
        let value = values
            .iter()
            .map(|(name, x)| {
                SummaryValue::scalar(format!("{prefix}/{}", name.replace(' ', "_")), *x as f32)
            })
            .collect();
        self.write(&Event {
            wall_time: now(),
            step: epoch as i64 + 1,
            what: Some(What::Summary(Summary { value })),
        })
    }

    fn write(&mut self, event: &Event) -> anyhow::Result<()> {
        let bytes = prost::Message::encode_to_vec(event);
        let mut record = Vec::with_capacity(bytes.len() + 16);
        let length = (bytes.len() as u64).to_le_bytes();
        record.extend_from_slice(&length);
        record.extend_from_slice(&masked_crc(&length).to_le_bytes());
        record.extend_from_slice(&bytes);
        record.extend_from_slice(&masked_crc(&bytes).to_le_bytes());
        self.file
            .write_all(&record)
            .and_then(|()| self.file.flush())
            .with_context(|| format!("writing {}", self.path.display()))
    }
}

/// The numbers in `value` as summary values named `prefix/field` (a
/// nested object's as `prefix/outer.inner`; spaces in names as `_`).
fn collect_numbers(prefix: &str, value: &serde_json::Value, out: &mut Vec<SummaryValue>) {
    fn walk(tag: &str, value: &serde_json::Value, out: &mut Vec<SummaryValue>) {
        match value {
            serde_json::Value::Object(fields) => {
                for (name, field) in fields {
                    walk(&format!("{tag}.{}", name.replace(' ', "_")), field, out);
                }
            }
            serde_json::Value::Number(n) => {
                if let Some(x) = n.as_f64() {
                    out.push(SummaryValue::scalar(tag, x as f32));
                }
            }
            _ => {}
        }
    }
    if let serde_json::Value::Object(fields) = value {
        for (name, field) in fields {
            walk(&format!("{prefix}/{}", name.replace(' ', "_")), field, out);
        }
    }
}

fn now() -> f64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map(|d| d.as_secs_f64())
        .unwrap_or(0.0)
}

/// TFRecord's checksum: CRC-32C, rotated and offset.
fn masked_crc(bytes: &[u8]) -> u32 {
    let crc = crc32c::crc32c(bytes);
    crc.rotate_right(15).wrapping_add(0xa282_ead8)
}

/// The events of the TFRecord file `path`, each record's checksums
/// verified: for tests and tools that read what [`EventWriter`] wrote.
pub fn read_events(path: &Path) -> anyhow::Result<Vec<Event>> {
    let bytes = std::fs::read(path).with_context(|| format!("reading {}", path.display()))?;
    let mut events = Vec::new();
    let mut at = 0;
    while at < bytes.len() {
        let header = bytes
            .get(at..at + 12)
            .with_context(|| format!("{}: a record cut at byte {at}", path.display()))?;
        let length = u64::from_le_bytes(header[..8].try_into().expect("8 bytes")) as usize;
        let length_crc = u32::from_le_bytes(header[8..].try_into().expect("4 bytes"));
        anyhow::ensure!(
            masked_crc(&header[..8]) == length_crc,
            "{}: bad length checksum at byte {at}",
            path.display()
        );
        let data = bytes
            .get(at + 12..at + 12 + length)
            .with_context(|| format!("{}: a record cut at byte {at}", path.display()))?;
        let crc = bytes
            .get(at + 12 + length..at + 16 + length)
            .with_context(|| format!("{}: a record cut at byte {at}", path.display()))?;
        anyhow::ensure!(
            masked_crc(data) == u32::from_le_bytes(crc.try_into().expect("4 bytes")),
            "{}: bad data checksum at byte {at}",
            path.display()
        );
        events.push(
            <Event as prost::Message>::decode(data)
                .with_context(|| format!("{}: record at byte {at}", path.display()))?,
        );
        at += 16 + length;
    }
    Ok(events)
}

/// The event files in `dir`, oldest session first.
pub fn event_files(dir: &Path) -> anyhow::Result<Vec<PathBuf>> {
    let mut files = Vec::new();
    for entry in std::fs::read_dir(dir).with_context(|| format!("reading {}", dir.display()))? {
        let path = entry?.path();
        let is_events = path
            .file_name()
            .and_then(|n| n.to_str())
            .is_some_and(|n| n.starts_with("events.out.") && n.contains(EVENTS_FILE_MARK));
        if is_events && path.is_file() {
            files.push(path);
        }
    }
    files.sort();
    Ok(files)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_checksum_is_crc32c() {
        // The standard check value of CRC-32C (Castagnoli): "123456789"
        // gives 0xe3069283. TensorBoard's reader checks the masking
        // (tests/integration/events.rs).
        assert_eq!(crc32c::crc32c(b"123456789"), 0xe306_9283);
    }

    #[test]
    fn writes_scalars_that_read_back() {
        let dir = tempfile::tempdir().unwrap();
        let mut writer = EventWriter::start_session(dir.path(), 0).unwrap();
        // A zero is written too (a proto3 default is otherwise left out).
        let metrics =
            serde_json::json!({"epoch": 0, "loss": 0.5, "token_accuracy": 0.0, "note": "x"});
        writer.scalars("train", 0, &metrics).unwrap();
        writer
            .named_scalars("validation", 0, &[("success", 0.75), ("goals met", 1.0)])
            .unwrap();
        let files = event_files(dir.path()).unwrap();
        assert_eq!(files.len(), 1);
        let events = read_events(&files[0]).unwrap();
        assert_eq!(events.len(), 3);
        assert_eq!(
            events[0].what,
            Some(What::FileVersion("brain.Event:2".into()))
        );
        let Some(What::Summary(train)) = &events[1].what else {
            panic!("expected a summary, got {:?}", events[1]);
        };
        assert_eq!(events[1].step, 1);
        let tags: Vec<(&str, f32)> = train
            .value
            .iter()
            .map(|v| (v.tag.as_str(), v.simple_value().unwrap()))
            .collect();
        assert_eq!(tags, [("train/loss", 0.5), ("train/token_accuracy", 0.0)]);
        let Some(What::Summary(validation)) = &events[2].what else {
            panic!("expected a summary, got {:?}", events[2]);
        };
        let tags: Vec<&str> = validation.value.iter().map(|v| v.tag.as_str()).collect();
        assert_eq!(tags, ["validation/success", "validation/goals_met"]);
    }

    #[test]
    fn a_resumed_session_starts_with_a_session_start() {
        let dir = tempfile::tempdir().unwrap();
        let writer = EventWriter::start_session(dir.path(), 3).unwrap();
        let events = read_events(writer.path()).unwrap();
        assert_eq!(events.len(), 2);
        assert_eq!(events[1].step, 4);
        assert_eq!(
            events[1].what,
            Some(What::SessionLog(SessionLog {
                status: SESSION_START
            }))
        );
    }

    #[test]
    fn a_cut_file_is_an_error_naming_it() {
        let dir = tempfile::tempdir().unwrap();
        let mut writer = EventWriter::start_session(dir.path(), 0).unwrap();
        writer
            .scalars("train", 0, &serde_json::json!({"loss": 1.0}))
            .unwrap();
        let path = writer.path().to_path_buf();
        let bytes = std::fs::read(&path).unwrap();
        std::fs::write(&path, &bytes[..bytes.len() - 3]).unwrap();
        let err = format!("{:#}", read_events(&path).unwrap_err());
        assert!(err.contains("tfevents") && err.contains("cut"), "{err}");
    }
}
