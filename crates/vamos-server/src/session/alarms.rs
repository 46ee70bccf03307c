//! Alarms as events: each session's per-frame anomaly flags debounced into alarms
//! ([`vamos_core::eval::alarm`], k of n frames, per profile), each with the thresholds in
//! force, every component at its start and at its peak, and which detectors fired.
//! An alarm's start and end go to the session's client ([`Output::Alarm`]); the recent
//! alarms of every session are kept in an [`AlarmBook`] (bounded) with a thumbnail of
//! the frame at each start. An operator marks an alarm as a false alarm
//! ([`mark_false_alarm`]): the mark is stored in the data directory
//! ([`crate::store::AlarmRecord`]) so the profile's false alarms outlive the session.

use super::error::SessionError;
use super::event::{Output, detector_of};
use super::hub::Hub;
use super::live::Thumb;
use super::state::{Session, lock};
use crate::store::{AlarmComponents, AlarmRecord, FalseAlarmMark, Store, StoreError};
use std::collections::{HashMap, VecDeque};
use std::sync::Mutex;
use std::sync::atomic::{AtomicU64, Ordering};
use vamos_core::eval::Detector;
use vamos_core::eval::alarm::{Debounce, Debouncer, Edge};
use vamos_core::pipeline::FrameScore;

/// Recent alarms kept in memory (all sessions); older ones leave with their thumbnails.
pub const RECENT_ALARMS: usize = 1000;

/// The longest note of a mark, characters.
pub const MAX_NOTE_CHARS: usize = 500;

/// An alarm started or ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum AlarmEdge {
    /// It starts at `alarm.start`.
    Started,
    /// It ended at `alarm.end_frame`.
    Ended,
}

/// An alarm event as the session's client hears it.
#[derive(Debug, Clone)]
pub struct AlarmEvent {
    /// Start or end.
    pub edge: AlarmEdge,
    /// The alarm as it is now.
    pub alarm: AlarmRecord,
}

/// The alarms of one session in progress.
#[derive(Debug)]
pub struct AlarmTracker {
    debouncer: Debouncer,
    /// The id of the alarm that is on.
    current: Option<String>,
}

impl AlarmTracker {
    /// A tracker with `rule` (an invalid rule falls back to the default, logged; profiles
    /// are checked when they load, so this does not happen with a loaded profile).
    pub fn new(rule: Option<Debounce>) -> Self {
        let rule = rule.unwrap_or_default();
        let debouncer = Debouncer::new(rule).unwrap_or_else(|e| {
            tracing::warn!("{e}; using the default 3 of 5 frames");
            Debouncer::default()
        });
        Self {
            debouncer,
            current: None,
        }
    }

    /// Whether an alarm is on.
    pub fn active(&self) -> bool {
        self.current.is_some()
    }
}

/// The recent alarms of every session, newest last.
pub struct AlarmBook {
    boot: String,
    next: AtomicU64,
    recent: Mutex<VecDeque<AlarmRecord>>,
    thumbs: Mutex<HashMap<String, Vec<u8>>>,
}

impl Default for AlarmBook {
    fn default() -> Self {
        let boot = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map_or(0, |d| d.as_millis() as u64);
        Self {
            boot: format!("{boot:x}"),
            next: AtomicU64::new(1),
            recent: Mutex::new(VecDeque::new()),
            thumbs: Mutex::new(HashMap::new()),
        }
    }
}

fn finite(v: Option<f64>) -> Option<f64> {
    v.filter(|x| x.is_finite())
}

fn components(s: &FrameScore) -> AlarmComponents {
    AlarmComponents {
        stamp_ns: s.stamp_ns,
        score: finite(Some(s.score)),
        values: s.values.map(|_, v| finite(*v)),
    }
}

impl AlarmBook {
    fn new_id(&self) -> String {
        format!(
            "al-{}-{}",
            self.boot,
            self.next.fetch_add(1, Ordering::Relaxed)
        )
    }

    fn insert(&self, alarm: AlarmRecord, thumb: Option<Vec<u8>>) {
        let mut recent = lock(&self.recent);
        let mut thumbs = lock(&self.thumbs);
        if recent.len() == RECENT_ALARMS
            && let Some(old) = recent.pop_front()
        {
            thumbs.remove(&old.id);
        }
        if let Some(t) = thumb {
            thumbs.insert(alarm.id.clone(), t);
        }
        recent.push_back(alarm);
    }

    /// Alarms of ended sessions brought back at a restart ([`super::history`]), oldest
    /// first, before any new alarm: without thumbnails, within the bound.
    pub(super) fn restore(&self, alarms: Vec<AlarmRecord>) {
        for a in alarms {
            if self.get(&a.id).is_none() {
                self.insert(a, None);
            }
        }
    }

    fn update(&self, id: &str, f: impl FnOnce(&mut AlarmRecord)) -> Option<AlarmRecord> {
        let mut recent = lock(&self.recent);
        let a = recent.iter_mut().rev().find(|a| a.id == id)?;
        f(a);
        Some(a.clone())
    }

