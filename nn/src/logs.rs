//! `libm`'s `log` and `logf`, main path only, without branches.
//!
//! The pinned `libm` crate's logarithms (FreeBSD's `e_log.c` / `e_logf.c`) reduce `x` to
//! `[sqrt(2)/2, sqrt(2)]` by its exponent bits and evaluate a fixed polynomial: pure arithmetic,
//! except for the branches that catch zero, negative, subnormal, infinite and NaN inputs and
//! `x == 1`. Those branches (and the call) keep a loop of `libm::logf` scalar: the squash's
//! log-determinant, one `logf` per latent coordinate, was half the time of sampling an action
//! in a DSRL gradient step (`perf` on `examples/bench --only dsrl`).
//!
//! These functions are the main path alone, the same operations in the same order (Rust never
//! fuses a multiply and an add), so for a positive, normal, finite input they give `libm`'s bits
//! (`x == 1` falls through the formula to `+0`, as the branch returns); a loop of them
//! vectorises. [`crate::ops::ln_into`] runs them over a slice and sends every other input to
//! `libm`. The constants are the algorithm's published coefficients (IEEE bit patterns in the
//! comments), as the `libm` source has them.

/// `libm::logf(x)` for positive, normal, finite `x`.
#[inline(always)]
pub fn logf_positive_normal(x: f32) -> f32 {
    const LN2_HI: f32 = f32::from_bits(0x3f31_7180);
    const LN2_LO: f32 = f32::from_bits(0x3717_f7d1);
    const LG1: f32 = f32::from_bits(0x3f2a_aaaa);
    const LG2: f32 = f32::from_bits(0x3ecc_ce13);
    const LG3: f32 = f32::from_bits(0x3e91_e9ee);
    const LG4: f32 = f32::from_bits(0x3e78_9e26);
    // reduce x into [sqrt(2)/2, sqrt(2)]
    let ix = x.to_bits().wrapping_add(0x3f80_0000 - 0x3f35_04f3);
    let k = ((ix >> 23) as i32) - 0x7f;
    let x = f32::from_bits((ix & 0x007f_ffff) + 0x3f35_04f3);
    let f = x - 1.;
    let s = f / (2. + f);
    let z = s * s;
    let w = z * z;
    let t1 = w * (LG2 + w * LG4);
    let t2 = z * (LG1 + w * LG3);
    let r = t2 + t1;
    let hfsq = 0.5 * f * f;
    let dk = k as f32;
    s * (hfsq + r) + dk * LN2_LO - hfsq + f + dk * LN2_HI
}

/// `libm::log(x)` for positive, normal, finite `x`.
#[inline(always)]
pub fn log_positive_normal(x: f64) -> f64 {
    const LN2_HI: f64 = f64::from_bits(0x3fe6_2e42_fee0_0000);
    const LN2_LO: f64 = f64::from_bits(0x3dea_39ef_3579_3c76);
    const LG1: f64 = f64::from_bits(0x3fe5_5555_5555_5593);
    const LG2: f64 = f64::from_bits(0x3fd9_9999_9997_fa04);
    const LG3: f64 = f64::from_bits(0x3fd2_4924_9422_9359);
    const LG4: f64 = f64::from_bits(0x3fcc_71c5_1d8e_78af);
    const LG5: f64 = f64::from_bits(0x3fc7_4664_96cb_03de);
    const LG6: f64 = f64::from_bits(0x3fc3_9a09_d078_c69f);
    const LG7: f64 = f64::from_bits(0x3fc2_f112_df3e_5244);
    let ui = x.to_bits();
    // reduce x into [sqrt(2)/2, sqrt(2)]
    let hx = ((ui >> 32) as u32).wrapping_add(0x3ff0_0000 - 0x3fe6_a09e);
    let k = ((hx >> 20) as i32) - 0x3ff;
    let hx = (hx & 0x000f_ffff) + 0x3fe6_a09e;
    let x = f64::from_bits(((hx as u64) << 32) | (ui & 0xffff_ffff));
    let f = x - 1.0;
    let hfsq = 0.5 * f * f;
    let s = f / (2.0 + f);
    let z = s * s;
    let w = z * z;
    let t1 = w * (LG2 + w * (LG4 + w * LG6));
    let t2 = z * (LG1 + w * (LG3 + w * (LG5 + w * LG7)));
    let r = t2 + t1;
    let dk = k as f64;
    s * (hfsq + r) + dk * LN2_LO - hfsq + f + dk * LN2_HI
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `libm`'s bits on every f32 of a dense sweep of the positive normals (every 97th bit
    /// pattern, about 22 million values, `1.0` and the extremes included), and on f64 values
    /// spread over the whole positive normal range and densely over (0, 1] (Box-Muller's
    /// inputs).
    #[test]
    fn the_main_paths_give_libms_bits() {
        let mut bits = f32::MIN_POSITIVE.to_bits();
        let mut checked = 0u64;
        while bits < f32::INFINITY.to_bits() {
            let x = f32::from_bits(bits);
            assert_eq!(logf_positive_normal(x).to_bits(), libm::logf(x).to_bits(), "logf({x:e})");
            bits += 97;
            checked += 1;
        }
        for x in [1.0f32, f32::MAX, f32::MIN_POSITIVE, 1e-6, 1.000_001] {
            assert_eq!(logf_positive_normal(x).to_bits(), libm::logf(x).to_bits(), "logf({x:e})");
        }
        assert!(checked > 20_000_000);
        let mut h = 0x9E37_79B9_7F4A_7C15u64;
        for i in 0..4_000_000u64 {
            h = h.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            let x = if i % 2 == 0 {
                // any positive normal: random exponent and mantissa
                f64::from_bits((h >> 1).clamp(f64::MIN_POSITIVE.to_bits(), f64::MAX.to_bits()))
            } else {
                1.0 - (h >> 11) as f64 / (1u64 << 53) as f64
            };
            if x.is_normal() {
                assert_eq!(log_positive_normal(x).to_bits(), libm::log(x).to_bits(), "log({x:e})");
            }
        }
        for x in [1.0f64, f64::MAX, f64::MIN_POSITIVE, 2f64.powi(-53)] {
            assert_eq!(log_positive_normal(x).to_bits(), libm::log(x).to_bits(), "log({x:e})");
        }
    }
}
