//! TV-L1 optical flow: the duality-based method of Zach, Pock and Bischof (2007) with
//! Chambolle's projection, coarse-to-fine with warps, as OpenCV's `DualTVL1`.
//!
//! # Direction and units
//! [`tvl1`]`(prev, cur)` returns the **forward** flow `prev -> cur` in **pixels of the
//! input images**: the content at `(x, y)` in `prev` is at `(x + u, y + v)` in `cur` (x
//! right, y down). This is what OpenCV's `DualTVL1OpticalFlow::calc(prev, cur)` returns.
//! (The paper's reference code called it with the frames swapped, current -> previous,
//! i.e. the negative of forward motion; vamos always uses forward flow.) Intensities are
//! in 0..=255 units; the data weight `lambda` is tuned for that range.
//!
//! # Layout
//! - [`params`]: [`FlowParams`] (OpenCV's defaults), the `realtime`, `realtime-hq` and `balanced`
//!   presets, validation.
//! - `pyramid`: OpenCV-geometry bilinear pyramid, gradients, flow resizing.
//! - `warp`: bicubic / bilinear warp and linearisation of the data term.
//! - `median`: vectorised median filter of the flow.
//! - `tvl1`: the per-level solver, with a scalar reference and a fused fast kernel.
//!
//! # Size rule
//! Levels smaller than [`MIN_LEVEL_SIZE_PX`] on a side are not built (so small images
//! use fewer than `n_scales` levels, as OpenCV does); an image smaller than that on a
//! side is [`FlowError::TooSmall`].
//!
//! # Threads and kernels
//! Passes over levels of at least 16k pixels run on the ambient rayon pool over row
//! bands when it has more than one thread; smaller ones, and all with one thread, run on
//! the calling thread. Results are bit-for-bit identical whatever the number of threads
//! (tested with pools of 1 and 2). On x86-64 with AVX2 and FMA the warp and the inner
//! iteration use vectorised kernels with FMA and refined reciprocal / square-root
//! estimates; they differ from the exact scalar kernels by about 1e-5 px on average (the
//! tests bound it), and the estimator reuses its buffers from frame to frame.
//!
//! This module imports only [`crate::image`] (and `synthetic` in tests).

mod median;
pub mod params;
mod planes;
mod pyramid;
mod tvl1;
mod warp;

pub use params::{FlowParams, Interpolation, PRESET_NAMES};

use crate::image::{FlowField, GrayImage};
use pyramid::{Pyramid, level_count, resize_bilinear_into};
use tvl1::{Dual, Kernel, LevelPlan, Workspace, solve_level};

/// Smallest side of a pyramid level, pixels; also the smallest accepted image side.
pub const MIN_LEVEL_SIZE_PX: usize = 16;

/// Errors of the flow estimation.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum FlowError {
    /// The two images (or a frame and the estimator's previous frame) differ in size.
    #[error("image is {width}x{height} but {expected_width}x{expected_height} was expected")]
    SizeMismatch {
        /// Width of the first / cached image, pixels.
        expected_width: usize,
        /// Height of the first / cached image, pixels.
        expected_height: usize,
        /// Width of the offending image, pixels.
        width: usize,
        /// Height of the offending image, pixels.
        height: usize,
    },
    /// An image has no pixels.
    #[error("image is empty ({width}x{height})")]
    EmptyImage {
        /// Width, pixels.
        width: usize,
        /// Height, pixels.
        height: usize,
    },
    /// An image is too small for the method.
    #[error("image is {width}x{height}; TV-L1 needs at least {min_side_px}x{min_side_px}")]
    TooSmall {
        /// Width, pixels.
        width: usize,
        /// Height, pixels.
        height: usize,
        /// Smallest accepted side, pixels.
        min_side_px: usize,
    },
    /// A pixel is NaN or infinite.
    #[error("pixel ({x}, {y}) is not finite ({value})")]
    NonFinite {
        /// Column of the first offending pixel.
        x: usize,
        /// Row of the first offending pixel.
        y: usize,
        /// Its value.
        value: f32,
    },
    /// A parameter is out of range.
    #[error("invalid flow parameter {field}: {reason}")]
    InvalidParams {
        /// The field of [`FlowParams`].
        field: &'static str,
        /// What is wrong with it.
        reason: String,
    },
    /// [`FlowParams::preset`] got an unknown name.
    #[error("unknown flow preset {name:?} (known: {known})")]
    UnknownPreset {
        /// The name given.
        name: String,
        /// The names accepted.
        known: String,
    },
}

