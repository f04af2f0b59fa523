//! `cargo xtask bench`: burn (`flex`, the CPU backend) against the
//! PyTorch twin, one table of medians and ratios.
//!
//! Three subprocesses, one after another, all with the same thread count:
//!
//! 1. burn, rows 1–5: the `twin_bench` bench of `ntg-model` (release),
//!    with `RAYON_NUM_THREADS=N` (burn's `flex` backend computes on rayon's
//!    global pool); one JSON line per row. Rows 1b and 2b are the state
//!    step and the frame step split into 2 data-parallel shards, as `ntg
//!    train` trains by default; then
//!    row 7, the data-parallel speedup in samples per second: the state
//!    step on a 1-thread pool and the 2-shard step on a 2-thread pool,
//!    alternated step by step in one process (`--rows data_parallel`), the
//!    median over pairs of their time ratio;
//! 2. PyTorch, rows 1–5: `crates/ntg-model/benches/pytorch/twin.py --bench
//!    all --threads N` (`torch.set_num_threads(N)`) with the interpreter
//!    `NTG_PYTHON` (default `python3`), on exactly the same batches; without
//!    torch (or numpy) there, its column says so and the command still
//!    succeeds;
//! 3. burn, row 6: expert demos generated per second, `env-blocks`'
//!    criterion bench `expert_demos/{state_only,rendered}_T_threads`
//!    (T = 1 for `--threads 1`, else 2: the bench has those two pools),
//!    read back from criterion's `estimates.json` (median) and
//!    `benchmark.json` (demos per iteration). PyTorch has no counterpart.
//!
//! 4. burn, rows 8 and 9: ntg-trainer's criterion bench `stages` (release,
//!    `RAYON_NUM_THREADS=N`): row 8 is stage A's training step of the
//!    128×128 frame encoder (16-channel stem, spatial-softmax keypoints,
//!    batch 64; `stage_a_keypoints_128_stem16/train`) beside its PyTorch
//!    twin `crates/ntg-trainer/benches/pytorch/stage_a.py --keypoints
//!    --image-size 128 --stem 16 --threads N`, row 8b the same step in 2
//!    data-parallel shards (`…/train_2_shards`, as `ntg train` runs stage
//!    A); row 9 is stage B's step
//!    (block stacking's recommended recipe on frame embeddings, the
//!    interpreter reading frames pooled by 4) over the state step, both
//!    burn (`stage_b/embedding_step_pool_4`, `stage_b/state_step`).
//!
//! Each side reports a `shape` per row (batch, rows, frames, tokens, ...);
//! a row whose shapes differ is flagged. The table is printed and written
//! as JSON (default `target/bench/bench.json`).

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};

use anyhow::{Context, bail};
use serde_json::{Value, json};

/// Settings of one `cargo xtask bench`.
pub struct Bench {
    /// Threads of both sides.
    pub threads: usize,
    /// A smoke check: few repeats.
    pub quick: bool,
    /// Timed repeats per training row (the policy row runs 10× as many).
    pub repeats: usize,
    /// Untimed calls before them.
    pub warmup: usize,
    /// Where the JSON table goes.
    pub out: PathBuf,
}

/// The rows both sides time: (key, label). The `_2_shards` rows are burn's
/// only; their PyTorch column is the twin's step without the suffix (see
/// [`twin_key`]).
const NET_ROWS: [(&str, &str); 7] = [
    ("state_step", "state training step (full model, batch 32)"),
    (
        "state_step_2_shards",
        "  the same, 2 data-parallel shards (ntg train --shards 2)",
    ),
    (
        "frame_step",
        "frame encoder training step (stage A, 64 frames)",
    ),
    (
        "frame_step_2_shards",
        "  the same, 2 data-parallel shards (stage A of ntg train --obs vid)",
    ),
    ("interpreter_step", "demo interpreter training step (state)"),
    ("gcn_step", "GCN training step (32 graphs)"),
    ("policy_step", "policy step at rollout (inference)"),
];

