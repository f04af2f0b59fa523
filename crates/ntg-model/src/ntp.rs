//! Neural Task Programming (NTP; Xu et al., ICRA 2018), the baseline of
//! the NTG paper's block-stacking figure, as `docs/BASELINES.md`
//! describes it: a neural program interpreter conditioned on a
//! demonstration (the *task specification*), run by a program stack.
//!
//! ```text
//! d_r    = Enc(spec row r)                         the demo, encoded once
//! e_p    = E[p]                                    current program p
//! α_r    = softmax_{r ∈ scope}((W_q e_p)ᵀ W_k d_r / √H)
//! c      = Σ_r α_r d_r                             task embedding
//! h      = relu(W_2 relu(W_1 [Enc(o); e_p; c]))    core
//! next sub-program  = softmax(W_p h)
//! end-of-program    = σ(w_eop h)
//! argument          = softmax(W_a h)               (a primitive's object)
//! callee's scope    = per spec row r: softmax(W_s relu(V [d_{r−1}; d_r; d_{r+1}] + U h))
//!                     over {outside, start, inside, end}
//! ```
//!
//! With [`NtpConfig::scope_match`] the scope head also compares each demo
//! row with the core state, `+ (G d_r) ⊙ (M h)` inside the `relu`: which
//! segment of the demo comes next is the one whose rows look like the
//! present, and a sum alone cannot compare a row with the present.
//!
//! With [`NtpConfig::recurrent_core`] (the GRU variant of the original
//! NTP) the heads read a GRU state instead of `h`: each program call
//! carries its own state through its decisions, `g_k = GRU(g_{k−1}, h_k)`
//! from `g_{−1} = 0`, so a program tells its decisions apart by what it
//! has done in this call (after `move`: `drop`; after `drop`: return)
//! even where two observations look alike. A callee starts from zeros;
//! its caller's state waits on the stack.
//!
//! The scope head is a temporal convolution of kernel 3 over the demo's
//! encoded rows, conditioned on the core state; a callee attends only to
//! its scope of the demo. Programs, arguments and the demo are plain
//! indices and rows here: which program is a primitive and what it does
//! in an environment is the caller's business ([`ProgramStack`] takes the
//! list of primitives).
//!
//! Trained on execution traces ([`ProgramCall`] trees): every call of a
//! non-primitive program yields one decision per child (the child program,
//! its argument, its scope of the demo when it has one) and a final
//! end-of-program decision, each made on the observation of that moment.

use std::path::Path;

use burn::config::Config;
use burn::module::{Module, Param};
use burn::nn::Linear;
use burn::tensor::activation::{relu, softmax};
use burn::tensor::{Device, Int, Tensor, TensorData};

use crate::batch::rows_tensor;
use crate::encoder::{Encoder, EncoderConfig};
use crate::nn::{
    GruCell, Init, MASKED_LOGIT, masked_accuracy, masked_cross_entropy, scalar, to_vec, to_vec_int,
};
use crate::{ModelError, Result};

/// Scope labels of a demo row, as the scope head classifies them.
pub const SCOPE_OUTSIDE: usize = 0;
/// The first row of the callee's scope.
pub const SCOPE_START: usize = 1;
/// A row strictly inside the callee's scope.
pub const SCOPE_INSIDE: usize = 2;
/// The last row of the callee's scope.
pub const SCOPE_END: usize = 3;

/// One call of an execution trace, in indices.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ProgramCall {
    /// The program's index.
    pub program: usize,
    /// The argument's index (a primitive's object), if it takes one.
    pub argument: Option<usize>,
    /// Index of the episode observation at which it was called.
    pub start: usize,
    /// Index of the episode observation at which it returned (`> start`).
    pub end: usize,
    /// The rows of the *specification* demo it reads, inclusive; `None`:
    /// its caller's (the root's is the whole demo).
    pub scope: Option<(usize, usize)>,
    /// The calls it made, in order (empty for a primitive).
    pub children: Vec<ProgramCall>,
}

/// Configuration of an [`NtpNet`]; saved beside its weights as JSON.
#[derive(Config, Debug)]
pub struct NtpConfig {
    /// Number of programs (primitives included).
    pub num_programs: usize,
    /// Number of argument values (e.g. the cubes a `move` can go to).
    pub num_arguments: usize,
    /// Observation encoder `Enc(o)`, shared by the demo rows and the
    /// current observation.
    pub encoder: EncoderConfig,
    /// Width `H` of the program embeddings, attention and core.
    #[config(default = 128)]
    pub hidden: usize,
    /// Read arguments off the demo's objects as well: with `Some(K)`, the
    /// first `3K` values of a row are `K` objects' positions and argument
    /// `i` is object `i`; a small MLP scores each object of each demo row
    /// (which object the demo is handling there), and the scores, pooled
    /// with the program's attention over its scope, are added to the
    /// argument logits. `None`: the argument is read from the core alone.
    pub object_arguments: Option<usize>,
    /// Scope head with a row-by-core comparison term `(G d_r) ⊙ (M h)`
    /// (see the module docs); `None` or `false`: the kernel-3 convolution
    /// plus the core's term only.
    pub scope_match: Option<bool>,
    /// A recurrent (GRU) core: the heads read a GRU state carried through
    /// each program call's decisions (see the module docs); `None` or
    /// `false`: the reactive feed-forward core.
    pub recurrent_core: Option<bool>,
    /// Seed of the initial weights.
    #[config(default = 0)]
    pub seed: u64,
}

impl NtpConfig {
    /// Checks the sizes.
    pub fn validate(&self) -> Result<()> {
        self.encoder.validate()?;
        if let Some(k) = self.object_arguments
            && (k != self.num_arguments || 3 * k > self.encoder.input_dim())
        {
            return Err(ModelError::Config(format!(
                "NTP: {k} object arguments need {k} argument values (got {}) and rows of at least {} values (got {})",
                self.num_arguments,
                3 * k,
                self.encoder.input_dim()
            )));
        }
        if self.num_programs < 2 || self.num_arguments == 0 || self.hidden == 0 {
            return Err(ModelError::Config(format!(
                "NTP: needs at least 2 programs, 1 argument value and a positive width (got {}, {}, {})",
                self.num_programs, self.num_arguments, self.hidden
            )));
        }
        Ok(())
    }

    /// Builds the network with weights drawn from `self.seed` on `device`.
    pub fn init(&self, device: &Device) -> Result<NtpNet> {
        self.validate()?;
        let encoder = self.encoder.init(self.seed.wrapping_add(17), device)?;
        let mut init = Init::new(self.seed ^ 0x4e7f_0b1d, device);
        let h = self.hidden;
        let e = encoder.out_dim();
        Ok(NtpNet {
            programs: init.matrix(self.num_programs, h, 1.0),
            query: init.linear(h, h, false),
            key: init.linear(e, h, false),
            // With object arguments the core also reads which object the
            // demo's scope handles and which the observation has at hand.
            core_in: init.linear(e + h + e + 2 * self.object_arguments.unwrap_or(0), h, true),
            core_hidden: init.linear(h, h, true),
            program_out: init.linear(h, self.num_programs, true),
            eop_out: init.linear(h, 1, true),
            argument_out: init.linear(h, self.num_arguments, true),
            scope_demo: init.linear(3 * e, h, true),
            scope_core: init.linear(h, h, false),
            scope_out: init.linear(h, 4, true),
            object_scorer: self
                .object_arguments
                .map(|_| (init.linear(3, 32, true), init.linear(32, 1, true))),
            scope_match: self
                .scope_match
                .unwrap_or(false)
                .then(|| (init.linear(e, h, false), init.linear(h, h, false))),
            // Drawn last, so the reactive core's weights are the same with
            // and without it.
            core_gru: self
                .recurrent_core
                .unwrap_or(false)
                .then(|| GruCell::init(&mut init, h, h)),
            encoder,
            config: self.clone(),
        })
    }
}

/// The NTP network (see the module docs for its equations).
#[derive(Module, Debug)]
pub struct NtpNet {
    /// `Enc(o)`, for demo rows and the current observation.
    pub encoder: Encoder,
    /// Program embeddings `E` `[P, H]`.
    pub programs: Param<Tensor<2>>,
    /// `W_q`: program embedding → attention query.
    pub query: Linear,
    /// `W_k`: encoded demo row → attention key.
    pub key: Linear,
    /// `W_1`: `[Enc(o); e_p; c]` → core.
    pub core_in: Linear,
    /// `W_2`: the core's second layer.
    pub core_hidden: Linear,
    /// Next sub-program logits.
    pub program_out: Linear,
    /// End-of-program logit.
    pub eop_out: Linear,
    /// Argument logits.
    pub argument_out: Linear,
    /// `V`: the scope convolution over three neighbouring demo rows.
    pub scope_demo: Linear,
    /// `U`: the core state's term in the scope convolution.
    pub scope_core: Linear,
    /// `W_s`: scope row labels.
    pub scope_out: Linear,
    /// With object arguments: the per-object scorer's two layers.
    pub object_scorer: Option<(Linear, Linear)>,
    /// With [`NtpConfig::scope_match`]: `G` (demo row) and `M` (core state)
    /// of the scope head's comparison term.
    pub scope_match: Option<(Linear, Linear)>,
    /// With [`NtpConfig::recurrent_core`]: the GRU cell over each call's
    /// decisions, reading the feed-forward core `h`.
    pub core_gru: Option<GruCell>,
    /// The configuration the network was built from.
    #[module(skip)]
    pub config: NtpConfig,
}

/// Specification demos encoded once: rows, attention keys and the scope
/// convolution's demo term.
#[derive(Debug, Clone)]
pub struct EncodedSpec {
    rows: Tensor<3>,
    keys: Tensor<3>,
    taps: Tensor<3>,
    /// With object arguments: each row's score of each object `[B, R, K]`.
    objects: Option<Tensor<3>>,
    /// With the scope comparison: `G d_r` `[B, R, H]`.
    matched: Option<Tensor<3>>,
}

