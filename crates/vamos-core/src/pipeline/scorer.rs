//! The detector of one stream: image (+ joint states) in, a scored frame out
//! (REFERENCE.md sections 1-3 and "Score").
//!
//! Per pushed image, with state carried across frames:
//! 1. the frame stride: only every `stride`-th image is processed (the others return
//!    `None` and cost nothing);
//! 2. joint states -> forward kinematics -> `camera_from_base` (when the scorer has a
//!    robot and the frame has joint states);
//! 3. the robot body rendered at `t` (body mask of the target frame, and the exact
//!    expected body flow `t-1 -> t` when the previous frame had a pose);
//! 4. the visual front end ([`FrameProcessor`]): TV-L1 flow, Fourier-Mellin registration
//!    with the body masked out, the flow variant, the 64x64 network input;
//! 5. `e_c` (expected camera motion from the two camera poses vs. the registration),
//!    `e_b` (body flow, expected vs. observed: the paper's medians or the per-pixel
//!    quantile), `e_r` (the scene-motion residual outside the robot, [`super::residual`]),
//!    `e_o` (the flow predictor);
//! 6. the fused score ([`crate::eval::fuse_frame`], `paper` or `calibrated`) and the alarm
//!    flag.
//!
//! A component that cannot be computed for a frame is `None`, never a made-up number:
//! no joint states (no `e_c`, no `e_b`), robot not in view (no `e_b`), first processed
//! frame (no flow at all), model warming up. Until the predictor has `A + B` frames of
//! history the frame is scored from `e_c` and `e_b` only and marked `warming_up`.
//! Everything switchable (detectors, variant, resolution, A, B, M) comes from
//! [`PipelineConfig`]; the paper's ablations are configuration changes.
//!
//! A frame that fails (bad pixels, NaN joints, stamps going backwards) is an error that
//! leaves the scorer as it was for the stages that had not run yet; the next good frame
//! goes on from the last good one.

use super::frames::{FrameProcessor, FrontEndTimings, PipelineError, ProcessedFrame};
use super::residual::{self, BodyError};
use super::{DetectorSwitches, PipelineConfig};
use crate::eval::{Components, Detector, Pooling, Thresholds, Window, fuse_frame, pool_cells};
use nalgebra::Isometry3;
use serde::Serialize;
use std::sync::Arc;
use std::time::Instant;
use vamos_model::predictor::{Prediction, Predictor, PredictorParams};
use vamos_model::{FlowModel, ModelError};
use vamos_robot::camera_motion::{
    CameraMotionError, Depth, camera_motion_error, expected_camera_motion, expected_image_flow,
    similarity_flow,
};
use vamos_robot::render::{
    BodyRenderer, RenderConfig, RenderError, RenderFrame, RenderOutput, RobotView,
};
use vamos_robot::{
    BodyMotionError, CameraMount, Intrinsics, IntrinsicsError, JointMapper, Robot, RobotError,
};
use vamos_vision::flow::FlowParams;
use vamos_vision::preprocess::NetworkInputParams;
use vamos_vision::registration::RegistrationParams;
use vamos_vision::{FlowField, GrayImage};

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
    /// Camera-motion error, pixels.
    pub e_c: Option<f64>,
    /// Body-motion error, pixels.
    pub e_b: Option<f64>,
    /// Flow-prediction error (mean squared error in network-input units).
    pub e_o: Option<f64>,
    /// Scene-motion residual: the pooled, nominal-normalised residual of the static
    /// scene (raw pixels before calibration).
    pub e_r: Option<f64>,
    /// Kinematic novelty: distance from the robot's state to the nearest nominal state, in
    /// nominal joint ranges (metres for `state = "links"`; none before calibration).
    pub e_k: Option<f64>,
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
    /// The robot's state (what calibration keeps as the nominal states of `e_k`).
    #[serde(skip)]
    pub kinematic_state: Option<Vec<f32>>,
}

/// The state that moves the robot and renders it.
struct BodyState {
    setup: RobotSetup,
    mapper: JointMapper,
    renderer: Box<dyn BodyRenderer>,
    out: RenderOutput,
    /// Previous processed frame: `base_from_link` and `camera_from_base`.
    previous: Option<(Vec<Isometry3<f64>>, Isometry3<f64>)>,
    /// The previous processed frame's stamp and the positions part of its robot state
    /// (`e_k`).
    previous_positions: Option<(i64, Vec<f64>)>,
    /// The previous processed frame's body mask (empty when it had none).
    previous_mask: Vec<bool>,
}

