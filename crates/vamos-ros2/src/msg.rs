//! The ROS 2 messages the bridge reads and writes, as serde structs in the exact field
//! order of their `.msg` definitions (CDR has no field names: order and types are the
//! format), and their conversions to and from `vamos.v1`.
//!
//! Read: `sensor_msgs/{Image, CompressedImage, CameraInfo, JointState}` (an `Image` also
//! as a depth image, [`Image::into_depth`]). Written:
//! `vamos_msgs/{FrameScore, AlarmEvent}` (`clients/ros2/vamos_msgs/msg/`), the anomaly
//! map as a mono8 `sensor_msgs/Image` ([`Image::anomaly_map`]), `std_msgs/{Float64, Bool}`
//! and `diagnostic_msgs/DiagnosticArray`.

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

/// `vamos_msgs/AlarmFrame`: one frame of an alarm (its start or its peak).
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct AlarmFrame {
    /// The frame's image stamp.
    pub stamp: Time,
    /// The fused score; NaN when none.
    pub score: f64,
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
}

/// `vamos_msgs/AlarmEvent`: an alarm started or ended, stamped with the image at which
/// it did.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct AlarmEvent {
    /// The stamp of the image at which it started or ended, and that image's frame.
    pub header: Header,
    /// [`AlarmEvent::STARTED`] or [`AlarmEvent::ENDED`].
    pub edge: u8,
    /// The alarm's id on the server (`/v1/alarms/{id}`).
    pub alarm_id: String,
    /// The vamos session.
    pub session_id: String,
    /// The robot of the session.
    pub robot_id: String,
    /// The detector that fired at its start, or empty.
    pub detector: String,
    /// Every detector that fired during it so far.
    pub detectors: Vec<String>,
    /// Processed-frame index of its start.
    pub start_frame: u64,
    /// Processed-frame index of its end (ended alarms; 0 while it is on).
    pub end_frame: u64,
    /// Flagged frames so far.
    pub frames_flagged: u64,
    /// The fused score's alarm threshold; NaN when none.
    pub alarm_threshold: f64,
    /// The camera-motion detector's own threshold; NaN when none.
    pub e_c_threshold: f64,
    /// The body-motion detector's own threshold; NaN when none.
    pub e_b_threshold: f64,
    /// The flow predictor's own threshold; NaN when none.
    pub e_o_threshold: f64,
    /// The scene residual's own threshold; NaN when none.
    pub e_r_threshold: f64,
    /// The kinematic novelty's own threshold; NaN when none.
    pub e_k_threshold: f64,
    /// Every component at its start frame.
    pub start: AlarmFrame,
    /// Every component at its highest-scoring frame so far.
    pub peak: AlarmFrame,
}

