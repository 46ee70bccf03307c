//! Scalar kernels of the registration: windows, mask feathering, warping, the log-polar
//! sampling map, normalised cross-power spectra and correlation-peak refinement.
//!
//! Everything here works on caller-provided buffers so that the [`super::Registrar`]
//! allocates nothing per frame after warm-up.

use realfft::num_complex::Complex;

use super::SubPixelMethod;

/// Separable apodisation window: a Hann taper over `fraction` of each border, flat (1)
/// in the middle. Row-major `w * h`.
pub(crate) fn apodization_window(w: usize, h: usize, fraction: f32) -> Vec<f32> {
    let wx = taper_1d(w, fraction);
    let wy = taper_1d(h, fraction);
    let mut out = Vec::with_capacity(w * h);
    for &vy in &wy {
        out.extend(wx.iter().map(|&vx| vx * vy));
    }
    out
}

/// 1-D taper of length `n`: half a Hann window rising over the first
/// `round(fraction * n)` samples and falling over the last as many; symmetric about
/// `(n - 1) / 2`.
pub(crate) fn taper_1d(n: usize, fraction: f32) -> Vec<f32> {
    let t = ((fraction * n as f32).round() as usize).min(n / 2);
    (0..n)
        .map(|i| {
            let d = i.min(n - 1 - i);
            if d >= t {
                1.0
            } else {
                let u = (d as f32 + 0.5) / t as f32;
                0.5 - 0.5 * (std::f32::consts::PI * u).cos()
            }
        })
        .collect()
}

/// Feathered weights of the unmasked pixels: 0 on masked pixels, rising smoothly
/// (smoothstep of the chamfer distance to the nearest masked pixel divided by
/// `feather_px`) to 1 at `feather_px` pixels from the mask. `out` is `w * h`.
pub(crate) fn feathered_mask(mask: &[bool], w: usize, h: usize, feather_px: f32, out: &mut [f32]) {
    const DIAG: f32 = std::f32::consts::SQRT_2;
    let far = feather_px + 2.0;
    for (o, &m) in out.iter_mut().zip(mask) {
        *o = if m { 0.0 } else { far };
    }
    // Two-pass chamfer distance, capped at `far` (all we need).
    for y in 0..h {
        for x in 0..w {
            let i = y * w + x;
            let mut d = out[i];
            if x > 0 {
                d = d.min(out[i - 1] + 1.0);
            }
            if y > 0 {
                d = d.min(out[i - w] + 1.0);
                if x > 0 {
                    d = d.min(out[i - w - 1] + DIAG);
                }
                if x + 1 < w {
                    d = d.min(out[i - w + 1] + DIAG);
                }
            }
            out[i] = d;
        }
    }
    for y in (0..h).rev() {
        for x in (0..w).rev() {
            let i = y * w + x;
            let mut d = out[i];
            if x + 1 < w {
                d = d.min(out[i + 1] + 1.0);
            }
            if y + 1 < h {
                d = d.min(out[i + w] + 1.0);
                if x + 1 < w {
                    d = d.min(out[i + w + 1] + DIAG);
                }
                if x > 0 {
                    d = d.min(out[i + w - 1] + DIAG);
                }
            }
            out[i] = d;
        }
    }
    for (o, &m) in out.iter_mut().zip(mask) {
        *o = if m {
            0.0
        } else if feather_px <= 0.0 {
            1.0
        } else {
            let u = (*o / feather_px).clamp(0.0, 1.0);
            u * u * (3.0 - 2.0 * u)
        };
    }
}

/// `out = (img - mean_w) * weights` where `mean_w` is the weighted mean of `img`, so
/// that the result has zero DC. Returns `false` (and zeros `out`) when all weights are 0.
pub(crate) fn weighted_zero_mean(img: &[f32], weights: &[f32], out: &mut [f32]) -> bool {
    let (mut sw, mut swx) = (0.0f64, 0.0f64);
    // Eight f32 lanes per block (so the loop vectorises), blocks summed in f64.
    for (ib, wb) in img.chunks(LANE_BLOCK).zip(weights.chunks(LANE_BLOCK)) {
        let (mut lw, mut lwx) = ([0.0f32; 8], [0.0f32; 8]);
        let (ic, wc) = (ib.chunks_exact(8), wb.chunks_exact(8));
        for (&v, &w) in ic.remainder().iter().zip(wc.remainder()) {
            lw[0] += w;
            lwx[0] += w * v;
        }
        for (i8, w8) in ic.zip(wc) {
            for k in 0..8 {
                lw[k] += w8[k];
                lwx[k] += w8[k] * i8[k];
            }
        }
        sw += lw.iter().map(|&v| v as f64).sum::<f64>();
        swx += lwx.iter().map(|&v| v as f64).sum::<f64>();
    }
    if sw <= 0.0 {
        out.fill(0.0);
        return false;
    }
    let mean = (swx / sw) as f32;
    for ((o, &v), &w) in out.iter_mut().zip(img).zip(weights) {
        *o = (v - mean) * w;
    }
    true
}

