//! Demonstrations for Neural Task Programming (NTP, Xu et al. 2018), the
//! baseline of the paper's block-stacking figure: the expert's episode at
//! the primitive level (`move(X)`, `grasp`, `drop`), every primitive
//! annotated with the program call it belongs to.
//!
//! NTP's hierarchy: the root (`stack`, or `sort` for object sorting) calls
//! `pick_place` once per cube moved; `pick_place` calls `pick` (one or
//! more: a pick the expert gave up on, e.g. to clear a cube first, stays
//! in the same `pick_place`) and then `place`; `pick` runs `move(X)` and
//! `grasp` (a grasp that slipped is grasped again inside the same `pick`),
//! `place` runs `move(Y)` and `drop`. Only the primitives take an argument
//! (which cube or bin to move to); a program learns what to do from its
//! *scope*, the slice of the demo its call spans.
//!
//! Every call spans primitives `start..end` of the episode, that is
//! observations `start..=end` (the one before its first primitive to the
//! one after its last).

use ctg_graph::{ActionId, CtgError, Environment, Result};
use serde::{Deserialize, Serialize};

use crate::env::{ActionLevel, BlocksAction, BlocksEnv, BlocksObservation, BlocksTask, EnvConfig};
use crate::world::{Primitive, Target};

/// A program of NTP's block-stacking hierarchy.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum NtpProgram {
    /// The root: `stack` (block stacking) or `sort` (object sorting).
    Root,
    /// Move one cube: `pick`, then `place`.
    PickPlace,
    /// Take a cube: `move(X)`, `grasp`.
    Pick,
    /// Put the held cube down: `move(Y)`, `drop`.
    Place,
    /// Primitive `move(target)`.
    Move,
    /// Primitive `grasp`.
    Grasp,
    /// Primitive `drop`.
    Drop,
}

impl NtpProgram {
    /// Every program, in index order.
    pub const ALL: [NtpProgram; 7] = [
        NtpProgram::Root,
        NtpProgram::PickPlace,
        NtpProgram::Pick,
        NtpProgram::Place,
        NtpProgram::Move,
        NtpProgram::Grasp,
        NtpProgram::Drop,
    ];

    /// Its position in [`NtpProgram::ALL`].
    pub fn index(self) -> usize {
        self as usize
    }

    /// The program at `index` in [`NtpProgram::ALL`].
    pub fn from_index(index: usize) -> Option<NtpProgram> {
        NtpProgram::ALL.get(index).copied()
    }

    /// Whether it acts in the environment (an API call, in NTP's words).
    pub fn is_primitive(self) -> bool {
        matches!(
            self,
            NtpProgram::Move | NtpProgram::Grasp | NtpProgram::Drop
        )
    }

    /// Its name (the root's is `stack`; see [`NtpProgram::root_name`]).
    pub fn name(self) -> &'static str {
        match self {
            NtpProgram::Root => "stack",
            NtpProgram::PickPlace => "pick_place",
            NtpProgram::Pick => "pick",
            NtpProgram::Place => "place",
            NtpProgram::Move => "move",
            NtpProgram::Grasp => "grasp",
            NtpProgram::Drop => "drop",
        }
    }

    /// The root program's name for `task`'s domain.
    pub fn root_name(task: &BlocksTask) -> &'static str {
        match task {
            BlocksTask::Stack(_) => "stack",
            BlocksTask::Sort(_) => "sort",
        }
    }

    /// The primitive as an environment action (`argument` is `move`'s
    /// target); `None` for a program that is not a primitive, or a `move`
    /// without a target.
    pub fn action(self, argument: Option<Target>) -> Option<BlocksAction> {
        match self {
            NtpProgram::Move => argument.map(|t| BlocksAction::Primitive(Primitive::Move(t))),
            NtpProgram::Grasp => Some(BlocksAction::Primitive(Primitive::Grasp)),
            NtpProgram::Drop => Some(BlocksAction::Primitive(Primitive::Drop)),
            _ => None,
        }
    }
}

/// One call of NTP's hierarchy in a recorded episode.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct NtpCall {
    /// The program called.
    pub program: NtpProgram,
    /// `move`'s target; `None` for every other program.
    pub argument: Option<Target>,
    /// Index of its first primitive in the episode.
    pub start: usize,
    /// Index after its last primitive (`end > start`).
    pub end: usize,
    /// The calls it made, in order (empty for a primitive).
    pub children: Vec<NtpCall>,
}

impl NtpCall {
    fn primitive(action: BlocksAction, t: usize) -> Result<NtpCall> {
        let (program, argument) = match action {
            BlocksAction::Primitive(Primitive::Move(target)) => (NtpProgram::Move, Some(target)),
            BlocksAction::Primitive(Primitive::Grasp) => (NtpProgram::Grasp, None),
            BlocksAction::Primitive(Primitive::Drop) => (NtpProgram::Drop, None),
            other => {
                return Err(CtgError::ExpertFailed(format!(
                    "a primitive-level episode took {other:?}"
                )));
            }
        };
        Ok(NtpCall {
            program,
            argument,
            start: t,
            end: t + 1,
            children: Vec::new(),
        })
    }

