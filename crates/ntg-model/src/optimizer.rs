//! An optimizer step split across the CPU's cores.
//!
//! burn's [`ModuleOptimizer`] updates a module's parameters one after the
//! other on one thread. With the batch already split across the cores
//! ([`sharded_gradients`](crate::sharded_gradients)), that update is the
//! largest part of a training step left on one core (~2 ms of a ~30 ms
//! two-shard state step). [`ParallelOptimizer`] gives each of `parts`
//! per-parameter optimizers a fixed share of the parameters and runs them
//! on rayon's pool at once. Adam (like every per-parameter optimizer)
//! updates each parameter from its own gradient and state only, so the
//! result is bit-identical to one optimizer's, whatever `parts` is; its
//! checkpoint is one record in burn's format, the same file one
//! optimizer writes, so either loads the other's.

use std::any::Any;
use std::collections::{BTreeMap, HashMap};
use std::path::Path;

use burn::module::{Module, ModuleMapper, ModuleVisitor, Param, ParamId};
use burn::optim::{GradientsParams, LearningRate, ModuleOptimizer, OptimizerRecord};
use burn::tensor::Tensor;
use rayon::prelude::*;

use crate::{ModelError, Result};

/// A whole-module optimizer whose step runs as `parts` optimizers on
/// rayon's pool, each over a fixed share of the parameters (module docs).
pub struct ParallelOptimizer {
    parts: Vec<ModuleOptimizer>,
    /// The part that updates each parameter, decided at the first step
    /// from the module's parameter order and sizes; parameters not in it
    /// are part 0's.
    owner: HashMap<ParamId, usize>,
}

impl ParallelOptimizer {
    /// `parts` optimizers built by `make` (at least one). With one part
    /// this is `make()` itself.
    pub fn new(parts: usize, make: impl Fn() -> ModuleOptimizer) -> Self {
        Self {
            parts: (0..parts.max(1)).map(|_| make()).collect(),
            owner: HashMap::new(),
        }
    }

    /// How many optimizers share the step.
    pub fn parts(&self) -> usize {
        self.parts.len()
    }

    /// Updates `module` with `grads`, as `ModuleOptimizer::step` does.
    pub fn step<M: Module>(&mut self, lr: LearningRate, module: M, grads: GradientsParams) -> M {
        if self.parts.len() == 1 {
            return self.parts[0].step(lr, module, grads);
        }
        if self.owner.is_empty() {
            self.owner = partition(&module, self.parts.len());
        }
        let mut split = SplitGrads {
            grads,
            parts: (0..self.parts.len())
                .map(|_| GradientsParams::new())
                .collect(),
            owner: &self.owner,
        };
        module.visit(&mut split);
        let mut copies: Vec<M> = (1..self.parts.len()).map(|_| module.clone()).collect();
        copies.push(module);
        let mut stepped: Vec<M> = self
            .parts
            .par_iter_mut()
            .zip(split.parts)
            .zip(copies)
            .map(|((optimizer, grads), copy)| optimizer.step(lr, copy, grads))
            .collect();
        // Part 0's module is the base; every other part's parameters are
        // taken from the module that part stepped.
        let mut taken = TakeParams {
            part: 0,
            owner: &self.owner,
            params: HashMap::new(),
        };
        for (part, other) in stepped.iter().enumerate().skip(1) {
            taken.part = part;
            other.visit(&mut taken);
        }
        stepped.truncate(1);
        let base = stepped.pop().expect("part 0 stepped");
        base.map(&mut PutParams {
            params: taken.params,
        })
    }

