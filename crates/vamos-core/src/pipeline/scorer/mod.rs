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

use super::attach::AttachedShapes;
use super::depth::{LearnedDepth, ViewIndex};
use super::detectors::{self, FrameContext, FrameDetector, Pose};
use super::frames::FrameProcessor;
use super::{DetectorSwitches, PipelineConfig};
use crate::eval::{DetectorValues, Thresholds, Window, fuse_frame};
use nalgebra::Isometry3;

use std::sync::Arc;
use std::time::Instant;
use vamos_model::FlowModel;
use vamos_model::predictor::PredictorParams;
use vamos_robot::JointMapper;
use vamos_robot::camera_motion::Depth;
use vamos_robot::render::{BodyRenderer, RenderConfig, RenderFrame, RenderOutput, RobotView};
use vamos_vision::flow::FlowParams;
use vamos_vision::preprocess::NetworkInputParams;
use vamos_vision::registration::RegistrationParams;

mod types;

pub use types::{FrameInput, FrameScore, JointInput, RobotSetup, ScorerError, StageTimings};

/// The state that moves the robot and renders it.
struct BodyState {
    setup: RobotSetup,
    mapper: JointMapper,
    renderer: Box<dyn BodyRenderer>,
    out: RenderOutput,
    /// Previous processed frame: `base_from_link` and `camera_from_base`.
    previous: Option<Pose>,
    /// The joints that move of their own (not fixed, not mimic): their indices in the
    /// robot's joint order (the positions the kinematic novelty takes).
    own: Vec<usize>,
    /// The previous processed frame's body mask (empty when it had none).
    previous_mask: Vec<bool>,
    /// The profile's attached shapes, and the link poses with theirs the renderer is given
    /// (reused buffers for the current and the previous view).
    shapes: AttachedShapes,
    view_poses: (Vec<Isometry3<f64>>, Vec<Isometry3<f64>>),
}

/// The detector of one stream (a session or an episode); see the module docs.
pub struct Scorer {
    config: PipelineConfig,
    thresholds: Thresholds,
    alarm_threshold: f64,
    processor: FrameProcessor,
    body: Option<BodyState>,
    /// The detectors in force, in the order they run.
    detectors: Vec<Box<dyn FrameDetector>>,
    /// The flow predictor's temporal parameters, when it runs.
    predictor: Option<PredictorParams>,
    images: u64,
    frames: u64,
    last_stamp_ns: Option<i64>,
    /// The stream's first image stamp: a frame's phase is its time since then.
    first_stamp_ns: Option<i64>,
    warned_no_joints: bool,
    /// The last processed frame's depth image at the processing resolution (NaN where it
    /// has none); empty when it came without one.
    previous_depth: Vec<f32>,
    warned_depth: bool,
    /// The calibration's learned depth of the static scene (used where a frame has no
    /// depth image); `None` without one.
    learned_depth: Option<LearnedDepthCache>,
    /// The last `temporal_window` fused scores.
    window: Window,
}

/// The learned depth of the static scene and the pixel depths of the view last used.
struct LearnedDepthCache {
    depth: LearnedDepth,
    index: ViewIndex,
    view: Option<usize>,
    pixels: Arc<[f32]>,
}

impl LearnedDepthCache {
    /// The pixel depths (`size`) for a frame whose flow starts at this camera pose: its
    /// view's, or every view's without a pose or a view near it.
    fn at(
        &mut self,
        camera_from_base: Option<&Isometry3<f64>>,
        size: (usize, usize),
    ) -> Arc<[f32]> {
        let view = camera_from_base.and_then(|p| self.index.nearest(p));
        if view != self.view {
            self.pixels = Arc::from(self.depth.pixel_depths(view, size.0, size.1));
            self.view = view;
        }
        self.pixels.clone()
    }
}

