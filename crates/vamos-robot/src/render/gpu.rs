//! The GPU back-end through wgpu (cargo feature `wgpu`): one headless render pass per
//! frame.
//!
//! A headless device is created once ([`WgpuRenderer::new`], no window or surface; the
//! primary back-ends, i.e. Vulkan where the `vulkan` wgpu feature is built). `prepare`
//! validates and (optionally) simplifies the meshes exactly as [`CpuRenderer`] does (it
//! reuses its preparation) and uploads them once: a vertex buffer of link-frame positions
//! with the index of the vertex's mesh group, and an index buffer. Per frame only a
//! storage buffer of per-group transforms (`camera_from_link` of the drawn view and of
//! the other view, f32 4x4) and a uniform block of intrinsics are written.
//!
//! The vertex shader projects with `K` (pixel `(0, 0)` centred at `(0, 0)`, so framebuffer
//! coordinates are pixel + 0.5) and reversed depth (`z_ndc = near / z`, which clips at
//! the near plane); it passes the camera-space position of the vertex in both views as
//! perspective-correct varyings. The fragment shader, at pixel centre `(x, y)`, writes
//! into an `Rgba32Float` target: the flow from the other view's position projected per
//! fragment (exact for rigid links: camera-space position is affine over a triangle),
//! the depth `z`, and the link index + 1, negated when the flow is undefined (no previous
//! view, or the point behind the other camera); 0 is the background. The target is copied
//! into a staging buffer (rows padded to 256 bytes) and unpacked into [`RenderOutput`];
//! the mask is grown by the shared CPU routine.
//!
//! [`RenderFrame::shade`] (the gray image) is drawn by the embedded [`CpuRenderer`]: the
//! whole frame is then rendered on the CPU (the shaded image only feeds the paper's TV-L1
//! variant, which is far slower than the render itself).
//!
//! The pixel coverage follows the GPU's rasterisation rules (top-left fill rule, sub-pixel
//! snapping of the driver), which agree with the CPU rasteriser except on a few edge
//! pixels; triangles far outside the view are clipped by the GPU rather than skipped.

use super::cpu::CpuRenderer;
use super::mask::grow_mask;
use super::{
    BodyRenderer, FlowGrid, RenderBackend, RenderConfig, RenderError, RenderFrame, RenderOutput,
};
use crate::geometry::LinkMesh;
use nalgebra::{Isometry3, Matrix4};

const SHADER: &str = r#"
struct Params {
    // fx, fy, cx, cy
    k: vec4<f32>,
    // width, height, near_m, has_other (0 or 1)
    size: vec4<f32>,
    // 1 for the target grid (flow ends at the pixel), -1 for the source grid
    sign: vec4<f32>,
};

@group(0) @binding(0) var<uniform> params: Params;
// Per mesh group: [2g] camera_from_link of the drawn view, [2g + 1] of the other view.
@group(0) @binding(1) var<storage, read> transforms: array<mat4x4<f32>>;

struct VertexOut {
    @builtin(position) clip: vec4<f32>,
    @location(0) shown: vec3<f32>,
    @location(1) other: vec3<f32>,
    @location(2) @interpolate(flat) link: u32,
};

@vertex
fn vs_main(@location(0) position: vec3<f32>, @location(1) group: vec2<u32>) -> VertexOut {
    let p = vec4<f32>(position, 1.0);
    let c = (transforms[2u * group.x] * p).xyz;
    let o = (transforms[2u * group.x + 1u] * p).xyz;
    let w = params.size.x;
    let h = params.size.y;
    // Framebuffer x = fx * x / z + cx + 0.5; NDC x = 2 fb_x / w - 1 (y flipped).
    let fb_x = params.k.x * c.x + (params.k.z + 0.5) * c.z;
    let fb_y = params.k.y * c.y + (params.k.w + 0.5) * c.z;
    var out: VertexOut;
    out.clip = vec4<f32>(2.0 * fb_x / w - c.z, c.z - 2.0 * fb_y / h, params.size.z, c.z);
    out.shown = c;
    out.other = o;
    out.link = group.y;
    return out;
}

