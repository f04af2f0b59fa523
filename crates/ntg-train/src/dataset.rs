//! Demonstration datasets: generated in parallel from any environment and
//! expert, held in one flat observation buffer, cached on disk.
//!
//! # On-disk format (`ntg-dataset/1`)
//!
//! A dataset folder holds two files:
//!
//! - `index.json`: `{"format": "ntg-dataset/1", "obs_dim": D, "dtype": "f32" | "u8",
//!   "vocabulary": [action names], "demos": [{"task": t, "seed": s,
//!   "actions": [ids], "first_row": r}]}`. Demo *i* owns observation rows
//!   `first_row .. first_row + actions.len() + 1`, in order; a video demo
//!   also has `"segment_ends": [e0, e1, ...]` (one per action plus the
//!   first, relative to `first_row`) and owns its `e_last` frames.
//! - `observations.bin`: every observation row back to back, `D` values per
//!   row, little-endian `f32`, or `u8` holding `round(255 * value)` for
//!   observations whose values are multiples of 1/255 in `[0, 1]` (frames).
//!
//! A dataset of bytes may be stored compressed (`"compression": "zlib"` in
//! its index; stage A's frame caches, [`DemoDataset::load_or_build_mapped_in_parts`]):
//! `observations.bin` then holds each row as its own zlib stream, back to
//! back, and `row_offsets.bin` where each row's stream starts, as
//! little-endian `u64`, followed by the file's length. Rendered frames
//! shrink about 60-fold, and any row is read without the others.

use std::fs;
use std::io::{BufReader, BufWriter, Read, Write};
use std::ops::Range;
use std::path::Path;

use anyhow::{Context, bail, ensure};
use ctg_graph::{
    ActionId, Demonstration, Environment, Expert, VideoDemonstration, Vocabulary,
    record_demonstration,
};
use indicatif::{ProgressBar, ProgressStyle};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

const FORMAT: &str = "ntg-dataset/1";

/// How observation values are stored.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum ObsDtype {
    /// 32-bit floats (state vectors, kinematics).
    F32,
    /// Bytes, `value = byte / 255` (rendered frames): 4x smaller.
    U8,
}

/// How a saved dataset's `observations.bin` holds its rows.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
enum RowCompression {
    /// Every row's values back to back.
    #[default]
    None,
    /// Each row of bytes a zlib stream of its own (module docs).
    Zlib,
}

impl RowCompression {
    fn is_none(&self) -> bool {
        *self == RowCompression::None
    }
}

/// The zlib level rows are compressed at: rendered 128x128 frames shrink
/// about 66-fold at 6 against 26-fold at 1, and inflating one takes about
/// 0.07 ms either way.
const ZLIB_LEVEL: u32 = 6;

/// The file beside a compressed `observations.bin` saying where its rows
/// start.
const ROW_OFFSETS: &str = "row_offsets.bin";

#[derive(Debug, Clone)]
enum ObsBuffer {
    F32(Vec<f32>),
    U8(Vec<u8>),
    /// Bytes of a saved dataset's `observations.bin`, mapped rather than
    /// read ([`DemoDataset::load_mapped`]): read-only.
    MappedU8(MappedBytes),
    /// Rows of bytes compressed one by one, mapped from a saved dataset's
    /// `observations.bin` (module docs): read-only.
    Zlib(ZlibRows),
}

/// A compressed `observations.bin`, mapped, and where each row's stream
/// starts (one offset more than rows: the last is the file's length).
/// Every row inflates to the dataset's row size: [`DemoDataset::load`]
/// checks it before handing the rows out.
#[derive(Debug, Clone)]
struct ZlibRows {
    data: MappedBytes,
    offsets: std::sync::Arc<Vec<u64>>,
}

impl ZlibRows {
    fn num_rows(&self) -> usize {
        self.offsets.len().saturating_sub(1)
    }

    /// Row `row`'s compressed stream.
    fn stream(&self, row: usize) -> &[u8] {
        &self.data.as_slice()[self.offsets[row] as usize..self.offsets[row + 1] as usize]
    }

    /// Row `row`'s bytes, inflated into `out` (cleared first).
    fn inflate(&self, row: usize, out: &mut Vec<u8>) -> std::io::Result<()> {
        out.clear();
        flate2::read::ZlibDecoder::new(self.stream(row)).read_to_end(out)?;
        Ok(())
    }

    /// The compressed rows of the dataset in `dir`, which its index says
    /// has `rows` rows of `obs_dim` bytes: `observations.bin` mapped and
    /// `row_offsets.bin` read, checking that the offsets fit the file and
    /// that every row inflates to `obs_dim` bytes (in parallel: about a
    /// second per 30,000 rows on one core), so that reading a row later
    /// cannot fail.
    fn read(dir: &Path, rows: usize, obs_dim: usize) -> anyhow::Result<Self> {
        let bin_path = dir.join("observations.bin");
        let offsets_path = dir.join(ROW_OFFSETS);
        let data = MappedBytes::map(&bin_path)?;
        let raw = fs::read(&offsets_path)
            .with_context(|| format!("reading {}", offsets_path.display()))?;
        ensure!(
            raw.len() == 8 * (rows + 1),
            "{}: {} bytes, expected {} (an offset for each of {rows} rows and the end); \
             the file is truncated or does not belong to this index",
            offsets_path.display(),
            raw.len(),
            8 * (rows + 1)
        );
        let offsets: Vec<u64> = raw
            .chunks_exact(8)
            .map(|c| u64::from_le_bytes(c.try_into().expect("8 bytes")))
            .collect();
        ensure!(
            offsets.first() == Some(&0)
                && offsets.windows(2).all(|w| w[0] < w[1])
                && offsets.last() == Some(&(data.as_slice().len() as u64)),
            "{}: the row offsets do not run from 0 to the length of {} ({} bytes): a file is truncated or does not belong to this index",
            offsets_path.display(),
            bin_path.display(),
            data.as_slice().len()
        );
        let rows = ZlibRows {
            data,
            offsets: std::sync::Arc::new(offsets),
        };
        let bad = (0..rows.num_rows()).into_par_iter().find_first(|&r| {
            let mut row = Vec::with_capacity(obs_dim);
            rows.inflate(r, &mut row).is_err() || row.len() != obs_dim
        });
        if let Some(r) = bad {
            bail!(
                "{}: row {r} does not inflate to {obs_dim} bytes; the file is damaged: remove {} to build it again",
                bin_path.display(),
                dir.display()
            );
        }
        Ok(rows)
    }
}

/// `bytes` as a zlib stream of its own.
fn deflate_row(bytes: &[u8]) -> Vec<u8> {
    let mut encoder = flate2::write::ZlibEncoder::new(
        Vec::with_capacity(bytes.len() / 16),
        flate2::Compression::new(ZLIB_LEVEL),
    );
    encoder
        .write_all(bytes)
        .and_then(|()| encoder.finish())
        .expect("writing to memory does not fail")
}

/// Equal values, however stored (in memory or mapped).
impl PartialEq for ObsBuffer {
    fn eq(&self, other: &Self) -> bool {
        match (self, other) {
            (ObsBuffer::F32(a), ObsBuffer::F32(b)) => a == b,
            (ObsBuffer::F32(_), _) | (_, ObsBuffer::F32(_)) => false,
            _ => self.same_bytes(other),
        }
    }
}

impl ObsBuffer {
    /// The stored bytes, where the values are bytes.
    fn bytes(&self) -> Option<&[u8]> {
        match self {
            ObsBuffer::F32(_) => None,
            ObsBuffer::U8(b) => Some(b),
            ObsBuffer::MappedU8(m) => Some(m.as_slice()),
            ObsBuffer::Zlib(_) => None,
        }
    }

