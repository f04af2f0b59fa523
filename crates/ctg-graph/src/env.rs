//! The Gymnasium-style environment and expert traits, and the conformance
//! checker every environment crate runs in its tests.

use std::fmt::Debug;

use crate::{ActionId, CtgError, Demonstration, Result, Vocabulary};

/// What one [`Environment::step`] returns.
///
/// As in Gymnasium, `terminated` (the episode reached its end: the agent
/// chose `<end>`, or the environment reached a terminal state) and
/// `truncated` (the step limit cut it off) are distinct; at most one is true.
#[derive(Debug, Clone, PartialEq)]
pub struct Step<O, I> {
    /// The observation after the action.
    pub observation: O,
    /// Reward for this step (environments here give 1 on a successful end).
    pub reward: f32,
    /// The episode reached its end.
    pub terminated: bool,
    /// The episode was cut off by the step limit.
    pub truncated: bool,
    /// Environment-specific information (e.g. whether the action failed).
    pub info: I,
}

impl<O, I> Step<O, I> {
    /// Whether the episode is over (terminated or truncated).
    pub fn is_done(&self) -> bool {
        self.terminated || self.truncated
    }
}

/// An environment whose actions are the nodes of a [`Vocabulary`].
///
/// The contract (checked by [`check_environment`]):
/// - `reset(seed)` starts an episode; the same seed gives the same episode.
/// - `step(a)` for a real action executes it. An action that is physically
///   impossible in the current state (grasping a covered block) is *not* an
///   error: it returns `Ok` and reports the failure in `info`, so a policy can
///   react. Errors are for actions outside the vocabulary, `<start>`,
///   stepping before `reset`, or after the episode is over.
/// - `step(<end>)` ends the episode: `terminated = true`, `truncated = false`.
/// - after `max_episode_steps()` steps without termination, the step returns
///   `truncated = true`.
/// - all randomness inside an episode (e.g. stochastic action failures)
///   derives from the reset seed, so the same seed and the same actions give
///   the same observations.
pub trait Environment {
    /// What the agent sees.
    type Observation: Clone;
    /// Extra per-step information.
    type Info: Clone + Debug;

    /// The actions (CTG nodes) of this environment.
    fn vocabulary(&self) -> &Vocabulary;

    /// Starts a new episode, seeded.
    fn reset(&mut self, seed: u64) -> Result<(Self::Observation, Self::Info)>;

    /// Takes one action.
    fn step(&mut self, action: ActionId) -> Result<Step<Self::Observation, Self::Info>>;

    /// Whether the current state satisfies the task.
    fn is_success(&self) -> bool;

    /// Step limit after which an episode is truncated.
    fn max_episode_steps(&self) -> usize;
}

/// A scripted policy with privileged access to the environment, used to
/// record demonstrations.
pub trait Expert<E: Environment + ?Sized> {
    /// Prepares for a new episode; called right after `env.reset(seed)`.
    fn reset(&mut self, env: &E, seed: u64);

    /// The next action in the current state (`<end>` when done).
    fn next_action(&mut self, env: &E) -> Result<ActionId>;
}

/// Runs `expert` in `env` from `reset(seed)` until it chooses `<end>`, and
/// returns the demonstration (the observation after `<end>` is not part of it).
///
/// Errors if the expert fails to finish before the step limit, chooses no
/// action at all, or the environment errors.
pub fn record_demonstration<E, X>(
    env: &mut E,
    expert: &mut X,
    seed: u64,
) -> Result<Demonstration<E::Observation>>
where
    E: Environment,
    X: Expert<E> + ?Sized,
{
    let (first, _) = env.reset(seed)?;
    expert.reset(env, seed);
    let mut observations = vec![first];
    let mut actions = Vec::new();
    loop {
        let action = expert.next_action(env)?;
        if action == Vocabulary::END {
            break;
        }
        let step = env.step(action)?;
        actions.push(action);
        observations.push(step.observation);
        if step.terminated {
            break;
        }
        if step.truncated {
            return Err(CtgError::ExpertFailed(format!(
                "hit the step limit ({}) before finishing (seed {seed})",
                env.max_episode_steps()
            )));
        }
    }
    Demonstration::new(observations, actions, env.vocabulary())
}

/// What [`check_environment`] verified.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct ConformanceReport {
    /// Seeds whose expert demonstration was recorded, replayed and checked.
    pub seeds_checked: usize,
    /// Whether different seeds gave different initial observations.
    pub seeds_vary_initial_observation: bool,
    /// Length of the longest expert demonstration seen.
    pub longest_demonstration: usize,
}

fn fail<T>(message: String) -> Result<T> {
    Err(CtgError::Conformance(message))
}

