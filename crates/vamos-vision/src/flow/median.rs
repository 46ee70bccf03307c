//! Square median filter of a flow component (replicated border, as `cv::medianBlur`).
//!
//! The fast path runs a selection network over [`LANES`] horizontally adjacent pixels at
//! once: each compare-exchange is a lane-wise min/max, which the compiler vectorises.
//! The network is Batcher's odd-even merge sort for the next power of two (the padding
//! wires hold +inf, so comparators that touch them are no-ops and are dropped), pruned
//! to the comparators that the middle output depends on. A sort-based scalar reference
//! checks it.

use std::sync::OnceLock;

use super::pyramid::{ROWS_PER_TASK, for_each_band};

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

/// Copy of `src` with a replicated border of `r` pixels on each side, into `out`.
fn pad_replicate(src: &[f32], width: usize, height: usize, r: usize, out: &mut Vec<f32>) {
    let pw = width + 2 * r;
    out.resize(pw * (height + 2 * r), 0.0);
    for (py, dst) in out.chunks_exact_mut(pw).enumerate() {
        let y = py.saturating_sub(r).min(height - 1);
        let row = &src[y * width..(y + 1) * width];
        dst[r..r + width].copy_from_slice(row);
        let (first, last) = (row[0], row[width - 1]);
        dst[..r].fill(first);
        dst[r + width..].fill(last);
    }
}

