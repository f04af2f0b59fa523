//! Episodes (expert demos, a policy's rollouts) as a dataset in LeRobot's
//! file layout, which Python reads with pyarrow or pandas in a few lines
//! (`docs/EXPORT.md`, "Demos and rollouts").
//!
//! ```text
//! DIR/meta/info.json        features (dtype, shape), counts, paths, the vocabulary
//! DIR/meta/episodes.jsonl   one line an episode: index, task, length, success
//! DIR/meta/tasks.jsonl      one line a task: task_index, task
//! DIR/data/chunk-000/episode_000000.parquet   one row a frame
//! ```
//!
//! A row is one decision: the frame the agent saw (`observation.image`, a
//! PNG in a `{bytes, path}` struct as LeRobot and Hugging Face `datasets`
//! store image features), optionally its state vector, and the action it
//! then took, by id and by name. An episode's last row holds the final
//! frame and the action `<end>`. Frames are PNG already, so the parquet
//! columns are written uncompressed.
//!
//! Why this format: LeRobot's layout is one parquet file an episode plus
//! JSON metadata: pyarrow, pandas and `datasets` read it without a custom
//! loader, and the writer (the `parquet` crate, Apache Arrow's own, without
//! its Arrow layer) is pure Rust. Robomimic's HDF5 would need the HDF5 C
//! library on every machine that builds `ntg`.

use std::fs::File;
use std::io::BufWriter;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use anyhow::{Context, bail};
use parquet::basic::{ConvertedType, Repetition, Type as PhysicalType};
use parquet::data_type::{BoolType, ByteArray, ByteArrayType, FloatType, Int64Type};
use parquet::file::properties::WriterProperties;
use parquet::file::writer::{SerializedColumnWriter, SerializedFileWriter};
use parquet::schema::types::Type;
use serde::Serialize;

/// The LeRobot layout version whose file names and metadata this writes.
pub const CODEBASE_VERSION: &str = "v2.0";
/// Episodes per `data/chunk-NNN` folder (LeRobot's default).
pub const CHUNK_SIZE: usize = 1000;
/// The metadata file that marks a folder as a dataset this module wrote
/// (and so one `--force` may replace).
pub const INFO_FILE: &str = "meta/info.json";

/// One decision of an episode.
#[derive(Debug, Clone)]
pub struct Row {
    /// The frame the agent saw.
    pub frame: image::RgbImage,
    /// The environment's state vector, if the dataset carries states.
    pub state: Option<Vec<f32>>,
    /// The action then taken (an id of the dataset's vocabulary).
    pub action: usize,
    /// Whether every goal held after the action.
    pub success_after: bool,
}

/// One episode.
#[derive(Debug, Clone)]
pub struct Episode {
    /// The task in words (`meta/tasks.jsonl`).
    pub task: String,
    /// The task's id (for example `stack_17`).
    pub task_id: String,
    /// The episode's seed.
    pub seed: u64,
    /// The rows in order; the last holds the final frame.
    pub rows: Vec<Row>,
    /// Whether the task was done at the end.
    pub success: bool,
}

/// What the whole dataset is.
#[derive(Debug, Clone)]
pub struct DatasetInfo {
    /// `robot_type` in `meta/info.json` (the environment's name).
    pub robot_type: String,
    /// Where the episodes come from, in words (`meta/info.json`'s
    /// `ntg.source`).
    pub source: String,
    /// The action vocabulary: `action` holds an index into it.
    pub vocabulary: Vec<String>,
    /// Rows per second of `timestamp` (one row is one decision).
    pub fps: u32,
}

/// What [`DatasetWriter::finish`] wrote.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Written {
    /// Episodes written.
    pub episodes: usize,
    /// Rows (frames) written.
    pub frames: usize,
    /// Distinct tasks.
    pub tasks: usize,
}

#[derive(Serialize)]
struct EpisodeLine {
    episode_index: usize,
    tasks: Vec<String>,
    length: usize,
    task_id: String,
    seed: u64,
    success: bool,
}

