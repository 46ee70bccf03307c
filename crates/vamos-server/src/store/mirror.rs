//! The data directory as a list of files, for a fleet of replicas that share one store
//! (`crate::service::fleet`): the writer publishes [`Store::stored_files`]; a reader
//! makes its own directory hold exactly the published list ([`Store::apply_mirror`]) and
//! refuses changes of its own ([`Store::set_read_only`]).
//!
//! Only `models/`, `robots/` and `profiles/` are published: every file there is
//! `<kind>/<name>/<file>` with store names (see the module docs of [`super`]). Job
//! records stay with the replica that ran the job.

use super::files::{self, check_name, list_dir};
use super::{OpenReport, State, Store, StoreError, scan_objects};
use serde::{Deserialize, Serialize};
use std::collections::{BTreeMap, BTreeSet, HashMap};
use std::path::{Path, PathBuf};
use std::time::SystemTime;

/// The folders published.
pub(crate) const PUBLISHED_DIRS: [&str; 3] = ["models", "robots", "profiles"];

/// One committed file of the data directory.
#[derive(Debug, Clone, PartialEq, Eq, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct StoredFile {
    /// `<kind>/<name>/<file>`, e.g. `models/arm/3.vamos`.
    pub path: String,
    /// sha256 of the content, lowercase hex.
    pub sha256: String,
    /// Size, bytes.
    pub size: u64,
}

/// What [`Store::apply_mirror`] changed.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct MirrorChange {
    /// Files written (new or with new content).
    pub written: Vec<String>,
    /// Files removed.
    pub removed: Vec<String>,
}

impl MirrorChange {
    /// Nothing changed.
    pub fn is_empty(&self) -> bool {
        self.written.is_empty() && self.removed.is_empty()
    }

    /// The objects touched, as `(kind folder, name)`: `("models", "arm")`.
    pub fn objects(&self) -> BTreeSet<(String, String)> {
        self.written
            .iter()
            .chain(&self.removed)
            .filter_map(|p| {
                let mut parts = p.split('/');
                Some((parts.next()?.to_string(), parts.next()?.to_string()))
            })
            .collect()
    }
}

/// Hashes of files by path, trusted while size and modification time are unchanged (so
/// a writer that publishes every second hashes each model once).
///
/// A hash is kept only for a file whose modification time was at least
/// [`RACY_WINDOW`] in the past when it was read. File systems stamp times with a coarse
/// clock (a kernel tick, or a whole second on some), so a file replaced moments after it
/// was hashed, by content of the same size (an index whose `"active": 1` became
/// `"active": 2`), can carry the very same time: trusting that entry would hide the
/// change for good. Such "racily clean" files are hashed again on the next listing, as
/// git does with its index.
#[derive(Debug, Default)]
pub(crate) struct HashCache {
    entries: HashMap<PathBuf, (u64, SystemTime, String)>,
}

/// How old a file's modification time must be for its hash to be cached: more than the
/// coarsest time stamp of common file systems (1 s; 2 s on FAT).
const RACY_WINDOW: std::time::Duration = std::time::Duration::from_secs(3);

/// Refuses a published path that is not `<models|robots|profiles>/<name>/<file>` with
/// store names: a shared store's listing never reaches outside the data directory.
pub(crate) fn check_published_path(path: &str) -> Result<(), StoreError> {
    let parts: Vec<&str> = path.split('/').collect();
    let ok = parts.len() == 3
        && PUBLISHED_DIRS.contains(&parts[0])
        && check_name(parts[1]).is_ok()
        && check_name(parts[2]).is_ok();
    if ok {
        Ok(())
    } else {
        Err(StoreError::invalid(format!(
            "{path:?} is not a data directory file (<models|robots|profiles>/<name>/<file>)"
        )))
    }
}

fn is_metadata(path: &str) -> bool {
    path.ends_with(".json")
}

