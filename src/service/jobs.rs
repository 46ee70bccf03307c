//! Background jobs started through REST (profile calibrations). They live in memory: a
//! restart forgets them (a finished calibration is in the data directory, a running one
//! is lost and must be started again).

use crate::pipeline::Calibration;
use serde::Serialize;
use std::collections::BTreeMap;
use std::sync::Mutex;

/// Where a job is.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum JobState {
    /// Still working.
    Running,
    /// Done; its result is recorded.
    Succeeded,
    /// Ended with an error.
    Failed,
}

/// A job as `GET /v1/jobs/{id}` shows it.
#[derive(Debug, Clone, Serialize)]
pub struct JobInfo {
    /// Its id.
    pub id: u64,
    /// Where it is.
    pub state: JobState,
    /// The profile it calibrates.
    pub profile: String,
    /// Started, seconds since the Unix epoch.
    pub started_unix_s: u64,
    /// Why it failed.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub error: Option<String>,
    /// The calibration saved, once it succeeded.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub calibration: Option<Calibration>,
    /// Remarks of the calibration (no conformal threshold and why, ...).
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub notes: Vec<String>,
}

/// The jobs of this process.
#[derive(Debug, Default)]
pub struct Jobs {
    inner: Mutex<BTreeMap<u64, JobInfo>>,
}

impl Jobs {
    fn lock(&self) -> std::sync::MutexGuard<'_, BTreeMap<u64, JobInfo>> {
        self.inner.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// Records a new running job for `profile` and returns its id.
    pub fn start(&self, profile: &str) -> u64 {
        let mut jobs = self.lock();
        let id = jobs.keys().next_back().map_or(1, |k| k + 1);
        let started_unix_s = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map_or(0, |d| d.as_secs());
        jobs.insert(
            id,
            JobInfo {
                id,
                state: JobState::Running,
                profile: profile.into(),
                started_unix_s,
                error: None,
                calibration: None,
                notes: Vec::new(),
            },
        );
        id
    }

    /// Records the end of job `id`.
    pub fn finish(&self, id: u64, result: Result<(Calibration, Vec<String>), String>) {
        if let Some(job) = self.lock().get_mut(&id) {
            match result {
                Ok((calibration, notes)) => {
                    job.state = JobState::Succeeded;
                    job.calibration = Some(calibration);
                    job.notes = notes;
                }
                Err(e) => {
                    job.state = JobState::Failed;
                    job.error = Some(e);
                }
            }
        }
    }

    /// Job `id`.
    pub fn get(&self, id: u64) -> Option<JobInfo> {
        self.lock().get(&id).cloned()
    }

    /// Every job, oldest first.
    pub fn list(&self) -> Vec<JobInfo> {
        self.lock().values().cloned().collect()
    }
}
