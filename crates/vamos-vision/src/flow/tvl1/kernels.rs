//! The inner iteration's kernels (see the [module docs](super)): the per-pixel steps, the
//! scalar reference, and the fused, banded kernel with its exact rows (the AVX2 + FMA
//! rows are in [`super::simd`]).
//!
//! A row kernel reads and writes named rows ([`LinRow`], [`DualRow`], [`DualAbove`],
//! [`FlowRow`] and their mutable forms) rather than tuples of slices, so that every call
//! says which array is which.

// The kernels walk several equal-length slices in lockstep; index loops say that most
// plainly and let the compiler drop the bounds checks and vectorise.
#![allow(clippy::needless_range_loop)]

use std::ops::Range;

use rayon::prelude::*;

use super::super::pyramid::run_parallel;
use super::super::warp::{GRAD_EPS, Linearised};
use super::{Dual, Steps};

/// One row of the linearised data term (see [`Linearised`]): the warped second image's
/// gradients, `|grad|^2` and the residual's constant part.
#[derive(Clone, Copy)]
pub(super) struct LinRow<'a> {
    pub ix: &'a [f32],
    pub iy: &'a [f32],
    pub grad: &'a [f32],
    pub rho_c: &'a [f32],
}

impl<'a> LinRow<'a> {
    /// The pixels `r` of `lin`.
    #[inline(always)]
    fn of(lin: &'a Linearised, r: Range<usize>) -> Self {
        let [ix, iy, grad, rho_c] = lin.parts();
        Self {
            ix: &ix[r.clone()],
            iy: &iy[r.clone()],
            grad: &grad[r.clone()],
            rho_c: &rho_c[r],
        }
    }
}

/// One row of the dual variables: `(p11, p12)` of `u1`, `(p21, p22)` of `u2`.
#[derive(Clone, Copy)]
pub(super) struct DualRow<'a> {
    pub p11: &'a [f32],
    pub p12: &'a [f32],
    pub p21: &'a [f32],
    pub p22: &'a [f32],
}

impl<'a> DualRow<'a> {
    /// The pixels `r` of the four arrays `[p11, p12, p21, p22]`.
    #[inline(always)]
    fn of(p: [&'a [f32]; 4], r: Range<usize>) -> Self {
        Self {
            p11: &p[0][r.clone()],
            p12: &p[1][r.clone()],
            p21: &p[2][r.clone()],
            p22: &p[3][r],
        }
    }
}

/// The vertical dual components of the row above (old values; zeros above row 0), which
/// the divergence's backward difference reads.
#[derive(Clone, Copy)]
pub(super) struct DualAbove<'a> {
    pub p12: &'a [f32],
    pub p22: &'a [f32],
}

/// One row of the dual variables, updated in place.
pub(super) struct DualRowMut<'a> {
    pub p11: &'a mut [f32],
    pub p12: &'a mut [f32],
    pub p21: &'a mut [f32],
    pub p22: &'a mut [f32],
}

impl<'a> DualRowMut<'a> {
    /// The pixels `r` of the four arrays `[p11, p12, p21, p22]`.
    #[inline(always)]
    fn of(p: [&'a mut [f32]; 4], r: Range<usize>) -> Self {
        let [p11, p12, p21, p22] = p;
        Self {
            p11: &mut p11[r.clone()],
            p12: &mut p12[r.clone()],
            p21: &mut p21[r.clone()],
            p22: &mut p22[r],
        }
    }
}

/// One row of the flow `(u1, u2)`.
#[derive(Clone, Copy)]
pub(super) struct FlowRow<'a> {
    pub u1: &'a [f32],
    pub u2: &'a [f32],
}

impl<'a> FlowRow<'a> {
    /// The pixels `r` of `u1` and `u2`.
    #[inline(always)]
    fn of(u1: &'a [f32], u2: &'a [f32], r: Range<usize>) -> Self {
        Self {
            u1: &u1[r.clone()],
            u2: &u2[r],
        }
    }
}

/// One row of the flow, updated in place.
pub(super) struct FlowRowMut<'a> {
    pub u1: &'a mut [f32],
    pub u2: &'a mut [f32],
}

impl<'a> FlowRowMut<'a> {
    /// The pixels `r` of `u1` and `u2`.
    #[inline(always)]
    fn of(u1: &'a mut [f32], u2: &'a mut [f32], r: Range<usize>) -> Self {
        Self {
            u1: &mut u1[r.clone()],
            u2: &mut u2[r],
        }
    }
}

