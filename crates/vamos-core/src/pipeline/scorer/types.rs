//! What a [`Scorer`](super::Scorer) takes in and gives out: the robot set-up, a frame's
//! input, its scores and stage timings, and the errors of a frame or of building a scorer.

use super::super::frames::{FrontEndTimings, PipelineError};
use crate::eval::{Detector, DetectorValues};
use serde::Serialize;
use std::sync::Arc;
use vamos_model::ModelError;
use vamos_robot::camera_motion::CameraMotionError;
use vamos_robot::render::RenderError;
use vamos_robot::{BodyMotionError, CameraMount, Intrinsics, IntrinsicsError, Robot, RobotError};
use vamos_vision::{DepthImage, GrayImage};

/// Errors of one pushed frame (the scorer stays usable) or of building a scorer.
#[derive(Debug, thiserror::Error)]
pub enum ScorerError {
    /// The visual front end failed.
    #[error(transparent)]
    Frame(#[from] PipelineError),
    /// Joint mapping or forward kinematics refused the joint states.
    #[error("robot: {0}")]
    Robot(#[from] RobotError),
    /// The kinematics gave no pose for the camera's link.
    #[error("robot: the camera link (link {link}) has no pose among the {poses} link poses")]
    CameraPose {
        /// The camera's link index.
        link: usize,
        /// Link poses the kinematics returned.
        poses: usize,
    },
    /// The intrinsics cannot be scaled to the processing resolution.
    #[error("robot: camera intrinsics at {width}x{height}: {source}")]
    Intrinsics {
        /// Processing width, pixels.
        width: usize,
        /// Processing height, pixels.
        height: usize,
        /// Why.
        #[source]
        source: IntrinsicsError,
    },
    /// The body renderer could not be made, prepared or run.
    #[error("robot: render: {0}")]
    Render(#[from] RenderError),
    /// The expected camera (or static scene) motion from two camera poses.
    #[error("robot: camera motion: {0}")]
    CameraMotion(#[from] CameraMotionError),
    /// The median body-motion error `e_b`.
    #[error("robot: body motion: {0}")]
    BodyMotion(#[from] BodyMotionError),
    /// The flow predictor failed.
    #[error("flow predictor: {0}")]
    Model(#[from] ModelError),
    /// Image stamps must increase.
    #[error(
        "image {index} has stamp {stamp_ns} ns, not after the previous image's {previous_ns} ns"
    )]
    StampNotIncreasing {
        /// Index of the refused image in the stream.
        index: u64,
        /// Its stamp.
        stamp_ns: i64,
        /// The last accepted stamp.
        previous_ns: i64,
    },
    /// The configuration cannot work (e.g. a masked variant without a robot).
    #[error("pipeline configuration: {0}")]
    Config(String),
}

/// The robot a scorer renders and moves: its description and where the camera sits.
#[derive(Clone)]
pub struct RobotSetup {
    /// The robot.
    pub robot: Arc<Robot>,
    /// The camera's link and optical frame.
    pub mount: CameraMount,
    /// The profile's intrinsics, at any resolution (scaled to the processing resolution);
    /// a frame's own camera info wins over it.
    pub intrinsics: Option<Intrinsics>,
}

/// Joint states of one frame (already interpolated to the image stamp).
#[derive(Debug, Clone, Copy)]
pub struct JointInput<'a> {
    /// Joint names.
    pub names: &'a [String],
    /// Positions, radians or metres, parallel to `names`.
    pub positions: &'a [f64],
    /// Efforts (N m or N), parallel to `names`; empty when the joint states carry none.
    pub efforts: &'a [f64],
}

/// One image of the stream.
#[derive(Debug, Clone, Copy)]
pub struct FrameInput<'a> {
    /// Image stamp, nanoseconds (must increase).
    pub stamp_ns: i64,
    /// Gray image 0..255 at any resolution (resized to the processing resolution).
    pub image: &'a GrayImage,
    /// Joint states at the image stamp, if any.
    pub joints: Option<JointInput<'a>>,
    /// Intrinsics from the stream's camera info, at the image's resolution.
    pub intrinsics: Option<&'a Intrinsics>,
    /// A depth image registered to `image` (same field of view, any resolution of the
    /// same aspect ratio), if the robot streams one: the next frame's expected static
    /// scene motion places each pixel at its depth instead of the assumed depth.
    pub depth: Option<&'a DepthImage>,
}

/// Wall time per stage of one frame, microseconds.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize)]
pub struct StageTimings {
    /// Forward kinematics and joint mapping.
    pub kinematics_us: u64,
    /// Robot render (mask, expected body flow).
    pub render_us: u64,
    /// The visual front end (resize, registration, flow, network input).
    pub front_end: FrontEndTimings,
    /// Expected camera motion and `e_c`.
    pub camera_us: u64,
    /// `e_b`.
    pub body_us: u64,
    /// `e_r` (expected image flow, residual cells, pooling).
    pub scene_us: u64,
    /// The flow predictor (encoder + head).
    pub model_us: u64,
    /// The whole push.
    pub total_us: u64,
}

impl StageTimings {
    /// The stage that holds `detector`'s own time (the kinematic novelty's shares the
    /// forward kinematics', the flow predictor's is `model_us`).
    pub fn of(&mut self, detector: Detector) -> &mut u64 {
        match detector {
            Detector::Camera => &mut self.camera_us,
            Detector::Body => &mut self.body_us,
            Detector::Flow => &mut self.model_us,
            Detector::Scene => &mut self.scene_us,
            Detector::Kinematics => &mut self.kinematics_us,
        }
    }
}

/// The score of one processed frame.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct FrameScore {
    /// Index of the image in the stream (0-based, counting skipped images).
    pub index: u64,
    /// Index among processed frames.
    pub frame: u64,
    /// Image stamp, nanoseconds.
    pub stamp_ns: i64,
    /// The fused score (see [`crate::eval::fuse`]).
    pub score: f64,
    /// Each detector's value (`None`: off, or not defined for this frame): `e_c` and
    /// `e_b` in pixels, `e_o` the mean squared flow-prediction error (network-input
    /// units), `e_r` the pooled, nominal-normalised scene residual (raw pixels before
    /// calibration), `e_k` the distance to the nearest nominal robot state in nominal
    /// joint ranges (metres for `state = "links"`; none before calibration). Serialised
    /// as the fields `e_c` .. `e_k`.
    #[serde(flatten)]
    pub values: DetectorValues,
    /// The alarm: `score` reached the alarm threshold.
    pub anomaly: bool,
    /// Which detector's threshold the frame crossed, if any.
    pub triggered: Option<Detector>,
    /// The predictor lacks `A + B` frames of history (scored from `e_c` and `e_b` only).
    pub warming_up: bool,
    /// The past offset `n` of the best prediction.
    pub best_offset: Option<usize>,
    /// Registration confidence (peak-energy share) of the observed camera motion.
    pub registration_confidence: Option<f32>,
    /// Robot pixels in the body mask.
    pub body_pixels: usize,
    /// Per-stage timings.
    pub timings: StageTimings,
    /// `[S, S]` squared prediction error of the best prediction (when heatmaps are on).
    #[serde(skip)]
    pub heatmap: Option<Vec<f32>>,
    /// The scene residual per cell, pixels, before normalisation (what calibration fits
    /// its per-cell statistics on); row-major, `scene_grid` cells.
    #[serde(skip)]
    pub scene_cells: Option<Vec<f32>>,
    /// Seconds since the stream's first image (the phase the scene statistics use).
    #[serde(skip)]
    pub phase_s: f64,
    /// `(columns, rows)` of `scene_cells`.
    #[serde(skip)]
    pub scene_grid: (usize, usize),
    /// The flow predictor's error per cell before normalisation (`flow_pooling =
    /// "cells"`: what calibration fits the `e_o` statistics on); `flow_grid` cells.
    #[serde(skip)]
    pub flow_cells: Option<Vec<f32>>,
    /// `(columns, rows)` of `flow_cells`.
    #[serde(skip)]
    pub flow_grid: (usize, usize),
    /// The robot's state (what calibration keeps as the nominal states of `e_k`).
    #[serde(skip)]
    pub kinematic_state: Option<Vec<f32>>,
    /// The frame's evidence on the static scene's depth (what calibration learns the
    /// depth from with `learn_depth`).
    #[serde(skip)]
    pub depth_evidence: Option<crate::pipeline::depth::DepthEvidence>,
}
