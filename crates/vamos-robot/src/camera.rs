//! Pinhole camera intrinsics and the ROS optical-frame convention.
//!
//! Camera coordinates are *optical* (REP 103): z forward, x right, y down, so a point
//! `(x, y, z)` projects to pixel `(fx x / z + cx, fy y / z + cy)`, with pixel `(0, 0)` the
//! centre of the top-left pixel (as `sensor_msgs/CameraInfo`'s `K`).

use nalgebra::{Isometry3, Matrix3, Point2, Point3, Translation3, UnitQuaternion};
use serde::{Deserialize, Serialize};

/// Errors for camera descriptions.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum IntrinsicsError {
    /// The image has no pixels.
    #[error("camera image size {width}x{height} has no pixels")]
    EmptyImage {
        /// Width in pixels.
        width: u32,
        /// Height in pixels.
        height: u32,
    },
    /// A focal length or principal point is not finite, or a focal length is not positive.
    #[error("camera intrinsics are invalid: {what} = {value}")]
    BadValue {
        /// Which value.
        what: &'static str,
        /// Its value.
        value: f64,
    },
}

/// Pinhole intrinsics of an image of `width` x `height` pixels.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Intrinsics {
    /// Image width in pixels.
    pub width: u32,
    /// Image height in pixels.
    pub height: u32,
    /// Focal length along x, pixels.
    pub fx: f64,
    /// Focal length along y, pixels.
    pub fy: f64,
    /// Principal point x, pixels.
    pub cx: f64,
    /// Principal point y, pixels.
    pub cy: f64,
}

impl Intrinsics {
    /// Checked constructor.
    pub fn new(
        width: u32,
        height: u32,
        fx: f64,
        fy: f64,
        cx: f64,
        cy: f64,
    ) -> Result<Self, IntrinsicsError> {
        let k = Self {
            width,
            height,
            fx,
            fy,
            cx,
            cy,
        };
        k.validate()?;
        Ok(k)
    }

    /// From a `sensor_msgs/CameraInfo`-style row-major 3x3 `K`.
    pub fn from_k(width: u32, height: u32, k: &[f64; 9]) -> Result<Self, IntrinsicsError> {
        Self::new(width, height, k[0], k[4], k[2], k[5])
    }

    /// A camera with the given horizontal field of view (degrees), square pixels and the
    /// principal point at the image centre.
    pub fn from_fov(width: u32, height: u32, hfov_deg: f64) -> Result<Self, IntrinsicsError> {
        let f = f64::from(width) / 2.0 / (hfov_deg.to_radians() / 2.0).tan();
        Self::new(
            width,
            height,
            f,
            f,
            (f64::from(width) - 1.0) / 2.0,
            (f64::from(height) - 1.0) / 2.0,
        )
    }

    /// Checks sizes and values.
    pub fn validate(&self) -> Result<(), IntrinsicsError> {
        if self.width == 0 || self.height == 0 {
            return Err(IntrinsicsError::EmptyImage {
                width: self.width,
                height: self.height,
            });
        }
        for (what, value, positive) in [
            ("fx", self.fx, true),
            ("fy", self.fy, true),
            ("cx", self.cx, false),
            ("cy", self.cy, false),
        ] {
            if !value.is_finite() || (positive && value <= 0.0) {
                return Err(IntrinsicsError::BadValue { what, value });
            }
        }
        Ok(())
    }

    /// The 3x3 camera matrix `K`.
    pub fn matrix(&self) -> Matrix3<f64> {
        Matrix3::new(
            self.fx, 0.0, self.cx, //
            0.0, self.fy, self.cy, //
            0.0, 0.0, 1.0,
        )
    }

    /// The same camera seen at another resolution (the image resized to `width` x
    /// `height`; pixel centres are kept aligned, as an area or bilinear resize does).
    pub fn scaled_to(&self, width: u32, height: u32) -> Result<Self, IntrinsicsError> {
        let sx = f64::from(width) / f64::from(self.width);
        let sy = f64::from(height) / f64::from(self.height);
        Self::new(
            width,
            height,
            self.fx * sx,
            self.fy * sy,
            (self.cx + 0.5) * sx - 0.5,
            (self.cy + 0.5) * sy - 0.5,
        )
    }

    /// Projects a point in optical camera coordinates; `None` when it is not in front of
    /// the camera (`z <= 0`).
    pub fn project(&self, p: &Point3<f64>) -> Option<Point2<f64>> {
        (p.z > 0.0)
            .then(|| Point2::new(self.fx * p.x / p.z + self.cx, self.fy * p.y / p.z + self.cy))
    }

