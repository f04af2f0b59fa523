//! What the shared loops need of a domain, and the one evaluation loop.
//!
//! A domain is a small adapter behind [`Domain`]: its environment and
//! expert (ctg-graph's [`Environment`] and [`Expert`]), how an observation
//! becomes a row, a task's name and how many of its goals hold. Everything
//! else is shared: [`record_demos`] records a training dataset, and
//! [`evaluate`] is the one evaluation loop (every episode records its
//! conditioning demo, conditions any method's model on it and rolls the
//! policy out in another scene, in parallel); [`crate::fit::fit`] is the one
//! training loop.

use anyhow::Context;
use ctg_graph::{Environment, Expert, Vocabulary, record_demonstration};
use serde::{Deserialize, Serialize};

use crate::dataset::{DatasetSpec, DemoDataset, ObsDtype, generate, progress_bar};
use crate::evaluate::in_parallel;
use crate::method::TrainedPolicy;
use crate::spec::ObsKind;
use crate::stats::SuccessRate;

/// What the shared loops need to know of a domain.
pub trait Domain: Sync {
    /// A task of the domain.
    type Task: Sync;
    /// Its environment.
    type Env: Environment;
    /// Its scripted expert.
    type Expert: Expert<Self::Env>;
    /// The flat action vocabulary (the CTG's nodes).
    fn vocabulary(&self) -> &Vocabulary;
    /// A fresh environment for `task`.
    fn env(&self, task: &Self::Task) -> anyhow::Result<Self::Env>;
    /// A fresh expert.
    fn expert(&self) -> Self::Expert;
    /// What the networks see: state rows unless the domain says frames
    /// ([`ObsKind::Vid`]: rows of bytes, stored as such).
    fn obs_kind(&self) -> ObsKind {
        ObsKind::State
    }
    /// Values per observation row.
    fn obs_dim(&self) -> usize;
    /// The observation as the networks' flat row.
    fn featurize(&self, observation: &<Self::Env as Environment>::Observation) -> Vec<f32>;
    /// The task's name in records.
    fn task_name(&self, task: &Self::Task) -> String;
    /// How many of the task's goals hold in `env` at the end of an
    /// episode, and how many it has.
    fn goals(&self, task: &Self::Task, env: &Self::Env) -> (usize, usize);
    /// The conditioning demo a policy reads: the expert's demonstration of
    /// `task` recorded with `seed` in `env`, as observation rows, and its
    /// actions. By default one row per CTG node; a domain that records
    /// demo videos gives every frame.
    fn record_demo(
        &self,
        env: &mut Self::Env,
        _task: &Self::Task,
        seed: u64,
    ) -> anyhow::Result<(Vec<Vec<f32>>, Vec<ctg_graph::ActionId>)> {
        record_keyframes(self, env, seed)
    }
}

/// A domain whose environment already sees what the networks read: its
/// observations are state rows (`Vec<f32>`, all of one length). Made from
/// the function that builds a task's environment and the one that makes an
/// expert; a task's name is its `Debug` form, and its one goal is met when
/// the environment reports success.
pub struct RowDomain<T, E, X> {
    vocabulary: Vocabulary,
    obs_dim: usize,
    env: MakeEnv<T, E>,
    expert: Box<dyn Fn() -> X + Sync>,
}

/// What builds a [`RowDomain`]'s environment of a task.
type MakeEnv<T, E> = Box<dyn Fn(&T) -> anyhow::Result<E> + Sync>;

impl<T, E, X> RowDomain<T, E, X>
where
    E: Environment<Observation = Vec<f32>>,
{
    /// The domain of the environments `env` builds (the vocabulary and the
    /// row length read off the environment of `example`, reset with seed
    /// 0) and the experts `expert` makes.
    pub fn new(
        example: &T,
        env: impl Fn(&T) -> anyhow::Result<E> + Sync + 'static,
        expert: impl Fn() -> X + Sync + 'static,
    ) -> anyhow::Result<Self> {
        let mut probe = env(example)?;
        let (first, _) = probe.reset(0)?;
        Ok(RowDomain {
            vocabulary: probe.vocabulary().clone(),
            obs_dim: first.len(),
            env: Box::new(env),
            expert: Box::new(expert),
        })
    }
}