/// Where decisions `[S]`, each reading one of `B` encoded demos, sit in a
/// `[B, M]` grid (`M`: the most decisions of one demo), so that a product
/// of each decision with its own demo's rows is one batched product of
/// `[B, M, ·]` with the demos' `[B, R, ·]`. Copying each demo's rows per
/// decision instead (`select` on `[B, R, ·]`) costs a scatter-add of
/// `[S, R, ·]` in the backward pass: 40% of NTP's training step.
struct DemoGrid {
    /// `S`.
    decisions: usize,
    /// `B`.
    demos: usize,
    /// `M`.
    width: usize,
    /// Per place `[B·M]`: its decision, or `S` (a zero row) where empty.
    gather: Tensor<1, Int>,
    /// Per decision `[S]`: its place `b·M + j`.
    place: Tensor<1, Int>,
}

impl DemoGrid {
    /// The grid of decisions reading demos `demo_index` (each below
    /// `demos`), in order within each demo.
    fn new(demo_index: Tensor<1, Int>, demos: usize) -> Result<Self> {
        let device = demo_index.device();
        let index = to_vec_int(demo_index)?;
        let mut counts = vec![0usize; demos];
        let mut place = Vec::with_capacity(index.len());
        for &d in &index {
            let d = usize::try_from(d)
                .ok()
                .filter(|&d| d < demos)
                .ok_or_else(|| ModelError::Input(format!("decision reads demo {d} of {demos}")))?;
            place.push((d, counts[d]));
            counts[d] += 1;
        }
        let width = counts.iter().copied().max().unwrap_or(0).max(1);
        let decisions = index.len();
        let mut gather = vec![decisions as i64; demos * width];
        let place: Vec<i64> = place
            .iter()
            .enumerate()
            .map(|(s, &(d, j))| {
                gather[d * width + j] = s as i64;
                (d * width + j) as i64
            })
            .collect();
        Ok(DemoGrid {
            decisions,
            demos,
            width,
            gather: Tensor::from_data(TensorData::new(gather, [demos * width]), &device),
            place: Tensor::from_data(TensorData::new(place, [decisions]), &device),
        })
    }

    /// Decision rows `[S, C]` laid out as `[B, M, C]` (zeros where empty).
    fn to_grid(&self, x: Tensor<2>) -> Tensor<3> {
        let c = x.dims()[1];
        let zero = Tensor::zeros([1, c], &x.device());
        Tensor::cat(vec![x, zero], 0)
            .select(0, self.gather.clone())
            .reshape([self.demos, self.width, c])
    }

    /// The decisions' rows `[S, C]` of a grid `[B, M, C]`.
    fn decisions_of(&self, x: Tensor<3>) -> Tensor<2> {
        let c = x.dims()[2];
        x.reshape([self.demos * self.width, c])
            .select(0, self.place.clone())
    }
}

/// A training batch of NTP decisions (see [`NtpBatch::new`]).
#[derive(Debug, Clone)]
pub struct NtpBatch {
    /// Specification demos `[B, R, D]` (zero padding).
    pub spec: Tensor<3>,
    /// `[B, R]`: 1 for a real row.
    pub spec_mask: Tensor<2>,
    /// Decisions: which example's demo each reads `[S]`.
    pub demo_index: Tensor<1, Int>,
    /// Decisions: the observation `[S, D]`.
    pub observations: Tensor<2>,
    /// Decisions: the current program `[S]`.
    pub programs: Tensor<1, Int>,
    /// Decisions: 1 on the demo rows of the current program's scope `[S, R]`.
    pub scope_mask: Tensor<2>,
    /// Decisions: 1 where the program returns `[S]`.
    pub eop: Tensor<1>,
    /// Decisions: the sub-program called `[S]` (0 where it returns).
    pub next_program: Tensor<1, Int>,
    /// Decisions: the called primitive's argument `[S]` (0 where none).
    pub argument: Tensor<1, Int>,
    /// Decisions: 1 where an argument is supervised `[S]`.
    pub argument_weight: Tensor<1>,
    /// The decisions whose callee's scope is supervised `[K]`.
    pub scope_steps: Tensor<1, Int>,
    /// Their row labels `[K, R]` (`SCOPE_*`).
    pub scope_labels: Tensor<2, Int>,
    /// 1 on the rows of the caller's scope `[K, R]`.
    pub scope_weight: Tensor<2>,
    /// The decisions grouped by the program call that makes them (what a
    /// recurrent core carries its state along).
    pub calls: CallSteps,
    /// Number of decisions `S`.
    pub decisions: usize,
}

/// A batch's decisions grouped by the program call that makes them, in
/// step-major order: first every call's first decision, then every
/// second decision of the calls that make one, and so on. A recurrent
/// core runs one GRU step per group ([`NtpNet::decide`] with
/// [`CoreState::Calls`]).
#[derive(Debug, Clone)]
pub struct CallSteps {
    /// Per step `j`: the decisions that are step `j` of their call.
    steps: Vec<Tensor<1, Int>>,
    /// Per step `j ≥ 1`: for each decision of `steps[j]`, the position of
    /// its call's step `j − 1` in the step-major order (`previous[0]` is
    /// empty and unused).
    previous: Vec<Tensor<1, Int>>,
    /// Per decision `[S]`: its position in the step-major order.
    position: Tensor<1, Int>,
}

impl CallSteps {
    /// The grouping of decisions whose calls are `call` (per decision, in
    /// order within each call).
    fn new(call: &[usize], device: &Device) -> Self {
        let calls = call.iter().map(|&c| c + 1).max().unwrap_or(0);
        let mut of_call: Vec<Vec<usize>> = vec![Vec::new(); calls];
        for (k, &c) in call.iter().enumerate() {
            of_call[c].push(k);
        }
        let longest = of_call.iter().map(Vec::len).max().unwrap_or(0);
        let mut position = vec![0i64; call.len()];
        let mut next = 0i64;
        let ints = |v: Vec<i64>| {
            Tensor::<1, Int>::from_data(TensorData::new(v.clone(), [v.len()]), device)
        };
        let (mut steps, mut previous) = (Vec::new(), Vec::new());
        for j in 0..longest {
            let (mut here, mut before) = (Vec::new(), Vec::new());
            for decisions in of_call.iter().filter(|d| d.len() > j) {
                here.push(decisions[j] as i64);
                if j > 0 {
                    before.push(position[decisions[j - 1]]);
                }
                position[decisions[j]] = next;
                next += 1;
            }
            steps.push(ints(here));
            previous.push(ints(before));
        }
        CallSteps {
            steps,
            previous,
            position: ints(position),
        }
    }
}

/// Where a recurrent core's state comes from for the decisions given to
/// [`NtpNet::decide`] (a reactive core ignores it).
#[derive(Debug, Clone)]
pub enum CoreState<'a> {
    /// Every decision is the first of its call (state zeros).
    First,
    /// A batch's decisions, in the calls that make them (teacher forcing).
    Calls(&'a CallSteps),
    /// Each decision continues its call from this state `[S, H]`.
    Previous(&'a Tensor<2>),
}

/// One training example: the specification demo's rows, the executed
/// episode's observation rows, and the episode's trace (its calls' scopes
/// index the specification's rows).
pub type NtpExample<'a, R> = (&'a [R], &'a [R], &'a ProgramCall);

struct Decision {
    demo: usize,
    /// Which call makes it (numbered over the batch).
    call: usize,
    observation: usize,
    program: usize,
    scope: (usize, usize),
    eop: bool,
    next_program: usize,
    argument: Option<usize>,
    callee_scope: Option<(usize, usize)>,
}

fn decisions_of(
    call: &ProgramCall,
    demo: usize,
    inherited: (usize, usize),
    calls: &mut usize,
    out: &mut Vec<Decision>,
) {
    if call.children.is_empty() {
        return;
    }
    let scope = call.scope.unwrap_or(inherited);
    let id = *calls;
    *calls += 1;
    for child in &call.children {
        out.push(Decision {
            demo,
            call: id,
            observation: child.start,
            program: call.program,
            scope,
            eop: false,
            next_program: child.program,
            argument: child.argument,
            callee_scope: if child.children.is_empty() {
                None
            } else {
                child.scope
            },
        });
        decisions_of(child, demo, scope, calls, out);
    }
    out.push(Decision {
        demo,
        call: id,
        observation: call.end,
        program: call.program,
        scope,
        eop: true,
        next_program: 0,
        argument: None,
        callee_scope: None,
    });
}

