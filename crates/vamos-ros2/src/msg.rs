//! The ROS 2 messages the bridge reads and writes, as serde structs in the exact field
//! order of their `.msg` definitions (CDR has no field names: order and types are the
//! format), and their conversions to and from `vamos.v1`.
//!
//! Read: `sensor_msgs/{Image, CompressedImage, CameraInfo, JointState}` (an `Image` also
//! as a depth image, [`Image::into_depth`]). Written:
//! `vamos_msgs/FrameScore` (`clients/ros2/vamos_msgs/msg/FrameScore.msg`),
//! `std_msgs/{Float64, Bool}` and `diagnostic_msgs/DiagnosticArray`.

use ros2_client::{Message, MessageTypeName};
use serde::{Deserialize, Serialize};
use serde_bytes::ByteBuf;
use vamos_core::episode::image::Encoding;
use vamos_proto as proto;

const NS_PER_S: i64 = 1_000_000_000;

/// `builtin_interfaces/Time`.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct Time {
    /// Seconds since the epoch.
    pub sec: i32,
    /// Nanoseconds in the second (`< 1e9` when well formed).
    pub nanosec: u32,
}

impl Time {
    /// Nanoseconds since the epoch (a `nanosec` out of range counts as it is, as rclcpp does).
    pub fn to_ns(self) -> i64 {
        i64::from(self.sec) * NS_PER_S + i64::from(self.nanosec)
    }

    /// The time of `ns` nanoseconds: exact (`sec * 1e9 + nanosec == ns`, `nanosec < 1e9`,
    /// also before 1970); `None` outside `sec`'s 32-bit range.
    pub fn from_ns(ns: i64) -> Option<Self> {
        let sec = i32::try_from(ns.div_euclid(NS_PER_S)).ok()?;
        let nanosec = ns.rem_euclid(NS_PER_S) as u32;
        Some(Self { sec, nanosec })
    }

    /// The wall clock now.
    pub fn now() -> Self {
        let ns = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map_or(0, |d| i64::try_from(d.as_nanos()).unwrap_or(i64::MAX));
        Self::from_ns(ns).unwrap_or_default()
    }
}

/// `std_msgs/Header`.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct Header {
    /// When the data was taken.
    pub stamp: Time,
    /// The coordinate frame the data is in.
    pub frame_id: String,
}

/// `sensor_msgs/Image`.
#[derive(Debug, Clone, Default, Serialize, Deserialize)]
pub struct Image {
    /// Stamp and camera frame.
    pub header: Header,
    /// Rows.
    pub height: u32,
    /// Columns.
    pub width: u32,
    /// Pixel encoding (`rgb8`, `bgr8`, `mono8`, ...).
    pub encoding: String,
    /// 1 when multi-byte pixels are big-endian.
    pub is_bigendian: u8,
    /// Bytes per row.
    pub step: u32,
    /// The pixels, `step * height` bytes.
    pub data: ByteBuf,
}

/// `sensor_msgs/CompressedImage`.
#[derive(Debug, Clone, Default, Serialize, Deserialize)]
pub struct CompressedImage {
    /// Stamp and camera frame.
    pub header: Header,
    /// `jpeg`, `png`, or image_transport's `"<encoding>; jpeg compressed <encoding>"`.
    pub format: String,
    /// The file's bytes.
    pub data: ByteBuf,
}

/// `sensor_msgs/RegionOfInterest`.
#[derive(Debug, Clone, Copy, Default, Serialize, Deserialize)]
pub struct RegionOfInterest {
    /// Left edge, px.
    pub x_offset: u32,
    /// Top edge, px.
    pub y_offset: u32,
    /// Rows.
    pub height: u32,
    /// Columns.
    pub width: u32,
    /// Whether the region is to be rectified.
    pub do_rectify: bool,
}

/// `sensor_msgs/CameraInfo`.
#[derive(Debug, Clone, Default, Serialize, Deserialize)]
pub struct CameraInfo {
    /// Stamp and camera frame.
    pub header: Header,
    /// Rows of the images.
    pub height: u32,
    /// Columns of the images.
    pub width: u32,
    /// Lens distortion model (`plumb_bob`, ...).
    pub distortion_model: String,
    /// Distortion coefficients.
    pub d: Vec<f64>,
    /// Intrinsic matrix, row-major.
    pub k: [f64; 9],
    /// Rectification rotation, row-major.
    pub r: [f64; 9],
    /// Projection matrix, row-major 3x4.
    pub p: [f64; 12],
    /// Horizontal binning.
    pub binning_x: u32,
    /// Vertical binning.
    pub binning_y: u32,
    /// Region of interest.
    pub roi: RegionOfInterest,
}

