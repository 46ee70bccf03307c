//! The warp: sample the second image and its gradient at `x + u` and linearise the data
//! term there.
//!
//! Produces, per pixel, `I1w_x`, `I1w_y`, `|grad I1w|^2` and the constant part of the
//! residual `rho_c = I1w - I1w_x u1 - I1w_y u2 - I0`, so that the inner iterations read
//! four contiguous arrays.

use rayon::prelude::*;

use super::params::Interpolation;
use super::planes::Planes;
use super::pyramid::{ROWS_PER_TASK, run_parallel};

/// `|grad I1w|^2` below which the data term is treated as flat (as OpenCV).
pub(crate) const GRAD_EPS: f32 = f32::EPSILON;

/// Per-warp arrays of one level: `[Ix, Iy, |grad|^2, rho_c]`, staggered (see
/// [`Planes`]; lead 0, the dual arrays follow them).
#[derive(Clone, Debug, Default)]
pub(crate) struct Linearised {
    planes: Planes<4>,
}

impl Linearised {
    /// `[Ix, Iy, |grad|^2, rho_c]`.
    pub(crate) fn parts(&self) -> [&[f32]; 4] {
        self.planes.all()
    }
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
    out.planes.resize(n);
    let [out_ix, out_iy, out_grad, out_rho] = out.planes.all_mut();
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
    let run = |(band, (((ix, iy), grad), rho)): Bands<'_>| {
        dispatch(&job, band * chunk, [ix, iy, grad, rho]);
    };
    if run_parallel(n) {
        out_ix
            .par_chunks_mut(chunk)
            .zip(out_iy.par_chunks_mut(chunk))
            .zip(out_grad.par_chunks_mut(chunk))
            .zip(out_rho.par_chunks_mut(chunk))
            .enumerate()
            .for_each(run);
    } else {
        out_ix
            .chunks_mut(chunk)
            .zip(out_iy.chunks_mut(chunk))
            .zip(out_grad.chunks_mut(chunk))
            .zip(out_rho.chunks_mut(chunk))
            .enumerate()
            .for_each(run);
    }
}

/// One band of the four output arrays, numbered.
type Bands<'a> = (
    usize,
    (
        ((&'a mut [f32], &'a mut [f32]), &'a mut [f32]),
        &'a mut [f32],
    ),
);

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
    if std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma") {
        // SAFETY: the CPU supports AVX2 and FMA (checked just above).
        unsafe { simd::linearise_band(job, start, out) };
        return;
    }
    linearise_band(job, start, out);
}

/// One pixel of the linearisation at `(x, y)` (index `k` of the level): `[Ix, Iy,
/// |grad|^2, rho_c]`.
#[inline(always)]
fn linearise_px(job: &Job<'_>, k: usize, x: usize, y: usize) -> [f32; 4] {
    let (u1, u2) = (job.u1[k], job.u2[k]);
    let (sx, sy) = (x as f32 + u1, y as f32 + u2);
    let (w, h) = (job.width, job.height);
    let (wi, hi) = (w as isize, h as isize);
    // Interior fast paths: integer/fraction split once, weights once for the three
    // planes, no border checks; the border goes through `sample`.
    let (fx, fy, tx, ty) = split(sx, sy, w, h);
    let s = match job.interpolation {
        Interpolation::Bicubic if fx >= 1 && fx + 2 < wi && fy >= 1 && fy + 2 < hi => {
            let base = (fy - 1) as usize * w + (fx - 1) as usize;
            bicubic_inside(job.packed1, w, base, cubic_weights(tx), cubic_weights(ty))
        }
        Interpolation::Bilinear if fx >= 0 && fx + 1 < wi && fy >= 0 && fy + 1 < hi => {
            bilinear_inside(job.packed1, w, fy as usize * w + fx as usize, tx, ty)
        }
        interpolation => sample(job.packed1, w, h, sx, sy, interpolation),
    };
    let (gx, gy) = (s[1], s[2]);
    [
        gx,
        gy,
        gx * gx + gy * gy,
        s[0] - gx * u1 - gy * u2 - job.i0[k],
    ]
}