impl NtpBatch {
    /// Every decision of every example's trace, with the specification
    /// demos padded to the longest; rows have `obs_dim` values, programs and
    /// arguments are below `num_programs` / `num_arguments`, and every
    /// index (observations, scopes) is in range.
    pub fn new<R: AsRef<[f32]>>(
        examples: &[NtpExample<'_, R>],
        obs_dim: usize,
        num_programs: usize,
        num_arguments: usize,
        device: &Device,
    ) -> Result<Self> {
        if examples.is_empty() {
            return Err(ModelError::Input("empty NTP batch".into()));
        }
        let b = examples.len();
        let r = examples.iter().map(|e| e.0.len()).max().unwrap_or(0);
        if r == 0 {
            return Err(ModelError::Input(
                "NTP batch: every specification needs a row".into(),
            ));
        }
        let mut spec = vec![0.0f32; b * r * obs_dim];
        let mut spec_mask = vec![0.0f32; b * r];
        let mut decisions = Vec::new();
        let mut calls = 0;
        for (i, (rows, episode, trace)) in examples.iter().enumerate() {
            if rows.is_empty() {
                return Err(ModelError::Input(format!(
                    "NTP example {i}: empty specification"
                )));
            }
            for (t, row) in rows.iter().enumerate() {
                let row = row.as_ref();
                if row.len() != obs_dim {
                    return Err(ModelError::shape(
                        "NTP specification row",
                        format!("{obs_dim} values"),
                        format!("{} in example {i}, row {t}", row.len()),
                    ));
                }
                spec[(i * r + t) * obs_dim..(i * r + t + 1) * obs_dim].copy_from_slice(row);
                spec_mask[i * r + t] = 1.0;
            }
            let first = decisions.len();
            decisions_of(trace, i, (0, rows.len() - 1), &mut calls, &mut decisions);
            for d in &decisions[first..] {
                let bad_scope = |(s, e): (usize, usize)| s > e || e >= rows.len();
                if d.observation >= episode.len()
                    || episode[d.observation].as_ref().len() != obs_dim
                    || d.program >= num_programs
                    || d.next_program >= num_programs
                    || d.argument.is_some_and(|a| a >= num_arguments)
                    || bad_scope(d.scope)
                    || d.callee_scope.is_some_and(bad_scope)
                {
                    return Err(ModelError::Input(format!(
                        "NTP example {i}: a trace call is out of range (observation {} of {}, program {} / {} of {num_programs}, argument {:?} of {num_arguments}, scope {:?} / {:?} of {} rows)",
                        d.observation,
                        episode.len(),
                        d.program,
                        d.next_program,
                        d.argument,
                        d.scope,
                        d.callee_scope,
                        rows.len()
                    )));
                }
            }
        }
        if decisions.is_empty() {
            return Err(ModelError::Input(
                "NTP batch: no trace calls a program".into(),
            ));
        }
        let s = decisions.len();
        let mut observations = vec![0.0f32; s * obs_dim];
        let mut scope_mask = vec![0.0f32; s * r];
        let mut scope_steps = Vec::new();
        let mut scope_labels = Vec::new();
        let mut scope_weight = Vec::new();
        for (k, d) in decisions.iter().enumerate() {
            let row = examples[d.demo].1[d.observation].as_ref();
            observations[k * obs_dim..(k + 1) * obs_dim].copy_from_slice(row);
            let (ps, pe) = d.scope;
            for v in &mut scope_mask[k * r + ps..=k * r + pe] {
                *v = 1.0;
            }
            if let Some((cs, ce)) = d.callee_scope {
                scope_steps.push(k as i64);
                for t in 0..r {
                    scope_labels.push(if t < cs || t > ce {
                        SCOPE_OUTSIDE
                    } else if t == cs {
                        SCOPE_START
                    } else if t == ce {
                        SCOPE_END
                    } else {
                        SCOPE_INSIDE
                    } as i64);
                    scope_weight.push(if (ps..=pe).contains(&t) { 1.0f32 } else { 0.0 });
                }
            }
        }
        let ints = |v: Vec<i64>| {
            Tensor::<1, Int>::from_data(TensorData::new(v.clone(), [v.len()]), device)
        };
        let floats =
            |v: Vec<f32>| Tensor::<1>::from_data(TensorData::new(v.clone(), [v.len()]), device);
        let k = scope_steps.len();
        Ok(NtpBatch {
            spec: Tensor::from_data(TensorData::new(spec, [b, r, obs_dim]), device),
            spec_mask: Tensor::from_data(TensorData::new(spec_mask, [b, r]), device),
            demo_index: ints(decisions.iter().map(|d| d.demo as i64).collect()),
            observations: Tensor::from_data(TensorData::new(observations, [s, obs_dim]), device),
            programs: ints(decisions.iter().map(|d| d.program as i64).collect()),
            scope_mask: Tensor::from_data(TensorData::new(scope_mask, [s, r]), device),
            eop: floats(
                decisions
                    .iter()
                    .map(|d| f32::from(u8::from(d.eop)))
                    .collect(),
            ),
            next_program: ints(decisions.iter().map(|d| d.next_program as i64).collect()),
            argument: ints(
                decisions
                    .iter()
                    .map(|d| d.argument.unwrap_or(0) as i64)
                    .collect(),
            ),
            argument_weight: floats(
                decisions
                    .iter()
                    .map(|d| f32::from(u8::from(d.argument.is_some())))
                    .collect(),
            ),
            scope_steps: ints(scope_steps),
            scope_labels: Tensor::from_data(TensorData::new(scope_labels, [k, r]), device),
            scope_weight: Tensor::from_data(TensorData::new(scope_weight, [k, r]), device),
            calls: CallSteps::new(
                &decisions.iter().map(|d| d.call).collect::<Vec<_>>(),
                device,
            ),
            decisions: s,
        })
    }
}

/// The heads' outputs for a set of decisions.
#[derive(Debug, Clone)]
pub struct NtpOutput {
    /// Core states `[S, H]`: the feed-forward core's, or a recurrent
    /// core's GRU state after the decision (what the heads read, and what
    /// its call's next decision continues from).
    pub core: Tensor<2>,
    /// Next sub-program logits `[S, P]`.
    pub program_logits: Tensor<2>,
    /// End-of-program logits `[S]`.
    pub eop_logits: Tensor<1>,
    /// Argument logits `[S, A]`.
    pub argument_logits: Tensor<2>,
}

/// NTP's training loss and what it got right.
#[derive(Debug, Clone)]
pub struct NtpLoss {
    /// Sum of the four losses (one element).
    pub loss: Tensor<1>,
    /// End-of-program decisions right.
    pub eop_accuracy: f32,
    /// Sub-programs right (where the program does not return).
    pub program_accuracy: f32,
    /// Arguments right (where supervised).
    pub argument_accuracy: f32,
    /// Scope row labels right (on the caller's scope rows).
    pub scope_accuracy: f32,
}

impl NtpNet {
    /// Number of programs.
    pub fn num_programs(&self) -> usize {
        self.config.num_programs
    }

    /// Number of argument values.
    pub fn num_arguments(&self) -> usize {
        self.config.num_arguments
    }

    /// Length `D` of one observation row.
    pub fn obs_dim(&self) -> usize {
        self.encoder.input_dim()
    }

    fn device(&self) -> Device {
        self.programs.val().device()
    }

    /// With object arguments, each row's score of each object `[N, K]`
    /// for rows `[N, D]` (from the object's three position values alone).
    fn object_scores(&self, rows: Tensor<2>) -> Option<Tensor<2>> {
        let ((first, second), k) = (self.object_scorer.as_ref()?, self.config.object_arguments?);
        let n = rows.dims()[0];
        let positions: Tensor<3> = rows.narrow(1, 0, 3 * k).reshape([n, k, 3]);
        Some(
            second
                .forward(relu(first.forward(positions)))
                .reshape([n, k]),
        )
    }

    /// Encodes specification demos `[B, R, D]` with `mask` `[B, R]`.
    pub fn encode_spec(&self, spec: Tensor<3>, mask: Tensor<2>) -> Result<EncodedSpec> {
        let [b, r, _] = spec.dims();
        if mask.dims() != [b, r] {
            return Err(ModelError::shape(
                "spec mask",
                format!("[{b}, {r}]"),
                mask.dims(),
            ));
        }
        let rows = self.encoder.forward_sequence(spec.clone())? * mask.unsqueeze_dim::<3>(2);
        let e = rows.dims()[2];
        let device = rows.device();
        let (prev, next) = if r == 1 {
            let z = Tensor::zeros([b, 1, e], &device);
            (z.clone(), z)
        } else {
            let z = Tensor::zeros([b, 1, e], &device);
            (
                Tensor::cat(vec![z.clone(), rows.clone().narrow(1, 0, r - 1)], 1),
                Tensor::cat(vec![rows.clone().narrow(1, 1, r - 1), z], 1),
            )
        };
        let taps = self
            .scope_demo
            .forward(Tensor::cat(vec![prev, rows.clone(), next], 2));
        let keys = self.key.forward(rows.clone());
        let matched = self
            .scope_match
            .as_ref()
            .map(|(g, _)| g.forward(rows.clone()));
        let objects = self
            .object_scores(spec.reshape([b * r, self.obs_dim()]))
            .map(|scores| {
                let k = scores.dims()[1];
                scores.reshape([b, r, k])
            });
        Ok(EncodedSpec {
            rows,
            keys,
            taps,
            objects,
            matched,
        })
    }

    /// The heads for decisions `demo_index` `[S]` (which encoded demo each
    /// reads), on `observations` `[S, D]`, in `programs` `[S]`, attending to
    /// `scope_mask` `[S, R]`; a recurrent core continues each decision's
    /// call from `state`.
    pub fn decide(
        &self,
        spec: &EncodedSpec,
        demo_index: Tensor<1, Int>,
        observations: Tensor<2>,
        programs: Tensor<1, Int>,
        scope_mask: Tensor<2>,
        state: CoreState<'_>,
    ) -> Result<NtpOutput> {
        let [s] = demo_index.dims();
        let [_, r, _] = spec.rows.dims();
        if observations.dims()[0] != s || programs.dims() != [s] || scope_mask.dims() != [s, r] {
            return Err(ModelError::shape(
                "NTP decisions",
                format!("{s} observations, programs and [{s}, {r}] scope masks"),
                (observations.dims(), programs.dims(), scope_mask.dims()),
            ));
        }
        let h = self.config.hidden;
        let grid = DemoGrid::new(demo_index, spec.rows.dims()[0])?;
        let observations_for_objects = observations.clone();
        let obs = self.encoder.forward(observations)?;
        let prog = self.programs.val().select(0, programs);
        let q = grid.to_grid(self.query.forward(prog.clone())); // [B, M, H]
        let scores = q
            .matmul(spec.keys.clone().swap_dims(1, 2))
            .div_scalar((h as f32).sqrt()); // [B, M, R]
        // Empty places of the grid attend nowhere (all rows masked) and are
        // dropped by `decisions_of`.
        let outside = grid.to_grid(scope_mask).lower_elem(0.5);
        let alpha = softmax(scores.mask_fill(outside, MASKED_LOGIT), 2);
        let pooled_objects = spec
            .objects
            .as_ref()
            .map(|objects| grid.decisions_of(alpha.clone().matmul(objects.clone()))); // [S, K]
        let context = grid.decisions_of(alpha.matmul(spec.rows.clone())); // [S, E]
        let mut core_input = vec![obs, prog, context];
        if let (Some(pooled), Some(current)) = (
            &pooled_objects,
            self.object_scores(observations_for_objects),
        ) {
            core_input.push(softmax(pooled.clone(), 1));
            core_input.push(softmax(current, 1));
        }
        let core = relu(
            self.core_hidden
                .forward(relu(self.core_in.forward(Tensor::cat(core_input, 1)))),
        );
        let core = match &self.core_gru {
            Some(gru) => recur(gru, core, state)?,
            None => core,
        };
        Ok(NtpOutput {
            program_logits: self.program_out.forward(core.clone()),
            eop_logits: self.eop_out.forward(core.clone()).reshape([s]),
            argument_logits: match pooled_objects {
                Some(p) => self.argument_out.forward(core.clone()) + p,
                None => self.argument_out.forward(core.clone()),
            },
            core,
        })
    }