/// Median filter of side `side` (3, 5 or 7) in place; other sides leave `data` as is.
/// `scratch` holds the padded copy (reused across calls to save the allocation).
pub(crate) fn median_filter(
    data: &mut [f32],
    width: usize,
    height: usize,
    side: usize,
    scratch: &mut Vec<f32>,
) {
    if !matches!(side, 3 | 5 | 7) {
        return;
    }
    let r = side / 2;
    pad_replicate(data, width, height, r, scratch);
    let padded = &scratch[..];
    let net = network_for(side);
    for_each_band(data, width, |band, rows| {
        let job = Job {
            padded,
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
    if side == 5 {
        median5_rows(job, rows);
        return;
    }
    if side == 3 {
        median3_rows(job, rows);
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

/// Lane-wise compare-exchange of the wires `(a, b)` of `v` (`a` gets the minimum); the
/// indices are literals, so the wires stay in registers.
macro_rules! exchange {
    ($v:ident; $(($a:literal, $b:literal)),* $(,)?) => {
        $( cx(&mut $v, $a, $b); )*
    };
}

#[inline(always)]
fn cx<const N: usize>(v: &mut [[f32; LANES]; N], a: usize, b: usize) {
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

/// Sorts 5 values: rank `r` ends on wire `r`.
macro_rules! sort5 {
    ($v:ident) => {
        exchange!($v; (0, 1), (2, 3), (0, 2), (1, 3), (1, 2), (0, 4), (2, 4), (1, 2), (3, 4))
    };
}
/// Merges two sorted runs of 5 (wires 0..5 and 5..10); rank `r` ends on `MERGE_5_5_OUT[r]`.
macro_rules! merge_5_5 {
    ($v:ident) => {
        exchange!($v; (0, 5), (4, 9), (4, 5), (2, 7), (2, 4), (7, 5), (1, 6), (3, 8), (3, 6), (1, 2), (3, 4), (6, 7), (8, 5))
    };
}
const MERGE_5_5_OUT: [u8; 10] = [0, 1, 2, 3, 4, 6, 7, 8, 5, 9];
/// Ranks 7..=12 of the union of two sorted runs of 10 (wires 0..10 and 10..20): rank
/// `7 + j` ends on `MID_10_10_OUT[j]`. Only those ranks can be the median of 25 once a
/// fifth sorted column is added (any other rank has 14 values on one side).
macro_rules! mid_10_10 {
    ($v:ident) => {
        exchange!($v; (0, 10), (8, 18), (8, 10), (4, 14), (4, 8), (14, 10), (2, 12), (6, 16), (6, 12), (6, 8), (12, 14), (1, 11), (9, 19), (9, 11), (5, 15), (5, 9), (15, 11), (3, 13), (7, 17), (7, 13), (7, 9), (13, 15), (7, 8), (9, 12), (13, 14))
    };
}
const MID_10_10_OUT: [u8; 6] = [7, 8, 9, 12, 13, 14];
/// Rank 5 of the union of a sorted run of 6 (wires 0..6: ranks 7..=12 of four columns)
/// and a sorted run of 5 (wires 6..11: the fifth column), which is the median of the
/// 25; it ends on wire 5.
macro_rules! select_6_5 {
    ($v:ident) => {
        exchange!($v; (0, 6), (4, 10), (4, 6), (2, 8), (8, 6), (1, 7), (5, 7), (3, 9), (3, 5), (5, 8))
    };
}

/// `LANES` values from the start of `s`.
#[inline(always)]
fn load(s: &[f32]) -> [f32; LANES] {
    let mut a = [0.0f32; LANES];
    a.copy_from_slice(&s[..LANES]);
    a
}

/// Starts of blocks of `LANES` covering `0..len` (`len >= LANES`); the last block
/// overlaps the one before instead of running short (every stage is a pure function of
/// its inputs, so writing a value twice writes it identically).
fn blocks(len: usize) -> impl Iterator<Item = usize> {
    (0..len.div_ceil(LANES)).map(move |b| (b * LANES).min(len - LANES))
}

/// Lane-wise `(min, max)`.
#[inline(always)]
fn minmax(p: [f32; LANES], q: [f32; LANES]) -> ([f32; LANES], [f32; LANES]) {
    let mut v = [p, q];
    cx(&mut v, 0, 1);
    (v[0], v[1])
}

/// Lane-wise median of three.
#[inline(always)]
fn med3(a: [f32; LANES], b: [f32; LANES], c: [f32; LANES]) -> [f32; LANES] {
    let (lo, hi) = minmax(a, b);
    let (_, m) = minmax(lo, c);
    minmax(m, hi).0
}

/// 3x3 median of the rows of a band (`width >= LANES`): each 3-pixel column of the
/// padded image is sorted once (3 compare-exchanges), and the median of a window is
/// the median of the largest of its three column minima, the median of its three
/// column medians and the smallest of its three column maxima (an exact identity for
/// nine values in sorted columns): 3 compare-exchanges per column, then four minima or
/// maxima and two medians of three per pixel, instead of the 19 exchanges of the
/// direct network.
#[inline(always)]
fn median3_rows(job: &Job<'_>, rows: &mut [f32]) {
    let width = job.width;
    let pw = width + 2;
    let mut cols = vec![0.0f32; 3 * pw];
    for (ry, dst) in rows.chunks_exact_mut(width).enumerate() {
        let y = job.y0 + ry;
        let src = &job.padded[y * pw..(y + 3) * pw];
        for x0 in blocks(pw) {
            let mut v = [[0.0f32; LANES]; 3];
            for k in 0..3 {
                v[k] = load(&src[k * pw + x0..]);
            }
            exchange!(v; (0, 1), (1, 2), (0, 1));
            for k in 0..3 {
                cols[k * pw + x0..][..LANES].copy_from_slice(&v[k]);
            }
        }
        let (lo, rest) = cols.split_at(pw);
        let (mid, hi) = rest.split_at(pw);
        for x0 in blocks(width) {
            let at = |c: &[f32], d: usize| load(&c[x0 + d..]);
            let low = minmax(minmax(at(lo, 0), at(lo, 1)).1, at(lo, 2)).1;
            let high = minmax(minmax(at(hi, 0), at(hi, 1)).0, at(hi, 2)).0;
            let m = med3(at(mid, 0), at(mid, 1), at(mid, 2));
            dst[x0..x0 + LANES].copy_from_slice(&med3(low, m, high));
        }
    }
}

/// 5x5 median of the rows of a band (`width >= LANES`), sharing work between
/// neighbouring windows: each 5-pixel column of the padded image is sorted once (9
/// compare-exchanges), adjacent sorted columns are merged into runs of 10 once (13),
/// two runs of 10 give the ranks 7..=12 of four columns (25), and the median of a
/// window is selected from those and its fifth sorted column (10): 57 compare-exchanges
/// per pixel instead of the 113 of the direct network of 25.
#[inline(always)]
fn median5_rows(job: &Job<'_>, rows: &mut [f32]) {
    let width = job.width;
    let pw = width + 4;
    let pn = width + 2;
    let mut cols = vec![0.0f32; 5 * pw];
    let mut pairs = vec![0.0f32; 10 * pn];
    let mut mids = vec![0.0f32; 6 * width];
    for (ry, dst) in rows.chunks_exact_mut(width).enumerate() {
        let y = job.y0 + ry;
        let src = &job.padded[y * pw..(y + 5) * pw];
        for x0 in blocks(pw) {
            let mut v = [[0.0f32; LANES]; 5];
            for k in 0..5 {
                v[k] = load(&src[k * pw + x0..]);
            }
            sort5!(v);
            for k in 0..5 {
                cols[k * pw + x0..][..LANES].copy_from_slice(&v[k]);
            }
        }
        for x0 in blocks(pn) {
            let mut v = [[0.0f32; LANES]; 10];
            for k in 0..5 {
                v[k] = load(&cols[k * pw + x0..]);
                v[5 + k] = load(&cols[k * pw + x0 + 1..]);
            }
            merge_5_5!(v);
            for (r, &o) in MERGE_5_5_OUT.iter().enumerate() {
                pairs[r * pn + x0..][..LANES].copy_from_slice(&v[o as usize]);
            }
        }
        for x0 in blocks(width) {
            let mut v = [[0.0f32; LANES]; 20];
            for r in 0..10 {
                v[r] = load(&pairs[r * pn + x0..]);
                v[10 + r] = load(&pairs[r * pn + x0 + 2..]);
            }
            mid_10_10!(v);
            for (j, &o) in MID_10_10_OUT.iter().enumerate() {
                mids[j * width + x0..][..LANES].copy_from_slice(&v[o as usize]);
            }
        }
        for x0 in blocks(width) {
            let mut v = [[0.0f32; LANES]; 11];
            for j in 0..6 {
                v[j] = load(&mids[j * width + x0..]);
            }
            for k in 0..5 {
                v[6 + k] = load(&cols[k * pw + x0 + 4..]);
            }
            select_6_5!(v);
            dst[x0..x0 + LANES].copy_from_slice(&v[5]);
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
    use crate::synthetic::SplitMix64;

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
        let sizes = [
            (37usize, 11usize),
            (5, 9),
            (3, 3),
            (16, 16),
            (8, 5),
            (9, 2),
            (70, 19),
        ];
        // Continuous values, then many ties (rounded values).
        for (round, (w, h)) in [false, true]
            .into_iter()
            .flat_map(|r| sizes.map(|s| (r, s)))
        {
            for side in [3usize, 5, 7] {
                let src: Vec<f32> = (0..w * h)
                    .map(|_| {
                        let v = rng.uniform(-5.0, 5.0) as f32;
                        if round { v.round() + 0.5 } else { v }
                    })
                    .collect();
                let mut fast = src.clone();
                let mut slow = src.clone();
                median_filter(&mut fast, w, h, side, &mut Vec::new());
                median_filter_reference(&mut slow, w, h, side);
                assert_eq!(fast, slow, "{w}x{h} side {side}");
            }
        }
    }
}