    /// The point at depth `z` (along the optical axis) that projects to `pixel`.
    pub fn backproject(&self, pixel: &Point2<f64>, z: f64) -> Point3<f64> {
        Point3::new(
            (pixel.x - self.cx) / self.fx * z,
            (pixel.y - self.cy) / self.fy * z,
            z,
        )
    }
}

/// How the URDF frame named as the camera is oriented.
#[derive(
    Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize, schemars::JsonSchema,
)]
#[serde(rename_all = "snake_case")]
pub enum CameraConvention {
    /// Already optical: z forward, x right, y down (e.g. `*_optical_frame` links).
    #[default]
    Optical,
    /// ROS body convention: x forward, y left, z up (e.g. `camera_link`).
    Body,
}

impl CameraConvention {
    /// `frame_from_optical`: maps optical coordinates into the URDF camera frame.
    pub fn frame_from_optical(self) -> Isometry3<f64> {
        match self {
            Self::Optical => Isometry3::identity(),
            // Columns: optical x (right) = -y_body, optical y (down) = -z_body,
            // optical z (forward) = x_body.
            Self::Body => {
                let r = Matrix3::new(
                    0.0, 0.0, 1.0, //
                    -1.0, 0.0, 0.0, //
                    0.0, -1.0, 0.0,
                );
                Isometry3::from_parts(Translation3::identity(), UnitQuaternion::from_matrix(&r))
            }
        }
    }
}

/// A camera as users describe it (e.g. `camera.json` of `vamos render`, a profile's
/// camera): the URDF link it is attached to, that link's axis convention, and the
/// intrinsics, given either as `fx, fy, cx, cy`, as a `sensor_msgs/CameraInfo` `k`
/// (row-major 3x3), or as a horizontal field of view `hfov_deg` (square pixels, centred).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct CameraSpec {
    /// The URDF link of the camera.
    pub frame: String,
    /// Axis convention of that link.
    #[serde(default)]
    pub convention: CameraConvention,
    /// Image width, pixels.
    pub width: u32,
    /// Image height, pixels.
    pub height: u32,
    /// Focal length x, pixels.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub fx: Option<f64>,
    /// Focal length y, pixels.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub fy: Option<f64>,
    /// Principal point x, pixels.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub cx: Option<f64>,
    /// Principal point y, pixels.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub cy: Option<f64>,
    /// `CameraInfo.k`, row-major.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub k: Option<[f64; 9]>,
    /// Horizontal field of view, degrees.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub hfov_deg: Option<f64>,
    /// Camera position in `frame`, metres, for a camera that is not itself a URDF link
    /// (as a URDF `<origin xyz>`; default 0).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub offset_xyz: Option<[f64; 3]>,
    /// Camera orientation in `frame`, roll-pitch-yaw radians (as a URDF `<origin rpy>`;
    /// default 0). `convention` applies to the offset frame.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub offset_rpy: Option<[f64; 3]>,
}

/// Errors of a [`CameraSpec`].
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum CameraSpecError {
    /// Not exactly one way of giving the intrinsics.
    #[error("camera {frame:?}: give the intrinsics exactly one way: fx/fy/cx/cy, k, or hfov_deg")]
    AmbiguousIntrinsics {
        /// The camera link.
        frame: String,
    },
    /// The intrinsics are invalid.
    #[error("camera {frame:?}: {source}")]
    Intrinsics {
        /// The camera link.
        frame: String,
        /// What is wrong.
        source: IntrinsicsError,
    },
}

impl CameraSpec {
    /// `frame_from_camera`: the offset of the camera in its link (identity by default).
    pub fn frame_from_camera(&self) -> Isometry3<f64> {
        let [x, y, z] = self.offset_xyz.unwrap_or([0.0; 3]);
        let [r, p, yaw] = self.offset_rpy.unwrap_or([0.0; 3]);
        Isometry3::from_parts(
            Translation3::new(x, y, z),
            UnitQuaternion::from_euler_angles(r, p, yaw),
        )
    }