    /// Scope row logits `[K, R, 4]` for the callees of decisions whose
    /// demos are `demo_index` `[K]` and core states `core` `[K, H]`.
    pub fn scope_logits(
        &self,
        spec: &EncodedSpec,
        demo_index: Tensor<1, Int>,
        core: Tensor<2>,
    ) -> Result<Tensor<3>> {
        let [b, r, _] = spec.taps.dims();
        let grid = DemoGrid::new(demo_index, b)?;
        // [B, 1, R, ·] + [B, M, 1, ·]: every demo row beside every decision
        // of that demo.
        let taps = spec.taps.clone().unsqueeze_dim::<4>(1);
        let u = grid
            .to_grid(self.scope_core.forward(core.clone()))
            .unsqueeze_dim::<4>(2);
        let hidden = match (&self.scope_match, &spec.matched) {
            (Some((_, m)), Some(matched)) => {
                let g = grid.to_grid(m.forward(core)).unsqueeze_dim::<4>(2);
                taps + u + matched.clone().unsqueeze_dim::<4>(1) * g
            }
            _ => taps + u,
        };
        let logits = self.scope_out.forward(relu(hidden)); // [B, M, R, 4]
        let [_, m, _, c] = logits.dims();
        let k = grid.decisions;
        Ok(grid
            .decisions_of(logits.reshape([b, m, r * c]))
            .reshape([k, r, c]))
    }

    /// The batch of `examples` for this network (its row length, programs
    /// and arguments; see [`NtpBatch::new`]).
    pub fn batch<R: AsRef<[f32]>>(
        &self,
        examples: &[NtpExample<'_, R>],
        device: &Device,
    ) -> Result<NtpBatch> {
        NtpBatch::new(
            examples,
            self.obs_dim(),
            self.num_programs(),
            self.num_arguments(),
            device,
        )
    }

    /// The encoded specification demos of `batch` and the heads of its
    /// decisions.
    fn heads(&self, batch: &NtpBatch) -> Result<(EncodedSpec, NtpOutput)> {
        let spec = self.encode_spec(batch.spec.clone(), batch.spec_mask.clone())?;
        let out = self.decide(
            &spec,
            batch.demo_index.clone(),
            batch.observations.clone(),
            batch.programs.clone(),
            batch.scope_mask.clone(),
            CoreState::Calls(&batch.calls),
        )?;
        Ok((spec, out))
    }

    /// The four losses on `batch` (end-of-program: binary cross-entropy;
    /// sub-program, argument, scope rows: cross-entropy where supervised).
    pub fn loss(&self, batch: &NtpBatch) -> Result<NtpLoss> {
        let (spec, out) = self.heads(batch)?;
        let s = batch.decisions;
        // Binary cross-entropy with logits: softplus(x) − y x.
        let x = out.eop_logits.clone();
        let softplus = relu(x.clone()) + x.clone().abs().neg().exp().add_scalar(1.0).log();
        let eop_loss = (softplus - batch.eop.clone() * x.clone()).mean();
        let predicted = x.detach().greater_elem(0.0).float();
        let eop_accuracy = 1.0 - scalar((predicted - batch.eop.clone()).abs().mean())?;
        let calls = batch.eop.clone().neg().add_scalar(1.0);
        let program_loss = masked_cross_entropy(
            out.program_logits.clone(),
            batch.next_program.clone(),
            calls.clone(),
        );
        let program_accuracy =
            masked_accuracy(out.program_logits, batch.next_program.clone(), calls)?;
        let argument_loss = masked_cross_entropy(
            out.argument_logits.clone(),
            batch.argument.clone(),
            batch.argument_weight.clone(),
        );
        let argument_accuracy = masked_accuracy(
            out.argument_logits,
            batch.argument.clone(),
            batch.argument_weight.clone(),
        )?;
        let mut loss = eop_loss + program_loss + argument_loss;
        let [k] = batch.scope_steps.dims();
        let mut scope_accuracy = 0.0;
        if k > 0 {
            let r = batch.scope_labels.dims()[1];
            let demos = batch
                .demo_index
                .clone()
                .select(0, batch.scope_steps.clone());
            let core = out.core.select(0, batch.scope_steps.clone());
            let logits = self.scope_logits(&spec, demos, core)?.reshape([k * r, 4]);
            let labels = batch.scope_labels.clone().reshape([k * r]);
            let weights = batch.scope_weight.clone().reshape([k * r]);
            scope_accuracy = masked_accuracy(logits.clone(), labels.clone(), weights.clone())?;
            loss = loss + masked_cross_entropy(logits, labels, weights);
        }
        debug_assert!(s > 0);
        Ok(NtpLoss {
            loss,
            eop_accuracy,
            program_accuracy,
            argument_accuracy,
            scope_accuracy,
        })
    }

    /// Each decision of `batch` checked against its trace (teacher
    /// forcing: every decision reads the trace's observation, program and
    /// scope), as the program stack would take it: end-of-program by the
    /// sign of its logit, the sub-program and argument by their argmax, the
    /// callee's scope by [`scope_from_logits`] within the caller's. Run it
    /// on the inference network ([`Module::valid`]).
    pub fn check_decisions(&self, batch: &NtpBatch) -> Result<Vec<NtpDecisionCheck>> {
        let (spec, out) = self.heads(batch)?;
        let s = batch.decisions;
        let argmax_rows = |v: Vec<f32>, width: usize| -> Vec<usize> {
            v.chunks_exact(width.max(1)).map(first_argmax).collect()
        };
        let eop_logits = to_vec(out.eop_logits.clone())?;
        let programs = argmax_rows(to_vec(out.program_logits.clone())?, self.num_programs());
        let arguments = argmax_rows(to_vec(out.argument_logits.clone())?, self.num_arguments());
        let index = |t: Tensor<1, Int>| -> Result<Vec<usize>> {
            Ok(to_vec_int(t)?.into_iter().map(|x| x as usize).collect())
        };
        let demo = index(batch.demo_index.clone())?;
        let caller = index(batch.programs.clone())?;
        let next = index(batch.next_program.clone())?;
        let argument = index(batch.argument.clone())?;
        let eop = to_vec(batch.eop.clone())?;
        let argument_weight = to_vec(batch.argument_weight.clone())?;
        let r = batch.spec_mask.dims()[1];
        let scope_mask = to_vec(batch.scope_mask.clone())?;
        let mut checks: Vec<NtpDecisionCheck> = (0..s)
            .map(|k| {
                let returns = eop[k] > 0.5;
                NtpDecisionCheck {
                    demo: demo[k],
                    program: caller[k],
                    returns,
                    next_program: next[k],
                    eop_right: (eop_logits[k] > 0.0) == returns,
                    program_right: (!returns).then(|| programs[k] == next[k]),
                    argument_right: (argument_weight[k] > 0.5).then(|| arguments[k] == argument[k]),
                    scope_right: None,
                }
            })
            .collect();
        let steps = index(batch.scope_steps.clone())?;
        if !steps.is_empty() {
            let demos = batch
                .demo_index
                .clone()
                .select(0, batch.scope_steps.clone());
            let core = out.core.select(0, batch.scope_steps.clone());
            let logits = to_vec(self.scope_logits(&spec, demos, core)?)?;
            let labels = to_vec_int(batch.scope_labels.clone())?;
            for (j, &step) in steps.iter().enumerate() {
                let rows = &scope_mask[step * r..(step + 1) * r];
                let lo = rows.iter().position(|&m| m > 0.5).unwrap_or(0);
                let hi = rows.iter().rposition(|&m| m > 0.5).unwrap_or(lo);
                let own = &labels[j * r..(j + 1) * r];
                let start = own.iter().position(|&l| l == SCOPE_START as i64);
                let end = own.iter().position(|&l| l == SCOPE_END as i64).or(start);
                let predicted = scope_from_logits(&logits[j * r * 4..(j + 1) * r * 4], (lo, hi));
                checks[step].scope_right = Some(start.zip(end) == Some(predicted));
            }
        }
        Ok(checks)
    }

    /// The network conditioned on one specification demo (its rows, in
    /// order), in inference mode, with the demo encoded once.
    pub fn condition<R: AsRef<[f32]>>(&self, spec: &[R]) -> Result<ConditionedNtp> {
        if spec.is_empty() {
            return Err(ModelError::Input(
                "a demonstration needs at least one observation".into(),
            ));
        }
        let model = self.valid();
        let device = model.device();
        let r = spec.len();
        let rows = rows_tensor(spec, model.obs_dim(), &device)?.unsqueeze_dim::<3>(0);
        let mask = Tensor::ones([1, r], &device);
        let encoded = model.encode_spec(rows, mask)?;
        Ok(ConditionedNtp {
            model,
            encoded,
            rows: r,
        })
    }

    /// Saves the configuration (`config.json`) and weights (`model.bpk`)
    /// into `dir`, creating it if needed.
    pub fn save(&self, dir: impl AsRef<Path>) -> Result<()> {
        crate::checkpoint::save(self, &self.config, dir.as_ref())
    }

    /// Loads a network saved by [`NtpNet::save`] onto `device`; a missing,
    /// corrupt or mismatched file is an error naming it.
    pub fn load(dir: impl AsRef<Path>, device: &Device) -> Result<Self> {
        let config: NtpConfig = crate::checkpoint::load_config(dir.as_ref(), NtpConfig::validate)?;
        crate::checkpoint::load_weights(config.init(device)?, dir.as_ref())
    }
}

/// A recurrent core's GRU states `[S, H]` for the feed-forward core's
/// states `core` `[S, H]`, each decision continuing its call from `state`.
fn recur(gru: &GruCell, core: Tensor<2>, state: CoreState<'_>) -> Result<Tensor<2>> {
    let [s, h] = core.dims();
    let x = gru.project_input(core);
    let device = x.device();
    match state {
        CoreState::First => Ok(gru.step_projected(x, Tensor::zeros([s, h], &device))),
        CoreState::Previous(previous) => {
            if previous.dims() != [s, h] {
                return Err(ModelError::shape(
                    "recurrent core state",
                    format!("[{s}, {h}]"),
                    previous.dims(),
                ));
            }
            Ok(gru.step_projected(x, previous.clone()))
        }
        CoreState::Calls(calls) => {
            let mut done: Option<Tensor<2>> = None;
            for (here, before) in calls.steps.iter().zip(&calls.previous) {
                let [n] = here.dims();
                let previous = match &done {
                    Some(d) => d.clone().select(0, before.clone()),
                    None => Tensor::zeros([n, h], &device),
                };
                let next = gru.step_projected(x.clone().select(0, here.clone()), previous);
                done = Some(match done {
                    Some(d) => Tensor::cat(vec![d, next], 0),
                    None => next,
                });
            }
            let done = done.ok_or_else(|| ModelError::Input("no decisions".into()))?;
            if done.dims()[0] != s {
                return Err(ModelError::shape(
                    "decisions of the calls",
                    format!("{s}"),
                    done.dims()[0],
                ));
            }
            Ok(done.select(0, calls.position.clone()))
        }
    }
}

/// One frame of the program stack: a running program and its scope of the
/// specification demo (rows, inclusive).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct StackFrame {
    /// The program.
    pub program: usize,
    /// Its scope of the demo.
    pub scope: (usize, usize),
}

/// What a program decides on one observation.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct NtpDecision {
    /// Return to the caller.
    pub end_of_program: bool,
    /// Otherwise, the sub-program to call.
    pub program: usize,
    /// Its argument (read for primitives).
    pub argument: usize,
    /// Its scope of the demo (read for non-primitives).
    pub scope: (usize, usize),
}