/// Block length of the lane-parallel sums: long enough to amortise the f64 fold, short
/// enough that an f32 lane sums at most 128 terms.
const LANE_BLOCK: usize = 1024;

/// Sum of `f` over `xs` in eight f32 lanes per block of [`LANE_BLOCK`] values (so the loop
/// vectorises), blocks added in f64.
#[inline(always)]
fn lane_sum<T: Copy>(xs: &[T], f: impl Fn(T) -> f32) -> f64 {
    let mut total = 0.0f64;
    for block in xs.chunks(LANE_BLOCK) {
        let mut lanes = [0.0f32; 8];
        let c = block.chunks_exact(8);
        for &v in c.remainder() {
            lanes[0] += f(v);
        }
        for x8 in c {
            for k in 0..8 {
                lanes[k] += f(x8[k]);
            }
        }
        total += lanes.iter().map(|&v| v as f64).sum::<f64>();
    }
    total
}

/// Sum of squares of `xs`, lane-parallel in f32 blocks folded into f64.
pub(crate) fn sum_squares(xs: &[f32]) -> f64 {
    lane_sum(xs, |v| v * v)
}

/// Warps `src` (`w x h`, row-major) by the similarity of scale `scale` and rotation
/// `rotation_deg` about the centre `((w-1)/2, (h-1)/2)`, no translation, in the
/// convention of [`crate::synthetic::similarity_forward`]:
/// `out(q) = src(p)` where `q = c + scale * R (p - c)`. Bilinear; zero outside.
pub(crate) fn warp_similarity(
    src: &[f32],
    w: usize,
    h: usize,
    scale: f64,
    rotation_deg: f64,
    out: &mut [f32],
) {
    let (s, c) = rotation_deg.to_radians().sin_cos();
    let (cx, cy) = ((w as f64 - 1.0) / 2.0, (h as f64 - 1.0) / 2.0);
    // p = c + R^T (q - c) / scale with R^T = [[c, -s], [s, c]].
    let (a, b) = (c / scale, -s / scale);
    let (d, e) = (s / scale, c / scale);
    #[cfg(target_arch = "x86_64")]
    // The vector path computes pixel indices in i32 lanes.
    if w * h < i32::MAX as usize && std::arch::is_x86_feature_detected!("avx2") {
        for y in 0..h {
            let row = WarpRow::new(cx, cy, a, b, d, e, y, w, h);
            // SAFETY: the CPU supports AVX2 (checked just above) and `w * h` fits i32.
            unsafe { row.fill_avx2(src, &mut out[y * w..(y + 1) * w]) };
        }
        return;
    }
    for y in 0..h {
        let row = WarpRow::new(cx, cy, a, b, d, e, y, w, h);
        row.fill(src, &mut out[y * w..(y + 1) * w], 0);
    }
}

/// One output row of [`warp_similarity`]: its source coordinates are
/// `(px0 + a x, py0 + d x)`, in f64 for the border path and as f32 offsets from the f64
/// row start for the interior path (under 1e-3 px of rounding up to 4096 px).
struct WarpRow {
    px0: f64,
    py0: f64,
    a: f64,
    d: f64,
    px0f: f32,
    py0f: f32,
    af: f32,
    df: f32,
    w: usize,
    h: usize,
}

impl WarpRow {
    #[allow(clippy::too_many_arguments)]
    fn new(cx: f64, cy: f64, a: f64, b: f64, d: f64, e: f64, y: usize, w: usize, h: usize) -> Self {
        let dy = y as f64 - cy;
        let px0 = cx + a * (-cx) + b * dy;
        let py0 = cy + d * (-cx) + e * dy;
        Self {
            px0,
            py0,
            a,
            d,
            px0f: px0 as f32,
            py0f: py0 as f32,
            af: a as f32,
            df: d as f32,
            w,
            h,
        }
    }

