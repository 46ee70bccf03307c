//! Models: versioned bundles with an active version.

use super::files::{self, check_name, now_unix_s, write_json};
use super::types::{ModelIndex, StoredVersion};
use super::{
    MODEL, MODEL_INDEX, MODEL_VERSION, ModelEntry, ModelInfo, ModelVersionInfo, Store, StoreError,
    Upload, UploadKind,
};
use std::path::{Path, PathBuf};

/// Whether a stored index is self-consistent: `Err(reason)` when not.
pub(super) fn check_index(name: &str, index: &ModelIndex) -> Result<(), String> {
    if index.name != name {
        return Err(format!("index.json names model {:?}", index.name));
    }
    let mut last = 0;
    for v in &index.versions {
        if v.version <= last || v.version >= index.next_version {
            return Err(format!(
                "version {} out of order or not below next_version {}",
                v.version, index.next_version
            ));
        }
        last = v.version;
    }
    if let Some(a) = index.active
        && !index.versions.iter().any(|v| v.version == a)
    {
        return Err(format!("active version {a} is not stored"));
    }
    Ok(())
}

impl ModelEntry {
    fn info(&self) -> ModelInfo {
        ModelInfo {
            name: self.index.name.clone(),
            active: self.index.active,
            versions: self
                .index
                .versions
                .iter()
                .map(|v| ModelVersionInfo {
                    version: v.version,
                    sha256: v.sha256.clone(),
                    size_bytes: v.size_bytes,
                    created_unix_s: v.created_unix_s,
                    summary: v.summary.clone(),
                    problem: self.problems.get(&v.version).cloned(),
                })
                .collect(),
        }
    }
}

impl Store {
    /// Stores a finished model upload as the next version of `name`, once `validate`
    /// accepted the file (it gets the temporary file's path, with a `.vamos` extension,
    /// and returns a summary to record, e.g. [`super::model_bundle_summary`]). A name's
    /// first version becomes active, as does a new version of a model left without one.
    /// A refusal is [`StoreError::Invalid`] with the validator's reason, and nothing is
    /// stored. Concurrent commits of one name get distinct versions.
    pub fn commit_model(
        &self,
        name: &str,
        mut upload: Upload,
        validate: impl FnOnce(&Path) -> Result<serde_json::Value, String>,
    ) -> Result<ModelVersionInfo, StoreError> {
        self.check_writable()?;
        check_name(name)?;
        Self::check_quarantine(&self.lock(), MODEL, name)?;
        let kind_ok = upload.kind == UploadKind::Model;
        let finished = self.finish_upload(&mut upload, kind_ok)?;
        let summary = validate(&upload.path).map_err(|reason| StoreError::Invalid { reason })?;
        let mut st = self.lock();
        Self::check_quarantine(&st, MODEL, name)?;
        let mut index = match st.models.get(name) {
            Some(e) => e.index.clone(),
            None => ModelIndex {
                name: name.into(),
                active: None,
                next_version: 1,
                versions: Vec::new(),
            },
        };
        let version = index.next_version;
        index.next_version = version.checked_add(1).ok_or_else(|| {
            StoreError::invalid(format!("model {name} has used every version number"))
        })?;
        let stored = StoredVersion {
            version,
            sha256: finished.sha256,
            size_bytes: finished.size_bytes,
            created_unix_s: now_unix_s(),
            summary,
        };
        index.versions.push(stored.clone());
        if index.active.is_none() {
            index.active = Some(version);
        }
        let tmp = self.tmp_dir();
        let file_name = format!("{version}.{}", super::MODEL_EXT);
        if st.models.contains_key(name) {
            let file = self.model_dir(name).join(&file_name);
            files::rename_durable(&upload.path, &file)?;
            upload.moved = true;
            if let Err(e) = write_json(&tmp, &self.model_dir(name).join(MODEL_INDEX), &index) {
                files::remove_file_quiet(&file);
                return Err(e);
            }
        } else {
            self.create_object_dir(&self.model_dir(name), |staging| {
                files::rename_durable(&upload.path, &staging.join(&file_name))?;
                upload.moved = true;
                write_json(&tmp, &staging.join(MODEL_INDEX), &index)
            })?;
        }
        let entry = st.models.entry(name.to_string()).or_insert(ModelEntry {
            index: index.clone(),
            problems: Default::default(),
        });
        entry.index = index;
        tracing::info!(model = name, version, sha256 = %stored.sha256, "model stored");
        Ok(ModelVersionInfo {
            version,
            sha256: stored.sha256,
            size_bytes: stored.size_bytes,
            created_unix_s: stored.created_unix_s,
            summary: stored.summary,
            problem: None,
        })
    }

    /// Every model, by name.
    pub fn models(&self) -> Vec<ModelInfo> {
        self.lock().models.values().map(ModelEntry::info).collect()
    }

    /// One model.
    pub fn model(&self, name: &str) -> Result<ModelInfo, StoreError> {
        check_name(name)?;
        let st = self.lock();
        Self::check_quarantine(&st, MODEL, name)?;
        st.models
            .get(name)
            .map(ModelEntry::info)
            .ok_or_else(|| not_found(name))
    }