/// The portable linearisation of the pixels `start..start + ix.len()`.
fn linearise_band(job: &Job<'_>, start: usize, [ix, iy, grad, rho]: [&mut [f32]; 4]) {
    let n = ix.len();
    let (iy, grad, rho) = (&mut iy[..n], &mut grad[..n], &mut rho[..n]);
    let w = job.width;
    let (mut x, mut y) = (start % w, start / w);
    for k in 0..n {
        [ix[k], iy[k], grad[k], rho[k]] = linearise_px(job, start + k, x, y);
        x += 1;
        if x == w {
            x = 0;
            y += 1;
        }
    }
}

/// The linearisation eight pixels at a time with AVX2 and FMA: positions, the integer /
/// fraction split and the cubic weights are computed for eight pixels at once, the 4x4
/// taps of one pixel as two 8-wide products per row (two `[I, Ix, Iy, 0]` taps per
/// register), and the outputs for eight pixels at once. Blocks with a tap outside the
/// image, a non-finite position or bilinear interpolation go through [`linearise_px`].
/// FMA rounds differently from the portable path, so results differ from it in the last
/// bits (the tests bound the difference).
#[cfg(target_arch = "x86_64")]
mod simd {
    use std::arch::x86_64::*;

    use super::{Interpolation, Job, linearise_px};

    const A: f32 = -0.75;

    /// Keys kernel for `|d| <= 1`.
    #[inline]
    #[target_feature(enable = "avx2,fma")]
    fn near(d: __m256) -> __m256 {
        let a = _mm256_fmsub_ps(_mm256_set1_ps(A + 2.0), d, _mm256_set1_ps(A + 3.0));
        _mm256_fmadd_ps(_mm256_mul_ps(a, d), d, _mm256_set1_ps(1.0))
    }

    /// Keys kernel for `1 <= |d| <= 2`.
    #[inline]
    #[target_feature(enable = "avx2,fma")]
    fn far(d: __m256) -> __m256 {
        let a = _mm256_fmsub_ps(_mm256_set1_ps(A), d, _mm256_set1_ps(5.0 * A));
        let b = _mm256_fmadd_ps(a, d, _mm256_set1_ps(8.0 * A));
        _mm256_fmsub_ps(b, d, _mm256_set1_ps(4.0 * A))
    }

    /// Keys weights of the taps at -1, 0, 1, 2 for fractions `t` (as `cubic_weights`),
    /// as lanes.
    #[inline]
    #[target_feature(enable = "avx2,fma")]
    fn weights(t: __m256) -> [[f32; 8]; 4] {
        let one = _mm256_set1_ps(1.0);
        let w0 = far(_mm256_add_ps(t, one));
        let w1 = near(t);
        let w2 = near(_mm256_sub_ps(one, t));
        let w3 = _mm256_sub_ps(_mm256_sub_ps(_mm256_sub_ps(one, w0), w1), w2);
        [w0, w1, w2, w3].map(|v| {
            let mut out = [0.0f32; 8];
            // SAFETY: writes eight lanes to the local array of eight.
            unsafe { _mm256_storeu_ps(out.as_mut_ptr(), v) };
            out
        })
    }

    /// The first eight values of `v`.
    #[inline]
    #[target_feature(enable = "avx2,fma")]
    fn load8(v: &[f32]) -> __m256 {
        let v = &v[..8];
        // SAFETY: `v` holds eight values (the slicing above checks it).
        unsafe { _mm256_loadu_ps(v.as_ptr()) }
    }

