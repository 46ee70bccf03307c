//! Profiles: what binds a robot, a camera, pipeline parameters, a model and thresholds.
//!
//! A profile is a TOML file (`deny_unknown_fields`; paths relative to the file):
//!
//! ```toml
//! name = "shelf-arm"
//! robot = "robot/arm.urdf"        # URDF file, package folder or .zip/.tar.gz (optional)
//! robot_packages = ["../ws/src"]  # where `package://NAME/...` meshes are (optional)
//! camera = "camera.json"          # camera description, as `vamos render --camera` (optional)
//! model = "model.vamos"           # flow-predictor bundle (optional)
//! flow_preset = "realtime"        # TV-L1 preset (optional; default: the settings' [vision.flow])
//! alarm = "conformal"             # which calibrated threshold sets the anomaly flag
//! [thresholds]                    # optional manual overrides of the calibrated thresholds
//! e_c = 2.5                       # e_c threshold, px (replaces the calibrated one)
//! alarm = 1000000.0               # fused-score alarm threshold (replaces the alarm rule's)
//! [pipeline]                      # optional; absent = the settings' [pipeline]
//! stride = 1
//! [topics]                        # optional; absent = the settings' [episode.topics]
//! image = "/head_camera/image_raw"
//! ```
//!
//! `vamos calibrate` writes the thresholds beside it, as `<stem>.calibration.json`
//! ([`Calibration`]), which [`Profile::load`] reads back when present. The thresholds in
//! force ([`Profile::thresholds`], [`Profile::alarm_threshold`]) are the calibrated ones
//! with the `[thresholds]` overrides on top ([`ThresholdOverrides`]).

use super::PipelineConfig;
use crate::episode::EpisodeTopics;
use crate::eval::{ConformalThreshold, Thresholds};
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};
use vamos_robot::CameraSpec;

/// Errors of reading and writing profiles.
#[derive(Debug, thiserror::Error)]
pub enum ProfileError {
    /// A file could not be read or written.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The error.
        source: std::io::Error,
    },
    /// A file is not a valid profile, camera or calibration.
    #[error("{path}: {reason}")]
    Invalid {
        /// The file.
        path: PathBuf,
        /// What is wrong.
        reason: String,
    },
}

/// Which calibrated threshold on the fused score sets the anomaly flag.
#[derive(
    Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize, schemars::JsonSchema,
)]
#[serde(rename_all = "snake_case")]
pub enum AlarmRule {
    /// The split-conformal threshold (episode-level false-alarm budget); falls back to
    /// `max` when the calibration has none.
    #[default]
    Conformal,
    /// The largest fused score seen on the training episodes (the paper's rule applied to
    /// the fused score).
    Max,
}

/// The profile file (see the module docs).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct ProfileFile {
    /// Name.
    pub name: String,
    /// Robot description path.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub robot: Option<PathBuf>,
    /// Where the ROS packages that the robot's `package://NAME/...` meshes name are:
    /// each a package folder or a folder holding packages (searched a few levels down),
    /// tried in order before the folders around the URDF (`vamos profile init` records
    /// the ones it found). Not read for archives or robots the service stores.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub robot_packages: Vec<PathBuf>,
    /// Camera description path (JSON [`CameraSpec`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub camera: Option<PathBuf>,
    /// Model bundle path.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub model: Option<PathBuf>,
    /// TV-L1 preset name.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub flow_preset: Option<String>,
    /// Which threshold drives the anomaly flag.
    #[serde(default)]
    pub alarm: AlarmRule,
    /// Pipeline parameters.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub pipeline: Option<PipelineConfig>,
    /// Topic names of this robot's bags (absent: the settings' `[episode.topics]`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub topics: Option<EpisodeTopics>,
    /// Manual threshold overrides, on top of the calibration.
    #[serde(default, skip_serializing_if = "ThresholdOverrides::is_empty")]
    pub thresholds: ThresholdOverrides,
    /// How per-frame flags become alarm events (`[alarm_events]`; absent: 3 of 5 frames).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub alarm_events: Option<crate::eval::alarm::Debounce>,
}

