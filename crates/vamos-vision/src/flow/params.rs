//! TV-L1 parameters, their validation and the named presets.

use serde::{Deserialize, Serialize};

use super::FlowError;

/// How the second image and its gradient are sampled at the warped positions.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(rename_all = "lowercase")]
pub enum Interpolation {
    /// 2x2 taps. Cheaper, slightly less accurate.
    Bilinear,
    /// 4x4 taps, Keys kernel with `a = -0.75` (OpenCV's `INTER_CUBIC`).
    Bicubic,
}

/// Parameters of [`tvl1`](super::tvl1) and [`FlowEstimator`](super::FlowEstimator).
///
/// `Default` holds OpenCV `DualTVL1`'s defaults (the `default` preset, the values each
/// field names); [`FlowParams::realtime`] is the fast preset and what vamos uses unless
/// told otherwise: a settings file's `[vision.flow]` starts from it, so keys left out
/// keep the realtime preset's values. Intensities are in 0..=255 units (see
/// [`GrayImage`](crate::GrayImage)).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(default = "FlowParams::realtime", deny_unknown_fields)]
pub struct FlowParams {
    /// Time step of the dual (Chambolle) update, dimensionless. Default 0.25.
    pub tau: f32,
    /// Weight of the data term, per intensity unit (0..=255 scale). Default 0.15.
    pub lambda: f32,
    /// Coupling between the flow `u` and its auxiliary `v`, dimensionless. Default 0.3.
    pub theta: f32,
    /// Number of pyramid levels, finest included. Fewer are used when a level would be
    /// smaller than [`MIN_LEVEL_SIZE_PX`](super::MIN_LEVEL_SIZE_PX). Default 5.
    pub n_scales: usize,
    /// Size ratio between consecutive pyramid levels, in (0, 1). Default 0.8.
    pub scale_step: f32,
    /// Warps (re-linearisations of the data term) per level. Default 5.
    pub warps: usize,
    /// Stopping threshold, pixels: the iterations of a warp stop when the root mean
    /// square flow update of one iteration drops below it. Default 0.01.
    pub epsilon: f32,
    /// Iterations between two median filterings, count. Default 30.
    pub inner_iterations: usize,
    /// Median filterings (each followed by `inner_iterations`) per warp, count. Default 10.
    pub outer_iterations: usize,
    /// Side of the square median filter applied to the flow before each outer iteration,
    /// pixels: 0 or 1 (off), 3, 5 or 7. Default 5.
    pub median_filter: usize,
    /// Interpolation of the warp. Default [`Interpolation::Bicubic`].
    pub interpolation: Interpolation,
    /// Finest pyramid level that is solved, count of levels below full resolution: 0
    /// solves at full resolution (OpenCV's behaviour); `k > 0` stops at the level of
    /// size `scale_step^k` and upsamples that flow (bilinear, multiplied by
    /// `1 / scale_step^k`) to full resolution. Clamped to the coarsest level that exists.
    /// Default 0.
    pub finest_scale: usize,
    /// Carry the dual variables `p` from one pyramid level to the next (bilinear
    /// upsampling) instead of restarting them at 0 on every level. Starts each level
    /// from the coarser level's regularisation state, so fewer iterations are needed.
    /// Default `false` (OpenCV's behaviour).
    pub warm_start_dual: bool,
    /// Warps on the finest solved level, count; 0 means [`warps`](Self::warps). Coarse
    /// levels are cheap, so a preset can warp them often and the finest level rarely.
    /// Default 0.
    pub finest_warps: usize,
    /// Iterations between two median filterings on the finest solved level, count; 0
    /// means [`inner_iterations`](Self::inner_iterations). Lets a preset iterate the
    /// cheap coarse levels more than the costly finest one. Default 0.
    pub finest_inner_iterations: usize,
    /// Interpolation of the warp on the levels coarser than the finest solved one; `None`
    /// means [`interpolation`](Self::interpolation). Bilinear there costs about a third
    /// of bicubic per pixel; the finest level decides the final accuracy. Default `None`.
    pub coarse_interpolation: Option<Interpolation>,
    /// Median filter side on the levels coarser than the finest solved one, pixels (as
    /// [`median_filter`](Self::median_filter)); `None` means `median_filter`.
    /// Default `None`.
    pub coarse_median_filter: Option<usize>,
}

