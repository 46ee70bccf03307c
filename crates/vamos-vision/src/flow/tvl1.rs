//! The TV-L1 solver of one pyramid level (Zach, Pock, Bischof 2007; Chambolle's
//! projection for the dual variable), in the iteration order of OpenCV `DualTVL1`.
//!
//! Per warp: linearise the data term at the current flow ([`super::warp`]); then outer
//! iterations, each a median filter of the flow followed by inner iterations of
//! 1. thresholding: `v = u + TH(rho(u))` with `TH` the soft threshold at `lambda theta`,
//! 2. primal update: `u = v + theta div p`,
//! 3. dual update: `p = (p + (tau/theta) grad u) / (1 + (tau/theta) |grad u|)`
//!    (forward differences for `grad`, its negative adjoint for `div`),
//!
//! stopping when the squared update summed over the level drops below
//! `epsilon^2 * pixels`.
//!
//! Two kernels compute an inner iteration:
//! - [`iterate_reference`]: one full-image pass per step, as written above.
//! - [`iterate_fast`]: steps 1+2 and the error in one pass over a row, step 3 of the row
//!   above right after it (one-row lag), over bands of rows in parallel. The rows at band
//!   edges are exchanged through a copy of the old dual row and a short sequential pass,
//!   so every pixel sees exactly the values the reference gives it. Both kernels use the
//!   same per-pixel arithmetic and the same per-row error sums, so they agree
//!   bit-for-bit, whatever the number of bands or threads.

// The kernels walk several equal-length slices in lockstep; index loops say that most
// plainly and let the compiler drop the bounds checks and vectorise.
#![allow(clippy::needless_range_loop)]

use rayon::prelude::*;

use super::median::median_filter;
use super::params::{FlowParams, Interpolation};
use super::planes::Planes;
use super::pyramid::{Level, run_parallel};
use super::warp::{GRAD_EPS, Linearised, linearise};

/// Which inner kernel runs (the reference and the portable kernel exist to test the
/// fast one).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Kernel {
    /// One full-image pass per step, exact arithmetic.
    #[cfg_attr(not(test), allow(dead_code))]
    Reference,
    /// The fused, banded kernel with exact arithmetic: equals the reference bit-for-bit.
    #[cfg_attr(not(test), allow(dead_code))]
    Portable,
    /// The fused, banded kernel with AVX2 + FMA where the CPU has them (reciprocals and
    /// square roots by refined estimates, see [`simd`]), else [`Kernel::Portable`].
    Fast,
}

/// Dual variables: `p1 = (p11, p12)` for `u1`, `p2 = (p21, p22)` for `u2`, in that
/// order, staggered against the linearised arrays (see [`Planes`]).
#[derive(Clone, Debug, PartialEq)]
pub(crate) struct Dual {
    planes: Planes<4>,
}

/// Cache-line lead of the dual arrays: after the four linearised arrays (lead 0).
const DUAL_LEAD: usize = 4;

impl Dual {
    pub(crate) fn zeros(n: usize) -> Self {
        Self {
            planes: Planes::zeros(n, DUAL_LEAD),
        }
    }

    /// Arrays of `n` pixels, reusing the allocation; contents unspecified (callers
    /// overwrite them or [`reset`](Self::reset)).
    pub(crate) fn resize(&mut self, n: usize) {
        self.planes.resize(n);
    }

    /// Zero arrays of `n` pixels, reusing the allocation.
    pub(crate) fn reset(&mut self, n: usize) {
        self.resize(n);
        for a in self.planes.all_mut() {
            a.fill(0.0);
        }
    }

    /// Pixels per array.
    pub(crate) fn len(&self) -> usize {
        self.planes.len()
    }

    /// `[p11, p12, p21, p22]`.
    pub(crate) fn parts(&self) -> [&[f32]; 4] {
        self.planes.all()
    }

