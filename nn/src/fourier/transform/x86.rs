//! The [`Tile`]s of x86-64: AVX2 (8 fields per tile, an 8 x 8 transpose of unpacks, shuffles
//! and 128-bit permutes) and AVX-512 (16 fields, three rounds of two-source permutes), and the
//! `target_feature` entry points that compile [`forward_tiles`] and [`inverse_tiles`] for each.

use std::arch::x86_64::*;

use super::{forward_tiles, inverse_tiles, Blocks, Tile, ORDER};

/// AVX2 + FMA: a tile is 8 fields, one field's 8 components per loaded vector.
pub struct Avx2;

/// AVX-512 F: a tile is 16 fields, two fields' components per loaded vector.
pub struct Avx512;

/// `[0, 1, .., 7]`, for the AVX2 lane masks.
const LANE_INDEX: [i32; 8] = [0, 1, 2, 3, 4, 5, 6, 7];

// SAFETY: every method is only reached from the AVX2 + FMA entry points below.
unsafe impl Tile for Avx2 {
    const LANES: usize = 8;
    type V = __m256;

    #[inline(always)]
    unsafe fn zero() -> __m256 {
        // SAFETY: the CPU has AVX (the trait's contract).
        unsafe { _mm256_setzero_ps() }
    }

    #[inline(always)]
    unsafe fn splat(v: f32) -> __m256 {
        // SAFETY: as above.
        unsafe { _mm256_set1_ps(v) }
    }

    #[inline(always)]
    unsafe fn fmadd(a: __m256, b: __m256, c: __m256) -> __m256 {
        // SAFETY: the CPU has FMA.
        unsafe { _mm256_fmadd_ps(a, b, c) }
    }

    #[inline(always)]
    unsafe fn load(p: *const f32, valid: usize) -> __m256 {
        // SAFETY: `p` is valid for `valid` lanes (the trait's contract); masked lanes are not read.
        unsafe {
            if valid == Self::LANES {
                _mm256_loadu_ps(p)
            } else {
                _mm256_maskload_ps(p, mask(valid))
            }
        }
    }

    #[inline(always)]
    unsafe fn store(p: *mut f32, v: __m256, valid: usize) {
        // SAFETY: as in `load`; masked lanes are not written.
        unsafe {
            if valid == Self::LANES {
                _mm256_storeu_ps(p, v)
            } else {
                _mm256_maskstore_ps(p, mask(valid), v)
            }
        }
    }

    #[inline(always)]
    unsafe fn fields_to_components(v: [__m256; ORDER]) -> [__m256; ORDER] {
        // SAFETY: the CPU has AVX.
        unsafe { transpose8(v) }
    }

    #[inline(always)]
    unsafe fn components_to_fields(v: [__m256; ORDER]) -> [__m256; ORDER] {
        // SAFETY: as above (an 8 x 8 transpose is its own inverse).
        unsafe { transpose8(v) }
    }
}

/// The first `valid` of 8 lanes (sign bits set).
#[inline(always)]
unsafe fn mask(valid: usize) -> __m256i {
    // SAFETY: the CPU has AVX2; the index array is 8 x i32.
    unsafe { _mm256_cmpgt_epi32(_mm256_set1_epi32(valid as i32), _mm256_loadu_si256(LANE_INDEX.as_ptr().cast())) }
}

/// Transpose an 8 x 8 tile held as eight row vectors.
#[inline(always)]
unsafe fn transpose8(r: [__m256; 8]) -> [__m256; 8] {
    // SAFETY: register operations only; the CPU has AVX.
    unsafe {
        let t: [__m256; 8] = std::array::from_fn(|i| {
            let (a, b) = (r[2 * (i / 2)], r[2 * (i / 2) + 1]);
            if i % 2 == 0 {
                _mm256_unpacklo_ps(a, b)
            } else {
                _mm256_unpackhi_ps(a, b)
            }
        });
        // u[4 g + q]: rows 4 g .. 4 g + 4, component q (and q + 4) of each 128-bit half
        let u: [__m256; 8] = std::array::from_fn(|i| {
            let (g, q) = (i / 4, i % 4);
            let (a, b) = (t[4 * g + q / 2], t[4 * g + 2 + q / 2]);
            if q % 2 == 0 {
                _mm256_shuffle_ps::<0x44>(a, b)
            } else {
                _mm256_shuffle_ps::<0xEE>(a, b)
            }
        });
        std::array::from_fn(|c| {
            if c < 4 {
                _mm256_permute2f128_ps::<0x20>(u[c], u[4 + c])
            } else {
                _mm256_permute2f128_ps::<0x31>(u[c - 4], u[c])
            }
        })
    }
}