impl Default for FlowParams {
    fn default() -> Self {
        Self {
            tau: 0.25,
            lambda: 0.15,
            theta: 0.3,
            n_scales: 5,
            scale_step: 0.8,
            warps: 5,
            epsilon: 0.01,
            inner_iterations: 30,
            outer_iterations: 10,
            median_filter: 5,
            interpolation: Interpolation::Bicubic,
            finest_scale: 0,
            warm_start_dual: false,
            finest_warps: 0,
            finest_inner_iterations: 0,
            coarse_interpolation: None,
            coarse_median_filter: None,
        }
    }
}

/// Names accepted by [`FlowParams::preset`].
pub const PRESET_NAMES: [&str; 4] = ["default", "realtime", "realtime-hq", "balanced"];

impl FlowParams {
    /// The real-time preset: half-resolution solve (`finest_scale` 1 with `scale_step`
    /// 0.5), 3 bicubic warps of 10 iterations per level, one median filter per warp.
    ///
    /// Chosen by a sweep with `examples/flow_time.rs` on the four synthetic pairs (one
    /// thread, minimum of 3-5 runs, on a 2-core machine shared with other builds, load
    /// average about 3: times are inflated, maybe 1.5-2x). AEE in pixels for translation /
    /// rotation / smooth / square, then mean ms per pair (see `benches/flow_presets.md`):
    ///
    /// | variant                              | 160x120 AEE                   | ms   | 320x240 AEE                   | ms   |
    /// |--------------------------------------|-------------------------------|------|-------------------------------|------|
    /// | `default()`                          | 0.056 / 0.076 / 0.059 / 0.017 | 41   | 0.082 / 1.92 / 0.097 / 0.35   | 175  |
    /// | **this preset** (bicubic)            | 0.159 / 0.163 / 0.166 / 0.040 | 3.7  | 0.228 / 0.198 / 0.145 / 0.058 | 11.2 |
    /// | bilinear (previous preset)           | 0.322 / 0.319 / 0.309 / 0.051 | 3.5  | 0.388 / 0.373 / 0.271 / 0.048 | 11.3 |
    /// | inner 15                             | 0.172 / 0.173 / 0.128 / 0.033 | 4.7  | 0.230 / 0.176 / 0.120 / 0.036 | 13.5 |
    /// | warps 2, inner 15                    | 0.182 / 0.195 / 0.202 / 0.056 | 2.6  | 0.305 / 0.629 / 0.156 / 0.088 | 8.3  |
    /// | bilinear, warps 4                    | 0.315 / 0.285 / 0.290 / 0.061 | 4.5  | 0.457 / 0.369 / 0.293 / 0.060 | 13.9 |
    /// | bilinear, full resolution, 4 scales, warps 2 | 0.075 / 0.083 / 0.100 / 0.014 | 11.6 | 0.313 / 0.370 / 0.151 / 0.054 | 25 |
    ///
    /// | `finest_warps` 1, `warps` 4, `warm_start_dual`, full res, 4 scales, inner 15 | 0.070 / 0.092 / 0.084 / 0.018 | 7.7 | 0.046 / 0.161 / 0.087 / 0.023 | 36-40 |
    /// | same, inner 10                       |                               |      | 0.137 / 0.178 / 0.093 / 0.042 | 41 (load) |
    /// | same, inner 15, `warm_start_dual` off |                              |      | 0.030 / 0.175 / 0.104 / 0.025 | 47 (load) |
    /// | same, inner 15, bilinear             |                               |      | 0.137 / 0.092 / 0.091 / 0.014 | 44 (load) |
    /// | same, 3 scales                       |                               |      | 0.210 / 0.959 / 0.111 / 0.249 | 40 (load) |
    /// | this preset + `warps` 5, `finest_warps` 3, `warm_start_dual` | 0.156 / 0.191 / 0.162 / 0.040 | 5.0 | 0.180 / 0.225 / 0.129 / 0.046 | 12.9-22.6 (this preset 12.7-16.0 beside it) |
    /// | this preset + `warm_start_dual`      |                               |      | 0.230 / 0.210 / 0.147 / 0.054 | 16.3 (this preset 16.4 beside it) |
    ///
    /// The full-resolution row with one finest warp reaches (or beats) the default's AEE
    /// at 320x240 on translation, smooth and square, but costs about 3x this preset
    /// (36-46 ms beside this preset's 13-16 ms on the loaded machine), so it is not the
    /// preset; build it from the knobs where accuracy matters more than the 15 ms budget.
    ///
    /// It is 3-4x faster than the 15 ms budget at 160x120 and within it at 320x240, but
    /// it does **not** reach the default's accuracy: on translation and smooth motion its
    /// AEE is 1.5-3x the default's (the default fails on the 320x240 rotation and square,
    /// where its 0.8-step pyramid does not follow the motion; this preset does).
    ///
    /// A third sweep (`benches/flow_presets.md`) tried the cheaper-level knobs
    /// ([`coarse_interpolation`](Self::coarse_interpolation),
    /// [`coarse_median_filter`](Self::coarse_median_filter),
    /// [`finest_inner_iterations`](Self::finest_inner_iterations)) and an over-relaxed
    /// primal (`u + r (u - u_prev)` in the dual step, since removed: it slowed the kernel
    /// and never helped) within about 1.2x this preset's cost:
    /// none improves every case robustly (the best, `warm_start_dual` + no coarse median +
    /// `inner_iterations` 13, gains 7-24% at 320x240 but loses 15% on the 160x120 square,
    /// and `inner_iterations` 12 or 14 beside it are worse than this preset), and
    /// over-relaxation diverges with OpenCV's thresholding scheme. So this preset is
    /// unchanged (the simulated benchmark, the demo's model and its calibration use
    /// it); [`FlowParams::realtime_hq`] is the real-time preset with the default's
    /// accuracy at 320x240.
    pub fn realtime() -> Self {
        Self {
            n_scales: 5,
            scale_step: 0.5,
            warps: 3,
            epsilon: 0.01,
            inner_iterations: 10,
            outer_iterations: 1,
            median_filter: 5,
            interpolation: Interpolation::Bicubic,
            finest_scale: 1,
            ..Self::default()
        }
    }

