//! Loading a robot: URDF text (file, string, package folder or archive) -> validated
//! [`Robot`] with its joint tree and per-link visual meshes.
//!
//! Mesh paths are resolved here, never by `urdf-rs` (its `package://` expansion needs ROS):
//! - relative paths: against the URDF's folder;
//! - `package://NAME/REST`: first in the package `NAME` found in the package paths the
//!   caller gives ([`Robot::load_with_packages`], [`find_package`]: a ROS package folder,
//!   or a folder holding packages); then in the URDF's folder and each folder above it, a
//!   folder that *is* `NAME` or *holds* `NAME` (this covers pybullet's layout, where
//!   `package://meshes/` sits beside the URDF); then a folder named `NAME` anywhere in the
//!   package (three levels deep at most); then the package root itself (packages renamed
//!   on disk);
//! - `file:///abs` and absolute paths: as given (folders only; refused inside archives).
//!
//! A mesh that cannot be found, read or parsed, or is over a cap, is left out with a
//! warning naming it ([`Robot::warnings`]; the ones not found, grouped by package, in
//! [`Robot::missing_meshes`]); the robot still loads. So do URDF constructs
//! urdfdom (the ROS parser) accepts and `urdf-rs` refuses: a `<texture>` without a
//! filename, a repeated `<axis>` (or other once-only element), a mesh `scale` of four
//! values, `<plane>` (or other unsupported) geometry are dropped or fixed before parsing,
//! each with a warning naming the element.

use super::camera::{CameraConvention, CameraSpec};
use super::config::RobotConfig;
use super::error::RobotError;
use super::geometry::LinkMesh;
use super::joints::JointMapper;
use super::kinematics::{CameraMount, Joint, JointPositions, Kinematics, LimitViolation};
use super::prepass;
use nalgebra::Isometry3;
use serde::Serialize;
use std::collections::{HashMap, HashSet};
use std::path::{Path, PathBuf};

mod package;
#[cfg(test)]
mod tests;
mod urdf;

use package::*;
pub use package::{PACKAGE_SEARCH_DEPTH, find_package, package_of, package_xml_name};
use urdf::*;

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

/// A mesh file of the robot's visuals that was not found (so left out), and the links
/// whose visuals name it.
#[derive(Debug, Clone, PartialEq, Eq, Serialize)]
pub struct MissingMesh {
    /// The filename as written in the URDF.
    pub uri: String,
    /// The ROS package a `package://NAME/...` filename names.
    pub package: Option<String>,
    /// The path inside that package (for other filenames: the filename).
    pub path: String,
    /// The links that use it, in URDF order.
    pub links: Vec<String>,
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
    /// Where in `warnings` the meshes not found are (those of `missing_meshes`).
    not_found_warnings: std::ops::Range<usize>,
    outside_meshes: Vec<String>,
}

impl Robot {
    /// Loads `path`: a folder (robot package), a `.zip`, `.tar.gz` or `.tgz` archive, or
    /// a URDF file. Its warnings are logged.
    pub fn load(path: &Path, cfg: &RobotConfig) -> Result<Self, RobotError> {
        Self::load_with_packages(path, &[], cfg).map(Self::logged)
    }

    /// As [`Robot::load`], with `package://NAME/...` meshes looked for first in the
    /// package `NAME` found in `packages` ([`find_package`]: each a ROS package folder or
    /// a folder holding packages, in order). Archives are sealed: they read no package
    /// path. Its warnings are not logged: the caller reports them ([`Robot::warnings`],
    /// [`Robot::missing_meshes`]).
    pub fn load_with_packages(
        path: &Path,
        packages: &[PathBuf],
        cfg: &RobotConfig,
    ) -> Result<Self, RobotError> {
        if path.is_dir() {
            return Self::package_dir(path, packages, cfg);
        }
        let lower = path.to_string_lossy().to_ascii_lowercase();
        if [".zip", ".tar.gz", ".tgz"]
            .iter()
            .any(|ext| lower.ends_with(ext))
        {
            return Self::archive_file(path, cfg);
        }
        Self::urdf_file(path, packages, cfg)
    }

    /// Logs each warning (once, at load).
    fn logged(self) -> Self {
        for w in &self.warnings {
            tracing::warn!(robot = %self.name, "{w}");
        }
        self
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
        Self::from_parts(&xml, &label, &store, Path::new(""), Path::new(""), &[], cfg)
            .map(Self::logged)
    }

    /// A URDF file; meshes resolved against its folder.
    pub fn from_urdf_file(path: &Path, cfg: &RobotConfig) -> Result<Self, RobotError> {
        Self::urdf_file(path, &[], cfg).map(Self::logged)
    }

