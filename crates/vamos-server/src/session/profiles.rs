//! The profiles sessions are scored with: profile files named in the settings, and the
//! data directory's profiles (loaded on first use, reloaded when they change). A loaded
//! profile is shared by `Arc`: a session keeps the one it opened with, so a model swap
//! changes new sessions only.
//!
//! A profile file takes priority over a stored profile of the same name. Stored profiles
//! are resolved ([`Store::resolve_profile`]) and loaded ([`Setup::from_profile`], which
//! loads the ONNX model: slow) once, then served from a cache until the REST API changes
//! the profile, its model (new version, active version, delete) or its robot
//! ([`ProfileCatalog::invalidate_profile`], [`ProfileCatalog::invalidate_model`],
//! [`ProfileCatalog::invalidate_robot`]).
//!
//! A profile file's calibration made by the service (a calibration job, an applied
//! recalibration) is kept in the data directory ([`FileCalibration`]) and replaces the
//! file's own calibration while the file still has the calibration it replaced; the
//! file itself is never written.

use crate::config::Settings;
use crate::store::{FileCalibration, Store, StoreError, StoreErrorKind};
use std::collections::HashMap;
use std::sync::{Arc, Mutex, MutexGuard};
use vamos_core::setup::{Setup, SetupError};

/// A profile with its robot and model loaded.
pub struct LoadedProfile {
    /// Profile name.
    pub name: String,
    /// Robot, camera, model, pipeline.
    pub setup: Setup,
    /// The model as a metric label and in listings (`name@version` for stored models,
    /// the file stem for files; `none` without a model).
    pub model_label: String,
    /// A profile file whose calibration in force is the data directory's (made by the
    /// service), not the file's own.
    pub calibration_stored: bool,
    /// What the profile asks for and cannot do ([`Setup::fallbacks`]), made once.
    pub notes: Vec<String>,
}

/// Why a profile cannot be used.
#[derive(Debug, thiserror::Error)]
pub enum ProfileLookupError {
    /// No profile of that name.
    #[error("unknown profile {name:?}")]
    NotFound {
        /// The name asked for.
        name: String,
    },
    /// It exists but does not load.
    #[error("profile {name:?} does not load: {source}")]
    Load {
        /// The name.
        name: String,
        /// Why.
        source: Box<SetupError>,
    },
    /// The data directory could not resolve it (a corrupt or unreadable entry).
    #[error("profile {name:?}: {source}")]
    Store {
        /// The name.
        name: String,
        /// Why.
        source: Box<StoreError>,
    },
}

/// Where sessions find their profiles.
pub struct ProfileCatalog {
    /// The profile files, as read.
    files: HashMap<String, Arc<LoadedProfile>>,
    /// Profile files with their calibration from the data directory (these win over
    /// `files`).
    recalibrated: Mutex<HashMap<String, Arc<LoadedProfile>>>,
    stored: Option<Arc<StoredProfiles>>,
}

/// The data directory's profiles and the cache of those loaded.
struct StoredProfiles {
    store: Store,
    settings: Settings,
    cache: Mutex<Cache>,
    /// One lock per profile name being loaded: sessions that miss the cache at once wait
    /// for one load instead of each loading the model.
    loading: Mutex<HashMap<String, Arc<Mutex<()>>>>,
}

#[derive(Default)]
struct Cache {
    entries: HashMap<String, CacheEntry>,
    /// Bumped by every invalidation: a load that started before one is not cached.
    generation: u64,
}

struct CacheEntry {
    loaded: Arc<LoadedProfile>,
    model: Option<String>,
    robot: Option<String>,
}

impl StoredProfiles {
    fn cache(&self) -> MutexGuard<'_, Cache> {
        self.cache.lock().unwrap_or_else(|e| e.into_inner())
    }

    fn cached(&self, name: &str) -> Option<Arc<LoadedProfile>> {
        self.cache().entries.get(name).map(|e| e.loaded.clone())
    }

    /// Resolves and loads `name` (blocking), caching it unless something changed
    /// meanwhile.
    fn load(&self, name: &str) -> Result<Arc<LoadedProfile>, ProfileLookupError> {
        if let Some(p) = self.cached(name) {
            return Ok(p);
        }
        let gate = self
            .loading
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .entry(name.to_string())
            .or_default()
            .clone();
        let _one_at_a_time = gate.lock().unwrap_or_else(|e| e.into_inner());
        // Loaded by the caller we waited for.
        if let Some(p) = self.cached(name) {
            return Ok(p);
        }
        let generation = self.cache().generation;
        let resolved = self
            .store
            .resolve_profile(name)
            .map_err(|e| match e.kind() {
                StoreErrorKind::NotFound => ProfileLookupError::NotFound { name: name.into() },
                _ => ProfileLookupError::Store {
                    name: name.into(),
                    source: Box::new(e),
                },
            })?;
        for w in &resolved.warnings {
            tracing::warn!(profile = name, "{w}");
        }
        let model_label = resolved
            .model
            .as_ref()
            .map_or_else(|| "none".into(), |m| format!("{}@{}", m.name, m.version));
        let setup = Setup::from_profile(&self.settings, resolved.profile).map_err(|e| {
            ProfileLookupError::Load {
                name: name.into(),
                source: Box::new(e),
            }
        })?;
        tracing::info!(profile = name, model = %model_label, "stored profile loaded");
        let loaded = Arc::new(LoadedProfile {
            name: name.into(),
            notes: setup.fallbacks(),
            setup,
            model_label,
            calibration_stored: false,
        });
        let mut cache = self.cache();
        if cache.generation == generation {
            cache.entries.insert(
                name.into(),
                CacheEntry {
                    loaded: loaded.clone(),
                    model: resolved.model.map(|m| m.name),
                    robot: resolved.robot,
                },
            );
        }
        Ok(loaded)
    }

    fn invalidate(&self, drop: impl Fn(&str, &CacheEntry) -> bool) {
        let mut cache = self.cache();
        cache.generation += 1;
        cache.entries.retain(|name, e| !drop(name, e));
    }
}