/// The detector of one stream (a session or an episode); see the module docs.
pub struct Scorer {
    config: PipelineConfig,
    thresholds: Thresholds,
    alarm_threshold: f64,
    heatmaps: bool,
    processor: FrameProcessor,
    body: Option<BodyState>,
    predictor: Option<Predictor>,
    images: u64,
    frames: u64,
    last_stamp_ns: Option<i64>,
    /// The stream's first image stamp: a frame's phase is its time since then.
    first_stamp_ns: Option<i64>,
    warned_no_joints: bool,
    /// The expected image flow of the current frame (reused buffer).
    expected_flow: FlowField,
    /// The last `temporal_window` fused scores.
    window: Window,
}

/// Seconds from `first_ns` to `stamp_ns` (a frame's phase in its episode).
pub fn phase_s(first_ns: i64, stamp_ns: i64) -> f64 {
    (stamp_ns.saturating_sub(first_ns)) as f64 * 1e-9
}

/// What a [`Scorer`] is built from.
pub struct ScorerParts {
    /// Pipeline parameters.
    pub config: PipelineConfig,
    /// TV-L1 parameters.
    pub flow: FlowParams,
    /// Registration parameters.
    pub registration: RegistrationParams,
    /// Flow -> network input.
    pub network: NetworkInputParams,
    /// Render settings.
    pub render: RenderConfig,
    /// The robot (without it: no `e_c`, no `e_b`, no masked variants).
    pub robot: Option<RobotSetup>,
    /// The flow predictor's model (without it: no `e_o`).
    pub model: Option<Arc<FlowModel>>,
    /// Prior samples M per past offset; 0 = the model bundle's (`[model] samples`).
    /// `config.samples`, when given, replaces it.
    pub samples: usize,
    /// Seed of the predictor's prior samples.
    pub seed: u64,
    /// Per-detector thresholds.
    pub thresholds: Thresholds,
    /// `anomaly` is set when the fused score is at least this (`+inf`: never).
    pub alarm_threshold: f64,
    /// Keep the prediction-error map of every scored frame.
    pub heatmaps: bool,
}

impl Scorer {
    /// Builds a scorer; checks that the configuration can work with what it is given.
    pub fn new(parts: ScorerParts) -> Result<Self, ScorerError> {
        let ScorerParts {
            config,
            flow,
            registration,
            network,
            render,
            robot,
            model,
            samples,
            seed,
            thresholds,
            alarm_threshold,
            heatmaps,
        } = parts;
        if config.stride == 0 {
            return Err(ScorerError::Config("stride must be at least 1".into()));
        }
        config.residual.validate().map_err(ScorerError::Config)?;
        if config.frames.variant.is_masked() && robot.is_none() {
            return Err(ScorerError::Config(format!(
                "flow variant {} masks the robot body: the profile needs a robot",
                config.frames.variant
            )));
        }
        let predictor = match model {
            Some(model) if config.detectors.flow => {
                let manifest = model.manifest();
                if manifest.flow_variant != config.frames.variant {
                    tracing::warn!(
                        model = ?manifest.flow_variant,
                        pipeline = %config.frames.variant,
                        "the model was trained on another flow variant than the pipeline computes"
                    );
                }
                let samples = config.samples.unwrap_or(samples);
                let mut params = PredictorParams::from_manifest(manifest, samples);
                if let Some(a) = config.offset_a {
                    params.a = a;
                }
                if let Some(b) = config.offset_b {
                    params.b = b;
                }
                Some(Predictor::new(model, params, seed)?)
            }
            _ => None,
        };
        let body = match robot {
            Some(setup) => {
                let mut renderer = vamos_robot::render::create_renderer(&render)?;
                // The robot's own meshes are used in place; a copy only with attachments.
                let with_attachments;
                let meshes = if config.attach.is_empty() {
                    setup.robot.link_meshes()
                } else {
                    with_attachments =
                        super::attach::meshes_with_attachments(&setup.robot, &config.attach).0;
                    with_attachments.as_slice()
                };
                renderer.prepare(meshes)?;
                Some(BodyState {
                    mapper: setup.robot.joint_mapper(),
                    setup,
                    renderer,
                    out: RenderOutput::default(),
                    previous: None,
                    previous_positions: None,
                    previous_mask: Vec::new(),
                })
            }
            None => None,
        };
        let processor = FrameProcessor::new(config.frames.clone(), flow, registration, network)?;
        let window = Window::new(config.temporal_window);
        Ok(Self {
            config,
            thresholds,
            alarm_threshold,
            heatmaps,
            processor,
            body,
            predictor,
            images: 0,
            frames: 0,
            last_stamp_ns: None,
            first_stamp_ns: None,
            warned_no_joints: false,
            expected_flow: FlowField::zeros(0, 0),
            window,
        })
    }