/// One decision of a trace checked against what the network decides
/// there ([`NtpNet::check_decisions`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct NtpDecisionCheck {
    /// Which example of the batch it belongs to.
    pub demo: usize,
    /// The program deciding (the caller).
    pub program: usize,
    /// Whether the trace returns here (end-of-program).
    pub returns: bool,
    /// The sub-program the trace calls (0 where it returns).
    pub next_program: usize,
    /// End-of-program decided right.
    pub eop_right: bool,
    /// Where the trace calls: the sub-program decided right.
    pub program_right: Option<bool>,
    /// Where the trace's call takes an argument: the argument decided right.
    pub argument_right: Option<bool>,
    /// Where the callee's scope is supervised: the scope the stack would
    /// give it is exactly the trace's.
    pub scope_right: Option<bool>,
}

impl NtpDecisionCheck {
    /// Whether the program stack would take exactly the trace's step here:
    /// the return, or the call with its argument and scope.
    pub fn right(&self) -> bool {
        self.eop_right
            && (self.returns
                || (self.program_right == Some(true)
                    && self.argument_right != Some(false)
                    && self.scope_right != Some(false)))
    }
}

/// Whatever decides for the running program: the network conditioned on a
/// demo ([`ConditionedNtp`]), or a replayed trace in tests.
pub trait NtpCore {
    /// The decision of `frame`'s program on `observation`.
    fn decide(&self, observation: &[f32], frame: &StackFrame) -> Result<NtpDecision>;

    /// The decision of `frame`'s program on `observation`, continuing the
    /// call from `state` (`None`: its first decision) and leaving the state
    /// after it there. A core without state (the default) decides alone.
    fn decide_in_call(
        &self,
        observation: &[f32],
        frame: &StackFrame,
        state: &mut Option<Vec<f32>>,
    ) -> Result<NtpDecision> {
        let _ = state;
        self.decide(observation, frame)
    }
}

/// What the program stack does next.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum StackStep {
    /// Run the primitive `program` with `argument` in the environment.
    Act {
        /// The primitive.
        program: usize,
        /// Its argument.
        argument: usize,
    },
    /// The root returned: the task is done.
    Done,
    /// No primitive within the call budget (programs calling and
    /// returning without acting, or the stack at its depth limit).
    Stalled,
}

/// NTP's executor: a call stack of programs. Each
/// [`ProgramStack::step`] asks the running program for decisions on the
/// current observation, pushing callees and popping returns, until a
/// primitive is called (the caller stays on the stack and decides again on
/// the next observation) or the root returns.
#[derive(Debug, Clone)]
pub struct ProgramStack {
    frames: Vec<StackFrame>,
    /// Per frame: its call's recurrent core state (`None` before its first
    /// decision, and for a core without state).
    states: Vec<Option<Vec<f32>>>,
    primitives: Vec<bool>,
    max_depth: usize,
}

impl ProgramStack {
    /// A stack running `root` over the whole demo of `demo_rows` rows;
    /// `primitives[p]` says whether program `p` acts in the environment;
    /// at most `max_depth` programs run at once.
    pub fn new(root: usize, demo_rows: usize, primitives: Vec<bool>, max_depth: usize) -> Self {
        ProgramStack {
            frames: vec![StackFrame {
                program: root,
                scope: (0, demo_rows.saturating_sub(1)),
            }],
            states: vec![None],
            primitives,
            max_depth: max_depth.max(1),
        }
    }

    /// The running programs, root first.
    pub fn frames(&self) -> &[StackFrame] {
        &self.frames
    }

    /// Decides on `observation` until a primitive is called, the root
    /// returns, or the budget (4 decisions per level) runs out.
    pub fn step(&mut self, core: &dyn NtpCore, observation: &[f32]) -> Result<StackStep> {
        for _ in 0..4 * self.max_depth + 4 {
            let Some(top) = self.frames.last().copied() else {
                return Ok(StackStep::Done);
            };
            let state = self.states.last_mut().expect("a state per frame");
            let d = core.decide_in_call(observation, &top, state)?;
            if d.end_of_program {
                self.frames.pop();
                self.states.pop();
                if self.frames.is_empty() {
                    return Ok(StackStep::Done);
                }
                continue;
            }
            if self.primitives.get(d.program).copied().unwrap_or(false) {
                return Ok(StackStep::Act {
                    program: d.program,
                    argument: d.argument,
                });
            }
            if self.frames.len() >= self.max_depth {
                return Ok(StackStep::Stalled);
            }
            self.frames.push(StackFrame {
                program: d.program,
                scope: d.scope,
            });
            self.states.push(None);
        }
        Ok(StackStep::Stalled)
    }
}

/// An [`NtpNet`] conditioned on one specification demo.
#[derive(Debug, Clone)]
pub struct ConditionedNtp {
    model: NtpNet,
    encoded: EncodedSpec,
    rows: usize,
}

impl ConditionedNtp {
    /// Rows of the specification demo.
    pub fn demo_rows(&self) -> usize {
        self.rows
    }
}

/// The index of the largest value of `v` (the first of equals; 0 if empty):
/// how the program stack reads a head's logits.
fn first_argmax(v: &[f32]) -> usize {
    v.iter()
        .enumerate()
        .fold(0, |best, (i, &x)| if x > v[best] { i } else { best })
}

/// The callee's scope from row-label logits `[R, 4]` within the caller's
/// scope: the row most probably a start, then the row after it most
/// probably an end (the start itself if it is the scope's last row).
pub fn scope_from_logits(logits: &[f32], caller: (usize, usize)) -> (usize, usize) {
    let (lo, hi) = caller;
    let probability = |r: usize, label: usize| {
        let Some(row) = logits.get(4 * r..4 * r + 4) else {
            return f32::MIN;
        };
        let max = row.iter().copied().fold(f32::MIN, f32::max);
        let total: f32 = row.iter().map(|&x| (x - max).exp()).sum();
        (row[label] - max).exp() / total
    };
    let argmax = |from: usize, label: usize| {
        (from..=hi).fold(from, |best, r| {
            if probability(r, label) > probability(best, label) {
                r
            } else {
                best
            }
        })
    };
    let start = argmax(lo, SCOPE_START);
    let end = if start < hi {
        argmax(start + 1, SCOPE_END)
    } else {
        start
    };
    (start, end)
}

impl NtpCore for ConditionedNtp {
    fn decide(&self, observation: &[f32], frame: &StackFrame) -> Result<NtpDecision> {
        self.decide_in_call(observation, frame, &mut None)
    }