    /// Recent alarms, newest first, of session `session` when given.
    pub fn list(&self, session: Option<&str>) -> Vec<AlarmRecord> {
        lock(&self.recent)
            .iter()
            .rev()
            .filter(|a| session.is_none_or(|s| a.session_id == s))
            .cloned()
            .collect()
    }

    /// A recent alarm by id.
    pub fn get(&self, id: &str) -> Option<AlarmRecord> {
        lock(&self.recent)
            .iter()
            .rev()
            .find(|a| a.id == id)
            .cloned()
    }

    /// The PNG thumbnail of the frame at alarm `id`'s start.
    pub fn thumbnail(&self, id: &str) -> Option<Vec<u8>> {
        lock(&self.thumbs).get(id).cloned()
    }
}

impl Hub {
    /// Feeds frame `score` of session `s` to its alarm tracker: on an alarm's start the
    /// alarm is recorded (with `frame`'s PNG thumbnail) and an event returned, on its
    /// end likewise; frames in between update its peak and detectors.
    pub(super) fn track_alarm(
        &self,
        s: &Session,
        score: &FrameScore,
        frame: Option<&Thumb>,
    ) -> Option<Output> {
        let mut tracker = lock(&s.alarms);
        let edge = tracker.debouncer.push(score.anomaly);
        let fired = detector_of(score).filter(|_| score.anomaly);
        match (edge, tracker.current.clone()) {
            (Edge::Start, _) => {
                let profile = s.profile();
                let detector = fired.map_or("flow", Detector::name).to_string();
                let alarm = AlarmRecord {
                    id: self.alarms.new_id(),
                    session_id: s.id.clone(),
                    robot_id: s.robot_id.clone(),
                    opener: s.opener,
                    profile: s.profile_name.clone(),
                    model: profile.model_label.clone(),
                    started_unix_s: crate::store::now_s(),
                    start_frame: score.frame,
                    end_frame: None,
                    end_stamp_ns: None,
                    frames_flagged: u64::from(score.anomaly),
                    detectors: vec![detector.clone()],
                    detector,
                    thresholds: profile.setup.detector_thresholds(),
                    start: components(score),
                    peak: components(score),
                    false_alarm: None,
                    recording: lock(&s.recorder).as_ref().map(|r| r.file_name()),
                };
                tracker.current = Some(alarm.id.clone());
                drop(tracker);
                tracing::info!(session = %s.id, alarm = %alarm.id, detector = %alarm.detector, "alarm started");
                self.metrics
                    .alarms
                    .with_label_values(&[&s.profile_name, &alarm.detector])
                    .inc();
                self.alarms.insert(alarm.clone(), frame.map(Thumb::to_png));
                Some(Output::Alarm(AlarmEvent {
                    edge: AlarmEdge::Started,
                    alarm,
                }))
            }
            (Edge::End, Some(id)) => {
                tracker.current = None;
                drop(tracker);
                let alarm = self.alarms.update(&id, |a| {
                    a.end_frame = Some(score.frame);
                    a.end_stamp_ns = Some(score.stamp_ns);
                })?;
                tracing::info!(session = %s.id, alarm = %id, "alarm ended");
                Some(Output::Alarm(AlarmEvent {
                    edge: AlarmEdge::Ended,
                    alarm,
                }))
            }
            (_, Some(id)) if score.anomaly => {
                drop(tracker);
                self.alarms.update(&id, |a| {
                    a.frames_flagged += 1;
                    if let Some(d) = fired.map(Detector::name)
                        && !a.detectors.iter().any(|x| x == d)
                    {
                        a.detectors.push(d.to_string());
                    }
                    if finite(Some(score.score)) > a.peak.score {
                        a.peak = components(score);
                    }
                });
                None
            }
            _ => None,
        }
    }
}

