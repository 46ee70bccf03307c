//! The warp: sample the second image and its gradient at `x + u` and linearise the data
//! term there.
//!
//! Produces, per pixel, `I1w_x`, `I1w_y`, `|grad I1w|^2` and the constant part of the
//! residual `rho_c = I1w - I1w_x u1 - I1w_y u2 - I0`, so that the inner iterations read
//! four contiguous arrays.

use rayon::prelude::*;

use super::params::Interpolation;
use super::pyramid::ROWS_PER_TASK;

/// Per-warp arrays of one level.
#[derive(Clone, Debug, Default)]
pub(crate) struct Linearised {
    pub ix: Vec<f32>,
    pub iy: Vec<f32>,
    pub grad: Vec<f32>,
    pub rho_c: Vec<f32>,
}

/// Keys cubic convolution weights (`a = -0.75`, OpenCV's `INTER_CUBIC`) for the taps at
/// offsets -1, 0, 1, 2 of a sample at fraction `t` in [0, 1).
#[inline(always)]
fn cubic_weights(t: f32) -> [f32; 4] {
    const A: f32 = -0.75;
    let near = |d: f32| ((A + 2.0) * d - (A + 3.0)) * d * d + 1.0;
    let far = |d: f32| ((A * d - 5.0 * A) * d + 8.0 * A) * d - 4.0 * A;
    let w0 = far(t + 1.0);
    let w1 = near(t);
    let w2 = near(1.0 - t);
    [w0, w1, w2, 1.0 - w0 - w1 - w2]
}

/// Integer parts (floor) and fractions of a sample position.
#[inline(always)]
fn split(sx: f32, sy: f32, width: usize, height: usize) -> (isize, isize, f32, f32) {
    // Far outside, every tap is outside anyway; clamping keeps the integer conversion in
    // range.
    let sx = sx.clamp(-4.0, width as f32 + 3.0);
    let sy = sy.clamp(-4.0, height as f32 + 3.0);
    // Truncation of a positive number is its floor (and avoids a libm call without
    // SSE4.1).
    let (ix, iy) = ((sx + 5.0) as isize - 5, (sy + 5.0) as isize - 5);
    (ix, iy, sx - ix as f32, sy - iy as f32)
}

/// Bicubic sample whose 4x4 taps all lie inside the image, the top-left one at `base`:
/// no border checks, the same arithmetic (and order) as [`sample`].
#[inline(always)]
fn bicubic_inside(
    packed: &[[f32; 4]],
    width: usize,
    base: usize,
    wx: [f32; 4],
    wy: [f32; 4],
) -> [f32; 4] {
    #[cfg(target_arch = "x86_64")]
    {
        use std::arch::x86_64::{
            __m128, _mm_add_ps, _mm_loadu_ps, _mm_mul_ps, _mm_set1_ps, _mm_setzero_ps,
            _mm_storeu_ps,
        };
        let rows: [&[[f32; 4]]; 4] = std::array::from_fn(|j| &packed[base + j * width..][..4]);
        // SAFETY: SSE is part of x86_64; every load reads a whole `[f32; 4]` of a
        // bounds-checked slice and the store writes the local `acc`.
        unsafe {
            let mut acc = _mm_setzero_ps();
            for j in 0..4 {
                let mut racc = _mm_setzero_ps();
                for k in 0..4 {
                    let p: __m128 = _mm_loadu_ps(rows[j][k].as_ptr());
                    racc = _mm_add_ps(racc, _mm_mul_ps(_mm_set1_ps(wx[k]), p));
                }
                acc = _mm_add_ps(acc, _mm_mul_ps(_mm_set1_ps(wy[j]), racc));
            }
            let mut out = [0.0f32; 4];
            _mm_storeu_ps(out.as_mut_ptr(), acc);
            out
        }
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        let mut acc = [0.0f32; 4];
        for j in 0..4 {
            let row = &packed[base + j * width..][..4];
            let mut racc = [0.0f32; 4];
            for k in 0..4 {
                let p = row[k];
                for c in 0..4 {
                    racc[c] += wx[k] * p[c];
                }
            }
            for c in 0..4 {
                acc[c] += wy[j] * racc[c];
            }
        }
        acc
    }
}

/// Bilinear sample whose 2x2 taps all lie inside the image, the top-left one at `base`:
/// no border checks, the same arithmetic (and order) as [`sample`].
#[inline(always)]
fn bilinear_inside(packed: &[[f32; 4]], width: usize, base: usize, tx: f32, ty: f32) -> [f32; 4] {
    let wx = [1.0 - tx, tx];
    let wy = [1.0 - ty, ty];
    let mut acc = [0.0f32; 4];
    for j in 0..2 {
        let row = &packed[base + j * width..][..2];
        let (a, b) = (row[0], row[1]);
        for c in 0..4 {
            acc[c] += wy[j] * (wx[0] * a[c] + wx[1] * b[c]);
        }
    }
    acc
}