    fn parent(program: NtpProgram, children: Vec<NtpCall>) -> NtpCall {
        NtpCall {
            program,
            argument: None,
            start: children.first().map_or(0, |c| c.start),
            end: children.last().map_or(0, |c| c.end),
            children,
        }
    }

    /// The primitives under this call, in execution order (itself if it is
    /// one).
    pub fn primitives(&self) -> Vec<&NtpCall> {
        if self.children.is_empty() {
            return vec![self];
        }
        self.children.iter().flat_map(NtpCall::primitives).collect()
    }

    /// NTP Flat's trace: the root calling every primitive directly.
    pub fn flattened(&self) -> NtpCall {
        NtpCall {
            program: self.program,
            argument: self.argument,
            start: self.start,
            end: self.end,
            children: self.primitives().into_iter().cloned().collect(),
        }
    }

    /// Depth of the hierarchy (a primitive is 1).
    pub fn depth(&self) -> usize {
        1 + self.children.iter().map(NtpCall::depth).max().unwrap_or(0)
    }

    /// Every call of the tree, this one first, depth first.
    pub fn calls(&self) -> Vec<&NtpCall> {
        let mut out = vec![self];
        for c in &self.children {
            out.extend(c.calls());
        }
        out
    }

    /// The call as text, e.g. `stack(pick_place(pick(move(A) grasp) ...))`.
    pub fn to_text(&self) -> String {
        let head = match (self.program, self.argument) {
            (NtpProgram::Move, Some(t)) => format!("move({})", crate::env::target_name(t)),
            (p, _) => p.name().to_owned(),
        };
        if self.children.is_empty() {
            return head;
        }
        let inner: Vec<String> = self.children.iter().map(NtpCall::to_text).collect();
        format!("{head}({})", inner.join(" "))
    }
}

/// The expert's episode at the primitive level with NTP's call tree.
#[derive(Debug, Clone)]
pub struct NtpDemo {
    /// The observation before the first primitive and after each.
    pub observations: Vec<BlocksObservation>,
    /// The primitives taken, as ids of the primitive-level vocabulary.
    pub actions: Vec<ActionId>,
    /// The root call (spanning the whole episode).
    pub root: NtpCall,
    /// Whether the task holds at the end.
    pub success: bool,
}

/// Records the expert's episode of `task` with `seed` at the primitive
/// level (whatever `config.level` says) and annotates it with NTP's call
/// tree; an episode that hits the step limit is an error.
pub fn record_ntp_demo(task: &BlocksTask, config: EnvConfig, seed: u64) -> Result<NtpDemo> {
    let config = EnvConfig {
        level: ActionLevel::Primitive,
        ..config
    };
    let (mut env, mut expert, first) = crate::expert::start_episode(task, config, seed)?;
    let mut observations = vec![first];
    let mut actions = Vec::new();
    // Per primitive: the primitive and the flat decision it serves.
    let mut taken: Vec<(BlocksAction, BlocksAction)> = Vec::new();
    loop {
        let (action, decision) = expert.next_with_decision(&env)?;
        if action == BlocksAction::End {
            break;
        }
        let id = env.encode(action).ok_or_else(|| {
            CtgError::ExpertFailed(format!("{action:?} is not a primitive-level action"))
        })?;
        let step = env.step(id)?;
        actions.push(id);
        observations.push(step.observation);
        taken.push((action, decision));
        if step.terminated {
            break;
        }
        if step.truncated {
            return Err(crate::expert::step_limit_hit(&env, seed));
        }
    }
    if taken.is_empty() {
        return Err(crate::expert::nothing_to_demonstrate(task, seed));
    }
    Ok(NtpDemo {
        root: call_tree(&taken)?,
        observations,
        actions,
        success: env.is_success(),
    })
}

/// NTP's call tree of a primitive-level episode, from each primitive's
/// flat decision: consecutive primitives serving the same `pick(X)` or
/// `place(Y)` are one call of it; each `place` closes a `pick_place` with
/// the picks before it; picks after the last place form an unfinished one.
fn call_tree(taken: &[(BlocksAction, BlocksAction)]) -> Result<NtpCall> {
    let mut flat_calls: Vec<(BlocksAction, Vec<NtpCall>)> = Vec::new();
    for (t, &(action, decision)) in taken.iter().enumerate() {
        let leaf = NtpCall::primitive(action, t)?;
        match flat_calls.last_mut() {
            Some((d, leaves)) if *d == decision => leaves.push(leaf),
            _ => flat_calls.push((decision, vec![leaf])),
        }
    }
    let mut pick_places = Vec::new();
    let mut open = Vec::new();
    for (decision, leaves) in flat_calls {
        match decision {
            BlocksAction::Pick(_) => open.push(NtpCall::parent(NtpProgram::Pick, leaves)),
            BlocksAction::Place(_) => {
                open.push(NtpCall::parent(NtpProgram::Place, leaves));
                pick_places.push(NtpCall::parent(
                    NtpProgram::PickPlace,
                    std::mem::take(&mut open),
                ));
            }
            other => {
                return Err(CtgError::ExpertFailed(format!(
                    "a primitive served the flat decision {other:?}"
                )));
            }
        }
    }
    if !open.is_empty() {
        pick_places.push(NtpCall::parent(NtpProgram::PickPlace, open));
    }
    Ok(NtpCall::parent(NtpProgram::Root, pick_places))
}

