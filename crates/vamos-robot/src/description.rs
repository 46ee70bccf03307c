//! Loading a robot: URDF text (file, string, package folder or archive) -> validated
//! [`Robot`] with its joint tree and per-link visual meshes.
//!
//! Mesh paths are resolved here, never by `urdf-rs` (its `package://` expansion needs ROS):
//! - relative paths: against the URDF's folder;
//! - `package://NAME/REST`: in the URDF's folder and each folder above it, a folder that
//!   *is* `NAME` or *holds* `NAME` (this covers pybullet's layout, where `package://meshes/`
//!   sits beside the URDF); then a folder named `NAME` anywhere in the package (three
//!   levels deep at most); then the package root itself (packages renamed on disk);
//! - `file:///abs` and absolute paths: as given (folders only; refused inside archives).
//!
//! A mesh that cannot be found, read or parsed, or is over a cap, is left out with a
//! warning naming it ([`Robot::warnings`]); the robot still loads. So do URDF constructs
//! urdfdom (the ROS parser) accepts and `urdf-rs` refuses: a `<texture>` without a
//! filename, a repeated `<axis>` (or other once-only element), a mesh `scale` of four
//! values, `<plane>` (or other unsupported) geometry are dropped or fixed before parsing,
//! each with a warning naming the element.

use super::camera::{CameraConvention, CameraSpec};
use super::config::RobotConfig;
use super::error::RobotError;
use super::geometry::{LinkMesh, TriMesh};
use super::joints::JointMapper;
use super::kinematics::{
    CameraMount, Joint, JointKind, JointLimits, JointPositions, Kinematics, LimitViolation, Mimic,
    isometry_from_xyz_rpy,
};
use super::mesh;
use super::prepass;
use nalgebra::{Isometry3, Unit, Vector3};
use rayon::prelude::*;
use serde::Serialize;
use std::collections::{HashMap, HashSet};
use std::io::Read;
use std::path::{Component, Path, PathBuf};

/// What a visual element of a link is.
#[derive(Debug, Clone, PartialEq, Serialize)]
#[serde(tag = "type", rename_all = "snake_case")]
pub enum VisualGeometry {
    /// A mesh file.
    Mesh {
        /// The filename as written in the URDF.
        uri: String,
        /// Where it was found (`archive!/entry` inside archives); `None` when not found.
        resolved: Option<String>,
        /// Per-axis scale.
        scale: [f64; 3],
    },
    /// A box centred on the visual origin.
    Box {
        /// Side lengths, metres.
        size_m: [f64; 3],
    },
    /// A cylinder along the visual origin's z.
    Cylinder {
        /// Radius, metres.
        radius_m: f64,
        /// Length, metres.
        length_m: f64,
    },
    /// A capsule along z.
    Capsule {
        /// Radius, metres.
        radius_m: f64,
        /// Length of the cylindrical part, metres.
        length_m: f64,
    },
    /// A sphere.
    Sphere {
        /// Radius, metres.
        radius_m: f64,
    },
}

/// One `<visual>` of a link and what came of it.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct VisualInfo {
    /// The geometry.
    #[serde(flatten)]
    pub geometry: VisualGeometry,
    /// Triangles it contributes to the link mesh (0 when left out).
    pub triangles: usize,
}

/// A loaded robot: names, joint tree, forward kinematics, visual meshes, load warnings.
///
/// Link indices (`links()`, [`LinkMesh::link`], the poses of [`Robot::forward`]) and joint
/// indices (`joints()`, [`JointPositions`]) follow the URDF's order.
#[derive(Debug, Clone)]
pub struct Robot {
    name: String,
    kinematics: Kinematics,
    visuals: Vec<Vec<VisualInfo>>,
    link_meshes: Vec<LinkMesh>,
    warnings: Vec<String>,
    outside_meshes: Vec<String>,
}

impl Robot {
    /// Loads `path`: a folder (robot package), a `.zip`, `.tar.gz` or `.tgz` archive, or
    /// a URDF file.
    pub fn load(path: &Path, cfg: &RobotConfig) -> Result<Self, RobotError> {
        if path.is_dir() {
            return Self::from_package_dir(path, cfg);
        }
        let lower = path.to_string_lossy().to_ascii_lowercase();
        if [".zip", ".tar.gz", ".tgz"]
            .iter()
            .any(|ext| lower.ends_with(ext))
        {
            return Self::from_archive_file(path, cfg);
        }
        Self::from_urdf_file(path, cfg)
    }

    /// A robot as the service stores it (see [`Robot::meshes_outside_package`]): an
    /// archive is read as [`Robot::from_archive_file`] does; a single URDF file is
    /// sealed, no mesh file is looked up on the file system (it has no package, so only
    /// its primitive shapes load, and every mesh is left out with a warning).
    pub fn load_stored(path: &Path, cfg: &RobotConfig) -> Result<Self, RobotError> {
        let lower = path.to_string_lossy().to_ascii_lowercase();
        if [".zip", ".tar.gz", ".tgz"]
            .iter()
            .any(|ext| lower.ends_with(ext))
        {
            return Self::from_archive_file(path, cfg);
        }
        let xml = std::fs::read_to_string(path).map_err(|e| RobotError::io(path, &e))?;
        let label = path.display().to_string();
        let store = Store::Memory {
            label: label.clone(),
            files: HashMap::new(),
        };
        Self::from_parts(&xml, &label, &store, Path::new(""), Path::new(""), cfg)
    }

    /// A URDF file; meshes resolved against its folder.
    pub fn from_urdf_file(path: &Path, cfg: &RobotConfig) -> Result<Self, RobotError> {
        let xml = std::fs::read_to_string(path).map_err(|e| RobotError::io(path, &e))?;
        let dir = urdf_folder(path)?;
        Self::from_parts(
            &xml,
            &path.display().to_string(),
            &Store::Dir,
            &dir,
            &dir,
            cfg,
        )
    }

