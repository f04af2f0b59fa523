//! Block-stacking tasks: the NTP task-file format (reader and writer), task
//! statistics, the seeded generator and the standard train/test split.
//!
//! A task is an ordered list of `pick_place(src, target)` goals; its end
//! constraints are `on_top(src, target)` for each goal. NTP's goals build one
//! tower at a time, bottom-up.

use std::collections::{BTreeMap, HashSet};
use std::path::Path;

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

use crate::error::BlocksError;
use crate::world::NUM_OBJECTS;

/// One `pick_place(src, target)` goal: put cube `src` on cube `target`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
pub struct Goal {
    /// The cube to move.
    pub src: usize,
    /// The cube it goes on.
    pub target: usize,
}

/// A block-stacking task.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct StackTask {
    /// The task's id, e.g. `stack_17`.
    pub id: String,
    /// The ordered goals; the end constraints are `on_top` of each.
    pub goals: Vec<Goal>,
}

/// The letter of cube `i` (`A` + i), `?` past `Z`.
pub fn cube_letter(i: usize) -> char {
    u8::try_from(i)
        .ok()
        .filter(|&b| b < 26)
        .map_or('?', |b| (b'A' + b) as char)
}

/// The NTP name of cube `i` (`cube_i`).
pub fn cube_name(i: usize) -> String {
    format!("cube_{i}")
}

fn parse_cube_name(name: &str) -> Option<usize> {
    let i: usize = name.strip_prefix("cube_")?.parse().ok()?;
    (i < NUM_OBJECTS).then_some(i)
}

impl StackTask {
    /// A task from goals, validated: at least one goal, cubes in range, no
    /// cube on itself, no cube moved twice or given two cubes on top, no
    /// cycle.
    pub fn new(id: impl Into<String>, goals: Vec<Goal>) -> Result<Self, String> {
        let task = StackTask {
            id: id.into(),
            goals,
        };
        task.validate()?;
        Ok(task)
    }

    fn validate(&self) -> Result<(), String> {
        if self.goals.is_empty() {
            return Err("a task needs at least one goal".into());
        }
        let mut srcs = HashSet::new();
        let mut targets = HashSet::new();
        for g in &self.goals {
            if g.src >= NUM_OBJECTS || g.target >= NUM_OBJECTS {
                return Err(format!("goal {g:?} names a cube outside 0..{NUM_OBJECTS}"));
            }
            if g.src == g.target {
                return Err(format!("goal puts cube_{} on itself", g.src));
            }
            if !srcs.insert(g.src) {
                return Err(format!("cube_{} is the src of two goals", g.src));
            }
            if !targets.insert(g.target) {
                return Err(format!("cube_{} is the target of two goals", g.target));
            }
        }
        // With unique srcs and targets the "on" relation is a set of chains
        // and cycles; a cycle has no bottom cube.
        for tower in self.towers_unchecked() {
            if tower.len() < 2 {
                return Err("the goals contain a cycle".into());
            }
        }
        let in_towers: usize = self.towers_unchecked().iter().map(|t| t.len() - 1).sum();
        if in_towers != self.goals.len() {
            return Err("the goals contain a cycle".into());
        }
        Ok(())
    }

    fn towers_unchecked(&self) -> Vec<Vec<usize>> {
        let on: BTreeMap<usize, usize> = self.goals.iter().map(|g| (g.target, g.src)).collect();
        let srcs: HashSet<usize> = self.goals.iter().map(|g| g.src).collect();
        // Bottoms: targets that are not srcs, in order of first appearance.
        let mut bottoms = Vec::new();
        for g in &self.goals {
            if !srcs.contains(&g.target) && !bottoms.contains(&g.target) {
                bottoms.push(g.target);
            }
        }
        bottoms
            .into_iter()
            .map(|b| {
                let mut tower = vec![b];
                let mut c = b;
                while let Some(&next) = on.get(&c) {
                    if tower.len() > NUM_OBJECTS {
                        break;
                    }
                    tower.push(next);
                    c = next;
                }
                tower
            })
            .collect()
    }

