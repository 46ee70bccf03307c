//! The service's data directory: models (versioned), robots, profiles and their
//! calibrations, persisted so that a restart finds everything as it was.
//!
//! Synchronous (std::fs only); the server calls it from blocking tasks. One [`Store`]
//! per directory (a lock file enforces it); clones share it, and every method takes
//! `&self` (one mutex orders the changes).
//!
//! # Layout
//!
//! ```text
//! <dir>/store.lock                         held (flock) while a Store has the directory open
//! <dir>/tmp/                               uploads in progress, temporary files; emptied on open
//! <dir>/models/<name>/index.json           versions, active version, next version number
//! <dir>/models/<name>/<version>.vamos      the bundle of each version
//! <dir>/robots/<name>/meta.json            format, revision, checksum, validator summary
//! <dir>/robots/<name>/<revision>.<ext>     the package: .urdf, .tar.gz or .zip
//! <dir>/profiles/<name>/profile.json       the ProfileSpec and timestamps
//! <dir>/profiles/<name>/calibration.json   the profile's Calibration, once saved
//! <dir>/jobs/<id>.json                     a background job's record (calibrations)
//! <dir>/alarms/<id>.json                   an alarm marked as false (the nominal set)
//! <dir>/ended/<key>.json                   a robot's ended live session as the live view
//!                                          keeps it (summary, downsampled timeline, alarms)
//! <dir>/file-calibrations/<name>.json      a server profile file's calibration made by the
//!                                          service (it replaces the file's own)
//! ```
//!
//! Every metadata file (`*.json`) is an envelope `{"format": "vamos-store/1", "sha256":
//! ..., "body": ...}` whose `sha256` is that of the body's compact JSON; each data file's
//! sha256 and size are recorded in its metadata.
//!
//! # Durability
//!
//! - Every write goes to a temporary file in `tmp/` (same file system), is fsynced, then
//!   renamed into place and the folder fsynced: readers and a restart see the old content
//!   or the new, never a part. Uploads stream to `tmp/` (hashed as they arrive, refused
//!   past [`StoreLimits`]) and are renamed in only after the validator accepted them.
//! - A new object's folder is assembled in `tmp/` and renamed in whole; a deleted one is
//!   renamed into `tmp/` first. Within an existing object the metadata file is the commit
//!   point: a data file is placed before the metadata naming it is written, and removed
//!   after the metadata no longer names it.
//! - [`Store::open`] removes what a crash can leave: everything in `tmp/`, and data
//!   files no metadata names ([`OpenReport`]). It verifies the checksum of every metadata
//!   and data file; what fails is logged, listed by [`Store::problems`] and never served
//!   (a [`StoreError::Corrupt`] instead) until it is deleted or replaced. A name whose
//!   metadata is unreadable is quarantined: only deleting it is allowed.
//! - Checksums are verified at open only; paths handed out stay valid until the object
//!   is deleted or (robots) replaced, which removes the file at once.
//!
//! # Rules
//!
//! - Names are `[A-Za-z0-9._-]{1,64}`, not starting with `.` ([`StoreError::BadName`]).
//! - Model versions: the first upload of a name is version 1 and active; each later one
//!   gets one more than the largest ever given under that name, also after deletes.
//!   Deleting a version is refused ([`StoreError::InUse`]) while a profile pins it, and
//!   for the active version while other versions exist (make another active first) or
//!   while a profile follows the active version. Deleting the last version keeps the
//!   model, empty, with its numbering. Deleting a whole model (its history and
//!   numbering) is refused while any profile uses it.
//! - Robots: an upload under an existing name replaces it (a new revision). Deleting is
//!   refused while a profile uses it.
//! - Profiles: [`Store::put_profile`] checks that the robot, model and pinned version it
//!   names exist. Replacing a profile keeps its calibration; [`ResolvedProfile::warnings`]
//!   says when the calibration was made with another model than the one resolved.

mod alarms;
mod ended;
mod error;
mod file_calibrations;
mod files;
mod jobs;
mod mirror;
mod models;
mod profiles;
mod robots;
mod scan;
mod types;
mod upload;
mod validate;

#[cfg(test)]
mod tests;