    #[target_feature(enable = "avx2,fma")]
    pub(super) unsafe fn linearise_band(
        job: &Job<'_>,
        start: usize,
        [ix, iy, grad, rho]: [&mut [f32]; 4],
    ) {
        let n = ix.len();
        let (iy, grad, rho) = (&mut iy[..n], &mut grad[..n], &mut rho[..n]);
        let (w, h) = (job.width, job.height);
        let packed = job.packed1;
        // The unchecked tap loads below rely on this.
        assert!(packed.len() >= w * h && job.u1.len() >= start + n && job.i0.len() >= start + n);
        let bicubic = job.interpolation == Interpolation::Bicubic;
        let offsets = _mm256_setr_ps(0.0, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0);
        let (lo, hi_x, hi_y) = (
            _mm256_set1_ps(1.0),
            _mm256_set1_ps(w as f32 - 3.0),
            _mm256_set1_ps(h as f32 - 3.0),
        );
        let mut k = 0;
        while k < n {
            let (x, y) = ((start + k) % w, (start + k) / w);
            let g = start + k;
            // A block of eight pixels of one row.
            if bicubic && x + 8 <= w && k + 8 <= n {
                let u1 = load8(&job.u1[g..]);
                let u2 = load8(&job.u2[g..]);
                let sx = _mm256_add_ps(_mm256_add_ps(_mm256_set1_ps(x as f32), offsets), u1);
                let sy = _mm256_add_ps(_mm256_set1_ps(y as f32), u2);
                let (fx, fy) = (_mm256_floor_ps(sx), _mm256_floor_ps(sy));
                // All taps inside: 1 <= floor <= size - 3 (false for NaN).
                let inside = _mm256_and_ps(
                    _mm256_and_ps(
                        _mm256_cmp_ps::<_CMP_GE_OQ>(fx, lo),
                        _mm256_cmp_ps::<_CMP_LE_OQ>(fx, hi_x),
                    ),
                    _mm256_and_ps(
                        _mm256_cmp_ps::<_CMP_GE_OQ>(fy, lo),
                        _mm256_cmp_ps::<_CMP_LE_OQ>(fy, hi_y),
                    ),
                );
                if _mm256_movemask_ps(inside) == 0xff {
                    let wx = weights(_mm256_sub_ps(sx, fx));
                    let wy = weights(_mm256_sub_ps(sy, fy));
                    // Index of the top-left tap, exact in i32 (checked above).
                    let base = _mm256_add_epi32(
                        _mm256_mullo_epi32(
                            _mm256_cvttps_epi32(_mm256_sub_ps(fy, lo)),
                            _mm256_set1_epi32(w as i32),
                        ),
                        _mm256_cvttps_epi32(_mm256_sub_ps(fx, lo)),
                    );
                    let mut bases = [0i32; 8];
                    // SAFETY: eight i32 lanes into the local array of eight.
                    unsafe { _mm256_storeu_si256(bases.as_mut_ptr().cast(), base) };
                    let taps = packed.as_ptr().cast::<f32>();
                    let mut px = [_mm_setzero_ps(); 8];
                    for l in 0..8 {
                        let w01 = _mm256_set_m128(_mm_set1_ps(wx[1][l]), _mm_set1_ps(wx[0][l]));
                        let w23 = _mm256_set_m128(_mm_set1_ps(wx[3][l]), _mm_set1_ps(wx[2][l]));
                        let mut acc = _mm256_setzero_ps();
                        for (j, wyj) in wy.iter().enumerate() {
                            // SAFETY: the inside test puts the 4x4 taps, `base + j * w +
                            // 0..4` for j in 0..4, inside the `w * h` packed pixels.
                            let row = unsafe { taps.add((bases[l] as usize + j * w) * 4) };
                            // SAFETY: 16 floats from `row`: the 4 taps of 4 floats above.
                            let (a, b) =
                                unsafe { (_mm256_loadu_ps(row), _mm256_loadu_ps(row.add(8))) };
                            let r = _mm256_fmadd_ps(b, w23, _mm256_mul_ps(a, w01));
                            acc = _mm256_fmadd_ps(_mm256_set1_ps(wyj[l]), r, acc);
                        }
                        px[l] = _mm_add_ps(
                            _mm256_castps256_ps128(acc),
                            _mm256_extractf128_ps::<1>(acc),
                        );
                    }
                    // Transpose eight [I, Ix, Iy, 0] into I, Ix, Iy registers.
                    let r0 = _mm256_set_m128(px[4], px[0]);
                    let r1 = _mm256_set_m128(px[5], px[1]);
                    let r2 = _mm256_set_m128(px[6], px[2]);
                    let r3 = _mm256_set_m128(px[7], px[3]);
                    let (t0, t1) = (_mm256_unpacklo_ps(r0, r1), _mm256_unpackhi_ps(r0, r1));
                    let (t2, t3) = (_mm256_unpacklo_ps(r2, r3), _mm256_unpackhi_ps(r2, r3));
                    let i1 = _mm256_shuffle_ps::<0x44>(t0, t2);
                    let gx = _mm256_shuffle_ps::<0xEE>(t0, t2);
                    let gy = _mm256_shuffle_ps::<0x44>(t1, t3);
                    let i0 = load8(&job.i0[g..]);
                    let gg = _mm256_fmadd_ps(gy, gy, _mm256_mul_ps(gx, gx));
                    let r =
                        _mm256_sub_ps(_mm256_fnmadd_ps(gy, u2, _mm256_fnmadd_ps(gx, u1, i1)), i0);
                    // SAFETY: each slice `[k..k + 8]` is bounds-checked to eight floats.
                    unsafe {
                        _mm256_storeu_ps(ix[k..k + 8].as_mut_ptr(), gx);
                        _mm256_storeu_ps(iy[k..k + 8].as_mut_ptr(), gy);
                        _mm256_storeu_ps(grad[k..k + 8].as_mut_ptr(), gg);
                        _mm256_storeu_ps(rho[k..k + 8].as_mut_ptr(), r);
                    }
                    k += 8;
                    continue;
                }
            }
            // One pixel (row tails, blocks near the border, bilinear).
            let end = if bicubic && x + 8 <= w { 8 } else { 1 }.min(n - k);
            for d in 0..end {
                let (x, y) = ((g + d) % w, (g + d) / w);
                [ix[k + d], iy[k + d], grad[k + d], rho[k + d]] = linearise_px(job, g + d, x, y);
            }
            k += end;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::flow::pyramid::pack_with_gradient;

    /// The AVX2 + FMA linearisation against the portable one, on a flow that sends
    /// pixels inside, across the border and far outside the image.
    #[test]
    fn simd_linearisation_is_close_to_portable() {
        let (w, h) = (37, 23);
        let img: Vec<f32> = (0..w * h)
            .map(|i| {
                let (x, y) = ((i % w) as f32, (i / w) as f32);
                100.0 + 60.0 * (0.37 * x).sin() * (0.23 * y).cos() + 0.5 * x
            })
            .collect();
        let packed = pack_with_gradient(&img, w, h);
        let i0: Vec<f32> = img.iter().map(|v| v * 0.9 + 3.0).collect();
        let u1: Vec<f32> = (0..w * h)
            .map(|i| {
                3.0 * ((i * 7919 % 113) as f32 / 113.0 - 0.5) + if i % 97 == 0 { 60.0 } else { 0.0 }
            })
            .collect();
        let u2: Vec<f32> = (0..w * h)
            .map(|i| 2.5 * ((i * 104729 % 89) as f32 / 89.0 - 0.5))
            .collect();
        for interpolation in [Interpolation::Bicubic, Interpolation::Bilinear] {
            let job = Job {
                i0: &i0,
                packed1: &packed,
                u1: &u1,
                u2: &u2,
                width: w,
                height: h,
                interpolation,
            };
            let mut a = vec![vec![0.0f32; w * h]; 4];
            let mut b = vec![vec![0.0f32; w * h]; 4];
            {
                let [x0, x1, x2, x3] = &mut a[..] else {
                    unreachable!()
                };
                linearise_band(&job, 0, [x0, x1, x2, x3]);
            }
            {
                let [x0, x1, x2, x3] = &mut b[..] else {
                    unreachable!()
                };
                dispatch(&job, 0, [x0, x1, x2, x3]);
            }
            for (k, (ra, rb)) in a.iter().zip(&b).enumerate() {
                for (i, (x, y)) in ra.iter().zip(rb).enumerate() {
                    assert!(
                        (x - y).abs() <= 1e-3 * (1.0 + x.abs()),
                        "{interpolation:?} output {k} pixel {i}: {x} vs {y}"
                    );
                }
            }
        }
    }

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