    /// The optimizer state of every parameter, one record as a single
    /// `ModuleOptimizer` would write it.
    pub fn to_record(&self) -> Result<OptimizerRecord> {
        if self.parts.len() == 1 || self.owner.is_empty() {
            return Ok(self.parts[0].to_record());
        }
        let owner: HashMap<u64, usize> = self.owner.iter().map(|(id, &p)| (id.val(), p)).collect();
        let owned_by = |id: u64, part: usize| owner.get(&id).copied().unwrap_or(0) == part;
        // Keys are `"{param id}.{field}"` (scalars) and `"{param id}"` (paths).
        let key_owner = |key: &str, part: usize| {
            key.split('.')
                .next()
                .and_then(|id| id.parse::<u64>().ok())
                .map_or(part == 0, |id| owned_by(id, part))
        };
        let pack = |e: burn_pack::Error| ModelError::Data(format!("optimizer record: {e}"));
        let (mut tensors, mut scalars, mut paths) = (Vec::new(), BTreeMap::new(), BTreeMap::new());
        for (part, optimizer) in self.parts.iter().enumerate() {
            let bytes = optimizer
                .to_record()
                .into_bytes()
                .map_err(|e| ModelError::Data(format!("optimizer record: {e}")))?;
            let reader = burn_pack::Reader::from_bytes(bytes).map_err(pack)?;
            for (key, value) in reader.scalars() {
                if key_owner(key, part) {
                    scalars.insert(key.clone(), *value);
                }
            }
            for (key, value) in reader.metadata() {
                if key_owner(key, part) {
                    paths.insert(key.clone(), value.clone());
                }
            }
            for tensor in reader.into_tensors().map_err(pack)? {
                let (name, dtype, shape, id, bytes) = tensor.into_parts().map_err(pack)?;
                if id.map_or(part == 0, |id| owned_by(id, part)) {
                    tensors.push(burn_pack::Tensor::new(name, dtype, shape, id, bytes));
                }
            }
        }
        let mut writer = burn_pack::Writer::new(tensors);
        for (key, value) in &scalars {
            writer = writer.with_scalar(key, *value);
        }
        for (key, value) in &paths {
            writer = writer.with_metadata(key, value);
        }
        let bytes = writer.into_bytes().map_err(pack)?;
        OptimizerRecord::from_bytes(bytes)
            .map_err(|e| ModelError::Data(format!("optimizer record: {e}")))
    }

    /// Saves the state (one burnpack record, see [`to_record`](Self::to_record))
    /// to `path`, sealed like every checkpoint file here.
    pub fn save(&self, path: impl AsRef<Path>) -> Result<()> {
        let path = path.as_ref();
        self.to_record()?
            .save(path)
            .map_err(|e| ModelError::file(path, e))?;
        crate::checkpoint::seal(path)
    }

    /// Loads a state saved by [`save`](Self::save) or by
    /// [`save_optimizer`](crate::save_optimizer) into every part (each
    /// part uses only its own parameters' states). A missing, corrupt or
    /// foreign file is an error naming it.
    pub fn load(self, path: impl AsRef<Path>) -> Result<Self> {
        let path = path.as_ref();
        let parts = self
            .parts
            .into_iter()
            .map(|part| crate::load_optimizer(part, path))
            .collect::<Result<Vec<_>>>()?;
        Ok(Self {
            parts,
            owner: self.owner,
        })
    }
}

/// Gives each float parameter of `module` to one of `parts` parts, in the
/// module's order, each to the part with the least work so far (a
/// parameter's work: its size plus a fixed per-parameter cost, as small
/// parameters cost about as much as their few operations).
fn partition<M: Module>(module: &M, parts: usize) -> HashMap<ParamId, usize> {
    struct Sizes(Vec<(ParamId, usize)>);
    impl ModuleVisitor for Sizes {
        fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<D>>) {
            self.0.push((param.id, param.val().shape().num_elements()));
        }
    }
    const PER_PARAMETER: usize = 4096;
    let mut sizes = Sizes(Vec::new());
    module.visit(&mut sizes);
    let mut load = vec![0usize; parts];
    let mut owner = HashMap::new();
    for (id, size) in sizes.0 {
        let part = (0..parts).min_by_key(|&p| (load[p], p)).unwrap_or(0);
        load[part] += size + PER_PARAMETER;
        owner.insert(id, part);
    }
    owner
}

/// Moves each parameter's gradient into its part's `GradientsParams`.
struct SplitGrads<'a> {
    grads: GradientsParams,
    parts: Vec<GradientsParams>,
    owner: &'a HashMap<ParamId, usize>,
}

impl ModuleVisitor for SplitGrads<'_> {
    fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<D>>) {
        if let Some(grad) = self.grads.remove::<D>(param.id) {
            let part = self.owner.get(&param.id).copied().unwrap_or(0);
            self.parts[part].register::<D>(param.id, grad);
        }
    }
}

/// Collects the parameters part `part` owns from the module it stepped.
struct TakeParams<'a> {
    part: usize,
    owner: &'a HashMap<ParamId, usize>,
    params: HashMap<ParamId, Box<dyn Any + Send>>,
}

impl ModuleVisitor for TakeParams<'_> {
    fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<D>>) {
        if self.owner.get(&param.id) == Some(&self.part) {
            self.params.insert(param.id, Box::new(param.clone()));
        }
    }
}

/// Puts the collected parameters in place of the base module's.
struct PutParams {
    params: HashMap<ParamId, Box<dyn Any + Send>>,
}

