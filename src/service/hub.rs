//! Sessions and the worker pool that scores them.
//!
//! A session owns a [`Scorer`], a buffer of joint states, the images waiting for a joint
//! state at or after their stamp (so they can be interpolated as offline scoring does),
//! and a bounded queue of frames ready to score. One pool of worker threads serves all
//! sessions: a session with work waits in one FIFO of ready sessions, a worker takes one
//! frame of the session at its head and puts the session back at the tail if more wait.
//! So sessions are served round-robin, one frame each, a busy robot cannot starve
//! another, and the frames of one session are scored in order by one worker at a time.
//!
//! Scores go to the session's outbound channel without blocking: a client that does not
//! read its scores loses them (counted as `undelivered`), it never stalls a worker.

use super::budget::{ByteBudget, Charge};
use super::config::{QueuePolicy, ServiceConfig};
use super::metrics::Metrics;
use super::profiles::LoadedProfile;
use super::proto;
use crate::episode::interpolate_rows;
use crate::episode::ros::{CompressedImageMsg, Header, ImageMsg};
use crate::eval::Detector;
use crate::pipeline::{FrameInput, FrameScore, JointInput, Scorer};
use crate::robot::Intrinsics;
use crate::vision::GrayImage;
use std::collections::{HashMap, VecDeque};
use std::panic::{AssertUnwindSafe, catch_unwind};
use std::sync::atomic::{AtomicBool, AtomicU64, AtomicUsize, Ordering};
use std::sync::{Arc, Condvar, Mutex, MutexGuard};
use std::time::{Duration, Instant};
use tokio::sync::mpsc;
use tonic::Status;

/// What a session's stream receives.
pub type Outbound = mpsc::Sender<Result<proto::StreamResponse, Status>>;

/// Longest joint name accepted, bytes.
const MAX_JOINT_NAME: usize = 256;

/// Heap bytes a buffered image is charged beyond its pixel bytes (the frame's
/// bookkeeping).
const FRAME_OVERHEAD: u64 = 256;

fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|e| e.into_inner())
}

/// Why a session cannot be opened.
#[derive(Debug, thiserror::Error)]
pub enum OpenError {
    /// `max_sessions` are open.
    #[error("the server has its maximum of {max} sessions open")]
    TooMany {
        /// The limit.
        max: usize,
    },
    /// A session with that id is streaming.
    #[error("session {id:?} is already streaming")]
    Busy {
        /// The id.
        id: String,
    },
    /// A resumed session belongs to another profile.
    #[error("session {id:?} was opened with profile {profile:?}")]
    ProfileMismatch {
        /// The id.
        id: String,
        /// Its profile.
        profile: String,
    },
    /// The server is shutting down.
    #[error("the server is shutting down")]
    ShuttingDown,
    /// The scorer could not be built.
    #[error("{0}")]
    Scorer(String),
    /// An id that is not acceptable.
    #[error("invalid session id: {0}")]
    BadId(String),
}

impl From<OpenError> for Status {
    fn from(e: OpenError) -> Self {
        match e {
            OpenError::TooMany { .. } => Status::resource_exhausted(e.to_string()),
            OpenError::Busy { .. } => Status::already_exists(e.to_string()),
            OpenError::ProfileMismatch { .. } | OpenError::BadId(_) => {
                Status::invalid_argument(e.to_string())
            }
            OpenError::ShuttingDown => Status::unavailable(e.to_string()),
            OpenError::Scorer(_) => Status::failed_precondition(e.to_string()),
        }
    }
}

/// An image as it came.
pub enum ImagePayload {
    /// A `vamos.v1.Image` (raw pixels or JPEG/PNG), decoded by the worker.
    Message(proto::Image),
    /// Already decoded (recorded episodes), with the frame's intrinsics if any.
    Decoded(GrayImage, Option<Intrinsics>),
}

/// A frame ready to be scored.
pub struct ReadyFrame {
    /// Image stamp, nanoseconds.
    pub stamp_ns: i64,
    /// The image.
    pub image: ImagePayload,
    /// Joint names and positions at the stamp.
    pub joints: Option<(Vec<String>, Vec<f64>)>,
    /// When the image reached the server.
    pub arrived: Instant,
    /// What the frame holds of the server's memory budget (given back when the frame is
    /// scored or dropped).
    pub charge: Option<Charge>,
}

/// Joint samples of one set of names (one publisher), stamps ascending.
struct JointGroup {
    names: Vec<String>,
    stamps_ns: Vec<i64>,
    rows: Vec<f64>,
}

/// Joint states of a session, grouped by their name lists.
#[derive(Default)]
pub(crate) struct JointBuffer {
    groups: Vec<JointGroup>,
}

impl JointBuffer {
    fn newest_ns(&self) -> Option<i64> {
        self.groups
            .iter()
            .filter_map(|g| g.stamps_ns.last().copied())
            .min()
    }

    /// Bytes of the samples and names held, for the session's cap and the server's
    /// budget (the vectors' spare capacity, at most as much again, is not counted).
    pub(crate) fn bytes(&self) -> u64 {
        self.groups
            .iter()
            .map(|g| {
                8 * (g.stamps_ns.len() + g.rows.len())
                    + g.names.iter().map(|n| n.len() + 24).sum::<usize>()
            })
            .sum::<usize>() as u64
    }

    /// Bytes a push of `names` would add at most (before any growth of capacity).
    pub(crate) fn push_cost(&self, names: &[String]) -> u64 {
        let row = 8 * (names.len() + 1);
        if self.groups.iter().any(|g| g.names == names) {
            row as u64
        } else {
            (row + names.iter().map(|n| n.len() + 24).sum::<usize>()) as u64
        }
    }

