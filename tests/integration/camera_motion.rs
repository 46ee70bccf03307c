//! The expected camera motion (kinematics) and the observed one (registration) use the same
//! convention: a camera moving in front of a textured plane is rendered by ray casting, the
//! two frames are registered, and the registration must agree with the prediction from
//! the two camera poses.
//!
//! The plane is fronto-parallel to the first camera at the assumed depth, so for rolls
//! about the optical axis and translations the image motion is an exact similarity and the
//! only differences are the registration's own errors (well under 0.1 px here, see
//! `registration_accuracy.rs`). Pans make the motion a homography: the least-squares
//! similarity and the registration then weight the image differently, so the bound is
//! looser.

use nalgebra::{Isometry3, Point2, Translation3, UnitQuaternion, Vector3};
use vamos::robot::Intrinsics;
use vamos::robot::camera_motion::{CameraMotionParams, Depth, expected_camera_motion};
use vamos::vision::GrayImage;
use vamos::vision::registration::{Registrar, RegistrationParams};
use vamos::vision::synthetic::Texture;

const DEPTH_M: f64 = 1.2;

/// The image of the textured plane `z = DEPTH_M` (first camera's frame) seen by a camera
/// whose pose in the first camera's frame is `first_from_camera`. The texture is painted on
/// the plane so that the first camera sees `texture(x, y)` at pixel `(x, y)`.
fn render_plane(
    k: &Intrinsics,
    texture: &Texture,
    first_from_camera: &Isometry3<f64>,
) -> GrayImage {
    GrayImage::from_fn(k.width as usize, k.height as usize, |x, y| {
        let ray = first_from_camera.rotation
            * k.backproject(&Point2::new(x as f64, y as f64), 1.0).coords;
        let origin = first_from_camera.translation.vector;
        // Intersect origin + s * ray with z = DEPTH_M.
        let s = (DEPTH_M - origin.z) / ray.z;
        let p = origin + ray * s;
        let pixel = k.project(&p.into()).unwrap();
        texture.eval(pixel.x, pixel.y) as f32
    })
}

fn check(first_from_second: Isometry3<f64>, tol_px: f64, tol_deg: f64, tol_scale: f64) {
    let k = Intrinsics::from_fov(320, 240, 60.0).unwrap();
    let texture = Texture::random(7);
    let a = render_plane(&k, &texture, &Isometry3::identity());
    let b = render_plane(&k, &texture, &first_from_second);
    let observed = Registrar::new(RegistrationParams::default())
        .unwrap()
        .register(&a, &b, None)
        .unwrap()
        .transform;
    // Base = the first camera.
    let expected = expected_camera_motion(
        &Isometry3::identity(),
        &first_from_second.inverse(),
        &k,
        Depth::Assumed,
        &CameraMotionParams {
            assumed_depth_m: DEPTH_M,
            ..CameraMotionParams::default()
        },
    )
    .unwrap()
    .transform;
    let (dt, dr, ds) = observed.difference(&expected);
    assert!(
        dt < tol_px && dr < tol_deg && ds < tol_scale,
        "observed {observed:?}, expected {expected:?}"
    );
}

fn pose(translation_m: [f64; 3], axis: Vector3<f64>, angle_deg: f64) -> Isometry3<f64> {
    Isometry3::from_parts(
        Translation3::new(translation_m[0], translation_m[1], translation_m[2]),
        UnitQuaternion::from_scaled_axis(axis * angle_deg.to_radians()),
    )
}

#[test]
fn sideways_translation_agrees() {
    // Measured: 0.028 px, 0.001 deg, 0.003 % scale.
    check(
        pose([0.03, -0.02, 0.0], Vector3::z(), 0.0),
        0.06,
        0.02,
        0.0005,
    );
}

#[test]
fn roll_and_forward_motion_agree() {
    check(
        pose([0.01, 0.02, 0.08], Vector3::z(), 5.0),
        0.15,
        0.15,
        0.003,
    );
    check(
        pose([-0.02, 0.0, -0.05], Vector3::z(), -3.0),
        0.15,
        0.15,
        0.003,
    );
}

#[test]
fn pan_and_tilt_agree_roughly() {
    // 1.5 degrees of pan and 1 of tilt at f = 277 px: about 7 and 5 px of motion.
    // Measured: 0.27 px, 0.05 deg, 0.2 %.
    check(
        pose(
            [0.0, 0.0, 0.0],
            Vector3::new(0.6, 1.0, 0.0).normalize(),
            1.8,
        ),
        0.5,
        0.2,
        0.01,
    );
}