/// Keeps the frame's depth image in `kept` at the processing resolution `size` for the
/// next frame, without the pixels of the robot and what it carries (`mask`, this frame's
/// body mask if it has one): they move with the robot, not with the static scene, so the
/// next frame takes the assumed depth there (what `e_c`'s grid fit used before depth
/// images; `e_r` leaves them out anyway). A depth image of another aspect ratio than the
/// frame's image is not registered to it and is left out (warned once per stream): the
/// next frame uses the assumed depth.
fn keep_depth(
    kept: &mut Vec<f32>,
    warned: &mut bool,
    (w, h): (usize, usize),
    input: &FrameInput<'_>,
    mask: Option<&[bool]>,
    index: u64,
) {
    let Some(depth) = input.depth else {
        return;
    };
    let (width, height) = input.image.size();
    if depth.fits(width, height) {
        depth.resample_into(w, h, kept);
        if let Some(mask) = mask.filter(|m| m.len() == kept.len()) {
            for (d, _) in kept.iter_mut().zip(mask).filter(|(_, m)| **m) {
                *d = f32::NAN;
            }
        }
    } else if !*warned {
        let (dw, dh) = depth.size();
        tracing::warn!(
            index,
            "depth image {dw}x{dh} does not fit the {width}x{height} image (another aspect \
             ratio: not registered to it); the assumed depth is used"
        );
        *warned = true;
    }
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
        let body = match robot {
            Some(setup) => {
                let mut renderer = vamos_robot::render::create_renderer(&render)?;
                // The robot's own meshes are used in place; a copy only with attachments.
                let (with_attachments, shapes, _) =
                    AttachedShapes::new(&setup.robot, &config.attach);
                renderer.prepare(if shapes.is_empty() {
                    setup.robot.link_meshes()
                } else {
                    &with_attachments
                })?;
                let joints = setup.robot.joints();
                let own: Vec<usize> = (0..joints.len())
                    .filter(|&j| joints[j].kind.is_moving() && joints[j].mimic.is_none())
                    .collect();
                Some(BodyState {
                    mapper: setup.robot.joint_mapper(),
                    setup,
                    own,
                    renderer,
                    out: RenderOutput::default(),
                    previous: None,
                    previous_mask: Vec::new(),
                    shapes,
                    view_poses: Default::default(),
                })
            }
            None => None,
        };
        let in_force = config.detectors.in_force(body.is_some(), model.is_some());
        let detectors = detectors::build(
            detectors::Inputs {
                config: &config,
                robot: body.as_ref().map(|b| &b.setup),
                model,
                samples,
                seed,
                heatmaps,
            },
            in_force,
        )?;
        let predictor = detectors.iter().find_map(|d| d.predictor_params());
        let processor = FrameProcessor::new(config.frames.clone(), flow, registration, network)?;
        // Only the flow predictor reads the network input.
        let processor = if predictor.is_some() {
            processor
        } else {
            processor.without_network_input()
        };
        let window = Window::new(config.temporal_window);
        let learned_depth = match &thresholds.depth {
            Some(d) => {
                d.validate().map_err(ScorerError::Config)?;
                Some(LearnedDepthCache {
                    pixels: Arc::from(d.pixel_depths(
                        None,
                        config.frames.width,
                        config.frames.height,
                    )),
                    view: None,
                    index: d.view_index(),
                    depth: d.clone(),
                })
            }
            None => None,
        };
        Ok(Self {
            config,
            thresholds,
            alarm_threshold,
            processor,
            body,
            detectors,
            predictor,
            images: 0,
            frames: 0,
            last_stamp_ns: None,
            first_stamp_ns: None,
            warned_no_joints: false,
            previous_depth: Vec::new(),
            warned_depth: false,
            learned_depth,
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
        self.config
            .detectors
            .in_force(self.body.is_some(), self.predictor.is_some())
    }

    /// The predictor's temporal parameters, if there is a model.
    pub fn predictor_params(&self) -> Option<PredictorParams> {
        self.predictor
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
            b.previous_mask.clear();
        }
        for d in &mut self.detectors {
            d.reset();
        }
        self.images = 0;
        self.frames = 0;
        self.last_stamp_ns = None;
        self.first_stamp_ns = None;
        self.previous_depth.clear();
        self.window.clear();
    }

    /// Images were lost before the next one (dropped by an overloaded server, refused, or
    /// missing from a recording): forgets the motion history as [`Self::reset`] does, but
    /// keeps the stream's position (the counters, the stamp order and the phase's origin).
    /// The next image starts the history afresh: it gets no motion score and cannot alarm
    /// (a [`FrameScore::warming_up`] frame), so the motion over a gap is never compared
    /// with the motion expected between two consecutive frames.
    pub fn restart_after_gap(&mut self) {
        let (images, frames) = (self.images, self.frames);
        let (last, first) = (self.last_stamp_ns, self.first_stamp_ns);
        self.reset();
        (self.images, self.frames) = (images, frames);
        (self.last_stamp_ns, self.first_stamp_ns) = (last, first);
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
        let mut positions = None;
        let pose = match (&mut self.body, input.joints) {
            (Some(body), Some(joints)) => {
                let (links, camera_from_base, q) = body.pose(joints)?;
                positions = Some(q);
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
                // Both views' link poses with the attached shapes' (there or not as decided
                // at this frame).
                let (now, before) = &mut body.view_poses;
                body.shapes.poses(links, camera_from_base, now);
                let previous = body.previous.as_ref().map(|(links, camera_from_base)| {
                    body.shapes.poses(links, camera_from_base, before);
                    RobotView {
                        camera_from_base: *camera_from_base,
                        base_from_link: before,
                    }
                });
                body.renderer.render(
                    &RenderFrame {
                        intrinsics: &k,
                        current: RobotView {
                            camera_from_base: *camera_from_base,
                            base_from_link: now,
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
        let (previous_pose, previous_mask) = match &mut self.body {
            Some(body) => {
                let previous = body.previous.take();
                body.previous = pose.clone();
                let previous_mask = std::mem::take(&mut body.previous_mask);
                if intrinsics.is_some() {
                    body.previous_mask.clone_from(&body.out.mask);
                }
                (previous, previous_mask)
            }
            None => (None, Vec::new()),
        };
        // The flow runs from the previous frame: its depth places the static scene.
        let previous_depth = std::mem::take(&mut self.previous_depth);
        keep_depth(
            &mut self.previous_depth,
            &mut self.warned_depth,
            (w, h),
            input,
            self.body
                .as_ref()
                .filter(|_| intrinsics.is_some())
                .map(|b| b.out.mask.as_slice()),
            index,
        );
        let learned_depth = match &mut self.learned_depth {
            Some(cache) if previous_depth.is_empty() && processed.is_some() => {
                Some(cache.at(previous_pose.as_ref().map(|p| &p.1), (w, h)))
            }
            _ => None,
        };
        let depth = match (&previous_depth, &learned_depth) {
            (d, _) if !d.is_empty() => Depth::Image(d),
            (_, Some(learned)) => Depth::Image(learned),
            _ => Depth::Assumed,
        };
        let phase = phase_s(first_ns, input.stamp_ns);
        let mut score = FrameScore {
            index,
            frame,
            stamp_ns: input.stamp_ns,
            score: 0.0,
            values: DetectorValues::default(),
            anomaly: false,
            triggered: None,
            warming_up: processed.is_none(),
            best_offset: None,
            registration_confidence: processed.as_ref().map(|p| p.registration.confidence),
            body_pixels,
            timings: StageTimings::default(),
            heatmap: None,
            scene_cells: None,
            scene_grid: (0, 0),
            flow_cells: None,
            flow_grid: (0, 0),
            phase_s: phase,
            kinematic_state: None,
            depth_evidence: None,
        };
        if let Some(p) = &processed {
            timings.front_end = p.timings;
        }
        let context = FrameContext {
            stamp_ns: input.stamp_ns,
            phase_s: phase,
            joints: input.joints,
            positions: positions.as_deref(),
            pose: pose.as_ref(),
            previous_pose: previous_pose.as_ref(),
            intrinsics: intrinsics.as_ref(),
            render: self
                .body
                .as_ref()
                .filter(|_| intrinsics.is_some())
                .map(|b| &b.out),
            previous_mask: &previous_mask,
            depth,
            processed: processed.as_ref(),
            image: self.processor.current(),
            thresholds: &self.thresholds,
            size: (w, h),
        };
        for detector in &mut self.detectors {
            let t0 = Instant::now();
            let d = detector.detector();
            score.values[d] = detector.measure(&context, &mut score)?;
            *timings.of(d) += micros(t0);
        }
        if processed.is_some() {
            let fused = self.window.push(fuse_frame(
                &score.values,
                &self.thresholds,
                self.config
                    .fusion
                    .resolve(&self.thresholds, self.predictor.is_some()),
            ));
            score.score = fused.score;
            score.anomaly = fused.score >= self.alarm_threshold;
            score.triggered = fused.triggered;
        }
        timings.total_us = micros(start);
        score.timings = timings;
        Ok(Some(score))
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
        self.shapes.update(q.as_slice());
        let links = self.setup.robot.forward(&q)?;
        let camera_from_base =
            self.setup
                .mount
                .camera_from_base(&links)
                .ok_or(ScorerError::CameraPose {
                    link: self.setup.mount.link,
                    poses: links.len(),
                })?;
        let own = self.own.iter().map(|&j| q.as_slice()[j]).collect();
        Ok((links, camera_from_base, own))
    }
}

fn micros(start: Instant) -> u64 {
    u64::try_from(start.elapsed().as_micros()).unwrap_or(u64::MAX)
}

#[cfg(test)]
mod tests;
