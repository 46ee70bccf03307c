//! Synthetic image pairs with exact ground-truth motion.
//!
//! Used by the accuracy tests, the benchmarks and `vamos demo`: a band-limited random
//! texture is a continuous function of position, so the second image of a pair is the
//! texture sampled through the exact inverse motion, with no resampling error, and the
//! forward flow is known at every pixel.
//!
//! Deterministic from a seed (a local SplitMix64, no `rand` dependency). Imports only
//! [`super::image`].

use super::image::{FlowField, GrayImage};

/// SplitMix64: tiny, fast, good enough for test textures.
#[derive(Clone, Debug)]
pub struct SplitMix64(u64);

impl SplitMix64 {
    /// A generator seeded with `seed`.
    pub fn new(seed: u64) -> Self {
        Self(seed)
    }

    /// Next 64 random bits.
    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    /// Uniform in `[lo, hi)`.
    pub fn uniform(&mut self, lo: f64, hi: f64) -> f64 {
        let unit = (self.next_u64() >> 11) as f64 / (1u64 << 53) as f64;
        lo + (hi - lo) * unit
    }
}

/// A band-limited random texture: a sum of plane waves with wavelengths between
/// `min_wavelength_px` and `max_wavelength_px`, values roughly in 20..235.
#[derive(Clone, Debug)]
pub struct Texture {
    waves: Vec<(f64, f64, f64, f64)>, // (kx, ky, phase, amplitude)
}

impl Texture {
    /// A texture of 48 waves with wavelengths in `[5, 80]` pixels.
    pub fn random(seed: u64) -> Self {
        Self::with_band(seed, 48, 5.0, 80.0)
    }

    /// A texture of `count` waves with wavelengths in `[min, max]` pixels.
    pub fn with_band(
        seed: u64,
        count: usize,
        min_wavelength_px: f64,
        max_wavelength_px: f64,
    ) -> Self {
        let mut rng = SplitMix64::new(seed);
        let total = 100.0;
        let waves = (0..count)
            .map(|_| {
                let angle = rng.uniform(0.0, std::f64::consts::TAU);
                // Log-uniform wavelength: texture at every scale of the pyramid.
                let wl = (rng.uniform(min_wavelength_px.ln(), max_wavelength_px.ln())).exp();
                let k = std::f64::consts::TAU / wl;
                let phase = rng.uniform(0.0, std::f64::consts::TAU);
                let amp = rng.uniform(0.5, 1.5);
                (k * angle.cos(), k * angle.sin(), phase, amp)
            })
            .collect::<Vec<_>>();
        let norm: f64 = waves
            .iter()
            .map(|w| w.3 * w.3)
            .sum::<f64>()
            .sqrt()
            .max(1e-9);
        let waves = waves
            .into_iter()
            .map(|(kx, ky, p, a)| (kx, ky, p, a * total / norm * 0.9))
            .collect();
        Self { waves }
    }

    /// Intensity at a continuous position (pixel centres are integers).
    pub fn eval(&self, x: f64, y: f64) -> f64 {
        let s: f64 = self
            .waves
            .iter()
            .map(|&(kx, ky, p, a)| a * (kx * x + ky * y + p).sin())
            .sum();
        (127.5 + s).clamp(0.0, 255.0)
    }

    /// Samples the texture on a `width x height` grid.
    pub fn render(&self, width: usize, height: usize) -> GrayImage {
        GrayImage::from_fn(width, height, |x, y| self.eval(x as f64, y as f64) as f32)
    }
}

