//! The paper's qualitative figures, found automatically among a trained
//! NTG run's test rollouts (the rollouts `ntg eval` scores, replayed):
//! - block stacking ([`blocks_trace`]): one unseen task executed step by
//!   step, where the executor is at one node of the task graph twice and
//!   takes a different edge each time (the graph used as a reactive
//!   policy, not replayed as a sequence): the trace's contact sheet, its
//!   task graph and a table of its steps ([`crate::trace::trace_task`]);
//! - object sorting ([`sorting_trace`]): a part-sorted scene finished in
//!   another order than the demo's, through transitions the demo never
//!   made (edges the GCN added).

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use anyhow::Context;
use serde::{Deserialize, Serialize};

use crate::experiment::template::QUALITATIVE;
use crate::run_dir::RunDir;
use crate::trace::Trace;

/// The trace chosen for the figure.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct BlocksTraceFigure {
    /// The run that acted.
    pub run: PathBuf,
    /// Test tasks searched, from the first.
    pub searched: usize,
    /// The trace (its files are in the figure's folder).
    pub trace: Trace,
    /// The node visited twice or more.
    pub node: String,
    /// The steps at that node, with the action chosen at each.
    pub visits: Vec<(usize, String)>,
}

/// The first node (by first visit) that the executor localised at two or
/// more steps and left by different actions, with those steps.
pub fn revisited_node(trace: &Trace) -> Option<(String, Vec<(usize, String)>)> {
    let mut order: Vec<(String, Vec<(usize, String)>)> = Vec::new();
    for step in &trace.steps {
        let Some(node) = step.localized.first() else {
            continue;
        };
        let visit = (step.step, step.chosen.name.clone());
        match order.iter_mut().find(|(n, _)| *n == node.name) {
            Some((_, visits)) => visits.push(visit),
            None => order.push((node.name.clone(), vec![visit])),
        }
    }
    order.into_iter().find(|(_, visits)| {
        visits.len() >= 2 && visits.iter().any(|(_, action)| *action != visits[0].1)
    })
}

/// Replays the first `test_tasks` test tasks of the state-input NTG run
/// `run` until one succeeds with a revisited node ([`revisited_node`]) and
/// writes its contact sheet, task graph, demo and step table into `out`
/// (replacing the figure's earlier files). `None` when no task qualifies
/// (or the run is not a state-input NTG run, which `ntg trace` cannot
/// replay). Candidates are traced in `run`'s `qualitative/` folder.
pub fn blocks_trace(
    run: &Path,
    test_tasks: usize,
    out: &Path,
) -> anyhow::Result<Option<BlocksTraceFigure>> {
    let dir = RunDir::open(run)?;
    let config: crate::blocks::BlocksRunConfig = RunDir::read_json(&dir.config_path())?;
    let device = crate::spec::device();
    let crate::blocks::TrainedBlocks::State(model) =
        crate::blocks::load_trained(&dir, None, &device)?
    else {
        return Ok(None);
    };
    let scratch = run.join("qualitative");
    for index in 0..test_tasks {
        let candidate = scratch.join(format!("task-{index:04}"));
        if candidate.exists() {
            std::fs::remove_dir_all(&candidate)
                .with_context(|| format!("removing {}", candidate.display()))?;
        }
        let trace = crate::trace::trace_task(
            &model,
            config.task_source(),
            config.obs,
            config.failures,
            index,
            &candidate,
        )?;
        let found = trace.success.then(|| revisited_node(&trace)).flatten();
        let Some((node, visits)) = found else {
            std::fs::remove_dir_all(&candidate)
                .with_context(|| format!("removing {}", candidate.display()))?;
            continue;
        };
        std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
        for file in [
            "contact-sheet.png",
            "ctg.svg",
            "ctg.dot",
            "demo.txt",
            "trace.txt",
        ] {
            std::fs::copy(candidate.join(file), out.join(file))
                .with_context(|| format!("copying {file} into {}", out.display()))?;
        }
        return Ok(Some(BlocksTraceFigure {
            run: run.to_path_buf(),
            searched: index + 1,
            trace,
            node,
            visits,
        }));
    }
    Ok(None)
}

