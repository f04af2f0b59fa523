//! NTG on an environment of one's own. *Lamps*: a task is an order in which
//! to switch on three of six lamps. A press fails one time in four (the lamp
//! stays off: press again), and pressing a lit lamp switches it off. NTG
//! learns from demos of some orders, then does orders of lamps never lit
//! together in training, each from one demo; it must beat the same model
//! choosing uniformly among a node's successors (no edge classifier).
use std::sync::LazyLock;

use ctg_graph::{ActionId, CtgError, Environment, Expert, Result, Step, Vocabulary, check_environment};
use ntg_train::domain::{Episode, RowDomain, evaluate, record_demos, success_rate};
use ntg_train::{fit::OptimConfig, method::ntg, run_dir::RunDir};

const LAMPS: usize = 6;
static PRESS: LazyLock<Vocabulary> =
    LazyLock::new(|| Vocabulary::new((0..LAMPS).map(|l| format!("press-{l}"))).expect("distinct names"));

#[derive(Default)]
struct Lamps {
    task: Vec<usize>,
    lit: Vec<usize>,
    pressed: Option<usize>,
    steps: Option<usize>,
    seed: u64,
}

impl Environment for Lamps {
    /// Which lamps are lit, and which was pressed last.
    type Observation = Vec<f32>;
    type Info = ();
    fn vocabulary(&self) -> &Vocabulary {
        &PRESS
    }
    fn reset(&mut self, seed: u64) -> Result<(Vec<f32>, ())> {
        *self = Lamps { task: std::mem::take(&mut self.task), steps: Some(0), seed, ..Lamps::default() };
        Ok((observe(self), ()))
    }
    fn step(&mut self, action: ActionId) -> Result<Step<Vec<f32>, ()>> {
        let steps = self.steps.ok_or(CtgError::NotReset)?;
        if action.index() >= PRESS.len() || action == Vocabulary::START {
            return Err(CtgError::ActionOutOfRange { id: action.index(), len: PRESS.len() });
        }
        let lamp = action.index().checked_sub(2);
        if let Some(lamp) = lamp {
            let mix = |x: u64| x.wrapping_mul(0x9E37_79B9_7F4A_7C15);
            let fails = mix(mix(self.seed) ^ steps as u64) >> 62 == 0;
            match self.lit.iter().position(|&l| l == lamp) {
                Some(i) => drop(self.lit.remove(i)),
                None if !fails => self.lit.push(lamp),
                None => {}
            }
            self.pressed = Some(lamp);
        }
        let (terminated, truncated) =
            (lamp.is_none(), lamp.is_some() && steps + 1 >= self.max_episode_steps());
        self.steps = (!terminated && !truncated).then_some(steps + 1);
        let reward = (terminated && self.is_success()) as u8 as f32;
        Ok(Step { observation: observe(self), reward, terminated, truncated, info: () })
    }
    fn is_success(&self) -> bool {
        self.lit == self.task
    }
    fn max_episode_steps(&self) -> usize {
        20
    }
}

fn observe(lamps: &Lamps) -> Vec<f32> {
    let lit = (0..LAMPS).map(|l| lamps.lit.contains(&l) as u8 as f32);
    lit.chain((0..LAMPS).map(|l| (lamps.pressed == Some(l)) as u8 as f32)).collect()
}

/// Presses the task's next unlit lamp until all are lit, in order.
struct Electrician;

impl Expert<Lamps> for Electrician {
    fn reset(&mut self, _: &Lamps, _: u64) {}
    fn next_action(&mut self, env: &Lamps) -> Result<ActionId> {
        Ok(env.task.get(env.lit.len()).map_or(Vocabulary::END, |&l| ActionId::new(l + 2)))
    }
}

fn main() -> ntg_train::anyhow::Result<()> {
    let make_env = |task: &Vec<usize>| Ok(Lamps { task: task.clone(), ..Lamps::default() });
    let report = check_environment(|| make_env(&vec![4, 0, 2]).unwrap(), &mut Electrician, &[1, 2])?;
    println!("{report:?}");
    let lamps = RowDomain::new(&vec![0, 1, 2], make_env, || Electrician)?;
    // Every order of three lamps; those whose lamps sum to a multiple of 3 are held out.
    let orders = (0..216).map(|i| vec![i / 36, i / 6 % 6, i % 6]);
    let orders = orders.filter(|t| t[0] != t[1] && t[1] != t[2] && t[0] != t[2]);
    let (test, train): (Vec<_>, Vec<_>) = orders.partition(|t| t.iter().sum::<usize>() % 3 == 0);
    let dataset = record_demos(&lamps, &train, 10, 0)?;
    let device = ntg_model::cpu_device().autodiff();
    let run = RunDir::create(&std::env::temp_dir().join(format!("ntg-own-env-{}", std::process::id())))?;
    let optim = OptimConfig::stage(12, 32, 3e-3, 0, 1);
    let mut model = ntg::train_on_rows(&dataset, &optim, &run, &device, &mut |r| println!("{r}"))?;
    let episodes = Episode::for_tasks(&test, 5, 1_000_000);
    let learned = success_rate(&evaluate(&lamps, &model, &episodes)?);
    model.config.ablation = ntg::Variant::NoEdgeClassifier.ablation_of(&model.config.ablation);
    let uniform = success_rate(&evaluate(&lamps, &model, &episodes)?);
    println!("{} unseen orders: NTG {learned}; uniform over its graph's edges {uniform}", test.len());
    std::fs::remove_dir_all(run.root())?;
    assert!(learned.rate > uniform.rate, "NTG must beat the uniform-edge policy");
    Ok(())
}
