//! Visual geometry: mesh files (STL, OBJ, COLLADA via `mesh-loader`) and tessellated URDF
//! primitives, as indexed [`TriMesh`]es in metres.

use super::config::RobotConfig;
use super::error::RobotError;
use super::geometry::TriMesh;
use nalgebra::Point3;
use std::collections::HashMap;
use std::f32::consts::PI;
use std::path::Path;

/// Parses a mesh file's bytes (`path` names it in messages and selects the format by its
/// extension, in any case, or content), merges its sub-meshes, welds duplicate vertices and
/// applies `scale` (per axis). Caps: `cfg.max_mesh_file_bytes`, `cfg.max_mesh_triangles`.
/// OBJ material libraries are not read (the renderer draws no colours).
///
/// Beyond `mesh-loader`: an STL file is binary when its size is exactly
/// `84 + 50 * triangle count` (the count read from bytes 80..84), whatever its header says
/// (exporters often start binary headers with `solid`); an OBJ file `mesh-loader` refuses
/// (e.g. faces with and without texture or normal indices in one file) is read again for
/// its positions and faces only ([`obj_positions_and_faces`]).
pub fn mesh_from_bytes(
    bytes: &[u8],
    path: &Path,
    scale: [f64; 3],
    cfg: &RobotConfig,
) -> Result<TriMesh, RobotError> {
    let name = path.display().to_string();
    let len = bytes.len() as u64;
    if len > cfg.max_mesh_file_bytes {
        return Err(RobotError::MeshFileTooLarge {
            path: name,
            bytes: len,
            limit_bytes: cfg.max_mesh_file_bytes,
        });
    }
    let ext = path
        .extension()
        .map(|e| e.to_string_lossy().to_ascii_lowercase());
    let is_obj = ext.as_deref() == Some("obj");
    if !matches!(ext.as_deref(), Some("obj" | "dae"))
        && let Some(count) = binary_stl_triangle_count(bytes)
    {
        check_triangles(count, &name, cfg)?;
        let vertices = binary_stl_vertices(bytes, count);
        let faces: Vec<[u32; 3]> = (0..count as u32)
            .map(|t| [3 * t, 3 * t + 1, 3 * t + 2])
            .collect();
        return weld(&[(&vertices, &faces)], &name, scale, cfg);
    }
    // mesh-loader picks the format from the extension in lower or upper case only.
    let lower_path = match &ext {
        Some(e) => path.with_extension(e),
        None => path.to_path_buf(),
    };
    let loader = mesh_loader::Loader::default();
    // No material files: the reader refuses, which mesh-loader treats as "no materials".
    // mesh-loader 0.1 panics on some malformed files (a COLLADA index past its positions,
    // found by the `mesh` fuzz target): a panic is this file's error, not the process's.
    let parsed = std::panic::catch_unwind(|| {
        loader.load_from_slice_with_reader(bytes, &lower_path, |_| {
            Err(std::io::Error::from(std::io::ErrorKind::NotFound))
        })
    });
    let scene = match parsed {
        Ok(Ok(scene)) => scene,
        Ok(Err(e)) => {
            if is_obj {
                // mesh-loader refuses some OBJ files urdfdom's loaders read (mixed face
                // formats): positions and faces are all vamos needs.
                let (vertices, faces) = obj_positions_and_faces(bytes, &name, cfg)?;
                return weld(&[(&vertices, &faces)], &name, scale, cfg);
            }
            return Err(RobotError::MeshUnreadable {
                path: name,
                message: e.to_string(),
            });
        }
        Err(panic) => {
            let what = panic
                .downcast_ref::<String>()
                .map(String::as_str)
                .or_else(|| panic.downcast_ref::<&str>().copied())
                .unwrap_or("the mesh parser failed");
            return Err(RobotError::MeshUnreadable {
                path: name,
                message: format!("malformed mesh ({what})"),
            });
        }
    };
    let parts: Vec<Part<'_>> = scene
        .meshes
        .iter()
        .map(|m| (m.vertices.as_slice(), m.faces.as_slice()))
        .collect();
    weld(&parts, &name, scale, cfg)
}