/// Writes a dataset episode by episode into a folder it creates.
pub struct DatasetWriter {
    root: PathBuf,
    info: DatasetInfo,
    tasks: Vec<String>,
    episodes: Vec<EpisodeLine>,
    frames: usize,
    /// (height, width) of the frames and the state's length, fixed by the
    /// first episode.
    shape: Option<((u32, u32), Option<usize>)>,
}

impl DatasetWriter {
    /// A writer into `root`, which must not exist or be empty.
    pub fn create(root: &Path, info: DatasetInfo) -> anyhow::Result<Self> {
        if std::fs::read_dir(root).is_ok_and(|mut d| d.next().is_some()) {
            bail!("{} is not empty", root.display());
        }
        for sub in ["meta", "data/chunk-000"] {
            let dir = root.join(sub);
            std::fs::create_dir_all(&dir).with_context(|| format!("creating {}", dir.display()))?;
        }
        Ok(Self {
            root: root.to_owned(),
            info,
            tasks: Vec::new(),
            episodes: Vec::new(),
            frames: 0,
            shape: None,
        })
    }

    /// Appends `episode` as the next episode's parquet file.
    pub fn add(&mut self, episode: &Episode) -> anyhow::Result<()> {
        let index = self.episodes.len();
        let Some(first) = episode.rows.first() else {
            bail!("episode {index} ({}) has no rows", episode.task_id);
        };
        let shape = (
            (first.frame.height(), first.frame.width()),
            first.state.as_ref().map(Vec::len),
        );
        let expected = self.shape.unwrap_or(shape);
        for (t, row) in episode.rows.iter().enumerate() {
            let this = (
                (row.frame.height(), row.frame.width()),
                row.state.as_ref().map(Vec::len),
            );
            if this != expected {
                bail!(
                    "episode {index} ({}), row {t}: frame {:?} and state {:?} differ from the dataset's {:?} and {:?}",
                    episode.task_id,
                    this.0,
                    this.1,
                    expected.0,
                    expected.1
                );
            }
            if row.action >= self.info.vocabulary.len() {
                bail!(
                    "episode {index} ({}), row {t}: action id {} is not in the vocabulary of {} actions",
                    episode.task_id,
                    row.action,
                    self.info.vocabulary.len()
                );
            }
        }
        let task_index =
            (self.tasks.iter().position(|t| *t == episode.task)).unwrap_or(self.tasks.len());
        let path = self.root.join(episode_path(index));
        if let Some(dir) = path.parent() {
            std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
        }
        write_episode(
            &path,
            episode,
            &self.info.vocabulary,
            index,
            self.frames,
            task_index,
            self.info.fps,
            expected.1,
        )
        .with_context(|| format!("writing {}", path.display()))?;
        self.shape = Some(expected);
        if task_index == self.tasks.len() {
            self.tasks.push(episode.task.clone());
        }
        self.frames += episode.rows.len();
        self.episodes.push(EpisodeLine {
            episode_index: index,
            tasks: vec![episode.task.clone()],
            length: episode.rows.len(),
            task_id: episode.task_id.clone(),
            seed: episode.seed,
            success: episode.success,
        });
        Ok(())
    }

