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
//! - **Wider registers, same order.** Where the CPU has AVX-512, [`gemm`] runs a third copy
//!   with 32-column blocks (two 16-lane vectors per row); each element is still the same chain
//!   of fused multiply-adds, so the bits are those of the AVX2 and portable copies (tested on
//!   the machine that runs the tests). On an Intel Xeon with AVX-512, `examples/bench` gave
//!   1.1-1.25x the Equi-DSRL and 1.15-1.35x the DSRL gradient steps/s of the AVX2 copy (two
//!   alternating pairs, one core).
//! - **The pointwise and LayerNorm kernels** ([`ops`]) are compiled the same way, one
//!   `#[inline(always)]` body per kernel in a portable, an AVX2 and an AVX-512 copy, chosen by
//!   [`Isa::best`]; their arithmetic has no multiply-add to fuse, so the copies differ only in
//!   vector width (tested bit for bit against the portable copy). On the AVX-512 Xeon, Tanh's
//!   share of a DSRL gradient step fell from 14 % to 10 % of `perf` samples. The LayerNorm
//!   statistics (each row's sums in index order, rows strided in memory) run sixteen rows per
//!   instruction on AVX-512 through an in-register transpose (`ops`' `rows16`), the same
//!   additions in the same order; elsewhere eight rows side by side.
//! - **Memory, not arithmetic, bounds the pointwise passes** at batch 256: LayerNorm and the
//!   Tanh after it run as one kernel that writes only the Tanh's output and keeps each row's
//!   mean and `1/std` ([`layer_norm::layer_norm`]). With that, the transposed statistics, the Fourier
//!   layers' own transform kernels and a branch-free argmax in the critic head, Equi-DSRL's
//!   gradient steps/s on the AVX-512 Xeon went from 67.4 to 108.7 and DSRL's from 216.1 to
//!   310.0 (best of 5 alternating runs of `examples/bench --only` against the previous build),
//!   and with the AVX-512 copies switched off Equi-DSRL's from 50.5 to 65.7; same bits (the
//!   golden runs did not change).
//!
//! Transcendentals (`tanh`, `exp`, `ln`) come from the pinned `libm` crate, not the platform's
//! C library (the f32 `tanh` of the layers is the crate's own [`tanh_f32`]); `sqrt` is exact
//! everywhere.
//!
//! Measured speed of these kernels, against the core's peak and PyTorch: [docs/agents.md](../docs/agents.md),
//! "Kernel speed (equigym-nn)".

#[macro_use]
mod kernel_copies;

pub mod adam;
pub mod fourier;
pub mod gemm;
pub mod layer_norm;
pub mod logs;
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
    /// Fused multiply-add `self * a + b` with one rounding (see the module docs). Only the
    /// matrix product uses it (inside its dispatched copies); elsewhere the code writes `a * b + c`,
    /// which Rust never fuses, so no other code path depends on the CPU's features.
    fn fma(self, a: Self, b: Self) -> Self;
    /// tanh; for `f32` the crate's own [`tanh_f32`] (pure arithmetic: the same bits on every
    /// machine, whatever its libm, and vectorisable).
    fn tanh(self) -> Self;
    fn exp(self) -> Self;
    fn ln(self) -> Self;
    /// [`Real::ln`] for a positive, normal, finite `self` (bit for bit), written without
    /// branches so that a loop of it vectorises; other inputs give garbage ([`ops::ln_into`]
    /// fixes them up).
    fn ln_positive_normal(self) -> Self;
    /// Whether [`Real::ln_positive_normal`] is exact for `self`.
    fn is_positive_normal(self) -> bool;
    fn ln_1p(self) -> Self;
    fn sqrt(self) -> Self;
    fn abs(self) -> Self;
    fn max(self, other: Self) -> Self;
    fn min(self, other: Self) -> Self;
    fn is_finite(self) -> bool;
}

macro_rules! real_impl {
    ($t:ty, $tanh:expr, $exp:expr, $ln:expr, $ln_pn:expr, $ln_1p:expr) => {
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
                $tanh(self)
            }
            #[inline(always)]
            fn exp(self) -> Self {
                $exp(self)
            }
            #[inline(always)]
            fn ln(self) -> Self {
                $ln(self)
            }
            #[inline(always)]
            fn ln_positive_normal(self) -> Self {
                $ln_pn(self)
            }
            #[inline(always)]
            fn is_positive_normal(self) -> bool {
                self.is_normal() && self > 0.0 && self.is_finite()
            }
            #[inline(always)]
            fn ln_1p(self) -> Self {
                $ln_1p(self)
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
                if self >= other {
                    self
                } else {
                    other
                }
            }
            #[inline(always)]
            fn min(self, other: Self) -> Self {
                if self <= other {
                    self
                } else {
                    other
                }
            }
            #[inline(always)]
            fn is_finite(self) -> bool {
                <$t>::is_finite(self)
            }
        }
    };
}
// exp, ln and ln_1p from the `libm` crate, not the system C library (see clippy.toml).
real_impl!(f32, tanh_f32, libm::expf, libm::logf, logs::logf_positive_normal, libm::log1pf);
real_impl!(f64, libm::tanh, libm::exp, libm::log, logs::log_positive_normal, libm::log1p);

