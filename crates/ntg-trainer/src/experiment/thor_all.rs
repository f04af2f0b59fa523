//! Fig. "thor_all" (b): object collection, success on unseen tasks against
//! the number of target objects N, for NTG and the Flat Policy trained on
//! N = 2 and 4 only. The runs are listed in `experiments/thor_all.toml`.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use anyhow::{Context as _, bail, ensure};
use serde::{Deserialize, Serialize};

use crate::collect::{
    CollectRunConfig, EVAL_OBJECTS, InterpreterDefaults, InterpreterKind, NPoint, evaluate,
    train_run,
};
use crate::domain::DomainId;
use crate::experiment::Profiles;
use crate::experiment::template::THOR_ALL;
use crate::figure::{Dash, Panel, Point, Series, method_look, write_figure as draw};
use crate::method::MethodId;
use crate::run_dir::RunDir;
use crate::spec::{ObsKind, Profile};

/// The figure's experiment file (`experiments/thor_all.toml`).
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ThorAllExperiment {
    /// Always object collection.
    pub domain: DomainId,
    /// The methods compared, in legend order.
    pub methods: Vec<MethodId>,
    /// Numbers of target objects of the training tasks.
    pub train_objects: Vec<usize>,
    /// Seed of every run's weights and shuffling.
    pub seed: u64,
    /// Per method name, fields of its run configuration to set.
    #[serde(default)]
    pub overrides: BTreeMap<String, toml::Table>,
    /// The scale of each profile.
    pub profiles: Profiles<ThorAllScale>,
    /// Where the file was read from (for messages).
    #[serde(skip)]
    pub origin: String,
}

/// The scale of fig. "thor_all" under a profile (one table of the
/// experiment file, and part of `results.json`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ThorAllScale {
    /// Observation kind.
    pub obs: ObsKind,
    /// Training tasks per N (N = 2 and 4).
    pub tasks_per_n: usize,
    /// Demonstrations per training task.
    pub demos_per_task: usize,
    /// Whether both methods learn the final `<end>` decision (the paper's
    /// protocol: an episode ends when the policy says so, or at the step
    /// limit); otherwise episodes always run to the step limit.
    #[serde(default)]
    pub learn_end: bool,
    /// Whether both methods have the execution memory
    /// ([`CollectRunConfig::memory`]).
    #[serde(default)]
    pub memory: bool,
    /// NTG's training epochs (learning rate on a half cosine per step down
    /// to a tenth, [`crate::fit::OptimConfig::cosine_decay`]: at a constant rate Adam
    /// blew the converged interpreter up late in training).
    pub ntg_epochs: usize,
    /// The Flat Policy's training epochs (constant learning rate: with the
    /// cosine decay its attention never learned to retrieve the receptacle).
    pub flat_epochs: usize,
    /// Demonstrations per optimisation step.
    pub batch_size: usize,
    /// Adam learning rate.
    pub learning_rate: f64,
    /// Test episodes per N.
    pub test_episodes: usize,
    /// Seeds trained besides the experiment's `seed` (each method once
    /// per seed, in folders `thor_all-METHOD-seedS`).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub extra_seeds: Vec<u64>,
    /// With `memory`: also train both methods without it (folders
    /// `thor_all-METHOD-no-memory`, first seed only), since the two
    /// memories differ in form (NTG's reads its own task graph): the
    /// comparison without memory gives both exactly the same information.
    #[serde(default, skip_serializing_if = "is_false")]
    pub without_memory: bool,
    /// Validation tasks per training N (held-out train-side tasks, rolled
    /// out after every epoch; the best epoch is the one evaluated:
    /// `CollectRunConfig::validation_tasks_per_n`). Absent: 0, none.
    #[serde(default, skip_serializing_if = "no_tasks")]
    pub validation_tasks_per_n: usize,
    /// Numbers of objects validated on besides the training ones
    /// (`CollectRunConfig::validation_objects`: lengths no test episode
    /// has), both methods. Absent: none.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub validation_objects: Vec<usize>,
    /// The demo interpreter of the runs (NTG reads it; the others keep it
    /// in their configuration as `ntg train` writes it). Absent: the
    /// default for `obs` (`InterpreterKind::default_for`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub interpreter: Option<InterpreterKind>,
    /// On video: the demo videos stage A trains both methods' frame
    /// encoders on (`video.encoder.demos`). Absent: the run's default.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub encoder_demos: Option<usize>,
    /// Names this protocol's runs apart from an earlier protocol's: run
    /// folders `thor_all-TAG-METHOD…`. Absent: `thor_all-METHOD…`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub tag: Option<String>,
    /// The profile's earlier protocol, kept: its runs (their records
    /// restored, or trained where there are none) are reported in a table
    /// of their own beside this protocol's, and not drawn (but for its
    /// NTG line beside the current protocol's). It may keep an earlier one
    /// of its own, and so on back; every protocol's run folders must
    /// differ from the others' (a `tag` on each but one).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub earlier: Option<Box<ThorAllScale>>,
    /// What sets this protocol apart from the one after it, in words, where
    /// the report and the figure name it as an earlier protocol (e.g.
    /// "the paper's interpreter"). Absent: none.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub about: Option<String>,
}

fn no_tasks(n: &usize) -> bool {
    *n == 0
}

fn is_false(b: &bool) -> bool {
    !*b
}

fn yes() -> bool {
    true
}

/// `scale` and the earlier protocols it keeps, newest first: index `k` is
/// the protocol `k` back.
pub fn protocols(scale: &ThorAllScale) -> Vec<&ThorAllScale> {
    let mut chain = vec![scale];
    while let Some(earlier) = chain.last().and_then(|s| s.earlier.as_deref()) {
        chain.push(earlier);
    }
    chain
}

fn is_current(earlier: &u8) -> bool {
    *earlier == 0
}

/// [`ThorAllLine::earlier`]: a number of protocols back, or (results
/// written before there could be more than one) `true` for one back.
fn protocol_back<'de, D: serde::Deserializer<'de>>(d: D) -> Result<u8, D::Error> {
    #[derive(Deserialize)]
    #[serde(untagged)]
    enum Back {
        Flag(bool),
        Count(u8),
    }
    Ok(match Back::deserialize(d)? {
        Back::Flag(b) => u8::from(b),
        Back::Count(n) => n,
    })
}

