//! The bad-input corpus: `ntg` invoked the way a user gets it wrong (bad
//! flags, flags of another domain, missing or malformed files, damaged
//! checkpoints, outputs that already exist). Every case must exit non-zero
//! without a panic, with a message naming the flag or file at fault, and
//! leave every file in its working folder as it was.

use crate::common;

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use common::{TINY_RUN, ntg, train_tiny_run};

/// Every file under `dir` (relative path → contents).
fn snapshot(dir: &Path) -> BTreeMap<PathBuf, Vec<u8>> {
    let mut files = BTreeMap::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        for entry in std::fs::read_dir(&d).unwrap() {
            let path = entry.unwrap().path();
            if path.is_dir() {
                files.insert(path.strip_prefix(dir).unwrap().to_path_buf(), Vec::new());
                stack.push(path);
            } else {
                let bytes = std::fs::read(&path).unwrap();
                files.insert(path.strip_prefix(dir).unwrap().to_path_buf(), bytes);
            }
        }
    }
    files
}

/// Copies the folder `from` to `to` (files and folders only).
fn copy_dir(from: &Path, to: &Path) {
    std::fs::create_dir_all(to).unwrap();
    for entry in std::fs::read_dir(from).unwrap() {
        let path = entry.unwrap().path();
        let target = to.join(path.file_name().unwrap());
        if path.is_dir() {
            copy_dir(&path, &target);
        } else {
            std::fs::copy(&path, &target).unwrap();
        }
    }
}