/// A known motion between the two images of a pair.
#[derive(Clone, Debug, PartialEq)]
pub enum Motion {
    /// Every pixel moves by `(dx, dy)` pixels.
    Translation {
        /// Right, pixels.
        dx: f64,
        /// Down, pixels.
        dy: f64,
    },
    /// About the image centre: rotate by `rotation_deg` (positive = counter-clockwise on
    /// screen), scale by `scale`, then translate by `(tx, ty)` pixels.
    Similarity {
        /// Right, pixels.
        tx: f64,
        /// Down, pixels.
        ty: f64,
        /// Content grows when > 1.
        scale: f64,
        /// Degrees, counter-clockwise on screen.
        rotation_deg: f64,
    },
    /// A smooth non-rigid field: a sum of a few Gaussian swirls and pushes whose largest
    /// displacement is about `amplitude_px`.
    Smooth {
        /// Largest displacement, pixels.
        amplitude_px: f64,
        /// Seed of the field.
        seed: u64,
    },
    /// A differently textured square of `size_px` at `(x, y)` (top-left) moves by
    /// `(dx, dy)` over a static background.
    MovingSquare {
        /// Left edge in the first image, pixels.
        x: f64,
        /// Top edge in the first image, pixels.
        y: f64,
        /// Side, pixels.
        size_px: f64,
        /// Right, pixels.
        dx: f64,
        /// Down, pixels.
        dy: f64,
    },
}

/// `m` (a case of [`accuracy_cases`] at `width x height`) with the displacements of the
/// 160x120 case: translations, the smooth amplitude and the square's step shrink by
/// `160 / width` (or `120 / height`, the smaller), as do the rotation angle and the scale
/// change (`benches/compare_flow.py`'s `pixels` scaling); positions and sizes stay.
pub fn with_160x120_displacements(m: Motion, width: usize, height: usize) -> Motion {
    let k = (160.0 / width as f64).min(120.0 / height as f64);
    match m {
        Motion::Translation { dx, dy } => Motion::Translation {
            dx: dx * k,
            dy: dy * k,
        },
        Motion::Similarity {
            tx,
            ty,
            scale,
            rotation_deg,
        } => Motion::Similarity {
            tx,
            ty,
            scale: 1.0 + (scale - 1.0) * k,
            rotation_deg: rotation_deg * k,
        },
        Motion::Smooth { amplitude_px, seed } => Motion::Smooth {
            amplitude_px: amplitude_px * k,
            seed,
        },
        Motion::MovingSquare {
            x,
            y,
            size_px,
            dx,
            dy,
        } => Motion::MovingSquare {
            x,
            y,
            size_px,
            dx: dx * k,
            dy: dy * k,
        },
    }
}

/// The four accuracy cases of the flow tests, benches and sweeps, scaled to a
/// `width x height` image (displacements grow with the width from their 160x120 values):
/// `translation` (2.5, -1.25 px), `rotation` (3 deg about the centre), `smooth`
/// (non-rigid, 3 px), `square` (a square of 0.35 h moving (3, 2) px over a static
/// background).
pub fn accuracy_cases(width: usize, height: usize) -> Vec<(&'static str, Motion)> {
    let s = width as f64 / 160.0;
    vec![
        (
            "translation",
            Motion::Translation {
                dx: 2.5 * s,
                dy: -1.25 * s,
            },
        ),
        (
            "rotation",
            Motion::Similarity {
                tx: 0.0,
                ty: 0.0,
                scale: 1.0,
                rotation_deg: 3.0,
            },
        ),
        (
            "smooth",
            Motion::Smooth {
                amplitude_px: 3.0 * s,
                seed: 2,
            },
        ),
        (
            "square",
            Motion::MovingSquare {
                x: 0.3 * width as f64,
                y: 0.3 * height as f64,
                size_px: 0.35 * height as f64,
                dx: 3.0 * s,
                dy: 2.0 * s,
            },
        ),
    ]
}

/// Forward map of a similarity about `(cx, cy)`: the point `p` of the first image lands
/// at the returned position in the second.
pub fn similarity_forward(
    p: (f64, f64),
    centre: (f64, f64),
    (tx, ty, scale, rotation_deg): (f64, f64, f64, f64),
) -> (f64, f64) {
    let (s, c) = rotation_deg.to_radians().sin_cos();
    let (dx, dy) = (p.0 - centre.0, p.1 - centre.1);
    (
        centre.0 + scale * (c * dx + s * dy) + tx,
        centre.1 + scale * (-s * dx + c * dy) + ty,
    )
}

