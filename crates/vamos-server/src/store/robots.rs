//! Robots: robot packages (URDF file or archive), replaced whole by a new upload.

use super::files::{self, check_name, now_unix_s, write_json};
use super::types::RobotMeta;
use super::{
    ROBOT, ROBOT_META, RobotEntry, RobotFormat, RobotInfo, Store, StoreError, Upload, UploadKind,
};
use std::io::Read;
use std::path::{Path, PathBuf};

impl RobotEntry {
    fn info(&self) -> RobotInfo {
        let m = &self.meta;
        RobotInfo {
            name: m.name.clone(),
            revision: m.revision,
            format: m.format,
            sha256: m.sha256.clone(),
            size_bytes: m.size_bytes,
            created_unix_s: m.created_unix_s,
            updated_unix_s: m.updated_unix_s,
            summary: m.summary.clone(),
            problem: self.problem.clone(),
        }
    }
}

/// Refuses an archive whose first bytes are not its format's magic number (a URDF is
/// left to the validator).
fn check_magic(path: &Path, format: RobotFormat) -> Result<(), StoreError> {
    let mut head = [0u8; 4];
    let mut f = std::fs::File::open(path).map_err(|e| StoreError::io(path, e))?;
    let n = f.read(&mut head).map_err(|e| StoreError::io(path, e))?;
    let head = &head[..n];
    let ok = match format {
        RobotFormat::Urdf => true,
        RobotFormat::TarGz => head.starts_with(&[0x1f, 0x8b]),
        RobotFormat::Zip => head.starts_with(b"PK\x03\x04") || head.starts_with(b"PK\x05\x06"),
    };
    if ok {
        Ok(())
    } else {
        Err(StoreError::invalid(format!(
            "the upload is not a {} file (its first bytes are {head:02x?})",
            format.extension()
        )))
    }
}

impl Store {
    /// Stores a finished robot upload under `name`, replacing the robot of that name if
    /// there is one (atomically: users see the old package or the new), once `validate`
    /// accepted the file (it gets the temporary file's path, whose extension matches the
    /// format, e.g. `robot_summary` with the settings' `RobotConfig`). A refusal is
    /// [`StoreError::Invalid`] and nothing changes.
    pub fn commit_robot(
        &self,
        name: &str,
        mut upload: Upload,
        validate: impl FnOnce(&Path) -> Result<serde_json::Value, String>,
    ) -> Result<RobotInfo, StoreError> {
        self.check_writable()?;
        check_name(name)?;
        Self::check_quarantine(&self.lock(), ROBOT, name)?;
        let format = match upload.kind {
            UploadKind::Robot { format } => Some(format),
            UploadKind::Model => None,
        };
        let finished = self.finish_upload(&mut upload, format.is_some())?;
        let format = format.unwrap_or(RobotFormat::Urdf);
        check_magic(&upload.path, format)?;
        let summary = validate(&upload.path).map_err(|reason| StoreError::Invalid { reason })?;
        let mut st = self.lock();
        Self::check_quarantine(&st, ROBOT, name)?;
        let now = now_unix_s();
        let previous = st.robots.get(name).map(|e| e.meta.clone());
        let revision = match &previous {
            Some(p) => p.revision.checked_add(1).ok_or_else(|| {
                StoreError::invalid(format!("robot {name} has used every revision number"))
            })?,
            None => 1,
        };
        let meta = RobotMeta {
            name: name.into(),
            revision,
            format,
            sha256: finished.sha256,
            size_bytes: finished.size_bytes,
            created_unix_s: previous.as_ref().map_or(now, |p| p.created_unix_s),
            updated_unix_s: now,
            summary,
        };
        let tmp = self.tmp_dir();
        let dir = self.robot_dir(name);
        match &previous {
            Some(old) => {
                let file = dir.join(meta.file_name());
                files::rename_durable(&upload.path, &file)?;
                upload.moved = true;
                if let Err(e) = write_json(&tmp, &dir.join(ROBOT_META), &meta) {
                    files::remove_file_quiet(&file);
                    return Err(e);
                }
                files::remove_file_quiet(&dir.join(old.file_name()));
            }
            None => self.create_object_dir(&dir, |staging| {
                files::rename_durable(&upload.path, &staging.join(meta.file_name()))?;
                upload.moved = true;
                write_json(&tmp, &staging.join(ROBOT_META), &meta)
            })?,
        }
        let entry = RobotEntry {
            meta,
            problem: None,
        };
        let info = entry.info();
        st.robots.insert(name.to_string(), entry);
        tracing::info!(robot = name, revision, sha256 = %info.sha256, "robot stored");
        Ok(info)
    }

    /// Every robot, by name.
    pub fn robots(&self) -> Vec<RobotInfo> {
        self.lock().robots.values().map(RobotEntry::info).collect()
    }

    /// One robot.
    pub fn robot(&self, name: &str) -> Result<RobotInfo, StoreError> {
        check_name(name)?;
        let st = self.lock();
        Self::check_quarantine(&st, ROBOT, name)?;
        st.robots
            .get(name)
            .map(RobotEntry::info)
            .ok_or_else(|| not_found(name))
    }

    /// The stored package file of robot `name` (`<revision>.urdf`, `.tar.gz` or `.zip`,
    /// loadable by [`vamos_robot::Robot::load`]).
    pub fn robot_path(&self, name: &str) -> Result<PathBuf, StoreError> {
        check_name(name)?;
        let st = self.lock();
        Self::check_quarantine(&st, ROBOT, name)?;
        let entry = st.robots.get(name).ok_or_else(|| not_found(name))?;
        let path = self.robot_dir(name).join(entry.meta.file_name());
        match &entry.problem {
            Some(reason) => Err(StoreError::Corrupt {
                path,
                reason: reason.clone(),
            }),
            None => Ok(path),
        }
    }

    /// Deletes robot `name`; refused ([`StoreError::InUse`]) while a profile uses it.
    pub fn delete_robot(&self, name: &str) -> Result<(), StoreError> {
        self.check_writable()?;
        check_name(name)?;
        let mut st = self.lock();
        let key = (ROBOT, name.to_string());
        let quarantined = st.quarantined.contains_key(&key);
        if !quarantined && !st.robots.contains_key(name) {
            return Err(not_found(name));
        }
        let by: Vec<String> = st
            .profiles
            .iter()
            .filter(|(_, e)| e.record.spec.robot.as_deref() == Some(name))
            .map(|(p, _)| format!("profile {p}"))
            .collect();
        if !by.is_empty() {
            return Err(StoreError::InUse {
                kind: ROBOT,
                name: name.into(),
                by,
            });
        }
        files::remove_dir_atomic(&self.tmp_dir(), &self.robot_dir(name))?;
        st.robots.remove(name);
        st.quarantined.remove(&key);
        tracing::info!(robot = name, "robot deleted");
        Ok(())
    }
}

fn not_found(name: &str) -> StoreError {
    StoreError::NotFound {
        kind: ROBOT,
        name: name.into(),
    }
}
