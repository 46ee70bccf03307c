//! A parsed URDF to vamos types: the validated joint tree and the per-link visual
//! meshes (loaded in parallel, each failure a warning).

use crate::config::RobotConfig;
use crate::error::RobotError;
use crate::geometry::{LinkMesh, TriMesh};
use crate::kinematics::{Joint, JointKind, JointLimits, Kinematics, Mimic, isometry_from_xyz_rpy};
use crate::mesh;
use nalgebra::{Unit, Vector3};
use rayon::prelude::*;
use std::collections::{HashMap, HashSet};
use std::path::PathBuf;

use super::package::Resolver;
use super::{VisualGeometry, VisualInfo};

pub(super) fn kind_of(t: &urdf_rs::JointType) -> JointKind {
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
pub(super) fn kinematics_from_urdf(
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

/// Per-link visuals, the link meshes, the warnings of meshes not found, the other
/// warnings.
type Visuals = (
    Vec<Vec<VisualInfo>>,
    Vec<LinkMesh>,
    Vec<String>,
    Vec<String>,
);

pub(super) fn load_visuals(
    urdf: &urdf_rs::Robot,
    resolver: &Resolver<'_>,
    cfg: &RobotConfig,
) -> Result<Visuals, RobotError> {
    let mut not_found = Vec::new();
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
                        not_found.push(format!(
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
    Ok((infos, link_meshes, not_found, warnings))
}

pub(super) fn scaled(m: &TriMesh, scale: [f64; 3]) -> TriMesh {
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