/// Thresholding + primal update of one pixel (branch-free form; equals the branchy
/// reference bit-for-bit). Returns the new `(u1, u2)`.
#[inline(always)]
#[allow(clippy::too_many_arguments)]
pub(super) fn primal_px(
    ix: f32,
    iy: f32,
    g: f32,
    rho_c: f32,
    u1: f32,
    u2: f32,
    div1: f32,
    div2: f32,
    s: Steps,
) -> (f32, f32) {
    let rho = rho_c + (ix * u1 + iy * u2);
    let lg = s.lt * g;
    // g.max(GRAD_EPS) only guards the lanes whose result the select discards.
    let mut f = if g > GRAD_EPS {
        -rho / g.max(GRAD_EPS)
    } else {
        0.0
    };
    f = if rho < -lg { s.lt } else { f };
    f = if rho > lg { -s.lt } else { f };
    let v1 = u1 + f * ix;
    let v2 = u2 + f * iy;
    (v1 + s.theta * div1, v2 + s.theta * div2)
}

/// Dual update of one pixel for one flow component.
#[inline(always)]
fn dual_px(pa: f32, pb: f32, ux: f32, uy: f32, taut: f32) -> (f32, f32) {
    let ng = 1.0 + taut * (ux * ux + uy * uy).sqrt();
    ((pa + taut * ux) / ng, (pb + taut * uy) / ng)
}

/// Sum of a row of squared updates: 8 lanes in `f32`, combined in `f64`. Both kernels
/// use it, so their errors (and hence their stopping decisions) are identical.
#[inline(always)]
fn row_sum(e: &[f32]) -> f64 {
    let mut lanes = [0.0f32; 8];
    let chunks = e.chunks_exact(8);
    let rest = chunks.remainder();
    for c in chunks {
        for l in 0..8 {
            lanes[l] += c[l];
        }
    }
    let mut total: f64 = lanes.iter().map(|&v| v as f64).sum();
    for &v in rest {
        total += v as f64;
    }
    total
}

/// Scalar reference of one inner iteration; returns the summed squared update.
pub(super) fn iterate_reference(
    lin: &Linearised,
    u1: &mut [f32],
    u2: &mut [f32],
    p: &mut Dual,
    width: usize,
    height: usize,
    s: Steps,
) -> f64 {
    let n = width * height;
    let [lix, liy, lgrad, lrho] = lin.parts();
    let [p11, p12, p21, p22] = p.parts_mut();
    // 1. thresholding.
    let mut v1 = vec![0.0f32; n];
    let mut v2 = vec![0.0f32; n];
    for i in 0..n {
        let (ix, iy, g) = (lix[i], liy[i], lgrad[i]);
        let rho = lrho[i] + (ix * u1[i] + iy * u2[i]);
        let (d1, d2) = if rho < -s.lt * g {
            (s.lt * ix, s.lt * iy)
        } else if rho > s.lt * g {
            (-s.lt * ix, -s.lt * iy)
        } else if g > GRAD_EPS {
            let f = -rho / g;
            (f * ix, f * iy)
        } else {
            (0.0, 0.0)
        };
        v1[i] = u1[i] + d1;
        v2[i] = u2[i] + d2;
    }
    // Divergence: backward differences, p taken as 0 outside the image.
    let div = |pa: &[f32], pb: &[f32], x: usize, y: usize| {
        let i = y * width + x;
        let left = if x > 0 { pa[i - 1] } else { 0.0 };
        let up = if y > 0 { pb[i - width] } else { 0.0 };
        (pa[i] - left) + (pb[i] - up)
    };
    // 2. primal update and error.
    let mut error = 0.0f64;
    let mut e = vec![0.0f32; width];
    for y in 0..height {
        for x in 0..width {
            let i = y * width + x;
            let n1 = v1[i] + s.theta * div(p11, p12, x, y);
            let n2 = v2[i] + s.theta * div(p21, p22, x, y);
            let (d1, d2) = (n1 - u1[i], n2 - u2[i]);
            e[x] = d1 * d1 + d2 * d2;
            u1[i] = n1;
            u2[i] = n2;
        }
        error += row_sum(&e);
    }
    // 3. dual update with forward differences (0 at the last column / row).
    for y in 0..height {
        for x in 0..width {
            let i = y * width + x;
            let fx = |u: &[f32]| if x + 1 < width { u[i + 1] - u[i] } else { 0.0 };
            let fy = |u: &[f32]| {
                if y + 1 < height {
                    u[i + width] - u[i]
                } else {
                    0.0
                }
            };
            (p11[i], p12[i]) = dual_px(p11[i], p12[i], fx(u1), fy(u1), s.taut);
            (p21[i], p22[i]) = dual_px(p21[i], p22[i], fx(u2), fy(u2), s.taut);
        }
    }
    error
}