/// One run of the figure: a method, a seed, and whether it has the
/// execution memory.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ThorAllRun {
    /// The method.
    pub method: MethodId,
    /// Seed of its weights and shuffling.
    pub seed: u64,
    /// Whether it has the execution memory.
    pub memory: bool,
    /// Which protocol: 0 the profile's current one, 1 its earlier one
    /// ([`ThorAllScale::earlier`]), 2 that one's earlier one, and so on.
    pub earlier: u8,
}

/// One method's line of fig. "thor_all".
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ThorAllLine {
    /// Which method.
    pub method: MethodId,
    /// Seed of the run's weights and shuffling (results written before
    /// seeds: 0).
    #[serde(default, skip_serializing_if = "is_zero")]
    pub seed: u64,
    /// Whether the run has the execution memory when the profile gives it
    /// one (results written before the variant without: yes).
    #[serde(default = "yes", skip_serializing_if = "Clone::clone")]
    pub memory: bool,
    /// Which protocol ([`ThorAllRun::earlier`]): 0 the current one; an
    /// earlier one's are reported apart, not drawn. Results written when
    /// the profile kept one earlier protocol say `true` for it.
    #[serde(
        default,
        skip_serializing_if = "is_current",
        deserialize_with = "protocol_back"
    )]
    pub earlier: u8,
    /// Success per N on unseen tasks.
    pub points: Vec<NPoint>,
    /// The epoch (from 0) that scored best on the validation tasks and was
    /// evaluated; absent when the run did not validate (the last epoch).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub selected_epoch: Option<usize>,
    /// Core-seconds of training epochs
    /// ([`crate::run_dir::RunDir::epoch_compute_seconds`]: CPU time where
    /// recorded, else wall time; from the run's metrics, so a reused run
    /// reports its original cost).
    pub train_seconds: f64,
    /// Run folder.
    pub run: PathBuf,
    /// Methods with a demo interpreter: per N (as `points`), the test
    /// demos it transcribed exactly, of those it transcribed (`(exact,
    /// of)`); empty for the others and in results written before it.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub transcribed: Vec<(usize, usize)>,
    /// A reduced profile: success per N (as `points`) on the same test
    /// episodes with the run's initial weights, the value each point must
    /// beat to show learning (see `ntp_exp::NtpExpPoint::untrained`);
    /// empty at the paper profile and where the run kept none.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub untrained: Vec<NPoint>,
}

/// Per point of `eval`, the episodes whose demo was transcribed exactly,
/// of those with a transcription; empty when no episode has one.
fn transcribed_per_n(eval: &crate::collect::CollectEval) -> Vec<(usize, usize)> {
    let per_n: Vec<(usize, usize)> = eval
        .points
        .iter()
        .map(|p| {
            let exact: Vec<bool> = eval
                .episodes
                .iter()
                .filter(|e| e.group == p.objects)
                .filter_map(|e| e.transcription_exact())
                .collect();
            (exact.iter().filter(|&&x| x).count(), exact.len())
        })
        .collect();
    if per_n.iter().all(|&(_, of)| of == 0) {
        return Vec::new();
    }
    per_n
}

fn is_zero(seed: &u64) -> bool {
    *seed == 0
}

/// Fig. "thor_all" (b) as measured (`results.json`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ThorAllResult {
    /// The scale.
    pub scale: ThorAllScale,
    /// Numbers of objects trained on.
    pub train_objects: Vec<usize>,
    /// NTG and the Flat Policy.
    pub lines: Vec<ThorAllLine>,
}

impl ThorAllExperiment {
    /// Reads `thor_all.toml` from `source`.
    pub fn load(source: crate::experiment::Source<'_>) -> anyhow::Result<Self> {
        let (mut experiment, origin): (Self, String) = crate::experiment::load("thor_all", source)?;
        experiment.origin = origin;
        for profile in [Profile::Smoke, Profile::Quick, Profile::Paper] {
            let scale = experiment.profiles.get(profile);
            let chain = protocols(scale);
            for s in &chain {
                if let Some(tag) = &s.tag {
                    ensure!(
                        !tag.is_empty()
                            && tag
                                .chars()
                                .all(|c| c.is_ascii_lowercase() || c.is_ascii_digit()),
                        "{}: profile {}: tag {tag:?} must be lowercase letters and digits",
                        experiment.origin,
                        profile.name()
                    );
                }
            }
            for (i, a) in chain.iter().enumerate() {
                ensure!(
                    chain[..i].iter().all(|b| b.tag != a.tag),
                    "{}: profile {}: each earlier protocol needs another tag than the protocols after it (their runs would share folders)",
                    experiment.origin,
                    profile.name()
                );
            }
            ensure!(
                chain.len() <= usize::from(u8::MAX),
                "{}: profile {}: too many earlier protocols",
                experiment.origin,
                profile.name()
            );
        }
        Ok(experiment)
    }

    /// The seeds of `profile`'s runs: the experiment's, then the extra.
    pub fn seeds(&self, profile: Profile) -> Vec<u64> {
        let mut seeds = vec![self.seed];
        seeds.extend_from_slice(&self.profiles.get(profile).extra_seeds);
        seeds
    }

    /// The scale of `profile`'s protocol `earlier` back (0: the current).
    pub fn scale(&self, profile: Profile, earlier: u8) -> anyhow::Result<&ThorAllScale> {
        protocols(self.profiles.get(profile))
            .get(usize::from(earlier))
            .copied()
            .with_context(|| {
                format!(
                    "{}: profile {} has no protocol {earlier} back",
                    self.origin,
                    profile.name()
                )
            })
    }

    /// Every run of `profile`: each method for each seed, then, with
    /// `without_memory`, each method without memory (first seed); then the
    /// same for each earlier protocol it keeps, newest first.
    pub fn runs(&self, profile: Profile) -> Vec<ThorAllRun> {
        let current = self.profiles.get(profile);
        let mut runs = Vec::new();
        for (earlier, scale) in protocols(current).into_iter().enumerate() {
            let earlier = u8::try_from(earlier).unwrap_or(u8::MAX);
            let mut seeds = vec![self.seed];
            seeds.extend_from_slice(&scale.extra_seeds);
            for seed in seeds {
                runs.extend(self.methods.iter().map(|&method| ThorAllRun {
                    method,
                    seed,
                    memory: true,
                    earlier,
                }));
            }
            if scale.memory && scale.without_memory {
                runs.extend(self.methods.iter().map(|&method| ThorAllRun {
                    method,
                    seed: self.seed,
                    memory: false,
                    earlier,
                }));
            }
        }
        runs
    }

