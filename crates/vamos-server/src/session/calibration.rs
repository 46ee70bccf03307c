//! Calibration jobs: a stored profile calibrated from nominal episodes (files or folders
//! on the server, or uploaded with the request), scored in the background one after
//! another, the calibration saved to the data directory. The job's record says how it
//! ended ([`super::jobs`]).

use super::budget::{ByteBudget, DECODE_WAIT, DecodeRoom};
use super::jobs::{JobError, JobHandle, Jobs};
use super::profiles::{LoadedProfile, ProfileCatalog, ProfileLookupError};
use crate::store::{JobInfo, JobState, Proposal, ProposalEpisode, Store, StoreError};
use std::path::{Path, PathBuf};
use std::sync::Arc;
use vamos_core::episode::files::{ExpandError, expand_episodes};
use vamos_core::episode::{EpisodeError, McapEpisode};
use vamos_core::pipeline::Calibration;
use vamos_core::pipeline::calibration::{calibrate, revise};
use vamos_core::pipeline::offline::{EpisodeScores, score_episode as score_offline};

fn default_alpha() -> f64 {
    0.1
}

/// What a calibration job scores: training episodes, held-out episodes (files or
/// folders of `.mcap` files) and the conformal level. As a JSON body of
/// `POST /v1/profiles/{name}/calibrate` it names files on the server.
#[derive(Debug, Clone, serde::Deserialize, schemars::JsonSchema)]
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

/// An episode of a profile's nominal set: the kept recording of a session whose alarm an
/// operator marked as a false alarm.
#[derive(Debug, Clone, PartialEq, serde::Serialize, schemars::JsonSchema)]
pub struct NominalEpisode {
    /// The session.
    pub session_id: String,
    /// Its alarms marked as false alarms.
    pub alarms: Vec<String>,
    /// The recording's file name (in the data directory's `recordings/`).
    pub recording: String,
    /// Whether the session has ended (a recording in progress is not used yet).
    pub finished: bool,
    /// Its size on disk, bytes (once finished).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub bytes: Option<u64>,
}

/// The nominal set of `profile`: the kept recordings (in `recordings`) of the sessions
/// with an alarm marked as a false alarm, one per session, oldest mark first.
pub fn nominal_set(
    store: &Store,
    recordings: &Path,
    profile: &str,
) -> Result<Vec<NominalEpisode>, StoreError> {
    let mut out: Vec<NominalEpisode> = Vec::new();
    let mut marked = store.marked_alarms(Some(profile))?;
    marked.sort_by_key(|a| a.false_alarm.as_ref().map_or(0, |m| m.marked_unix_s));
    for a in marked {
        let Some(file) = a.recording.clone() else {
            continue;
        };
        if let Some(e) = out.iter_mut().find(|e| e.session_id == a.session_id) {
            e.alarms.push(a.id);
            continue;
        }
        let path = recordings.join(&file);
        let bytes = std::fs::metadata(&path).ok().map(|m| m.len());
        let in_progress = recordings.join(format!("{file}.part")).is_file();
        if bytes.is_none() && !in_progress {
            continue; // removed by hand: nothing to score
        }
        out.push(NominalEpisode {
            session_id: a.session_id,
            alarms: vec![a.id],
            recording: file,
            finished: bytes.is_some(),
            bytes,
        });
    }
    Ok(out)
}

/// A recalibration that cannot start, or a proposal that cannot be applied.
#[derive(Debug, thiserror::Error)]
pub enum RecalibrationRefused {
    /// The profile does not resolve or load.
    #[error(transparent)]
    Profile(#[from] ProfileLookupError),
    /// Nothing to revise.
    #[error("profile {name:?} is not calibrated: calibrate it from nominal episodes first")]
    NotCalibrated {
        /// The profile.
        name: String,
    },
    /// No finished episode in the nominal set.
    #[error(
        "profile {name:?} has no finished episode in its nominal set: mark a false alarm of a \
         recorded session ([service] record_sessions) and let the session end"
    )]
    NoNominalEpisodes {
        /// The profile.
        name: String,
    },
    /// The job is not a finished recalibration.
    #[error("job {id} is not a finished recalibration with a proposal")]
    NotAProposal {
        /// The job.
        id: u64,
    },
    /// Applied already.
    #[error("job {id}'s proposal was applied already")]
    Applied {
        /// The job.
        id: u64,
    },
    /// The profile's calibration changed since the proposal was made.
    #[error(
        "profile {name:?} was calibrated again since job {id} made its proposal: start a new \
         recalibration"
    )]
    Stale {
        /// The profile.
        name: String,
        /// The job.
        id: u64,
    },
    /// No job slot, or the store.
    #[error(transparent)]
    Job(#[from] JobError),
    /// The store.
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
    /// The server's memory budget: each image a job decodes is charged to it first.
    pub budget: Arc<ByteBudget>,
}

