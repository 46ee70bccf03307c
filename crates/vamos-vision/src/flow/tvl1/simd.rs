//! The fast kernel's rows with AVX2 and FMA, eight pixels per step.
//!
//! Same steps as the exact `primal_px` and `dual_px` (in `kernels`), but no instruction of the divider:
//! reciprocals (`1 / |grad I1w|^2` in the primal step, `1 / (1 + ...)` in the dual step)
//! come from the hardware estimate and `sqrt(q)` from `q` times the estimate of
//! `1 / sqrt(q)`, each refined by one Newton step (relative error about 1e-7 instead of
//! 0.5 ulp). The division and square root units were the bottleneck of the exact
//! kernel: five divisions and two square roots per eight pixels and iteration. Row ends
//! use masked loads and stores; column 0 uses the exact per-pixel code.

use std::arch::x86_64::*;

use super::super::warp::{GRAD_EPS, Linearised};
use super::kernels::{
    Band, DualAbove, DualRow, DualRowMut, FlowRow, FlowRowMut, LinRow, Rows,
    band_pass as generic_band_pass, pair_pass as generic_pair_pass, primal_px,
};
use super::{Dual, Steps};

/// The AVX2 + FMA rows.
struct SimdRows;

impl Rows for SimdRows {
    #[inline(always)]
    fn primal(
        lin: LinRow<'_>,
        p: DualRow<'_>,
        up: DualAbove<'_>,
        u: FlowRowMut<'_>,
        _e: &mut [f32],
        s: Steps,
    ) -> f64 {
        // SAFETY: `SimdRows` is only used by `band_pass` and `pair_pass` below, which
        // require AVX2 and FMA.
        unsafe { primal_row(lin, p, up, u, s) }
    }

    #[inline(always)]
    fn dual(u: FlowRow<'_>, below: FlowRow<'_>, p: DualRowMut<'_>, taut: f32) {
        // SAFETY: as above.
        unsafe { dual_row(u, below, p, taut) }
    }
}

/// The band pass with the AVX2 + FMA rows.
///
/// # Safety
/// The CPU must have AVX2 and FMA ([`super::kernels::simd_rows`]).
#[target_feature(enable = "avx2,fma")]
pub(super) unsafe fn band_pass(
    lin: &Linearised,
    band: Band<'_>,
    up: &[f32],
    w: usize,
    height: usize,
    s: Steps,
) {
    generic_band_pass::<SimdRows>(lin, band, up, w, height, s);
}

/// The two-iteration pass with the AVX2 + FMA rows.
///
/// # Safety
/// The CPU must have AVX2 and FMA ([`super::kernels::simd_rows`]).
#[target_feature(enable = "avx2,fma")]
pub(super) unsafe fn pair_pass(
    lin: &Linearised,
    u1: &mut [f32],
    u2: &mut [f32],
    p: &mut Dual,
    size: (usize, usize),
    s: Steps,
    rows: (&[f32], &mut [f32]),
) -> f64 {
    generic_pair_pass::<SimdRows>(lin, u1, u2, p, size, s, rows)
}

#[inline(always)]
fn ld(v: &[f32], i: usize) -> __m256 {
    let v = &v[i..i + 8];
    // SAFETY: eight values (checked by the slicing); AVX is enabled in every caller.
    unsafe { _mm256_loadu_ps(v.as_ptr()) }
}

#[inline(always)]
fn st(v: &mut [f32], i: usize, x: __m256) {
    let v = &mut v[i..i + 8];
    // SAFETY: as `ld`.
    unsafe { _mm256_storeu_ps(v.as_mut_ptr(), x) }
}

/// `1 / x` from the hardware estimate and one Newton step.
#[inline]
#[target_feature(enable = "avx2,fma")]
fn recip(x: __m256) -> __m256 {
    let r = _mm256_rcp_ps(x);
    _mm256_mul_ps(r, _mm256_fnmadd_ps(x, r, _mm256_set1_ps(2.0)))
}

/// `sqrt(q)` for `q >= 0` as `q * rsqrt(q)`, the estimate refined by one Newton step
/// (0 stays 0).
#[inline]
#[target_feature(enable = "avx2,fma")]
fn sqrt(q: __m256) -> __m256 {
    let y = _mm256_rsqrt_ps(_mm256_max_ps(q, _mm256_set1_ps(f32::MIN_POSITIVE)));
    let qy = _mm256_mul_ps(q, y);
    // y' = y (1.5 - 0.5 q y^2), so q y' = qy (1.5 - 0.5 qy y).
    let h = _mm256_fnmadd_ps(
        _mm256_mul_ps(_mm256_set1_ps(0.5), qy),
        y,
        _mm256_set1_ps(1.5),
    );
    _mm256_mul_ps(qy, h)
}

