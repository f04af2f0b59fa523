//! Writing a demonstration to disk: JSON, one PNG per frame, and a contact
//! sheet; contact sheets of video demonstrations.

use std::fs;
use std::path::{Path, PathBuf};

use ctg_graph::{Demonstration, Environment, VideoDemonstration, Vocabulary, record_demonstration};
use image::RgbImage;
use serde::Serialize;

use crate::env::{CollectConfig, CollectEnv, CollectObservation, Scene, state_layout};
use crate::render::contact_sheet;
use crate::{CollectError, CollectExpert, Task, vocabulary};

/// Identifies the JSON layout written by [`write_demo`].
pub const DEMO_FORMAT: &str = "ntg-collect-demo/1";
/// Frames per row of a contact sheet.
pub const SHEET_COLUMNS: usize = 6;
/// The folder of a written demo's frames (`step_NNN.png`).
pub const FRAMES_DIR: &str = "frames";

/// A written demo's contact sheet.
pub const CONTACT_SHEET: &str = "contact-sheet.png";

/// Magnification of frames on a contact sheet.
pub const SHEET_SCALE: u32 = 2;
/// Frames per row of a video's contact sheet.
pub const VIDEO_SHEET_COLUMNS: usize = 8;

/// One observation of a written demonstration.
#[derive(Debug, Clone, Serialize)]
pub struct StepRecord {
    /// Position in the demonstration (0 = before the first action).
    pub index: usize,
    /// The CTG node this observation is at: `<start>`, then the action just
    /// taken.
    pub node: String,
    /// The action the expert took next (`<end>` at the last observation).
    pub next_action: String,
    /// The frame's file name, relative to the demo's folder.
    pub frame: Option<String>,
    /// The symbolic state vector.
    pub state: Vec<f32>,
}

/// The JSON file [`write_demo`] writes (`demo.json`).
#[derive(Debug, Clone, Serialize)]
pub struct DemoFile {
    /// Always [`DEMO_FORMAT`].
    pub format: String,
    /// The task.
    pub task: Task,
    /// N, the number of targets.
    pub num_objects: usize,
    /// The episode seed.
    pub seed: u64,
    /// The episode settings.
    pub config: CollectConfig,
    /// The domain's vocabulary (real actions, in id order from 2).
    pub vocabulary: Vocabulary,
    /// The demonstrated actions.
    pub actions: Vec<String>,
    /// Names of the state vector's entries.
    pub state_layout: Vec<String>,
    /// One record per observation (one more than the actions).
    pub steps: Vec<StepRecord>,
    /// The hidden scene (for debugging; a policy never sees it).
    pub scene: Scene,
    /// The contact sheet's file name, relative to the demo's folder.
    pub contact_sheet: Option<String>,
}

/// What [`write_demo`] wrote.
#[derive(Debug, Clone)]
pub struct Written {
    /// The demonstration's JSON.
    pub json: PathBuf,
    /// The frames, in order.
    pub frames: Vec<PathBuf>,
    /// The contact sheet.
    pub contact_sheet: Option<PathBuf>,
    /// The demonstration itself.
    pub demo: Demonstration<CollectObservation>,
}

/// Captions for a demonstration's frames: `0 <START>`, then `i action`.
pub fn captions(demo: &Demonstration<CollectObservation>) -> Vec<String> {
    let vocab = vocabulary();
    demo.node_labels()
        .iter()
        .enumerate()
        .map(|(i, &node)| format!("{i} {}", vocab.name(node).unwrap_or("?")))
        .collect()
}

/// A contact sheet of a rendered demonstration (`None` if it has no frames).
pub fn demo_contact_sheet(demo: &Demonstration<CollectObservation>) -> Option<RgbImage> {
    let frames: Option<Vec<&RgbImage>> = demo
        .observations()
        .iter()
        .map(|o| o.frame.as_ref())
        .collect();
    let cells: Vec<(&RgbImage, String)> = frames?.into_iter().zip(captions(demo)).collect();
    Some(contact_sheet(&cells, SHEET_COLUMNS, SHEET_SCALE))
}