    /// Whether `self` and `other`, both rows of bytes, hold the same values
    /// in the same order, inflating compressed rows one at a time (never
    /// the whole of a cache of many gigabytes).
    fn same_bytes(&self, other: &Self) -> bool {
        let (mut a, mut b) = (Vec::new(), Vec::new());
        match (self, other) {
            (ObsBuffer::Zlib(x), ObsBuffer::Zlib(y)) => {
                x.num_rows() == y.num_rows()
                    && (0..x.num_rows()).all(|r| {
                        x.inflate(r, &mut a).is_ok() && y.inflate(r, &mut b).is_ok() && a == b
                    })
            }
            (ObsBuffer::Zlib(rows), plain) | (plain, ObsBuffer::Zlib(rows)) => {
                let Some(bytes) = plain.bytes() else {
                    return false;
                };
                let mut at = 0;
                (0..rows.num_rows()).all(|r| {
                    let fits = rows.inflate(r, &mut a).is_ok()
                        && bytes.get(at..at + a.len()) == Some(&a[..]);
                    at += a.len();
                    fits
                }) && at == bytes.len()
            }
            _ => self.bytes().is_some() && self.bytes() == other.bytes(),
        }
    }
}

/// A file mapped into memory, shared by the clones of its dataset; pages
/// are read from disk as rows are used and the kernel may drop them again,
/// so a dataset larger than the machine's memory can be trained on.
#[derive(Clone)]
struct MappedBytes(std::sync::Arc<memmap2::Mmap>);

impl MappedBytes {
    fn map(path: &Path) -> anyhow::Result<Self> {
        let file = fs::File::open(path).with_context(|| format!("reading {}", path.display()))?;
        // SAFETY: the mapped file is a finished dataset's
        // `observations.bin`, which this crate only ever replaces by
        // renaming a new file over it (`save`), never writes in place; a
        // rename leaves the mapped file's pages as they were.
        #[allow(unsafe_code)]
        let map = unsafe { memmap2::Mmap::map(&file) }
            .with_context(|| format!("mapping {}", path.display()))?;
        Ok(MappedBytes(std::sync::Arc::new(map)))
    }

    fn as_slice(&self) -> &[u8] {
        &self.0
    }
}

impl PartialEq for MappedBytes {
    fn eq(&self, other: &Self) -> bool {
        self.as_slice() == other.as_slice()
    }
}

impl std::fmt::Debug for MappedBytes {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "MappedBytes({} bytes)", self.0.len())
    }
}

/// One demonstration's entry in a [`DemoDataset`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct DemoEntry {
    /// Index of the task in the domain's task list.
    pub task: usize,
    /// Seed the demonstration was recorded with.
    pub seed: u64,
    /// The flat action sequence.
    pub actions: Vec<ActionId>,
    /// First observation row.
    pub first_row: usize,
    /// Video demonstrations: the exclusive end of each frame segment,
    /// relative to `first_row` (see `ctg_graph::VideoDemonstration`); the
    /// demo owns every frame. `None`: one row per CTG node (keyframes).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub segment_ends: Option<Vec<usize>>,
}

impl DemoEntry {
    /// Number of observation rows: one more than actions, or a video's
    /// frames.
    pub fn num_rows(&self) -> usize {
        match &self.segment_ends {
            Some(ends) => ends.last().copied().unwrap_or(0),
            None => self.actions.len() + 1,
        }
    }

    /// Observation rows of this demonstration (all of a video's frames).
    pub fn rows(&self) -> Range<usize> {
        self.first_row..self.first_row + self.num_rows()
    }

    /// Index within [`DemoEntry::rows`] of the row at each CTG node (one
    /// more than actions): every row, or the last frame of each segment of
    /// a video.
    pub fn keyframes(&self) -> Vec<usize> {
        match &self.segment_ends {
            Some(ends) => ends.iter().map(|&e| e - 1).collect(),
            None => (0..=self.actions.len()).collect(),
        }
    }

    /// Checks that a video's segments fit its actions (one non-empty
    /// segment per action, plus the first).
    fn check_segments(&self) -> anyhow::Result<()> {
        if let Some(ends) = &self.segment_ends {
            ensure!(
                ends.len() == self.actions.len() + 1,
                "{} segments for {} actions",
                ends.len(),
                self.actions.len()
            );
            ensure!(
                ends.first().is_some_and(|&e| e > 0) && ends.windows(2).all(|w| w[0] < w[1]),
                "frame segments must be non-empty and in order"
            );
        }
        Ok(())
    }
}

#[derive(Serialize, Deserialize)]
struct Index {
    format: String,
    obs_dim: usize,
    dtype: ObsDtype,
    #[serde(default, skip_serializing_if = "RowCompression::is_none")]
    compression: RowCompression,
    vocabulary: Vocabulary,
    demos: Vec<DemoEntry>,
}

/// Featurised demonstrations of many (task, seed) pairs.
#[derive(Debug, Clone, PartialEq)]
pub struct DemoDataset {
    vocab: Vocabulary,
    obs_dim: usize,
    obs: ObsBuffer,
    demos: Vec<DemoEntry>,
}

/// Bytes a dataset built in parts of about `part_bytes` each still needs
/// on disk when `missing` parts are not built yet: those
/// parts, and one part more while they are concatenated (each part is
/// removed once it is written into the whole, so the whole never sits
/// beside all of its parts).
fn space_needed(part_bytes: u64, missing: usize) -> u64 {
    part_bytes * (missing as u64 + 1)
}

/// Refuses to go on building the dataset of `dir` when `needed` bytes are
/// more than the `available` ones, saying both and what they are made of.
fn check_space(
    dir: &Path,
    needed: u64,
    available: u64,
    part_bytes: u64,
    num_parts: usize,
) -> anyhow::Result<()> {
    let gb = |b: u64| b as f64 / 1e9;
    ensure!(
        needed <= available,
        "{}: building this dataset needs about {:.1} GB more disk space, and {:.1} GB are free \
         ({num_parts} parts of about {:.1} GB, then their concatenation); free some space \
         or use fewer videos, then run the same command again (finished parts are kept)",
        dir.display(),
        gb(needed),
        gb(available),
        gb(part_bytes)
    );
    Ok(())
}

impl DemoDataset {
    /// Errors unless the dataset's vocabulary has the `num_nodes` nodes of
    /// the network (`what`: "model", "policy") that is to learn from it.
    pub fn check_num_nodes(&self, num_nodes: usize, what: &str) -> anyhow::Result<()> {
        ensure!(
            self.vocabulary().len() == num_nodes,
            "the dataset's vocabulary has {} nodes, the {what} {num_nodes}",
            self.vocabulary().len()
        );
        Ok(())
    }

    /// Builds a dataset from featurised demonstrations (each observation a
    /// row of `obs_dim` values).
    pub fn from_demos(
        vocab: Vocabulary,
        obs_dim: usize,
        dtype: ObsDtype,
        demos: impl IntoIterator<Item = (usize, u64, Demonstration<Vec<f32>>)>,
    ) -> anyhow::Result<Self> {
        let mut obs = match dtype {
            ObsDtype::F32 => ObsBuffer::F32(Vec::new()),
            ObsDtype::U8 => ObsBuffer::U8(Vec::new()),
        };
        let mut entries = Vec::new();
        let mut row = 0;
        for (task, seed, demo) in demos {
            for o in demo.observations() {
                ensure!(
                    o.len() == obs_dim,
                    "task {task} seed {seed}: observation has {} values, expected {obs_dim}",
                    o.len()
                );
                match &mut obs {
                    ObsBuffer::F32(buf) => buf.extend_from_slice(o),
                    ObsBuffer::U8(buf) => {
                        for &v in o {
                            ensure!(
                                (0.0..=1.0).contains(&v),
                                "task {task} seed {seed}: value {v} cannot be stored as u8"
                            );
                            buf.push((v * 255.0).round() as u8);
                        }
                    }
                    ObsBuffer::MappedU8(_) | ObsBuffer::Zlib(_) => {
                        unreachable!("a new dataset is in memory")
                    }
                }
            }
            entries.push(DemoEntry {
                task,
                seed,
                actions: demo.actions().to_vec(),
                first_row: row,
                segment_ends: None,
            });
            row += demo.len() + 1;
        }
        Ok(DemoDataset {
            vocab,
            obs_dim,
            obs,
            demos: entries,
        })
    }

