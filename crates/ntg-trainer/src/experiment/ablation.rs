//! Fig. "ablation" (a): NTG trained whole and trained without each of its
//! parts (demo interpreter, node localizer, edge classifier, GCN), block
//! stacking, scored on the same unseen tasks. The runs are listed in
//! `experiments/ablation.toml`, in the form of fig. "ntp_exp" (a panel's
//! `ablations`), and are trained and evaluated by [`ntp_exp::run`]; this
//! module draws them and checks the paper's trend.

use std::fmt::Write as _;
use std::path::Path;

use crate::experiment::ntp_exp::{self, NtpExpExperiment, NtpExpPoint};
use crate::figure::{Panel, Point, Series};
use crate::method::ntg::Variant;

/// Reads `ablation.toml` from `source`.
pub fn load(source: crate::experiment::Source<'_>) -> anyhow::Result<NtpExpExperiment> {
    NtpExpExperiment::load_named("ablation", source)
}

/// Writes the figure as `stem.svg` and `stem.png`: one panel, success and
/// goals met per variant (x: the variant's number in the legend's order).
pub fn write_figure(points: &[NtpExpPoint], stem: &Path) -> anyhow::Result<()> {
    let x = |i: usize| (i + 1) as f64;
    let legend: Vec<String> = points
        .iter()
        .enumerate()
        .map(|(i, p)| format!("{} {}", i + 1, short_name(p.ablation)))
        .collect();
    let panel = Panel {
        title: "(a) block stacking: NTG without each part".into(),
        x_label: legend.join(", "),
        y_label: "unseen tasks: success, goals met".into(),
        x_log: false,
        x_ticks_at_points: true,
        y_range: (0.0, 1.0),
        series: vec![
            Series {
                name: "success".into(),
                points: points
                    .iter()
                    .enumerate()
                    .map(|(i, p)| Point::success(x(i), &p.success))
                    .collect(),
            },
            Series {
                name: "goals met".into(),
                points: points
                    .iter()
                    .enumerate()
                    .map(|(i, p)| Point::exact(x(i), p.goal_fraction))
                    .collect(),
            },
        ],
    };
    crate::figure::write_figure(&[panel], stem)
}

/// A variant's name on the figure's axis.
fn short_name(ablation: Variant) -> &'static str {
    match ablation {
        Variant::NoDemoInterpreter => "no demo int.",
        Variant::NoNodeLocalizer => "no node loc.",
        Variant::NoEdgeClassifier => "no edge cls.",
        Variant::NoGcn => "no GCN",
        _ => "full",
    }
}

/// The paper's trend, each part checked on `points` (Markdown lines):
/// holds / does not hold, with the numbers. A part is "near zero" when its
/// interval's upper end is below a tenth, and the whole model is "best"
/// when its success is at least every variant's.
pub fn trend_checks(points: &[NtpExpPoint]) -> Vec<String> {
    let of = |v: Variant| points.iter().find(|p| p.ablation == v);
    let Some(full) = of(Variant::Full) else {
        return vec!["The whole model was not run: nothing to compare.".into()];
    };
    let rate = |p: &NtpExpPoint| {
        format!(
            "{:.3} ({:.3}–{:.3})",
            p.success.rate, p.success.ci_low, p.success.ci_high
        )
    };
    let holds = |ok: bool| if ok { "holds" } else { "does not hold" };
    let mut lines = Vec::new();
    for v in [Variant::NoDemoInterpreter, Variant::NoNodeLocalizer] {
        if let Some(p) = of(v) {
            lines.push(format!(
                "Without {} almost no task is completed: **{}** ({}).",
                ntp_exp::ablation_part(v),
                holds(p.success.ci_high < 0.1),
                rate(p)
            ));
        }
    }
    for v in [Variant::NoEdgeClassifier, Variant::NoGcn] {
        if let (Some(p), Some(drop_to_zero)) = (
            of(v),
            [Variant::NoDemoInterpreter, Variant::NoNodeLocalizer]
                .iter()
                .filter_map(|&z| of(z))
                .map(|z| z.success.rate)
                .reduce(f64::max),
        ) {
            lines.push(format!(
                "Without {} a smaller drop than without the demo interpreter or node localizer (below the whole model, above those): **{}** ({} against the whole model's {} and at most {:.3}).",
                ntp_exp::ablation_part(v),
                holds(p.success.rate <= full.success.rate && p.success.rate > drop_to_zero),
                rate(p),
                rate(full),
                drop_to_zero
            ));
        }
    }
    let best = points.iter().all(|p| p.success.rate <= full.success.rate);
    lines.push(format!(
        "The whole model is best: **{}** ({}).",
        holds(best),
        rate(full)
    ));
    lines
}