/// One line of the table.
struct Row {
    /// "1", "1b", ...
    number: String,
    key: String,
    label: String,
    /// "ms" (a median time), "demos/s" (a rate) or "x" (a speedup).
    unit: &'static str,
    burn: Option<f64>,
    burn_repeats: Option<u64>,
    pytorch: Option<f64>,
    pytorch_repeats: Option<u64>,
    shape: Option<String>,
    shape_mismatch: bool,
}

/// What the PyTorch side gave: rows by key, or why there are none.
enum Twin {
    Rows(Vec<Value>, String),
    Missing(String),
}

fn python() -> String {
    std::env::var("NTG_PYTHON").unwrap_or_else(|_| "python3".to_owned())
}

/// The JSON objects among `stdout`'s lines.
fn json_lines(stdout: &[u8]) -> Vec<Value> {
    String::from_utf8_lossy(stdout)
        .lines()
        .filter(|l| l.trim_start().starts_with('{'))
        .filter_map(|l| serde_json::from_str(l).ok())
        .collect()
}

/// The twin's row a burn row is compared with: the data-parallel step
/// against the twin's plain step, which uses its threads inside each
/// operation (the same batch, the same thread count).
fn twin_key(key: &str) -> &str {
    match key {
        "state_step_2_shards" => "state_step",
        "frame_step_2_shards" => "frame_step",
        _ => key,
    }
}

fn find<'a>(lines: &'a [Value], key: &str) -> Option<&'a Value> {
    lines.iter().find(|v| v["row"] == key)
}

/// Runs a cargo command in `root` (its stderr shown) and returns its
/// output, or an error naming `what` with its stdout if it failed.
fn cargo_output(
    cmd: &mut Command,
    root: &Path,
    what: &str,
) -> anyhow::Result<std::process::Output> {
    let out = cmd
        .current_dir(root)
        .stderr(Stdio::inherit())
        .output()
        .context("could not start cargo")?;
    if !out.status.success() {
        bail!(
            "{what} failed ({}):\n{}",
            out.status,
            String::from_utf8_lossy(&out.stdout)
        );
    }
    Ok(out)
}

/// The `twin_bench` bench's rows `rows` with `threads` rayon threads.
fn twin_bench(root: &Path, b: &Bench, rows: &str, threads: usize) -> anyhow::Result<Vec<Value>> {
    let mut cmd = Command::new(env!("CARGO"));
    cmd.args([
        "bench",
        "--quiet",
        "-p",
        "ntg-model",
        "--bench",
        "twin_bench",
        "--",
    ])
    .args(["--rows", rows])
    .args(["--repeats", &b.repeats.to_string()])
    .args(["--warmup", &b.warmup.to_string()])
    .env("RAYON_NUM_THREADS", threads.to_string());
    let out = cargo_output(&mut cmd, root, "the twin_bench bench")?;
    Ok(json_lines(&out.stdout))
}

/// Rows 1–5 on burn (the `twin_bench` bench), and its `data_parallel`
/// row (row 7: the 1-thread and 2-shard medians and the paired speedup).
fn burn_rows(root: &Path, b: &Bench) -> anyhow::Result<(Vec<Value>, [f64; 3])> {
    eprintln!("bench: burn rows 1-5 (release build of ntg-model's twin_bench bench)");
    let lines = twin_bench(root, b, "all", b.threads)?;
    for (key, _) in NET_ROWS {
        if find(&lines, key).is_none() {
            bail!("the twin_bench bench printed no row {key:?}");
        }
    }
    eprintln!("bench: row 7, the state step on 1 thread alternated with 2 shards on 2");
    let parallel = twin_bench(root, b, "data_parallel", b.threads)?;
    let parallel = find(&parallel, "data_parallel")
        .context("the twin_bench bench printed no data_parallel row")?;
    let field = |name: &str| {
        parallel[name]
            .as_f64()
            .with_context(|| format!("the data_parallel row has no {name}"))
    };
    let row7 = [
        field("one_thread_median_ms")?,
        field("two_shards_median_ms")?,
        field("speedup")?,
    ];
    Ok((lines, row7))
}