    /// Scalar fill of `row[from..]` (`row` is the whole output row).
    #[inline(always)]
    fn fill(&self, src: &[f32], row: &mut [f32], from: usize) {
        let w = self.w;
        let (wl, hl) = ((w - 1) as f32, (self.h - 1) as f32);
        for (x, o) in row.iter_mut().enumerate().skip(from) {
            let pxf = self.px0f + self.af * x as f32;
            let pyf = self.py0f + self.df * x as f32;
            // Fast interior path: truncation is the floor for non-negative coordinates,
            // which avoids a libm `floor` call per sample.
            if pxf >= 0.0 && pyf >= 0.0 && pxf < wl && pyf < hl {
                let (xi, yi) = (pxf as usize, pyf as usize);
                let fx = pxf - xi as f32;
                let fy = pyf - yi as f32;
                let i = yi * w + xi;
                let (t0, t1) = (src[i], src[i + 1]);
                let (b0, b1) = (src[i + w], src[i + w + 1]);
                let top = t0 + fx * (t1 - t0);
                let bot = b0 + fx * (b1 - b0);
                *o = top + fy * (bot - top);
                continue;
            }
            let (px, py) = (self.px0 + self.a * x as f64, self.py0 + self.d * x as f64);
            *o = sample_bilinear(src, w, self.h, px, py);
        }
    }

    /// [`WarpRow::fill`] eight pixels at a time with AVX2 where all eight are interior
    /// (coordinates, indices and interpolation in vectors, the four taps loaded one by
    /// one); the same operations in the same order, so bit-identical results.
    ///
    /// # Safety
    /// The CPU must support AVX2 and `w * h` must fit an `i32`.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    unsafe fn fill_avx2(&self, src: &[f32], row: &mut [f32]) {
        use std::arch::x86_64::*;
        let w = self.w;
        debug_assert_eq!(src.len(), w * self.h);
        let (wl, hl) = (
            _mm256_set1_ps((w - 1) as f32),
            _mm256_set1_ps((self.h - 1) as f32),
        );
        let zero = _mm256_setzero_ps();
        // Half a pixel beyond the last coordinate with a tap in the image.
        let lo = _mm256_set1_ps(-1.5);
        let (wfar, hfar) = (
            _mm256_set1_ps(w as f32 + 0.5),
            _mm256_set1_ps(self.h as f32 + 0.5),
        );
        let (px0, py0) = (_mm256_set1_ps(self.px0f), _mm256_set1_ps(self.py0f));
        let (af, df) = (_mm256_set1_ps(self.af), _mm256_set1_ps(self.df));
        let wv = _mm256_set1_epi32(w as i32);
        let lanes = _mm256_setr_ps(0.0, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0);
        let base = src.as_ptr();
        let mut idx = [0i32; 8];
        let mut taps = [[0.0f32; 8]; 4];
        let mut x = 0usize;
        while x + 8 <= w {
            let xs = _mm256_add_ps(_mm256_set1_ps(x as f32), lanes);
            let pxf = _mm256_add_ps(px0, _mm256_mul_ps(af, xs));
            let pyf = _mm256_add_ps(py0, _mm256_mul_ps(df, xs));
            let inside = _mm256_and_ps(
                _mm256_and_ps(
                    _mm256_cmp_ps::<_CMP_GE_OQ>(pxf, zero),
                    _mm256_cmp_ps::<_CMP_GE_OQ>(pyf, zero),
                ),
                _mm256_and_ps(
                    _mm256_cmp_ps::<_CMP_LT_OQ>(pxf, wl),
                    _mm256_cmp_ps::<_CMP_LT_OQ>(pyf, hl),
                ),
            );
            if _mm256_movemask_ps(inside) != 0xff {
                // All eight far outside (no tap in the image even with f32 rounding, so
                // the border path gives 0 too): zeros.
                let far = _mm256_or_ps(
                    _mm256_or_ps(
                        _mm256_cmp_ps::<_CMP_LT_OQ>(pxf, lo),
                        _mm256_cmp_ps::<_CMP_LT_OQ>(pyf, lo),
                    ),
                    _mm256_or_ps(
                        _mm256_cmp_ps::<_CMP_GT_OQ>(pxf, wfar),
                        _mm256_cmp_ps::<_CMP_GT_OQ>(pyf, hfar),
                    ),
                );
                if _mm256_movemask_ps(far) == 0xff {
                    // SAFETY: x + 8 <= w = row.len().
                    unsafe { _mm256_storeu_ps(row.as_mut_ptr().add(x), zero) };
                    x += 8;
                    continue;
                }
                // Some lane needs the border path: do these eight one by one.
                let end = x + 8;
                self.fill(src, &mut row[..end], x);
                x = end;
                continue;
            }
            let xi = _mm256_cvttps_epi32(pxf);
            let yi = _mm256_cvttps_epi32(pyf);
            let fx = _mm256_sub_ps(pxf, _mm256_cvtepi32_ps(xi));
            let fy = _mm256_sub_ps(pyf, _mm256_cvtepi32_ps(yi));
            let i = _mm256_add_epi32(_mm256_mullo_epi32(yi, wv), xi);
            // SAFETY: `idx` holds eight i32.
            unsafe { _mm256_storeu_si256(idx.as_mut_ptr().cast(), i) };
            // Scalar loads beat `vgatherdps` here (measured on AMD EPYC, where gathers
            // are microcoded).
            for (k, &ik) in idx.iter().enumerate() {
                // SAFETY: every lane is interior (0 <= xi <= w-2, 0 <= yi <= h-2), so
                // i, i+1, i+w and i+w+1 all lie in `src`.
                unsafe {
                    let p = base.add(ik as usize);
                    taps[0][k] = *p;
                    taps[1][k] = *p.add(1);
                    taps[2][k] = *p.add(w);
                    taps[3][k] = *p.add(w + 1);
                }
            }
            let [t0, t1, b0, b1] = taps.map(|t| {
                // SAFETY: `t` holds eight f32.
                unsafe { _mm256_loadu_ps(t.as_ptr()) }
            });
            let top = _mm256_add_ps(t0, _mm256_mul_ps(fx, _mm256_sub_ps(t1, t0)));
            let bot = _mm256_add_ps(b0, _mm256_mul_ps(fx, _mm256_sub_ps(b1, b0)));
            let v = _mm256_add_ps(top, _mm256_mul_ps(fy, _mm256_sub_ps(bot, top)));
            // SAFETY: x + 8 <= w = row.len().
            unsafe { _mm256_storeu_ps(row.as_mut_ptr().add(x), v) };
            x += 8;
        }
        self.fill(src, row, x);
    }
}