/// Manual thresholds that replace calibrated ones (`[thresholds]` of a profile; the
/// service's `PATCH` of a profile's thresholds). Each value given replaces its calibrated
/// counterpart; an absent one leaves the calibration's in force.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct ThresholdOverrides {
    /// Threshold on e_c, pixels at processing resolution.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub e_c: Option<f64>,
    /// Threshold on e_b, pixels.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub e_b: Option<f64>,
    /// Fused-score alarm threshold (`score >= alarm` alarms), in place of the alarm rule's.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub alarm: Option<f64>,
}

impl ThresholdOverrides {
    /// True when nothing is overridden.
    pub fn is_empty(&self) -> bool {
        self.e_c.is_none() && self.e_b.is_none() && self.alarm.is_none()
    }

    /// The first override that is not a finite number, as `(key, value)`.
    pub fn non_finite(&self) -> Option<(&'static str, f64)> {
        [("e_c", self.e_c), ("e_b", self.e_b), ("alarm", self.alarm)]
            .into_iter()
            .find_map(|(k, v)| v.filter(|x| !x.is_finite()).map(|x| (k, x)))
    }

    /// The `e_c`/`e_b` thresholds in force: the calibration's (none without one), each
    /// replaced by its override when given.
    pub fn thresholds(&self, calibration: Option<&Calibration>) -> Thresholds {
        let calibrated = calibration
            .map(|c| c.thresholds.clone())
            .unwrap_or_default();
        Thresholds {
            e_c: self.e_c.or(calibrated.e_c),
            e_b: self.e_b.or(calibrated.e_b),
            ..calibrated
        }
    }

    /// The fused-score alarm threshold in force: the override, else the calibration's
    /// under `rule`, else `+inf` (no alarms).
    pub fn alarm_threshold(&self, calibration: Option<&Calibration>, rule: AlarmRule) -> f64 {
        self.alarm
            .unwrap_or_else(|| calibration.map_or(f64::INFINITY, |c| c.alarm_threshold(rule)))
    }
}

/// Thresholds and how they were obtained (`<profile>.calibration.json`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct Calibration {
    /// When, seconds since the Unix epoch.
    pub created_unix_s: u64,
    /// sha256 of the model bundle the scores came from (`None`: no model).
    pub model_sha256: Option<String>,
    /// The episodes the maximum thresholds come from.
    pub training_episodes: Vec<String>,
    /// The held-out nominal episodes of the conformal threshold.
    pub calibration_episodes: Vec<String>,
    /// Frames scored on the training episodes.
    pub training_frames: usize,
    /// `e_c` and `e_b` thresholds: their maxima over the training episodes (the paper).
    pub thresholds: Thresholds,
    /// The largest fused score over the training episodes.
    pub score_max: f64,
    /// The split-conformal threshold on the fused score, from the held-out episodes.
    pub conformal: Option<ConformalThreshold>,
}

impl Calibration {
    /// The fused-score threshold of `rule`: a frame alarms when `score >= threshold`.
    /// For `max`, the next float above the training maximum (no training frame alarms).
    pub fn alarm_threshold(&self, rule: AlarmRule) -> f64 {
        match (rule, &self.conformal) {
            (AlarmRule::Conformal, Some(c)) => c.threshold,
            _ => self.score_max.next_up(),
        }
    }
}

/// A loaded profile: the file with its paths resolved, and its calibration if any.
#[derive(Debug, Clone)]
pub struct Profile {
    /// The profile file's path.
    pub path: PathBuf,
    /// Its contents, paths resolved against its folder.
    pub file: ProfileFile,
    /// The camera description, read.
    pub camera: Option<CameraSpec>,
    /// The calibration, if `vamos calibrate` has run.
    pub calibration: Option<Calibration>,
    /// The robot is one the service stores: it is loaded sealed
    /// ([`vamos_robot::Robot::load_stored`]), never reading files outside its package.
    pub robot_stored: bool,
}

