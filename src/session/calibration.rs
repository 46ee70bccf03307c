//! Calibration jobs: a stored profile calibrated from nominal episodes (files or folders
//! on the server, or uploaded with the request), scored in the background one after
//! another, the calibration saved to the data directory. The job's record says how it
//! ended ([`super::jobs`]).

use super::jobs::{JobError, JobHandle, Jobs};
use super::profiles::{ProfileCatalog, ProfileLookupError};
use crate::episode::files::{ExpandError, expand_episodes};
use crate::episode::{EpisodeError, McapEpisode};
use crate::pipeline::Calibration;
use crate::pipeline::calibration::calibrate;
use crate::pipeline::offline::score_episode as score_offline;
use crate::store::{Store, StoreError};
use std::path::PathBuf;
use std::sync::Arc;

fn default_alpha() -> f64 {
    0.1
}

/// What a calibration job scores: training episodes, held-out episodes (files or
/// folders of `.mcap` files) and the conformal level. As a JSON body of
/// `POST /v1/profiles/{name}/calibrate` it names files on the server.
#[derive(Debug, Clone, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CalibrationRequest {
    /// Nominal training episodes.
    pub episodes: Vec<PathBuf>,
    /// Held-out nominal episodes.
    #[serde(default)]
    pub holdout: Vec<PathBuf>,
    /// Conformal miscoverage level, in (0, 1).
    #[serde(default = "default_alpha")]
    pub alpha: f64,
}

impl Default for CalibrationRequest {
    fn default() -> Self {
        Self {
            episodes: Vec::new(),
            holdout: Vec::new(),
            alpha: default_alpha(),
        }
    }
}

/// A calibration request that cannot start.
#[derive(Debug, thiserror::Error)]
pub enum CalibrationRefused {
    /// No training episode named.
    #[error("`episodes` is empty")]
    NoEpisodes,
    /// A level outside (0, 1).
    #[error("alpha {alpha} is not in (0, 1)")]
    BadAlpha {
        /// The level given.
        alpha: f64,
    },
}

impl CalibrationRequest {
    /// Refuses a request no job could run.
    pub fn check(&self) -> Result<(), CalibrationRefused> {
        if self.episodes.is_empty() {
            return Err(CalibrationRefused::NoEpisodes);
        }
        if !(self.alpha > 0.0 && self.alpha < 1.0) {
            return Err(CalibrationRefused::BadAlpha { alpha: self.alpha });
        }
        Ok(())
    }
}

/// Why a calibration job failed (the reason its record keeps).
#[derive(Debug, thiserror::Error)]
pub enum CalibrationFailed {
    /// The profile does not resolve or load.
    #[error(transparent)]
    Profile(#[from] ProfileLookupError),
    /// An episode file or folder named in the request.
    #[error(transparent)]
    Episodes(#[from] ExpandError),
    /// No training episode after expansion.
    #[error("no training episodes")]
    NoTraining,
    /// An episode that does not score.
    #[error("{}: {source}", path.display())]
    Scoring {
        /// The episode.
        path: PathBuf,
        /// Why (opening the bag, building the scorer, scoring).
        #[source]
        source: Box<dyn std::error::Error + Send + Sync>,
    },
    /// Cancelled through the API.
    #[error("cancelled")]
    Cancelled,
    /// The calibration could not be saved.
    #[error(transparent)]
    Store(#[from] StoreError),
}

/// Where calibration jobs run: the profiles, the data directory and the job records.
#[derive(Clone)]
pub struct Calibrator {
    /// The profiles (a job's profile is reloaded once it is calibrated).
    pub profiles: Arc<ProfileCatalog>,
    /// The data directory (the calibration is saved there).
    pub store: Store,
    /// The job records.
    pub jobs: Arc<Jobs>,
}

impl Calibrator {
    /// Starts a job calibrating stored profile `name` (`episodes` and `holdout`: the
    /// inputs' names for the job's record). `keep` (uploaded episodes and their disk) is
    /// dropped when the job ends. Returns the job's id. Needs a tokio runtime.
    pub fn start<K: Send + 'static>(
        &self,
        name: String,
        request: CalibrationRequest,
        episodes: Vec<String>,
        holdout: Vec<String>,
        keep: K,
    ) -> Result<u64, JobError> {
        let job = self.jobs.start(&name, episodes, holdout)?;
        let id = job.id;
        let this = self.clone();
        tokio::task::spawn_blocking(move || {
            let result = this.run(&name, &request, &job);
            match &result {
                Ok(_) => {
                    this.profiles.invalidate_profile(&name);
                    tracing::info!(job = id, profile = %name, "calibration job succeeded");
                }
                Err(e) => tracing::warn!(job = id, profile = %name, "calibration job failed: {e}"),
            }
            this.jobs.finish(&job, result.map_err(|e| e.to_string()));
            // The uploaded episodes go with the job.
            drop(keep);
        });
        Ok(id)
    }

    /// The job's work (blocking): scores the episodes with the profile, saves the
    /// calibration. Stops before the next episode once `job` is cancelled.
    fn run(
        &self,
        name: &str,
        req: &CalibrationRequest,
        job: &JobHandle,
    ) -> Result<(Calibration, Vec<String>), CalibrationFailed> {
        let profile = self.profiles.get(name)?;
        let setup = &profile.setup;
        let training = expand_episodes(&req.episodes)?;
        let holdout = expand_episodes(&req.holdout)?;
        if training.is_empty() {
            return Err(CalibrationFailed::NoTraining);
        }
        let model_sha256 = setup.model.as_ref().map(|m| m.sha256().to_string());
        let outcome = calibrate(
            &training,
            &holdout,
            req.alpha,
            model_sha256,
            &setup.config,
            |episodes, thresholds| {
                episodes
                    .iter()
                    .map(|path| {
                        if job.cancelled() {
                            return Err(CalibrationFailed::Cancelled);
                        }
                        let failed = |e: Box<dyn std::error::Error + Send + Sync>| {
                            CalibrationFailed::Scoring {
                                path: path.clone(),
                                source: e,
                            }
                        };
                        let episode = McapEpisode::open(path, &setup.episode)
                            .map_err(|e| failed(e.into()))?;
                        let mut scorer = setup
                            .scorer(
                                episode.name(),
                                thresholds.clone(),
                                f64::INFINITY,
                                false,
                                None,
                                None,
                            )
                            .map_err(|e| failed(e.into()))?;
                        score_offline::<EpisodeError>(&mut scorer, &episode, |_, _| Ok(()))
                            .map_err(|e| failed(e.into()))
                    })
                    .collect()
            },
        )?;
        if job.cancelled() {
            return Err(CalibrationFailed::Cancelled);
        }
        self.store
            .save_calibration(name, outcome.calibration.clone())?;
        Ok((outcome.calibration, outcome.notes))
    }
}
