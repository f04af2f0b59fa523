//! The scripted expert.

use ctg_graph::{ActionId, CtgError, Expert, Vocabulary};

use crate::domain::Action;
use crate::env::CollectEnv;

/// The expert: with privileged access to the task and the hidden state, it
/// searches until an undelivered target is visible, picks it up, drops it
/// off at its designated receptacle, and repeats; `<end>` once every target
/// is delivered.
///
/// Deterministic given the state, so demonstrations differ across seeds
/// only because scenes (where the targets are, in which visiting order) do.
/// It also copes with states a policy may leave behind: holding a
/// distractor, it drops it in the fridge (distractors do not count); a target
/// lying in the wrong receptacle is picked up again when the agent is there.
#[derive(Debug, Clone, Copy, Default)]
pub struct CollectExpert;

impl CollectExpert {
    /// The expert's action in the current state (`<end>` when done).
    pub fn action(env: &CollectEnv) -> Result<ActionId, CtgError> {
        if env.place().is_none() {
            return Err(CtgError::NotReset);
        }
        let task = env.task();
        if let Some(held) = env.held() {
            let receptacle = task
                .receptacle_of(held)
                .unwrap_or(crate::Receptacle::Fridge);
            return Ok(Action::Dropoff(receptacle).id());
        }
        if let Some(target) = env
            .visible()
            .into_iter()
            .find(|&c| task.is_target(c) && !env.is_delivered(c))
        {
            return Ok(Action::Pickup(target).id());
        }
        if env.delivered() == task.num_objects() {
            return Ok(Vocabulary::END);
        }
        Ok(Action::Search.id())
    }
}

impl Expert<CollectEnv> for CollectExpert {
    fn reset(&mut self, _env: &CollectEnv, _seed: u64) {}

    fn next_action(&mut self, env: &CollectEnv) -> Result<ActionId, CtgError> {
        Self::action(env)
    }
}