impl Profile {
    /// Reads a profile, its camera description and its calibration (when present).
    pub fn load(path: &Path) -> Result<Self, ProfileError> {
        let text = read(path)?;
        let mut file: ProfileFile = toml::from_str(&text).map_err(|e| ProfileError::Invalid {
            path: path.into(),
            reason: e.to_string(),
        })?;
        if let Some((key, value)) = file.thresholds.non_finite() {
            return Err(ProfileError::Invalid {
                path: path.into(),
                reason: format!("thresholds.{key} = {value} is not a finite number"),
            });
        }
        if let Some(Err(e)) = file.alarm_events.map(|d| d.check()) {
            return Err(ProfileError::Invalid {
                path: path.into(),
                reason: e.to_string(),
            });
        }
        let dir = path.parent().unwrap_or(Path::new("."));
        for p in [&mut file.robot, &mut file.camera, &mut file.model]
            .into_iter()
            .flatten()
            .chain(file.robot_packages.iter_mut())
        {
            if p.is_relative() {
                *p = dir.join(&*p);
            }
        }
        let camera = match &file.camera {
            Some(c) => Some(serde_json::from_str::<CameraSpec>(&read(c)?).map_err(|e| {
                ProfileError::Invalid {
                    path: c.clone(),
                    reason: format!("not a camera description: {e}"),
                }
            })?),
            None => None,
        };
        let cal_path = Self::calibration_path_for(path);
        let calibration = if cal_path.exists() {
            Some(
                serde_json::from_str::<Calibration>(&read(&cal_path)?).map_err(|e| {
                    ProfileError::Invalid {
                        path: cal_path.clone(),
                        reason: format!("not a calibration: {e}"),
                    }
                })?,
            )
        } else {
            None
        };
        Ok(Self {
            path: path.into(),
            file,
            camera,
            calibration,
            robot_stored: false,
        })
    }

    /// Where the calibration of the profile at `path` lives.
    pub fn calibration_path_for(path: &Path) -> PathBuf {
        let stem = path
            .file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_else(|| "profile".into());
        path.with_file_name(format!("{stem}.calibration.json"))
    }

    /// Writes `calibration` beside the profile (atomically: a temporary file, then a
    /// rename, so a crash never leaves half a file).
    pub fn save_calibration(&mut self, calibration: Calibration) -> Result<PathBuf, ProfileError> {
        let path = Self::calibration_path_for(&self.path);
        let text =
            serde_json::to_string_pretty(&calibration).map_err(|e| ProfileError::Invalid {
                path: path.clone(),
                reason: e.to_string(),
            })?;
        let tmp = path.with_extension("json.tmp");
        std::fs::write(&tmp, text + "\n").map_err(|source| ProfileError::Io {
            path: tmp.clone(),
            source,
        })?;
        std::fs::rename(&tmp, &path).map_err(|source| ProfileError::Io {
            path: path.clone(),
            source,
        })?;
        self.calibration = Some(calibration);
        Ok(path)
    }

    /// The thresholds in force: the calibrated ones (none before calibration) with the
    /// profile's overrides on top.
    pub fn thresholds(&self) -> Thresholds {
        self.file.thresholds.thresholds(self.calibration.as_ref())
    }

    /// The fused-score alarm threshold in force (`score >= threshold` alarms): the
    /// override, else the calibration's under the profile's alarm rule, else `+inf`.
    pub fn alarm_threshold(&self) -> f64 {
        self.file
            .thresholds
            .alarm_threshold(self.calibration.as_ref(), self.file.alarm)
    }
}

