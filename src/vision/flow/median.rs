//! Square median filter of a flow component (replicated border, as `cv::medianBlur`).
//!
//! The fast path runs a selection network over [`LANES`] horizontally adjacent pixels at
//! once: each compare-exchange is a lane-wise min/max, which the compiler vectorises.
//! The network is Batcher's odd-even merge sort for the next power of two (the padding
//! wires hold +inf, so comparators that touch them are no-ops and are dropped), pruned
//! to the comparators that the middle output depends on. A sort-based scalar reference
//! checks it.

use std::sync::OnceLock;

use rayon::prelude::*;

use super::pyramid::ROWS_PER_TASK;

/// Pixels processed together by the network.
const LANES: usize = 8;

/// Comparators `(lo, hi)` whose cone contains the median of `n` values (`n` odd).
fn median_network(n: usize) -> Vec<(u8, u8)> {
    let size = n.next_power_of_two();
    let mut all = Vec::new();
    let mut p = 1;
    while p < size {
        let mut k = p;
        while k >= 1 {
            let mut j = k % p;
            while j + k < size {
                for i in 0..k.min(size - j - k) {
                    if (i + j) / (2 * p) == (i + j + k) / (2 * p) {
                        all.push((i + j, i + j + k));
                    }
                }
                j += 2 * k;
            }
            k /= 2;
        }
        p *= 2;
    }
    // Wires >= n hold +inf: min/max with them changes nothing.
    all.retain(|&(_, b)| b < n);
    let mut needed = vec![false; n];
    needed[n / 2] = true;
    let mut kept = Vec::new();
    for &(a, b) in all.iter().rev() {
        if needed[a] || needed[b] {
            needed[a] = true;
            needed[b] = true;
            // Invariant: a < b < n <= 49, so both fit in u8.
            kept.push((a as u8, b as u8));
        }
    }
    kept.reverse();
    kept
}

fn network_for(side: usize) -> &'static [(u8, u8)] {
    static NETS: [OnceLock<Vec<(u8, u8)>>; 3] = [OnceLock::new(), OnceLock::new(), OnceLock::new()];
    let slot = match side {
        3 => 0,
        5 => 1,
        _ => 2,
    };
    NETS[slot].get_or_init(|| median_network(side * side))
}

/// Copy of `src` with a replicated border of `r` pixels on each side.
fn pad_replicate(src: &[f32], width: usize, height: usize, r: usize) -> Vec<f32> {
    let pw = width + 2 * r;
    let mut out = vec![0.0f32; pw * (height + 2 * r)];
    for (py, dst) in out.chunks_exact_mut(pw).enumerate() {
        let y = py.saturating_sub(r).min(height - 1);
        let row = &src[y * width..(y + 1) * width];
        dst[r..r + width].copy_from_slice(row);
        let (first, last) = (row[0], row[width - 1]);
        dst[..r].fill(first);
        dst[r + width..].fill(last);
    }
    out
}

/// Median filter of side `side` (3, 5 or 7) in place; other sides leave `data` as is.
pub(crate) fn median_filter(data: &mut [f32], width: usize, height: usize, side: usize) {
    if !matches!(side, 3 | 5 | 7) {
        return;
    }
    let r = side / 2;
    let padded = pad_replicate(data, width, height, r);
    let net = network_for(side);
    data.par_chunks_mut(width * ROWS_PER_TASK)
        .enumerate()
        .for_each(|(band, rows)| {
            let job = Job {
                padded: &padded,
                width,
                side,
                net,
                y0: band * ROWS_PER_TASK,
            };
            dispatch(&job, rows);
        });
}

/// One band of rows of the median filter.
struct Job<'a> {
    padded: &'a [f32],
    width: usize,
    side: usize,
    net: &'a [(u8, u8)],
    y0: usize,
}

fn dispatch(job: &Job<'_>, rows: &mut [f32]) {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") {
        // SAFETY: the CPU supports AVX2 (checked just above).
        unsafe { median_rows_avx2(job, rows) };
        return;
    }
    median_rows(job, rows);
}

/// [`median_rows`] compiled with AVX2 (same arithmetic, wider vectors: min/max are
/// exact, so the output is identical).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn median_rows_avx2(job: &Job<'_>, rows: &mut [f32]) {
    median_rows(job, rows);
}

