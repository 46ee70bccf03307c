//! Each robot's last ended live sessions, as the live view shows them after they end:
//! the session's summary, its whole timeline downsampled ([`super::live::Overview`],
//! at most [`super::live::OVERVIEW_POINTS`] points) and its alarms (the last
//! [`ALARMS_PER_SESSION`]), never frames.
//!
//! Bounds: `[service] ended_sessions_per_robot` per robot (at most
//! [`MAX_PER_ROBOT`]), none older than `ended_session_max_age_s`, and
//! [`MAX_ENDED_SESSIONS`] in all (the one that ended first leaves first); so the memory
//! is at most about 50 KiB a session (256 points of 136 bytes, 20 alarm records), 50 MiB
//! in all, whatever the robots send, and the data directory's `ended/` at most about
//! 130 KiB a session (pretty-printed JSON), 130 MiB in all.
//!
//! Persistence: once a store is attached ([`History::restore`]), each ended session is
//! written to the data directory (`ended/<key>.json`, by a writer thread, never on the
//! caller's thread) and removed from it when it leaves; at the next start the records
//! come back with the marks stored since ([`crate::store::Store::marked_alarm`]), and
//! their alarms rejoin the recent alarms so they can be listed and marked. What a
//! restart does not bring back: the alarms' thumbnails, the latest frame and map, and
//! which robot token opened a session (kept in memory only: a restored session is seen
//! by viewers, admins and the tokens issued for its robot, like a stored false alarm).

use super::alarms::AlarmBook;
use super::state::{Session, SessionSummary, lock};
use crate::config::ServiceConfig;
use crate::store::{AlarmRecord, Store};
use serde::{Deserialize, Serialize};
use std::collections::VecDeque;
use std::sync::Mutex;
use std::sync::mpsc::{SyncSender, TrySendError};
use vamos_core::eval::DetectorThresholds;

/// Ended sessions kept in all robots together.
pub const MAX_ENDED_SESSIONS: usize = 1000;

/// The most ended sessions a robot keeps, whatever `ended_sessions_per_robot` says.
pub const MAX_PER_ROBOT: usize = 100;

/// Alarms kept with an ended session (its last ones).
pub const ALARMS_PER_SESSION: usize = 20;

/// Writes waiting for the writer thread; past this many a record is not persisted
/// (logged), the view in memory is unchanged.
const WRITES_WAITING: usize = 256;

/// How many ended sessions are kept, and how long.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HistoryLimits {
    /// Per robot (0: none are kept).
    pub per_robot: usize,
    /// The oldest end kept, seconds ago (0: none are kept).
    pub max_age_s: f64,
}

impl HistoryLimits {
    /// The limits of `[service]` (`ended_sessions_per_robot` at most [`MAX_PER_ROBOT`]).
    pub fn of(config: &ServiceConfig) -> Self {
        Self {
            per_robot: config.ended_sessions_per_robot.min(MAX_PER_ROBOT),
            max_age_s: config.ended_session_max_age_s.max(0.0),
        }
    }

    fn keeps_any(&self) -> bool {
        self.per_robot > 0 && self.max_age_s > 0.0
    }
}

/// An ended live session as kept (and stored).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct EndedSession {
    /// Its store name (`e-<16 hex of the id's sha256>-<opened, ms since the epoch>`).
    pub key: String,
    /// Session id.
    pub id: String,
    /// Robot id.
    pub robot_id: String,
    /// The robot token that opened it (in memory only; `None` once restored).
    #[serde(skip)]
    pub opener: Option<usize>,
    /// Profile.
    pub profile: String,
    /// Model label at its end.
    pub model: String,
    /// Task.
    pub task: String,
    /// Its last phase.
    pub phase: Option<String>,
    /// Images received.
    pub images: u64,
    /// Frames scored.
    pub frames_scored: u64,
    /// Images dropped.
    pub dropped: u64,
    /// Images lost before scored frames.
    pub frames_lost: u64,
    /// Frames flagged anomalous.
    pub anomalies: u64,
    /// Reloads.
    pub reloads: u64,
    /// From open to end, seconds.
    pub duration_s: f64,
    /// Opened, seconds since the Unix epoch.
    pub opened_unix_s: u64,
    /// Ended, seconds since the Unix epoch.
    pub ended_unix_s: u64,
    /// Why it ended (`None`: it finished).
    pub end_reason: Option<String>,
    /// Mean latency over the whole session, seconds.
    pub latency_s: Option<f64>,
    /// Scored frames per second over its timeline's last points (image stamps).
    pub frame_rate_hz: Option<f64>,
    /// The stamp of its first scored frame, nanoseconds.
    pub first_stamp_ns: Option<i64>,
    /// Its last score.
    pub latest: Option<super::state::LatestScore>,
    /// Each detector's threshold in force at its end.
    pub thresholds: DetectorThresholds,
    /// Its whole timeline, downsampled ([`super::live::Overview`]).
    pub points: Vec<super::live::FramePoint>,
    /// Its last [`ALARMS_PER_SESSION`] alarms, newest first.
    pub alarms: Vec<AlarmRecord>,
    /// What its profile could not do ([`SessionSummary::notes`]).
    #[serde(default)]
    pub notes: Vec<String>,
}

