//! Alarms an operator marked as false alarms (`alarms/<id>.json`): kept across restarts
//! so that they can be listed per profile, their thresholds compared with the profile's,
//! and a recalibration planned from them. Live alarms are held by the session layer; only
//! marked ones are stored.

use super::files::{check_name, list_dir, now_unix_s, read_json, write_json};
use super::{Store, StoreError};
use serde::{Deserialize, Serialize};
use vamos_core::eval::DetectorValues;

/// Marked alarms kept; the oldest are removed past this many.
pub const KEPT_MARKED_ALARMS: usize = 5000;

/// Detector values of one frame (absent: off, not yet defined, or not finite).
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize, schemars::JsonSchema)]
pub struct AlarmComponents {
    /// Image stamp, nanoseconds.
    pub stamp_ns: i64,
    /// Fused score.
    pub score: Option<f64>,
    /// Each detector's value, as the fields `e_c` .. `e_k` (records stored before a
    /// detector existed read with it absent; other fields are refused).
    #[serde(flatten)]
    pub values: DetectorValues,
}

/// The thresholds in force when an alarm started: the fused score's and each
/// detector's own (absent: none, i.e. never crossed). Records stored before `e_o` and
/// `e_r` (or `e_k`) were kept read with them absent.
pub use vamos_core::eval::DetectorThresholds as AlarmThresholds;

/// An operator's verdict on an alarm.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct FalseAlarmMark {
    /// When, seconds since the Unix epoch.
    pub marked_unix_s: u64,
    /// The role of the token that marked it (`robot`, `admin`).
    pub by_role: String,
    /// Free text (at most 500 characters).
    #[serde(default)]
    pub note: String,
}

/// One alarm: a debounced run of anomalous frames of a session.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct AlarmRecord {
    /// Unique id (`al-<boot>-<n>`).
    pub id: String,
    /// The session it belongs to.
    pub session_id: String,
    /// The session's robot.
    pub robot_id: String,
    /// The robot token that opened the session ([`crate::session::Session::opener`]):
    /// kept in memory only, never shown or stored.
    #[serde(skip)]
    #[schemars(skip)]
    pub opener: Option<usize>,
    /// The session's profile.
    pub profile: String,
    /// The session's model label.
    pub model: String,
    /// When it started, seconds since the Unix epoch (server clock).
    pub started_unix_s: u64,
    /// Frame index (among processed frames) of its start.
    pub start_frame: u64,
    /// Frame index of its end (`None`: still on, or the session ended during it).
    pub end_frame: Option<u64>,
    /// Image stamp of its end, nanoseconds.
    pub end_stamp_ns: Option<i64>,
    /// Flagged frames so far.
    pub frames_flagged: u64,
    /// The detector that fired at its start (`camera`, `body`, `flow`, `scene`).
    pub detector: String,
    /// Every detector that fired during it, in the order they first did.
    pub detectors: Vec<String>,
    /// The thresholds in force.
    pub thresholds: AlarmThresholds,
    /// Every component at the start frame.
    pub start: AlarmComponents,
    /// Every component at its highest-scoring frame.
    pub peak: AlarmComponents,
    /// The operator's mark, once marked.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub false_alarm: Option<FalseAlarmMark>,
    /// The session's recording (a file of the data directory's `recordings/`), if it was
    /// recorded; once the alarm is marked it is kept and joins the profile's nominal set.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub recording: Option<String>,
}

impl Store {
    fn alarms_dir(&self) -> std::path::PathBuf {
        self.dir().join("alarms")
    }

    /// Stores a marked alarm (replacing an earlier record of the same id). Refused on a
    /// read-only store and for an unmarked one.
    pub fn put_marked_alarm(&self, alarm: &AlarmRecord) -> Result<(), StoreError> {
        self.check_writable()?;
        check_name(&alarm.id)?;
        if alarm.false_alarm.is_none() {
            return Err(StoreError::invalid(format!(
                "alarm {} is not marked; only marked alarms are stored",
                alarm.id
            )));
        }
        let dir = self.alarms_dir();
        std::fs::create_dir_all(&dir).map_err(|e| StoreError::io(&dir, e))?;
        write_json(
            &self.dir().join("tmp"),
            &dir.join(format!("{}.json", alarm.id)),
            alarm,
        )?;
        self.trim_marked_alarms();
        Ok(())
    }

