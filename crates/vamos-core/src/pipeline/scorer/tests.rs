//! Tests of the scorer: a pan head over a textured scene whose images move exactly as its
//! joint states say (nominal) or move while the joint states stand still (anomaly).

use super::*;
use crate::eval::Detector;
use crate::pipeline::depth::LearnedDepth;
use vamos_robot::camera_motion::{CameraMotionParams, expected_camera_motion};
use vamos_robot::camera_motion::{Depth, expected_image_flow};
use vamos_robot::render::RenderBackend;
use vamos_robot::{CameraConvention, RobotConfig};
use vamos_robot::{Intrinsics, Robot};
use vamos_vision::synthetic::Texture;
use vamos_vision::{DepthImage, FlowField, GrayImage};

const W: usize = 160;
const H: usize = 120;

/// A base with a panning head (optical camera frame) and a box 0.8 m in front of it.
const URDF: &str = r#"<robot name="pan_head">
  <link name="base"/>
  <link name="head"/>
  <link name="camera_optical"/>
  <link name="box">
    <visual><geometry><box size="0.1 0.3 0.3"/></geometry></visual>
  </link>
  <joint name="pan" type="revolute">
    <parent link="base"/><child link="head"/><axis xyz="0 0 1"/>
    <limit lower="-3" upper="3" effort="1" velocity="1"/>
  </joint>
  <joint name="optical" type="fixed">
    <parent link="head"/><child link="camera_optical"/>
    <origin rpy="-1.5707963267948966 0 -1.5707963267948966"/>
  </joint>
  <joint name="box_fixed" type="fixed">
    <parent link="base"/><child link="box"/>
    <origin xyz="0.8 0.25 0"/>
  </joint>
</robot>"#;

fn setup() -> RobotSetup {
    let robot = Robot::from_urdf_str(URDF, None, &RobotConfig::default()).unwrap();
    let mount = robot
        .camera("camera_optical", CameraConvention::Optical)
        .unwrap();
    RobotSetup {
        robot: Arc::new(robot),
        mount,
        intrinsics: Some(Intrinsics::from_fov(W as u32, H as u32, 60.0).unwrap()),
    }
}

fn scorer(robot: Option<RobotSetup>, thresholds: Thresholds, stride: usize) -> Scorer {
    scorer_with(robot, thresholds, stride, |_| {})
}

/// [`scorer`] with the pipeline's settings changed by `adjust`.
fn scorer_with(
    robot: Option<RobotSetup>,
    thresholds: Thresholds,
    stride: usize,
    adjust: impl FnOnce(&mut PipelineConfig),
) -> Scorer {
    let mut config = PipelineConfig {
        stride,
        // The paper's bands (the tests below read `triggered` as the paper's trigger).
        fusion: crate::eval::Fusion::Paper,
        ..PipelineConfig::default()
    };
    adjust(&mut config);
    config.frames.width = W;
    config.frames.height = H;
    Scorer::new(ScorerParts {
        config,
        flow: FlowParams::realtime(),
        registration: RegistrationParams::default(),
        network: NetworkInputParams::default(),
        render: RenderConfig {
            backend: RenderBackend::Cpu,
            ..RenderConfig::default()
        },
        robot,
        model: None,
        samples: 0,
        seed: 0,
        thresholds,
        // Alarm on any triggered frame.
        alarm_threshold: crate::eval::TRIGGER_BASE,
        heatmaps: false,
    })
    .unwrap()
}

/// The image shift (tx, ty) of the pan from `from_rad` to `to_rad`, from the same
/// kinematics the scorer uses.
fn expected_shift(setup: &RobotSetup, from_rad: f64, to_rad: f64) -> (f64, f64) {
    let pose = |q: f64| {
        let q = setup
            .robot
            .joint_mapper()
            .map(&names(), &[q])
            .unwrap()
            .positions;
        let links = setup.robot.forward(&q).unwrap();
        setup.mount.camera_from_base(&links).unwrap()
    };
    let k = setup.intrinsics.unwrap();
    let m = expected_camera_motion(
        &pose(from_rad),
        &pose(to_rad),
        &k,
        Depth::Assumed,
        &CameraMotionParams::default(),
    )
    .unwrap();
    (m.transform.tx_px, m.transform.ty_px)
}