@fragment
fn fs_main(v: VertexOut) -> @location(0) vec4<f32> {
    let x = v.clip.x - 0.5;
    let y = v.clip.y - 0.5;
    let code = f32(v.link) + 1.0;
    let o = v.other;
    if (params.size.w < 0.5 || o.z <= 0.0) {
        return vec4<f32>(0.0, 0.0, v.shown.z, -code);
    }
    let qx = params.k.x * o.x / o.z + params.k.z;
    let qy = params.k.y * o.y / o.z + params.k.w;
    let s = params.sign.x;
    return vec4<f32>(s * (x - qx), s * (y - qy), v.shown.z, code);
}
"#;

/// Bytes of one texel of the `Rgba32Float` target.
const TEXEL_BYTES: u32 = 16;
const TARGET_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Rgba32Float;
const DEPTH_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Depth32Float;

/// Offscreen targets and their staging buffer for one image size.
struct Targets {
    width: u32,
    height: u32,
    padded_row_bytes: u32,
    color: wgpu::Texture,
    color_view: wgpu::TextureView,
    depth_view: wgpu::TextureView,
    staging: wgpu::Buffer,
}

/// Uploaded meshes.
struct Meshes {
    vertices: wgpu::Buffer,
    indices: wgpu::Buffer,
    index_count: u32,
    transforms: wgpu::Buffer,
    bind_group: wgpu::BindGroup,
    /// Link index of each mesh group.
    group_links: Vec<usize>,
}

/// The wgpu renderer (see the module docs).
pub struct WgpuRenderer {
    grid: FlowGrid,
    margin_px: u32,
    near_m: f32,
    /// Validates and simplifies in `prepare`, and draws shaded frames.
    cpu: CpuRenderer,
    adapter_info: wgpu::AdapterInfo,
    device: wgpu::Device,
    queue: wgpu::Queue,
    pipeline: wgpu::RenderPipeline,
    layout: wgpu::BindGroupLayout,
    params: wgpu::Buffer,
    meshes: Option<Meshes>,
    targets: Option<Targets>,
    transform_scratch: Vec<f32>,
    mask_scratch: Vec<u8>,
}

impl std::fmt::Debug for WgpuRenderer {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("WgpuRenderer")
            .field("adapter", &self.adapter_info.name)
            .field("device_type", &self.adapter_info.device_type)
            .field("grid", &self.grid)
            .finish_non_exhaustive()
    }
}

/// Why no adapter could be used.
const NO_ADAPTER: &str = "no usable wgpu adapter (a Vulkan driver is needed; on a machine \
without a GPU install Mesa lavapipe: apt-get install mesa-vulkan-drivers libvulkan1)";

fn instance() -> wgpu::Instance {
    let mut desc = wgpu::InstanceDescriptor::new_without_display_handle();
    desc.backends = wgpu::Backends::PRIMARY;
    wgpu::Instance::new(desc.with_env())
}

/// Headless: no surface; a discrete GPU before an integrated or software one.
fn adapter_options() -> wgpu::RequestAdapterOptions<'static, 'static> {
    wgpu::RequestAdapterOptions {
        power_preference: wgpu::PowerPreference::HighPerformance,
        ..Default::default()
    }
}

/// Whether the adapter can render into the `Rgba32Float` target.
fn adapter_is_usable(adapter: &wgpu::Adapter) -> bool {
    adapter
        .get_texture_format_features(TARGET_FORMAT)
        .allowed_usages
        .contains(wgpu::TextureUsages::RENDER_ATTACHMENT | wgpu::TextureUsages::COPY_SRC)
}

