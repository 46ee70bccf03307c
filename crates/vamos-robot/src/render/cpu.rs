//! The CPU back-end: a z-buffer rasteriser.
//!
//! Per frame: every link's `camera_from_link` is formed once (f64, then f32), links whose
//! bounding sphere lies outside the view frustum are skipped, the remaining vertices are
//! transformed and projected once (f32, planar buffers), each vertex gets the integer
//! bounds of the pixel centres it could reach, a branch-free pass over those keeps the
//! triangles whose box holds a pixel centre (most of a dense mesh's hold none), and each
//! kept triangle is clipped
//! against the near plane (cut into at most two triangles) and scan-converted with
//! integer edge functions in 24.8 fixed point over its bounding box, evaluated
//! incrementally along each row, with the top-left fill rule (a pixel centre on a shared
//! edge is drawn once) and a depth test on `1/z` (perspective-correct: `1/z` is affine in
//! screen space). Each pixel keeps the id of the nearest triangle; a second pass over the
//! covered pixels turns `1/z` into depth, recovers the 3-D point from pixel and depth,
//! moves it rigidly with its link to the other time and projects it: the exact flow.
//!
//! Single-threaded by design (see the parent module); buffers are kept between frames.

use super::mask::grow_mask;
use super::{FlowGrid, RenderConfig, RenderError, RenderFrame, RenderOutput, RobotView};
use crate::camera::Intrinsics;
use crate::geometry::LinkMesh;
use nalgebra::{Isometry3, Matrix3, Point3, Vector3};
use vamos_vision::image::GrayImage;

/// Vertices further than this from the image origin (pixels, after projection) are out
/// of the rasteriser's fixed-point range; their triangles are skipped.
pub const GUARD_BAND_PX: f32 = 1_048_576.0;

/// Shift that makes every in-guard-band value positive, for floor by truncation.
const OFFSET: f64 = (1u64 << 40) as f64;

/// `floor(x)` for `|x|` within a little more than the guard band.
fn floor_in_guard(x: f32) -> i64 {
    (f64::from(x) + OFFSET) as i64 - OFFSET as i64
}

/// Sub-pixel precision of the rasteriser: 8 bits (1/256 px).
const SUB_BITS: u32 = 8;
const SUB_SCALE: f64 = (1u32 << SUB_BITS) as f64;
/// `tri_id` of a pixel that no triangle covers.
const NO_TRIANGLE: u32 = u32::MAX;
/// Gray levels of the shaded image: background, darkest and brightest robot pixel.
const GRAY_BACKGROUND: f32 = 255.0;
const GRAY_DARK: f32 = 38.0;
const GRAY_BRIGHT: f32 = 217.0;

/// Geometry of one mesh: a contiguous range of the renderer's vertex and triangle
/// buffers, attached to one link.
#[derive(Debug, Clone)]
struct Group {
    link: usize,
    vertices: std::ops::Range<usize>,
    triangles: std::ops::Range<usize>,
    /// Bounding sphere in the link frame.
    centre: Vector3<f32>,
    radius: f32,
}

/// What [`CpuRenderer::prepared_geometry`] lends: vertices, triangles, per group its
/// link index and vertex range.
#[cfg_attr(not(feature = "wgpu"), allow(dead_code))]
pub(super) type PreparedGeometry<'a> = (
    &'a [[f32; 3]],
    &'a [[u32; 3]],
    Vec<(usize, std::ops::Range<usize>)>,
);

/// The CPU z-buffer renderer (see the module docs).
#[derive(Debug, Clone)]
pub struct CpuRenderer {
    near_m: f32,
    margin_px: u32,
    grid: FlowGrid,
    cull_back_faces: bool,
    simplify_cell_m: f32,
    groups: Vec<Group>,
    /// Vertex positions in their link's frame.
    positions: Vec<[f32; 3]>,
    /// Triangles with indices into `positions`.
    triangles: Vec<[u32; 3]>,
    /// Group of each triangle.
    triangle_group: Vec<u32>,
    max_link: Option<usize>,
    // Per-frame scratch, kept between frames.
    camera_xyz: Vec<[f32; 3]>,
    screen: Vec<[f32; 3]>,
    /// Per vertex, the pixel-centre bounds of [`centre_bounds`], for the triangle pre-pass.
    centres: Vec<[i16; 4]>,
    /// Triangles of the current group that pass the pre-pass.
    candidates: Vec<u32>,
    inv_z: Vec<f32>,
    tri_id: Vec<u32>,
    /// Per group: rotation and translation of `other_from_shown` (matrix form: cheaper
    /// per pixel than the quaternion).
    other_from_shown: Vec<Option<(Matrix3<f64>, Vector3<f64>)>>,
    mask_scratch: Vec<u8>,
}

impl CpuRenderer {
    /// A renderer with `config`'s near plane, mask margin, flow grid and culling.
    pub fn new(config: &RenderConfig) -> Result<Self, RenderError> {
        config.validate()?;
        Ok(Self {
            near_m: config.near_m as f32,
            margin_px: config.mask_margin_px,
            grid: config.flow_grid,
            cull_back_faces: config.cull_back_faces,
            simplify_cell_m: config.simplify_cell_m as f32,
            groups: Vec::new(),
            positions: Vec::new(),
            triangles: Vec::new(),
            triangle_group: Vec::new(),
            max_link: None,
            camera_xyz: Vec::new(),
            screen: Vec::new(),
            centres: Vec::new(),
            candidates: Vec::new(),
            inv_z: Vec::new(),
            tri_id: Vec::new(),
            other_from_shown: Vec::new(),
            mask_scratch: Vec::new(),
        })
    }

