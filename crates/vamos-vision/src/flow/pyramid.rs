//! Image pyramids (OpenCV `resize` geometry), centred gradients and flow resizing.
//!
//! A level is `scale_step` times the size of the one below it (rounded to the nearest
//! integer, ties to even, as `cv::resize` does); pixel `x` of level `s + 1` samples level
//! `s` at `(x + 0.5) / scale_step - 0.5` (bilinear, replicated border, no
//! pre-smoothing: the counterpart of OpenCV `DualTVL1`, which calls `resize` with
//! `INTER_LINEAR`).

use rayon::prelude::*;

/// Rows per rayon task of the per-pixel kernels (results do not depend on it).
pub(crate) const ROWS_PER_TASK: usize = 8;

/// Pixels below which a per-pixel pass runs on the calling thread: handing work to the
/// rayon pool and waiting for it costs a thread wake-up (tens of microseconds), more than
/// a pass over a small pyramid level takes.
const PARALLEL_MIN_PX: usize = 16_384;

/// Whether a pass over `pixels` pixels goes to the rayon pool: only when the pool has more
/// than one thread and the pass is big enough to pay for the hand-off. With one thread the
/// calling thread does the work itself instead of waking the pool's single worker and
/// sleeping. Results never depend on the choice.
pub(crate) fn run_parallel(pixels: usize) -> bool {
    pixels >= PARALLEL_MIN_PX && rayon::current_num_threads() > 1
}

/// Calls `f(band, rows)` on consecutive bands of [`ROWS_PER_TASK`] rows of `data` (rows
/// of `width` elements), in parallel where [`run_parallel`] says so.
pub(crate) fn for_each_band<T: Send>(
    data: &mut [T],
    width: usize,
    f: impl Fn(usize, &mut [T]) + Sync + Send,
) {
    let chunk = (width * ROWS_PER_TASK).max(1);
    if run_parallel(data.len()) {
        data.par_chunks_mut(chunk)
            .enumerate()
            .for_each(|(band, rows)| f(band, rows));
    } else {
        for (band, rows) in data.chunks_mut(chunk).enumerate() {
            f(band, rows);
        }
    }
}

/// One pyramid level of one frame.
#[derive(Clone, Debug)]
pub(crate) struct Level {
    pub width: usize,
    pub height: usize,
    /// Intensities, row-major.
    pub image: Vec<f32>,
    /// `[I, dI/dx, dI/dy, 0]` per pixel (centred differences, replicated border): the
    /// warp samples all three with one set of weights.
    pub packed: Vec<[f32; 4]>,
}

/// Pyramid of one frame, finest level first.
#[derive(Clone, Debug)]
pub(crate) struct Pyramid {
    pub levels: Vec<Level>,
}

/// Size of the next coarser level (OpenCV rounding: nearest, ties to even).
pub(crate) fn scaled_size(width: usize, height: usize, step: f32) -> (usize, usize) {
    let f = |n: usize| ((n as f64) * step as f64).round_ties_even() as usize;
    (f(width), f(height))
}

/// Number of levels for an image of `width x height`: at most `n_scales`, and only
/// levels whose sides are all at least `min_side`.
pub(crate) fn level_count(
    width: usize,
    height: usize,
    n_scales: usize,
    step: f32,
    min_side: usize,
) -> usize {
    let (mut w, mut h) = (width, height);
    let mut n = 1;
    while n < n_scales {
        (w, h) = scaled_size(w, h, step);
        if w < min_side || h < min_side {
            break;
        }
        n += 1;
    }
    n
}

/// Bilinear resize of `src` (`sw x sh`) to `dw x dh` where destination pixel `x` samples
/// `(x + 0.5) * inv_x - 0.5` (and likewise in y), clamped to the image.
pub(crate) fn resize_bilinear(
    src: &[f32],
    (sw, sh): (usize, usize),
    (dw, dh): (usize, usize),
    (inv_x, inv_y): (f32, f32),
) -> Vec<f32> {
    let mut out = vec![0.0f32; dw * dh];
    resize_bilinear_into(src, (sw, sh), (dw, dh), (inv_x, inv_y), &mut out);
    out
}

/// [`resize_bilinear`] into `out` (`dw * dh` values).
pub(crate) fn resize_bilinear_into(
    src: &[f32],
    (sw, sh): (usize, usize),
    (dw, dh): (usize, usize),
    (inv_x, inv_y): (f32, f32),
    out: &mut [f32],
) {
    debug_assert_eq!(out.len(), dw * dh);
    // Horizontal taps are the same for every row.
    let taps: Vec<(usize, usize, f32)> = (0..dw).map(|x| axis_tap(x, inv_x, sw)).collect();
    for_each_band(out, dw, |band, rows| {
        let mut mid = vec![0.0f32; sw];
        for (r, dst) in rows.chunks_exact_mut(dw).enumerate() {
            let y = band * ROWS_PER_TASK + r;
            let (y0, y1, fy) = axis_tap(y, inv_y, sh);
            let (r0, r1) = (&src[y0 * sw..(y0 + 1) * sw], &src[y1 * sw..(y1 + 1) * sw]);
            // Vertical pass over the source row (vectorised), then the horizontal taps.
            for ((m, &a), &b) in mid.iter_mut().zip(r0).zip(r1) {
                *m = a + fy * (b - a);
            }
            for (d, &(x0, x1, fx)) in dst.iter_mut().zip(&taps) {
                *d = mid[x0] + fx * (mid[x1] - mid[x0]);
            }
        }
    });
}

