//! The macro that compiles one kernel body as a portable, an AVX2 and an AVX-512 copy.

/// Defines a kernel as a dispatcher over compiled copies of one `#[inline(always)]` body:
/// `$name` runs the widest copy this CPU has ([`Isa::best`]), `$on` the copy `isa` (for the
/// tests that compare them). The copies differ only in the registers LLVM may use: the
/// arithmetic is the same `+`, `-`, `*`, `/` and `sqrt` in the same order (Rust never fuses a
/// multiply and an add), so every copy gives the same bits. Before, these loops ran as SSE2
/// (4 lanes) except Tanh (AVX2); on an AVX-512 Xeon, Tanh and the LayerNorm passes were 35 %
/// of a DSRL gradient step's samples (`perf` on `examples/bench --only dsrl`).
macro_rules! kernel_copies {
    ($(#[$doc:meta])* pub fn $name:ident / $on:ident ($($arg:ident: $ty:ty),* $(,)?) => $body:ident;) => {
        $(#[$doc])*
        #[allow(clippy::too_many_arguments)]
        pub fn $name<T: Real>($($arg: $ty),*) {
            $on(Isa::best(), $($arg),*)
        }

        #[doc = concat!("[`", stringify!($name), "`] in the compiled copy `isa` (the portable one where this CPU lacks it).")]
        #[allow(clippy::too_many_arguments)]
        pub fn $on<T: Real>(isa: Isa, $($arg: $ty),*) {
            #[cfg(target_arch = "x86_64")]
            {
                #[target_feature(enable = "avx512f,avx512vl,avx2")]
                #[allow(clippy::too_many_arguments)]
                unsafe fn avx512<T: Real>($($arg: $ty),*) {
                    $body($($arg),*)
                }
                #[target_feature(enable = "avx2")]
                #[allow(clippy::too_many_arguments)]
                unsafe fn avx2<T: Real>($($arg: $ty),*) {
                    $body($($arg),*)
                }
                match isa {
                    // SAFETY: the guard checks that the CPU has the copy's features.
                    Isa::Avx512 if crate::has_avx512() => return unsafe { avx512($($arg),*) },
                    // SAFETY: as above.
                    Isa::Avx2 if crate::has_fast_fma() => return unsafe { avx2($($arg),*) },
                    _ => {}
                }
            }
            let _ = isa;
            $body($($arg),*)
        }
    };
}