impl<T, E, X> Domain for RowDomain<T, E, X>
where
    T: Sync + std::fmt::Debug,
    E: Environment<Observation = Vec<f32>>,
    X: Expert<E>,
{
    type Task = T;
    type Env = E;
    type Expert = X;
    fn vocabulary(&self) -> &Vocabulary {
        &self.vocabulary
    }
    fn env(&self, task: &T) -> anyhow::Result<E> {
        (self.env)(task)
    }
    fn expert(&self) -> X {
        (self.expert)()
    }
    fn obs_dim(&self) -> usize {
        self.obs_dim
    }
    fn featurize(&self, observation: &Vec<f32>) -> Vec<f32> {
        observation.clone()
    }
    fn task_name(&self, task: &T) -> String {
        format!("{task:?}")
    }
    fn goals(&self, _: &T, env: &E) -> (usize, usize) {
        (usize::from(env.is_success()), 1)
    }
}

/// [`Domain::record_demo`]'s default: the expert's demonstration recorded
/// with `seed` in `env`, one featurised row per CTG node, and its actions.
pub fn record_keyframes<D: Domain + ?Sized>(
    domain: &D,
    env: &mut D::Env,
    seed: u64,
) -> anyhow::Result<(Vec<Vec<f32>>, Vec<ctg_graph::ActionId>)> {
    let demo = record_demonstration(env, &mut domain.expert(), seed)?;
    let rows = demo
        .observations()
        .iter()
        .map(|o| domain.featurize(o))
        .collect();
    Ok((rows, demo.actions().to_vec()))
}

/// One evaluation episode: a task, the seed of its conditioning demo and
/// the seed of the scene the policy acts in.
#[derive(Debug, Clone, PartialEq)]
pub struct Episode<T> {
    /// The group the episode is reported in (object collection: the number
    /// of objects N; block stacking: 0).
    pub group: usize,
    /// Index of the episode within its group.
    pub index: usize,
    /// The task.
    pub task: T,
    /// Seed of the expert's conditioning demonstration.
    pub demo_seed: u64,
    /// Seed of the rollout scene.
    pub rollout_seed: u64,
}

impl<T: Clone> Episode<T> {
    /// `per_task` episodes of each of `tasks` (group 0, numbered in order),
    /// episode `k` with demo seed `seed + 2k` and rollout seed `seed + 2k + 1`:
    /// every demo and scene distinct, and none of them a seed that
    /// [`record_demos`] gives a training demo when `seed` lies above the
    /// training seeds.
    pub fn for_tasks(tasks: &[T], per_task: usize, seed: u64) -> Vec<Episode<T>> {
        let pairs = tasks.iter().flat_map(|t| std::iter::repeat_n(t, per_task));
        pairs
            .enumerate()
            .map(|(k, task)| Episode {
                group: 0,
                index: k,
                task: task.clone(),
                demo_seed: seed + 2 * k as u64,
                rollout_seed: seed + 2 * k as u64 + 1,
            })
            .collect()
    }
}

/// One evaluated episode.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct EpisodeRecord {
    /// The episode's group (see [`Episode::group`]).
    #[serde(default)]
    pub group: usize,
    /// Index of the episode within its group.
    pub index: usize,
    /// The task.
    pub task: String,
    /// Whether the task was done at the end.
    pub success: bool,
    /// Actions taken (`<end>` included if chosen).
    pub steps: usize,
    /// Goals that held at the end (block stacking: `on_top` constraints;
    /// object collection: objects delivered).
    #[serde(default)]
    pub goals_met: usize,
    /// Goals of the task.
    #[serde(default)]
    pub goals: usize,
    /// The executed actions, by name (empty in committed run records:
    /// ntg-trainer's run records).
    #[serde(default)]
    pub trace: Vec<String>,
    /// NTG only: the demo interpreter's transcription of the demo.
    #[serde(default)]
    pub transcription: Vec<String>,
    /// The expert's actual actions in the conditioning demo.
    #[serde(default)]
    pub demo_actions: Vec<String>,
    /// Methods with a demo interpreter: whether its transcription is the
    /// demo's action sequence exactly (kept in committed run records,
    /// which drop the sequences themselves; absent in evaluations saved
    /// before it).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub transcribed_exactly: Option<bool>,
}

impl EpisodeRecord {
    /// [`Self::transcribed_exactly`], or where it was not saved, the
    /// comparison of the saved sequences (`None` without a transcription).
    pub fn transcription_exact(&self) -> Option<bool> {
        self.transcribed_exactly.or_else(|| {
            (!self.transcription.is_empty()).then(|| self.transcription == self.demo_actions)
        })
    }
}