/// Samples `[I, Ix, Iy, 0]` at `(sx, sy)`; taps outside the image read 0 (OpenCV
/// `remap`'s default `BORDER_CONSTANT`): where the flow points out of the second image
/// the data term fades out and the regulariser fills the flow in.
#[inline(always)]
fn sample(
    packed: &[[f32; 4]],
    width: usize,
    height: usize,
    sx: f32,
    sy: f32,
    interpolation: Interpolation,
) -> [f32; 4] {
    let (ix, iy, tx, ty) = split(sx, sy, width, height);
    let (w, h) = (width as isize, height as isize);
    let mut acc = [0.0f32; 4];
    match interpolation {
        Interpolation::Bicubic => {
            let mut wx = cubic_weights(tx);
            let mut wy = cubic_weights(ty);
            let inside = ix >= 1 && ix + 2 < w && iy >= 1 && iy + 2 < h;
            let mut cols = [0usize; 4];
            let mut rows = [0usize; 4];
            if inside {
                for k in 0..4 {
                    cols[k] = (ix - 1) as usize + k;
                    rows[k] = ((iy - 1) as usize + k) * width;
                }
            } else {
                for k in 0..4 {
                    let (c, r) = (ix - 1 + k as isize, iy - 1 + k as isize);
                    if c < 0 || c >= w {
                        wx[k] = 0.0;
                    }
                    if r < 0 || r >= h {
                        wy[k] = 0.0;
                    }
                    cols[k] = c.clamp(0, w - 1) as usize;
                    rows[k] = r.clamp(0, h - 1) as usize * width;
                }
            }
            for j in 0..4 {
                let row = &packed[rows[j]..rows[j] + width];
                let mut racc = [0.0f32; 4];
                for k in 0..4 {
                    let p = row[cols[k]];
                    for c in 0..4 {
                        racc[c] += wx[k] * p[c];
                    }
                }
                for c in 0..4 {
                    acc[c] += wy[j] * racc[c];
                }
            }
        }
        Interpolation::Bilinear => {
            let mut wx = [1.0 - tx, tx];
            let mut wy = [1.0 - ty, ty];
            let mut cols = [0usize; 2];
            let mut rows = [0usize; 2];
            for k in 0..2 {
                let (c, r) = (ix + k as isize, iy + k as isize);
                if c < 0 || c >= w {
                    wx[k] = 0.0;
                }
                if r < 0 || r >= h {
                    wy[k] = 0.0;
                }
                cols[k] = c.clamp(0, w - 1) as usize;
                rows[k] = r.clamp(0, h - 1) as usize * width;
            }
            for j in 0..2 {
                let (a, b) = (packed[rows[j] + cols[0]], packed[rows[j] + cols[1]]);
                for c in 0..4 {
                    acc[c] += wy[j] * (wx[0] * a[c] + wx[1] * b[c]);
                }
            }
        }
    }
    acc
}

/// Fills `out` for the flow `(u1, u2)` of a `width x height` level.
#[allow(clippy::too_many_arguments)]
pub(crate) fn linearise(
    i0: &[f32],
    packed1: &[[f32; 4]],
    u1: &[f32],
    u2: &[f32],
    width: usize,
    height: usize,
    interpolation: Interpolation,
    out: &mut Linearised,
) {
    let n = width * height;
    for v in [&mut out.ix, &mut out.iy, &mut out.grad, &mut out.rho_c] {
        v.resize(n, 0.0);
    }
    let chunk = width * ROWS_PER_TASK;
    let job = Job {
        i0,
        packed1,
        u1,
        u2,
        width,
        height,
        interpolation,
    };
    out.ix
        .par_chunks_mut(chunk)
        .zip(out.iy.par_chunks_mut(chunk))
        .zip(out.grad.par_chunks_mut(chunk))
        .zip(out.rho_c.par_chunks_mut(chunk))
        .enumerate()
        .for_each(|(band, (((ix, iy), grad), rho))| {
            dispatch(&job, band * chunk, [ix, iy, grad, rho]);
        });
}

/// Inputs of the linearisation.
struct Job<'a> {
    i0: &'a [f32],
    packed1: &'a [[f32; 4]],
    u1: &'a [f32],
    u2: &'a [f32],
    width: usize,
    height: usize,
    interpolation: Interpolation,
}

fn dispatch(job: &Job<'_>, start: usize, out: [&mut [f32]; 4]) {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") {
        // SAFETY: the CPU supports AVX2 (checked just above).
        unsafe { linearise_band_avx2(job, start, out) };
        return;
    }
    linearise_band(job, start, out);
}