    pub(crate) fn push(
        &mut self,
        stamp_ns: i64,
        names: Vec<String>,
        positions: Vec<f64>,
    ) -> Result<(), String> {
        if names.len() != positions.len() {
            return Err(format!(
                "joint state has {} names and {} positions",
                names.len(),
                positions.len()
            ));
        }
        if names.is_empty() {
            return Err("joint state without joints".into());
        }
        if let Some(bad) = names.iter().zip(&positions).find(|(_, p)| !p.is_finite()) {
            return Err(format!("joint {:?} has a non-finite position", bad.0));
        }
        if let Some(long) = names.iter().find(|n| n.len() > MAX_JOINT_NAME) {
            return Err(format!(
                "joint name of {} bytes (at most {MAX_JOINT_NAME}): {:?}...",
                long.len(),
                long.chars().take(32).collect::<String>()
            ));
        }
        let group = match self.groups.iter_mut().position(|g| g.names == names) {
            Some(i) => &mut self.groups[i],
            None => {
                if self.groups.len() >= 16 {
                    return Err("more than 16 distinct joint-name lists".into());
                }
                self.groups.push(JointGroup {
                    names,
                    stamps_ns: Vec::new(),
                    rows: Vec::new(),
                });
                let last = self.groups.len() - 1;
                &mut self.groups[last]
            }
        };
        if let Some(&last) = group.stamps_ns.last()
            && stamp_ns <= last
        {
            return Err(format!(
                "joint state stamp {stamp_ns} ns is not after the previous one ({last} ns)"
            ));
        }
        group.stamps_ns.push(stamp_ns);
        group.rows.extend(positions);
        Ok(())
    }

    /// Joint positions at `stamp_ns`: each group interpolated (nearest outside its span),
    /// names concatenated.
    pub(crate) fn at(&self, stamp_ns: i64) -> Option<(Vec<String>, Vec<f64>)> {
        if self.groups.is_empty() {
            return None;
        }
        let mut names = Vec::new();
        let mut positions = Vec::new();
        for g in &self.groups {
            let s = interpolate_rows(&g.stamps_ns, &g.rows, g.names.len(), stamp_ns);
            names.extend(g.names.iter().cloned());
            positions.extend(s.positions);
        }
        Some((names, positions))
    }

    /// Forgets samples that can no longer be the neighbours of an image at or after
    /// `stamp_ns` (keeps the last one before it).
    pub(crate) fn trim_before(&mut self, stamp_ns: i64) {
        for g in &mut self.groups {
            let keep_from = g
                .stamps_ns
                .partition_point(|&t| t < stamp_ns)
                .saturating_sub(1);
            if keep_from > 0 {
                let n = g.names.len();
                g.stamps_ns.drain(..keep_from);
                g.rows.drain(..keep_from * n);
                // A burst must not pin its capacity for the session's life.
                if g.stamps_ns.capacity() > 4 * g.stamps_ns.len().max(64) {
                    g.stamps_ns.shrink_to(2 * g.stamps_ns.len());
                    g.rows.shrink_to(2 * g.rows.len());
                }
            }
        }
    }
}

/// A streamed image decoded to gray: raw ROS encodings (a zero `step` means packed rows)
/// and PNG / JPEG files, at most `max_pixels`. With a `budget`, the decoding's memory
/// (estimated from the declared size, before anything is decoded) is charged to it for
/// as long as the returned charge lives, or the image is refused.
pub(crate) fn decode_image(
    image: &proto::Image,
    max_pixels: usize,
    budget: Option<&Arc<ByteBudget>>,
) -> Result<(GrayImage, Option<Charge>), String> {
    let enc = image.encoding.to_ascii_lowercase();
    let charge = |w: usize, h: usize, bytes_per_px: u64| match budget {
        Some(b) => b
            .charge((w * h) as u64 * bytes_per_px)
            .map(Some)
            .map_err(|e| format!("{w}x{h} image not decoded: {e}")),
        None => Ok(None),
    };
    if matches!(enc.as_str(), "jpeg" | "jpg" | "png") {
        let msg = CompressedImageMsg {
            header: Header::from_stamp_ns(image.stamp_ns, ""),
            format: enc,
            data: &image.data,
        };
        let (w, h) = msg.dimensions().map_err(|e| e.to_string())?;
        crate::episode::ros::check_image_size(w, h, max_pixels).map_err(|e| e.to_string())?;
        // Decoded pixels (up to 16-bit RGBA), a float conversion of colour, the gray f32.
        let mut held = charge(w, h, 24)?;
        let gray = msg.to_gray(max_pixels).map_err(|e| e.to_string())?;
        // Decoded: only the gray image stays.
        if let Some(c) = held.as_mut() {
            let _ = c.resize(4 * gray.data().len() as u64);
        }
        return Ok((gray, held));
    }
    let bpp = match enc.as_str() {
        "rgb8" | "bgr8" => 3,
        "rgba8" | "bgra8" => 4,
        "mono8" | "8uc1" => 1,
        "mono16" | "16uc1" => 2,
        "32fc1" => 4,
        _ => 0,
    };
    let step = if image.step == 0 {
        image.width.saturating_mul(bpp)
    } else {
        image.step
    };
    let msg = ImageMsg {
        header: Header::from_stamp_ns(image.stamp_ns, ""),
        height: image.height,
        width: image.width,
        encoding: image.encoding.clone(),
        is_bigendian: image.big_endian,
        step,
        data: &image.data,
    };
    let (w, h) = msg.validate(max_pixels).map_err(|e| e.to_string())?;
    let held = charge(w, h, 4)?;
    let gray = msg.to_gray(max_pixels).map_err(|e| e.to_string())?;
    Ok((gray, held))
}

/// The latest score of a session, for listings.
#[derive(Debug, Clone, Copy, serde::Serialize)]
pub struct LatestScore {
    /// Image stamp, nanoseconds.
    pub stamp_ns: i64,
    /// Fused score.
    pub score: f64,
    /// Anomaly flag.
    pub anomaly: bool,
}

/// A session as listed by the REST API.
#[derive(Debug, Clone, serde::Serialize)]
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
    /// Current phase (latest phase marker).
    pub phase: Option<String>,
    /// `streaming`, `detached` (waiting to be resumed), `episode`.
    pub state: &'static str,
    /// Images received.
    pub images: u64,
    /// Frames scored.
    pub frames_scored: u64,
    /// Images dropped (queue full, rejected, undecodable, undelivered).
    pub dropped: u64,
    /// Frames flagged anomalous.
    pub anomalies: u64,
    /// Images waiting.
    pub queued: usize,
    /// Seconds since open.
    pub age_s: f64,
    /// The latest score.
    pub latest: Option<LatestScore>,
    /// Times the session was moved to its profile's stored state ([`Hub::reload`]).
    pub reloads: u64,
}

struct SessionState {
    pending: VecDeque<ReadyFrame>,
    queue: VecDeque<ReadyFrame>,
    scheduled: bool,
    joints: JointBuffer,
    /// The joint buffer's bytes, charged to the server's budget.
    joint_charge: Charge,
    last_image_ns: Option<i64>,
    newest_ns: i64,
    out: Option<Outbound>,
    finishing: bool,
    closed: bool,
    detached_since: Option<Instant>,
    last_activity: Instant,
    phase: Option<String>,
    latest: Option<LatestScore>,
    images: u64,
    /// Whether `warming_up` has been reported.
    warm_reported: bool,
}