    /// URDF text (e.g. ROS `/robot_description`); relative and `package://` mesh paths are
    /// resolved against `mesh_root` (as if the URDF were a file in it). Without a root,
    /// only absolute and `file://` meshes load (the others are reported as warnings).
    pub fn from_urdf_str(
        xml: &str,
        mesh_root: Option<&Path>,
        cfg: &RobotConfig,
    ) -> Result<Self, RobotError> {
        let root = match mesh_root {
            Some(r) => std::fs::canonicalize(r).map_err(|e| RobotError::io(r, &e))?,
            None => PathBuf::new(),
        };
        let store = if mesh_root.is_some() {
            Store::Dir
        } else {
            Store::Nothing
        };
        Self::from_parts(xml, "<string>", &store, &root, &root, cfg)
    }

    /// A robot package folder: the one `.urdf` file nearest its top (at most four levels
    /// down) is loaded, meshes resolved within and above the folder.
    pub fn from_package_dir(dir: &Path, cfg: &RobotConfig) -> Result<Self, RobotError> {
        let root = std::fs::canonicalize(dir).map_err(|e| RobotError::io(dir, &e))?;
        let mut urdfs = Vec::new();
        walk_dir(&root, 0, 4, &mut |p: &Path, is_dir| {
            if !is_dir && has_urdf_extension(p) {
                urdfs.push(p.to_path_buf());
            }
        });
        let urdf = pick_urdf(&root, &urdfs, &dir.display().to_string())?;
        let xml = std::fs::read_to_string(&urdf).map_err(|e| RobotError::io(&urdf, &e))?;
        let urdf_dir = urdf.parent().map(Path::to_path_buf).unwrap_or(root.clone());
        Self::from_parts(
            &xml,
            &urdf.display().to_string(),
            &Store::Dir,
            &urdf_dir,
            &root,
            cfg,
        )
    }

    /// A `.zip` or `.tar.gz` robot package file (see [`Robot::from_archive_bytes`]).
    pub fn from_archive_file(path: &Path, cfg: &RobotConfig) -> Result<Self, RobotError> {
        let bytes = std::fs::read(path).map_err(|e| RobotError::io(path, &e))?;
        Self::from_archive_bytes(&bytes, &path.display().to_string(), cfg)
    }

    /// A robot package archive in memory (zip or gzip-compressed tar, told apart by their
    /// magic bytes), unpacked into memory: entries with absolute paths or `..` are
    /// errors, links are skipped, sizes are capped (`max_archive_bytes`,
    /// `max_archive_entries`). `label` names the archive in messages. When every entry
    /// sits in one top folder, that folder is the package root.
    pub fn from_archive_bytes(
        bytes: &[u8],
        label: &str,
        cfg: &RobotConfig,
    ) -> Result<Self, RobotError> {
        let files = unpack_archive(bytes, label, cfg)?;
        // The first component of every entry that sits in a folder.
        let tops: HashSet<PathBuf> = files
            .keys()
            .filter(|p| p.components().count() > 1)
            .filter_map(|p| p.components().next())
            .map(|c| PathBuf::from(c.as_os_str()))
            .collect();
        let single_top = files.keys().all(|p| p.components().count() > 1) && tops.len() == 1;
        let root = match (single_top, tops.into_iter().next()) {
            (true, Some(top)) => top,
            _ => PathBuf::new(),
        };
        let urdfs: Vec<PathBuf> = files
            .keys()
            .filter(|p| has_urdf_extension(p))
            .cloned()
            .collect();
        let urdf = pick_urdf(&root, &urdfs, label)?;
        let xml =
            String::from_utf8_lossy(files.get(&urdf).map_or(&[][..], Vec::as_slice)).into_owned();
        let urdf_dir = urdf.parent().map(Path::to_path_buf).unwrap_or_default();
        let store = Store::Memory {
            label: label.to_string(),
            files,
        };
        Self::from_parts(
            &xml,
            &format!("{label}!/{}", urdf.display()),
            &store,
            &urdf_dir,
            &root,
            cfg,
        )
    }

    fn from_parts(
        xml: &str,
        source_name: &str,
        store: &Store,
        urdf_dir: &Path,
        package_root: &Path,
        cfg: &RobotConfig,
    ) -> Result<Self, RobotError> {
        // Constructs urdfdom tolerates and urdf-rs refuses: dropped or fixed, with warnings.
        let (xml, mut warnings) = prepass::tolerate(xml);
        let urdf = urdf_rs::read_from_string(&xml).map_err(|e| RobotError::MalformedUrdf {
            source_name: source_name.to_string(),
            message: e.to_string(),
        })?;
        let kinematics = kinematics_from_urdf(&urdf, &mut warnings)?;
        let resolver = Resolver {
            store,
            urdf_dir,
            package_root,
        };
        let (visuals, link_meshes, mesh_warnings) = load_visuals(&urdf, &resolver, cfg)?;
        warnings.extend(mesh_warnings);
        for w in &warnings {
            tracing::warn!(robot = %urdf.name, "{w}");
        }
        let mut outside_meshes: Vec<String> = urdf
            .links
            .iter()
            .flat_map(|l| &l.visual)
            .filter_map(|v| match &v.geometry {
                urdf_rs::Geometry::Mesh { filename, .. } if resolver.leaves_package(filename) => {
                    Some(filename.clone())
                }
                _ => None,
            })
            .collect();
        outside_meshes.sort();
        outside_meshes.dedup();
        Ok(Self {
            name: urdf.name,
            kinematics,
            visuals,
            link_meshes,
            warnings,
            outside_meshes,
        })
    }

    /// The URDF robot name.
    pub fn name(&self) -> &str {
        &self.name
    }

    /// Link names; index = link index ([`LinkMesh::link`], pose index).
    pub fn links(&self) -> &[String] {
        self.kinematics.links()
    }

    /// Joints in URDF order (the order of [`JointPositions`]).
    pub fn joints(&self) -> &[Joint] {
        self.kinematics.joints()
    }