    /// Builds a dataset of video demonstrations whose frames are already
    /// featurised (`obs_dim` values each, stored as `f32`).
    pub fn from_videos(
        vocab: Vocabulary,
        obs_dim: usize,
        videos: impl IntoIterator<Item = (usize, u64, VideoDemonstration<Vec<f32>>)>,
    ) -> anyhow::Result<Self> {
        let mut dataset = DemoDataset {
            vocab,
            obs_dim,
            obs: ObsBuffer::F32(Vec::new()),
            demos: Vec::new(),
        };
        for (task, seed, video) in videos {
            dataset.push_video(task, seed, video)?;
        }
        Ok(dataset)
    }

    /// Appends one featurised video demonstration.
    pub fn push_video(
        &mut self,
        task: usize,
        seed: u64,
        video: VideoDemonstration<Vec<f32>>,
    ) -> anyhow::Result<()> {
        let first_row = self.num_rows();
        let ends = video.segments().map(|r| r.end).collect::<Vec<usize>>();
        let (frames, _, actions) = video.into_parts();
        for (k, f) in frames.iter().enumerate() {
            ensure!(
                f.len() == self.obs_dim,
                "task {task} seed {seed}: frame {k} has {} values, expected {}",
                f.len(),
                self.obs_dim
            );
            match &mut self.obs {
                ObsBuffer::F32(buf) => buf.extend_from_slice(f),
                ObsBuffer::U8(buf) => {
                    for &v in f {
                        ensure!(
                            (0.0..=1.0).contains(&v),
                            "task {task} seed {seed}: value {v} cannot be stored as u8"
                        );
                        buf.push((v * 255.0).round() as u8);
                    }
                }
                ObsBuffer::MappedU8(_) | ObsBuffer::Zlib(_) => {
                    bail!("a dataset read from disk (mapped) takes no more demonstrations")
                }
            }
        }
        self.demos.push(DemoEntry {
            task,
            seed,
            actions,
            first_row,
            segment_ends: Some(ends),
        });
        Ok(())
    }

    /// Whether the demonstrations are videos (several frames per action).
    pub fn is_video(&self) -> bool {
        self.demos.iter().any(|d| d.segment_ends.is_some())
    }

    /// The action vocabulary.
    pub fn vocabulary(&self) -> &Vocabulary {
        &self.vocab
    }

    /// Values per observation row.
    pub fn obs_dim(&self) -> usize {
        self.obs_dim
    }

    /// The demonstrations.
    pub fn demos(&self) -> &[DemoEntry] {
        &self.demos
    }

    /// Total observation rows.
    pub fn num_rows(&self) -> usize {
        match (&self.obs, self.obs.bytes()) {
            (ObsBuffer::F32(b), _) => b.len() / self.obs_dim.max(1),
            (ObsBuffer::Zlib(rows), _) => rows.num_rows(),
            (_, bytes) => bytes.map_or(0, <[u8]>::len) / self.obs_dim.max(1),
        }
    }

    /// Bytes the observations take in memory or on disk (compressed where
    /// they are).
    fn stored_bytes(&self) -> u64 {
        match &self.obs {
            ObsBuffer::F32(b) => 4 * b.len() as u64,
            ObsBuffer::Zlib(rows) => rows.data.as_slice().len() as u64,
            obs => obs.bytes().map_or(0, |b| b.len() as u64),
        }
    }

    /// Appends observation row `row` (as `f32`) to `out`.
    pub fn extend_row(&self, row: usize, out: &mut Vec<f32>) {
        let range = row * self.obs_dim..(row + 1) * self.obs_dim;
        match (&self.obs, self.obs.bytes()) {
            (ObsBuffer::F32(b), _) => out.extend_from_slice(&b[range]),
            (ObsBuffer::Zlib(rows), _) => {
                let mut bytes = Vec::with_capacity(self.obs_dim);
                rows.inflate(row, &mut bytes)
                    .expect("every row inflates: checked when the dataset was read");
                out.extend(bytes.iter().map(|&v| f32::from(v) / 255.0));
            }
            (_, Some(b)) => out.extend(b[range].iter().map(|&v| f32::from(v) / 255.0)),
            (_, None) => unreachable!("values are f32 or bytes"),
        }
    }

    /// Observation row `row` as a new vector.
    pub fn row(&self, row: usize) -> Vec<f32> {
        let mut v = Vec::with_capacity(self.obs_dim);
        self.extend_row(row, &mut v);
        v
    }

    /// Demonstration `i` as rows of `f32` (a video's keyframes).
    pub fn demonstration(&self, i: usize) -> anyhow::Result<Demonstration<Vec<f32>>> {
        let entry = &self.demos[i];
        let obs = entry
            .keyframes()
            .into_iter()
            .map(|k| self.row(entry.first_row + k))
            .collect();
        Ok(Demonstration::new(obs, entry.actions.clone(), &self.vocab)?)
    }

    /// Writes `observations.bin` and then `index.json` into `dir` (created
    /// if needed), each through a temporary file renamed into place: the
    /// index, which [`DemoDataset::load_or_build`] looks for, appears only
    /// once the observations are whole, so a save killed half-way is
    /// rebuilt rather than read. A compressed dataset stays compressed.
    pub fn save(&self, dir: &Path) -> anyhow::Result<()> {
        let compression = match self.obs {
            ObsBuffer::Zlib(_) => RowCompression::Zlib,
            _ => RowCompression::None,
        };
        self.save_as(dir, compression)
    }

    /// [`DemoDataset::save`] with each row compressed on its own (module
    /// docs), for rows of bytes: a frame cache of many gigabytes takes a
    /// few hundred megabytes. It is read back mapped, whichever way it is
    /// loaded.
    pub fn save_compressed(&self, dir: &Path) -> anyhow::Result<()> {
        ensure!(
            !matches!(self.obs, ObsBuffer::F32(_)),
            "only a dataset of bytes (frames) is stored compressed"
        );
        self.save_as(dir, RowCompression::Zlib)
    }

    fn save_as(&self, dir: &Path, compression: RowCompression) -> anyhow::Result<()> {
        fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
        let index = Index {
            format: FORMAT.into(),
            obs_dim: self.obs_dim,
            dtype: match self.obs {
                ObsBuffer::F32(_) => ObsDtype::F32,
                ObsBuffer::U8(_) | ObsBuffer::MappedU8(_) | ObsBuffer::Zlib(_) => ObsDtype::U8,
            },
            compression,
            vocabulary: self.vocab.clone(),
            demos: self.demos.clone(),
        };
        let index_path = dir.join("index.json");
        if index_path.exists() {
            fs::remove_file(&index_path)
                .with_context(|| format!("removing {}", index_path.display()))?;
        }
        let bin_path = dir.join("observations.bin");
        let bin_tmp = dir.join("observations.bin.partial");
        let file =
            fs::File::create(&bin_tmp).with_context(|| format!("writing {}", bin_tmp.display()))?;
        let mut w = BufWriter::new(file);
        let mut offsets = Vec::new();
        match (compression, &self.obs) {
            (RowCompression::Zlib, obs) => {
                write_compressed_rows(obs, self.obs_dim, &mut w, &mut offsets, 0)
                    .with_context(|| format!("writing {}", bin_tmp.display()))?;
            }
            (RowCompression::None, ObsBuffer::F32(b)) => {
                for v in b {
                    w.write_all(&v.to_le_bytes())?;
                }
            }
            (RowCompression::None, ObsBuffer::U8(b)) => w.write_all(b)?,
            (RowCompression::None, ObsBuffer::MappedU8(m)) => w.write_all(m.as_slice())?,
            (RowCompression::None, ObsBuffer::Zlib(rows)) => {
                let mut row = Vec::new();
                for r in 0..rows.num_rows() {
                    rows.inflate(r, &mut row)?;
                    w.write_all(&row)?;
                }
            }
        }
        w.flush()
            .with_context(|| format!("writing {}", bin_tmp.display()))?;
        drop(w);
        fs::rename(&bin_tmp, &bin_path)
            .with_context(|| format!("renaming {} to {}", bin_tmp.display(), bin_path.display()))?;
        write_row_offsets(dir, compression, &offsets)?;
        write_index(&index, &index_path)
    }