    /// The towers, each bottom-up, in order of their first goal.
    pub fn towers(&self) -> Vec<Vec<usize>> {
        self.towers_unchecked()
    }

    /// The goals regrouped tower by tower, bottom-up (NTP's order); for an
    /// NTP-ordered task this equals `goals`.
    pub fn goals_by_tower(&self) -> Vec<Vec<Goal>> {
        self.towers()
            .iter()
            .map(|t| {
                t.windows(2)
                    .map(|w| Goal {
                        src: w[1],
                        target: w[0],
                    })
                    .collect()
            })
            .collect()
    }

    /// Human-readable form, e.g. `B>A C>B E>D` ("B on A", ...).
    pub fn describe(&self) -> String {
        self.goals
            .iter()
            .map(|g| format!("{}>{}", cube_letter(g.src), cube_letter(g.target)))
            .collect::<Vec<_>>()
            .join(" ")
    }

    /// The task's structure: its goals with the cubes renamed in order of
    /// first appearance, so `B>A C>B` and `E>D F>E` share one (what a task
    /// is once cube names are ignored). Each pair is `(src, target)`.
    pub fn structure_key(&self) -> Vec<(usize, usize)> {
        let mut names: Vec<usize> = Vec::new();
        let mut rename = |cube: usize| match names.iter().position(|&n| n == cube) {
            Some(i) => i,
            None => {
                names.push(cube);
                names.len() - 1
            }
        };
        self.goals
            .iter()
            .map(|g| {
                let src = rename(g.src);
                (src, rename(g.target))
            })
            .collect()
    }

    /// A key equal for tasks with the same end configuration (the same
    /// towers, in any order).
    pub fn configuration_key(&self) -> Vec<Vec<usize>> {
        let mut towers = self.towers();
        towers.sort();
        towers
    }
}

// ---------------------------------------------------------------------------
// NTP file format.

#[derive(Debug, Serialize, Deserialize)]
struct NtpGoal {
    name: String,
    src: String,
    target: String,
}

#[derive(Debug, Serialize, Deserialize)]
struct NtpConstraint {
    #[serde(rename = "type")]
    kind: String,
    src: String,
    target: String,
}

#[derive(Debug, Serialize, Deserialize)]
struct NtpTask {
    #[serde(default)]
    end_constraints: Vec<NtpConstraint>,
    goals: Vec<NtpGoal>,
    id: String,
    #[serde(default)]
    name: Option<String>,
}

#[derive(Debug, Serialize, Deserialize)]
struct NtpFile {
    #[serde(default)]
    name: Option<String>,
    #[serde(default)]
    scene: Option<serde_json::Value>,
    tasks: Vec<NtpTask>,
}

/// Reads an NTP task file (such as NTP's `stack_2000.json`).
pub fn read_ntp_tasks(path: &Path) -> Result<Vec<StackTask>, BlocksError> {
    let text = std::fs::read_to_string(path).map_err(|source| BlocksError::Io {
        path: path.display().to_string(),
        source,
    })?;
    parse_ntp_tasks(&text, &path.display().to_string())
}