/// Steps 1 and 2 on one row (`up`: the old dual row above). Leaves the squared updates in
/// `e`.
#[inline(always)]
fn primal_row(
    lin: LinRow<'_>,
    p: DualRow<'_>,
    up: DualAbove<'_>,
    u: FlowRowMut<'_>,
    e: &mut [f32],
    s: Steps,
) {
    let w = u.u1.len();
    let (u1, u2) = (u.u1, &mut u.u2[..w]);
    let (ix, iy, g, rc) = (&lin.ix[..w], &lin.iy[..w], &lin.grad[..w], &lin.rho_c[..w]);
    let (p11, p12, p21, p22) = (&p.p11[..w], &p.p12[..w], &p.p21[..w], &p.p22[..w]);
    let (p12_up, p22_up) = (&up.p12[..w], &up.p22[..w]);
    let e = &mut e[..w];
    // Column 0: p is 0 left of the image.
    {
        let d1 = p11[0] + (p12[0] - p12_up[0]);
        let d2 = p21[0] + (p22[0] - p22_up[0]);
        let (n1, n2) = primal_px(ix[0], iy[0], g[0], rc[0], u1[0], u2[0], d1, d2, s);
        let (a, b) = (n1 - u1[0], n2 - u2[0]);
        e[0] = a * a + b * b;
        u1[0] = n1;
        u2[0] = n2;
    }
    let m = w - 1;
    // Shifted views so that every index below is in bounds by construction.
    let (ix, iy, g, rc) = (&ix[1..][..m], &iy[1..][..m], &g[1..][..m], &rc[1..][..m]);
    let (p11l, p21l) = (&p11[..m], &p21[..m]);
    let (p11, p12, p21, p22) = (
        &p11[1..][..m],
        &p12[1..][..m],
        &p21[1..][..m],
        &p22[1..][..m],
    );
    let (p12_up, p22_up) = (&p12_up[1..][..m], &p22_up[1..][..m]);
    let u1 = &mut u1[1..][..m];
    let u2 = &mut u2[1..][..m];
    let e = &mut e[1..][..m];
    for x in 0..m {
        let d1 = (p11[x] - p11l[x]) + (p12[x] - p12_up[x]);
        let d2 = (p21[x] - p21l[x]) + (p22[x] - p22_up[x]);
        let (n1, n2) = primal_px(ix[x], iy[x], g[x], rc[x], u1[x], u2[x], d1, d2, s);
        let (a, b) = (n1 - u1[x], n2 - u2[x]);
        e[x] = a * a + b * b;
        u1[x] = n1;
        u2[x] = n2;
    }
}

/// Step 3 on one row; `below` is the flow row below (the row itself on the last row,
/// which makes the vertical difference 0).
#[inline(always)]
fn dual_row(u: FlowRow<'_>, below: FlowRow<'_>, p: DualRowMut<'_>, taut: f32) {
    let w = u.u1.len();
    let (u1, u2, u1n, u2n) = (u.u1, &u.u2[..w], &below.u1[..w], &below.u2[..w]);
    let (p11, p12, p21, p22) = (
        &mut p.p11[..w],
        &mut p.p12[..w],
        &mut p.p21[..w],
        &mut p.p22[..w],
    );
    let m = w - 1;
    for x in 0..m {
        let (a, b) = dual_px(p11[x], p12[x], u1[x + 1] - u1[x], u1n[x] - u1[x], taut);
        p11[x] = a;
        p12[x] = b;
        let (a, b) = dual_px(p21[x], p22[x], u2[x + 1] - u2[x], u2n[x] - u2[x], taut);
        p21[x] = a;
        p22[x] = b;
    }
    (p11[m], p12[m]) = dual_px(p11[m], p12[m], 0.0, u1n[m] - u1[m], taut);
    (p21[m], p22[m]) = dual_px(p21[m], p22[m], 0.0, u2n[m] - u2[m], taut);
}

/// Mutable rows `[y0, y1)` of the iterated arrays.
pub(super) struct Band<'a> {
    pub y0: usize,
    pub u1: &'a mut [f32],
    pub u2: &'a mut [f32],
    pub p11: &'a mut [f32],
    pub p12: &'a mut [f32],
    pub p21: &'a mut [f32],
    pub p22: &'a mut [f32],
    pub err: &'a mut [f64],
}