    /// The dataset cached in `dir` if there is one; otherwise `build`'s,
    /// saved there first.
    pub fn load_or_build(
        dir: &Path,
        build: impl FnOnce() -> anyhow::Result<Self>,
    ) -> anyhow::Result<Self> {
        if dir.join("index.json").is_file() {
            return Self::load(dir);
        }
        let dataset = build()?;
        dataset.save(dir)?;
        Ok(dataset)
    }

    /// Like [`DemoDataset::load_or_build`] for a dataset of one demo per
    /// `(task, seed)` of `pairs`, in that order, whose build is long
    /// (stage B's encoding of 100,000 videos takes most of an hour on one
    /// core): built `part_len` pairs at a time by `build_part`, each part
    /// saved as it is done in `DIR.parts/NNNNN/`, so a build that is killed
    /// resumes after its last whole part. The whole is then saved in `dir`
    /// and the parts removed. Parts are independent (`build_part` of a
    /// slice gives the same demos whatever the slices), so the result is
    /// the one [`DemoDataset::load_or_build`] would give. Up to `part_len`
    /// pairs are built in one go, with no parts.
    pub fn load_or_build_in_parts(
        dir: &Path,
        pairs: &[(usize, u64)],
        part_len: usize,
        mut build_part: impl FnMut(&[(usize, u64)], &str) -> anyhow::Result<Self>,
    ) -> anyhow::Result<Self> {
        ensure!(
            part_len > 0,
            "parts of a dataset must hold at least one demo"
        );
        if pairs.len() <= part_len {
            return Self::load_or_build(dir, || build_part(pairs, ""));
        }
        let parts_dir = dir.with_extension("parts");
        if dir.join("index.json").is_file() {
            // Parts a kill left after the whole was saved.
            if parts_dir.exists() {
                fs::remove_dir_all(&parts_dir)
                    .with_context(|| format!("removing {}", parts_dir.display()))?;
            }
            return Self::load(dir);
        }
        let mut parts = build_in_parts(
            &parts_dir,
            pairs,
            part_len,
            |part_dir| {
                part_dir
                    .join("index.json")
                    .is_file()
                    .then(|| Self::load(part_dir))
                    .transpose()
            },
            |part: &Self, part_pairs| {
                part.demos
                    .iter()
                    .map(|d| (d.task, d.seed))
                    .eq(part_pairs.iter().copied())
            },
            &mut build_part,
            |part, part_dir| part.save(part_dir),
        )?
        .into_iter();
        let mut whole = parts.next().context("no parts")?;
        for part in parts {
            whole.append(part)?;
        }
        whole.save(dir)?;
        fs::remove_dir_all(&parts_dir)
            .with_context(|| format!("removing {}", parts_dir.display()))?;
        Ok(whole)
    }

    /// [`DemoDataset::load_or_build_in_parts`] for a dataset of bytes too
    /// large to hold in memory (stage A's frames of 20,000 videos at
    /// 128×128 are 18 GB): each part is built, saved in `DIR.parts/NNNNN/`
    /// and dropped before the next, the whole is written by concatenating
    /// the parts' files, and it is returned mapped from its file
    /// ([`DemoDataset::load_mapped`]). Its rows are those
    /// [`DemoDataset::load_or_build`] would give; at most one part's are in
    /// memory at a time.
    pub fn load_or_build_mapped_in_parts(
        dir: &Path,
        pairs: &[(usize, u64)],
        part_len: usize,
        mut build_part: impl FnMut(&[(usize, u64)], &str) -> anyhow::Result<Self>,
    ) -> anyhow::Result<Self> {
        ensure!(
            part_len > 0,
            "parts of a dataset must hold at least one demo"
        );
        let parts_dir = dir.with_extension("parts");
        if dir.join("index.json").is_file() {
            if parts_dir.exists() {
                fs::remove_dir_all(&parts_dir)
                    .with_context(|| format!("removing {}", parts_dir.display()))?;
            }
            return Self::load_mapped(dir);
        }
        if pairs.len() <= part_len {
            build_part(pairs, "")?.save_compressed(dir)?;
            return Self::load_mapped(dir);
        }
        let num_parts = pairs.len().div_ceil(part_len);
        let part_dir_of = |k: usize| parts_dir.join(format!("{k:05}"));
        let mut parts = Vec::with_capacity(num_parts);
        for (k, part_pairs) in pairs.chunks(part_len).enumerate() {
            let part_dir = part_dir_of(k);
            if !part_dir.join("index.json").is_file() {
                build_part(part_pairs, &format!(" {}/{num_parts}", k + 1))?
                    .save_compressed(&part_dir)?;
            }
            let part = Self::load_mapped(&part_dir)?;
            if k == 0 {
                // The first part tells the size of the others: refuse now,
                // with the numbers, rather than fill the disk hours later.
                let missing = (1..num_parts)
                    .filter(|&j| !part_dir_of(j).join("index.json").is_file())
                    .count();
                let part_bytes = part.stored_bytes();
                let needed = space_needed(part_bytes, missing);
                let available = fs4::available_space(&parts_dir).with_context(|| {
                    format!("reading the free space of {}", parts_dir.display())
                })?;
                check_space(dir, needed, available, part_bytes, num_parts)?;
            }
            ensure!(
                part.demos
                    .iter()
                    .map(|d| (d.task, d.seed))
                    .eq(part_pairs.iter().copied()),
                "{}: a part holding other demos than this build's part {k} \
                 (built with other settings?); remove {} to build again",
                part_dir.display(),
                parts_dir.display()
            );
            parts.push((part, part_dir));
        }
        Self::concatenate(parts, dir)?;
        fs::remove_dir_all(&parts_dir)
            .with_context(|| format!("removing {}", parts_dir.display()))?;
        Self::load_mapped(dir)
    }

    /// Saves `parts` (of one vocabulary and row size, rows of bytes, each
    /// with the folder it is mapped from) one after the other as one
    /// compressed dataset in `dir`, as [`DemoDataset::save_compressed`]
    /// does, writing each part's rows straight to the file (compressing
    /// those of a part saved uncompressed) and removing the part's folder
    /// once they are written: the disk holds the whole and at most one part
    /// beside it. A build killed meanwhile builds the removed parts again
    /// (the same frames: each video's draw is its own) and concatenates
    /// anew.
    fn concatenate(parts: Vec<(Self, std::path::PathBuf)>, dir: &Path) -> anyhow::Result<()> {
        let (vocab, obs_dim) = match parts.first() {
            Some((first, _)) => (first.vocab.clone(), first.obs_dim),
            None => bail!("no parts"),
        };
        fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
        let mut demos = Vec::new();
        let bin_tmp = dir.join("observations.bin.partial");
        let file =
            fs::File::create(&bin_tmp).with_context(|| format!("writing {}", bin_tmp.display()))?;
        let mut w = BufWriter::new(file);
        let mut offset = 0;
        let (mut row_offsets, mut written) = (Vec::new(), 0);
        for (part, part_dir) in parts {
            ensure!(
                part.vocab == vocab && part.obs_dim == obs_dim,
                "datasets of different vocabularies or row sizes"
            );
            ensure!(
                !matches!(part.obs, ObsBuffer::F32(_)),
                "only datasets of bytes are concatenated on disk"
            );
            written += write_compressed_rows(&part.obs, obs_dim, &mut w, &mut row_offsets, written)
                .with_context(|| format!("writing {}", bin_tmp.display()))?;
            // The part's rows are on their way to the file: flushed before
            // the part they come from is unmapped and removed.
            w.flush()
                .with_context(|| format!("writing {}", bin_tmp.display()))?;
            demos.extend(part.demos.iter().map(|d| DemoEntry {
                first_row: d.first_row + offset,
                ..d.clone()
            }));
            offset += part.num_rows();
            drop(part);
            fs::remove_dir_all(&part_dir)
                .with_context(|| format!("removing {}", part_dir.display()))?;
        }
        drop(w);
        let index = Index {
            format: FORMAT.into(),
            obs_dim,
            dtype: ObsDtype::U8,
            compression: RowCompression::Zlib,
            vocabulary: vocab,
            demos,
        };
        let bin_path = dir.join("observations.bin");
        fs::rename(&bin_tmp, &bin_path)
            .with_context(|| format!("renaming {} to {}", bin_tmp.display(), bin_path.display()))?;
        write_row_offsets(dir, RowCompression::Zlib, &row_offsets)?;
        let index_path = dir.join("index.json");
        write_index(&index, &index_path)
    }

