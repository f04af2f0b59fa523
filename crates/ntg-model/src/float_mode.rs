//! Subnormal floats flushed to zero on the threads that compute.
//!
//! x86 CPUs run an operation whose input or result is subnormal (nonzero
//! and below `f32::MIN_POSITIVE`, about 1.2e-38) through a microcode
//! assist, tens to a hundred times slower than a normal one. As training
//! goes on, saturated units and confident outputs make such values in the
//! forward and backward passes, and Adam's moments of parameters whose
//! gradient is zero sink into them: epochs of the paper profile's runs
//! grew up to 2x slower from first to last. Measured on the no-GCN
//! ablation (block stacking, 1000 tasks): its 30th epoch took 154 CPU
//! seconds as it was, 144 with subnormals flushed inside the optimizer
//! step only, and 80 flushed everywhere (its first epoch took 81); the
//! weights after the epoch were the same to the bit
//! (docs/results/speed-2026-11-29.md).
//!
//! Flushing can change results where a tiny value decides something (a
//! ReLU's mask reads a subnormal as zero): of the quick profile's results
//! one line changed (fig. thor_all's Flat Policy with memory), all
//! others repeated. So each run's `sessions.jsonl` notes the mode every
//! stretch of its training ran in.
//!
//! So the `ntg` binary sets the CPU's flush-to-zero and denormals-are-zero
//! modes (MXCSR's FTZ and DAZ bits on x86-64; FPCR's FZ bit on AArch64) on
//! every thread that computes: the main thread, rayon's global pool and the
//! per-run pools of `ntg reproduce`. `NTG_FLUSH_SUBNORMALS=0` keeps IEEE
//! subnormals. The mode is a property of the thread, so it is chosen once
//! per process ([`init_float_mode`]) and each thread the process starts
//! afterwards applies it ([`apply_float_mode`]).
//!
//! Architecture invariant: the same seed gives the same numbers only under
//! the same mode; every compute thread of a process has the mode the
//! process chose.

use std::sync::atomic::{AtomicBool, Ordering};

static FLUSH_SUBNORMALS: AtomicBool = AtomicBool::new(false);

/// Chooses the process's float mode from `NTG_FLUSH_SUBNORMALS` (flush
/// unless it is `0`) and applies it to the calling thread. Returns whether
/// subnormals are flushed (false where the CPU has no such mode).
pub fn init_float_mode() -> bool {
    let wanted = !matches!(
        std::env::var("NTG_FLUSH_SUBNORMALS")
            .as_deref()
            .map(str::trim),
        Ok("0")
    );
    let flushing = wanted && flush_subnormals_on_this_thread();
    FLUSH_SUBNORMALS.store(flushing, Ordering::SeqCst);
    flushing
}

/// Whether the process chose to flush subnormals ([`init_float_mode`]).
pub fn flushes_subnormals() -> bool {
    FLUSH_SUBNORMALS.load(Ordering::SeqCst)
}

/// Gives the calling thread the process's float mode: call it first thing
/// in a thread that computes (pools' start handlers do it for their
/// workers).
pub fn apply_float_mode() {
    if flushes_subnormals() {
        flush_subnormals_on_this_thread();
    }
}

/// Sets the calling thread to flush subnormal results and read subnormal
/// inputs as zero. Returns false on CPUs where this crate knows no such
/// mode (the thread is left as it was).
pub fn flush_subnormals_on_this_thread() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        // MXCSR bit 15 (FTZ: subnormal results become zero) and bit 6
        // (DAZ: subnormal inputs read as zero).
        const FTZ_DAZ: u32 = 0x8040;
        let mut csr: u32 = 0;
        // SAFETY: `stmxcsr`/`ldmxcsr` read and write this thread's SSE
        // control register through a valid pointer; setting FTZ and DAZ
        // changes only how later float operations round tiny values.
        #[allow(unsafe_code)]
        unsafe {
            std::arch::asm!("stmxcsr [{}]", in(reg) &raw mut csr, options(nostack));
            csr |= FTZ_DAZ;
            std::arch::asm!("ldmxcsr [{}]", in(reg) &raw const csr, options(nostack));
        }
        true
    }
    #[cfg(target_arch = "aarch64")]
    {
        // FPCR bit 24 (FZ): subnormal inputs and results become zero.
        const FZ: u64 = 1 << 24;
        let mut fpcr: u64;
        // SAFETY: reads and writes this thread's floating-point control
        // register; FZ changes only how later float operations treat tiny
        // values.
        #[allow(unsafe_code)]
        unsafe {
            std::arch::asm!("mrs {}, fpcr", out(reg) fpcr, options(nomem, nostack));
            fpcr |= FZ;
            std::arch::asm!("msr fpcr, {}", in(reg) fpcr, options(nomem, nostack));
        }
        true
    }
    #[cfg(not(any(target_arch = "x86_64", target_arch = "aarch64")))]
    {
        false
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::hint::black_box;

    /// Half the smallest normal f32, computed at run time.
    fn a_subnormal() -> f32 {
        black_box(f32::MIN_POSITIVE) * black_box(0.5)
    }

    #[test]
    fn a_flushing_thread_computes_zero_where_others_keep_subnormals() {
        // On threads of their own: the mode would otherwise leak into the
        // test harness's thread.
        let kept = std::thread::spawn(a_subnormal).join().unwrap();
        assert!(
            kept > 0.0 && kept.is_subnormal(),
            "IEEE by default: {kept:e}"
        );
        let flushed = std::thread::spawn(|| {
            if !flush_subnormals_on_this_thread() {
                return None;
            }
            // DAZ: a subnormal input reads as zero too.
            let input = f32::from_bits(black_box(1));
            Some((a_subnormal(), input * black_box(1.0)))
        })
        .join()
        .unwrap();
        if let Some((result, input)) = flushed {
            assert_eq!(result.to_bits(), 0);
            assert_eq!(input.to_bits(), 0);
        }
        // Normal numbers are untouched.
        let normal = std::thread::spawn(|| {
            flush_subnormals_on_this_thread();
            black_box(f32::MIN_POSITIVE) * black_box(2.0)
        })
        .join()
        .unwrap();
        assert_eq!(normal, f32::MIN_POSITIVE * 2.0);
    }
}