/// The two source indices and the weight of the second for destination index `i`.
fn axis_tap(i: usize, inv: f32, n: usize) -> (usize, usize, f32) {
    let s = ((i as f32 + 0.5) * inv - 0.5).max(0.0);
    let i0 = (s.floor() as usize).min(n - 1);
    let i1 = (i0 + 1).min(n - 1);
    let f = if i0 + 1 < n { s - i0 as f32 } else { 0.0 };
    (i0, i1, f)
}

/// `[I, Ix, Iy, 0]` with centred differences (one-sided halves at the border).
pub(crate) fn pack_with_gradient(image: &[f32], width: usize, height: usize) -> Vec<[f32; 4]> {
    let mut out = vec![[0.0f32; 4]; width * height];
    for_each_band(&mut out, width, |band, rows| {
        for (r, dst) in rows.chunks_exact_mut(width).enumerate() {
            let y = band * ROWS_PER_TASK + r;
            let row = &image[y * width..(y + 1) * width];
            let up = &image[y.saturating_sub(1) * width..][..width];
            let down = &image[(y + 1).min(height - 1) * width..][..width];
            for x in 0..width {
                let l = row[x.saturating_sub(1)];
                let r = row[(x + 1).min(width - 1)];
                dst[x] = [row[x], 0.5 * (r - l), 0.5 * (down[x] - up[x]), 0.0];
            }
        }
    });
    out
}

impl Level {
    #[cfg(test)]
    pub(crate) fn new(image: Vec<f32>, width: usize, height: usize) -> Self {
        Self::with_gradient(image, width, height, true)
    }

    /// A level; `packed` stays empty when `gradient` is false (levels that are never
    /// solved only feed the next coarser one).
    pub(crate) fn with_gradient(
        image: Vec<f32>,
        width: usize,
        height: usize,
        gradient: bool,
    ) -> Self {
        let packed = if gradient {
            pack_with_gradient(&image, width, height)
        } else {
            Vec::new()
        };
        Self {
            width,
            height,
            image,
            packed,
        }
    }
}

impl Pyramid {
    /// Builds `levels` levels from a full-resolution image; levels below `first_solved`
    /// get no gradient.
    pub(crate) fn build(
        image: &[f32],
        width: usize,
        height: usize,
        levels: usize,
        step: f32,
        first_solved: usize,
    ) -> Self {
        let mut out = Vec::with_capacity(levels);
        out.push(Level::with_gradient(
            image.to_vec(),
            width,
            height,
            first_solved == 0,
        ));
        for s in 1..levels {
            let Some(prev) = out.last() else { break };
            let (w, h) = scaled_size(prev.width, prev.height, step);
            let inv = 1.0 / step;
            let img = resize_bilinear(&prev.image, (prev.width, prev.height), (w, h), (inv, inv));
            out.push(Level::with_gradient(img, w, h, s >= first_solved));
        }
        Self { levels: out }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn level_sizes_follow_opencv_rounding() {
        assert_eq!(scaled_size(320, 240, 0.8), (256, 192));
        assert_eq!(scaled_size(256, 192, 0.8), (205, 154));
        assert_eq!(scaled_size(205, 154, 0.8), (164, 123));
        assert_eq!(level_count(320, 240, 5, 0.8, 16), 5);
        assert_eq!(level_count(20, 20, 5, 0.8, 16), 2);
        assert_eq!(level_count(16, 40, 5, 0.8, 16), 1);
    }

    #[test]
    fn resize_of_a_ramp_is_exact() {
        // I(x) = x in the source; destination x samples (x + 0.5) / 0.8 - 0.5.
        let (sw, sh) = (40, 10);
        let src: Vec<f32> = (0..sw * sh).map(|i| (i % sw) as f32).collect();
        let (dw, dh) = scaled_size(sw, sh, 0.8);
        let out = resize_bilinear(&src, (sw, sh), (dw, dh), (1.25, 1.25));
        for x in 0..dw - 1 {
            let expect = ((x as f32 + 0.5) * 1.25 - 0.5).max(0.0);
            assert!((out[3 * dw + x] - expect).abs() < 1e-5, "x {x}");
        }
    }

    #[test]
    fn gradient_of_a_plane() {
        let (w, h) = (6, 5);
        let img: Vec<f32> = (0..w * h)
            .map(|i| 2.0 * (i % w) as f32 + 3.0 * (i / w) as f32)
            .collect();
        let p = pack_with_gradient(&img, w, h);
        assert_eq!(p[2 * w + 2], [img[2 * w + 2], 2.0, 3.0, 0.0]);
        // Border: half of the one-sided difference.
        assert_eq!(p[0][1], 1.0);
        assert_eq!(p[0][2], 1.5);
    }
}
