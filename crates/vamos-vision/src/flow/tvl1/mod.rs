//! The TV-L1 solver of one pyramid level (Zach, Pock, Bischof 2007; Chambolle's
//! projection for the dual variable), in the iteration order of OpenCV `DualTVL1`.
//!
//! Per warp: linearise the data term at the current flow ([`super::warp`]); then outer
//! iterations, each a median filter of the flow followed by inner iterations of
//! 1. thresholding: `v = u + TH(rho(u))` with `TH` the soft threshold at `lambda theta`,
//! 2. primal update: `u = v + theta div p`,
//! 3. dual update: `p = (p + (tau/theta) grad u) / (1 + (tau/theta) |grad u|)`
//!    (forward differences for `grad`, its negative adjoint for `div`),
//!
//! stopping when the squared update summed over the level drops below
//! `epsilon^2 * pixels`.
//!
//! Two kernels compute an inner iteration:
//! - [`iterate_reference`]: one full-image pass per step, as written above.
//! - [`iterate_fast`]: steps 1+2 and the error in one pass over a row, step 3 of the row
//!   above right after it (one-row lag), over bands of rows in parallel. The rows at band
//!   edges are exchanged through a copy of the old dual row and a short sequential pass,
//!   so every pixel sees exactly the values the reference gives it. Both kernels use the
//!   same per-pixel arithmetic and the same per-row error sums, so they agree
//!   bit-for-bit, whatever the number of bands or threads.

mod kernels;
#[cfg(test)]
mod tests;

use rayon::prelude::*;

use super::median::median_filter;
use super::params::{FlowParams, Interpolation};
use super::planes::Planes;
use super::pyramid::{Level, run_parallel};
use super::warp::{GRAD_EPS, Linearised, linearise};
use kernels::{
    FastScratch, PAIR_MARGIN, band_rows, iterate_fast, iterate_pair, iterate_reference, simd_rows,
};

/// Which inner kernel runs (the reference and the portable kernel exist to test the
/// fast one).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Kernel {
    /// One full-image pass per step, exact arithmetic.
    #[cfg_attr(not(test), allow(dead_code))]
    Reference,
    /// The fused, banded kernel with exact arithmetic: equals the reference bit-for-bit.
    #[cfg_attr(not(test), allow(dead_code))]
    Portable,
    /// The fused, banded kernel with AVX2 + FMA where the CPU has them (reciprocals and
    /// square roots by refined estimates, see `kernels::simd`), else [`Kernel::Portable`].
    Fast,
}

/// Dual variables: `p1 = (p11, p12)` for `u1`, `p2 = (p21, p22)` for `u2`, in that
/// order, staggered against the linearised arrays (see [`Planes`]).
#[derive(Clone, Debug, PartialEq)]
pub(crate) struct Dual {
    planes: Planes<4>,
}

/// Cache-line lead of the dual arrays: after the four linearised arrays (lead 0).
const DUAL_LEAD: usize = 4;

impl Dual {
    pub(crate) fn zeros(n: usize) -> Self {
        Self {
            planes: Planes::zeros(n, DUAL_LEAD),
        }
    }

    /// Arrays of `n` pixels, reusing the allocation; contents unspecified (callers
    /// overwrite them or [`reset`](Self::reset)).
    pub(crate) fn resize(&mut self, n: usize) {
        self.planes.resize(n);
    }

    /// Zero arrays of `n` pixels, reusing the allocation.
    pub(crate) fn reset(&mut self, n: usize) {
        self.resize(n);
        for a in self.planes.all_mut() {
            a.fill(0.0);
        }
    }

    /// Pixels per array.
    pub(crate) fn len(&self) -> usize {
        self.planes.len()
    }

    /// `[p11, p12, p21, p22]`.
    pub(crate) fn parts(&self) -> [&[f32]; 4] {
        self.planes.all()
    }

    /// `[p11, p12, p21, p22]`, mutably.
    pub(crate) fn parts_mut(&mut self) -> [&mut [f32]; 4] {
        self.planes.all_mut()
    }
}

/// Step constants of an inner iteration.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Steps {
    /// `lambda * theta`.
    pub lt: f32,
    pub theta: f32,
    /// `tau / theta`.
    pub taut: f32,
}

/// Buffers of the level solver, kept by the estimator from level to level and frame to
/// frame (allocating and first touching them per level cost about as much as a warp).
#[derive(Clone, Debug, Default)]
pub(crate) struct Workspace {
    lin: Linearised,
    scratch: FastScratch,
    median: Vec<f32>,
}

