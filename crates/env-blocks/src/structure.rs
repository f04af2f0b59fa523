//! A benchmark of generalisation to new task *structures* (issue 66): the
//! structures a block-stacking task can have, split into training,
//! validation and test sets that share none, plus a set of taller towers
//! than any training structure has.
//!
//! A structure is a task with its cube names ignored
//! ([`StackTask::structure_key`]): how many goals each tower has, tower by
//! tower. With eight cubes there are 33: the 23 whose towers have two to
//! four cubes (every structure of the standard set) and 10 with a tower of
//! five cubes or more. [`StructureBenchmark::new`] splits the 23 by a
//! seeded shuffle into training, validation and test structures (the
//! training ones holding a four-cube tower, so that the test set's heights
//! are all seen in training), and the 10 into 2 more validation structures
//! and the 8 of the taller test set: model selection sees towers taller
//! than any trained on, never one of those it is tested on.
//! [`StructureBenchmark::tasks`] draws any number of tasks of a set, spread
//! evenly over its structures, cubes assigned by a random permutation:
//! unlike the standard set, no structure is short of tasks.

use std::collections::HashSet;

use rand::SeedableRng;
use rand::seq::SliceRandom;
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

use crate::error::BlocksError;
use crate::task::{StackTask, random_cube_order, tower_goals};
use crate::world::NUM_OBJECTS;

/// The seed of the committed benchmark's split of structures.
pub const STRUCTURE_BENCHMARK_SEED: u64 = 20_261_206;
/// Most goals per tower in the standard set (a tower of four cubes).
pub const STANDARD_MAX_GOALS_PER_TOWER: usize = 3;
/// Validation structures of the benchmark.
pub const VALIDATION_STRUCTURES: usize = 4;
/// Test structures (heights seen in training) of the benchmark.
pub const TEST_STRUCTURES: usize = 6;
/// Structures with a taller tower than training's that validate instead
/// of testing.
pub const TALLER_VALIDATION_STRUCTURES: usize = 2;
/// Draws in a row without a new end configuration after which a structure
/// leaves [`StructureBenchmark::tasks`]'s turn.
pub const DRAWS_PER_TASK: usize = 200;

/// The sets of [`StructureBenchmark`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum StructureSet {
    /// Structures the training tasks have.
    Train,
    /// Structures model selection sees (none trained on, none tested).
    Validation,
    /// New structures whose towers are no taller than training ones.
    Test,
    /// Structures with a tower taller than any training structure's.
    Taller,
}

impl StructureSet {
    /// Every set, in order.
    pub const ALL: [StructureSet; 4] = [
        StructureSet::Train,
        StructureSet::Validation,
        StructureSet::Test,
        StructureSet::Taller,
    ];

    /// Its name in task ids and reports: `train`, `validation`, `test`,
    /// `taller`.
    pub fn name(self) -> &'static str {
        match self {
            StructureSet::Train => "train",
            StructureSet::Validation => "validation",
            StructureSet::Test => "test",
            StructureSet::Taller => "taller",
        }
    }
}

/// Every structure of at most [`NUM_OBJECTS`] cubes as a composition: the
/// number of goals of each tower, in tower order (each at least one; a
/// tower of `g` goals has `g + 1` cubes).
pub fn all_compositions() -> Vec<Vec<usize>> {
    fn extend(prefix: &mut Vec<usize>, cubes_left: usize, out: &mut Vec<Vec<usize>>) {
        if !prefix.is_empty() {
            out.push(prefix.clone());
        }
        for g in 1..cubes_left {
            prefix.push(g);
            extend(prefix, cubes_left - g - 1, out);
            prefix.pop();
        }
    }
    let mut out = Vec::new();
    extend(&mut Vec::new(), NUM_OBJECTS, &mut out);
    out
}

/// Training, validation, test and taller structures, pairwise disjoint.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct StructureBenchmark {
    /// The seed the structures were split with.
    pub seed: u64,
    /// Training structures (compositions, see [`all_compositions`]).
    pub train: Vec<Vec<usize>>,
    /// Validation structures: of standard heights, then taller ones.
    pub validation: Vec<Vec<usize>>,
    /// Test structures, towers no taller than the training ones'.
    pub test: Vec<Vec<usize>>,
    /// Test structures with a tower of five cubes or more.
    pub taller: Vec<Vec<usize>>,
}

impl StructureBenchmark {
    /// Splits the structures with `seed` (see the module's text).
    pub fn new(seed: u64) -> Self {
        let (mut standard, mut taller): (Vec<Vec<usize>>, Vec<Vec<usize>>) = all_compositions()
            .into_iter()
            .partition(|c| c.iter().all(|&g| g <= STANDARD_MAX_GOALS_PER_TOWER));
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        standard.shuffle(&mut rng);
        taller.shuffle(&mut rng);
        // The first structure with a four-cube tower trains, so every test
        // height is a training height.
        let tallest = standard
            .iter()
            .position(|c| c.contains(&STANDARD_MAX_GOALS_PER_TOWER))
            .unwrap_or(0);
        let anchor = standard.remove(tallest);
        let mut validation: Vec<Vec<usize>> = standard.drain(..VALIDATION_STRUCTURES).collect();
        validation.extend(taller.drain(..TALLER_VALIDATION_STRUCTURES));
        let test: Vec<Vec<usize>> = standard.drain(..TEST_STRUCTURES).collect();
        let mut train = vec![anchor];
        train.extend(standard);
        StructureBenchmark {
            seed,
            train,
            validation,
            test,
            taller,
        }
    }

