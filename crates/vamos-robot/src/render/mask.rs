//! Growing the rendered silhouette into the body mask: a binary dilation by a disc.

/// `out` = `coverage` dilated by a disc of radius `margin_px` (a pixel is set when a
/// covered pixel lies within Euclidean distance `margin_px`). Row-separable: a first pass
/// stores each pixel's horizontal distance to the nearest covered pixel of its row
/// (saturated), then a pixel is set when, for some row offset `dy` of the disc, the pixel
/// above or below at that offset has a horizontal distance within the disc's half-width
/// `floor(sqrt(r^2 - dy^2))`. `scratch` holds the distances between calls.
pub(crate) fn grow_mask(
    coverage: &[bool],
    width: usize,
    height: usize,
    margin_px: u32,
    scratch: &mut Vec<u8>,
    out: &mut Vec<bool>,
) {
    out.clear();
    out.extend_from_slice(coverage);
    if margin_px == 0 || width == 0 || height == 0 {
        return;
    }
    let r = margin_px as usize;
    // Saturates above every half-width (margin_px <= MAX_MASK_MARGIN_PX < 255).
    let far = (r + 1).min(255) as u8;
    scratch.clear();
    scratch.resize(coverage.len(), far);
    let mut row_has = vec![false; height];
    for y in 0..height {
        let row = &coverage[y * width..(y + 1) * width];
        if !row.iter().any(|&c| c) {
            continue;
        }
        row_has[y] = true;
        let dist = &mut scratch[y * width..(y + 1) * width];
        let mut d = far;
        for x in 0..width {
            d = if row[x] {
                0
            } else {
                d.saturating_add(1).min(far)
            };
            dist[x] = d;
        }
        d = far;
        for x in (0..width).rev() {
            d = if row[x] {
                0
            } else {
                d.saturating_add(1).min(far)
            };
            dist[x] = dist[x].min(d);
        }
    }
    let half: Vec<u8> = (0..=r)
        .map(|dy| (((r * r - dy * dy) as f64).sqrt().floor() as usize).min(254) as u8)
        .collect();
    for y in 0..height {
        let dst = &mut out[y * width..(y + 1) * width];
        for dy in -(r as i64)..=r as i64 {
            let sy = y as i64 + dy;
            if sy < 0 || sy >= height as i64 || !row_has[sy as usize] {
                continue;
            }
            let k = half[dy.unsigned_abs() as usize];
            let src = &scratch[sy as usize * width..(sy as usize + 1) * width];
            for (d, s) in dst.iter_mut().zip(src) {
                *d |= *s <= k;
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
        grow_mask(&cov, w, h, 2, &mut Vec::new(), &mut out);
        // Disc of radius 2 on the integer grid: 13 pixels.
        assert_eq!(out.iter().filter(|&&m| m).count(), 13);
        assert!(out[4 * w + 7] && out[2 * w + 5] && out[3 * w + 6]);
        assert!(!out[2 * w + 6] && !out[4 * w + 8]);
        grow_mask(&cov, w, h, 0, &mut Vec::new(), &mut out);
        assert_eq!(out, cov);
    }

    #[test]
    fn matches_brute_force_on_a_random_pattern() {
        let (w, h) = (23, 17);
        let mut state = 12345u32;
        let cov: Vec<bool> = (0..w * h)
            .map(|_| {
                state = state.wrapping_mul(1_103_515_245).wrapping_add(12345);
                (state >> 16).is_multiple_of(13)
            })
            .collect();
        for r in [1, 2, 3, 5] {
            let mut out = Vec::new();
            grow_mask(&cov, w, h, r, &mut Vec::new(), &mut out);
            assert_eq!(out, reference(&cov, w, h, r), "radius {r}");
        }
    }
}
