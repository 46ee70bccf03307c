//! The per-frame detectors, one module each, behind one trait.
//!
//! A detector module holds everything that is the detector's own: the value it measures
//! per frame, the map it keeps for calibration and anomaly maps, its state across frames,
//! and (for those that have them) how calibration fits its nominal statistics. The scorer
//! runs the robot pose, the render and the visual front end once per frame and hands what
//! they made to every detector in force through a [`FrameContext`]; each writes its value
//! and whatever else it measures into the [`FrameScore`] under construction.
//!
//! | module | value | needs |
//! |---|---|---|
//! | [`camera`] | `e_c`: expected vs registered camera motion | robot, joint states, two poses |
//! | [`body`] | `e_b`: rendered vs observed body flow | robot, joint states, two poses |
//! | [`flow`] | `e_o`: the flow predictor's error | a model |
//! | [`scene`] | `e_r`: the static scene's residual motion | (the registration without a robot) |
//! | [`kinematics`] | `e_k`: distance to the nominal robot states | robot, joint states, a calibration |
//!
//! Adding a detector: a [`crate::eval::Detector`] variant (its key and names), its module
//! here, and one line in [`build`]. The wire formats carry each detector's value under its
//! key.

pub mod body;
pub mod camera;
mod cells;
pub mod flow;
pub mod kinematics;
pub mod scene;

use super::frames::ProcessedFrame;
use super::scorer::{FrameScore, JointInput, RobotSetup, ScorerError};
use super::{DetectorSwitches, PipelineConfig};
use crate::eval::{Detector, Thresholds};
use nalgebra::Isometry3;
use std::sync::Arc;
use vamos_model::FlowModel;
use vamos_model::predictor::PredictorParams;
use vamos_robot::Intrinsics;
use vamos_robot::camera_motion::Depth;
use vamos_robot::render::RenderOutput;
use vamos_vision::GrayImage;

/// A processed frame's robot pose: `base_from_link` of every link and `camera_from_base`.
pub type Pose = (Vec<Isometry3<f64>>, Isometry3<f64>);

/// What the scorer computed once for a frame, for every detector.
pub struct FrameContext<'a> {
    /// Image stamp, nanoseconds.
    pub stamp_ns: i64,
    /// Seconds since the stream's first image.
    pub phase_s: f64,
    /// The frame's joint states, if any.
    pub joints: Option<JointInput<'a>>,
    /// The positions of the joints that move of their own (robot joint order), when the
    /// frame has joint states.
    pub positions: Option<&'a [f64]>,
    /// This frame's pose and the previous processed frame's.
    pub pose: Option<&'a Pose>,
    /// The previous processed frame's pose.
    pub previous_pose: Option<&'a Pose>,
    /// The intrinsics at the processing resolution (when the robot was rendered).
    pub intrinsics: Option<&'a Intrinsics>,
    /// The body render of this frame (mask, depth, expected body flow from the previous
    /// pose), when the robot was rendered.
    pub render: Option<&'a RenderOutput>,
    /// The previous processed frame's body mask (empty when it had none).
    pub previous_mask: &'a [bool],
    /// Where the static scene lies at the previous frame: its depth image, the learned
    /// depth, or the assumed depth.
    pub depth: Depth<'a>,
    /// The visual front end's output (`None` on a stream's first frame: no flow yet).
    pub processed: Option<&'a ProcessedFrame>,
    /// This frame's image at the processing resolution, equalised.
    pub image: Option<&'a GrayImage>,
    /// The calibration the frame is scored against.
    pub thresholds: &'a Thresholds,
    /// Processing `(width, height)`.
    pub size: (usize, usize),
}

/// One detector of a stream.
pub trait FrameDetector: Send {
    /// Which detector this is.
    fn detector(&self) -> Detector;

    /// Measures `frame`: returns the detector's value (`None`: not defined for this frame)
    /// and writes what else it measures (maps, states, evidence) into `out`.
    fn measure(
        &mut self,
        frame: &FrameContext<'_>,
        out: &mut FrameScore,
    ) -> Result<Option<f64>, ScorerError>;

    /// Forgets the stream's history.
    fn reset(&mut self) {}

    /// The flow predictor's temporal parameters (the flow detector's).
    fn predictor_params(&self) -> Option<PredictorParams> {
        None
    }
}

/// What the detectors of a stream are built from.
pub struct Inputs<'a> {
    /// The pipeline.
    pub config: &'a PipelineConfig,
    /// The robot, if the profile has one.
    pub robot: Option<&'a RobotSetup>,
    /// The flow predictor's model, if any.
    pub model: Option<Arc<FlowModel>>,
    /// Prior samples M per offset (0: the bundle's).
    pub samples: usize,
    /// The predictor's seed.
    pub seed: u64,
    /// Keep each frame's prediction-error map.
    pub heatmaps: bool,
}

/// The detectors in force (`in_force`), in the order they run. The kinematic novelty
/// runs first: it is defined on a stream's first frame, which has no flow.
pub fn build(
    inputs: Inputs<'_>,
    in_force: DetectorSwitches,
) -> Result<Vec<Box<dyn FrameDetector>>, ScorerError> {
    let mut out: Vec<Box<dyn FrameDetector>> = Vec::new();
    let config = inputs.config;
    if let (true, Some(robot)) = (in_force.kinematics, inputs.robot) {
        out.push(Box::new(kinematics::Kinematics::new(config, robot)));
    }
    if in_force.camera {
        out.push(Box::new(camera::Camera::new(config)));
    }
    if in_force.body {
        out.push(Box::new(body::Body::new(config)));
    }
    if in_force.scene {
        out.push(Box::new(scene::Scene::new(config)));
    }
    if let (true, Some(model)) = (in_force.flow, inputs.model) {
        out.push(Box::new(flow::Flow::new(
            config,
            model,
            inputs.samples,
            inputs.seed,
            inputs.heatmaps,
        )?));
    }
    Ok(out)
}
