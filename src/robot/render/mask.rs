//! Growing the rendered silhouette into the body mask: a binary dilation by a disc.

/// `out` = `coverage` dilated by a disc of radius `margin_px` (a pixel is set when a
/// covered pixel lies within Euclidean distance `margin_px`). Row-separable: each row
/// offset `dy` of the disc is a horizontal run of half-width `floor(sqrt(r^2 - dy^2))`,
/// so the rows are dilated horizontally once per distinct half-width and OR-ed.
pub(crate) fn grow_mask(
    coverage: &[bool],
    width: usize,
    height: usize,
    margin_px: u32,
    out: &mut Vec<bool>,
) {
    out.clear();
    out.extend_from_slice(coverage);
    if margin_px == 0 || width == 0 || height == 0 {
        return;
    }
    let r = margin_px as i64;
    // Half-width of the disc at each |dy| = 0..=r.
    let half: Vec<usize> = (0..=r)
        .map(|dy| ((r * r - dy * dy) as f64).sqrt().floor() as usize)
        .collect();
    // horizontal[k]: coverage dilated horizontally by half-width k, for the widths used.
    let mut widths: Vec<usize> = half.clone();
    widths.sort_unstable();
    widths.dedup();
    let mut horizontal: Vec<(usize, Vec<bool>)> = Vec::with_capacity(widths.len());
    for &k in &widths {
        let mut dil = vec![false; coverage.len()];
        for y in 0..height {
            let row = &coverage[y * width..(y + 1) * width];
            let dst = &mut dil[y * width..(y + 1) * width];
            // Distance to the nearest covered pixel on the left, then on the right.
            let mut last: Option<usize> = None;
            for x in 0..width {
                if row[x] {
                    last = Some(x);
                }
                dst[x] = last.is_some_and(|l| x - l <= k);
            }
            let mut next: Option<usize> = None;
            for x in (0..width).rev() {
                if row[x] {
                    next = Some(x);
                }
                dst[x] |= next.is_some_and(|l| l - x <= k);
            }
        }
        horizontal.push((k, dil));
    }
    for y in 0..height {
        let dst = &mut out[y * width..(y + 1) * width];
        for dy in -r..=r {
            let sy = y as i64 + dy;
            if sy < 0 || sy >= height as i64 {
                continue;
            }
            let k = half[dy.unsigned_abs() as usize];
            let Some((_, dil)) = horizontal.iter().find(|(w, _)| *w == k) else {
                continue;
            };
            let src = &dil[sy as usize * width..(sy as usize + 1) * width];
            for (d, s) in dst.iter_mut().zip(src) {
                *d |= *s;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Brute force: any covered pixel within distance r.
    fn reference(cov: &[bool], w: usize, h: usize, r: u32) -> Vec<bool> {
        let r2 = (r * r) as i64;
        (0..w * h)
            .map(|i| {
                let (x, y) = ((i % w) as i64, (i / w) as i64);
                (0..w * h).any(|j| {
                    let (a, b) = ((j % w) as i64, (j / w) as i64);
                    cov[j] && (a - x).pow(2) + (b - y).pow(2) <= r2
                })
            })
            .collect()
    }

    #[test]
    fn single_pixel_grows_to_a_disc() {
        let (w, h) = (11, 9);
        let mut cov = vec![false; w * h];
        cov[4 * w + 5] = true;
        let mut out = Vec::new();
        grow_mask(&cov, w, h, 2, &mut out);
        // Disc of radius 2 on the integer grid: 13 pixels.
        assert_eq!(out.iter().filter(|&&m| m).count(), 13);
        assert!(out[4 * w + 7] && out[2 * w + 5] && out[3 * w + 6]);
        assert!(!out[2 * w + 6] && !out[4 * w + 8]);
        grow_mask(&cov, w, h, 0, &mut out);
        assert_eq!(out, cov);
    }

    #[test]
    fn matches_brute_force_on_a_random_pattern() {
        let (w, h) = (23, 17);
        let mut state = 12345u32;
        let cov: Vec<bool> = (0..w * h)
            .map(|_| {
                state = state.wrapping_mul(1_103_515_245).wrapping_add(12345);
                (state >> 16) % 13 == 0
            })
            .collect();
        for r in [1, 2, 3, 5] {
            let mut out = Vec::new();
            grow_mask(&cov, w, h, r, &mut out);
            assert_eq!(out, reference(&cov, w, h, r), "radius {r}");
        }
    }
}