impl Store {
    /// Makes this store refuse every change with [`StoreError::ReadOnly`] and `reason`
    /// (`None`: writable again).
    pub fn set_read_only(&self, reason: Option<String>) {
        *self
            .inner
            .read_only
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner) = reason;
    }

    /// Why changes are refused, if they are.
    pub fn read_only(&self) -> Option<String> {
        self.inner
            .read_only
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
            .clone()
    }

    pub(crate) fn check_writable(&self) -> Result<(), StoreError> {
        match self.read_only() {
            Some(reason) => Err(StoreError::ReadOnly { reason }),
            None => Ok(()),
        }
    }

    /// Every committed file of `models/`, `robots/` and `profiles/`, sorted by path; taken
    /// under the store's lock, so it is one state of the store, never half a change.
    pub fn stored_files(&self) -> Result<Vec<StoredFile>, StoreError> {
        let _st = self.lock();
        self.stored_files_locked()
    }

    fn stored_files_locked(&self) -> Result<Vec<StoredFile>, StoreError> {
        let mut cache = self
            .inner
            .hashes
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner);
        let mut seen = HashMap::new();
        let mut out = Vec::new();
        let listed_at = SystemTime::now();
        for kind in PUBLISHED_DIRS {
            for (name, obj, is_dir) in list_dir(&self.inner.dir.join(kind))? {
                if !is_dir {
                    continue;
                }
                for (file, path, is_dir) in list_dir(&obj)? {
                    let rel = format!("{kind}/{name}/{file}");
                    if is_dir || check_published_path(&rel).is_err() {
                        tracing::debug!(path = %path.display(), "not published: not a store file");
                        continue;
                    }
                    let meta = std::fs::metadata(&path).map_err(|e| StoreError::io(&path, e))?;
                    let mtime = meta.modified().map_err(|e| StoreError::io(&path, e))?;
                    let sha256 = match cache.entries.get(&path) {
                        Some((size, t, sha)) if *size == meta.len() && *t == mtime => sha.clone(),
                        _ => files::hash_file(&path)?.0,
                    };
                    let settled = listed_at
                        .duration_since(mtime)
                        .is_ok_and(|age| age >= RACY_WINDOW);
                    if settled {
                        seen.insert(path, (meta.len(), mtime, sha256.clone()));
                    }
                    out.push(StoredFile {
                        path: rel,
                        sha256,
                        size: meta.len(),
                    });
                }
            }
        }
        cache.entries = seen;
        out.sort();
        Ok(out)
    }

    /// Makes `models/`, `robots/` and `profiles/` hold exactly `files`, then reads the
    /// objects again. A file whose content differs is copied from `staged` (sha256 -> a
    /// file already checked against it); files not listed are removed. Data files are
    /// placed before the metadata naming them and removed after it, each by an atomic
    /// rename, and the whole runs under the store's lock: callers see the state before or
    /// after. Fails, changing nothing, when a path is not a store file or a needed
    /// content is not staged.
    pub fn apply_mirror(
        &self,
        files: &[StoredFile],
        staged: &HashMap<String, PathBuf>,
    ) -> Result<MirrorChange, StoreError> {
        let mut st = self.lock();
        let mut wanted = BTreeMap::new();
        for f in files {
            check_published_path(&f.path)?;
            if wanted.insert(f.path.as_str(), f).is_some() {
                return Err(StoreError::invalid(format!("{:?} is listed twice", f.path)));
            }
        }
        let current: HashMap<String, StoredFile> = self
            .stored_files_locked()?
            .into_iter()
            .map(|f| (f.path.clone(), f))
            .collect();
        let mut to_write: Vec<&StoredFile> = wanted
            .values()
            .copied()
            .filter(|f| current.get(&f.path).is_none_or(|c| c.sha256 != f.sha256))
            .collect();
        if let Some(f) = to_write.iter().find(|f| !staged.contains_key(&f.sha256)) {
            return Err(StoreError::invalid(format!(
                "the content of {:?} ({}) was not fetched",
                f.path, f.sha256
            )));
        }
        // Data files first, metadata last: a reader of the folder never finds metadata
        // naming a file that is not there yet.
        to_write.sort_by_key(|f| (is_metadata(&f.path), f.path.clone()));
        let mut to_remove: Vec<&String> = current
            .keys()
            .filter(|p| !wanted.contains_key(p.as_str()))
            .collect();
        to_remove.sort_by_key(|p| (!is_metadata(p), (*p).clone()));

        let mut change = MirrorChange::default();
        let tmp = self.tmp_dir();
        for f in to_write {
            let target = self.inner.dir.join(&f.path);
            let parent = target.parent().unwrap_or(&self.inner.dir);
            std::fs::create_dir_all(parent).map_err(|e| StoreError::io(parent, e))?;
            place_copy(&tmp, &staged[&f.sha256], &target)?;
            change.written.push(f.path.clone());
        }
        for p in to_remove {
            let path = self.inner.dir.join(p);
            files::remove_file_quiet(&path);
            if let Some(parent) = path.parent() {
                // Only succeeds once the object's folder is empty.
                if std::fs::remove_dir(parent).is_ok()
                    && let Some(kind_dir) = parent.parent()
                {
                    files::sync_dir(kind_dir)?;
                }
            }
            change.removed.push(p.clone());
        }
        let mut fresh = State::default();
        let mut report = OpenReport::default();
        scan_objects(&self.inner.dir, &mut fresh, &mut report)?;
        fresh.jobs = std::mem::take(&mut st.jobs);
        fresh.next_job = st.next_job;
        *st = fresh;
        Ok(change)
    }
}

/// Copies `from` to `target` through a temporary file in `tmp` (fsynced, renamed in).
fn place_copy(tmp: &Path, from: &Path, target: &Path) -> Result<(), StoreError> {
    let part = tmp.join(files::unique_name("mirror", ".tmp"));
    let result = (|| {
        std::fs::copy(from, &part).map_err(|e| StoreError::io(&part, e))?;
        std::fs::File::open(&part)
            .and_then(|f| f.sync_all())
            .map_err(|e| StoreError::io(&part, e))?;
        files::rename_durable(&part, target)
    })();
    if result.is_err() {
        let _ = std::fs::remove_file(&part);
    }
    result
}
