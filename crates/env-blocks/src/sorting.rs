//! Object sorting tasks: eight objects of four categories (two each) go into
//! the bins their category is mapped to.

use std::collections::HashSet;

use glam::Vec2;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

use crate::error::BlocksError;
use crate::world::{Bin, NUM_OBJECTS};

/// Number of object categories.
pub const NUM_CATEGORIES: usize = 4;
/// Number of bins.
pub const NUM_BINS: usize = 4;

/// The category of object `i` (objects `2c` and `2c + 1` are category `c`).
pub const fn category_of(object: usize) -> usize {
    object / 2
}

/// The four bins, in a row beyond the objects' start rows (y = 0.16 m).
pub fn standard_bins() -> Vec<Bin> {
    [-0.18, -0.06, 0.06, 0.18]
        .into_iter()
        .map(|x| Bin {
            centre: Vec2::new(x, 0.16),
        })
        .collect()
}

/// Rows of the start grid used in sorting (the bins take the far side).
pub const SORTING_GRID_YS: [f32; 3] = [-0.2, -0.1, 0.0];

/// A sorting task: which bin each category goes to, and which objects start
/// already sorted (placed in their bins at reset).
#[derive(Debug, Clone, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub struct SortTask {
    /// The task's id, e.g. `sort_3`.
    pub id: String,
    /// `bin_of_category[c]` is the bin of category `c`.
    pub bin_of_category: [usize; NUM_CATEGORIES],
    /// Objects that start in their bins (a part-done scene).
    pub presorted: Vec<usize>,
}

impl SortTask {
    /// A validated task.
    pub fn new(
        id: impl Into<String>,
        bin_of_category: [usize; NUM_CATEGORIES],
        presorted: Vec<usize>,
    ) -> Result<Self, BlocksError> {
        if let Some(b) = bin_of_category.iter().find(|&&b| b >= NUM_BINS) {
            return Err(BlocksError::Invalid(format!(
                "bin {b} does not exist (bins 0..{NUM_BINS})"
            )));
        }
        let mut seen = HashSet::new();
        for &o in &presorted {
            if o >= NUM_OBJECTS || !seen.insert(o) {
                return Err(BlocksError::Invalid(format!(
                    "presorted object {o} is out of range or repeated"
                )));
            }
        }
        Ok(SortTask {
            id: id.into(),
            bin_of_category,
            presorted,
        })
    }

    /// The bin object `i` belongs in.
    pub fn bin_of(&self, object: usize) -> usize {
        self.bin_of_category[category_of(object) % NUM_CATEGORIES]
    }

    /// The same task with `k` random objects presorted (drawn from `seed`):
    /// a part-done scene whose remaining order differs from a full demo's.
    pub fn with_random_presorted(&self, k: usize, seed: u64) -> SortTask {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let mut objects: Vec<usize> = (0..NUM_OBJECTS).collect();
        for i in 0..objects.len() {
            let j = rng.random_range(i..objects.len());
            objects.swap(i, j);
        }
        objects.truncate(k.min(NUM_OBJECTS));
        objects.sort_unstable();
        SortTask {
            presorted: objects,
            ..self.clone()
        }
    }
}

/// `count` distinct sorting tasks (distinct category→bin maps, any map of
/// the 4⁴ = 256), ids `sort_0`.., none presorted.
pub fn generate_sort_tasks(seed: u64, count: usize) -> Result<Vec<SortTask>, BlocksError> {
    let max = NUM_BINS.pow(NUM_CATEGORIES as u32);
    if count > max {
        return Err(BlocksError::Generator(format!(
            "only {max} distinct sorting tasks exist, asked for {count}"
        )));
    }
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut seen = HashSet::new();
    let mut tasks = Vec::with_capacity(count);
    while tasks.len() < count {
        let map: [usize; NUM_CATEGORIES] = std::array::from_fn(|_| rng.random_range(0..NUM_BINS));
        if seen.insert(map) {
            tasks.push(SortTask::new(
                format!("sort_{}", tasks.len()),
                map,
                Vec::new(),
            )?);
        }
    }
    Ok(tasks)
}

/// The seed of the standard sorting task list.
pub const STANDARD_SORT_SEED: u64 = 20_190_617;

/// All 256 sorting tasks (every category→bin map) in the order drawn from
/// [`STANDARD_SORT_SEED`], ids `sort_0`..`sort_255`, none presorted.
pub fn standard_sort_tasks() -> Result<Vec<SortTask>, BlocksError> {
    generate_sort_tasks(STANDARD_SORT_SEED, NUM_BINS.pow(NUM_CATEGORIES as u32))
}