/// One sub-mesh before welding: vertex positions and triangles indexing them.
type Part<'a> = (&'a [[f32; 3]], &'a [[u32; 3]]);

/// Vertex positions and the triangles (0-based indices into them) of a mesh file.
pub type PositionsAndFaces = (Vec<[f32; 3]>, Vec<[u32; 3]>);

fn check_triangles(triangles: usize, name: &str, cfg: &RobotConfig) -> Result<(), RobotError> {
    if triangles > cfg.max_mesh_triangles {
        return Err(RobotError::TooManyTriangles {
            what: name.to_string(),
            triangles,
            limit: cfg.max_mesh_triangles,
        });
    }
    Ok(())
}

/// Merges indexed triangle lists into one welded, scaled mesh (`name` for messages).
fn weld(
    parts: &[Part<'_>],
    name: &str,
    scale: [f64; 3],
    cfg: &RobotConfig,
) -> Result<TriMesh, RobotError> {
    let triangles: usize = parts.iter().map(|(_, f)| f.len()).sum();
    check_triangles(triangles, name, cfg)?;
    let s = scale.map(|v| v as f32);
    let mut welder = Welder::with_capacity(triangles);
    for (vertices, faces) in parts {
        for face in *faces {
            let mut tri = [0u32; 3];
            for (slot, &i) in tri.iter_mut().zip(face) {
                let Some(v) = vertices.get(i as usize) else {
                    return Err(RobotError::MeshUnreadable {
                        path: name.to_string(),
                        message: format!("face index {i} out of range"),
                    });
                };
                if !v.iter().all(|c| c.is_finite()) {
                    return Err(RobotError::MeshUnreadable {
                        path: name.to_string(),
                        message: "non-finite vertex".into(),
                    });
                }
                *slot = welder.index(Point3::new(v[0] * s[0], v[1] * s[1], v[2] * s[2]));
            }
            welder.mesh.triangles.push(tri);
        }
    }
    Ok(welder.mesh)
}

/// Binary STL: an 80-byte header, a little-endian `u32` triangle count, then 50 bytes per
/// triangle (normal and three vertices as 12 little-endian `f32`, a `u16` attribute).
const STL_HEADER: usize = 84;
const STL_TRIANGLE: usize = 50;

/// The triangle count of a binary STL file: `Some` exactly when the size is
/// `84 + 50 * count` for the count stored at bytes 80..84.
pub fn binary_stl_triangle_count(bytes: &[u8]) -> Option<usize> {
    let count_bytes: [u8; 4] = bytes.get(80..STL_HEADER)?.try_into().ok()?;
    let count = u32::from_le_bytes(count_bytes) as usize;
    let body = count.checked_mul(STL_TRIANGLE)?;
    (bytes.len().checked_sub(STL_HEADER)? == body).then_some(count)
}

/// The `3 count` vertices of a binary STL file whose size
/// [`binary_stl_triangle_count`] accepted (the normals are not needed).
fn binary_stl_vertices(bytes: &[u8], count: usize) -> Vec<[f32; 3]> {
    let mut vertices = Vec::with_capacity(3 * count);
    for tri in bytes[STL_HEADER..].chunks_exact(STL_TRIANGLE).take(count) {
        // 12 bytes of normal, then 3 x 12 bytes of vertices, then the attribute.
        for corner in tri[12..48].chunks_exact(12) {
            let f = |k: usize| {
                f32::from_le_bytes([
                    corner[4 * k],
                    corner[4 * k + 1],
                    corner[4 * k + 2],
                    corner[4 * k + 3],
                ])
            };
            vertices.push([f(0), f(1), f(2)]);
        }
    }
    vertices
}

/// Positions and triangles of an OBJ file, nothing else: `v x y z` (further values, `w` or
/// a colour, ignored) and `f` faces whose corners are `a`, `a/t`, `a/t/n` or `a//n`
/// (negative indices count back from the last vertex read), polygons fan-triangulated.
/// Faces of fewer than three corners (points, lines) and other statements are skipped; a
/// line ending in `\` continues on the next. `name` names the file in errors.
pub fn obj_positions_and_faces(
    bytes: &[u8],
    name: &str,
    cfg: &RobotConfig,
) -> Result<PositionsAndFaces, RobotError> {
    let text = String::from_utf8_lossy(bytes);
    let bad = |line: usize, what: String| RobotError::MeshUnreadable {
        path: name.to_string(),
        message: format!("OBJ line {line}: {what}"),
    };
    let mut vertices: Vec<[f32; 3]> = Vec::new();
    let mut faces: Vec<[u32; 3]> = Vec::new();
    let mut corners: Vec<u32> = Vec::new();
    let mut pending = String::new();
    for (k, raw) in text.lines().enumerate() {
        let line_no = k + 1;
        let raw = raw.split('#').next().unwrap_or("");
        if let Some(head) = raw.trim_end().strip_suffix('\\') {
            pending.push_str(head);
            pending.push(' ');
            continue;
        }
        pending.push_str(raw);
        let line = std::mem::take(&mut pending);
        let mut words = line.split_whitespace();
        match words.next() {
            Some("v") => {
                let mut p = [0f32; 3];
                for c in &mut p {
                    let w = words
                        .next()
                        .ok_or_else(|| bad(line_no, "a vertex needs three coordinates".into()))?;
                    *c = w
                        .parse()
                        .map_err(|_| bad(line_no, format!("{w:?} is not a number")))?;
                }
                vertices.push(p);
            }
            Some("f") => {
                corners.clear();
                for w in words {
                    let first = w.split('/').next().unwrap_or("");
                    let i: i64 = first
                        .parse()
                        .map_err(|_| bad(line_no, format!("{w:?} is not a face corner")))?;
                    let n = vertices.len() as i64;
                    // 1-based; negative: relative to the vertices read so far.
                    let index = match i {
                        i if i > 0 => i - 1,
                        i if i < 0 => n + i,
                        _ => -1,
                    };
                    let index = u32::try_from(index)
                        .map_err(|_| bad(line_no, format!("face index {i} out of range")))?;
                    corners.push(index);
                }
                if let [a, rest @ ..] = corners.as_slice() {
                    for pair in rest.windows(2) {
                        faces.push([*a, pair[0], pair[1]]);
                    }
                }
                check_triangles(faces.len(), name, cfg)?;
            }
            _ => {}
        }
    }
    // Positive indices may refer to vertices declared later in the file.
    if let Some(&i) = faces
        .iter()
        .flatten()
        .find(|&&i| i as usize >= vertices.len())
    {
        return Err(RobotError::MeshUnreadable {
            path: name.to_string(),
            message: format!("face index {} out of range", u64::from(i) + 1),
        });
    }
    Ok((vertices, faces))
}

/// Builds an indexed mesh, giving bit-identical positions one index.
struct Welder {
    mesh: TriMesh,
    seen: HashMap<[u32; 3], u32>,
}

impl Welder {
    fn with_capacity(triangles: usize) -> Self {
        Self {
            mesh: TriMesh {
                positions: Vec::with_capacity(triangles / 2 + 3),
                triangles: Vec::with_capacity(triangles),
            },
            seen: HashMap::with_capacity(triangles / 2 + 3),
        }
    }

    fn index(&mut self, p: Point3<f32>) -> u32 {
        // +0.0 and -0.0 are the same point.
        let key = [p.x + 0.0, p.y + 0.0, p.z + 0.0].map(f32::to_bits);
        let next = self.mesh.positions.len() as u32;
        *self.seen.entry(key).or_insert_with(|| {
            self.mesh.positions.push(p);
            next
        })
    }
}

/// An axis-aligned box centred on the origin with side lengths `size_m`: 8 vertices,
/// 12 triangles, counter-clockwise seen from outside.
pub fn box_mesh(size_m: [f64; 3]) -> TriMesh {
    let h = size_m.map(|v| (v / 2.0) as f32);
    let positions = (0..8)
        .map(|i| {
            let sx = if i & 1 == 0 { -h[0] } else { h[0] };
            let sy = if i & 2 == 0 { -h[1] } else { h[1] };
            let sz = if i & 4 == 0 { -h[2] } else { h[2] };
            Point3::new(sx, sy, sz)
        })
        .collect();
    // Corner i has bit 0 = +x, bit 1 = +y, bit 2 = +z.
    let triangles = vec![
        [0, 2, 3],
        [0, 3, 1], // -z
        [4, 5, 7],
        [4, 7, 6], // +z
        [0, 1, 5],
        [0, 5, 4], // -y
        [2, 6, 7],
        [2, 7, 3], // +y
        [0, 4, 6],
        [0, 6, 2], // -x
        [1, 3, 7],
        [1, 7, 5], // +x
    ];
    TriMesh {
        positions,
        triangles,
    }
}

/// A closed cylinder along z, centred on the origin: `segments` (at least 3) around,
/// `2 segments + 2` vertices, `4 segments` triangles.
pub fn cylinder_mesh(radius_m: f64, length_m: f64, segments: u32) -> TriMesh {
    let n = segments.max(3);
    let (r, h) = (radius_m as f32, (length_m / 2.0) as f32);
    let mut positions = Vec::with_capacity(2 * n as usize + 2);
    for k in 0..n {
        let a = 2.0 * PI * k as f32 / n as f32;
        positions.push(Point3::new(r * a.cos(), r * a.sin(), -h));
        positions.push(Point3::new(r * a.cos(), r * a.sin(), h));
    }
    let (bottom, top) = (2 * n, 2 * n + 1);
    positions.push(Point3::new(0.0, 0.0, -h));
    positions.push(Point3::new(0.0, 0.0, h));
    let mut triangles = Vec::with_capacity(4 * n as usize);
    for k in 0..n {
        let (b0, t0) = (2 * k, 2 * k + 1);
        let (b1, t1) = (2 * ((k + 1) % n), 2 * ((k + 1) % n) + 1);
        triangles.push([b0, b1, t1]);
        triangles.push([b0, t1, t0]);
        triangles.push([bottom, b1, b0]);
        triangles.push([top, t0, t1]);
    }
    TriMesh {
        positions,
        triangles,
    }
}

/// A UV sphere centred on the origin: `rings` (at least 2) latitude bands and
/// `2 rings` longitude segments; `2 + (rings - 1) 2 rings` vertices and
/// `2 (2 rings) (rings - 1)` triangles.
pub fn sphere_mesh(radius_m: f64, rings: u32) -> TriMesh {
    let rings = rings.max(2);
    let segs = 2 * rings;
    let r = radius_m as f32;
    let mut positions = vec![Point3::new(0.0, 0.0, r), Point3::new(0.0, 0.0, -r)];
    for i in 1..rings {
        let polar = PI * i as f32 / rings as f32;
        for k in 0..segs {
            let a = 2.0 * PI * k as f32 / segs as f32;
            positions.push(Point3::new(
                r * polar.sin() * a.cos(),
                r * polar.sin() * a.sin(),
                r * polar.cos(),
            ));
        }
    }
    let at = |i: u32, k: u32| 2 + (i - 1) * segs + k % segs;
    let mut triangles = Vec::with_capacity((2 * segs * (rings - 1)) as usize);
    for k in 0..segs {
        triangles.push([0, at(1, k), at(1, k + 1)]);
        triangles.push([1, at(rings - 1, k + 1), at(rings - 1, k)]);
    }
    for i in 1..rings - 1 {
        for k in 0..segs {
            triangles.push([at(i, k), at(i + 1, k), at(i + 1, k + 1)]);
            triangles.push([at(i, k), at(i + 1, k + 1), at(i, k + 1)]);
        }
    }
    TriMesh {
        positions,
        triangles,
    }
}

/// A capsule along z: a cylinder of `length_m` with hemispherical caps (drawn as whole
/// spheres at the ends; the overlap is hidden inside).
pub fn capsule_mesh(radius_m: f64, length_m: f64, segments: u32, rings: u32) -> TriMesh {
    let mut m = cylinder_mesh(radius_m, length_m, segments);
    let sphere = sphere_mesh(radius_m, rings);
    for z in [-length_m / 2.0, length_m / 2.0] {
        let pose = nalgebra::Isometry3::translation(0.0, 0.0, z as f32);
        m.append_transformed(&sphere, &pose);
    }
    m
}

#[cfg(test)]
#[path = "mesh_tests.rs"]
mod tests;