#[test]
fn every_bad_input_is_a_clean_error_that_changes_nothing() {
    let tmp = tempfile::tempdir().unwrap();
    let root = tmp.path();
    let p = |name: &str| root.join(name).to_str().unwrap().to_owned();

    // Fixtures.
    std::fs::write(root.join("existing.json"), "mine").unwrap();
    std::fs::write(root.join("existing.png"), "mine").unwrap();
    std::fs::create_dir(root.join("nonempty")).unwrap();
    std::fs::write(root.join("nonempty/notes.txt"), "mine").unwrap();
    std::fs::write(root.join("malformed.json"), "{ not json").unwrap();
    std::fs::write(root.join("tasks.json"), r#"{"stack_0": "nope"}"#).unwrap();
    std::fs::create_dir(root.join("norun")).unwrap();
    std::fs::create_dir(root.join("badconfig")).unwrap();
    std::fs::create_dir(root.join("collectrun")).unwrap();
    std::fs::write(
        root.join("collectrun/config.json"),
        r#"{"domain": "collect"}"#,
    )
    .unwrap();
    std::fs::write(root.join("badconfig/config.json"), r#"{"obs": 3}"#).unwrap();
    std::fs::create_dir(root.join("emptyjigsaws")).unwrap();
    let run = train_tiny_run(root);
    let run_s = run.to_str().unwrap().to_owned();
    // Damaged copies of the run.
    let damaged = |name: &str, edit: &dyn Fn(&Path)| -> String {
        let dir = root.join(name);
        copy_dir(&run, &dir);
        edit(&dir);
        dir.to_str().unwrap().to_owned()
    };
    let flipped = damaged("flipped", &|d| {
        let path = d.join("checkpoint/model.bpk");
        let mut bytes = std::fs::read(&path).unwrap();
        let mid = bytes.len() / 2;
        for b in &mut bytes[mid..mid + 20] {
            *b = !*b;
        }
        std::fs::write(&path, bytes).unwrap();
    });
    let truncated = damaged("truncated", &|d| {
        let path = d.join("checkpoint/model.bpk");
        let bytes = std::fs::read(&path).unwrap();
        std::fs::write(&path, &bytes[..bytes.len() / 3]).unwrap();
    });
    let wrong_type = damaged("wrongtype", &|d| {
        let path = d.join("config.json");
        let text = std::fs::read_to_string(&path).unwrap();
        std::fs::write(
            &path,
            text.replace("\"train_tasks\": 2", "\"train_tasks\": \"two\""),
        )
        .unwrap();
    });
    let no_weights = damaged("noweights", &|d| {
        std::fs::remove_file(d.join("checkpoint/model.bpk")).unwrap();
    });
    let other_obs = damaged("otherobs", &|d| {
        let path = d.join("config.json");
        let text = std::fs::read_to_string(&path).unwrap();
        std::fs::write(
            &path,
            text.replace("\"obs\": \"state\"", "\"obs\": \"vid\""),
        )
        .unwrap();
    });
    // Held by another live process (this test, holding the OS lock on the
    // file for the whole test; the id in it names no process, so only the
    // OS lock can refuse), with a cache that training would rebuild:
    // refused before anything is written, not only once the epochs start.
    let locked = damaged("locked", &|d| {
        std::fs::remove_dir_all(d.join("dataset")).unwrap();
        std::fs::write(d.join("train.lock"), "4194304999").unwrap();
    });
    let lock_holder = std::fs::File::open(Path::new(&locked).join("train.lock")).unwrap();
    lock_holder.try_lock().unwrap();

    let train = |extra: &[&str]| -> Vec<String> {
        let mut args = vec!["train".to_owned(), "--out".to_owned(), p("new-run")];
        args.extend(extra.iter().map(|s| s.to_string()));
        args
    };
    let s = |args: &[&str]| -> Vec<String> { args.iter().map(|a| a.to_string()).collect() };
    let mut cases: Vec<(Vec<String>, String)> = vec![
        // Numbers out of range, refused at parse time.
        (train(&["--lr", "NaN"]), "--lr".into()),
        (train(&["--lr", "inf"]), "--lr".into()),
        (train(&["--lr=-1"]), "--lr".into()),
        (train(&["--epochs", "0"]), "--epochs".into()),
        (train(&["--device", "tpu"]), "--device".into()),
        (train(&["--batch-size", "0"]), "--batch-size".into()),
        (train(&["--shards", "0"]), "--shards".into()),
        (train(&["--train-tasks", "0"]), "--train-tasks".into()),
        (
            train(&["--demos-per-task", "many"]),
            "--demos-per-task".into(),
        ),
        (train(&["--retry-weight", "NaN"]), "--retry-weight".into()),
        (train(&["--token-dropout", "1"]), "--token-dropout".into()),
        (train(&["--obs", "pixels"]), "--obs".into()),
        (train(&["--domain", "chess"]), "--domain".into()),
        (train(&["--recipe", "secret"]), "--recipe".into()),
        (
            train(&["--obs", "vid", "--encoder-lr", "NaN"]),
            "--encoder-lr".into(),
        ),
        (
            train(&["--obs", "vid", "--encoder-frame-fraction", "2"]),
            "--encoder-frame-fraction".into(),
        ),
        (
            train(&["--obs", "vid", "--encoder-demos", "0"]),
            "--encoder-demos".into(),
        ),
        (train(&["--lr", "1e-3", "--lr", "2e-3"]), "--lr".into()),
        (
            s(&[TINY_RUN, &["--resume", "--out", &locked]].concat()),
            "being written by another process".into(),
        ),
        // Flags of another domain or another input.
        (
            train(&["--domain", "blocks", "--learn-end"]),
            "--learn-end".into(),
        ),
        (
            train(&["--domain", "collect", "--location-step-prior", "inf"]),
            "--location-step-prior".into(),
        ),
        // A demo interpreter for a method or domain that trains none.
        (
            train(&[
                "--domain",
                "blocks",
                "--method",
                "ntp",
                "--interpreter",
                "stepping",
            ]),
            "--interpreter".into(),
        ),
        (
            train(&["--domain", "sorting", "--interpreter", "stepping"]),
            "--interpreter".into(),
        ),
        // The node source is NTG's only; the localizer reads the previous
        // frame only where it chooses the node.
        (
            train(&[
                "--domain",
                "blocks",
                "--method",
                "ntp",
                "--node-source",
                "executed",
            ]),
            "--node-source".into(),
        ),
        (
            train(&[
                "--domain",
                "blocks",
                "--obs",
                "vid",
                "--method",
                "ntp-flat",
                "--node-source",
                "localizer",
            ]),
            "--node-source".into(),
        ),
        (
            train(&["--domain", "blocks", "--node-source", "nowhere"]),
            "--node-source".into(),
        ),
        (
            train(&[
                "--domain",
                "blocks",
                "--obs",
                "vid",
                "--recipe",
                "recommended",
                "--localizer-previous-frame",
            ]),
            "add --node-source localizer".into(),
        ),
        // A height clamp is a positive length, and a state run's.
        (
            train(&["--domain", "blocks", "--state-height-clamp", "-1"]),
            "--state-height-clamp".into(),
        ),
        (
            train(&[
                "--domain",
                "blocks",
                "--obs",
                "vid",
                "--state-height-clamp",
                "0.075",
            ]),
            "--state-height-clamp".into(),
        ),
        // An execution memory is NTG's, and not object sorting's.
        (
            train(&["--domain", "sorting", "--memory"]),
            "--memory".into(),
        ),
        (
            train(&["--domain", "blocks", "--method", "ntp", "--memory"]),
            "--memory".into(),
        ),
        // A validation length that test episodes have (N = 5).
        (
            train(&[
                "--domain",
                "collect",
                "--validation-tasks-per-n",
                "2",
                "--validation-objects",
                "5",
            ]),
            "--validation-objects".into(),
        ),
        (
            train(&["--domain", "blocks", "--validation-objects", "6"]),
            "--validation-objects".into(),
        ),
        (train(&["--encoder-demos", "10"]), "--encoder-demos".into()),
        (
            train(&["--encoder-keypoints"]),
            "--encoder-keypoints".into(),
        ),
        (
            train(&["--encoder-retry-repeats", "4"]),
            "--encoder-retry-repeats".into(),
        ),
        (
            train(&["--obs", "vid", "--encoder-retry-repeats", "0"]),
            "--encoder-retry-repeats".into(),
        ),
        (
            train(&["--encoder-progress", "1"]),
            "--encoder-progress".into(),
        ),
        (
            train(&["--obs", "vid", "--encoder-progress", "nan"]),
            "--encoder-progress".into(),
        ),
        (
            train(&["--interpreter-frame-pool", "2"]),
            "--interpreter-frame-pool".into(),
        ),
        (
            train(&["--obs", "vid", "--interpreter-frame-pool", "0"]),
            "--interpreter-frame-pool".into(),
        ),
        (
            train(&["--video-renaming-group", "2"]),
            "--video-renaming-group".into(),
        ),
        (
            train(&["--encoder-labels", "primitive"]),
            "--encoder-labels".into(),
        ),
        (train(&["--ntp-core", "gru"]), "--ntp-core".into()),
        (
            train(&["--method", "ntp", "--ntp-core", "recurrent"]),
            "--ntp-core".into(),
        ),
        (
            train(&["--obs", "vid", "--encoder-labels", "primitive"]),
            "--encoder-labels".into(),
        ),
        (
            train(&[
                "--obs",
                "vid",
                "--method",
                "ntp",
                "--encoder-labels",
                "keyframes",
            ]),
            "--encoder-labels".into(),
        ),
        // An evaluation setting is not a trained ablation; only NTG has
        // parts to ablate; object collection has no --ablation.
        (
            train(&["--ablation", "executed-node"]),
            "executed-node is an evaluation setting".into(),
        ),
        (
            train(&["--method", "ntp", "--ablation", "no-gcn"]),
            "the ablations are NTG's".into(),
        ),
        (
            train(&["--domain", "collect", "--ablation", "no-gcn"]),
            "--ablation".into(),
        ),
        // Object sorting: NTG on states, from its 200-task pool, with its
        // own flags only.
        (
            train(&["--domain", "sorting", "--obs", "vid"]),
            "object sorting trains NTG on state input".into(),
        ),
        (
            train(&["--domain", "sorting", "--train-tasks", "201"]),
            "1 to 200".into(),
        ),
        (
            train(&["--domain", "sorting", "--pairwise"]),
            "--pairwise is a flag of --domain blocks".into(),
        ),
        // Methods a domain or an input does not have.
        (
            train(&["--domain", "collect", "--method", "ntp"]),
            "--method ntp".into(),
        ),
        (train(&["--method", "flat"]), "--method flat".into()),
        (train(&["--method", "ntp-detector"]), "--obs vid".into()),
        (
            train(&[
                "--method",
                "ntp-detector",
                "--obs",
                "vid",
                "--encoder-epochs",
                "2",
            ]),
            "--encoder-".into(),
        ),
        (
            train(&["--detector-epochs", "2"]),
            "--method ntp-detector".into(),
        ),
        (
            train(&["--ntp-on-true-states"]),
            "--method ntp-detector".into(),
        ),
        (
            train(&[
                "--method",
                "ntp-detector",
                "--obs",
                "vid",
                "--detector-episodes",
                "0",
            ]),
            "--detector-episodes".into(),
        ),
        (
            train(&["--encoder-hidden", "64"]),
            "--encoder-hidden".into(),
        ),
        // Too much asked, refused before the run folder exists.
        (train(&["--train-tasks", "5000"]), "--train-tasks".into()),
        // Missing flags and subcommands.
        (s(&["train"]), "--out".into()),
        (s(&["eval"]), "--run".into()),
        (s(&["fly"]), "fly".into()),
        (
            s(&["reproduce", "--no-train", "--only", "ntp_exp-state-5"]),
            "--no-train".into(),
        ),
        // Nothing to train from and no saved fig. jigsaws.
        (
            s(&[
                "reproduce",
                "--profile",
                "smoke",
                "--no-train",
                "--runs",
                &p("no-runs"),
                "--out",
                &p("nonempty"),
            ]),
            "jigsaws.json".into(),
        ),
        // Run folders that are not there, or not runs, or damaged.
        (s(&["eval", "--run", &p("missing")]), p("missing")),
        (s(&["eval", "--run", &p("norun")]), "config.json".into()),
        (s(&["eval", "--run", &p("badconfig")]), "config.json".into()),
        (
            s(&["eval", "--run", &wrong_type]),
            "config.json: field `train_tasks`".into(),
        ),
        (s(&["eval", "--run", &flipped]), "model.bpk".into()),
        (s(&["eval", "--run", &truncated]), "model.bpk".into()),
        (s(&["eval", "--run", &no_weights]), "model.bpk".into()),
        (
            s(&["eval", "--run", &other_obs]),
            "reads state observations".into(),
        ),
        // Typos get a suggestion and the usage line; bare `ntg` the
        // command list.
        (
            train(&["--train-task", "50"]),
            "a similar argument exists: '--train-tasks'".into(),
        ),
        (s(&["eval", "--runs", &run_s]), "Usage: ntg eval".into()),
        (s(&[]), "Commands:".into()),
        // Messages that name the real cause.
        (
            s(&["eval", "--run", &p("existing.json")]),
            "it is a file".into(),
        ),
        (
            s(&[
                "trace",
                "--run",
                &p("collectrun"),
                "--task",
                "0",
                "--out",
                &p("t"),
            ]),
            "this is a run of --domain collect".into(),
        ),
        (
            s(&[
                "collect",
                "demo",
                "--objects",
                "7",
                "--seed",
                "0",
                "--out",
                &p("d"),
            ]),
            "--objects 7: a task has 1 to 6".into(),
        ),
        (
            s(&[
                "collect",
                "demo",
                "--objects",
                "2",
                "--seed",
                "0",
                "--out",
                &p("nonempty"),
            ]),
            "--force".into(),
        ),
        // `ntg export`: not a run, damaged weights, an --out that holds
        // something else (never replaced, even with --force) or is a file.
        (
            s(&["export", &p("missing"), "--out", &p("x")]),
            p("missing"),
        ),
        (
            s(&["export", &p("norun"), "--out", &p("x")]),
            "config.json".into(),
        ),
        (
            s(&["export", &flipped, "--out", &p("x")]),
            "model.bpk".into(),
        ),
        (
            s(&["export", &run_s, "--out", &p("nonempty"), "--force"]),
            "holds no export".into(),
        ),
        (
            s(&["export", &run_s, "--out", &p("existing.json")]),
            "not a folder".into(),
        ),
        // `ntg blocks demos`: tasks beyond the set, a bad camera, an --out
        // that holds something else (never replaced) or is a file.
        (
            s(&[
                "blocks",
                "demos",
                "--first",
                "1999",
                "--count",
                "5",
                "--out",
                &p("x"),
            ]),
            "--first 1999 --count 5".into(),
        ),
        (
            s(&["blocks", "demos", "--camera-size", "7", "--out", &p("x")]),
            "--camera-size 7".into(),
        ),
        (
            s(&["blocks", "demos", "--out", &p("nonempty"), "--force"]),
            "holds no dataset".into(),
        ),
        (
            s(&["blocks", "demos", "--out", &p("existing.json")]),
            "not a folder".into(),
        ),
        // `ntg eval --tasks`: a file that is missing, or not a task file.
        (
            s(&["eval", "--run", &run_s, "--tasks", &p("missing.json")]),
            "--tasks".into(),
        ),
        (
            s(&["eval", "--run", &run_s, "--tasks", &p("malformed.json")]),
            "malformed.json".into(),
        ),
        // The cluster interface: an index beyond the list, a task index
        // that is not one, a script that exists.
        (
            s(&[
                "reproduce",
                "--profile",
                "smoke",
                "--array-index",
                "999",
                "--runs",
                &p("x"),
            ]),
            "--array-index 999".into(),
        ),
        (
            s(&[
                "cluster",
                "slurm",
                "--runs",
                &p("x"),
                "--script",
                &p("existing.json"),
            ]),
            "--force".into(),
        ),
        // `ntg plot`: not a run, an --out that is not a PNG or exists
        // (replaced only with --force).
        (s(&["plot", &p("norun")]), "config.json".into()),
        (
            s(&["plot", &run_s, "--out", &p("curves.svg")]),
            ".png".into(),
        ),
        (
            s(&["plot", &run_s, "--out", &p("existing.png")]),
            "--force".into(),
        ),
        (
            s(&["eval", "--run", &run_s, "--test-tasks", "0"]),
            "--test-tasks".into(),
        ),
        (
            s(&["eval", "--run", &run_s, "--edge-threshold", "2"]),
            "--edge-threshold".into(),
        ),
        // Decision checks are NTP's.
        (
            s(&["eval", "--run", &run_s, "--decisions"]),
            "--decisions checks an NTP baseline".into(),
        ),
        (
            s(&[
                "eval",
                "--run",
                &run_s,
                "--split",
                "validation",
                "--test-tasks",
                "18446744073709551615",
            ]),
            "10000".into(),
        ),
        (
            s(&["train", "--out", &p("missing"), "--resume"]),
            p("missing"),
        ),
        (s(&["train", "--out", &p("nonempty")]), p("nonempty")),
        (
            s(&[
                "train",
                "--domain",
                "blocks",
                "--train-tasks",
                "2",
                "--demos-per-task",
                "2",
                "--epochs",
                "3",
                "--validation-tasks",
                "0",
                "--out",
                &run_s,
                "--resume",
            ]),
            "epochs".into(),
        ),
        (
            s(&[
                "trace",
                "--run",
                &p("missing"),
                "--task",
                "0",
                "--out",
                &p("t"),
            ]),
            p("missing"),
        ),
        (
            s(&[
                "trace",
                "--run",
                &run_s,
                "--task",
                "0",
                "--out",
                &p("nonempty"),
            ]),
            p("nonempty"),
        ),
        (
            s(&[
                "trace",
                "--run",
                &run_s,
                "--task",
                "stack_nope",
                "--out",
                &p("t"),
            ]),
            "stack_nope".into(),
        ),
        // Block-stacking task files and demos.
        (
            s(&["blocks", "tasks", "--source", &p("missing.json")]),
            p("missing.json"),
        ),
        (
            s(&["blocks", "tasks", "--source", &p("malformed.json")]),
            p("malformed.json"),
        ),
        (
            s(&["blocks", "tasks", "--source", &p("tasks.json")]),
            p("tasks.json"),
        ),
        (
            s(&["blocks", "tasks", "--write", &p("existing.json")]),
            "--force".into(),
        ),
        (
            s(&["blocks", "demo", "--task", "1", "--out", &p("nonempty")]),
            p("nonempty"),
        ),
        (
            s(&["blocks", "demo", "--task", "nope", "--out", &p("d")]),
            "nope".into(),
        ),
        (
            s(&[
                "blocks",
                "demo",
                "--task",
                "1",
                "--out",
                &p("d"),
                "--columns",
                "0",
            ]),
            "--columns".into(),
        ),
        (
            s(&[
                "blocks",
                "demo",
                "--task",
                "1",
                "--out",
                &p("d"),
                "--scale",
                "0",
            ]),
            "--scale".into(),
        ),
        // Object collection.
        (
            s(&[
                "collect",
                "demo",
                "--objects",
                "5",
                "--max-distractors",
                "4",
                "--seed",
                "0",
                "--out",
                &p("c"),
            ]),
            "--max-distractors".into(),
        ),
        (s(&["collect", "tasks", "--objects", "9"]), "objects".into()),
        // Graphs and JIGSAWS.
        (s(&["graph", "--demo", ""]), "demo".into()),
        (s(&["graph", "--demo", "a <start> b"]), "<start>".into()),
        (
            s(&["graph", "--demo", "a", "--format", "xml"]),
            "--format".into(),
        ),
        (
            s(&["jigsaws", "stats", "--root", &p("missing")]),
            p("missing"),
        ),
        (
            s(&["jigsaws", "stats", "--root", &p("emptyjigsaws")]),
            p("emptyjigsaws"),
        ),
    ];
    // GPU backends a default build lacks.
    if !cfg!(feature = "cuda") {
        cases.push((train(&["--device", "cuda"]), "--features cuda".into()));
    }
    if !cfg!(feature = "wgpu") {
        cases.push((
            s(&["eval", "--run", &run_s, "--device", "wgpu"]),
            "--features wgpu".into(),
        ));
    }
    assert!(cases.len() >= 40, "{} cases", cases.len());

    let before = snapshot(root);
    let mut failures = Vec::new();
    for (args, expected) in &cases {
        let argv: Vec<&str> = args.iter().map(String::as_str).collect();
        let (code, out, err) = ntg(&argv);
        let text = format!("{out}{err}");
        let problem = if code == 0 {
            Some("exit 0")
        } else if code < 0 || text.contains("panicked") {
            Some("panicked or killed")
        } else if !text.contains(expected.as_str()) {
            Some("message does not name the input")
        } else {
            None
        };
        if let Some(problem) = problem {
            failures.push(format!("{argv:?}: {problem} (exit {code}): {text}"));
        }
        let after = snapshot(root);
        if after != before {
            let changed: Vec<_> = after
                .keys()
                .chain(before.keys())
                .filter(|k| after.get(*k) != before.get(*k))
                .collect();
            failures.push(format!("{argv:?} changed files: {changed:?}"));
            break;
        }
    }
    drop(lock_holder);
    assert!(failures.is_empty(), "{}", failures.join("\n\n"));
}