    /// Triangles prepared.
    pub fn triangle_count(&self) -> usize {
        self.triangles.len()
    }

    /// The prepared (validated, possibly simplified) geometry, for other back-ends:
    /// link-frame vertex positions, triangles indexing them, and per mesh group its link
    /// index and vertex range (groups own contiguous vertex ranges).
    #[cfg_attr(not(feature = "wgpu"), allow(dead_code))]
    pub(super) fn prepared_geometry(&self) -> PreparedGeometry<'_> {
        let groups = self
            .groups
            .iter()
            .map(|g| (g.link, g.vertices.clone()))
            .collect();
        (&self.positions, &self.triangles, groups)
    }

    pub(super) fn check_links(
        &self,
        view: &RobotView<'_>,
        which: &'static str,
    ) -> Result<(), RenderError> {
        view.validate(which)?;
        if let Some(link) = self.max_link
            && link >= view.base_from_link.len()
        {
            return Err(RenderError::LinkOutOfRange {
                link,
                link_count: view.base_from_link.len(),
                which,
            });
        }
        Ok(())
    }
}

impl super::BodyRenderer for CpuRenderer {
    fn prepare(&mut self, meshes: &[LinkMesh]) -> Result<(), RenderError> {
        let vertex_count: usize = meshes.iter().map(|m| m.mesh.positions.len()).sum();
        let triangle_count: usize = meshes.iter().map(|m| m.mesh.triangles.len()).sum();
        // Triangle ids must stay below the NO_TRIANGLE sentinel.
        let max = (u32::MAX - 1) as usize;
        for (what, count) in [("vertices", vertex_count), ("triangles", triangle_count)] {
            if count > max {
                return Err(RenderError::TooLarge { what, count, max });
            }
        }
        for (m, lm) in meshes.iter().enumerate() {
            let n = lm.mesh.positions.len();
            if let Some(vertex) = lm
                .mesh
                .positions
                .iter()
                .position(|p| !p.coords.iter().all(|c| c.is_finite()))
            {
                return Err(RenderError::NonFiniteVertex {
                    mesh: m,
                    link: lm.link,
                    vertex,
                });
            }
            for (t, tri) in lm.mesh.triangles.iter().enumerate() {
                if let Some(&index) = tri.iter().find(|&&i| i as usize >= n) {
                    return Err(RenderError::IndexOutOfRange {
                        mesh: m,
                        link: lm.link,
                        triangle: t,
                        index,
                        vertex_count: n,
                    });
                }
            }
        }
        self.groups.clear();
        self.positions.clear();
        self.triangles.clear();
        self.triangle_group.clear();
        self.max_link = None;
        for lm in meshes.iter().filter(|m| !m.mesh.triangles.is_empty()) {
            let simplified;
            let lm = if self.simplify_cell_m > 0.0 {
                simplified = LinkMesh {
                    link: lm.link,
                    mesh: super::simplify::cluster_vertices(&lm.mesh, self.simplify_cell_m),
                };
                &simplified
            } else {
                lm
            };
            let v0 = self.positions.len();
            let t0 = self.triangles.len();
            self.positions
                .extend(lm.mesh.positions.iter().map(|p| [p.x, p.y, p.z]));
            let offset = v0 as u32;
            self.triangles.extend(
                lm.mesh
                    .triangles
                    .iter()
                    .map(|t| [t[0] + offset, t[1] + offset, t[2] + offset]),
            );
            let g = self.groups.len() as u32;
            self.triangle_group
                .extend(std::iter::repeat_n(g, lm.mesh.triangles.len()));
            let (centre, radius) = bounding_sphere(&self.positions[v0..]);
            self.groups.push(Group {
                link: lm.link,
                vertices: v0..self.positions.len(),
                triangles: t0..self.triangles.len(),
                centre,
                radius,
            });
            self.max_link = Some(self.max_link.map_or(lm.link, |l| l.max(lm.link)));
        }
        Ok(())
    }

