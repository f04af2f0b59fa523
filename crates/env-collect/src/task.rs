//! Tasks (which objects go where), a seeded task generator, and a fixed
//! train/test split by task identity.

use std::fmt;

use rand::Rng;
use rand::SeedableRng;
use rand::seq::SliceRandom;
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

use crate::domain::{
    Category, MAX_OBJECTS, MIN_OBJECTS, NUM_CATEGORIES, NUM_RECEPTACLES, Receptacle,
};
use crate::{CollectError, splitmix64};

/// One target of a task: an object category and its designated receptacle.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
pub struct Target {
    /// What to collect.
    pub category: Category,
    /// Where to put it.
    pub receptacle: Receptacle,
}

/// An object-collection task: N ∈ [1, 6] targets of distinct categories,
/// each with its designated drop-off receptacle (receptacles may repeat).
///
/// A task is a *set* of targets: they are kept sorted by category, so two
/// tasks with the same targets are equal and have the same [`Task::code`].
/// Deserialisation validates like [`Task::new`].
#[derive(Debug, Clone, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(try_from = "TaskRepr", into = "TaskRepr")]
pub struct Task {
    targets: Vec<Target>,
}

#[derive(Serialize, Deserialize)]
struct TaskRepr {
    targets: Vec<Target>,
}

impl TryFrom<TaskRepr> for Task {
    type Error = CollectError;
    fn try_from(repr: TaskRepr) -> Result<Self, CollectError> {
        Task::new(repr.targets)
    }
}

impl From<Task> for TaskRepr {
    fn from(task: Task) -> Self {
        TaskRepr {
            targets: task.targets,
        }
    }
}

impl Task {
    /// A task of these targets (any order). Errors unless there are 1 to 6
    /// targets with distinct categories.
    pub fn new(mut targets: Vec<Target>) -> Result<Task, CollectError> {
        if !(MIN_OBJECTS..=MAX_OBJECTS).contains(&targets.len()) {
            return Err(CollectError::InvalidTask(format!(
                "a task has {MIN_OBJECTS} to {MAX_OBJECTS} targets, got {}",
                targets.len()
            )));
        }
        targets.sort();
        if let Some(w) = targets.windows(2).find(|w| w[0].category == w[1].category) {
            return Err(CollectError::InvalidTask(format!(
                "category {} appears twice",
                w[0].category
            )));
        }
        Ok(Task { targets })
    }

    /// The targets, sorted by category.
    pub fn targets(&self) -> &[Target] {
        &self.targets
    }

    /// Number of targets, N.
    pub fn num_objects(&self) -> usize {
        self.targets.len()
    }

    /// Number of search locations of its scenes, M = N + 3.
    pub fn num_locations(&self) -> usize {
        self.targets.len() + crate::domain::EXTRA_LOCATIONS
    }

    /// The designated receptacle of `category`, if it is a target.
    pub fn receptacle_of(&self, category: Category) -> Option<Receptacle> {
        self.targets
            .iter()
            .find(|t| t.category == category)
            .map(|t| t.receptacle)
    }

    /// Whether `category` is one of the targets.
    pub fn is_target(&self, category: Category) -> bool {
        self.receptacle_of(category).is_some()
    }

    /// The task's identity as a number: digit `c` in base 6 is 0 if category
    /// `c` is not a target, else 1 + its receptacle's index. Distinct tasks
    /// have distinct codes; codes are below 6⁸.
    pub fn code(&self) -> u32 {
        let mut digits = [0u32; NUM_CATEGORIES];
        for t in &self.targets {
            digits[t.category.index()] = 1 + t.receptacle.index() as u32;
        }
        digits
            .iter()
            .rev()
            .fold(0, |acc, &d| acc * (NUM_RECEPTACLES as u32 + 1) + d)
    }

    /// The task with this code, if it is a valid one (see [`Task::code`]).
    pub fn from_code(code: u32) -> Option<Task> {
        let base = NUM_RECEPTACLES as u32 + 1;
        let mut rest = code;
        let mut targets = Vec::new();
        for category in Category::ALL {
            let digit = rest % base;
            rest /= base;
            if digit > 0 {
                targets.push(Target {
                    category,
                    receptacle: Receptacle::from_index(digit as usize - 1)?,
                });
            }
        }
        if rest != 0 {
            return None;
        }
        Task::new(targets).ok()
    }

    /// A uniformly random task with `n` targets: `n` distinct categories,
    /// each with a uniformly random receptacle. Errors if `n` is not in
    /// [1, 6].
    pub fn random<R: Rng + ?Sized>(n: usize, rng: &mut R) -> Result<Task, CollectError> {
        check_objects(n)?;
        let mut categories = Category::ALL;
        categories.shuffle(rng);
        let targets = categories[..n]
            .iter()
            .map(|&category| Target {
                category,
                receptacle: Receptacle::ALL[rng.random_range(0..NUM_RECEPTACLES)],
            })
            .collect();
        Task::new(targets)
    }