    /// The run folder name of `run` at `profile`.
    pub fn run_name(&self, profile: Profile, run: ThorAllRun) -> String {
        let tag = self
            .scale(profile, run.earlier)
            .ok()
            .and_then(|s| s.tag.as_deref());
        let mut base = match tag {
            Some(tag) => format!("thor_all-{tag}-{}", run.method.name()),
            None => format!("thor_all-{}", run.method.name()),
        };
        if !run.memory {
            base.push_str("-no-memory");
        }
        crate::experiment::seeded_name(base, run.seed, self.seed)
    }

    /// The run configuration of `run` at `profile`.
    pub fn run_config(
        &self,
        profile: Profile,
        run: ThorAllRun,
    ) -> anyhow::Result<CollectRunConfig> {
        let ThorAllRun {
            method,
            seed,
            memory,
            earlier,
        } = run;
        ensure!(
            self.domain == DomainId::Collect,
            "{}: thor_all trains on object collection (domain = \"collect\")",
            self.origin
        );
        let scale = self.scale(profile, earlier)?;
        let epochs = match method {
            MethodId::Ntg => scale.ntg_epochs,
            MethodId::Flat => scale.flat_epochs,
            other => bail!(
                "{}: thor_all compares ntg and flat, not {}",
                self.origin,
                other.name()
            ),
        };
        let mut config = CollectRunConfig::new(
            method,
            scale.obs,
            self.train_objects.clone(),
            scale.tasks_per_n,
            scale.demos_per_task,
            epochs,
            seed,
        );
        config.learn_end = scale.learn_end;
        config.memory = scale.memory && memory;
        config.optim.batch_size = scale.batch_size;
        config.optim.learning_rate = scale.learning_rate;
        config.validation_tasks_per_n = scale.validation_tasks_per_n;
        config.validation_objects = scale.validation_objects.clone();
        if let Some(interpreter) = scale.interpreter {
            config.interpreter = interpreter;
            config.location_step_prior = crate::collect::default_step_prior(method, interpreter);
        }
        if let Some(demos) = scale.encoder_demos {
            let video = config.video.as_mut().with_context(|| {
                format!(
                    "{}: profile {}: encoder_demos sets stage A of runs on frames; this profile's obs is {:?}",
                    self.origin,
                    profile.name(),
                    scale.obs
                )
            })?;
            video.encoder.demos = demos;
        }
        let overrides = self
            .overrides
            .get(method.name())
            .cloned()
            .unwrap_or_default();
        crate::experiment::with_overrides(&config, &overrides, &self.origin)
    }
}

/// Runs fig. "thor_all" at `profile`: trains every method of the
/// experiment (or those whose run folders `only` names; finished runs
/// under `runs` are reused, interrupted ones resumed), `jobs` at a time,
/// and evaluates them on unseen tasks with N = 1..5.
pub fn run(
    experiment: &ThorAllExperiment,
    profile: Profile,
    plan: &crate::experiment::Plan<'_>,
) -> anyhow::Result<ThorAllResult> {
    let scale = experiment.profiles.get(profile).clone();
    let line = |variant: ThorAllRun| -> anyhow::Result<Option<ThorAllLine>> {
        let ThorAllRun { method, seed, .. } = variant;
        let scale = experiment.scale(profile, variant.earlier)?;
        let config = experiment.run_config(profile, variant)?;
        let name = experiment.run_name(profile, variant);
        let eval_file = format!("collect-{}.json", scale.test_episodes);
        let Some(dir) = plan.prepare(&name, &config, &eval_file)? else {
            return Ok(None);
        };
        let run = RunDir::open_or_create(&dir, &config)?;
        // One writer for the whole run: the stages it shares in, training,
        // evaluation and its record.
        let _writer = run.lock()?;
        if let Some(video) = &config.video {
            share_videos(
                experiment, profile, variant, plan.runs, &run, &config, video,
            )?;
        }
        eprintln!(
            "thor_all ({}): training -> {}",
            method.name(),
            dir.display()
        );
        let device = crate::spec::device().autodiff();
        let eval = run.cached_eval(&eval_file, || {
            let model = train_run(&run, &config, &device, |line| {
                eprintln!("  [{name}] {line}")
            })?;
            evaluate(model.as_ref(), &config, &EVAL_OBJECTS, scale.test_episodes)
        })?;
        // A reduced profile shows that the run learned: the same episodes
        // at its initial weights.
        let untrained = super::untrained_eval(&run, profile, &eval_file, || {
            let model = config
                .method
                .load(&run.initial_dir(), &device)
                .with_context(|| format!("loading the untrained model of {}", dir.display()))?;
            evaluate(model.as_ref(), &config, &EVAL_OBJECTS, scale.test_episodes)
        })?
        .map_or_else(Vec::new, |eval| eval.points);
        plan.finish(&dir)?;
        for p in &eval.points {
            eprintln!(
                "  [{name}] N = {}: success {:.3} ({:.3}-{:.3})",
                p.objects, p.success.rate, p.success.ci_low, p.success.ci_high
            );
        }
        let transcribed = transcribed_per_n(&eval);
        Ok(Some(ThorAllLine {
            method,
            seed,
            memory: variant.memory,
            earlier: variant.earlier,
            points: eval.points,
            selected_epoch: crate::fit::selected_epoch(&run)?.map(|r| r.epoch),
            train_seconds: run.epoch_compute_seconds()?,
            run: dir,
            transcribed,
            untrained,
        }))
    };
    let line = &line;
    // On video the first run of each seed trains stage A; the others of
    // that seed start after it and link its encoder and embeddings. Where
    // this invocation does not run that first one (`--only` leaves it
    // out: finished, or not asked for), nothing here is waited for.
    let (mut first, mut after) = (Vec::new(), Vec::new());
    for run in experiment.runs(profile) {
        let on_video = experiment.scale(profile, run.earlier)?.obs == ObsKind::Vid;
        let wave = if on_video
            && first.iter().any(|r: &ThorAllRun| {
                (r.seed, r.earlier) == (run.seed, run.earlier)
                    && plan.selected(&experiment.run_name(profile, *r))
            }) {
            &mut after
        } else {
            &mut first
        };
        wave.push(run);
    }
    let mut lines = Vec::new();
    for wave in [first, after] {
        let jobs = wave
            .into_iter()
            .filter(|&run| plan.selected(&experiment.run_name(profile, run)))
            .map(|run| {
                Box::new(move || line(run)) as crate::experiment::Job<'_, Option<ThorAllLine>>
            })
            .collect();
        lines.extend(
            crate::experiment::in_parallel("thor_all", &plan.slots, jobs)?
                .into_iter()
                .flatten(),
        );
    }
    lines.sort_by_key(|l: &ThorAllLine| {
        experiment.runs(profile).iter().position(|r| {
            (r.method, r.seed, r.memory, r.earlier) == (l.method, l.seed, l.memory, l.earlier)
        })
    });
    Ok(ThorAllResult {
        scale,
        train_objects: experiment.train_objects.clone(),
        lines,
    })
}

