//! Background jobs started through REST (profile calibrations). Their records live in
//! the data directory ([`Store::start_job`]), so the job list survives a restart; a job
//! that was running when the server stopped is reported `failed` (interrupted) after it.
//! At most `max_jobs` run at once; a running job can be cancelled (it stops before its
//! next episode).

use crate::store::{JobInfo, JobState, Store, StoreError};
use std::collections::HashMap;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use vamos_core::pipeline::Calibration;

/// Why a job cannot start.
#[derive(Debug, thiserror::Error)]
pub enum JobError {
    /// `max_jobs` jobs are running.
    #[error(
        "{running} calibration job(s) are running, the most this server runs at once; retry when one has ended"
    )]
    Busy {
        /// How many run.
        running: usize,
    },
    /// The data directory refused the record.
    #[error(transparent)]
    Store(#[from] StoreError),
}

/// A running job's handle: its id and its cancel flag. The job counts as running (for
/// [`Jobs::stop_all`]) until its last handle is dropped: the job's thread drops it last.
#[derive(Debug, Clone)]
pub struct JobHandle {
    /// The job's id.
    pub id: u64,
    cancel: Arc<AtomicBool>,
    _alive: Arc<()>,
}

impl JobHandle {
    /// Whether the job was asked to stop.
    pub fn cancelled(&self) -> bool {
        self.cancel.load(Ordering::SeqCst)
    }
}

/// The jobs of this server: the stored records and the running jobs' cancel flags.
#[derive(Debug)]
pub struct Jobs {
    store: Store,
    max_running: usize,
    running: Mutex<HashMap<u64, Arc<AtomicBool>>>,
    /// One strong count per live job handle beside this one.
    alive: Arc<()>,
    /// Set by [`Jobs::stop_all`]: a job stopped now was interrupted, not cancelled.
    stopping: AtomicBool,
}

impl Jobs {
    /// Jobs over `store`, at most `max_running` at once (0 counts as 1).
    pub fn new(store: Store, max_running: usize) -> Self {
        Self {
            store,
            max_running: max_running.max(1),
            running: Mutex::new(HashMap::new()),
            alive: Arc::new(()),
            stopping: AtomicBool::new(false),
        }
    }

    /// Asks every running job to stop and waits, at most `grace`, until their threads
    /// have let go of their handles (and with them of the data directory); whether they
    /// all did. Blocking. For shutdown: a job left running would hold the store's lock.
    pub fn stop_all(&self, grace: std::time::Duration) -> bool {
        self.stopping.store(true, Ordering::SeqCst);
        for flag in self.running().values() {
            flag.store(true, Ordering::SeqCst);
        }
        let deadline = std::time::Instant::now() + grace;
        while Arc::strong_count(&self.alive) > 1 {
            if std::time::Instant::now() >= deadline {
                return false;
            }
            std::thread::sleep(std::time::Duration::from_millis(10));
        }
        true
    }

    fn running(&self) -> std::sync::MutexGuard<'_, HashMap<u64, Arc<AtomicBool>>> {
        self.running.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// Refuses as [`Jobs::start`] would if it were called now (checked before a job's
    /// episodes are uploaded; `start` checks again).
    pub fn check_room(&self) -> Result<(), JobError> {
        let running = self.running().len();
        if running >= self.max_running {
            return Err(JobError::Busy { running });
        }
        Ok(())
    }

    /// Records a new running job for `profile` with its inputs' names.
    pub fn start(
        &self,
        profile: &str,
        episodes: Vec<String>,
        holdout: Vec<String>,
    ) -> Result<JobHandle, JobError> {
        let mut running = self.running();
        if running.len() >= self.max_running {
            return Err(JobError::Busy {
                running: running.len(),
            });
        }
        let job = self.store.start_job(profile, episodes, holdout)?;
        let cancel = Arc::new(AtomicBool::new(false));
        running.insert(job.id, cancel.clone());
        Ok(JobHandle {
            id: job.id,
            cancel,
            _alive: self.alive.clone(),
        })
    }

    /// Records the end of a job: succeeded with its calibration, or failed (cancelled
    /// when its cancel flag was set) with the reason.
    pub fn finish(&self, job: &JobHandle, result: Result<(Calibration, Vec<String>), String>) {
        let result = result.map_err(|e| {
            if job.cancelled() && self.stopping.load(Ordering::SeqCst) {
                (
                    JobState::Failed,
                    "interrupted: the server stopped while the job ran; nothing was saved, start it again"
                        .to_string(),
                )
            } else if job.cancelled() {
                (JobState::Cancelled, "cancelled through the API".to_string())
            } else {
                (JobState::Failed, e)
            }
        });
        if let Err(e) = self.store.finish_job(job.id, result) {
            tracing::error!(job = job.id, "cannot record the end of the job: {e}");
        }
        self.running().remove(&job.id);
    }

    /// Asks running job `id` to stop; `Ok(false)` when it has already ended.
    pub fn cancel(&self, id: u64) -> Result<bool, StoreError> {
        let job = self.store.job(id)?;
        match self.running().get(&id) {
            Some(flag) if !job.state.is_final() => {
                flag.store(true, Ordering::SeqCst);
                Ok(true)
            }
            _ => Ok(false),
        }
    }

    /// Job `id`.
    pub fn get(&self, id: u64) -> Result<JobInfo, StoreError> {
        self.store.job(id)
    }

    /// Every job, oldest first.
    pub fn list(&self) -> Vec<JobInfo> {
        self.store.jobs()
    }

    /// Removes a finished job's record.
    pub fn delete(&self, id: u64) -> Result<(), StoreError> {
        self.store.delete_job(id)
    }
}