/// `sensor_msgs/JointState`.
#[derive(Debug, Clone, Default, Serialize, Deserialize)]
pub struct JointState {
    /// Stamp.
    pub header: Header,
    /// Joint names.
    pub name: Vec<String>,
    /// Positions, rad or m.
    pub position: Vec<f64>,
    /// Velocities.
    pub velocity: Vec<f64>,
    /// Efforts.
    pub effort: Vec<f64>,
}

/// `std_msgs/Float64`.
#[derive(Debug, Clone, Copy, Default, Serialize, Deserialize)]
pub struct Float64 {
    /// The value.
    pub data: f64,
}

/// `std_msgs/Bool`.
#[derive(Debug, Clone, Copy, Default, Serialize, Deserialize)]
pub struct Bool {
    /// The value.
    pub data: bool,
}

/// `diagnostic_msgs/KeyValue`.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct KeyValue {
    /// The key.
    pub key: String,
    /// The value.
    pub value: String,
}

/// `diagnostic_msgs/DiagnosticStatus`.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct DiagnosticStatus {
    /// [`Level`] as its byte.
    pub level: u8,
    /// What is reported on (`vamos: /robot1/vamos_bridge`).
    pub name: String,
    /// A short summary.
    pub message: String,
    /// The hardware it concerns (the robot's id).
    pub hardware_id: String,
    /// Details.
    pub values: Vec<KeyValue>,
}

/// `diagnostic_msgs/DiagnosticArray`.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct DiagnosticArray {
    /// When the statuses were taken.
    pub header: Header,
    /// The statuses.
    pub status: Vec<DiagnosticStatus>,
}

/// `vamos_msgs/FrameScore`: one frame's score, with the scored image's header.
#[derive(Debug, Clone, Default, Serialize, Deserialize)]
pub struct FrameScore {
    /// The scored image's stamp and frame.
    pub header: Header,
    /// The fused score.
    pub score: f64,
    /// Whether it reached the alarm threshold.
    pub anomaly: bool,
    /// The detector that set the score (`camera`, `body`, `flow`, `scene`,
    /// `kinematics`), or empty.
    pub detector: String,
    /// Camera-motion error; NaN when not computed.
    pub e_c: f64,
    /// Body-motion error; NaN when not computed.
    pub e_b: f64,
    /// Flow-predictor error; NaN when not computed.
    pub e_o: f64,
    /// Scene residual; NaN when not computed.
    pub e_r: f64,
    /// Kinematic novelty; NaN when not computed.
    pub e_k: f64,
    /// The flow predictor lacks its history.
    pub warming_up: bool,
    /// The session's frame counter.
    pub frame: u64,
    /// From the image reaching vamos to its score leaving it, s.
    pub latency_s: f64,
    /// The vamos session.
    pub session_id: String,
}

impl Message for Image {}
impl Message for CompressedImage {}
impl Message for CameraInfo {}
impl Message for JointState {}
impl Message for Float64 {}
impl Message for Bool {}
impl Message for DiagnosticArray {}
impl Message for FrameScore {}

/// The ROS 2 type names (DDS: `pkg::msg::dds_::Type_`).
pub mod types {
    use super::MessageTypeName;

    /// `sensor_msgs/msg/Image`.
    pub fn image() -> MessageTypeName {
        MessageTypeName::new("sensor_msgs", "Image")
    }
    /// `sensor_msgs/msg/CompressedImage`.
    pub fn compressed_image() -> MessageTypeName {
        MessageTypeName::new("sensor_msgs", "CompressedImage")
    }
    /// `sensor_msgs/msg/CameraInfo`.
    pub fn camera_info() -> MessageTypeName {
        MessageTypeName::new("sensor_msgs", "CameraInfo")
    }
    /// `sensor_msgs/msg/JointState`.
    pub fn joint_state() -> MessageTypeName {
        MessageTypeName::new("sensor_msgs", "JointState")
    }
    /// `std_msgs/msg/Float64`.
    pub fn float64() -> MessageTypeName {
        MessageTypeName::new("std_msgs", "Float64")
    }
    /// `std_msgs/msg/Bool`.
    pub fn bool() -> MessageTypeName {
        MessageTypeName::new("std_msgs", "Bool")
    }
    /// `diagnostic_msgs/msg/DiagnosticArray`.
    pub fn diagnostic_array() -> MessageTypeName {
        MessageTypeName::new("diagnostic_msgs", "DiagnosticArray")
    }
    /// `vamos_msgs/msg/FrameScore`.
    pub fn frame_score() -> MessageTypeName {
        MessageTypeName::new("vamos_msgs", "FrameScore")
    }
}

/// A message the bridge cannot pass on.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ConvertError {
    /// A `CompressedImage` whose bytes and format name neither JPEG nor PNG.
    #[error("compressed image format {0:?} is neither JPEG nor PNG")]
    CompressedFormat(String),
    /// A `CameraInfo` whose intrinsics cannot be used.
    #[error("camera info: {0}")]
    CameraInfo(String),
}