// SAFETY: every method is only reached from the AVX-512 entry points below.
unsafe impl Tile for Avx512 {
    const LANES: usize = 16;
    type V = __m512;

    #[inline(always)]
    unsafe fn zero() -> __m512 {
        // SAFETY: the CPU has AVX-512 F (the trait's contract).
        unsafe { _mm512_setzero_ps() }
    }

    #[inline(always)]
    unsafe fn splat(v: f32) -> __m512 {
        // SAFETY: as above.
        unsafe { _mm512_set1_ps(v) }
    }

    #[inline(always)]
    unsafe fn fmadd(a: __m512, b: __m512, c: __m512) -> __m512 {
        // SAFETY: as above.
        unsafe { _mm512_fmadd_ps(a, b, c) }
    }

    #[inline(always)]
    unsafe fn load(p: *const f32, valid: usize) -> __m512 {
        // SAFETY: `p` is valid for `valid` lanes; masked lanes are not read.
        unsafe { _mm512_maskz_loadu_ps(first(valid), p) }
    }

    #[inline(always)]
    unsafe fn store(p: *mut f32, v: __m512, valid: usize) {
        // SAFETY: as in `load`; masked lanes are not written.
        unsafe { _mm512_mask_storeu_ps(p, first(valid), v) }
    }

    #[inline(always)]
    unsafe fn fields_to_components(v: [__m512; ORDER]) -> [__m512; ORDER] {
        // SAFETY: register operations only; the CPU has AVX-512 F.
        unsafe {
            let s1i = [idx(to_components(1, 0)), idx(to_components(1, 1))];
            let s2i = [idx(to_components(2, 0)), idx(to_components(2, 1))];
            let s3i = [idx(to_components(3, 0)), idx(to_components(3, 1))];
            // s1[g][h]: fields 4 g .. 4 g + 4, components 4 h .. 4 h + 4
            let s1: [[__m512; 2]; 4] = std::array::from_fn(|g| {
                std::array::from_fn(|h| _mm512_permutex2var_ps(v[2 * g], s1i[h], v[2 * g + 1]))
            });
            // s2[g][h][q]: fields 8 g .. 8 g + 8, components 4 h + 2 q, + 1
            let s2: [[[__m512; 2]; 2]; 2] = std::array::from_fn(|g| {
                std::array::from_fn(|h| {
                    std::array::from_fn(|q| _mm512_permutex2var_ps(s1[2 * g][h], s2i[q], s1[2 * g + 1][h]))
                })
            });
            std::array::from_fn(|a| {
                let (h, q, c) = (a / 4, (a / 2) % 2, a % 2);
                _mm512_permutex2var_ps(s2[0][h][q], s3i[c], s2[1][h][q])
            })
        }
    }

    #[inline(always)]
    unsafe fn components_to_fields(w: [__m512; ORDER]) -> [__m512; ORDER] {
        // SAFETY: as above.
        unsafe {
            let j3 = [idx(to_fields(3, 0)), idx(to_fields(3, 1))];
            let j2 = [idx(to_fields(2, 0)), idx(to_fields(2, 1))];
            let j1 = [idx(to_fields(1, 0)), idx(to_fields(1, 1))];
            let s2: [[[__m512; 2]; 2]; 2] = std::array::from_fn(|g| {
                std::array::from_fn(|h| {
                    std::array::from_fn(|q| _mm512_permutex2var_ps(w[4 * h + 2 * q], j3[g], w[4 * h + 2 * q + 1]))
                })
            });
            let s1: [[__m512; 2]; 4] = std::array::from_fn(|g4| {
                let (g, t) = (g4 / 2, g4 % 2);
                std::array::from_fn(|h| _mm512_permutex2var_ps(s2[g][h][0], j2[t], s2[g][h][1]))
            });
            std::array::from_fn(|i| {
                let (g4, u) = (i / 2, i % 2);
                _mm512_permutex2var_ps(s1[g4][0], j1[u], s1[g4][1])
            })
        }
    }
}