    fn render(
        &mut self,
        frame: &RenderFrame<'_>,
        out: &mut RenderOutput,
    ) -> Result<(), RenderError> {
        let k = frame.intrinsics;
        k.validate()?;
        self.check_links(&frame.current, "current")?;
        if let Some(prev) = &frame.previous {
            self.check_links(prev, "previous")?;
        }
        let (shown, other) = match (frame.previous, self.grid) {
            (None, _) => (frame.current, None),
            (Some(prev), FlowGrid::Target) => (frame.current, Some(prev)),
            (Some(prev), FlowGrid::Source) => (prev, Some(frame.current)),
        };
        let (w, h) = (k.width as usize, k.height as usize);
        let n = w * h;
        self.inv_z.clear();
        self.inv_z.resize(n, 0.0);
        self.tri_id.clear();
        self.tri_id.resize(n, NO_TRIANGLE);
        self.camera_xyz.resize(self.positions.len(), [0.0; 3]);
        self.screen.resize(self.positions.len(), [0.0; 3]);
        self.centres.resize(self.positions.len(), [0; 4]);
        self.other_from_shown.clear();

        let frustum = Frustum::new(k, self.near_m);
        let mut target = Target {
            inv_z: &mut self.inv_z,
            tri_id: &mut self.tri_id,
            width: w,
            height: h,
            cull_back_faces: self.cull_back_faces,
        };
        let proj = [k.fx as f32, k.fy as f32, k.cx as f32, k.cy as f32];
        for group in &self.groups {
            let shown_from_link = shown.camera_from_base * shown.base_from_link[group.link];
            self.other_from_shown.push(other.map(|o| {
                let m: Isometry3<f64> =
                    o.camera_from_base * o.base_from_link[group.link] * shown_from_link.inverse();
                (
                    m.rotation.to_rotation_matrix().into_inner(),
                    m.translation.vector,
                )
            }));
            let rot: Matrix3<f32> = shown_from_link
                .rotation
                .to_rotation_matrix()
                .matrix()
                .cast();
            let tr: Vector3<f32> = shown_from_link.translation.vector.cast();
            if !frustum.may_see(&(rot * group.centre + tr), group.radius) {
                continue;
            }
            transform_vertices(
                &self.positions[group.vertices.clone()],
                &rot,
                &tr,
                proj,
                self.near_m,
                &mut self.camera_xyz[group.vertices.clone()],
                &mut self.screen[group.vertices.clone()],
            );
            if w < PREPASS_MAX_SIDE && h < PREPASS_MAX_SIDE {
                centre_bounds(
                    &self.screen[group.vertices.clone()],
                    (w, h),
                    &mut self.centres[group.vertices.clone()],
                );
                // Most triangles of a dense mesh cover no pixel centre: a branch-free
                // pass over small per-vertex integers keeps the others, in order (so
                // ties in depth resolve as before).
                select_candidates(
                    &self.triangles[group.triangles.clone()],
                    group.triangles.start as u32,
                    &self.centres,
                    (w, h),
                    &mut self.candidates,
                );
            } else {
                self.candidates.clear();
                self.candidates
                    .extend(group.triangles.start as u32..group.triangles.end as u32);
            }
            for &t in &self.candidates {
                let [a, b, c] = self.triangles[t as usize].map(|i| i as usize);
                let (sa, sb, sc) = (self.screen[a], self.screen[b], self.screen[c]);
                // `transform_vertices` marks vertices before the near plane with a
                // negative 1/z, so the common case reads only the screen positions.
                if sa[2] > 0.0 && sb[2] > 0.0 && sc[2] > 0.0 {
                    target.raster([sa, sb, sc], t);
                    continue;
                }
                let near = self.near_m;
                let za = self.camera_xyz[a][2];
                let zb = self.camera_xyz[b][2];
                let zc = self.camera_xyz[c][2];
                if za >= near || zb >= near || zc >= near {
                    let poly = clip_near(
                        [self.camera_xyz[a], self.camera_xyz[b], self.camera_xyz[c]],
                        near,
                    );
                    let s: Vec<[f32; 3]> = poly.iter().map(|p| project(p, proj)).collect();
                    for i in 1..s.len() - 1 {
                        target.raster([s[0], s[i], s[i + 1]], t);
                    }
                }
            }
        }
        self.resolve(k, frame.shade, other.is_some(), out);
        Ok(())
    }

    fn name(&self) -> &'static str {
        "cpu"
    }
}

impl CpuRenderer {
    /// Second pass: depth, link, flow, gray and mask from the z-buffer.
    fn resolve(&mut self, k: &Intrinsics, shade: bool, with_flow: bool, out: &mut RenderOutput) {
        let (w, h) = (k.width as usize, k.height as usize);
        let n = w * h;
        out.reset(w, h);
        let mut gray = if shade {
            let mut data = out
                .gray
                .take()
                .map(GrayImage::into_data)
                .unwrap_or_default();
            data.clear();
            data.resize(n, GRAY_BACKGROUND);
            Some(data)
        } else {
            out.gray = None;
            None
        };
        let source_grid = self.grid == FlowGrid::Source;
        for y in 0..h {
            let ray_y = (y as f64 - k.cy) / k.fy;
            for x in 0..w {
                let i = y * w + x;
                let id = self.tri_id[i];
                if id == NO_TRIANGLE {
                    continue;
                }
                let g = self.triangle_group[id as usize] as usize;
                let z = 1.0 / f64::from(self.inv_z[i]);
                out.coverage[i] = true;
                out.depth_m[i] = z as f32;
                out.link[i] = self.groups[g].link as u32;
                let ray_x = (x as f64 - k.cx) / k.fx;
                let p = Point3::new(ray_x * z, ray_y * z, z);
                if with_flow && let Some((rot, tr)) = &self.other_from_shown[g] {
                    let q = rot * p.coords + tr;
                    if q.z > 0.0 {
                        let qx = k.fx * q.x / q.z + k.cx;
                        let qy = k.fy * q.y / q.z + k.cy;
                        let (du, dv) = if source_grid {
                            (qx - x as f64, qy - y as f64)
                        } else {
                            (x as f64 - qx, y as f64 - qy)
                        };
                        out.flow.u[i] = du as f32;
                        out.flow.v[i] = dv as f32;
                    }
                }
                if let Some(data) = gray.as_mut() {
                    let [a, b, c] =
                        self.triangles[id as usize].map(|v| self.camera_xyz[v as usize]);
                    let e1 = Vector3::new(b[0] - a[0], b[1] - a[1], b[2] - a[2]);
                    let e2 = Vector3::new(c[0] - a[0], c[1] - a[1], c[2] - a[2]);
                    let normal = e1.cross(&e2);
                    // Headlight along the optical axis: constant over a flat face.
                    let len = normal.norm();
                    let cos = if len > 0.0 {
                        (normal.z / len).abs()
                    } else {
                        0.0
                    };
                    data[i] = GRAY_DARK + (GRAY_BRIGHT - GRAY_DARK) * cos.min(1.0);
                }
            }
        }
        if let Some(data) = gray {
            // Invariant: `data` has exactly w * h values.
            out.gray = GrayImage::new(w, h, data).ok();
        }
        grow_mask(
            &out.coverage,
            w,
            h,
            self.margin_px,
            &mut self.mask_scratch,
            &mut out.mask,
        );
    }
}