impl EndedSession {
    /// What is kept of session `s` as it ends (`reason`: why, `None` when it finished),
    /// with its alarms from `book`.
    pub fn of(s: &Session, reason: Option<String>, book: &AlarmBook) -> Self {
        let summary = s.summary();
        let profile = s.profile();
        let (points, latency_s) = {
            let live = lock(&s.live);
            (live.overview.points(), live.mean_latency_s())
        };
        // Its own alarms: not those of an earlier session that had the same id.
        let mut alarms = book.list(Some(&s.id));
        alarms.retain(|a| a.started_unix_s >= s.opened_unix_ms / 1000);
        alarms.truncate(ALARMS_PER_SESSION);
        let ended_unix_s = crate::store::now_s();
        Self {
            key: key_of(&s.id, s.opened_unix_ms),
            id: summary.id,
            robot_id: summary.robot_id,
            opener: s.opener,
            profile: summary.profile,
            model: summary.model,
            task: summary.task,
            phase: summary.phase,
            images: summary.images,
            frames_scored: summary.frames_scored,
            dropped: summary.dropped,
            frames_lost: summary.frames_lost,
            anomalies: summary.anomalies,
            reloads: summary.reloads,
            duration_s: summary.age_s,
            opened_unix_s: summary.opened_unix_s,
            ended_unix_s,
            end_reason: reason,
            latency_s,
            frame_rate_hz: summary.frame_rate_hz,
            notes: summary.notes,
            first_stamp_ns: summary.first_stamp_ns,
            latest: summary.latest,
            thresholds: profile.setup.detector_thresholds(),
            points,
            alarms,
        }
    }

    /// The session as the REST API lists it (state `ended`).
    pub fn summary(&self) -> SessionSummary {
        SessionSummary {
            id: self.id.clone(),
            robot_id: self.robot_id.clone(),
            profile: self.profile.clone(),
            model: self.model.clone(),
            task: self.task.clone(),
            opener: self.opener,
            phase: self.phase.clone(),
            state: "ended",
            images: self.images,
            frames_scored: self.frames_scored,
            dropped: self.dropped,
            frames_lost: self.frames_lost,
            degraded: self.frames_lost > 0,
            anomalies: self.anomalies,
            queued: 0,
            age_s: self.duration_s,
            opened_unix_s: self.opened_unix_s,
            ended_unix_s: Some(self.ended_unix_s),
            end_reason: self.end_reason.clone(),
            first_stamp_ns: self.first_stamp_ns,
            latest: self.latest,
            reloads: self.reloads,
            alarm_on: false,
            latency_s: self.latency_s,
            frame_rate_hz: self.frame_rate_hz,
            notes: self.notes.clone(),
        }
    }
}

/// The store name of session `id` opened at `opened_ms` (ms since the epoch): at most 35
/// characters of `[0-9a-z-]`, whatever the id.
fn key_of(id: &str, opened_ms: u64) -> String {
    let hash = vamos_model::bundle::sha256_hex(id.as_bytes());
    format!("e-{}-{opened_ms}", &hash[..16])
}

enum Write {
    Put(Box<EndedSession>),
    Remove(String),
}