/// Two-source permute indices of the three transpose stages (field-major -> one vector per
/// component). Stage 1 (by component half `h`): lane `4 l + c` = field `l` (of 4), component
/// `4 h + c`. Stage 2 (by component pair `q`): lane `2 l + c` = field `l` (of 8), component
/// `2 q + c` of the half. Stage 3 (by component parity `c`): lane `l` = field `l` (of 16).
const fn to_components(stage: usize, sel: usize) -> [i32; 16] {
    let mut idx = [0i32; 16];
    let mut lane = 0;
    while lane < 16 {
        idx[lane] = match stage {
            1 => {
                let (l, c) = (lane / 4, lane % 4);
                (l / 2) * 16 + (l % 2) * 8 + 4 * sel + c
            }
            2 => {
                let (l, c) = (lane / 2, lane % 2);
                (l / 4) * 16 + (l % 4) * 4 + 2 * sel + c
            }
            _ => (lane / 8) * 16 + (lane % 8) * 2 + sel,
        } as i32;
        lane += 1;
    }
    idx
}

/// The inverse stages (one vector per component -> field-major), in the order they run.
const fn to_fields(stage: usize, sel: usize) -> [i32; 16] {
    let mut idx = [0i32; 16];
    let mut lane = 0;
    while lane < 16 {
        idx[lane] = match stage {
            // undo stage 3: lane 2 l + c of field block `sel` (of 8 fields)
            3 => {
                let (l, c) = (lane / 2, lane % 2);
                c * 16 + 8 * sel + l
            }
            // undo stage 2: lane 4 l + c, fields 4 sel + l of the 8
            2 => {
                let (l, c) = (lane / 4, lane % 4);
                (c / 2) * 16 + (4 * sel + l) * 2 + c % 2
            }
            // undo stage 1: lane p = field (2 sel + p / 8), component p % 8
            _ => {
                let comp = lane % 8;
                (comp / 4) * 16 + (2 * sel + lane / 8) * 4 + comp % 4
            }
        } as i32;
        lane += 1;
    }
    idx
}

#[inline(always)]
unsafe fn idx(v: [i32; 16]) -> __m512i {
    // SAFETY: reads the 16 i32 of `v`; the CPU has AVX-512 F.
    unsafe { _mm512_loadu_si512(v.as_ptr() as *const _) }
}

/// Mask of the first `n` lanes (`n <= 16`).
#[inline(always)]
fn first(n: usize) -> __mmask16 {
    ((1u32 << n) - 1) as __mmask16
}

/// # Safety
///
/// The CPU has AVX2 and FMA; `t` is 8 x 8; `x` and `out` hold `blocks.len()` values.
#[target_feature(enable = "avx2,fma")]
pub unsafe fn forward_avx2(t: &[f32], x: &[f32], blocks: Blocks, out: &mut [f32]) {
    // SAFETY: this function's contract.
    unsafe { forward_tiles::<Avx2>(t, x, blocks, out) }
}

/// # Safety
///
/// As [`forward_avx2`]; `init`, when given, holds `blocks.f` values.
#[target_feature(enable = "avx2,fma")]
pub unsafe fn inverse_avx2(t: &[f32], xh: &[f32], blocks: Blocks, init: Option<&[f32]>, out: &mut [f32]) {
    // SAFETY: this function's contract.
    unsafe { inverse_tiles::<Avx2>(t, xh, blocks, init, out) }
}

/// # Safety
///
/// As [`forward_avx2`], with AVX-512 F in place of AVX2 and FMA.
#[target_feature(enable = "avx512f")]
pub unsafe fn forward_avx512(t: &[f32], x: &[f32], blocks: Blocks, out: &mut [f32]) {
    // SAFETY: this function's contract.
    unsafe { forward_tiles::<Avx512>(t, x, blocks, out) }
}

/// # Safety
///
/// As [`inverse_avx2`], with AVX-512 F in place of AVX2 and FMA.
#[target_feature(enable = "avx512f")]
pub unsafe fn inverse_avx512(t: &[f32], xh: &[f32], blocks: Blocks, init: Option<&[f32]>, out: &mut [f32]) {
    // SAFETY: this function's contract.
    unsafe { inverse_tiles::<Avx512>(t, xh, blocks, init, out) }
}
