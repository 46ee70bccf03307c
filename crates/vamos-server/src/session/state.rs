//! One session: a streamed task execution or an uploaded episode. Its state (images
//! waiting for joint states, the queue of frames ready to score, the joint buffer), its
//! scorer, and what the REST API lists of it.

use super::budget::Charge;
use super::event::{LiveImage, Outbound};
use super::joints::JointBuffer;
use super::profiles::LoadedProfile;
use std::collections::VecDeque;
use std::sync::atomic::{AtomicBool, AtomicU64, AtomicUsize, Ordering};
use std::sync::{Arc, Condvar, Mutex, MutexGuard};
use std::time::{Duration, Instant};
use vamos_core::episode::Reserved;
use vamos_core::pipeline::Scorer;
use vamos_robot::Intrinsics;
use vamos_vision::{DepthImage, GrayImage};

pub(super) fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|e| e.into_inner())
}

/// An image as it came.
pub enum ImagePayload {
    /// A streamed image (raw pixels or JPEG/PNG), decoded by the worker.
    Live(LiveImage),
    /// Already decoded (recorded episodes), with the frame's intrinsics and depth image if
    /// any.
    Decoded(GrayImage, Option<Intrinsics>, Option<DepthImage>),
}

/// Joint states interpolated to an image's stamp.
#[derive(Debug, Clone, PartialEq)]
pub struct FrameJoints {
    /// Joint names.
    pub names: Vec<String>,
    /// Positions (rad or m), one per name.
    pub positions: Vec<f64>,
    /// Efforts (N m or N), one per name; empty when the joint states carry none.
    pub efforts: Vec<f64>,
}

/// A frame ready to be scored.
pub struct ReadyFrame {
    /// Image stamp, nanoseconds.
    pub stamp_ns: i64,
    /// The image.
    pub image: ImagePayload,
    /// The joint states at the stamp.
    pub joints: Option<FrameJoints>,
    /// When the image reached the server.
    pub arrived: Instant,
    /// What the frame holds of the server's memory budget (given back when the frame is
    /// scored or dropped): its buffered bytes, or its decoded image's reservations.
    pub held: Vec<Arc<dyn Reserved>>,
}

/// The latest score of a session, for listings.
#[derive(
    Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize, schemars::JsonSchema,
)]
#[serde(deny_unknown_fields)]
pub struct LatestScore {
    /// Image stamp, nanoseconds.
    pub stamp_ns: i64,
    /// Fused score.
    pub score: f64,
    /// Anomaly flag.
    pub anomaly: bool,
}

/// A session as listed by the REST API.
#[derive(Debug, Clone, serde::Serialize, schemars::JsonSchema)]
pub struct SessionSummary {
    /// Session id.
    pub id: String,
    /// Robot id given at open.
    pub robot_id: String,
    /// Profile.
    pub profile: String,
    /// Model label.
    pub model: String,
    /// Task given at open.
    pub task: String,
    /// The robot token that opened it ([`Session::opener`]; never shown).
    #[serde(skip)]
    #[schemars(skip)]
    pub opener: Option<usize>,
    /// Current phase (latest phase marker).
    pub phase: Option<String>,
    /// `streaming`, `detached` (waiting to be resumed), `episode`, or `ended` (kept with
    /// its robot's last sessions, [`super::history`]).
    pub state: &'static str,
    /// Images received.
    pub images: u64,
    /// Frames scored.
    pub frames_scored: u64,
    /// Images dropped (queue full, rejected, undecodable, undelivered).
    pub dropped: u64,
    /// Images lost before a scored frame (dropped by a full queue, refused): each such
    /// frame restarted the motion history (its score's `frames_lost`).
    pub frames_lost: u64,
    /// Images were lost before one of its last 100 scored frames, or lost images wait
    /// for the next frame: its scores have gaps (an ended session: images were lost at
    /// any time).
    pub degraded: bool,
    /// Frames flagged anomalous.
    pub anomalies: u64,
    /// Images waiting.
    pub queued: usize,
    /// Seconds since open (an ended session: from open to end).
    pub age_s: f64,
    /// When it opened, seconds since the Unix epoch (server clock).
    pub opened_unix_s: u64,
    /// When it ended, seconds since the Unix epoch (`None`: open).
    pub ended_unix_s: Option<u64>,
    /// Why it ended (`None`: open, or it finished normally).
    pub end_reason: Option<String>,
    /// The image stamp of its first scored frame, nanoseconds (the origin of its
    /// timeline's time axis).
    pub first_stamp_ns: Option<i64>,
    /// The latest score.
    pub latest: Option<LatestScore>,
    /// Times the session was moved to its profile's stored state ([`Hub::reload`]).
    pub reloads: u64,
    /// An alarm is on.
    pub alarm_on: bool,
    /// Mean server latency of the frames on its timeline, seconds.
    pub latency_s: Option<f64>,
    /// Scored frames per second over its timeline (image stamps).
    pub frame_rate_hz: Option<f64>,
    /// What its profile asks for and cannot do: the conformal threshold's fallback, no
    /// alarms, a detector that cannot run, and why (the live view shows them).
    pub notes: Vec<String>,
}

