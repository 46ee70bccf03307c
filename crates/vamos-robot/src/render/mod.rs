//! Rendering the robot's own body as the camera sees it: body mask, depth and the exact
//! expected body flow between two joint states (REFERENCE.md section 2).
//!
//! Inputs are the shared robot types: [`LinkMesh`] (a link's visual mesh in that link's
//! frame, metres), [`Intrinsics`] (pinhole `K` at the processing resolution, optical
//! frame: z forward, x right, y down) and poses as `Isometry3<f64>`:
//! `base_from_link[i]` for every link index and `camera_from_base` (optical camera frame),
//! grouped in a [`RobotView`].
//!
//! # Back-ends
//! [`BodyRenderer`] is the back-end trait: [`BodyRenderer::prepare`] uploads the meshes
//! once per robot, [`BodyRenderer::render`] draws one frame from the link transforms into
//! a caller-owned [`RenderOutput`] whose buffers are reused from frame to frame.
//! [`CpuRenderer`] is a z-buffer rasteriser written for this crate (see [`cpu`]); it is
//! single-threaded on purpose: the service renders for many robots at once, one frame per
//! worker, and a frame at 320x240 is far too small to amortise fork/join. With the cargo
//! feature `wgpu`, `gpu::WgpuRenderer` draws the same outputs in one headless wgpu render
//! pass (see the `gpu` module); without it `backend = "wgpu"` is a
//! [`RenderError::BackendUnavailable`]. `backend = "auto"` considers the wgpu back-end only
//! when the feature is built and wgpu's adapter is a hardware GPU (discrete or integrated),
//! and then times both on the robot's first frames and keeps the faster
//! ([`auto::AutoRenderer`]); a software adapter such as Mesa's lavapipe is slower than the
//! CPU rasteriser (see `benches/README.md`), so there it is the CPU rasteriser.
//!
//! # Conventions of [`RenderOutput`]
//! - **Pixel grid**: pixel `(x, y)` is the pixel whose centre is at `(x, y)` in the
//!   [`Intrinsics`] convention (centre of the top-left pixel at `(0, 0)`). A pixel is robot
//!   when a triangle covers its centre (top-left fill rule: a centre on an edge shared by
//!   two triangles belongs to exactly one).
//! - **Which frame is drawn**: the frame chosen by [`FlowGrid`]. The default,
//!   [`FlowGrid::Target`], draws the robot at the *current* time `t` — the target frame of
//!   the observed flow `t-1 -> t` — so one render per frame gives both the target-frame
//!   mask that REFERENCE.md's masked-flow variants use and the expected flow for `e_b`.
//!   [`FlowGrid::Source`] draws it at `t-1` instead, the grid on which the observed flow
//!   is indexed.
//! - **Flow** (`flow`): forward flow `t-1 -> t` in pixels, the convention of
//!   [`FlowField`] and of [`vamos_vision::flow::tvl1`]`(frame_{t-1}, frame_t)`, so it is
//!   directly comparable with the observed TV-L1 flow. For [`FlowGrid::Target`] the vector
//!   stored at pixel `(x, y)` of frame `t` is the motion of the surface point seen there:
//!   `(x, y) - project_{t-1}(P)`, where `P` is that point carried back rigidly with its
//!   link to time `t-1`; i.e. the flow vector *ends* at `(x, y)`. For [`FlowGrid::Source`]
//!   the vector at pixel `(x, y)` of frame `t-1` *starts* there: `project_t(P) - (x, y)`,
//!   exactly how TV-L1 indexes its output. The two differ by where each vector is filed
//!   (a shift of one flow vector, sub-pixel to a few pixels), which does not matter to
//!   `e_b`'s medians over the body; the body is rigid per link, so the field is exact
//!   (the 3-D point is recovered from the pixel and the rendered depth, and the depth
//!   comes from perspective-correct interpolation of `1/z`). `NaN` where the pixel is not
//!   covered, where no previous view was given, or where the point is behind the other
//!   camera.
//! - **Depth** (`depth_m`): metres along the optical axis (`z` of the optical frame) of the
//!   nearest robot surface at the pixel centre; `+inf` where there is no robot.
//! - **Mask** (`mask`): `coverage` grown by [`RenderConfig::mask_margin_px`] pixels: a
//!   pixel is in the mask when a covered pixel lies within that Euclidean distance (a disc,
//!   so a margin of 2 turns one pixel into 13). The paper grows the robot silhouette by
//!   about 2 px to absorb calibration and rendering error.
//! - **Link** (`link`): the link index drawn at each pixel, [`NO_LINK`] where none.
//! - **Gray** (`gray`): optional shaded rendering as in the paper (white background 255,
//!   robot 38..217 by the angle between the face normal and the optical axis, i.e. a
//!   headlight at infinity: constant over a flat face, so a moving face keeps its
//!   brightness), the input to
//!   [`tvl1_body_flow`], the paper's variant of the expected flow.
//!
//! # Near plane
//! Geometry in front of the camera closer than [`RenderConfig::near_m`] is clipped away
//! (triangles crossing the plane are cut, not dropped). Vertices that project further than
//! [`cpu::GUARD_BAND_PX`] from the image are outside the rasteriser's fixed-point range and
//! their triangles are skipped (with the default near plane this needs a vertex about
//! 100 m off-axis).
//!
//! This module imports only [`vamos_vision`] (images, flow fields, TV-L1) and the robot
//! module's shared types.