/// The sorting episode chosen for the figure.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SortingTraceFigure {
    /// The run that acted.
    pub run: PathBuf,
    /// The episode (its task names the objects presorted).
    pub episode: crate::domain::EpisodeRecord,
    /// Executed transitions `a -> b` that the demo's transcription never
    /// makes (edges only the completed graph has).
    pub new_transitions: Vec<(String, String)>,
}

/// The transitions of `actions` (with `<start>` first) that `path` (with
/// `<start>` first) does not make, in order, without repeats.
pub fn transitions_not_in(actions: &[String], path: &[String]) -> Vec<(String, String)> {
    fn pairs(xs: &[String]) -> Vec<(String, String)> {
        let start = "<start>".to_owned();
        std::iter::once(&start)
            .chain(xs)
            .zip(xs)
            .map(|(a, b)| (a.clone(), b.clone()))
            .collect()
    }
    let known = pairs(path);
    let mut new = Vec::new();
    for pair in pairs(actions) {
        if !known.contains(&pair) && !new.contains(&pair) {
            new.push(pair);
        }
    }
    new
}

/// Finds, among the first `episodes` test episodes of the sorting run
/// `run` (the ones its evaluation scores), the first that succeeds through
/// at least one transition between two different actions that its demo's
/// transcription never makes (another order than the demo's), replays it
/// with frames and writes its contact sheet and step table into `out`.
/// `None` when none qualifies.
pub fn sorting_trace(
    run: &Path,
    episodes: usize,
    out: &Path,
) -> anyhow::Result<Option<SortingTraceFigure>> {
    use crate::domain::sorting;
    let dir = RunDir::open(run)?;
    let config: sorting::SortingRunConfig = RunDir::read_json(&dir.config_path())?;
    let model = sorting::load_model(&dir, &crate::spec::device())?;
    let (_, _, test) = sorting::split()?;
    let all = sorting::episodes(&test, episodes, sorting::TEST_SEEDS);
    let domain = sorting::SortingDomain::rendering(config.failures, config.step_limit);
    let model = crate::method::TrainedPolicy::for_inference(&model);
    for episode in &all {
        let mut frames = Vec::new();
        let record = crate::domain::run_episode_observed(&domain, model.as_ref(), episode, |d| {
            frames.push(d.observation.frame().cloned());
            if d.step.is_done() {
                frames.push(d.step.observation.frame().cloned());
            }
            Ok(())
        })?;
        // The demo's path ends in `<end>`; a retry (`a -> a`) is a GCN edge
        // too, but not another order.
        let mut path = record.transcription.clone();
        path.push(ctg_graph::Vocabulary::END_NAME.to_owned());
        let new = transitions_not_in(&record.trace, &path);
        if !record.success || new.iter().all(|(a, b)| a == b) {
            continue;
        }
        let frames: Vec<image::RgbImage> = frames.into_iter().flatten().collect();
        let refs: Vec<&image::RgbImage> = frames.iter().collect();
        std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
        let sheet = env_blocks::sheet::contact_sheet(&refs, 8, 2, 4);
        let path = out.join("contact-sheet.png");
        sheet
            .save(&path)
            .with_context(|| format!("writing {}", path.display()))?;
        let mut table = format!(
            "task {} (test episode {}): success\ndemo (expert):     {}\ntranscribed (NTG): {}\n\nstep  action          transition\n",
            record.task,
            record.index,
            record.demo_actions.join(" "),
            record.transcription.join(" ")
        );
        let mut previous = "<start>".to_owned();
        for (step, action) in record.trace.iter().enumerate() {
            let pair = (previous.clone(), action.clone());
            let note = match new.contains(&pair) {
                true if pair.0 == pair.1 => "a retry the demo never makes (a GCN edge)",
                true => "another order than the demo's (a GCN edge)",
                false => "",
            };
            let _ = writeln!(table, "{step:>4}  {action:<15} {note}");
            previous = action.clone();
        }
        let path = out.join("trace.txt");
        std::fs::write(&path, &table).with_context(|| format!("writing {}", path.display()))?;
        return Ok(Some(SortingTraceFigure {
            run: run.to_path_buf(),
            episode: record,
            new_transitions: new,
        }));
    }
    Ok(None)
}

