//! Calibrations of the server's profile files made by the service (a calibration job or
//! an applied recalibration): the file stays as the operator wrote it, and the
//! calibration lives in the data directory, `file-calibrations/<name>.json`, named as the
//! profile file's. [`crate::session::ProfileCatalog`] puts it in force over the file's
//! own calibration while that is the one it replaced.

use super::files::{check_name, read_json, write_json};
use super::profiles::check_calibration;
use super::{Store, StoreError};
use serde::{Deserialize, Serialize};
use std::path::PathBuf;
use vamos_core::pipeline::Calibration;

/// A profile file's calibration kept in the data directory.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FileCalibration {
    /// The profile file it calibrates, as the server's settings name it.
    pub profile_path: PathBuf,
    /// The file's own calibration it replaces (its `created_unix_s`; `None`: the file had
    /// none). When the file's calibration changes, the file's wins again.
    pub replaces_unix_s: Option<u64>,
    /// The calibration.
    pub calibration: Calibration,
}

impl Store {
    fn file_calibration_path(&self, name: &str) -> PathBuf {
        self.dir()
            .join("file-calibrations")
            .join(format!("{name}.json"))
    }

    /// The stored calibration of profile file `name`, if any.
    pub fn file_calibration(&self, name: &str) -> Result<Option<FileCalibration>, StoreError> {
        check_name(name)?;
        read_json(&self.file_calibration_path(name))
    }

    /// Stores (replaces) profile file `name`'s calibration. Refused on a read-only store
    /// and for a calibration with non-finite numbers.
    pub fn save_file_calibration(
        &self,
        name: &str,
        calibration: &FileCalibration,
    ) -> Result<(), StoreError> {
        self.check_writable()?;
        check_name(name)?;
        check_calibration(&calibration.calibration)?;
        let path = self.file_calibration_path(name);
        if let Some(dir) = path.parent() {
            std::fs::create_dir_all(dir).map_err(|e| StoreError::io(dir, e))?;
        }
        write_json(&self.dir().join("tmp"), &path, calibration)?;
        tracing::info!(
            profile = name,
            "profile file's calibration saved in the data directory"
        );
        Ok(())
    }
}