fn model_label_of(setup: &Setup) -> String {
    setup
        .profile
        .file
        .model
        .as_ref()
        .and_then(|p| p.file_stem())
        .map_or_else(|| "none".into(), |s| s.to_string_lossy().into_owned())
}

fn loaded_file(setup: Setup) -> (String, Arc<LoadedProfile>) {
    let name = setup.profile.file.name.clone();
    let model_label = model_label_of(&setup);
    (
        name.clone(),
        Arc::new(LoadedProfile {
            name,
            notes: setup.fallbacks(),
            setup,
            model_label,
            calibration_stored: false,
        }),
    )
}

/// Profile file `base` with `stored` as its calibration, unless the file's own
/// calibration is no longer the one `stored` replaced (then `None`: the file's wins).
fn with_stored_calibration(
    base: &LoadedProfile,
    stored: &FileCalibration,
) -> Option<Arc<LoadedProfile>> {
    let own = base
        .setup
        .profile
        .calibration
        .as_ref()
        .map(|c| c.created_unix_s);
    if own != stored.replaces_unix_s {
        return None;
    }
    let mut setup = base.setup.clone();
    setup.profile.calibration = Some(stored.calibration.clone());
    Some(Arc::new(LoadedProfile {
        name: base.name.clone(),
        notes: setup.fallbacks(),
        setup,
        model_label: base.model_label.clone(),
        calibration_stored: true,
    }))
}

impl ProfileCatalog {
    /// Loads the profile files of `[service] profiles` (the data directory's profiles come
    /// with [`Self::with_store`]).
    pub fn load(settings: &Settings) -> Result<Self, ProfileLookupError> {
        let mut files = HashMap::new();
        for path in &settings.service.profiles {
            let setup = Setup::load(settings, path).map_err(|e| ProfileLookupError::Load {
                name: path.display().to_string(),
                source: Box::new(e),
            })?;
            let (name, loaded) = loaded_file(setup);
            tracing::info!(profile = %name, model = %loaded.model_label, path = %path.display(), "profile loaded");
            files.insert(name, loaded);
        }
        Ok(Self {
            files,
            recalibrated: Mutex::default(),
            stored: None,
        })
    }

    /// A catalog of profiles already loaded (tests, the demo).
    pub fn from_setups(setups: Vec<Setup>) -> Self {
        Self {
            files: setups.into_iter().map(loaded_file).collect(),
            recalibrated: Mutex::default(),
            stored: None,
        }
    }

    /// This catalog, also serving the profiles of `store` (loaded with `settings`), and
    /// the profile files' calibrations kept there. `crate::service::Server::start`
    /// attaches the data directory it opened.
    pub fn with_store(mut self, store: Store, settings: Settings) -> Self {
        let mut recalibrated = HashMap::new();
        for (name, base) in &self.files {
            match store.file_calibration(name) {
                Ok(None) => {}
                Ok(Some(stored)) => match with_stored_calibration(base, &stored) {
                    Some(loaded) => {
                        tracing::info!(profile = %name, "the profile file's calibration made by the service is in force (data directory)");
                        recalibrated.insert(name.clone(), loaded);
                    }
                    None => tracing::warn!(
                        profile = %name,
                        "the profile file's own calibration changed since the service calibrated it: the file's is in force"
                    ),
                },
                Err(e) => {
                    tracing::warn!(profile = %name, "the calibration the service made for this profile file is not used: {e}")
                }
            }
        }
        self.recalibrated = Mutex::new(recalibrated);
        self.stored = Some(Arc::new(StoredProfiles {
            store,
            settings,
            cache: Mutex::new(Cache::default()),
            loading: Mutex::new(HashMap::new()),
        }));
        self
    }