/// Frame `k` of a scene whose content has moved by `(sx, sy)` pixels.
fn frame(texture: &Texture, sx: f64, sy: f64) -> GrayImage {
    GrayImage::from_fn(W, H, |x, y| {
        texture.eval(x as f64 - sx, y as f64 - sy) as f32
    })
}

fn names() -> Vec<String> {
    vec!["pan".to_string()]
}

/// Runs `frames` frames panning by `step_rad` per frame; the joint states report
/// `reported(k)`. Returns the scores of the processed frames.
fn run(
    s: &mut Scorer,
    setup: &RobotSetup,
    frames: usize,
    step_rad: f64,
    reported: impl Fn(usize) -> f64,
) -> Vec<FrameScore> {
    run_with_effort(s, setup, frames, step_rad, reported, |_| None)
}

/// [`run`] with the joint states' effort `effort(k)` (none for `None`).
fn run_with_effort(
    s: &mut Scorer,
    setup: &RobotSetup,
    frames: usize,
    step_rad: f64,
    reported: impl Fn(usize) -> f64,
    effort: impl Fn(usize) -> Option<f64>,
) -> Vec<FrameScore> {
    let texture = Texture::random(11);
    let names = names();
    let mut out = Vec::new();
    for k in 0..frames {
        let (sx, sy) = expected_shift(setup, 0.0, step_rad * k as f64);
        let image = frame(&texture, sx, sy);
        let q = [reported(k)];
        let e: Vec<f64> = effort(k).into_iter().collect();
        let score = s
            .push(&FrameInput {
                stamp_ns: k as i64 * 100_000_000,
                image: &image,
                joints: Some(JointInput {
                    names: &names,
                    positions: &q,
                    efforts: &e,
                }),
                intrinsics: None,
                depth: None,
            })
            .unwrap();
        out.extend(score);
    }
    out
}

#[test]
fn nominal_pan_gives_small_errors_and_no_trigger() {
    let setup = setup();
    let thresholds = Thresholds::paper(Some(0.8), None);
    let mut s = scorer(Some(setup.clone()), thresholds, 1);
    let step = 0.01;
    let scores = run(&mut s, &setup, 5, step, |k| step * k as f64);
    assert_eq!(scores.len(), 5);
    assert!(scores[0].warming_up && scores[0].values[Detector::Camera].is_none());
    let (sx, _) = expected_shift(&setup, 0.0, step);
    assert!(
        sx.abs() > 1.0,
        "the pan moves the image by {sx} px per frame"
    );
    for f in &scores[1..] {
        let e_c = f.values[Detector::Camera].unwrap();
        assert!(e_c < 0.3, "nominal e_c {e_c} (frame {})", f.frame);
        let e_b = f.values[Detector::Body].expect("the box is in view");
        assert!(e_b < 0.5, "nominal e_b {e_b}");
        assert!(f.body_pixels > 100, "{}", f.body_pixels);
        assert_eq!(f.triggered, None);
        assert!(!f.anomaly);
        assert!(f.values[Detector::Flow].is_none(), "no model");
    }
}

#[test]
fn motion_the_joints_do_not_show_triggers_the_camera_detector() {
    let setup = setup();
    let thresholds = Thresholds::paper(Some(0.8), None);
    let mut s = scorer(Some(setup.clone()), thresholds, 1);
    let step = 0.01;
    let (sx, sy) = expected_shift(&setup, 0.0, step);
    let shift = sx.abs() + sy.abs();
    // The camera is pushed: the image pans, the joint states stay at 0.
    let scores = run(&mut s, &setup, 4, step, |_| 0.0);
    for f in &scores[1..] {
        let e_c = f.values[Detector::Camera].unwrap();
        assert!(
            (e_c - shift).abs() < 0.35,
            "e_c {e_c} should be the unexplained shift {shift}"
        );
        let e_b = f.values[Detector::Body].unwrap();
        assert!((e_b - shift).abs() < 0.5, "e_b {e_b} vs {shift}");
        assert_eq!(f.triggered, Some(Detector::Camera));
        assert!(f.score > 1.0, "a triggered frame outranks e_o: {}", f.score);
        assert!(f.anomaly, "{}", f.score);
    }
}

