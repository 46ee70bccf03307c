//! Triangle meshes attached to robot links: what the renderer draws.

use nalgebra::{Isometry3, Point3};

/// An indexed triangle mesh in metres. Triangles are counter-clockwise seen from outside
/// where the source says so; the renderer does not cull back faces.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct TriMesh {
    /// Vertex positions.
    pub positions: Vec<Point3<f32>>,
    /// Vertex indices of each triangle (all `< positions.len()`).
    pub triangles: Vec<[u32; 3]>,
}

impl TriMesh {
    /// Number of triangles.
    pub fn triangle_count(&self) -> usize {
        self.triangles.len()
    }

    /// True when every index is in range and every position finite.
    pub fn is_valid(&self) -> bool {
        let n = self.positions.len();
        self.triangles
            .iter()
            .all(|t| t.iter().all(|&i| (i as usize) < n))
            && self
                .positions
                .iter()
                .all(|p| p.coords.iter().all(|c| c.is_finite()))
    }

    /// Appends `other`, transformed by `pose` (maps `other`'s frame into this mesh's).
    pub fn append_transformed(&mut self, other: &TriMesh, pose: &Isometry3<f32>) {
        let offset = self.positions.len() as u32;
        self.positions
            .extend(other.positions.iter().map(|p| pose * p));
        self.triangles.extend(
            other
                .triangles
                .iter()
                .map(|t| [t[0] + offset, t[1] + offset, t[2] + offset]),
        );
    }
}

/// The visual geometry of one link, in that link's frame (visual origins and mesh scales
/// already applied). `link` indexes the robot's link list (and so its `base_from_link`
/// poses).
#[derive(Debug, Clone, PartialEq)]
pub struct LinkMesh {
    /// Index of the link the mesh is attached to.
    pub link: usize,
    /// The mesh in the link's frame.
    pub mesh: TriMesh,
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Translation3, UnitQuaternion};

    #[test]
    fn append_transformed_offsets_indices_and_moves_points() {
        let tri = TriMesh {
            positions: vec![
                Point3::new(0.0, 0.0, 0.0),
                Point3::new(1.0, 0.0, 0.0),
                Point3::new(0.0, 1.0, 0.0),
            ],
            triangles: vec![[0, 1, 2]],
        };
        let mut m = tri.clone();
        let pose =
            Isometry3::from_parts(Translation3::new(0.0, 0.0, 2.0), UnitQuaternion::identity());
        m.append_transformed(&tri, &pose);
        assert_eq!(m.triangles, vec![[0, 1, 2], [3, 4, 5]]);
        assert_eq!(m.positions[4], Point3::new(1.0, 0.0, 2.0));
        assert!(m.is_valid());
        m.triangles.push([0, 1, 9]);
        assert!(!m.is_valid());
    }
}