#[cfg(feature = "wgpu")]
pub mod auto;
pub mod cpu;
#[cfg(feature = "wgpu")]
pub mod gpu;
#[cfg(all(test, feature = "wgpu"))]
mod gpu_tests;
mod mask;
pub mod shapes;
pub mod simplify;
#[cfg(test)]
mod tests;

pub use cpu::CpuRenderer;
#[cfg(feature = "wgpu")]
pub use gpu::WgpuRenderer;

use crate::camera::Intrinsics;
use crate::geometry::LinkMesh;
use nalgebra::Isometry3;
use serde::{Deserialize, Serialize};
use vamos_vision::flow::{FlowError, FlowParams, tvl1};
use vamos_vision::image::{FlowField, GrayImage};

/// The value of [`RenderOutput::link`] where no robot is drawn.
pub const NO_LINK: u32 = u32::MAX;

/// Errors of preparing and rendering.
#[derive(Debug, PartialEq, thiserror::Error)]
pub enum RenderError {
    /// The intrinsics describe an empty image or hold invalid values.
    #[error("invalid intrinsics: {0}")]
    Intrinsics(#[from] crate::camera::IntrinsicsError),
    /// A mesh triangle refers to a vertex that does not exist.
    #[error(
        "mesh {mesh} (link {link}): triangle {triangle} uses vertex {index}, but the mesh has {vertex_count} vertices"
    )]
    IndexOutOfRange {
        /// Position of the mesh in the list given to `prepare`.
        mesh: usize,
        /// Its link index.
        link: usize,
        /// The triangle.
        triangle: usize,
        /// The offending vertex index.
        index: u32,
        /// Vertices in the mesh.
        vertex_count: usize,
    },
    /// A mesh vertex is NaN or infinite.
    #[error("mesh {mesh} (link {link}): vertex {vertex} is not finite")]
    NonFiniteVertex {
        /// Position of the mesh in the list given to `prepare`.
        mesh: usize,
        /// Its link index.
        link: usize,
        /// The offending vertex.
        vertex: usize,
    },
    /// The meshes together have more vertices or triangles than the renderer indexes.
    #[error("meshes are too large: {count} {what} (at most {max})")]
    TooLarge {
        /// "vertices" or "triangles".
        what: &'static str,
        /// How many there are.
        count: usize,
        /// The limit.
        max: usize,
    },
    /// A prepared mesh belongs to a link for which no pose was given.
    #[error(
        "a mesh is attached to link {link} but the {which} view has poses for {link_count} links"
    )]
    LinkOutOfRange {
        /// The link index of the mesh.
        link: usize,
        /// Number of `base_from_link` poses given.
        link_count: usize,
        /// "current" or "previous".
        which: &'static str,
    },
    /// A pose is NaN or infinite.
    #[error("{which} view: pose {pose} is not finite")]
    NonFinitePose {
        /// "current" or "previous".
        which: &'static str,
        /// "camera_from_base" or "base_from_link[i]".
        pose: String,
    },
    /// A setting is out of range.
    #[error("invalid render setting {name} = {value}: {reason}")]
    BadConfig {
        /// The setting.
        name: &'static str,
        /// Its value.
        value: String,
        /// What is allowed.
        reason: &'static str,
    },
    /// The requested back-end is not built into this binary or has no device.
    #[error("render back-end {backend:?} is not available: {reason}")]
    BackendUnavailable {
        /// The requested back-end.
        backend: RenderBackend,
        /// Why.
        reason: &'static str,
    },
    /// TV-L1 on the rendered images failed.
    #[error("flow of the rendered images: {0}")]
    Flow(#[from] FlowError),
}