pub use alarms::{
    AlarmComponents, AlarmRecord, AlarmThresholds, FalseAlarmMark, KEPT_MARKED_ALARMS, now_s,
};
pub use error::{StoreError, StoreErrorKind};
pub use file_calibrations::FileCalibration;
pub use jobs::{JobInfo, JobState, KEPT_JOBS, Proposal, ProposalEpisode};
pub use mirror::{MirrorChange, StoredFile};
pub use types::{
    ModelInfo, ModelRef, ModelVersionInfo, OpenReport, ProfileInfo, ProfileSpec, ResolvedModel,
    ResolvedProfile, RobotInfo, StoreLimits, StoreProblem, ThresholdsPatch,
};
pub use upload::{RobotFormat, Upload, UploadKind};
pub use validate::{ModelValidator, model_bundle_summary, robot_summary};

use files::{check_name, list_dir, read_json};
pub(crate) use files::{hex, now_unix_s};
use scan::*;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex, MutexGuard};
use types::{ModelIndex, ProfileRecord, RobotMeta};
use vamos_core::pipeline::Calibration;

/// The lock file's name.
const LOCK_FILE: &str = "store.lock";
/// Metadata file names.
const MODEL_INDEX: &str = "index.json";
const ROBOT_META: &str = "meta.json";
const PROFILE_FILE: &str = "profile.json";
const CALIBRATION_FILE: &str = "calibration.json";
/// A model bundle's extension.
const MODEL_EXT: &str = "vamos";

/// The data directory, open (see the module docs).
#[derive(Clone, Debug)]
pub struct Store {
    inner: Arc<Inner>,
}

#[derive(Debug)]
struct Inner {
    dir: PathBuf,
    limits: StoreLimits,
    report: OpenReport,
    state: Mutex<State>,
    /// Held open for its lock; released when the last clone is dropped.
    _lock: std::fs::File,
    /// Fault injection for tests: uploads fail as on a full disk past this many bytes.
    storage_full_after: std::sync::atomic::AtomicU64,
    /// Set on a replica that mirrors a shared store: why changes are refused.
    read_only: Mutex<Option<String>>,
    /// sha256 of published files by path, valid while size and mtime are unchanged.
    hashes: Mutex<mirror::HashCache>,
}

/// What is stored, as read at open and kept in step with every change.
#[derive(Debug, Default)]
struct State {
    models: BTreeMap<String, ModelEntry>,
    robots: BTreeMap<String, RobotEntry>,
    profiles: BTreeMap<String, ProfileEntry>,
    /// Names whose metadata cannot be read: only deleting them is allowed.
    quarantined: BTreeMap<(&'static str, String), StoreProblem>,
    /// Entries that are no store object (foreign files, bad names).
    strays: Vec<StoreProblem>,
    /// Job records by id.
    jobs: BTreeMap<u64, JobInfo>,
    /// The next job id.
    next_job: u64,
}

#[derive(Debug, Clone)]
struct ModelEntry {
    index: ModelIndex,
    /// Versions that are not served, and why.
    problems: BTreeMap<u32, String>,
}

#[derive(Debug, Clone)]
struct RobotEntry {
    meta: RobotMeta,
    problem: Option<String>,
}

#[derive(Debug, Clone)]
struct ProfileEntry {
    record: ProfileRecord,
    calibration: Option<Calibration>,
    calibration_problem: Option<String>,
}

/// Object kinds, as named in errors and problems.
const MODEL: &str = "model";
const MODEL_VERSION: &str = "model version";
const ROBOT: &str = "robot";
const PROFILE: &str = "profile";
const JOB: &str = "job";

impl Store {
    /// Opens (creating when needed) the data directory `dir`: takes its lock, removes the
    /// leftovers of interrupted uploads and writes, and reads and verifies every stored
    /// object (see the module docs). Fails with [`StoreError::Locked`] when another
    /// store has it open.
    pub fn open(dir: &Path, limits: StoreLimits) -> Result<Self, StoreError> {
        std::fs::create_dir_all(dir).map_err(|e| StoreError::io(dir, e))?;
        let dir = std::fs::canonicalize(dir).map_err(|e| StoreError::io(dir, e))?;
        let lock_path = dir.join(LOCK_FILE);
        let lock = std::fs::File::options()
            .create(true)
            .truncate(false)
            .write(true)
            .open(&lock_path)
            .map_err(|e| StoreError::io(&lock_path, e))?;
        match lock.try_lock() {
            Ok(()) => {}
            Err(std::fs::TryLockError::WouldBlock) => {
                return Err(StoreError::Locked { path: lock_path });
            }
            Err(std::fs::TryLockError::Error(e)) if e.kind() == std::io::ErrorKind::Unsupported => {
                tracing::warn!(path = %lock_path.display(), "file locking unsupported here: {e}");
            }
            Err(std::fs::TryLockError::Error(e)) => return Err(StoreError::io(&lock_path, e)),
        }
        for sub in ["tmp", "models", "robots", "profiles", "jobs"] {
            let p = dir.join(sub);
            std::fs::create_dir_all(&p).map_err(|e| StoreError::io(&p, e))?;
        }
        let mut report = OpenReport::default();
        let tmp = dir.join("tmp");
        for (_, path, is_dir) in list_dir(&tmp)? {
            let removed = if is_dir {
                std::fs::remove_dir_all(&path)
            } else {
                std::fs::remove_file(&path)
            };
            removed.map_err(|e| StoreError::io(&path, e))?;
            report.removed_temp_entries += 1;
        }
        files::sync_dir(&tmp)?;
        let mut state = State::default();
        scan_objects(&dir, &mut state, &mut report)?;
        jobs::scan_jobs(&dir, &mut state)?;
        let store = Self {
            inner: Arc::new(Inner {
                dir,
                limits,
                report,
                state: Mutex::new(state),
                _lock: lock,
                storage_full_after: std::sync::atomic::AtomicU64::new(u64::MAX),
                read_only: Mutex::new(None),
                hashes: Mutex::new(mirror::HashCache::default()),
            }),
        };
        let problems = store.problems();
        for p in &problems {
            tracing::warn!(kind = p.kind, name = %p.name, path = %p.path.display(), "not served: {}", p.reason);
        }
        {
            let st = store.lock();
            tracing::info!(
                dir = %store.inner.dir.display(),
                models = st.models.len(),
                robots = st.robots.len(),
                profiles = st.profiles.len(),
                problems = problems.len(),
                removed_temp_entries = report.removed_temp_entries,
                removed_orphan_files = report.removed_orphan_files,
                verified_files = report.verified_files,
                "data directory open"
            );
        }
        Ok(store)
    }

