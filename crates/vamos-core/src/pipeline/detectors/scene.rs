//! `e_r`, the scene-motion residual: the observed flow against the static scene's
//! expected flow (from the two camera poses where both frames have one, else the
//! registered similarity), outside both frames' body masks grown by a margin, per cell
//! ([`crate::pipeline::residual::scene_cells`]), pooled against the nominal per-cell
//! statistics at the frame's phase ([`crate::eval::pool_cells`]).
//!
//! Calibration ([`fit`]): per-cell statistics of the training frames' cell maps, per
//! phase window with `phase_window_s`; the frames' `e_r` pooled again with them. With
//! `[pipeline.camera_motion] learn_depth` the frames also give evidence on the static
//! scene's depth ([`learn_depth`]).

use super::cells::{self, CellDetector};
use super::{FrameContext, FrameDetector};
use crate::eval::{CellStats, Detector, Pooling, pool_cells};
use crate::pipeline::PipelineConfig;
use crate::pipeline::depth::{LearnedDepth, depth_evidence};
use crate::pipeline::offline::EpisodeScores;
use crate::pipeline::residual::{self, ResidualParams};
use crate::pipeline::scorer::{FrameScore, ScorerError};
use vamos_robot::camera_motion::{CameraMotionParams, Depth, expected_image_flow, similarity_flow};
use vamos_vision::FlowField;

/// The scene-motion detector.
pub struct Scene {
    residual: ResidualParams,
    camera_motion: CameraMotionParams,
    /// The expected image flow of the current frame (reused buffer).
    expected_flow: FlowField,
}

impl Scene {
    /// With the pipeline's residual and camera-motion settings.
    pub fn new(config: &PipelineConfig) -> Scene {
        Scene {
            residual: config.residual.clone(),
            camera_motion: config.camera_motion.clone(),
            expected_flow: FlowField::zeros(0, 0),
        }
    }
}

impl FrameDetector for Scene {
    fn detector(&self) -> Detector {
        Detector::Scene
    }

    /// Writes the frame's cells (`scene_cells`, `scene_grid`) and, for a profile that
    /// learns the depth and has no calibration yet, its depth evidence.
    fn measure(
        &mut self,
        frame: &FrameContext<'_>,
        out: &mut FrameScore,
    ) -> Result<Option<f64>, ScorerError> {
        let Some(processed) = frame.processed else {
            return Ok(None);
        };
        let (w, h) = frame.size;
        let poses = match (frame.pose, frame.previous_pose, frame.intrinsics) {
            (Some((_, current)), Some((_, previous)), Some(k)) => Some((current, previous, k)),
            _ => None,
        };
        match poses {
            Some((current, previous, k)) => expected_image_flow(
                previous,
                current,
                k,
                frame.depth,
                self.camera_motion.assumed_depth_m,
                &mut self.expected_flow,
            )?,
            None => similarity_flow(
                &processed.registration.transform,
                w,
                h,
                &mut self.expected_flow,
            ),
        }
        let (current_mask, motion_px) = match frame.render {
            Some(render) => (
                render.mask.as_slice(),
                residual::body_motion_px(&render.flow, &render.mask),
            ),
            None => (&[][..], 0.0),
        };
        let margin = self.residual.margin_px
            + (self.residual.motion_margin * motion_px).ceil().min(64.0) as usize;
        let exclude = residual::grow_union(current_mask, frame.previous_mask, w, h, margin);
        let thresholds = frame.thresholds;
        out.depth_evidence = match (poses, frame.depth) {
            (Some((current, previous, k)), Depth::Assumed)
                if self.camera_motion.learn_depth
                    && thresholds.depth.is_none()
                    && thresholds.scales.is_none() =>
            {
                let grid = (
                    self.camera_motion.grid_columns,
                    self.camera_motion.grid_rows,
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
            self.residual.cell_px,
            self.residual
                .normal_flow
                .then_some(&processed.previous_image),
            // Scored as the statistics were fitted (a calibration made before the check
            // keeps scoring as it was made).
            thresholds
                .scene
                .as_ref()
                .map_or(self.residual.takes_photometric(), |s| s.photometric)
                .then_some(frame.image)
                .flatten(),
        );
        let (columns, rows) = residual::cell_grid(w, h, self.residual.cell_px);
        let e_r = pool_cells(
            &cells,
            columns,
            rows,
            thresholds.scene.as_ref().map(|s| s.at(Some(frame.phase_s))),
            Pooling {
                top_fraction: self.residual.top_fraction,
            },
            None,
        );
        out.scene_cells = Some(cells);
        out.scene_grid = (columns, rows);
        Ok(e_r)
    }
}

/// A frame's scene residual cells and their `(columns, rows)`.
pub fn cell_map(f: &FrameScore) -> Option<(&[f32], (usize, usize))> {
    Some((f.scene_cells.as_deref()?, f.scene_grid))
}

/// The scene statistics of a calibration from the training `frames` (`phases`: each
/// one's seconds into its episode), and each frame's `e_r` pooled again with them (as
/// scored without statistics where they cannot be fitted: too few maps, said in `notes`).
pub fn fit(
    frames: &[&FrameScore],
    phases: &[f64],
    residual: &ResidualParams,
    notes: &mut Vec<String>,
) -> (Option<CellStats>, Vec<Option<f64>>) {
    let (stats, values) = cells::fit(
        frames,
        phases,
        residual,
        notes,
        &CellDetector {
            detector: Detector::Scene,
            map: cell_map,
            what: "scene",
            then: "e_r is scored from raw residuals",
        },
    );
    // Scoring against these statistics takes its maps as they were fitted.
    let stats = stats.map(|stats| CellStats {
        photometric: residual.takes_photometric(),
        ..stats
    });
    (stats, values)
}

/// The static scene's depth learned from the training frames' evidence
/// (`[pipeline.camera_motion] learn_depth`), said in a note; `None` (with the reason) when
/// they show none.
pub fn learn_depth(
    train: &[EpisodeScores],
    pipeline: &PipelineConfig,
    notes: &mut Vec<String>,
) -> Option<LearnedDepth> {
    if !pipeline.detectors.scene {
        notes.push(
            "learn_depth needs the scene detector ([pipeline.detectors] scene = true): the \
             assumed depth stays"
                .into(),
        );
        return None;
    }
    let grid = (
        pipeline.camera_motion.grid_columns,
        pipeline.camera_motion.grid_rows,
    );
    let evidence = train
        .iter()
        .flat_map(|e| &e.frames)
        .filter_map(|f| f.depth_evidence.as_ref());
    match LearnedDepth::fit(evidence, grid) {
        Ok(d) => {
            let (median, near, far) = d.summary();
            notes.push(format!(
                "learned the static scene's depth from {} training frames in {} views of the \
                 camera: over all of them median {median:.2} m, {near:.2} to {far:.2} m over \
                 the {}x{} cells ({} with too little evidence took the median of all)",
                d.frames,
                d.views.len(),
                d.columns,
                d.rows,
                d.filled_cells
            ));
            Some(d)
        }
        Err(e) => {
            notes.push(format!("learn_depth: {e}; the assumed depth stays"));
            None
        }
    }
}
