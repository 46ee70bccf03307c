//! A profile loaded with its robot and model, ready to make [`Scorer`]s: what `vamos
//! score`, `calibrate`, `eval` and the service's sessions share.

use crate::episode::EpisodeConfig;
use crate::eval::{Detector, Thresholds};
use crate::pipeline::{
    PipelineConfig, Profile, ProfileError, RobotSetup, Scorer, ScorerError, ScorerParts,
};
use std::path::PathBuf;
use std::sync::Arc;
use vamos_model::{FlowModel, ModelConfig, ModelError};
use vamos_robot::render::RenderConfig;
use vamos_robot::{Robot, RobotConfig, RobotError};
use vamos_vision::VisionConfig;
use vamos_vision::flow::{FlowError, FlowParams};

/// Errors of loading a profile's parts.
#[derive(Debug, thiserror::Error)]
pub enum SetupError {
    /// The profile, its camera or its calibration.
    #[error(transparent)]
    Profile(#[from] ProfileError),
    /// The robot description.
    #[error("cannot load robot {path}: {source}")]
    Robot {
        /// Its path.
        path: PathBuf,
        /// Why.
        source: RobotError,
    },
    /// The profile names a robot without a camera.
    #[error("profile {profile} names a robot but no camera: add `camera = \"camera.json\"`")]
    NoCamera {
        /// The profile's path.
        profile: PathBuf,
    },
    /// The model bundle.
    #[error("cannot load model {path}: {source}")]
    Model {
        /// Its path.
        path: PathBuf,
        /// Why.
        source: ModelError,
    },
    /// The TV-L1 preset.
    #[error(transparent)]
    Flow(#[from] FlowError),
    /// The scorer refused its parts.
    #[error(transparent)]
    Scorer(#[from] ScorerError),
}

/// The settings sections the core falls back on and builds scorers with: everything of
/// the `vamos` settings but the server's `[service]` and the `[log]` sections.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct CoreSettings {
    /// Vision kernels (`[vision]`).
    pub vision: VisionConfig,
    /// The detection pipeline (`[pipeline]`): a profile without its own uses these.
    pub pipeline: PipelineConfig,
    /// Robot descriptions (`[robot]`).
    pub robot: RobotConfig,
    /// Rendering of the robot body (`[render]`).
    pub render: RenderConfig,
    /// The flow predictor (`[model]`).
    pub model: ModelConfig,
    /// Recorded episodes (`[episode]`).
    pub episode: EpisodeConfig,
}

/// The meshes `robot` lacks, by package (`package "NAME"`, or `not in a package`), in
/// the order the URDF names them.
fn missing_by_package(robot: &Robot) -> Vec<(String, Vec<String>)> {
    let mut groups: Vec<(String, Vec<String>)> = Vec::new();
    for m in robot.missing_meshes() {
        let key = m.package.as_ref().map_or_else(
            || "not in a package".to_string(),
            |p| format!("package {p:?}"),
        );
        match groups.iter_mut().find(|(k, _)| *k == key) {
            Some((_, list)) => list.push(m.path),
            None => groups.push((key, vec![m.path])),
        }
    }
    groups
}

/// A profile with its robot and model loaded.
#[derive(Clone)]
pub struct Setup {
    /// The settings it was loaded with.
    pub settings: CoreSettings,
    /// The profile.
    pub profile: Profile,
    /// Pipeline parameters in force (the profile's, else the settings').
    pub config: PipelineConfig,
    /// TV-L1 parameters in force.
    pub flow: FlowParams,
    /// The robot, if the profile has one.
    pub robot: Option<RobotSetup>,
    /// The model, if the profile has one.
    pub model: Option<Arc<FlowModel>>,
    /// How bags are read (the settings' `[episode]`, topics from the profile if it has
    /// them).
    pub episode: EpisodeConfig,
}

/// Which threshold on the fused score sets the anomaly flag, and why (`alarm_rule` of the
/// score summary).
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct AlarmRuleInForce {
    /// `conformal` (the calibration's split-conformal threshold), `max` (the training
    /// maximum of the fused score), `manual` (the profile's `[thresholds] alarm`) or
    /// `none` (not calibrated: no alarms).
    pub rule: &'static str,
    /// The threshold (`None`: no alarms).
    pub threshold: Option<f64>,
    /// True when the profile asks for the conformal threshold and the training maximum
    /// stands in for it.
    pub fallback: bool,
    /// Why this rule.
    pub why: String,
}

impl Setup {
    /// The alarm threshold and each detector's own threshold in force (the profile's
    /// thresholds under its fusion, resolved on whether it has a flow model).
    pub fn detector_thresholds(&self) -> crate::eval::DetectorThresholds {
        crate::eval::DetectorThresholds::new(
            &self.profile.thresholds(),
            self.profile.alarm_threshold(),
            self.config.fusion,
            self.model.is_some(),
        )
    }

    /// The alarm rule in force (see [`AlarmRuleInForce`]): which threshold sets the
    /// anomaly flag, and why, saying when the training maximum stands in for the conformal
    /// threshold.
    pub fn alarm_rule(&self) -> AlarmRuleInForce {
        use crate::pipeline::AlarmRule;
        let profile = &self.profile;
        let threshold = Some(profile.alarm_threshold()).filter(|t| t.is_finite());
        let rule = |rule, fallback, why: String| AlarmRuleInForce {
            rule,
            threshold,
            fallback,
            why,
        };
        if profile.file.thresholds.alarm.is_some() {
            return rule(
                "manual",
                false,
                "the profile's [thresholds] alarm replaces the calibrated threshold".into(),
            );
        }
        let Some(cal) = &profile.calibration else {
            return rule(
                "none",
                false,
                "the profile is not calibrated (`vamos calibrate`): no alarms".into(),
            );
        };
        match (profile.file.alarm, &cal.conformal) {
            (AlarmRule::Max, _) => rule(
                "max",
                false,
                "alarm = \"max\": the training maximum of the fused score".into(),
            ),
            (AlarmRule::Conformal, Some(c)) => rule(
                "conformal",
                false,
                format!(
                    "the split-conformal threshold at alpha {} over {} held-out episodes",
                    c.alpha, c.n
                ),
            ),
            (AlarmRule::Conformal, None) => {
                let n = cal.calibration_episodes.len();
                let held = if n == 0 {
                    "it was calibrated without held-out episodes".to_string()
                } else {
                    format!(
                        "its {n} held-out episode{} too few",
                        if n == 1 { " was" } else { "s were" }
                    )
                };
                rule(
                    "max",
                    true,
                    format!(
                        "the profile asks for the conformal threshold, but its calibration has \
                         none ({held}; at alpha 0.1, `vamos calibrate`'s default, it needs at \
                         least {}): alarms use the training maximum of the fused score instead; \
                         calibrate with more held-out nominal runs (`vamos calibrate --holdout`)",
                        crate::eval::conformal_episodes_needed(0.1)
                    ),
                )
            }
        }
    }

    /// What this profile cannot do that it asks for, said once (the live view shows it
    /// for each session): the conformal threshold's fallback or no alarms at all, and each
    /// detector switched on that cannot run with this profile (no robot, no flow model,
    /// no calibrated nominal states).
    pub fn fallbacks(&self) -> Vec<String> {
        let mut out = Vec::new();
        let rule = self.alarm_rule();
        if rule.fallback || rule.rule == "none" {
            out.push(rule.why);
        }
        let on = self.config.detectors;
        let robot = self.robot.is_some();
        let no_robot = "the profile has no robot (`robot` and `camera`)";
        for d in Detector::ALL.into_iter().filter(|&d| on.get(d)) {
            let why = if d.needs_robot() && !robot {
                Some(no_robot)
            } else {
                match d {
                    Detector::Flow => self
                        .model
                        .is_none()
                        .then_some("the profile has no flow model (`model`)"),
                    Detector::Kinematics => match &self.profile.calibration {
                        None => Some(
                            "the profile is not calibrated: e_k needs the calibration's \
                             nominal states",
                        ),
                        Some(c) if c.thresholds.kinematics.is_none() => {
                            Some("the calibration has no nominal robot states: calibrate again")
                        }
                        Some(_) => None,
                    },
                    Detector::Camera | Detector::Body | Detector::Scene => None,
                }
            };
            if let Some(why) = why {
                out.push(format!("{} does not run: {why}", d.key()));
            }
        }
        out
    }

    /// What the scored bags of this profile carry ([`crate::pipeline::layout`]): the
    /// detectors in force (`e_k` once calibrated with nominal states), and the anomaly
    /// map (calibrated scene statistics or a flow model).
    pub fn scored_content(&self) -> crate::pipeline::layout::ScoredContent {
        let mut detectors = self
            .config
            .detectors
            .in_force(self.robot.is_some(), self.model.is_some());
        let thresholds = self.profile.thresholds();
        detectors.kinematics &= thresholds.kinematics.is_some();
        crate::pipeline::layout::ScoredContent {
            detectors,
            anomaly_map: detectors.flow || (detectors.scene && thresholds.scene.is_some()),
        }
    }

    /// Reads the profile file at `path` and loads its robot, camera and model.
    pub fn load(
        settings: impl Into<CoreSettings>,
        path: &std::path::Path,
    ) -> Result<Self, SetupError> {
        Self::from_profile(settings, Profile::load(path)?)
    }

    /// Loads the robot and model of a profile already read.
    pub fn from_profile(
        settings: impl Into<CoreSettings>,
        profile: Profile,
    ) -> Result<Self, SetupError> {
        let settings = settings.into();
        let config = profile
            .file
            .pipeline
            .clone()
            .unwrap_or_else(|| settings.pipeline.clone());
        let flow = match &profile.file.flow_preset {
            Some(p) => FlowParams::preset(p)?,
            None => settings.vision.flow.clone(),
        };
        let robot = match (&profile.file.robot, &profile.camera) {
            (Some(path), Some(spec)) => {
                // A stored robot is sealed; a file's reads the profile's package paths.
                let robot = if profile.robot_stored {
                    Robot::load_stored(path, &settings.robot)
                } else {
                    Robot::load_with_packages(path, &profile.file.robot_packages, &settings.robot)
                }
                .map_err(|source| SetupError::Robot {
                    path: path.clone(),
                    source,
                })?;
                // Meshes not found in one line per package, not one per mesh.
                for (package, meshes) in missing_by_package(&robot) {
                    tracing::warn!(
                        robot = %path.display(),
                        "{} mesh file{} not found ({package}), left out (the camera does not \
                         see the links that use them: no body mask there): {}",
                        meshes.len(),
                        if meshes.len() == 1 { "" } else { "s" },
                        meshes.join(", ")
                    );
                }
                for w in robot.other_warnings() {
                    tracing::warn!(robot = %path.display(), "{w}");
                }
                let mount = robot.camera_for(spec).map_err(|source| SetupError::Robot {
                    path: path.clone(),
                    source,
                })?;
                Some(RobotSetup {
                    robot: Arc::new(robot),
                    mount,
                    intrinsics: spec.intrinsics().ok(),
                })
            }
            (Some(_), None) => {
                return Err(SetupError::NoCamera {
                    profile: profile.path.clone(),
                });
            }
            (None, _) => None,
        };
        let model = match &profile.file.model {
            Some(path) => Some(Arc::new(
                FlowModel::load(path, &settings.model.load_options()).map_err(|source| {
                    SetupError::Model {
                        path: path.clone(),
                        source,
                    }
                })?,
            )),
            None => None,
        };
        let mut episode = settings.episode.clone();
        if let Some(topics) = &profile.file.topics {
            episode.topics = topics.clone();
        }
        Ok(Self {
            settings,
            episode,
            profile,
            config,
            flow,
            robot,
            model,
        })
    }

    /// A scorer for the episode (or session) `key` (it seeds the predictor's sampling),
    /// with `config` (default: the profile's) and `model` (default: the profile's).
    pub fn scorer(
        &self,
        key: &str,
        thresholds: Thresholds,
        alarm_threshold: f64,
        heatmaps: bool,
        config: Option<&PipelineConfig>,
        model: Option<&Arc<FlowModel>>,
    ) -> Result<Scorer, SetupError> {
        Ok(Scorer::new(ScorerParts {
            config: config.unwrap_or(&self.config).clone(),
            flow: self.flow.clone(),
            registration: self.settings.vision.registration.clone(),
            network: self.settings.vision.network_input.clone(),
            render: self.settings.render.clone(),
            robot: self.robot.clone(),
            model: model.or(self.model.as_ref()).cloned(),
            samples: self.settings.model.samples,
            seed: self.settings.model.session_seed(key),
            thresholds,
            alarm_threshold,
            heatmaps,
        })?)
    }

    /// A scorer with the profile's calibrated thresholds (none: no alarms).
    pub fn calibrated_scorer(&self, key: &str, heatmaps: bool) -> Result<Scorer, SetupError> {
        self.scorer(
            key,
            self.profile.thresholds(),
            self.profile.alarm_threshold(),
            heatmaps,
            None,
            None,
        )
    }
}