    /// The bundle file of `version` of model `name` (`None`: the active version), with
    /// the version number. A version that failed its checksum is [`StoreError::Corrupt`].
    pub fn model_path(
        &self,
        name: &str,
        version: Option<u32>,
    ) -> Result<(u32, PathBuf), StoreError> {
        check_name(name)?;
        let st = self.lock();
        Self::check_quarantine(&st, MODEL, name)?;
        let entry = st.models.get(name).ok_or_else(|| not_found(name))?;
        let v = self.servable_version(name, entry, version)?;
        Ok((v, self.model_file(name, v)))
    }

    /// `version` (or the active one) of `entry`, when stored and intact.
    pub(super) fn servable_version(
        &self,
        name: &str,
        entry: &ModelEntry,
        version: Option<u32>,
    ) -> Result<u32, StoreError> {
        let v = match version.or(entry.index.active) {
            Some(v) => v,
            None => {
                return Err(StoreError::NotFound {
                    kind: MODEL_VERSION,
                    name: format!("{name}@active"),
                });
            }
        };
        if !entry.index.versions.iter().any(|s| s.version == v) {
            return Err(version_not_found(name, v));
        }
        if let Some(reason) = entry.problems.get(&v) {
            return Err(StoreError::Corrupt {
                path: self.model_file(name, v),
                reason: reason.clone(),
            });
        }
        Ok(v)
    }

    /// Makes `version` the active version of `name`.
    pub fn set_active_model(&self, name: &str, version: u32) -> Result<(), StoreError> {
        self.check_writable()?;
        check_name(name)?;
        let mut st = self.lock();
        Self::check_quarantine(&st, MODEL, name)?;
        let entry = st.models.get(name).ok_or_else(|| not_found(name))?;
        self.servable_version(name, entry, Some(version))?;
        let mut index = entry.index.clone();
        index.active = Some(version);
        write_json(
            &self.tmp_dir(),
            &self.model_dir(name).join(MODEL_INDEX),
            &index,
        )?;
        if let Some(e) = st.models.get_mut(name) {
            e.index = index;
        }
        tracing::info!(model = name, version, "active model version set");
        Ok(())
    }

    /// Deletes one version of model `name`, or (`None`) the whole model with its
    /// numbering; see the module docs for what is refused ([`StoreError::InUse`]). A
    /// quarantined model can be deleted whole.
    pub fn delete_model(&self, name: &str, version: Option<u32>) -> Result<(), StoreError> {
        self.check_writable()?;
        check_name(name)?;
        let mut st = self.lock();
        let key = (MODEL, name.to_string());
        if st.quarantined.contains_key(&key) {
            if version.is_some() {
                Self::check_quarantine(&st, MODEL, name)?;
            }
            files::remove_dir_atomic(&self.tmp_dir(), &self.model_dir(name))?;
            st.quarantined.remove(&key);
            tracing::info!(model = name, "quarantined model deleted");
            return Ok(());
        }
        let entry = st.models.get(name).ok_or_else(|| not_found(name))?;
        let users = st.model_users(name);
        let Some(v) = version else {
            if !users.is_empty() {
                return Err(StoreError::InUse {
                    kind: MODEL,
                    name: name.into(),
                    by: users.iter().map(|(p, _)| format!("profile {p}")).collect(),
                });
            }
            files::remove_dir_atomic(&self.tmp_dir(), &self.model_dir(name))?;
            st.models.remove(name);
            tracing::info!(model = name, "model deleted");
            return Ok(());
        };
        if !entry.index.versions.iter().any(|s| s.version == v) {
            return Err(version_not_found(name, v));
        }
        let mut by: Vec<String> = users
            .iter()
            .filter(|(_, pinned)| *pinned == Some(v))
            .map(|(p, _)| format!("profile {p}"))
            .collect();
        if entry.index.active == Some(v) {
            if entry.index.versions.len() > 1 {
                by.push("the active version (make another version active first)".into());
            }
            by.extend(
                users
                    .iter()
                    .filter(|(_, pinned)| pinned.is_none())
                    .map(|(p, _)| format!("profile {p} (follows the active version)")),
            );
        }
        if !by.is_empty() {
            return Err(StoreError::InUse {
                kind: MODEL_VERSION,
                name: format!("{name}@{v}"),
                by,
            });
        }
        let mut index = entry.index.clone();
        index.versions.retain(|s| s.version != v);
        if index.active == Some(v) {
            index.active = None;
        }
        write_json(
            &self.tmp_dir(),
            &self.model_dir(name).join(MODEL_INDEX),
            &index,
        )?;
        files::remove_file_quiet(&self.model_file(name, v));
        if let Some(e) = st.models.get_mut(name) {
            e.index = index;
            e.problems.remove(&v);
        }
        tracing::info!(model = name, version = v, "model version deleted");
        Ok(())
    }
}

fn not_found(name: &str) -> StoreError {
    StoreError::NotFound {
        kind: MODEL,
        name: name.into(),
    }
}

pub(super) fn version_not_found(name: &str, version: u32) -> StoreError {
    StoreError::NotFound {
        kind: MODEL_VERSION,
        name: format!("{name}@{version}"),
    }
}