impl Calibrator {
    /// Saves `calibration` as profile `name`'s: a stored profile's in the data directory;
    /// a profile file's in the data directory too, in force over the file's own
    /// ([`ProfileCatalog::save_file_calibration`]: the file is not written). Blocking.
    fn save<E: From<StoreError> + From<ProfileLookupError>>(
        &self,
        name: &str,
        calibration: Calibration,
    ) -> Result<(), E> {
        if self.profiles.is_file(name) {
            self.profiles.save_file_calibration(name, calibration)?;
        } else {
            self.store.save_calibration(name, calibration)?;
        }
        Ok(())
    }

    /// Starts a job calibrating profile `name` (stored or a file) (`episodes` and `holdout`: the
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
            // The uploaded episodes go with the job, then the store; the handle last: the
            // job counts as running until then (Jobs::stop_all).
            drop(keep);
            drop(this);
            drop(job);
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
        let mut refused = Vec::new();
        let mut outcome = calibrate(
            &training,
            &holdout,
            req.alpha,
            model_sha256,
            &setup.config,
            |episodes, thresholds| {
                let scores = score_all(&profile, episodes, None, thresholds, &self.budget, job)?;
                refused.extend(refused_frames(&scores));
                Ok::<_, CalibrationFailed>(scores)
            },
        )?;
        refused.dedup();
        outcome.notes.extend(refused);
        if job.cancelled() {
            return Err(CalibrationFailed::Cancelled);
        }
        self.save::<CalibrationFailed>(name, outcome.calibration.clone())?;
        Ok((outcome.calibration, outcome.notes))
    }

    /// Starts a job revising stored profile `name`'s calibration with its nominal set
    /// (the finished recordings in `recordings`, see [`nominal_set`]): it scores them with
    /// the profile as it is and records a [`Proposal`] ([`revise`]); nothing is saved
    /// until [`Calibrator::apply`]. Returns the job's id. Needs a tokio runtime; blocking
    /// (file I/O) before it returns.
    pub fn recalibrate(
        &self,
        name: String,
        recordings: &Path,
    ) -> Result<u64, RecalibrationRefused> {
        let profile = self.profiles.get(&name)?;
        let Some(current) = profile.setup.profile.calibration.clone() else {
            return Err(RecalibrationRefused::NotCalibrated { name });
        };
        let (episodes, sessions): (Vec<PathBuf>, Vec<String>) =
            nominal_set(&self.store, recordings, &name)?
                .into_iter()
                .filter(|e| e.finished)
                .map(|e| (recordings.join(e.recording), e.session_id))
                .unzip();
        if episodes.is_empty() {
            return Err(RecalibrationRefused::NoNominalEpisodes { name });
        }
        let names = episodes.iter().map(|p| p.display().to_string()).collect();
        let job = self.jobs.start(&name, names, Vec::new())?;
        let id = job.id;
        let this = self.clone();
        tokio::task::spawn_blocking(move || {
            let result = this.propose(&profile, &current, &episodes, &sessions, &job);
            if let Err(e) = &result {
                tracing::warn!(job = id, profile = %name, "recalibration failed: {e}");
            }
            this.jobs.finish(&job, result.map_err(|e| e.to_string()));
            drop(this);
            drop(job);
        });
        Ok(id)
    }

    /// The recalibration's work (blocking): scores the episodes, revises the calibration
    /// and records the proposal on the job (before the job is finished with it).
    fn propose(
        &self,
        profile: &LoadedProfile,
        current: &Calibration,
        episodes: &[PathBuf],
        sessions: &[String],
        job: &JobHandle,
    ) -> Result<(Calibration, Vec<String>), CalibrationFailed> {
        let setup = &profile.setup;
        // Seeded as their sessions were: a recording scores as its session did.
        let scores = score_all(
            profile,
            episodes,
            Some(sessions),
            setup.profile.thresholds(),
            &self.budget,
            job,
        )?;
        let revision = revise(current, &setup.config, setup.model.is_some(), &scores);
        let mut after = setup.profile.clone();
        after.calibration = Some(revision.calibration.clone());
        let proposed = vamos_core::eval::DetectorThresholds::new(
            &after.thresholds(),
            after.alarm_threshold(),
            setup.config.fusion,
            setup.model.is_some(),
        );
        let mut notes = revision.notes;
        notes.extend(refused_frames(&scores));
        if setup.profile.file.thresholds.alarm.is_some() {
            notes.push(
                "the profile's own alarm threshold ([thresholds] alarm) stays in force".into(),
            );
        }
        let proposal = Proposal {
            revises_unix_s: current.created_unix_s,
            current: setup.detector_thresholds(),
            proposed,
            episodes: revision
                .episodes
                .into_iter()
                .map(|(name, before, after)| ProposalEpisode {
                    name,
                    max_score_before: before,
                    max_score_after: after,
                })
                .collect(),
            applied_unix_s: None,
        };
        if job.cancelled() {
            return Err(CalibrationFailed::Cancelled);
        }
        self.store
            .update_job(job.id, |j| j.proposal = Some(proposal))?;
        Ok((revision.calibration, notes))
    }

    /// Applies recalibration job `id`'s proposal: its calibration becomes the profile's
    /// (sessions opened from now on use it) and the job records when. Refused for a job
    /// that is not a finished recalibration, one applied already, and when the profile's
    /// calibration changed since the proposal. Blocking (file I/O).
    pub fn apply(&self, id: u64) -> Result<JobInfo, RecalibrationRefused> {
        let job = self.store.job(id)?;
        let (Some(proposal), Some(calibration), JobState::Succeeded) =
            (&job.proposal, &job.calibration, job.state)
        else {
            return Err(RecalibrationRefused::NotAProposal { id });
        };
        if proposal.applied_unix_s.is_some() {
            return Err(RecalibrationRefused::Applied { id });
        }
        let profile = self.profiles.get(&job.profile)?;
        let now = profile.setup.profile.calibration.as_ref();
        if now.map(|c| c.created_unix_s) != Some(proposal.revises_unix_s) {
            return Err(RecalibrationRefused::Stale {
                name: job.profile.clone(),
                id,
            });
        }
        self.save::<RecalibrationRefused>(&job.profile, calibration.clone())?;
        self.profiles.invalidate_profile(&job.profile);
        let applied = crate::store::now_s();
        let job = self.store.update_job(id, |j| {
            if let Some(p) = j.proposal.as_mut() {
                p.applied_unix_s = Some(applied);
            }
        })?;
        tracing::info!(job = id, profile = %job.profile, "recalibration applied");
        Ok(job)
    }
}

