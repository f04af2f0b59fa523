//! Demos and rollouts as LeRobot datasets: `ntg blocks demos`, and the
//! `lerobot/` folder of `ntg trace`.
//!
//! The episode files are read back with the `parquet` crate's own record
//! reader and compared with what `ntg blocks demo` writes for the same task
//! and seed. Where `NTG_PYTHON` (default `python3`) has pyarrow, the
//! README's Python snippet (between the `lerobot-snippet` markers) runs on
//! the dataset; without it that part prints "skipped:" to stderr.

use std::path::{Path, PathBuf};
use std::process::Command;

use parquet::file::reader::{FileReader, SerializedFileReader};
use parquet::record::{Field, RowAccessor};

use crate::common::ntg;

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// One parquet row: image PNG bytes, state, action id and name.
pub struct EpisodeRow {
    pub png: Vec<u8>,
    pub state: Vec<f32>,
    pub action: i64,
    pub action_name: String,
    pub frame_index: i64,
    pub done: bool,
}

/// Reads an episode file with parquet's record API.
pub fn read_episode(path: &Path) -> Vec<EpisodeRow> {
    let file = std::fs::File::open(path).unwrap();
    let reader = SerializedFileReader::new(file).unwrap();
    let names: Vec<String> = reader
        .metadata()
        .file_metadata()
        .schema()
        .get_fields()
        .iter()
        .map(|f| f.name().to_owned())
        .collect();
    let at = |name: &str| names.iter().position(|n| n == name).unwrap();
    reader
        .get_row_iter(None)
        .unwrap()
        .map(|row| {
            let row = row.unwrap();
            let image = row.get_group(at("observation.image")).unwrap();
            let state = row
                .get_list(at("observation.state"))
                .unwrap()
                .elements()
                .iter()
                .map(|f| match f {
                    Field::Float(v) => *v,
                    other => panic!("state element {other:?}"),
                })
                .collect();
            EpisodeRow {
                png: image.get_bytes(0).unwrap().data().to_vec(),
                state,
                action: row.get_long(at("action")).unwrap(),
                action_name: row.get_string(at("action.name")).unwrap().clone(),
                frame_index: row.get_long(at("frame_index")).unwrap(),
                done: row.get_bool(at("next.done")).unwrap(),
            }
        })
        .collect()
}

fn python() -> String {
    std::env::var("NTG_PYTHON").unwrap_or_else(|_| "python3".to_owned())
}

/// The README's Python snippet (between `<!-- lerobot-snippet -->`
/// markers, inside a ```python fence).
fn readme_snippet() -> String {
    let readme =
        std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("../../README.md"))
            .unwrap();
    let start = readme
        .find("<!-- lerobot-snippet -->")
        .expect("README.md has the lerobot-snippet marker");
    let rest = &readme[start..];
    let fence = rest.find("```python\n").unwrap() + "```python\n".len();
    let end = rest[fence..].find("```").unwrap();
    rest[fence..fence + end].to_owned()
}

#[test]
fn demos_match_the_single_demo_and_read_in_python() {
    let tmp = tempfile::tempdir().unwrap();
    let demos = tmp.path().join("demos");
    let (code, stdout, err) = ntg(&["blocks", "demos", "--count", "3", "--out", s(&demos)]);
    assert_eq!(code, 0, "{err}");
    assert!(stdout.contains("wrote 3 expert demos"), "{stdout}");

    let info: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(demos.join("meta/info.json")).unwrap())
            .unwrap();
    assert_eq!(info["total_episodes"], 3);
    assert_eq!(
        info["features"]["observation.image"]["shape"],
        serde_json::json!([64, 64, 3])
    );
    let vocabulary: Vec<String> =
        serde_json::from_value(info["ntg"]["vocabulary"].clone()).unwrap();
    let episodes = std::fs::read_to_string(demos.join("meta/episodes.jsonl")).unwrap();
    assert_eq!(episodes.lines().count(), 3);

    // Task 0 with seed 0 is what `ntg blocks demo --task 0 --seed 0` records.
    let single = tmp.path().join("single");
    let (code, _, err) = ntg(&["blocks", "demo", "--task", "0", "--out", s(&single)]);
    assert_eq!(code, 0, "{err}");
    let demo: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(single.join("demo.json")).unwrap()).unwrap();
    let rows = read_episode(&demos.join("data/chunk-000/episode_000000.parquet"));
    let mut expected: Vec<String> = demo["action_sequence"]
        .as_str()
        .unwrap()
        .split(' ')
        .map(String::from)
        .collect();
    expected.push("<end>".into());
    let names: Vec<String> = rows.iter().map(|r| r.action_name.clone()).collect();
    assert_eq!(names, expected);
    for (t, row) in rows.iter().enumerate() {
        assert_eq!(row.frame_index, t as i64);
        assert_eq!(vocabulary[row.action as usize], row.action_name);
        assert_eq!(row.done, t + 1 == rows.len());
        let states: Vec<f32> = serde_json::from_value(demo["states"][t].clone()).unwrap();
        assert_eq!(row.state, states, "state of row {t}");
        let frame = image::load_from_memory(&row.png).unwrap().to_rgb8();
        let file = image::open(single.join(format!("frames/step_{t:03}.png")))
            .unwrap()
            .to_rgb8();
        assert!(
            frame == file,
            "frame of row {t} differs from frames/step_{t:03}.png"
        );
    }
    let task: serde_json::Value = serde_json::from_str(
        std::fs::read_to_string(demos.join("meta/tasks.jsonl"))
            .unwrap()
            .lines()
            .next()
            .unwrap(),
    )
    .unwrap();
    assert!(
        task["task"].as_str().unwrap().starts_with("stack "),
        "{task}"
    );

    // A second export into the same folder is refused, then replaced with
    // --force; a folder of other files is never replaced.
    let (code, _, err) = ntg(&["blocks", "demos", "--count", "2", "--out", s(&demos)]);
    assert_eq!(code, 1, "{err}");
    assert!(err.contains("pass --force"), "{err}");
    let (code, _, err) = ntg(&[
        "blocks",
        "demos",
        "--count",
        "2",
        "--out",
        s(&demos),
        "--force",
    ]);
    assert_eq!(code, 0, "{err}");
    assert_eq!(
        std::fs::read_dir(demos.join("data/chunk-000"))
            .unwrap()
            .count(),
        2
    );

    run_snippet(tmp.path(), &demos, &names);
}

/// Runs the README's snippet in `dir` on the dataset `demos` (the snippet
/// reads `demos/`), checking it prints the first episode's action names.
fn run_snippet(dir: &Path, demos: &Path, names: &[String]) {
    let python = python();
    let has_pyarrow = Command::new(&python)
        .args(["-c", "import pyarrow.parquet"])
        .output()
        .is_ok_and(|o| o.status.success());
    if !has_pyarrow {
        eprintln!(
            "skipped: the README's Python snippet (`{python} -c \"import pyarrow.parquet\"` failed; point NTG_PYTHON at a Python with pyarrow)"
        );
        return;
    }
    assert_eq!(demos.file_name().unwrap(), "demos");
    let script: PathBuf = dir.join("snippet.py");
    std::fs::write(&script, readme_snippet()).unwrap();
    let out = Command::new(&python)
        .arg(&script)
        .current_dir(dir)
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "the README's snippet failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    // The snippet prints the first episode's task and action names.
    for name in names {
        assert!(stdout.contains(name.as_str()), "{name} not in {stdout}");
    }
}
