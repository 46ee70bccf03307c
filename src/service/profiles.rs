//! The profiles sessions are scored with: profile files named in the settings, and the
//! data directory's profiles (loaded on first use, reloaded when they change). A loaded
//! profile is shared by `Arc`: a session keeps the one it opened with, so a model swap
//! changes new sessions only.

use crate::config::Settings;
use crate::setup::{Setup, SetupError};
use std::collections::HashMap;
use std::sync::{Arc, Mutex};

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
}

/// Where sessions find their profiles.
pub struct ProfileCatalog {
    files: HashMap<String, Arc<LoadedProfile>>,
    cache: Mutex<HashMap<String, Arc<LoadedProfile>>>,
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

impl ProfileCatalog {
    /// Loads the profile files of `[service] profiles`.
    pub fn load(settings: &Settings) -> Result<Self, ProfileLookupError> {
        let mut files = HashMap::new();
        for path in &settings.service.profiles {
            let setup = Setup::load(settings, path).map_err(|e| ProfileLookupError::Load {
                name: path.display().to_string(),
                source: Box::new(e),
            })?;
            let name = setup.profile.file.name.clone();
            let model_label = model_label_of(&setup);
            tracing::info!(profile = %name, model = %model_label, path = %path.display(), "profile loaded");
            files.insert(
                name.clone(),
                Arc::new(LoadedProfile {
                    name,
                    setup,
                    model_label,
                }),
            );
        }
        Ok(Self {
            files,
            cache: Mutex::new(HashMap::new()),
        })
    }

    /// A catalog of profiles already loaded (tests, the demo).
    pub fn from_setups(setups: Vec<Setup>) -> Self {
        let files = setups
            .into_iter()
            .map(|setup| {
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
            })
            .collect();
        Self {
            files,
            cache: Mutex::new(HashMap::new()),
        }
    }

    /// The profile `name`.
    pub fn get(&self, name: &str) -> Result<Arc<LoadedProfile>, ProfileLookupError> {
        if let Some(p) = self.files.get(name) {
            return Ok(p.clone());
        }
        let cache = self.cache.lock().unwrap_or_else(|e| e.into_inner());
        cache
            .get(name)
            .cloned()
            .ok_or_else(|| ProfileLookupError::NotFound { name: name.into() })
    }

    /// Names of the profiles known now.
    pub fn names(&self) -> Vec<String> {
        let mut names: Vec<String> = self.files.keys().cloned().collect();
        names.extend(
            self.cache
                .lock()
                .unwrap_or_else(|e| e.into_inner())
                .keys()
                .cloned(),
        );
        names.sort();
        names.dedup();
        names
    }
}
