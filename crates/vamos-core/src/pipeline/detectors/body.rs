//! `e_b`, the body-motion error (REFERENCE.md section 2): the flow of the rendered robot
//! (exact, from the previous and current poses) against the observed flow over the body
//! mask, as the paper's difference of medians or the per-pixel quantile
//! (`[pipeline.residual] body_error`). Calibration: as `e_c`, the paper's maximum and the
//! nominal scale.

use super::{FrameContext, FrameDetector};
use crate::eval::Detector;
use crate::pipeline::PipelineConfig;
use crate::pipeline::residual::{self, BodyError};
use crate::pipeline::scorer::{FrameScore, ScorerError};

/// The body-motion detector.
pub struct Body {
    error: BodyError,
    quantile: f64,
    moving_px: f64,
}

impl Body {
    /// With the pipeline's residual settings.
    pub fn new(config: &PipelineConfig) -> Body {
        Body {
            error: config.residual.body_error,
            quantile: config.residual.body_quantile,
            moving_px: config.residual.moving_px,
        }
    }
}

impl FrameDetector for Body {
    fn detector(&self) -> Detector {
        Detector::Body
    }

    /// Needs the render of this frame from the previous pose, and the flow; `None` when
    /// the robot is not in view.
    fn measure(
        &mut self,
        frame: &FrameContext<'_>,
        _out: &mut FrameScore,
    ) -> Result<Option<f64>, ScorerError> {
        let (Some(render), Some(processed), Some(_)) =
            (frame.render, frame.processed, frame.previous_pose)
        else {
            return Ok(None);
        };
        Ok(match self.error {
            BodyError::Median => {
                let m = vamos_robot::body_motion::body_motion_error(
                    &render.flow,
                    &processed.flow,
                    &render.mask,
                )?;
                m.body_visible.then_some(m.e_b_px)
            }
            BodyError::Quantile => residual::body_residual(
                &render.flow,
                &render.mask,
                &processed.flow,
                self.quantile,
                self.moving_px,
            ),
        })
    }
}
