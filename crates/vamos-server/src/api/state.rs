//! The state the gRPC and REST handlers share.

use super::auth::Tokens;
use crate::config::Settings;
use crate::session::budget::{UploadPlane, UploadTicket, Uploads};
use crate::session::calibration::Calibrator;
use crate::session::fleet::Fleet;
use crate::session::jobs::Jobs;
use crate::session::metrics::Metrics;
use crate::session::{Hub, ProfileCatalog, SessionError, SessionSlot, admission};
use crate::store::{ModelValidator, Store};
use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::AtomicBool;

/// State shared by the gRPC and REST handlers.
pub struct Shared {
    /// The settings the server started with.
    pub settings: Settings,
    /// Sessions and workers.
    pub hub: Arc<Hub>,
    /// Profiles.
    pub profiles: Arc<ProfileCatalog>,
    /// The data directory: models, robots, profiles, calibrations.
    pub store: Store,
    /// The store shared with other replicas, when configured.
    pub fleet: Option<Arc<Fleet>>,
    /// Calibration jobs (their records are in the data directory).
    pub jobs: Arc<Jobs>,
    /// Bearer tokens.
    pub tokens: Tokens,
    /// Set once when the server begins to stop.
    pub stop: tokio::sync::watch::Sender<bool>,
    /// The server is up (listeners bound, profiles loaded).
    pub ready: AtomicBool,
    /// Uploads in progress and their temporary disk.
    pub uploads: Uploads,
    /// Held while an uploaded model is validated (one at a time).
    pub model_validation: tokio::sync::Mutex<()>,
    /// How uploaded models are validated (a bounded child process).
    pub model_validator: ModelValidator,
}

impl Shared {
    /// Where episode uploads are buffered (the data directory's `tmp/`, emptied when the
    /// store opens).
    pub fn upload_dir(&self) -> PathBuf {
        self.store.dir().join("tmp")
    }

    /// The metrics.
    pub fn metrics(&self) -> &Metrics {
        self.hub.metrics()
    }

    /// Admits an admin-plane upload (a model, a robot, calibration episodes) declaring
    /// `declared` bytes before its body is read (an upload slot and its disk).
    pub fn admit_upload(&self, declared: Option<u64>) -> Result<UploadTicket, SessionError> {
        admission::admit_upload(&self.hub, &self.uploads, UploadPlane::Admin, declared)
    }

    /// Admits an episode to score before its body is read: a session place, then an
    /// upload slot.
    pub fn admit_episode(
        &self,
        declared: Option<u64>,
    ) -> Result<(SessionSlot, UploadTicket), SessionError> {
        admission::admit_episode(&self.hub, &self.uploads, declared)
    }

    /// Where calibration jobs run.
    pub fn calibrator(&self) -> Calibrator {
        Calibrator {
            profiles: self.profiles.clone(),
            store: self.store.clone(),
            jobs: self.jobs.clone(),
            budget: self.hub.budget().clone(),
        }
    }
}