fn similarity_inverse(
    q: (f64, f64),
    centre: (f64, f64),
    (tx, ty, scale, rotation_deg): (f64, f64, f64, f64),
) -> (f64, f64) {
    let (s, c) = rotation_deg.to_radians().sin_cos();
    let (dx, dy) = ((q.0 - centre.0 - tx) / scale, (q.1 - centre.1 - ty) / scale);
    // R^-1 = R^T with R = [[c, s], [-s, c]].
    (centre.0 + c * dx - s * dy, centre.1 + s * dx + c * dy)
}

struct SmoothField {
    bumps: Vec<(f64, f64, f64, f64, f64)>, // (cx, cy, sigma, ax, ay)
}

impl SmoothField {
    fn new(width: usize, height: usize, amplitude_px: f64, seed: u64) -> Self {
        let mut rng = SplitMix64::new(seed ^ 0x5EED);
        let diag = ((width * width + height * height) as f64).sqrt();
        let bumps = (0..5)
            .map(|_| {
                let cx = rng.uniform(0.0, width as f64);
                let cy = rng.uniform(0.0, height as f64);
                let sigma = rng.uniform(0.2, 0.4) * diag;
                let ang = rng.uniform(0.0, std::f64::consts::TAU);
                let a = rng.uniform(0.4, 1.0) * amplitude_px;
                (cx, cy, sigma, a * ang.cos(), a * ang.sin())
            })
            .collect();
        Self { bumps }
    }

    /// Backward displacement `w(q)`: the second image at `q` shows the first at `q - w(q)`.
    fn at(&self, q: (f64, f64)) -> (f64, f64) {
        self.bumps
            .iter()
            .fold((0.0, 0.0), |acc, &(cx, cy, s, ax, ay)| {
                let d2 = (q.0 - cx).powi(2) + (q.1 - cy).powi(2);
                let g = (-d2 / (2.0 * s * s)).exp();
                (acc.0 + ax * g, acc.1 + ay * g)
            })
    }
}