/// The fraction of `records`' demos the demo interpreter transcribed
/// exactly, with its 95% Wilson interval, over the records that say
/// ([`EpisodeRecord::transcription_exact`]); `None` if none does.
pub fn transcription_exact_rate<'a>(
    records: impl IntoIterator<Item = &'a EpisodeRecord>,
) -> Option<SuccessRate> {
    let outcomes: Vec<bool> = records
        .into_iter()
        .filter_map(EpisodeRecord::transcription_exact)
        .collect();
    (!outcomes.is_empty()).then(|| SuccessRate::from_outcomes(outcomes))
}

/// Where a method with a demo interpreter failed: in transcribing the demo,
/// or in acting on a right transcription.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct TranscriptionSplit {
    /// The fraction of demos transcribed exactly.
    pub exact: SuccessRate,
    /// Success on the episodes whose demo was transcribed exactly.
    pub success_if_exact: SuccessRate,
    /// Success on the others.
    pub success_otherwise: SuccessRate,
}

impl TranscriptionSplit {
    /// The split of `records` ([`EpisodeRecord::transcription_exact`]),
    /// over the records that say; `None` if none does.
    pub fn of(records: &[EpisodeRecord]) -> Option<Self> {
        let said: Vec<(bool, bool)> = records
            .iter()
            .filter_map(|r| r.transcription_exact().map(|e| (e, r.success)))
            .collect();
        (!said.is_empty()).then(|| TranscriptionSplit {
            exact: SuccessRate::from_outcomes(said.iter().map(|&(e, _)| e)),
            success_if_exact: SuccessRate::from_outcomes(
                said.iter().filter(|&&(e, _)| e).map(|&(_, s)| s),
            ),
            success_otherwise: SuccessRate::from_outcomes(
                said.iter().filter(|&&(e, _)| !e).map(|&(_, s)| s),
            ),
        })
    }
}

/// The success rate of `records`, with its 95% Wilson interval.
pub fn success_rate<'a>(records: impl IntoIterator<Item = &'a EpisodeRecord>) -> SuccessRate {
    SuccessRate::from_outcomes(records.into_iter().map(|r| r.success))
}

/// The mean over `records` of the fraction of each task's goals met.
pub fn mean_goal_fraction(records: &[EpisodeRecord]) -> f64 {
    records
        .iter()
        .map(|r| r.goals_met as f64 / r.goals.max(1) as f64)
        .sum::<f64>()
        / records.len().max(1) as f64
}

/// Records `demos_per_task` expert demonstrations of each of `tasks` in
/// parallel (demo `j` of task `t` with seed `seed_base + 1000 t + j`) into
/// a dataset; frames are stored as bytes.
pub fn record_demos<D: Domain>(
    domain: &D,
    tasks: &[D::Task],
    demos_per_task: usize,
    seed_base: u64,
) -> anyhow::Result<DemoDataset> {
    let pairs: Vec<(usize, u64)> = (0..tasks.len())
        .flat_map(|t| (0..demos_per_task).map(move |j| (t, seed_base + 1000 * t as u64 + j as u64)))
        .collect();
    let bar = progress_bar(pairs.len() as u64, "demos");
    generate(
        &pairs,
        |t| domain.env(&tasks[t]),
        || domain.expert(),
        |o| domain.featurize(o),
        DatasetSpec {
            vocabulary: domain.vocabulary().clone(),
            obs_dim: domain.obs_dim(),
            dtype: match domain.obs_kind() {
                ObsKind::State => ObsDtype::F32,
                ObsKind::Vid => ObsDtype::U8,
            },
        },
        &bar,
    )
}

/// The one evaluation loop: for every episode, in parallel, the expert
/// records the conditioning demo in the task's environment, `model` is
/// conditioned on it, and the policy acts greedily in the rollout scene
/// until the episode ends (`<end>` or the step limit).
pub fn evaluate<D: Domain>(
    domain: &D,
    model: &dyn TrainedPolicy,
    episodes: &[Episode<D::Task>],
) -> anyhow::Result<Vec<EpisodeRecord>> {
    let model = model.for_inference();
    in_parallel(episodes, "rollouts", |_, episode| {
        run_episode(domain, model.as_ref(), episode)
    })
}

fn run_episode<D: Domain>(
    domain: &D,
    model: &dyn TrainedPolicy,
    episode: &Episode<D::Task>,
) -> anyhow::Result<EpisodeRecord> {
    run_episode_observed(domain, model, episode, |_| Ok(()))
}