impl Message for Image {}
impl Message for CompressedImage {}
impl Message for CameraInfo {}
impl Message for JointState {}
impl Message for Float64 {}
impl Message for Bool {}
impl Message for DiagnosticArray {}
impl Message for FrameScore {}
impl Message for AlarmEvent {}

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
    /// `vamos_msgs/msg/AlarmEvent`.
    pub fn alarm_event() -> MessageTypeName {
        MessageTypeName::new("vamos_msgs", "AlarmEvent")
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
    /// An anomaly map that is not a PNG file.
    #[error("anomaly map: {0}")]
    AnomalyMap(String),
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

impl Image {
    /// The anomaly map of a score (`FrameScore.anomaly_map`: a PNG file, 8-bit gray, 0 =
    /// nominal) as a `mono8` image with `header` (the scored image's stamp and frame):
    /// one pixel per map cell, packed rows.
    pub fn anomaly_map(png: &[u8], header: Header) -> Result<Self, ConvertError> {
        let map = image::load_from_memory_with_format(png, image::ImageFormat::Png)
            .map_err(|e| ConvertError::AnomalyMap(e.to_string()))?
            .into_luma8();
        let (width, height) = map.dimensions();
        Ok(Self {
            header,
            height,
            width,
            encoding: "mono8".into(),
            is_bigendian: 0,
            step: width,
            data: ByteBuf::from(map.into_raw()),
        })
    }
}

impl AlarmFrame {
    fn from_proto(c: &proto::AlarmComponents) -> Option<Self> {
        let nan = |x: Option<f64>| x.unwrap_or(f64::NAN);
        Some(Self {
            stamp: Time::from_ns(c.stamp_ns)?,
            score: nan(c.score),
            e_c: nan(c.e_c),
            e_b: nan(c.e_b),
            e_o: nan(c.e_o),
            e_r: nan(c.e_r),
            e_k: nan(c.e_k),
        })
    }
}

impl AlarmEvent {
    /// `edge`: the alarm starts at this message's stamp.
    pub const STARTED: u8 = 1;
    /// `edge`: the alarm ended at this message's stamp.
    pub const ENDED: u8 = 2;

    /// The message of `a`, of robot `robot_id`, with `frame_id` (the camera's): stamped
    /// with its start frame's image stamp when it started, its end's when it ended.
    /// `None` for an event with no edge or a stamp outside `builtin_interfaces/Time`'s
    /// range.
    pub fn from_proto(a: &proto::AlarmEvent, frame_id: String, robot_id: &str) -> Option<Self> {
        use proto::alarm_event::Edge;
        let nan = |x: Option<f64>| x.unwrap_or(f64::NAN);
        let name = |d: i32| {
            vamos_proto::detector_name(d)
                .unwrap_or_default()
                .to_string()
        };
        let start = a.start.unwrap_or_default();
        let (edge, stamp_ns) = match a.edge() {
            Edge::Started => (Self::STARTED, start.stamp_ns),
            Edge::Ended => (Self::ENDED, a.end_stamp_ns.unwrap_or(start.stamp_ns)),
            Edge::Unspecified => return None,
        };
        Some(Self {
            header: Header {
                stamp: Time::from_ns(stamp_ns)?,
                frame_id,
            },
            edge,
            alarm_id: a.alarm_id.clone(),
            session_id: a.session_id.clone(),
            robot_id: robot_id.to_string(),
            detector: name(a.detector),
            detectors: a.detectors.iter().map(|&d| name(d)).collect(),
            start_frame: a.start_frame,
            end_frame: a.end_frame.unwrap_or(0),
            frames_flagged: a.frames_flagged,
            alarm_threshold: nan(a.alarm_threshold),
            e_c_threshold: nan(a.e_c_threshold),
            e_b_threshold: nan(a.e_b_threshold),
            e_o_threshold: nan(a.e_o_threshold),
            e_r_threshold: nan(a.e_r_threshold),
            e_k_threshold: nan(a.e_k_threshold),
            start: AlarmFrame::from_proto(&start)?,
            peak: AlarmFrame::from_proto(&a.peak.unwrap_or_default())?,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use ros2_client::dds::rustdds::serialization::{
        RepresentationIdentifier, deserialize_from_cdr_with_rep_id, to_writer_with_rep_id,
    };

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

    /// The alarm event of the layout test: an ended alarm, some values NaN.
    fn ended_alarm() -> proto::AlarmEvent {
        proto::AlarmEvent {
            edge: proto::alarm_event::Edge::Ended as i32,
            alarm_id: "a1".into(),
            session_id: "r1-s".into(),
            detector: proto::Detector::Flow as i32,
            detectors: vec![proto::Detector::Flow as i32, proto::Detector::Camera as i32],
            start_frame: 7,
            end_frame: Some(11),
            end_stamp_ns: Some(12_000_000_345),
            frames_flagged: 3,
            alarm_threshold: Some(0.5),
            e_o_threshold: Some(0.5),
            start: Some(proto::AlarmComponents {
                stamp_ns: 10_000_000_005,
                score: Some(2.0),
                e_c: Some(0.25),
                e_o: Some(2.0),
                ..Default::default()
            }),
            peak: Some(proto::AlarmComponents {
                stamp_ns: 11_000_000_000,
                score: Some(3.0),
                e_c: Some(0.5),
                e_o: Some(3.0),
                ..Default::default()
            }),
            ..Default::default()
        }
    }

    fn cdr<T: Serialize>(m: &T) -> Vec<u8> {
        let mut bytes = Vec::new();
        to_writer_with_rep_id(&mut bytes, m, RepresentationIdentifier::CDR_LE).unwrap();
        bytes
    }

    #[test]
    fn an_alarm_event_is_stamped_at_its_edge_with_its_robot_and_nan_for_what_is_missing() {
        let mut a = ended_alarm();
        let m = AlarmEvent::from_proto(&a, "cam".into(), "r1").unwrap();
        assert_eq!(m.edge, AlarmEvent::ENDED);
        assert_eq!(
            m.header,
            Header {
                stamp: Time {
                    sec: 12,
                    nanosec: 345
                },
                frame_id: "cam".into()
            }
        );
        assert_eq!(
            (
                m.robot_id.as_str(),
                m.session_id.as_str(),
                m.alarm_id.as_str()
            ),
            ("r1", "r1-s", "a1")
        );
        assert_eq!(m.detector, "flow");
        assert_eq!(m.detectors, ["flow", "camera"]);
        assert_eq!((m.start_frame, m.end_frame, m.frames_flagged), (7, 11, 3));
        assert_eq!((m.alarm_threshold, m.e_o_threshold), (0.5, 0.5));
        assert!(m.e_c_threshold.is_nan() && m.e_b_threshold.is_nan());
        assert!(m.e_r_threshold.is_nan() && m.e_k_threshold.is_nan());
        assert_eq!(
            m.start.stamp,
            Time {
                sec: 10,
                nanosec: 5
            }
        );
        assert_eq!((m.start.score, m.start.e_c, m.peak.score), (2.0, 0.25, 3.0));
        assert!(m.start.e_b.is_nan() && m.peak.e_k.is_nan());
        // Started: stamped with its start frame; no end yet.
        a.edge = proto::alarm_event::Edge::Started as i32;
        a.end_frame = None;
        a.end_stamp_ns = None;
        let m = AlarmEvent::from_proto(&a, "cam".into(), "r1").unwrap();
        assert_eq!((m.edge, m.end_frame), (AlarmEvent::STARTED, 0));
        assert_eq!(m.header.stamp, m.start.stamp);
        // No edge, or a stamp ROS cannot carry: not published.
        a.edge = proto::alarm_event::Edge::Unspecified as i32;
        assert_eq!(AlarmEvent::from_proto(&a, "cam".into(), "r1"), None);
        a.edge = proto::alarm_event::Edge::Started as i32;
        a.start.as_mut().unwrap().stamp_ns = i64::MAX;
        assert_eq!(AlarmEvent::from_proto(&a, "cam".into(), "r1"), None);
    }

    #[test]
    fn an_alarm_event_round_trips_through_cdr() {
        let m = AlarmEvent::from_proto(&ended_alarm(), "cam".into(), "r1").unwrap();
        let bytes = cdr(&m);
        let (back, used): (AlarmEvent, usize) =
            deserialize_from_cdr_with_rep_id(&bytes, RepresentationIdentifier::CDR_LE).unwrap();
        assert_eq!(used, bytes.len());
        // NaN != NaN: compare the encodings of the two.
        assert_eq!(cdr(&back), bytes);
        assert_eq!(back.detectors, m.detectors);
        assert_eq!(back.header, m.header);
        assert_eq!((back.start_frame, back.end_frame), (7, 11));
        assert!(back.e_c_threshold.is_nan());
    }

    /// The bytes of `ended_alarm()` as ROS 2 itself lays them out: rclpy's
    /// `serialize_message` of the `vamos_msgs/AlarmEvent` that colcon generated from
    /// `AlarmEvent.msg` (Fast CDR, little-endian), less the 4-byte encapsulation header,
    /// with its padding bytes (which Fast CDR leaves unset) as zeros. Offsets count from
    /// after the header: 8-byte values sit at multiples of 8.
    #[test]
    fn an_alarm_event_has_the_byte_layout_of_ros_2s_generated_type() {
        let m = AlarmEvent::from_proto(&ended_alarm(), "cam".into(), "r1").unwrap();
        let rows: [&str; 34] = [
            "0c00000059010000", //   0 header.stamp: sec 12, nanosec 345
            "0400000063616d00", //   8 header.frame_id "cam" (length 4 with the NUL)
            "0200000003000000", //  16 edge ENDED, pad; alarm_id length 3
            "6131000005000000", //  24 "a1"; pad; session_id length 5
            "72312d7300000000", //  32 "r1-s"; pad
            "0300000072310000", //  40 robot_id "r1"; pad
            "05000000666c6f77", //  48 detector "flow"
            "0000000002000000", //  56 NUL; pad; detectors: 2 strings
            "05000000666c6f77", //  64 "flow"
            "0000000007000000", //  72 NUL; pad; "camera" length 7
            "63616d6572610000", //  80 "camera"; pad to 8
            "0700000000000000", //  88 start_frame 7
            "0b00000000000000", //  96 end_frame 11
            "0300000000000000", // 104 frames_flagged 3
            "000000000000e03f", // 112 alarm_threshold 0.5
            "000000000000f87f", // 120 e_c_threshold NaN
            "000000000000f87f", // 128 e_b_threshold NaN
            "000000000000e03f", // 136 e_o_threshold 0.5
            "000000000000f87f", // 144 e_r_threshold NaN
            "000000000000f87f", // 152 e_k_threshold NaN
            "0a00000005000000", // 160 start.stamp: sec 10, nanosec 5
            "0000000000000040", // 168 start.score 2
            "000000000000d03f", // 176 start.e_c 0.25
            "000000000000f87f", // 184 start.e_b NaN
            "0000000000000040", // 192 start.e_o 2
            "000000000000f87f", // 200 start.e_r NaN
            "000000000000f87f", // 208 start.e_k NaN
            "0b00000000000000", // 216 peak.stamp: sec 11, nanosec 0
            "0000000000000840", // 224 peak.score 3
            "000000000000e03f", // 232 peak.e_c 0.5
            "000000000000f87f", // 240 peak.e_b NaN
            "0000000000000840", // 248 peak.e_o 3
            "000000000000f87f", // 256 peak.e_r NaN
            "000000000000f87f", // 264 peak.e_k NaN
        ];
        let expected: Vec<u8> = rows
            .concat()
            .as_bytes()
            .chunks(2)
            .map(|h| u8::from_str_radix(std::str::from_utf8(h).unwrap(), 16).unwrap())
            .collect();
        assert_eq!(cdr(&m), expected);
    }

    /// `vamos_msgs/FrameScore` keeps the layout of ROS 2's generated type (as for the
    /// alarm event above; rclpy's bytes with Fast CDR's unset padding as zeros).
    #[test]
    fn a_frame_score_has_the_byte_layout_of_ros_2s_generated_type() {
        let s = proto::FrameScore {
            stamp_ns: 12_000_000_345,
            score: 0.5,
            anomaly: true,
            e_c: Some(0.1),
            e_k: Some(2.0),
            detector: proto::Detector::Kinematics as i32,
            frame: 7,
            latency_s: 0.25,
            ..Default::default()
        };
        let m = FrameScore::from_proto(&s, "camera_link".into(), "r1-abc").unwrap();
        let rows = [
            "0c00000059010000", //   0 header.stamp: sec 12, nanosec 345
            "0c00000063616d65", //   8 header.frame_id "camera_link" (12 with the NUL)
            "72615f6c696e6b00", //  16
            "000000000000e03f", //  24 score 0.5
            "010000000b000000", //  32 anomaly; pad; detector length 11
            "6b696e656d617469", //  40 "kinematics"
            "6373000000000000", //  48 NUL; pad to 8
            "9a9999999999b93f", //  56 e_c 0.1
            "000000000000f87f", //  64 e_b NaN
            "000000000000f87f", //  72 e_o NaN
            "000000000000f87f", //  80 e_r NaN
            "0000000000000040", //  88 e_k 2
            "0000000000000000", //  96 warming_up false; pad
            "0700000000000000", // 104 frame 7
            "000000000000d03f", // 112 latency_s 0.25
            "0700000072312d61", // 120 session_id "r1-abc" (7 with the NUL)
            "626300",           // 128
        ];
        let expected: Vec<u8> = rows
            .concat()
            .as_bytes()
            .chunks(2)
            .map(|h| u8::from_str_radix(std::str::from_utf8(h).unwrap(), 16).unwrap())
            .collect();
        assert_eq!(cdr(&m), expected);
    }

    #[test]
    fn an_anomaly_map_becomes_a_mono8_image_with_the_scored_images_header() {
        let (w, h) = (5u32, 3u32);
        let pixels: Vec<u8> = (0..w * h).map(|i| (i * 17) as u8).collect();
        let mut png = Vec::new();
        image::GrayImage::from_raw(w, h, pixels.clone())
            .unwrap()
            .write_to(&mut std::io::Cursor::new(&mut png), image::ImageFormat::Png)
            .unwrap();
        let header = Header {
            stamp: Time { sec: 4, nanosec: 2 },
            frame_id: "camera_optical".into(),
        };
        let m = Image::anomaly_map(&png, header.clone()).unwrap();
        assert_eq!(m.header, header);
        assert_eq!(
            (
                m.width,
                m.height,
                m.step,
                m.encoding.as_str(),
                m.is_bigendian
            ),
            (5, 3, 5, "mono8", 0)
        );
        assert_eq!(m.data.as_slice(), pixels.as_slice());
        let err = Image::anomaly_map(b"not a png", header).unwrap_err();
        assert!(matches!(err, ConvertError::AnomalyMap(_)), "{err}");
    }
}
