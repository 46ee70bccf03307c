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

use crate::config::Settings;
use crate::store::{Store, StoreError, StoreErrorKind};
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
    files: HashMap<String, Arc<LoadedProfile>>,
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
            setup,
            model_label,
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
            setup,
            model_label,
        }),
    )
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
            stored: None,
        })
    }

    /// A catalog of profiles already loaded (tests, the demo).
    pub fn from_setups(setups: Vec<Setup>) -> Self {
        Self {
            files: setups.into_iter().map(loaded_file).collect(),
            stored: None,
        }
    }

    /// This catalog, also serving the profiles of `store` (loaded with `settings`).
    /// `crate::service::Server::start` attaches the data directory it opened.
    pub fn with_store(mut self, store: Store, settings: Settings) -> Self {
        self.stored = Some(Arc::new(StoredProfiles {
            store,
            settings,
            cache: Mutex::new(Cache::default()),
            loading: Mutex::new(HashMap::new()),
        }));
        self
    }

    /// Whether `name` is a profile file (those take priority over stored profiles and
    /// cannot be changed through the API).
    pub fn is_file(&self, name: &str) -> bool {
        self.files.contains_key(name)
    }

    /// The profile `name`, if a file or already loaded: never blocks on loading.
    pub fn get_cached(&self, name: &str) -> Option<Arc<LoadedProfile>> {
        if let Some(p) = self.files.get(name) {
            return Some(p.clone());
        }
        self.stored.as_ref().and_then(|s| s.cached(name))
    }

    /// The profile `name`; a stored profile not loaded yet is loaded here (blocking: from
    /// async code use [`Self::get_async`]).
    pub fn get(&self, name: &str) -> Result<Arc<LoadedProfile>, ProfileLookupError> {
        if let Some(p) = self.files.get(name) {
            return Ok(p.clone());
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
        let mut out: Vec<_> = self.files.values().cloned().collect();
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