#[test]
fn after_a_gap_the_next_frame_starts_the_history_afresh_and_cannot_alarm() {
    let setup = setup();
    let thresholds = Thresholds::paper(Some(0.8), None);
    let mut s = scorer(Some(setup.clone()), thresholds, 1);
    let step = 0.01;
    // A pushed camera alarms on every frame with a predecessor.
    let texture = Texture::random(11);
    let names = names();
    let push = |s: &mut Scorer, k: usize| {
        let (sx, sy) = expected_shift(&setup, 0.0, step * k as f64);
        let image = frame(&texture, sx, sy);
        s.push(&FrameInput {
            stamp_ns: k as i64 * 100_000_000,
            image: &image,
            joints: Some(JointInput {
                names: &names,
                positions: &[0.0],
                efforts: &[],
            }),
            intrinsics: None,
            depth: None,
        })
        .unwrap()
        .unwrap()
    };
    for k in 0..3 {
        let f = push(&mut s, k);
        assert_eq!(f.anomaly, k > 0, "frame {k}: {}", f.score);
    }
    // Images 3 and 4 were lost.
    s.restart_after_gap();
    let resumed = push(&mut s, 5);
    assert!(resumed.warming_up && !resumed.anomaly && resumed.values[Detector::Camera].is_none());
    assert_eq!(resumed.score, 0.0);
    // The stream's position goes on: counters, phase, stamp order.
    assert_eq!((resumed.index, resumed.frame), (3, 3));
    assert!((resumed.phase_s - 0.5).abs() < 1e-9, "{}", resumed.phase_s);
    let next = push(&mut s, 6);
    assert!(
        next.anomaly && next.values[Detector::Camera].is_some(),
        "{}",
        next.score
    );
    s.restart_after_gap();
    let image = frame(&texture, 0.0, 0.0);
    let back = s.push(&FrameInput {
        stamp_ns: 600_000_000,
        image: &image,
        joints: None,
        intrinsics: None,
        depth: None,
    });
    assert!(
        matches!(back, Err(ScorerError::StampNotIncreasing { .. })),
        "{back:?}"
    );
}

#[test]
fn joint_states_no_nominal_run_had_show_in_e_k() {
    let setup = setup();
    let step = 0.01;
    // A nominal run: no reference yet, so no e_k, but every frame after the first has
    // a state (positions and velocities need two frames).
    let mut s = scorer(Some(setup.clone()), Thresholds::default(), 1);
    let nominal = run(&mut s, &setup, 6, step, |k| step * k as f64);
    assert!(
        nominal
            .iter()
            .all(|f| f.values[Detector::Kinematics].is_none())
    );
    assert!(nominal[0].kinematic_state.is_none());
    let states: Vec<Vec<f32>> = nominal
        .iter()
        .filter_map(|f| f.kinematic_state.clone())
        .collect();
    assert_eq!(states.len(), 5);
    let dims = states[0].len();
    let reference = crate::eval::StateReference::fit(&[states], dims, None).unwrap();
    let thresholds = Thresholds {
        kinematics: Some(reference),
        ..Thresholds::default()
    };
    // The same run again: every state is a nominal one.
    let mut s = scorer(Some(setup.clone()), thresholds.clone(), 1);
    let again = run(&mut s, &setup, 6, step, |k| step * k as f64);
    for f in &again[1..] {
        assert!(
            f.values[Detector::Kinematics].unwrap() < 1e-6,
            "{:?}",
            f.values[Detector::Kinematics]
        );
    }
    // The head reads half a radian further round (moving as before): its state lies at
    // least 0.45 rad (unscaled here) from every nominal one.
    let mut s = scorer(Some(setup.clone()), thresholds, 1);
    let turned = run(&mut s, &setup, 6, step, |k| 0.5 + step * k as f64);
    for f in &turned[1..] {
        let e_k = f.values[Detector::Kinematics].unwrap();
        assert!(e_k > 0.44, "e_k {e_k}");
    }
}