    /// Writes the metadata (`meta/`); the dataset is complete after it.
    pub fn finish(self) -> anyhow::Result<Written> {
        let Some(((height, width), state)) = self.shape else {
            bail!("no episodes to write into {}", self.root.display());
        };
        let scalar = |dtype: &str| serde_json::json!({"dtype": dtype, "shape": [1], "names": null});
        let mut features = serde_json::Map::new();
        features.insert(
            "observation.image".into(),
            serde_json::json!({
                "dtype": "image",
                "shape": [height, width, 3],
                "names": ["height", "width", "channel"],
            }),
        );
        if let Some(dim) = state {
            features.insert(
                "observation.state".into(),
                serde_json::json!({"dtype": "float32", "shape": [dim], "names": null}),
            );
        }
        features.insert("action".into(), scalar("int64"));
        features.insert("action.name".into(), scalar("string"));
        features.insert("next.success".into(), scalar("bool"));
        features.insert("next.done".into(), scalar("bool"));
        features.insert("timestamp".into(), scalar("float32"));
        for name in ["frame_index", "episode_index", "index", "task_index"] {
            features.insert(name.into(), scalar("int64"));
        }
        let episodes = self.episodes.len();
        let info = serde_json::json!({
            "codebase_version": CODEBASE_VERSION,
            "robot_type": self.info.robot_type,
            "total_episodes": episodes,
            "total_frames": self.frames,
            "total_tasks": self.tasks.len(),
            "total_videos": 0,
            "total_chunks": episodes.div_ceil(CHUNK_SIZE),
            "chunks_size": CHUNK_SIZE,
            "fps": self.info.fps,
            "splits": {"train": format!("0:{episodes}")},
            "data_path": "data/chunk-{episode_chunk:03d}/episode_{episode_index:06d}.parquet",
            "video_path": null,
            "features": features,
            "ntg": {
                "source": self.info.source,
                "vocabulary": self.info.vocabulary,
                "rows": "one row a decision: the frame seen, then the action taken; an episode's last row holds the final frame and <end>",
            },
        });
        let info_path = self.root.join(INFO_FILE);
        std::fs::write(&info_path, serde_json::to_string_pretty(&info)? + "\n")
            .with_context(|| format!("writing {}", info_path.display()))?;
        let lines = |items: Vec<serde_json::Value>| -> String {
            items.iter().map(|v| format!("{v}\n")).collect()
        };
        let episodes_path = self.root.join("meta/episodes.jsonl");
        let episode_lines = self
            .episodes
            .iter()
            .map(serde_json::to_value)
            .collect::<Result<Vec<_>, _>>()?;
        std::fs::write(&episodes_path, lines(episode_lines))
            .with_context(|| format!("writing {}", episodes_path.display()))?;
        let tasks_path = self.root.join("meta/tasks.jsonl");
        let task_lines = self
            .tasks
            .iter()
            .enumerate()
            .map(|(i, t)| serde_json::json!({"task_index": i, "task": t}))
            .collect();
        std::fs::write(&tasks_path, lines(task_lines))
            .with_context(|| format!("writing {}", tasks_path.display()))?;
        Ok(Written {
            episodes,
            frames: self.frames,
            tasks: self.tasks.len(),
        })
    }
}

/// Where episode `index`'s parquet file lies, relative to the dataset.
pub fn episode_path(index: usize) -> String {
    format!(
        "data/chunk-{:03}/episode_{index:06}.parquet",
        index / CHUNK_SIZE
    )
}

fn required(name: &str, physical: PhysicalType) -> anyhow::Result<Arc<Type>> {
    Ok(Arc::new(
        Type::primitive_type_builder(name, physical)
            .with_repetition(Repetition::REQUIRED)
            .build()?,
    ))
}

fn string(name: &str) -> anyhow::Result<Arc<Type>> {
    Ok(Arc::new(
        Type::primitive_type_builder(name, PhysicalType::BYTE_ARRAY)
            .with_repetition(Repetition::REQUIRED)
            .with_converted_type(ConvertedType::UTF8)
            .build()?,
    ))
}

/// The parquet schema of one episode file (column order is write order).
fn schema(state: bool) -> anyhow::Result<Type> {
    let image = Type::group_type_builder("observation.image")
        .with_repetition(Repetition::REQUIRED)
        .with_fields(vec![
            required("bytes", PhysicalType::BYTE_ARRAY)?,
            string("path")?,
        ])
        .build()?;
    let mut fields = vec![Arc::new(image)];
    if state {
        // Parquet's three-level LIST: a required list of required floats.
        let element = required("element", PhysicalType::FLOAT)?;
        let repeated = Type::group_type_builder("list")
            .with_repetition(Repetition::REPEATED)
            .with_fields(vec![element])
            .build()?;
        let list = Type::group_type_builder("observation.state")
            .with_repetition(Repetition::REQUIRED)
            .with_converted_type(ConvertedType::LIST)
            .with_fields(vec![Arc::new(repeated)])
            .build()?;
        fields.push(Arc::new(list));
    }
    fields.push(required("action", PhysicalType::INT64)?);
    fields.push(string("action.name")?);
    fields.push(required("next.success", PhysicalType::BOOLEAN)?);
    fields.push(required("next.done", PhysicalType::BOOLEAN)?);
    fields.push(required("timestamp", PhysicalType::FLOAT)?);
    for name in ["frame_index", "episode_index", "index", "task_index"] {
        fields.push(required(name, PhysicalType::INT64)?);
    }
    Ok(Type::group_type_builder("schema")
        .with_fields(fields)
        .build()?)
}

