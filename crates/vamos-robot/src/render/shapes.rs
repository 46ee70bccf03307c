//! Tessellated primitives (boxes, spheres, cylinders) and a synthetic 7-joint arm built
//! from them: test and benchmark robots with known geometry.
//!
//! Every mesh is closed and wound counter-clockwise seen from outside.

use crate::camera::{Intrinsics, IntrinsicsError};
use crate::geometry::{LinkMesh, TriMesh};
use nalgebra::{Isometry3, Point3, Translation3, UnitQuaternion, Vector3};

/// Flips triangles of a mesh that is convex around `centre` so that each is
/// counter-clockwise seen from outside.
fn orient_outward(mesh: &mut TriMesh, centre: Point3<f32>) {
    for t in &mut mesh.triangles {
        let [a, b, c] = t.map(|i| mesh.positions[i as usize]);
        let n = (b - a).cross(&(c - a));
        let out = Point3::from((a.coords + b.coords + c.coords) / 3.0) - centre;
        if n.dot(&out) < 0.0 {
            t.swap(1, 2);
        }
    }
}

/// An axis-aligned box centred on the origin with the given half extents (metres):
/// 8 vertices, 12 triangles.
pub fn cuboid(half_extents_m: [f32; 3]) -> TriMesh {
    let [hx, hy, hz] = half_extents_m;
    let positions = (0..8)
        .map(|i| {
            Point3::new(
                if i & 1 == 0 { -hx } else { hx },
                if i & 2 == 0 { -hy } else { hy },
                if i & 4 == 0 { -hz } else { hz },
            )
        })
        .collect();
    // Two triangles per face; faces -x, +x, -y, +y, -z, +z (vertex bits: x=1, y=2, z=4).
    let quads: [[u32; 4]; 6] = [
        [0, 2, 6, 4],
        [1, 3, 7, 5],
        [0, 1, 5, 4],
        [2, 3, 7, 6],
        [0, 1, 3, 2],
        [4, 5, 7, 6],
    ];
    let triangles = quads
        .iter()
        .flat_map(|q| [[q[0], q[1], q[2]], [q[0], q[2], q[3]]])
        .collect();
    let mut mesh = TriMesh {
        positions,
        triangles,
    };
    orient_outward(&mut mesh, Point3::origin());
    mesh
}

/// A UV sphere centred on the origin: `rings` >= 2 latitude bands, `segments` >= 3
/// longitudes; `2 * segments * (rings - 1)` triangles.
pub fn uv_sphere(radius_m: f32, rings: u32, segments: u32) -> TriMesh {
    let rings = rings.max(2);
    let segments = segments.max(3);
    let mut positions = vec![Point3::new(0.0, 0.0, radius_m)];
    for r in 1..rings {
        let theta = std::f32::consts::PI * r as f32 / rings as f32;
        for s in 0..segments {
            let phi = std::f32::consts::TAU * s as f32 / segments as f32;
            positions.push(Point3::new(
                radius_m * theta.sin() * phi.cos(),
                radius_m * theta.sin() * phi.sin(),
                radius_m * theta.cos(),
            ));
        }
    }
    positions.push(Point3::new(0.0, 0.0, -radius_m));
    let south = positions.len() as u32 - 1;
    let ring = |r: u32, s: u32| 1 + (r - 1) * segments + s % segments;
    let mut triangles = Vec::new();
    for s in 0..segments {
        triangles.push([0, ring(1, s), ring(1, s + 1)]);
        triangles.push([south, ring(rings - 1, s), ring(rings - 1, s + 1)]);
    }
    for r in 1..rings - 1 {
        for s in 0..segments {
            let (a, b, c, d) = (
                ring(r, s),
                ring(r, s + 1),
                ring(r + 1, s),
                ring(r + 1, s + 1),
            );
            triangles.push([a, c, d]);
            triangles.push([a, d, b]);
        }
    }
    let mut mesh = TriMesh {
        positions,
        triangles,
    };
    orient_outward(&mut mesh, Point3::origin());
    mesh
}

/// A capped cylinder along z from `z = 0` to `z = length_m`: `segments` >= 3 around,
/// `stacks` >= 1 bands along; `2 * segments * (stacks + 1)` triangles.
pub fn cylinder(radius_m: f32, length_m: f32, segments: u32, stacks: u32) -> TriMesh {
    let segments = segments.max(3);
    let stacks = stacks.max(1);
    let mut positions = Vec::new();
    for k in 0..=stacks {
        let z = length_m * k as f32 / stacks as f32;
        for s in 0..segments {
            let phi = std::f32::consts::TAU * s as f32 / segments as f32;
            positions.push(Point3::new(radius_m * phi.cos(), radius_m * phi.sin(), z));
        }
    }
    let bottom = positions.len() as u32;
    positions.push(Point3::new(0.0, 0.0, 0.0));
    let top = bottom + 1;
    positions.push(Point3::new(0.0, 0.0, length_m));
    let at = |k: u32, s: u32| k * segments + s % segments;
    let mut triangles = Vec::new();
    for k in 0..stacks {
        for s in 0..segments {
            let (a, b, c, d) = (at(k, s), at(k, s + 1), at(k + 1, s), at(k + 1, s + 1));
            triangles.push([a, b, d]);
            triangles.push([a, d, c]);
        }
    }
    for s in 0..segments {
        triangles.push([bottom, at(0, s), at(0, s + 1)]);
        triangles.push([top, at(stacks, s), at(stacks, s + 1)]);
    }
    let mut mesh = TriMesh {
        positions,
        triangles,
    };
    orient_outward(&mut mesh, Point3::new(0.0, 0.0, length_m / 2.0));
    mesh
}