#[test]
fn a_load_the_nominal_runs_never_had_shows_in_e_k_with_efforts_on() {
    let setup = setup();
    let step = 0.01;
    let effort_on = |c: &mut PipelineConfig| {
        c.kinematics.effort = true;
        c.kinematics.effort_window = 3;
    };
    let pan = |k: usize| step * k as f64;
    let mut s = scorer_with(Some(setup.clone()), Thresholds::default(), 1, effort_on);
    let nominal = run_with_effort(&mut s, &setup, 6, step, pan, |_| Some(1.0));
    let states: Vec<Vec<f32>> = nominal
        .iter()
        .filter_map(|f| f.kinematic_state.clone())
        .collect();
    assert_eq!(states.len(), 5);
    assert_eq!(states[0].len(), 3, "position, velocity, effort");
    let reference = crate::eval::StateReference::fit(&[states], 3, None).unwrap();
    let thresholds = Thresholds {
        kinematics: Some(reference),
        ..Thresholds::default()
    };
    let e_k = |effort: &dyn Fn(usize) -> Option<f64>| {
        let mut s = scorer_with(Some(setup.clone()), thresholds.clone(), 1, effort_on);
        run_with_effort(&mut s, &setup, 6, step, pan, effort)
            .iter()
            .map(|f| f.values[Detector::Kinematics])
            .collect::<Vec<_>>()
    };
    // The same motion against a load of 4 (unscaled here): e_k is that load once the
    // median of three has it.
    let loaded = e_k(&|k| Some(if k >= 2 { 5.0 } else { 1.0 }));
    assert!(loaded[1].unwrap() < 1e-6, "{loaded:?}");
    assert!(
        loaded[2].unwrap() < 1e-6,
        "one frame of three is no load: {loaded:?}"
    );
    for e in &loaded[3..] {
        assert!((e.unwrap() - 4.0).abs() < 1e-3, "{loaded:?}");
    }
    // One spike is smoothed away.
    let spike = e_k(&|k| Some(if k == 3 { 50.0 } else { 1.0 }));
    assert!(spike[1..].iter().all(|e| e.unwrap() < 1e-6), "{spike:?}");
    // Joint states without efforts: no state, so no e_k (rather than a wrong one).
    let none = e_k(&|_| None);
    assert!(none.iter().all(Option::is_none), "{none:?}");
}

#[test]
fn stride_stamps_and_missing_joints() {
    let texture = Texture::random(3);
    let mut s = scorer(None, Thresholds::default(), 2);
    let image = frame(&texture, 0.0, 0.0);
    let input = |stamp_ns| FrameInput {
        stamp_ns,
        image: &image,
        joints: None,
        intrinsics: None,
        depth: None,
    };
    let first = s.push(&input(0)).unwrap().unwrap();
    assert_eq!((first.index, first.frame), (0, 0));
    assert!(
        s.push(&input(10)).unwrap().is_none(),
        "skipped by the stride"
    );
    let e = s.push(&input(10)).unwrap_err();
    assert!(
        matches!(e, ScorerError::StampNotIncreasing { index: 2, .. }),
        "{e}"
    );
    let next = s.push(&input(30)).unwrap();
    // Image 3 is odd: skipped; the refused image 2 still counted.
    assert!(next.is_none());
    let f = s.push(&input(40)).unwrap().unwrap();
    assert_eq!((f.index, f.frame), (4, 1));
    assert!(
        f.values[Detector::Camera].is_none()
            && f.values[Detector::Body].is_none()
            && f.values[Detector::Flow].is_none()
    );
    assert!(!f.warming_up, "no model: nothing to warm up");
    assert_eq!(f.score, 0.0);
    // A robot profile whose frames come without joint states scores them anyway.
    let setup = setup();
    let mut s = scorer(Some(setup), Thresholds::default(), 1);
    s.push(&input(0)).unwrap();
    let f = s.push(&input(1)).unwrap().unwrap();
    assert!(f.values[Detector::Camera].is_none() && f.values[Detector::Body].is_none());
    assert_eq!(f.body_pixels, 0);
}

#[test]
fn masked_variant_needs_a_robot_and_bad_joints_are_errors() {
    let mut config = PipelineConfig::default();
    config.frames.variant = super::super::FlowVariant::Masked;
    let parts = |robot| ScorerParts {
        config: config.clone(),
        flow: FlowParams::realtime(),
        registration: RegistrationParams::default(),
        network: NetworkInputParams::default(),
        render: RenderConfig::default(),
        robot,
        model: None,
        samples: 0,
        seed: 0,
        thresholds: Thresholds::default(),
        alarm_threshold: f64::INFINITY,
        heatmaps: false,
    };
    assert!(matches!(
        Scorer::new(parts(None)),
        Err(ScorerError::Config(_))
    ));
    let setup = setup();
    let mut s = scorer(Some(setup), Thresholds::default(), 1);
    let image = frame(&Texture::random(1), 0.0, 0.0);
    let names = names();
    let e = s
        .push(&FrameInput {
            stamp_ns: 0,
            image: &image,
            joints: Some(JointInput {
                names: &names,
                positions: &[f64::NAN],
                efforts: &[],
            }),
            intrinsics: None,
            depth: None,
        })
        .unwrap_err();
    assert!(matches!(e, ScorerError::Robot(_)), "{e}");
}