/// Checks that `image` can be processed (non-empty, large enough, finite).
fn validate_image(image: &GrayImage) -> Result<(), FlowError> {
    let (width, height) = image.size();
    if width == 0 || height == 0 {
        return Err(FlowError::EmptyImage { width, height });
    }
    if width < MIN_LEVEL_SIZE_PX || height < MIN_LEVEL_SIZE_PX {
        return Err(FlowError::TooSmall {
            width,
            height,
            min_side_px: MIN_LEVEL_SIZE_PX,
        });
    }
    if let Some(i) = image.data().iter().position(|v| !v.is_finite()) {
        return Err(FlowError::NonFinite {
            x: i % width,
            y: i / width,
            value: image.data()[i],
        });
    }
    Ok(())
}

/// A frame's pyramid, cached between pushes.
#[derive(Clone, Debug)]
struct Cached {
    width: usize,
    height: usize,
    pyramid: Pyramid,
}

/// Streaming TV-L1: push frames, get the flow from the previous frame to each new one.
///
/// Each frame's pyramid (images and gradients at every level) is built exactly once:
/// it serves as the target of the flow when the frame is pushed and as the source when
/// the next frame is pushed.
#[derive(Clone, Debug)]
pub struct FlowEstimator {
    params: FlowParams,
    prev: Option<Cached>,
    kernel: Kernel,
    /// Buffers reused by every level of every frame.
    work: Workspace,
    /// Flow and dual arrays of the level being solved and of the next finer one.
    flow_bufs: [Vec<f32>; 4],
    duals: [Dual; 2],
}

impl FlowEstimator {
    /// An estimator with validated `params` and no cached frame.
    pub fn new(params: FlowParams) -> Result<Self, FlowError> {
        params.validate()?;
        Ok(Self {
            params,
            prev: None,
            kernel: Kernel::Fast,
            work: Workspace::default(),
            flow_bufs: Default::default(),
            duals: [Dual::zeros(0), Dual::zeros(0)],
        })
    }

    /// The parameters.
    pub fn params(&self) -> &FlowParams {
        &self.params
    }

    /// Forgets the cached frame: the next push returns `None`.
    pub fn reset(&mut self) {
        self.prev = None;
    }

    /// Adds a frame. Returns `None` for the first frame (after `new` or `reset`), else
    /// the forward flow from the previous frame to `frame`.
    ///
    /// A frame that fails validation ([`FlowError::EmptyImage`], [`FlowError::TooSmall`],
    /// [`FlowError::NonFinite`]) or differs in size from the cached one
    /// ([`FlowError::SizeMismatch`]) is rejected and leaves the cache as it was; call
    /// [`reset`](Self::reset) to start over at a new size.
    pub fn push(&mut self, frame: &GrayImage) -> Result<Option<FlowField>, FlowError> {
        validate_image(frame)?;
        let (width, height) = frame.size();
        if let Some(prev) = &self.prev
            && (prev.width, prev.height) != (width, height)
        {
            return Err(FlowError::SizeMismatch {
                expected_width: prev.width,
                expected_height: prev.height,
                width,
                height,
            });
        }
        let p = &self.params;
        let levels = level_count(width, height, p.n_scales, p.scale_step, MIN_LEVEL_SIZE_PX);
        let finest = p.finest_scale.min(levels - 1);
        let pyramid = Pyramid::build(frame.data(), width, height, levels, p.scale_step, finest);
        let flow = match self.prev.take() {
            Some(prev) => {
                let flow = self.flow_between(&prev.pyramid, &pyramid, width, height, finest);
                Some(flow)
            }
            None => None,
        };
        self.prev = Some(Cached {
            width,
            height,
            pyramid,
        });
        Ok(flow)
    }