/// Scratch of the fast kernel, reused across iterations.
#[derive(Clone, Debug, Default)]
pub(crate) struct FastScratch {
    /// Old `p12`, `p22` rows above each band's first row.
    above: Vec<f32>,
    /// Per-row error sums.
    row_err: Vec<f64>,
    /// A row of zeros (the dual above row 0) and a row of squared updates, for
    /// [`iterate_pair`].
    zeros: Vec<f32>,
    row: Vec<f32>,
}

/// Splits the first `n` elements off `s`.
fn take_front<'a, T>(s: &mut &'a mut [T], n: usize) -> &'a mut [T] {
    let (head, tail) = std::mem::take(s).split_at_mut(n);
    *s = tail;
    head
}

/// Rows per band: the whole image when the iteration runs on the calling thread.
pub(super) fn band_rows(width: usize, height: usize) -> usize {
    if !run_parallel(width * height) {
        return height;
    }
    let tasks = 4 * rayon::current_num_threads();
    height.div_ceil(tasks).max(16)
}

/// Whether the fast kernel runs its AVX2 + FMA rows on this CPU.
pub(super) fn simd_rows() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma")
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

/// Row kernels of a band pass.
pub(super) trait Rows {
    /// Steps 1 and 2 on one row; returns the row's summed squared update (`e` is
    /// scratch of the row's length).
    fn primal(
        lin: LinRow<'_>,
        p: DualRow<'_>,
        up: DualAbove<'_>,
        u: FlowRowMut<'_>,
        e: &mut [f32],
        s: Steps,
    ) -> f64;
    /// Step 3 on one row (`below`: the flow row below, the row itself on the last row).
    fn dual(u: FlowRow<'_>, below: FlowRow<'_>, p: DualRowMut<'_>, taut: f32);
}

/// Exact arithmetic (as the reference).
struct ExactRows;

impl Rows for ExactRows {
    #[inline(always)]
    fn primal(
        lin: LinRow<'_>,
        p: DualRow<'_>,
        up: DualAbove<'_>,
        u: FlowRowMut<'_>,
        e: &mut [f32],
        s: Steps,
    ) -> f64 {
        primal_row(lin, p, up, u, e, s);
        row_sum(e)
    }