    /// A stored (marked) alarm by id.
    pub fn marked_alarm(&self, id: &str) -> Result<Option<AlarmRecord>, StoreError> {
        if check_name(id).is_err() {
            return Ok(None);
        }
        read_json(&self.alarms_dir().join(format!("{id}.json")))
    }

    /// Stored (marked) alarms, of `profile` when given, oldest mark first. Unreadable
    /// records are skipped with a warning.
    pub fn marked_alarms(&self, profile: Option<&str>) -> Result<Vec<AlarmRecord>, StoreError> {
        let dir = self.alarms_dir();
        if !dir.exists() {
            return Ok(Vec::new());
        }
        let mut out = Vec::new();
        for (name, path, is_dir) in list_dir(&dir)? {
            if is_dir || !name.ends_with(".json") {
                continue;
            }
            match read_json::<AlarmRecord>(&path) {
                Ok(Some(a)) if profile.is_none_or(|p| a.profile == p) => out.push(a),
                Ok(_) => {}
                Err(e) => tracing::warn!(path = %path.display(), "marked alarm not read: {e}"),
            }
        }
        out.sort_by_key(|a| {
            (
                a.false_alarm.as_ref().map_or(0, |m| m.marked_unix_s),
                a.id.clone(),
            )
        });
        Ok(out)
    }

    fn trim_marked_alarms(&self) {
        let Ok(all) = self.marked_alarms(None) else {
            return;
        };
        let excess = all.len().saturating_sub(KEPT_MARKED_ALARMS);
        for a in all.iter().take(excess) {
            super::files::remove_file_quiet(&self.alarms_dir().join(format!("{}.json", a.id)));
        }
    }
}

/// Seconds since the Unix epoch (for marks).
pub fn now_s() -> u64 {
    now_unix_s()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::store::StoreLimits;
    use vamos_core::eval::Detector;

    fn alarm(id: &str, profile: &str, marked: bool) -> AlarmRecord {
        AlarmRecord {
            id: id.into(),
            session_id: "s1".into(),
            robot_id: "r".into(),
            opener: None,
            profile: profile.into(),
            model: "none".into(),
            started_unix_s: 1,
            start_frame: 4,
            end_frame: Some(9),
            end_stamp_ns: Some(900),
            frames_flagged: 3,
            detector: "camera".into(),
            detectors: vec!["camera".into()],
            thresholds: AlarmThresholds {
                alarm: Some(0.5),
                detectors: DetectorValues::of(&[(Detector::Camera, 2.0), (Detector::Flow, 0.5)]),
            },
            start: AlarmComponents {
                stamp_ns: 400,
                score: Some(1e6),
                values: DetectorValues::of(&[(Detector::Camera, 3.0)]),
            },
            peak: AlarmComponents::default(),
            false_alarm: marked.then(|| FalseAlarmMark {
                marked_unix_s: 7,
                by_role: "admin".into(),
                note: "a person walked by".into(),
            }),
            recording: None,
        }
    }

    #[test]
    fn marked_alarms_survive_a_reopen_and_unmarked_ones_are_refused() {
        let dir = tempfile::tempdir().unwrap();
        {
            let store = Store::open(dir.path(), StoreLimits::default()).unwrap();
            store.put_marked_alarm(&alarm("al-1", "p", true)).unwrap();
            store.put_marked_alarm(&alarm("al-2", "q", true)).unwrap();
            let err = store
                .put_marked_alarm(&alarm("al-3", "p", false))
                .unwrap_err();
            assert!(err.to_string().contains("not marked"), "{err}");
            assert!(store.put_marked_alarm(&alarm("../x", "p", true)).is_err());
        }
        let store = Store::open(dir.path(), StoreLimits::default()).unwrap();
        assert!(store.problems().is_empty(), "{:?}", store.problems());
        assert_eq!(
            store.marked_alarm("al-1").unwrap(),
            Some(alarm("al-1", "p", true))
        );
        assert_eq!(store.marked_alarm("../etc").unwrap(), None);
        let p: Vec<String> = store
            .marked_alarms(Some("p"))
            .unwrap()
            .into_iter()
            .map(|a| a.id)
            .collect();
        assert_eq!(p, ["al-1"]);
        assert_eq!(store.marked_alarms(None).unwrap().len(), 2);
    }
}