/// What differs between levels: the finest solved level may have its own warps,
/// iterations, interpolation and median filter (see [`FlowParams`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct LevelPlan {
    pub warps: usize,
    pub inner_iterations: usize,
    pub interpolation: Interpolation,
    pub median_filter: usize,
}

impl LevelPlan {
    /// The plan of the finest solved level (`finest`) or of a coarser one.
    pub(crate) fn new(params: &FlowParams, finest: bool) -> Self {
        let or = |v: usize, fallback: usize| if v > 0 { v } else { fallback };
        if finest {
            Self {
                warps: or(params.finest_warps, params.warps),
                inner_iterations: or(params.finest_inner_iterations, params.inner_iterations),
                interpolation: params.interpolation,
                median_filter: params.median_filter,
            }
        } else {
            Self {
                warps: params.warps,
                inner_iterations: params.inner_iterations,
                interpolation: params.coarse_interpolation.unwrap_or(params.interpolation),
                median_filter: params.coarse_median_filter.unwrap_or(params.median_filter),
            }
        }
    }
}

/// Solves one level, refining `(u1, u2)` and the dual variables `p` in place (`p` is
/// zeros for OpenCV's behaviour, or the coarser level's dual upsampled).
#[allow(clippy::too_many_arguments)]
pub(crate) fn solve_level(
    i0: &Level,
    i1: &Level,
    u1: &mut [f32],
    u2: &mut [f32],
    p: &mut Dual,
    params: &FlowParams,
    plan: LevelPlan,
    kernel: Kernel,
    work: &mut Workspace,
) {
    let (w, h) = (i0.width, i0.height);
    let n = w * h;
    let s = Steps {
        lt: params.lambda * params.theta,
        theta: params.theta,
        taut: params.tau / params.theta,
    };
    let scaled_eps = (params.epsilon as f64).powi(2) * n as f64;
    debug_assert_eq!(p.len(), n);
    let Workspace {
        lin,
        scratch,
        median: median_scratch,
    } = work;
    let simd = kernel == Kernel::Fast && simd_rows();
    let (mut t_lin, mut t_med, mut t_it, mut n_it, mut n_med) = (0.0, 0.0, 0.0, 0usize, 0usize);
    for _ in 0..plan.warps {
        let t0 = std::time::Instant::now();
        linearise(&i0.image, &i1.packed, u1, u2, w, h, plan.interpolation, lin);
        t_lin += t0.elapsed().as_secs_f64();
        let mut error = f64::MAX;
        let mut outer = 0;
        while error > scaled_eps && outer < params.outer_iterations {
            if plan.median_filter > 1 {
                let t0 = std::time::Instant::now();
                median_filter(u1, w, h, plan.median_filter, median_scratch);
                median_filter(u2, w, h, plan.median_filter, median_scratch);
                t_med += t0.elapsed().as_secs_f64();
                n_med += 1;
            }
            let t0 = std::time::Instant::now();
            let mut inner = 0;
            while error > scaled_eps && inner < plan.inner_iterations {
                // Two iterations without a stopping test between them while the first is
                // unlikely to meet epsilon (see `PAIR_MARGIN`); in one pass where the
                // level runs as one band (`iterate_pair`), else as two passes. The
                // decision does not depend on the thread count, so neither does the
                // result.
                let pair = kernel == Kernel::Fast
                    && inner + 2 <= plan.inner_iterations
                    && error > PAIR_MARGIN * scaled_eps;
                if pair {
                    error = if band_rows(w, h) >= h {
                        iterate_pair(lin, u1, u2, p, w, h, s, scratch, simd)
                    } else {
                        iterate_fast(lin, u1, u2, p, w, h, s, scratch, simd);
                        iterate_fast(lin, u1, u2, p, w, h, s, scratch, simd)
                    };
                    inner += 2;
                    n_it += 2;
                    continue;
                }
                error = match kernel {
                    Kernel::Fast => iterate_fast(lin, u1, u2, p, w, h, s, scratch, simd),
                    Kernel::Portable => iterate_fast(lin, u1, u2, p, w, h, s, scratch, false),
                    Kernel::Reference => iterate_reference(lin, u1, u2, p, w, h, s),
                };
                inner += 1;
                n_it += 1;
            }
            t_it += t0.elapsed().as_secs_f64();
            outer += 1;
        }
    }
    tracing::trace!(
        width = w,
        height = h,
        warp_ms = t_lin * 1e3,
        median_ms = t_med * 1e3,
        median_calls = n_med,
        iterate_ms = t_it * 1e3,
        iterations = n_it,
        "tv-l1 level solved"
    );
}