/// [`linearise_band`] compiled with AVX2 (no FMA: identical results).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn linearise_band_avx2(job: &Job<'_>, start: usize, out: [&mut [f32]; 4]) {
    linearise_band(job, start, out);
}

#[inline(always)]
fn linearise_band(job: &Job<'_>, start: usize, [ix, iy, grad, rho]: [&mut [f32]; 4]) {
    let n = ix.len();
    let (iy, grad, rho) = (&mut iy[..n], &mut grad[..n], &mut rho[..n]);
    let (u1, u2, i0) = (
        &job.u1[start..][..n],
        &job.u2[start..][..n],
        &job.i0[start..][..n],
    );
    let w = job.width;
    let (mut x, mut y) = (start % w, start / w);
    let (wi, hi) = (w as isize, job.height as isize);
    for k in 0..n {
        let (sx, sy) = (x as f32 + u1[k], y as f32 + u2[k]);
        // Interior fast paths: integer/fraction split once, weights once for the three
        // planes, no border checks; the border goes through `sample`.
        let (fx, fy, tx, ty) = split(sx, sy, w, job.height);
        let s = match job.interpolation {
            Interpolation::Bicubic if fx >= 1 && fx + 2 < wi && fy >= 1 && fy + 2 < hi => {
                let base = (fy - 1) as usize * w + (fx - 1) as usize;
                bicubic_inside(job.packed1, w, base, cubic_weights(tx), cubic_weights(ty))
            }
            Interpolation::Bilinear if fx >= 0 && fx + 1 < wi && fy >= 0 && fy + 1 < hi => {
                bilinear_inside(job.packed1, w, fy as usize * w + fx as usize, tx, ty)
            }
            interpolation => sample(job.packed1, w, job.height, sx, sy, interpolation),
        };
        let (gx, gy) = (s[1], s[2]);
        ix[k] = gx;
        iy[k] = gy;
        grad[k] = gx * gx + gy * gy;
        rho[k] = s[0] - gx * u1[k] - gy * u2[k] - i0[k];
        x += 1;
        if x == w {
            x = 0;
            y += 1;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::vision::flow::pyramid::pack_with_gradient;

    #[test]
    fn cubic_weights_interpolate() {
        assert_eq!(cubic_weights(0.0), [0.0, 1.0, 0.0, 0.0]);
        let w = cubic_weights(0.3);
        assert!((w.iter().sum::<f32>() - 1.0).abs() < 1e-6);
        // With a = -0.75 (not -0.5) the kernel does not reproduce linear functions
        // exactly: sum w_k * (k - 1) is only close to t.
        let lin: f32 = w
            .iter()
            .enumerate()
            .map(|(k, wk)| wk * (k as f32 - 1.0))
            .sum();
        assert!((lin - 0.3).abs() < 0.05, "{lin}");
        // Symmetric: the weights at 1 - t are those at t reversed.
        let mut r = cubic_weights(0.7);
        r.reverse();
        assert!(w.iter().zip(&r).all(|(a, b)| (a - b).abs() < 1e-6));
    }

    #[test]
    fn warp_of_a_linear_image() {
        let (w, h) = (12, 10);
        let img: Vec<f32> = (0..w * h)
            .map(|i| 3.0 * (i % w) as f32 + 2.0 * (i / w) as f32)
            .collect();
        let packed = pack_with_gradient(&img, w, h);
        for interp in [Interpolation::Bicubic, Interpolation::Bilinear] {
            let s = sample(&packed, w, h, 5.25, 4.5, interp);
            // Exact for bilinear; the a = -0.75 cubic is off by a fraction of a level.
            let tol = if interp == Interpolation::Bilinear {
                1e-4
            } else {
                0.2
            };
            assert!(
                (s[0] - (3.0 * 5.25 + 2.0 * 4.5)).abs() < tol,
                "{interp:?} {s:?}"
            );
            let at_pixel = sample(&packed, w, h, 5.0, 4.0, interp);
            assert!((at_pixel[0] - img[4 * w + 5]).abs() < 1e-4);
            assert!((s[1] - 3.0).abs() < 1e-5 && (s[2] - 2.0).abs() < 1e-5);
            // Far outside: zero (constant border).
            let far = sample(&packed, w, h, -50.0, 1e9, interp);
            assert_eq!(far, [0.0; 4]);
            // Half a pixel left of the image (bilinear): half the border value.
            if interp == Interpolation::Bilinear {
                let edge = sample(&packed, w, h, -0.5, 2.0, interp);
                assert!((edge[0] - 0.5 * img[2 * w]).abs() < 1e-4);
            }
        }
    }
}
