//! File-level building blocks: names, atomic writes, checksummed JSON, hashing.

use super::StoreError;
use serde::Serialize;
use serde::de::DeserializeOwned;
use sha2::{Digest, Sha256};
use std::io::{Read, Write};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};

/// `format` of every metadata file.
pub(crate) const ENVELOPE_FORMAT: &str = "vamos-store/1";
/// Longest object name.
pub(crate) const MAX_NAME_CHARS: usize = 64;

/// Refuses names that are not `[A-Za-z0-9._-]{1,64}` or that start with `.` (so a name is
/// always one plain path component, never `..`).
pub(crate) fn check_name(name: &str) -> Result<(), StoreError> {
    let ok = !name.is_empty()
        && name.len() <= MAX_NAME_CHARS
        && !name.starts_with('.')
        && name
            .bytes()
            .all(|b| b.is_ascii_alphanumeric() || matches!(b, b'.' | b'_' | b'-'));
    if ok {
        Ok(())
    } else {
        Err(StoreError::BadName { name: name.into() })
    }
}

/// Seconds since the Unix epoch (0 if the clock is before it).
pub(crate) fn now_unix_s() -> u64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_secs())
}

/// A name for a temporary entry, unique within this process and distinct from other
/// processes' (pid), e.g. `upload-1234-7.part`.
pub(crate) fn unique_name(prefix: &str, suffix: &str) -> String {
    static COUNTER: AtomicU64 = AtomicU64::new(0);
    let n = COUNTER.fetch_add(1, Ordering::Relaxed);
    format!("{prefix}-{}-{n}{suffix}", std::process::id())
}

/// Lowercase hex of a digest.
pub(crate) fn hex(bytes: &[u8]) -> String {
    use std::fmt::Write as _;
    let mut s = String::with_capacity(bytes.len() * 2);
    for b in bytes {
        // Invariant: writing into a String cannot fail.
        let _ = write!(s, "{b:02x}");
    }
    s
}

/// sha256 (hex) and length of a file, streamed.
pub(crate) fn hash_file(path: &Path) -> Result<(String, u64), StoreError> {
    let mut f = std::fs::File::open(path).map_err(|e| StoreError::io(path, e))?;
    let mut hasher = Sha256::new();
    let mut buf = vec![0u8; 1 << 16];
    let mut total = 0u64;
    loop {
        let n = f.read(&mut buf).map_err(|e| StoreError::io(path, e))?;
        if n == 0 {
            break;
        }
        hasher.update(&buf[..n]);
        total += n as u64;
    }
    Ok((hex(&hasher.finalize()), total))
}

/// Makes the entries of `dir` (creations, renames, removals) durable.
pub(crate) fn sync_dir(dir: &Path) -> Result<(), StoreError> {
    #[cfg(unix)]
    {
        std::fs::File::open(dir)
            .and_then(|d| d.sync_all())
            .map_err(|e| StoreError::io(dir, e))?;
    }
    #[cfg(not(unix))]
    let _ = dir;
    Ok(())
}

/// Renames `from` to `to` and makes both folders' entries durable.
pub(crate) fn rename_durable(from: &Path, to: &Path) -> Result<(), StoreError> {
    std::fs::rename(from, to).map_err(|e| StoreError::io(to, e))?;
    if let Some(parent) = to.parent() {
        sync_dir(parent)?;
    }
    if let Some(parent) = from.parent()
        && Some(parent) != to.parent()
    {
        sync_dir(parent)?;
    }
    Ok(())
}

/// Writes `bytes` to `target` atomically: a temporary file in `tmp_dir` (same file
/// system), written and fsynced, renamed over `target`, and `target`'s folder fsynced.
/// Readers see the old content or the new, never a part.
pub(crate) fn write_atomic(tmp_dir: &Path, target: &Path, bytes: &[u8]) -> Result<(), StoreError> {
    let tmp = tmp_dir.join(unique_name("write", ".tmp"));
    let result = (|| {
        let mut f = std::fs::File::create(&tmp).map_err(|e| StoreError::io(&tmp, e))?;
        f.write_all(bytes).map_err(|e| StoreError::io(&tmp, e))?;
        f.sync_all().map_err(|e| StoreError::io(&tmp, e))?;
        drop(f);
        rename_durable(&tmp, target)
    })();
    if result.is_err() {
        let _ = std::fs::remove_file(&tmp);
    }
    result
}

