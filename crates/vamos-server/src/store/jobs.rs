//! Job records (`jobs/<id>.json`): the history of background jobs (calibrations), kept
//! across restarts. A record still `running` when the directory is opened belongs to a
//! server that stopped while the job ran: [`Store::open`] marks it `failed` (the
//! calibration it was computing was never saved, so the profile is as it was).

use super::files::{list_dir, now_unix_s, read_json, remove_file_quiet, write_json};
use super::{JOB, State, Store, StoreError, StoreProblem};
use serde::{Deserialize, Serialize};
use std::path::Path;
use vamos_core::eval::DetectorThresholds;
use vamos_core::pipeline::Calibration;

/// Finished job records kept; older ones are removed as new jobs start.
pub const KEPT_JOBS: usize = 200;

/// Where a job is.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(rename_all = "snake_case")]
pub enum JobState {
    /// Still working.
    Running,
    /// Done; its result is recorded.
    Succeeded,
    /// Ended with an error (or the server stopped while it ran).
    Failed,
    /// Cancelled through the API before it finished.
    Cancelled,
}

impl JobState {
    /// Whether the job has ended.
    pub fn is_final(self) -> bool {
        self != Self::Running
    }
}

/// A job as `GET /v1/jobs/{id}` shows it, and as it is stored.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct JobInfo {
    /// Its id (unique in this data directory).
    pub id: u64,
    /// Where it is.
    pub state: JobState,
    /// The profile it calibrates.
    pub profile: String,
    /// Started, seconds since the Unix epoch.
    pub started_unix_s: u64,
    /// Ended, seconds since the Unix epoch.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub finished_unix_s: Option<u64>,
    /// The episodes it was given (file names for uploads, paths on the server).
    #[serde(default)]
    pub episodes: Vec<String>,
    /// The held-out episodes it was given.
    #[serde(default)]
    pub holdout: Vec<String>,
    /// Why it failed.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub error: Option<String>,
    /// The calibration saved, once it succeeded.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub calibration: Option<Calibration>,
    /// Remarks of the calibration (no conformal threshold and why, ...).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub notes: Vec<String>,
    /// A recalibration from the profile's nominal set: its `calibration` is a proposal,
    /// saved only when applied (`POST /v1/jobs/{id}/apply`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub proposal: Option<Proposal>,
}

/// What a recalibration proposes, to be looked at before it is applied.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct Proposal {
    /// `created_unix_s` of the calibration it revises (applying it is refused once the
    /// profile's calibration has changed).
    pub revises_unix_s: u64,
    /// The thresholds in force when it started.
    pub current: DetectorThresholds,
    /// The thresholds once applied.
    pub proposed: DetectorThresholds,
    /// Each nominal episode with its largest fused score before and after.
    pub episodes: Vec<ProposalEpisode>,
    /// When it was applied.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub applied_unix_s: Option<u64>,
}

/// One episode of a [`Proposal`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct ProposalEpisode {
    /// The episode (a kept session recording).
    pub name: String,
    /// Its largest fused score under the current calibration.
    pub max_score_before: f64,
    /// ... and under the proposed one.
    pub max_score_after: f64,
}

/// Reads `jobs/` at open: records by id; running ones are marked failed and rewritten;
/// unreadable ones are listed as problems (left on disk for inspection).
pub(super) fn scan_jobs(dir: &Path, state: &mut State) -> Result<(), StoreError> {
    let tmp = dir.join("tmp");
    for (file, path, is_dir) in list_dir(&dir.join("jobs"))? {
        let id = file
            .strip_suffix(".json")
            .and_then(|s| s.parse::<u64>().ok());
        let (Some(id), false) = (id, is_dir) else {
            state.strays.push(StoreProblem {
                kind: "entry",
                name: file,
                path,
                reason: "not a job record (jobs/<id>.json)".into(),
            });
            continue;
        };
        let mut job: JobInfo = match read_json(&path) {
            Ok(Some(j)) => j,
            Ok(None) => continue,
            Err(e) => {
                // Its id is not given again.
                state.next_job = state.next_job.max(id + 1);
                state.strays.push(StoreProblem {
                    kind: JOB,
                    name: id.to_string(),
                    path,
                    reason: e.to_string(),
                });
                continue;
            }
        };
        if job.id != id {
            state.strays.push(StoreProblem {
                kind: JOB,
                name: id.to_string(),
                path,
                reason: format!("the record names job {}", job.id),
            });
            continue;
        }
        if job.state == JobState::Running {
            job.state = JobState::Failed;
            job.finished_unix_s = Some(now_unix_s());
            job.error = Some(
                "interrupted: the server stopped while the job ran; nothing was saved, start it again"
                    .into(),
            );
            write_json(&tmp, &path, &job)?;
            tracing::warn!(job = id, profile = %job.profile, "job interrupted by a restart: marked failed");
        }
        state.next_job = state.next_job.max(id + 1);
        state.jobs.insert(id, job);
    }
    Ok(())
}