/// Which renderer draws the body.
#[derive(
    Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize, schemars::JsonSchema,
)]
#[serde(rename_all = "snake_case")]
pub enum RenderBackend {
    /// With the `wgpu` feature and a hardware GPU adapter: both back-ends, the first
    /// frames timed on each, then the faster ([`auto::AutoRenderer`]). Otherwise (no
    /// feature, no adapter, or a software one such as lavapipe, measured 4-15x slower
    /// than the CPU rasteriser) the CPU rasteriser.
    #[default]
    Auto,
    /// The CPU z-buffer rasteriser.
    Cpu,
    /// The wgpu renderer (cargo feature `wgpu`; an error without it or without an
    /// adapter).
    Wgpu,
}

/// Which frame's pixel grid the render (mask, depth, flow) lives on; see the module docs.
#[derive(
    Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize, schemars::JsonSchema,
)]
#[serde(rename_all = "snake_case")]
pub enum FlowGrid {
    /// Draw at the current time `t` (the target frame of the flow `t-1 -> t`); the flow
    /// vector at a pixel ends there.
    #[default]
    Target,
    /// Draw at the previous time `t-1`; the flow vector at a pixel starts there (the
    /// indexing of TV-L1's output).
    Source,
}

/// The `[render]` settings section: how the robot body is rendered.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(default, deny_unknown_fields)]
pub struct RenderConfig {
    /// Back-end: `auto`, `cpu` or `wgpu`.
    pub backend: RenderBackend,
    /// Growth of the body mask around the rendered silhouette, pixels (Euclidean). The
    /// paper uses about 2 px.
    pub mask_margin_px: u32,
    /// Near clipping plane, metres in front of the camera (> 0).
    pub near_m: f64,
    /// Which frame's pixel grid the render lives on (`target` = time `t`, `source` =
    /// time `t-1`).
    pub flow_grid: FlowGrid,
    /// Skip triangles seen from behind. Only safe for closed meshes with outward
    /// counter-clockwise winding: open or inconsistently wound meshes (common in URDF
    /// visual meshes) lose faces. Saves little at low resolutions; off by default.
    pub cull_back_faces: bool,
    /// Render-time simplification by vertex clustering, metres: at `prepare`, vertices of
    /// each mesh that fall into the same cube of this side (in the link frame) merge into
    /// their mean and collapsed triangles are dropped, so no surface point moves by more
    /// than `sqrt(3)` x this. 0 = off. Pick it from the resolution: a fraction of a pixel
    /// at the nearest expected distance, `cell = fraction x distance / fx` (0.5 px at 0.5 m
    /// with fx = 340 px: 0.7 mm).
    pub simplify_cell_m: f64,
}

impl Default for RenderConfig {
    fn default() -> Self {
        Self {
            backend: RenderBackend::Auto,
            mask_margin_px: 2,
            near_m: 0.05,
            flow_grid: FlowGrid::Target,
            cull_back_faces: false,
            simplify_cell_m: 0.0,
        }
    }
}

impl RenderConfig {
    /// Checks ranges.
    pub fn validate(&self) -> Result<(), RenderError> {
        if !(self.near_m.is_finite() && self.near_m > 0.0) {
            return Err(RenderError::BadConfig {
                name: "near_m",
                value: self.near_m.to_string(),
                reason: "must be a positive number of metres",
            });
        }
        if !(self.simplify_cell_m.is_finite() && self.simplify_cell_m >= 0.0) {
            return Err(RenderError::BadConfig {
                name: "simplify_cell_m",
                value: self.simplify_cell_m.to_string(),
                reason: "must be 0 (off) or a positive number of metres",
            });
        }
        if self.mask_margin_px > MAX_MASK_MARGIN_PX {
            return Err(RenderError::BadConfig {
                name: "mask_margin_px",
                value: self.mask_margin_px.to_string(),
                reason: "must be at most 64 pixels",
            });
        }
        Ok(())
    }
}