#[inline]
fn sample_bilinear(src: &[f32], w: usize, h: usize, x: f64, y: f64) -> f32 {
    let x0 = x.floor();
    let y0 = y.floor();
    let fx = (x - x0) as f32;
    let fy = (y - y0) as f32;
    let (xi, yi) = (x0 as isize, y0 as isize);
    let (wi, hi) = (w as isize, h as isize);
    if xi >= 0 && yi >= 0 && xi + 1 < wi && yi + 1 < hi {
        let i = yi as usize * w + xi as usize;
        let top = src[i] + fx * (src[i + 1] - src[i]);
        let bot = src[i + w] + fx * (src[i + w + 1] - src[i + w]);
        return top + fy * (bot - top);
    }
    if xi < -1 || yi < -1 || xi >= wi || yi >= hi {
        return 0.0;
    }
    let at = |xx: isize, yy: isize| -> f32 {
        if xx >= 0 && yy >= 0 && xx < wi && yy < hi {
            src[yy as usize * w + xx as usize]
        } else {
            0.0
        }
    };
    let top = at(xi, yi) * (1.0 - fx) + at(xi + 1, yi) * fx;
    let bot = at(xi, yi + 1) * (1.0 - fx) + at(xi + 1, yi + 1) * fx;
    top * (1.0 - fy) + bot * fy
}

/// Reddy-Chatterji high-pass emphasis `(1 - X)(2 - X)`, `X = cos(pi fx) cos(pi fy)` with
/// `fx, fy` in cycles per pixel (`-0.5..=0.5`), in the column-major spectrum layout of
/// [`super::fft2::Fft2`]. All ones when `enabled` is false.
pub(crate) fn highpass(w: usize, h: usize, enabled: bool) -> Vec<f32> {
    let wc = w / 2 + 1;
    let mut out = vec![1.0; wc * h];
    if enabled {
        for kx in 0..wc {
            let fx = kx as f64 / w as f64;
            for ky in 0..h {
                let fy = signed_freq(ky, h) as f64 / h as f64;
                let x = (std::f64::consts::PI * fx).cos() * (std::f64::consts::PI * fy).cos();
                out[kx * h + ky] = ((1.0 - x) * (2.0 - x)) as f32;
            }
        }
    }
    out
}