/// Transforms link-frame vertices into the camera frame and projects those in front of
/// the near plane to `(x_px, y_px, 1/z)`.
fn transform_vertices(
    positions: &[[f32; 3]],
    rot: &Matrix3<f32>,
    tr: &Vector3<f32>,
    proj: [f32; 4],
    near: f32,
    camera_xyz: &mut [[f32; 3]],
    screen: &mut [[f32; 3]],
) {
    let r = rot;
    for ((p, c), s) in positions
        .iter()
        .zip(camera_xyz.iter_mut())
        .zip(screen.iter_mut())
    {
        let x = r[(0, 0)] * p[0] + r[(0, 1)] * p[1] + r[(0, 2)] * p[2] + tr.x;
        let y = r[(1, 0)] * p[0] + r[(1, 1)] * p[1] + r[(1, 2)] * p[2] + tr.y;
        let z = r[(2, 0)] * p[0] + r[(2, 1)] * p[1] + r[(2, 2)] * p[2] + tr.z;
        *c = [x, y, z];
        *s = if z >= near {
            project(c, proj)
        } else {
            BEHIND_NEAR
        };
    }
}

/// Images at least this wide or high skip the triangle pre-pass (its bounds are `i16`).
const PREPASS_MAX_SIDE: usize = 16_384;

/// Per vertex: `[ceil(x - pad), -floor(x + pad), ceil(y - pad), -floor(y + pad)]` with
/// `pad` the rasteriser's snapping step ([`Target::setup`]'s float box), the values
/// clamped to `-1..=width` (or `height`) before the sign. A triangle's box holds a pixel
/// centre of the image only if `max(min ceil, 0) <= min(max floor, width - 1)` on both
/// axes; the floors are stored negated so that one lane-wise minimum over the three
/// vertices gives all four bounds ([`select_candidates`]). Clamping is monotone and the
/// `f32` floor below can only come out low for a `ceil` lane (high for a `floor`), so
/// the test never rejects a triangle that `setup` keeps. Vertices before the near plane
/// get the widest bounds, so their triangles always go on to `raster`.
fn centre_bounds(screen: &[[f32; 3]], (w, h): (usize, usize), out: &mut [[i16; 4]]) {
    let pad = 1.0 / SUB_SCALE as f32;
    let (wf, hf) = (w as f32, h as f32);
    let lo = [-1.0, -wf, -1.0, -hf];
    let hi = [wf, 1.0, hf, 1.0];
    // ceil(v) = K - floor(K - v), and K - v > 0 after the clamp, so the floor is a
    // truncation.
    let k = w.max(h) as i32 + 2;
    let wide = [-1, -(w as i16), -1, -(h as i16)];
    for (s, o) in screen.iter().zip(out.iter_mut()) {
        let [x, y, iz] = *s;
        *o = if iz > 0.0 && (x + y).is_finite() {
            ceil_lanes([x - pad, -(x + pad), y - pad, -(y + pad)], lo, hi, k)
        } else {
            wide
        };
    }
}

/// Lane-wise `ceil(clamp(v, lo, hi))` as `k - trunc(k - clamped)` (see [`centre_bounds`]).
#[inline(always)]
fn ceil_lanes(v: [f32; 4], lo: [f32; 4], hi: [f32; 4], k: i32) -> [i16; 4] {
    #[cfg(target_arch = "x86_64")]
    {
        use std::arch::x86_64::*;
        // SAFETY: SSE2 is part of x86_64; the loads and the store go through 16-byte
        // `[f32; 4]` and 8-byte `[i16; 4]` values, unaligned forms only.
        unsafe {
            let load = |a: &[f32; 4]| _mm_loadu_ps(a.as_ptr());
            let clamped = _mm_min_ps(_mm_max_ps(load(&v), load(&lo)), load(&hi));
            let t = _mm_cvttps_epi32(_mm_sub_ps(_mm_set1_ps(k as f32), clamped));
            let c = _mm_sub_epi32(_mm_set1_epi32(k), t);
            let mut out = [0i16; 4];
            _mm_storel_epi64(out.as_mut_ptr().cast::<__m128i>(), _mm_packs_epi32(c, c));
            out
        }
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        std::array::from_fn(|j| (k - (k as f32 - v[j].max(lo[j]).min(hi[j])) as i32) as i16)
    }
}

/// The triangles of `tris` (numbered from `first`) whose pixel-centre box, from the
/// per-vertex [`centre_bounds`], holds a pixel centre of the `w x h` image, in order.
fn select_candidates(
    tris: &[[u32; 3]],
    first: u32,
    centres: &[[i16; 4]],
    (w, h): (usize, usize),
    out: &mut Vec<u32>,
) {
    out.clear();
    out.resize(tris.len(), 0);
    // Lane-wise lower bounds of the minimum: [0, -(w - 1), 0, -(h - 1)].
    let floor = [0, 1 - w as i16, 0, 1 - h as i16];
    let mut n = 0;
    for (k, t) in tris.iter().enumerate() {
        let [a, b, c] = t.map(|i| &centres[i as usize]);
        out[n] = first + k as u32;
        n += usize::from(holds_centre(a, b, c, &floor));
    }
    out.truncate(n);
}

