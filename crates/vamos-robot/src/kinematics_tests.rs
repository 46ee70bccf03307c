//! Kinematics: the URDF rpy convention, revolute / prismatic / continuous / mimic joints,
//! tree errors, position checks and a body-convention camera.

use super::*;
use nalgebra::Point3;
use std::f64::consts::FRAC_PI_2;

fn joint(name: &str, kind: JointKind, parent: usize, child: usize) -> Joint {
    Joint {
        name: name.into(),
        kind,
        parent,
        child,
        parent_from_joint: Isometry3::translation(0.0, 0.0, 1.0),
        axis: Vector3::z_axis(),
        limits: None,
        mimic: None,
    }
}

fn names(n: usize) -> Vec<String> {
    (0..n).map(|i| format!("l{i}")).collect()
}

#[test]
fn rpy_matches_the_urdf_convention() {
    // URDF: rotate about fixed x by roll, then fixed y by pitch, then fixed z by yaw.
    let (r, p, y) = (0.3_f64, -0.7_f64, 1.1_f64);
    let rx = nalgebra::Rotation3::from_axis_angle(&Vector3::x_axis(), r);
    let ry = nalgebra::Rotation3::from_axis_angle(&Vector3::y_axis(), p);
    let rz = nalgebra::Rotation3::from_axis_angle(&Vector3::z_axis(), y);
    let expect = rz * ry * rx;
    let got = isometry_from_xyz_rpy([0.0; 3], [r, p, y])
        .rotation
        .to_rotation_matrix();
    assert!((expect.matrix() - got.matrix()).norm() < 1e-12);
}

#[test]
fn revolute_chain_rotates_children() {
    // l0 -j0(rev z, +1 z)-> l1 -j1(fixed, +1 z then x offset)-> l2
    let mut j1 = joint("j1", JointKind::Fixed, 1, 2);
    j1.parent_from_joint = Isometry3::translation(1.0, 0.0, 0.0);
    let k = Kinematics::new(names(3), vec![joint("j0", JointKind::Revolute, 0, 1), j1]).unwrap();
    let q = k.positions(vec![FRAC_PI_2, 0.0]).unwrap();
    let poses = k.forward(&q).unwrap();
    assert_eq!(poses[0], Isometry3::identity());
    let p2 = poses[2] * Point3::origin();
    assert!((p2 - Point3::new(0.0, 1.0, 1.0)).norm() < 1e-12, "{p2}");
}

#[test]
fn prismatic_moves_along_its_axis_in_the_joint_frame() {
    let mut j = joint("slide", JointKind::Prismatic, 0, 1);
    j.parent_from_joint = isometry_from_xyz_rpy([0.0, 0.0, 1.0], [0.0, 0.0, FRAC_PI_2]);
    j.axis = Vector3::x_axis();
    let k = Kinematics::new(names(2), vec![j]).unwrap();
    let poses = k.forward(&k.positions(vec![0.25]).unwrap()).unwrap();
    // The joint frame's x is the parent's y after the 90 degree yaw.
    let p = poses[1] * Point3::origin();
    assert!((p - Point3::new(0.0, 0.25, 1.0)).norm() < 1e-12, "{p}");
}

#[test]
fn continuous_wraps_past_two_pi() {
    let k = Kinematics::new(names(2), vec![joint("c", JointKind::Continuous, 0, 1)]).unwrap();
    let a = k.forward(&k.positions(vec![0.4]).unwrap()).unwrap();
    let b = k
        .forward(&k.positions(vec![0.4 + 2.0 * std::f64::consts::PI]).unwrap())
        .unwrap();
    assert!(a[1].rotation.angle_to(&b[1].rotation) < 1e-9);
    assert!((a[1].rotation.angle() - 0.4).abs() < 1e-12);
    assert!(
        k.out_of_limits(&k.positions(vec![100.0]).unwrap())
            .is_empty()
    );
}