    /// Number of distinct tasks with `n` targets: C(8, n) · 5ⁿ.
    pub fn count_with(n: usize) -> usize {
        if !(MIN_OBJECTS..=MAX_OBJECTS).contains(&n) {
            return 0;
        }
        let choose = (0..n).fold(1usize, |acc, i| acc * (NUM_CATEGORIES - i) / (i + 1));
        choose * NUM_RECEPTACLES.pow(n as u32)
    }
}

impl fmt::Display for Task {
    /// `Apple->Fridge Egg->Sink`.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        for (i, t) in self.targets.iter().enumerate() {
            if i > 0 {
                f.write_str(" ")?;
            }
            write!(f, "{}->{}", t.category, t.receptacle)?;
        }
        Ok(())
    }
}

fn check_objects(n: usize) -> Result<(), CollectError> {
    if (MIN_OBJECTS..=MAX_OBJECTS).contains(&n) {
        Ok(())
    } else {
        Err(CollectError::InvalidTask(format!(
            "the number of objects must be in [{MIN_OBJECTS}, {MAX_OBJECTS}], got {n}"
        )))
    }
}

/// Which side of the train/test split a task is on.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Split {
    /// Tasks the models may be trained on.
    Train,
    /// Held-out tasks, for evaluation only.
    Test,
}

/// A fixed split of all tasks into train and test by task identity: a task
/// is a test task when a hash of its [`Task::code`] (mixed with `salt`)
/// falls below `test_fraction`. Every task is on exactly one side whatever
/// its N, so train and test sets drawn through the same splitter are
/// disjoint by construction.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct TaskSplitter {
    /// Share of tasks (in expectation) on the test side, in [0, 1].
    pub test_fraction: f64,
    /// Changes which tasks are held out.
    pub salt: u64,
}

impl Default for TaskSplitter {
    /// A quarter of the tasks held out, salt 0.
    fn default() -> Self {
        TaskSplitter {
            test_fraction: 0.25,
            salt: 0,
        }
    }
}

impl TaskSplitter {
    /// A splitter; errors unless `test_fraction` is a number in [0, 1].
    pub fn new(test_fraction: f64, salt: u64) -> Result<Self, CollectError> {
        if !(0.0..=1.0).contains(&test_fraction) {
            return Err(CollectError::InvalidConfig(format!(
                "test_fraction must be in [0, 1], got {test_fraction}"
            )));
        }
        Ok(TaskSplitter {
            test_fraction,
            salt,
        })
    }

    /// The side `task` is on.
    pub fn split_of(&self, task: &Task) -> Split {
        let h = splitmix64(u64::from(task.code()) ^ splitmix64(self.salt));
        // 53 high bits to a uniform number in [0, 1).
        let u = (h >> 11) as f64 / (1u64 << 53) as f64;
        if u < self.test_fraction {
            Split::Test
        } else {
            Split::Train
        }
    }

    /// Every task with `n` targets on side `split` (`None`: both sides), in
    /// increasing code order.
    pub fn tasks_with(&self, n: usize, split: Option<Split>) -> Result<Vec<Task>, CollectError> {
        check_objects(n)?;
        let base = NUM_RECEPTACLES as u32 + 1;
        let mut tasks = Vec::with_capacity(Task::count_with(n));
        for code in 0..base.pow(NUM_CATEGORIES as u32) {
            // Count non-zero base-6 digits without building the task.
            let (mut rest, mut nonzero) = (code, 0);
            while rest > 0 {
                nonzero += usize::from(rest % base != 0);
                rest /= base;
            }
            if nonzero != n {
                continue;
            }
            let Some(task) = Task::from_code(code) else {
                continue;
            };
            if split.is_none_or(|s| self.split_of(&task) == s) {
                tasks.push(task);
            }
        }
        Ok(tasks)
    }

    /// One random task with `n` targets on side `split` (`None`: either).
    /// Errors if `n` is out of range or that side has no task with `n`
    /// targets.
    pub fn sample<R: Rng + ?Sized>(
        &self,
        n: usize,
        split: Option<Split>,
        rng: &mut R,
    ) -> Result<Task, CollectError> {
        check_objects(n)?;
        // Rejection sampling is exact and fast unless a side is (nearly) empty.
        for _ in 0..10_000 {
            let task = Task::random(n, rng)?;
            if split.is_none_or(|s| self.split_of(&task) == s) {
                return Ok(task);
            }
        }
        let pool = self.tasks_with(n, split)?;
        pool.get(rng.random_range(0..pool.len().max(1)))
            .cloned()
            .ok_or_else(|| {
                CollectError::InvalidTask(format!("no task with {n} objects on the {split:?} side"))
            })
    }