/// One streamed task execution (or one uploaded episode).
pub struct Session {
    /// Session id.
    pub id: String,
    /// Robot id.
    pub robot_id: String,
    /// Task.
    pub task: String,
    /// Whether the client chose the id (it can resume).
    pub resumable: bool,
    /// Whether it scores an uploaded episode.
    pub episode: bool,
    /// The name of its profile (fixed for the session's life).
    pub profile_name: String,
    /// The profile it scores with: the one it was opened with, until a reload
    /// ([`Hub::reload`]) moves it to the profile as stored now.
    profile: Mutex<Arc<LoadedProfile>>,
    /// What seeds the predictor's sampling (kept for a reload's new scorer).
    seed_key: String,
    /// The camera of the open message, else the profile's.
    camera: Option<Intrinsics>,
    /// Whether images wait for joint states (the profile has a robot).
    needs_joints: AtomicBool,
    /// Reloads so far.
    reloads: AtomicU64,
    opened: Instant,
    state: Mutex<SessionState>,
    space: Condvar,
    scorer: Mutex<Scorer>,
    frames_scored: AtomicU64,
    dropped: AtomicU64,
    anomalies: AtomicU64,
}

impl Session {
    /// The profile the session scores with now.
    pub fn profile(&self) -> Arc<LoadedProfile> {
        lock(&self.profile).clone()
    }

    fn needs_joints(&self) -> bool {
        self.needs_joints.load(Ordering::Relaxed)
    }

