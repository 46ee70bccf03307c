use super::*;
use crate::session::live::FramePoint;
use crate::store::{AlarmComponents, AlarmThresholds, FalseAlarmMark, StoreLimits};

fn limits(per_robot: usize, max_age_s: f64) -> HistoryLimits {
    HistoryLimits {
        per_robot,
        max_age_s,
    }
}

fn alarm(id: &str, session: &str, robot: &str) -> AlarmRecord {
    AlarmRecord {
        id: id.into(),
        session_id: session.into(),
        robot_id: robot.into(),
        opener: Some(0),
        profile: "p".into(),
        model: "none".into(),
        started_unix_s: crate::store::now_s(),
        start_frame: 2,
        end_frame: Some(6),
        end_stamp_ns: Some(600),
        frames_flagged: 3,
        detector: "flow".into(),
        detectors: vec!["flow".into()],
        thresholds: AlarmThresholds::default(),
        start: AlarmComponents::default(),
        peak: AlarmComponents::default(),
        false_alarm: None,
        recording: None,
    }
}

/// Session `id` of `robot` that ended `ago_s` seconds ago, with `frames` points and one
/// alarm `al-<id>`.
fn ended(robot: &str, id: &str, ago_s: u64, frames: u64) -> EndedSession {
    let now = crate::store::now_s();
    let points = (0..frames)
        .map(|i| FramePoint {
            frame: i,
            stamp_ns: 1_000_000_000 + i as i64 * 100_000_000,
            score: Some(i as f64),
            values: vamos_core::eval::DetectorValues::of(&[(
                vamos_core::eval::Detector::Camera,
                0.5,
            )]),
            anomaly: i >= 2,
            warming_up: false,
            alarm: i >= 4,
            latency_s: 0.01,
            frames_lost: u64::from(i == 3),
        })
        .collect();
    EndedSession {
        key: key_of(id, now * 1000),
        id: id.into(),
        robot_id: robot.into(),
        opener: Some(0),
        profile: "p".into(),
        model: "none".into(),
        task: "t".into(),
        phase: None,
        images: frames,
        frames_scored: frames,
        dropped: 1,
        frames_lost: 1,
        anomalies: frames.saturating_sub(2),
        reloads: 0,
        duration_s: 3.0,
        opened_unix_s: now - ago_s - 3,
        ended_unix_s: now - ago_s,
        end_reason: None,
        latency_s: Some(0.01),
        frame_rate_hz: Some(10.0),
        first_stamp_ns: Some(1_000_000_000),
        latest: None,
        thresholds: AlarmThresholds::default(),
        points,
        alarms: vec![alarm(&format!("al-{id}"), id, robot)],
        notes: vec!["e_k does not run: the profile is not calibrated".into()],
    }
}

fn ids(h: &History) -> Vec<String> {
    h.summaries().into_iter().map(|s| s.id).collect()
}

#[test]
fn each_robot_keeps_its_last_sessions_up_to_the_count() {
    let h = History::new(limits(3, 3600.0));
    for i in 0..5 {
        h.insert(ended("arm-a", &format!("a-{i}"), 0, 4));
        if i < 2 {
            h.insert(ended("arm-b", &format!("b-{i}"), 0, 4));
        }
    }
    // Newest end first; arm-a's two oldest left, arm-b's two stay.
    assert_eq!(ids(&h), ["a-4", "a-3", "a-2", "b-1", "b-0"]);
    let s = &h.summaries()[0];
    assert_eq!((s.state, s.robot_id.as_str()), ("ended", "arm-a"));
    assert!(s.ended_unix_s.is_some() && s.degraded && s.frames_lost == 1);
    assert!(h.get("a-0").is_none() && h.alarm("al-a-0").is_none());
    assert_eq!(h.get("a-4").unwrap().points.len(), 4);
    assert_eq!(h.alarm("al-b-0").unwrap().session_id, "b-0");
    // 0 keeps nothing.
    let none = History::new(limits(0, 3600.0));
    none.insert(ended("arm-a", "x", 0, 1));
    assert!(none.summaries().is_empty());
}

#[test]
fn sessions_older_than_the_age_limit_leave() {
    let h = History::new(limits(10, 60.0));
    h.insert(ended("arm-a", "old", 61, 2));
    assert!(ids(&h).is_empty(), "too old when it arrives");
    // Sessions arrive as they end.
    h.insert(ended("arm-b", "mid", 30, 2));
    h.insert(ended("arm-a", "fresh", 0, 2));
    assert_eq!(h.prune(), 0);
    assert_eq!(ids(&h), ["fresh", "mid"]);
    // 31 s pass: "mid" is past the limit, "fresh" not.
    for e in lock(&h.ended).iter_mut() {
        e.ended_unix_s -= 31;
    }
    assert_eq!(h.prune(), 1);
    assert_eq!(ids(&h), ["fresh"]);
    assert!(h.alarm("al-mid").is_none());
}

#[test]
fn all_robots_together_keep_at_most_the_global_bound() {
    let h = History::new(limits(MAX_PER_ROBOT, 3600.0));
    for i in 0..(MAX_ENDED_SESSIONS + 5) {
        h.insert(ended(&format!("robot-{}", i % 50), &format!("s-{i}"), 0, 1));
    }
    let all = ids(&h);
    assert_eq!(all.len(), MAX_ENDED_SESSIONS);
    assert_eq!(all[0], format!("s-{}", MAX_ENDED_SESSIONS + 4));
    assert!(h.get("s-4").is_none() && h.get("s-5").is_some());
    // The setting cannot raise the bound per robot.
    let config = ServiceConfig {
        ended_sessions_per_robot: 10_000,
        ..ServiceConfig::default()
    };
    assert_eq!(HistoryLimits::of(&config).per_robot, MAX_PER_ROBOT);
}