    /// `count` distinct tasks with `n` targets on side `split`, drawn without
    /// replacement with `ChaCha8Rng::seed_from_u64(seed)`. Errors if fewer
    /// exist.
    pub fn sample_distinct(
        &self,
        n: usize,
        count: usize,
        split: Option<Split>,
        seed: u64,
    ) -> Result<Vec<Task>, CollectError> {
        let mut pool = self.tasks_with(n, split)?;
        if count > pool.len() {
            return Err(CollectError::InvalidTask(format!(
                "asked for {count} distinct tasks with {n} objects on the {} side, only {} exist",
                split.map_or("any", |s| if s == Split::Train { "train" } else { "test" }),
                pool.len()
            )));
        }
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let (chosen, _) = pool.partial_shuffle(&mut rng, count);
        Ok(chosen.to_vec())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn t(c: Category, r: Receptacle) -> Target {
        Target {
            category: c,
            receptacle: r,
        }
    }

    #[test]
    fn tasks_are_validated_and_canonical() {
        let a = Task::new(vec![
            t(Category::Egg, Receptacle::Sink),
            t(Category::Apple, Receptacle::Fridge),
        ])
        .unwrap();
        let b = Task::new(vec![
            t(Category::Apple, Receptacle::Fridge),
            t(Category::Egg, Receptacle::Sink),
        ])
        .unwrap();
        assert_eq!(a, b);
        assert_eq!(a.code(), b.code());
        assert_eq!(a.to_string(), "Apple->Fridge Egg->Sink");
        assert!(Task::new(vec![]).is_err());
        assert!(
            Task::new(vec![
                t(Category::Egg, Receptacle::Sink),
                t(Category::Egg, Receptacle::Fridge)
            ])
            .is_err()
        );
        let seven = Category::ALL[..MAX_OBJECTS + 1]
            .iter()
            .map(|&c| t(c, Receptacle::Sink))
            .collect();
        assert!(Task::new(seven).is_err());
    }

    #[test]
    fn codes_round_trip_and_counts_match() {
        let splitter = TaskSplitter::default();
        for n in 1..=3 {
            let all = splitter.tasks_with(n, None).unwrap();
            assert_eq!(all.len(), Task::count_with(n));
            for task in all.iter().step_by(37) {
                assert_eq!(Task::from_code(task.code()).as_ref(), Some(task));
            }
        }
        assert_eq!(Task::count_with(1), 40);
        assert_eq!(Task::count_with(2), 700);
        assert_eq!(Task::from_code(6u32.pow(8)), None);
        assert!(splitter.tasks_with(0, None).is_err());
    }

    #[test]
    fn split_sides_are_disjoint_and_cover_everything() {
        let splitter = TaskSplitter::default();
        let train = splitter.tasks_with(2, Some(Split::Train)).unwrap();
        let test = splitter.tasks_with(2, Some(Split::Test)).unwrap();
        assert_eq!(train.len() + test.len(), 700);
        assert!(train.iter().all(|x| !test.contains(x)));
        // Roughly a quarter held out (binomial, 700 draws: sd ≈ 11.5).
        assert!((120..230).contains(&test.len()), "{}", test.len());
    }

    #[test]
    fn sampling_is_seeded_and_respects_the_split() {
        let splitter = TaskSplitter::default();
        let a = splitter
            .sample_distinct(4, 50, Some(Split::Test), 7)
            .unwrap();
        let b = splitter
            .sample_distinct(4, 50, Some(Split::Test), 7)
            .unwrap();
        let c = splitter
            .sample_distinct(4, 50, Some(Split::Test), 8)
            .unwrap();
        assert_eq!(a, b);
        assert_ne!(a, c);
        assert!(
            a.iter()
                .all(|x| splitter.split_of(x) == Split::Test && x.num_objects() == 4)
        );
        let mut codes: Vec<u32> = a.iter().map(Task::code).collect();
        codes.sort_unstable();
        codes.dedup();
        assert_eq!(codes.len(), 50);
        assert!(splitter.sample_distinct(1, 41, None, 0).is_err());

        let mut rng = ChaCha8Rng::seed_from_u64(3);
        for _ in 0..20 {
            let task = splitter.sample(2, Some(Split::Train), &mut rng).unwrap();
            assert_eq!(splitter.split_of(&task), Split::Train);
        }
        assert!(splitter.sample(MAX_OBJECTS + 1, None, &mut rng).is_err());
        assert!(splitter.sample(0, None, &mut rng).is_err());
        assert!(TaskSplitter::new(1.5, 0).is_err());
        assert!(TaskSplitter::new(f64::NAN, 0).is_err());
    }

    #[test]
    fn serde_validates() {
        let task = Task::new(vec![t(Category::Knife, Receptacle::Cabinet)]).unwrap();
        let json = serde_json::to_string(&task).unwrap();
        assert_eq!(serde_json::from_str::<Task>(&json).unwrap(), task);
        let bad = r#"{"targets":[]}"#;
        assert!(serde_json::from_str::<Task>(bad).is_err());
    }
}
