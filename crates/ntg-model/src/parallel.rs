//! Data-parallel gradients on the CPU's cores: one batch split into
//! shards, each shard's forward and backward pass on its own thread over a
//! replica of the model, the gradients summed.
//!
//! burn's CPU backend gains little from a second thread on networks this
//! small (a training step is many small tensor operations), so the trainer
//! uses the cores across the batch instead. The replicas share the
//! parameters' ids but record separate autodiff graphs, so the threads never
//! touch each other's state; summing their gradients gives the gradient of
//! the summed losses, as one thread would (up to float rounding).

use std::panic::{AssertUnwindSafe, catch_unwind};

use burn::module::Module;
use burn::optim::{GradientsAccumulator, GradientsParams};
use burn::tensor::Tensor;
use rayon::prelude::*;

use crate::ModelError;
use crate::float_mode::{apply_float_mode, init_float_mode};

/// The gradients of `Σ_i loss_i` over `shards` shards, where
/// `shard(replica, i)` returns shard `i`'s loss (weighted as the caller
/// wants the sum to come out: by its share of the batch for a mean) and a
/// value `T` handed back in shard order. Each shard runs as a task of
/// rayon's global pool (in parallel up to its size, `RAYON_NUM_THREADS`)
/// over a fresh replica of `model` (same parameter ids, its own autodiff
/// graph).
///
/// The result depends on `shards` but not on the machine's core count or
/// the order the threads finish in. An error of any shard is returned (the
/// first in shard order); a panicking shard becomes an error too.
pub fn sharded_gradients<M, T, E, F>(
    model: &M,
    shards: usize,
    shard: F,
) -> Result<(GradientsParams, Vec<T>), E>
where
    M: Module,
    T: Send,
    E: Send + From<ModelError>,
    F: Fn(&M, usize) -> Result<(Tensor<1>, T), E> + Sync,
{
    // The shards run on rayon's pool, which burn's CPU backend also
    // computes on: a tensor operation that splits its work inside a shard
    // shares the pool's threads instead of waking more threads than cores
    // (plain threads beside the pool lost about 5% to its spinning workers).
    let replicas: Vec<M> = (0..shards.max(1)).map(|_| model.valid().train()).collect();
    let results: Vec<Result<(GradientsParams, T), E>> = replicas
        .into_par_iter()
        .enumerate()
        .map(|(i, replica)| {
            catch_unwind(AssertUnwindSafe(|| {
                let (loss, value) = shard(&replica, i)?;
                Ok((
                    GradientsParams::from_grads(loss.backward(), &replica),
                    value,
                ))
            }))
            .unwrap_or_else(|_| Err(ModelError::Input("a training shard panicked".into()).into()))
        })
        .collect();
    let mut accumulator = GradientsAccumulator::<M>::new();
    let mut values = Vec::with_capacity(results.len());
    for result in results {
        let (grads, value) = result?;
        accumulator.accumulate(model, grads);
        values.push(value);
    }
    Ok((accumulator.grads(), values))
}

/// What [`init_thread_pool`] set up.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ThreadPoolInfo {
    /// Threads in rayon's global pool.
    pub threads: usize,
    /// Whether each worker thread was pinned to a core of its own.
    pub pinned: bool,
    /// Whether the process flushes subnormal floats to zero
    /// ([`crate::float_mode`]).
    pub flush_subnormals: bool,
}

/// The cores this process may run on (its CPU affinity), in order.
fn allowed_cores() -> Vec<core_affinity::CoreId> {
    core_affinity::get_core_ids().unwrap_or_default()
}

/// A rayon pool builder of `threads` threads whose worker `i` is pinned to
/// the `i`-th core this process may run on, when there are at least
/// `threads` such cores (otherwise the threads are left to the scheduler).
///
/// Why pin: on the 2-vCPU machine this project is measured on, the two
/// shards of a data-parallel step ran 8-12% slower each than one shard
/// alone while unpinned threads moved between the vCPUs; pinned, the
/// two-shard state step's speedup over one thread rose from ~1.62 to
/// ~1.73 (`docs/results/speed-2026-11-27.md`).
pub fn pinned_pool_builder(threads: usize) -> rayon::ThreadPoolBuilder {
    let cores = allowed_cores();
    if threads == 0 || cores.len() < threads {
        return compute_pool_builder(threads);
    }
    rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .start_handler(move |i| {
            apply_float_mode();
            // A refused pin leaves the thread where the scheduler puts it.
            let _ = core_affinity::set_for_current(cores[i]);
        })
}

/// A rayon pool builder of `threads` threads that compute in the process's
/// float mode ([`crate::float_mode`]); use it for every pool that runs
/// tensor work.
pub fn compute_pool_builder(threads: usize) -> rayon::ThreadPoolBuilder {
    rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .start_handler(|_| apply_float_mode())
}