/// Captions for a video's frames: `s.j/n action`, frame `j` of the `n` of
/// segment `s` and its action (`<START>` for segment 0); `j = n` is the
/// keyframe.
pub fn video_captions<F>(video: &VideoDemonstration<F>) -> Vec<String> {
    let vocab = vocabulary();
    let nodes = video.node_labels();
    video
        .segments()
        .enumerate()
        .flat_map(|(s, range)| {
            let n = range.len();
            let name = vocab.name(nodes[s]).unwrap_or("?");
            (1..=n).map(move |j| format!("{s}.{j}/{n} {name}"))
        })
        .collect()
}

/// A contact sheet of a video demonstration: every frame with its
/// [`video_captions`] caption, [`VIDEO_SHEET_COLUMNS`] per row.
pub fn video_contact_sheet(video: &VideoDemonstration<RgbImage>) -> RgbImage {
    let cells: Vec<(&RgbImage, String)> =
        video.frames().iter().zip(video_captions(video)).collect();
    contact_sheet(&cells, VIDEO_SHEET_COLUMNS, SHEET_SCALE)
}

/// Writes [`video_contact_sheet`] as a PNG at `path`.
pub fn write_video_contact_sheet(
    path: &Path,
    video: &VideoDemonstration<RgbImage>,
) -> Result<(), CollectError> {
    save_png(&video_contact_sheet(video), path)
}

fn save_png(img: &RgbImage, path: &Path) -> Result<(), CollectError> {
    img.save(path).map_err(|source| CollectError::Image {
        path: path.to_owned(),
        source,
    })
}

/// Records the expert's demonstration of `task` with `seed` and writes it to
/// `dir` (created if needed): `demo.json` ([`DemoFile`]),
/// `frames/step_NNN.png` and `contact-sheet.png` (frames only when
/// `config.render`): the file names of every demo and trace `ntg` writes.
pub fn write_demo(
    dir: &Path,
    task: &Task,
    seed: u64,
    config: &CollectConfig,
) -> Result<Written, CollectError> {
    let mut env = CollectEnv::new(task.clone(), *config)?;
    let demo = record_demonstration(&mut env, &mut CollectExpert, seed)?;
    // The recording ran from reset(seed); reset again for the scene.
    env.reset(seed)?;
    let scene = env
        .scene()
        .cloned()
        .ok_or_else(|| CollectError::InvalidConfig("no scene after reset".into()))?;

    let frames_dir = dir.join(FRAMES_DIR);
    fs::create_dir_all(if config.render { &frames_dir } else { dir }).map_err(|source| {
        CollectError::Io {
            path: dir.to_owned(),
            source,
        }
    })?;
    let vocab = vocabulary();
    let name = |id| vocab.name(id).unwrap_or("?").to_owned();
    let mut frames = Vec::new();
    let mut steps = Vec::new();
    let labels = demo.node_labels();
    let next = demo.next_actions();
    for (i, obs) in demo.observations().iter().enumerate() {
        let frame = match &obs.frame {
            Some(img) => {
                let file = format!("{FRAMES_DIR}/step_{i:03}.png");
                let path = dir.join(&file);
                save_png(img, &path)?;
                frames.push(path);
                Some(file)
            }
            None => None,
        };
        steps.push(StepRecord {
            index: i,
            node: name(labels[i]),
            next_action: name(next[i]),
            frame,
            state: obs.state.clone(),
        });
    }
    let sheet_path = match demo_contact_sheet(&demo) {
        Some(sheet) => {
            let path = dir.join(CONTACT_SHEET);
            save_png(&sheet, &path)?;
            Some(path)
        }
        None => None,
    };
    let file = DemoFile {
        format: DEMO_FORMAT.to_owned(),
        task: task.clone(),
        num_objects: task.num_objects(),
        seed,
        config: *config,
        vocabulary: vocab.clone(),
        actions: demo.actions().iter().map(|&a| name(a)).collect(),
        state_layout: state_layout(),
        steps,
        scene,
        contact_sheet: sheet_path.as_ref().map(|_| CONTACT_SHEET.to_owned()),
    };
    let json = dir.join("demo.json");
    let text = serde_json::to_string_pretty(&file)?;
    fs::write(&json, text).map_err(|source| CollectError::Io {
        path: json.clone(),
        source,
    })?;
    Ok(Written {
        json,
        frames,
        contact_sheet: sheet_path,
        demo,
    })
}