/// `[lo_x, -hi_x, lo_y, -hi_y]` = lane-wise `max(min(a, b, c), floor)`; true when
/// `lo <= hi` on both axes.
#[inline(always)]
fn holds_centre(a: &[i16; 4], b: &[i16; 4], c: &[i16; 4], floor: &[i16; 4]) -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        use std::arch::x86_64::*;
        // SAFETY: SSE2 is part of x86_64; each pointer is to 8 readable bytes (an
        // `[i16; 4]`), and the unaligned 64-bit loads have no alignment requirement.
        unsafe {
            let load = |p: &[i16; 4]| _mm_loadl_epi64(p.as_ptr().cast::<__m128i>());
            let m = _mm_min_epi16(_mm_min_epi16(load(a), load(b)), load(c));
            let m = _mm_max_epi16(m, load(floor));
            // Lane 0 + lane 1 and lane 2 + lane 3: lo - hi on each axis.
            let d = _mm_add_epi16(m, _mm_srli_epi64::<16>(m));
            let bad = _mm_cmpgt_epi16(d, _mm_setzero_si128());
            _mm_movemask_epi8(bad) & 0b11_0011 == 0
        }
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        let m: [i16; 4] = std::array::from_fn(|j| a[j].min(b[j]).min(c[j]).max(floor[j]));
        m[0] + m[1] <= 0 && m[2] + m[3] <= 0
    }
}

/// The screen position of a vertex before the near plane: a negative 1/z (a vertex at or
/// beyond the near plane, `near > 0`, has a positive one).
const BEHIND_NEAR: [f32; 3] = [f32::NAN, f32::NAN, -1.0];

fn project(p: &[f32; 3], [fx, fy, cx, cy]: [f32; 4]) -> [f32; 3] {
    let iz = 1.0 / p[2];
    [fx * p[0] * iz + cx, fy * p[1] * iz + cy, iz]
}

/// Clips a camera-space triangle to `z >= near` (Sutherland-Hodgman against one plane):
/// a convex polygon of 3 or 4 vertices (at least one vertex must be in front).
fn clip_near(tri: [[f32; 3]; 3], near: f32) -> Vec<[f32; 3]> {
    let mut out = Vec::with_capacity(4);
    for i in 0..3 {
        let p = tri[i];
        let q = tri[(i + 1) % 3];
        let p_in = p[2] >= near;
        let q_in = q[2] >= near;
        if p_in {
            out.push(p);
        }
        if p_in != q_in {
            let t = (near - p[2]) / (q[2] - p[2]);
            out.push([p[0] + t * (q[0] - p[0]), p[1] + t * (q[1] - p[1]), near]);
        }
    }
    out
}

/// Bounding sphere of points (centre of the box around them; radius to the furthest).
fn bounding_sphere(points: &[[f32; 3]]) -> (Vector3<f32>, f32) {
    let mut lo = [f32::INFINITY; 3];
    let mut hi = [f32::NEG_INFINITY; 3];
    for p in points {
        for a in 0..3 {
            lo[a] = lo[a].min(p[a]);
            hi[a] = hi[a].max(p[a]);
        }
    }
    let c = Vector3::new(
        (lo[0] + hi[0]) * 0.5,
        (lo[1] + hi[1]) * 0.5,
        (lo[2] + hi[2]) * 0.5,
    );
    let r = points
        .iter()
        .map(|p| (Vector3::new(p[0], p[1], p[2]) - c).norm())
        .fold(0.0f32, f32::max);
    // Pad for f32 rounding of the transformed centre.
    (c, r * 1.0001 + 1e-6)
}

/// The view frustum's planes through the camera centre plus the near plane, for
/// conservative bounding-sphere culling.
struct Frustum {
    /// Unit normals pointing into the frustum.
    sides: [Vector3<f32>; 4],
    near: f32,
}

impl Frustum {
    fn new(k: &Intrinsics, near: f32) -> Self {
        let (w, h) = (f64::from(k.width), f64::from(k.height));
        let side = |x: f64, y: f64, z: f64| Vector3::new(x, y, z).normalize().cast::<f32>();
        Self {
            sides: [
                side(k.fx, 0.0, k.cx + 0.5),
                side(-k.fx, 0.0, w - 0.5 - k.cx),
                side(0.0, k.fy, k.cy + 0.5),
                side(0.0, -k.fy, h - 0.5 - k.cy),
            ],
            near,
        }
    }

    fn may_see(&self, centre: &Vector3<f32>, radius: f32) -> bool {
        centre.z + radius >= self.near && self.sides.iter().all(|n| n.dot(centre) >= -radius)
    }
}

/// The z-buffer being drawn into.
pub(super) struct Target<'a> {
    inv_z: &'a mut [f32],
    tri_id: &'a mut [u32],
    width: usize,
    height: usize,
    cull_back_faces: bool,
}