    /// Index of the root link: the base frame of every pose.
    pub fn root(&self) -> usize {
        self.kinematics.root()
    }

    /// The joint tree and forward kinematics.
    pub fn kinematics(&self) -> &Kinematics {
        &self.kinematics
    }

    /// The visuals of link `link` (empty for an unknown index).
    pub fn visuals(&self, link: usize) -> &[VisualInfo] {
        self.visuals.get(link).map_or(&[], Vec::as_slice)
    }

    /// One merged mesh per link that has visual geometry, in the link's frame.
    pub fn link_meshes(&self) -> &[LinkMesh] {
        &self.link_meshes
    }

    /// Total visual triangles.
    pub fn triangle_count(&self) -> usize {
        self.link_meshes
            .iter()
            .map(|m| m.mesh.triangle_count())
            .sum()
    }

    /// What was left out or fixed while loading (missing or unreadable meshes, limits,
    /// tolerated URDF constructs), by name.
    pub fn warnings(&self) -> &[String] {
        &self.warnings
    }

    /// Mesh paths of a package read from an archive or of a stored robot
    /// ([`Robot::load_stored`]) that point outside it: absolute, `file://`, or leaving
    /// it with `..`. They are never read (the service refuses such robots at upload);
    /// empty for robots read from folders, where absolute paths are allowed.
    pub fn meshes_outside_package(&self) -> &[String] {
        &self.outside_meshes
    }

    /// All joints at zero.
    pub fn zero_positions(&self) -> JointPositions {
        self.kinematics.zero_positions()
    }

    /// Checked joint positions in joint order (see [`Kinematics::positions`]).
    pub fn positions(&self, values: Vec<f64>) -> Result<JointPositions, RobotError> {
        self.kinematics.positions(values)
    }

    /// A name -> joint-vector mapper for this robot (build once per session).
    pub fn joint_mapper(&self) -> JointMapper {
        JointMapper::new(&self.kinematics)
    }

    /// `base_from_link` of every link (base = root link).
    pub fn forward(&self, q: &JointPositions) -> Result<Vec<Isometry3<f64>>, RobotError> {
        self.kinematics.forward(q)
    }

    /// As [`Robot::forward`] into a reusable buffer.
    pub fn forward_into(
        &self,
        q: &JointPositions,
        out: &mut Vec<Isometry3<f64>>,
    ) -> Result<(), RobotError> {
        self.kinematics.forward_into(q, out)
    }

    /// Joints outside their limits at `q` (limits are never enforced; mimic joints, which
    /// follow their leaders, are not listed).
    pub fn out_of_limits(&self, q: &JointPositions) -> Vec<LimitViolation> {
        self.kinematics.out_of_limits(q)
    }

    /// Resolves a camera link once (for per-frame [`CameraMount::camera_from_base`]).
    pub fn camera(
        &self,
        frame: &str,
        convention: CameraConvention,
    ) -> Result<CameraMount, RobotError> {
        self.kinematics.camera(frame, convention)
    }

    /// The mount of the camera a [`CameraSpec`] describes: its frame and convention, with
    /// the spec's optional offset applied on top.
    pub fn camera_for(&self, spec: &CameraSpec) -> Result<CameraMount, RobotError> {
        let mut mount = self.camera(&spec.frame, spec.convention)?;
        mount.link_from_optical = spec.frame_from_camera() * mount.link_from_optical;
        Ok(mount)
    }

    /// `camera_from_base` (optical frame) of the camera link `frame` at `q`.
    pub fn camera_from_base(
        &self,
        q: &JointPositions,
        frame: &str,
        convention: CameraConvention,
    ) -> Result<Isometry3<f64>, RobotError> {
        let mount = self.camera(frame, convention)?;
        let poses = self.forward(q)?;
        mount
            .camera_from_base(&poses)
            .ok_or_else(|| RobotError::UnknownCameraLink {
                name: frame.to_string(),
            })
    }
}

fn urdf_folder(path: &Path) -> Result<PathBuf, RobotError> {
    let abs = std::fs::canonicalize(path).map_err(|e| RobotError::io(path, &e))?;
    Ok(abs.parent().map(Path::to_path_buf).unwrap_or_default())
}

fn has_urdf_extension(p: &Path) -> bool {
    p.extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("urdf"))
}