/// Lanes `0..n` set (n <= 8), as a mask for the masked loads and stores.
#[inline]
#[target_feature(enable = "avx2,fma")]
fn first_lanes(n: usize) -> __m256i {
    _mm256_cmpgt_epi32(
        _mm256_set1_epi32(n as i32),
        _mm256_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7),
    )
}

/// Lanes `0..n` of `v[i..]` (`n = min(8, v.len() - i)`), 0 in the others.
#[inline(always)]
fn ld_part(v: &[f32], i: usize, mask: __m256i) -> __m256 {
    let v = &v[i..];
    // SAFETY: the mask selects lanes `0..min(8, v.len())` only (callers build it from
    // the remaining length); AVX is enabled in every caller.
    unsafe { _mm256_maskload_ps(v.as_ptr(), mask) }
}

#[inline(always)]
fn st_part(v: &mut [f32], i: usize, mask: __m256i, x: __m256) {
    let v = &mut v[i..];
    // SAFETY: as `ld_part`.
    unsafe { _mm256_maskstore_ps(v.as_mut_ptr(), mask, x) }
}

/// Eight (or, with a mask, fewer) consecutive values.
#[derive(Clone, Copy)]
enum Span {
    Full,
    Part(__m256i),
}

impl Span {
    #[inline(always)]
    fn ld(self, v: &[f32], i: usize) -> __m256 {
        match self {
            Span::Full => ld(v, i),
            Span::Part(m) => ld_part(v, i, m),
        }
    }

    #[inline(always)]
    fn st(self, v: &mut [f32], i: usize, x: __m256) {
        match self {
            Span::Full => st(v, i, x),
            Span::Part(m) => st_part(v, i, m, x),
        }
    }
}

/// Steps 1 and 2 on one row (as the exact rows' `primal_row`). `|grad|^2` and its
/// reciprocal are recomputed from `Ix`, `Iy` (cheaper than reading two more arrays: the
/// kernel is bound by memory traffic once the divider is out of it).
///
/// # Safety
/// The CPU must have AVX2 and FMA.
#[target_feature(enable = "avx2,fma")]
unsafe fn primal_row(
    lin: LinRow<'_>,
    p: DualRow<'_>,
    up: DualAbove<'_>,
    u: FlowRowMut<'_>,
    s: Steps,
) -> f64 {
    let w = u.u1.len();
    let (u1, u2) = (u.u1, &mut u.u2[..w]);
    let (ix, iy, g, rc) = (&lin.ix[..w], &lin.iy[..w], &lin.grad[..w], &lin.rho_c[..w]);
    let (p11, p12, p21, p22) = (&p.p11[..w], &p.p12[..w], &p.p21[..w], &p.p22[..w]);
    let (p12_up, p22_up) = (&up.p12[..w], &up.p22[..w]);
    // Column 0 (p is 0 left of the image): the exact code.
    let first = {
        let d1 = p11[0] + (p12[0] - p12_up[0]);
        let d2 = p21[0] + (p22[0] - p22_up[0]);
        let (n1, n2) = primal_px(ix[0], iy[0], g[0], rc[0], u1[0], u2[0], d1, d2, s);
        let (a, b) = (n1 - u1[0], n2 - u2[0]);
        u1[0] = n1;
        u2[0] = n2;
        a * a + b * b
    };
    // Squared updates summed in eight lanes (masked-off lanes add 0).
    let mut acc = _mm256_setzero_ps();
    let (lt, theta) = (_mm256_set1_ps(s.lt), _mm256_set1_ps(s.theta));
    let (neg_lt, eps) = (_mm256_set1_ps(-s.lt), _mm256_set1_ps(GRAD_EPS));
    let sign = _mm256_set1_ps(-0.0);
    let mut x = 1;
    while x < w {
        let span = if x + 8 <= w {
            Span::Full
        } else {
            Span::Part(first_lanes(w - x))
        };
        let d1 = _mm256_add_ps(
            _mm256_sub_ps(span.ld(p11, x), span.ld(p11, x - 1)),
            _mm256_sub_ps(span.ld(p12, x), span.ld(p12_up, x)),
        );
        let d2 = _mm256_add_ps(
            _mm256_sub_ps(span.ld(p21, x), span.ld(p21, x - 1)),
            _mm256_sub_ps(span.ld(p22, x), span.ld(p22_up, x)),
        );
        let (vx, vy) = (span.ld(ix, x), span.ld(iy, x));
        let (o1, o2) = (span.ld(u1, x), span.ld(u2, x));
        let rho = _mm256_add_ps(
            span.ld(rc, x),
            _mm256_fmadd_ps(vy, o2, _mm256_mul_ps(vx, o1)),
        );
        let gg = _mm256_fmadd_ps(vy, vy, _mm256_mul_ps(vx, vx));
        let lg = _mm256_mul_ps(lt, gg);
        // -rho / g where the gradient is not flat, else 0.
        let flat = _mm256_cmp_ps::<_CMP_LE_OQ>(gg, eps);
        let inv = _mm256_andnot_ps(flat, recip(_mm256_max_ps(gg, eps)));
        let mut f = _mm256_xor_ps(_mm256_mul_ps(rho, inv), sign);
        let below = _mm256_cmp_ps::<_CMP_LT_OQ>(rho, _mm256_xor_ps(lg, sign));
        f = _mm256_blendv_ps(f, lt, below);
        let above = _mm256_cmp_ps::<_CMP_GT_OQ>(rho, lg);
        f = _mm256_blendv_ps(f, neg_lt, above);
        let n1 = _mm256_fmadd_ps(theta, d1, _mm256_fmadd_ps(f, vx, o1));
        let n2 = _mm256_fmadd_ps(theta, d2, _mm256_fmadd_ps(f, vy, o2));
        let (a, b) = (_mm256_sub_ps(n1, o1), _mm256_sub_ps(n2, o2));
        acc = _mm256_add_ps(acc, _mm256_fmadd_ps(b, b, _mm256_mul_ps(a, a)));
        span.st(u1, x, n1);
        span.st(u2, x, n2);
        x += 8;
    }
    let mut lanes = [0.0f32; 8];
    // SAFETY: writes eight lanes to the local array of eight.
    unsafe { _mm256_storeu_ps(lanes.as_mut_ptr(), acc) };
    lanes.iter().map(|&v| v as f64).sum::<f64>() + first as f64
}