#[inline(always)]
fn median_rows(job: &Job<'_>, rows: &mut [f32]) {
    let (width, side) = (job.width, job.side);
    let pw = width + 2 * (side / 2);
    let mid = side * side / 2;
    if width < LANES {
        // Too narrow for a block of lanes: sort each window.
        for (ry, dst) in rows.chunks_exact_mut(width).enumerate() {
            let y = job.y0 + ry;
            for (x, d) in dst.iter_mut().enumerate() {
                let mut win = [0.0f32; 49];
                for dy in 0..side {
                    let prow = &job.padded[(y + dy) * pw..][..pw];
                    win[dy * side..(dy + 1) * side].copy_from_slice(&prow[x..x + side]);
                }
                let win = &mut win[..side * side];
                win.sort_by(f32::total_cmp);
                *d = win[mid];
            }
        }
        return;
    }
    let mut v = [[0.0f32; LANES]; 49];
    for (ry, dst) in rows.chunks_exact_mut(width).enumerate() {
        let y = job.y0 + ry;
        let mut x = 0;
        while x < width {
            // The last block overlaps the previous one instead of running short.
            let x0 = if x + LANES <= width { x } else { width - LANES };
            for dy in 0..side {
                let prow = &job.padded[(y + dy) * pw..][..pw];
                for dx in 0..side {
                    let src: &[f32; LANES] = match prow[x0 + dx..].first_chunk() {
                        Some(c) => c,
                        // Invariant: x0 + dx + LANES <= width + side - 1 < pw.
                        None => return,
                    };
                    v[dy * side + dx] = *src;
                }
            }
            for &(a, b) in job.net {
                let (a, b) = (a as usize, b as usize);
                let (va, vb) = (v[a], v[b]);
                let mut lo = [0.0f32; LANES];
                let mut hi = [0.0f32; LANES];
                for l in 0..LANES {
                    let (p, q) = (va[l], vb[l]);
                    lo[l] = if q < p { q } else { p };
                    hi[l] = if q < p { p } else { q };
                }
                v[a] = lo;
                v[b] = hi;
            }
            dst[x0..x0 + LANES].copy_from_slice(&v[mid]);
            x = x0 + LANES;
        }
    }
}

/// Scalar reference: sort each window.
#[cfg(test)]
pub(crate) fn median_filter_reference(data: &mut [f32], width: usize, height: usize, side: usize) {
    let r = side as isize / 2;
    let src = data.to_vec();
    for y in 0..height as isize {
        for x in 0..width as isize {
            let mut win = Vec::with_capacity(side * side);
            for dy in -r..=r {
                for dx in -r..=r {
                    let yy = (y + dy).clamp(0, height as isize - 1) as usize;
                    let xx = (x + dx).clamp(0, width as isize - 1) as usize;
                    win.push(src[yy * width + xx]);
                }
            }
            win.sort_by(f32::total_cmp);
            data[y as usize * width + x as usize] = win[win.len() / 2];
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::vision::synthetic::SplitMix64;

    #[test]
    fn network_selects_the_median() {
        let mut rng = SplitMix64::new(9);
        for n in [9usize, 25, 49] {
            let net = median_network(n);
            for _ in 0..200 {
                let mut v: Vec<f32> = (0..n)
                    .map(|_| (rng.uniform(-3.0, 3.0) as f32).round())
                    .collect();
                let mut sorted = v.clone();
                sorted.sort_by(f32::total_cmp);
                for &(a, b) in &net {
                    let (a, b) = (a as usize, b as usize);
                    if v[b] < v[a] {
                        v.swap(a, b);
                    }
                }
                assert_eq!(v[n / 2], sorted[n / 2], "n {n}");
            }
        }
        // Far fewer comparators than a full sort of 32 wires (191).
        assert!(median_network(25).len() < 191);
    }

    #[test]
    fn fast_filter_matches_reference() {
        let mut rng = SplitMix64::new(4);
        for (w, h) in [(37usize, 11usize), (5, 9), (3, 3), (16, 16)] {
            for side in [3usize, 5, 7] {
                let src: Vec<f32> = (0..w * h).map(|_| rng.uniform(-5.0, 5.0) as f32).collect();
                let mut fast = src.clone();
                let mut slow = src.clone();
                median_filter(&mut fast, w, h, side);
                median_filter_reference(&mut slow, w, h, side);
                assert_eq!(fast, slow, "{w}x{h} side {side}");
            }
        }
    }
}