/// Gaussian `exp(-2 pi^2 sigma^2 |f|^2)` in the column-major spectrum layout: the
/// transform of a spatial Gaussian of standard deviation `sigma` (pixels or samples).
pub(crate) fn gaussian_spectrum(w: usize, h: usize, sigma: f32) -> Vec<f32> {
    let wc = w / 2 + 1;
    let k = -2.0 * std::f64::consts::PI.powi(2) * (sigma as f64).powi(2);
    let mut out = vec![0.0; wc * h];
    for kx in 0..wc {
        let fx = kx as f64 / w as f64;
        for ky in 0..h {
            let fy = signed_freq(ky, h) as f64 / h as f64;
            out[kx * h + ky] = (k * (fx * fx + fy * fy)).exp() as f32;
        }
    }
    out
}

/// `exp(-2 pi i (kx / w + ky / h))`. The image `y[n] = x[N - 1 - n]` (rotated by 180
/// degrees about `(N - 1) / 2` on both axes) has `Y = exp(+2 pi i k / N) conj(X)`, so
/// `conj(Y) = ramp * X`.
pub(crate) fn half_turn_ramp(w: usize, h: usize) -> Vec<Complex<f32>> {
    let wc = w / 2 + 1;
    let mut out = vec![Complex::new(0.0, 0.0); wc * h];
    for kx in 0..wc {
        for ky in 0..h {
            let ph = -std::f64::consts::TAU * (kx as f64 / w as f64 + ky as f64 / h as f64);
            out[kx * h + ky] = Complex::new(ph.cos() as f32, ph.sin() as f32);
        }
    }
    out
}

/// Frequency index `k` of an `n`-point FFT as a signed frequency in `-n/2..n/2`.
#[inline]
pub(crate) fn signed_freq(k: usize, n: usize) -> isize {
    if k > n / 2 {
        k as isize - n as isize
    } else {
        k as isize
    }
}

/// One bilinear tap set of the log-polar map into the column-major half spectrum.
#[derive(Clone, Copy, Debug)]
pub(crate) struct LogPolarTap {
    idx: [u32; 4],
    wt: [f32; 4],
}

/// The log-polar sampling grid of a `w x h` spectrum.
///
/// Row `i` (of `angles`) is the direction `phi = i * 180 / angles` degrees (atan2 of the
/// vertical over the horizontal frequency, image axes); column `j` (of `radii`) is the
/// radius `f_min * exp(j * log_step)` cycles per pixel, up to `f_max`, see
/// [`LogPolarMap::new`]. Directions beyond 90 degrees use the Hermitian symmetry
/// `|F(-k)| = |F(k)|` to stay in the stored half spectrum.
pub(crate) struct LogPolarMap {
    pub(crate) angles: usize,
    pub(crate) radii: usize,
    /// Natural log of the ratio between consecutive radii.
    pub(crate) log_step: f64,
    taps: Vec<LogPolarTap>,
}

impl LogPolarMap {
    /// Radii from `f_min` to `f_max = 0.45` cycles per pixel (short of Nyquist, where
    /// aliasing lives), log-spaced; `f_min = f_max / max_scale^4`, but not below two
    /// frequency bins of the shorter side.
    pub(crate) fn new(w: usize, h: usize, angles: usize, radii: usize, max_scale: f64) -> Self {
        let f_max = 0.45f64;
        let f_floor = 2.0 / w.min(h) as f64;
        let f_min = (f_max / max_scale.powi(4)).max(f_floor).min(f_max / 2.0);
        let log_step = (f_max / f_min).ln() / (radii as f64 - 1.0);
        let wc = w / 2 + 1;
        let mut taps = Vec::with_capacity(angles * radii);
        for i in 0..angles {
            let phi = std::f64::consts::PI * i as f64 / angles as f64;
            let (sn, cs) = phi.sin_cos();
            for j in 0..radii {
                let f = f_min * (log_step * j as f64).exp();
                // Fractional frequency indices (bins) along x and y.
                let kx = f * cs * w as f64;
                let ky = f * sn * h as f64;
                let (x0, y0) = (kx.floor(), ky.floor());
                let (fx, fy) = ((kx - x0) as f32, (ky - y0) as f32);
                let mut tap = LogPolarTap {
                    idx: [0; 4],
                    wt: [0.0; 4],
                };
                let corners = [
                    (0isize, 0isize, (1.0 - fx) * (1.0 - fy)),
                    (1, 0, fx * (1.0 - fy)),
                    (0, 1, (1.0 - fx) * fy),
                    (1, 1, fx * fy),
                ];
                for (n, &(ox, oy, wt)) in corners.iter().enumerate() {
                    let ix = (x0 as isize + ox).rem_euclid(w as isize) as usize;
                    let iy = (y0 as isize + oy).rem_euclid(h as isize) as usize;
                    // Fold the left half plane onto the stored right half: |F(-k)| = |F(k)|.
                    let (ix, iy) = if ix >= wc {
                        (w - ix, (h - iy) % h)
                    } else {
                        (ix, iy)
                    };
                    tap.idx[n] = (ix * h + iy) as u32;
                    tap.wt[n] = wt;
                }
                taps.push(tap);
            }
        }
        Self {
            angles,
            radii,
            log_step,
            taps,
        }
    }