/// Builds rayon's global pool, on which burn's CPU backend computes and
/// the trainer runs its data-parallel shards and rollouts:
/// `RAYON_NUM_THREADS` threads (default: the cores this process may use),
/// each pinned to a core of its own when the pool takes every such core
/// and there are at least two (see [`pinned_pool_builder`]). A pool smaller
/// than the machine is not pinned, so two processes of one thread each
/// (two runs side by side) are not put on the same core.
/// `NTG_PIN_THREADS=0` turns pinning off. If the global pool already
/// exists, it is left as it is (and reported unpinned).
///
/// First it chooses the process's float mode ([`init_float_mode`]: flush
/// subnormals unless `NTG_FLUSH_SUBNORMALS=0`) and applies it to the
/// calling thread and to the pool's workers.
pub fn init_thread_pool() -> ThreadPoolInfo {
    let flush_subnormals = init_float_mode();
    let cores = allowed_cores();
    let machine = if cores.is_empty() {
        std::thread::available_parallelism().map_or(1, |n| n.get())
    } else {
        cores.len()
    };
    let threads = std::env::var("RAYON_NUM_THREADS")
        .ok()
        .and_then(|v| v.trim().parse::<usize>().ok())
        .filter(|&n| n > 0)
        .unwrap_or(machine);
    let pin = threads >= 2
        && threads == cores.len()
        && !matches!(
            std::env::var("NTG_PIN_THREADS").as_deref().map(str::trim),
            Ok("0")
        );
    let builder = if pin {
        pinned_pool_builder(threads)
    } else {
        compute_pool_builder(threads)
    };
    match builder.build_global() {
        Ok(()) => ThreadPoolInfo {
            threads,
            pinned: pin,
            flush_subnormals,
        },
        Err(_) => ThreadPoolInfo {
            threads: rayon::current_num_threads(),
            pinned: false,
            flush_subnormals,
        },
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use burn::nn::{Linear, LinearConfig};
    use burn::tensor::TensorData;

    use crate::nn::to_vec;

    /// A linear model and its mean squared error on rows `rows` of a fixed
    /// 6-row batch, weighted by `weight`.
    fn loss(model: &Linear, rows: std::ops::Range<usize>, weight: f32) -> Tensor<1> {
        let device = model.weight.val().device();
        let n = rows.len();
        let xs: Vec<f32> = rows
            .clone()
            .flat_map(|i| [i as f32 * 0.3, 1.0 - i as f32 * 0.2])
            .collect();
        let ys: Vec<f32> = rows.map(|i| (i % 3) as f32).collect();
        let x = Tensor::<2>::from_data(TensorData::new(xs, [n, 2]), &device);
        let y = Tensor::<2>::from_data(TensorData::new(ys, [n, 1]), &device);
        (model.forward(x) - y)
            .powi_scalar(2)
            .mean()
            .mul_scalar(weight)
    }

    fn weight_grad(model: &Linear, grads: &mut GradientsParams) -> Vec<f32> {
        let g = grads
            .remove::<2>(model.weight.id)
            .expect("a gradient for the weight");
        to_vec(g).unwrap()
    }

    #[test]
    fn two_shards_give_the_whole_batch_gradient_and_their_values_in_order() {
        let device = crate::cpu_device().autodiff();
        let model = LinearConfig::new(2, 1).init(&device);
        let mut whole = GradientsParams::from_grads(loss(&model, 0..6, 1.0).backward(), &model);
        let whole = weight_grad(&model, &mut whole);
        let (mut grads, values) = sharded_gradients::<_, _, ModelError, _>(&model, 2, |m, i| {
            let rows = 3 * i..3 * i + 3;
            Ok((loss(m, rows, 0.5), i * 10))
        })
        .unwrap();
        assert_eq!(values, vec![0, 10]);
        let sharded = weight_grad(&model, &mut grads);
        for (a, b) in sharded.iter().zip(&whole) {
            assert!((a - b).abs() < 1e-5, "sharded {a} vs whole {b}");
        }
    }

    #[test]
    fn a_failing_or_panicking_shard_is_an_error() {
        let device = crate::cpu_device().autodiff();
        let model = LinearConfig::new(2, 1).init(&device);
        let failed = sharded_gradients::<_, (), ModelError, _>(&model, 2, |m, i| {
            if i == 1 {
                Err(ModelError::Input("shard 1 failed".into()))
            } else {
                Ok((loss(m, 0..3, 1.0), ()))
            }
        });
        assert!(failed.unwrap_err().to_string().contains("shard 1 failed"));
        let panicked = sharded_gradients::<_, (), ModelError, _>(&model, 2, |m, i| {
            assert!(i == 0, "planted panic");
            Ok((loss(m, 0..3, 1.0), ()))
        });
        assert!(panicked.unwrap_err().to_string().contains("panicked"));
    }
}
