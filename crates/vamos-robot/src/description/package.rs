//! A robot package's files: finding the URDF in a folder, unpacking an archive into
//! memory (paths normalised, caps enforced), and resolving mesh URIs against either.

use crate::config::RobotConfig;
use crate::error::RobotError;
use std::collections::{HashMap, HashSet};
use std::io::Read;
use std::path::{Component, Path, PathBuf};

pub(super) fn urdf_folder(path: &Path) -> Result<PathBuf, RobotError> {
    let abs = std::fs::canonicalize(path).map_err(|e| RobotError::io(path, &e))?;
    Ok(abs.parent().map(Path::to_path_buf).unwrap_or_default())
}

pub(super) fn has_urdf_extension(p: &Path) -> bool {
    p.extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("urdf"))
}

/// The shallowest `.urdf` below `root`; several at that depth is an error.
pub(super) fn pick_urdf(
    root: &Path,
    urdfs: &[PathBuf],
    label: &str,
) -> Result<PathBuf, RobotError> {
    let depth = |p: &Path| p.strip_prefix(root).unwrap_or(p).components().count();
    let Some(best) = urdfs.iter().map(|p| depth(p)).min() else {
        return Err(RobotError::UrdfNotFound {
            path: label.to_string(),
            reason: "it holds no .urdf file".into(),
        });
    };
    let mut at_best: Vec<&PathBuf> = urdfs.iter().filter(|p| depth(p) == best).collect();
    at_best.sort();
    match at_best.as_slice() {
        [one] => Ok((*one).clone()),
        many => Err(RobotError::UrdfNotFound {
            path: label.to_string(),
            reason: format!(
                "several .urdf files at the same level: {}",
                many.iter()
                    .map(|p| p.display().to_string())
                    .collect::<Vec<_>>()
                    .join(", ")
            ),
        }),
    }
}

/// Visits entries below `dir` up to `max_depth` levels (hidden entries and links skipped).
pub(super) fn walk_dir(
    dir: &Path,
    depth: usize,
    max_depth: usize,
    visit: &mut dyn FnMut(&Path, bool),
) {
    if depth >= max_depth {
        return;
    }
    let Ok(entries) = std::fs::read_dir(dir) else {
        return;
    };
    let mut entries: Vec<_> = entries.filter_map(Result::ok).collect();
    entries.sort_by_key(|e| e.file_name());
    for e in entries {
        if e.file_name().to_string_lossy().starts_with('.') {
            continue;
        }
        let Ok(ft) = e.file_type() else { continue };
        let p = e.path();
        if ft.is_dir() {
            visit(&p, true);
            walk_dir(&p, depth + 1, max_depth, visit);
        } else if ft.is_file() {
            visit(&p, false);
        }
    }
}

/// Lexically normalised relative path: no root, no `..` above the start.
pub(super) fn normalize_relative(p: &Path) -> Option<PathBuf> {
    let mut out = PathBuf::new();
    for c in p.components() {
        match c {
            Component::Normal(s) => out.push(s),
            Component::CurDir => {}
            Component::ParentDir => {
                if !out.pop() {
                    return None;
                }
            }
            Component::RootDir | Component::Prefix(_) => return None,
        }
    }
    Some(out)
}