    /// The session as listed by the REST API.
    pub fn summary(&self) -> SessionSummary {
        let model = self.profile().model_label.clone();
        let st = lock(&self.state);
        SessionSummary {
            id: self.id.clone(),
            robot_id: self.robot_id.clone(),
            profile: self.profile_name.clone(),
            model,
            task: self.task.clone(),
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
            anomalies: self.anomalies.load(Ordering::Relaxed),
            queued: st.queue.len() + st.pending.len(),
            age_s: self.opened.elapsed().as_secs_f64(),
            latest: st.latest,
            reloads: self.reloads.load(Ordering::Relaxed),
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

fn event(
    session: &str,
    kind: proto::session_event::Kind,
    detail: impl Into<String>,
    stamp_ns: i64,
    count: u64,
) -> proto::StreamResponse {
    proto::StreamResponse {
        message: Some(proto::stream_response::Message::Event(
            proto::SessionEvent {
                kind: kind as i32,
                session_id: session.to_string(),
                detail: detail.into(),
                stamp_ns,
                count,
            },
        )),
    }
}

/// How an open message asks for a session.
pub struct OpenRequest {
    /// Robot id.
    pub robot_id: String,
    /// Task.
    pub task: String,
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
}

/// A session place held for an episode while its upload is read
/// ([`Hub::reserve_session`]): [`Hub::open`] with it never finds the server full;
/// dropped unused, it frees the place.
pub struct SessionSlot {
    reserved: Arc<AtomicUsize>,
}

impl Drop for SessionSlot {
    fn drop(&mut self) {
        self.reserved.fetch_sub(1, Ordering::SeqCst);
    }
}

/// The sessions and the worker pool.
pub struct Hub {
    config: ServiceConfig,
    metrics: Metrics,
    sessions: Mutex<HashMap<String, Arc<Session>>>,
    ready: Mutex<VecDeque<Arc<Session>>>,
    work: Condvar,
    stopping: AtomicBool,
    next_id: AtomicU64,
    workers: Mutex<Vec<std::thread::JoinHandle<()>>>,
    /// Workers running (a panicking one restarts; it is counted out only when it ends).
    live_workers: AtomicUsize,
    /// Session places held by [`SessionSlot`]s.
    reserved: Arc<AtomicUsize>,
    /// Memory the clients can make the server hold.
    budget: Arc<ByteBudget>,
    /// Test hooks: the next frames scored panic; the next worker turns panic outside a
    /// frame.
    injected_frame_panics: AtomicU64,
    injected_worker_panics: AtomicU64,
}

impl Hub {
    /// Starts the worker pool.
    pub fn start(config: ServiceConfig, metrics: Metrics) -> Arc<Self> {
        let n = if config.workers == 0 {
            std::thread::available_parallelism().map_or(2, |n| n.get())
        } else {
            config.workers
        };
        let limit = match config.memory_budget_mb {
            0 => super::budget::default_limit(),
            mb => mb << 20,
        };
        let budget = ByteBudget::new("memory budget", limit, metrics.memory_budget_used.clone());
        tracing::info!(
            memory_budget_mib = limit >> 20,
            "memory budget for buffered client data"
        );
        let hub = Arc::new(Self {
            budget,
            live_workers: AtomicUsize::new(0),
            reserved: Arc::new(AtomicUsize::new(0)),
            injected_frame_panics: AtomicU64::new(0),
            injected_worker_panics: AtomicU64::new(0),
            config,
            metrics,
            sessions: Mutex::new(HashMap::new()),
            ready: Mutex::new(VecDeque::new()),
            work: Condvar::new(),
            stopping: AtomicBool::new(false),
            next_id: AtomicU64::new(1),
            workers: Mutex::new(Vec::new()),
        });
        let mut handles = Vec::new();
        for i in 0..n {
            let h = hub.clone();
            hub.live_workers.fetch_add(1, Ordering::SeqCst);
            hub.metrics.workers_alive.inc();
            match std::thread::Builder::new()
                .name(format!("vamos-worker-{i}"))
                .spawn(move || h.supervised_worker(i))
            {
                Ok(handle) => handles.push(handle),
                Err(e) => {
                    hub.live_workers.fetch_sub(1, Ordering::SeqCst);
                    hub.metrics.workers_alive.dec();
                    tracing::error!("cannot start worker {i}: {e}");
                }
            }
        }
        tracing::info!(workers = handles.len(), "scoring workers started");
        *lock(&hub.workers) = handles;
        hub
    }

    /// The settings.
    pub fn config(&self) -> &ServiceConfig {
        &self.config
    }

    /// The metrics.
    pub fn metrics(&self) -> &Metrics {
        &self.metrics
    }

    /// The server's memory budget for client data.
    pub fn budget(&self) -> &Arc<ByteBudget> {
        &self.budget
    }

    /// Scoring workers running: 0 means nothing can be scored (health says so).
    pub fn live_workers(&self) -> usize {
        self.live_workers.load(Ordering::SeqCst)
    }

    /// Test hook: the next `frames` frames scored panic inside the scorer's turn.
    #[doc(hidden)]
    pub fn inject_frame_panics(&self, frames: u64) {
        self.injected_frame_panics.store(frames, Ordering::SeqCst);
    }

    /// Test hook: the next `turns` worker turns panic outside any frame (the worker
    /// itself fails and is restarted).
    #[doc(hidden)]
    pub fn inject_worker_panics(&self, turns: u64) {
        self.injected_worker_panics.store(turns, Ordering::SeqCst);
        self.work.notify_all();
    }

    fn take_injected(counter: &AtomicU64) -> bool {
        counter
            .fetch_update(Ordering::SeqCst, Ordering::SeqCst, |n| n.checked_sub(1))
            .is_ok()
    }

    /// Opens (or resumes) a session whose scores go to `out`. Returns the session and
    /// whether it was resumed.
    pub fn open(
        &self,
        profile: Arc<LoadedProfile>,
        req: OpenRequest,
        out: Outbound,
    ) -> Result<(Arc<Session>, bool), OpenError> {
        if self.stopping.load(Ordering::SeqCst) {
            return Err(OpenError::ShuttingDown);
        }
        let id = req.session_id.trim().to_string();
        if id.len() > 128 || id.chars().any(|c| c.is_control()) {
            return Err(OpenError::BadId("at most 128 printable characters".into()));
        }
        let mut sessions = lock(&self.sessions);
        if !id.is_empty()
            && let Some(s) = sessions.get(&id)
        {
            if s.profile_name != profile.name {
                return Err(OpenError::ProfileMismatch {
                    id,
                    profile: s.profile_name.clone(),
                });
            }
            let mut st = lock(&s.state);
            if st.detached_since.is_none() || st.closed {
                return Err(OpenError::Busy { id });
            }
            st.detached_since = None;
            st.out = Some(out);
            st.last_activity = Instant::now();
            drop(st);
            tracing::info!(session = %id, "session resumed");
            return Ok((s.clone(), true));
        }
        // An episode whose place was reserved before its upload was read has it.
        let slot = req.slot;
        if slot.is_none()
            && sessions.len() + self.reserved.load(Ordering::SeqCst) >= self.config.max_sessions
        {
            self.metrics
                .sessions_opened
                .with_label_values(&[&profile.name, "refused"])
                .inc();
            return Err(OpenError::TooMany {
                max: self.config.max_sessions,
            });
        }
        let resumable = !id.is_empty();
        let id = if resumable {
            id
        } else {
            format!(
                "s{}-{:x}",
                self.next_id.fetch_add(1, Ordering::Relaxed),
                std::time::SystemTime::now()
                    .duration_since(std::time::UNIX_EPOCH)
                    .map_or(0, |d| d.as_nanos() as u64 & 0xffff_ffff)
            )
        };
        let seed_key = req.seed_key.unwrap_or_else(|| id.clone());
        let scorer = profile
            .setup
            .calibrated_scorer(&seed_key, false)
            .map_err(|e| OpenError::Scorer(e.to_string()))?;
        let session = Arc::new(Session {
            id: id.clone(),
            robot_id: req.robot_id,
            task: req.task,
            resumable,
            episode: req.episode,
            needs_joints: AtomicBool::new(profile.setup.robot.is_some()),
            reloads: AtomicU64::new(0),
            seed_key,
            profile_name: profile.name.clone(),
            camera: req.camera,
            opened: Instant::now(),
            state: Mutex::new(SessionState {
                pending: VecDeque::new(),
                queue: VecDeque::new(),
                scheduled: false,
                joints: JointBuffer::default(),
                joint_charge: self.budget.empty(),
                last_image_ns: None,
                newest_ns: i64::MIN,
                out: Some(out),
                finishing: false,
                closed: false,
                detached_since: None,
                last_activity: Instant::now(),
                phase: None,
                latest: None,
                images: 0,
                warm_reported: false,
            }),
            space: Condvar::new(),
            scorer: Mutex::new(scorer),
            frames_scored: AtomicU64::new(0),
            dropped: AtomicU64::new(0),
            anomalies: AtomicU64::new(0),
            profile: Mutex::new(profile),
        });
        sessions.insert(id.clone(), session.clone());
        // The place is the session's now (the table's lock is still held).
        drop(slot);
        self.metrics
            .sessions_active
            .with_label_values(&[&session.profile_name])
            .inc();
        self.metrics
            .sessions_opened
            .with_label_values(&[&session.profile_name, "ok"])
            .inc();
        tracing::info!(session = %id, robot = %session.robot_id, profile = %session.profile_name, "session opened");
        Ok((session, false))
    }

    /// Reserves a session place for an episode before its upload is read, so a full
    /// server refuses it before a byte is buffered.
    pub fn reserve_session(&self) -> Result<SessionSlot, OpenError> {
        if self.stopping.load(Ordering::SeqCst) {
            return Err(OpenError::ShuttingDown);
        }
        let sessions = lock(&self.sessions);
        if sessions.len() + self.reserved.load(Ordering::SeqCst) >= self.config.max_sessions {
            return Err(OpenError::TooMany {
                max: self.config.max_sessions,
            });
        }
        self.reserved.fetch_add(1, Ordering::SeqCst);
        Ok(SessionSlot {
            reserved: self.reserved.clone(),
        })
    }

    /// Sessions, sorted by id.
    pub fn sessions(&self) -> Vec<SessionSummary> {
        let sessions: Vec<Arc<Session>> = lock(&self.sessions).values().cloned().collect();
        let mut out: Vec<SessionSummary> = sessions.iter().map(|s| s.summary()).collect();
        out.sort_by(|a, b| a.id.cmp(&b.id));
        out
    }

    /// The open session `id` (streaming, detached or an episode upload).
    pub fn session(&self, id: &str) -> Option<Arc<Session>> {
        lock(&self.sessions).get(id).cloned()
    }

    /// Moves session `s` to `profile` (the same profile as stored now: another model
    /// version, thresholds or calibration) from its next frame on. The new scorer starts
    /// with an empty history, so the flow predictor warms up again (`warming_up` is
    /// reported anew); frames already queued are scored by the new scorer. The client
    /// gets a `KIND_RELOADED` event naming the new model. Refused for another profile's
    /// name and for a closed session.
    pub fn reload(&self, s: &Arc<Session>, profile: Arc<LoadedProfile>) -> Result<(), OpenError> {
        if profile.name != s.profile_name {
            return Err(OpenError::ProfileMismatch {
                id: s.id.clone(),
                profile: s.profile_name.clone(),
            });
        }
        let mut scorer = profile
            .setup
            .calibrated_scorer(&s.seed_key, false)
            .map_err(|e| OpenError::Scorer(e.to_string()))?;
        if lock(&s.state).closed {
            return Err(OpenError::Scorer(format!("session {:?} is closed", s.id)));
        }
        let model = profile.model_label.clone();
        {
            // The scorer's lock first: a worker scoring a frame finishes it with the old
            // scorer, the next frame sees the new one.
            let mut current = lock(&s.scorer);
            scorer.continue_after(&current);
            *current = scorer;
            s.needs_joints
                .store(profile.setup.robot.is_some(), Ordering::Relaxed);
            *lock(&s.profile) = profile;
        }
        lock(&s.state).warm_reported = false;
        let n = s.reloads.fetch_add(1, Ordering::Relaxed) + 1;
        tracing::info!(session = %s.id, model = %model, reloads = n, "session reloaded");
        self.send(
            s,
            event(
                &s.id,
                proto::session_event::Kind::Reloaded,
                format!("session {} profile {} model {model}", s.id, s.profile_name),
                0,
                n,
            ),
        );
        Ok(())
    }

    /// Number of open sessions.
    pub fn session_count(&self) -> usize {
        lock(&self.sessions).len()
    }

    fn send(&self, s: &Session, msg: proto::StreamResponse) {
        let out = lock(&s.state).out.clone();
        if let Some(out) = out
            && out.try_send(Ok(msg)).is_err()
        {
            s.dropped.fetch_add(1, Ordering::Relaxed);
            self.metrics
                .drops
                .with_label_values(&[&s.profile_name, "undelivered"])
                .inc();
        }
    }

    fn message_error(&self, s: &Session, kind: &str, detail: String, stamp_ns: i64) {
        tracing::debug!(session = %s.id, kind, "{detail}");
        self.metrics
            .message_errors
            .with_label_values(&[&s.profile_name, kind])
            .inc();
        self.send(
            s,
            event(
                &s.id,
                proto::session_event::Kind::MessageError,
                detail,
                stamp_ns,
                0,
            ),
        );
    }

    /// An image that will not be scored: counted as dropped (`bad_message`) and
    /// reported to the client.
    fn refuse(&self, s: &Session, kind: &str, detail: String, stamp_ns: i64) {
        s.dropped.fetch_add(1, Ordering::Relaxed);
        self.metrics
            .drops
            .with_label_values(&[&s.profile_name, "bad_message"])
            .inc();
        self.message_error(s, kind, detail, stamp_ns);
    }

    /// An image not buffered because the server's memory budget is spent: counted as
    /// dropped (`memory_budget`) and reported to the client.
    fn refuse_for_memory(&self, s: &Session, detail: String, stamp_ns: i64) {
        s.dropped.fetch_add(1, Ordering::Relaxed);
        self.metrics
            .drops
            .with_label_values(&[&s.profile_name, "memory_budget"])
            .inc();
        self.message_error(s, "memory", detail, stamp_ns);
    }

    /// An image of a live session.
    pub fn image(&self, s: &Arc<Session>, image: proto::Image) {
        let stamp = image.stamp_ns;
        let mut st = lock(&s.state);
        st.last_activity = Instant::now();
        st.images += 1;
        if let Some(last) = st.last_image_ns
            && stamp <= last
        {
            drop(st);
            self.refuse(
                s,
                "stamp",
                format!("image stamp {stamp} ns is not after the previous image ({last} ns): image dropped"),
                stamp,
            );
            return;
        }
        let charge = match self.budget.charge(image.data.len() as u64 + FRAME_OVERHEAD) {
            Ok(c) => c,
            Err(e) => {
                drop(st);
                self.refuse_for_memory(s, format!("image at {stamp} ns dropped: {e}"), stamp);
                return;
            }
        };
        st.last_image_ns = Some(stamp);
        st.newest_ns = st.newest_ns.max(stamp);
        st.pending.push_back(ReadyFrame {
            stamp_ns: stamp,
            image: ImagePayload::Message(image),
            joints: None,
            arrived: Instant::now(),
            charge: Some(charge),
        });
        let released = self.release(s, &mut st, false);
        drop(st);
        self.after_release(s, released);
    }

    /// A joint state of a live session.
    pub fn joints(&self, s: &Arc<Session>, j: proto::JointState) {
        let stamp = j.stamp_ns;
        let mut st = lock(&s.state);
        st.last_activity = Instant::now();
        if j.names.len() > self.config.max_joints {
            drop(st);
            let e = format!(
                "joint state refused: {} joints (at most {}, [service] max_joints)",
                j.names.len(),
                self.config.max_joints
            );
            self.message_error(s, "joints", e, stamp);
            return;
        }
        // The buffer's growth is checked against the session's cap and charged to the
        // server's budget before it happens.
        let g = &mut *st;
        let now = g.joints.bytes();
        let cost = g.joints.push_cost(&j.names);
        let limit = self.config.max_joint_buffer_bytes;
        let refused = if now + cost > limit {
            Some((
                "memory",
                format!(
                    "joint state refused: the session's joint buffer holds {now} bytes (at \
                     most {limit}, [service] max_joint_buffer_bytes); joint states run far \
                     ahead of the images"
                ),
            ))
        } else if let Err(e) = g.joint_charge.resize(now + cost) {
            Some(("memory", format!("joint state refused: {e}")))
        } else if let Err(e) = g.joints.push(stamp, j.names, j.positions) {
            Some(("joints", format!("joint state refused: {e}")))
        } else {
            None
        };
        if let Some((kind, detail)) = refused {
            let _ = g.joint_charge.resize(g.joints.bytes());
            drop(st);
            self.message_error(s, kind, detail, stamp);
            return;
        }
        // Samples no waiting image can need, beyond the window, are forgotten.
        let window_ns = (self.config.joint_buffer_s.max(0.0) * 1e9) as i64;
        let horizon = stamp.saturating_sub(window_ns);
        let keep = st
            .pending
            .front()
            .map_or(horizon, |f| f.stamp_ns.min(horizon));
        st.joints.trim_before(keep);
        let bytes = st.joints.bytes();
        let _ = st.joint_charge.resize(bytes);
        st.newest_ns = st.newest_ns.max(stamp);
        let released = self.release(s, &mut st, false);
        drop(st);
        self.after_release(s, released);
    }

    /// A phase marker of a live session.
    pub fn phase(&self, s: &Arc<Session>, p: proto::PhaseMarker) {
        {
            let mut st = lock(&s.state);
            st.last_activity = Instant::now();
            st.phase = Some(p.phase.clone());
        }
        tracing::info!(session = %s.id, phase = %p.phase, "phase");
        self.send(
            s,
            event(
                &s.id,
                proto::session_event::Kind::Phase,
                p.phase,
                p.stamp_ns,
                0,
            ),
        );
    }

    /// Moves pending images whose joint states are known (or waited for long enough in
    /// stamp time or in wall time, or `flush`) into the queue. Returns how many images the queue policy dropped and
    /// whether the session must be scheduled.
    fn release(&self, s: &Session, st: &mut SessionState, flush: bool) -> (u64, u64, bool) {
        let wait_ns = (self.config.joint_wait_ms * 1e6) as i64;
        let wait = Duration::from_secs_f64(self.config.joint_wait_ms.max(0.0) * 1e-3);
        let mut dropped = 0;
        let mut rejected = 0;
        while let Some(front) = st.pending.front() {
            let t = front.stamp_ns;
            // A session may keep a few queues' worth of images waiting for joints; past
            // that the oldest goes on with the joint states known.
            let ready = !s.needs_joints()
                || flush
                || st.pending.len() > 4 * self.config.queue_depth.max(1)
                || st.joints.newest_ns().is_some_and(|n| n >= t)
                || st.newest_ns.saturating_sub(t) > wait_ns
                || front.arrived.elapsed() > wait;
            if !ready {
                break;
            }
            let Some(mut frame) = st.pending.pop_front() else {
                break;
            };
            if s.needs_joints() {
                frame.joints = st.joints.at(t);
                st.joints.trim_before(t);
                let _ = st.joint_charge.resize(st.joints.bytes());
            }
            if st.queue.len() >= self.config.queue_depth.max(1) {
                match self.config.queue_policy {
                    QueuePolicy::DropOldest => {
                        st.queue.pop_front();
                        self.metrics.queue_depth.dec();
                        dropped += 1;
                    }
                    QueuePolicy::Reject => {
                        rejected += 1;
                        continue;
                    }
                }
            }
            st.queue.push_back(frame);
            self.metrics.queue_depth.inc();
        }
        let schedule = !st.queue.is_empty() && !st.scheduled;
        if schedule {
            st.scheduled = true;
        }
        (dropped, rejected, schedule)
    }

    fn after_release(&self, s: &Arc<Session>, (dropped, rejected, schedule): (u64, u64, bool)) {
        for (n, reason) in [(dropped, "queue_full"), (rejected, "rejected")] {
            if n == 0 {
                continue;
            }
            let total = s.dropped.fetch_add(n, Ordering::Relaxed) + n;
            self.metrics
                .drops
                .with_label_values(&[&s.profile_name, reason])
                .inc_by(n);
            self.send(
                s,
                event(
                    &s.id,
                    proto::session_event::Kind::FramesDropped,
                    format!(
                        "{n} image(s) {}: the session queue ({} images) is full",
                        if reason == "rejected" {
                            "rejected"
                        } else {
                            "dropped (oldest first)"
                        },
                        self.config.queue_depth
                    ),
                    0,
                    total,
                ),
            );
        }
        if schedule {
            lock(&self.ready).push_back(s.clone());
            self.work.notify_one();
        }
    }

    /// Queues a decoded frame of an episode, waiting while the queue is full. Returns
    /// false when the session was closed.
    pub fn push_blocking(&self, s: &Arc<Session>, frame: ReadyFrame) -> bool {
        let mut st = lock(&s.state);
        while st.queue.len() >= self.config.queue_depth.max(1) && !st.closed {
            st = s.space.wait(st).unwrap_or_else(|e| e.into_inner());
        }
        if st.closed {
            return false;
        }
        st.images += 1;
        st.queue.push_back(frame);
        self.metrics.queue_depth.inc();
        let schedule = !st.scheduled;
        st.scheduled = true;
        drop(st);
        self.after_release(s, (0, 0, schedule));
        true
    }

    /// Whether the session is closed.
    pub fn is_closed(&self, s: &Session) -> bool {
        lock(&s.state).closed
    }

    /// Blocks until the session is closed.
    pub fn wait_closed(&self, s: &Session) {
        let mut st = lock(&s.state);
        while !st.closed {
            st = s
                .space
                .wait_timeout(st, Duration::from_millis(100))
                .map_or_else(|e| e.into_inner().0, |r| r.0);
        }
    }

    /// The client ended its stream: pending images are scored with the joint states
    /// known, then the stream closes.
    pub fn finish(&self, s: &Arc<Session>) {
        let mut st = lock(&s.state);
        st.finishing = true;
        let released = self.release(s, &mut st, true);
        let done = st.queue.is_empty() && !st.scheduled && !released.2;
        drop(st);
        self.after_release(s, released);
        if done {
            self.close(s, None);
        }
    }

    /// The client's stream broke: a resumable session waits `resume_window_s` for its
    /// client, others close.
    pub fn detach(&self, s: &Arc<Session>) {
        if s.resumable && !self.stopping.load(Ordering::SeqCst) {
            let mut st = lock(&s.state);
            st.detached_since = Some(Instant::now());
            st.out = None;
            tracing::info!(session = %s.id, "stream lost: session kept for resumption");
        } else {
            self.close(s, None);
        }
    }

    /// Closes a session: `status` ends its stream with an error (else OK), waiting frames
    /// are discarded.
    pub fn close(&self, s: &Arc<Session>, status: Option<Status>) {
        let out = {
            let mut st = lock(&s.state);
            if st.closed {
                return;
            }
            st.closed = true;
            let n = (st.queue.len() + st.pending.len()) as i64;
            st.queue.clear();
            st.pending.clear();
            self.metrics
                .queue_depth
                .sub(n.min(self.metrics.queue_depth.get()));
            st.out.take()
        };
        s.space.notify_all();
        // The session leaves the table before its stream ends, so a client that sees
        // the end of its stream never finds the session still listed.
        if lock(&self.sessions).remove(&s.id).is_some() {
            self.metrics
                .sessions_active
                .with_label_values(&[&s.profile_name])
                .dec();
        }
        if let (Some(out), Some(status)) = (out.as_ref(), status) {
            let _ = out.try_send(Err(status));
        }
        drop(out);
        tracing::info!(
            session = %s.id,
            frames = s.frames_scored.load(Ordering::Relaxed),
            dropped = s.dropped.load(Ordering::Relaxed),
            "session closed"
        );
    }

    /// Releases images that waited `joint_wait_ms` (wall time) for a joint state; closes
    /// detached sessions past their resume window and sessions too old. Returns the
    /// sessions closed.
    pub fn sweep(&self) -> usize {
        let window = Duration::from_secs_f64(self.config.resume_window_s.max(0.0));
        let max_age = Duration::from_secs_f64(self.config.max_session_s.max(0.0));
        let sessions: Vec<Arc<Session>> = lock(&self.sessions).values().cloned().collect();
        let mut closed = 0;
        for s in sessions {
            let (expired, released) = {
                let mut st = lock(&s.state);
                let released = if st.closed || st.finishing {
                    (0, 0, false)
                } else {
                    self.release(&s, &mut st, false)
                };
                (
                    st.detached_since.is_some_and(|t| t.elapsed() > window),
                    released,
                )
            };
            self.after_release(&s, released);
            if expired {
                self.close(&s, None);
                closed += 1;
            } else if s.age() > max_age {
                self.close(
                    &s,
                    Some(Status::deadline_exceeded(format!(
                        "session exceeded the maximum length of {} s",
                        self.config.max_session_s
                    ))),
                );
                closed += 1;
            }
        }
        closed
    }

    /// Stops taking sessions; waits up to `grace` for queued frames; closes every
    /// session with UNAVAILABLE; stops the workers.
    pub fn shutdown(&self, grace: Duration) {
        self.stopping.store(true, Ordering::SeqCst);
        let sessions: Vec<Arc<Session>> = lock(&self.sessions).values().cloned().collect();
        for s in &sessions {
            let mut st = lock(&s.state);
            st.finishing = true;
            let released = self.release(s, &mut st, true);
            drop(st);
            self.after_release(s, released);
        }
        let deadline = Instant::now() + grace;
        while Instant::now() < deadline {
            let busy = sessions.iter().any(|s| {
                let st = lock(&s.state);
                !st.closed && (st.scheduled || !st.queue.is_empty())
            });
            if !busy {
                break;
            }
            std::thread::sleep(Duration::from_millis(10));
        }
        for s in &sessions {
            self.close(s, Some(Status::unavailable("the server is shutting down")));
        }
        self.work.notify_all();
        let handles = std::mem::take(&mut *lock(&self.workers));
        for h in handles {
            let _ = h.join();
        }
    }

    /// A worker thread: [`Self::worker`] restarted after any panic that escapes a frame,
    /// until the hub stops.
    fn supervised_worker(self: &Arc<Self>, i: usize) {
        loop {
            match catch_unwind(AssertUnwindSafe(|| self.worker())) {
                Ok(()) => break,
                Err(panic) => {
                    self.metrics.worker_restarts.inc();
                    tracing::error!(
                        worker = i,
                        "scoring worker panicked ({}); restarted",
                        panic_message(panic.as_ref())
                    );
                }
            }
        }
        self.live_workers.fetch_sub(1, Ordering::SeqCst);
        self.metrics.workers_alive.dec();
    }

    fn worker(&self) {
        loop {
            if Self::take_injected(&self.injected_worker_panics) {
                panic!("injected worker panic");
            }
            let session = {
                let mut ready = lock(&self.ready);
                loop {
                    if let Some(s) = ready.pop_front() {
                        break s;
                    }
                    if self.stopping.load(Ordering::SeqCst) && self.session_count() == 0 {
                        return;
                    }
                    ready = self
                        .work
                        .wait_timeout(ready, Duration::from_millis(200))
                        .map_or_else(|e| e.into_inner().0, |r| r.0);
                    if self.stopping.load(Ordering::SeqCst) && ready.is_empty() {
                        return;
                    }
                }
            };
            let frame = {
                let mut st = lock(&session.state);
                let f = st.queue.pop_front();
                if f.is_some() {
                    self.metrics.queue_depth.dec();
                }
                f
            };
            session.space.notify_all();
            if let Some(frame) = frame {
                let stamp = frame.stamp_ns;
                if let Err(panic) = catch_unwind(AssertUnwindSafe(|| self.score(&session, frame))) {
                    self.recover(&session, stamp, panic_message(panic.as_ref()));
                }
            }
            let mut st = lock(&session.state);
            if !st.queue.is_empty() && !st.closed {
                drop(st);
                lock(&self.ready).push_back(session);
                self.work.notify_one();
            } else {
                st.scheduled = false;
                let done = st.finishing && st.pending.is_empty() && !st.closed;
                drop(st);
                if done {
                    self.close(&session, None);
                }
            }
        }
    }

    /// After a panic while scoring frame `stamp` of `s`: the frame is reported failed,
    /// the session's scorer (whose state the panic may have left half-updated) is
    /// rebuilt from its profile, continuing its indices, and the session goes on.
    fn recover(&self, s: &Arc<Session>, stamp: i64, what: String) {
        self.metrics
            .scoring_panics
            .with_label_values(&[&s.profile_name])
            .inc();
        tracing::error!(session = %s.id, stamp_ns = stamp, "scoring panicked: {what}");
        let profile = s.profile();
        let rebuilt = match profile.setup.calibrated_scorer(&s.seed_key, false) {
            Ok(mut fresh) => {
                let mut current = lock(&s.scorer);
                fresh.continue_after(&current);
                *current = fresh;
                "its scorer was rebuilt (the flow predictor warms up again)".to_string()
            }
            Err(e) => format!("its scorer could not be rebuilt ({e}) and goes on as it was"),
        };
        lock(&s.state).warm_reported = false;
        self.refuse(
            s,
            "internal",
            format!("frame failed: internal error while scoring it ({what}); {rebuilt}"),
            stamp,
        );
    }

    fn score(&self, s: &Arc<Session>, frame: ReadyFrame) {
        let stamp = frame.stamp_ns;
        let started = Instant::now();
        // Held until the frame is scored: the buffered bytes, then the decoding's.
        let _buffered = frame.charge;
        let (image, frame_camera, _decoding) = match frame.image {
            ImagePayload::Decoded(img, k) => (img, k, None),
            ImagePayload::Message(msg) => {
                match decode_image(&msg, self.config.max_image_pixels, Some(&self.budget)) {
                    Ok((img, charge)) => (img, None, charge),
                    Err(e) => {
                        self.refuse(s, "image", format!("image refused: {e}"), stamp);
                        return;
                    }
                }
            }
        };
        if Self::take_injected(&self.injected_frame_panics) {
            panic!("injected scoring panic");
        }
        let decode_s = started.elapsed().as_secs_f64();
        let intrinsics = frame_camera.or_else(|| {
            s.camera.and_then(|k| {
                // The open message's camera at the image's resolution.
                (k.width as usize == image.width() && k.height as usize == image.height())
                    .then_some(k)
            })
        });
        let joints = frame.joints.as_ref().map(|(n, p)| JointInput {
            names: n,
            positions: p,
        });
        let result = lock(&s.scorer).push(&FrameInput {
            stamp_ns: stamp,
            image: &image,
            joints,
            intrinsics: intrinsics.as_ref(),
        });
        match result {
            Ok(Some(score)) => self.deliver(s, &score, frame.arrived, started, decode_s),
            Ok(None) => {}
            Err(e) => self.refuse(s, "frame", format!("frame refused: {e}"), stamp),
        }
    }

    fn deliver(
        &self,
        s: &Arc<Session>,
        score: &FrameScore,
        arrived: Instant,
        started: Instant,
        decode_s: f64,
    ) {
        let m = &self.metrics;
        let profile = s.profile_name.as_str();
        m.frames.with_label_values(&[profile]).inc();
        s.frames_scored.fetch_add(1, Ordering::Relaxed);
        let t = &score.timings;
        let us = |v: u64| v as f64 * 1e-6;
        for (stage, v) in [
            ("decode", decode_s),
            ("kinematics", us(t.kinematics_us)),
            ("render", us(t.render_us)),
            ("flow", us(t.front_end.flow_us)),
            ("registration", us(t.front_end.registration_us)),
            ("camera", us(t.camera_us)),
            ("body", us(t.body_us)),
            ("model", us(t.model_us)),
            ("total", us(t.total_us)),
        ] {
            m.stage_seconds.with_label_values(&[stage]).observe(v);
        }
        let current = s.profile();
        if current.setup.model.is_some() {
            m.inference_seconds
                .with_label_values(&[&current.model_label])
                .observe(us(t.model_us));
        }
        let detector = match score.triggered {
            Some(Detector::Camera) => proto::Detector::Camera,
            Some(Detector::Body) => proto::Detector::Body,
            Some(Detector::Flow) => proto::Detector::Flow,
            Some(Detector::Scene) => proto::Detector::Scene,
            None if score.anomaly => proto::Detector::Flow,
            None => proto::Detector::Unspecified,
        };
        if score.anomaly {
            s.anomalies.fetch_add(1, Ordering::Relaxed);
            let label = match detector {
                proto::Detector::Camera => "camera",
                proto::Detector::Body => "body",
                proto::Detector::Scene => "scene",
                _ => "flow",
            };
            m.anomalies.with_label_values(&[profile, label]).inc();
        }
        let warm_event = {
            let mut st = lock(&s.state);
            st.latest = Some(LatestScore {
                stamp_ns: score.stamp_ns,
                score: score.score,
                anomaly: score.anomaly,
            });
            let first = score.warming_up && !st.warm_reported;
            if first {
                st.warm_reported = true;
            }
            first
        };
        if warm_event {
            self.send(
                s,
                event(
                    &s.id,
                    proto::session_event::Kind::WarmingUp,
                    "the flow predictor is collecting its history: scores use e_c and e_b only",
                    score.stamp_ns,
                    0,
                ),
            );
        }
        // One clock reading for both, so compute time never exceeds latency.
        let now = Instant::now();
        let latency = now.saturating_duration_since(arrived).as_secs_f64();
        m.latency_seconds
            .with_label_values(&[profile])
            .observe(latency);
        let msg = proto::FrameScore {
            stamp_ns: score.stamp_ns,
            index: score.index,
            frame: score.frame,
            score: score.score,
            e_c: score.e_c,
            e_b: score.e_b,
            e_o: score.e_o,
            e_r: score.e_r,
            anomaly: score.anomaly,
            detector: detector as i32,
            warming_up: score.warming_up,
            latency_s: latency,
            compute_s: now.saturating_duration_since(started).as_secs_f64(),
        };
        self.send(
            s,
            proto::StreamResponse {
                message: Some(proto::stream_response::Message::Score(msg)),
            },
        );
    }
}

/// The text of a caught panic's payload.
fn panic_message(panic: &(dyn std::any::Any + Send)) -> String {
    panic
        .downcast_ref::<&str>()
        .map(|s| s.to_string())
        .or_else(|| panic.downcast_ref::<String>().cloned())
        .unwrap_or_else(|| "a panic without a message".into())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn joint_buffer_interpolates_per_group_and_refuses_bad_samples() {
        let mut b = JointBuffer::default();
        let arm = vec!["a".to_string(), "b".to_string()];
        let head = vec!["h".to_string()];
        b.push(0, arm.clone(), vec![0.0, 10.0]).unwrap();
        b.push(100, arm.clone(), vec![1.0, 20.0]).unwrap();
        b.push(50, head.clone(), vec![5.0]).unwrap();
        assert_eq!(b.newest_ns(), Some(50));
        let (names, pos) = b.at(25).unwrap();
        assert_eq!(names, vec!["a", "b", "h"]);
        assert_eq!(pos, vec![0.25, 12.5, 5.0]);
        assert!(b.push(100, arm.clone(), vec![0.0, 0.0]).is_err());
        assert!(b.push(200, arm.clone(), vec![f64::NAN, 0.0]).is_err());
        assert!(b.push(200, arm.clone(), vec![0.0]).is_err());
        b.push(200, arm.clone(), vec![2.0, 30.0]).unwrap();
        b.trim_before(150);
        // The sample before 150 (t = 100) stays as the left neighbour.
        assert_eq!(b.groups[0].stamps_ns, vec![100, 200]);
        assert_eq!(b.at(150).unwrap().1[..2], [1.5, 25.0]);
    }
}