    #[inline(always)]
    fn dual(u: FlowRow<'_>, below: FlowRow<'_>, p: DualRowMut<'_>, taut: f32) {
        dual_row(u, below, p, taut);
    }
}

#[allow(clippy::too_many_arguments)]
fn band_dispatch(
    lin: &Linearised,
    band: Band<'_>,
    up: &[f32],
    w: usize,
    height: usize,
    s: Steps,
    simd: bool,
) {
    #[cfg(target_arch = "x86_64")]
    if simd {
        // SAFETY: `simd` is only set where the CPU has AVX2 and FMA (`simd_rows`).
        unsafe { super::simd::band_pass(lin, band, up, w, height, s) };
        return;
    }
    let _ = simd;
    band_pass::<ExactRows>(lin, band, up, w, height, s);
}

/// Steps 1-3 on a band of rows, the dual step one row behind; the band's last row's
/// dual step is left to the caller unless it is the image's last row. `up` holds the old
/// `p12` and `p22` rows above the band.
#[inline(always)]
pub(super) fn band_pass<R: Rows>(
    lin: &Linearised,
    band: Band<'_>,
    up: &[f32],
    w: usize,
    height: usize,
    s: Steps,
) {
    let Band {
        y0,
        u1,
        u2,
        p11,
        p12,
        p21,
        p22,
        err,
    } = band;
    let h = err.len();
    let mut e = vec![0.0f32; w];
    for r in 0..h {
        let i = (y0 + r) * w;
        let row = r * w..(r + 1) * w;
        let above = if r == 0 {
            DualAbove {
                p12: &up[..w],
                p22: &up[w..],
            }
        } else {
            let prev = row.start - w..row.start;
            DualAbove {
                p12: &p12[prev.clone()],
                p22: &p22[prev],
            }
        };
        err[r] = R::primal(
            LinRow::of(lin, i..i + w),
            DualRow::of([p11, p12, p21, p22], row.clone()),
            above,
            FlowRowMut::of(u1, u2, row.clone()),
            &mut e,
            s,
        );
        if r > 0 {
            let prev = row.start - w..row.start;
            R::dual(
                FlowRow::of(u1, u2, prev.clone()),
                FlowRow::of(u1, u2, row),
                DualRowMut::of([&mut *p11, &mut *p12, &mut *p21, &mut *p22], prev),
                s.taut,
            );
        }
    }
    if y0 + h == height {
        let last = (h - 1) * w..h * w;
        let (a1, a2) = (u1[last.clone()].to_vec(), u2[last.clone()].to_vec());
        let this = FlowRow { u1: &a1, u2: &a2 };
        R::dual(
            this,
            this,
            DualRowMut::of([p11, p12, p21, p22], last),
            s.taut,
        );
    }
}

/// Fused inner iteration; equals [`iterate_reference`] bit-for-bit.
#[allow(clippy::too_many_arguments)]
pub(super) fn iterate_fast(
    lin: &Linearised,
    u1: &mut [f32],
    u2: &mut [f32],
    p: &mut Dual,
    width: usize,
    height: usize,
    s: Steps,
    scratch: &mut FastScratch,
    simd: bool,
) -> f64 {
    let rows = band_rows(width, height);
    iterate_bands(lin, u1, u2, p, width, height, s, scratch, rows, simd)
}

/// [`iterate_fast`] on bands of `rows` rows (the last one may be shorter); the result does
/// not depend on `rows`.
#[allow(clippy::too_many_arguments)]
pub(super) fn iterate_bands(
    lin: &Linearised,
    u1: &mut [f32],
    u2: &mut [f32],
    p: &mut Dual,
    width: usize,
    height: usize,
    s: Steps,
    scratch: &mut FastScratch,
    rows: usize,
    simd: bool,
) -> f64 {
    let w = width;
    let nbands = height.div_ceil(rows);
    // Old dual rows above each band (zeros above the image).
    scratch.above.clear();
    scratch.above.resize(nbands * 2 * w, 0.0);
    for b in 1..nbands {
        let y = b * rows - 1;
        let dst = &mut scratch.above[b * 2 * w..(b + 1) * 2 * w];
        dst[..w].copy_from_slice(&p.parts()[1][y * w..(y + 1) * w]);
        dst[w..].copy_from_slice(&p.parts()[3][y * w..(y + 1) * w]);
    }
    scratch.row_err.clear();
    scratch.row_err.resize(height, 0.0);

    // Split every array into bands.
    let mut bands = Vec::with_capacity(nbands);
    {
        let (mut r1, mut r2) = (&mut u1[..], &mut u2[..]);
        let [mut q11, mut q12, mut q21, mut q22] = p.parts_mut();
        let mut re = &mut scratch.row_err[..];
        for b in 0..nbands {
            let y0 = b * rows;
            let h = rows.min(height - y0);
            let n = h * w;
            bands.push(Band {
                y0,
                u1: take_front(&mut r1, n),
                u2: take_front(&mut r2, n),
                p11: take_front(&mut q11, n),
                p12: take_front(&mut q12, n),
                p21: take_front(&mut q21, n),
                p22: take_front(&mut q22, n),
                err: take_front(&mut re, h),
            });
        }
    }
    let above = &scratch.above;
    let run = |(b, band): (usize, Band<'_>)| {
        let up = &above[b * 2 * w..(b + 1) * 2 * w];
        band_dispatch(lin, band, up, w, height, s, simd);
    };
    if nbands > 1 {
        bands.into_par_iter().enumerate().for_each(run);
    } else {
        bands.into_iter().enumerate().for_each(run);
    }
    // Deferred dual rows: the last row of every band but the last needs the next band's
    // first row of u.
    let [p11, p12, p21, p22] = p.parts_mut();
    for b in 1..nbands {
        let y = b * rows - 1;
        let (cur, next) = (y * w..(y + 1) * w, (y + 1) * w..(y + 2) * w);
        let deferred = if simd { dual_row_fast } else { dual_row };
        deferred(
            FlowRow::of(u1, u2, cur.clone()),
            FlowRow::of(u1, u2, next),
            DualRowMut::of([&mut *p11, &mut *p12, &mut *p21, &mut *p22], cur),
            s.taut,
        );
    }
    scratch.row_err.iter().sum()
}

/// The fast kernel runs two iterations in one pass only while the last error is above
/// this multiple of the stopping threshold: the error falls by a few percent per
/// iteration, so the first of the pair practically never meets the threshold by itself
/// (if it does, the level runs one iteration more than the reference would).
pub(super) const PAIR_MARGIN: f64 = 4.0;

/// Two inner iterations in one pass over the image, the second two rows behind the first
/// (temporal blocking): every row is loaded from memory once for both, which halves the
/// traffic that bounds the kernel once a level outgrows the L2 cache (320x240 and up).
/// Per step `t`: primal of row `t` and dual of row `t - 1` of the first iteration, then
/// primal of row `t - 1` and dual of row `t - 2` of the second. Every row sees exactly
/// the values it would see in two separate passes (the second iteration reads a dual row
/// only after the first has updated it, and overwrites a flow row only after the first
/// has used it), so the result equals two calls of [`iterate_fast`] with the same rows.
/// Returns the second iteration's summed squared update. The whole image is one band
/// (used where [`band_rows`] gives one).
#[allow(clippy::too_many_arguments)]
pub(super) fn iterate_pair(
    lin: &Linearised,
    u1: &mut [f32],
    u2: &mut [f32],
    p: &mut Dual,
    w: usize,
    h: usize,
    s: Steps,
    scratch: &mut FastScratch,
    simd: bool,
) -> f64 {
    scratch.zeros.clear();
    scratch.zeros.resize(w, 0.0);
    scratch.row.resize(w, 0.0);
    let (zeros, e) = (&scratch.zeros[..], &mut scratch.row[..]);
    #[cfg(target_arch = "x86_64")]
    if simd {
        // SAFETY: `simd` is only set where the CPU has AVX2 and FMA (`simd_rows`).
        return unsafe { super::simd::pair_pass(lin, u1, u2, p, (w, h), s, (zeros, e)) };
    }
    let _ = simd;
    pair_pass::<ExactRows>(lin, u1, u2, p, (w, h), s, (zeros, e))
}

/// The body of [`iterate_pair`] for one set of row kernels.
#[inline(always)]
pub(super) fn pair_pass<R: Rows>(
    lin: &Linearised,
    u1: &mut [f32],
    u2: &mut [f32],
    p: &mut Dual,
    (w, h): (usize, usize),
    s: Steps,
    (zeros, e): (&[f32], &mut [f32]),
) -> f64 {
    let mut second = 0.0f64;
    let row = |y: usize| y * w..(y + 1) * w;
    let [p11, p12, p21, p22] = p.parts_mut();
    // Primal step of row `y`, returning its summed squared update.
    let primal = |y: usize, u1: &mut [f32], u2: &mut [f32], p: [&[f32]; 4], e: &mut [f32]| {
        let above = if y == 0 {
            DualAbove {
                p12: zeros,
                p22: zeros,
            }
        } else {
            DualAbove {
                p12: &p[1][row(y - 1)],
                p22: &p[3][row(y - 1)],
            }
        };
        R::primal(
            LinRow::of(lin, row(y)),
            DualRow::of(p, row(y)),
            above,
            FlowRowMut::of(u1, u2, row(y)),
            e,
            s,
        )
    };
    // Dual step of row `y` (the row below is `y` itself on the last row).
    let dual = |y: usize, u1: &[f32], u2: &[f32], p: [&mut [f32]; 4]| {
        R::dual(
            FlowRow::of(u1, u2, row(y)),
            FlowRow::of(u1, u2, row((y + 1).min(h - 1))),
            DualRowMut::of(p, row(y)),
            s.taut,
        );
    };
    for t in 0..h + 2 {
        if t < h {
            primal(t, u1, u2, [p11, p12, p21, p22], e);
        }
        if (1..=h).contains(&t) {
            dual(t - 1, u1, u2, [&mut *p11, &mut *p12, &mut *p21, &mut *p22]);
            second += primal(t - 1, u1, u2, [p11, p12, p21, p22], e);
        }
        if (2..=h + 1).contains(&t) {
            dual(t - 2, u1, u2, [&mut *p11, &mut *p12, &mut *p21, &mut *p22]);
        }
    }
    second
}

/// [`dual_row`] with the fast kernel's arithmetic (for the deferred band-edge rows).
fn dual_row_fast(u: FlowRow<'_>, below: FlowRow<'_>, p: DualRowMut<'_>, taut: f32) {
    #[cfg(target_arch = "x86_64")]
    {
        // SAFETY: only called when `simd_rows()` holds (AVX2 and FMA present).
        unsafe { super::simd::dual_row(u, below, p, taut) }
    }
    #[cfg(not(target_arch = "x86_64"))]
    dual_row(u, below, p, taut);
}