pub(super) fn unpack_archive(
    bytes: &[u8],
    label: &str,
    cfg: &RobotConfig,
) -> Result<HashMap<PathBuf, Vec<u8>>, RobotError> {
    let archive_err = |message: String| RobotError::Archive {
        path: label.to_string(),
        message,
    };
    let mut files = HashMap::new();
    let mut total = 0u64;
    let mut add = |name: &str, path: Option<PathBuf>, reader: &mut dyn Read| {
        let Some(rel) = path.as_deref().and_then(normalize_relative) else {
            return Err(RobotError::ArchiveUnsafeEntry {
                path: label.to_string(),
                entry: name.to_string(),
            });
        };
        if files.len() >= cfg.max_archive_entries {
            return Err(RobotError::ArchiveTooLarge {
                path: label.to_string(),
                what: "entries",
                limit: cfg.max_archive_entries as u64,
            });
        }
        let left = cfg.max_archive_bytes.saturating_sub(total);
        let mut data = Vec::new();
        reader
            .take(left + 1)
            .read_to_end(&mut data)
            .map_err(|e| archive_err(format!("{name}: {e}")))?;
        total += data.len() as u64;
        if total > cfg.max_archive_bytes {
            return Err(RobotError::ArchiveTooLarge {
                path: label.to_string(),
                what: "bytes",
                limit: cfg.max_archive_bytes,
            });
        }
        files.insert(rel, data);
        Ok(())
    };
    if bytes.starts_with(b"PK\x03\x04") || bytes.starts_with(b"PK\x05\x06") {
        let mut zip = zip::ZipArchive::new(std::io::Cursor::new(bytes))
            .map_err(|e| archive_err(e.to_string()))?;
        for i in 0..zip.len() {
            let mut f = zip.by_index(i).map_err(|e| archive_err(e.to_string()))?;
            if f.is_dir() || f.is_symlink() {
                continue;
            }
            let name = f
                .name()
                .map_or_else(|_| format!("entry {i}"), |n| n.to_string());
            let path = f.enclosed_name();
            add(&name, path, &mut f)?;
        }
    } else if bytes.starts_with(&[0x1f, 0x8b]) {
        let mut tar = tar::Archive::new(flate2::read::GzDecoder::new(bytes));
        let entries = tar.entries().map_err(|e| archive_err(e.to_string()))?;
        for entry in entries {
            let mut e = entry.map_err(|e| archive_err(e.to_string()))?;
            if !e.header().entry_type().is_file() {
                continue; // folders, links, pax headers
            }
            let path = e
                .path()
                .map_err(|e| archive_err(e.to_string()))?
                .into_owned();
            let name = path.display().to_string();
            add(&name, Some(path), &mut e)?;
        }
    } else {
        return Err(archive_err(
            "not a zip or gzip-compressed tar archive".into(),
        ));
    }
    Ok(files)
}

/// Where the files of a robot come from.
pub(super) enum Store {
    /// The file system (absolute paths).
    Dir,
    /// An unpacked archive (relative, normalised paths).
    Memory {
        label: String,
        files: HashMap<PathBuf, Vec<u8>>,
    },
    /// A URDF string without a mesh root: only absolute paths (`file://`) on the file
    /// system.
    Nothing,
}

impl Store {
    pub(super) fn is_file(&self, p: &Path) -> bool {
        match self {
            Self::Dir => p.is_file(),
            Self::Memory { files, .. } => files.contains_key(p),
            Self::Nothing => p.is_absolute() && p.is_file(),
        }
    }

    pub(super) fn display(&self, p: &Path) -> String {
        match self {
            Self::Memory { label, .. } => format!("{label}!/{}", p.display()),
            _ => p.display().to_string(),
        }
    }

    /// Reads a file, refusing files over `cap` bytes before reading them.
    pub(super) fn read(&self, p: &Path, cap: u64) -> Result<Vec<u8>, RobotError> {
        let too_large = |bytes: u64| RobotError::MeshFileTooLarge {
            path: self.display(p),
            bytes,
            limit_bytes: cap,
        };
        match self {
            Self::Dir => {
                let unreadable = |e: std::io::Error| RobotError::MeshUnreadable {
                    path: p.display().to_string(),
                    message: e.to_string(),
                };
                let len = std::fs::metadata(p).map_err(unreadable)?.len();
                if len > cap {
                    return Err(too_large(len));
                }
                std::fs::read(p).map_err(unreadable)
            }
            Self::Memory { files, .. } => {
                let data = files.get(p).ok_or_else(|| RobotError::MeshUnreadable {
                    path: self.display(p),
                    message: "not in the archive".into(),
                })?;
                if data.len() as u64 > cap {
                    return Err(too_large(data.len() as u64));
                }
                Ok(data.clone())
            }
            Self::Nothing if p.is_absolute() => Self::Dir.read(p, cap),
            Self::Nothing => Err(RobotError::MeshUnreadable {
                path: p.display().to_string(),
                message: "no mesh root given".into(),
            }),
        }
    }

