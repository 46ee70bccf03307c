//! The hub: the table of sessions and their lifecycle (open, resume, reload, close,
//! sweep, shutdown) and the worker pool that scores them. What a live session receives
//! is in [`super::input`], the workers' turn in [`super::worker`].
//!
//! A session owns a [`Scorer`](vamos_core::pipeline::Scorer), a buffer of joint states, the images waiting for a joint
//! state at or after their stamp (so they can be interpolated as offline scoring does),
//! and a bounded queue of frames ready to score. One pool of worker threads serves all
//! sessions: a session with work waits in one FIFO of ready sessions, a worker takes one
//! frame of the session at its head and puts the session back at the tail if more wait.
//! So sessions are served round-robin, one frame each, a busy robot cannot starve
//! another, and the frames of one session are scored in order by one worker at a time.
//!
//! Output ([`Output`]: scores, events, the error that ends the stream) goes to the
//! session's outbound channel without blocking: a client that does not read loses it
//! (counted as `undelivered`), it never stalls a worker.

use super::budget::ByteBudget;
use super::error::{SessionError, check_label};
use super::event::{Event, EventKind, Outbound, Output};
use super::joints::JointBuffer;
use super::metrics::Metrics;
use super::profiles::LoadedProfile;
use super::state::{OpenRequest, Session, SessionSlot, SessionState, SessionSummary, lock};
use crate::config::ServiceConfig;
use std::collections::{HashMap, VecDeque};
use std::sync::atomic::{AtomicBool, AtomicU64, AtomicUsize, Ordering};
use std::sync::{Arc, Condvar, Mutex};
use std::time::{Duration, Instant};

/// The sessions and the worker pool.
pub struct Hub {
    pub(super) config: ServiceConfig,
    pub(super) metrics: Metrics,
    pub(super) sessions: Mutex<HashMap<String, Arc<Session>>>,
    pub(super) ready: Mutex<VecDeque<Arc<Session>>>,
    pub(super) work: Condvar,
    pub(super) stopping: AtomicBool,
    pub(super) next_id: AtomicU64,
    pub(super) workers: Mutex<Vec<std::thread::JoinHandle<()>>>,
    /// Workers running (a panicking one restarts; it is counted out only when it ends).
    pub(super) live_workers: AtomicUsize,
    /// Session places held by [`SessionSlot`]s.
    pub(super) reserved: Arc<AtomicUsize>,
    /// Memory the clients can make the server hold.
    pub(super) budget: Arc<ByteBudget>,
    /// Test hooks: the next frames scored panic; the next worker turns panic outside a
    /// frame.
    pub(super) injected_frame_panics: AtomicU64,
    pub(super) injected_worker_panics: AtomicU64,
    /// The recent alarms of every session.
    pub alarms: super::alarms::AlarmBook,
    /// Each robot's last ended live sessions.
    pub history: super::history::History,
    /// The pool's capacity and the live sessions' load.
    pub(super) capacity: super::capacity::Capacity,
}

impl Hub {
    /// The folder of session recordings ([`super::recording`]).
    pub fn recordings_dir(&self) -> std::path::PathBuf {
        self.config.data_dir.join(super::recording::DIR)
    }