/// Parses the text of an NTP task file; `source` names it in errors.
///
/// Checks every task: known goal names (`pick_place`), cube names
/// `cube_0`..`cube_7`, valid goals (see [`StackTask::new`]), end constraints
/// of type `on_top` equal as a set to the goals (when present), unique ids.
pub fn parse_ntp_tasks(text: &str, source: &str) -> Result<Vec<StackTask>, BlocksError> {
    let file: NtpFile = serde_json::from_str(text).map_err(|e| BlocksError::Json {
        path: source.to_owned(),
        line: e.line(),
        column: e.column(),
        message: e.to_string(),
    })?;
    let mut ids = HashSet::new();
    let mut tasks = Vec::with_capacity(file.tasks.len());
    for (index, t) in file.tasks.into_iter().enumerate() {
        let err = |message: String| BlocksError::Task {
            path: source.to_owned(),
            index,
            id: t.id.clone(),
            message,
        };
        if !ids.insert(t.id.clone()) {
            return Err(err("duplicate task id".into()));
        }
        let mut goals = Vec::with_capacity(t.goals.len());
        for (k, g) in t.goals.iter().enumerate() {
            if g.name != "pick_place" {
                return Err(err(format!(
                    "goal {k}: unknown goal `{}` (expected pick_place)",
                    g.name
                )));
            }
            let cube = |n: &str| {
                parse_cube_name(n).ok_or_else(|| {
                    err(format!(
                        "goal {k}: `{n}` is not a cube name (cube_0..cube_{})",
                        NUM_OBJECTS - 1
                    ))
                })
            };
            goals.push(Goal {
                src: cube(&g.src)?,
                target: cube(&g.target)?,
            });
        }
        if !t.end_constraints.is_empty() {
            let mut cons = Vec::with_capacity(t.end_constraints.len());
            for (k, c) in t.end_constraints.iter().enumerate() {
                if c.kind != "on_top" {
                    return Err(err(format!(
                        "end constraint {k}: unknown type `{}`",
                        c.kind
                    )));
                }
                match (parse_cube_name(&c.src), parse_cube_name(&c.target)) {
                    (Some(src), Some(target)) => cons.push(Goal { src, target }),
                    _ => return Err(err(format!("end constraint {k}: unknown cube name"))),
                }
            }
            let mut a = goals.clone();
            a.sort();
            cons.sort();
            if a != cons {
                return Err(err("end constraints differ from the goals".into()));
            }
        }
        let task = StackTask::new(t.id.clone(), goals).map_err(err)?;
        tasks.push(task);
    }
    Ok(tasks)
}

/// Writes tasks in NTP's format: NTP's scene block, then one task per line.
pub fn write_ntp_tasks(tasks: &[StackTask]) -> String {
    let mut out = String::new();
    out.push_str("{\n\"name\": \"stacking\",\n\"scene\": ");
    out.push_str(&ntp_scene().to_string());
    out.push_str(",\n\"tasks\": [\n");
    for (k, t) in tasks.iter().enumerate() {
        let task = NtpTask {
            end_constraints: t
                .goals
                .iter()
                .map(|g| NtpConstraint {
                    kind: "on_top".into(),
                    src: cube_name(g.src),
                    target: cube_name(g.target),
                })
                .collect(),
            goals: t
                .goals
                .iter()
                .map(|g| NtpGoal {
                    name: "pick_place".into(),
                    src: cube_name(g.src),
                    target: cube_name(g.target),
                })
                .collect(),
            id: t.id.clone(),
            name: Some("stack".into()),
        };
        // Serialising plain strings and vectors cannot fail.
        out.push_str(&serde_json::to_string(&task).unwrap_or_default());
        out.push_str(if k + 1 < tasks.len() { ",\n" } else { "\n" });
    }
    out.push_str("]\n}\n");
    out
}

fn ntp_scene() -> serde_json::Value {
    let objects: Vec<serde_json::Value> = (0..NUM_OBJECTS)
        .map(|i| {
            serde_json::json!({
                "boundary": [0.08, 0.08, 0.08],
                "filename": format!("cubes/cube_{i}.urdf"),
                "fixed": false,
                "name": cube_name(i),
                "pose": {"rpy": [0, 0, 0], "type": "random", "z": 0.7},
                "scale": [0.05, 0.05, 0.05]
            })
        })
        .collect();
    serde_json::json!({
        "objects": objects,
        "task_objects": (0..NUM_OBJECTS).map(cube_name).collect::<Vec<_>>(),
        "workspace": {"pos_eps": 0.03, "size": 0.1, "xlim": [-0.2, 0.2], "ylim": [-0.2, 0.2]}
    })
}

// ---------------------------------------------------------------------------
// Statistics.