/// The primitive-level vocabulary id of `program(argument)` in `env`, if it
/// is a primitive of it.
pub fn primitive_id(
    env: &BlocksEnv,
    program: NtpProgram,
    argument: Option<Target>,
) -> Option<ActionId> {
    env.encode(program.action(argument)?)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::world::FailureConfig;

    fn tasks() -> Vec<BlocksTask> {
        crate::standard_split()
            .unwrap()
            .train(12)
            .unwrap()
            .iter()
            .cloned()
            .map(BlocksTask::Stack)
            .collect()
    }

    fn check_tree(demo: &NtpDemo) {
        let root = &demo.root;
        assert_eq!(root.program, NtpProgram::Root);
        assert_eq!((root.start, root.end), (0, demo.actions.len()));
        assert_eq!(demo.observations.len(), demo.actions.len() + 1);
        // The leaves are the episode's primitives, in order, one per step.
        let leaves = root.primitives();
        assert_eq!(leaves.len(), demo.actions.len());
        for (t, leaf) in leaves.iter().enumerate() {
            assert!(leaf.program.is_primitive());
            assert_eq!((leaf.start, leaf.end), (t, t + 1));
            assert_eq!(leaf.argument.is_some(), leaf.program == NtpProgram::Move);
        }
        for pp in &root.children {
            assert_eq!(pp.program, NtpProgram::PickPlace);
            assert!(
                pp.children
                    .iter()
                    .all(|c| matches!(c.program, NtpProgram::Pick | NtpProgram::Place))
            );
            for c in &pp.children {
                // pick: moves and grasps; place: moves and drops.
                let allowed = match c.program {
                    NtpProgram::Pick => NtpProgram::Grasp,
                    _ => NtpProgram::Drop,
                };
                assert!(
                    c.children
                        .iter()
                        .all(|p| p.program == NtpProgram::Move || p.program == allowed),
                    "{}",
                    c.to_text()
                );
            }
        }
        // Children tile their parent's span.
        for call in root.calls() {
            let mut t = call.start;
            for c in &call.children {
                assert_eq!(c.start, t, "{}", call.to_text());
                t = c.end;
            }
            if !call.children.is_empty() {
                assert_eq!(t, call.end);
            }
        }
    }

    #[test]
    fn every_expert_episode_is_a_tiled_call_tree_that_succeeds() {
        for (i, task) in tasks().iter().enumerate() {
            for seed in 0..4 {
                let demo =
                    record_ntp_demo(task, EnvConfig::state_only(), 100 * i as u64 + seed).unwrap();
                assert!(demo.success);
                check_tree(&demo);
                assert_eq!(demo.root.depth(), 4);
                let flat = demo.root.flattened();
                assert_eq!(flat.depth(), 2);
                assert_eq!(flat.children.len(), demo.actions.len());
            }
        }
    }

    #[test]
    fn a_failure_free_pick_place_is_move_grasp_move_drop() {
        let task = &tasks()[0];
        let config = EnvConfig::state_only().without_failures();
        let demo = record_ntp_demo(task, config, 3).unwrap();
        for pp in &demo.root.children {
            let text = pp.to_text();
            assert!(
                text.starts_with("pick_place(pick(move(") && text.contains(") grasp) place(move("),
                "{text}"
            );
            assert!(text.ends_with(") drop))"), "{text}");
        }
    }

    #[test]
    fn slipped_grasps_are_retried_inside_one_pick() {
        let config = EnvConfig {
            failures: FailureConfig {
                grasp_slip: 0.5,
                ..FailureConfig::none()
            },
            ..EnvConfig::state_only()
        };
        let task = &tasks()[1];
        let mut retried = 0;
        for seed in 0..10 {
            let demo = record_ntp_demo(task, config, seed).unwrap();
            check_tree(&demo);
            for call in demo.root.calls() {
                if call.program == NtpProgram::Pick {
                    let grasps = call
                        .children
                        .iter()
                        .filter(|c| c.program == NtpProgram::Grasp)
                        .count();
                    retried += usize::from(grasps > 1);
                }
            }
        }
        assert!(retried > 0, "no pick retried a grasp at a 50% slip rate");
    }

    #[test]
    fn replaying_the_tree_primitives_reproduces_the_episode() {
        let task = &tasks()[2];
        let config = EnvConfig::state_only();
        let demo = record_ntp_demo(task, config, 7).unwrap();
        let mut env = BlocksEnv::new(
            task.clone(),
            EnvConfig {
                level: ActionLevel::Primitive,
                ..config
            },
        )
        .unwrap();
        env.reset(7).unwrap();
        for leaf in demo.root.primitives() {
            let id = primitive_id(&env, leaf.program, leaf.argument).unwrap();
            env.step(id).unwrap();
        }
        assert!(env.is_success());
    }
}
