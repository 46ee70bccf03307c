//! The inner-iteration kernels of [`super`]: the per-pixel steps, the reference pass,
//! the fused banded pass (portable rows, and AVX2 + FMA rows in [`simd`]), the paired
//! iterations. Kept in one file: the row kernels inline into the band passes.

// The kernels walk several equal-length slices in lockstep; index loops say that most
// plainly and let the compiler drop the bounds checks and vectorise.
#![allow(clippy::needless_range_loop)]

use super::*;

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