/// The on-disk form of every metadata file: the body and the sha256 of its compact JSON.
#[derive(Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
struct Envelope {
    format: String,
    sha256: String,
    body: serde_json::Value,
}

/// Serialises `body` into a checksummed envelope and writes it atomically to `target`.
/// A body that does not read back as itself (a NaN float becomes `null` in JSON) is
/// refused as invalid before anything is written.
pub(crate) fn write_json<T: Serialize + DeserializeOwned>(
    tmp_dir: &Path,
    target: &Path,
    body: &T,
) -> Result<(), StoreError> {
    let value = serde_json::to_value(body).map_err(|e| StoreError::invalid(e.to_string()))?;
    serde_json::from_value::<T>(value.clone()).map_err(|e| {
        StoreError::invalid(format!(
            "{} would not read back ({e}); non-finite numbers cannot be stored",
            target.display()
        ))
    })?;
    let compact = serde_json::to_vec(&value).map_err(|e| StoreError::invalid(e.to_string()))?;
    let envelope = Envelope {
        format: ENVELOPE_FORMAT.into(),
        sha256: vamos_model::bundle::sha256_hex(&compact),
        body: value,
    };
    let mut text =
        serde_json::to_vec_pretty(&envelope).map_err(|e| StoreError::invalid(e.to_string()))?;
    text.push(b'\n');
    write_atomic(tmp_dir, target, &text)
}

/// Reads a checksummed metadata file. `Ok(None)` when it does not exist; a file that is
/// not an envelope, fails its checksum or does not parse as `T` is [`StoreError::Corrupt`].
pub(crate) fn read_json<T: DeserializeOwned>(path: &Path) -> Result<Option<T>, StoreError> {
    let bytes = match std::fs::read(path) {
        Ok(b) => b,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(None),
        Err(e) => return Err(StoreError::io(path, e)),
    };
    let corrupt = |reason: String| StoreError::Corrupt {
        path: path.into(),
        reason,
    };
    let envelope: Envelope = serde_json::from_slice(&bytes)
        .map_err(|e| corrupt(format!("not a store metadata file: {e}")))?;
    if envelope.format != ENVELOPE_FORMAT {
        return Err(corrupt(format!(
            "format {:?}, expected {ENVELOPE_FORMAT:?}",
            envelope.format
        )));
    }
    let compact = serde_json::to_vec(&envelope.body).map_err(|e| corrupt(e.to_string()))?;
    let actual = vamos_model::bundle::sha256_hex(&compact);
    if actual != envelope.sha256 {
        return Err(corrupt(format!(
            "checksum mismatch: recorded {}, content has {actual}",
            envelope.sha256
        )));
    }
    serde_json::from_value(envelope.body)
        .map(Some)
        .map_err(|e| corrupt(format!("unexpected content: {e}")))
}

/// Removes a folder so that it vanishes at once: renamed into `tmp_dir` first (atomic),
/// then deleted there (a crash in between leaves only a temporary entry, which the next
/// open removes).
pub(crate) fn remove_dir_atomic(tmp_dir: &Path, dir: &Path) -> Result<(), StoreError> {
    let trash = tmp_dir.join(unique_name("deleted", ""));
    rename_durable(dir, &trash)?;
    if let Err(e) = std::fs::remove_dir_all(&trash) {
        tracing::warn!(path = %trash.display(), "cannot remove a deleted folder: {e}");
    }
    Ok(())
}

/// Removes a file; a missing file is not an error.
pub(crate) fn remove_file_quiet(path: &Path) {
    if let Err(e) = std::fs::remove_file(path)
        && e.kind() != std::io::ErrorKind::NotFound
    {
        tracing::warn!(path = %path.display(), "cannot remove: {e}");
    }
}

/// Entries of a folder as `(file name, path, is_dir)`; names that are not UTF-8 are
/// returned lossily (they never match a store name).
pub(crate) fn list_dir(dir: &Path) -> Result<Vec<(String, PathBuf, bool)>, StoreError> {
    let mut out = Vec::new();
    for entry in std::fs::read_dir(dir).map_err(|e| StoreError::io(dir, e))? {
        let entry = entry.map_err(|e| StoreError::io(dir, e))?;
        let is_dir = entry
            .file_type()
            .map_err(|e| StoreError::io(entry.path(), e))?
            .is_dir();
        out.push((
            entry.file_name().to_string_lossy().into_owned(),
            entry.path(),
            is_dir,
        ));
    }
    out.sort();
    Ok(out)
}