    /// Samples `mag` (column-major half spectrum) into `out` (`angles x radii`, row-major).
    pub(crate) fn sample(&self, mag: &[f32], out: &mut [f32]) {
        for (o, t) in out.iter_mut().zip(&self.taps) {
            *o = t.wt[0] * mag[t.idx[0] as usize]
                + t.wt[1] * mag[t.idx[1] as usize]
                + t.wt[2] * mag[t.idx[2] as usize]
                + t.wt[3] * mag[t.idx[3] as usize];
        }
    }
}

/// `out = b * conj(a) * g / (|a| |b| + eps)`, the
/// Gaussian-smoothed normalised cross-power spectrum: its inverse transform peaks at the
/// shift `d` with `b(x) = a(x - d)`. `eps` is 1e-3 of the mean of `|a| |b|`, which keeps
/// empty frequencies from dividing by zero. With `ramp` (from [`half_turn_ramp`]), `a`
/// is replaced by the spectrum of its image rotated by 180 degrees about the centre:
/// that spectrum's conjugate is `ramp * a`.
pub(crate) fn cross_power(
    a: &[Complex<f32>],
    b: &[Complex<f32>],
    g: &[f32],
    ramp: Option<&[Complex<f32>]>,
    out: &mut [Complex<f32>],
) {
    if ramp.is_some() {
        // conj of the half-turned spectrum: ramp * a (see `half_turn_ramp`).
        for ((o, &av), &bv) in out.iter_mut().zip(a).zip(b) {
            *o = bv * av;
        }
    } else {
        for ((o, &av), &bv) in out.iter_mut().zip(a).zip(b) {
            *o = bv * av.conj();
        }
    }
    // Sum of magnitudes: eight f32 lanes per block, blocks summed in f64.
    let sum = lane_sum(out, |v| v.norm_sqr().sqrt());
    let eps = ((1e-3 * sum / out.len().max(1) as f64) as f32).max(f32::MIN_POSITIVE);
    match ramp {
        None => {
            for (o, &gv) in out.iter_mut().zip(g) {
                *o *= gv / (o.norm_sqr().sqrt() + eps);
            }
        }
        Some(r) => {
            for ((o, &gv), &rv) in out.iter_mut().zip(g).zip(r) {
                *o *= rv * (gv / (o.norm_sqr().sqrt() + eps));
            }
        }
    }
}

/// The refined peak of a correlation surface.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Peak {
    /// Shift along x (columns), wrapped to `-w/2..w/2`, sub-pixel.
    pub(crate) dx: f64,
    /// Shift along y (rows), wrapped to `-h/2..h/2`, sub-pixel.
    pub(crate) dy: f64,
    /// Share of the surface's energy (sum of squares) within `radius` of the peak.
    pub(crate) energy_fraction: f32,
}