/// Histograms of a task set, as NTP's README reports them.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct TaskStats {
    /// Number of tasks.
    pub tasks: usize,
    /// Number of distinct end configurations.
    pub distinct: usize,
    /// pick_place goals per task → number of tasks.
    pub goals_per_task: BTreeMap<usize, usize>,
    /// Towers per task → number of tasks.
    pub towers_per_task: BTreeMap<usize, usize>,
    /// Cubes in the tallest tower → number of tasks.
    pub tallest_tower: BTreeMap<usize, usize>,
    /// Tasks whose goals go tower by tower, bottom-up.
    pub bottom_up_tower_order: usize,
}

impl TaskStats {
    /// Statistics of `tasks`.
    pub fn of(tasks: &[StackTask]) -> TaskStats {
        let mut s = TaskStats {
            tasks: tasks.len(),
            distinct: 0,
            goals_per_task: BTreeMap::new(),
            towers_per_task: BTreeMap::new(),
            tallest_tower: BTreeMap::new(),
            bottom_up_tower_order: 0,
        };
        let mut keys = HashSet::new();
        for t in tasks {
            let towers = t.towers();
            *s.goals_per_task.entry(t.goals.len()).or_default() += 1;
            *s.towers_per_task.entry(towers.len()).or_default() += 1;
            let tallest = towers.iter().map(Vec::len).max().unwrap_or(0);
            *s.tallest_tower.entry(tallest).or_default() += 1;
            let ordered: Vec<Goal> = t.goals_by_tower().concat();
            if ordered == t.goals {
                s.bottom_up_tower_order += 1;
            }
            keys.insert(t.configuration_key());
        }
        s.distinct = keys.len();
        s
    }

    /// One line per histogram, in the words of NTP's README.
    pub fn to_text(&self) -> String {
        let h = |m: &BTreeMap<usize, usize>| {
            m.iter()
                .map(|(k, v)| format!("{k}: {v}"))
                .collect::<Vec<_>>()
                .join(", ")
        };
        format!(
            "tasks: {} ({} distinct end configurations, {} in bottom-up tower order)\n\
             pick_place goals per task {}\n\
             towers per task {}\n\
             tallest tower {} cubes\n",
            self.tasks,
            self.distinct,
            self.bottom_up_tower_order,
            h(&self.goals_per_task),
            h(&self.towers_per_task),
            h(&self.tallest_tower)
        )
    }
}

// ---------------------------------------------------------------------------
// The generator.

/// Histogram of goals per task in NTP's `stack_2000.json` (its README):
/// index k holds the number of tasks with k + 1 goals.
pub const NTP_GOALS_PER_TASK: [usize; 6] = [4, 43, 239, 689, 904, 121];
/// Histogram of towers per task in NTP's file: index k holds the number of
/// tasks with k + 1 towers.
pub const NTP_TOWERS_PER_TASK: [usize; 4] = [47, 1148, 785, 20];
/// Histogram of the tallest tower (cubes) in NTP's file: index k holds the
/// number of tasks whose tallest tower has k + 2 cubes. The generator does
/// not use it; it is what the generated set is checked against.
pub const NTP_TALLEST_TOWER: [usize; 3] = [125, 767, 1108];

/// Every (goals, towers) cell with its tower compositions: goals per tower
/// in 1..=3 (towers of 2 to 4 cubes) using at most eight cubes.
/// A (goals, towers) cell and its compositions (goals per tower).
type Cell = ((usize, usize), Vec<Vec<usize>>);

fn cells() -> Vec<Cell> {
    let mut out = Vec::new();
    for goals in 1..=NTP_GOALS_PER_TASK.len() {
        for towers in 1..=NTP_TOWERS_PER_TASK.len() {
            if goals + towers > NUM_OBJECTS {
                continue;
            }
            let mut comps = Vec::new();
            let mut stack = vec![(Vec::new(), goals)];
            while let Some((prefix, left)) = stack.pop() {
                if prefix.len() == towers {
                    if left == 0 {
                        comps.push(prefix);
                    }
                    continue;
                }
                for g in 1..=3usize.min(left) {
                    let mut p = prefix.clone();
                    p.push(g);
                    stack.push((p, left - g));
                }
            }
            if !comps.is_empty() {
                comps.sort();
                out.push(((goals, towers), comps));
            }
        }
    }
    out
}