fn read(path: &Path) -> Result<String, ProfileError> {
    std::fs::read_to_string(path).map_err(|source| ProfileError::Io {
        path: path.into(),
        source,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn profile_paths_resolve_against_its_folder_and_calibration_round_trips() {
        let dir = tempfile::tempdir().unwrap();
        std::fs::write(
            dir.path().join("camera.json"),
            r#"{"frame": "cam", "width": 320, "height": 240, "hfov_deg": 60.0}"#,
        )
        .unwrap();
        let path = dir.path().join("p.toml");
        std::fs::write(
            &path,
            "name = \"p\"\nrobot = \"r.urdf\"\ncamera = \"camera.json\"\nalarm = \"max\"\n\
             [pipeline]\nstride = 3\n[topics]\nimage = \"/head/image\"\n",
        )
        .unwrap();
        let mut p = Profile::load(&path).unwrap();
        assert_eq!(
            p.file.robot.as_deref(),
            Some(dir.path().join("r.urdf").as_path())
        );
        assert_eq!(p.camera.as_ref().unwrap().width, 320);
        assert_eq!(p.file.pipeline.as_ref().unwrap().stride, 3);
        let topics = p.file.topics.as_ref().unwrap();
        assert_eq!(topics.image.as_deref(), Some("/head/image"));
        assert!(p.calibration.is_none());
        assert_eq!(p.alarm_threshold(), f64::INFINITY);
        let cal = Calibration {
            created_unix_s: 1,
            model_sha256: None,
            training_episodes: vec!["a".into()],
            calibration_episodes: vec![],
            training_frames: 10,
            thresholds: Thresholds::paper(Some(2.0), None),
            score_max: 0.5,
            conformal: None,
        };
        let saved = p.save_calibration(cal.clone()).unwrap();
        assert_eq!(saved, dir.path().join("p.calibration.json"));
        let again = Profile::load(&path).unwrap();
        assert_eq!(again.calibration.as_ref(), Some(&cal));
        assert_eq!(
            again.alarm_threshold(),
            0.5f64.next_up(),
            "max rule, and conformal absent"
        );
        assert_eq!(again.thresholds().e_c, Some(2.0));
    }

    #[test]
    fn threshold_overrides_replace_calibrated_values_one_by_one() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("p.toml");
        std::fs::write(
            &path,
            "name = \"p\"\nalarm = \"max\"\n[thresholds]\ne_b = 7.5\nalarm = 0.25\n",
        )
        .unwrap();
        let mut p = Profile::load(&path).unwrap();
        // Before calibration: only the overrides.
        assert_eq!(p.thresholds(), Thresholds::paper(None, Some(7.5)));
        assert_eq!(p.alarm_threshold(), 0.25);
        p.calibration = Some(Calibration {
            created_unix_s: 1,
            model_sha256: None,
            training_episodes: vec![],
            calibration_episodes: vec![],
            training_frames: 0,
            thresholds: Thresholds::paper(Some(2.0), Some(3.0)),
            score_max: 0.5,
            conformal: None,
        });
        assert_eq!(
            p.thresholds(),
            Thresholds::paper(Some(2.0), Some(7.5)),
            "e_c calibrated, e_b overridden"
        );
        assert_eq!(p.alarm_threshold(), 0.25);
        p.file.thresholds.alarm = None;
        assert_eq!(
            p.alarm_threshold(),
            0.5f64.next_up(),
            "back to the max rule"
        );
        // Written back, the overrides survive; non-finite ones are refused.
        let text = toml::to_string(&p.file).unwrap();
        assert!(text.contains("e_b = 7.5"), "{text}");
        std::fs::write(&path, "name = \"p\"\n[thresholds]\ne_c = nan\n").unwrap();
        let e = Profile::load(&path).unwrap_err().to_string();
        assert!(e.contains("thresholds.e_c"), "{e}");
    }

    #[test]
    fn unknown_keys_and_missing_files_are_named() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("p.toml");
        std::fs::write(&path, "name = \"p\"\nrobt = \"r.urdf\"\n").unwrap();
        let e = Profile::load(&path).unwrap_err().to_string();
        assert!(e.contains("robt"), "{e}");
        std::fs::write(&path, "name = \"p\"\ncamera = \"nope.json\"\n").unwrap();
        let e = Profile::load(&path).unwrap_err().to_string();
        assert!(e.contains("nope.json"), "{e}");
    }
}