    /// Whether `name` is a profile file (those take priority over stored profiles and
    /// cannot be changed through the API; the service can calibrate them, see the module docs).
    pub fn is_file(&self, name: &str) -> bool {
        self.files.contains_key(name)
    }

    fn recalibrated(&self) -> MutexGuard<'_, HashMap<String, Arc<LoadedProfile>>> {
        self.recalibrated.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// Profile file `name` as in force: with the calibration the service made, if any.
    fn file(&self, name: &str) -> Option<Arc<LoadedProfile>> {
        let base = self.files.get(name)?;
        Some(self.recalibrated().get(name).unwrap_or(base).clone())
    }

    /// Puts `calibration` in force for profile file `name` (sessions opened from now on
    /// use it) and keeps it in the data directory; the file is not written. Blocking.
    pub fn save_file_calibration(
        &self,
        name: &str,
        calibration: vamos_core::pipeline::Calibration,
    ) -> Result<(), ProfileLookupError> {
        let (Some(base), Some(stored)) = (self.files.get(name), &self.stored) else {
            return Err(ProfileLookupError::NotFound { name: name.into() });
        };
        let kept = FileCalibration {
            profile_path: base.setup.profile.path.clone(),
            replaces_unix_s: base
                .setup
                .profile
                .calibration
                .as_ref()
                .map(|c| c.created_unix_s),
            calibration,
        };
        stored
            .store
            .save_file_calibration(name, &kept)
            .map_err(|e| ProfileLookupError::Store {
                name: name.into(),
                source: Box::new(e),
            })?;
        if let Some(loaded) = with_stored_calibration(base, &kept) {
            self.recalibrated().insert(name.into(), loaded);
        }
        Ok(())
    }

    /// The profile `name`, if a file or already loaded: never blocks on loading.
    pub fn get_cached(&self, name: &str) -> Option<Arc<LoadedProfile>> {
        if let Some(p) = self.file(name) {
            return Some(p);
        }
        self.stored.as_ref().and_then(|s| s.cached(name))
    }

    /// The profile `name`; a stored profile not loaded yet is loaded here (blocking: from
    /// async code use [`Self::get_async`]).
    pub fn get(&self, name: &str) -> Result<Arc<LoadedProfile>, ProfileLookupError> {
        if let Some(p) = self.file(name) {
            return Ok(p);
        }
        match &self.stored {
            Some(s) => s.load(name),
            None => Err(ProfileLookupError::NotFound { name: name.into() }),
        }
    }

    /// [`Self::get`] for async code: loading runs on a blocking thread.
    pub async fn get_async(&self, name: &str) -> Result<Arc<LoadedProfile>, ProfileLookupError> {
        if let Some(p) = self.get_cached(name) {
            return Ok(p);
        }
        let Some(stored) = self.stored.clone() else {
            return Err(ProfileLookupError::NotFound { name: name.into() });
        };
        let owned = name.to_string();
        match tokio::task::spawn_blocking(move || stored.load(&owned)).await {
            Ok(r) => r,
            Err(e) => Err(ProfileLookupError::Store {
                name: name.into(),
                source: Box::new(StoreError::Io {
                    path: std::path::PathBuf::from(name),
                    source: std::io::Error::other(e.to_string()),
                }),
            }),
        }
    }

    /// The profiles loaded now: the files, and the stored profiles in the cache.
    pub fn loaded(&self) -> Vec<Arc<LoadedProfile>> {
        let mut out: Vec<_> = self.files.keys().filter_map(|n| self.file(n)).collect();
        if let Some(s) = &self.stored {
            out.extend(s.cache().entries.values().map(|e| e.loaded.clone()));
        }
        out
    }

    /// Forgets the loaded stored profile `name`: the next session loads it again.
    pub fn invalidate_profile(&self, name: &str) {
        if let Some(s) = &self.stored {
            s.invalidate(|n, _| n == name);
        }
    }

    /// Forgets the loaded stored profiles that use model `name`.
    pub fn invalidate_model(&self, name: &str) {
        if let Some(s) = &self.stored {
            s.invalidate(|_, e| e.model.as_deref() == Some(name));
        }
    }

    /// Forgets the loaded stored profiles that use robot `name`.
    pub fn invalidate_robot(&self, name: &str) {
        if let Some(s) = &self.stored {
            s.invalidate(|_, e| e.robot.as_deref() == Some(name));
        }
    }

    /// Names of the profiles known now: the files and the data directory's profiles.
    pub fn names(&self) -> Vec<String> {
        let mut names: Vec<String> = self.files.keys().cloned().collect();
        if let Some(s) = &self.stored {
            names.extend(s.store.profiles().into_iter().map(|p| p.name));
        }
        names.sort();
        names.dedup();
        names
    }
}