/// Finds the maximum of the periodic `w x h` surface, considering only x shifts with
/// `|dx| <= max_dx` when given, refines it with `method` and measures its sharpness.
pub(crate) fn find_peak(
    surface: &[f32],
    w: usize,
    h: usize,
    max_dx: Option<usize>,
    method: SubPixelMethod,
    radius: usize,
) -> Peak {
    let mut best = f32::NEG_INFINITY;
    let mut bi = 0usize;
    let allowed = |x: usize| match max_dx {
        None => true,
        Some(m) => x <= m || w - x <= m,
    };
    for y in 0..h {
        let row = &surface[y * w..(y + 1) * w];
        for (x, &v) in row.iter().enumerate() {
            if v > best && allowed(x) {
                best = v;
                bi = y * w + x;
            }
        }
    }
    let (px, py) = (bi % w, bi / w);
    let at = |ox: isize, oy: isize| -> f32 {
        let x = (px as isize + ox).rem_euclid(w as isize) as usize;
        let y = (py as isize + oy).rem_euclid(h as isize) as usize;
        surface[y * w + x]
    };
    let (fx, fy) = match method {
        SubPixelMethod::Gaussian => (
            gaussian_offset(at(-1, 0), at(0, 0), at(1, 0)),
            gaussian_offset(at(0, -1), at(0, 0), at(0, 1)),
        ),
        SubPixelMethod::Parabolic => (
            parabolic_offset(at(-1, 0), at(0, 0), at(1, 0)),
            parabolic_offset(at(0, -1), at(0, 0), at(0, 1)),
        ),
        SubPixelMethod::Centroid => {
            let (mut s, mut sx, mut sy) = (0.0f64, 0.0f64, 0.0f64);
            for oy in -1..=1isize {
                for ox in -1..=1isize {
                    let v = at(ox, oy).max(0.0) as f64;
                    s += v;
                    sx += v * ox as f64;
                    sy += v * oy as f64;
                }
            }
            if s > 0.0 {
                (sx / s, sy / s)
            } else {
                (0.0, 0.0)
            }
        }
    };
    let total = sum_squares(surface);
    let r = radius as isize;
    let mut local = 0.0f64;
    let rx = r.min((w as isize - 1) / 2);
    let ry = r.min((h as isize - 1) / 2);
    for oy in -ry..=ry {
        for ox in -rx..=rx {
            let v = at(ox, oy) as f64;
            local += v * v;
        }
    }
    let energy_fraction = if total > 0.0 && best > 0.0 {
        (local / total).clamp(0.0, 1.0) as f32
    } else {
        0.0
    };
    let wrap = |p: usize, n: usize| signed_freq(p, n) as f64;
    Peak {
        dx: wrap(px, w) + fx,
        dy: wrap(py, h) + fy,
        energy_fraction,
    }
}

/// Vertex of the parabola through `(-1, l), (0, c), (1, r)`, clamped to `[-1, 1]`.
fn parabolic_offset(l: f32, c: f32, r: f32) -> f64 {
    let (l, c, r) = (l as f64, c as f64, r as f64);
    let den = l - 2.0 * c + r;
    if den < 0.0 {
        (0.5 * (l - r) / den).clamp(-1.0, 1.0)
    } else {
        0.0
    }
}

