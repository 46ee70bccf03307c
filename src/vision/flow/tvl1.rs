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
use super::pyramid::Level;
use super::warp::{Linearised, linearise};

/// `|grad I1w|^2` below which the data term is treated as flat (as OpenCV).
const GRAD_EPS: f32 = f32::EPSILON;

/// Which inner kernel runs (the reference exists to test the fast one).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Kernel {
    #[cfg_attr(not(test), allow(dead_code))]
    Reference,
    Fast,
}

/// Dual variables: `p1 = (p11, p12)` for `u1`, `p2 = (p21, p22)` for `u2`.
#[derive(Clone, Debug, PartialEq)]
pub(crate) struct Dual {
    pub p11: Vec<f32>,
    pub p12: Vec<f32>,
    pub p21: Vec<f32>,
    pub p22: Vec<f32>,
}

impl Dual {
    pub(crate) fn zeros(n: usize) -> Self {
        Self {
            p11: vec![0.0; n],
            p12: vec![0.0; n],
            p21: vec![0.0; n],
            p22: vec![0.0; n],
        }
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
    // 1. thresholding.
    let mut v1 = vec![0.0f32; n];
    let mut v2 = vec![0.0f32; n];
    for i in 0..n {
        let (ix, iy, g) = (lin.ix[i], lin.iy[i], lin.grad[i]);
        let rho = lin.rho_c[i] + (ix * u1[i] + iy * u2[i]);
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
            let n1 = v1[i] + s.theta * div(&p.p11, &p.p12, x, y);
            let n2 = v2[i] + s.theta * div(&p.p21, &p.p22, x, y);
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
            (p.p11[i], p.p12[i]) = dual_px(p.p11[i], p.p12[i], fx(u1), fy(u1), s.taut);
            (p.p21[i], p.p22[i]) = dual_px(p.p21[i], p.p22[i], fx(u2), fy(u2), s.taut);
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
#[derive(Debug, Default)]
pub(crate) struct FastScratch {
    /// Old `p12`, `p22` rows above each band's first row.
    above: Vec<f32>,
    /// Per-row error sums.
    row_err: Vec<f64>,
}

/// Splits the first `n` elements off `s`.
fn take_front<'a, T>(s: &mut &'a mut [T], n: usize) -> &'a mut [T] {
    let (head, tail) = std::mem::take(s).split_at_mut(n);
    *s = tail;
    head
}

fn band_rows(height: usize) -> usize {
    let tasks = 4 * rayon::current_num_threads();
    height.div_ceil(tasks).max(16)
}

fn band_dispatch(lin: &Linearised, band: Band<'_>, up: &[f32], w: usize, height: usize, s: Steps) {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") {
        // SAFETY: the CPU supports AVX2 (checked just above).
        unsafe { band_pass_avx2(lin, band, up, w, height, s) };
        return;
    }
    band_pass(lin, band, up, w, height, s);
}

/// [`band_pass`] compiled with AVX2. No FMA is enabled and Rust never contracts
/// `a * b + c`, and division and square root are correctly rounded, so the results are
/// identical to the baseline build.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn band_pass_avx2(lin: &Linearised, band: Band<'_>, up: &[f32], w: usize, height: usize, s: Steps) {
    band_pass(lin, band, up, w, height, s);
}