    /// Appends every demonstration of `other`, which must have the same
    /// vocabulary, row size and storage.
    pub fn append(&mut self, other: DemoDataset) -> anyhow::Result<()> {
        ensure!(
            self.vocab == other.vocab && self.obs_dim == other.obs_dim,
            "datasets of different vocabularies or row sizes"
        );
        let offset = self.num_rows();
        match (&mut self.obs, other.obs) {
            (ObsBuffer::F32(a), ObsBuffer::F32(b)) => a.extend_from_slice(&b),
            (ObsBuffer::U8(a), ObsBuffer::U8(b)) => a.extend_from_slice(&b),
            (ObsBuffer::U8(a), ObsBuffer::MappedU8(b)) => a.extend_from_slice(b.as_slice()),
            (ObsBuffer::MappedU8(_) | ObsBuffer::Zlib(_), _) => {
                bail!("a dataset read from disk (mapped) takes no more demonstrations")
            }
            (ObsBuffer::U8(_), ObsBuffer::Zlib(_)) => {
                bail!("a compressed dataset is not appended to one in memory")
            }
            _ => bail!("datasets of different storage (f32 and u8)"),
        }
        self.demos
            .extend(other.demos.into_iter().map(|d| DemoEntry {
                first_row: d.first_row + offset,
                ..d
            }));
        Ok(())
    }

    /// Reads a dataset written by [`DemoDataset::save`], checking that the
    /// index and the observation file agree.
    pub fn load(dir: &Path) -> anyhow::Result<Self> {
        Self::load_with(dir, false)
    }

    /// [`DemoDataset::load`], a dataset of bytes (frames) mapped from its
    /// file rather than read into memory: the kernel reads its pages as
    /// rows are used and may drop them under memory pressure, so a dataset
    /// larger than memory can be trained on (at the cost of disk reads).
    /// The same rows as [`DemoDataset::load`]'s; it takes no more demos.
    pub fn load_mapped(dir: &Path) -> anyhow::Result<Self> {
        Self::load_with(dir, true)
    }

    fn load_with(dir: &Path, mapped: bool) -> anyhow::Result<Self> {
        let index_path = dir.join("index.json");
        let text = fs::read_to_string(&index_path)
            .with_context(|| format!("reading {}", index_path.display()))?;
        let index: Index = serde_json::from_str(&text)
            .with_context(|| format!("{}: not a dataset index", index_path.display()))?;
        if index.format != FORMAT {
            bail!(
                "{}: format `{}`, expected `{FORMAT}`",
                index_path.display(),
                index.format
            );
        }
        let mut expected_rows = 0;
        for (i, d) in index.demos.iter().enumerate() {
            if d.first_row != expected_rows {
                bail!(
                    "{}: demo {i} starts at row {}, expected {expected_rows}",
                    index_path.display(),
                    d.first_row
                );
            }
            if d.actions.is_empty() {
                bail!("{}: demo {i} has no actions", index_path.display());
            }
            d.check_segments()
                .with_context(|| format!("{}: demo {i}", index_path.display()))?;
            for &a in &d.actions {
                index
                    .vocabulary
                    .check_action(a)
                    .with_context(|| format!("{}: demo {i}", index_path.display()))?;
            }
            expected_rows += d.num_rows();
        }
        let bin_path = dir.join("observations.bin");
        if index.compression == RowCompression::Zlib {
            ensure!(
                index.dtype == ObsDtype::U8,
                "{}: only rows of bytes are stored compressed",
                index_path.display()
            );
            let rows = ZlibRows::read(dir, expected_rows, index.obs_dim)?;
            return Ok(DemoDataset {
                vocab: index.vocabulary,
                obs_dim: index.obs_dim,
                obs: ObsBuffer::Zlib(rows),
                demos: index.demos,
            });
        }
        let width = match index.dtype {
            ObsDtype::F32 => 4,
            ObsDtype::U8 => 1,
        };
        let expected = expected_rows * index.obs_dim * width;
        let check_len = |len: usize| {
            ensure!(
                len == expected,
                "{}: {len} bytes, expected {expected} ({expected_rows} rows of {} {:?} values); the file is truncated or does not belong to this index",
                bin_path.display(),
                index.obs_dim,
                index.dtype
            );
            Ok(())
        };
        let obs = if mapped && index.dtype == ObsDtype::U8 {
            let map = MappedBytes::map(&bin_path)?;
            check_len(map.as_slice().len())?;
            ObsBuffer::MappedU8(map)
        } else {
            let mut bytes = Vec::new();
            BufReader::new(
                fs::File::open(&bin_path)
                    .with_context(|| format!("reading {}", bin_path.display()))?,
            )
            .read_to_end(&mut bytes)
            .with_context(|| format!("reading {}", bin_path.display()))?;
            check_len(bytes.len())?;
            match index.dtype {
                ObsDtype::F32 => ObsBuffer::F32(
                    bytes
                        .chunks_exact(4)
                        .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
                        .collect(),
                ),
                ObsDtype::U8 => ObsBuffer::U8(bytes),
            }
        };
        Ok(DemoDataset {
            vocab: index.vocabulary,
            obs_dim: index.obs_dim,
            obs,
            demos: index.demos,
        })
    }
}

/// Writes `index` to `index_path` through a temporary file renamed into
/// place, so that an index is never half-written.
fn write_index(index: &Index, index_path: &Path) -> anyhow::Result<()> {
    let index_tmp = index_path.with_extension("json.partial");
    fs::write(&index_tmp, serde_json::to_vec(index)?)
        .with_context(|| format!("writing {}", index_tmp.display()))?;
    fs::rename(&index_tmp, index_path).with_context(|| {
        format!(
            "renaming {} to {}",
            index_tmp.display(),
            index_path.display()
        )
    })
}

/// Writes every row of `obs` (rows of bytes, `obs_dim` each) to `w`, each
/// as its own zlib stream (copied where `obs` is compressed already),
/// pushing where each starts onto `offsets`, the first at byte `start`;
/// the byte after the last row is pushed too only by the caller
/// ([`write_row_offsets`] closes the list). Returns the bytes written.
fn write_compressed_rows(
    obs: &ObsBuffer,
    obs_dim: usize,
    w: &mut impl Write,
    offsets: &mut Vec<u64>,
    start: u64,
) -> anyhow::Result<u64> {
    /// Rows compressed at once, in parallel.
    const CHUNK: usize = 1024;
    let mut at = start;
    let mut put = |stream: &[u8], offsets: &mut Vec<u64>| -> std::io::Result<()> {
        offsets.push(at);
        at += stream.len() as u64;
        w.write_all(stream)
    };
    match obs {
        ObsBuffer::Zlib(rows) => {
            for r in 0..rows.num_rows() {
                put(rows.stream(r), offsets)?;
            }
        }
        ObsBuffer::F32(_) => bail!("only rows of bytes (frames) are stored compressed"),
        _ => {
            let bytes = obs.bytes().expect("rows of bytes");
            let obs_dim = obs_dim.max(1);
            for chunk in bytes.chunks(CHUNK * obs_dim) {
                let streams: Vec<Vec<u8>> = chunk.par_chunks(obs_dim).map(deflate_row).collect();
                for stream in &streams {
                    put(stream, offsets)?;
                }
            }
        }
    }
    Ok(at - start)
}