/// Vertex of the Gaussian through the three samples (a parabola through their logs);
/// exact for a sampled Gaussian. Falls back to the parabola when a sample is not
/// positive.
fn gaussian_offset(l: f32, c: f32, r: f32) -> f64 {
    if l > 0.0 && c > 0.0 && r > 0.0 {
        parabolic_offset(l.ln(), c.ln(), r.ln())
    } else {
        parabolic_offset(l, c, r)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn taper_is_symmetric_and_flat_in_the_middle() {
        let t = taper_1d(100, 0.12);
        for i in 0..100 {
            assert!((t[i] - t[99 - i]).abs() < 1e-6);
        }
        assert_eq!(t[50], 1.0);
        assert!(t[0] < 0.01 && t[0] > 0.0);
        assert_eq!(t[12], 1.0);
        assert!(t[11] < 1.0);
    }

    #[test]
    fn feathered_mask_ramps_from_the_mask() {
        let (w, h) = (20, 10);
        let mask: Vec<bool> = (0..w * h).map(|i| i % w < 5).collect();
        let mut out = vec![0.0; w * h];
        feathered_mask(&mask, w, h, 4.0, &mut out);
        let row = &out[3 * w..4 * w];
        assert_eq!(row[4], 0.0);
        assert!(row[5] > 0.0 && row[5] < row[6] && row[6] < row[7]);
        assert_eq!(row[9], 1.0);
        feathered_mask(&mask, w, h, 0.0, &mut out);
        assert_eq!(out[3 * w + 5], 1.0);
    }

    #[test]
    fn gaussian_offset_is_exact_for_a_gaussian() {
        for &d in &[-0.4f64, -0.1, 0.0, 0.25, 0.49] {
            let g = |x: f64| (-(x - d).powi(2) / 2.0).exp() as f32;
            assert!((gaussian_offset(g(-1.0), g(0.0), g(1.0)) - d).abs() < 1e-4);
        }
    }

    #[test]
    fn warp_fast_path_matches_per_pixel_sampling() {
        let (w, h) = (37usize, 29usize);
        let src: Vec<f32> = (0..w * h).map(|i| ((i * 7919) % 251) as f32).collect();
        let mut out = vec![0.0; w * h];
        for &(scale, rot) in &[
            (1.0, 0.0),
            (1.1, 7.0),
            (0.8, -33.0),
            (1.3, 90.0),
            (0.9, 180.0),
            (1.0, 45.0),
        ] {
            warp_similarity(&src, w, h, scale, rot, &mut out);
            let (s, c) = rot.to_radians().sin_cos();
            let (cx, cy) = ((w as f64 - 1.0) / 2.0, (h as f64 - 1.0) / 2.0);
            for y in 0..h {
                for x in 0..w {
                    let (qx, qy) = (x as f64 - cx, y as f64 - cy);
                    let px = cx + (c * qx - s * qy) / scale;
                    let py = cy + (s * qx + c * qy) / scale;
                    let want = sample_bilinear(&src, w, h, px, py);
                    let got = out[y * w + x];
                    assert!(
                        (got - want).abs() < 0.05,
                        "scale {scale} rot {rot} ({x},{y}): {got} vs {want}"
                    );
                }
            }
        }
    }

    #[test]
    fn warp_vector_path_equals_scalar_path_bit_for_bit() {
        // On AVX2 machines `warp_similarity` works eight pixels at a time; the scalar
        // row fill is the reference. Widths not divisible by 8, borders crossed.
        for &(w, h) in &[(37usize, 29usize), (64, 48), (13, 40)] {
            let src: Vec<f32> = (0..w * h)
                .map(|i| ((i * 7919) % 251) as f32 * 0.37)
                .collect();
            let mut out = vec![0.0; w * h];
            for &(scale, rot) in &[
                (1.0, 0.0),
                (1.05, 6.0),
                (0.8, -33.0),
                (1.3, 90.0),
                (0.7, 170.0),
                (0.5, 10.0),
                (1.0 / 1.05, -6.0),
            ] {
                warp_similarity(&src, w, h, scale, rot, &mut out);
                let (s, c) = f64::to_radians(rot).sin_cos();
                let (cx, cy) = ((w as f64 - 1.0) / 2.0, (h as f64 - 1.0) / 2.0);
                let mut want = vec![0.0f32; w];
                for y in 0..h {
                    let row =
                        WarpRow::new(cx, cy, c / scale, -s / scale, s / scale, c / scale, y, w, h);
                    row.fill(&src, &mut want, 0);
                    let got = &out[y * w..(y + 1) * w];
                    for (x, (g, e)) in got.iter().zip(&want).enumerate() {
                        assert_eq!(
                            g.to_bits(),
                            e.to_bits(),
                            "{w}x{h} s {scale} r {rot} ({x},{y})"
                        );
                    }
                }
            }
        }
    }

    #[test]
    fn warp_identity_copies_and_half_turn_reverses() {
        let (w, h) = (9, 7);
        let src: Vec<f32> = (0..w * h).map(|i| i as f32).collect();
        let mut out = vec![0.0; w * h];
        warp_similarity(&src, w, h, 1.0, 0.0, &mut out);
        for (a, b) in out.iter().zip(&src) {
            assert!((a - b).abs() < 1e-4);
        }
        warp_similarity(&src, w, h, 1.0, 180.0, &mut out);
        for i in 0..w * h {
            assert!((out[i] - src[w * h - 1 - i]).abs() < 1e-3);
        }
    }

    #[test]
    fn peak_of_a_shifted_gaussian() {
        let (w, h) = (32, 16);
        let (dx, dy) = (-3.3f64, 2.2f64);
        let mut s = vec![0.0; w * h];
        for y in 0..h {
            for x in 0..w {
                let (xs, ys) = (signed_freq(x, w) as f64, signed_freq(y, h) as f64);
                s[y * w + x] = (-((xs - dx).powi(2) + (ys - dy).powi(2)) / 2.0).exp() as f32;
            }
        }
        let p = find_peak(&s, w, h, None, SubPixelMethod::Gaussian, 2);
        assert!(
            (p.dx - dx).abs() < 1e-3 && (p.dy - dy).abs() < 1e-3,
            "{p:?}"
        );
        assert!(p.energy_fraction > 0.95);
        let p = find_peak(&s, w, h, Some(2), SubPixelMethod::Parabolic, 2);
        assert!(p.dx.abs() <= 3.0);
    }
}