/// A synthetic pair: `(first, second, forward flow first -> second)`.
///
/// The texture is seeded by `seed`; pixels whose source falls outside the first image
/// still get texture (the texture is infinite), so the whole ground truth is valid except
/// at occlusions of [`Motion::MovingSquare`].
pub fn pair(
    width: usize,
    height: usize,
    motion: &Motion,
    seed: u64,
) -> (GrayImage, GrayImage, FlowField) {
    let tex = Texture::random(seed);
    let centre = ((width as f64 - 1.0) / 2.0, (height as f64 - 1.0) / 2.0);
    match *motion {
        Motion::Translation { dx, dy } => {
            let a = tex.render(width, height);
            let b = GrayImage::from_fn(width, height, |x, y| {
                tex.eval(x as f64 - dx, y as f64 - dy) as f32
            });
            let f = FlowField::from_fn(width, height, |_, _| (dx as f32, dy as f32));
            (a, b, f)
        }
        Motion::Similarity {
            tx,
            ty,
            scale,
            rotation_deg,
        } => {
            let t = (tx, ty, scale, rotation_deg);
            let a = tex.render(width, height);
            let b = GrayImage::from_fn(width, height, |x, y| {
                let p = similarity_inverse((x as f64, y as f64), centre, t);
                tex.eval(p.0, p.1) as f32
            });
            let f = FlowField::from_fn(width, height, |x, y| {
                let q = similarity_forward((x as f64, y as f64), centre, t);
                ((q.0 - x as f64) as f32, (q.1 - y as f64) as f32)
            });
            (a, b, f)
        }
        Motion::Smooth {
            amplitude_px,
            seed: field_seed,
        } => {
            let field = SmoothField::new(width, height, amplitude_px, field_seed);
            let a = tex.render(width, height);
            let b = GrayImage::from_fn(width, height, |x, y| {
                let q = (x as f64, y as f64);
                let w = field.at(q);
                tex.eval(q.0 - w.0, q.1 - w.1) as f32
            });
            // Forward flow at p: the q with q - w(q) = p, by fixed-point iteration
            // (w is smooth and small, so the map is a contraction).
            let f = FlowField::from_fn(width, height, |x, y| {
                let p = (x as f64, y as f64);
                let mut q = p;
                for _ in 0..50 {
                    let w = field.at(q);
                    q = (p.0 + w.0, p.1 + w.1);
                }
                ((q.0 - p.0) as f32, (q.1 - p.1) as f32)
            });
            (a, b, f)
        }
        Motion::MovingSquare {
            x: sx,
            y: sy,
            size_px,
            dx,
            dy,
        } => {
            let fg = Texture::with_band(seed.wrapping_add(1), 32, 4.0, 30.0);
            let inside = |px: f64, py: f64, ox: f64, oy: f64| {
                px >= sx + ox && px < sx + ox + size_px && py >= sy + oy && py < sy + oy + size_px
            };
            let a = GrayImage::from_fn(width, height, |x, y| {
                let (px, py) = (x as f64, y as f64);
                if inside(px, py, 0.0, 0.0) {
                    fg.eval(px - sx, py - sy) as f32
                } else {
                    tex.eval(px, py) as f32
                }
            });
            let b = GrayImage::from_fn(width, height, |x, y| {
                let (px, py) = (x as f64, y as f64);
                if inside(px, py, dx, dy) {
                    fg.eval(px - sx - dx, py - sy - dy) as f32
                } else {
                    tex.eval(px, py) as f32
                }
            });
            let f = FlowField::from_fn(width, height, |x, y| {
                if inside(x as f64, y as f64, 0.0, 0.0) {
                    (dx as f32, dy as f32)
                } else {
                    (0.0, 0.0)
                }
            });
            (a, b, f)
        }
    }
}

/// Pixels covered by a [`Motion::MovingSquare`]'s square in either image, grown by
/// `grow_px`: the mask a caller gives registration so that only the background counts
/// (the square stands in for the robot body). `None` for other motions.
pub fn moving_square_cover(
    width: usize,
    height: usize,
    motion: &Motion,
    grow_px: f64,
) -> Option<Vec<bool>> {
    let Motion::MovingSquare {
        x,
        y,
        size_px,
        dx,
        dy,
    } = *motion
    else {
        return None;
    };
    let inside = |px: f64, py: f64, ox: f64, oy: f64| {
        let (l, t) = (x + ox - grow_px, y + oy - grow_px);
        let side = size_px + 2.0 * grow_px;
        px >= l && px < l + side && py >= t && py < t + side
    };
    Some(
        (0..width * height)
            .map(|i| {
                let (px, py) = ((i % width) as f64, (i / width) as f64);
                inside(px, py, 0.0, 0.0) || inside(px, py, dx, dy)
            })
            .collect(),
    )
}