    /// Coarse-to-fine TV-L1 between two pyramids of the same geometry.
    fn flow_between(
        &mut self,
        p0: &Pyramid,
        p1: &Pyramid,
        width: usize,
        height: usize,
        finest: usize,
    ) -> FlowField {
        let p = &self.params;
        let [mut u1, mut u2, mut f1, mut f2] = std::mem::take(&mut self.flow_bufs);
        let [mut dual, mut next] =
            std::mem::replace(&mut self.duals, [Dual::zeros(0), Dual::zeros(0)]);
        let coarsest = p0.levels.len() - 1;
        let top = &p0.levels[coarsest];
        let n_top = top.width * top.height;
        for u in [&mut u1, &mut u2] {
            u.clear();
            u.resize(n_top, 0.0);
        }
        dual.reset(n_top);
        let mut s = coarsest;
        loop {
            let (l0, l1) = (&p0.levels[s], &p1.levels[s]);
            let plan = LevelPlan::new(p, s == finest);
            solve_level(
                l0,
                l1,
                &mut u1,
                &mut u2,
                &mut dual,
                p,
                plan,
                self.kernel,
                &mut self.work,
            );
            if s == finest {
                break;
            }
            // Upscale to the next finer level (OpenCV: resize to its size, then multiply
            // by 1 / scale_step).
            let fine = &p0.levels[s - 1];
            let src = (l0.width, l0.height);
            let dst = (fine.width, fine.height);
            let inv = (
                l0.width as f32 / fine.width as f32,
                l0.height as f32 / fine.height as f32,
            );
            let k = 1.0 / p.scale_step;
            for (coarse, fine) in [(&u1, &mut f1), (&u2, &mut f2)] {
                fine.resize(dst.0 * dst.1, 0.0);
                resize_bilinear_into(coarse, src, dst, inv, fine);
                fine.iter_mut().for_each(|v| *v *= k);
            }
            std::mem::swap(&mut u1, &mut f1);
            std::mem::swap(&mut u2, &mut f2);
            // The dual is dimensionless and bounded by 1 in norm; bilinear interpolation
            // keeps that bound (a convex combination), so no rescaling.
            if p.warm_start_dual {
                next.resize(dst.0 * dst.1);
                for (fine, coarse) in next.parts_mut().into_iter().zip(dual.parts()) {
                    resize_bilinear_into(coarse, src, dst, inv, fine);
                }
            } else {
                next.reset(dst.0 * dst.1);
            }
            std::mem::swap(&mut dual, &mut next);
            s -= 1;
        }
        let mut flow = FlowField::zeros(width, height);
        if finest > 0 {
            let l = &p0.levels[finest];
            let ratio = (p.scale_step as f64).powi(finest as i32) as f32;
            let src = (l.width, l.height);
            let k = 1.0 / ratio;
            for (coarse, out) in [(&u1, &mut flow.u), (&u2, &mut flow.v)] {
                resize_bilinear_into(coarse, src, (width, height), (ratio, ratio), out);
                out.iter_mut().for_each(|v| *v *= k);
            }
        } else {
            flow.u.copy_from_slice(&u1);
            flow.v.copy_from_slice(&u2);
        }
        self.flow_bufs = [u1, u2, f1, f2];
        self.duals = [dual, next];
        flow
    }
}

/// Forward TV-L1 flow `prev -> cur` in pixels (see the module docs for conventions).
///
/// A thin wrapper over [`FlowEstimator`]: validates `params` and both images.
pub fn tvl1(
    prev: &GrayImage,
    cur: &GrayImage,
    params: &FlowParams,
) -> Result<FlowField, FlowError> {
    let mut est = FlowEstimator::new(params.clone())?;
    flow_pair(&mut est, prev, cur)
}

