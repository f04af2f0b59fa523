//! Validated demonstrations.

use crate::{ActionId, Ctg, CtgError, Result, Vocabulary};

/// One demonstration: the flat action sequence an expert took and what was
/// observed along the way.
///
/// `observations[0]` is seen before the first action, `observations[i + 1]`
/// right after `actions[i]`, so there is exactly one more observation than
/// actions. In CTG terms observation `i` sits at node
/// [`node_labels`](Demonstration::node_labels)`()[i]` (the last action taken,
/// `<start>` at first) and the action that follows it is
/// [`next_actions`](Demonstration::next_actions)`()[i]` (`<end>` at last).
///
/// Validated at construction: at least one action, the counts agree, and
/// every action is a real (non-reserved) action of the vocabulary.
#[derive(Debug, Clone, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize))]
pub struct Demonstration<O> {
    observations: Vec<O>,
    actions: Vec<ActionId>,
}

impl<O> Demonstration<O> {
    /// A validated demonstration.
    ///
    /// ```
    /// use ctg_graph::{Demonstration, Vocabulary};
    /// let vocab = Vocabulary::new(["pick", "place"]).unwrap();
    /// let actions = vocab.parse_sequence("pick place").unwrap();
    /// let demo = Demonstration::new(vec![0, 1, 2], actions, &vocab).unwrap();
    /// assert_eq!(demo.len(), 2);
    /// assert!(Demonstration::new(vec![0, 1], vocab.parse_sequence("pick place").unwrap(), &vocab).is_err());
    /// ```
    pub fn new(observations: Vec<O>, actions: Vec<ActionId>, vocab: &Vocabulary) -> Result<Self> {
        if actions.is_empty() {
            return Err(CtgError::EmptyDemonstration);
        }
        if observations.len() != actions.len() + 1 {
            return Err(CtgError::ObservationCount {
                actions: actions.len(),
                observations: observations.len(),
                expected: actions.len() + 1,
            });
        }
        for &action in &actions {
            vocab.check_action(action)?;
        }
        Ok(Demonstration {
            observations,
            actions,
        })
    }

    /// A demonstration from parts the caller has already validated (same
    /// rules as [`Demonstration::new`]).
    pub(crate) fn from_validated(observations: Vec<O>, actions: Vec<ActionId>) -> Self {
        debug_assert!(!actions.is_empty() && observations.len() == actions.len() + 1);
        Demonstration {
            observations,
            actions,
        }
    }

    /// The observations, one more than the actions.
    pub fn observations(&self) -> &[O] {
        &self.observations
    }

    /// The demonstrated action sequence (no `<start>`/`<end>`).
    pub fn actions(&self) -> &[ActionId] {
        &self.actions
    }

    /// Number of actions (never zero).
    #[allow(clippy::len_without_is_empty)] // never empty by construction
    pub fn len(&self) -> usize {
        self.actions.len()
    }

    /// The CTG node each observation is at: `<start>`, then each action.
    pub fn node_labels(&self) -> Vec<ActionId> {
        node_labels_of(&self.actions)
    }

    /// The action that follows each observation: each action, then `<end>`.
    pub fn next_actions(&self) -> Vec<ActionId> {
        next_actions_of(&self.actions)
    }

    /// The path graph `<start> -> actions... -> <end>` over `vocab`.
    pub fn path_graph(&self, vocab: &Vocabulary) -> Result<Ctg> {
        Ctg::from_path(vocab.len(), &self.actions)
    }

    /// Splits into observations and actions.
    pub fn into_parts(self) -> (Vec<O>, Vec<ActionId>) {
        (self.observations, self.actions)
    }

    /// The same demonstration with every observation transformed by `f`
    /// (for example encoded into a feature vector).
    pub fn map_observations<P>(self, f: impl FnMut(O) -> P) -> Demonstration<P> {
        Demonstration {
            observations: self.observations.into_iter().map(f).collect(),
            actions: self.actions,
        }
    }
}

/// The CTG node before each action and after the last: `<start>`, then
/// each action.
pub(crate) fn node_labels_of(actions: &[ActionId]) -> Vec<ActionId> {
    std::iter::once(Vocabulary::START)
        .chain(actions.iter().copied())
        .collect()
}

/// The action after each node of [`node_labels_of`]: each action, then
/// `<end>`.
pub(crate) fn next_actions_of(actions: &[ActionId]) -> Vec<ActionId> {
    actions
        .iter()
        .copied()
        .chain(std::iter::once(Vocabulary::END))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn labels_line_up_with_observations() {
        let v = Vocabulary::new(["a", "b"]).unwrap();
        let d =
            Demonstration::new(vec!['x', 'y', 'z'], v.parse_sequence("a b").unwrap(), &v).unwrap();
        let (a, b) = (v.id("a").unwrap(), v.id("b").unwrap());
        assert_eq!(d.node_labels(), [Vocabulary::START, a, b]);
        assert_eq!(d.next_actions(), [a, b, Vocabulary::END]);
        assert_eq!(d.observations().len(), d.node_labels().len());
        assert_eq!(
            d.clone().map_observations(|c| c as u32).observations()[0],
            'x' as u32
        );
    }

    #[test]
    fn rejects_invalid_demonstrations() {
        let v = Vocabulary::new(["a"]).unwrap();
        let a = v.id("a").unwrap();
        assert_eq!(
            Demonstration::<()>::new(vec![()], vec![], &v),
            Err(CtgError::EmptyDemonstration)
        );
        assert!(matches!(
            Demonstration::new(vec![(); 3], vec![a], &v),
            Err(CtgError::ObservationCount { expected: 2, .. })
        ));
        assert_eq!(
            Demonstration::new(vec![(); 2], vec![Vocabulary::END], &v),
            Err(CtgError::ReservedAction("<end>"))
        );
        assert!(matches!(
            Demonstration::new(vec![(); 2], vec![ActionId::new(7)], &v),
            Err(CtgError::ActionOutOfRange { .. })
        ));
    }
}