/// The robots' ended sessions (see the module docs).
pub struct History {
    limits: HistoryLimits,
    /// Every robot's, the one that ended first at the front.
    ended: Mutex<VecDeque<EndedSession>>,
    /// The writer thread's queue and handle, once a store is attached.
    writer: Mutex<Option<(SyncSender<Write>, std::thread::JoinHandle<()>)>>,
}

impl History {
    /// An empty history with `limits`, kept in memory until [`Self::restore`] attaches a
    /// store.
    pub fn new(limits: HistoryLimits) -> Self {
        Self {
            limits,
            ended: Mutex::new(VecDeque::new()),
            writer: Mutex::new(None),
        }
    }

    /// The limits.
    pub fn limits(&self) -> HistoryLimits {
        self.limits
    }

    /// Keeps `e` (and stores it when a store is attached); removes what the limits no
    /// longer hold.
    pub fn insert(&self, e: EndedSession) {
        if !self.limits.keeps_any() {
            return;
        }
        let removed = {
            let mut ended = lock(&self.ended);
            ended.push_back(e.clone());
            self.prune_locked(&mut ended, crate::store::now_s())
        };
        if !removed.contains(&e.key) {
            self.write(Write::Put(Box::new(e)));
        }
        for key in removed {
            self.write(Write::Remove(key));
        }
    }

    /// Removes what is older than the age limit. Returns how many left.
    pub fn prune(&self) -> usize {
        let removed = {
            let mut ended = lock(&self.ended);
            // Cheap when nothing is due: the front ended first.
            let due = ended.front().is_some_and(|e| {
                (crate::store::now_s().saturating_sub(e.ended_unix_s) as f64)
                    > self.limits.max_age_s
            });
            if !due {
                return 0;
            }
            self.prune_locked(&mut ended, crate::store::now_s())
        };
        let n = removed.len();
        for key in removed {
            self.write(Write::Remove(key));
        }
        n
    }

    /// Applies the limits at `now_s`; returns the keys removed.
    fn prune_locked(&self, ended: &mut VecDeque<EndedSession>, now_s: u64) -> Vec<String> {
        let mut removed = Vec::new();
        let max_age = self.limits.max_age_s;
        ended.retain(|e| {
            let keep = now_s.saturating_sub(e.ended_unix_s) as f64 <= max_age;
            if !keep {
                removed.push(e.key.clone());
            }
            keep
        });
        // Per robot, newest kept: walk from the newest end.
        let mut counts: std::collections::HashMap<String, usize> = Default::default();
        let mut keep = vec![true; ended.len()];
        for (i, e) in ended.iter().enumerate().rev() {
            let n = counts.entry(e.robot_id.clone()).or_default();
            *n += 1;
            keep[i] = *n <= self.limits.per_robot;
        }
        let mut i = 0;
        ended.retain(|e| {
            let k = keep[i];
            i += 1;
            if !k {
                removed.push(e.key.clone());
            }
            k
        });
        while ended.len() > MAX_ENDED_SESSIONS {
            if let Some(e) = ended.pop_front() {
                removed.push(e.key);
            }
        }
        removed
    }

    /// Summaries of the ended sessions, newest end first.
    pub fn summaries(&self) -> Vec<SessionSummary> {
        lock(&self.ended)
            .iter()
            .rev()
            .map(EndedSession::summary)
            .collect()
    }

    /// Summaries of the ended sessions with each one's last alarm, newest end first.
    pub fn listing(&self) -> Vec<(SessionSummary, Option<AlarmRecord>)> {
        lock(&self.ended)
            .iter()
            .rev()
            .map(|e| (e.summary(), e.alarms.first().cloned()))
            .collect()
    }

    /// The latest ended session with id `id`.
    pub fn get(&self, id: &str) -> Option<EndedSession> {
        lock(&self.ended).iter().rev().find(|e| e.id == id).cloned()
    }

    /// An alarm of an ended session.
    pub fn alarm(&self, id: &str) -> Option<AlarmRecord> {
        lock(&self.ended)
            .iter()
            .rev()
            .find_map(|e| e.alarms.iter().find(|a| a.id == id))
            .cloned()
    }