/// Links the stage A encoder and the frame embeddings of another run of
/// the figure with the same seed into `run`, where that run finished them
/// and records the same videos ([`CollectRunConfig::same_videos`]): NTG
/// and the Flat Policy, with or without memory, read the same videos
/// through the same encoder, so they are computed once per seed.
fn share_videos(
    experiment: &ThorAllExperiment,
    profile: Profile,
    variant: ThorAllRun,
    runs: &Path,
    run: &RunDir,
    config: &CollectRunConfig,
    video: &crate::collect::CollectVideo,
) -> anyhow::Result<()> {
    use crate::experiment::share_part;
    let same = |theirs: &CollectRunConfig| config.same_videos(theirs);
    for other in experiment.runs(profile) {
        if other == variant || (other.seed, other.earlier) != (variant.seed, variant.earlier) {
            continue;
        }
        let source = runs.join(experiment.run_name(profile, other));
        let linked = share_part(
            (&source, crate::video::STAGE_A_DIR),
            run,
            |stage_a| crate::video::stage_a_finished(stage_a, &video.encoder),
            same,
            "stage A: the frame encoder",
        )?;
        if linked {
            share_part(
                (&source, crate::video::EMBEDDINGS_DIR),
                run,
                |embeddings| Ok(embeddings.join("index.json").is_file()),
                same,
                "the frames' embeddings",
            )?;
            return Ok(());
        }
    }
    Ok(())
}

/// Writes the figure (one panel, success vs N) as `stem.svg` and
/// `stem.png`: one line per method (and memory setting: the variant
/// without is dashed), the mean over its seeds, with a band from the
/// lowest seed's interval end to the highest's (one seed: its interval).
/// While the current protocol has no line the earlier one's are drawn (the
/// title says so); else the current ones, and the earlier protocol's NTG
/// with memory dotted, for comparison.
pub fn write_figure(result: &ThorAllResult, stem: &Path) -> anyhow::Result<()> {
    // The newest protocol with a line is drawn; beside the current one,
    // the NTG of the protocol just before it.
    let shown = result.lines.iter().map(|l| l.earlier).min().unwrap_or(0);
    let mut kinds: Vec<(MethodId, bool, u8)> = Vec::new();
    for l in result.lines.iter().filter(|l| l.earlier == shown) {
        if !kinds.contains(&(l.method, l.memory, l.earlier)) {
            kinds.push((l.method, l.memory, l.earlier));
        }
    }
    if shown == 0
        && result
            .lines
            .iter()
            .any(|l| l.earlier == 1 && l.method == MethodId::Ntg && l.memory)
    {
        kinds.push((MethodId::Ntg, true, 1));
    }
    let chain = protocols(&result.scale);
    let series = kinds
        .into_iter()
        .map(|(method, memory, of_earlier)| {
            let seeds: Vec<&ThorAllLine> = result
                .lines
                .iter()
                .filter(|l| l.earlier == of_earlier && l.method == method && l.memory == memory)
                .collect();
            let mut objects: Vec<usize> = seeds
                .iter()
                .flat_map(|l| l.points.iter().map(|p| p.objects))
                .collect();
            objects.sort_unstable();
            objects.dedup();
            let points = objects
                .into_iter()
                .map(|n| {
                    let rates: Vec<&crate::stats::SuccessRate> = seeds
                        .iter()
                        .filter_map(|l| l.points.iter().find(|p| p.objects == n))
                        .map(|p| &p.success)
                        .collect();
                    match rates.as_slice() {
                        [one] => Point::success(n as f64, one),
                        many => Point {
                            x: n as f64,
                            y: many.iter().map(|r| r.rate).sum::<f64>() / many.len() as f64,
                            lo: many.iter().map(|r| r.ci_low).fold(1.0, f64::min),
                            hi: many.iter().map(|r| r.ci_high).fold(0.0, f64::max),
                        },
                    }
                })
                .collect();
            let mut name = method.legend().to_owned();
            if seeds.len() > 1 {
                name.push_str(&format!(", mean of {} seeds", seeds.len()));
            }
            if !memory {
                name.push_str(", no memory");
            }
            let dash = if of_earlier != shown {
                name.push_str(&earlier_name(&chain, of_earlier));
                Dash::Dotted
            } else if memory {
                Dash::Solid
            } else {
                Dash::Dashed
            };
            Series {
                name,
                points,
                look: Some(method_look(method.legend(), dash)),
            }
        })
        .collect();
    let panel = Panel {
        title: format!(
            "(b) object collection, {} input{}",
            obs_name(result.scale.obs),
            if shown > 0 { " (earlier protocol)" } else { "" }
        ),
        x_label: "number of target objects N".into(),
        y_label: "success on unseen tasks".into(),
        x_log: false,
        x_ticks_at_points: true,
        y_range: (0.0, 1.0),
        series,
    };
    draw(&[panel], stem)
}

fn obs_name(obs: ObsKind) -> &'static str {
    match obs {
        ObsKind::State => "symbolic state",
        ObsKind::Vid => "64×64 frame",
    }
}

/// The protocol sentence of the report: how episodes end and what the
/// policies remember.
fn protocol(sc: &ThorAllScale) -> String {
    THOR_ALL.text(match (sc.learn_end, sc.memory) {
        (true, true) => "protocol_memory",
        (true, false) => "protocol_reactive",
        (false, _) => "protocol_end_not_learned",
    })
}

/// "seed 0", or "seeds 0, 1, 2": the seeds the figure's lines were trained
/// with (each line names its own where there are several).
fn seeds_phrase(lines: &[&ThorAllLine]) -> String {
    let mut seeds: Vec<u64> = lines.iter().map(|l| l.seed).collect();
    seeds.sort_unstable();
    seeds.dedup();
    let list: Vec<String> = seeds.iter().map(u64::to_string).collect();
    match list.len() {
        0 | 1 => format!("seed {}", list.first().map_or("0", String::as_str)),
        _ => format!("seeds {}", list.join(", ")),
    }
}