fn png_bytes(frame: &image::RgbImage) -> anyhow::Result<Vec<u8>> {
    let mut bytes = Vec::new();
    frame.write_to(
        &mut std::io::Cursor::new(&mut bytes),
        image::ImageFormat::Png,
    )?;
    Ok(bytes)
}

fn byte_arrays(items: impl IntoIterator<Item = Vec<u8>>) -> Vec<ByteArray> {
    items.into_iter().map(ByteArray::from).collect()
}

/// The values of one column, in the order of [`schema`]'s leaves.
enum Column {
    Bytes(Vec<ByteArray>),
    /// Flattened list values with their repetition levels.
    FloatList(Vec<f32>, Vec<i16>),
    Int(Vec<i64>),
    Bool(Vec<bool>),
    Float(Vec<f32>),
}

impl Column {
    fn write(&self, column: &mut SerializedColumnWriter<'_>) -> anyhow::Result<()> {
        match self {
            Column::Bytes(v) => {
                column.typed::<ByteArrayType>().write_batch(v, None, None)?;
            }
            Column::FloatList(v, rep) => {
                let def = vec![1i16; v.len()];
                column
                    .typed::<FloatType>()
                    .write_batch(v, Some(&def), Some(rep))?;
            }
            Column::Int(v) => {
                column.typed::<Int64Type>().write_batch(v, None, None)?;
            }
            Column::Bool(v) => {
                column.typed::<BoolType>().write_batch(v, None, None)?;
            }
            Column::Float(v) => {
                column.typed::<FloatType>().write_batch(v, None, None)?;
            }
        }
        Ok(())
    }
}

