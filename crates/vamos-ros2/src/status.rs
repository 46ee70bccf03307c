//! What the bridge knows about its session, and the `diagnostic_msgs/DiagnosticStatus`
//! it implies (the same levels and messages as the Python bridge's).

use std::time::{Duration, Instant};
use vamos_proto as proto;
use vamos_proto::session_event::Kind;

/// `diagnostic_msgs/DiagnosticStatus` levels.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(u8)]
pub enum Level {
    /// Scoring.
    Ok = 0,
    /// Scoring with drops or refusals, or no scores coming back.
    Warn = 1,
    /// Not connected to vamos.
    Error = 2,
    /// No images from the camera.
    Stale = 3,
}

/// Counters and the latest score of one bridge.
#[derive(Debug, Clone, Default)]
pub struct BridgeState {
    /// The server's session id (once opened).
    pub session_id: String,
    /// The session is open.
    pub connected: bool,
    /// Images passed to the server.
    pub images_sent: u64,
    /// Of those, the images sent with a depth image.
    pub images_with_depth: u64,
    /// Scores received.
    pub frames_scored: u64,
    /// Images the server dropped under backpressure (its running count).
    pub dropped: u64,
    /// Messages refused: by the server (one event each) or by the bridge.
    pub refused: u64,
    /// Sessions that ended and were opened again.
    pub reconnects: u64,
    /// The latest score.
    pub latest: Option<proto::FrameScore>,
    /// The latest error, for the diagnostics.
    pub last_error: String,
    /// When the latest image was sent.
    pub last_image: Option<Instant>,
    /// When the latest score arrived.
    pub last_score: Option<Instant>,
}

impl BridgeState {
    /// Records a session event.
    pub fn on_event(&mut self, e: &proto::SessionEvent) {
        match e.kind() {
            Kind::Opened | Kind::Resumed | Kind::Reloaded => {
                self.session_id.clone_from(&e.session_id);
                self.connected = true;
            }
            Kind::FramesDropped => self.dropped = self.dropped.max(e.count),
            Kind::MessageError => {
                self.refused += 1;
                self.last_error.clone_from(&e.detail);
            }
            _ => {}
        }
    }

    /// Records a score.
    pub fn on_score(&mut self, s: &proto::FrameScore, now: Instant) {
        self.frames_scored += 1;
        self.latest = Some(s.clone());
        self.last_score = Some(now);
    }

    /// `(level, message, key-values)` at `now`; without images or scores for
    /// `stale_after`, the camera or the server is taken to be silent.
    pub fn diagnostic(
        &self,
        now: Instant,
        stale_after: Duration,
    ) -> (Level, String, Vec<(String, String)>) {
        let mut values: Vec<(String, String)> = [
            ("session_id", self.session_id.clone()),
            ("images_sent", self.images_sent.to_string()),
            ("images_with_depth", self.images_with_depth.to_string()),
            ("frames_scored", self.frames_scored.to_string()),
            ("dropped", self.dropped.to_string()),
            ("refused", self.refused.to_string()),
            ("reconnects", self.reconnects.to_string()),
        ]
        .into_iter()
        .map(|(k, v)| (k.to_string(), v))
        .collect();
        if let Some(s) = &self.latest {
            values.push(("score".into(), s.score.to_string()));
            values.push(("anomaly".into(), s.anomaly.to_string()));
            values.push(("latency_s".into(), format!("{:.4}", s.latency_s)));
        }
        let silent =
            |t: Option<Instant>| t.is_none_or(|t| now.saturating_duration_since(t) > stale_after);
        let (level, message) = if !self.connected {
            let why = if self.last_error.is_empty() {
                String::new()
            } else {
                format!(": {}", self.last_error)
            };
            (Level::Error, format!("not connected to vamos{why}"))
        } else if silent(self.last_image) {
            (Level::Stale, "no images from the camera topic".to_string())
        } else if silent(self.last_score) {
            (Level::Warn, "images sent but no scores back".to_string())
        } else if self.dropped > 0 || self.refused > 0 {
            (
                Level::Warn,
                format!(
                    "{} image(s) dropped, {} message(s) refused",
                    self.dropped, self.refused
                ),
            )
        } else if self.latest.as_ref().is_some_and(|s| s.warming_up) {
            (Level::Ok, "scoring (flow predictor warming up)".to_string())
        } else {
            (Level::Ok, "scoring".to_string())
        };
        (level, message, values)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_level_follows_connection_images_scores_and_drops() {
        let t0 = Instant::now();
        let stale = Duration::from_secs(5);
        let mut s = BridgeState::default();
        let (level, message, _) = s.diagnostic(t0, stale);
        assert_eq!(
            (level, message.as_str()),
            (Level::Error, "not connected to vamos")
        );
        s.on_event(&proto::SessionEvent {
            kind: Kind::Opened as i32,
            session_id: "r1-x".into(),
            ..Default::default()
        });
        assert_eq!(s.diagnostic(t0, stale).0, Level::Stale);
        s.images_sent += 1;
        s.last_image = Some(t0);
        assert_eq!(s.diagnostic(t0, stale).0, Level::Warn);
        s.on_score(
            &proto::FrameScore {
                score: 0.25,
                ..Default::default()
            },
            t0,
        );
        let (level, message, values) = s.diagnostic(t0 + Duration::from_secs(1), stale);
        assert_eq!((level, message.as_str()), (Level::Ok, "scoring"));
        assert!(values.contains(&("session_id".into(), "r1-x".into())));
        assert!(values.contains(&("score".into(), "0.25".into())));
        s.on_event(&proto::SessionEvent {
            kind: Kind::FramesDropped as i32,
            count: 3,
            ..Default::default()
        });
        assert_eq!(
            s.diagnostic(t0, stale).1,
            "3 image(s) dropped, 0 message(s) refused"
        );
        assert_eq!(
            s.diagnostic(t0 + Duration::from_secs(6), stale).0,
            Level::Stale
        );
    }
}