impl Target<'_> {
    /// The edge functions and pixel box of a screen-space triangle; `None` when it covers
    /// no pixel centre for certain, is degenerate, or is culled.
    fn setup(&self, v: [[f32; 3]; 3]) -> Option<Setup> {
        // Most triangles of a dense mesh cover no pixel centre: reject them on a
        // conservative float bounding box (padded by the snapping step) before any
        // fixed-point set-up. (`min`/`max` skip NaN, so check the coordinates' sum.)
        if !(v[0][0] + v[1][0] + v[2][0] + v[0][1] + v[1][1] + v[2][1]).is_finite() {
            return None;
        }
        let pad = 1.0 / SUB_SCALE as f32;
        let x_lo = v[0][0].min(v[1][0]).min(v[2][0]) - pad;
        let x_hi = v[0][0].max(v[1][0]).max(v[2][0]) + pad;
        let y_lo = v[0][1].min(v[1][1]).min(v[2][1]) - pad;
        let y_hi = v[0][1].max(v[1][1]).max(v[2][1]) + pad;
        if !(x_lo >= -GUARD_BAND_PX
            && x_hi <= GUARD_BAND_PX
            && y_lo >= -GUARD_BAND_PX
            && y_hi <= GUARD_BAND_PX)
        {
            return None;
        }
        // Inside the guard band, so the floor-by-truncation helper applies (and avoids a
        // libm call on targets without SSE4.1).
        let (wi, hi) = (self.width as i64 - 1, self.height as i64 - 1);
        if -floor_in_guard(-x_lo) > floor_in_guard(x_hi).min(wi)
            || -floor_in_guard(-y_lo) > floor_in_guard(y_hi).min(hi)
            || x_hi < 0.0
            || y_hi < 0.0
        {
            return None;
        }
        // Round to the 1/256 grid, half up, by truncating a positive number.
        let fixed = |c: f32| (f64::from(c) * SUB_SCALE + (OFFSET + 0.5)) as i64 - OFFSET as i64;
        let mut x = v.map(|p| fixed(p[0]));
        let mut y = v.map(|p| fixed(p[1]));
        let area = (x[1] - x[0]) * (y[2] - y[0]) - (y[1] - y[0]) * (x[2] - x[0]);
        if area == 0 {
            return None;
        }
        // With y down, a positive area is clockwise on screen: a counter-clockwise
        // (outward) triangle seen from behind.
        if area > 0 && self.cull_back_faces {
            return None;
        }
        // Edge functions below assume a positive area (the plane fit of 1/z does not
        // depend on the order).
        if area < 0 {
            x.swap(1, 2);
            y.swap(1, 2);
        }
        let (w, h) = (self.width as i64, self.height as i64);
        let one = 1i64 << SUB_BITS;
        let x_min = ((x[0].min(x[1]).min(x[2]) + one - 1) >> SUB_BITS).max(0);
        let x_max = (x[0].max(x[1]).max(x[2]) >> SUB_BITS).min(w - 1);
        let y_min = ((y[0].min(y[1]).min(y[2]) + one - 1) >> SUB_BITS).max(0);
        let y_max = (y[0].max(y[1]).max(y[2]) >> SUB_BITS).min(h - 1);
        if x_min > x_max || y_min > y_max {
            return None;
        }
        // Edge i is opposite vertex i: E_i(p) = A p.x + B p.y + C, positive inside.
        let mut a = [0i64; 3];
        let mut b = [0i64; 3];
        let mut c = [0i64; 3];
        let mut bias = [0i64; 3];
        for i in 0..3 {
            let (s, e) = ((i + 1) % 3, (i + 2) % 3);
            let dx = x[e] - x[s];
            let dy = y[e] - y[s];
            a[i] = -dy;
            b[i] = dx;
            c[i] = dy * x[s] - dx * y[s];
            // Top-left rule (y down, this winding): left edges go up, top edges go right.
            let top_left = dy < 0 || (dy == 0 && dx > 0);
            bias[i] = if top_left { 0 } else { 1 };
        }
        Some(Setup {
            a,
            b,
            c,
            bias,
            x_range: (x_min, x_max),
            y_range: (y_min, y_max),
        })
    }

    /// Scan-converts one screen-space triangle (`x_px, y_px, 1/z` per vertex).
    pub(super) fn raster(&mut self, v: [[f32; 3]; 3], id: u32) {
        let Some(setup) = self.setup(v) else {
            return;
        };
        let ((x_min, x_max), (y_min, y_max)) = (setup.x_range, setup.y_range);
        // Most triangles that get here are sub-pixel: at most 2x2 candidate pixel centres.
        if x_max - x_min <= 1 && y_max - y_min <= 1 {
            self.fill_small(&setup, v, id);
        } else {
            self.fill_spans(&setup, v, id);
        }
    }

    /// Tests each candidate pixel centre directly (no span divisions) and fits the depth
    /// plane only once one is covered: the same pixels and the same depth arithmetic as
    /// [`Target::fill_spans`] (tested), cheaper for triangles of a pixel or two.
    fn fill_small(&mut self, s: &Setup, v: [[f32; 3]; 3], id: u32) {
        let one = 1i64 << SUB_BITS;
        let mut plane: Option<(f64, f64, f64)> = None;
        for py in s.y_range.0..=s.y_range.1 {
            // (first covered x, its row depth), as the span path's `z_row`.
            let mut row_start: Option<(i64, f64)> = None;
            for px in s.x_range.0..=s.x_range.1 {
                let (fx, fy) = (px * one, py * one);
                if (0..3).any(|i| s.a[i] * fx + s.b[i] * fy + s.c[i] < s.bias[i]) {
                    continue;
                }
                let (z0, dzdx, dzdy) = *plane.get_or_insert_with(|| depth_plane(v));
                let (x0, z_row) =
                    *row_start.get_or_insert((px, z0 + dzdy * py as f64 + dzdx * px as f64));
                let z = (z_row + dzdx * (px - x0) as f64) as f32;
                let i = py as usize * self.width + px as usize;
                if z > self.inv_z[i] {
                    self.inv_z[i] = z;
                    self.tri_id[i] = id;
                }
            }
        }
    }

    /// Fills each row's covered span, found with exact integer arithmetic.
    fn fill_spans(&mut self, s: &Setup, v: [[f32; 3]; 3], id: u32) {
        let one = 1i64 << SUB_BITS;
        let (x_min, x_max) = s.x_range;
        let (z0, dzdx, dzdy) = depth_plane(v);
        let step = s.a.map(|ai| ai * one);
        let last = x_max - x_min;
        for py in s.y_range.0..=s.y_range.1 {
            let fy = py * one;
            let fx = x_min * one;
            let e = [0usize, 1, 2].map(|i| s.a[i] * fx + s.b[i] * fy + s.c[i]);
            let Some((lo, hi)) = row_span(e, step, s.bias, last) else {
                continue;
            };
            let row = py as usize * self.width + x_min as usize;
            let span = row + lo as usize..=row + hi as usize;
            let zs = &mut self.inv_z[span.clone()];
            let ids = &mut self.tri_id[span];
            let z_row = z0 + dzdy * py as f64 + dzdx * (x_min + lo) as f64;
            for (k, (zp, idp)) in zs.iter_mut().zip(ids.iter_mut()).enumerate() {
                let z = (z_row + dzdx * k as f64) as f32;
                if z > *zp {
                    *zp = z;
                    *idp = id;
                }
            }
        }
    }
}