/// Largest accepted [`RenderConfig::mask_margin_px`].
pub const MAX_MASK_MARGIN_PX: u32 = 64;

/// The robot at one instant as one camera sees it.
#[derive(Debug, Clone, Copy)]
pub struct RobotView<'a> {
    /// Optical camera frame from the robot base.
    pub camera_from_base: Isometry3<f64>,
    /// Pose of every link in the base frame, indexed by link index.
    pub base_from_link: &'a [Isometry3<f64>],
}

impl RobotView<'_> {
    /// Checks that every pose is finite (`which` names the view in the error).
    pub fn validate(&self, which: &'static str) -> Result<(), RenderError> {
        if !pose_is_finite(&self.camera_from_base) {
            return Err(RenderError::NonFinitePose {
                which,
                pose: "camera_from_base".into(),
            });
        }
        if let Some(i) = self.base_from_link.iter().position(|p| !pose_is_finite(p)) {
            return Err(RenderError::NonFinitePose {
                which,
                pose: format!("base_from_link[{i}]"),
            });
        }
        Ok(())
    }
}

fn pose_is_finite(p: &Isometry3<f64>) -> bool {
    p.translation.vector.iter().all(|v| v.is_finite())
        && p.rotation.coords.iter().all(|v| v.is_finite())
}

/// One frame to render.
#[derive(Debug, Clone, Copy)]
pub struct RenderFrame<'a> {
    /// Camera at the processing resolution.
    pub intrinsics: &'a Intrinsics,
    /// The robot at time `t`.
    pub current: RobotView<'a>,
    /// The robot at time `t-1`; `None` renders without flow (the flow is all `NaN` and
    /// the drawn frame is `current` whatever [`RenderConfig::flow_grid`] says).
    pub previous: Option<RobotView<'a>>,
    /// Also produce the shaded gray image ([`RenderOutput::gray`]).
    pub shade: bool,
}

/// What a render produces; buffers are reused across frames. See the module docs for the
/// conventions (pixel grid, depth encoding, mask margin).
#[derive(Debug, Clone, PartialEq)]
pub struct RenderOutput {
    /// Image width, pixels.
    pub width: usize,
    /// Image height, pixels.
    pub height: usize,
    /// Pixels whose centre a robot triangle covers, row-major.
    pub coverage: Vec<bool>,
    /// `coverage` grown by the mask margin: the body mask.
    pub mask: Vec<bool>,
    /// Depth along the optical axis, metres; `+inf` where there is no robot.
    pub depth_m: Vec<f32>,
    /// Link index drawn at each pixel; [`NO_LINK`] where none.
    pub link: Vec<u32>,
    /// Expected forward body flow `t-1 -> t`, pixels; `NaN` where undefined.
    pub flow: FlowField,
    /// Shaded gray rendering (0..255, white background) when requested.
    pub gray: Option<GrayImage>,
}

impl Default for RenderOutput {
    fn default() -> Self {
        Self {
            width: 0,
            height: 0,
            coverage: Vec::new(),
            mask: Vec::new(),
            depth_m: Vec::new(),
            link: Vec::new(),
            flow: FlowField::zeros(0, 0),
            gray: None,
        }
    }
}

impl RenderOutput {
    /// Sizes the buffers for a `width x height` frame (allocations reused) and clears them
    /// to "no robot": coverage false, depth `+inf`, link [`NO_LINK`], flow `NaN`.
    pub(crate) fn reset(&mut self, width: usize, height: usize) {
        let n = width * height;
        self.width = width;
        self.height = height;
        self.coverage.clear();
        self.coverage.resize(n, false);
        self.depth_m.clear();
        self.depth_m.resize(n, f32::INFINITY);
        self.link.clear();
        self.link.resize(n, NO_LINK);
        if self.flow.size() != (width, height) {
            self.flow = FlowField::zeros(width, height);
        }
        self.flow.u.fill(f32::NAN);
        self.flow.v.fill(f32::NAN);
    }