#[test]
fn marks_reach_an_ended_sessions_alarms() {
    let h = History::new(limits(5, 3600.0));
    h.insert(ended("arm-a", "a-1", 0, 3));
    let mark = FalseAlarmMark {
        marked_unix_s: 1,
        by_role: "robot".into(),
        note: String::new(),
    };
    h.update_alarm("al-a-1", |a| a.false_alarm = Some(mark.clone()));
    assert_eq!(h.alarm("al-a-1").unwrap().false_alarm, Some(mark.clone()));
    assert_eq!(
        h.get("a-1").unwrap().alarms[0].false_alarm,
        Some(mark),
        "the session's copy"
    );
}

#[test]
fn a_restart_restores_what_the_limits_still_hold_with_the_marks_stored_since() {
    let dir = tempfile::tempdir().unwrap();
    let a2 = ended("arm-a", "a-2", 0, 5);
    {
        let store = Store::open(dir.path(), StoreLimits::default()).unwrap();
        let h = History::new(limits(5, 3600.0));
        let book = AlarmBook::default();
        assert_eq!(h.restore(&store, &book), 0);
        h.insert(ended("arm-a", "a-1", 10, 3));
        h.insert(a2.clone());
        h.insert(ended("arm-b", "b-1", 5, 2));
        h.insert(ended("arm-b", "b-gone", 7200, 2)); // too old: never stored
        h.flush();
        assert_eq!(
            std::fs::read_dir(dir.path().join("ended")).unwrap().count(),
            3
        );
        // b-1's alarm is marked (as mark_false_alarm stores it) after its session ended.
        let mut marked = alarm("al-b-1", "b-1", "arm-b");
        marked.false_alarm = Some(FalseAlarmMark {
            marked_unix_s: 9,
            by_role: "admin".into(),
            note: "shadow".into(),
        });
        store.put_marked_alarm(&marked).unwrap();
    }
    // Restarted with room for one session per robot: a-1 goes, from disk too.
    let store = Store::open(dir.path(), StoreLimits::default()).unwrap();
    let h = History::new(limits(1, 3600.0));
    let book = AlarmBook::default();
    assert_eq!(h.restore(&store, &book), 2);
    assert_eq!(ids(&h), ["a-2", "b-1"]);
    let back = h.get("a-2").unwrap();
    assert_eq!(back.opener, None, "a token's identity is never stored");
    assert_eq!(
        EndedSession {
            opener: Some(0),
            alarms: back
                .alarms
                .iter()
                .map(|a| AlarmRecord {
                    opener: Some(0),
                    ..a.clone()
                })
                .collect(),
            ..back.clone()
        },
        a2
    );
    assert_eq!(
        h.alarm("al-b-1").unwrap().false_alarm.unwrap().note,
        "shadow"
    );
    // Their alarms are recent alarms again (markable), without thumbnails.
    let recent: Vec<String> = book.list(None).into_iter().map(|a| a.id).collect();
    assert_eq!(recent.len(), 2);
    assert!(recent.contains(&"al-a-2".to_string()) && recent.contains(&"al-b-1".to_string()));
    assert!(book.thumbnail("al-a-2").is_none());
    assert!(book.get("al-b-1").unwrap().false_alarm.is_some());
    let stored: Vec<(String, EndedSession)> = store.ended_sessions().unwrap();
    assert_eq!(stored.len(), 2, "the pruned record left the disk");
    // New ends are stored by the restored history; one pushed out is removed.
    h.insert(ended("arm-a", "a-3", 0, 1));
    h.flush();
    let mut keys: Vec<String> = store
        .ended_sessions::<EndedSession>()
        .unwrap()
        .into_iter()
        .map(|(_, e)| e.id)
        .collect();
    keys.sort();
    assert_eq!(keys, ["a-3", "b-1"]);
}

#[test]
fn an_ended_sessions_alarm_is_marked_after_it_left_the_recent_alarms() {
    use crate::session::alarms::mark_false_alarm;
    let dir = tempfile::tempdir().unwrap();
    let store = Store::open(dir.path(), StoreLimits::default()).unwrap();
    let hub = crate::session::Hub::start(
        ServiceConfig {
            workers: 1,
            data_dir: dir.path().to_path_buf(),
            ..ServiceConfig::default()
        },
        crate::session::metrics::Metrics::new(),
    );
    hub.history.insert(ended("arm-a", "a-1", 0, 3));
    assert!(hub.alarms.get("al-a-1").is_none(), "not a recent alarm");
    let a = mark_false_alarm(&hub, &store, "al-a-1", "robot", "glare").unwrap();
    assert_eq!(a.false_alarm.as_ref().unwrap().note, "glare");
    assert_eq!(hub.history.alarm("al-a-1"), Some(a.clone()));
    // Stored as any mark is (without the opener, which stays in memory).
    let stored = store.marked_alarm("al-a-1").unwrap().unwrap();
    assert_eq!(
        AlarmRecord {
            opener: a.opener,
            ..stored
        },
        a
    );
    hub.shutdown(std::time::Duration::from_millis(10));
}