#[test]
fn a_small_object_falling_in_the_static_scene_shows_in_e_r() {
    let setup = setup();
    let mut s = scorer(Some(setup.clone()), Thresholds::paper(Some(0.8), None), 1);
    let (texture, object) = (Texture::random(11), Texture::random(5));
    let step = 0.01;
    let names = names();
    let mut scores = Vec::new();
    for k in 0..8usize {
        let (sx, sy) = expected_shift(&setup, 0.0, step * k as f64);
        // A 24x24 px object right of the box (two cells by two: the scene residual needs a
        // whole 2x2 block of cells to move), falling 3 px per frame from frame 5 on.
        let drop = 3.0 * k.saturating_sub(4) as f64;
        let image = GrayImage::from_fn(W, H, |x, y| {
            let (u, v) = (x as f64 - sx, y as f64 - sy);
            let (ou, ov) = (u - 110.0, v - 30.0 - drop);
            if (0.0..24.0).contains(&ou) && (0.0..24.0).contains(&ov) {
                (255.0 - object.eval(ou * 2.0, ov * 2.0)) as f32
            } else {
                texture.eval(u, v) as f32
            }
        });
        let q = [step * k as f64];
        let f = s
            .push(&FrameInput {
                stamp_ns: k as i64 * 100_000_000,
                image: &image,
                joints: Some(JointInput {
                    names: &names,
                    positions: &q,
                    efforts: &[],
                }),
                intrinsics: None,
                depth: None,
            })
            .unwrap()
            .unwrap();
        scores.push(f);
    }
    let e_r = |k: usize| scores[k].values[Detector::Scene].expect("scene residual");
    let nominal = (1..5).map(e_r).fold(0.0, f64::max);
    let falling = (5..8).map(e_r).fold(f64::INFINITY, f64::min);
    assert!(
        falling > 2.0 * nominal,
        "falling object e_r {falling} vs nominal max {nominal}"
    );
    // The cells keep where it happened: the block of 2x2 cells whose smallest value is the
    // largest (what e_r pools) lies on the object.
    let f = &scores[6];
    let (columns, rows) = f.scene_grid;
    let cells = f.scene_cells.as_ref().unwrap();
    let mut best = (f32::MIN, 0, 0);
    for r in 0..rows - 1 {
        for c in 0..columns - 1 {
            let block = [
                cells[r * columns + c],
                cells[r * columns + c + 1],
                cells[(r + 1) * columns + c],
                cells[(r + 1) * columns + c + 1],
            ];
            let m = block.iter().copied().fold(f32::INFINITY, f32::min);
            if m.is_finite() && m > best.0 {
                best = (m, c, r);
            }
        }
    }
    let (cx, cy) = (best.1 * 8 + 8, best.2 * 8 + 8);
    assert!(
        (100..148).contains(&cx) && (24..72).contains(&cy),
        "worst block at ({cx}, {cy})"
    );
    // The paper's camera and body detectors do not see it.
    assert!(
        scores[5..]
            .iter()
            .all(|f| f.values[Detector::Camera].unwrap() < 0.8)
    );
}

#[test]
fn the_expected_image_flow_of_a_pan_is_the_rotation_homography() {
    let setup = setup();
    let pose = |q: f64| {
        let q = setup
            .robot
            .joint_mapper()
            .map(&names(), &[q])
            .unwrap()
            .positions;
        let links = setup.robot.forward(&q).unwrap();
        setup.mount.camera_from_base(&links).unwrap()
    };
    let k = setup.intrinsics.unwrap();
    let mut flow = FlowField::zeros(0, 0);
    expected_image_flow(&pose(0.0), &pose(0.02), &k, Depth::Assumed, 1.0, &mut flow).unwrap();
    assert_eq!(flow.size(), (W, H));
    // A pure rotation: the depth does not matter.
    let mut far = FlowField::zeros(0, 0);
    expected_image_flow(&pose(0.0), &pose(0.02), &k, Depth::Assumed, 50.0, &mut far).unwrap();
    for (a, b) in flow.u.iter().zip(&far.u) {
        assert!((a - b).abs() < 1e-4);
    }
    // Near the centre the flow is the shift the similarity fit predicts; towards the edges
    // a pan moves pixels further (f / cos^2).
    let (sx, _) = expected_shift(&setup, 0.0, 0.02);
    let centre = flow.get(W / 2, H / 2).0 as f64;
    assert!((centre - sx).abs() < 0.1 * sx.abs(), "{centre} vs {sx}");
    let edge = flow.get(0, H / 2).0 as f64;
    assert!(edge.abs() > centre.abs() * 1.1, "{edge} vs {centre}");
    assert!(
        expected_image_flow(&pose(0.0), &pose(0.02), &k, Depth::Assumed, 0.0, &mut flow).is_err(),
        "depth 0"
    );
}