    /// The data directory (absolute).
    pub fn dir(&self) -> &Path {
        &self.inner.dir
    }

    /// The upload size limits.
    pub fn limits(&self) -> StoreLimits {
        self.inner.limits
    }

    /// What [`Store::open`] removed and verified.
    pub fn open_report(&self) -> OpenReport {
        self.inner.report
    }

    /// Everything not served: objects that failed their checksum or cannot be read,
    /// foreign entries, profiles naming a robot or model version that is missing.
    pub fn problems(&self) -> Vec<StoreProblem> {
        let st = self.lock();
        let mut out: Vec<StoreProblem> = st.quarantined.values().cloned().collect();
        out.extend(st.strays.iter().cloned());
        for (name, entry) in &st.models {
            for (v, reason) in &entry.problems {
                out.push(StoreProblem {
                    kind: MODEL_VERSION,
                    name: format!("{name}@{v}"),
                    path: self.model_file(name, *v),
                    reason: reason.clone(),
                });
            }
        }
        for (name, entry) in &st.robots {
            if let Some(reason) = &entry.problem {
                out.push(StoreProblem {
                    kind: ROBOT,
                    name: name.clone(),
                    path: self.robot_dir(name).join(entry.meta.file_name()),
                    reason: reason.clone(),
                });
            }
        }
        for (name, entry) in &st.profiles {
            let path = self.profile_dir(name);
            let mut problem = |reason: String| {
                out.push(StoreProblem {
                    kind: PROFILE,
                    name: name.clone(),
                    path: path.clone(),
                    reason,
                })
            };
            if let Some(reason) = &entry.calibration_problem {
                problem(format!("calibration: {reason}"));
            }
            if let Some(reason) = st.dangling_reference(&entry.record.spec) {
                problem(reason);
            }
        }
        out
    }

    fn lock(&self) -> MutexGuard<'_, State> {
        // A panic while holding the lock cannot leave the disk half-changed (every change
        // is one rename); the in-memory state is updated only after the disk, so it is
        // still usable.
        self.inner
            .state
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
    }

    fn tmp_dir(&self) -> PathBuf {
        self.inner.dir.join("tmp")
    }

    fn model_dir(&self, name: &str) -> PathBuf {
        self.inner.dir.join("models").join(name)
    }

    fn model_file(&self, name: &str, version: u32) -> PathBuf {
        self.model_dir(name).join(format!("{version}.{MODEL_EXT}"))
    }

    fn robot_dir(&self, name: &str) -> PathBuf {
        self.inner.dir.join("robots").join(name)
    }

    fn profile_dir(&self, name: &str) -> PathBuf {
        self.inner.dir.join("profiles").join(name)
    }