/// The report section of fig. "thor_all" (Markdown): the current
/// protocol's lines, then the earlier protocol's, if the profile keeps one.
pub fn report_section(result: &ThorAllResult) -> String {
    use std::fmt::Write as _;
    let sc = &result.scale;
    let of = |earlier: u8| -> Vec<&ThorAllLine> {
        result
            .lines
            .iter()
            .filter(|l| l.earlier == earlier)
            .collect()
    };
    let current = of(0);
    let mut s = match super::open_section(&THOR_ALL.text("head"), !result.lines.is_empty()) {
        Ok(head) => head,
        Err(whole) => return whole,
    };
    if current.is_empty() {
        let _ = writeln!(s, "{}", THOR_ALL.text("current_not_trained"));
    } else {
        protocol_tables(&mut s, sc, &result.train_objects, &current);
    }
    let _ = writeln!(s, "\n{}\n", THOR_ALL.text("trend"));
    if let Some(c) = compare(&current, true) {
        let _ = writeln!(s, "{}\n", THOR_ALL.fill("measured", &[("comparison", &c)]));
    }
    if let Some(without) = compare(&current, false) {
        let without = THOR_ALL.fill("without_memory", &[("comparison", &without)]);
        let _ = writeln!(s, "{without}\n");
    }
    for (back, old) in protocols(sc).into_iter().enumerate().skip(1) {
        let earlier = of(u8::try_from(back).unwrap_or(u8::MAX));
        if earlier.is_empty() {
            continue;
        }
        let about = old
            .about
            .as_deref()
            .map(|a| format!(" ({a})"))
            .unwrap_or_default();
        let _ = writeln!(
            s,
            "{}\n",
            THOR_ALL.fill("earlier_title", &[("about", &about)])
        );
        protocol_tables(&mut s, old, &result.train_objects, &earlier);
        if let Some(c) = compare(&earlier, true) {
            let _ = writeln!(
                s,
                "\n{}\n",
                THOR_ALL.fill("measured", &[("comparison", &c)])
            );
        }
        if let Some(without) = compare(&earlier, false) {
            let without = THOR_ALL.fill("without_memory", &[("comparison", &without)]);
            let _ = writeln!(s, "{without}\n");
        }
    }
    s
}

/// What a legend adds for a line of the protocol `back` protocols before
/// the current one in `chain` ([`protocols`]): ", earlier protocol", and
/// the protocol's words where it has them.
fn earlier_name(chain: &[&ThorAllScale], back: u8) -> String {
    match chain
        .get(usize::from(back))
        .and_then(|s| s.about.as_deref())
    {
        Some(about) => format!(", earlier protocol ({about})"),
        None => ", earlier protocol".to_owned(),
    }
}

/// The interpreter phrase of the report's setup for NTG runs of `sc`.
fn interpreter_phrase(sc: &ThorAllScale) -> String {
    let interpreter = sc
        .interpreter
        .unwrap_or_else(|| InterpreterKind::default_for(sc.obs));
    THOR_ALL.text(match (sc.obs, interpreter) {
        (_, InterpreterKind::SteppingVideo) => "interpreter_stepping_video",
        (ObsKind::State, _) => "interpreter_state",
        (ObsKind::Vid, _) => "interpreter_vid",
    })
}

/// One protocol's setup, selection, results table, transcriptions and
/// learning check, for its `lines`.
fn protocol_tables(
    s: &mut String,
    sc: &ThorAllScale,
    train_objects: &[usize],
    lines: &[&ThorAllLine],
) {
    use std::fmt::Write as _;
    let state_input = match (sc.obs, sc.encoder_demos) {
        (ObsKind::State, _) => format!(", {}", THOR_ALL.text("state_input")),
        (ObsKind::Vid, Some(videos)) => format!(
            ", {}",
            THOR_ALL.fill("stage_a_videos", &[("videos", &videos)])
        ),
        (ObsKind::Vid, None) => String::new(),
    };
    let setup = THOR_ALL.fill(
        "setup",
        &[
            ("obs", &obs_name(sc.obs)),
            ("state_input", &state_input),
            ("train_objects", &format!("{train_objects:?}")),
            ("tasks_per_n", &sc.tasks_per_n),
            ("demos", &sc.demos_per_task),
            ("batch", &sc.batch_size),
            ("learning_rate", &sc.learning_rate),
            ("ntg_epochs", &sc.ntg_epochs),
            ("flat_epochs", &sc.flat_epochs),
            ("seeds", &seeds_phrase(lines)),
            ("test_episodes", &sc.test_episodes),
            ("protocol", &protocol(sc)),
            ("interpreter", &interpreter_phrase(sc)),
        ],
    );
    let _ = writeln!(s, "{setup}\n");
    let validated = sc.validation_tasks_per_n > 0;
    if validated {
        let tasks = sc.validation_tasks_per_n;
        let _ = writeln!(
            s,
            "{}\n",
            THOR_ALL.fill("selection", &[("validation_tasks", &tasks)])
        );
        if !sc.validation_objects.is_empty() {
            let longer: Vec<String> = sc.validation_objects.iter().map(usize::to_string).collect();
            let _ = writeln!(
                s,
                "{}\n",
                THOR_ALL.fill(
                    "selection_longer",
                    &[
                        ("validation_tasks", &tasks),
                        ("objects", &longer.join(", "))
                    ]
                )
            );
        }
    }
    let _ = write!(s, "| method | training time |");
    if validated {
        let _ = write!(s, " epoch |");
    }
    for n in EVAL_OBJECTS {
        let _ = write!(s, " N = {n} |");
    }
    let _ = writeln!(s);
    let _ = writeln!(
        s,
        "|---|---|{}{}",
        if validated { "---|" } else { "" },
        "---|".repeat(EVAL_OBJECTS.len())
    );
    for line in lines {
        let _ = write!(s, "| {} | {:.0} s |", line_name(line), line.train_seconds);
        if validated {
            match line.selected_epoch {
                Some(e) => {
                    let _ = write!(s, " {} |", e + 1);
                }
                None => {
                    let _ = write!(s, " last |");
                }
            }
        }
        for p in &line.points {
            let _ = write!(
                s,
                " {}/{} = {:.3} ({:.3}–{:.3}){} |",
                p.success.successes,
                p.success.trials,
                p.success.rate,
                p.success.ci_low,
                p.success.ci_high,
                if sc.learn_end {
                    format!("; {} ended by `<end>`", p.ended)
                } else {
                    String::new()
                }
            );
        }
        let _ = writeln!(s);
    }
    let transcribing: Vec<&&ThorAllLine> =
        lines.iter().filter(|l| !l.transcribed.is_empty()).collect();
    if !transcribing.is_empty() {
        let _ = writeln!(s, "\n{}\n", THOR_ALL.text("transcription_title"));
        for line in transcribing {
            let per_n: Vec<String> = line
                .points
                .iter()
                .zip(&line.transcribed)
                .map(|(p, &(exact, of))| format!("N = {}: {exact}/{of}", p.objects))
                .collect();
            let _ = writeln!(s, "- {}: {}", line_name(line), per_n.join(", "));
        }
    }
    let learning: Vec<String> = lines
        .iter()
        .filter(|l| !l.untrained.is_empty())
        .map(|line| {
            let per_n: Vec<String> = line
                .points
                .iter()
                .zip(&line.untrained)
                .map(|(p, u)| {
                    let verdict = super::learning_verdict(&p.success, &u.success);
                    format!(
                        "N = {}: {:.3} against {:.3}, {verdict}",
                        p.objects, p.success.rate, u.success.rate
                    )
                })
                .collect();
            format!("- {}: {}", line_name(line), per_n.join("; "))
        })
        .collect();
    if !learning.is_empty() {
        let _ = writeln!(s, "\n{}\n", THOR_ALL.text("learning_title"));
        for l in learning {
            let _ = writeln!(s, "{l}");
        }
    }
}

