//! A robot package's files: finding the URDF in a folder, unpacking an archive into
//! memory (paths normalised, caps enforced), resolving mesh URIs against either, and
//! finding ROS packages in folders given by the user ([`find_package`]).

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

/// Folder levels below a package search folder that [`find_package`] looks through (a
/// colcon workspace's `install/NAME/share/NAME` is three).
pub const PACKAGE_SEARCH_DEPTH: usize = 4;

/// Entries [`find_package`] looks at below one search folder before it gives up on it.
const PACKAGE_SEARCH_MAX_ENTRIES: usize = 200_000;

/// The largest `package.xml` read, bytes.
const MAX_PACKAGE_XML_BYTES: u64 = 1 << 20;

/// The package name and the path inside it of a `package://NAME/REST` mesh URI.
pub fn package_of(uri: &str) -> Option<(&str, &str)> {
    let rest = uri.strip_prefix("package://")?;
    Some(rest.split_once('/').unwrap_or((rest, "")))
}

/// The `<name>` that the ROS `package.xml` in `dir` declares, if there is one.
pub fn package_xml_name(dir: &Path) -> Option<String> {
    let path = dir.join("package.xml");
    let meta = std::fs::metadata(&path).ok()?;
    if !meta.is_file() || meta.len() > MAX_PACKAGE_XML_BYTES {
        return None;
    }
    let text = std::fs::read_to_string(&path).ok()?;
    let doc = roxmltree::Document::parse(&text).ok()?;
    let root = doc.root_element();
    if !root.has_tag_name("package") {
        return None;
    }
    root.children()
        .find(|n| n.has_tag_name("name"))
        .and_then(|n| n.text())
        .map(|t| t.trim().to_string())
        .filter(|t| !t.is_empty())
}

/// How a folder is the package `name`: by its `package.xml` (certain) or only by its
/// folder name (a package without one, e.g. a copied `meshes` tree).
#[derive(Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
enum Match {
    Declared,
    Named,
}

/// How `dir` is the package `name` (if it is), and whether it is a package at all (a
/// `package.xml` declaring any name).
fn match_package(dir: &Path, name: &str) -> (Option<Match>, bool) {
    match package_xml_name(dir) {
        Some(declared) if declared == name => (Some(Match::Declared), true),
        // A package.xml naming another package: that package, whatever the folder.
        Some(_) => (None, true),
        None if dir.file_name().is_some_and(|n| n == name) => (Some(Match::Named), false),
        None => (None, false),
    }
}

/// The folder of the ROS package `name` in `roots`, tried in order: a root that is the
/// package itself (its `package.xml` declares `name`, or, without one, its folder is
/// called `name`), else the package found below it, at most [`PACKAGE_SEARCH_DEPTH`]
/// levels down (hidden folders skipped, links followed). Below one root, a folder whose
/// `package.xml` declares `name` wins over one that is only called `name` (so a colcon
/// `install/NAME/share/NAME` is found, not `install/NAME`), then the shallowest, then
/// the first in name order. Other packages are not searched inside (ROS packages do not
/// nest). `None` when no root holds it.
pub fn find_package(name: &str, roots: &[PathBuf]) -> Option<PathBuf> {
    if name.is_empty() {
        return None;
    }
    roots.iter().find_map(|root| find_below(root, name))
}

fn find_below(root: &Path, name: &str) -> Option<PathBuf> {
    if !root.is_dir() {
        return None;
    }
    // The best candidate so far: (how it matches, depth, path), smallest first.
    let mut best: Option<(Match, usize, PathBuf)> = match match_package(root, name) {
        (Some(Match::Declared), _) => return Some(root.to_path_buf()),
        (Some(Match::Named), _) => Some((Match::Named, 0, root.to_path_buf())),
        (None, true) => return None, // another package: nothing nests in it
        (None, false) => None,
    };
    let mut level = vec![root.to_path_buf()];
    let mut seen = 0usize;
    for depth in 1..=PACKAGE_SEARCH_DEPTH {
        let mut next = Vec::new();
        for dir in &level {
            let Ok(entries) = std::fs::read_dir(dir) else {
                continue;
            };
            for entry in entries.filter_map(Result::ok) {
                seen += 1;
                if seen > PACKAGE_SEARCH_MAX_ENTRIES {
                    return best.map(|(_, _, p)| p);
                }
                if entry.file_name().to_string_lossy().starts_with('.') {
                    continue;
                }
                let path = entry.path();
                if !path.is_dir() {
                    continue;
                }
                let (found, is_package) = match_package(&path, name);
                if let Some(m) = found
                    && best
                        .as_ref()
                        .is_none_or(|(bm, bd, bp)| (m, depth, &path) < (*bm, *bd, bp))
                {
                    best = Some((m, depth, path.clone()));
                }
                // Into folders that are no package (one only called `name` may hold the
                // declared one, as colcon's isolated install does).
                if !is_package {
                    next.push(path);
                }
            }
        }
        if best.as_ref().is_some_and(|(m, _, _)| *m == Match::Declared) {
            break;
        }
        level = next;
    }
    best.map(|(_, _, p)| p)
}

/// Mesh path resolution for one URDF.
pub(super) struct Resolver<'a> {
    pub(super) store: &'a Store,
    pub(super) urdf_dir: &'a Path,
    pub(super) package_root: &'a Path,
    /// Package folders found in the package paths the caller gave, by package name;
    /// tried before the folders around the URDF.
    pub(super) packages: &'a HashMap<String, PathBuf>,
}

impl Resolver<'_> {
    /// Whether `uri` points outside a sealed (in-memory) package: absolute, or leaving
    /// it with `..`. Never for the file system, where absolute paths are allowed.
    pub(super) fn leaves_package(&self, uri: &str) -> bool {
        if !matches!(self.store, Store::Memory { .. }) {
            return false;
        }
        if let Some((_, rel)) = package_of(uri) {
            return normalize_relative(Path::new(rel)).is_none();
        }
        let path = Path::new(uri.strip_prefix("file://").unwrap_or(uri));
        path.is_absolute() || normalize_relative(&self.urdf_dir.join(path)).is_none()
    }

    /// The path of a mesh `uri` in the store, or why it was not found.
    pub(super) fn resolve(&self, uri: &str) -> Result<PathBuf, String> {
        let in_memory = matches!(self.store, Store::Memory { .. });
        if let Some((name, rel)) = package_of(uri) {
            if rel.is_empty() {
                return Err("no path after the package name".into());
            }
            let rel = normalize_relative(Path::new(rel)).ok_or("path leaves the package")?;
            let mut candidates = Vec::new();
            if let Some(dir) = self.packages.get(name) {
                candidates.push(dir.join(&rel));
            }
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
                .ok_or_else(|| match self.packages.get(name) {
                    Some(dir) => format!(
                        "package {name:?} is at {}, but it does not hold {}",
                        dir.display(),
                        rel.display()
                    ),
                    None => {
                        format!("no folder named {name:?} in or above the package holds it")
                    }
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