/// The kind of device wgpu would render on (`None` when there is no usable adapter):
/// e.g. `Cpu` for Mesa's lavapipe, `DiscreteGpu` for a graphics card. Probed once per
/// process (instance creation costs ~0.3 s), so `render.backend = "auto"` costs nothing
/// per session after the first.
pub fn default_adapter_type() -> Option<wgpu::DeviceType> {
    static PROBED: std::sync::OnceLock<Option<wgpu::DeviceType>> = std::sync::OnceLock::new();
    *PROBED.get_or_init(|| {
        let instance = instance();
        let adapter = pollster::block_on(instance.request_adapter(&adapter_options())).ok()?;
        adapter_is_usable(&adapter).then(|| adapter.get_info().device_type)
    })
}

impl WgpuRenderer {
    /// Creates the headless device and pipeline. [`RenderError::BackendUnavailable`] when
    /// no adapter can render into 32-bit float targets.
    pub fn new(config: &RenderConfig) -> Result<Self, RenderError> {
        let cpu = CpuRenderer::new(config)?;
        let unavailable = |reason| RenderError::BackendUnavailable {
            backend: RenderBackend::Wgpu,
            reason,
        };
        let instance = instance();
        let adapter = pollster::block_on(instance.request_adapter(&adapter_options()))
            .map_err(|_| unavailable(NO_ADAPTER))?;
        if !adapter_is_usable(&adapter) {
            return Err(unavailable(
                "the wgpu adapter cannot render into Rgba32Float targets",
            ));
        }
        let (device, queue) = pollster::block_on(adapter.request_device(&wgpu::DeviceDescriptor {
            label: Some("vamos body renderer"),
            required_limits: adapter.limits(),
            ..Default::default()
        }))
        .map_err(|_| unavailable("the wgpu adapter refused to create a device"))?;
        let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("body"),
            source: wgpu::ShaderSource::Wgsl(SHADER.into()),
        });
        let layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("body"),
            entries: &[
                wgpu::BindGroupLayoutEntry {
                    binding: 0,
                    visibility: wgpu::ShaderStages::VERTEX_FRAGMENT,
                    ty: wgpu::BindingType::Buffer {
                        ty: wgpu::BufferBindingType::Uniform,
                        has_dynamic_offset: false,
                        min_binding_size: None,
                    },
                    count: None,
                },
                wgpu::BindGroupLayoutEntry {
                    binding: 1,
                    visibility: wgpu::ShaderStages::VERTEX,
                    ty: wgpu::BindingType::Buffer {
                        ty: wgpu::BufferBindingType::Storage { read_only: true },
                        has_dynamic_offset: false,
                        min_binding_size: None,
                    },
                    count: None,
                },
            ],
        });
        let pipeline_layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("body"),
            bind_group_layouts: &[Some(&layout)],
            immediate_size: 0,
        });
        let vertex_attributes = wgpu::vertex_attr_array![0 => Float32x3, 1 => Uint32x2];
        let pipeline = device.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
            label: Some("body"),
            layout: Some(&pipeline_layout),
            vertex: wgpu::VertexState {
                module: &module,
                entry_point: Some("vs_main"),
                compilation_options: Default::default(),
                buffers: &[Some(wgpu::VertexBufferLayout {
                    array_stride: 20,
                    step_mode: wgpu::VertexStepMode::Vertex,
                    attributes: &vertex_attributes,
                })],
            },
            primitive: wgpu::PrimitiveState {
                topology: wgpu::PrimitiveTopology::TriangleList,
                // Counter-clockwise as seen in the image is front (the CPU convention).
                front_face: wgpu::FrontFace::Ccw,
                cull_mode: config.cull_back_faces.then_some(wgpu::Face::Back),
                ..Default::default()
            },
            depth_stencil: Some(wgpu::DepthStencilState {
                format: DEPTH_FORMAT,
                depth_write_enabled: Some(true),
                // Reversed depth: near / z, larger is nearer.
                depth_compare: Some(wgpu::CompareFunction::Greater),
                stencil: Default::default(),
                bias: Default::default(),
            }),
            multisample: Default::default(),
            fragment: Some(wgpu::FragmentState {
                module: &module,
                entry_point: Some("fs_main"),
                compilation_options: Default::default(),
                targets: &[Some(wgpu::ColorTargetState {
                    format: TARGET_FORMAT,
                    blend: None,
                    write_mask: wgpu::ColorWrites::ALL,
                })],
            }),
            multiview_mask: None,
            cache: None,
        });
        let params = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("params"),
            size: 48,
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        Ok(Self {
            grid: config.flow_grid,
            margin_px: config.mask_margin_px,
            near_m: config.near_m as f32,
            cpu,
            adapter_info: adapter.get_info(),
            device,
            queue,
            pipeline,
            layout,
            params,
            meshes: None,
            targets: None,
            transform_scratch: Vec::new(),
            mask_scratch: Vec::new(),
        })
    }

    /// Name of the adapter (e.g. "llvmpipe (LLVM 15.0.6, 256 bits)").
    pub fn adapter_name(&self) -> &str {
        &self.adapter_info.name
    }

    /// Kind of the adapter (`Cpu` for a software rasteriser such as lavapipe).
    pub fn adapter_type(&self) -> wgpu::DeviceType {
        self.adapter_info.device_type
    }

    fn targets(&mut self, width: u32, height: u32) -> Result<&Targets, RenderError> {
        let max = self.device.limits().max_texture_dimension_2d;
        if width > max || height > max {
            return Err(RenderError::BadConfig {
                name: "intrinsics.width/height",
                value: format!("{width}x{height}"),
                reason: "larger than the GPU's largest texture",
            });
        }
        let fits = self
            .targets
            .as_ref()
            .is_some_and(|t| t.width == width && t.height == height);
        if !fits {
            let size = wgpu::Extent3d {
                width,
                height,
                depth_or_array_layers: 1,
            };
            let texture = |label, format, usage| {
                self.device.create_texture(&wgpu::TextureDescriptor {
                    label: Some(label),
                    size,
                    mip_level_count: 1,
                    sample_count: 1,
                    dimension: wgpu::TextureDimension::D2,
                    format,
                    usage,
                    view_formats: &[],
                })
            };
            let color = texture(
                "flow-depth-link",
                TARGET_FORMAT,
                wgpu::TextureUsages::RENDER_ATTACHMENT | wgpu::TextureUsages::COPY_SRC,
            );
            let depth = texture(
                "z-buffer",
                DEPTH_FORMAT,
                wgpu::TextureUsages::RENDER_ATTACHMENT,
            );
            let align = wgpu::COPY_BYTES_PER_ROW_ALIGNMENT;
            let padded_row_bytes = (width * TEXEL_BYTES).div_ceil(align) * align;
            let staging = self.device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("readback"),
                size: u64::from(padded_row_bytes) * u64::from(height),
                usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
                mapped_at_creation: false,
            });
            self.targets = Some(Targets {
                width,
                height,
                padded_row_bytes,
                color_view: color.create_view(&Default::default()),
                depth_view: depth.create_view(&Default::default()),
                color,
                staging,
            });
        }
        self.targets
            .as_ref()
            .ok_or(RenderError::BackendUnavailable {
                backend: RenderBackend::Wgpu,
                reason: "render targets missing",
            })
    }
}

