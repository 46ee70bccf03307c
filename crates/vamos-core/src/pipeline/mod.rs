//! Frame in, scores out. Synchronous and deterministic; the service and the offline tools
//! (`vamos export-dataset`, later `vamos score`) run exactly this code.
//!
//! - [`frames`]: the visual front end of every processed frame: resize to the processing
//!   resolution, histogram equalisation, TV-L1 flow from the previous processed frame,
//!   Fourier-Mellin registration, and the flow predictor's 64x64 input in the configured
//!   [`FlowVariant`].
//! - [`scorer`]: the detector of one stream: frames and joint states in, fused scores out.
//! - [`detectors`]: the per-frame detectors (`e_c`, `e_b`, `e_o`, `e_r`, `e_k`), one module
//!   each behind one trait, with their calibration statistics.
//! - [`profile`]: what binds a robot, a camera, pipeline parameters, a model and the
//!   calibrated thresholds, as a TOML file plus its calibration.
//! - [`calibration`]: thresholds from nominal episodes (`vamos calibrate`, service jobs).
//! - [`novelty`]: the robot's state (link positions and velocities) whose distance to
//!   every nominal state is the kinematic novelty `e_k`.
//! - [`dataset`]: the training dataset (`docs/model-bundle.md`) written from processed frames.

pub mod attach;
pub mod calibration;
pub mod dataset;
pub mod depth;
pub mod detectors;
pub mod frames;
pub mod layout;
pub mod novelty;
pub mod offline;
pub mod profile;
pub mod residual;
pub mod scorer;

// The flow variant is the model's type (a bundle's manifest names the one it was trained
// on); the pipeline computes it.
pub use frames::{
    FrameProcessor, FrameProcessorParams, FrontEndTimings, PipelineError, ProcessedFrame,
};
pub use profile::{AlarmRule, Calibration, Profile, ProfileError, ProfileFile, ThresholdOverrides};
pub use scorer::{
    FrameInput, FrameScore, JointInput, RobotSetup, Scorer, ScorerError, ScorerParts, StageTimings,
};
pub use vamos_model::FlowVariant;

pub use novelty::{EffortWindow, KinematicsParams, StateKind};
pub use residual::{BodyError, FlowPooling, ResidualParams};

use crate::eval::{Detector, Fusion};
use serde::{Deserialize, Serialize};
use vamos_robot::camera_motion::{CameraErrorWeights, CameraMotionParams};

/// The `[pipeline]` settings.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
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
    /// Which detectors contribute to the score (the paper's ablation columns).
    pub detectors: DetectorSwitches,
    /// The scene and body residuals.
    pub residual: ResidualParams,
    /// The robot state of the kinematic novelty `e_k`.
    pub kinematics: KinematicsParams,
    /// Shapes attached to the robot's links (rendered and masked with the body).
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub attach: Vec<attach::Attachment>,
    /// How the detectors become one score (`auto`, `paper` or `calibrated`).
    pub fusion: Fusion,
    /// A frame's score is the largest fused score of the last this many processed frames
    /// (itself included; 1: its own): evidence a few frames long counts, an alarm starts as
    /// early and lasts `temporal_window - 1` frames longer.
    pub temporal_window: usize,
    /// Smallest past offset A (processed frames); absent = the model bundle's.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub offset_a: Option<usize>,
    /// Offsets span `A..=A+B`; absent = the model bundle's B.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub offset_b: Option<usize>,
    /// Prior samples M per past offset; absent = the settings' `[model] samples` (whose 0
    /// means the bundle's `temporal.m`); 0 here also means the bundle's.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub samples: Option<usize>,
}

/// Which detectors contribute to the score. A detector also needs its inputs: camera and
/// body need a robot and joint states, flow a model.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(default, deny_unknown_fields)]
pub struct DetectorSwitches {
    /// Camera-motion error `e_c`.
    pub camera: bool,
    /// Body-motion error `e_b`.
    pub body: bool,
    /// Flow-prediction error `e_o`.
    pub flow: bool,
    /// Scene-motion residual `e_r`.
    pub scene: bool,
    /// Kinematic novelty `e_k`.
    pub kinematics: bool,
}

impl Default for DetectorSwitches {
    fn default() -> Self {
        Self {
            camera: true,
            body: true,
            flow: true,
            scene: true,
            kinematics: true,
        }
    }
}

impl DetectorSwitches {
    /// Whether `detector` is switched on.
    pub fn get(&self, detector: Detector) -> bool {
        match detector {
            Detector::Camera => self.camera,
            Detector::Body => self.body,
            Detector::Flow => self.flow,
            Detector::Scene => self.scene,
            Detector::Kinematics => self.kinematics,
        }
    }

    /// The switches in force for a profile with or without a robot and a flow model: the
    /// camera, body and kinematic detectors need a robot, the flow detector a model.
    pub fn in_force(&self, robot: bool, flow_model: bool) -> DetectorSwitches {
        DetectorSwitches {
            camera: self.camera && robot,
            body: self.body && robot,
            flow: self.flow && flow_model,
            scene: self.scene,
            kinematics: self.kinematics && robot,
        }
    }
}

/// Largest `temporal_window`, frames.
pub const MAX_TEMPORAL_WINDOW: usize = 64;

impl PipelineConfig {
    /// Refuses sizes no scorer is built with: a processing resolution out of range
    /// ([`FrameProcessorParams::validate`]) or a past offset override beyond
    /// [`vamos_model::predictor::MAX_PAST_OFFSET`]. The scorer checks them again when it
    /// is built (with the model's own offsets); the store checks a profile's pipeline when
    /// the profile is stored, so that it is refused then rather than when a robot first
    /// uses it.
    pub fn check_limits(&self) -> Result<(), String> {
        if self.stride == 0 {
            return Err("pipeline parameter stride must be at least 1".into());
        }
        self.frames.validate().map_err(|e| e.to_string())?;
        self.residual.validate()?;
        self.kinematics.validate()?;
        if !(1..=MAX_TEMPORAL_WINDOW).contains(&self.temporal_window) {
            return Err(format!(
                "pipeline parameter temporal_window = {} must lie in 1..={MAX_TEMPORAL_WINDOW} frames",
                self.temporal_window
            ));
        }
        let max = vamos_model::predictor::MAX_PAST_OFFSET;
        for (name, value) in [("offset_a", self.offset_a), ("offset_b", self.offset_b)] {
            if let Some(v) = value
                && v > max
            {
                return Err(format!(
                    "pipeline parameter {name} = {v} is above the limit of {max} frames"
                ));
            }
        }
        let max = vamos_model::predictor::MAX_SAMPLES;
        if let Some(m) = self.samples
            && m > max
        {
            return Err(format!(
                "pipeline parameter samples = {m} is above the limit of {max} prior samples"
            ));
        }
        Ok(())
    }
}

impl Default for PipelineConfig {
    fn default() -> Self {
        Self {
            stride: 1,
            frames: FrameProcessorParams::default(),
            camera_motion: CameraMotionParams::default(),
            camera_error: CameraErrorWeights::default(),
            detectors: DetectorSwitches::default(),
            residual: ResidualParams::default(),
            kinematics: KinematicsParams::default(),
            attach: Vec::new(),
            fusion: Fusion::default(),
            temporal_window: 1,
            offset_a: None,
            offset_b: None,
            samples: None,
        }
    }
}
