//! Tests of the scorer: a pan head over a textured scene whose images move exactly as its
//! joint states say (nominal) or move while the joint states stand still (anomaly).

use super::*;
use crate::robot::camera_motion::{CameraMotionParams, expected_camera_motion};
use crate::robot::render::RenderBackend;
use crate::robot::{CameraConvention, RobotConfig};
use crate::vision::synthetic::Texture;

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
    let mut config = PipelineConfig {
        stride,
        ..PipelineConfig::default()
    };
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
    let texture = Texture::random(11);
    let names = names();
    let mut out = Vec::new();
    for k in 0..frames {
        let (sx, sy) = expected_shift(setup, 0.0, step_rad * k as f64);
        let image = frame(&texture, sx, sy);
        let q = [reported(k)];
        let score = s
            .push(&FrameInput {
                stamp_ns: k as i64 * 100_000_000,
                image: &image,
                joints: Some(JointInput {
                    names: &names,
                    positions: &q,
                }),
                intrinsics: None,
            })
            .unwrap();
        out.extend(score);
    }
    out
}

#[test]
fn nominal_pan_gives_small_errors_and_no_trigger() {
    let setup = setup();
    let thresholds = Thresholds {
        e_c: Some(0.8),
        e_b: None,
    };
    let mut s = scorer(Some(setup.clone()), thresholds, 1);
    let step = 0.01;
    let scores = run(&mut s, &setup, 5, step, |k| step * k as f64);
    assert_eq!(scores.len(), 5);
    assert!(scores[0].warming_up && scores[0].e_c.is_none());
    let (sx, _) = expected_shift(&setup, 0.0, step);
    assert!(
        sx.abs() > 1.0,
        "the pan moves the image by {sx} px per frame"
    );
    for f in &scores[1..] {
        let e_c = f.e_c.unwrap();
        assert!(e_c < 0.3, "nominal e_c {e_c} (frame {})", f.frame);
        let e_b = f.e_b.expect("the box is in view");
        assert!(e_b < 0.5, "nominal e_b {e_b}");
        assert!(f.body_pixels > 100, "{}", f.body_pixels);
        assert_eq!(f.triggered, None);
        assert!(!f.anomaly);
        assert!(f.e_o.is_none(), "no model");
    }
}

#[test]
fn motion_the_joints_do_not_show_triggers_the_camera_detector() {
    let setup = setup();
    let thresholds = Thresholds {
        e_c: Some(0.8),
        e_b: None,
    };
    let mut s = scorer(Some(setup.clone()), thresholds, 1);
    let step = 0.01;
    let (sx, sy) = expected_shift(&setup, 0.0, step);
    let shift = sx.abs() + sy.abs();
    // The camera is pushed: the image pans, the joint states stay at 0.
    let scores = run(&mut s, &setup, 4, step, |_| 0.0);
    for f in &scores[1..] {
        let e_c = f.e_c.unwrap();
        assert!(
            (e_c - shift).abs() < 0.35,
            "e_c {e_c} should be the unexplained shift {shift}"
        );
        let e_b = f.e_b.unwrap();
        assert!((e_b - shift).abs() < 0.5, "e_b {e_b} vs {shift}");
        assert_eq!(f.triggered, Some(Detector::Camera));
        assert!(f.score > 1.0, "a triggered frame outranks e_o: {}", f.score);
        assert!(f.anomaly, "{}", f.score);
    }
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
    assert!(f.e_c.is_none() && f.e_b.is_none() && f.e_o.is_none());
    assert!(!f.warming_up, "no model: nothing to warm up");
    assert_eq!(f.score, 0.0);
    // A robot profile whose frames come without joint states scores them anyway.
    let setup = setup();
    let mut s = scorer(Some(setup), Thresholds::default(), 1);
    s.push(&input(0)).unwrap();
    let f = s.push(&input(1)).unwrap().unwrap();
    assert!(f.e_c.is_none() && f.e_b.is_none());
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
            }),
            intrinsics: None,
        })
        .unwrap_err();
    assert!(matches!(e, ScorerError::Robot(_)), "{e}");
}