/// The joint distribution of (goals, towers) used by the generator: the
/// maximum-entropy joint on the feasible cells whose marginals are NTP's
/// goal and tower histograms, found by iterative proportional fitting.
pub fn goal_tower_joint() -> Vec<((usize, usize), f64)> {
    let cells = cells();
    let mut p: Vec<f64> = vec![1.0; cells.len()];
    let goal_total: usize = NTP_GOALS_PER_TASK.iter().sum();
    let tower_total: usize = NTP_TOWERS_PER_TASK.iter().sum();
    for _ in 0..500 {
        for (k, &count) in NTP_GOALS_PER_TASK.iter().enumerate() {
            let want = count as f64 / goal_total as f64;
            let have: f64 = cells
                .iter()
                .zip(&p)
                .filter(|(c, _)| c.0.0 == k + 1)
                .map(|(_, v)| v)
                .sum();
            if have > 0.0 {
                for (c, v) in cells.iter().zip(p.iter_mut()) {
                    if c.0.0 == k + 1 {
                        *v *= want / have;
                    }
                }
            }
        }
        for (k, &count) in NTP_TOWERS_PER_TASK.iter().enumerate() {
            let want = count as f64 / tower_total as f64;
            let have: f64 = cells
                .iter()
                .zip(&p)
                .filter(|(c, _)| c.0.1 == k + 1)
                .map(|(_, v)| v)
                .sum();
            if have > 0.0 {
                for (c, v) in cells.iter().zip(p.iter_mut()) {
                    if c.0.1 == k + 1 {
                        *v *= want / have;
                    }
                }
            }
        }
    }
    cells.into_iter().map(|(c, _)| c).zip(p).collect()
}

/// The cubes in a random order (a Fisher-Yates shuffle drawn from `rng`):
/// how task generators assign cubes to the places of a structure.
pub(crate) fn random_cube_order(rng: &mut ChaCha8Rng) -> Vec<usize> {
    let mut cubes: Vec<usize> = (0..NUM_OBJECTS).collect();
    for i in 0..cubes.len() {
        let j = rng.random_range(i..cubes.len());
        cubes.swap(i, j);
    }
    cubes
}

/// Generates `count` block-stacking tasks with distinct end configurations,
/// ids `stack_0`.., from `seed`.
///
/// Each task: draw (goals, towers) from [`goal_tower_joint`], split the goals
/// into towers uniformly among the compositions with 1 to 3 goals per tower,
/// assign cubes by a random permutation, and order the goals tower by tower,
/// bottom-up. Tasks whose end configuration already occurred are redrawn.
pub fn generate_stack_tasks(seed: u64, count: usize) -> Result<Vec<StackTask>, BlocksError> {
    let cells = cells();
    let joint = goal_tower_joint();
    let total: f64 = joint.iter().map(|(_, p)| p).sum();
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut seen = HashSet::new();
    let mut tasks = Vec::with_capacity(count);
    let mut draws = 0usize;
    while tasks.len() < count {
        draws += 1;
        if draws > count.saturating_mul(50) + 1000 {
            return Err(BlocksError::Generator(format!(
                "could not find {count} distinct tasks in {draws} draws"
            )));
        }
        let mut u = rng.random::<f64>() * total;
        let mut cell = cells.len() - 1;
        for (k, (_, p)) in joint.iter().enumerate() {
            if u < *p {
                cell = k;
                break;
            }
            u -= p;
        }
        let comps = &cells[cell].1;
        let comp = &comps[rng.random_range(0..comps.len())];
        let cubes = random_cube_order(&mut rng);
        let mut goals = Vec::new();
        let mut next = 0;
        for &g in comp {
            let tower = &cubes[next..next + g + 1];
            next += g + 1;
            for w in tower.windows(2) {
                goals.push(Goal {
                    src: w[1],
                    target: w[0],
                });
            }
        }
        let task = StackTask::new(format!("stack_{}", tasks.len()), goals)
            .map_err(BlocksError::Generator)?;
        if seen.insert(task.configuration_key()) {
            tasks.push(task);
        }
    }
    Ok(tasks)
}