fn flow_pair(
    est: &mut FlowEstimator,
    prev: &GrayImage,
    cur: &GrayImage,
) -> Result<FlowField, FlowError> {
    validate_image(prev)?;
    validate_image(cur)?;
    if prev.size() != cur.size() {
        return Err(FlowError::SizeMismatch {
            expected_width: prev.width(),
            expected_height: prev.height(),
            width: cur.width(),
            height: cur.height(),
        });
    }
    est.push(prev)?;
    match est.push(cur)? {
        Some(flow) => Ok(flow),
        // Invariant: the estimator had a cached frame (`prev`), so push returns a flow.
        None => Err(FlowError::EmptyImage {
            width: cur.width(),
            height: cur.height(),
        }),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::synthetic::{Motion, moving_square_valid, pair};

    fn smooth_pair(w: usize, h: usize, seed: u64) -> (GrayImage, GrayImage, FlowField) {
        pair(
            w,
            h,
            &Motion::Smooth {
                amplitude_px: 2.0,
                seed,
            },
            seed,
        )
    }

    /// Cheap parameters for the tests that compare two code paths (the crate is built
    /// unoptimised in `cargo test`).
    fn quick() -> FlowParams {
        FlowParams {
            n_scales: 3,
            warps: 2,
            outer_iterations: 2,
            inner_iterations: 10,
            ..FlowParams::default()
        }
    }

    fn aee(w: usize, h: usize, m: &Motion, p: &FlowParams) -> f64 {
        let (a, b, gt) = pair(w, h, m, 7);
        let f = tvl1(&a, &b, p).unwrap();
        let valid = moving_square_valid(w, h, m, 2.0);
        f.average_endpoint_error(&gt, valid.as_deref()).unwrap()
    }

    #[test]
    fn translation_accuracy_small() {
        let m = Motion::Translation { dx: 2.5, dy: -1.25 };
        let e = aee(80, 60, &m, &FlowParams::default());
        println!("translation 80x60 default AEE {e:.4}");
        assert!(e < 0.15, "AEE {e}");
    }

    /// Largest endpoint difference between the fast kernel (hardware reciprocal and
    /// square-root estimates, FMA) and the exact reference, pixels. The estimates differ
    /// from exact arithmetic by about 1e-7 relative per step; a pixel whose residual sits
    /// right at a threshold of the data term can then take the other branch, which moves
    /// its flow by up to `lambda theta |grad I|`-sized steps that the next iterations
    /// mostly undo. Measured on the pairs of the tests below: largest difference 1e-4 to
    /// 1e-2 px (the 1e-2 with `realtime`), mean 1e-6 to 3e-5 px.
    const FAST_MAX_DIFF_PX: f32 = 0.05;
    /// Mean endpoint difference bound, pixels.
    const FAST_MEAN_DIFF_PX: f64 = 1e-3;

    /// The flow of `(a, b)` with one kernel.
    fn flow_with(kernel: Kernel, a: &GrayImage, b: &GrayImage, p: &FlowParams) -> FlowField {
        let mut est = FlowEstimator::new(p.clone()).unwrap();
        est.kernel = kernel;
        est.push(a).unwrap();
        est.push(b).unwrap().unwrap()
    }

    /// The portable fused kernel equals the reference bit-for-bit; the fast one (what
    /// `tvl1` runs) stays within the bounds above. Returns the largest difference.
    fn kernels_agree(a: &GrayImage, b: &GrayImage, p: &FlowParams) -> f32 {
        let reference = flow_with(Kernel::Reference, a, b, p);
        assert_eq!(flow_with(Kernel::Portable, a, b, p), reference);
        let fast = tvl1(a, b, p).unwrap();
        assert_eq!(fast, flow_with(Kernel::Fast, a, b, p));
        let (w, h) = fast.size();
        let mut max = 0.0f32;
        for y in 0..h {
            for x in 0..w {
                let (f, r) = (fast.get(x, y), reference.get(x, y));
                max = max.max((f.0 - r.0).hypot(f.1 - r.1));
            }
        }
        let mean = fast.average_endpoint_error(&reference, None).unwrap();
        println!("fast vs reference {w}x{h}: max {max:.2e} px, mean {mean:.2e} px");
        assert!(max <= FAST_MAX_DIFF_PX, "max difference {max} px");
        assert!(mean <= FAST_MEAN_DIFF_PX, "mean difference {mean} px");
        max
    }

    #[test]
    fn fast_kernel_matches_reference_end_to_end() {
        for (w, h, seed) in [(40, 32, 3), (97, 61, 4), (192, 128, 5)] {
            let (a, b, _) = smooth_pair(w, h, seed);
            kernels_agree(&a, &b, &quick());
        }
        let (a, b, _) = smooth_pair(160, 120, 6);
        kernels_agree(&a, &b, &FlowParams::realtime());
    }

    #[test]
    fn same_result_with_one_and_two_threads() {
        // Big enough that the finest level runs on the pool with two threads.
        let (a, b, _) = smooth_pair(192, 128, 5);
        let p = quick();
        let run = |threads: usize| {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap();
            pool.install(|| tvl1(&a, &b, &p).unwrap())
        };
        assert_eq!(run(1), run(2));
    }

    #[test]
    fn estimator_reuses_frames() {
        let (a, b, _) = smooth_pair(48, 40, 1);
        let (_, c, _) = smooth_pair(48, 40, 2);
        let p = quick();
        let mut est = FlowEstimator::new(p.clone()).unwrap();
        assert!(est.push(&a).unwrap().is_none());
        assert_eq!(est.push(&b).unwrap().unwrap(), tvl1(&a, &b, &p).unwrap());
        assert_eq!(est.push(&c).unwrap().unwrap(), tvl1(&b, &c, &p).unwrap());
        assert_eq!(est.params(), &p);
        est.reset();
        assert!(est.push(&c).unwrap().is_none());
    }

    #[test]
    fn size_mismatch_is_an_error_and_keeps_the_cache() {
        let (a, b, _) = smooth_pair(48, 40, 1);
        let small = GrayImage::zeros(32, 32);
        let p = quick();
        assert!(matches!(
            tvl1(&a, &small, &p),
            Err(FlowError::SizeMismatch {
                expected_width: 48,
                width: 32,
                ..
            })
        ));
        let mut est = FlowEstimator::new(p.clone()).unwrap();
        est.push(&a).unwrap();
        assert!(matches!(
            est.push(&small),
            Err(FlowError::SizeMismatch { .. })
        ));
        // The cached frame is still `a`.
        assert_eq!(est.push(&b).unwrap().unwrap(), tvl1(&a, &b, &p).unwrap());
    }

    #[test]
    fn empty_and_too_small_images_are_errors() {
        let p = FlowParams::default();
        let empty = GrayImage::zeros(0, 10);
        assert!(matches!(
            tvl1(&empty, &empty, &p),
            Err(FlowError::EmptyImage { width: 0, .. })
        ));
        let tiny = GrayImage::zeros(15, 40);
        let err = tvl1(&tiny, &tiny, &p).unwrap_err();
        assert!(matches!(
            err,
            FlowError::TooSmall {
                width: 15,
                min_side_px: 16,
                ..
            }
        ));
        assert!(err.to_string().contains("16x16"));
        // The minimum itself works (one level).
        let (a, b, _) = smooth_pair(16, 16, 1);
        assert_eq!(tvl1(&a, &b, &quick()).unwrap().size(), (16, 16));
    }

    #[test]
    fn non_finite_pixels_are_errors() {
        let (a, b, _) = smooth_pair(32, 24, 1);
        for bad in [f32::NAN, f32::INFINITY, f32::NEG_INFINITY] {
            let mut c = b.clone();
            c.data_mut()[3 * 32 + 7] = bad;
            match tvl1(&a, &c, &quick()) {
                Err(FlowError::NonFinite { x, y, .. }) => assert_eq!((x, y), (7, 3)),
                other => panic!("{bad}: unexpected {other:?}"),
            }
        }
    }

    #[test]
    fn invalid_params_are_errors() {
        let (a, b, _) = smooth_pair(32, 24, 1);
        let p = FlowParams {
            scale_step: 1.5,
            ..FlowParams::default()
        };
        assert!(matches!(
            tvl1(&a, &b, &p),
            Err(FlowError::InvalidParams {
                field: "scale_step",
                ..
            })
        ));
        assert!(FlowEstimator::new(p).is_err());
    }

    #[test]
    fn finest_scale_returns_full_resolution_flow() {
        let m = Motion::Translation { dx: 2.0, dy: 1.0 };
        let (a, b, gt) = pair(64, 48, &m, 3);
        let p = FlowParams {
            finest_scale: 1,
            ..quick()
        };
        let f = tvl1(&a, &b, &p).unwrap();
        assert_eq!(f.size(), (64, 48));
        let e = f.average_endpoint_error(&gt, None).unwrap();
        assert!(e < 0.5, "AEE {e}");
    }

    /// The solver knobs off the OpenCV path: dual carried across levels, one warp on the
    /// finest level. Still accurate, and the fast kernel still equals the reference.
    #[test]
    fn warm_start_dual_and_finest_warps() {
        let m = Motion::Translation { dx: 2.0, dy: 1.0 };
        let (a, b, gt) = pair(64, 48, &m, 3);
        let p = FlowParams {
            warm_start_dual: true,
            finest_warps: 1,
            warps: 3,
            ..quick()
        };
        let f = tvl1(&a, &b, &p).unwrap();
        let e = f.average_endpoint_error(&gt, None).unwrap();
        assert!(e < 0.5, "AEE {e}");
        kernels_agree(&a, &b, &p);
    }

    /// The per-level knobs: the fast kernel still equals the scalar reference end to
    /// end, and the flow is still close to the truth.
    #[test]
    fn level_knobs_match_reference() {
        let m = Motion::Translation { dx: 2.0, dy: 1.0 };
        let (a, b, gt) = pair(64, 48, &m, 3);
        let p = FlowParams {
            warm_start_dual: true,
            finest_warps: 1,
            finest_inner_iterations: 4,
            coarse_interpolation: Some(Interpolation::Bilinear),
            coarse_median_filter: Some(3),
            warps: 3,
            ..quick()
        };
        let f = tvl1(&a, &b, &p).unwrap();
        let e = f.average_endpoint_error(&gt, None).unwrap();
        assert!(e < 0.5, "AEE {e}");
        kernels_agree(&a, &b, &p);
    }
}