impl Store {
    fn job_file(&self, id: u64) -> std::path::PathBuf {
        self.inner.dir.join("jobs").join(format!("{id}.json"))
    }

    /// Records a new running job for `profile` and returns it (with its new id). Finished
    /// records beyond [`KEPT_JOBS`] are removed, oldest first.
    pub fn start_job(
        &self,
        profile: &str,
        episodes: Vec<String>,
        holdout: Vec<String>,
    ) -> Result<JobInfo, StoreError> {
        self.check_writable()?;
        let mut st = self.lock();
        let id = st.next_job.max(1);
        let job = JobInfo {
            id,
            state: JobState::Running,
            profile: profile.into(),
            started_unix_s: now_unix_s(),
            finished_unix_s: None,
            episodes,
            holdout,
            error: None,
            calibration: None,
            notes: Vec::new(),
            proposal: None,
        };
        write_json(&self.tmp_dir(), &self.job_file(id), &job)?;
        st.next_job = id + 1;
        st.jobs.insert(id, job.clone());
        let finished: Vec<u64> = st
            .jobs
            .values()
            .filter(|j| j.state.is_final())
            .map(|j| j.id)
            .collect();
        for old in finished
            .iter()
            .take(finished.len().saturating_sub(KEPT_JOBS))
        {
            remove_file_quiet(&self.job_file(*old));
            st.jobs.remove(old);
        }
        Ok(job)
    }

    /// Records the end of job `id`: `Ok` succeeded with its calibration and notes, `Err`
    /// failed (or cancelled, per `state`) with the reason. A job already ended stays as
    /// it is.
    pub fn finish_job(
        &self,
        id: u64,
        result: Result<(Calibration, Vec<String>), (JobState, String)>,
    ) -> Result<JobInfo, StoreError> {
        let mut st = self.lock();
        let Some(job) = st.jobs.get(&id).cloned() else {
            return Err(StoreError::NotFound {
                kind: JOB,
                name: id.to_string(),
            });
        };
        if job.state.is_final() {
            return Ok(job);
        }
        let mut job = job;
        job.finished_unix_s = Some(now_unix_s());
        match result {
            Ok((calibration, notes)) => {
                job.state = JobState::Succeeded;
                job.calibration = Some(calibration);
                job.notes = notes;
            }
            Err((state, reason)) => {
                job.state = if state == JobState::Cancelled {
                    JobState::Cancelled
                } else {
                    JobState::Failed
                };
                job.error = Some(reason);
            }
        }
        write_json(&self.tmp_dir(), &self.job_file(id), &job)?;
        st.jobs.insert(id, job.clone());
        Ok(job)
    }

    /// Job `id`.
    pub fn job(&self, id: u64) -> Result<JobInfo, StoreError> {
        self.lock()
            .jobs
            .get(&id)
            .cloned()
            .ok_or_else(|| StoreError::NotFound {
                kind: JOB,
                name: id.to_string(),
            })
    }

    /// Changes job `id`'s record with `f` (its proposal: set while it runs, marked applied
    /// once applied) and writes it; returns the record as written.
    pub fn update_job(&self, id: u64, f: impl FnOnce(&mut JobInfo)) -> Result<JobInfo, StoreError> {
        self.check_writable()?;
        let mut st = self.lock();
        let Some(job) = st.jobs.get_mut(&id) else {
            return Err(StoreError::NotFound {
                kind: JOB,
                name: id.to_string(),
            });
        };
        let mut updated = job.clone();
        f(&mut updated);
        write_json(&self.tmp_dir(), &self.job_file(id), &updated)?;
        *job = updated.clone();
        Ok(updated)
    }

    /// Every job record, oldest first.
    pub fn jobs(&self) -> Vec<JobInfo> {
        self.lock().jobs.values().cloned().collect()
    }

    /// Removes the record of a finished job; a running one is refused
    /// ([`StoreError::InUse`]: cancel it first).
    pub fn delete_job(&self, id: u64) -> Result<(), StoreError> {
        let mut st = self.lock();
        let Some(job) = st.jobs.get(&id) else {
            return Err(StoreError::NotFound {
                kind: JOB,
                name: id.to_string(),
            });
        };
        if !job.state.is_final() {
            return Err(StoreError::InUse {
                kind: JOB,
                name: id.to_string(),
                by: vec!["its own run (cancel it first)".into()],
            });
        }
        let path = self.job_file(id);
        std::fs::remove_file(&path).map_err(|e| StoreError::io(&path, e))?;
        super::files::sync_dir(&self.inner.dir.join("jobs"))?;
        st.jobs.remove(&id);
        Ok(())
    }
}