fn gpu_error(what: &'static str) -> RenderError {
    RenderError::BackendUnavailable {
        backend: RenderBackend::Wgpu,
        reason: what,
    }
}

/// `camera_from_link` as column-major f32 (the WGSL `mat4x4` layout).
fn push_matrix(out: &mut Vec<f32>, m: &Isometry3<f64>) {
    let h: Matrix4<f64> = m.to_homogeneous();
    out.extend(h.as_slice().iter().map(|&v| v as f32));
}

impl BodyRenderer for WgpuRenderer {
    fn prepare(&mut self, meshes: &[LinkMesh]) -> Result<(), RenderError> {
        use wgpu::util::DeviceExt;
        self.cpu.prepare(meshes)?;
        let (positions, triangles, groups) = self.cpu.prepared_geometry();
        let mut vertex_bytes = Vec::with_capacity(positions.len() * 20);
        for (g, (link, range)) in groups.iter().enumerate() {
            for p in &positions[range.clone()] {
                for c in p {
                    vertex_bytes.extend_from_slice(&c.to_le_bytes());
                }
                vertex_bytes.extend_from_slice(&(g as u32).to_le_bytes());
                vertex_bytes.extend_from_slice(&(*link as u32).to_le_bytes());
            }
        }
        let index_bytes: Vec<u8> = triangles
            .iter()
            .flatten()
            .flat_map(|i| i.to_le_bytes())
            .collect();
        let index_count =
            u32::try_from(triangles.len() * 3).map_err(|_| RenderError::TooLarge {
                what: "triangle indices",
                count: triangles.len() * 3,
                max: u32::MAX as usize,
            })?;
        if groups.is_empty() {
            self.meshes = None;
            return Ok(());
        }
        let vertices = self
            .device
            .create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some("vertices"),
                contents: &vertex_bytes,
                usage: wgpu::BufferUsages::VERTEX,
            });
        let indices = self
            .device
            .create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some("indices"),
                contents: &index_bytes,
                usage: wgpu::BufferUsages::INDEX,
            });
        let transforms = self.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("transforms"),
            size: (groups.len() * 2 * 64) as u64,
            usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let bind_group = self.device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("body"),
            layout: &self.layout,
            entries: &[
                wgpu::BindGroupEntry {
                    binding: 0,
                    resource: self.params.as_entire_binding(),
                },
                wgpu::BindGroupEntry {
                    binding: 1,
                    resource: transforms.as_entire_binding(),
                },
            ],
        });
        self.meshes = Some(Meshes {
            vertices,
            indices,
            index_count,
            transforms,
            bind_group,
            group_links: groups.iter().map(|(l, _)| *l).collect(),
        });
        Ok(())
    }

    fn render(
        &mut self,
        frame: &RenderFrame<'_>,
        out: &mut RenderOutput,
    ) -> Result<(), RenderError> {
        if frame.shade {
            return self.cpu.render(frame, out);
        }
        let k = frame.intrinsics;
        k.validate()?;
        self.cpu.check_links(&frame.current, "current")?;
        if let Some(prev) = &frame.previous {
            self.cpu.check_links(prev, "previous")?;
        }
        let (shown, other) = match (frame.previous, self.grid) {
            (None, _) => (frame.current, None),
            (Some(prev), FlowGrid::Target) => (frame.current, Some(prev)),
            (Some(prev), FlowGrid::Source) => (prev, Some(frame.current)),
        };
        let sign: f32 = if self.grid == FlowGrid::Source {
            -1.0
        } else {
            1.0
        };
        let (width, height) = (k.width, k.height);
        let padded_row_bytes = self.targets(width, height)?.padded_row_bytes;

        let params: [f32; 12] = [
            k.fx as f32,
            k.fy as f32,
            k.cx as f32,
            k.cy as f32,
            width as f32,
            height as f32,
            self.near_m,
            if other.is_some() { 1.0 } else { 0.0 },
            sign,
            0.0,
            0.0,
            0.0,
        ];
        let param_bytes: Vec<u8> = params.iter().flat_map(|v| v.to_le_bytes()).collect();
        self.queue.write_buffer(&self.params, 0, &param_bytes);
        if let Some(meshes) = &self.meshes {
            self.transform_scratch.clear();
            for &link in &meshes.group_links {
                let shown_from_link = shown.camera_from_base * shown.base_from_link[link];
                push_matrix(&mut self.transform_scratch, &shown_from_link);
                let other_from_link = match other {
                    Some(o) => o.camera_from_base * o.base_from_link[link],
                    None => shown_from_link,
                };
                push_matrix(&mut self.transform_scratch, &other_from_link);
            }
            let bytes: Vec<u8> = self
                .transform_scratch
                .iter()
                .flat_map(|v| v.to_le_bytes())
                .collect();
            self.queue.write_buffer(&meshes.transforms, 0, &bytes);
        }

        let Some(targets) = self.targets.as_ref() else {
            return Err(gpu_error("render targets missing"));
        };
        let mut encoder = self
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                label: Some("body"),
            });
        {
            let mut pass = encoder.begin_render_pass(&wgpu::RenderPassDescriptor {
                label: Some("body"),
                color_attachments: &[Some(wgpu::RenderPassColorAttachment {
                    view: &targets.color_view,
                    depth_slice: None,
                    resolve_target: None,
                    ops: wgpu::Operations {
                        load: wgpu::LoadOp::Clear(wgpu::Color::TRANSPARENT),
                        store: wgpu::StoreOp::Store,
                    },
                })],
                depth_stencil_attachment: Some(wgpu::RenderPassDepthStencilAttachment {
                    view: &targets.depth_view,
                    depth_ops: Some(wgpu::Operations {
                        load: wgpu::LoadOp::Clear(0.0),
                        store: wgpu::StoreOp::Discard,
                    }),
                    stencil_ops: None,
                }),
                timestamp_writes: None,
                occlusion_query_set: None,
                multiview_mask: None,
            });
            if let Some(meshes) = &self.meshes {
                pass.set_pipeline(&self.pipeline);
                pass.set_bind_group(0, &meshes.bind_group, &[]);
                pass.set_vertex_buffer(0, meshes.vertices.slice(..));
                pass.set_index_buffer(meshes.indices.slice(..), wgpu::IndexFormat::Uint32);
                pass.draw_indexed(0..meshes.index_count, 0, 0..1);
            }
        }
        encoder.copy_texture_to_buffer(
            wgpu::TexelCopyTextureInfo {
                texture: &targets.color,
                mip_level: 0,
                origin: wgpu::Origin3d::ZERO,
                aspect: wgpu::TextureAspect::All,
            },
            wgpu::TexelCopyBufferInfo {
                buffer: &targets.staging,
                layout: wgpu::TexelCopyBufferLayout {
                    offset: 0,
                    bytes_per_row: Some(padded_row_bytes),
                    rows_per_image: Some(height),
                },
            },
            wgpu::Extent3d {
                width,
                height,
                depth_or_array_layers: 1,
            },
        );
        self.queue.submit([encoder.finish()]);

        let slice = targets.staging.slice(..);
        let (tx, rx) = std::sync::mpsc::channel();
        slice.map_async(wgpu::MapMode::Read, move |r| {
            let _ = tx.send(r);
        });
        self.device
            .poll(wgpu::PollType::wait_indefinitely())
            .map_err(|_| gpu_error("the GPU did not finish the frame"))?;
        match rx.recv() {
            Ok(Ok(())) => {}
            _ => return Err(gpu_error("mapping the readback buffer failed")),
        }

        let (w, h) = (width as usize, height as usize);
        out.reset(w, h);
        out.gray = None;
        {
            let data = slice
                .get_mapped_range()
                .map_err(|_| gpu_error("reading the mapped readback buffer failed"))?;
            for y in 0..h {
                let row = &data[y * padded_row_bytes as usize..][..w * TEXEL_BYTES as usize];
                for (x, texel) in row.chunks_exact(TEXEL_BYTES as usize).enumerate() {
                    let f = |c: usize| {
                        f32::from_le_bytes([
                            texel[4 * c],
                            texel[4 * c + 1],
                            texel[4 * c + 2],
                            texel[4 * c + 3],
                        ])
                    };
                    let code = f(3);
                    if code == 0.0 {
                        continue;
                    }
                    let i = y * w + x;
                    out.coverage[i] = true;
                    out.depth_m[i] = f(2);
                    out.link[i] = (code.abs() - 1.0) as u32;
                    if code > 0.0 {
                        out.flow.u[i] = f(0);
                        out.flow.v[i] = f(1);
                    }
                }
            }
        }
        targets.staging.unmap();
        grow_mask(
            &out.coverage,
            w,
            h,
            self.margin_px,
            &mut self.mask_scratch,
            &mut out.mask,
        );
        Ok(())
    }

    fn name(&self) -> &'static str {
        "wgpu"
    }
}