    /// Starts a streamed upload of `kind`, limited by [`StoreLimits`].
    pub fn begin_upload(&self, kind: UploadKind) -> Result<Upload, StoreError> {
        self.check_writable()?;
        let limit = match kind {
            UploadKind::Model => self.inner.limits.max_model_bytes,
            UploadKind::Robot { .. } => self.inner.limits.max_robot_bytes,
        };
        let full_after = self
            .inner
            .storage_full_after
            .load(std::sync::atomic::Ordering::Relaxed);
        Upload::create(&self.tmp_dir(), kind, limit, full_after)
    }

    /// Fault injection for tests: every upload begun from now on fails once it has
    /// written `bytes` (`u64::MAX`: never), with the error a full disk gives (`ENOSPC`).
    #[doc(hidden)]
    pub fn inject_storage_full_after(&self, bytes: u64) {
        self.inner
            .storage_full_after
            .store(bytes, std::sync::atomic::Ordering::Relaxed);
    }

    /// Checks that `upload` is this store's and of `kind`, and finishes it.
    fn finish_upload(
        &self,
        upload: &mut Upload,
        kind_ok: bool,
    ) -> Result<upload::Finished, StoreError> {
        if upload.path.parent() != Some(self.tmp_dir().as_path()) {
            return Err(StoreError::invalid("the upload belongs to another store"));
        }
        if !kind_ok {
            return Err(StoreError::invalid(format!(
                "an upload of kind {:?} cannot be committed here",
                upload.kind
            )));
        }
        let finished = upload.finish()?;
        if finished.size_bytes == 0 {
            return Err(StoreError::invalid("the upload is empty"));
        }
        Ok(finished)
    }

    /// Creates a new object's folder: `fill` populates a staging folder in `tmp/`, which
    /// is then renamed to `target` whole. On failure the staging folder is removed.
    fn create_object_dir(
        &self,
        target: &Path,
        fill: impl FnOnce(&Path) -> Result<(), StoreError>,
    ) -> Result<(), StoreError> {
        let staging = self.tmp_dir().join(files::unique_name("new", ""));
        std::fs::create_dir(&staging).map_err(|e| StoreError::io(&staging, e))?;
        let result = fill(&staging)
            .and_then(|()| files::sync_dir(&staging))
            .and_then(|()| files::rename_durable(&staging, target));
        if result.is_err() {
            let _ = std::fs::remove_dir_all(&staging);
        }
        result
    }

    /// The quarantine entry of `(kind, name)`, as an error.
    fn check_quarantine(st: &State, kind: &'static str, name: &str) -> Result<(), StoreError> {
        match st.quarantined.get(&(kind, name.to_string())) {
            Some(p) => Err(StoreError::Corrupt {
                path: p.path.clone(),
                reason: format!("{} (delete it to start over)", p.reason),
            }),
            None => Ok(()),
        }
    }
}

impl State {
    /// Why `spec` cannot be resolved now for want of a stored robot or model, if so.
    fn dangling_reference(&self, spec: &ProfileSpec) -> Option<String> {
        if let Some(robot) = &spec.robot
            && !self.robots.contains_key(robot)
        {
            return Some(format!("robot {robot:?} is missing"));
        }
        let model = spec.model.as_ref()?;
        let Some(entry) = self.models.get(&model.name) else {
            return Some(format!("model {:?} is missing", model.name));
        };
        match model.version.or(entry.index.active) {
            None => Some(format!("model {:?} has no active version", model.name)),
            Some(v) if !entry.index.versions.iter().any(|s| s.version == v) => {
                Some(format!("model version {}@{v} is missing", model.name))
            }
            Some(_) => None,
        }
    }

    /// Profiles using model `name`, with the version each pins (`None`: follows active).
    fn model_users(&self, name: &str) -> Vec<(String, Option<u32>)> {
        self.profiles
            .iter()
            .filter_map(|(p, e)| {
                let m = e.record.spec.model.as_ref()?;
                (m.name == name).then(|| (p.clone(), m.version))
            })
            .collect()
    }

    fn quarantine(&mut self, kind: &'static str, name: &str, path: PathBuf, reason: String) {
        self.quarantined.insert(
            (kind, name.to_string()),
            StoreProblem {
                kind,
                name: name.into(),
                path,
                reason,
            },
        );
    }

    fn stray(&mut self, path: PathBuf, name: &str, reason: &str) {
        self.strays.push(StoreProblem {
            kind: "entry",
            name: name.into(),
            path,
            reason: reason.into(),
        });
    }
}