    /// The balanced preset: close to the default's accuracy at a third of its cost
    /// (within 10% of its AEE on the four 160x120 accuracy pairs below and better on the
    /// 320x240 ones; 1.1-2.1x its AEE on the smooth/translation pairs of
    /// `benches/compare_flow.py`). Full-resolution solve on 4
    /// levels of ratio 0.5, dual carried across levels (`warm_start_dual`), 4 warps per
    /// coarse level and 2 on the finest, 15 iterations and one 5x5 median per warp.
    ///
    /// Measured with `examples/flow_time.rs`, the three presets back to back (one thread,
    /// minimum of 7 runs, mean ms per pair; 2-core VM running slow: `realtime` took 16.4
    /// ms at 320x240 against 11.1 ms idle, so times are inflated about 1.5x; compare the
    /// ratios). AEE translation / rotation / smooth / square:
    ///
    /// | preset       | 160x120 AEE                   | ms    | 320x240 AEE                   | ms    |
    /// |--------------|-------------------------------|-------|-------------------------------|-------|
    /// | `default()`  | 0.056 / 0.076 / 0.059 / 0.017 | 105   | 0.082 / 1.92 / 0.097 / 0.35   | 380   |
    /// | **balanced** | 0.057 / 0.077 / 0.063 / 0.018 | 21.8  | 0.030 / 0.145 / 0.075 / 0.021 | 78.7  |
    /// | `realtime()` | 0.159 / 0.163 / 0.166 / 0.040 | 6.1   | 0.228 / 0.198 / 0.145 / 0.058 | 16.4  |
    ///
    /// The `default()` times in this table include a since-removed slowdown of the
    /// kernel (`benches/flow_presets.md`). On an idle machine after the fix
    /// (`benches/README.md`), 320x240, one thread: default 111-117 ms, balanced 38-41 ms,
    /// realtime 10-11 ms. It does not fit a 15 ms budget at 320x240.
    pub fn balanced() -> Self {
        Self {
            n_scales: 4,
            scale_step: 0.5,
            warps: 4,
            finest_warps: 2,
            inner_iterations: 15,
            outer_iterations: 1,
            median_filter: 5,
            interpolation: Interpolation::Bicubic,
            warm_start_dual: true,
            ..Self::default()
        }
    }