    /// A recorder for session `id` when sessions are recorded and the data directory
    /// exists (a server's store makes it; a hub without one records nothing); `None`,
    /// logged, when the recordings' disk is spent.
    fn start_recording(
        &self,
        id: &str,
        topics: &vamos_core::episode::EpisodeTopics,
    ) -> Option<super::recording::Recorder> {
        let c = &self.config;
        if !c.record_sessions || !c.data_dir.is_dir() {
            return None;
        }
        let limits = super::recording::RecordingLimits {
            disk_bytes: c.recordings_disk_mb.saturating_mul(1 << 20),
            session_bytes: c.max_recording_mb.saturating_mul(1 << 20),
        };
        match super::recording::Recorder::start(&self.recordings_dir(), id, topics, limits) {
            Ok(r) => Some(r),
            Err(e) => {
                tracing::warn!(session = %id, "session not recorded: {e}");
                None
            }
        }
    }

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
        let recordings = config.data_dir.join(super::recording::DIR);
        match super::recording::recover_interrupted(&recordings) {
            Ok(0) => {}
            Ok(n) => tracing::warn!(
                recordings = n,
                "recordings left in progress by a server that stopped are kept as finished"
            ),
            Err(e) => tracing::warn!("cannot recover the recordings left in progress: {e}"),
        }
        let capacity = super::capacity::Capacity::new(n, config.admission_load);
        metrics.capacity_cores.set(capacity.capacity_cores());
        let hub = Arc::new(Self {
            budget,
            capacity,
            live_workers: AtomicUsize::new(0),
            reserved: Arc::new(AtomicUsize::new(0)),
            injected_frame_panics: AtomicU64::new(0),
            injected_worker_panics: AtomicU64::new(0),
            alarms: super::alarms::AlarmBook::default(),
            history: super::history::History::new(super::history::HistoryLimits::of(&config)),
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

    pub(super) fn take_injected(counter: &AtomicU64) -> bool {
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
    ) -> Result<(Arc<Session>, bool), SessionError> {
        if self.stopping.load(Ordering::SeqCst) {
            return Err(SessionError::ShuttingDown);
        }
        let id = req.session_id.trim().to_string();
        if id.len() > 128 || id.chars().any(|c| c.is_control()) {
            return Err(SessionError::BadId("at most 128 printable characters"));
        }
        check_label("robot_id", &req.robot_id)?;
        check_label("task", &req.task)?;
        let mut sessions = lock(&self.sessions);
        if !id.is_empty()
            && let Some(s) = sessions.get(&id)
        {
            if s.profile_name != profile.name {
                return Err(SessionError::ProfileMismatch {
                    id,
                    profile: s.profile_name.clone(),
                });
            }
            let mut st = lock(&s.state);
            if st.detached_since.is_none() || st.closed {
                return Err(SessionError::Busy { id });
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
            return Err(SessionError::TooMany {
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
        // A live session's place in the workers' capacity, before the scorer is built:
        // a refusal costs the server nothing (episodes are paced by their queue instead).
        let share = if req.episode {
            Default::default()
        } else {
            self.capacity
                .admit(&profile.name, req.image_rate_hz)
                .map_err(|e| {
                    self.metrics
                        .sessions_opened
                        .with_label_values(&[&profile.name, "refused"])
                        .inc();
                    tracing::warn!(profile = %profile.name, "session refused: {e}");
                    SessionError::OverCapacity(e)
                })?
        };
        self.metrics.load_cores.set(self.capacity.load_cores());
        let seed_key = req.seed_key.unwrap_or_else(|| id.clone());
        let scorer = match profile.setup.calibrated_scorer(&seed_key, req.maps) {
            Ok(s) => s,
            Err(e) => {
                self.capacity.release(&share);
                self.metrics.load_cores.set(self.capacity.load_cores());
                return Err(SessionError::scorer(e));
            }
        };
        let alarm_rule = profile.setup.profile.file.alarm_events;
        let record = !req.episode; // an uploaded episode is its own record
        let session = Arc::new(Session {
            id: id.clone(),
            robot_id: req.robot_id,
            task: req.task,
            opener: req.opener,
            resumable,
            episode: req.episode,
            needs_joints: AtomicBool::new(profile.setup.robot.is_some()),
            reloads: AtomicU64::new(0),
            seed_key,
            profile_name: profile.name.clone(),
            request_id: req.request_id,
            camera: req.camera,
            opened: Instant::now(),
            opened_unix_ms: std::time::SystemTime::now()
                .duration_since(std::time::UNIX_EPOCH)
                .map_or(0, |d| d.as_millis() as u64),
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
                lost: 0,
                load: Default::default(),
            }),
            space: Condvar::new(),
            scorer: Mutex::new(scorer),
            frames_scored: AtomicU64::new(0),
            dropped: AtomicU64::new(0),
            anomalies: AtomicU64::new(0),
            maps: req.maps,
            alarms: Mutex::new(super::alarms::AlarmTracker::new(alarm_rule)),
            live: Mutex::new(super::live::LiveView::default()),
            recorder: Mutex::new(None),
            share,
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
        drop(sessions);
        // The recording starts outside the table's lock (it may prune old recordings);
        // no frame reaches the session before `open` returns.
        if record {
            let profile = session.profile();
            *lock(&session.recorder) = self.start_recording(&id, &profile.setup.episode.topics);
        }
        tracing::info!(session = %id, robot = %session.robot_id, profile = %session.profile_name, "session opened");
        Ok((session, false))
    }

    /// Brings back the ended sessions `store` holds and stores the next ones there
    /// ([`super::history::History::restore`]); returns how many. Blocking (file I/O);
    /// once, at the server's start.
    pub fn restore_ended_sessions(&self, store: &crate::store::Store) -> usize {
        self.history.restore(store, &self.alarms)
    }

    /// Reserves a session place for an episode before its upload is read, so a full
    /// server refuses it before a byte is buffered.
    pub fn reserve_session(&self) -> Result<SessionSlot, SessionError> {
        if self.stopping.load(Ordering::SeqCst) {
            return Err(SessionError::ShuttingDown);
        }
        let sessions = lock(&self.sessions);
        if sessions.len() + self.reserved.load(Ordering::SeqCst) >= self.config.max_sessions {
            return Err(SessionError::TooMany {
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
    pub fn reload(
        &self,
        s: &Arc<Session>,
        profile: Arc<LoadedProfile>,
    ) -> Result<(), SessionError> {
        if profile.name != s.profile_name {
            return Err(SessionError::ProfileMismatch {
                id: s.id.clone(),
                profile: s.profile_name.clone(),
            });
        }
        let mut scorer = profile
            .setup
            .calibrated_scorer(&s.seed_key, s.maps)
            .map_err(SessionError::scorer)?;
        if lock(&s.state).closed {
            return Err(SessionError::Closed { id: s.id.clone() });
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
                EventKind::Reloaded,
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

    pub(super) fn send(&self, s: &Session, msg: Output) {
        let out = lock(&s.state).out.clone();
        if let Some(out) = out
            && out.try_send(msg).is_err()
        {
            s.dropped.fetch_add(1, Ordering::Relaxed);
            self.metrics
                .drops
                .with_label_values(&[&s.profile_name, "undelivered"])
                .inc();
        }
    }

    pub(super) fn message_error(&self, s: &Session, kind: &str, detail: String, stamp_ns: i64) {
        tracing::debug!(session = %s.id, kind, "{detail}");
        self.metrics
            .message_errors
            .with_label_values(&[&s.profile_name, kind])
            .inc();
        self.send(
            s,
            event(&s.id, EventKind::MessageError, detail, stamp_ns, 0),
        );
    }

    /// An image that will not be scored: counted as dropped (`bad_message`) and
    /// reported to the client.
    pub(super) fn refuse(&self, s: &Session, kind: &str, detail: String, stamp_ns: i64) {
        s.dropped.fetch_add(1, Ordering::Relaxed);
        self.metrics
            .drops
            .with_label_values(&[&s.profile_name, "bad_message"])
            .inc();
        self.message_error(s, kind, detail, stamp_ns);
    }

    /// An image not buffered because the server's memory budget is spent: counted as
    /// dropped (`memory_budget`) and reported to the client.
    pub(super) fn refuse_for_memory(&self, s: &Session, detail: String, stamp_ns: i64) {
        s.dropped.fetch_add(1, Ordering::Relaxed);
        self.metrics
            .drops
            .with_label_values(&[&s.profile_name, "memory_budget"])
            .inc();
        self.message_error(s, "memory", detail, stamp_ns);
    }

    /// Closes a session: `error` ends its stream with an error (else it just ends),
    /// waiting frames are discarded. A live session joins its robot's ended sessions
    /// ([`super::history`]) before it leaves the table, so a reader finds it in one or
    /// the other.
    pub fn close(&self, s: &Arc<Session>, error: Option<SessionError>) {
        let out = {
            let mut st = lock(&s.state);
            if st.closed {
                return;
            }
            st.closed = true;
            self.capacity.release(&s.share);
            self.metrics.load_cores.set(self.capacity.load_cores());
            let n = (st.queue.len() + st.pending.len()) as i64;
            st.queue.clear();
            st.pending.clear();
            self.metrics
                .queue_depth
                .sub(n.min(self.metrics.queue_depth.get()));
            st.out.take()
        };
        s.space.notify_all();
        if !s.episode {
            let reason = error.as_ref().map(ToString::to_string);
            self.history
                .insert(super::history::EndedSession::of(s, reason, &self.alarms));
        }
        // The session leaves the table before its stream ends, so a client that sees
        // the end of its stream never finds the session still listed.
        if lock(&self.sessions).remove(&s.id).is_some() {
            self.metrics
                .sessions_active
                .with_label_values(&[&s.profile_name])
                .dec();
        }
        if let (Some(out), Some(error)) = (out.as_ref(), error) {
            let _ = out.try_send(Output::Closed(error));
        }
        drop(out);
        if let Some(recorder) = lock(&s.recorder).take() {
            match recorder.finish() {
                Ok(path) => {
                    tracing::debug!(session = %s.id, recording = %path.display(), "recording finished")
                }
                Err(e) => tracing::warn!(session = %s.id, "the session's recording is lost: {e}"),
            }
        }
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
        self.history.prune();
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
                    Some(SessionError::TooOld {
                        max_s: self.config.max_session_s,
                    }),
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
            self.close(s, Some(SessionError::ShuttingDown));
        }
        // The ended sessions are stored before the process goes.
        self.history.flush();
        self.work.notify_all();
        let handles = std::mem::take(&mut *lock(&self.workers));
        for h in handles {
            let _ = h.join();
        }
    }
}

/// An event of session `session` as output.
pub(super) fn event(
    session: &str,
    kind: EventKind,
    detail: impl Into<String>,
    stamp_ns: i64,
    count: u64,
) -> Output {
    Output::Event(Event {
        kind,
        session_id: session.to_string(),
        detail: detail.into(),
        stamp_ns,
        count,
    })
}