/// The seed of the committed standard task set (`datasets/blocks/`).
pub const STANDARD_SEED: u64 = 20_190_616;
/// Number of tasks in the standard set.
pub const STANDARD_TASKS: usize = 2000;
/// Size of the training pool (the first tasks of the standard set).
pub const TRAIN_POOL: usize = 1000;
/// The nested training-set sizes of the experiments.
pub const TRAIN_SIZES: [usize; 4] = [50, 100, 500, 1000];

/// The standard split: tasks `stack_0..stack_999` are the training pool
/// (the n-task training set is its first n tasks), `stack_1000..stack_1999`
/// the test tasks.
#[derive(Debug, Clone, PartialEq)]
pub struct StandardSplit {
    /// The 1000-task training pool.
    pub train_pool: Vec<StackTask>,
    /// The 1000 test tasks.
    pub test: Vec<StackTask>,
}

impl StandardSplit {
    /// The training set of the first `n` pool tasks (n ≤ 1000).
    pub fn train(&self, n: usize) -> Result<&[StackTask], BlocksError> {
        self.train_pool.get(..n).ok_or_else(|| {
            BlocksError::Generator(format!(
                "asked for {n} training tasks; the pool has {}",
                self.train_pool.len()
            ))
        })
    }
}

/// The standard task set (2000 tasks from [`STANDARD_SEED`]); equal to the
/// committed `datasets/blocks/stack_2000.json` (checked by a test).
pub fn standard_tasks() -> Result<Vec<StackTask>, BlocksError> {
    generate_stack_tasks(STANDARD_SEED, STANDARD_TASKS)
}

/// The standard split of [`standard_tasks`].
pub fn standard_split() -> Result<StandardSplit, BlocksError> {
    let mut tasks = standard_tasks()?;
    let test = tasks.split_off(TRAIN_POOL);
    Ok(StandardSplit {
        train_pool: tasks,
        test,
    })
}

/// The seed of the validation tasks (see [`validation_tasks`]).
pub const VALIDATION_SEED: u64 = 20_190_617;

/// The most validation tasks [`validation_tasks`] draws.
pub const MAX_VALIDATION_TASKS: usize = 10_000;

/// `count` (at most [`MAX_VALIDATION_TASKS`]) validation tasks, ids `val_0`..: drawn like the standard set
/// (same distribution, from [`VALIDATION_SEED`]) but with end
/// configurations that occur nowhere in the standard set, so a trainer can
/// select among checkpoints on them without touching training or test
/// tasks.
pub fn validation_tasks(count: usize) -> Result<Vec<StackTask>, BlocksError> {
    validation_tasks_avoiding(count, &standard_tasks()?)
}

/// `count` validation tasks drawn as [`validation_tasks`] draws them, but
/// outside the end configurations of `avoid` (another task set, such as
/// NTP's own `stack_2000.json`) instead of the standard set's.
pub fn validation_tasks_avoiding(
    count: usize,
    avoid: &[StackTask],
) -> Result<Vec<StackTask>, BlocksError> {
    if count > MAX_VALIDATION_TASKS {
        return Err(BlocksError::Generator(format!(
            "asked for {count} validation tasks; there are at most {MAX_VALIDATION_TASKS}"
        )));
    }
    let standard: HashSet<_> = avoid.iter().map(StackTask::configuration_key).collect();
    // Distinct configurations are plentiful (8 cubes), so a few extra draws
    // cover the ones the standard set already holds.
    let drawn = generate_stack_tasks(VALIDATION_SEED, 2 * count + 64)?;
    let tasks: Vec<StackTask> = drawn
        .into_iter()
        .filter(|t| !standard.contains(&t.configuration_key()))
        .take(count)
        .enumerate()
        .map(|(i, t)| StackTask::new(format!("val_{i}"), t.goals).map_err(BlocksError::Generator))
        .collect::<Result<_, _>>()?;
    if tasks.len() < count {
        return Err(BlocksError::Generator(format!(
            "found only {} validation tasks outside the task set, asked for {count}",
            tasks.len()
        )));
    }
    Ok(tasks)
}