/// A triangle ready to fill: edge functions `E_i(p) = a p.x + b p.y + c` in 1/256 px
/// (covered where `E_i >= bias_i` for all three) and the pixel-centre box to scan.
struct Setup {
    a: [i64; 3],
    b: [i64; 3],
    c: [i64; 3],
    bias: [i64; 3],
    x_range: (i64, i64),
    y_range: (i64, i64),
}

/// 1/z is affine in screen space: its plane `(z0, d/dx, d/dy)` through the unsnapped
/// vertices (snapping decides coverage only, so depth stays exact to f32 rounding).
fn depth_plane(v: [[f32; 3]; 3]) -> (f64, f64, f64) {
    let (px, py) = (v.map(|p| f64::from(p[0])), v.map(|p| f64::from(p[1])));
    let wz = v.map(|p| f64::from(p[2]));
    let det = (px[1] - px[0]) * (py[2] - py[0]) - (px[2] - px[0]) * (py[1] - py[0]);
    let (dzdx, dzdy) = if det != 0.0 {
        (
            ((wz[1] - wz[0]) * (py[2] - py[0]) - (wz[2] - wz[0]) * (py[1] - py[0])) / det,
            ((px[1] - px[0]) * (wz[2] - wz[0]) - (px[2] - px[0]) * (wz[1] - wz[0])) / det,
        )
    } else {
        (0.0, 0.0)
    };
    (wz[0] - dzdx * px[0] - dzdy * py[0], dzdx, dzdy)
}

/// The pixels `k` in `0..=last` of a row where every edge function
/// `e[i] + step[i] * k >= bias[i]`, as an inclusive range (exact integer arithmetic, so
/// the same pixels as testing each one); `None` when there are none.
fn row_span(e: [i64; 3], step: [i64; 3], bias: [i64; 3], last: i64) -> Option<(i64, i64)> {
    let (mut lo, mut hi) = (0i64, last);
    for i in 0..3 {
        let need = bias[i] - e[i];
        match step[i].cmp(&0) {
            // k >= ceil(need / step)
            std::cmp::Ordering::Greater => lo = lo.max(-(-need).div_euclid(step[i])),
            // k <= floor(-need / -step)
            std::cmp::Ordering::Less => hi = hi.min((-need).div_euclid(-step[i])),
            std::cmp::Ordering::Equal => {
                if need > 0 {
                    return None;
                }
            }
        }
    }
    (lo <= hi).then_some((lo, hi))
}

#[cfg(test)]
mod span_tests {
    use super::row_span;

    #[test]
    fn row_span_matches_testing_every_pixel() {
        let mut state = 99u64;
        let mut next = |m: i64| {
            state = state
                .wrapping_mul(6_364_136_223_846_793_005)
                .wrapping_add(1_442_695_040_888_963_407);
            ((state >> 33) as i64 % (2 * m + 1)) - m
        };
        for _ in 0..20_000 {
            let e = [next(5000), next(5000), next(5000)];
            let step = [next(700), next(700), next(2)];
            let bias = [next(1).abs(), 0, 1];
            let last = next(30).abs();
            let brute: Vec<i64> = (0..=last)
                .filter(|&k| (0..3).all(|i| e[i] + step[i] * k >= bias[i]))
                .collect();
            let span = row_span(e, step, bias, last);
            match span {
                None => assert!(brute.is_empty(), "{e:?} {step:?} {bias:?} {last}"),
                Some((lo, hi)) => assert_eq!(brute, (lo..=hi).collect::<Vec<_>>()),
            }
        }
    }
}

#[cfg(test)]
mod fill_tests {
    use super::tests_support::{target, uniform_source};