/// A line's legend: the method's, with its seed if not 0, and "no memory"
/// for the variant without.
fn line_name(line: &ThorAllLine) -> String {
    let mut name = line.method.legend().to_owned();
    if line.seed != 0 {
        name.push_str(&format!(", seed {}", line.seed));
    }
    if !line.memory {
        name.push_str(", no memory");
    }
    name
}

/// How NTG's success compares with the Flat Policy's at each N, over every
/// seed trained: above with every seed's 95% interval above every seed's
/// of the other (one seed each: disjoint intervals), above in mean success
/// within overlapping intervals, tied, or below. `None` when a method is
/// missing.
/// The current protocol's lines only.
pub fn comparison_sentence(result: &ThorAllResult) -> Option<String> {
    let current: Vec<&ThorAllLine> = result.lines.iter().filter(|l| l.earlier == 0).collect();
    compare(&current, true).map(|c| THOR_ALL.fill("measured", &[("comparison", &c)]))
}

/// [`comparison_sentence`]'s comparison (without "Measured"), of `lines`
/// with or without the execution memory.
fn compare(lines_of: &[&ThorAllLine], memory: bool) -> Option<String> {
    let lines = |m: MethodId| -> Vec<&ThorAllLine> {
        lines_of
            .iter()
            .copied()
            .filter(|l| l.method == m && l.memory == memory)
            .collect()
    };
    let (ntg, flat) = (lines(MethodId::Ntg), lines(MethodId::Flat));
    let (first_ntg, _) = (ntg.first()?, flat.first()?);
    let at = |lines: &[&ThorAllLine], n: usize| -> Vec<crate::stats::SuccessRate> {
        lines
            .iter()
            .filter_map(|l| l.points.iter().find(|p| p.objects == n))
            .map(|p| p.success)
            .collect()
    };
    let mut groups: [(&str, Vec<usize>); 4] = [
        ("above, with disjoint 95% intervals", Vec::new()),
        ("above, within overlapping intervals", Vec::new()),
        ("tied", Vec::new()),
        ("below", Vec::new()),
    ];
    for p in &first_ntg.points {
        let (a, b) = (at(&ntg, p.objects), at(&flat, p.objects));
        if b.is_empty() {
            continue;
        }
        let (mean_a, mean_b) = (crate::stats::mean_rate(&a), crate::stats::mean_rate(&b));
        let (low_a, high_b) = (
            crate::stats::interval_span(&a).0,
            crate::stats::interval_span(&b).1,
        );
        let group = if mean_a > mean_b && low_a > high_b {
            0
        } else if mean_a > mean_b {
            1
        } else if mean_a == mean_b {
            2
        } else {
            3
        };
        groups[group].1.push(p.objects);
    }
    let parts: Vec<String> = groups
        .iter()
        .filter(|(_, ns)| !ns.is_empty())
        .map(|(what, ns)| {
            let ns: Vec<String> = ns.iter().map(usize::to_string).collect();
            format!("{what} at N = {}", ns.join(", "))
        })
        .collect();
    Some(format!("NTG's success is {}", parts.join("; ")))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::stats::SuccessRate;

    fn line(method: MethodId, successes: &[usize], trials: usize) -> ThorAllLine {
        ThorAllLine {
            method,
            seed: 0,
            memory: true,
            earlier: 0,
            points: successes
                .iter()
                .enumerate()
                .map(|(i, &k)| NPoint {
                    objects: i + 1,
                    success: SuccessRate::new(k, trials),
                    ended: 0,
                })
                .collect(),
            selected_epoch: None,
            train_seconds: 0.0,
            run: PathBuf::new(),
            transcribed: Vec::new(),
            untrained: Vec::new(),
        }
    }

    /// The report gives, per N, how many test demos NTG's interpreter
    /// transcribed exactly; the Flat Policy has no line.
    #[test]
    fn the_report_shows_the_interpreter_s_exact_transcriptions_per_n() {
        let experiment = ThorAllExperiment::load(crate::experiment::Source::BuiltIn).unwrap();
        let mut ntg = line(MethodId::Ntg, &[9, 9, 8, 7, 2], 10);
        ntg.transcribed = vec![(10, 10), (9, 10), (9, 10), (10, 10), (2, 10)];
        let result = ThorAllResult {
            scale: experiment.profiles.get(Profile::Smoke).clone(),
            train_objects: vec![2, 4],
            lines: vec![ntg, line(MethodId::Flat, &[9, 5, 3, 2, 1], 10)],
        };
        let report = report_section(&result);
        assert!(
            report.contains(
                "- NTG (ours): N = 1: 10/10, N = 2: 9/10, N = 3: 9/10, N = 4: 10/10, N = 5: 2/10"
            ),
            "{report}"
        );
        assert!(!report.contains("- Flat Policy: N = 1"), "{report}");
        assert!(report.contains("trained well), seed 0. Tested"), "{report}");
        // With more seeds the protocol names them all.
        let mut seeded = result.clone();
        for seed in [2, 1] {
            let mut more = line(MethodId::Flat, &[9, 5, 3, 2, 1], 10);
            more.seed = seed;
            seeded.lines.push(more);
        }
        let report = report_section(&seeded);
        assert!(
            report.contains("trained well), seeds 0, 1, 2. Tested"),
            "{report}"
        );
    }

    #[test]
    fn the_paper_profile_trains_each_method_with_three_seeds() {
        let experiment = ThorAllExperiment::load(Default::default()).unwrap();
        assert_eq!(experiment.seeds(Profile::Quick), vec![0]);
        assert_eq!(experiment.seeds(Profile::Paper), vec![0, 1, 2]);
        let run = |method, seed, memory, earlier| ThorAllRun {
            method,
            seed,
            memory,
            earlier,
        };
        let paper = Profile::Paper;
        assert_eq!(
            experiment.run_name(paper, run(MethodId::Ntg, 0, true, 0)),
            "thor_all-a4k-ntg"
        );
        assert_eq!(
            experiment.run_name(paper, run(MethodId::Flat, 2, true, 0)),
            "thor_all-a4k-flat-seed2"
        );
        // The earlier protocols keep their folders, so their records still
        // belong to their runs.
        assert_eq!(
            experiment.run_name(paper, run(MethodId::Ntg, 0, true, 1)),
            "thor_all-len-ntg"
        );
        assert_eq!(
            experiment.run_name(paper, run(MethodId::Ntg, 0, true, 2)),
            "thor_all-ntg"
        );
        assert_eq!(
            experiment.run_name(Profile::Quick, run(MethodId::Ntg, 0, true, 0)),
            "thor_all-ntg"
        );
        let c = experiment
            .run_config(paper, run(MethodId::Ntg, 2, true, 0))
            .unwrap();
        assert_eq!((c.model_seed, c.optim.seed), (2, 2));
        // Both methods once more without the memory, first seed; then the
        // same eight runs of each earlier protocol.
        let runs = experiment.runs(paper);
        assert_eq!(runs.len(), 24);
        assert_eq!(
            experiment.run_name(paper, runs[7]),
            "thor_all-a4k-flat-no-memory"
        );
        assert_eq!(
            experiment.run_name(paper, runs[15]),
            "thor_all-len-flat-no-memory"
        );
        assert_eq!(
            experiment.run_name(paper, runs[23]),
            "thor_all-flat-no-memory"
        );
        let c = experiment.run_config(paper, runs[7]).unwrap();
        assert!(!c.memory && c.learn_end);
        assert!(experiment.run_config(paper, runs[0]).unwrap().memory);
        // The current protocol: NTG reads videos with the stepping-video
        // interpreter, and both methods also validate on N = 6.
        let ntg = experiment.run_config(paper, runs[0]).unwrap();
        assert_eq!(ntg.interpreter, InterpreterKind::SteppingVideo);
        assert_eq!(
            ntg.location_step_prior,
            Some(crate::collect::LOCATION_STEP_PRIOR)
        );
        assert_eq!(ntg.validation_objects, vec![6]);
        let flat = experiment.run_config(paper, runs[1]).unwrap();
        assert_eq!(
            (flat.method, flat.validation_objects.clone()),
            (MethodId::Flat, vec![6])
        );
        assert_eq!(flat.location_step_prior, None);
        assert!(ntg.same_videos(&flat));
        // Stage A on 4000 videos, the protocol before on the runs' 1000.
        let video = |c: &CollectRunConfig| c.video.as_ref().unwrap().encoder.demos;
        assert_eq!((video(&ntg), video(&flat)), (4000, 4000));
        let len = experiment.run_config(paper, runs[8]).unwrap();
        assert_eq!(video(&len), 1000);
        let ntg = CollectRunConfig {
            video: len.video.clone(),
            ..ntg
        };
        assert_eq!(ntg, len);
        // The protocol before that: the paper's interpreter, training
        // lengths only.
        let old = experiment.run_config(paper, runs[16]).unwrap();
        assert_eq!(old.interpreter, InterpreterKind::Luong);
        assert_eq!(
            (old.location_step_prior, old.validation_objects.len()),
            (None, 0)
        );
        let stripped = CollectRunConfig {
            interpreter: InterpreterKind::Luong,
            location_step_prior: None,
            validation_objects: Vec::new(),
            ..ntg.clone()
        };
        assert_eq!(
            old, stripped,
            "the protocols differ in the interpreter and validation only"
        );
    }

    #[test]
    fn an_earlier_protocol_needs_folders_of_its_own() {
        let text = crate::experiment::BUILT_IN
            .iter()
            .find(|(name, _)| *name == "thor_all")
            .unwrap()
            .1
            .replace("tag = \"len\"\n", "");
        let dir = tempfile::tempdir().unwrap();
        std::fs::write(dir.path().join("thor_all.toml"), text).unwrap();
        let err = ThorAllExperiment::load(crate::experiment::Source::Dir(dir.path()))
            .unwrap_err()
            .to_string();
        assert!(err.contains("another tag"), "{err}");
    }

    #[test]
    fn a_profile_keeps_a_chain_of_earlier_protocols_each_in_folders_of_its_own() {
        // The current protocol becomes the earlier one of a newer protocol
        // (tag "new"), which keeps the chain: current, len, the paper's
        // interpreter.
        let text = crate::experiment::BUILT_IN
            .iter()
            .find(|(name, _)| *name == "thor_all")
            .unwrap()
            .1;
        let mut experiment: ThorAllExperiment = {
            let dir = tempfile::tempdir().unwrap();
            std::fs::write(dir.path().join("thor_all.toml"), text).unwrap();
            ThorAllExperiment::load(crate::experiment::Source::Dir(dir.path())).unwrap()
        };
        let len = experiment.profiles.paper.clone();
        let mut newer = len.clone();
        newer.tag = Some("new".into());
        newer.encoder_demos = Some(8000);
        let mut len = len;
        len.about = Some("stage A on fewer videos".into());
        newer.earlier = Some(Box::new(len));
        experiment.profiles.paper = newer;
        let chain = protocols(&experiment.profiles.paper);
        assert_eq!(
            chain.iter().map(|s| s.tag.as_deref()).collect::<Vec<_>>(),
            [Some("new"), Some("a4k"), Some("len"), None]
        );
        let runs = experiment.runs(Profile::Paper);
        let names: Vec<String> = runs
            .iter()
            .map(|&r| experiment.run_name(Profile::Paper, r))
            .collect();
        for (back, name) in [
            (0, "thor_all-new-ntg"),
            (1, "thor_all-a4k-ntg"),
            (2, "thor_all-len-ntg"),
            (3, "thor_all-ntg"),
        ] {
            let i = names
                .iter()
                .position(|n| n == name)
                .unwrap_or_else(|| panic!("{names:?}"));
            assert_eq!(runs[i].earlier, back, "{name}");
        }
        let unique: std::collections::BTreeSet<&String> = names.iter().collect();
        assert_eq!(unique.len(), names.len(), "{names:?}");
        // Each protocol's own settings: stage A of the newest only.
        let demos = |back: u8| {
            let run = ThorAllRun {
                method: MethodId::Ntg,
                seed: 0,
                memory: true,
                earlier: back,
            };
            experiment
                .run_config(Profile::Paper, run)
                .unwrap()
                .video
                .unwrap()
                .encoder
                .demos
        };
        assert_eq!((demos(0), demos(1), demos(2)), (8000, 4000, 1000));
        assert!(experiment.scale(Profile::Paper, 4).is_err());
        // Two protocols of one tag would share folders: refused.
        let dir = tempfile::tempdir().unwrap();
        let nested = text.replace(
            "[profiles.paper.earlier.earlier]\n",
            "[profiles.paper.earlier.earlier]\ntag = \"a4k\"\n",
        );
        std::fs::write(dir.path().join("thor_all.toml"), nested).unwrap();
        let err = ThorAllExperiment::load(crate::experiment::Source::Dir(dir.path()))
            .unwrap_err()
            .to_string();
        assert!(err.contains("another tag"), "{err}");
        // Results written when a profile kept one earlier protocol read it
        // as one back.
        let mut json = serde_json::to_value(line(MethodId::Ntg, &[1000], 1000)).unwrap();
        json["earlier"] = true.into();
        let old: ThorAllLine = serde_json::from_value(json).unwrap();
        assert_eq!(old.earlier, 1);
        let json = serde_json::to_value(&old).unwrap();
        assert_eq!(json["earlier"], 1);
    }

    #[test]
    fn a_protocol_s_encoder_demos_set_both_methods_stage_a_on_frames_only() {
        let mut experiment = ThorAllExperiment::load(Default::default()).unwrap();
        let run = |method| ThorAllRun {
            method,
            seed: 0,
            memory: true,
            earlier: 0,
        };
        let demos = |e: &ThorAllExperiment, method| {
            e.run_config(Profile::Paper, run(method))
                .unwrap()
                .video
                .unwrap()
                .encoder
                .demos
        };
        experiment.profiles.paper.encoder_demos = None;
        let default = demos(&experiment, MethodId::Ntg);
        experiment.profiles.paper.encoder_demos = Some(default + 3000);
        for method in [MethodId::Ntg, MethodId::Flat] {
            assert_eq!(demos(&experiment, method), default + 3000, "{method:?}");
        }
        // The earlier protocol keeps its own.
        let earlier = ThorAllRun {
            earlier: 1,
            ..run(MethodId::Ntg)
        };
        let config = experiment.run_config(Profile::Paper, earlier).unwrap();
        assert_eq!(config.video.unwrap().encoder.demos, default);
        // On the state there is no stage A to set.
        experiment.profiles.quick.encoder_demos = Some(4000);
        let err = experiment
            .run_config(Profile::Quick, run(MethodId::Ntg))
            .unwrap_err()
            .to_string();
        assert!(err.contains("encoder_demos"), "{err}");
    }

    #[test]
    fn comparison_sentence_groups_each_n_by_its_intervals() {
        let result = ThorAllResult {
            scale: ThorAllExperiment::load(Default::default())
                .unwrap()
                .profiles
                .smoke,
            train_objects: vec![2, 4],
            lines: vec![
                line(MethodId::Ntg, &[1000, 999, 500, 400, 997], 1000),
                line(MethodId::Flat, &[997, 900, 500, 600, 0], 1000),
            ],
        };
        assert_eq!(
            comparison_sentence(&result).unwrap(),
            "Measured: NTG's success is above, with disjoint 95% intervals at N = 2, 5; \
             above, within overlapping intervals at N = 1; tied at N = 3; below at N = 4."
        );
        // A second seed counts: NTG's N = 2 lead (0.999 against 0.900)
        // no longer has every interval apart when its seed 1 scores 0.9.
        let mut seeds = result.clone();
        let mut seed1 = line(MethodId::Ntg, &[1000, 900, 500, 400, 997], 1000);
        seed1.seed = 1;
        seeds.lines.push(seed1);
        assert_eq!(
            comparison_sentence(&seeds).unwrap(),
            "Measured: NTG's success is above, with disjoint 95% intervals at N = 5; \
             above, within overlapping intervals at N = 1, 2; tied at N = 3; below at N = 4."
        );
        let only_ntg = ThorAllResult {
            lines: result.lines[..1].to_vec(),
            ..result
        };
        assert_eq!(comparison_sentence(&only_ntg), None);
    }

    #[test]
    fn the_built_in_file_gives_the_configurations_the_figure_was_measured_with() {
        let experiment = ThorAllExperiment::load(crate::experiment::Source::BuiltIn).unwrap();
        assert_eq!(experiment.methods, [MethodId::Ntg, MethodId::Flat]);
        for method in [MethodId::Ntg, MethodId::Flat] {
            let ntg = method == MethodId::Ntg;
            // The configurations the figure's committed results were
            // measured with.
            let expected = CollectRunConfig {
                domain: "collect".into(),
                method,
                obs: ObsKind::State,
                train_objects: vec![2, 4],
                tasks_per_n: 200,
                demos_per_task: 3,
                segments: true,
                learn_end: true,
                memory: true,
                interpreter: crate::collect::InterpreterKind::Stepping,
                location_step_prior: ntg.then_some(crate::collect::LOCATION_STEP_PRIOR),
                model_seed: 0,
                optim: crate::fit::OptimConfig {
                    epochs: if ntg { 30 } else { 50 },
                    batch_size: 32,
                    learning_rate: 3e-3,
                    seed: 0,
                    token_dropout: 0.0,
                    cosine_decay: ntg,
                    shards: 0, // unset in the file: one thread, as measured
                    gcn_from_other_demo: false,
                },
                video: None,
                // Every epoch scored on 50 held-out training-side tasks
                // per N, the best one tested.
                validation_tasks_per_n: 50,
                validation_objects: Vec::new(),
            };
            assert_eq!(
                experiment
                    .run_config(
                        Profile::Quick,
                        ThorAllRun {
                            method,
                            seed: 0,
                            memory: true,
                            earlier: 0,
                        }
                    )
                    .unwrap(),
                expected
            );
        }
        let paper = experiment
            .run_config(
                Profile::Paper,
                ThorAllRun {
                    method: MethodId::Flat,
                    seed: 0,
                    memory: true,
                    earlier: 0,
                },
            )
            .unwrap();
        assert_eq!(
            (paper.obs, paper.tasks_per_n, paper.validation_tasks_per_n),
            (ObsKind::Vid, 400, 100)
        );
    }
}
