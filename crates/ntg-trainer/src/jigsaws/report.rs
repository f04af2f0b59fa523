//! Outputs of the experiment: `jigsaws.json`, the bar chart and the report section.

use super::*;

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
    let _ = writeln!(
        s,
        "## Fig. jigsaws: cross-task NLL on {TEST_TASK}\n\n![jigsaws](jigsaws.png)\n\nData: {}. Trained on {} {} + {} demos for up to {} epochs; the model of each method is the one with the lowest NLL on held-out {} and {} demos (every {}-th trial), checked every {} epochs: {} epochs (the two full methods are one training run). Each of the {} {TEST_TASK} demos conditions one policy, scored on all the others. Per-step NLL in nats with ε = {} smoothing (a probability-0 step costs ln(16/ε); such steps are counted); ± is the standard deviation over conditioning demos. Definitions: module docs of `ntg_trainer::jigsaws`.\n",
        result.source,
        result.train_demos,
        TRAIN_TASKS[0],
        TRAIN_TASKS[1],
        result.config.optim.epochs,
        TRAIN_TASKS[0],
        TRAIN_TASKS[1],
        result.config.validation_every,
        result.config.eval_every,
        selected.join("; "),
        result.test_demos,
        result.config.smoothing
    );
    let _ = writeln!(
        s,
        "| method | NLL (mean ± std) | min–max over demos | steps at probability 0 | training time |"
    );
    let _ = writeln!(s, "|---|---|---|---|---|");
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
        "the same order here".to_owned()
    } else {
        format!("**not the order measured here** (full {f:.3}, no graph {ng:.3}, uniform {u:.3})")
    };
    let _ = writeln!(
        s,
        "\nPaper: uniform worst, no graph better, full NTG best (no numbers in the text): {verdict}. **Deviation from the paper:** \"NTG (full)\" uses the completed graph as a prior on the no-graph model's node localizer and edge classifier, `ε(a|n,o) ∝ C_na^τ · ε₀(a|n,o)`, with τ chosen on the held-out training-task demos; \"NTG, own head\" is the full model with the paper's wiring (an edge classifier reading the GCN's embeddings), shown for comparison.\n"
    );
    if let Some(table) = &result.seeds {
        let _ = writeln!(
            s,
            "**Seed sensitivity.** The same experiment with one seed changed at a time (synthetic data, or both models' initial weights); mean NLL over conditioning demos, τ the selected prior weight of NTG (full):\n\n{}",
            seed_table_markdown(table)
        );
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
        let _ = writeln!(
            s,
            "**Seed sensitivity.** Not run here: `ntg jigsaws nll --seed-table` repeats the experiment with one seed changed at a time (the paper profile of `ntg reproduce` includes it; the table measured at the quick profile is in the docs of `ntg_trainer::jigsaws`).\n"
        );
    }
    let _ = writeln!(
        s,
        "Predicted graph for {} ([SVG](jigsaws_graph.svg), [DOT](jigsaws_graph.dot); dashed: added by the GCN, with its probability): transcription `{}` (expert: `{}`); the path has {} edges, the completed graph {} ({} of them in the ground-truth {TEST_TASK} graph of {} edges, the union of all its demos); added by the GCN: {}.\n",
        g.trial,
        short(&g.transcription),
        short(&g.demo_gestures),
        g.path_edges,
        g.graph_edges,
        g.correct_edges,
        g.truth_edges,
        if g.added_edges.is_empty() {
            "none".to_owned()
        } else {
            g.added_edges.join(", ")
        }
    );
    s
}
