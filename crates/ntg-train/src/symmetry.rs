//! Renaming a domain's interchangeable objects (block stacking's cubes) in
//! a training demo: observation columns, actions and task graph together.
//! Not in the paper: for domains whose dynamics do not depend on object
//! identity, it shows the networks many more task configurations than were
//! demonstrated.

use anyhow::bail;
use ctg_graph::{ActionId, Ctg};
use rand::Rng;
use rand::seq::SliceRandom;
use serde::{Deserialize, Serialize};

/// How a domain's observations and actions change when its objects are
/// renamed: object `i`'s observation columns are
/// `obs_offset + obs_stride * i ..` (`obs_stride` of them), and each action
/// family (say `pick(·)`) lists its action id for every object. Columns and
/// actions outside these are left alone.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct ObjectSymmetry {
    /// Number of interchangeable objects.
    pub num_objects: usize,
    /// First observation column of object 0.
    pub obs_offset: usize,
    /// Observation columns per object.
    pub obs_stride: usize,
    /// Per family, the action id of each object (`num_objects` each).
    pub action_families: Vec<Vec<ActionId>>,
}

/// Most renamings [`ObjectSymmetry::random_accepted`] draws before it gives
/// up.
pub const MAX_RENAMING_DRAWS: usize = 10_000;

/// Decides whether a renaming `perm` (object `i` becomes `perm[i]`) of a
/// demo of dataset task `task` may be trained on (see
/// [`crate::method::ntg::NtgTraining::accept_renaming`]).
pub type RenamingFilter<'a> = &'a (dyn Fn(usize, &[usize]) -> bool + Sync);

/// One renaming of the objects: object `i` becomes `perm[i]`.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Relabeling {
    perm: Vec<usize>,
    /// Action id -> renamed action id, over the whole vocabulary.
    actions: Vec<ActionId>,
}

impl ObjectSymmetry {
    /// Checks the description against a vocabulary of `num_actions` and
    /// rows of `obs_dim` values.
    pub fn validate(&self, num_actions: usize, obs_dim: usize) -> anyhow::Result<()> {
        if self.obs_offset + self.obs_stride * self.num_objects > obs_dim {
            bail!(
                "the object symmetry covers columns up to {}, rows have {obs_dim}",
                self.obs_offset + self.obs_stride * self.num_objects
            );
        }
        for family in &self.action_families {
            if family.len() != self.num_objects {
                bail!(
                    "an action family of the object symmetry lists {} actions for {} objects",
                    family.len(),
                    self.num_objects
                );
            }
            if let Some(a) = family.iter().find(|a| a.index() >= num_actions) {
                bail!("the object symmetry names action {a:?}; the vocabulary has {num_actions}");
            }
        }
        Ok(())
    }

    /// A uniformly random renaming.
    pub fn random(&self, num_actions: usize, rng: &mut impl Rng) -> Relabeling {
        let mut perm: Vec<usize> = (0..self.num_objects).collect();
        perm.shuffle(rng);
        self.relabeling(perm, num_actions)
    }

    /// A uniformly random renaming among those `accept` takes: drawn again
    /// until one is accepted, an error after [`MAX_RENAMING_DRAWS`] draws.
    pub fn random_accepted(
        &self,
        num_actions: usize,
        rng: &mut impl Rng,
        accept: impl Fn(&[usize]) -> bool,
    ) -> anyhow::Result<Relabeling> {
        for _ in 0..MAX_RENAMING_DRAWS {
            let relabeling = self.random(num_actions, rng);
            if accept(&relabeling.perm) {
                return Ok(relabeling);
            }
        }
        bail!("no acceptable renaming of the objects in {MAX_RENAMING_DRAWS} draws")
    }

    /// The renaming `perm` (object `i` becomes `perm[i]`).
    pub fn relabeling(&self, perm: Vec<usize>, num_actions: usize) -> Relabeling {
        let mut actions: Vec<ActionId> = (0..num_actions).map(ActionId::new).collect();
        for family in &self.action_families {
            for (i, &a) in family.iter().enumerate() {
                actions[a.index()] = family[perm[i]];
            }
        }
        Relabeling { perm, actions }
    }

    /// `row` with object `i`'s columns moved to object `perm[i]`'s place.
    pub fn apply_to_row(&self, relabeling: &Relabeling, row: &[f32]) -> Vec<f32> {
        let mut out = row.to_vec();
        let w = self.obs_stride;
        for (i, &j) in relabeling.perm.iter().enumerate() {
            let from = self.obs_offset + w * i;
            let to = self.obs_offset + w * j;
            out[to..to + w].copy_from_slice(&row[from..from + w]);
        }
        out
    }
}

impl Relabeling {
    /// The renaming: object `i` becomes `perm()[i]`.
    pub fn perm(&self) -> &[usize] {
        &self.perm
    }

    /// The renamed action.
    pub fn action(&self, a: ActionId) -> ActionId {
        self.actions[a.index()]
    }

    /// The renamed action sequence.
    pub fn sequence(&self, actions: &[ActionId]) -> Vec<ActionId> {
        actions.iter().map(|&a| self.action(a)).collect()
    }

    /// The graph with its nodes renamed.
    pub fn graph(&self, graph: &Ctg) -> anyhow::Result<Ctg> {
        let mut out = Ctg::empty(graph.num_nodes());
        for e in graph.edges() {
            out.set_weight(self.action(e.from), self.action(e.to), e.weight)?;
        }
        Ok(out)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;

    #[test]
    fn accepted_renamings_are_drawn_again_until_accepted() {
        let sym = ObjectSymmetry {
            num_objects: 4,
            obs_offset: 0,
            obs_stride: 1,
            action_families: vec![(0..4).map(ActionId::new).collect()],
        };
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        for _ in 0..50 {
            let r = sym
                .random_accepted(5, &mut rng, |perm| perm[0] == 0)
                .unwrap();
            assert_eq!(r.perm[0], 0);
        }
        let err = sym
            .random_accepted(5, &mut rng, |_| false)
            .unwrap_err()
            .to_string();
        assert!(err.contains("no acceptable renaming"), "{err}");
    }
}