/// The shallowest `.urdf` below `root`; several at that depth is an error.
fn pick_urdf(root: &Path, urdfs: &[PathBuf], label: &str) -> Result<PathBuf, RobotError> {
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
fn walk_dir(dir: &Path, depth: usize, max_depth: usize, visit: &mut dyn FnMut(&Path, bool)) {
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
fn normalize_relative(p: &Path) -> Option<PathBuf> {
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

fn unpack_archive(
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
enum Store {
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
    fn is_file(&self, p: &Path) -> bool {
        match self {
            Self::Dir => p.is_file(),
            Self::Memory { files, .. } => files.contains_key(p),
            Self::Nothing => p.is_absolute() && p.is_file(),
        }
    }

    fn display(&self, p: &Path) -> String {
        match self {
            Self::Memory { label, .. } => format!("{label}!/{}", p.display()),
            _ => p.display().to_string(),
        }
    }

    /// Reads a file, refusing files over `cap` bytes before reading them.
    fn read(&self, p: &Path, cap: u64) -> Result<Vec<u8>, RobotError> {
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
    fn folders_named(&self, root: &Path, name: &str, max_depth: usize) -> Vec<PathBuf> {
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
struct Resolver<'a> {
    store: &'a Store,
    urdf_dir: &'a Path,
    package_root: &'a Path,
}

impl Resolver<'_> {
    /// Whether `uri` points outside a sealed (in-memory) package: absolute, or leaving
    /// it with `..`. Never for the file system, where absolute paths are allowed.
    fn leaves_package(&self, uri: &str) -> bool {
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
    fn resolve(&self, uri: &str) -> Result<PathBuf, String> {
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

fn kind_of(t: &urdf_rs::JointType) -> JointKind {
    match t {
        urdf_rs::JointType::Revolute => JointKind::Revolute,
        urdf_rs::JointType::Continuous => JointKind::Continuous,
        urdf_rs::JointType::Prismatic => JointKind::Prismatic,
        urdf_rs::JointType::Fixed => JointKind::Fixed,
        urdf_rs::JointType::Floating => JointKind::Floating,
        urdf_rs::JointType::Planar => JointKind::Planar,
        urdf_rs::JointType::Spherical => JointKind::Spherical,
    }
}

/// The joint tree of `urdf`. A mimic of a joint that does not exist (or does not move) is
/// ignored with a warning, as urdfdom does: the joint then moves on its own.
fn kinematics_from_urdf(
    urdf: &urdf_rs::Robot,
    warnings: &mut Vec<String>,
) -> Result<Kinematics, RobotError> {
    let mut link_index = HashMap::new();
    for (i, l) in urdf.links.iter().enumerate() {
        if link_index.insert(l.name.as_str(), i).is_some() {
            return Err(RobotError::DuplicateLink {
                name: l.name.clone(),
            });
        }
    }
    let mut joint_index = HashMap::new();
    for (i, j) in urdf.joints.iter().enumerate() {
        if joint_index.insert(j.name.as_str(), i).is_some() {
            return Err(RobotError::DuplicateJoint {
                name: j.name.clone(),
            });
        }
    }
    let mut joints = Vec::with_capacity(urdf.joints.len());
    for j in &urdf.joints {
        let find = |link: &str| {
            link_index
                .get(link)
                .copied()
                .ok_or_else(|| RobotError::MissingLink {
                    joint: j.name.clone(),
                    link: link.to_string(),
                })
        };
        let (parent, child) = (find(&j.parent.link)?, find(&j.child.link)?);
        let kind = kind_of(&j.joint_type);
        let invalid = |what| RobotError::InvalidJoint {
            joint: j.name.clone(),
            what,
        };
        let (xyz, rpy) = (j.origin.xyz.0, j.origin.rpy.0);
        if !xyz.iter().chain(&rpy).all(|v| v.is_finite()) {
            return Err(invalid("origin"));
        }
        let axis = Vector3::from(j.axis.xyz.0);
        let axis = match Unit::try_new(axis, 1e-12) {
            Some(a) if axis.iter().all(|v| v.is_finite()) => a,
            _ if kind.is_moving() => return Err(invalid("axis")),
            _ => Vector3::x_axis(),
        };
        let lim = &j.limit;
        let limits = (matches!(kind, JointKind::Revolute | JointKind::Prismatic)
            && lim.lower <= lim.upper
            && !(lim.lower == 0.0 && lim.upper == 0.0))
            .then_some(JointLimits {
                lower: lim.lower,
                upper: lim.upper,
            });
        joints.push(Joint {
            name: j.name.clone(),
            kind,
            parent,
            child,
            parent_from_joint: isometry_from_xyz_rpy(xyz, rpy),
            axis,
            limits,
            mimic: None,
        });
    }
    // Mimic relations, chains composed down to a joint that is not itself a mimic.
    'joints: for (i, j) in urdf.joints.iter().enumerate() {
        let Some(m) = &j.mimic else { continue };
        if !joints[i].kind.is_moving() {
            continue;
        }
        let (mut multiplier, mut offset) = (m.multiplier.unwrap_or(1.0), m.offset.unwrap_or(0.0));
        if !multiplier.is_finite() || !offset.is_finite() {
            return Err(RobotError::InvalidJoint {
                joint: j.name.clone(),
                what: "mimic",
            });
        }
        let mut target_name = &m.joint;
        let mut hops = 0;
        let target = loop {
            let Some(t) = joint_index
                .get(target_name.as_str())
                .copied()
                .filter(|&t| joints[t].kind.is_moving())
            else {
                warnings.push(format!(
                    "joint {:?} mimics {target_name:?}, which is not a moving joint of the \
                     robot: the mimic is ignored (the joint is set on its own)",
                    j.name
                ));
                continue 'joints;
            };
            match &urdf.joints[t].mimic {
                None => break t,
                Some(next) => {
                    hops += 1;
                    if t == i || hops > urdf.joints.len() {
                        return Err(RobotError::MimicCycle {
                            joint: j.name.clone(),
                        });
                    }
                    // q_t = m' q_next + o'  =>  q_i = m m' q_next + (m o' + o)
                    let (m2, o2) = (next.multiplier.unwrap_or(1.0), next.offset.unwrap_or(0.0));
                    offset += multiplier * o2;
                    multiplier *= m2;
                    target_name = &next.joint;
                }
            }
        };
        joints[i].mimic = Some(Mimic {
            joint: target,
            multiplier,
            offset,
        });
    }
    let links = urdf.links.iter().map(|l| l.name.clone()).collect();
    Kinematics::new(links, joints)
}

type Visuals = (Vec<Vec<VisualInfo>>, Vec<LinkMesh>, Vec<String>);

fn load_visuals(
    urdf: &urdf_rs::Robot,
    resolver: &Resolver<'_>,
    cfg: &RobotConfig,
) -> Result<Visuals, RobotError> {
    let mut warnings = Vec::new();
    let mut infos: Vec<Vec<VisualInfo>> = Vec::with_capacity(urdf.links.len());
    // Resolve every mesh first, then parse each distinct file once, in parallel.
    let mut resolved: HashMap<String, Option<PathBuf>> = HashMap::new();
    for link in &urdf.links {
        for v in &link.visual {
            if let urdf_rs::Geometry::Mesh { filename, .. } = &v.geometry {
                if resolved.contains_key(filename) {
                    continue;
                }
                let r = match resolver.resolve(filename) {
                    Ok(p) => Some(p),
                    Err(why) => {
                        warnings.push(format!(
                            "mesh {filename:?} of link {:?} left out: not found ({why})",
                            link.name
                        ));
                        None
                    }
                };
                resolved.insert(filename.clone(), r);
            }
        }
    }
    let mut paths: Vec<&PathBuf> = resolved.values().flatten().collect();
    paths.sort();
    paths.dedup();
    let parsed: HashMap<&PathBuf, Result<TriMesh, RobotError>> = paths
        .par_iter()
        .map(|&p| {
            let m = resolver
                .store
                .read(p, cfg.max_mesh_file_bytes)
                .and_then(|bytes| mesh::mesh_from_bytes(&bytes, p, [1.0; 3], cfg));
            (p, m)
        })
        .collect();
    let mut reported = HashSet::new();
    let mut link_meshes = Vec::new();
    let mut total = 0usize;
    for (li, link) in urdf.links.iter().enumerate() {
        let mut merged = TriMesh::default();
        let mut link_infos = Vec::new();
        for v in &link.visual {
            let (xyz, rpy) = (v.origin.xyz.0, v.origin.rpy.0);
            let link_from_visual = isometry_from_xyz_rpy(xyz, rpy).cast::<f32>();
            let (geometry, part) = match &v.geometry {
                urdf_rs::Geometry::Mesh { filename, scale } => {
                    let scale = scale.as_ref().map_or([1.0; 3], |s| s.0);
                    let path = resolved.get(filename).cloned().flatten();
                    let part = match path.as_ref().and_then(|p| parsed.get(p)) {
                        Some(Ok(m)) => Some(scaled(m, scale)),
                        Some(Err(e)) => {
                            if reported.insert(filename.clone()) {
                                warnings.push(format!(
                                    "mesh {filename:?} of link {:?} left out: {e}",
                                    link.name
                                ));
                            }
                            None
                        }
                        None => None,
                    };
                    let resolved = path.map(|p| resolver.store.display(&p));
                    (
                        VisualGeometry::Mesh {
                            uri: filename.clone(),
                            resolved,
                            scale,
                        },
                        part,
                    )
                }
                urdf_rs::Geometry::Box { size } => (
                    VisualGeometry::Box { size_m: size.0 },
                    Some(mesh::box_mesh(size.0)),
                ),
                urdf_rs::Geometry::Cylinder { radius, length } => (
                    VisualGeometry::Cylinder {
                        radius_m: *radius,
                        length_m: *length,
                    },
                    Some(mesh::cylinder_mesh(*radius, *length, cfg.cylinder_segments)),
                ),
                urdf_rs::Geometry::Capsule { radius, length } => (
                    VisualGeometry::Capsule {
                        radius_m: *radius,
                        length_m: *length,
                    },
                    Some(mesh::capsule_mesh(
                        *radius,
                        *length,
                        cfg.cylinder_segments,
                        cfg.sphere_rings,
                    )),
                ),
                urdf_rs::Geometry::Sphere { radius } => (
                    VisualGeometry::Sphere { radius_m: *radius },
                    Some(mesh::sphere_mesh(*radius, cfg.sphere_rings)),
                ),
            };
            let part = part.filter(|m| {
                let ok = m.is_valid();
                if !ok {
                    warnings.push(format!(
                        "a visual of link {:?} has non-finite geometry; left out",
                        link.name
                    ));
                }
                ok
            });
            let triangles = part.as_ref().map_or(0, TriMesh::triangle_count);
            if let Some(p) = &part {
                merged.append_transformed(p, &link_from_visual);
            }
            link_infos.push(VisualInfo {
                geometry,
                triangles,
            });
        }
        total += merged.triangle_count();
        if total > cfg.max_robot_triangles {
            return Err(RobotError::TooManyTriangles {
                what: "robot".into(),
                triangles: total,
                limit: cfg.max_robot_triangles,
            });
        }
        if !merged.triangles.is_empty() {
            link_meshes.push(LinkMesh {
                link: li,
                mesh: merged,
            });
        }
        infos.push(link_infos);
    }
    Ok((infos, link_meshes, warnings))
}

fn scaled(m: &TriMesh, scale: [f64; 3]) -> TriMesh {
    if scale == [1.0; 3] {
        return m.clone();
    }
    let s = scale.map(|v| v as f32);
    TriMesh {
        positions: m
            .positions
            .iter()
            .map(|p| nalgebra::Point3::new(p.x * s[0], p.y * s[1], p.z * s[2]))
            .collect(),
        triangles: m.triangles.clone(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const STL: &str = "solid t\nfacet normal 0 0 1\nouter loop\nvertex 0 0 0\nvertex 1 0 0\n\
                       vertex 0 1 0\nendloop\nendfacet\nendsolid t\n";

    fn urdf(body: &str) -> String {
        format!("<robot name=\"r\">{body}</robot>")
    }

    fn link(name: &str) -> String {
        format!("<link name=\"{name}\"/>")
    }

    fn joint(name: &str, kind: &str, parent: &str, child: &str, extra: &str) -> String {
        format!(
            "<joint name=\"{name}\" type=\"{kind}\"><parent link=\"{parent}\"/>\
             <child link=\"{child}\"/><axis xyz=\"0 0 1\"/>\
             <limit lower=\"-1\" upper=\"1\" effort=\"1\" velocity=\"1\"/>{extra}</joint>"
        )
    }

    fn load(xml: &str) -> Result<Robot, RobotError> {
        Robot::from_urdf_str(xml, None, &RobotConfig::default())
    }

    #[test]
    fn malformed_and_invalid_descriptions_are_typed_errors() {
        let e = load("<robot name=\"r\"><link name=\"a\">").unwrap_err();
        assert!(matches!(e, RobotError::MalformedUrdf { .. }), "{e}");
        let e = load(&urdf(&(link("a") + &link("a")))).unwrap_err();
        assert_eq!(e, RobotError::DuplicateLink { name: "a".into() });
        let two = link("a") + &link("b") + &link("c");
        let e = load(&urdf(
            &(two.clone()
                + &joint("j", "fixed", "a", "b", "")
                + &joint("j", "fixed", "a", "c", "")),
        ))
        .unwrap_err();
        assert_eq!(e, RobotError::DuplicateJoint { name: "j".into() });
        let e = load(&urdf(&(link("a") + &joint("j", "fixed", "a", "ghost", "")))).unwrap_err();
        assert_eq!(
            e,
            RobotError::MissingLink {
                joint: "j".into(),
                link: "ghost".into()
            }
        );
        // A mimic of a joint that does not exist is ignored with a warning (urdfdom loads
        // such robots, e.g. alex_psyonic_hands): j2 is then a joint of its own.
        let r = load(&urdf(
            &(two.clone()
                + &joint("j1", "revolute", "a", "b", "")
                + &joint("j2", "revolute", "a", "c", "<mimic joint=\"nope\"/>")),
        ))
        .unwrap();
        assert!(
            r.warnings()
                .iter()
                .any(|w| w.contains("\"j2\" mimics \"nope\"")),
            "{:?}",
            r.warnings()
        );
        assert!(r.joints()[1].mimic.is_none());
        let e = load(&urdf(
            &(two.clone()
                + &joint("j1", "revolute", "a", "b", "<mimic joint=\"j2\"/>")
                + &joint("j2", "revolute", "a", "c", "<mimic joint=\"j1\"/>")),
        ))
        .unwrap_err();
        assert!(matches!(e, RobotError::MimicCycle { .. }), "{e}");
        let e = load(&urdf(
            &(two.clone()
                + &joint("j1", "fixed", "b", "c", "")
                + &joint("j2", "fixed", "c", "b", "")),
        ))
        .unwrap_err();
        assert!(matches!(
            e,
            RobotError::TwoParents { .. } | RobotError::KinematicCycle { .. }
        ));
        let e = load(&urdf(&(two + &joint("j1", "fixed", "a", "b", "")))).unwrap_err();
        assert!(matches!(e, RobotError::MultipleRoots { .. }), "{e}");
    }

    #[test]
    fn mimic_chains_compose_and_limits_are_kept() {
        let r = load(&urdf(
            &(link("a")
                + &link("b")
                + &link("c")
                + &link("d")
                + &joint("j1", "revolute", "a", "b", "")
                + &joint(
                    "j2",
                    "revolute",
                    "a",
                    "c",
                    "<mimic joint=\"j1\" multiplier=\"2\" offset=\"0.1\"/>",
                )
                + &joint(
                    "j3",
                    "continuous",
                    "a",
                    "d",
                    "<mimic joint=\"j2\" multiplier=\"-1\" offset=\"0.5\"/>",
                )),
        ))
        .unwrap();
        let m = r.joints()[2].mimic.unwrap();
        // q3 = -(2 q1 + 0.1) + 0.5 = -2 q1 + 0.4
        assert_eq!((m.joint, m.multiplier), (0, -2.0));
        assert!((m.offset - 0.4).abs() < 1e-15);
        let q = r.positions(vec![0.25, 0.0, 0.0]).unwrap();
        let poses = r.forward(&q).unwrap();
        assert!((poses[3].rotation.scaled_axis().z - (-0.1)).abs() < 1e-12);
        assert_eq!(r.joints()[0].limits.unwrap().upper, 1.0);
        assert!(
            r.joints()[2].limits.is_none(),
            "continuous joints have no limits"
        );
    }

    fn write(dir: &Path, rel: &str, text: &str) {
        let p = dir.join(rel);
        std::fs::create_dir_all(p.parent().unwrap()).unwrap();
        std::fs::write(p, text).unwrap();
    }

    fn mesh_link(name: &str, uri: &str) -> String {
        format!(
            "<link name=\"{name}\"><visual><origin xyz=\"0 0 1\"/><geometry>\
             <mesh filename=\"{uri}\" scale=\"2 2 2\"/></geometry></visual></link>"
        )
    }

    #[test]
    fn package_uris_resolve_in_every_supported_layout() {
        let tmp = tempfile::tempdir().unwrap();
        let ws = tmp.path();
        // ws/src/my_robot/urdf/r.urdf; meshes in several places.
        write(ws, "src/my_robot/meshes/a.stl", STL); // package://my_robot (ancestor named so)
        write(ws, "src/my_robot/urdf/meshes/b.stl", STL); // package://meshes beside the URDF
        write(ws, "src/other_pkg/meshes/c.stl", STL); // sibling package above
        write(ws, "src/my_robot/urdf/rel/d.stl", STL); // relative path
        write(ws, "src/my_robot/deep/third_pkg/e.stl", STL); // a folder named so inside
        let xml = urdf(
            &(mesh_link("a", "package://my_robot/meshes/a.stl")
                + &mesh_link("b", "package://meshes/b.stl")
                + &mesh_link("c", "package://other_pkg/meshes/c.stl")
                + &mesh_link("d", "rel/d.stl")
                + &mesh_link("e", "package://third_pkg/e.stl")
                + &mesh_link(
                    "f",
                    &format!("file://{}", ws.join("src/other_pkg/meshes/c.stl").display()),
                )
                + &mesh_link("g", "package://nowhere/g.stl")
                + &joint("j1", "fixed", "a", "b", "")
                + &joint("j2", "fixed", "a", "c", "")
                + &joint("j3", "fixed", "a", "d", "")
                + &joint("j4", "fixed", "a", "e", "")
                + &joint("j5", "fixed", "a", "f", "")
                + &joint("j6", "fixed", "a", "g", "")),
        );
        write(ws, "src/my_robot/urdf/r.urdf", &xml);
        let r = Robot::from_package_dir(&ws.join("src/my_robot"), &RobotConfig::default()).unwrap();
        let resolved: Vec<Option<String>> = (0..7)
            .map(|l| match &r.visuals(l)[0].geometry {
                VisualGeometry::Mesh { resolved, .. } => resolved.clone(),
                other => panic!("{other:?}"),
            })
            .collect();
        let real = std::fs::canonicalize(ws).unwrap();
        let want = |rel: &str| Some(real.join(rel).display().to_string());
        assert_eq!(resolved[0], want("src/my_robot/meshes/a.stl"));
        assert_eq!(resolved[1], want("src/my_robot/urdf/meshes/b.stl"));
        assert_eq!(resolved[2], want("src/other_pkg/meshes/c.stl"));
        assert_eq!(resolved[3], want("src/my_robot/urdf/rel/d.stl"));
        assert_eq!(resolved[4], want("src/my_robot/deep/third_pkg/e.stl"));
        assert!(resolved[5].is_some());
        assert_eq!(resolved[6], None);
        // The missing mesh is a warning naming it; the rest loaded, scaled and placed.
        assert_eq!(r.warnings().len(), 1);
        assert!(
            r.warnings()[0].contains("package://nowhere/g.stl"),
            "{:?}",
            r.warnings()
        );
        assert_eq!(r.link_meshes().len(), 6);
        let m = &r.link_meshes()[0].mesh;
        assert!(m.positions.contains(&nalgebra::Point3::new(2.0, 0.0, 1.0)));
    }

    #[test]
    fn a_string_without_root_loads_only_absolute_meshes() {
        let tmp = tempfile::tempdir().unwrap();
        write(tmp.path(), "a.stl", STL);
        let abs = tmp.path().join("a.stl").display().to_string();
        let xml = urdf(
            &(mesh_link("a", &format!("file://{abs}"))
                + &mesh_link("b", "a.stl")
                + &joint("j", "fixed", "a", "b", "")),
        );
        let r = load(&xml).unwrap();
        assert_eq!(r.visuals(0)[0].triangles, 1);
        assert_eq!(r.visuals(1)[0].triangles, 0);
        assert_eq!(r.warnings().len(), 1);
        assert!(r.warnings()[0].contains("\"a.stl\""), "{:?}", r.warnings());
    }

    #[test]
    fn the_package_root_stands_for_a_renamed_package() {
        let tmp = tempfile::tempdir().unwrap();
        write(tmp.path(), "meshes/a.stl", STL);
        let xml = urdf(&mesh_link("a", "package://robot_description/meshes/a.stl"));
        write(tmp.path(), "robot.urdf", &xml);
        let r = Robot::load(tmp.path(), &RobotConfig::default()).unwrap();
        assert!(r.warnings().is_empty(), "{:?}", r.warnings());
        assert_eq!(r.triangle_count(), 1);
    }

    #[test]
    fn oversized_meshes_are_left_out_with_a_warning_and_robot_caps_are_errors() {
        let tmp = tempfile::tempdir().unwrap();
        write(tmp.path(), "a.stl", STL);
        let xml = urdf(&mesh_link("a", "a.stl"));
        write(tmp.path(), "r.urdf", &xml);
        let cfg = RobotConfig {
            max_mesh_file_bytes: 20,
            ..RobotConfig::default()
        };
        let r = Robot::load(&tmp.path().join("r.urdf"), &cfg).unwrap();
        assert_eq!(r.triangle_count(), 0);
        assert!(r.warnings()[0].contains("cap"), "{:?}", r.warnings());
        let cfg = RobotConfig {
            max_robot_triangles: 10,
            ..RobotConfig::default()
        };
        let xml = urdf(
            "<link name=\"a\"><visual><geometry><box size=\"1 1 1\"/></geometry></visual></link>",
        );
        let e = Robot::from_urdf_str(&xml, None, &cfg).unwrap_err();
        assert!(
            matches!(e, RobotError::TooManyTriangles { triangles: 12, .. }),
            "{e}"
        );
    }

    #[test]
    fn primitives_are_tessellated_in_the_visual_frame() {
        let xml = urdf(
            "<link name=\"a\"><visual><origin xyz=\"1 0 0\" rpy=\"0 1.5707963267948966 0\"/>\
             <geometry><cylinder radius=\"0.1\" length=\"0.4\"/></geometry></visual>\
             <visual><geometry><sphere radius=\"0.05\"/></geometry></visual></link>",
        );
        let r = load(&xml).unwrap();
        assert_eq!(r.visuals(0)[0].triangles, 4 * 32);
        assert_eq!(r.visuals(0)[1].triangles, 2 * 24 * 11);
        let m = &r.link_meshes()[0].mesh;
        // The cylinder's axis (z) was turned onto x: it spans x in 1 +- 0.2.
        let max_x = m.positions.iter().map(|p| p.x).fold(f32::MIN, f32::max);
        let min_x = m.positions.iter().map(|p| p.x).fold(f32::MAX, f32::min);
        assert!(
            (max_x - 1.2).abs() < 1e-5 && (min_x + 0.05).abs() < 1e-5,
            "{min_x} {max_x}"
        );
    }

    /// Loads `xml`, asserting it loads, and returns it with its warnings.
    fn load_with_warnings(xml: &str) -> (Robot, Vec<String>) {
        let r = load(xml).unwrap_or_else(|e| panic!("{e}\n{xml}"));
        let w = r.warnings().to_vec();
        (r, w)
    }

    #[test]
    fn a_texture_without_filename_is_dropped_with_a_warning() {
        // iCub, romeo: `<texture/>` in a material (urdf-rs: "missing field `filename`").
        let xml = urdf(
            &("<material name=\"skin\"><color rgba=\"1 1 1 1\"/><texture/></material>\
             <link name=\"a\"><visual><geometry><box size=\"1 1 1\"/></geometry>\
             <material name=\"paint\"><texture/></material></visual></link>\
             <link name=\"b\"><visual><geometry><box size=\"1 1 1\"/></geometry>\
             <material name=\"img\"><texture filename=\"t.png\"/></material></visual></link>"
                .to_string()
                + &joint("j", "fixed", "a", "b", "")),
        );
        let (r, w) = load_with_warnings(&xml);
        assert_eq!(r.triangle_count(), 24);
        assert_eq!(w.len(), 2, "{w:?}");
        assert!(w[0].contains("material \"skin\"") && w[0].contains("texture"));
        assert!(w[1].contains("material \"paint\" of link \"a\""), "{w:?}");
    }

    #[test]
    fn a_duplicate_axis_keeps_the_first_with_a_warning() {
        let xml = urdf(
            &(link("a")
                + &link("b")
                + "<joint name=\"j\" type=\"revolute\"><parent link=\"a\"/><child link=\"b\"/>\
                   <axis xyz=\"0 1 0\"/><axis xyz=\"1 0 0\"/>\
                   <limit lower=\"-1\" upper=\"1\" effort=\"1\" velocity=\"1\"/>\
                   <limit lower=\"-2\" upper=\"2\" effort=\"1\" velocity=\"1\"/></joint>"),
        );
        let (r, w) = load_with_warnings(&xml);
        assert_eq!(r.joints()[0].axis.into_inner(), Vector3::y());
        assert_eq!(r.joints()[0].limits.unwrap().upper, 1.0);
        assert_eq!(w.len(), 2, "{w:?}");
        assert!(w[0].contains("joint \"j\" has 2 <axis> elements"), "{w:?}");
        assert!(w[1].contains("<limit>"), "{w:?}");
    }

    #[test]
    fn a_four_value_mesh_scale_uses_the_first_three_with_a_warning() {
        let tmp = tempfile::tempdir().unwrap();
        write(tmp.path(), "a.stl", STL);
        let xml = urdf(
            "<link name=\"a\"><visual><geometry><mesh filename=\"a.stl\" scale=\" 2 3 4 1 \"/>\
             </geometry></visual><collision><geometry>\
             <mesh filename=\"a.stl\" scale=\"1 1 1 1\"/></geometry></collision></link>",
        );
        let r = Robot::from_urdf_str(&xml, Some(tmp.path()), &RobotConfig::default()).unwrap();
        let w = r.warnings();
        assert_eq!(w.len(), 2, "{w:?}");
        assert!(
            w[0].contains("mesh \"a.stl\" in a visual of link \"a\"") && w[0].contains("first 3"),
            "{w:?}"
        );
        assert!(w[1].contains("in a collision of link \"a\""), "{w:?}");
        match &r.visuals(0)[0].geometry {
            VisualGeometry::Mesh { scale, .. } => assert_eq!(*scale, [2.0, 3.0, 4.0]),
            other => panic!("{other:?}"),
        }
        assert!(
            r.link_meshes()[0]
                .mesh
                .positions
                .contains(&nalgebra::Point3::new(0.0, 3.0, 0.0))
        );
        // Fewer than three values, or words, stay errors.
        let e = load(&urdf(
            "<link name=\"a\"><visual><geometry><mesh filename=\"a.stl\" scale=\"1 1\"/>\
             </geometry></visual></link>",
        ))
        .unwrap_err();
        assert!(matches!(e, RobotError::MalformedUrdf { .. }), "{e}");
    }

    #[test]
    fn plane_geometry_drops_that_visual_with_a_warning() {
        let xml = urdf(
            "<link name=\"floor\"><visual name=\"ground\"><geometry><plane normal=\"0 0 1\"/>\
             </geometry></visual><visual><geometry><box size=\"1 1 1\"/></geometry></visual>\
             <collision><geometry><plane normal=\"0 0 1\"/></geometry></collision></link>",
        );
        let (r, w) = load_with_warnings(&xml);
        assert_eq!(r.visuals(0).len(), 1);
        assert_eq!(r.triangle_count(), 12);
        assert_eq!(w.len(), 2, "{w:?}");
        assert!(
            w[0].contains("a visual \"ground\" of link \"floor\"") && w[0].contains("<plane>"),
            "{w:?}"
        );
        assert!(w[1].contains("a collision of link \"floor\""), "{w:?}");
    }

    #[test]
    fn a_binary_stl_with_a_solid_header_loads_through_the_urdf() {
        let tmp = tempfile::tempdir().unwrap();
        let mut stl = b"solid foot (binary, SolidWorks)".to_vec();
        stl.resize(80, 0);
        stl.extend(1u32.to_le_bytes());
        for v in [
            [0f32, 0.0, 1.0],
            [0.0, 0.0, 0.0],
            [1.0, 0.0, 0.0],
            [0.0, 1.0, 0.0],
        ] {
            stl.extend(v.iter().flat_map(|c| c.to_le_bytes()));
        }
        stl.extend([0u8; 2]);
        std::fs::write(tmp.path().join("foot.stl"), &stl).unwrap();
        let xml = urdf(&mesh_link("foot", "foot.stl"));
        let r = Robot::from_urdf_str(&xml, Some(tmp.path()), &RobotConfig::default()).unwrap();
        assert!(r.warnings().is_empty(), "{:?}", r.warnings());
        assert_eq!(r.triangle_count(), 1);
    }

    #[test]
    fn unknown_camera_link_is_an_error() {
        let r = load(&urdf(&link("a"))).unwrap();
        let e = r
            .camera_from_base(&r.zero_positions(), "cam", CameraConvention::Optical)
            .unwrap_err();
        assert_eq!(e, RobotError::UnknownCameraLink { name: "cam".into() });
    }

    #[test]
    fn archive_paths_are_normalised_or_refused() {
        assert_eq!(
            normalize_relative(Path::new("a/./b/../c")),
            Some(PathBuf::from("a/c"))
        );
        assert_eq!(normalize_relative(Path::new("../x")), None);
        assert_eq!(normalize_relative(Path::new("/etc/passwd")), None);
        let e =
            Robot::from_archive_bytes(b"plain text", "x.zip", &RobotConfig::default()).unwrap_err();
        assert!(matches!(e, RobotError::Archive { .. }), "{e}");
    }
}