/// Rows 1–5 on PyTorch: `twin.py --bench all`, or why not.
fn pytorch_rows(root: &Path, b: &Bench) -> Twin {
    let python = python();
    let probe = Command::new(&python)
        .args(["-c", "import numpy, torch; print(torch.__version__)"])
        .stderr(Stdio::null())
        .output();
    let version = match probe {
        Ok(o) if o.status.success() => String::from_utf8_lossy(&o.stdout).trim().to_owned(),
        _ => {
            eprintln!("bench: `{python}` has no torch (or numpy): burn column only");
            return Twin::Missing("PyTorch not installed (set NTG_PYTHON)".into());
        }
    };
    eprintln!("bench: PyTorch rows 1-5 ({python}, torch {version})");
    let script = root.join("crates/ntg-model/benches/pytorch/twin.py");
    let n = b.threads.to_string();
    let out = Command::new(&python)
        .arg(&script)
        .args(["--bench", "all", "--threads", &n])
        .args(["--repeats", &b.repeats.to_string()])
        .args(["--warmup", &b.warmup.to_string()])
        // torch.set_num_threads(N) sets the intra-op pool; these size the
        // rest the same.
        .env("OMP_NUM_THREADS", &n)
        .env("MKL_NUM_THREADS", &n)
        .current_dir(root)
        .stderr(Stdio::inherit())
        .output();
    match out {
        Ok(o) if o.status.success() => Twin::Rows(json_lines(&o.stdout), version),
        Ok(o) => {
            eprintln!(
                "bench: twin.py failed ({}):\n{}",
                o.status,
                String::from_utf8_lossy(&o.stdout)
            );
            Twin::Missing(format!("twin.py failed ({})", o.status))
        }
        Err(e) => Twin::Missing(format!("could not run {python}: {e}")),
    }
}

/// `cargo bench --quiet -p PACKAGE --bench BENCH -- --noplot`, for the
/// caller to add criterion's options and filter to.
fn criterion_command(package: &str, bench: &str) -> Command {
    let mut cmd = Command::new(env!("CARGO"));
    cmd.args(["bench", "--quiet", "-p", package, "--bench", bench])
        .args(["--", "--noplot"]);
    cmd
}

/// Row 6 on burn: env-blocks' criterion bench of expert demos. Returns
/// `(state-only demos/s, rendered demos/s, pool threads)`.
fn demo_rows(root: &Path, b: &Bench) -> anyhow::Result<(f64, f64, usize)> {
    let pool = if b.threads == 1 { 1 } else { 2 };
    eprintln!(
        "bench: row 6, expert demos per second (env-blocks' criterion bench, {pool}-thread pool)"
    );
    let home = root.join("target/bench/criterion");
    let mut cmd = criterion_command("env-blocks", "blocks");
    if b.quick {
        cmd.arg("--quick");
    } else {
        cmd.args(["--warm-up-time", "1", "--measurement-time", "4"]);
    }
    cmd.arg(format!(
        "^expert_demos/(state_only|rendered)_{pool}_threads$"
    ))
    .env("CRITERION_HOME", &home);
    cargo_output(&mut cmd, root, "cargo bench -p env-blocks")?;
    let rate = |name: &str| -> anyhow::Result<f64> {
        let dir = home
            .join("expert_demos")
            .join(format!("{name}_{pool}_threads/new"));
        let read = |file: &str| -> anyhow::Result<Value> {
            let path = dir.join(file);
            let text = std::fs::read_to_string(&path)
                .with_context(|| format!("reading {}", path.display()))?;
            serde_json::from_str(&text).with_context(|| format!("parsing {}", path.display()))
        };
        let ns = read("estimates.json")?["median"]["point_estimate"]
            .as_f64()
            .context("estimates.json: no median")?;
        let demos = read("benchmark.json")?["throughput"]["Elements"]
            .as_f64()
            .context("benchmark.json: no element throughput")?;
        Ok(demos / (ns * 1e-9))
    };
    Ok((rate("state_only")?, rate("rendered")?, pool))
}