#[test]
fn a_gated_attachment_is_masked_only_while_its_joint_condition_holds() {
    let setup = setup();
    let step = 0.01;
    let body_pixels = |attach| {
        let mut s = scorer_with(Some(setup.clone()), Thresholds::paper(None, None), 1, |c| {
            c.attach = attach
        });
        run(&mut s, &setup, 5, step, |k| step * k as f64)
            .iter()
            .map(|f| f.body_pixels)
            .collect::<Vec<_>>()
    };
    let ball = |present_while| crate::pipeline::attach::Attachment {
        link: "base".into(),
        cuboid: None,
        cylinder: None,
        sphere: Some(0.08),
        xyz: [0.8, -0.2, 0.0],
        rpy: [0.0; 3],
        present_while,
    };
    let bare = body_pixels(Vec::new());
    let always = body_pixels(vec![ball(None)]);
    // There while the pan reads below 0.015 rad: the first two frames.
    let gated = body_pixels(vec![ball(Some(crate::pipeline::attach::JointCondition {
        joint: "pan".into(),
        below: Some(0.015),
        above: None,
    }))]);
    for k in 0..5 {
        assert!(
            always[k] > bare[k] + 300,
            "frame {k}: the ball adds its pixels ({} vs {})",
            always[k],
            bare[k]
        );
        let expected = if k < 2 { always[k] } else { bare[k] };
        assert_eq!(
            gated[k], expected,
            "frame {k}: {gated:?} {always:?} {bare:?}"
        );
    }
}

/// A camera on a slide (prismatic, sideways) looking at a wall.
const SLIDE_URDF: &str = r#"<robot name="slide_camera">
  <link name="base"/>
  <link name="carriage"/>
  <link name="camera_optical"/>
  <joint name="slide" type="prismatic">
    <parent link="base"/><child link="carriage"/><axis xyz="0 1 0"/>
    <limit lower="-1" upper="1" effort="1" velocity="1"/>
  </joint>
  <joint name="optical" type="fixed">
    <parent link="carriage"/><child link="camera_optical"/>
    <origin rpy="-1.5707963267948966 0 -1.5707963267948966"/>
  </joint>
</robot>"#;