    /// The direct test of a few pixel centres and the span fill write the same pixels with
    /// bit-identical depths, for random triangles of up to ~3 px with random depths, over
    /// a z-buffer already holding other triangles.
    #[test]
    fn small_fill_equals_span_fill() {
        let mut uniform = uniform_source(7u64);
        let (w, h) = (8, 8);
        let mut tested = 0;
        for t in 0..20_000u32 {
            let (cx, cy, size) = (
                1.0 + 5.0 * uniform(),
                1.0 + 5.0 * uniform(),
                3.0 * uniform(),
            );
            let v: [[f32; 3]; 3] = std::array::from_fn(|_| {
                [
                    cx + size * (uniform() - 0.5),
                    cy + size * (uniform() - 0.5),
                    0.2 + uniform(),
                ]
            });
            let base_z: Vec<f32> = (0..w * h).map(|_| 0.5 * uniform()).collect();
            let (mut za, mut zb) = (base_z.clone(), base_z);
            let (mut ia, mut ib) = (vec![u32::MAX; w * h], vec![u32::MAX; w * h]);
            let Some(setup) = target(&mut za, &mut ia, w, h).setup(v) else {
                continue;
            };
            target(&mut za, &mut ia, w, h).fill_small(&setup, v, t);
            target(&mut zb, &mut ib, w, h).fill_spans(&setup, v, t);
            assert_eq!(ia, ib, "triangle {t}: {v:?}");
            assert!(
                za.iter().zip(&zb).all(|(a, b)| a.to_bits() == b.to_bits()),
                "triangle {t}: {v:?}"
            );
            tested += 1;
        }
        assert!(tested > 5_000, "{tested}");
    }
}

#[cfg(test)]
mod prepass_tests {
    use super::tests_support::{target, uniform_source};
    use super::{centre_bounds, select_candidates};

    /// The integer pre-pass is conservative: every triangle that `Target::setup` keeps
    /// (so might cover a pixel centre) passes it. Random triangles of up to ~4 px, many of
    /// them with vertices a hair from pixel centres and image edges (where the snapping
    /// pad and the clamps matter), some reaching far outside the image.
    #[test]
    fn the_prepass_keeps_every_triangle_setup_keeps() {
        let mut uniform = uniform_source(11u64);
        let (w, h) = (12usize, 9usize);
        let (mut z, mut ids) = (vec![0.0f32; w * h], vec![u32::MAX; w * h]);
        let (mut kept, mut rejected) = (0, 0);
        for t in 0..200_000u32 {
            let (cx, cy) = (-3.0 + 18.0 * uniform(), -3.0 + 15.0 * uniform());
            let size = if t % 10 == 0 { 400.0 } else { 4.0 * uniform() };
            let mut v: [[f32; 3]; 3] = std::array::from_fn(|_| {
                [
                    cx + size * (uniform() - 0.5),
                    cy + size * (uniform() - 0.5),
                    0.2 + uniform(),
                ]
            });
            if t % 3 == 0 {
                // Move one vertex to within 1/256 px of a pixel centre.
                let j = (t as usize / 3) % 3;
                let nudge = (uniform() - 0.5) * (2.0 / 256.0);
                v[j][0] = v[j][0].round() + nudge;
                v[j][1] = v[j][1].round() - nudge;
            }
            let screen = v.to_vec();
            let mut centres = vec![[0i16; 4]; 3];
            centre_bounds(&screen, (w, h), &mut centres);
            let mut out = Vec::new();
            select_candidates(&[[0, 1, 2]], t, &centres, (w, h), &mut out);
            let passes = out == [t];
            let keeps = target(&mut z, &mut ids, w, h).setup(v).is_some();
            assert!(passes || !keeps, "triangle {t}: {v:?}, bounds {centres:?}");
            if passes && !keeps {
                rejected += 1;
            }
            kept += usize::from(keeps);
        }
        // The test must see both outcomes in numbers.
        assert!(kept > 20_000, "{kept}");
        assert!(rejected > 1_000, "{rejected}");
    }

    /// Vertices before the near plane (negative 1/z) or off any scale get the widest
    /// bounds, so their triangles always reach the clipping path.
    #[test]
    fn vertices_before_the_near_plane_always_pass() {
        let (w, h) = (16usize, 16usize);
        let screen = [
            [1e9, 1e9, 0.5],
            [f32::NAN, f32::NAN, -1.0],
            [-1e9, 3.0, 0.5],
            [2e9, 5e8, 0.5],
        ];
        let mut centres = vec![[0i16; 4]; 4];
        centre_bounds(&screen, (w, h), &mut centres);
        assert_eq!(centres[1], [-1, -16, -1, -16]);
        let mut out = Vec::new();
        // Far off the image on the right: rejected; through a near-plane vertex: kept.
        select_candidates(&[[0, 3, 0], [0, 1, 3]], 5, &centres, (w, h), &mut out);
        assert_eq!(out, [6]);
    }
}

#[cfg(test)]
pub(super) mod tests_support {
    use super::Target;

    /// Uniform numbers in [0, 1) from a fixed seed (a 64-bit LCG's top 24 bits).
    pub(in crate::render) fn uniform_source(seed: u64) -> impl FnMut() -> f32 {
        let mut state = seed;
        move || {
            state = state
                .wrapping_mul(6_364_136_223_846_793_005)
                .wrapping_add(1_442_695_040_888_963_407);
            (state >> 40) as f32 / (1u64 << 24) as f32
        }
    }

    /// A z-buffer target over caller buffers, without back-face culling.
    pub(in crate::render) fn target<'a>(
        inv_z: &'a mut [f32],
        tri_id: &'a mut [u32],
        width: usize,
        height: usize,
    ) -> Target<'a> {
        Target {
            inv_z,
            tri_id,
            width,
            height,
            cull_back_faces: false,
        }
    }
}