    /// The accurate real-time preset (`realtime-hq`): within 10 % of the default's AEE
    /// on every 320x240 accuracy pair, under 15 ms per 320x240 pair on one core.
    /// Seven levels of ratio 0.75 solved at full resolution, two bicubic warps per
    /// level with 11 iterations (15 on the finest), one 3x3 median per warp, dual
    /// restarted on every level.
    ///
    /// Chosen by a fourth sweep (`benches/flow_presets.md`) after the kernel work of
    /// 2026-12-02 (AVX2 + FMA warp and iteration, two iterations per pass, staggered
    /// arrays, reused buffers): `examples/flow_time.rs`, one thread, one estimator
    /// reused per case, min of 5 runs, best of 4-5 interleaved rounds. AEE translation /
    /// rotation / smooth / square at 320x240, motions growing with the image
    /// (`motion=scaled`) and the 160x120 motions (`motion=pixels`, as
    /// `benches/compare_flow.py`):
    ///
    /// | preset        | scaled AEE                    | ms   | pixels AEE                        | ms   |
    /// |---------------|-------------------------------|------|-----------------------------------|------|
    /// | `default()`   | 0.083 / 1.94 / 0.096 / 0.362  | 62.7 | 0.0465 / 0.0474 / 0.0435 / 0.0090 | 46.7 |
    /// | **this**      | 0.041 / 0.144 / 0.047 / 0.019 | 13.0 | 0.0469 / 0.0474 / 0.0437 / 0.0087 | 12.2 |
    /// | `balanced()`  | 0.031 / 0.134 / 0.077 / 0.021 | 12.4 | 0.0783 / 0.0720 / 0.0520 / 0.0104 | 12.6 |
    /// | `realtime()`  | 0.226 / 0.197 / 0.143 / 0.058 | 3.2  | 0.1245 / 0.1766 / 0.1484 / 0.0296 | 3.2  |
    ///
    /// On the 8-bit pairs of `benches/compare_flow.py` (its own smooth field, through the
    /// CLI): 0.0419 px against the default's 0.0412 on smooth (1.02x) and 0.0451 against
    /// 0.0419 on translation (1.08x), 13.6 and 12.9 ms. Times on the 2-core VM drift by
    /// 10-30 % from minute to minute. The iteration counts sit on a knife edge: with 12
    /// or 13 coarse iterations instead of 11 the translation AEE rises to 1.1-1.3x the
    /// default's on some of these pairs, with 10 the compare_flow smooth one to 1.18x.
    ///
    /// It is tuned for 320x240: at 160x120 its square's AEE is 1.36x the default's
    /// (use [`FlowParams::balanced`] there), at 640x480 the square's (0.003 px against
    /// 0.0016) is 2x; the other cases stay within 6 % or better.
    pub fn realtime_hq() -> Self {
        Self {
            n_scales: 7,
            scale_step: 0.75,
            warps: 2,
            inner_iterations: 11,
            finest_inner_iterations: 15,
            outer_iterations: 1,
            median_filter: 3,
            interpolation: Interpolation::Bicubic,
            warm_start_dual: false,
            ..Self::default()
        }
    }

    /// A preset by name: one of [`PRESET_NAMES`].
    pub fn preset(name: &str) -> Result<Self, FlowError> {
        match name {
            "default" => Ok(Self::default()),
            "realtime" => Ok(Self::realtime()),
            "realtime-hq" => Ok(Self::realtime_hq()),
            "balanced" => Ok(Self::balanced()),
            other => Err(FlowError::UnknownPreset {
                name: other.to_string(),
                known: PRESET_NAMES.join(", "),
            }),
        }
    }

