//! vamos-proto: the generated gRPC types and services of `proto/vamos/v1` (package
//! `vamos.v1`), with the JSON form of a score that the REST API and `vamos stream` share.

tonic::include_proto!("vamos.v1");

/// The encoded `FileDescriptorSet` of `vamos.v1`, served by gRPC reflection.
pub const FILE_DESCRIPTOR_SET: &[u8] =
    include_bytes!(concat!(env!("OUT_DIR"), "/vamos_descriptor.bin"));

/// The name of a `Detector` code as JSON outputs write it (`camera`, `body`, `flow`,
/// `scene`, `kinematics`); `None` for unspecified or unknown codes.
pub fn detector_name(code: i32) -> Option<&'static str> {
    DetectorName::from_code(code).map(DetectorName::as_str)
}

/// A frame's score as the JSON object the REST API and `vamos stream` print: the gRPC
/// answer's fields and names (a NaN becomes `null`).
#[derive(Debug, Clone, PartialEq, serde::Serialize, schemars::JsonSchema)]
pub struct ScoreJson {
    /// Image stamp, nanoseconds.
    pub stamp_ns: i64,
    /// Index of the image in the stream (0-based, counting images not processed).
    pub index: u64,
    /// Index among processed frames.
    pub frame: u64,
    /// The fused score (see `FrameScore.score` in `proto/vamos/v1/monitor.proto`).
    #[schemars(with = "Option<f64>")]
    pub score: f64,
    /// Camera-motion error; `null` when that detector is off or not yet defined.
    pub e_c: Option<f64>,
    /// Body-motion error.
    pub e_b: Option<f64>,
    /// Flow-prediction error.
    pub e_o: Option<f64>,
    /// Scene-motion residual.
    pub e_r: Option<f64>,
    /// Kinematic novelty.
    pub e_k: Option<f64>,
    /// The score reached the alarm threshold.
    pub anomaly: bool,
    /// The detector that set the score (calibrated fusion), if one did.
    pub detector: Option<DetectorName>,
    /// The predictor lacks its history: scored without `e_o`.
    pub warming_up: bool,
    /// Time spent computing the score, seconds.
    pub compute_s: f64,
}

/// A `Detector` code as JSON outputs name it ([`detector_name`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, schemars::JsonSchema)]
#[serde(rename_all = "lowercase")]
pub enum DetectorName {
    /// `e_c`.
    Camera,
    /// `e_b`.
    Body,
    /// `e_o`.
    Flow,
    /// `e_r`.
    Scene,
    /// `e_k`.
    Kinematics,
}

impl DetectorName {
    /// The name of a `Detector` code; `None` for unspecified or unknown codes.
    pub fn from_code(code: i32) -> Option<DetectorName> {
        match Detector::try_from(code) {
            Ok(Detector::Camera) => Some(DetectorName::Camera),
            Ok(Detector::Body) => Some(DetectorName::Body),
            Ok(Detector::Flow) => Some(DetectorName::Flow),
            Ok(Detector::Scene) => Some(DetectorName::Scene),
            Ok(Detector::Kinematics) => Some(DetectorName::Kinematics),
            _ => None,
        }
    }

    /// The name as JSON writes it.
    pub fn as_str(self) -> &'static str {
        match self {
            DetectorName::Camera => "camera",
            DetectorName::Body => "body",
            DetectorName::Flow => "flow",
            DetectorName::Scene => "scene",
            DetectorName::Kinematics => "kinematics",
        }
    }
}

impl From<&FrameScore> for ScoreJson {
    fn from(s: &FrameScore) -> ScoreJson {
        ScoreJson {
            stamp_ns: s.stamp_ns,
            index: s.index,
            frame: s.frame,
            score: s.score,
            e_c: s.e_c,
            e_b: s.e_b,
            e_o: s.e_o,
            e_r: s.e_r,
            e_k: s.e_k,
            anomaly: s.anomaly,
            detector: DetectorName::from_code(s.detector),
            warming_up: s.warming_up,
            compute_s: s.compute_s,
        }
    }
}

/// A frame's score as the JSON object the REST API and `vamos stream` print
/// ([`ScoreJson`]).
pub fn score_json(s: &FrameScore) -> serde_json::Value {
    serde_json::to_value(ScoreJson::from(s)).unwrap_or_default()
}
