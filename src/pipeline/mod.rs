//! Frame in, scores out. Synchronous and deterministic; the service and the offline tools
//! (`vamos export-dataset`, later `vamos score`) run exactly this code.
//!
//! - [`frames`]: the visual front end of every processed frame: resize to the processing
//!   resolution, histogram equalisation, TV-L1 flow from the previous processed frame,
//!   Fourier-Mellin registration, and the flow predictor's 64x64 input in the configured
//!   [`FlowVariant`].
//! - [`dataset`]: the training dataset (`docs/model-bundle.md`) written from processed frames.

pub mod dataset;
pub mod frames;

pub use frames::{
    FlowVariant, FrameProcessor, FrameProcessorParams, PipelineError, ProcessedFrame,
};

use crate::robot::camera_motion::{CameraErrorWeights, CameraMotionParams};
use serde::{Deserialize, Serialize};

/// The `[pipeline]` settings.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct PipelineConfig {
    /// Process every `stride`-th image (the paper: 3, i.e. 10 Hz flow from a 30 Hz camera).
    pub stride: usize,
    /// The visual front end.
    pub frames: FrameProcessorParams,
    /// The expected camera motion.
    pub camera_motion: CameraMotionParams,
    /// Optional rotation and scale terms of `e_c`.
    pub camera_error: CameraErrorWeights,
}

impl Default for PipelineConfig {
    fn default() -> Self {
        Self {
            stride: 1,
            frames: FrameProcessorParams::default(),
            camera_motion: CameraMotionParams::default(),
            camera_error: CameraErrorWeights::default(),
        }
    }
}