#[test]
fn mimic_follows_multiplier_and_offset() {
    let mut m = joint("m", JointKind::Revolute, 0, 2);
    m.mimic = Some(Mimic {
        joint: 0,
        multiplier: -2.0,
        offset: 0.1,
    });
    m.limits = Some(JointLimits {
        lower: -0.5,
        upper: 0.5,
    });
    let k = Kinematics::new(names(3), vec![joint("a", JointKind::Revolute, 0, 1), m]).unwrap();
    // The mimic's own entry (99) is ignored.
    let q = k.positions(vec![0.4, 99.0]).unwrap();
    let poses = k.forward(&q).unwrap();
    let angle = poses[2].rotation.scaled_axis().z;
    assert!((angle - (-2.0 * 0.4 + 0.1)).abs() < 1e-12, "{angle}");
    // The mimic is at -0.7, past its limits, but it cannot be set: not listed.
    assert!(k.out_of_limits(&q).is_empty(), "{:?}", k.out_of_limits(&q));
    // A leader past its own limits is listed (and its mimic still is not).
    let mut joints = k.joints().to_vec();
    joints[0].limits = Some(JointLimits {
        lower: -0.3,
        upper: 0.3,
    });
    let k = Kinematics::new(names(3), joints).unwrap();
    let v = k.out_of_limits(&k.positions(vec![0.4, 0.0]).unwrap());
    assert_eq!(v.len(), 1, "{v:?}");
    assert_eq!(v[0].joint, "a");
    assert!(
        k.out_of_limits(&k.positions(vec![0.1, 0.0]).unwrap())
            .is_empty()
    );
}

#[test]
fn tree_errors() {
    let e = Kinematics::new(
        names(3),
        vec![
            joint("a", JointKind::Fixed, 0, 1),
            joint("b", JointKind::Fixed, 2, 1),
        ],
    )
    .unwrap_err();
    assert!(
        matches!(e, RobotError::TwoParents { ref link, .. } if link == "l1"),
        "{e}"
    );
    let e = Kinematics::new(names(3), vec![joint("a", JointKind::Fixed, 0, 1)]).unwrap_err();
    assert_eq!(
        e,
        RobotError::MultipleRoots {
            roots: vec!["l0".into(), "l2".into()]
        }
    );
    let e = Kinematics::new(
        names(2),
        vec![
            joint("a", JointKind::Fixed, 0, 1),
            joint("b", JointKind::Fixed, 1, 0),
        ],
    )
    .unwrap_err();
    assert!(matches!(e, RobotError::KinematicCycle { .. }), "{e}");
    // A cycle beside a valid root.
    let e = Kinematics::new(
        names(3),
        vec![
            joint("a", JointKind::Fixed, 1, 2),
            joint("b", JointKind::Fixed, 2, 1),
        ],
    )
    .unwrap_err();
    assert!(matches!(e, RobotError::KinematicCycle { .. }), "{e}");
}

#[test]
fn positions_are_checked() {
    let k = Kinematics::new(names(2), vec![joint("a", JointKind::Revolute, 0, 1)]).unwrap();
    assert_eq!(
        k.positions(vec![]).unwrap_err(),
        RobotError::JointCount {
            expected: 1,
            got: 0
        }
    );
    let e = k.positions(vec![f64::NAN]).unwrap_err();
    assert!(matches!(e, RobotError::NonFiniteJoint { ref joint, .. } if joint == "a"));
    assert!(matches!(
        k.camera("nope", CameraConvention::Optical),
        Err(RobotError::UnknownCameraLink { .. })
    ));
}

#[test]
fn body_camera_looking_along_x_sees_a_point_ahead_on_its_axis() {
    // Camera link 1 m up, yawed 90 degrees: its x (forward) is the base's +y.
    let mut j = joint("cam_joint", JointKind::Fixed, 0, 1);
    j.parent_from_joint = isometry_from_xyz_rpy([0.0, 0.0, 1.0], [0.0, 0.0, FRAC_PI_2]);
    let k = Kinematics::new(vec!["base".into(), "camera_link".into()], vec![j]).unwrap();
    let poses = k.forward(&k.zero_positions()).unwrap();
    let cam = k.camera("camera_link", CameraConvention::Body).unwrap();
    let camera_from_base = cam.camera_from_base(&poses).unwrap();
    let ahead = camera_from_base * Point3::new(0.0, 3.0, 1.0);
    assert!(
        (ahead - Point3::new(0.0, 0.0, 3.0)).norm() < 1e-12,
        "{ahead}"
    );
    // Base +z (up) is image up: optical -y. Looking along +y with z up, base +x is the
    // camera's right (+x optical).
    let up = camera_from_base * Point3::new(0.0, 3.0, 2.0);
    assert!((up - Point3::new(0.0, -1.0, 3.0)).norm() < 1e-12, "{up}");
    let right = camera_from_base * Point3::new(1.0, 3.0, 1.0);
    assert!(
        (right - Point3::new(1.0, 0.0, 3.0)).norm() < 1e-12,
        "{right}"
    );
    // In the optical convention camera_from_base is link_from_base: a point 2 m along
    // base +y from the link is on the link's x axis.
    let cam = k.camera("camera_link", CameraConvention::Optical).unwrap();
    let p = cam.camera_from_base(&poses).unwrap() * Point3::new(0.0, 2.0, 1.0);
    assert!((p - Point3::new(2.0, 0.0, 0.0)).norm() < 1e-12, "{p}");
}