    /// Number of covered (robot) pixels.
    pub fn covered_pixels(&self) -> usize {
        self.coverage.iter().filter(|&&c| c).count()
    }

    /// Number of mask pixels.
    pub fn mask_pixels(&self) -> usize {
        self.mask.iter().filter(|&&c| c).count()
    }
}

/// A body renderer back-end.
pub trait BodyRenderer: Send {
    /// Takes the robot's meshes (once per robot; replaces earlier meshes). Validates
    /// indices and vertices.
    fn prepare(&mut self, meshes: &[LinkMesh]) -> Result<(), RenderError>;

    /// Renders one frame into `out` (resized as needed; its buffers are reused).
    fn render(
        &mut self,
        frame: &RenderFrame<'_>,
        out: &mut RenderOutput,
    ) -> Result<(), RenderError>;

    /// Short name of the back-end, for logs.
    fn name(&self) -> &'static str;
}

/// The renderer `config` asks for (see [`RenderBackend`]). With the `wgpu` feature,
/// `auto` probes wgpu's default adapter (instance creation, ~0.3 s, once per process).
pub fn create_renderer(config: &RenderConfig) -> Result<Box<dyn BodyRenderer>, RenderError> {
    config.validate()?;
    match config.backend {
        RenderBackend::Cpu => Ok(Box::new(CpuRenderer::new(config)?)),
        #[cfg(feature = "wgpu")]
        RenderBackend::Auto => {
            // A software adapter (lavapipe, llvmpipe: device type Cpu) is slower than the
            // CPU rasteriser (benches/README.md); a hardware GPU is timed against it on
            // the first frames.
            let cpu = CpuRenderer::new(config)?;
            match gpu::default_adapter_type() {
                Some(wgpu::DeviceType::DiscreteGpu | wgpu::DeviceType::IntegratedGpu) => {
                    match WgpuRenderer::new(config) {
                        Ok(g) => Ok(Box::new(auto::AutoRenderer::new(cpu, Some(g)))),
                        Err(e) => {
                            tracing::warn!(error = %e, "render.backend auto: the GPU adapter cannot be used; using the CPU rasteriser");
                            Ok(Box::new(cpu))
                        }
                    }
                }
                _ => Ok(Box::new(cpu)),
            }
        }
        #[cfg(not(feature = "wgpu"))]
        RenderBackend::Auto => Ok(Box::new(CpuRenderer::new(config)?)),
        #[cfg(feature = "wgpu")]
        RenderBackend::Wgpu => Ok(Box::new(WgpuRenderer::new(config)?)),
        #[cfg(not(feature = "wgpu"))]
        RenderBackend::Wgpu => Err(RenderError::BackendUnavailable {
            backend: RenderBackend::Wgpu,
            reason: "this build has no GPU back-end (build with --features wgpu); use backend = \"cpu\" or \"auto\"",
        }),
    }
}

/// The paper's expected body flow: renders shaded gray images of the robot at `t-1` and
/// `t` (white background) and runs TV-L1 from the first to the second. Returns the flow
/// (on the grid of frame `t-1`, as TV-L1 indexes it) and the render at `t` (its mask is the
/// target-frame mask). `scratch` holds the `t-1` render.
pub fn tvl1_body_flow(
    renderer: &mut dyn BodyRenderer,
    intrinsics: &Intrinsics,
    previous: RobotView<'_>,
    current: RobotView<'_>,
    params: &FlowParams,
    scratch: &mut RenderOutput,
    out: &mut RenderOutput,
) -> Result<FlowField, RenderError> {
    for (view, target) in [(previous, &mut *scratch), (current, &mut *out)] {
        renderer.render(
            &RenderFrame {
                intrinsics,
                current: view,
                previous: None,
                shade: true,
            },
            target,
        )?;
    }
    let (Some(a), Some(b)) = (&scratch.gray, &out.gray) else {
        // Invariant: render with `shade: true` always fills `gray`.
        return Err(RenderError::BackendUnavailable {
            backend: RenderBackend::Auto,
            reason: "the back-end did not produce a gray image",
        });
    };
    Ok(tvl1(a, b, params)?)
}