/// The seed of [`structure_test_tasks`].
pub const STRUCTURE_SEED: u64 = 20_190_618;

/// The goals of a task with towers of `composition[i]` goals each (at
/// least one), built tower by tower bottom-up on the cubes in `cubes`'s
/// order (as the standard set orders its goals).
pub(crate) fn tower_goals(composition: &[usize], cubes: &[usize]) -> Vec<Goal> {
    let mut goals = Vec::new();
    let mut next = 0;
    for &g in composition {
        for w in cubes[next..next + g + 1].windows(2) {
            goals.push(Goal {
                src: w[1],
                target: w[0],
            });
        }
        next += g + 1;
    }
    goals
}

/// `count` block-stacking tasks (ids `struct_0`..) whose structures
/// ([`StackTask::structure_key`]) no task of `seen` has: towers of any
/// height (one to seven goals each, at most eight cubes in all), goals
/// ordered tower by tower bottom-up as in the standard set, drawn from
/// `seed` uniformly over those unseen structures, cubes assigned by a
/// random permutation, end configurations distinct. A test of
/// generalisation to new *structures*: the standard set has 23, all with
/// towers of two to four cubes, and its training pool holds nearly all of
/// them; against that pool the unseen ones are the 10 with a tower of five
/// cubes or more.
pub fn structure_test_tasks(
    seen: &[StackTask],
    count: usize,
    seed: u64,
) -> Result<Vec<StackTask>, BlocksError> {
    let seen: HashSet<_> = seen.iter().map(StackTask::structure_key).collect();
    let identity: Vec<usize> = (0..NUM_OBJECTS).collect();
    let novel: Vec<Vec<usize>> = crate::structure::all_compositions()
        .into_iter()
        .filter(|c| {
            let task = StackTask {
                id: String::new(),
                goals: tower_goals(c, &identity),
            };
            !seen.contains(&task.structure_key())
        })
        .collect();
    if novel.is_empty() {
        return Err(BlocksError::Generator(
            "every structure of at most eight cubes is among the seen tasks".into(),
        ));
    }
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut configurations = HashSet::new();
    let mut tasks = Vec::with_capacity(count);
    let mut draws = 0usize;
    while tasks.len() < count {
        draws += 1;
        if draws > count.saturating_mul(50) + 1000 {
            return Err(BlocksError::Generator(format!(
                "could not find {count} distinct tasks of unseen structures in {draws} draws"
            )));
        }
        let composition = &novel[rng.random_range(0..novel.len())];
        let cubes = random_cube_order(&mut rng);
        let task = StackTask::new(
            format!("struct_{}", tasks.len()),
            tower_goals(composition, &cubes),
        )
        .map_err(BlocksError::Generator)?;
        if configurations.insert(task.configuration_key()) {
            tasks.push(task);
        }
    }
    Ok(tasks)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn structure_test_tasks_have_structures_no_seen_task_has() {
        let split = standard_split().unwrap();
        let pool: HashSet<_> = split
            .train_pool
            .iter()
            .map(StackTask::structure_key)
            .collect();
        let standard: HashSet<_> = standard_tasks()
            .unwrap()
            .iter()
            .map(StackTask::structure_key)
            .collect();
        assert_eq!(standard.len(), 23, "the measured count of the README");
        let tasks = structure_test_tasks(&split.train_pool, 200, STRUCTURE_SEED).unwrap();
        assert_eq!(tasks.len(), 200);
        assert_eq!(tasks[3].id, "struct_3");
        let mut keys = HashSet::new();
        for t in &tasks {
            assert!(!pool.contains(&t.structure_key()), "{}", t.describe());
            assert!(keys.insert(t.configuration_key()), "duplicate {}", t.id);
        }
        // Of the 33 structures of at most eight cubes (towers built
        // bottom-up, one after another) the standard set has the 23 whose
        // towers have one to three goals; the other 10 each have a tower
        // of five cubes or more, and 200 draws cover them all.
        let structures: HashSet<_> = tasks.iter().map(StackTask::structure_key).collect();
        assert_eq!(structures.len(), 10);
        assert!(
            tasks
                .iter()
                .all(|t| t.towers().iter().any(|tower| tower.len() >= 5))
        );
        assert_eq!(
            tasks,
            structure_test_tasks(&split.train_pool, 200, STRUCTURE_SEED).unwrap(),
            "seeded"
        );
        // Renaming cubes keeps a structure.
        let t = &split.test[0];
        let renamed = StackTask::new(
            "r",
            t.goals
                .iter()
                .map(|g| Goal {
                    src: (g.src + 1) % NUM_OBJECTS,
                    target: (g.target + 1) % NUM_OBJECTS,
                })
                .collect(),
        )
        .unwrap();
        assert_eq!(renamed.structure_key(), t.structure_key());
    }

    #[test]
    fn validation_tasks_are_disjoint_from_the_standard_set() {
        let standard: HashSet<_> = standard_tasks()
            .unwrap()
            .iter()
            .map(StackTask::configuration_key)
            .collect();
        let too_many = validation_tasks(usize::MAX).unwrap_err().to_string();
        assert!(too_many.contains("at most 10000"), "{too_many}");
        let val = validation_tasks(200).unwrap();
        assert_eq!(val.len(), 200);
        assert_eq!(val[7].id, "val_7");
        let mut keys = HashSet::new();
        for t in &val {
            assert!(!standard.contains(&t.configuration_key()), "{}", t.id);
            assert!(keys.insert(t.configuration_key()), "duplicate {}", t.id);
        }
        assert_eq!(val, validation_tasks(200).unwrap(), "deterministic");
        assert_eq!(val[..50], validation_tasks(50).unwrap()[..], "nested");
    }

    #[test]
    fn joint_has_ntp_marginals() {
        let joint = goal_tower_joint();
        let goals: usize = NTP_GOALS_PER_TASK.iter().sum();
        let towers: usize = NTP_TOWERS_PER_TASK.iter().sum();
        for (k, &c) in NTP_GOALS_PER_TASK.iter().enumerate() {
            let p: f64 = joint
                .iter()
                .filter(|(c, _)| c.0 == k + 1)
                .map(|(_, p)| p)
                .sum();
            assert!(
                (p - c as f64 / goals as f64).abs() < 1e-6,
                "goals {}",
                k + 1
            );
        }
        for (k, &c) in NTP_TOWERS_PER_TASK.iter().enumerate() {
            let p: f64 = joint
                .iter()
                .filter(|(c, _)| c.1 == k + 1)
                .map(|(_, p)| p)
                .sum();
            assert!(
                (p - c as f64 / towers as f64).abs() < 1e-6,
                "towers {}",
                k + 1
            );
        }
        // Every cell fits eight cubes.
        assert!(joint.iter().all(|((g, t), _)| g + t <= NUM_OBJECTS));
    }

    #[test]
    fn compositions_use_towers_of_two_to_four() {
        for ((goals, towers), comps) in cells() {
            for c in comps {
                assert_eq!(c.len(), towers);
                assert_eq!(c.iter().sum::<usize>(), goals);
                assert!(c.iter().all(|&g| (1..=3).contains(&g)));
            }
        }
    }

    #[test]
    fn letters_and_names() {
        assert_eq!(cube_letter(0), 'A');
        assert_eq!(cube_letter(7), 'H');
        assert_eq!(cube_letter(99), '?');
        assert_eq!(parse_cube_name("cube_3"), Some(3));
        assert_eq!(parse_cube_name("cube_8"), None);
        assert_eq!(parse_cube_name("cube_x"), None);
    }
}
