//! SIMD: the one way the crate's kernels use the wider vector units, and the four-lane vector
//! ([`v4`]) the fluid, particle and vortex kernels share.
//!
//! **One dispatch style.** The shipped binary targets generic x86-64 (SSE2). A kernel that gains
//! from AVX2 exists a second time compiled with `#[target_feature(enable = "avx2,fma")]`, and the
//! caller picks it at run time when [`avx2_fma`] says the CPU has both:
//! - portable code (loops written so that LLVM vectorises them) implements [`Kernel`] and runs
//!   through [`dispatch`], which compiles it twice: the same source and operations either way, so
//!   the same results to the bit (Rust never contracts `a * b + c` into a fused multiply-add);
//! - where the compiler cannot vectorise (gathers, lane transposes), an `unsafe fn` with that
//!   attribute written with intrinsics sits beside its scalar reference, in the module of the
//!   kernel, and is called only after [`avx2_fma`] said yes.
//!
//! Every AVX2 kernel has a test against its scalar reference: equal to the bit where the kernel
//! promises the scalar code's operations in their order, else within a tolerance that the test
//! derives (FMA rounds once where the reference rounds twice). [`set_portable`] runs every kernel
//! on its portable path, for the tests that compare whole runs and for benchmarks.
//!
//! Not pulp: its explicit SIMD types were 2-10x slower than the auto-vectorised loops
//! (BENCHMARKS.md, "Tried and dropped"), and as a dispatcher it did what [`dispatch`] does.

use std::sync::atomic::{AtomicU8, Ordering};

pub mod v4;

pub(crate) use v4::V4;

/// [`LEVEL`] before the first [`avx2_fma`].
const UNKNOWN: u8 = 0;
/// The portable paths only (no AVX2 and FMA, or [`set_portable`]).
const PORTABLE: u8 = 1;
/// The AVX2 + FMA paths.
const AVX2_FMA: u8 = 2;

/// What [`avx2_fma`] answers, once known.
static LEVEL: AtomicU8 = AtomicU8::new(UNKNOWN);

/// Whether the AVX2 + FMA kernels run: the CPU has both (detected once) and [`set_portable`] did
/// not turn them off.
#[inline]
pub fn avx2_fma() -> bool {
    match LEVEL.load(Ordering::Relaxed) {
        AVX2_FMA => true,
        PORTABLE => false,
        _ => detect(),
    }
}

#[cold]
fn detect() -> bool {
    let level = if cpu_has_avx2_fma() {
        AVX2_FMA
    } else {
        PORTABLE
    };
    // A concurrent `set_portable` wins: it only ever lowers the level.
    let _ = LEVEL.compare_exchange(UNKNOWN, level, Ordering::Relaxed, Ordering::Relaxed);
    LEVEL.load(Ordering::Relaxed) == AVX2_FMA
}

/// Whether the CPU has AVX2 and FMA (`is_x86_feature_detected` caches its answer).
fn cpu_has_avx2_fma() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        is_x86_feature_detected!("avx2") && is_x86_feature_detected!("fma")
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

/// Runs every kernel on its portable path (`true`) or, where the CPU has AVX2 and FMA, on the
/// AVX2 path again (`false`): process-wide, for tests that compare the two and for benchmarks.
/// A kernel already running finishes on the path it started on.
#[cfg_attr(not(feature = "harness"), allow(dead_code))]
pub fn set_portable(portable: bool) {
    let level = if !portable && cpu_has_avx2_fma() {
        AVX2_FMA
    } else {
        PORTABLE
    };
    LEVEL.store(level, Ordering::Relaxed);
}

/// A kernel written as portable code, compiled twice by [`dispatch`].
pub(crate) trait Kernel {
    /// What the kernel returns.
    type Output;
    /// Runs the kernel. Implementations are `#[inline(always)]`: their body must be inlined into
    /// [`dispatch`]'s two instantiations to be compiled for each instruction set.
    fn run(self) -> Self::Output;
}

/// Runs `kernel` compiled for AVX2 and FMA where [`avx2_fma`] allows, else for the baseline.
#[inline(always)]
pub(crate) fn dispatch<K: Kernel>(kernel: K) -> K::Output {
    #[cfg(target_arch = "x86_64")]
    if avx2_fma() {
        // SAFETY: the CPU has AVX2 and FMA (`avx2_fma` checked it).
        return unsafe { run_avx2_fma(kernel) };
    }
    kernel.run()
}

/// [`Kernel::run`] compiled with AVX2 and FMA.
///
/// # Safety
/// The CPU must have AVX2 and FMA.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
unsafe fn run_avx2_fma<K: Kernel>(kernel: K) -> K::Output {
    kernel.run()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A reduction whose lanes the compiler vectorises: the sum of squares of `v` in eight fixed
    /// lanes, then the lanes in order.
    struct SumSquares<'a>(&'a [f32]);

    impl Kernel for SumSquares<'_> {
        type Output = f32;
        #[inline(always)]
        fn run(self) -> f32 {
            let mut acc = [0f32; 8];
            let chunks = self.0.chunks_exact(8);
            let tail: f32 = chunks.remainder().iter().map(|x| x * x).sum();
            for c in chunks {
                for k in 0..8 {
                    acc[k] += c[k] * c[k];
                }
            }
            acc.iter().sum::<f32>() + tail
        }
    }

    /// Both instantiations of a portable kernel give the same bits (no contraction into FMA, no
    /// reassociation), and [`set_portable`] selects the baseline one.
    #[test]
    fn both_compilations_of_a_portable_kernel_agree_to_the_bit() {
        let mut rng = fastrand::Rng::with_seed(3);
        let v: Vec<f32> = (0..1003).map(|_| rng.f32() * 2.0 - 1.0).collect();
        let portable = SumSquares(&v).run();
        #[cfg(target_arch = "x86_64")]
        if cpu_has_avx2_fma() {
            // SAFETY: the CPU has AVX2 and FMA (checked just above).
            let wide = unsafe { run_avx2_fma(SumSquares(&v)) };
            assert_eq!(wide.to_bits(), portable.to_bits());
        } else {
            eprintln!("SKIP the AVX2 half: no AVX2 + FMA");
        }
        assert_eq!(dispatch(SumSquares(&v)).to_bits(), portable.to_bits());
    }
}