    /// Checks every field; the error names the first bad one.
    pub fn validate(&self) -> Result<(), FlowError> {
        let bad =
            |field: &'static str, reason: String| Err(FlowError::InvalidParams { field, reason });
        for (field, value) in [
            ("tau", self.tau),
            ("lambda", self.lambda),
            ("theta", self.theta),
        ] {
            if !(value.is_finite() && value > 0.0) {
                return bad(field, format!("must be finite and > 0, got {value}"));
            }
        }
        if !(self.epsilon.is_finite() && self.epsilon >= 0.0) {
            return bad(
                "epsilon",
                format!("must be finite and >= 0, got {}", self.epsilon),
            );
        }
        if !(self.scale_step.is_finite() && self.scale_step > 0.0 && self.scale_step < 1.0) {
            return bad(
                "scale_step",
                format!("must be in (0, 1), got {}", self.scale_step),
            );
        }
        for (field, value) in [
            ("n_scales", self.n_scales),
            ("warps", self.warps),
            ("inner_iterations", self.inner_iterations),
            ("outer_iterations", self.outer_iterations),
        ] {
            if value == 0 {
                return bad(field, "must be at least 1".into());
            }
        }
        if self.n_scales > 64 {
            return bad(
                "n_scales",
                format!("must be at most 64, got {}", self.n_scales),
            );
        }
        if !matches!(self.median_filter, 0 | 1 | 3 | 5 | 7) {
            return bad(
                "median_filter",
                format!("must be 0, 1, 3, 5 or 7, got {}", self.median_filter),
            );
        }
        if let Some(m) = self.coarse_median_filter
            && !matches!(m, 0 | 1 | 3 | 5 | 7)
        {
            return bad(
                "coarse_median_filter",
                format!("must be 0, 1, 3, 5 or 7, got {m}"),
            );
        }
        if self.finest_scale >= self.n_scales {
            return bad(
                "finest_scale",
                format!(
                    "must be below n_scales ({}), got {}",
                    self.n_scales, self.finest_scale
                ),
            );
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn defaults_are_opencv_dual_tvl1() {
        let p = FlowParams::default();
        assert_eq!(
            (p.tau, p.lambda, p.theta, p.n_scales, p.scale_step, p.warps),
            (0.25, 0.15, 0.3, 5, 0.8, 5)
        );
        assert_eq!(
            (
                p.epsilon,
                p.inner_iterations,
                p.outer_iterations,
                p.median_filter
            ),
            (0.01, 30, 10, 5)
        );
        assert_eq!(p.interpolation, Interpolation::Bicubic);
        assert_eq!(p.finest_scale, 0);
        p.validate().unwrap();
        FlowParams::realtime().validate().unwrap();
        FlowParams::balanced().validate().unwrap();
        assert_eq!(
            (
                p.finest_inner_iterations,
                p.coarse_interpolation,
                p.coarse_median_filter,
            ),
            (0, None, None)
        );
    }

    #[test]
    fn presets_by_name() {
        assert_eq!(
            FlowParams::preset("default").unwrap(),
            FlowParams::default()
        );
        assert_eq!(
            FlowParams::preset("realtime").unwrap(),
            FlowParams::realtime()
        );
        assert_eq!(
            FlowParams::preset("balanced").unwrap(),
            FlowParams::balanced()
        );
        assert_eq!(
            FlowParams::preset("realtime-hq").unwrap(),
            FlowParams::realtime_hq()
        );
        for name in PRESET_NAMES {
            FlowParams::preset(name).unwrap().validate().unwrap();
        }
        let err = FlowParams::preset("turbo").unwrap_err();
        assert!(err.to_string().contains("turbo"));
    }

    #[test]
    fn invalid_params_name_the_field() {
        let cases: Vec<(FlowParams, &str)> = vec![
            (
                FlowParams {
                    tau: 0.0,
                    ..FlowParams::default()
                },
                "tau",
            ),
            (
                FlowParams {
                    lambda: f32::NAN,
                    ..FlowParams::default()
                },
                "lambda",
            ),
            (
                FlowParams {
                    theta: -1.0,
                    ..FlowParams::default()
                },
                "theta",
            ),
            (
                FlowParams {
                    scale_step: 1.0,
                    ..FlowParams::default()
                },
                "scale_step",
            ),
            (
                FlowParams {
                    epsilon: -0.1,
                    ..FlowParams::default()
                },
                "epsilon",
            ),
            (
                FlowParams {
                    warps: 0,
                    ..FlowParams::default()
                },
                "warps",
            ),
            (
                FlowParams {
                    n_scales: 0,
                    ..FlowParams::default()
                },
                "n_scales",
            ),
            (
                FlowParams {
                    inner_iterations: 0,
                    ..FlowParams::default()
                },
                "inner_iterations",
            ),
            (
                FlowParams {
                    outer_iterations: 0,
                    ..FlowParams::default()
                },
                "outer_iterations",
            ),
            (
                FlowParams {
                    median_filter: 4,
                    ..FlowParams::default()
                },
                "median_filter",
            ),
            (
                FlowParams {
                    finest_scale: 5,
                    ..FlowParams::default()
                },
                "finest_scale",
            ),
            (
                FlowParams {
                    coarse_median_filter: Some(4),
                    ..FlowParams::default()
                },
                "coarse_median_filter",
            ),
        ];
        for (p, field) in cases {
            match p.validate() {
                Err(FlowError::InvalidParams { field: f, .. }) => assert_eq!(f, field),
                other => panic!("{field}: unexpected {other:?}"),
            }
        }
    }

    #[test]
    fn serde_defaults_and_unknown_fields() {
        let p: FlowParams =
            serde_json::from_str(r#"{"warps": 3, "interpolation": "bilinear"}"#).unwrap();
        assert_eq!(p.warps, 3);
        assert_eq!(p.interpolation, Interpolation::Bilinear);
        assert_eq!(p.tau, 0.25);
        assert!(serde_json::from_str::<FlowParams>(r#"{"wraps": 3}"#).is_err());
        let back: FlowParams =
            serde_json::from_str(&serde_json::to_string(&FlowParams::realtime()).unwrap()).unwrap();
        assert_eq!(back, FlowParams::realtime());
    }
}