pub(super) struct SessionState {
    pub(super) pending: VecDeque<ReadyFrame>,
    pub(super) queue: VecDeque<ReadyFrame>,
    pub(super) scheduled: bool,
    pub(super) joints: JointBuffer,
    /// The joint buffer's bytes, charged to the server's budget.
    pub(super) joint_charge: Charge,
    pub(super) last_image_ns: Option<i64>,
    pub(super) newest_ns: i64,
    pub(super) out: Option<Outbound>,
    pub(super) finishing: bool,
    pub(super) closed: bool,
    pub(super) detached_since: Option<Instant>,
    pub(super) last_activity: Instant,
    pub(super) phase: Option<String>,
    pub(super) latest: Option<LatestScore>,
    pub(super) images: u64,
    /// Whether `warming_up` has been reported.
    pub(super) warm_reported: bool,
    /// Images lost (dropped by the queue, refused) since the worker last took a frame:
    /// the next frame it takes restarts the scorer's motion history
    /// ([`vamos_core::pipeline::Scorer::restart_after_gap`]). Under the `reject` queue
    /// policy a frame queued before a rejected one restarts too (it is older, so it had
    /// no gap): one frame without a motion score, never a score over a gap.
    pub(super) lost: u64,
    /// Its measured cost and image rate.
    pub(super) load: super::capacity::SessionLoad,
}

/// One streamed task execution (or one uploaded episode).
pub struct Session {
    /// Session id.
    pub id: String,
    /// Robot id.
    pub robot_id: String,
    /// Task.
    pub task: String,
    /// The robot token that opened it (its place among the server's robot tokens;
    /// `None`: an admin, or no tokens): who besides admins and viewers may see it.
    pub opener: Option<usize>,
    /// Whether the client chose the id (it can resume).
    pub resumable: bool,
    /// Whether it scores an uploaded episode.
    pub episode: bool,
    /// The name of its profile (fixed for the session's life).
    pub profile_name: String,
    /// The request id of the call that opened it (may be empty).
    pub request_id: String,
    /// The profile it scores with: the one it was opened with, until a reload
    /// ([`Hub::reload`]) moves it to the profile as stored now.
    pub(super) profile: Mutex<Arc<LoadedProfile>>,
    /// What seeds the predictor's sampling (kept for a reload's new scorer).
    pub(super) seed_key: String,
    /// The camera of the open message, else the profile's.
    pub(super) camera: Option<Intrinsics>,
    /// Whether images wait for joint states (the profile has a robot).
    pub(super) needs_joints: AtomicBool,
    /// Reloads so far.
    pub(super) reloads: AtomicU64,
    pub(super) opened: Instant,
    /// When it opened, milliseconds since the Unix epoch.
    pub(super) opened_unix_ms: u64,
    pub(super) state: Mutex<SessionState>,
    pub(super) space: Condvar,
    pub(super) scorer: Mutex<Scorer>,
    pub(super) frames_scored: AtomicU64,
    pub(super) dropped: AtomicU64,
    pub(super) anomalies: AtomicU64,
    /// Whether scores carry anomaly maps ([`OpenRequest::maps`]).
    pub maps: bool,
    /// Its alarm in progress and the debouncer.
    pub(super) alarms: Mutex<super::alarms::AlarmTracker>,
    /// What the live view shows of it.
    pub(super) live: Mutex<super::live::LiveView>,
    /// Its recording in progress ([`super::recording`]), if it is recorded.
    pub(super) recorder: Mutex<Option<super::recording::Recorder>>,
    /// Its part of the pool's load.
    pub(super) share: super::capacity::SessionShare,
}

impl Session {
    /// The profile the session scores with now.
    pub fn profile(&self) -> Arc<LoadedProfile> {
        lock(&self.profile).clone()
    }

    pub(super) fn needs_joints(&self) -> bool {
        self.needs_joints.load(Ordering::Relaxed)
    }

