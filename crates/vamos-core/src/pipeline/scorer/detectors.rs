//! The geometric detectors of a processed frame, each `None` when switched off or when
//! the frame lacks what it needs: `e_c` (camera motion), `e_b` (body motion) and `e_r`
//! (the scene-motion residual outside the robot).

use super::super::depth::{DepthEvidence, depth_evidence};
use super::super::frames::ProcessedFrame;
use super::super::residual::{self, BodyError};
use super::{Pose, Scorer, ScorerError};
use crate::eval::{Pooling, pool_cells};
use vamos_robot::Intrinsics;
use vamos_robot::camera_motion::{
    Depth, camera_motion_error, expected_camera_motion, expected_image_flow, similarity_flow,
};

/// `e_r` of a frame and what calibration takes from it.
#[derive(Default)]
pub(super) struct SceneResidual {
    pub e_r: Option<f64>,
    /// The per-cell residuals and their `(columns, rows)`.
    pub cells: Option<Vec<f32>>,
    pub grid: (usize, usize),
    /// The frame's evidence on the static scene's depth (for a profile with
    /// `learn_depth` before any calibration, what calibration learns it from; frames with
    /// a depth image give none).
    pub depth_evidence: Option<DepthEvidence>,
}

impl Scorer {
    /// `e_c`: the camera motion expected from the previous and current camera poses
    /// against the registered one (the grid points at the previous frame's `depth`). A
    /// registration that failed numerically gives `+inf`.
    pub(super) fn camera_error(
        &self,
        pose: Option<&Pose>,
        previous_pose: Option<&Pose>,
        intrinsics: Option<&Intrinsics>,
        depth: Depth<'_>,
        processed: &ProcessedFrame,
    ) -> Result<Option<f64>, ScorerError> {
        let (Some((_, current)), Some((_, previous)), Some(k)) = (pose, previous_pose, intrinsics)
        else {
            return Ok(None);
        };
        if !self.config.detectors.camera {
            return Ok(None);
        }
        let expected =
            expected_camera_motion(previous, current, k, depth, &self.config.camera_motion)?;
        let e = camera_motion_error(
            &expected.transform,
            &processed.registration.transform,
            &self.config.camera_error,
        );
        // A registration that failed numerically must alarm, not hide.
        Ok(Some(if e.is_nan() { f64::INFINITY } else { e }))
    }

    /// `e_b`: the rendered body flow against the observed flow over the body mask (the
    /// paper's medians or the per-pixel quantile); needs the previous pose and the
    /// intrinsics (`rendered`).
    pub(super) fn body_error(
        &self,
        rendered: bool,
        processed: &ProcessedFrame,
    ) -> Result<Option<f64>, ScorerError> {
        let Some(body) = &self.body else {
            return Ok(None);
        };
        if !rendered || !self.config.detectors.body {
            return Ok(None);
        }
        Ok(match self.config.residual.body_error {
            BodyError::Median => {
                let m = vamos_robot::body_motion::body_motion_error(
                    &body.out.flow,
                    &processed.flow,
                    &body.out.mask,
                )?;
                m.body_visible.then_some(m.e_b_px)
            }
            BodyError::Quantile => residual::body_residual(
                &body.out.flow,
                &body.out.mask,
                &processed.flow,
                self.config.residual.body_quantile,
                self.config.residual.moving_px,
            ),
        })
    }

    /// `e_r`: the observed flow against the static scene's expected flow (from the camera
    /// poses when both frames have one, else the registered similarity), outside both
    /// frames' body masks grown by a margin, per cell, pooled against the nominal cell
    /// statistics at the frame's `phase_s`. The expected flow moves each pixel at the
    /// previous frame's `depth`.
    #[allow(clippy::too_many_arguments)]
    pub(super) fn scene_residual(
        &mut self,
        pose: Option<&Pose>,
        previous_pose: Option<&Pose>,
        intrinsics: Option<&Intrinsics>,
        depth: Depth<'_>,
        previous_mask: &[bool],
        processed: &ProcessedFrame,
        phase_s: f64,
    ) -> Result<SceneResidual, ScorerError> {
        if !self.config.detectors.scene {
            return Ok(SceneResidual::default());
        }
        let (w, h) = (self.config.frames.width, self.config.frames.height);
        match (pose, previous_pose, intrinsics) {
            (Some((_, current)), Some((_, previous)), Some(k)) => expected_image_flow(
                previous,
                current,
                k,
                depth,
                self.config.camera_motion.assumed_depth_m,
                &mut self.expected_flow,
            )?,
            _ => similarity_flow(
                &processed.registration.transform,
                w,
                h,
                &mut self.expected_flow,
            ),
        }
        let (current_mask, motion_px) = match (&self.body, intrinsics) {
            (Some(body), Some(_)) => (
                body.out.mask.as_slice(),
                residual::body_motion_px(&body.out.flow, &body.out.mask),
            ),
            _ => (&[][..], 0.0),
        };
        let margin = self.config.residual.margin_px
            + (self.config.residual.motion_margin * motion_px)
                .ceil()
                .min(64.0) as usize;
        let exclude = residual::grow_union(current_mask, previous_mask, w, h, margin);
        let depth_evidence = match (pose, previous_pose, intrinsics, depth) {
            (Some((_, current)), Some((_, previous)), Some(k), Depth::Assumed)
                if self.config.camera_motion.learn_depth
                    && self.thresholds.depth.is_none()
                    && self.thresholds.scales.is_none() =>
            {
                let grid = (
                    self.config.camera_motion.grid_columns,
                    self.config.camera_motion.grid_rows,
                );
                Some(depth_evidence(
                    previous,
                    current,
                    k,
                    &processed.flow,
                    &processed.previous_image,
                    &exclude,
                    grid,
                ))
            }
            _ => None,
        };
        let cells = residual::scene_cells(
            &processed.flow,
            &self.expected_flow,
            &exclude,
            self.config.residual.cell_px,
            self.config
                .residual
                .normal_flow
                .then_some(&processed.previous_image),
            // Scored as the statistics were fitted (a calibration made before the check
            // keeps scoring as it was made).
            self.thresholds
                .scene
                .as_ref()
                .map_or(self.config.residual.takes_photometric(), |s| s.photometric)
                .then(|| self.processor.current())
                .flatten(),
        );
        let (columns, rows) = residual::cell_grid(w, h, self.config.residual.cell_px);
        let e_r = pool_cells(
            &cells,
            columns,
            rows,
            self.thresholds.scene.as_ref().map(|s| s.at(Some(phase_s))),
            Pooling {
                top_fraction: self.config.residual.top_fraction,
            },
            None,
        );
        Ok(SceneResidual {
            e_r,
            cells: Some(cells),
            grid: (columns, rows),
            depth_evidence,
        })
    }
}
