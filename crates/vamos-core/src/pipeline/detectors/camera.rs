//! `e_c`, the camera-motion error (REFERENCE.md section 1): the image motion expected
//! from the previous and current camera poses (the kinematics) against the registered
//! similarity (Fourier-Mellin). Calibration: the paper's threshold is its maximum over
//! the training frames ([`crate::eval::Thresholds::e_c`]); the calibrated fusion scales it
//! by its nominal median and spread.

use super::{FrameContext, FrameDetector};
use crate::eval::Detector;
use crate::pipeline::PipelineConfig;
use crate::pipeline::scorer::{FrameScore, ScorerError};
use vamos_robot::camera_motion::{
    CameraErrorWeights, CameraMotionParams, camera_motion_error, expected_camera_motion,
};

/// The camera-motion detector.
pub struct Camera {
    motion: CameraMotionParams,
    weights: CameraErrorWeights,
}

impl Camera {
    /// With the pipeline's camera-motion settings.
    pub fn new(config: &PipelineConfig) -> Camera {
        Camera {
            motion: config.camera_motion.clone(),
            weights: config.camera_error.clone(),
        }
    }
}

impl FrameDetector for Camera {
    fn detector(&self) -> Detector {
        Detector::Camera
    }

    /// Needs both poses, the intrinsics and the flow's frame pair. A registration that
    /// failed numerically gives `+inf` (it must alarm, not hide).
    fn measure(
        &mut self,
        frame: &FrameContext<'_>,
        _out: &mut FrameScore,
    ) -> Result<Option<f64>, ScorerError> {
        let (Some((_, current)), Some((_, previous)), Some(k), Some(processed)) = (
            frame.pose,
            frame.previous_pose,
            frame.intrinsics,
            frame.processed,
        ) else {
            return Ok(None);
        };
        let expected = expected_camera_motion(previous, current, k, frame.depth, &self.motion)?;
        let e = camera_motion_error(
            &expected.transform,
            &processed.registration.transform,
            &self.weights,
        );
        Ok(Some(if e.is_nan() { f64::INFINITY } else { e }))
    }
}