impl From<Image> for proto::Image {
    fn from(m: Image) -> Self {
        proto::Image {
            stamp_ns: m.header.stamp.to_ns(),
            encoding: m.encoding,
            width: m.width,
            height: m.height,
            step: m.step,
            big_endian: m.is_bigendian != 0,
            data: m.data.into_vec(),
            depth: None,
        }
    }
}

impl Image {
    /// The depth image this message carries, to ride with a colour image: its stamp, and
    /// its rows as they came (the server checks the encoding, `16UC1` or `32FC1`, and
    /// refuses another for that frame with a message).
    pub fn into_depth(self) -> (i64, proto::DepthImage) {
        (
            self.header.stamp.to_ns(),
            proto::DepthImage {
                encoding: self.encoding,
                width: self.width,
                height: self.height,
                step: self.step,
                big_endian: self.is_bigendian != 0,
                data: self.data.into_vec(),
            },
        )
    }
}

impl TryFrom<CompressedImage> for proto::Image {
    type Error = ConvertError;

    /// The file's magic decides; the format string only when the magic is unknown (the
    /// server then reports a decoding error for that one frame).
    fn try_from(m: CompressedImage) -> Result<Self, ConvertError> {
        let encoding = if m.data.starts_with(&[0xFF, 0xD8, 0xFF]) {
            Encoding::Jpeg
        } else if m.data.starts_with(b"\x89PNG\r\n\x1a\n") {
            Encoding::Png
        } else {
            Encoding::from_compressed_format(&m.format)
                .ok_or_else(|| ConvertError::CompressedFormat(m.format.clone()))?
        };
        Ok(proto::Image {
            stamp_ns: m.header.stamp.to_ns(),
            encoding: if encoding == Encoding::Png {
                "png"
            } else {
                "jpeg"
            }
            .to_string(),
            data: m.data.into_vec(),
            ..Default::default()
        })
    }
}

impl From<JointState> for proto::JointState {
    /// Not validated here: the server reports bad samples as session events, as it would
    /// for any robot.
    fn from(m: JointState) -> Self {
        proto::JointState {
            stamp_ns: m.header.stamp.to_ns(),
            names: m.name,
            positions: m.position,
            velocities: m.velocity,
            efforts: m.effort,
        }
    }
}

impl TryFrom<&CameraInfo> for proto::CameraInfo {
    type Error = ConvertError;

    /// The intrinsics; an error for an uncalibrated camera (`k` all zeros, the ROS
    /// convention), a focal length that is not positive and finite, a centre that is not
    /// finite, or no image size.
    fn try_from(m: &CameraInfo) -> Result<Self, ConvertError> {
        let bad = |why: String| Err(ConvertError::CameraInfo(why));
        if m.k.iter().all(|&v| v == 0.0) {
            return bad("K is all zeros: an uncalibrated camera".into());
        }
        let (fx, fy, cx, cy) = (m.k[0], m.k[4], m.k[2], m.k[5]);
        if ![fx, fy, cx, cy].iter().all(|v| v.is_finite()) {
            return bad(format!("K has non-finite entries: {:?}", m.k));
        }
        if fx <= 0.0 || fy <= 0.0 {
            return bad(format!(
                "K has no positive focal lengths (fx {fx}, fy {fy})"
            ));
        }
        if m.width == 0 || m.height == 0 {
            return bad(format!("no image size ({}x{})", m.width, m.height));
        }
        Ok(proto::CameraInfo {
            width: m.width,
            height: m.height,
            fx,
            fy,
            cx,
            cy,
        })
    }
}