/// A synthetic 7-joint arm sized like a Franka Panda (about 1.1 m reach), for tests and
/// benchmarks: link 0 is the base, links 1..=7 follow a chain of revolute joints
/// (alternately about z and y), each link a capped cylinder with a sphere at its joint.
#[derive(Debug, Clone)]
pub struct SyntheticArm {
    /// One mesh per link, in the link frame.
    pub meshes: Vec<LinkMesh>,
    /// Length of each link along its z axis, metres.
    pub lengths_m: Vec<f64>,
}

impl SyntheticArm {
    /// Number of links (base + 7).
    pub const LINKS: usize = 8;

    /// An arm tessellated to roughly `triangles` triangles in all.
    pub fn new(triangles: usize) -> Self {
        let lengths_m: Vec<f64> = vec![0.33, 0.0, 0.316, 0.0, 0.384, 0.0, 0.088, 0.107];
        let radii = [0.09f32, 0.07, 0.065, 0.06, 0.06, 0.055, 0.05, 0.045];
        // Per link: a cylinder (segments s, stacks s/2) and a sphere (rings s/2,
        // segments s): about 2 s (s/2 + 1) + s^2 - s = 2 s^2 triangles.
        let per_link = triangles as f64 / Self::LINKS as f64;
        let s = ((per_link / 2.0).sqrt().round() as u32).max(6);
        let meshes = (0..Self::LINKS)
            .map(|i| {
                let len = lengths_m[i].max(0.12) as f32;
                let mut mesh = cylinder(radii[i], len, s, s / 2);
                mesh.append_transformed(
                    &uv_sphere(radii[i] * 1.15, s / 2, s),
                    &Isometry3::identity(),
                );
                LinkMesh { link: i, mesh }
            })
            .collect();
        Self { meshes, lengths_m }
    }

    /// Triangles in all links.
    pub fn triangle_count(&self) -> usize {
        self.meshes.iter().map(|m| m.mesh.triangle_count()).sum()
    }

    /// The benchmark camera at `width` x `height`: 50 degrees horizontal field of view.
    pub fn intrinsics(width: u32, height: u32) -> Result<Intrinsics, IntrinsicsError> {
        Intrinsics::from_fov(width, height, 50.0)
    }

    /// A bent, non-singular pose used by tests and benchmarks (radians).
    pub const POSE_RAD: [f64; 7] = [0.3, -0.4, 0.2, -1.2, 0.1, 1.0, 0.0];

    /// `base_from_link` for joint angles `q` (7 values, radians; missing ones are 0).
    pub fn base_from_link(&self, q: &[f64]) -> Vec<Isometry3<f64>> {
        let mut poses = vec![Isometry3::identity()];
        let mut pose = Isometry3::identity();
        for j in 0..Self::LINKS - 1 {
            let angle = q.get(j).copied().unwrap_or(0.0);
            let axis = if j % 2 == 0 {
                Vector3::z_axis()
            } else {
                Vector3::y_axis()
            };
            let offset = Translation3::new(0.0, 0.0, self.lengths_m[j].max(0.12));
            pose *= Isometry3::from_parts(offset, UnitQuaternion::from_axis_angle(&axis, angle));
            poses.push(pose);
        }
        poses
    }

    /// A camera 1 m in front of the arm (along base +x), at 0.6 m height, looking back
    /// at it (optical frame: z towards the arm, y down).
    pub fn camera_from_base() -> Isometry3<f64> {
        let eye = Point3::new(1.0, 0.0, 0.6);
        let target = Point3::new(0.0, 0.0, 0.55);
        // Optical z towards the target, optical y down (-base z).
        let base_from_camera =
            Isometry3::face_towards(&eye, &target, &Vector3::new(0.0, 0.0, -1.0));
        base_from_camera.inverse()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn signed_volume(m: &TriMesh) -> f32 {
        m.triangles
            .iter()
            .map(|t| {
                let [a, b, c] = t.map(|i| m.positions[i as usize].coords);
                a.dot(&b.cross(&c)) / 6.0
            })
            .sum()
    }

    #[test]
    fn primitives_are_closed_outward_and_have_the_right_volume() {
        let b = cuboid([0.1, 0.2, 0.3]);
        assert!(b.is_valid());
        assert_eq!(b.triangle_count(), 12);
        assert!((signed_volume(&b) - 0.2 * 0.4 * 0.6).abs() < 1e-6);
        let s = uv_sphere(0.5, 64, 128);
        let exact = 4.0 / 3.0 * std::f32::consts::PI * 0.125;
        assert!((signed_volume(&s) - exact).abs() / exact < 0.01);
        assert_eq!(s.triangle_count(), 2 * 128 * 63);
        let c = cylinder(0.1, 0.5, 256, 3);
        let exact = std::f32::consts::PI * 0.01 * 0.5;
        assert!((signed_volume(&c) - exact).abs() / exact < 0.001);
        assert_eq!(c.triangle_count(), 2 * 256 * 4);
    }

    #[test]
    fn synthetic_arm_has_the_requested_size() {
        let arm = SyntheticArm::new(100_000);
        let n = arm.triangle_count();
        assert!((90_000..110_000).contains(&n), "{n}");
        let poses = arm.base_from_link(&[0.0; 7]);
        assert_eq!(poses.len(), SyntheticArm::LINKS);
        // Zero angles: a straight column; link 2 sits 0.33 + 0.12 m above the base.
        assert!((poses[2].translation.vector.z - 0.45).abs() < 1e-12);
        let cam = SyntheticArm::camera_from_base();
        let base_in_camera = cam * Point3::new(0.0, 0.0, 0.55);
        assert!(base_in_camera.x.abs() < 1e-9 && base_in_camera.y.abs() < 1e-9);
        assert!((base_in_camera.z - (1.0f64 + 0.05f64.powi(2)).sqrt()).abs() < 1e-9);
    }
}