    /// The structures of `set`.
    pub fn structures(&self, set: StructureSet) -> &[Vec<usize>] {
        match set {
            StructureSet::Train => &self.train,
            StructureSet::Validation => &self.validation,
            StructureSet::Test => &self.test,
            StructureSet::Taller => &self.taller,
        }
    }

    /// `count` tasks of `set` (ids `SET_0`..), its structures taken in
    /// turn, cubes assigned by a random permutation drawn from `seed`; end
    /// configurations distinct (a draw that repeats one is drawn again). A
    /// structure with few configurations (a single two-cube tower has 56)
    /// leaves the turn once [`DRAWS_PER_TASK`] draws in a row find none new.
    pub fn tasks(
        &self,
        set: StructureSet,
        count: usize,
        seed: u64,
    ) -> Result<Vec<StackTask>, BlocksError> {
        let structures = self.structures(set);
        if structures.is_empty() {
            return Err(BlocksError::Generator(format!(
                "the {} set has no structure",
                set.name()
            )));
        }
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let mut configurations = HashSet::new();
        let mut tasks = Vec::with_capacity(count);
        let mut in_turn: Vec<&Vec<usize>> = structures.iter().collect();
        let mut next = 0;
        while tasks.len() < count {
            if in_turn.is_empty() {
                return Err(BlocksError::Generator(format!(
                    "the {} set's structures have only {} distinct end configurations; asked for {count}",
                    set.name(),
                    tasks.len()
                )));
            }
            let composition = in_turn[next % in_turn.len()];
            let mut found = false;
            for _ in 0..DRAWS_PER_TASK {
                let cubes = random_cube_order(&mut rng);
                let task = StackTask::new(
                    format!("{}_{}", set.name(), tasks.len()),
                    tower_goals(composition, &cubes),
                )
                .map_err(BlocksError::Generator)?;
                if configurations.insert(task.configuration_key()) {
                    tasks.push(task);
                    found = true;
                    break;
                }
            }
            if found {
                next += 1;
            } else {
                in_turn.remove(next % in_turn.len());
            }
        }
        Ok(tasks)
    }

    /// Which set `task`'s structure belongs to.
    pub fn set_of(&self, task: &StackTask) -> Option<StructureSet> {
        let key = task.structure_key();
        let identity: Vec<usize> = (0..NUM_OBJECTS).collect();
        StructureSet::ALL.into_iter().find(|&set| {
            self.structures(set).iter().any(|c| {
                StackTask::new(String::new(), tower_goals(c, &identity))
                    .is_ok_and(|t| t.structure_key() == key)
            })
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::task::standard_tasks;

    #[test]
    fn the_sets_are_disjoint_and_cover_every_structure() {
        let all = all_compositions();
        assert_eq!(all.len(), 33);
        let b = StructureBenchmark::new(STRUCTURE_BENCHMARK_SEED);
        assert_eq!(
            (
                b.train.len(),
                b.validation.len(),
                b.test.len(),
                b.taller.len()
            ),
            (
                13,
                VALIDATION_STRUCTURES + TALLER_VALIDATION_STRUCTURES,
                TEST_STRUCTURES,
                10 - TALLER_VALIDATION_STRUCTURES
            )
        );
        let mut seen = HashSet::new();
        for set in StructureSet::ALL {
            for c in b.structures(set) {
                assert!(seen.insert(c.clone()), "{c:?} in two sets");
            }
        }
        assert_eq!(seen.len(), all.len());
        // Test heights are training heights; the taller set's are not.
        let tallest = |cs: &[Vec<usize>]| cs.iter().flatten().copied().max().unwrap();
        assert!(tallest(&b.test) <= tallest(&b.train));
        let (standard, taller) = b.validation.split_at(VALIDATION_STRUCTURES);
        assert!(tallest(standard) <= tallest(&b.train));
        let above = |c: &Vec<usize>| c.iter().any(|&g| g > tallest(&b.train));
        assert!(taller.iter().all(above));
        assert!(b.taller.iter().all(above));
        // Another seed, another split of the same structures.
        let other = StructureBenchmark::new(1);
        assert_ne!(other.test, b.test);
        assert_eq!(other, StructureBenchmark::new(1));
    }

    #[test]
    fn tasks_are_of_their_set_spread_over_its_structures_and_distinct() {
        let b = StructureBenchmark::new(STRUCTURE_BENCHMARK_SEED);
        for set in StructureSet::ALL {
            let tasks = b.tasks(set, 120, 3).unwrap();
            assert_eq!(tasks, b.tasks(set, 120, 3).unwrap());
            assert_eq!(tasks[0].id, format!("{}_0", set.name()));
            let keys: HashSet<_> = tasks.iter().map(StackTask::configuration_key).collect();
            assert_eq!(keys.len(), 120);
            for t in &tasks {
                assert_eq!(b.set_of(t), Some(set), "{}", t.describe());
            }
            let structures: HashSet<_> = tasks.iter().map(StackTask::structure_key).collect();
            assert_eq!(structures.len(), b.structures(set).len());
        }
        // A thousand of each set, though some structures have few
        // configurations: those leave the turn, the others fill it.
        for set in StructureSet::ALL {
            let many = b.tasks(set, 1000, 5).unwrap();
            let keys: HashSet<_> = many.iter().map(StackTask::configuration_key).collect();
            assert_eq!(keys.len(), 1000, "{}", set.name());
        }
        // Every standard task's structure is in one of the three sets of
        // standard heights.
        for t in standard_tasks().unwrap().iter().take(200) {
            assert_ne!(b.set_of(t), Some(StructureSet::Taller), "{}", t.describe());
            assert!(b.set_of(t).is_some());
        }
    }
}