/// Steps 1-3 on a band of rows, the dual step one row behind; the band's last row's
/// dual step is left to the caller unless it is the image's last row.
#[inline(always)]
fn band_pass(lin: &Linearised, band: Band<'_>, up: &[f32], w: usize, height: usize, s: Steps) {
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
        let lin_row = (
            &lin.ix[i..i + w],
            &lin.iy[i..i + w],
            &lin.grad[i..i + w],
            &lin.rho_c[i..i + w],
        );
        let ups = if r == 0 {
            (&up[..w], &up[w..])
        } else {
            (
                &p12[row.start - w..row.start],
                &p22[row.start - w..row.start],
            )
        };
        primal_row(
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
        err[r] = row_sum(&e);
        if r > 0 {
            let prev = row.start - w..row.start;
            dual_row(
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
        dual_row(
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
) -> f64 {
    let w = width;
    let rows = band_rows(height);
    let nbands = height.div_ceil(rows);
    // Old dual rows above each band (zeros above the image).
    scratch.above.clear();
    scratch.above.resize(nbands * 2 * w, 0.0);
    for b in 1..nbands {
        let y = b * rows - 1;
        let dst = &mut scratch.above[b * 2 * w..(b + 1) * 2 * w];
        dst[..w].copy_from_slice(&p.p12[y * w..(y + 1) * w]);
        dst[w..].copy_from_slice(&p.p22[y * w..(y + 1) * w]);
    }
    scratch.row_err.clear();
    scratch.row_err.resize(height, 0.0);

    // Split every array into bands.
    let mut bands = Vec::with_capacity(nbands);
    {
        let (mut r1, mut r2) = (&mut u1[..], &mut u2[..]);
        let (mut q11, mut q12, mut q21, mut q22) = (
            &mut p.p11[..],
            &mut p.p12[..],
            &mut p.p21[..],
            &mut p.p22[..],
        );
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
    bands.into_par_iter().enumerate().for_each(|(b, band)| {
        let up = &above[b * 2 * w..(b + 1) * 2 * w];
        band_dispatch(lin, band, up, w, height, s);
    });
    // Deferred dual rows: the last row of every band but the last needs the next band's
    // first row of u.
    for b in 1..nbands {
        let y = b * rows - 1;
        let (cur, next) = (y * w..(y + 1) * w, (y + 1) * w..(y + 2) * w);
        dual_row(
            (&u1[cur.clone()], &u2[cur.clone()]),
            (&u1[next.clone()], &u2[next]),
            &mut p.p11[cur.clone()],
            &mut p.p12[cur.clone()],
            &mut p.p21[cur.clone()],
            &mut p.p22[cur],
            s.taut,
        );
    }
    scratch.row_err.iter().sum()
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
) {
    let (w, h) = (i0.width, i0.height);
    let n = w * h;
    let s = Steps {
        lt: params.lambda * params.theta,
        theta: params.theta,
        taut: params.tau / params.theta,
    };
    let scaled_eps = (params.epsilon as f64).powi(2) * n as f64;
    debug_assert_eq!(p.p11.len(), n);
    let mut lin = Linearised::default();
    let mut scratch = FastScratch::default();
    let mut median_scratch = Vec::new();
    let (mut t_lin, mut t_med, mut t_it, mut n_it, mut n_med) = (0.0, 0.0, 0.0, 0usize, 0usize);
    for _ in 0..plan.warps {
        let t0 = std::time::Instant::now();
        linearise(
            &i0.image,
            &i1.packed,
            u1,
            u2,
            w,
            h,
            plan.interpolation,
            &mut lin,
        );
        t_lin += t0.elapsed().as_secs_f64();
        let mut error = f64::MAX;
        let mut outer = 0;
        while error > scaled_eps && outer < params.outer_iterations {
            if plan.median_filter > 1 {
                let t0 = std::time::Instant::now();
                median_filter(u1, w, h, plan.median_filter, &mut median_scratch);
                median_filter(u2, w, h, plan.median_filter, &mut median_scratch);
                t_med += t0.elapsed().as_secs_f64();
                n_med += 1;
            }
            let t0 = std::time::Instant::now();
            let mut inner = 0;
            while error > scaled_eps && inner < plan.inner_iterations {
                error = match kernel {
                    Kernel::Fast => iterate_fast(&lin, u1, u2, p, w, h, s, &mut scratch),
                    Kernel::Reference => iterate_reference(&lin, u1, u2, p, w, h, s),
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
    use crate::vision::flow::pyramid::Level;
    use crate::vision::synthetic::{Motion, pair};

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

    #[test]
    fn fast_iteration_equals_reference() {
        let s = Steps {
            lt: 0.045,
            theta: 0.3,
            taut: 0.25 / 0.3,
        };
        for (w, h) in [(37usize, 29usize), (64, 70), (2, 2), (9, 1), (1, 7)] {
            let (lin, u1, u2) = setup(w, h);
            let (mut a1, mut a2, mut pa) = (u1.clone(), u2.clone(), Dual::zeros(w * h));
            let (mut b1, mut b2, mut pb) = (u1.clone(), u2.clone(), Dual::zeros(w * h));
            let mut scratch = FastScratch::default();
            for it in 0..6 {
                let ea = iterate_reference(&lin, &mut a1, &mut a2, &mut pa, w, h, s);
                let eb = iterate_fast(&lin, &mut b1, &mut b2, &mut pb, w, h, s, &mut scratch);
                assert_eq!(ea, eb, "{w}x{h} iteration {it}");
                assert_eq!((&a1, &a2), (&b1, &b2), "{w}x{h} iteration {it}");
                assert_eq!(pa, pb, "{w}x{h} iteration {it}");
            }
        }
    }
}