/// The report section of the qualitative sorting figure (Markdown);
/// `folder` is the figure's folder relative to the report.
pub fn sorting_report_section(figure: Option<&SortingTraceFigure>, folder: &str) -> String {
    let mut s = String::new();
    let _ = writeln!(s, "{}\n", QUALITATIVE.text("sorting_head"));
    let Some(f) = figure else {
        let _ = writeln!(s, "{}\n", QUALITATIVE.text("sorting_none"));
        return s;
    };
    let e = &f.episode;
    let transitions: Vec<String> = f
        .new_transitions
        .iter()
        .map(|(a, b)| format!("`{a} -> {b}`"))
        .collect();
    let run = f.run.file_name().unwrap_or_default().to_string_lossy();
    let text = QUALITATIVE.fill(
        "sorting",
        &[
            ("run", &run),
            ("episode", &e.index),
            ("task", &e.task),
            ("transitions", &f.new_transitions.len()),
            ("transition_list", &transitions.join(", ")),
            ("folder", &folder),
        ],
    );
    let _ = writeln!(s, "{text}\n");
    let sequences = QUALITATIVE.fill(
        "sorting_sequences",
        &[
            ("demo", &e.demo_actions.join(" ")),
            ("transcription", &e.transcription.join(" ")),
            ("executed", &e.trace.join(" ")),
        ],
    );
    let _ = writeln!(s, "{sequences}\n");
    s
}

/// The report section of the qualitative block-stacking figure
/// (Markdown); `folder` is the figure's folder relative to the report.
pub fn report_section(figure: Option<&BlocksTraceFigure>, folder: &str) -> String {
    let mut s = String::new();
    let _ = writeln!(s, "{}\n", QUALITATIVE.text("blocks_head"));
    let Some(f) = figure else {
        let _ = writeln!(s, "{}\n", QUALITATIVE.text("blocks_none"));
        return s;
    };
    let run = f.run.file_name().unwrap_or_default().to_string_lossy();
    let steps: Vec<String> = f.visits.iter().map(|(step, _)| step.to_string()).collect();
    let chosen: Vec<String> = f
        .visits
        .iter()
        .map(|(step, action)| format!("`{action}` (step {step})"))
        .collect();
    let text = QUALITATIVE.fill(
        "blocks",
        &[
            ("run", &run),
            ("task", &f.trace.task),
            ("index", &f.trace.index),
            ("searched", &f.searched),
            ("node", &f.node),
            ("steps", &steps.join(", ")),
            ("chosen", &chosen.join(", ")),
            ("folder", &folder),
        ],
    );
    let _ = writeln!(s, "{text}\n");
    let _ = writeln!(s, "```\n{}```\n", crate::trace::trace_table(&f.trace));
    s
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::trace::{Scored, TraceStep};

    fn step(step: usize, node: &str, chosen: &str) -> TraceStep {
        let scored = |name: &str| Scored {
            name: name.into(),
            p: 1.0,
        };
        TraceStep {
            step,
            localized: vec![scored(node)],
            edges_from_localized: Vec::new(),
            chosen: scored(chosen),
            failure: None,
            success_after: false,
        }
    }

    fn trace(steps: Vec<TraceStep>) -> Trace {
        Trace {
            index: 0,
            task: "t".into(),
            demo_actions: Vec::new(),
            transcription: Vec::new(),
            steps,
            success: true,
            truncated: false,
        }
    }

    #[test]
    fn a_node_left_twice_by_the_same_edge_is_not_a_revisit_with_another_edge() {
        let same = trace(vec![
            step(0, "a", "b"),
            step(1, "b", "a"),
            step(2, "a", "b"),
        ]);
        assert_eq!(revisited_node(&same), None);
        let other = trace(vec![
            step(0, "a", "b"),
            step(1, "b", "c"),
            step(2, "c", "b"),
            step(3, "b", "d"),
        ]);
        assert_eq!(
            revisited_node(&other),
            Some(("b".into(), vec![(1, "c".into()), (3, "d".into())]))
        );
    }

    #[test]
    fn transitions_the_demo_never_makes_are_found_once_in_order() {
        let v = |xs: &[&str]| xs.iter().map(|x| x.to_string()).collect::<Vec<_>>();
        let demo = v(&["a", "x", "b", "x", "c"]);
        assert!(transitions_not_in(&v(&["a", "x", "c"]), &demo).is_empty());
        assert_eq!(
            transitions_not_in(&v(&["b", "x", "a", "x", "b"]), &demo),
            vec![
                ("<start>".to_owned(), "b".to_owned()),
                ("x".to_owned(), "a".to_owned())
            ]
        );
    }
}