impl FrameScore {
    /// The message of `s`, with the scored image's `frame_id`; `None` when its stamp is
    /// outside `builtin_interfaces/Time`'s range.
    pub fn from_proto(s: &proto::FrameScore, frame_id: String, session_id: &str) -> Option<Self> {
        let nan = |x: Option<f64>| x.unwrap_or(f64::NAN);
        Some(Self {
            header: Header {
                stamp: Time::from_ns(s.stamp_ns)?,
                frame_id,
            },
            score: s.score,
            anomaly: s.anomaly,
            detector: vamos_proto::detector_name(s.detector)
                .unwrap_or_default()
                .to_string(),
            e_c: nan(s.e_c),
            e_b: nan(s.e_b),
            e_o: nan(s.e_o),
            e_r: nan(s.e_r),
            e_k: nan(s.e_k),
            warming_up: s.warming_up,
            frame: s.frame,
            latency_s: s.latency_s,
            session_id: session_id.to_string(),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn stamps_round_trip_exactly_also_before_1970() {
        for ns in [
            0,
            1,
            999_999_999,
            1_000_000_000,
            1_733_000_000_123_456_789,
            -1,
            -1_500_000_000,
        ] {
            let t = Time::from_ns(ns).unwrap();
            assert!(t.nanosec < 1_000_000_000);
            assert_eq!(t.to_ns(), ns, "{t:?}");
        }
        assert_eq!(
            Time::from_ns(-1),
            Some(Time {
                sec: -1,
                nanosec: 999_999_999
            })
        );
        assert_eq!(Time::from_ns(i64::MAX), None);
    }

    #[test]
    fn a_depth_image_keeps_its_stamp_encoding_and_rows_as_they_came() {
        let m = Image {
            header: Header {
                stamp: Time {
                    sec: 3,
                    nanosec: 500,
                },
                frame_id: "depth".into(),
            },
            height: 2,
            width: 3,
            encoding: "16UC1".into(),
            is_bigendian: 1,
            step: 8,
            data: ByteBuf::from((0..16).collect::<Vec<u8>>()),
        };
        let (stamp, d) = m.into_depth();
        assert_eq!(stamp, 3_000_000_500);
        assert_eq!(
            (d.encoding.as_str(), d.width, d.height, d.step, d.big_endian),
            ("16UC1", 3, 2, 8, true)
        );
        assert_eq!(d.data, (0..16).collect::<Vec<u8>>());
        // Not a depth encoding: passed on all the same (the server says why not).
        let rgb = Image {
            encoding: "rgb8".into(),
            ..Default::default()
        };
        assert_eq!(rgb.into_depth().1.encoding, "rgb8");
    }

    #[test]
    fn compressed_images_are_told_by_their_magic_before_their_format_name() {
        let png = CompressedImage {
            format: "jpeg".into(),
            data: ByteBuf::from(b"\x89PNG\r\n\x1a\n....".to_vec()),
            ..Default::default()
        };
        assert_eq!(proto::Image::try_from(png).unwrap().encoding, "png");
        let named = CompressedImage {
            format: "rgb8; jpeg compressed bgr8".into(),
            data: ByteBuf::from(vec![1, 2, 3]),
            ..Default::default()
        };
        assert_eq!(proto::Image::try_from(named).unwrap().encoding, "jpeg");
        let unknown = CompressedImage {
            format: "theora".into(),
            data: ByteBuf::from(vec![1, 2, 3]),
            ..Default::default()
        };
        assert_eq!(
            proto::Image::try_from(unknown).unwrap_err(),
            ConvertError::CompressedFormat("theora".into())
        );
    }

    #[test]
    fn unusable_camera_infos_are_refused_with_the_reason() {
        let mut info = CameraInfo {
            width: 320,
            height: 240,
            k: [200.0, 0.0, 160.0, 0.0, 210.0, 120.0, 0.0, 0.0, 1.0],
            ..Default::default()
        };
        let c = proto::CameraInfo::try_from(&info).unwrap();
        assert_eq!((c.fx, c.fy, c.cx, c.cy), (200.0, 210.0, 160.0, 120.0));
        info.k[4] = f64::NAN;
        assert!(
            proto::CameraInfo::try_from(&info)
                .unwrap_err()
                .to_string()
                .contains("non-finite")
        );
        info.k = [0.0; 9];
        assert!(
            proto::CameraInfo::try_from(&info)
                .unwrap_err()
                .to_string()
                .contains("uncalibrated")
        );
        info.k = [-1.0, 0.0, 160.0, 0.0, 210.0, 120.0, 0.0, 0.0, 1.0];
        assert!(
            proto::CameraInfo::try_from(&info)
                .unwrap_err()
                .to_string()
                .contains("focal")
        );
        info.k[0] = 200.0;
        info.width = 0;
        assert!(
            proto::CameraInfo::try_from(&info)
                .unwrap_err()
                .to_string()
                .contains("size")
        );
    }

    #[test]
    fn a_score_keeps_its_image_stamp_and_marks_missing_detectors_nan() {
        let s = proto::FrameScore {
            stamp_ns: 12_000_000_345,
            score: 0.5,
            e_c: Some(0.1),
            e_k: Some(2.0),
            detector: proto::Detector::Kinematics as i32,
            frame: 7,
            ..Default::default()
        };
        let m = FrameScore::from_proto(&s, "camera_link".into(), "r1-abc").unwrap();
        assert_eq!(
            m.header.stamp,
            Time {
                sec: 12,
                nanosec: 345
            }
        );
        assert_eq!(m.header.frame_id, "camera_link");
        assert_eq!((m.e_c, m.e_k), (0.1, 2.0));
        assert!(m.e_b.is_nan() && m.e_o.is_nan() && m.e_r.is_nan());
        assert_eq!(
            (m.detector.as_str(), m.frame, m.session_id.as_str()),
            ("kinematics", 7, "r1-abc")
        );
    }
}