    /// The intrinsics at the spec's own resolution.
    pub fn intrinsics(&self) -> Result<Intrinsics, CameraSpecError> {
        let explicit = [self.fx, self.fy, self.cx, self.cy];
        let given = [
            explicit.iter().all(Option::is_some),
            self.k.is_some(),
            self.hfov_deg.is_some(),
        ];
        let partial = explicit.iter().any(Option::is_some) && !given[0];
        if partial || given.iter().filter(|&&g| g).count() != 1 {
            return Err(CameraSpecError::AmbiguousIntrinsics {
                frame: self.frame.clone(),
            });
        }
        let wrap = |source| CameraSpecError::Intrinsics {
            frame: self.frame.clone(),
            source,
        };
        match (explicit, self.k, self.hfov_deg) {
            ([Some(fx), Some(fy), Some(cx), Some(cy)], _, _) => {
                Intrinsics::new(self.width, self.height, fx, fy, cx, cy).map_err(wrap)
            }
            (_, Some(k), _) => Intrinsics::from_k(self.width, self.height, &k).map_err(wrap),
            (_, _, Some(h)) if h.is_finite() && h > 0.0 && h < 180.0 => {
                Intrinsics::from_fov(self.width, self.height, h).map_err(wrap)
            }
            (_, _, h) => Err(wrap(IntrinsicsError::BadValue {
                what: "hfov_deg",
                value: h.unwrap_or(f64::NAN),
            })),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn project_backproject_round_trip() {
        let k = Intrinsics::new(640, 480, 525.0, 520.0, 319.5, 239.5).unwrap();
        let p = Point3::new(0.2, -0.1, 1.5);
        let px = k.project(&p).unwrap();
        let q = k.backproject(&px, 1.5);
        assert!((p - q).norm() < 1e-12);
        assert!(k.project(&Point3::new(0.0, 0.0, -1.0)).is_none());
    }

    #[test]
    fn scaling_keeps_pixel_centres() {
        let k = Intrinsics::new(640, 480, 500.0, 500.0, 319.5, 239.5).unwrap();
        let h = k.scaled_to(320, 240).unwrap();
        assert_eq!((h.fx, h.cx, h.cy), (250.0, 159.5, 119.5));
    }

    #[test]
    fn invalid_values_are_errors() {
        assert!(matches!(
            Intrinsics::new(0, 10, 1.0, 1.0, 0.0, 0.0),
            Err(IntrinsicsError::EmptyImage { .. })
        ));
        assert!(matches!(
            Intrinsics::new(10, 10, f64::NAN, 1.0, 0.0, 0.0),
            Err(IntrinsicsError::BadValue { what: "fx", .. })
        ));
        assert!(matches!(
            Intrinsics::new(10, 10, 1.0, -1.0, 0.0, 0.0),
            Err(IntrinsicsError::BadValue { what: "fy", .. })
        ));
    }

    #[test]
    fn camera_spec_takes_exactly_one_form_of_intrinsics() {
        let spec: CameraSpec = serde_json::from_str(
            r#"{"frame": "cam", "width": 640, "height": 480, "hfov_deg": 90}"#,
        )
        .unwrap();
        let k = spec.intrinsics().unwrap();
        assert!((k.fx - 320.0).abs() < 1e-9 && k.cx == 319.5);
        assert_eq!(spec.convention, CameraConvention::Optical);
        let spec: CameraSpec = serde_json::from_str(
            r#"{"frame": "cam", "convention": "body", "width": 4, "height": 2,
                "k": [5, 0, 2, 0, 6, 1, 0, 0, 1]}"#,
        )
        .unwrap();
        assert_eq!(spec.intrinsics().unwrap().fy, 6.0);
        for bad in [
            r#"{"frame": "c", "width": 4, "height": 2}"#,
            r#"{"frame": "c", "width": 4, "height": 2, "fx": 1, "hfov_deg": 60}"#,
            r#"{"frame": "c", "width": 4, "height": 2, "fx": 1, "fy": 1, "cx": 1}"#,
        ] {
            let spec: CameraSpec = serde_json::from_str(bad).unwrap();
            assert!(matches!(
                spec.intrinsics(),
                Err(CameraSpecError::AmbiguousIntrinsics { .. })
            ));
        }
        let spec: CameraSpec =
            serde_json::from_str(r#"{"frame": "c", "width": 0, "height": 2, "hfov_deg": 60}"#)
                .unwrap();
        assert!(matches!(
            spec.intrinsics(),
            Err(CameraSpecError::Intrinsics { .. })
        ));
        assert!(
            serde_json::from_str::<CameraSpec>(
                r#"{"frame": "c", "width": 1, "height": 1, "f": 1}"#
            )
            .is_err()
        );
    }

    #[test]
    fn body_convention_looks_along_x() {
        // A point 2 m ahead of a body-convention camera (x forward) is on the optical axis.
        let frame_from_optical = CameraConvention::Body.frame_from_optical();
        let optical = frame_from_optical.inverse() * Point3::new(2.0, 0.0, 0.0);
        assert!((optical - Point3::new(0.0, 0.0, 2.0)).norm() < 1e-12);
        // Left in the body frame (+y) is left on screen (-x optical); up (+z) is -y.
        let left = frame_from_optical.inverse() * Point3::new(1.0, 1.0, 0.0);
        assert!(left.x < 0.0);
        let up = frame_from_optical.inverse() * Point3::new(1.0, 0.0, 1.0);
        assert!(up.y < 0.0);
    }
}