/// The report section of fig. "ablation" (Markdown); `recipe_note` says
/// what the file changes in the recipe.
pub fn report_section(points: &[NtpExpPoint], recipe_note: &str) -> String {
    let mut s = String::new();
    let _ = writeln!(
        s,
        "## Fig. ablation (a): NTG without each part, block stacking\n\n![ablation](ablation.png)\n"
    );
    if points.is_empty() {
        let _ = writeln!(s, "No run at this profile.\n");
        return s;
    }
    let _ = writeln!(
        s,
        "| variant | input | training tasks | demos/task | epochs (selected) | training time | test tasks | success (95% CI) | goals met |"
    );
    let _ = writeln!(s, "|---|---|---|---|---|---|---|---|---|");
    for p in points {
        let _ = writeln!(
            s,
            "| {} | {} | {} |",
            ntp_exp::curve_name(p.method, p.recipe, p.ablation),
            ntp_exp::scale_cells(p),
            ntp_exp::outcome_cells(p)
        );
    }
    let _ = writeln!(
        s,
        "\nEach variant is trained as the variant (the missing part's loss trains nothing; without the GCN the edge classifier learns on the GCN's task-independent initial node embeddings, the ones it gets when it acts) and selected on validation tasks like the whole model. Without the demo interpreter the task graph starts fully connected; without the node localizer or the edge classifier its term of the policy is a constant (uniform over nodes, over the node's successors). {recipe_note}\n\nThe paper's trend (its fig. 5(a), no numbers in the text), checked on these runs:\n"
    );
    for line in trend_checks(points) {
        let _ = writeln!(s, "- {line}");
    }
    let _ = writeln!(s);
    s
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::spec::Profile;

    #[test]
    fn the_built_in_file_trains_every_part_away_from_the_same_run() {
        let experiment = load(crate::experiment::Source::BuiltIn).unwrap();
        let ntp_exp = NtpExpExperiment::load(crate::experiment::Source::BuiltIn).unwrap();
        let panel = &experiment.profiles.get(Profile::Quick).panels[0];
        let runs = experiment.runs_of(panel);
        assert_eq!(runs.len(), 5);
        // The whole model is fig. ntp_exp's quick state point at 1000
        // tasks, in a folder of its own.
        let state = &ntp_exp.profiles.get(Profile::Quick).panels[1];
        let whole = (crate::method::MethodId::Ntg, Variant::Full);
        assert_eq!(
            experiment
                .run_config(Profile::Quick, panel, whole, 1000)
                .unwrap(),
            ntp_exp
                .run_config(Profile::Quick, state, whole, 1000)
                .unwrap()
        );
        assert_eq!(
            experiment.run_name(panel, whole, 1000),
            "ablation-state-1000"
        );
        for &(method, ablation) in &runs[1..] {
            let c = experiment
                .run_config(Profile::Quick, panel, (method, ablation), 1000)
                .unwrap();
            assert_eq!(c.ablation, ablation);
            assert_eq!(
                experiment.run_name(panel, (method, ablation), 1000),
                format!("ablation-state-{}-1000", ablation.name())
            );
        }
        // An evaluation setting is not a trained variant.
        let err = experiment
            .run_config(
                Profile::Quick,
                panel,
                (crate::method::MethodId::Ntg, Variant::ExecutedNode),
                1000,
            )
            .unwrap_err();
        assert!(format!("{err:#}").contains("ablations are NTG"), "{err:#}");
    }

    #[test]
    fn the_smoke_profile_trains_each_variant_and_the_report_checks_the_trend() {
        let dir = tempfile::tempdir().unwrap();
        let mut experiment = load(crate::experiment::Source::BuiltIn).unwrap();
        let panel = &mut experiment.profiles.smoke.panels[0];
        panel.train_tasks = vec![2];
        panel.epochs = 1;
        panel.test_tasks = 2;
        panel.ablations = Some(vec![Variant::Full, Variant::NoGcn]);
        let runs = dir.path().join("runs");
        let points = ntp_exp::run(&experiment, Profile::Smoke, &runs, 2).unwrap();
        assert_eq!(
            points.iter().map(|p| p.ablation).collect::<Vec<_>>(),
            vec![Variant::Full, Variant::NoGcn]
        );
        let no_gcn = &points[1];
        assert!(no_gcn.run.ends_with("ablation-state-no-gcn-2"));
        let saved: ntg_model::NtgConfig =
            crate::run_dir::RunDir::read_json(&no_gcn.run.join("checkpoint").join("config.json"))
                .unwrap();
        assert!(!saved.ablation.gcn, "the switch is saved with the model");
        let report = report_section(&points, "RECIPE");
        assert!(report.contains("NTG (ours) without the GCN"), "{report}");
        assert!(report.contains("The whole model is best: **"), "{report}");
        write_figure(&points, &dir.path().join("ablation")).unwrap();
        assert!(dir.path().join("ablation.svg").is_file());
    }
}
