//! `vamos.v1` messages to the session layer's types and back.

use crate::api::proto;
use crate::session::alarms::{AlarmEdge, AlarmEvent};
use crate::session::{Event, EventKind, LiveImage, LiveJoints, Output, ScoredFrame, SessionError};
use crate::store::AlarmComponents;
use tonic::Status;
use vamos_core::episode::image::Encoding;
use vamos_core::eval::{Detector, DetectorValues};
use vamos_robot::Intrinsics;

/// The camera of an open message.
pub fn intrinsics_of(c: &proto::CameraInfo) -> Result<Intrinsics, SessionError> {
    Intrinsics::new(c.width, c.height, c.fx, c.fy, c.cx, c.cy)
        .map_err(|source| SessionError::BadCamera { source })
}

/// A streamed image and its depth image, if any; a zero `step` means packed rows.
pub fn live_image(image: proto::Image) -> LiveImage {
    let depth = image.depth.map(|d| {
        Box::new(LiveImage {
            stamp_ns: image.stamp_ns,
            step: packed_step(d.step, &d.encoding, d.width),
            encoding: d.encoding,
            width: d.width,
            height: d.height,
            big_endian: d.big_endian,
            data: d.data,
            depth: None,
        })
    });
    LiveImage {
        stamp_ns: image.stamp_ns,
        step: packed_step(image.step, &image.encoding, image.width),
        encoding: image.encoding,
        width: image.width,
        height: image.height,
        big_endian: image.big_endian,
        data: image.data,
        depth,
    }
}

/// `step`, or the packed row of `width` pixels of `encoding` when it is 0.
fn packed_step(step: u32, encoding: &str, width: u32) -> u32 {
    if step == 0 {
        let bpp = Encoding::from_name(encoding)
            .and_then(Encoding::bytes_per_pixel)
            .unwrap_or(0);
        width.saturating_mul(bpp as u32)
    } else {
        step
    }
}

/// A streamed joint state (velocities are not used).
pub fn live_joints(j: proto::JointState) -> LiveJoints {
    LiveJoints {
        stamp_ns: j.stamp_ns,
        names: j.names,
        positions: j.positions,
        efforts: j.efforts,
    }
}

/// A detector as its `vamos.v1` code.
pub fn detector_code(d: Option<Detector>) -> proto::Detector {
    match d {
        Some(Detector::Camera) => proto::Detector::Camera,
        Some(Detector::Body) => proto::Detector::Body,
        Some(Detector::Flow) => proto::Detector::Flow,
        Some(Detector::Scene) => proto::Detector::Scene,
        Some(Detector::Kinematics) => proto::Detector::Kinematics,
        None => proto::Detector::Unspecified,
    }
}

/// Detector values in the order of the proto messages' five fields (`e_c`, `e_b`,
/// `e_o`, `e_r`, `e_k`: [`Detector::ALL`]'s).
fn fields(v: &DetectorValues) -> [Option<f64>; 5] {
    v.into_array()
}

/// A scored frame as `vamos.v1.FrameScore`, its anomaly map as PNG.
pub fn frame_score(f: &ScoredFrame) -> proto::FrameScore {
    proto::FrameScore {
        anomaly_map: f
            .anomaly_map
            .as_ref()
            .map(crate::session::live::Thumb::to_png)
            .unwrap_or_default(),
        ..frame_score_fields(f)
    }
}

/// [`frame_score`] without the anomaly map (no PNG to encode): what REST prints.
pub fn frame_score_fields(f: &ScoredFrame) -> proto::FrameScore {
    let s = &f.score;
    let [e_c, e_b, e_o, e_r, e_k] = fields(&s.values);
    proto::FrameScore {
        stamp_ns: s.stamp_ns,
        index: s.index,
        frame: s.frame,
        score: s.score,
        e_c,
        e_b,
        e_o,
        e_r,
        e_k,
        anomaly: s.anomaly,
        detector: detector_code(f.detector()) as i32,
        warming_up: s.warming_up,
        latency_s: f.latency_s,
        compute_s: f.compute_s,
        anomaly_map: Vec::new(),
        frames_lost: f.frames_lost,
    }
}

fn detector_by_name(name: &str) -> proto::Detector {
    detector_code(Detector::parse(name))
}

fn alarm_components(c: &AlarmComponents) -> proto::AlarmComponents {
    let [e_c, e_b, e_o, e_r, e_k] = fields(&c.values);
    proto::AlarmComponents {
        stamp_ns: c.stamp_ns,
        score: c.score,
        e_c,
        e_b,
        e_o,
        e_r,
        e_k,
    }
}

/// An alarm event as `vamos.v1.AlarmEvent`.
pub fn alarm_event(e: &AlarmEvent) -> proto::AlarmEvent {
    use proto::alarm_event::Edge;
    let a = &e.alarm;
    let [e_c, e_b, e_o, e_r, e_k] = fields(&a.thresholds.detectors);
    proto::AlarmEvent {
        edge: match e.edge {
            AlarmEdge::Started => Edge::Started,
            AlarmEdge::Ended => Edge::Ended,
        } as i32,
        alarm_id: a.id.clone(),
        session_id: a.session_id.clone(),
        detector: detector_by_name(&a.detector) as i32,
        detectors: a
            .detectors
            .iter()
            .map(|d| detector_by_name(d) as i32)
            .collect(),
        start_frame: a.start_frame,
        end_frame: a.end_frame,
        end_stamp_ns: a.end_stamp_ns,
        frames_flagged: a.frames_flagged,
        alarm_threshold: a.thresholds.alarm,
        e_c_threshold: e_c,
        e_b_threshold: e_b,
        e_o_threshold: e_o,
        e_r_threshold: e_r,
        e_k_threshold: e_k,
        start: Some(alarm_components(&a.start)),
        peak: Some(alarm_components(&a.peak)),
    }
}

/// An event kind as its `vamos.v1` code.
pub fn event_kind(k: EventKind) -> proto::session_event::Kind {
    use proto::session_event::Kind;
    match k {
        EventKind::Opened => Kind::Opened,
        EventKind::Resumed => Kind::Resumed,
        EventKind::WarmingUp => Kind::WarmingUp,
        EventKind::FramesDropped => Kind::FramesDropped,
        EventKind::MessageError => Kind::MessageError,
        EventKind::Phase => Kind::Phase,
        EventKind::Reloaded => Kind::Reloaded,
    }
}

/// An event as `vamos.v1.SessionEvent`.
pub fn session_event(e: Event) -> proto::SessionEvent {
    proto::SessionEvent {
        kind: event_kind(e.kind) as i32,
        session_id: e.session_id,
        detail: e.detail,
        stamp_ns: e.stamp_ns,
        count: e.count,
    }
}

/// A session's output as a `Monitor.Stream` response (or the status that ends it).
pub fn stream_response(o: Output) -> Result<proto::StreamResponse, Status> {
    use proto::stream_response::Message;
    let message = match o {
        Output::Score(f) => Message::Score(frame_score(&f)),
        Output::Event(e) => Message::Event(session_event(e)),
        Output::Alarm(a) => Message::Alarm(alarm_event(&a)),
        Output::Closed(e) => return Err(e.into()),
    };
    Ok(proto::StreamResponse {
        message: Some(message),
    })
}