/// The criterion benchmarks of ntg-trainer's `stages` bench that rows 8
/// and 9 read, in this order: stage A's 128-px step, the state step,
/// stage B's step (pool 4).
const STAGE_BENCHES: [&str; 4] = [
    "stage_a_keypoints_128_stem16/train",
    "stage_b/state_step",
    "stage_b/embedding_step_pool_4",
    "stage_a_keypoints_128_stem16/train_2_shards",
];

/// Rows 8, 8b and 9 on burn: the medians (ms) of [`STAGE_BENCHES`].
fn stage_rows(root: &Path, b: &Bench) -> anyhow::Result<[f64; 4]> {
    eprintln!(
        "bench: rows 8-9, stage A's 128-px encoder step and stage B's step (ntg-trainer's criterion bench `stages`, {} threads)",
        b.threads
    );
    let home = root.join("target/bench/criterion");
    let mut cmd = criterion_command("ntg-trainer", "stages");
    if b.quick {
        cmd.arg("--quick");
    }
    cmd.arg(format!("^({})$", STAGE_BENCHES.join("|")))
        .env("RAYON_NUM_THREADS", b.threads.to_string())
        .env("CRITERION_HOME", &home);
    cargo_output(&mut cmd, root, "cargo bench -p ntg-trainer --bench stages")?;
    let median_ms = |id: &str| -> anyhow::Result<f64> {
        let path = home.join(id).join("new/estimates.json");
        let text = std::fs::read_to_string(&path)
            .with_context(|| format!("reading {}", path.display()))?;
        let v: Value =
            serde_json::from_str(&text).with_context(|| format!("parsing {}", path.display()))?;
        let ns = v["median"]["point_estimate"]
            .as_f64()
            .with_context(|| format!("{}: no median", path.display()))?;
        Ok(ns * 1e-6)
    };
    Ok([
        median_ms(STAGE_BENCHES[0])?,
        median_ms(STAGE_BENCHES[1])?,
        median_ms(STAGE_BENCHES[2])?,
        median_ms(STAGE_BENCHES[3])?,
    ])
}

/// Row 8 on PyTorch: `stage_a.py`'s median training step (ms) of the
/// 128-px encoder, or why there is none.
fn stage_a_twin(root: &Path, b: &Bench, twin: &Twin) -> Result<f64, String> {
    if let Twin::Missing(why) = twin {
        return Err(why.clone());
    }
    let python = python();
    eprintln!("bench: PyTorch row 8 (stage_a.py, 128x128 frames, stem 16, keypoints)");
    let n = b.threads.to_string();
    let out = Command::new(&python)
        .arg(root.join("crates/ntg-trainer/benches/pytorch/stage_a.py"))
        .args(["--keypoints", "--image-size", "128", "--stem", "16"])
        .args(["--threads", &n, "--repeats", &b.repeats.to_string()])
        .env("OMP_NUM_THREADS", &n)
        .env("MKL_NUM_THREADS", &n)
        .current_dir(root)
        .stderr(Stdio::inherit())
        .output()
        .map_err(|e| format!("could not run {python}: {e}"))?;
    if !out.status.success() {
        return Err(format!("stage_a.py failed ({})", out.status));
    }
    json_lines(&out.stdout)
        .iter()
        .find_map(|v| v["train_ms"].as_f64())
        .ok_or_else(|| "stage_a.py printed no train_ms".to_owned())
}

/// `x` with about 3 significant digits.
fn number(x: f64) -> String {
    if x >= 1000.0 {
        format!("{x:.0}")
    } else if x >= 100.0 {
        format!("{x:.1}")
    } else if x >= 1.0 {
        format!("{x:.2}")
    } else {
        format!("{x:.3}")
    }
}