    /// Timeline points after frame `after` (all kept when `None`).
    pub fn timeline(&self, after: Option<u64>) -> Vec<super::live::FramePoint> {
        lock(&self.live).since(after)
    }

    /// The latest frame (shrunk) and anomaly map, as PNG files.
    pub fn latest_images(&self) -> (Option<Vec<u8>>, Option<Vec<u8>>) {
        let live = lock(&self.live);
        (
            live.frame.as_ref().map(super::live::Thumb::to_png),
            live.map.as_ref().map(super::live::Thumb::to_png),
        )
    }

    /// Whether an alarm is on.
    pub fn alarm_on(&self) -> bool {
        lock(&self.alarms).active()
    }

    /// The session as listed by the REST API.
    pub fn summary(&self) -> SessionSummary {
        let model = self.profile().model_label.clone();
        let alarm_on = self.alarm_on();
        let (latency_s, frame_rate_hz, frames_lost, recent_lost, first_stamp_ns) = {
            let live = lock(&self.live);
            let n = live.history.len();
            let latency =
                (n > 0).then(|| live.history.iter().map(|p| p.latency_s).sum::<f64>() / n as f64);
            let rate = match (live.history.front(), live.history.back()) {
                (Some(a), Some(b)) if b.stamp_ns > a.stamp_ns => {
                    Some((n - 1) as f64 / ((b.stamp_ns - a.stamp_ns) as f64 * 1e-9))
                }
                _ => None,
            };
            (
                latency,
                rate,
                live.frames_lost,
                live.recent_lost(super::live::DEGRADED_FRAMES),
                live.first_stamp_ns,
            )
        };
        let st = lock(&self.state);
        SessionSummary {
            id: self.id.clone(),
            robot_id: self.robot_id.clone(),
            profile: self.profile_name.clone(),
            model,
            task: self.task.clone(),
            opener: self.opener,
            phase: st.phase.clone(),
            state: if self.episode {
                "episode"
            } else if st.detached_since.is_some() {
                "detached"
            } else {
                "streaming"
            },
            images: st.images,
            frames_scored: self.frames_scored.load(Ordering::Relaxed),
            dropped: self.dropped.load(Ordering::Relaxed),
            frames_lost: frames_lost + st.lost,
            degraded: recent_lost + st.lost > 0,
            anomalies: self.anomalies.load(Ordering::Relaxed),
            queued: st.queue.len() + st.pending.len(),
            age_s: self.opened.elapsed().as_secs_f64(),
            opened_unix_s: self.opened_unix_ms / 1000,
            ended_unix_s: None,
            end_reason: None,
            first_stamp_ns,
            latest: st.latest,
            reloads: self.reloads.load(Ordering::Relaxed),
            alarm_on,
            latency_s,
            frame_rate_hz,
            notes: self.profile().notes.clone(),
        }
    }

    /// Seconds since the last message from the client.
    pub fn idle_for(&self) -> Duration {
        lock(&self.state).last_activity.elapsed()
    }

    /// Time since the session opened.
    pub fn age(&self) -> Duration {
        self.opened.elapsed()
    }
}

/// How an open message asks for a session.
pub struct OpenRequest {
    /// Robot id.
    pub robot_id: String,
    /// Task.
    pub task: String,
    /// The robot token opening it ([`Session::opener`]).
    pub opener: Option<usize>,
    /// Client-chosen id (resumable) or empty.
    pub session_id: String,
    /// Camera of the open message.
    pub camera: Option<Intrinsics>,
    /// Whether it is an episode upload.
    pub episode: bool,
    /// What seeds the predictor's sampling (default: the session id); `vamos score`
    /// uses the episode's file stem.
    pub seed_key: Option<String>,
    /// A place reserved before the episode's upload was read ([`Hub::reserve_session`]).
    pub slot: Option<SessionSlot>,
    /// The request id of the call that opened it (`x-request-id`), for its spans; may be
    /// empty.
    pub request_id: String,
    /// Whether each streamed score carries the frame's anomaly map (the scorer keeps
    /// the flow predictor's error map for it).
    pub maps: bool,
    /// The image rate the client says it will send, Hz (see [`super::capacity`]).
    pub image_rate_hz: Option<f64>,
}

/// A session place held for an episode while its upload is read
/// ([`Hub::reserve_session`]): [`Hub::open`] with it never finds the server full;
/// dropped unused, it frees the place.
pub struct SessionSlot {
    pub(super) reserved: Arc<AtomicUsize>,
}

impl Drop for SessionSlot {
    fn drop(&mut self) {
        self.reserved.fetch_sub(1, Ordering::SeqCst);
    }
}