    /// The alarm threshold and each detector's own threshold this scorer alarms with
    /// (its thresholds under its fusion, resolved on whether it has a predictor).
    pub fn detector_thresholds(&self) -> crate::eval::DetectorThresholds {
        crate::eval::DetectorThresholds::new(
            &self.thresholds,
            self.alarm_threshold,
            self.config.fusion,
            self.predictor.is_some(),
        )
    }

    /// The pipeline parameters.
    pub fn config(&self) -> &PipelineConfig {
        &self.config
    }

    /// The detector switches actually in force (flow needs a model, camera and body a
    /// robot).
    pub fn active(&self) -> DetectorSwitches {
        DetectorSwitches {
            camera: self.config.detectors.camera && self.body.is_some(),
            body: self.config.detectors.body && self.body.is_some(),
            flow: self.predictor.is_some(),
            scene: self.config.detectors.scene,
            kinematics: self.config.detectors.kinematics && self.body.is_some(),
        }
    }

    /// The predictor's temporal parameters, if there is a model.
    pub fn predictor_params(&self) -> Option<PredictorParams> {
        self.predictor.as_ref().map(Predictor::params)
    }

    /// Images pushed so far (including skipped and refused ones).
    pub fn images_seen(&self) -> u64 {
        self.images
    }

    /// Starts a new stream: forgets every past frame (the random generator goes on).
    pub fn reset(&mut self) {
        self.processor.reset();
        if let Some(b) = &mut self.body {
            b.previous = None;
            b.previous_positions = None;
            b.previous_mask.clear();
        }
        if let Some(p) = &mut self.predictor {
            p.reset();
        }
        self.images = 0;
        self.frames = 0;
        self.last_stamp_ns = None;
        self.first_stamp_ns = None;
        self.window.clear();
    }

    /// Takes over the stream position of `previous` (the image and frame counters and
    /// the last stamp) with none of its history: a scorer that replaces another mid-stream
    /// (another model version) keeps the indices going and the stamp order checked, and
    /// warms up like a new stream.
    pub fn continue_after(&mut self, previous: &Scorer) {
        self.images = previous.images;
        self.frames = previous.frames;
        self.last_stamp_ns = previous.last_stamp_ns;
        self.first_stamp_ns = previous.first_stamp_ns;
    }

