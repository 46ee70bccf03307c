//! Ended live sessions (`ended/<key>.json`): what the live view keeps of a robot's last
//! sessions (their summary, a downsampled timeline, their alarms), so that a restart
//! finds them again. The session layer owns the record's type and its bounds
//! ([`crate::session::history`]); the store only writes, lists and removes the files.
//! They are this replica's own, like its recordings: written on a read-only replica too,
//! and never part of a fleet's shared store.

use super::files::{check_name, list_dir, read_json, remove_file_quiet, write_json};
use super::{Store, StoreError};
use serde::Serialize;
use serde::de::DeserializeOwned;

/// The folder of ended sessions in the data directory.
const DIR: &str = "ended";

impl Store {
    fn ended_dir(&self) -> std::path::PathBuf {
        self.dir().join(DIR)
    }

    /// Stores ended session `key` (a store name), replacing an earlier record of it.
    pub fn put_ended_session<T: Serialize + DeserializeOwned>(
        &self,
        key: &str,
        record: &T,
    ) -> Result<(), StoreError> {
        check_name(key)?;
        let dir = self.ended_dir();
        std::fs::create_dir_all(&dir).map_err(|e| StoreError::io(&dir, e))?;
        write_json(
            &self.dir().join("tmp"),
            &dir.join(format!("{key}.json")),
            record,
        )
    }

    /// Every stored ended session as `(key, record)`, by key. A file that does not read
    /// (a checksum, a record of another version) is skipped with a warning and removed:
    /// these records are a view's memory, not data anyone depends on.
    pub fn ended_sessions<T: DeserializeOwned>(&self) -> Result<Vec<(String, T)>, StoreError> {
        let dir = self.ended_dir();
        if !dir.exists() {
            return Ok(Vec::new());
        }
        let mut out = Vec::new();
        for (name, path, is_dir) in list_dir(&dir)? {
            let Some(key) = name.strip_suffix(".json").filter(|_| !is_dir) else {
                continue;
            };
            match read_json::<T>(&path) {
                Ok(Some(record)) => out.push((key.to_string(), record)),
                Ok(None) => {}
                Err(e) => {
                    tracing::warn!(path = %path.display(), "ended session not restored (removed): {e}");
                    remove_file_quiet(&path);
                }
            }
        }
        Ok(out)
    }

    /// Removes ended session `key` (nothing when there is none).
    pub fn remove_ended_session(&self, key: &str) {
        if check_name(key).is_ok() {
            remove_file_quiet(&self.ended_dir().join(format!("{key}.json")));
        }
    }
}

#[cfg(test)]
mod tests {
    use crate::store::{Store, StoreLimits};

    #[derive(Debug, PartialEq, serde::Serialize, serde::Deserialize)]
    struct Record {
        robot: String,
        frames: u64,
    }

    #[test]
    fn ended_sessions_survive_a_reopen_and_bad_files_are_dropped() {
        let dir = tempfile::tempdir().unwrap();
        let r = |robot: &str, frames| Record {
            robot: robot.into(),
            frames,
        };
        {
            let store = Store::open(dir.path(), StoreLimits::default()).unwrap();
            store.put_ended_session("a-1", &r("a", 3)).unwrap();
            store.put_ended_session("b-1", &r("b", 4)).unwrap();
            store.put_ended_session("a-1", &r("a", 5)).unwrap();
            assert!(store.put_ended_session("../x", &r("x", 1)).is_err());
            store.remove_ended_session("b-1");
            store.remove_ended_session("../b-1");
        }
        std::fs::write(dir.path().join("ended/broken.json"), b"{}").unwrap();
        let store = Store::open(dir.path(), StoreLimits::default()).unwrap();
        assert!(store.problems().is_empty(), "{:?}", store.problems());
        let all: Vec<(String, Record)> = store.ended_sessions().unwrap();
        assert_eq!(all, vec![("a-1".to_string(), r("a", 5))]);
        assert!(!dir.path().join("ended/broken.json").exists());
    }
}