impl ModuleMapper for PutParams {
    fn map_float<const D: usize>(&mut self, param: Param<Tensor<D>>) -> Param<Tensor<D>> {
        match self.params.remove(&param.id) {
            Some(taken) => match taken.downcast::<Param<Tensor<D>>>() {
                Ok(taken) => *taken,
                // Same id, other rank: cannot happen for one module's copies.
                Err(_) => param,
            },
            None => param,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use burn::nn::{Linear, LinearConfig};
    use burn::optim::AdamConfig;
    use burn::tensor::TensorData;

    use crate::nn::to_vec;

    /// Three linear layers in a row.
    fn model() -> Vec<Linear> {
        let device = crate::cpu_device().autodiff();
        vec![
            LinearConfig::new(4, 6).init(&device),
            LinearConfig::new(6, 5).init(&device),
            LinearConfig::new(5, 2).init(&device),
        ]
    }

    /// The gradients of the squared output on inputs that change with `step`.
    fn grads(model: &[Linear], step: usize) -> GradientsParams {
        let device = model[0].weight.val().device();
        let xs: Vec<f32> = (0..12)
            .map(|i| ((i * 7 + step * 3) % 11) as f32 * 0.37 - 1.5)
            .collect();
        let mut x = Tensor::<2>::from_data(TensorData::new(xs, [3, 4]), &device);
        for layer in model {
            x = layer.forward(x).tanh();
        }
        GradientsParams::from_grads(x.powi_scalar(2).mean().backward(), &model.to_vec())
    }

    fn bits(model: &[Linear]) -> Vec<u32> {
        model
            .iter()
            .flat_map(|l| {
                let mut v = to_vec(l.weight.val()).unwrap();
                v.extend(to_vec(l.bias.as_ref().unwrap().val()).unwrap());
                v
            })
            .map(f32::to_bits)
            .collect()
    }

    #[test]
    fn parts_give_bit_identical_updates_and_one_record_either_optimizer_loads() {
        let start = model();
        let mut single = AdamConfig::new().init();
        let mut parallel = ParallelOptimizer::new(2, || AdamConfig::new().init());
        let (mut a, mut b) = (start.clone(), start);
        for step in 0..5 {
            let lr = 1e-2 / (1 + step) as f64;
            let ga = grads(&a, step);
            a = single.step(lr, a, ga);
            let gb = grads(&b, step);
            b = parallel.step(lr, b, gb);
            assert_eq!(bits(&a), bits(&b), "step {step}");
        }
        // Both parts updated something: the split is real.
        let mut counts = [0; 2];
        for part in parallel.owner.values() {
            counts[*part] += 1;
        }
        assert!(counts.iter().all(|&c| c > 0), "{counts:?}");

        // The merged record carries every parameter's state: saved by the
        // parallel optimizer, loaded by a single one (and the other way),
        // the next step is the same.
        let dir = tempfile::tempdir().unwrap();
        let (from_parallel, from_single) = (dir.path().join("p.bpk"), dir.path().join("s.bpk"));
        parallel.save(&from_parallel).unwrap();
        crate::save_optimizer(&single, &from_single).unwrap();
        let mut single2 = crate::load_optimizer(AdamConfig::new().init(), &from_parallel).unwrap();
        let mut parallel2 = ParallelOptimizer::new(2, || AdamConfig::new().init())
            .load(&from_single)
            .unwrap();
        let (ga, gb) = (grads(&a, 5), grads(&b, 5));
        let (a2, b2) = (
            single2.step(1e-3, a.clone(), ga),
            parallel2.step(1e-3, b.clone(), gb),
        );
        assert_eq!(bits(&a2), bits(&b2));
        let (ga, gb) = (grads(&a, 5), grads(&b, 5));
        let (a3, b3) = (single.step(1e-3, a, ga), parallel.step(1e-3, b, gb));
        assert_eq!(bits(&a2), bits(&a3));
        assert_eq!(bits(&b2), bits(&b3));
    }

    #[test]
    fn a_missing_or_corrupt_state_file_is_an_error_naming_it() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("optimizer.bpk");
        let err = ParallelOptimizer::new(2, || AdamConfig::new().init())
            .load(&path)
            .err()
            .expect("missing file");
        assert!(err.to_string().contains("optimizer.bpk"), "{err}");
        std::fs::write(&path, b"not a record").unwrap();
        let err = ParallelOptimizer::new(2, || AdamConfig::new().init())
            .load(&path)
            .err()
            .expect("corrupt file");
        assert!(err.to_string().contains("optimizer.bpk"), "{err}");
    }
}