    fn decide_in_call(
        &self,
        observation: &[f32],
        frame: &StackFrame,
        state: &mut Option<Vec<f32>>,
    ) -> Result<NtpDecision> {
        let device = self.model.device();
        let (lo, hi) = frame.scope;
        if lo > hi || hi >= self.rows {
            return Err(ModelError::Input(format!(
                "scope {lo}..={hi} outside a demo of {} rows",
                self.rows
            )));
        }
        let mask: Vec<f32> = (0..self.rows)
            .map(|r| f32::from(u8::from((lo..=hi).contains(&r))))
            .collect();
        let index = Tensor::<1, Int>::from_data(TensorData::new(vec![0i64], [1]), &device);
        let previous = state.take().map(|previous| {
            let h = previous.len();
            Tensor::<2>::from_data(TensorData::new(previous, [1, h]), &device)
        });
        let out = self.model.decide(
            &self.encoded,
            index.clone(),
            rows_tensor(&[observation], self.model.obs_dim(), &device)?,
            Tensor::from_data(TensorData::new(vec![frame.program as i64], [1]), &device),
            Tensor::from_data(TensorData::new(mask, [1, self.rows]), &device),
            previous
                .as_ref()
                .map_or(CoreState::First, CoreState::Previous),
        )?;
        if self.model.core_gru.is_some() {
            *state = Some(to_vec(out.core.clone())?);
        }
        let eop = to_vec(out.eop_logits)?[0] > 0.0;
        let program = first_argmax(&to_vec(out.program_logits)?);
        let argument = first_argmax(&to_vec(out.argument_logits)?);
        let scope = if eop || self.model.config.num_programs <= program {
            frame.scope
        } else {
            let logits = to_vec(self.model.scope_logits(&self.encoded, index, out.core)?)?;
            scope_from_logits(&logits, frame.scope)
        };
        Ok(NtpDecision {
            end_of_program: eop,
            program,
            argument,
            scope,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::tests::device as cpu_device;
    use std::cell::RefCell;

    // Programs of the hand-written traces: 0 root, 1 sub, 2 act-a, 3 act-b.
    const ROOT: usize = 0;
    const SUB: usize = 1;
    const A: usize = 2;
    const B: usize = 3;

    fn leaf(program: usize, argument: Option<usize>, t: usize) -> ProgramCall {
        ProgramCall {
            program,
            argument,
            start: t,
            end: t + 1,
            scope: None,
            children: Vec::new(),
        }
    }

    /// root(sub[rows 0..=2](a(1) b) sub[rows 2..=4](a(0) b)), 4 primitives.
    fn trace() -> ProgramCall {
        let sub = |t: usize, arg: usize, scope: (usize, usize)| ProgramCall {
            program: SUB,
            argument: None,
            start: t,
            end: t + 2,
            scope: Some(scope),
            children: vec![leaf(A, Some(arg), t), leaf(B, None, t + 1)],
        };
        ProgramCall {
            program: ROOT,
            argument: None,
            start: 0,
            end: 4,
            scope: None,
            children: vec![sub(0, 1, (0, 2)), sub(2, 0, (2, 4))],
        }
    }

    /// A core replaying a list of decisions, recording what it was asked.
    struct Scripted {
        decisions: RefCell<Vec<NtpDecision>>,
        asked: RefCell<Vec<StackFrame>>,
    }

    fn call(program: usize, argument: usize, scope: (usize, usize)) -> NtpDecision {
        NtpDecision {
            end_of_program: false,
            program,
            argument,
            scope,
        }
    }

    fn ret() -> NtpDecision {
        NtpDecision {
            end_of_program: true,
            program: 0,
            argument: 0,
            scope: (0, 0),
        }
    }

    impl NtpCore for Scripted {
        fn decide(&self, _: &[f32], frame: &StackFrame) -> Result<NtpDecision> {
            self.asked.borrow_mut().push(*frame);
            let mut d = self.decisions.borrow_mut();
            if d.is_empty() {
                return Err(ModelError::Input("script exhausted".into()));
            }
            Ok(d.remove(0))
        }
    }

    fn scripted(decisions: Vec<NtpDecision>) -> Scripted {
        Scripted {
            decisions: RefCell::new(decisions),
            asked: RefCell::new(Vec::new()),
        }
    }

    fn primitives() -> Vec<bool> {
        vec![false, false, true, true]
    }

    #[test]
    fn the_stack_calls_acts_returns_and_ends() {
        let core = scripted(vec![
            call(SUB, 0, (1, 3)), // root → sub over rows 1..=3
            call(A, 5, (0, 0)),   // sub → a(5)
            call(B, 0, (0, 0)),   // sub → b
            ret(),                // sub returns
            ret(),                // root returns
        ]);
        let mut stack = ProgramStack::new(ROOT, 6, primitives(), 3);
        assert_eq!(stack.frames()[0].scope, (0, 5));
        let o = [0.0f32];
        assert_eq!(
            stack.step(&core, &o).unwrap(),
            StackStep::Act {
                program: A,
                argument: 5
            }
        );
        // The callee runs in the scope its caller gave it.
        assert_eq!(
            stack.frames(),
            &[
                StackFrame {
                    program: ROOT,
                    scope: (0, 5)
                },
                StackFrame {
                    program: SUB,
                    scope: (1, 3)
                }
            ]
        );
        assert_eq!(
            stack.step(&core, &o).unwrap(),
            StackStep::Act {
                program: B,
                argument: 0
            }
        );
        // After the primitive, the same program decides again; returning
        // hands the same observation back to the caller.
        assert_eq!(stack.step(&core, &o).unwrap(), StackStep::Done);
        let asked: Vec<usize> = core.asked.borrow().iter().map(|f| f.program).collect();
        assert_eq!(asked, vec![ROOT, SUB, SUB, SUB, ROOT]);
    }

    #[test]
    fn a_stack_that_never_acts_stalls_instead_of_looping() {
        // The root calls sub, which returns at once, forever.
        let core = scripted(
            (0..100)
                .flat_map(|_| [call(SUB, 0, (0, 1)), ret()])
                .collect(),
        );
        let mut stack = ProgramStack::new(ROOT, 2, primitives(), 3);
        assert_eq!(stack.step(&core, &[0.0]).unwrap(), StackStep::Stalled);
        // So does one that nests deeper than its limit.
        let core = scripted(vec![call(SUB, 0, (0, 1)); 10]);
        let mut stack = ProgramStack::new(ROOT, 2, primitives(), 3);
        assert_eq!(stack.step(&core, &[0.0]).unwrap(), StackStep::Stalled);
        assert_eq!(stack.frames().len(), 3);
    }

    #[test]
    fn a_trace_becomes_one_decision_per_call_and_return() {
        let device = cpu_device();
        let spec: Vec<Vec<f32>> = (0..5).map(|i| vec![i as f32, 0.0]).collect();
        let episode: Vec<Vec<f32>> = (0..5).map(|i| vec![10.0 + i as f32, 1.0]).collect();
        let t = trace();
        let batch = NtpBatch::new(&[(&spec[..], &episode[..], &t)], 2, 4, 2, &device).unwrap();
        // root: 2 calls + return; each sub: 2 calls + return.
        assert_eq!(batch.decisions, 9);
        let ints = |x: Tensor<1, Int>| crate::nn::to_vec_int(x).unwrap();
        assert_eq!(
            ints(batch.programs.clone()),
            vec![0, 1, 1, 1, 0, 1, 1, 1, 0]
        );
        assert_eq!(
            ints(batch.next_program.clone()),
            vec![1, 2, 3, 0, 1, 2, 3, 0, 0]
        );
        assert_eq!(
            to_vec(batch.eop.clone()).unwrap(),
            vec![0., 0., 0., 1., 0., 0., 0., 1., 1.]
        );
        // Observations: the episode row at each call's start, and at the
        // returning program's end.
        let obs = to_vec(batch.observations.clone()).unwrap();
        let firsts: Vec<f32> = obs.chunks(2).map(|r| r[0] - 10.0).collect();
        assert_eq!(firsts, vec![0., 0., 1., 2., 2., 2., 3., 4., 4.]);
        assert_eq!(ints(batch.argument.clone())[1], 1);
        assert_eq!(ints(batch.argument.clone())[5], 0);
        assert_eq!(
            to_vec(batch.argument_weight.clone()).unwrap(),
            vec![0., 1., 0., 0., 0., 1., 0., 0., 0.]
        );
        // The root's calls have their scopes supervised, within the whole
        // demo; the subs read only theirs.
        assert_eq!(ints(batch.scope_steps.clone()), vec![0, 4]);
        let labels = crate::nn::to_vec_int(batch.scope_labels.clone()).unwrap();
        assert_eq!(labels, vec![1, 2, 3, 0, 0, 0, 0, 1, 2, 3]);
        let mask = to_vec(batch.scope_mask.clone()).unwrap();
        assert_eq!(&mask[5..10], &[1., 1., 1., 0., 0.]);
        assert_eq!(&mask[25..30], &[0., 0., 1., 1., 1.]);
    }

    #[test]
    fn a_trace_out_of_range_is_an_error_not_a_panic() {
        let device = cpu_device();
        let spec: Vec<Vec<f32>> = (0..3).map(|i| vec![i as f32, 0.0]).collect();
        let episode = spec.clone();
        let t = trace(); // its scopes reach row 4 and observation 4
        let err = NtpBatch::new(&[(&spec[..], &episode[..], &t)], 2, 4, 2, &device).unwrap_err();
        assert!(err.to_string().contains("out of range"), "{err}");
        let err = NtpBatch::new(&[(&spec[..], &episode[..], &t)], 2, 3, 2, &device);
        assert!(err.is_err(), "program 3 of 3 accepted");
    }

    #[test]
    fn the_scope_is_the_likeliest_start_then_the_likeliest_end_after_it() {
        let mut logits = vec![0.0f32; 4 * 6];
        logits[4 * 2 + SCOPE_START] = 5.0;
        logits[4 + SCOPE_END] = 9.0; // before the start: ignored
        logits[4 * 4 + SCOPE_END] = 3.0;
        // A row whose end logit is larger but whose label is likelier
        // outside is not the end: probabilities, not logits, compare.
        logits[4 * 5 + SCOPE_END] = 4.0;
        logits[4 * 5 + SCOPE_OUTSIDE] = 9.0;
        assert_eq!(scope_from_logits(&logits, (0, 5)), (2, 4));
        // Limited to the caller's scope.
        assert_eq!(scope_from_logits(&logits, (3, 5)), (3, 4));
        assert_eq!(scope_from_logits(&logits, (5, 5)), (5, 5));
    }

    fn tiny_net(seed: u64) -> NtpNet {
        NtpConfig::new(4, 2, EncoderConfig::state(2))
            .with_hidden(32)
            .with_scope_match(Some(true))
            .with_seed(seed)
            .init(&cpu_device())
            .unwrap()
    }

    #[test]
    fn decision_checks_follow_the_trace_and_agree_with_the_loss() {
        let device = cpu_device();
        let spec: Vec<Vec<f32>> = (0..5).map(|i| vec![i as f32 / 4.0, 0.0]).collect();
        let episode: Vec<Vec<f32>> = (0..5).map(|i| vec![i as f32 / 4.0, 1.0]).collect();
        let t = trace();
        let batch = NtpBatch::new(
            &[(&spec[..], &episode[..], &t), (&spec[..], &episode[..], &t)],
            2,
            4,
            2,
            &device,
        )
        .unwrap();
        for seed in 0..4 {
            let net = tiny_net(seed);
            let checks = net.check_decisions(&batch).unwrap();
            assert_eq!(checks.len(), 18);
            let per_demo: Vec<usize> = (0..2)
                .map(|d| checks.iter().filter(|c| c.demo == d).count())
                .collect();
            assert_eq!(per_demo, vec![9, 9]);
            // The trace's steps, in order: root calls sub, sub calls a and
            // b and returns, again, and the root returns.
            let steps: Vec<(usize, bool, usize)> = checks[..9]
                .iter()
                .map(|c| (c.program, c.returns, c.next_program))
                .collect();
            let call = |p, n| (p, false, n);
            let ret = |p| (p, true, 0);
            assert_eq!(
                steps,
                vec![
                    call(ROOT, SUB),
                    call(SUB, A),
                    call(SUB, B),
                    ret(SUB),
                    call(ROOT, SUB),
                    call(SUB, A),
                    call(SUB, B),
                    ret(SUB),
                    ret(ROOT)
                ]
            );
            // Arguments where `a` is called, scopes where `sub` is.
            let supervised =
                |f: fn(&NtpDecisionCheck) -> bool| checks.iter().filter(|c| f(c)).count();
            assert_eq!(supervised(|c| c.argument_right.is_some()), 4);
            assert_eq!(supervised(|c| c.scope_right.is_some()), 4);
            assert_eq!(supervised(|c| c.program_right.is_some()), 12);
            // The loss's accuracies are the checks' means.
            let loss = net.loss(&batch).unwrap();
            let mean = |f: fn(&NtpDecisionCheck) -> Option<bool>| {
                let v: Vec<bool> = checks.iter().filter_map(f).collect();
                v.iter().filter(|&&x| x).count() as f32 / v.len() as f32
            };
            assert!((mean(|c| Some(c.eop_right)) - loss.eop_accuracy).abs() < 1e-6);
            assert!((mean(|c| c.program_right) - loss.program_accuracy).abs() < 1e-6);
            assert!((mean(|c| c.argument_right) - loss.argument_accuracy).abs() < 1e-6);
        }
    }

    #[test]
    fn the_network_learns_a_trace_and_replays_it_through_the_stack() {
        let episode: Vec<Vec<f32>> = (0..5).map(|i| vec![i as f32 / 4.0, 1.0]).collect();
        for (scope_match, recurrent) in [(false, false), (true, false), (false, true)] {
            learn_a_trace_and_replay_it(scope_match, recurrent, &episode);
        }
    }

    #[test]
    fn only_a_recurrent_core_tells_apart_decisions_on_the_same_observation() {
        // Every observation alike: within a call, only what the call has
        // done so far says what comes next.
        let episode = vec![vec![0.5, 1.0]; 5];
        learn_a_trace_and_replay_it(false, true, &episode);
        let (_, _, reactive) = train_on_trace(false, false, &episode);
        assert!(
            reactive.program_accuracy < 1.0 && reactive.eop_accuracy < 1.0,
            "a reactive core sees the same input at sub's `a`, `b` and return: {reactive:?}"
        );
    }

    #[test]
    fn the_recurrent_core_of_a_batch_is_the_one_the_stack_runs() {
        // Teacher-forced states of a batch (`CoreState::Calls`) are the
        // states of each call's decisions taken one at a time.
        let device = cpu_device();
        let net = NtpConfig::new(4, 2, EncoderConfig::state(2))
            .with_hidden(16)
            .with_recurrent_core(Some(true))
            .with_seed(5)
            .init(&device)
            .unwrap();
        let spec: Vec<Vec<f32>> = (0..5).map(|i| vec![i as f32 / 4.0, 0.0]).collect();
        let episode: Vec<Vec<f32>> = (0..5).map(|i| vec![0.3, i as f32 / 5.0]).collect();
        let t = trace();
        let batch = NtpBatch::new(&[(&spec[..], &episode[..], &t)], 2, 4, 2, &device).unwrap();
        let (_, out) = net.heads(&batch).unwrap();
        let batch_core = to_vec(out.core).unwrap();
        // Decision order (see `decisions_of`): root→sub, sub→a, sub→b,
        // sub returns, root→sub, sub→a, sub→b, sub returns, root returns;
        // the calls: root (0, 4, 8), first sub (1, 2, 3), second (5, 6, 7).
        let calls: [&[usize]; 3] = [&[0, 4, 8], &[1, 2, 3], &[5, 6, 7]];
        let observations = to_vec(batch.observations.clone()).unwrap();
        let programs = to_vec_int(batch.programs.clone()).unwrap();
        let masks = to_vec(batch.scope_mask.clone()).unwrap();
        let spec_encoded = net
            .encode_spec(batch.spec.clone(), batch.spec_mask.clone())
            .unwrap();
        for call in calls {
            let mut state: Option<Tensor<2>> = None;
            for &k in call {
                let one = |v: &[f32], w: usize| {
                    Tensor::<2>::from_data(
                        TensorData::new(v[k * w..(k + 1) * w].to_vec(), [1, w]),
                        &device,
                    )
                };
                let out = net
                    .decide(
                        &spec_encoded,
                        Tensor::from_data(TensorData::new(vec![0i64], [1]), &device),
                        one(&observations, 2),
                        Tensor::from_data(TensorData::new(vec![programs[k]], [1]), &device),
                        one(&masks, 5),
                        state.as_ref().map_or(CoreState::First, CoreState::Previous),
                    )
                    .unwrap();
                let alone = to_vec(out.core.clone()).unwrap();
                for (a, b) in alone.iter().zip(&batch_core[k * 16..(k + 1) * 16]) {
                    assert!((a - b).abs() < 1e-5, "decision {k}: {a} vs {b}");
                }
                state = Some(out.core);
            }
        }
    }

    /// A tiny network (`scope_match`, `recurrent` core) trained for 300
    /// steps on [`trace`] with the episode's `episode` observations: the
    /// network, its first loss and its loss after training.
    fn train_on_trace(
        scope_match: bool,
        recurrent: bool,
        episode: &[Vec<f32>],
    ) -> (NtpNet, f32, NtpLoss) {
        use burn::optim::{AdamConfig, GradientsParams, ModuleOptimizer};
        let device = cpu_device().autodiff();
        let spec: Vec<Vec<f32>> = (0..5).map(|i| vec![i as f32 / 4.0, 0.0]).collect();
        let t = trace();
        let mut net = NtpConfig::new(4, 2, EncoderConfig::state(2))
            .with_hidden(32)
            .with_scope_match(Some(scope_match))
            .with_recurrent_core(Some(recurrent))
            .with_seed(3)
            .init(&device)
            .unwrap();
        let batch = NtpBatch::new(&[(&spec[..], episode, &t)], 2, 4, 2, &device).unwrap();
        let mut optim: ModuleOptimizer = AdamConfig::new().init();
        let first = scalar(net.loss(&batch).unwrap().loss).unwrap();
        for _ in 0..300 {
            let out = net.loss(&batch).unwrap();
            let grads = GradientsParams::from_grads(out.loss.backward(), &net);
            net = optim.step(3e-3, net, grads);
        }
        let out = net.loss(&batch).unwrap();
        (net, first, out)
    }

    fn learn_a_trace_and_replay_it(scope_match: bool, recurrent: bool, episode: &[Vec<f32>]) {
        let spec: Vec<Vec<f32>> = (0..5).map(|i| vec![i as f32 / 4.0, 0.0]).collect();
        let t = trace();
        let (net, first, out) = train_on_trace(scope_match, recurrent, episode);
        let last = scalar(out.loss.clone()).unwrap();
        assert!(
            last < 0.1 * first,
            "scope_match {scope_match}, recurrent {recurrent}: loss {first} → {last}"
        );
        assert_eq!(out.program_accuracy, 1.0);
        assert_eq!(out.eop_accuracy, 1.0);
        assert_eq!(out.argument_accuracy, 1.0);
        assert_eq!(out.scope_accuracy, 1.0);
        // Checked decision by decision, the trained network takes every
        // step of the trace as the stack would.
        let valid_batch =
            NtpBatch::new(&[(&spec[..], episode, &t)], 2, 4, 2, &cpu_device()).unwrap();
        let checks = net.valid().check_decisions(&valid_batch).unwrap();
        assert_eq!(
            checks.len(),
            9,
            "2 + 2 x 3 calls and returns + the root's return"
        );
        assert!(checks.iter().all(NtpDecisionCheck::right), "{checks:?}");
        // Executed through the stack, the trained network replays the
        // trace's primitives when shown the trace's observations.
        let policy = net.valid().condition(&spec).unwrap();
        let mut stack = ProgramStack::new(ROOT, spec.len(), primitives(), 3);
        let mut acted = Vec::new();
        for row in episode {
            match stack.step(&policy, row).unwrap() {
                // Only program A takes an argument.
                StackStep::Act { program, argument } => {
                    acted.push((program, if program == A { argument } else { 0 }))
                }
                other => {
                    acted.push((99, 0));
                    assert_eq!(other, StackStep::Done);
                    break;
                }
            }
        }
        assert_eq!(acted, vec![(A, 1), (B, 0), (A, 0), (B, 0), (99, 0)]);
    }

    /// The decisions' heads as first written: each decision's demo copied
    /// out (`select`) and attended on its own.
    fn heads_per_decision(
        net: &NtpNet,
        spec: &EncodedSpec,
        demo_index: Tensor<1, Int>,
        observations: Tensor<2>,
        programs: Tensor<1, Int>,
        scope_mask: Tensor<2>,
    ) -> (Tensor<2>, Tensor<2>, Tensor<3>) {
        let s = demo_index.dims()[0];
        let h = net.config.hidden;
        let observations_for_objects = observations.clone();
        let obs = net.encoder.forward(observations).unwrap();
        let prog = net.programs.val().select(0, programs);
        let q = net.query.forward(prog.clone()).unsqueeze_dim::<3>(1);
        let keys = spec.keys.clone().select(0, demo_index.clone());
        let rows = spec.rows.clone().select(0, demo_index.clone());
        let scores = q.matmul(keys.swap_dims(1, 2)).div_scalar((h as f32).sqrt());
        let outside = scope_mask.lower_elem(0.5).unsqueeze_dim::<3>(1);
        let alpha = softmax(scores.mask_fill(outside, MASKED_LOGIT), 2);
        let objects = spec.objects.clone().unwrap().select(0, demo_index.clone());
        let k = objects.dims()[2];
        let pooled = alpha.clone().matmul(objects).reshape([s, k]);
        let context: Tensor<2> = alpha.matmul(rows).reshape([s as i32, -1]);
        let current = net.object_scores(observations_for_objects).unwrap();
        let core_input = vec![
            obs,
            prog,
            context,
            softmax(pooled.clone(), 1),
            softmax(current, 1),
        ];
        let core = relu(
            net.core_hidden
                .forward(relu(net.core_in.forward(Tensor::cat(core_input, 1)))),
        );
        let arguments = net.argument_out.forward(core.clone()) + pooled;
        let taps = spec.taps.clone().select(0, demo_index.clone());
        let u = net.scope_core.forward(core.clone()).unsqueeze_dim::<3>(1);
        let (_, m) = net.scope_match.as_ref().unwrap();
        let matched = spec.matched.clone().unwrap().select(0, demo_index);
        let hidden = taps + u + matched * m.forward(core.clone()).unsqueeze_dim::<3>(1);
        (
            net.program_out.forward(core),
            arguments,
            net.scope_out.forward(relu(hidden)),
        )
    }

    #[test]
    fn decisions_laid_out_by_demo_give_the_per_decision_heads_and_gradients() {
        let device = cpu_device().autodiff();
        let net = NtpConfig::new(4, 3, EncoderConfig::state(10))
            .with_hidden(16)
            .with_object_arguments(Some(3))
            .with_scope_match(Some(true))
            .with_seed(5)
            .init(&device)
            .unwrap();
        let (b, r, d) = (3, 5, 10);
        let values = |n: usize, salt: usize| -> Vec<f32> {
            (0..n)
                .map(|i| (((i * 37 + salt * 11) % 23) as f32 / 11.0) - 1.0)
                .collect()
        };
        let spec =
            Tensor::<3>::from_data(TensorData::new(values(b * r * d, 1), [b, r, d]), &device);
        let mut mask = vec![1.0f32; b * r];
        mask[r - 1] = 0.0; // demo 0 has 4 rows
        let mask = Tensor::<2>::from_data(TensorData::new(mask, [b, r]), &device);
        // Decisions out of demo order, three per demo but one.
        let demos = vec![2i64, 0, 0, 2, 1, 2, 0];
        let s = demos.len();
        let index = Tensor::<1, Int>::from_data(TensorData::new(demos, [s]), &device);
        let observations =
            Tensor::<2>::from_data(TensorData::new(values(s * d, 2), [s, d]), &device);
        let programs = Tensor::<1, Int>::from_data(
            TensorData::new(vec![0i64, 1, 2, 3, 1, 0, 2], [s]),
            &device,
        );
        let scope: Vec<f32> = (0..s * r)
            .map(|i| f32::from(u8::from((i / r + i % r) % 3 != 0)))
            .collect();
        let scope = Tensor::<2>::from_data(TensorData::new(scope, [s, r]), &device);

        // Each from its own forward pass (a tape is consumed by backward).
        let heads = |grid: bool| {
            let encoded = net.encode_spec(spec.clone(), mask.clone()).unwrap();
            let (index, observations, programs, scope) = (
                index.clone(),
                observations.clone(),
                programs.clone(),
                scope.clone(),
            );
            if grid {
                let out = net
                    .decide(
                        &encoded,
                        index.clone(),
                        observations,
                        programs,
                        scope,
                        CoreState::First,
                    )
                    .unwrap();
                let scopes = net.scope_logits(&encoded, index, out.core).unwrap();
                (out.program_logits, out.argument_logits, scopes)
            } else {
                heads_per_decision(&net, &encoded, index, observations, programs, scope)
            }
        };
        let (program_logits, argument_logits, scopes) = heads(true);
        let (programs_ref, arguments_ref, scopes_ref) = heads(false);
        let close = |a: Vec<f32>, b: Vec<f32>, what: &str| {
            assert_eq!(a.len(), b.len(), "{what}");
            for (x, y) in a.iter().zip(&b) {
                assert!(
                    (x - y).abs() <= 1e-5 * (1.0 + y.abs()),
                    "{what}: {x} vs {y}"
                );
            }
        };
        let v2 = |t: Tensor<2>| to_vec(t).unwrap();
        let v3 = |t: Tensor<3>| to_vec(t).unwrap();
        close(
            v2(program_logits.clone()),
            v2(programs_ref.clone()),
            "programs",
        );
        close(
            v2(argument_logits.clone()),
            v2(arguments_ref.clone()),
            "arguments",
        );
        close(v3(scopes.clone()), v3(scopes_ref.clone()), "scopes");
        // The same gradients reach the demo encoder's weights.
        let loss = |p: Tensor<2>, a: Tensor<2>, sc: Tensor<3>| {
            p.powf_scalar(2.0).sum() + a.sin().sum() + sc.tanh().sum()
        };
        let grads = loss(program_logits, argument_logits, scopes).backward();
        let grads_ref = loss(programs_ref, arguments_ref, scopes_ref).backward();
        for (what, weight) in [
            ("key", net.key.weight.val()),
            ("scope taps", net.scope_demo.weight.val()),
            ("query", net.query.weight.val()),
        ] {
            let grad = |g| {
                weight
                    .grad(g)
                    .expect("gradient")
                    .into_data()
                    .try_to_vec::<f32>()
                    .unwrap()
            };
            close(grad(&grads), grad(&grads_ref), what);
        }
    }

    #[test]
    fn object_arguments_must_name_every_argument_and_fit_in_a_row() {
        let config = |k: usize, args: usize, dim: usize| {
            NtpConfig::new(4, args, EncoderConfig::state(dim)).with_object_arguments(Some(k))
        };
        assert!(config(2, 2, 7).validate().is_ok());
        assert!(config(2, 3, 7).validate().is_err());
        assert!(config(3, 3, 7).validate().is_err());
        // The objects' scores reach the argument logits and the core.
        let net = config(2, 2, 7).with_hidden(16).init(&cpu_device()).unwrap();
        let spec: Vec<Vec<f32>> = (0..3).map(|i| vec![i as f32; 7]).collect();
        let frame = StackFrame {
            program: ROOT,
            scope: (0, 2),
        };
        let d = net
            .condition(&spec)
            .unwrap()
            .decide(&[0.1; 7], &frame)
            .unwrap();
        assert!(d.argument < 2);
    }

    #[test]
    fn a_saved_network_loads_with_the_same_outputs() {
        for recurrent in [false, true] {
            let net = NtpConfig::new(4, 2, EncoderConfig::state(2))
                .with_hidden(32)
                .with_scope_match(Some(true))
                .with_recurrent_core(Some(recurrent))
                .with_seed(5)
                .init(&cpu_device())
                .unwrap();
            let dir = tempfile::tempdir().unwrap();
            net.save(dir.path()).unwrap();
            let loaded = NtpNet::load(dir.path(), &cpu_device()).unwrap();
            assert_eq!(loaded.core_gru.is_some(), recurrent);
            let spec: Vec<Vec<f32>> = (0..4).map(|i| vec![i as f32, 1.0]).collect();
            let frame = StackFrame {
                program: ROOT,
                scope: (0, 3),
            };
            // Two decisions of one call: the second continues the first's
            // state in a recurrent core.
            let decide_twice = |net: &NtpNet| {
                let policy = net.condition(&spec).unwrap();
                let mut state = None;
                let first = policy
                    .decide_in_call(&[0.5, 0.5], &frame, &mut state)
                    .unwrap();
                assert_eq!(state.is_some(), recurrent);
                let second = policy
                    .decide_in_call(&[0.2, 0.5], &frame, &mut state)
                    .unwrap();
                (first, second, state)
            };
            assert_eq!(decide_twice(&net), decide_twice(&loaded));
        }
    }
}
