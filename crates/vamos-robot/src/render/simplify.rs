//! Render-time mesh simplification by vertex clustering (Rossignac and Borrel 1993):
//! vertices in the same grid cube merge into their mean, triangles that collapse are
//! dropped. Camera-independent (link frame), done once per robot at `prepare`.

use crate::geometry::TriMesh;
use nalgebra::Point3;
use std::collections::HashMap;

/// `mesh` with its vertices clustered on a grid of `cell_m` metres. Every output vertex is
/// the mean of the input vertices of one cell, so no vertex moves by more than the cell's
/// diagonal. `cell_m <= 0` (or not finite) returns the mesh unchanged. Expects valid
/// indices (as checked by `prepare`).
pub fn cluster_vertices(mesh: &TriMesh, cell_m: f32) -> TriMesh {
    if !(cell_m.is_finite() && cell_m > 0.0) {
        return mesh.clone();
    }
    let mut cell_of: HashMap<[i64; 3], u32> = HashMap::new();
    let mut sums: Vec<([f64; 3], u32)> = Vec::new();
    let remap: Vec<u32> = mesh
        .positions
        .iter()
        .map(|p| {
            let key = [p.x, p.y, p.z].map(|c| (f64::from(c) / f64::from(cell_m)).floor() as i64);
            let id = *cell_of.entry(key).or_insert_with(|| {
                sums.push(([0.0; 3], 0));
                (sums.len() - 1) as u32
            });
            let s = &mut sums[id as usize];
            s.0[0] += f64::from(p.x);
            s.0[1] += f64::from(p.y);
            s.0[2] += f64::from(p.z);
            s.1 += 1;
            id
        })
        .collect();
    let positions = sums
        .iter()
        .map(|(s, n)| {
            let n = f64::from(*n);
            Point3::new((s[0] / n) as f32, (s[1] / n) as f32, (s[2] / n) as f32)
        })
        .collect();
    let triangles = mesh
        .triangles
        .iter()
        .filter_map(|t| {
            let [a, b, c] = t.map(|i| remap.get(i as usize).copied().unwrap_or(0));
            (a != b && b != c && a != c).then_some([a, b, c])
        })
        .collect();
    TriMesh {
        positions,
        triangles,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::render::shapes::uv_sphere;

    #[test]
    fn clustering_reduces_a_fine_sphere_and_keeps_its_surface_within_the_cell() {
        let fine = uv_sphere(0.1, 64, 128);
        let coarse = cluster_vertices(&fine, 0.01);
        assert!(coarse.is_valid());
        assert!(
            coarse.triangle_count() * 4 < fine.triangle_count(),
            "{} vs {}",
            coarse.triangle_count(),
            fine.triangle_count()
        );
        // Every vertex stays within the cell diagonal of the sphere's surface.
        let bound = 0.01 * 3f32.sqrt();
        for p in &coarse.positions {
            assert!(
                (p.coords.norm() - 0.1).abs() <= bound,
                "{}",
                p.coords.norm()
            );
        }
        assert_eq!(cluster_vertices(&fine, 0.0), fine);
    }
}