/// Below this |x|, tanh uses its odd Taylor series to x^13 (truncation < 1e-9 there).
const TANH_SERIES_BELOW: f32 = 0.4;
/// Above this |x|, tanh(x) rounds to +-1 in f32.
const TANH_SATURATES: f32 = 10.0;

/// tanh in f32 from +, -, *, / and bit operations only (no libm, no fusing): the same bits on
/// every machine. |x| < 0.4: odd Taylor series to x^13; otherwise 1 - 2 / (exp(2|x|) + 1) with
/// exp by Cody-Waite reduction to |r| <= ln2/2 and a degree-7 polynomial. Within 4 ulp of the
/// true value over the whole range (3 measured; checked against f64 in the tests); branch-free, so loops
/// over it vectorise.
#[inline(always)]
pub fn tanh_f32(x: f32) -> f32 {
    const LOG2E: f32 = std::f32::consts::LOG2_E;
    const LN2_HI: f32 = 0.693_145_75;
    const LN2_LO: f32 = 1.428_606_8e-6;
    const ROUND: f32 = 12_582_912.0; // 1.5 * 2^23: adding it rounds to an integer
    let a = x.abs().min(TANH_SATURATES);
    // series
    let a2 = a * a;
    let series = a + a
        * a2
        * (-1.0 / 3.0
            + a2 * (2.0 / 15.0
                + a2 * (-17.0 / 315.0
                    + a2 * (62.0 / 2835.0 + a2 * (-1382.0 / 155_925.0 + a2 * (21_844.0 / 6_081_075.0))))));
    // exp(2a)
    let y = 2.0 * a;
    let t = y * LOG2E + ROUND;
    let k = t.to_bits().wrapping_sub(ROUND.to_bits()) as i32;
    let kf = t - ROUND;
    let r = (y - kf * LN2_HI) - kf * LN2_LO;
    let p = 1.0
        + r * (1.0
            + r * (0.5
                + r * (1.0 / 6.0 + r * (1.0 / 24.0 + r * (1.0 / 120.0 + r * (1.0 / 720.0 + r * (1.0 / 5040.0)))))));
    let e = p * f32::from_bits(((k + 127) as u32) << 23);
    let big = 1.0 - 2.0 / (e + 1.0);
    let v = if a < TANH_SERIES_BELOW { series } else { big };
    if x < 0.0 {
        -v
    } else {
        v
    }
}

/// `v` as `f32`s when `T` is `f32`: the kernels with a hand-written AVX-512 copy (f32 only)
/// take it through this.
pub fn as_f32s<T: Real>(v: &[T]) -> Option<&[f32]> {
    (std::any::TypeId::of::<T>() == std::any::TypeId::of::<f32>())
        // SAFETY: T is f32.
        .then(|| unsafe { std::slice::from_raw_parts(v.as_ptr() as *const f32, v.len()) })
}

/// [`as_f32s`] for a mutable slice.
pub fn as_f32s_mut<T: Real>(v: &mut [T]) -> Option<&mut [f32]> {
    (std::any::TypeId::of::<T>() == std::any::TypeId::of::<f32>())
        // SAFETY: T is f32.
        .then(|| unsafe { std::slice::from_raw_parts_mut(v.as_mut_ptr() as *mut f32, v.len()) })
}

/// Test data for the kernels' bit-for-bit tests (here and in the agents): `n` values in
/// [-3, 3) from a fixed integer hash of `(salt, index)`, no random stream involved.
#[doc(hidden)]
pub fn hashed_values(n: usize, salt: u64) -> Vec<f32> {
    (0..n as u64)
        .map(|i| {
            let h = (i.wrapping_add(salt << 32)).wrapping_mul(0x9E37_79B9_7F4A_7C15) >> 40;
            (h as f32 / (1u64 << 24) as f32) * 6.0 - 3.0
        })
        .collect()
}

/// Whether this machine runs the AVX-512 copy of the matrix kernel (wider register blocks; the
/// same bits as the other copies).
pub fn has_avx512() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        std::is_x86_feature_detected!("avx512f") && std::is_x86_feature_detected!("avx512vl") && has_fast_fma()
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

/// A compiled copy of a kernel, by the instruction set it may use. Every copy gives the same
/// bits (the tests compare them); only the speed differs.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
pub enum Isa {
    /// Baseline x86-64 (SSE2), or whatever the target has.
    Portable,
    /// AVX2 + FMA.
    Avx2,
    /// AVX-512 (F and VL) as well.
    Avx512,
}

impl Isa {
    /// The widest copy this CPU runs.
    pub fn best() -> Self {
        if has_avx512() {
            Self::Avx512
        } else if has_fast_fma() {
            Self::Avx2
        } else {
            Self::Portable
        }
    }

    /// Every copy this CPU runs, narrowest first.
    pub fn available() -> Vec<Self> {
        [Self::Portable, Self::Avx2, Self::Avx512].into_iter().filter(|&i| i <= Self::best()).collect()
    }
}

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