/// Pixels of a [`Motion::MovingSquare`] pair whose ground truth is defined in both
/// images (not within `margin_px` of the square's outline in either image).
pub fn moving_square_valid(
    width: usize,
    height: usize,
    motion: &Motion,
    margin_px: f64,
) -> Option<Vec<bool>> {
    let Motion::MovingSquare {
        x: sx,
        y: sy,
        size_px,
        dx,
        dy,
    } = *motion
    else {
        return None;
    };
    let near_edge = |px: f64, py: f64, ox: f64, oy: f64| {
        let (l, t) = (sx + ox, sy + oy);
        let (r, b) = (l + size_px, t + size_px);
        let in_outer =
            px >= l - margin_px && px < r + margin_px && py >= t - margin_px && py < b + margin_px;
        let in_inner =
            px >= l + margin_px && px < r - margin_px && py >= t + margin_px && py < b - margin_px;
        in_outer && !in_inner
    };
    let covered_later = |px: f64, py: f64| {
        px >= sx + dx && px < sx + dx + size_px && py >= sy + dy && py < sy + dy + size_px
    };
    let in_first =
        |px: f64, py: f64| px >= sx && px < sx + size_px && py >= sy && py < sy + size_px;
    Some(
        (0..width * height)
            .map(|i| {
                let (px, py) = ((i % width) as f64, (i / width) as f64);
                // Background that the square covers in the second image is occluded.
                let occluded = !in_first(px, py) && covered_later(px, py);
                !(near_edge(px, py, 0.0, 0.0) || near_edge(px, py, dx, dy) || occluded)
            })
            .collect(),
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn texture_is_deterministic_and_textured() {
        let a = Texture::random(7).render(64, 48);
        let b = Texture::random(7).render(64, 48);
        assert_eq!(a, b);
        let mean = a.data().iter().sum::<f32>() / a.data().len() as f32;
        let var = a.data().iter().map(|v| (v - mean).powi(2)).sum::<f32>() / a.data().len() as f32;
        assert!(var.sqrt() > 20.0, "texture too flat: std {}", var.sqrt());
    }

    #[test]
    fn translation_pair_matches_ground_truth() {
        let (a, b, f) = pair(40, 30, &Motion::Translation { dx: 2.0, dy: -1.0 }, 3);
        // Integer shift: b(x + 2, y - 1) == a(x, y).
        assert_eq!(b.get(12, 10), a.get(10, 11));
        assert_eq!(f.get(5, 5), (2.0, -1.0));
    }

    #[test]
    fn similarity_inverse_undoes_forward() {
        let t = (3.0, -2.0, 1.1, 7.0);
        let q = similarity_forward((10.0, 20.0), (32.0, 24.0), t);
        let p = similarity_inverse(q, (32.0, 24.0), t);
        assert!((p.0 - 10.0).abs() < 1e-9 && (p.1 - 20.0).abs() < 1e-9);
        // Positive rotation is counter-clockwise on screen: a point right of the centre
        // moves up (y decreases).
        let r = similarity_forward((42.0, 24.0), (32.0, 24.0), (0.0, 0.0, 1.0, 90.0));
        assert!((r.0 - 32.0).abs() < 1e-9 && (r.1 - 14.0).abs() < 1e-9);
    }

    #[test]
    fn square_cover_spans_both_positions() {
        let m = Motion::MovingSquare {
            x: 10.0,
            y: 10.0,
            size_px: 5.0,
            dx: 3.0,
            dy: 0.0,
        };
        let c = moving_square_cover(30, 30, &m, 1.0).unwrap();
        // x from 9 to 18 (exclusive 19 + ... ), y from 9 to 15.
        assert!(c[9 * 30 + 9] && c[15 * 30 + 18]);
        assert!(!c[8 * 30 + 9] && !c[9 * 30 + 19] && !c[16 * 30 + 12]);
        assert_eq!(c.iter().filter(|&&v| v).count(), 10 * 7);
        assert!(
            moving_square_cover(30, 30, &Motion::Translation { dx: 1.0, dy: 0.0 }, 1.0).is_none()
        );
    }

    #[test]
    fn smooth_field_flow_is_consistent() {
        let m = Motion::Smooth {
            amplitude_px: 3.0,
            seed: 1,
        };
        let (a, b, f) = pair(64, 48, &m, 5);
        let tex = Texture::random(5);
        // The content at p in a appears at p + flow(p) in b.
        let (u, v) = f.get(20, 30);
        let field = SmoothField::new(64, 48, 3.0, 1);
        let q = (20.0 + u as f64, 30.0 + v as f64);
        let w = field.at(q);
        assert!((q.0 - w.0 - 20.0).abs() < 1e-4 && (q.1 - w.1 - 30.0).abs() < 1e-4);
        assert_eq!(a.get(20, 30), tex.eval(20.0, 30.0) as f32);
        assert!(b.data().iter().all(|v| v.is_finite()));
    }
}
