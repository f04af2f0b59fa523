//! Outputs of the experiment: `jigsaws.json`, the bar chart and the report section.

use super::*;
use crate::experiment::template::JIGSAWS;

/// Runs the experiment at `profile` (synthetic data, seed 0, unless `root`
/// names a JIGSAWS copy), and writes `<out>/jigsaws.{svg,png}` (the bar
/// chart), `<out>/jigsaws_graph.{dot,svg}` (the predicted Needle Passing
/// graph) and `<out>/jigsaws.json`.
pub fn reproduce(
    profile: Profile,
    root: Option<&Path>,
    runs: &Path,
    out: &Path,
    experiments: crate::experiment::Source<'_>,
) -> anyhow::Result<JigsawsResult> {
    let source = match root {
        Some(path) => DataSource::Root {
            path: path.to_owned(),
        },
        None => DataSource::Synthetic {
            seed: 0,
            duration_scale: 1.0,
        },
    };
    let config = JigsawsConfig::for_profile(profile, source, experiments)?;
    let mut result = run_experiment(&config, runs, |line| eprintln!("{line}"))?;
    // The table multiplies the experiment's cost by ten: the paper profile
    // runs it; at the quick profile (whose whole run must fit 15 minutes
    // with the build) it is `ntg jigsaws nll --seed-table`.
    if profile == Profile::Paper {
        result.seeds = Some(seed_table(&config, Some(&result), runs, |line| {
            eprintln!("{line}")
        })?);
    }
    write_outputs(&result, out)?;
    Ok(result)
}

/// Writes the figure, the graph, the report section (`jigsaws.md`) and the
/// JSON of `result` into `out`.
pub fn write_outputs(result: &JigsawsResult, out: &Path) -> anyhow::Result<()> {
    std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
    write_figure(result, &out.join("jigsaws"))?;
    let dot_path = out.join("jigsaws_graph.dot");
    std::fs::write(&dot_path, &result.graph.dot)
        .with_context(|| format!("writing {}", dot_path.display()))?;
    let svg = crate::svg::dot_to_svg(&result.graph.dot)?;
    let svg_path = out.join("jigsaws_graph.svg");
    std::fs::write(&svg_path, svg).with_context(|| format!("writing {}", svg_path.display()))?;
    let md_path = out.join("jigsaws.md");
    std::fs::write(&md_path, report_section(result))
        .with_context(|| format!("writing {}", md_path.display()))?;
    RunDir::write_json(&out.join("jigsaws.json"), result)
}

/// The bar chart: mean per-step NLL per method, ±1 standard deviation over
/// conditioning demos.
pub fn write_figure(result: &JigsawsResult, stem: &Path) -> anyhow::Result<()> {
    let bars = result
        .methods
        .iter()
        .map(|m| crate::figure::Bar {
            label: m.method.label().to_owned(),
            value: m.mean_nll,
            lo: m.mean_nll - m.std_nll,
            hi: m.mean_nll + m.std_nll,
        })
        .collect();
    crate::figure::write_bar_chart(
        &crate::figure::BarChart {
            title: format!(
                "{TEST_TASK} from one demo ({} demos, {})",
                result.test_demos,
                match result.config.source {
                    DataSource::Synthetic { .. } => "synthetic stand-in",
                    DataSource::Root { .. } => "JIGSAWS copy",
                }
            ),
            y_label: "NLL per step (nats, lower is better)".into(),
            bars,
        },
        stem,
    )
}

/// The report section (Markdown) of a result.
pub fn report_section(result: &JigsawsResult) -> String {
    let mut s = String::new();
    let selected: Vec<String> = result
        .runs
        .iter()
        .map(|r| {
            format!(
                "{} after {}{}",
                r.method.label(),
                r.selection.epochs,
                r.selection
                    .prior_weight
                    .map_or(String::new(), |w| format!(" (prior weight τ = {w})"))
            )
        })
        .collect();
    let head = JIGSAWS.fill(
        "head",
        &[
            ("test_task", &TEST_TASK),
            ("source", &result.source),
            ("train_demos", &result.train_demos),
            ("train_task_a", &TRAIN_TASKS[0]),
            ("train_task_b", &TRAIN_TASKS[1]),
            ("epochs", &result.config.optim.epochs),
            ("validation_every", &result.config.validation_every),
            ("eval_every", &result.config.eval_every),
            ("selected", &selected.join("; ")),
            ("test_demos", &result.test_demos),
            ("smoothing", &result.config.smoothing),
        ],
    );
    let _ = writeln!(s, "{head}\n");
    let _ = writeln!(s, "{}", JIGSAWS.text("table_head"));
    for m in &result.methods {
        let time = result
            .runs
            .iter()
            .find(|r| r.method == m.method)
            .map_or("–".to_owned(), |r| format!("{:.0} s", r.train_seconds));
        let _ = writeln!(
            s,
            "| {} | {:.3} ± {:.3} | {:.3}–{:.3} | {} of {} | {time} |",
            m.method.label(),
            m.mean_nll,
            m.std_nll,
            m.min_nll,
            m.max_nll,
            m.zero_probability_steps,
            m.steps
        );
    }
    let nll = |m| result.method(m).map_or(f64::NAN, |r| r.mean_nll);
    let (u, ng, f) = (
        nll(Method::Uniform),
        nll(Method::NoGraph),
        nll(Method::Full),
    );
    let verdict = if f < ng && ng < u {
        JIGSAWS.text("order_same")
    } else {
        let (f, ng, u) = (format!("{f:.3}"), format!("{ng:.3}"), format!("{u:.3}"));
        JIGSAWS.fill(
            "order_other",
            &[("full", &f), ("no_graph", &ng), ("uniform", &u)],
        )
    };
    let _ = writeln!(s, "\n{}\n", JIGSAWS.fill("paper", &[("verdict", &verdict)]));
    if let Some(table) = &result.seeds {
        let title = JIGSAWS.text("seeds_title");
        let _ = writeln!(s, "{title}\n\n{}", seed_table_markdown(table));
    }
    let g = &result.graph;
    let short = |v: &[String]| {
        if v.len() > 30 {
            format!("{} … ({} gestures)", v[..30].join(" "), v.len())
        } else {
            v.join(" ")
        }
    };
    if result.seeds.is_none() {
        let _ = writeln!(s, "{}\n", JIGSAWS.text("seeds_not_run"));
    }
    let added = if g.added_edges.is_empty() {
        JIGSAWS.text("graph_none_added")
    } else {
        g.added_edges.join(", ")
    };
    let graph = JIGSAWS.fill(
        "graph",
        &[
            ("trial", &g.trial),
            ("transcription", &short(&g.transcription)),
            ("expert", &short(&g.demo_gestures)),
            ("path_edges", &g.path_edges),
            ("graph_edges", &g.graph_edges),
            ("correct_edges", &g.correct_edges),
            ("test_task", &TEST_TASK),
            ("truth_edges", &g.truth_edges),
            ("added", &added),
        ],
    );
    let _ = writeln!(s, "{graph}\n");
    s
}