/// One decision of an episode, as [`run_episode_observed`] shows it.
pub struct Decision<'a, E: Environment> {
    /// The observation the agent acted on.
    pub observation: &'a E::Observation,
    /// The action it chose.
    pub action: ctg_graph::ActionId,
    /// What the agent says it was doing (see [`crate::method::Agent::explain`]).
    pub explanation: Option<String>,
    /// What the environment returned.
    pub step: &'a ctg_graph::Step<E::Observation, E::Info>,
}

/// One evaluation episode exactly as [`evaluate`] runs it (`model` must
/// already be the inference model), calling `observe` after every
/// decision: for traces.
pub fn run_episode_observed<D: Domain>(
    domain: &D,
    model: &dyn TrainedPolicy,
    episode: &Episode<D::Task>,
    mut observe: impl FnMut(Decision<'_, D::Env>) -> anyhow::Result<()>,
) -> anyhow::Result<EpisodeRecord> {
    let name = domain.task_name(&episode.task);
    let mut env = domain.env(&episode.task)?;
    let (rows, demo_actions) = domain
        .record_demo(&mut env, &episode.task, episode.demo_seed)
        .with_context(|| format!("demo of task {name}"))?;
    let agent = model.condition(&rows, domain.vocabulary())?;
    let (mut observation, _) = env.reset(episode.rollout_seed)?;
    let mut ties = crate::method::Ties::for_episode(episode.rollout_seed);
    let mut trace = Vec::new();
    loop {
        let action = agent
            .act(&domain.featurize(&observation), &trace, &mut ties)
            .with_context(|| format!("rollout of task {name}"))?;
        trace.push(action);
        let step = env.step(action)?;
        observe(Decision {
            observation: &observation,
            action,
            explanation: agent.explain(),
            step: &step,
        })?;
        let done = step.is_done();
        observation = step.observation;
        if done {
            break;
        }
    }
    let (goals_met, goals) = domain.goals(&episode.task, &env);
    let vocab = domain.vocabulary();
    let names = |ids: &[ctg_graph::ActionId]| -> Vec<String> {
        ids.iter()
            .map(|&a| vocab.name(a).unwrap_or("?").to_owned())
            .collect()
    };
    Ok(EpisodeRecord {
        group: episode.group,
        index: episode.index,
        task: name,
        success: env.is_success(),
        steps: trace.len(),
        goals_met,
        goals,
        trace: names(&trace),
        transcribed_exactly: (!agent.transcription().is_empty())
            .then(|| agent.transcription() == demo_actions.as_slice()),
        transcription: names(agent.transcription()),
        demo_actions: names(&demo_actions),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn record(transcription: &[&str], demo: &[&str], saved: Option<bool>) -> EpisodeRecord {
        let names = |a: &[&str]| a.iter().map(|s| (*s).to_owned()).collect();
        EpisodeRecord {
            group: 0,
            index: 0,
            task: "t".into(),
            success: false,
            steps: 0,
            goals_met: 0,
            goals: 1,
            trace: Vec::new(),
            transcription: names(transcription),
            demo_actions: names(demo),
            transcribed_exactly: saved,
        }
    }

    #[test]
    fn exact_transcriptions_are_counted_over_the_records_that_say() {
        let records = [
            record(&["a", "b"], &["a", "b"], None),
            record(&["a", "c"], &["a", "b"], None),
            // A committed record: sequences dropped, the verdict kept.
            record(&[], &[], Some(true)),
            // No demo interpreter (NTP): not counted.
            record(&[], &["a"], None),
        ];
        assert_eq!(records[0].transcription_exact(), Some(true));
        assert_eq!(records[1].transcription_exact(), Some(false));
        assert_eq!(records[3].transcription_exact(), None);
        let rate = transcription_exact_rate(&records).unwrap();
        assert_eq!((rate.successes, rate.trials), (2, 3));
        let mut records = records.to_vec();
        records[0].success = true;
        let split = TranscriptionSplit::of(&records).unwrap();
        assert_eq!((split.exact.successes, split.exact.trials), (2, 3));
        let (hit, miss) = (split.success_if_exact, split.success_otherwise);
        assert_eq!((hit.successes, hit.trials), (1, 2));
        assert_eq!((miss.successes, miss.trials), (0, 1));
        assert!(transcription_exact_rate(&records[3..]).is_none());
    }
}