/// Writes `row_offsets.bin` for a compressed dataset in `dir` whose rows
/// start at `offsets` (the file's length appended), through a temporary
/// file renamed into place; for an uncompressed one, removes a stale one.
fn write_row_offsets(
    dir: &Path,
    compression: RowCompression,
    offsets: &[u64],
) -> anyhow::Result<()> {
    let path = dir.join(ROW_OFFSETS);
    if compression.is_none() {
        if path.exists() {
            fs::remove_file(&path).with_context(|| format!("removing {}", path.display()))?;
        }
        return Ok(());
    }
    let end = fs::metadata(dir.join("observations.bin"))
        .with_context(|| format!("reading {}", dir.join("observations.bin").display()))?
        .len();
    let tmp = path.with_extension("bin.partial");
    let bytes: Vec<u8> = offsets
        .iter()
        .chain(std::iter::once(&end))
        .flat_map(|o| o.to_le_bytes())
        .collect();
    fs::write(&tmp, bytes).with_context(|| format!("writing {}", tmp.display()))?;
    fs::rename(&tmp, &path)
        .with_context(|| format!("renaming {} to {}", tmp.display(), path.display()))
}

/// The parts of a long build of one item per `(task, seed)` of `pairs`, in
/// order, `part_len` pairs each (see
/// [`DemoDataset::load_or_build_in_parts`]): part `k` is read back from
/// `parts_dir/NNNNN/` by `read` (`None`: absent, or not usable, such as
/// another encoder's) if it was saved there and `holds` its pairs, else
/// built by `build` (given its pairs and a label such as " 3/25" for its
/// progress bar) and saved there by `save` before the next starts. A saved
/// part of other pairs is an error naming it.
pub fn build_in_parts<T>(
    parts_dir: &Path,
    pairs: &[(usize, u64)],
    part_len: usize,
    mut read: impl FnMut(&Path) -> anyhow::Result<Option<T>>,
    holds: impl Fn(&T, &[(usize, u64)]) -> bool,
    mut build: impl FnMut(&[(usize, u64)], &str) -> anyhow::Result<T>,
    mut save: impl FnMut(&T, &Path) -> anyhow::Result<()>,
) -> anyhow::Result<Vec<T>> {
    ensure!(
        part_len > 0,
        "parts of a dataset must hold at least one item"
    );
    let num_parts = pairs.len().div_ceil(part_len);
    let mut parts = Vec::with_capacity(num_parts);
    for (k, part_pairs) in pairs.chunks(part_len).enumerate() {
        let part_dir = parts_dir.join(format!("{k:05}"));
        let part = match read(&part_dir)? {
            Some(part) => {
                ensure!(
                    holds(&part, part_pairs),
                    "{}: a part holding other items than this build's part {k} \
                     (built with other settings?); remove {} to build again",
                    part_dir.display(),
                    parts_dir.display()
                );
                part
            }
            None => {
                let part = build(part_pairs, &format!(" {}/{num_parts}", k + 1))?;
                save(&part, &part_dir)?;
                part
            }
        };
        parts.push(part);
    }
    Ok(parts)
}

/// A progress bar for `len` items of work. On a terminal the bars of work
/// that runs at once (`ntg reproduce --jobs`) stack, one line each. When
/// stderr is not a terminal (a background run writing to a log), it is
/// written as a plain line at most every 30 seconds instead, so the log
/// shows that the work goes on.
pub fn progress_bar(len: u64, what: &str) -> ProgressBar {
    use std::io::IsTerminal;
    static BARS: std::sync::OnceLock<indicatif::MultiProgress> = std::sync::OnceLock::new();
    let mut bar = ProgressBar::new(len);
    if std::io::stderr().is_terminal() {
        bar = BARS.get_or_init(indicatif::MultiProgress::new).add(bar);
    } else {
        bar.set_draw_target(indicatif::ProgressDrawTarget::term_like_with_hz(
            Box::new(LogLines::default()),
            1,
        ));
    }
    bar.set_style(
        ProgressStyle::with_template("{prefix:>12} [{bar:30}] {pos}/{len} ({eta} left)")
            .unwrap_or_else(|_| ProgressStyle::default_bar())
            .progress_chars("=> "),
    );
    bar.set_prefix(what.to_owned());
    bar
}

/// A progress bar's draw target for logs: the drawn state as one line on
/// stderr once [`LogLines::EVERY`] has passed since the bar started or its
/// last line (work shorter than that prints nothing).
#[derive(Debug)]
struct LogLines {
    last: std::sync::Mutex<std::time::Instant>,
}

impl Default for LogLines {
    fn default() -> Self {
        LogLines {
            last: std::sync::Mutex::new(std::time::Instant::now()),
        }
    }
}

impl LogLines {
    const EVERY: std::time::Duration = std::time::Duration::from_secs(30);

    /// Prints `text` if its time has come; whether it did.
    fn emit(&self, text: &str) -> bool {
        let text = text.trim();
        let mut last = self.last.lock().unwrap_or_else(|e| e.into_inner());
        if text.is_empty() || last.elapsed() < Self::EVERY {
            return false;
        }
        *last = std::time::Instant::now();
        eprintln!("{text}");
        true
    }
}

impl indicatif::TermLike for LogLines {
    fn width(&self) -> u16 {
        100
    }
    fn move_cursor_up(&self, _: usize) -> std::io::Result<()> {
        Ok(())
    }
    fn move_cursor_down(&self, _: usize) -> std::io::Result<()> {
        Ok(())
    }
    fn move_cursor_right(&self, _: usize) -> std::io::Result<()> {
        Ok(())
    }
    fn move_cursor_left(&self, _: usize) -> std::io::Result<()> {
        Ok(())
    }
    fn write_line(&self, text: &str) -> std::io::Result<()> {
        self.emit(text);
        Ok(())
    }
    fn write_str(&self, text: &str) -> std::io::Result<()> {
        self.emit(text);
        Ok(())
    }
    fn clear_line(&self) -> std::io::Result<()> {
        Ok(())
    }
    fn flush(&self) -> std::io::Result<()> {
        Ok(())
    }
}

/// What the rows of a dataset are: the vocabulary of its actions, the
/// number of values per observation, and how they are stored.
#[derive(Debug, Clone, PartialEq)]
pub struct DatasetSpec {
    /// The action vocabulary.
    pub vocabulary: Vocabulary,
    /// Values per observation row.
    pub obs_dim: usize,
    /// Storage of the values.
    pub dtype: ObsDtype,
}