/// Checks that an environment keeps the [`Environment`] contract, driving it
/// with `expert` on each of `seeds`:
///
/// 1. stepping a fresh environment before `reset` is an error;
/// 2. the same seed gives the same initial observation;
/// 3. an out-of-range action and `<start>` are errors, and the environment
///    still works afterwards;
/// 4. the expert's demonstration is reproducible: recording it twice gives
///    the same demonstration, and replaying its actions after the same reset
///    gives the same observations and ends in success;
/// 5. `<end>` terminates (`terminated && !truncated`) and stepping after that
///    is an error;
/// 6. taking real actions without ever choosing `<end>` is truncated within
///    `max_episode_steps()` steps, with `truncated && !terminated`, and
///    stepping after that is an error.
///
/// `make_env` builds a fresh environment each time it is called.
pub fn check_environment<E, X>(
    mut make_env: impl FnMut() -> E,
    expert: &mut X,
    seeds: &[u64],
) -> Result<ConformanceReport>
where
    E: Environment,
    E::Observation: PartialEq + Debug,
    X: Expert<E> + ?Sized,
{
    if seeds.is_empty() {
        return fail("no seeds given".into());
    }
    let mut report = ConformanceReport::default();

    // 1. No stepping before reset.
    {
        let mut env = make_env();
        let some_action = env.vocabulary().actions().next();
        let Some(action) = some_action else {
            return fail("the vocabulary has no actions".into());
        };
        if env.step(action).is_ok() {
            return fail("step before reset succeeded; it must be an error".into());
        }
    }

    let mut first_initial: Option<E::Observation> = None;
    for &seed in seeds {
        let mut env = make_env();
        let vocab = env.vocabulary().clone();

        // 2. Seeded resets are reproducible.
        let (a, _) = env.reset(seed)?;
        let (b, _) = env.reset(seed)?;
        if a != b {
            return fail(format!("reset({seed}) twice gave different observations"));
        }
        match &first_initial {
            None => first_initial = Some(a.clone()),
            Some(first) if *first != a => report.seeds_vary_initial_observation = true,
            Some(_) => {}
        }

        // 3. Invalid actions are errors, not panics, and leave the env usable.
        if env.step(ActionId::new(vocab.len())).is_ok() {
            return fail("an out-of-range action id was accepted".into());
        }
        if env.step(Vocabulary::START).is_ok() {
            return fail("the <start> node was accepted as an action".into());
        }

        // 4. Expert demonstrations are reproducible and replay exactly.
        let demo = record_demonstration(&mut env, expert, seed)?;
        let again = record_demonstration(&mut env, expert, seed)?;
        if demo != again {
            return fail(format!("two expert demonstrations with seed {seed} differ"));
        }
        let (replayed_first, _) = env.reset(seed)?;
        if replayed_first != demo.observations()[0] {
            return fail(format!(
                "replay of seed {seed}: initial observation differs"
            ));
        }
        for (i, &action) in demo.actions().iter().enumerate() {
            let step = env.step(action)?;
            if step.observation != demo.observations()[i + 1] {
                return fail(format!(
                    "replay of seed {seed}: observation after action {i} ({}) differs",
                    vocab.name(action).unwrap_or("?")
                ));
            }
            if step.is_done() && i + 1 < demo.len() {
                return fail(format!(
                    "replay of seed {seed}: episode ended early at step {i}"
                ));
            }
        }
        if !env.is_success() {
            return fail(format!(
                "the expert's demonstration with seed {seed} does not succeed"
            ));
        }

        // 5. <end> terminates; stepping afterwards is an error.
        let end = env.step(Vocabulary::END)?;
        if !end.terminated || end.truncated {
            return fail(format!(
                "<end> gave terminated={} truncated={}; expected true/false",
                end.terminated, end.truncated
            ));
        }
        if env
            .step(vocab.actions().next().unwrap_or(Vocabulary::END))
            .is_ok()
        {
            return fail("a step after termination succeeded".into());
        }

        // 6. Never choosing <end> is truncated by the step limit.
        env.reset(seed)?;
        let limit = env.max_episode_steps();
        let actions: Vec<ActionId> = vocab.actions().collect();
        let mut truncated = false;
        for t in 0..limit {
            let step = env.step(actions[t % actions.len()])?;
            if step.terminated && step.truncated {
                return fail("a step was both terminated and truncated".into());
            }
            if step.terminated {
                // The environment reached a terminal state on its own; allowed.
                truncated = true;
                break;
            }
            if step.truncated {
                if t + 1 != limit {
                    return fail(format!("truncated after {} steps, limit is {limit}", t + 1));
                }
                truncated = true;
                break;
            }
        }
        if !truncated {
            return fail(format!("{limit} steps without <end> were not truncated"));
        }
        if env.step(actions[0]).is_ok() {
            return fail("a step after truncation succeeded".into());
        }

        report.seeds_checked += 1;
        report.longest_demonstration = report.longest_demonstration.max(demo.len());
    }
    Ok(report)
}