    /// `[p11, p12, p21, p22]`, mutably.
    pub(crate) fn parts_mut(&mut self) -> [&mut [f32]; 4] {
        self.planes.all_mut()
    }
}

/// Step constants of an inner iteration.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Steps {
    /// `lambda * theta`.
    pub lt: f32,
    pub theta: f32,
    /// `tau / theta`.
    pub taut: f32,
}

/// Thresholding + primal update of one pixel (branch-free form; equals the branchy
/// reference bit-for-bit). Returns the new `(u1, u2)`.
#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn primal_px(
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
pub(crate) fn iterate_reference(
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

/// Steps 1 and 2 on one row; `*_up` are the old dual rows above (zeros on row 0).
/// Leaves the squared updates in `e`.
#[allow(clippy::too_many_arguments)]
#[inline(always)]
fn primal_row(
    lin: (&[f32], &[f32], &[f32], &[f32]),
    p: (&[f32], &[f32], &[f32], &[f32]),
    (p12_up, p22_up): (&[f32], &[f32]),
    u1: &mut [f32],
    u2: &mut [f32],
    e: &mut [f32],
    s: Steps,
) {
    let w = u1.len();
    let (ix, iy, g, rc) = (&lin.0[..w], &lin.1[..w], &lin.2[..w], &lin.3[..w]);
    let (p11, p12, p21, p22) = (&p.0[..w], &p.1[..w], &p.2[..w], &p.3[..w]);
    let (p12_up, p22_up) = (&p12_up[..w], &p22_up[..w]);
    let u2 = &mut u2[..w];
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

/// Step 3 on one row; `(u1n, u2n)` are the rows below (the row itself on the last row,
/// which makes the vertical difference 0).
#[inline(always)]
fn dual_row(
    (u1, u2): (&[f32], &[f32]),
    (u1n, u2n): (&[f32], &[f32]),
    p11: &mut [f32],
    p12: &mut [f32],
    p21: &mut [f32],
    p22: &mut [f32],
    taut: f32,
) {
    let w = u1.len();
    let (u2, u1n, u2n) = (&u2[..w], &u1n[..w], &u2n[..w]);
    let (p11, p12, p21, p22) = (&mut p11[..w], &mut p12[..w], &mut p21[..w], &mut p22[..w]);
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
struct Band<'a> {
    y0: usize,
    u1: &'a mut [f32],
    u2: &'a mut [f32],
    p11: &'a mut [f32],
    p12: &'a mut [f32],
    p21: &'a mut [f32],
    p22: &'a mut [f32],
    err: &'a mut [f64],
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
fn band_rows(width: usize, height: usize) -> usize {
    if !run_parallel(width * height) {
        return height;
    }
    let tasks = 4 * rayon::current_num_threads();
    height.div_ceil(tasks).max(16)
}

/// Whether the fast kernel runs its AVX2 + FMA rows on this CPU.
fn simd_rows() -> bool {
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
trait Rows {
    /// Steps 1 and 2 on one row; returns the row's summed squared update (`e` is
    /// scratch of the row's length).
    #[allow(clippy::too_many_arguments)]
    fn primal(
        lin: (&[f32], &[f32], &[f32], &[f32]),
        p: (&[f32], &[f32], &[f32], &[f32]),
        up: (&[f32], &[f32]),
        u1: &mut [f32],
        u2: &mut [f32],
        e: &mut [f32],
        s: Steps,
    ) -> f64;
    #[allow(clippy::too_many_arguments)]
    fn dual(
        u: (&[f32], &[f32]),
        un: (&[f32], &[f32]),
        p11: &mut [f32],
        p12: &mut [f32],
        p21: &mut [f32],
        p22: &mut [f32],
        taut: f32,
    );
}

/// Exact arithmetic (as the reference).
struct ExactRows;

impl Rows for ExactRows {
    #[inline(always)]
    fn primal(
        lin: (&[f32], &[f32], &[f32], &[f32]),
        p: (&[f32], &[f32], &[f32], &[f32]),
        up: (&[f32], &[f32]),
        u1: &mut [f32],
        u2: &mut [f32],
        e: &mut [f32],
        s: Steps,
    ) -> f64 {
        primal_row(lin, p, up, u1, u2, e, s);
        row_sum(e)
    }

    #[inline(always)]
    fn dual(
        u: (&[f32], &[f32]),
        un: (&[f32], &[f32]),
        p11: &mut [f32],
        p12: &mut [f32],
        p21: &mut [f32],
        p22: &mut [f32],
        taut: f32,
    ) {
        dual_row(u, un, p11, p12, p21, p22, taut);
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
        unsafe { simd::band_pass(lin, band, up, w, height, s) };
        return;
    }
    let _ = simd;
    band_pass::<ExactRows>(lin, band, up, w, height, s);
}

/// Steps 1-3 on a band of rows, the dual step one row behind; the band's last row's
/// dual step is left to the caller unless it is the image's last row.
#[inline(always)]
fn band_pass<R: Rows>(
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
    let [lix, liy, lgrad, lrho] = lin.parts();
    let mut e = vec![0.0f32; w];
    for r in 0..h {
        let i = (y0 + r) * w;
        let row = r * w..(r + 1) * w;
        let lin_row = (
            &lix[i..i + w],
            &liy[i..i + w],
            &lgrad[i..i + w],
            &lrho[i..i + w],
        );
        let ups = if r == 0 {
            (&up[..w], &up[w..])
        } else {
            (
                &p12[row.start - w..row.start],
                &p22[row.start - w..row.start],
            )
        };
        err[r] = R::primal(
            lin_row,
            (
                &p11[row.clone()],
                &p12[row.clone()],
                &p21[row.clone()],
                &p22[row.clone()],
            ),
            ups,
            &mut u1[row.clone()],
            &mut u2[row.clone()],
            &mut e,
            s,
        );
        if r > 0 {
            let prev = row.start - w..row.start;
            R::dual(
                (&u1[prev.clone()], &u2[prev.clone()]),
                (&u1[row.clone()], &u2[row.clone()]),
                &mut p11[prev.clone()],
                &mut p12[prev.clone()],
                &mut p21[prev.clone()],
                &mut p22[prev.clone()],
                s.taut,
            );
        }
    }
    if y0 + h == height {
        let last = (h - 1) * w..h * w;
        let (a1, a2) = (u1[last.clone()].to_vec(), u2[last.clone()].to_vec());
        R::dual(
            (&a1, &a2),
            (&a1, &a2),
            &mut p11[last.clone()],
            &mut p12[last.clone()],
            &mut p21[last.clone()],
            &mut p22[last.clone()],
            s.taut,
        );
    }
}

/// Fused inner iteration; equals [`iterate_reference`] bit-for-bit.
#[allow(clippy::too_many_arguments)]
pub(crate) fn iterate_fast(
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
fn iterate_bands(
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
            (&u1[cur.clone()], &u2[cur.clone()]),
            (&u1[next.clone()], &u2[next]),
            &mut p11[cur.clone()],
            &mut p12[cur.clone()],
            &mut p21[cur.clone()],
            &mut p22[cur],
            s.taut,
        );
    }
    scratch.row_err.iter().sum()
}

/// The fast kernel runs two iterations in one pass only while the last error is above
/// this multiple of the stopping threshold: the error falls by a few percent per
/// iteration, so the first of the pair practically never meets the threshold by itself
/// (if it does, the level runs one iteration more than the reference would).
const PAIR_MARGIN: f64 = 4.0;

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
fn iterate_pair(
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
        return unsafe { simd::pair_pass(lin, u1, u2, p, (w, h), s, (zeros, e)) };
    }
    let _ = simd;
    pair_pass::<ExactRows>(lin, u1, u2, p, (w, h), s, (zeros, e))
}

/// The body of [`iterate_pair`] for one set of row kernels.
#[inline(always)]
fn pair_pass<R: Rows>(
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
    let [lix, liy, lgrad, lrho] = lin.parts();
    let [p11, p12, p21, p22] = p.parts_mut();
    // Primal step of row `y`, returning its summed squared update.
    let primal = |y: usize, u: [&mut [f32]; 2], p: [&[f32]; 4], e: &mut [f32]| {
        let r = row(y);
        let ups = if y == 0 {
            (zeros, zeros)
        } else {
            (&p[1][row(y - 1)], &p[3][row(y - 1)])
        };
        let [u1, u2] = u;
        R::primal(
            (
                &lix[r.clone()],
                &liy[r.clone()],
                &lgrad[r.clone()],
                &lrho[r.clone()],
            ),
            (
                &p[0][r.clone()],
                &p[1][r.clone()],
                &p[2][r.clone()],
                &p[3][r.clone()],
            ),
            ups,
            &mut u1[r.clone()],
            &mut u2[r],
            e,
            s,
        )
    };
    // Dual step of row `y` (the row below is `y` itself on the last row).
    let dual = |y: usize, u1: &[f32], u2: &[f32], p: [&mut [f32]; 4]| {
        let (r, rn) = (row(y), row((y + 1).min(h - 1)));
        let [p11, p12, p21, p22] = p;
        R::dual(
            (&u1[r.clone()], &u2[r.clone()]),
            (&u1[rn.clone()], &u2[rn]),
            &mut p11[r.clone()],
            &mut p12[r.clone()],
            &mut p21[r.clone()],
            &mut p22[r],
            s.taut,
        );
    };
    for t in 0..h + 2 {
        if t < h {
            primal(t, [&mut *u1, &mut *u2], [p11, p12, p21, p22], e);
        }
        if (1..=h).contains(&t) {
            dual(t - 1, u1, u2, [&mut *p11, &mut *p12, &mut *p21, &mut *p22]);
            second += primal(t - 1, [&mut *u1, &mut *u2], [p11, p12, p21, p22], e);
        }
        if (2..=h + 1).contains(&t) {
            dual(t - 2, u1, u2, [&mut *p11, &mut *p12, &mut *p21, &mut *p22]);
        }
    }
    second
}

/// [`dual_row`] with the fast kernel's arithmetic (for the deferred band-edge rows).
#[allow(clippy::too_many_arguments)]
fn dual_row_fast(
    u: (&[f32], &[f32]),
    un: (&[f32], &[f32]),
    p11: &mut [f32],
    p12: &mut [f32],
    p21: &mut [f32],
    p22: &mut [f32],
    taut: f32,
) {
    #[cfg(target_arch = "x86_64")]
    {
        // SAFETY: only called when `simd_rows()` holds (AVX2 and FMA present).
        unsafe { simd::dual_row(u, un, p11, p12, p21, p22, taut) }
    }
    #[cfg(not(target_arch = "x86_64"))]
    dual_row(u, un, p11, p12, p21, p22, taut);
}

/// The fast kernel's rows with AVX2 and FMA, eight pixels per step.
///
/// Same steps as [`primal_px`] and [`dual_px`], but no instruction of the divider:
/// reciprocals (`1 / |grad I1w|^2` in the primal step, `1 / (1 + ...)` in the dual step)
/// come from the hardware estimate and `sqrt(q)` from `q` times the estimate of
/// `1 / sqrt(q)`, each refined by one Newton step (relative error about 1e-7 instead of
/// 0.5 ulp). The division and square root units were the bottleneck of the exact
/// kernel: five divisions and two square roots per eight pixels and iteration. Row ends
/// use masked loads and stores; column 0 uses the exact per-pixel code.
#[cfg(target_arch = "x86_64")]
mod simd {
    use std::arch::x86_64::*;

    use super::{
        Band, Dual, GRAD_EPS, Linearised, Rows, Steps, band_pass as generic_band_pass,
        pair_pass as generic_pair_pass, primal_px,
    };

    /// The AVX2 + FMA rows.
    struct SimdRows;

    impl Rows for SimdRows {
        #[inline(always)]
        fn primal(
            lin: (&[f32], &[f32], &[f32], &[f32]),
            p: (&[f32], &[f32], &[f32], &[f32]),
            up: (&[f32], &[f32]),
            u1: &mut [f32],
            u2: &mut [f32],
            _e: &mut [f32],
            s: Steps,
        ) -> f64 {
            // SAFETY: `SimdRows` is only used by `band_pass` below, which requires AVX2
            // and FMA.
            unsafe { primal_row(lin, p, up, u1, u2, s) }
        }

        #[inline(always)]
        fn dual(
            u: (&[f32], &[f32]),
            un: (&[f32], &[f32]),
            p11: &mut [f32],
            p12: &mut [f32],
            p21: &mut [f32],
            p22: &mut [f32],
            taut: f32,
        ) {
            // SAFETY: as above.
            unsafe { dual_row(u, un, p11, p12, p21, p22, taut) }
        }
    }

    /// The band pass with the AVX2 + FMA rows.
    ///
    /// # Safety
    /// The CPU must have AVX2 and FMA (`simd_rows`).
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
    /// The CPU must have AVX2 and FMA (`simd_rows`).
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

    /// Steps 1 and 2 on one row (as `super::primal_row`). `|grad|^2` and its reciprocal
    /// are recomputed from `Ix`, `Iy` (cheaper than reading two more arrays: the kernel
    /// is bound by memory traffic once the divider is out of it).
    ///
    /// # Safety
    /// The CPU must have AVX2 and FMA.
    #[target_feature(enable = "avx2,fma")]
    unsafe fn primal_row(
        lin: (&[f32], &[f32], &[f32], &[f32]),
        p: (&[f32], &[f32], &[f32], &[f32]),
        (p12_up, p22_up): (&[f32], &[f32]),
        u1: &mut [f32],
        u2: &mut [f32],
        s: Steps,
    ) -> f64 {
        let w = u1.len();
        let (ix, iy, g, rc) = (&lin.0[..w], &lin.1[..w], &lin.2[..w], &lin.3[..w]);
        let (p11, p12, p21, p22) = (&p.0[..w], &p.1[..w], &p.2[..w], &p.3[..w]);
        let (p12_up, p22_up) = (&p12_up[..w], &p22_up[..w]);
        let u2 = &mut u2[..w];
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

    /// Step 3 on the pixels `x..` of `span` for one flow component.
    ///
    /// # Safety
    /// The CPU must have AVX2 and FMA (it is inlined into the `dual_row` that requires
    /// them).
    #[inline(always)]
    unsafe fn dual_block(
        span: Span,
        right: Span,
        has_right: __m256,
        (u, un): (&[f32], &[f32]),
        (pa, pb): (&mut [f32], &mut [f32]),
        x: usize,
        taut: f32,
    ) {
        // SAFETY: the caller guarantees AVX2 and FMA.
        unsafe {
            let t = _mm256_set1_ps(taut);
            let c = span.ld(u, x);
            let ux = _mm256_and_ps(has_right, _mm256_sub_ps(right.ld(u, x + 1), c));
            let uy = _mm256_sub_ps(span.ld(un, x), c);
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

    /// Step 3 on one row (as `super::dual_row`).
    ///
    /// # Safety
    /// The CPU must have AVX2 and FMA.
    #[target_feature(enable = "avx2,fma")]
    pub(super) unsafe fn dual_row(
        (u1, u2): (&[f32], &[f32]),
        (u1n, u2n): (&[f32], &[f32]),
        p11: &mut [f32],
        p12: &mut [f32],
        p21: &mut [f32],
        p22: &mut [f32],
        taut: f32,
    ) {
        let w = u1.len();
        let (u2, u1n, u2n) = (&u2[..w], &u1n[..w], &u2n[..w]);
        let (p11, p12, p21, p22) = (&mut p11[..w], &mut p12[..w], &mut p21[..w], &mut p22[..w]);
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
            // SAFETY: this function requires AVX2 and FMA.
            unsafe {
                dual_block(span, right, has_right, (u1, u1n), (p11, p12), x, taut);
                dual_block(span, right, has_right, (u2, u2n), (p21, p22), x, taut);
            }
            x += 8;
        }
    }
}

/// Buffers of the level solver, kept by the estimator from level to level and frame to
/// frame (allocating and first touching them per level cost about as much as a warp).
#[derive(Clone, Debug, Default)]
pub(crate) struct Workspace {
    lin: Linearised,
    scratch: FastScratch,
    median: Vec<f32>,
}

/// What differs between levels: the finest solved level may have its own warps,
/// iterations, interpolation and median filter (see [`FlowParams`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct LevelPlan {
    pub warps: usize,
    pub inner_iterations: usize,
    pub interpolation: Interpolation,
    pub median_filter: usize,
}

impl LevelPlan {
    /// The plan of the finest solved level (`finest`) or of a coarser one.
    pub(crate) fn new(params: &FlowParams, finest: bool) -> Self {
        let or = |v: usize, fallback: usize| if v > 0 { v } else { fallback };
        if finest {
            Self {
                warps: or(params.finest_warps, params.warps),
                inner_iterations: or(params.finest_inner_iterations, params.inner_iterations),
                interpolation: params.interpolation,
                median_filter: params.median_filter,
            }
        } else {
            Self {
                warps: params.warps,
                inner_iterations: params.inner_iterations,
                interpolation: params.coarse_interpolation.unwrap_or(params.interpolation),
                median_filter: params.coarse_median_filter.unwrap_or(params.median_filter),
            }
        }
    }
}

/// Solves one level, refining `(u1, u2)` and the dual variables `p` in place (`p` is
/// zeros for OpenCV's behaviour, or the coarser level's dual upsampled).
#[allow(clippy::too_many_arguments)]
pub(crate) fn solve_level(
    i0: &Level,
    i1: &Level,
    u1: &mut [f32],
    u2: &mut [f32],
    p: &mut Dual,
    params: &FlowParams,
    plan: LevelPlan,
    kernel: Kernel,
    work: &mut Workspace,
) {
    let (w, h) = (i0.width, i0.height);
    let n = w * h;
    let s = Steps {
        lt: params.lambda * params.theta,
        theta: params.theta,
        taut: params.tau / params.theta,
    };
    let scaled_eps = (params.epsilon as f64).powi(2) * n as f64;
    debug_assert_eq!(p.len(), n);
    let Workspace {
        lin,
        scratch,
        median: median_scratch,
    } = work;
    let simd = kernel == Kernel::Fast && simd_rows();
    let (mut t_lin, mut t_med, mut t_it, mut n_it, mut n_med) = (0.0, 0.0, 0.0, 0usize, 0usize);
    for _ in 0..plan.warps {
        let t0 = std::time::Instant::now();
        linearise(&i0.image, &i1.packed, u1, u2, w, h, plan.interpolation, lin);
        t_lin += t0.elapsed().as_secs_f64();
        let mut error = f64::MAX;
        let mut outer = 0;
        while error > scaled_eps && outer < params.outer_iterations {
            if plan.median_filter > 1 {
                let t0 = std::time::Instant::now();
                median_filter(u1, w, h, plan.median_filter, median_scratch);
                median_filter(u2, w, h, plan.median_filter, median_scratch);
                t_med += t0.elapsed().as_secs_f64();
                n_med += 1;
            }
            let t0 = std::time::Instant::now();
            let mut inner = 0;
            while error > scaled_eps && inner < plan.inner_iterations {
                // Two iterations without a stopping test between them while the first is
                // unlikely to meet epsilon (see `PAIR_MARGIN`); in one pass where the
                // level runs as one band (`iterate_pair`), else as two passes. The
                // decision does not depend on the thread count, so neither does the
                // result.
                let pair = kernel == Kernel::Fast
                    && inner + 2 <= plan.inner_iterations
                    && error > PAIR_MARGIN * scaled_eps;
                if pair {
                    error = if band_rows(w, h) >= h {
                        iterate_pair(lin, u1, u2, p, w, h, s, scratch, simd)
                    } else {
                        iterate_fast(lin, u1, u2, p, w, h, s, scratch, simd);
                        iterate_fast(lin, u1, u2, p, w, h, s, scratch, simd)
                    };
                    inner += 2;
                    n_it += 2;
                    continue;
                }
                error = match kernel {
                    Kernel::Fast => iterate_fast(lin, u1, u2, p, w, h, s, scratch, simd),
                    Kernel::Portable => iterate_fast(lin, u1, u2, p, w, h, s, scratch, false),
                    Kernel::Reference => iterate_reference(lin, u1, u2, p, w, h, s),
                };
                inner += 1;
                n_it += 1;
            }
            t_it += t0.elapsed().as_secs_f64();
            outer += 1;
        }
    }
    tracing::trace!(
        width = w,
        height = h,
        warp_ms = t_lin * 1e3,
        median_ms = t_med * 1e3,
        median_calls = n_med,
        iterate_ms = t_it * 1e3,
        iterations = n_it,
        "tv-l1 level solved"
    );
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::flow::pyramid::Level;
    use crate::synthetic::{Motion, pair};

    fn setup(w: usize, h: usize) -> (Linearised, Vec<f32>, Vec<f32>) {
        let (a, b, _) = pair(
            w,
            h,
            &Motion::Smooth {
                amplitude_px: 2.0,
                seed: 3,
            },
            11,
        );
        let (l0, l1) = (
            Level::new(a.data().to_vec(), w, h),
            Level::new(b.data().to_vec(), w, h),
        );
        let u1: Vec<f32> = (0..w * h).map(|i| 0.3 + 0.01 * (i % 7) as f32).collect();
        let u2: Vec<f32> = (0..w * h).map(|i| -0.2 + 0.02 * (i % 5) as f32).collect();
        let mut lin = Linearised::default();
        linearise(
            &l0.image,
            &l1.packed,
            &u1,
            &u2,
            w,
            h,
            Interpolation::Bicubic,
            &mut lin,
        );
        (lin, u1, u2)
    }

    /// The AVX2 + FMA rows against the reference, one iteration at a time from the same
    /// state, on widths that exercise every masked row end (1 to 8 leftover pixels).
    #[test]
    fn simd_iteration_is_close_to_reference() {
        if !simd_rows() {
            println!("no AVX2 + FMA on this CPU: the SIMD rows are not used here");
            return;
        }
        let s = Steps {
            lt: 0.045,
            theta: 0.3,
            taut: 0.25 / 0.3,
        };
        let close = |a: &[f32], b: &[f32], what: &str| {
            for (i, (x, y)) in a.iter().zip(b).enumerate() {
                assert!(
                    (x - y).abs() <= 1e-5 * (1.0 + x.abs()),
                    "{what}[{i}]: {x} vs {y}"
                );
            }
        };
        for (w, h) in [
            (1, 7),
            (2, 2),
            (9, 1),
            (10, 3),
            (16, 4),
            (17, 5),
            (37, 29),
            (64, 70),
        ] {
            let (lin, u1, u2) = setup(w, h);
            let (mut a1, mut a2, mut pa) = (u1.clone(), u2.clone(), Dual::zeros(w * h));
            let mut scratch = FastScratch::default();
            for it in 0..6 {
                // Both kernels start every iteration from the reference's state.
                let (mut b1, mut b2, mut pb) = (a1.clone(), a2.clone(), pa.clone());
                let ea = iterate_reference(&lin, &mut a1, &mut a2, &mut pa, w, h, s);
                let eb = iterate_bands(
                    &lin,
                    &mut b1,
                    &mut b2,
                    &mut pb,
                    w,
                    h,
                    s,
                    &mut scratch,
                    5,
                    true,
                );
                let at = format!("{w}x{h} iteration {it}");
                assert!(
                    (ea - eb).abs() <= 1e-4 * (1.0 + ea),
                    "{at}: error {ea} vs {eb}"
                );
                close(&a1, &b1, &format!("{at} u1"));
                close(&a2, &b2, &format!("{at} u2"));
                for ((x, y), name) in pa
                    .parts()
                    .iter()
                    .zip(pb.parts())
                    .zip(["p11", "p12", "p21", "p22"])
                {
                    close(x, y, &format!("{at} {name}"));
                }
            }
        }
    }

    /// Two iterations fused in one pass equal two separate passes, bit for bit, with
    /// either set of rows.
    #[test]
    fn paired_iterations_equal_two_passes() {
        let s = Steps {
            lt: 0.045,
            theta: 0.3,
            taut: 0.25 / 0.3,
        };
        let flags: &[bool] = if simd_rows() {
            &[false, true]
        } else {
            &[false]
        };
        for &simd in flags {
            for (w, h) in [(1, 1), (1, 7), (9, 1), (2, 2), (17, 5), (37, 29), (64, 70)] {
                let (lin, u1, u2) = setup(w, h);
                let (mut a1, mut a2, mut pa) = (u1.clone(), u2.clone(), Dual::zeros(w * h));
                let (mut b1, mut b2, mut pb) = (u1.clone(), u2.clone(), Dual::zeros(w * h));
                let mut scratch = FastScratch::default();
                for it in 0..3 {
                    let mut ea = 0.0;
                    for _ in 0..2 {
                        ea = iterate_bands(
                            &lin,
                            &mut a1,
                            &mut a2,
                            &mut pa,
                            w,
                            h,
                            s,
                            &mut scratch,
                            h,
                            simd,
                        );
                    }
                    let eb =
                        iterate_pair(&lin, &mut b1, &mut b2, &mut pb, w, h, s, &mut scratch, simd);
                    let at = format!("{w}x{h} simd {simd} pair {it}");
                    assert_eq!(ea, eb, "{at}");
                    assert_eq!((&a1, &a2), (&b1, &b2), "{at}");
                    assert_eq!(pa, pb, "{at}");
                }
            }
        }
    }

    #[test]
    fn fast_iteration_equals_reference() {
        let s = Steps {
            lt: 0.045,
            theta: 0.3,
            taut: 0.25 / 0.3,
        };
        for (w, h) in [(37usize, 29usize), (64, 70), (2, 2), (9, 1), (1, 7)] {
            let (lin, u1, u2) = setup(w, h);
            for rows in [1, 2, 5, 16, h] {
                let (mut b1, mut b2, mut pb) = (u1.clone(), u2.clone(), Dual::zeros(w * h));
                let mut scratch = FastScratch::default();
                let (mut a1, mut a2, mut pa) = (u1.clone(), u2.clone(), Dual::zeros(w * h));
                for it in 0..6 {
                    let ea = iterate_reference(&lin, &mut a1, &mut a2, &mut pa, w, h, s);
                    let eb = iterate_bands(
                        &lin,
                        &mut b1,
                        &mut b2,
                        &mut pb,
                        w,
                        h,
                        s,
                        &mut scratch,
                        rows,
                        false,
                    );
                    let at = format!("{w}x{h} bands of {rows} rows, iteration {it}");
                    assert_eq!(ea, eb, "{at}");
                    assert_eq!((&a1, &a2), (&b1, &b2), "{at}");
                    assert_eq!(pa, pb, "{at}");
                }
            }
        }
    }
}