#[allow(clippy::too_many_arguments)]
fn write_episode(
    path: &Path,
    episode: &Episode,
    vocabulary: &[String],
    episode_index: usize,
    first_index: usize,
    task_index: usize,
    fps: u32,
    state: Option<usize>,
) -> anyhow::Result<()> {
    let rows = &episode.rows;
    let n = rows.len();
    let images = rows
        .iter()
        .map(|r| png_bytes(&r.frame))
        .collect::<anyhow::Result<Vec<_>>>()?;
    let mut columns = vec![
        Column::Bytes(byte_arrays(images)),
        Column::Bytes(byte_arrays((0..n).map(|t| {
            format!("episode_{episode_index:06}/frame_{t:06}.png").into_bytes()
        }))),
    ];
    if state.is_some() {
        let mut values = Vec::new();
        let mut rep = Vec::new();
        for row in rows {
            let s = row.state.as_deref().unwrap_or_default();
            values.extend_from_slice(s);
            rep.extend((0..s.len()).map(|i| if i == 0 { 0 } else { 1 }));
        }
        columns.push(Column::FloatList(values, rep));
    }
    columns.push(Column::Int(rows.iter().map(|r| r.action as i64).collect()));
    columns.push(Column::Bytes(byte_arrays(
        rows.iter()
            .map(|r| vocabulary[r.action].clone().into_bytes()),
    )));
    columns.push(Column::Bool(rows.iter().map(|r| r.success_after).collect()));
    columns.push(Column::Bool((0..n).map(|t| t + 1 == n).collect()));
    columns.push(Column::Float(
        (0..n).map(|t| t as f32 / fps.max(1) as f32).collect(),
    ));
    columns.push(Column::Int((0..n as i64).collect()));
    columns.push(Column::Int(vec![episode_index as i64; n]));
    columns.push(Column::Int(
        (0..n).map(|t| (first_index + t) as i64).collect(),
    ));
    columns.push(Column::Int(vec![task_index as i64; n]));

    let file = File::create(path)?;
    let props = Arc::new(WriterProperties::builder().build());
    let mut writer = SerializedFileWriter::new(
        BufWriter::new(file),
        Arc::new(schema(state.is_some())?),
        props,
    )?;
    let mut group = writer.next_row_group()?;
    for values in &columns {
        let mut column = group
            .next_column()?
            .context("the schema has fewer columns than the rows")?;
        values.write(&mut column)?;
        column.close()?;
    }
    if group.next_column()?.is_some() {
        bail!("the schema has more columns than the rows");
    }
    group.close()?;
    writer.close()?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn episode(task: &str, rows: usize, state: Option<usize>) -> Episode {
        Episode {
            task: task.into(),
            task_id: task.into(),
            seed: 3,
            rows: (0..rows)
                .map(|t| Row {
                    frame: image::RgbImage::from_pixel(4, 6, image::Rgb([t as u8, 0, 9])),
                    state: state.map(|d| vec![t as f32; d]),
                    action: if t + 1 == rows { 1 } else { 2 + t % 2 },
                    success_after: t + 1 == rows,
                })
                .collect(),
            success: true,
        }
    }

    fn info() -> DatasetInfo {
        DatasetInfo {
            robot_type: "test".into(),
            source: "unit test".into(),
            vocabulary: ["<start>", "<end>", "a", "b"].map(String::from).to_vec(),
            fps: 1,
        }
    }

    #[test]
    fn writes_episodes_and_metadata() {
        let dir = tempfile::tempdir().unwrap();
        let root = dir.path().join("ds");
        let mut writer = DatasetWriter::create(&root, info()).unwrap();
        writer.add(&episode("x", 3, Some(2))).unwrap();
        writer.add(&episode("y", 2, Some(2))).unwrap();
        writer.add(&episode("x", 4, Some(2))).unwrap();
        let written = writer.finish().unwrap();
        assert_eq!(
            written,
            Written {
                episodes: 3,
                frames: 9,
                tasks: 2
            }
        );
        let info: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(root.join(INFO_FILE)).unwrap()).unwrap();
        assert_eq!(info["total_frames"], 9);
        assert_eq!(
            info["features"]["observation.image"]["shape"],
            serde_json::json!([6, 4, 3])
        );
        assert_eq!(
            info["features"]["observation.state"]["shape"],
            serde_json::json!([2])
        );
        let tasks = std::fs::read_to_string(root.join("meta/tasks.jsonl")).unwrap();
        assert_eq!(tasks.lines().count(), 2);
        for i in 0..3 {
            let file = root.join(episode_path(i));
            let bytes = std::fs::read(&file).unwrap();
            assert_eq!(&bytes[..4], b"PAR1", "{}", file.display());
        }
    }

    #[test]
    fn refuses_mismatched_rows_and_unknown_actions() {
        let dir = tempfile::tempdir().unwrap();
        let mut writer = DatasetWriter::create(&dir.path().join("ds"), info()).unwrap();
        writer.add(&episode("x", 2, Some(2))).unwrap();
        let err = writer.add(&episode("x", 2, Some(3))).unwrap_err();
        assert!(err.to_string().contains("differ"), "{err}");
        let mut bad = episode("x", 2, Some(2));
        bad.rows[0].action = 9;
        let err = writer.add(&bad).unwrap_err();
        assert!(err.to_string().contains("not in the vocabulary"), "{err}");
        let err = writer.add(&episode("x", 0, None)).unwrap_err();
        assert!(err.to_string().contains("no rows"), "{err}");
    }

    #[test]
    fn refuses_a_folder_that_is_not_empty() {
        let dir = tempfile::tempdir().unwrap();
        std::fs::write(dir.path().join("keep.txt"), "mine").unwrap();
        let err = DatasetWriter::create(dir.path(), info()).err().unwrap();
        assert!(err.to_string().contains("is not empty"), "{err}");
        assert_eq!(
            std::fs::read_to_string(dir.path().join("keep.txt")).unwrap(),
            "mine"
        );
    }
}
