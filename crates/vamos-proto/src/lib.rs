//! vamos-proto: the generated gRPC types and services of `proto/vamos/v1` (package
//! `vamos.v1`), with the JSON form of a score that the REST API and `vamos stream` share.

tonic::include_proto!("vamos.v1");

/// The encoded `FileDescriptorSet` of `vamos.v1`, served by gRPC reflection.
pub const FILE_DESCRIPTOR_SET: &[u8] =
    include_bytes!(concat!(env!("OUT_DIR"), "/vamos_descriptor.bin"));

/// The name of a `Detector` code as JSON outputs write it (`camera`, `body`, `flow`);
/// `None` for unspecified or unknown codes.
pub fn detector_name(code: i32) -> Option<&'static str> {
    match Detector::try_from(code) {
        Ok(Detector::Camera) => Some("camera"),
        Ok(Detector::Body) => Some("body"),
        Ok(Detector::Flow) => Some("flow"),
        Ok(Detector::Scene) => Some("scene"),
        Ok(Detector::Kinematics) => Some("kinematics"),
        _ => None,
    }
}

/// A frame's score as the JSON object the REST API and `vamos stream` print.
pub fn score_json(s: &FrameScore) -> serde_json::Value {
    serde_json::json!({
        "stamp_ns": s.stamp_ns,
        "index": s.index,
        "frame": s.frame,
        "score": s.score,
        "e_c": s.e_c,
        "e_b": s.e_b,
        "e_o": s.e_o,
        "e_r": s.e_r,
        "e_k": s.e_k,
        "anomaly": s.anomaly,
        "detector": detector_name(s.detector),
        "warming_up": s.warming_up,
        "compute_s": s.compute_s,
    })
}
