//! # equigym-nn: small neural-network kernels with bitwise-reproducible results
//!
//! The one home of the dense arithmetic that the steering agents (`equigym-agents`) and the
//! DDIM runtime (`equigym_wrappers::edp`) run on: a matrix product ([`gemm`]), LayerNorm, Tanh
//! and ReLU forward and backward ([`ops`]), and Adam / AdamW ([`adam`]). Everything is generic
//! over [`Real`]: `f32` is what the agents train in, `f64` is kept for the parity and
//! finite-difference tests.
//!
//! ## Why the results are bitwise reproducible
//!
//! - **One summation order per output element.** [`gemm`] computes every `C[i, j]` as
//!   `(((c0 + a[i,0] b[0,j]) + a[i,1] b[1,j]) + ...)`, always from `p = 0` up. It vectorises
//!   across the *output* columns `j` (eight or sixteen neighbouring outputs share one
//!   instruction), never across the summation axis `p`. A row's result therefore does not depend
//!   on the batch size, on which block of rows it falls in, on the edge (scalar) path or the
//!   blocked path, or on how rows are split across threads. Reductions in [`ops`] (LayerNorm
//!   statistics, parameter gradients summed over a batch) run in index order on one thread.
//! - **Always fused, never "sometimes fused".** Every multiply-add is `mul_add`, i.e. an IEEE
//!   fused multiply-add with a single rounding. On x86-64 with AVX2 + FMA (every Intel core since
//!   Haswell, every AMD core since Zen/Piledriver) the kernels run in a `#[target_feature(enable =
//!   "avx2,fma")]` copy selected at run time and `mul_add` becomes `vfmadd`; on anything else the
//!   same source calls the C library's `fma`, which IEEE 754 also requires to be correctly
//!   rounded. Both give the same bits; only the speed differs (the software path is ~50x
//!   slower and exists so that no machine silently gives other numbers). The alternative, never
//!   fusing, would halve the attainable peak: a core issues two FMAs per cycle but cannot issue
//!   more separate multiplies and adds. The compiler never contracts `a * b + c` on its own
//!   (Rust has no fast-math), so no other instruction sequence can appear.
//! - **Why not a SIMD crate.** `wide` (in the lock file through rapier) picks its instruction set
//!   with `cfg(target_feature)` at *compile* time, so a portable binary would run its SSE2 path
//!   on every machine, and its `mul_add` is an FMA on some builds and a multiply then add on
//!   others: exactly the divergence to avoid. Plain fixed-size array loops inside a
//!   `target_feature` function are vectorised by LLVM to the selected features and keep the
//!   lane arithmetic explicit, so the crate has no SIMD dependency.
//!
//! Transcendentals (`tanh`, `exp`, `ln`, `sqrt`) come from Rust's `std`, which calls the
//! platform's libm: bit-identical across x86-64 Linux machines with the same glibc; `sqrt` is
//! exact everywhere.
//!
//! ## Measured speed
//!
//! See `benches/agents.md` (made by `python benches/agents.py`) for the GFLOP/s of [`gemm`]
//! against the core's measured FMA peak.

pub mod adam;
pub mod gemm;
pub mod ops;

pub use adam::{Adam, AdamConfig};
pub use gemm::{gemm, Trans};

/// The float types the kernels run on (`f32` for training, `f64` for parity tests).
pub trait Real:
    Copy
    + Default
    + PartialOrd
    + Send
    + Sync
    + std::fmt::Debug
    + std::ops::Add<Output = Self>
    + std::ops::Sub<Output = Self>
    + std::ops::Mul<Output = Self>
    + std::ops::Div<Output = Self>
    + std::ops::Neg<Output = Self>
    + std::ops::AddAssign
    + std::ops::MulAssign
    + 'static
{
    const ZERO: Self;
    const ONE: Self;
    fn from_f64(v: f64) -> Self;
    fn to_f64(self) -> f64;
    /// Fused multiply-add `self * a + b` with one rounding (see the module docs).
    fn fma(self, a: Self, b: Self) -> Self;
    fn tanh(self) -> Self;
    fn exp(self) -> Self;
    fn ln(self) -> Self;
    fn ln_1p(self) -> Self;
    fn sqrt(self) -> Self;
    fn abs(self) -> Self;
    fn max(self, other: Self) -> Self;
    fn min(self, other: Self) -> Self;
    fn is_finite(self) -> bool;
}

macro_rules! real_impl {
    ($t:ty) => {
        impl Real for $t {
            const ZERO: Self = 0.0;
            const ONE: Self = 1.0;
            #[inline(always)]
            fn from_f64(v: f64) -> Self {
                v as $t
            }
            #[inline(always)]
            fn to_f64(self) -> f64 {
                self as f64
            }
            #[inline(always)]
            fn fma(self, a: Self, b: Self) -> Self {
                self.mul_add(a, b)
            }
            #[inline(always)]
            fn tanh(self) -> Self {
                <$t>::tanh(self)
            }
            #[inline(always)]
            fn exp(self) -> Self {
                <$t>::exp(self)
            }
            #[inline(always)]
            fn ln(self) -> Self {
                <$t>::ln(self)
            }
            #[inline(always)]
            fn ln_1p(self) -> Self {
                <$t>::ln_1p(self)
            }
            #[inline(always)]
            fn sqrt(self) -> Self {
                <$t>::sqrt(self)
            }
            #[inline(always)]
            fn abs(self) -> Self {
                <$t>::abs(self)
            }
            #[inline(always)]
            fn max(self, other: Self) -> Self {
                if self >= other { self } else { other }
            }
            #[inline(always)]
            fn min(self, other: Self) -> Self {
                if self <= other { self } else { other }
            }
            #[inline(always)]
            fn is_finite(self) -> bool {
                <$t>::is_finite(self)
            }
        }
    };
}
real_impl!(f32);
real_impl!(f64);

/// Whether this machine runs the vector (AVX2 + FMA) copies of the kernels. Results are the
/// same either way; this only says how fast they come.
pub fn has_fast_fma() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        std::is_x86_feature_detected!("avx2") && std::is_x86_feature_detected!("fma")
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}