    /// Pushes the next image. `Ok(None)` for images the stride skips.
    pub fn push(&mut self, input: &FrameInput<'_>) -> Result<Option<FrameScore>, ScorerError> {
        let start = Instant::now();
        let index = self.images;
        self.images += 1;
        if let Some(previous_ns) = self.last_stamp_ns
            && input.stamp_ns <= previous_ns
        {
            return Err(ScorerError::StampNotIncreasing {
                index,
                stamp_ns: input.stamp_ns,
                previous_ns,
            });
        }
        self.last_stamp_ns = Some(input.stamp_ns);
        let first_ns = *self.first_stamp_ns.get_or_insert(input.stamp_ns);
        if !index.is_multiple_of(self.config.stride as u64) {
            return Ok(None);
        }
        let mut timings = StageTimings::default();
        let (w, h) = (self.config.frames.width, self.config.frames.height);

        // Robot pose and render at t.
        let t0 = Instant::now();
        let mut joint_positions = None;
        let pose = match (&mut self.body, input.joints) {
            (Some(body), Some(joints)) => {
                let (links, camera_from_base, q) = body.pose(joints)?;
                joint_positions = Some(q);
                Some((links, camera_from_base))
            }
            (Some(_), None) => {
                if !self.warned_no_joints {
                    tracing::warn!(
                        index,
                        "frame without joint states: no e_c, no e_b, body not masked"
                    );
                    self.warned_no_joints = true;
                }
                None
            }
            _ => None,
        };
        timings.kinematics_us = micros(t0);
        let t0 = Instant::now();
        let mut intrinsics = None;
        if let (Some(body), Some((links, camera_from_base))) = (&mut self.body, &pose) {
            let k = input.intrinsics.or(body.setup.intrinsics.as_ref());
            if let Some(k) = k {
                let k =
                    k.scaled_to(w as u32, h as u32)
                        .map_err(|source| ScorerError::Intrinsics {
                            width: w,
                            height: h,
                            source,
                        })?;
                let previous = body
                    .previous
                    .as_ref()
                    .map(|(links, camera_from_base)| RobotView {
                        camera_from_base: *camera_from_base,
                        base_from_link: links,
                    });
                body.renderer.render(
                    &RenderFrame {
                        intrinsics: &k,
                        current: RobotView {
                            camera_from_base: *camera_from_base,
                            base_from_link: links,
                        },
                        previous,
                        shade: false,
                    },
                    &mut body.out,
                )?;
                intrinsics = Some(k);
            }
        }
        timings.render_us = micros(t0);
        let mask = match (&self.body, &intrinsics) {
            (Some(body), Some(_)) => Some(body.out.mask.as_slice()),
            _ => None,
        };
        // A masked variant without a mask this frame (no joints or no intrinsics): nothing
        // is masked, rather than no score at all.
        let empty;
        let mask = match mask {
            None if self.config.frames.variant.is_masked() => {
                empty = vec![false; w * h];
                Some(empty.as_slice())
            }
            m => m,
        };
        let body_pixels = mask.map_or(0, |m| m.iter().filter(|&&v| v).count());

        let processed = self.processor.push(input.image, mask)?;
        let frame = self.frames;
        self.frames += 1;
        // The positions part of the robot's state for e_k.
        let kinematic_positions = match (&pose, &joint_positions) {
            (Some((links, _)), Some(q)) if self.config.detectors.kinematics => {
                Some(self.config.kinematics.positions(q, links))
            }
            _ => None,
        };
        let (previous_pose, previous_mask, previous_positions) = match &mut self.body {
            Some(body) => {
                let previous = body.previous.take();
                body.previous = pose.clone();
                let previous_positions = std::mem::replace(
                    &mut body.previous_positions,
                    kinematic_positions.clone().map(|p| (input.stamp_ns, p)),
                );
                let previous_mask = std::mem::take(&mut body.previous_mask);
                if intrinsics.is_some() {
                    body.previous_mask.clone_from(&body.out.mask);
                }
                (previous, previous_mask, previous_positions)
            }
            None => (None, Vec::new(), None),
        };
        // The robot's state for e_k (positions and their change since the previous frame).
        let t0 = Instant::now();
        let kinematic_state = kinematic_positions.as_deref().and_then(|now| {
            self.config.kinematics.state(
                now,
                previous_positions
                    .as_ref()
                    .map(|(then, before)| (before.as_slice(), phase_s(*then, input.stamp_ns))),
            )
        });
        let e_k = kinematic_state.as_deref().and_then(|s| {
            self.thresholds
                .kinematics
                .as_ref()
                .and_then(|r| r.distance(s))
        });
        timings.kinematics_us += micros(t0);
        let Some(processed) = processed else {
            timings.total_us = micros(start);
            return Ok(Some(FrameScore {
                index,
                frame,
                stamp_ns: input.stamp_ns,
                score: 0.0,
                e_c: None,
                e_b: None,
                e_o: None,
                e_r: None,
                e_k,
                anomaly: false,
                triggered: None,
                warming_up: true,
                best_offset: None,
                registration_confidence: None,
                body_pixels,
                timings,
                heatmap: None,
                scene_cells: None,
                scene_grid: (0, 0),
                phase_s: phase_s(first_ns, input.stamp_ns),
                kinematic_state,
            }));
        };
        timings.front_end = processed.timings;

        let t0 = Instant::now();
        let e_c = match (&pose, &previous_pose, &intrinsics) {
            (Some((_, current)), Some((_, previous)), Some(k)) if self.config.detectors.camera => {
                let expected = expected_camera_motion(
                    previous,
                    current,
                    k,
                    Depth::Assumed,
                    &self.config.camera_motion,
                )?;
                let e = camera_motion_error(
                    &expected.transform,
                    &processed.registration.transform,
                    &self.config.camera_error,
                );
                // A registration that failed numerically must alarm, not hide.
                Some(if e.is_nan() { f64::INFINITY } else { e })
            }
            _ => None,
        };
        timings.camera_us = micros(t0);
        let t0 = Instant::now();
        let e_b = match (&self.body, &previous_pose, &intrinsics) {
            (Some(body), Some(_), Some(_)) if self.config.detectors.body => {
                match self.config.residual.body_error {
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
                }
            }
            _ => None,
        };
        timings.body_us = micros(t0);

        let t0 = Instant::now();
        let (e_r, scene_cells, scene_grid) = if self.config.detectors.scene {
            // The expected motion of the static scene: from the camera poses when both
            // frames have one, else the registered similarity.
            match (&pose, &previous_pose, &intrinsics) {
                (Some((_, current)), Some((_, previous)), Some(k)) => expected_image_flow(
                    previous,
                    current,
                    k,
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
            let (current_mask, motion_px) = match (&self.body, &intrinsics) {
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
            let exclude = residual::grow_union(current_mask, &previous_mask, w, h, margin);
            let cells = residual::scene_cells(
                &processed.flow,
                &self.expected_flow,
                &exclude,
                self.config.residual.cell_px,
                self.config
                    .residual
                    .normal_flow
                    .then_some(&processed.previous_image),
            );
            let (columns, rows) = residual::cell_grid(w, h, self.config.residual.cell_px);
            let e_r = pool_cells(
                &cells,
                columns,
                rows,
                self.thresholds
                    .scene
                    .as_ref()
                    .map(|s| s.at(Some(phase_s(first_ns, input.stamp_ns)))),
                Pooling {
                    top_fraction: self.config.residual.top_fraction,
                },
                None,
            );
            (e_r, Some(cells), (columns, rows))
        } else {
            (None, None, (0, 0))
        };
        timings.scene_us = micros(t0);

        let t0 = Instant::now();
        let (e_o, best_offset, heatmap, warming_up) = self.predict(&processed)?;
        timings.model_us = micros(t0);

        let fused = self.window.push(fuse_frame(
            &Components {
                e_c,
                e_b,
                e_r,
                e_o,
                e_k,
            },
            &self.thresholds,
            self.config.fusion.resolve(self.predictor.is_some()),
        ));
        timings.total_us = micros(start);
        Ok(Some(FrameScore {
            index,
            frame,
            stamp_ns: input.stamp_ns,
            score: fused.score,
            e_c,
            e_b,
            e_o,
            e_r,
            e_k,
            anomaly: fused.score >= self.alarm_threshold,
            triggered: fused.triggered,
            warming_up,
            best_offset,
            registration_confidence: Some(processed.registration.confidence),
            body_pixels,
            timings,
            heatmap,
            scene_cells,
            scene_grid,
            phase_s: phase_s(first_ns, input.stamp_ns),
            kinematic_state,
        }))
    }

    /// Runs the predictor on a processed frame: `(e_o, best n, heatmap, warming_up)`.
    #[allow(clippy::type_complexity)]
    fn predict(
        &mut self,
        processed: &ProcessedFrame,
    ) -> Result<(Option<f64>, Option<usize>, Option<Vec<f32>>, bool), ScorerError> {
        let Some(predictor) = &mut self.predictor else {
            return Ok((None, None, None, false));
        };
        let p = predictor.params();
        let history = predictor.frames_seen();
        let prediction =
            predictor.push(&processed.network_input, processed.network_valid.as_deref())?;
        let full_history = history >= (p.a + p.b) as u64;
        Ok(match prediction {
            Prediction::Scored(s) if full_history => (
                Some(s.e_o),
                Some(s.n),
                self.heatmaps.then_some(s.error_map),
                false,
            ),
            Prediction::Scored(_) | Prediction::WarmingUp { .. } => (None, None, None, true),
            Prediction::NoValidPixels { .. } => (None, None, None, !full_history),
        })
    }
}

impl BodyState {
    /// Maps the joint states and runs the kinematics: `(base_from_link, camera_from_base)`.
    /// The links' poses, the camera's pose and the positions of the joints that move of
    /// their own (not fixed, not mimic; joint order) of `joints`.
    #[allow(clippy::type_complexity)]
    fn pose(
        &mut self,
        joints: JointInput<'_>,
    ) -> Result<(Vec<Isometry3<f64>>, Isometry3<f64>, Vec<f64>), ScorerError> {
        let q = self.mapper.map(joints.names, joints.positions)?.positions;
        let links = self.setup.robot.forward(&q)?;
        let camera_from_base =
            self.setup
                .mount
                .camera_from_base(&links)
                .ok_or(ScorerError::CameraPose {
                    link: self.setup.mount.link,
                    poses: links.len(),
                })?;
        let own = self
            .setup
            .robot
            .joints()
            .iter()
            .zip(q.as_slice())
            .filter(|(j, _)| j.kind.is_moving() && j.mimic.is_none())
            .map(|(_, &v)| v)
            .collect();
        Ok((links, camera_from_base, own))
    }
}

fn micros(start: Instant) -> u64 {
    u64::try_from(start.elapsed().as_micros()).unwrap_or(u64::MAX)
}

#[cfg(test)]
#[path = "scorer_tests.rs"]
mod tests;
