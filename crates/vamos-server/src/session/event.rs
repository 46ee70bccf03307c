//! The session layer's vocabulary with its clients: what comes in (images, joint states,
//! phase markers, in core types) and what goes out (scores, events, the reason a stream
//! ends). The transports convert their messages to and from these, and nothing else.

use super::error::SessionError;
use tokio::sync::mpsc;
use vamos_core::episode::image::EncodedImage;
use vamos_core::eval::Detector;
use vamos_core::pipeline::FrameScore;

/// An image as a robot streams it: raw pixel rows or a JPEG/PNG file, owned.
#[derive(Debug, Clone)]
pub struct LiveImage {
    /// Capture stamp, nanoseconds.
    pub stamp_ns: i64,
    /// Encoding name (`rgb8`, `mono16`, `jpeg`, ... any case; see
    /// [`vamos_core::episode::image::Encoding::from_name`]).
    pub encoding: String,
    /// Columns (raw pixels).
    pub width: u32,
    /// Rows (raw pixels).
    pub height: u32,
    /// Bytes per row (raw pixels; the transport resolves "packed").
    pub step: u32,
    /// Whether multi-byte pixels are big endian.
    pub big_endian: bool,
    /// Pixels or the file.
    pub data: Vec<u8>,
    /// A depth image registered to this image (raw `16UC1` millimetres or `32FC1` metres,
    /// the same stamp), if the robot sends one.
    pub depth: Option<Box<LiveImage>>,
}

impl LiveImage {
    /// The image for the decoder.
    pub fn encoded(&self) -> EncodedImage<'_> {
        EncodedImage::raw(
            &self.encoding,
            self.width,
            self.height,
            self.step,
            self.big_endian,
            &self.data,
        )
    }
}

/// A joint state as a robot streams it.
#[derive(Debug, Clone, Default)]
pub struct LiveJoints {
    /// Stamp, nanoseconds.
    pub stamp_ns: i64,
    /// Joint names.
    pub names: Vec<String>,
    /// Positions (rad or m), one per name.
    pub positions: Vec<f64>,
    /// Efforts (N m or N), one per name or none.
    pub efforts: Vec<f64>,
}

/// A scored frame as it leaves the session.
#[derive(Debug, Clone)]
pub struct ScoredFrame {
    /// The scorer's result.
    pub score: FrameScore,
    /// From the image's arrival to its score, seconds.
    pub latency_s: f64,
    /// Time spent computing the score, seconds.
    pub compute_s: f64,
    /// Images lost (dropped or refused) between the previous score and this frame: when
    /// above 0 the frame started the motion history afresh, so it has no motion score
    /// and cannot alarm.
    pub frames_lost: u64,
    /// The frame's anomaly map (8-bit gray, 0 = nominal; see [`super::live`]), for
    /// sessions that asked for maps.
    pub anomaly_map: Option<super::live::Thumb>,
}

impl ScoredFrame {
    /// The detector reported for the frame: the one that triggered, `flow` for an
    /// anomaly no threshold triggered (the fused score's alarm), none otherwise.
    pub fn detector(&self) -> Option<Detector> {
        detector_of(&self.score)
    }
}

/// The detector reported for `score` (see [`ScoredFrame::detector`]).
pub fn detector_of(score: &FrameScore) -> Option<Detector> {
    match score.triggered {
        Some(d) => Some(d),
        None if score.anomaly => Some(Detector::Flow),
        None => None,
    }
}

/// What happened to a session, as its client hears it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum EventKind {
    /// The session is open.
    Opened,
    /// The session was resumed under its client-chosen id.
    Resumed,
    /// The flow predictor is collecting its history.
    WarmingUp,
    /// Images were dropped under backpressure (count: how many so far).
    FramesDropped,
    /// One message was refused; the session goes on.
    MessageError,
    /// A phase marker was received.
    Phase,
    /// The session moved to its profile as stored now (count: reloads so far).
    Reloaded,
}

/// An event of a session.
#[derive(Debug, Clone)]
pub struct Event {
    /// What happened.
    pub kind: EventKind,
    /// The session.
    pub session_id: String,
    /// Details for people.
    pub detail: String,
    /// The stamp it concerns, nanoseconds (0: none).
    pub stamp_ns: i64,
    /// A count (drops, reloads).
    pub count: u64,
}

/// What a session sends its client.
#[derive(Debug)]
// Scores are nearly every message: they stay inline rather than boxed once per frame.
#[allow(clippy::large_enum_variant)]
pub enum Output {
    /// A frame's score.
    Score(ScoredFrame),
    /// An event.
    Event(Event),
    /// An alarm started or ended.
    Alarm(super::alarms::AlarmEvent),
    /// The stream ends with this error (a stream that just ends ended well).
    Closed(SessionError),
}

/// Where a session's output goes. Sends never block a worker: a client that does not
/// read loses output (counted as `undelivered`).
pub type Outbound = mpsc::Sender<Output>;