/// A note per episode with frames left out (refused by the memory budget, or bad
/// frames), so that a calibration says what it did not see.
fn refused_frames(scores: &[EpisodeScores]) -> Vec<String> {
    scores
        .iter()
        .filter_map(|e| {
            let first = e.frame_errors.first()?;
            Some(format!(
                "episode {}: {} frame(s) left out (first: {})",
                e.name,
                e.frame_errors.len(),
                first.message
            ))
        })
        .collect()
}

/// Scores `episodes` with `profile` (no alarm threshold) and `thresholds`, one after
/// another, the predictor's sampling seeded with each one's name or its entry of
/// `seeds`; each image's decoding is charged to `budget` first (waiting for room up to
/// [`DECODE_WAIT`], then the frame is left out); stops before the next one once `job` is
/// cancelled.
fn score_all(
    profile: &LoadedProfile,
    episodes: &[PathBuf],
    seeds: Option<&[String]>,
    thresholds: vamos_core::eval::Thresholds,
    budget: &Arc<ByteBudget>,
    job: &JobHandle,
) -> Result<Vec<EpisodeScores>, CalibrationFailed> {
    let setup = &profile.setup;
    episodes
        .iter()
        .enumerate()
        .map(|(i, path)| {
            if job.cancelled() {
                return Err(CalibrationFailed::Cancelled);
            }
            let failed = |e: Box<dyn std::error::Error + Send + Sync>| CalibrationFailed::Scoring {
                path: path.clone(),
                source: e,
            };
            let episode = McapEpisode::open(path, &setup.episode)
                .map_err(|e| failed(e.into()))?
                .with_decode_budget(DecodeRoom::new(budget.clone(), DECODE_WAIT));
            let seed = seeds
                .and_then(|s| s.get(i))
                .map_or(episode.name(), String::as_str);
            let mut scorer = setup
                .scorer(seed, thresholds.clone(), f64::INFINITY, false, None, None)
                .map_err(|e| failed(e.into()))?;
            score_offline::<EpisodeError>(&mut scorer, &episode, |_, _| Ok(()))
                .map_err(|e| failed(e.into()))
        })
        .collect()
}