pub fn run(root: &Path, b: &Bench) -> anyhow::Result<()> {
    let (burn, [one_thread, two_shards, speedup]) = burn_rows(root, b)?;
    let twin = pytorch_rows(root, b);
    let (state_rate, rendered_rate, pool) = demo_rows(root, b)?;
    let [stage_a_ms, state_step_ms, stage_b_ms, stage_a_2_shards_ms] = stage_rows(root, b)?;
    let stage_a_torch = stage_a_twin(root, b, &twin);

    let (twin_rows, torch, missing) = match &twin {
        Twin::Rows(rows, version) => (rows.as_slice(), Some(version.clone()), None),
        Twin::Missing(why) => (&[][..], None, Some(why.clone())),
    };
    let mut rows: Vec<Row> = Vec::new();
    let numbers = ["1", "1b", "2", "2b", "3", "4", "5"];
    for ((key, label), number) in NET_ROWS.iter().zip(numbers) {
        let ours = find(&burn, key);
        let theirs = find(twin_rows, twin_key(key));
        let shape = ours.and_then(|v| v["shape"].as_str()).map(str::to_owned);
        let their_shape = theirs.and_then(|v| v["shape"].as_str());
        rows.push(Row {
            number: number.to_owned(),
            key: (*key).to_owned(),
            label: (*label).to_owned(),
            unit: "ms",
            burn: ours.and_then(|v| v["median_ms"].as_f64()),
            burn_repeats: ours.and_then(|v| v["repeats"].as_u64()),
            pytorch: theirs.and_then(|v| v["median_ms"].as_f64()),
            pytorch_repeats: theirs.and_then(|v| v["repeats"].as_u64()),
            shape_mismatch: theirs.is_some() && their_shape != shape.as_deref(),
            shape,
        });
    }
    for (key, label, rate) in [
        (
            "demos_state",
            "expert demos generated, state only",
            state_rate,
        ),
        (
            "demos_rendered",
            "expert demos generated, rendered 64x64",
            rendered_rate,
        ),
    ] {
        rows.push(Row {
            number: "6".to_owned(),
            key: key.to_owned(),
            label: format!("{label} ({pool}-thread pool)"),
            unit: "demos/s",
            burn: Some(rate),
            burn_repeats: None,
            pytorch: None,
            pytorch_repeats: None,
            shape: None,
            shape_mismatch: false,
        });
    }

    rows.push(Row {
        number: "7".to_owned(),
        key: "data_parallel_speedup".to_owned(),
        label: format!(
            "data-parallel speedup: state step samples/s, 2 shards on 2 threads ({} ms) over 1 thread ({} ms), alternated, median paired ratio",
            number(two_shards),
            number(one_thread)
        ),
        unit: "x",
        burn: Some(speedup),
        burn_repeats: None,
        pytorch: None,
        pytorch_repeats: None,
        shape: None,
        shape_mismatch: false,
    });

    // Rows 8 and 8b: the same network, one step plain and in 2 shards,
    // beside the twin's one step.
    for (number, key, label, ms) in [
        (
            "8",
            "frame_step_128_stem16",
            "frame encoder training step, 128x128 frames, 16-channel stem, keypoints (stage A, 64 frames)",
            stage_a_ms,
        ),
        (
            "8b",
            "frame_step_128_stem16_2_shards",
            "  the same, 2 data-parallel shards (stage A of ntg train --obs vid)",
            stage_a_2_shards_ms,
        ),
    ] {
        rows.push(Row {
            number: number.to_owned(),
            key: key.to_owned(),
            label: label.to_owned(),
            unit: "ms",
            burn: Some(ms),
            burn_repeats: None,
            pytorch: stage_a_torch.as_ref().ok().copied(),
            pytorch_repeats: stage_a_torch.as_ref().ok().map(|_| b.repeats as u64),
            shape: Some("64 frames of 3x128x128".to_owned()),
            shape_mismatch: false,
        });
    }
    rows.push(Row {
        number: "9".to_owned(),
        key: "stage_b_over_state_step".to_owned(),
        label: format!(
            "stage B step over the state step (recommended recipe, 32 demos; frame embeddings pooled by 4, {} ms; state rows, {} ms)",
            number(stage_b_ms),
            number(state_step_ms)
        ),
        unit: "x",
        burn: Some(stage_b_ms / state_step_ms),
        burn_repeats: None,
        pytorch: None,
        pytorch_repeats: None,
        shape: None,
        shape_mismatch: false,
    });
    if let Err(why) = &stage_a_torch {
        eprintln!("bench: row 8 has no PyTorch median: {why}");
    }

    // The table.
    let cell = |r: &Row, v: Option<f64>| match v {
        Some(x) if r.unit == "ms" => format!("{} ms", number(x)),
        Some(x) if r.unit == "x" => format!("{x:.2}x"),
        Some(x) => format!("{x:.0}/s"),
        None => "–".to_owned(),
    };
    let pytorch_cell = |r: &Row| match (&missing, r.unit) {
        (Some(why), "ms") => why.clone(),
        _ => cell(r, r.pytorch),
    };
    let ratio = |r: &Row| match (r.burn, r.pytorch) {
        (Some(a), Some(p)) if p > 0.0 => Some(a / p),
        _ => None,
    };
    let label_w = rows
        .iter()
        .map(|r| r.label.chars().count())
        .max()
        .unwrap_or(0)
        + 3;
    let py_w = rows
        .iter()
        .map(|r| pytorch_cell(r).chars().count())
        .max()
        .unwrap_or(0)
        .max("PyTorch median".len());
    println!();
    println!(
        "cargo xtask bench: medians, {} threads on both sides{}",
        b.threads,
        if b.quick {
            " (--quick: few repeats, a smoke check)"
        } else {
            ""
        }
    );
    println!(
        "{:<label_w$}  {:>16}  {:>py_w$}  {:>12}  {:>7}",
        "row", "burn flex median", "PyTorch median", "burn/PyTorch", "threads"
    );
    for r in &rows {
        let label = format!(
            "{} {}{}",
            r.number,
            r.label,
            if r.shape_mismatch { " !" } else { "" }
        );
        let threads = if r.unit == "demos/s" { pool } else { b.threads };
        println!(
            "{:<label_w$}  {:>16}  {:>py_w$}  {:>12}  {:>7}",
            label,
            cell(r, r.burn),
            pytorch_cell(r),
            ratio(r).map_or("–".to_owned(), |x| format!("{x:.2}")),
            threads
        );
    }
    println!(
        "burn: RAYON_NUM_THREADS={}; PyTorch: torch.set_num_threads({}){}. \
         Rows 1b, 2b and 8b have the PyTorch column of rows 1, 2 and 8; rows 6, 7 and 9 have no PyTorch counterpart.",
        b.threads,
        b.threads,
        torch
            .as_ref()
            .map_or(String::new(), |v| format!(", torch {v}"))
    );
    if rows.iter().any(|r| r.shape_mismatch) {
        println!("! the two sides timed differently shaped batches (see `shape` in the JSON)");
    }

    // The JSON.
    let json_rows: Vec<Value> = rows
        .iter()
        .map(|r| {
            json!({
                "row": r.number,
                "key": r.key,
                "name": r.label,
                "unit": r.unit,
                "burn_flex_median": r.burn,
                "burn_repeats": r.burn_repeats,
                "pytorch_median": r.pytorch,
                "pytorch_repeats": r.pytorch_repeats,
                "ratio_burn_over_pytorch": ratio(r),
                "threads": if r.unit == "demos/s" { pool } else { b.threads },
                "shape": r.shape,
                "shape_mismatch": r.shape_mismatch,
            })
        })
        .collect();
    let doc = json!({
        "format": "ntg-bench/1",
        "threads": b.threads,
        "quick": b.quick,
        "repeats": b.repeats,
        "warmup": b.warmup,
        "python": python(),
        "torch": torch,
        "pytorch_note": missing,
        "rows": json_rows,
    });
    if let Some(dir) = b.out.parent() {
        std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    }
    std::fs::write(&b.out, serde_json::to_string_pretty(&doc)? + "\n")
        .with_context(|| format!("writing {}", b.out.display()))?;
    println!("table written to {}", b.out.display());
    Ok(())
}