    /// Folders named `name` within `root`, at most `max_depth` levels down.
    pub(super) fn folders_named(&self, root: &Path, name: &str, max_depth: usize) -> Vec<PathBuf> {
        let mut found = Vec::new();
        match self {
            Self::Dir => walk_dir(root, 0, max_depth, &mut |p: &Path, is_dir| {
                if is_dir && p.file_name().is_some_and(|n| n == name) {
                    found.push(p.to_path_buf());
                }
            }),
            Self::Memory { files, .. } => {
                let mut set = HashSet::new();
                for f in files.keys() {
                    let Ok(rel) = f.strip_prefix(root) else {
                        continue;
                    };
                    let mut dir = root.to_path_buf();
                    let comps: Vec<_> = rel.components().collect();
                    for c in comps
                        .iter()
                        .take(comps.len().saturating_sub(1))
                        .take(max_depth)
                    {
                        dir.push(c.as_os_str());
                        if c.as_os_str() == name {
                            set.insert(dir.clone());
                        }
                    }
                }
                found = set.into_iter().collect();
                found.sort();
            }
            Self::Nothing => {}
        }
        found
    }
}

/// Mesh path resolution for one URDF.
pub(super) struct Resolver<'a> {
    pub(super) store: &'a Store,
    pub(super) urdf_dir: &'a Path,
    pub(super) package_root: &'a Path,
}

impl Resolver<'_> {
    /// Whether `uri` points outside a sealed (in-memory) package: absolute, or leaving
    /// it with `..`. Never for the file system, where absolute paths are allowed.
    pub(super) fn leaves_package(&self, uri: &str) -> bool {
        if !matches!(self.store, Store::Memory { .. }) {
            return false;
        }
        if let Some(rest) = uri.strip_prefix("package://") {
            let rel = rest.split_once('/').map_or("", |(_, rel)| rel);
            return normalize_relative(Path::new(rel)).is_none();
        }
        let path = Path::new(uri.strip_prefix("file://").unwrap_or(uri));
        path.is_absolute() || normalize_relative(&self.urdf_dir.join(path)).is_none()
    }

    /// The path of a mesh `uri` in the store, or why it was not found.
    pub(super) fn resolve(&self, uri: &str) -> Result<PathBuf, String> {
        let in_memory = matches!(self.store, Store::Memory { .. });
        if let Some(rest) = uri.strip_prefix("package://") {
            let (name, rel) = rest
                .split_once('/')
                .ok_or("no path after the package name")?;
            let rel = normalize_relative(Path::new(rel)).ok_or("path leaves the package")?;
            let mut candidates = Vec::new();
            for dir in self.urdf_dir.ancestors() {
                if dir.file_name().is_some_and(|n| n == name) {
                    candidates.push(dir.join(&rel));
                }
                candidates.push(dir.join(name).join(&rel));
            }
            for dir in self.store.folders_named(self.package_root, name, 3) {
                candidates.push(dir.join(&rel));
            }
            candidates.push(self.package_root.join(&rel));
            candidates.push(self.urdf_dir.join(&rel));
            return candidates
                .into_iter()
                .find(|c| self.store.is_file(c))
                .ok_or_else(|| {
                    format!("no folder named {name:?} in or above the package holds it")
                });
        }
        let plain = uri.strip_prefix("file://").unwrap_or(uri);
        let path = Path::new(plain);
        let candidate = if path.is_absolute() {
            if in_memory {
                return Err("absolute paths are not allowed inside an archive".into());
            }
            path.to_path_buf()
        } else if in_memory {
            let joined = self.urdf_dir.join(path);
            normalize_relative(&joined).ok_or("path leaves the archive")?
        } else {
            self.urdf_dir.join(path)
        };
        if self.store.is_file(&candidate) {
            Ok(candidate)
        } else {
            Err(format!("{} does not exist", self.store.display(&candidate)))
        }
    }
}