    /// Applies `f` to alarm `id` wherever an ended session keeps it (the stored records
    /// are not rewritten: a restore takes marks from the stored false alarms).
    pub fn update_alarm(&self, id: &str, f: impl Fn(&mut AlarmRecord)) {
        for e in lock(&self.ended).iter_mut() {
            for a in e.alarms.iter_mut().filter(|a| a.id == id) {
                f(a);
            }
        }
    }

    fn write(&self, w: Write) {
        let writer = lock(&self.writer);
        let Some((tx, _)) = writer.as_ref() else {
            return;
        };
        match tx.try_send(w) {
            Ok(()) => {}
            Err(TrySendError::Full(Write::Put(e))) => {
                tracing::warn!(session = %e.id, "ended session not stored: the writer is behind");
            }
            Err(TrySendError::Full(Write::Remove(key))) => {
                tracing::warn!(key = %key, "ended session not removed from the store: the writer is behind");
            }
            Err(TrySendError::Disconnected(_)) => {}
        }
    }

    /// Brings back the ended sessions `store` holds (with the false-alarm marks stored
    /// since they were written; their alarms rejoin `book`), applies the limits (removing
    /// what they no longer hold), and from now on stores each ended session there.
    /// Returns how many were restored. Blocking (file I/O); once, at the server's start.
    pub fn restore(&self, store: &Store, book: &AlarmBook) -> usize {
        let mut records: Vec<EndedSession> = match store.ended_sessions::<EndedSession>() {
            Ok(r) => r
                .into_iter()
                .map(|(key, mut e)| {
                    e.key = key;
                    e
                })
                .collect(),
            Err(e) => {
                tracing::warn!("ended sessions not restored: {e}");
                Vec::new()
            }
        };
        records.sort_by(|a, b| (a.ended_unix_s, &a.key).cmp(&(b.ended_unix_s, &b.key)));
        let mut alarms = Vec::new();
        for e in &mut records {
            for a in &mut e.alarms {
                if let Ok(Some(marked)) = store.marked_alarm(&a.id) {
                    *a = marked;
                }
                alarms.push(a.clone());
            }
        }
        let (restored, removed) = {
            let mut ended = lock(&self.ended);
            ended.extend(records);
            let removed = if self.limits.keeps_any() {
                self.prune_locked(&mut ended, crate::store::now_s())
            } else {
                ended.drain(..).map(|e| e.key).collect()
            };
            // Only the alarms of sessions still kept rejoin the book.
            alarms.retain(|a| ended.iter().any(|e| e.id == a.session_id));
            (ended.len(), removed)
        };
        for key in &removed {
            store.remove_ended_session(key);
        }
        alarms.sort_by(|a, b| (a.started_unix_s, &a.id).cmp(&(b.started_unix_s, &b.id)));
        book.restore(alarms);
        self.attach(store.clone());
        if restored > 0 {
            tracing::info!(
                sessions = restored,
                "ended sessions restored for the live view (without thumbnails)"
            );
        }
        restored
    }

    /// Starts the writer thread that stores ended sessions in `store`.
    fn attach(&self, store: Store) {
        let (tx, rx) = std::sync::mpsc::sync_channel::<Write>(WRITES_WAITING);
        let spawned = std::thread::Builder::new()
            .name("vamos-ended-sessions".into())
            .spawn(move || {
                for w in rx {
                    match w {
                        Write::Put(e) => {
                            if let Err(err) = store.put_ended_session(&e.key, e.as_ref()) {
                                tracing::warn!(session = %e.id, "ended session not stored: {err}");
                            }
                        }
                        Write::Remove(key) => store.remove_ended_session(&key),
                    }
                }
            });
        match spawned {
            Ok(handle) => *lock(&self.writer) = Some((tx, handle)),
            Err(e) => tracing::warn!("ended sessions are not stored: {e}"),
        }
    }

    /// Writes what waits and stops storing (the server's shutdown, after the last
    /// session closed).
    pub fn flush(&self) {
        let writer = lock(&self.writer).take();
        if let Some((tx, handle)) = writer {
            drop(tx);
            if handle.join().is_err() {
                tracing::warn!("the ended sessions' writer panicked");
            }
        }
    }
}

#[cfg(test)]
#[path = "history_tests.rs"]
mod tests;
