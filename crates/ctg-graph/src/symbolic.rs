//! A tiny symbolic environment, for tests, examples and conformance checks
//! of the executor without any simulator.

use crate::{ActionId, CtgError, Environment, Expert, Result, Step, Vocabulary};

/// What [`SequenceTask`] shows the agent: how many actions were taken and
/// the last one (`<start>` before the first).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
pub struct SequenceObservation {
    /// Number of actions taken so far.
    pub step: usize,
    /// The last action taken, `<start>` at the beginning.
    pub last: ActionId,
}

/// A symbolic task: reproduce a target action sequence exactly.
///
/// Success means the actions taken so far equal the target. Every real
/// action is applicable; there is no randomness, so the seed is ignored.
/// The step limit is twice the target length plus two.
#[derive(Debug, Clone)]
pub struct SequenceTask {
    vocab: Vocabulary,
    target: Vec<ActionId>,
    taken: Vec<ActionId>,
    state: EpisodeState,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum EpisodeState {
    NotReset,
    Running,
    Over,
}

impl SequenceTask {
    /// A task whose goal is `target` (ids of `vocab`; not checked until
    /// compared).
    pub fn new(vocab: Vocabulary, target: Vec<ActionId>) -> Self {
        SequenceTask {
            vocab,
            target,
            taken: Vec::new(),
            state: EpisodeState::NotReset,
        }
    }

    /// The target sequence.
    pub fn target(&self) -> &[ActionId] {
        &self.target
    }

    /// The actions taken in this episode.
    pub fn taken(&self) -> &[ActionId] {
        &self.taken
    }

    fn observation(&self) -> SequenceObservation {
        SequenceObservation {
            step: self.taken.len(),
            last: self.taken.last().copied().unwrap_or(Vocabulary::START),
        }
    }
}

impl Environment for SequenceTask {
    type Observation = SequenceObservation;
    type Info = ();

    fn vocabulary(&self) -> &Vocabulary {
        &self.vocab
    }

    fn reset(&mut self, _seed: u64) -> Result<(SequenceObservation, ())> {
        self.taken.clear();
        self.state = EpisodeState::Running;
        Ok((self.observation(), ()))
    }

    fn step(&mut self, action: ActionId) -> Result<Step<SequenceObservation, ()>> {
        match self.state {
            EpisodeState::NotReset => return Err(CtgError::NotReset),
            EpisodeState::Over => return Err(CtgError::EpisodeOver),
            EpisodeState::Running => {}
        }
        self.vocab.check(action)?;
        if action == Vocabulary::START {
            return Err(CtgError::InvalidAction {
                action: Vocabulary::START_NAME.into(),
                reason: "<start> is not an action".into(),
            });
        }
        if action == Vocabulary::END {
            self.state = EpisodeState::Over;
            return Ok(Step {
                observation: self.observation(),
                reward: if self.is_success() { 1.0 } else { 0.0 },
                terminated: true,
                truncated: false,
                info: (),
            });
        }
        self.taken.push(action);
        let truncated = self.taken.len() >= self.max_episode_steps();
        if truncated {
            self.state = EpisodeState::Over;
        }
        Ok(Step {
            observation: self.observation(),
            reward: 0.0,
            terminated: false,
            truncated,
            info: (),
        })
    }

    fn is_success(&self) -> bool {
        self.taken == self.target
    }

    fn max_episode_steps(&self) -> usize {
        2 * self.target.len() + 2
    }
}

/// The expert for [`SequenceTask`]: takes the target's next action, or
/// `<end>` when the target is done (or can no longer be reached).
#[derive(Debug, Clone, Copy, Default)]
pub struct SequenceExpert;

impl Expert<SequenceTask> for SequenceExpert {
    fn reset(&mut self, _env: &SequenceTask, _seed: u64) {}

    fn next_action(&mut self, env: &SequenceTask) -> Result<ActionId> {
        let taken = env.taken();
        if !env.target().starts_with(taken) {
            return Ok(Vocabulary::END);
        }
        Ok(env
            .target()
            .get(taken.len())
            .copied()
            .unwrap_or(Vocabulary::END))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::check_environment;

    #[test]
    fn sequence_task_passes_conformance() {
        let v = Vocabulary::new(["a", "b"]).unwrap();
        let target = v.parse_sequence("a b b a").unwrap();
        let report = check_environment(
            || SequenceTask::new(v.clone(), target.clone()),
            &mut SequenceExpert,
            &[0, 1, 2],
        )
        .unwrap();
        assert_eq!(report.seeds_checked, 3);
        assert_eq!(report.longest_demonstration, 4);
        assert!(!report.seeds_vary_initial_observation);
    }

    /// An environment that breaks the contract must be caught.
    #[test]
    fn conformance_catches_a_broken_environment() {
        #[derive(Clone)]
        struct NeverTruncates(SequenceTask);
        impl Environment for NeverTruncates {
            type Observation = SequenceObservation;
            type Info = ();
            fn vocabulary(&self) -> &Vocabulary {
                self.0.vocabulary()
            }
            fn reset(&mut self, seed: u64) -> Result<(SequenceObservation, ())> {
                self.0.reset(seed)
            }
            fn step(&mut self, a: ActionId) -> Result<Step<SequenceObservation, ()>> {
                let mut s = self.0.step(a)?;
                if s.truncated {
                    s.truncated = false;
                    self.0.state = EpisodeState::Running;
                }
                Ok(s)
            }
            fn is_success(&self) -> bool {
                self.0.is_success()
            }
            fn max_episode_steps(&self) -> usize {
                self.0.max_episode_steps()
            }
        }
        struct Wrapped;
        impl Expert<NeverTruncates> for Wrapped {
            fn reset(&mut self, _: &NeverTruncates, _: u64) {}
            fn next_action(&mut self, env: &NeverTruncates) -> Result<ActionId> {
                SequenceExpert.next_action(&env.0)
            }
        }
        let v = Vocabulary::new(["a"]).unwrap();
        let target = v.parse_sequence("a").unwrap();
        let err = check_environment(
            || NeverTruncates(SequenceTask::new(v.clone(), target.clone())),
            &mut Wrapped,
            &[0],
        )
        .unwrap_err();
        assert!(matches!(err, CtgError::Conformance(m) if m.contains("not truncated")));
    }
}