/// Where a block of step 3 lies: its first pixel `x`, its lanes (`span`), the lanes
/// whose right neighbour is in the row (`right`) and that as an all-ones lane mask.
#[derive(Clone, Copy)]
struct Block {
    x: usize,
    span: Span,
    right: Span,
    has_right: __m256,
}

/// Step 3 on one block for one flow component: `u` and the row `below` of it, its dual
/// pair `(pa, pb)` updated in place.
///
/// # Safety
/// The CPU must have AVX2 and FMA (it is inlined into the `dual_row` that requires
/// them).
#[inline(always)]
unsafe fn dual_block(
    b: Block,
    u: &[f32],
    below: &[f32],
    pa: &mut [f32],
    pb: &mut [f32],
    taut: f32,
) {
    // SAFETY: the caller guarantees AVX2 and FMA.
    unsafe {
        let t = _mm256_set1_ps(taut);
        let Block {
            x,
            span,
            right,
            has_right,
        } = b;
        let c = span.ld(u, x);
        let ux = _mm256_and_ps(has_right, _mm256_sub_ps(right.ld(u, x + 1), c));
        let uy = _mm256_sub_ps(span.ld(below, x), c);
        let q = _mm256_fmadd_ps(uy, uy, _mm256_mul_ps(ux, ux));
        let r = recip(_mm256_fmadd_ps(t, sqrt(q), _mm256_set1_ps(1.0)));
        span.st(
            pa,
            x,
            _mm256_mul_ps(_mm256_fmadd_ps(t, ux, span.ld(pa, x)), r),
        );
        span.st(
            pb,
            x,
            _mm256_mul_ps(_mm256_fmadd_ps(t, uy, span.ld(pb, x)), r),
        );
    }
}

/// Step 3 on one row (as the exact rows' `dual_row`).
///
/// # Safety
/// The CPU must have AVX2 and FMA.
#[target_feature(enable = "avx2,fma")]
pub(super) unsafe fn dual_row(u: FlowRow<'_>, below: FlowRow<'_>, p: DualRowMut<'_>, taut: f32) {
    let w = u.u1.len();
    let (u1, u2, u1n, u2n) = (u.u1, &u.u2[..w], &below.u1[..w], &below.u2[..w]);
    let (p11, p12, p21, p22) = (
        &mut p.p11[..w],
        &mut p.p12[..w],
        &mut p.p21[..w],
        &mut p.p22[..w],
    );
    let mut x = 0;
    while x < w {
        // The right neighbour exists for the lanes before the last column; there the
        // horizontal difference is 0.
        let (span, right) = if x + 9 <= w {
            (Span::Full, Span::Full)
        } else {
            (
                Span::Part(first_lanes(w - x)),
                Span::Part(first_lanes(w - x - 1)),
            )
        };
        let has_right = match right {
            Span::Full => _mm256_castsi256_ps(_mm256_set1_epi32(-1)),
            Span::Part(m) => _mm256_castsi256_ps(m),
        };
        let b = Block {
            x,
            span,
            right,
            has_right,
        };
        // SAFETY: this function requires AVX2 and FMA.
        unsafe {
            dual_block(b, u1, u1n, p11, p12, taut);
            dual_block(b, u2, u2n, p21, p22, taut);
        }
        x += 8;
    }
}
