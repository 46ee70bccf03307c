//! What `Store::open` reads: every object directory scanned, data files verified against
//! their checksums, orphans removed, problems quarantined.

use super::*;

/// Verifies a data file against its recorded checksum and size: `Err(reason)` when it
/// does not match or cannot be read.
pub(super) fn verify_file(path: &Path, sha256: &str, size_bytes: u64) -> Result<(), String> {
    let (actual, size) = files::hash_file(path).map_err(|e| e.to_string())?;
    if size != size_bytes {
        return Err(format!("size {size} bytes, recorded {size_bytes}"));
    }
    if actual != sha256 {
        return Err(format!(
            "checksum mismatch: recorded {sha256}, file has {actual}"
        ));
    }
    Ok(())
}

/// Sub-folders of `parent` that are named like objects; other entries become strays.
pub(super) fn object_dirs(
    parent: &Path,
    state: &mut State,
) -> Result<Vec<(String, PathBuf)>, StoreError> {
    let mut out = Vec::new();
    for (name, path, is_dir) in list_dir(parent)? {
        if !is_dir {
            state.stray(path, &name, "not a folder");
        } else if check_name(&name).is_err() {
            state.stray(path, &name, "not a valid object name");
        } else {
            out.push((name, path));
        }
    }
    Ok(out)
}

/// `<digits>.<ext>` -> the number.
pub(super) fn numbered(file: &str, ext: &str) -> Option<u32> {
    let stem = file.strip_suffix(ext)?.strip_suffix('.')?;
    if stem.is_empty() || !stem.bytes().all(|b| b.is_ascii_digit()) {
        return None;
    }
    stem.parse().ok()
}

pub(super) fn remove_orphan(path: &Path, report: &mut OpenReport) {
    tracing::info!(path = %path.display(), "removing a data file no metadata names (interrupted write)");
    files::remove_file_quiet(path);
    report.removed_orphan_files += 1;
}

/// Reads models, robots and profiles (not jobs) into `state`.
pub(super) fn scan_objects(
    dir: &Path,
    state: &mut State,
    report: &mut OpenReport,
) -> Result<(), StoreError> {
    scan_models(dir, state, report)?;
    scan_robots(dir, state, report)?;
    scan_profiles(dir, state, report)
}

pub(super) fn scan_models(
    dir: &Path,
    state: &mut State,
    report: &mut OpenReport,
) -> Result<(), StoreError> {
    for (name, path) in object_dirs(&dir.join("models"), state)? {
        let index_path = path.join(MODEL_INDEX);
        let index: ModelIndex = match read_json(&index_path) {
            Ok(Some(i)) => i,
            Ok(None) => {
                state.quarantine(MODEL, &name, index_path, "index.json is missing".into());
                continue;
            }
            Err(e) => {
                state.quarantine(MODEL, &name, index_path, e.to_string());
                continue;
            }
        };
        report.verified_files += 1;
        if let Err(reason) = models::check_index(&name, &index) {
            state.quarantine(MODEL, &name, index_path, reason);
            continue;
        }
        let mut problems = BTreeMap::new();
        for v in &index.versions {
            let file = path.join(format!("{}.{MODEL_EXT}", v.version));
            match verify_file(&file, &v.sha256, v.size_bytes) {
                Ok(()) => report.verified_files += 1,
                Err(reason) => {
                    problems.insert(v.version, reason);
                }
            }
        }
        for (file, fpath, _) in list_dir(&path)? {
            if file == MODEL_INDEX {
                continue;
            }
            match numbered(&file, MODEL_EXT) {
                Some(n) if !index.versions.iter().any(|v| v.version == n) => {
                    remove_orphan(&fpath, report);
                }
                Some(_) => {}
                None => {
                    tracing::warn!(path = %fpath.display(), "unexpected entry in a model folder; left alone")
                }
            }
        }
        state.models.insert(name, ModelEntry { index, problems });
    }
    Ok(())
}

pub(super) fn scan_robots(
    dir: &Path,
    state: &mut State,
    report: &mut OpenReport,
) -> Result<(), StoreError> {
    for (name, path) in object_dirs(&dir.join("robots"), state)? {
        let meta_path = path.join(ROBOT_META);
        let meta: RobotMeta = match read_json(&meta_path) {
            Ok(Some(m)) => m,
            Ok(None) => {
                state.quarantine(ROBOT, &name, meta_path, "meta.json is missing".into());
                continue;
            }
            Err(e) => {
                state.quarantine(ROBOT, &name, meta_path, e.to_string());
                continue;
            }
        };
        report.verified_files += 1;
        if meta.name != name {
            let reason = format!("meta.json names robot {:?}", meta.name);
            state.quarantine(ROBOT, &name, meta_path, reason);
            continue;
        }
        let current = meta.file_name();
        let problem = match verify_file(&path.join(&current), &meta.sha256, meta.size_bytes) {
            Ok(()) => {
                report.verified_files += 1;
                None
            }
            Err(reason) => Some(reason),
        };
        for (file, fpath, _) in list_dir(&path)? {
            if file == ROBOT_META || file == current {
                continue;
            }
            let ours = [RobotFormat::Urdf, RobotFormat::TarGz, RobotFormat::Zip]
                .iter()
                .any(|f| numbered(&file, f.extension()).is_some());
            if ours {
                remove_orphan(&fpath, report);
            } else {
                tracing::warn!(path = %fpath.display(), "unexpected entry in a robot folder; left alone");
            }
        }
        state.robots.insert(name, RobotEntry { meta, problem });
    }
    Ok(())
}

pub(super) fn scan_profiles(
    dir: &Path,
    state: &mut State,
    report: &mut OpenReport,
) -> Result<(), StoreError> {
    for (name, path) in object_dirs(&dir.join("profiles"), state)? {
        let record_path = path.join(PROFILE_FILE);
        let record: ProfileRecord = match read_json(&record_path) {
            Ok(Some(r)) => r,
            Ok(None) => {
                state.quarantine(
                    PROFILE,
                    &name,
                    record_path,
                    "profile.json is missing".into(),
                );
                continue;
            }
            Err(e) => {
                state.quarantine(PROFILE, &name, record_path, e.to_string());
                continue;
            }
        };
        report.verified_files += 1;
        if record.name != name {
            let reason = format!("profile.json names profile {:?}", record.name);
            state.quarantine(PROFILE, &name, record_path, reason);
            continue;
        }
        let (calibration, calibration_problem) =
            match read_json::<Calibration>(&path.join(CALIBRATION_FILE)) {
                Ok(Some(c)) => {
                    report.verified_files += 1;
                    (Some(c), None)
                }
                Ok(None) => (None, None),
                Err(e) => (None, Some(e.to_string())),
            };
        for (file, fpath, _) in list_dir(&path)? {
            if file != PROFILE_FILE && file != CALIBRATION_FILE {
                tracing::warn!(path = %fpath.display(), "unexpected entry in a profile folder; left alone");
            }
        }
        state.profiles.insert(
            name,
            ProfileEntry {
                record,
                calibration,
                calibration_problem,
            },
        );
    }
    Ok(())
}