#[test]
fn a_depth_image_places_the_static_scene_of_a_translating_camera() {
    let robot = Robot::from_urdf_str(SLIDE_URDF, None, &RobotConfig::default()).unwrap();
    let mount = robot
        .camera("camera_optical", CameraConvention::Optical)
        .unwrap();
    let setup = RobotSetup {
        robot: Arc::new(robot),
        mount,
        intrinsics: Some(Intrinsics::from_fov(W as u32, H as u32, 60.0).unwrap()),
    };
    // The wall is 0.5 m away; the profile assumes 1 m. The camera slides 1 cm per frame.
    let (wall_m, step_m) = (0.5, 0.01);
    let names = vec!["slide".to_string()];
    let pose = |q: f64| {
        let q = setup
            .robot
            .joint_mapper()
            .map(&names, &[q])
            .unwrap()
            .positions;
        setup
            .mount
            .camera_from_base(&setup.robot.forward(&q).unwrap())
            .unwrap()
    };
    let mut flow = FlowField::zeros(0, 0);
    let k = setup.intrinsics.unwrap();
    expected_image_flow(
        &pose(0.0),
        &pose(step_m),
        &k,
        Depth::Assumed,
        wall_m,
        &mut flow,
    )
    .unwrap();
    let (shift, _) = flow.get(W / 2, H / 2);
    assert!(shift.abs() > 2.0, "{shift} px per frame");
    let texture = Texture::random(5);
    let wall = DepthImage::new(W / 2, H / 2, vec![wall_m as f32; W * H / 4]).unwrap();
    let squashed = DepthImage::new(W, H / 4, vec![wall_m as f32; W * H / 4]).unwrap();
    // Mean raw e_r (pixels) over the frames after the first two, with the given depth
    // image or learned depth, and the frames' depth evidence (with `learn_depth`).
    let run = |depth: Option<&DepthImage>, learned: Option<LearnedDepth>, learn: bool| {
        let thresholds = Thresholds {
            depth: learned,
            ..Thresholds::default()
        };
        let mut s = scorer_with(Some(setup.clone()), thresholds, 1, |c| {
            c.camera_motion.learn_depth = learn
        });
        let (mut e_r, mut evidence) = (Vec::new(), Vec::new());
        for i in 0..6 {
            let image = frame(&texture, f64::from(shift) * i as f64, 0.0);
            let q = [step_m * i as f64];
            let score = s
                .push(&FrameInput {
                    stamp_ns: i as i64 * 100_000_000,
                    image: &image,
                    joints: Some(JointInput {
                        names: &names,
                        positions: &q,
                        efforts: &[],
                    }),
                    intrinsics: None,
                    depth,
                })
                .unwrap()
                .unwrap();
            if i >= 2 {
                e_r.push(score.values[Detector::Scene].expect("e_r"));
            }
            evidence.extend(score.depth_evidence);
        }
        (e_r.iter().sum::<f64>() / e_r.len() as f64, evidence)
    };
    let (with_depth, none) = run(Some(&wall), None, true);
    assert!(
        none.is_empty(),
        "frames with a depth image give no evidence"
    );
    let (assumed, evidence) = run(None, None, true);
    // A depth image of another aspect ratio is not registered to the image: left out.
    let (misfit, _) = run(Some(&squashed), None, false);
    assert!(with_depth < 0.3, "with the depth image: {with_depth} px");
    assert!(
        assumed > 0.2 * f64::from(shift.abs()),
        "assumed 1 m: {assumed} px (the true shift is {shift} px per frame)"
    );
    assert!(with_depth < 0.4 * assumed, "{with_depth} vs {assumed}");
    assert_eq!(misfit, assumed);
    // Learned from the frames without a depth image: the wall's depth, and the scene
    // residual of a stream without depth images as low as with them.
    assert_eq!(evidence.len(), 5, "every frame with flow and two poses");
    let learned = LearnedDepth::fit(&evidence, (16, 12)).unwrap();
    let (median, near, far) = learned.summary();
    assert!((median - 0.5).abs() < 0.05, "{median} m ({near} to {far})");
    let (with_learned, none) = run(None, Some(learned), true);
    assert!(none.is_empty(), "a calibrated depth is not learned again");
    assert!(
        with_learned < 1.5 * with_depth.max(0.1),
        "learned: {with_learned} px, depth image: {with_depth} px, assumed {assumed} px"
    );
}

#[test]
fn the_kept_depth_leaves_out_the_robot_and_refuses_another_aspect_ratio() {
    let image = GrayImage::zeros(8, 4);
    let input = |depth| FrameInput {
        stamp_ns: 0,
        image: &image,
        joints: None,
        intrinsics: None,
        depth: Some(depth),
    };
    // Half resolution, resampled to 8x4; the robot covers the two left columns.
    let depth = DepthImage::new(4, 2, vec![2.0; 8]).unwrap();
    let mask: Vec<bool> = (0..32).map(|i| i % 8 < 2).collect();
    let (mut kept, mut warned) = (Vec::new(), false);
    keep_depth(
        &mut kept,
        &mut warned,
        (8, 4),
        &input(&depth),
        Some(&mask),
        0,
    );
    assert_eq!(kept.len(), 32);
    for (i, d) in kept.iter().enumerate() {
        assert_eq!(d.is_nan(), mask[i], "pixel {i}: {d}");
        assert!(d.is_nan() || *d == 2.0);
    }
    assert!(!warned);
    // A depth image of another aspect ratio is not kept.
    let tall = DepthImage::new(2, 4, vec![2.0; 8]).unwrap();
    kept.clear();
    keep_depth(&mut kept, &mut warned, (8, 4), &input(&tall), None, 1);
    assert!(kept.is_empty() && warned);
}