/// Marks alarm `id` as a false alarm (by a token of role `by_role`, with `note`) and
/// stores it. Refused: an unknown id (not among the recent alarms nor those of the ended
/// sessions kept, [`super::history`]), one already marked,
/// a note over [`MAX_NOTE_CHARS`], a store that cannot write (read-only replica, full
/// disk). Nothing changes when it is refused. Blocking (file I/O).
pub fn mark_false_alarm(
    hub: &Hub,
    store: &Store,
    id: &str,
    by_role: &str,
    note: &str,
) -> Result<AlarmRecord, SessionError> {
    if note.chars().count() > MAX_NOTE_CHARS {
        return Err(SessionError::BadNote {
            max: MAX_NOTE_CHARS,
        });
    }
    let stored = store.marked_alarm(id).map_err(store_error)?;
    let Some(mut alarm) = hub
        .alarms
        .get(id)
        .or_else(|| hub.history.alarm(id))
        .or(stored.clone())
    else {
        return Err(SessionError::UnknownAlarm { id: id.into() });
    };
    if alarm.false_alarm.is_some() || stored.is_some() {
        return Err(SessionError::AlarmMarked { id: id.into() });
    }
    alarm.false_alarm = Some(FalseAlarmMark {
        marked_unix_s: crate::store::now_s(),
        by_role: by_role.into(),
        note: note.trim().into(),
    });
    // The session's recording is kept: the episode joins the profile's nominal set.
    if let Some(file) = alarm.recording.clone() {
        match super::recording::keep(&hub.recordings_dir(), &file) {
            Ok(true) => {}
            Ok(false) => alarm.recording = None, // removed to make room meanwhile
            Err(e) => {
                tracing::warn!(alarm = %id, "cannot keep the session's recording: {e}");
                alarm.recording = None;
            }
        }
    }
    store.put_marked_alarm(&alarm).map_err(store_error)?;
    let (mark, recording) = (alarm.false_alarm.clone(), alarm.recording.clone());
    // The live record and an ended session's copy now carry the mark too (the stored one
    // is the record of it).
    hub.history.update_alarm(id, |a| {
        a.false_alarm = mark.clone();
        a.recording = recording.clone();
    });
    let updated = hub
        .alarms
        .update(id, |a| {
            a.false_alarm = mark;
            a.recording = recording;
        })
        .unwrap_or(alarm);
    tracing::info!(alarm = %id, profile = %updated.profile, role = by_role, "alarm marked as a false alarm");
    Ok(updated)
}

fn store_error(source: StoreError) -> SessionError {
    SessionError::Store {
        source: Box::new(source),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::store::AlarmThresholds;

    fn record(id: &str, session: &str) -> AlarmRecord {
        AlarmRecord {
            id: id.into(),
            session_id: session.into(),
            robot_id: "r".into(),
            opener: None,
            profile: "p".into(),
            model: "none".into(),
            started_unix_s: 0,
            start_frame: 0,
            end_frame: None,
            end_stamp_ns: None,
            frames_flagged: 1,
            detector: "flow".into(),
            detectors: vec!["flow".into()],
            thresholds: AlarmThresholds::default(),
            start: AlarmComponents::default(),
            peak: AlarmComponents::default(),
            false_alarm: None,
            recording: None,
        }
    }

    #[test]
    fn the_book_is_bounded_and_lists_newest_first_per_session() {
        let book = AlarmBook::default();
        for i in 0..(RECENT_ALARMS + 3) {
            let s = if i % 2 == 0 { "a" } else { "b" };
            book.insert(record(&format!("x{i}"), s), Some(vec![i as u8]));
        }
        let all = book.list(None);
        assert_eq!(all.len(), RECENT_ALARMS);
        assert_eq!(all[0].id, format!("x{}", RECENT_ALARMS + 2));
        assert!(book.get("x0").is_none());
        assert!(
            book.thumbnail("x0").is_none(),
            "thumbnails leave with alarms"
        );
        assert_eq!(book.thumbnail("x5"), Some(vec![5]));
        assert!(book.list(Some("a")).iter().all(|a| a.session_id == "a"));
        assert_eq!(book.list(Some("nobody")).len(), 0);
    }

    #[test]
    fn marking_stores_the_mark_once_and_refuses_what_it_cannot_do() {
        use crate::config::ServiceConfig;
        use crate::store::StoreLimits;
        let dir = tempfile::tempdir().unwrap();
        let store = Store::open(dir.path(), StoreLimits::default()).unwrap();
        let hub = Hub::start(
            ServiceConfig {
                workers: 1,
                ..ServiceConfig::default()
            },
            crate::session::metrics::Metrics::new(),
        );
        hub.alarms.insert(record("al-1", "s"), None);
        let e = mark_false_alarm(&hub, &store, "al-9", "admin", "").unwrap_err();
        assert!(matches!(e, SessionError::UnknownAlarm { .. }), "{e}");
        let long = "x".repeat(MAX_NOTE_CHARS + 1);
        let e = mark_false_alarm(&hub, &store, "al-1", "admin", &long).unwrap_err();
        assert!(matches!(e, SessionError::BadNote { .. }), "{e}");
        assert!(store.marked_alarms(None).unwrap().is_empty());
        let a = mark_false_alarm(&hub, &store, "al-1", "robot", " shadow ").unwrap();
        let mark = a.false_alarm.clone().unwrap();
        assert_eq!(
            (mark.by_role.as_str(), mark.note.as_str()),
            ("robot", "shadow")
        );
        assert_eq!(hub.alarms.get("al-1"), Some(a.clone()));
        assert_eq!(store.marked_alarm("al-1").unwrap(), Some(a));
        let e = mark_false_alarm(&hub, &store, "al-1", "admin", "").unwrap_err();
        assert!(matches!(e, SessionError::AlarmMarked { .. }), "{e}");
        hub.shutdown(std::time::Duration::from_millis(10));
    }
}
