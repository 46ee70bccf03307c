//! Evaluation labels of an episode: a sidecar `<dir>/<stem>.labels.json` beside the
//! episode file (or a `std_msgs/msg/String` label topic in the bag carrying the same
//! JSON, see [`super::McapEpisode::labels`]).
//!
//! ```json
//! {"episode": "run_03", "anomalous": true, "anomaly_type": "collision",
//!  "intervals_ns": [[1000000000, 2500000000]]}
//! ```
//! A frame is anomalous when its image stamp lies in an interval, both ends included.

use super::EpisodeError;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

/// Labels of one episode.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Labels {
    /// The episode's name.
    pub episode: String,
    /// Whether the episode contains an anomaly.
    pub anomalous: bool,
    /// The kind of anomaly (free text), if any.
    #[serde(default)]
    pub anomaly_type: Option<String>,
    /// Anomalous stamp intervals `[start_ns, end_ns]`, inclusive.
    #[serde(default)]
    pub intervals_ns: Vec<[i64; 2]>,
}

impl Labels {
    /// The sidecar path of an episode file or folder: `<dir>/<stem>.labels.json`.
    pub fn sidecar_path(episode_path: &Path) -> PathBuf {
        let stem = episode_path
            .file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_else(|| "episode".into());
        episode_path
            .parent()
            .unwrap_or_else(|| Path::new(""))
            .join(format!("{stem}.labels.json"))
    }

    /// Parses and checks label JSON (`source` names it in errors): every interval must
    /// have `start_ns <= end_ns`.
    pub fn parse(json: &str, source: &str) -> Result<Self, EpisodeError> {
        let labels: Labels = serde_json::from_str(json).map_err(|e| EpisodeError::Labels {
            path: source.into(),
            reason: e.to_string(),
        })?;
        if let Some([a, b]) = labels.intervals_ns.iter().find(|[a, b]| a > b) {
            return Err(EpisodeError::Labels {
                path: source.into(),
                reason: format!("interval [{a}, {b}] ends before it starts"),
            });
        }
        Ok(labels)
    }

    /// Loads the sidecar of `episode_path`; `Ok(None)` when there is none.
    pub fn load_for(episode_path: &Path) -> Result<Option<Self>, EpisodeError> {
        let path = Self::sidecar_path(episode_path);
        if !path.is_file() {
            return Ok(None);
        }
        let text = std::fs::read_to_string(&path).map_err(|e| EpisodeError::Io {
            path: path.display().to_string(),
            reason: e.to_string(),
        })?;
        Self::parse(&text, &path.display().to_string()).map(Some)
    }

    /// Whether `stamp_ns` lies in an anomalous interval (ends included).
    pub fn is_anomalous(&self, stamp_ns: i64) -> bool {
        self.intervals_ns
            .iter()
            .any(|&[a, b]| a <= stamp_ns && stamp_ns <= b)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sidecar_intervals_are_inclusive() {
        let dir = tempfile::tempdir().unwrap();
        let bag = dir.path().join("run_1.mcap");
        assert_eq!(
            Labels::sidecar_path(&bag),
            dir.path().join("run_1.labels.json")
        );
        assert_eq!(Labels::load_for(&bag).unwrap(), None);
        std::fs::write(
            dir.path().join("run_1.labels.json"),
            r#"{"episode":"run_1","anomalous":true,"anomaly_type":"drop","intervals_ns":[[10,20],[30,30]]}"#,
        )
        .unwrap();
        let l = Labels::load_for(&bag).unwrap().unwrap();
        assert_eq!(l.anomaly_type.as_deref(), Some("drop"));
        let hits: Vec<i64> = (8..33).filter(|&t| l.is_anomalous(t)).collect();
        assert_eq!(hits, [10, 11, 12, 13, 14, 15, 16, 17, 18, 19, 20, 30]);
    }

    #[test]
    fn malformed_labels_are_errors() {
        for bad in [
            r#"{"episode":"e","anomalous":true,"intervals_ns":[[5,1]]}"#,
            r#"{"episode":"e"}"#,
            r#"{"episode":"e","anomalous":false,"extra":1}"#,
        ] {
            assert!(
                matches!(Labels::parse(bad, "x"), Err(EpisodeError::Labels { .. })),
                "{bad}"
            );
        }
    }
}