    fn urdf_file(path: &Path, packages: &[PathBuf], cfg: &RobotConfig) -> Result<Self, RobotError> {
        let xml = std::fs::read_to_string(path).map_err(|e| RobotError::io(path, &e))?;
        let dir = urdf_folder(path)?;
        Self::from_parts(
            &xml,
            &path.display().to_string(),
            &Store::Dir,
            &dir,
            &dir,
            packages,
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
        Self::from_parts(xml, "<string>", &store, &root, &root, &[], cfg).map(Self::logged)
    }

    /// A robot package folder: the one `.urdf` file nearest its top (at most four levels
    /// down) is loaded, meshes resolved within and above the folder.
    pub fn from_package_dir(dir: &Path, cfg: &RobotConfig) -> Result<Self, RobotError> {
        Self::package_dir(dir, &[], cfg).map(Self::logged)
    }

    fn package_dir(
        dir: &Path,
        packages: &[PathBuf],
        cfg: &RobotConfig,
    ) -> Result<Self, RobotError> {
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
            packages,
            cfg,
        )
    }

    /// A `.zip` or `.tar.gz` robot package file (see [`Robot::from_archive_bytes`]).
    pub fn from_archive_file(path: &Path, cfg: &RobotConfig) -> Result<Self, RobotError> {
        Self::archive_file(path, cfg).map(Self::logged)
    }

    fn archive_file(path: &Path, cfg: &RobotConfig) -> Result<Self, RobotError> {
        let bytes = std::fs::read(path).map_err(|e| RobotError::io(path, &e))?;
        Self::archive_bytes(&bytes, &path.display().to_string(), cfg)
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
        Self::archive_bytes(bytes, label, cfg).map(Self::logged)
    }

    fn archive_bytes(bytes: &[u8], label: &str, cfg: &RobotConfig) -> Result<Self, RobotError> {
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
            &[],
            cfg,
        )
    }

    /// The robot of `xml`, its meshes resolved in `store` (see the module docs); `packages`
    /// are the caller's package paths (read only from the file system). Nothing is logged.
    fn from_parts(
        xml: &str,
        source_name: &str,
        store: &Store,
        urdf_dir: &Path,
        package_root: &Path,
        packages: &[PathBuf],
        cfg: &RobotConfig,
    ) -> Result<Self, RobotError> {
        // Constructs urdfdom tolerates and urdf-rs refuses: dropped or fixed, with warnings.
        let (xml, mut warnings) = prepass::tolerate(xml);
        let urdf = urdf_rs::read_from_string(&xml).map_err(|e| RobotError::MalformedUrdf {
            source_name: source_name.to_string(),
            message: e.to_string(),
        })?;
        let kinematics = kinematics_from_urdf(&urdf, &mut warnings)?;
        // The package folders of the caller's package paths, each package found once.
        let mut found = HashMap::new();
        if !packages.is_empty() && !matches!(store, Store::Memory { .. }) {
            for v in urdf.links.iter().flat_map(|l| &l.visual) {
                if let urdf_rs::Geometry::Mesh { filename, .. } = &v.geometry
                    && let Some((name, _)) = package_of(filename)
                    && !found.contains_key(name)
                    && let Some(dir) = find_package(name, packages)
                {
                    found.insert(name.to_string(), dir);
                }
            }
        }
        let resolver = Resolver {
            store,
            urdf_dir,
            package_root,
            packages: &found,
        };
        let (visuals, link_meshes, not_found, mesh_warnings) = load_visuals(&urdf, &resolver, cfg)?;
        let not_found_warnings = warnings.len()..warnings.len() + not_found.len();
        warnings.extend(not_found);
        warnings.extend(mesh_warnings);
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
            not_found_warnings,
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

    /// The warnings but those of meshes not found (which [`Robot::missing_meshes`] lists):
    /// meshes unreadable or over a cap, URDF constructs dropped or fixed.
    pub fn other_warnings(&self) -> impl Iterator<Item = &str> {
        self.warnings
            .iter()
            .enumerate()
            .filter(|(i, _)| !self.not_found_warnings.contains(i))
            .map(|(_, w)| w.as_str())
    }

    /// The mesh files of the visuals that were not found (left out, each also a warning),
    /// one entry per filename in the order the URDF first names them.
    pub fn missing_meshes(&self) -> Vec<MissingMesh> {
        let mut out: Vec<MissingMesh> = Vec::new();
        for (link, visuals) in self.links().iter().zip(&self.visuals) {
            for v in visuals {
                let VisualGeometry::Mesh {
                    uri,
                    resolved: None,
                    ..
                } = &v.geometry
                else {
                    continue;
                };
                if let Some(m) = out.iter_mut().find(|m| &m.uri == uri) {
                    if m.links.last() != Some(link) {
                        m.links.push(link.clone());
                    }
                    continue;
                }
                let (package, path) = match package_of(uri) {
                    Some((name, rel)) => (Some(name.to_string()), rel.to_string()),
                    None => (None, uri.clone()),
                };
                out.push(MissingMesh {
                    uri: uri.clone(),
                    package,
                    path,
                    links: vec![link.clone()],
                });
            }
        }
        out
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