/// Records one expert demonstration per `(task, seed)` pair, in parallel
/// (rayon), featurising each observation. The result is in the order of
/// `pairs` and does not depend on the number of threads.
pub fn generate<E, X>(
    pairs: &[(usize, u64)],
    make_env: impl Fn(usize) -> anyhow::Result<E> + Sync,
    make_expert: impl Fn() -> X + Sync,
    featurize: impl Fn(&E::Observation) -> Vec<f32> + Sync,
    spec: DatasetSpec,
    progress: &ProgressBar,
) -> anyhow::Result<DemoDataset>
where
    E: Environment,
    X: Expert<E>,
{
    let demos: Vec<(usize, u64, Demonstration<Vec<f32>>)> = pairs
        .par_iter()
        .map(|&(task, seed)| {
            let mut env = make_env(task)?;
            let mut expert = make_expert();
            let demo = record_demonstration(&mut env, &mut expert, seed)
                .with_context(|| format!("expert demonstration of task {task}, seed {seed}"))?;
            progress.inc(1);
            Ok((task, seed, demo.map_observations(|o| featurize(&o))))
        })
        .collect::<anyhow::Result<_>>()?;
    progress.finish_and_clear();
    DemoDataset::from_demos(spec.vocabulary, spec.obs_dim, spec.dtype, demos)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A dataset in parts needs room for the parts still to build and for
    /// their concatenation; short of it, the build stops at once, saying
    /// how much it needs and has.
    #[test]
    fn building_in_parts_refuses_when_the_disk_cannot_hold_it() {
        // 4 parts of 10 bytes, 3 still to build: 30 for them, and 10 more
        // while they are concatenated (each part removed once written).
        assert_eq!(space_needed(10, 3), 40);
        assert_eq!(space_needed(10, 0), 10);
        let err = check_space(
            Path::new("cache"),
            70_000_000_000,
            50_000_000_000,
            1e10 as u64,
            4,
        )
        .unwrap_err();
        let message = format!("{err:#}");
        assert!(
            message.starts_with("cache: ")
                && message.contains("70.0 GB more")
                && message.contains("50.0 GB are free")
                && message.contains("4 parts of about 10.0 GB"),
            "{message}"
        );
        check_space(Path::new("cache"), 70, 70, 10, 4).unwrap();
    }

    #[test]
    fn progress_in_a_log_is_a_line_every_thirty_seconds_at_most() {
        let lines = LogLines::default();
        assert!(!lines.emit("epoch 0 [=>  ] 1/4"), "printed at once");
        {
            let mut last = lines.last.lock().unwrap();
            *last = last
                .checked_sub(LogLines::EVERY)
                .expect("an uptime over 30 s");
        }
        assert!(!lines.emit("   "), "printed an empty line");
        assert!(lines.emit("epoch 0 [==> ] 2/4"));
        assert!(!lines.emit("epoch 0 [===>] 3/4"), "printed twice in 30 s");
    }
    use ctg_graph::symbolic::{SequenceExpert, SequenceTask};

    fn dataset(dtype: ObsDtype) -> DemoDataset {
        let pairs: Vec<(usize, u64)> = (0..3).flat_map(|t| [(t, 1), (t, 2)]).collect();
        dataset_of(&pairs, dtype)
    }

    /// Demos of `pairs` (tasks 0..3, any seeds).
    fn dataset_of(pairs: &[(usize, u64)], dtype: ObsDtype) -> DemoDataset {
        let vocab = Vocabulary::new(["a", "b", "c"]).unwrap();
        let tasks = ["a b", "c a b c", "b"];
        let v = vocab.clone();
        generate(
            pairs,
            |t| Ok(SequenceTask::new(v.clone(), v.parse_sequence(tasks[t])?)),
            || SequenceExpert,
            |o| vec![o.step as f32 / 10.0, o.last.index() as f32 / 10.0],
            DatasetSpec {
                vocabulary: vocab,
                obs_dim: 2,
                dtype,
            },
            &ProgressBar::hidden(),
        )
        .unwrap()
    }

    #[test]
    fn a_network_of_another_vocabulary_size_is_refused() {
        let ds = dataset(ObsDtype::F32);
        let n = ds.vocabulary().len();
        ds.check_num_nodes(n, "model").unwrap();
        let err = ds.check_num_nodes(n + 1, "policy").unwrap_err().to_string();
        assert_eq!(
            err,
            format!(
                "the dataset's vocabulary has {n} nodes, the policy {}",
                n + 1
            )
        );
    }

    #[test]
    fn generate_then_save_and_load_round_trips() {
        for dtype in [ObsDtype::F32, ObsDtype::U8] {
            let ds = dataset(dtype);
            assert_eq!(ds.demos().len(), 6);
            assert_eq!(ds.num_rows(), 2 * (3 + 5 + 2));
            let demo = ds.demonstration(2).unwrap();
            assert_eq!(ds.vocabulary().format_sequence(demo.actions()), "c a b c");
            assert_eq!(demo.observations()[4], vec![0.4, 0.4]);
            let dir = tempfile::tempdir().unwrap();
            ds.save(dir.path()).unwrap();
            let back = DemoDataset::load(dir.path()).unwrap();
            if dtype == ObsDtype::F32 {
                assert_eq!(back, ds);
            } else {
                assert_eq!(back.row(7), ds.row(7));
            }
        }
    }

    #[test]
    fn corrupt_files_are_reported() {
        let ds = dataset(ObsDtype::F32);
        let dir = tempfile::tempdir().unwrap();
        ds.save(dir.path()).unwrap();
        let bin = dir.path().join("observations.bin");
        let bytes = fs::read(&bin).unwrap();
        fs::write(&bin, &bytes[..bytes.len() - 3]).unwrap();
        let err = format!("{:#}", DemoDataset::load(dir.path()).unwrap_err());
        assert!(
            err.contains("observations.bin") && err.contains("truncated"),
            "{err}"
        );
        fs::write(dir.path().join("index.json"), "{not json").unwrap();
        let err = format!("{:#}", DemoDataset::load(dir.path()).unwrap_err());
        assert!(err.contains("index.json"), "{err}");
    }

    #[test]
    fn a_save_killed_before_its_index_is_rebuilt_not_read() {
        let ds = dataset(ObsDtype::F32);
        let dir = tempfile::tempdir().unwrap();
        // What a kill during the observations' write leaves: part of them,
        // and no index.
        fs::write(dir.path().join("observations.bin.partial"), [1u8, 2, 3]).unwrap();
        fs::write(dir.path().join("observations.bin"), [1u8, 2, 3]).unwrap();
        let built = DemoDataset::load_or_build(dir.path(), || Ok(ds.clone())).unwrap();
        assert_eq!(built, ds);
        assert_eq!(DemoDataset::load(dir.path()).unwrap(), ds);
        assert!(!dir.path().join("observations.bin.partial").exists());
        assert!(!dir.path().join("index.json.partial").exists());
        let read = DemoDataset::load_or_build(dir.path(), || panic!("cached")).unwrap();
        assert_eq!(read, ds);
        // A save that fails while placing the observations leaves no index.
        let failing = tempfile::tempdir().unwrap();
        fs::create_dir(failing.path().join("observations.bin")).unwrap();
        assert!(ds.save(failing.path()).is_err());
        assert!(!failing.path().join("index.json").exists());
    }

    #[test]
    fn a_build_in_parts_resumes_after_its_last_whole_part() {
        let pairs: Vec<(usize, u64)> = (0..3).flat_map(|t| [(t, 1), (t, 2), (t, 3)]).collect();
        let whole = dataset_of(&pairs, ObsDtype::F32);
        let dir = tempfile::tempdir().unwrap();
        let target = dir.path().join("embeddings");
        // A build killed in its third part of four (pairs 4-5) keeps the
        // first two.
        let mut built = Vec::new();
        let err = DemoDataset::load_or_build_in_parts(&target, &pairs, 2, |part, _| {
            built.push(part.to_vec());
            anyhow::ensure!(built.len() < 3, "killed");
            Ok(dataset_of(part, ObsDtype::F32))
        })
        .unwrap_err();
        assert_eq!(err.to_string(), "killed");
        assert!(!target.join("index.json").exists());
        assert!(target.with_extension("parts").join("00001").is_dir());
        // Resumed: parts 0 and 1 are read back, the rest built.
        let mut rebuilt = Vec::new();
        let resumed = DemoDataset::load_or_build_in_parts(&target, &pairs, 2, |part, _| {
            rebuilt.push(part.to_vec());
            Ok(dataset_of(part, ObsDtype::F32))
        })
        .unwrap();
        assert_eq!(
            rebuilt,
            [
                pairs[4..6].to_vec(),
                pairs[6..8].to_vec(),
                pairs[8..].to_vec()
            ]
        );
        assert_eq!(resumed, whole, "the same dataset as built in one go");
        assert_eq!(DemoDataset::load(&target).unwrap(), whole);
        assert!(!target.with_extension("parts").exists(), "parts removed");
        let cached =
            DemoDataset::load_or_build_in_parts(&target, &pairs, 2, |_, _| panic!("cached"))
                .unwrap();
        assert_eq!(cached, whole);
        // Parts left by a kill after the whole was saved are removed.
        fs::create_dir_all(target.with_extension("parts").join("00000")).unwrap();
        DemoDataset::load_or_build_in_parts(&target, &pairs, 2, |_, _| panic!("cached")).unwrap();
        assert!(!target.with_extension("parts").exists());
        // A part of other demos (another build's) is an error naming it.
        let other = dir.path().join("other");
        dataset_of(&pairs[2..4], ObsDtype::F32)
            .save(&other.with_extension("parts").join("00000"))
            .unwrap();
        let err = DemoDataset::load_or_build_in_parts(&other, &pairs, 2, |part, _| {
            Ok(dataset_of(part, ObsDtype::F32))
        })
        .unwrap_err()
        .to_string();
        assert!(
            err.contains("00000") && err.contains("other items"),
            "{err}"
        );
        // Appending a dataset of other storage is refused.
        let mut f32s = dataset_of(&pairs[..1], ObsDtype::F32);
        assert!(f32s.append(dataset_of(&pairs[1..2], ObsDtype::U8)).is_err());
    }

    #[test]
    fn a_dataset_of_bytes_built_in_parts_on_disk_is_read_mapped_with_the_same_rows() {
        let pairs: Vec<(usize, u64)> = (0..3).flat_map(|t| [(t, 1), (t, 2), (t, 3)]).collect();
        let whole = dataset_of(&pairs, ObsDtype::U8);
        let dir = tempfile::tempdir().unwrap();
        let target = dir.path().join("frames");
        // Killed in its third part: the first two stay on disk.
        let mut built = 0;
        let err = DemoDataset::load_or_build_mapped_in_parts(&target, &pairs, 2, |part, _| {
            built += 1;
            anyhow::ensure!(built < 3, "killed");
            Ok(dataset_of(part, ObsDtype::U8))
        })
        .unwrap_err();
        assert_eq!(err.to_string(), "killed");
        let mut rebuilt = Vec::new();
        let mapped = DemoDataset::load_or_build_mapped_in_parts(&target, &pairs, 2, |part, _| {
            rebuilt.push(part.to_vec());
            Ok(dataset_of(part, ObsDtype::U8))
        })
        .unwrap();
        assert_eq!(rebuilt.len(), 3, "parts 0 and 1 read back: {rebuilt:?}");
        assert!(
            matches!(mapped.obs, ObsBuffer::Zlib(_)),
            "stored compressed"
        );
        assert_eq!(mapped, whole);
        for row in 0..whole.num_rows() {
            assert_eq!(mapped.row(row), whole.row(row));
        }
        assert_eq!(
            mapped.demonstration(4).unwrap(),
            whole.demonstration(4).unwrap()
        );
        assert!(!target.with_extension("parts").exists(), "parts removed");
        // The files are the ones a compressed save in memory writes.
        let saved = dir.path().join("saved");
        whole.save_compressed(&saved).unwrap();
        for file in ["observations.bin", ROW_OFFSETS] {
            assert_eq!(
                fs::read(saved.join(file)).unwrap(),
                fs::read(target.join(file)).unwrap(),
                "{file}"
            );
        }
        assert_eq!(DemoDataset::load(&target).unwrap(), whole);
        // Cached: read mapped, nothing built.
        let cached =
            DemoDataset::load_or_build_mapped_in_parts(&target, &pairs, 2, |_, _| panic!("cached"))
                .unwrap();
        assert_eq!(cached, whole);
        // A mapped dataset takes no more demos.
        let mut read_only = cached.clone();
        let err = read_only
            .append(dataset_of(&pairs[..1], ObsDtype::U8))
            .unwrap_err();
        assert!(err.to_string().contains("mapped"), "{err}");
        // A truncated file is an error naming it.
        let bin = target.join("observations.bin");
        let bytes = fs::read(&bin).unwrap();
        drop((mapped, cached, read_only));
        fs::write(&bin, &bytes[..bytes.len() - 1]).unwrap();
        let err = DemoDataset::load_mapped(&target).unwrap_err().to_string();
        assert!(
            err.contains("observations.bin") && err.contains("truncated"),
            "{err}"
        );
        // So is a damaged row, and a missing offsets file.
        let mut damaged = bytes.clone();
        let last = damaged.len() - 2;
        damaged[last] ^= 0xff;
        fs::write(&bin, &damaged).unwrap();
        let err = DemoDataset::load(&target).unwrap_err().to_string();
        assert!(err.contains("does not inflate"), "{err}");
        fs::remove_file(target.join(ROW_OFFSETS)).unwrap();
        let err = format!("{:#}", DemoDataset::load(&target).unwrap_err());
        assert!(err.contains(ROW_OFFSETS), "{err}");
    }

    #[test]
    fn compressed_frames_keep_their_rows_and_shrink() {
        // Rows like rendered frames: a plain background and a few blocks.
        let vocab = Vocabulary::new(["a"]).unwrap();
        let obs_dim = 3 * 32 * 32;
        let frame = |k: usize| -> Vec<f32> {
            (0..obs_dim)
                .map(|i| {
                    let (x, y) = (i % 32, (i / 32) % 32);
                    if (k..k + 6).contains(&x) && (10..16).contains(&y) {
                        1.0
                    } else {
                        f32::from(((i / 1024) * 40) as u8) / 255.0
                    }
                })
                .collect()
        };
        let demos = (0..4).map(|k| {
            let demo = Demonstration::new(
                vec![frame(k), frame(k + 8)],
                vec![vocab.id("a").unwrap()],
                &vocab,
            )
            .unwrap();
            (k, k as u64, demo)
        });
        let plain = DemoDataset::from_demos(vocab.clone(), obs_dim, ObsDtype::U8, demos).unwrap();
        let dir = tempfile::tempdir().unwrap();
        plain.save_compressed(dir.path()).unwrap();
        let read = DemoDataset::load(dir.path()).unwrap();
        assert!(matches!(read.obs, ObsBuffer::Zlib(_)));
        assert_eq!(read, plain);
        // One value off, or one row short, and the rows differ.
        let ObsBuffer::U8(bytes) = &plain.obs else {
            panic!("frames in memory are bytes")
        };
        let mut changed = bytes.clone();
        changed[obs_dim + 5] ^= 1;
        assert!(!read.obs.same_bytes(&ObsBuffer::U8(changed)));
        let short = ObsBuffer::U8(bytes[..bytes.len() - obs_dim].to_vec());
        assert!(!read.obs.same_bytes(&short) && !short.same_bytes(&read.obs));
        assert_eq!(read.num_rows(), 8);
        for row in 0..8 {
            assert_eq!(read.row(row), plain.row(row));
        }
        let stored = fs::metadata(dir.path().join("observations.bin"))
            .unwrap()
            .len();
        assert!(stored * 10 < (8 * obs_dim) as u64, "{stored} bytes");
        // Saved again it stays compressed; saved plainly it reads the same.
        let again = dir.path().join("again");
        read.save(&again).unwrap();
        assert_eq!(DemoDataset::load(&again).unwrap(), plain);
        assert!(again.join(ROW_OFFSETS).exists());
        let unpacked = dir.path().join("unpacked");
        read.save_as(&unpacked, RowCompression::None).unwrap();
        assert!(!unpacked.join(ROW_OFFSETS).exists());
        assert!(matches!(
            DemoDataset::load(&unpacked).unwrap().obs,
            ObsBuffer::U8(_)
        ));
        assert_eq!(DemoDataset::load(&unpacked).unwrap(), plain);
        // States are not stored compressed.
        let states = dataset_of(&[(0, 1)], ObsDtype::F32);
        assert!(states.save_compressed(&dir.path().join("states")).is_err());
    }

    #[test]
    fn parts_saved_uncompressed_before_are_compressed_into_the_whole() {
        let pairs: Vec<(usize, u64)> = (0..3).flat_map(|t| [(t, 1), (t, 2)]).collect();
        let whole = dataset_of(&pairs, ObsDtype::U8);
        let dir = tempfile::tempdir().unwrap();
        let target = dir.path().join("frames");
        // Part 0 left by an earlier build that saved parts uncompressed.
        dataset_of(&pairs[..2], ObsDtype::U8)
            .save(&target.with_extension("parts").join("00000"))
            .unwrap();
        let mapped = DemoDataset::load_or_build_mapped_in_parts(&target, &pairs, 2, |part, _| {
            anyhow::ensure!(part != &pairs[..2], "part 0 rebuilt");
            Ok(dataset_of(part, ObsDtype::U8))
        })
        .unwrap();
        assert!(matches!(mapped.obs, ObsBuffer::Zlib(_)));
        assert_eq!(mapped, whole);
    }

    #[test]
    fn parallel_equals_sequential() {
        let parallel = dataset(ObsDtype::F32);
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(1)
            .build()
            .unwrap();
        let sequential = pool.install(|| dataset(ObsDtype::F32));
        assert_eq!(parallel, sequential);
    }
}
