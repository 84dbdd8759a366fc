//! The wgpu renderer, offscreen (tests, `octolod render`) or on a window
//! surface (`octolod view`).
//!
//! Takes: [`DrawMesh`]es (uploaded once per resident node into a [`GpuMesh`])
//! and per-frame [`DrawParams`]. Gives: frames, as tightly packed RGBA8 bytes
//! ([`Renderer::render_offscreen`]) or presented to the window
//! ([`Renderer::render_to_surface`]), with an optional text overlay.
//!
//! Choices:
//! * Adapter: `WGPU_BACKEND` (e.g. `vulkan`, `gl`) and `WGPU_ADAPTER_NAME`
//!   are honoured. Without `WGPU_BACKEND`, native backends (Vulkan, Metal,
//!   DX12) are tried first and OpenGL only when none has an adapter: wgpu
//!   ranks GL's "Other" device type above a CPU device, and on a machine with
//!   only Mesa it would otherwise pick GL llvmpipe over Vulkan lavapipe.
//!   Software (CPU) adapters are accepted.
//! * Shading: per-vertex normals and colors, headlight (or a fixed light when
//!   [`DrawParams::light_dir`] is non-zero) plus [`AMBIENT`], two-sided (the
//!   normal is turned towards the eye), depth test `Less` on Depth32Float,
//!   no back-face culling (scans are not consistently oriented; views from
//!   inside closed surfaces must not be empty).
//! * Color target: an sRGB format. Vertex colors are display (sRGB-encoded)
//!   bytes and read back unchanged where fully lit; [`DrawParams::clear`] is
//!   linear like `wgpu::Color` and reads back sRGB-encoded ([`clear_rgba8`]).
//!   Lighting is computed in linear space.
//! * Textures ([`Renderer::set_textures`], drawn when
//!   [`DrawParams::textured`]): one RGBA8 sRGB texture per material slot,
//!   each with its mip chain and bind group, sampled trilinearly
//!   (anisotropic where the device can), repeating, at (u, 1 − v); lit
//!   like the shaded view. Meshes carry uvs in a second vertex buffer, so
//!   untextured meshes keep 28 bytes per vertex, and their triangles'
//!   materials as runs ([`crate::view::MaterialRun`], made off the render
//!   thread when the node is decoded), not per vertex: each drawn range
//!   is split at the runs' bounds, one draw per (mesh, run) with that
//!   slot's bind group. A run whose slot has no texture (or
//!   [`crate::mesh::Vertex::NO_TEXTURE`]) is drawn shaded, as a store
//!   without textures is. A mesh without runs uses slot 0 throughout.
//! * Wireframe: `PolygonMode::Line` when the device has
//!   `Features::POLYGON_MODE_LINE` (Vulkan incl. lavapipe, Metal, DX12).
//!   Otherwise (GL, or [`RendererOptions::line_list_wireframe`]) every
//!   upload also builds a line-list index buffer (3 edges per triangle, 24
//!   bytes per triangle) that is counted in [`GpuMesh::gpu_bytes`].

use crate::error::{Error, Result};
use crate::view::overlay::OverlayImage;
use crate::view::texture::MipChain;
use crate::view::{DrawItem, DrawMesh, GpuBytes, GpuVertex, MaterialRun};
use glam::{Mat4, Vec3};
use std::sync::Arc;
use wgpu::util::DeviceExt;

/// Ambient fraction of the shading (the rest is diffuse).
pub const AMBIENT: f32 = 0.25;
/// Color target format of offscreen rendering (RGBA bytes, sRGB).
pub const OFFSCREEN_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Rgba8UnormSrgb;
/// Depth buffer format.
pub const DEPTH_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Depth32Float;
/// Where the overlay's top-left corner goes, in pixels from the frame's.
pub const OVERLAY_MARGIN: u32 = 8;

/// Per-frame drawing parameters.
#[derive(Clone, Copy, Debug)]
pub struct DrawParams {
    /// World (relative to the store's origin) to clip space, wgpu depth
    /// convention (0 near, 1 far; depth test is `Less`).
    pub view_proj: Mat4,
    /// Eye position relative to the store's origin.
    pub eye: Vec3,
    /// Direction towards a fixed light; zero for a headlight.
    pub light_dir: Vec3,
    pub wireframe: bool,
    /// Draw meshes that have uvs with the texture (when one is set).
    pub textured: bool,
    /// Background, linear RGBA in 0..=1 (as `wgpu::Color`; the sRGB target
    /// encodes it: see [`clear_rgba8`]).
    pub clear: [f64; 4],
}

impl Default for DrawParams {
    fn default() -> Self {
        DrawParams { view_proj: Mat4::IDENTITY, eye: Vec3::ZERO, light_dir: Vec3::ZERO, wireframe: false, textured: false, clear: [0.0, 0.0, 0.0, 1.0] }
    }
}

/// The RGBA8 value a linear clear color reads back as from an sRGB target
/// (see [`DrawParams::clear`]); alpha is not encoded.
pub fn clear_rgba8(clear: [f64; 4]) -> [u8; 4] {
    let b = |c: f64| (c.clamp(0.0, 1.0) * 255.0).round() as u8;
    [b(linear_to_srgb(clear[0])), b(linear_to_srgb(clear[1])), b(linear_to_srgb(clear[2])), b(clear[3])]
}

pub use crate::color::{linear_to_srgb, srgb_to_linear};

/// Construction options.
#[derive(Clone, Copy, Debug, Default)]
pub struct RendererOptions {
    /// Window only: present with vsync (`Fifo`). Off: `Mailbox`, else
    /// `Immediate`, else `Fifo`.
    pub vsync: bool,
    /// Draw wireframes from line-list index buffers even when the device
    /// supports `PolygonMode::Line` (tests the fallback path).
    pub line_list_wireframe: bool,
    /// Cull back faces (as glTF's single-sided materials do); octolod
    /// itself draws both sides (open scans show their back).
    pub cull_back_faces: bool,
}

/// How wireframes are drawn on this device.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum WireframeMode {
    /// Triangles rasterised with `PolygonMode::Line`.
    PolygonLine,
    /// A line-list index buffer built at upload time.
    LineList,
}

/// One mesh resident on the GPU.
pub struct GpuMesh {
    vertices: Option<wgpu::Buffer>,
    uvs: Option<wgpu::Buffer>,
    indices: Option<wgpu::Buffer>,
    lines: Option<wgpu::Buffer>,
    /// Triangle runs by material (empty: all texture 0).
    materials: Vec<MaterialRun>,
    index_count: u32,
    line_index_count: u32,
    bytes: u64,
}

impl GpuMesh {
    pub fn index_count(&self) -> u32 {
        self.index_count
    }
    pub fn triangles(&self) -> u32 {
        self.index_count / 3
    }
    pub fn is_empty(&self) -> bool {
        self.index_count == 0
    }
}

impl GpuBytes for GpuMesh {
    /// The sizes of the buffers this mesh owns (vertex, index, and the
    /// line-list buffer on devices without `PolygonMode::Line`).
    fn gpu_bytes(&self) -> u64 {
        self.bytes
    }
}

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct Globals {
    view_proj: [[f32; 4]; 4],
    eye: [f32; 4],
    light: [f32; 4],
    params: [f32; 4],
}

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct OverlayRect {
    origin: [f32; 2],
    size: [f32; 2],
    screen: [f32; 2],
    pad: [f32; 2],
}

struct Target {
    _texture: wgpu::Texture,
    view: wgpu::TextureView,
}

struct OverlayGpu {
    pipeline: wgpu::RenderPipeline,
    layout: wgpu::BindGroupLayout,
    rect: wgpu::Buffer,
    srgb_target: bool,
    /// The image currently in `bind`'s texture.
    current: Option<(OverlayImage, wgpu::BindGroup)>,
}

/// What an offscreen frame draws: the parameters, the meshes and an
/// optional overlay.
type Scene<'a> = (&'a DrawParams, &'a [DrawItem<'a, GpuMesh>], Option<&'a OverlayImage>);

/// The renderer: device, pipelines and render targets.
pub struct Renderer {
    _instance: wgpu::Instance,
    adapter: wgpu::Adapter,
    device: wgpu::Device,
    queue: wgpu::Queue,
    format: wgpu::TextureFormat,
    width: u32,
    height: u32,
    /// Offscreen color target (headless only).
    color: Option<Target>,
    depth: Target,
    surface: Option<(wgpu::Surface<'static>, wgpu::SurfaceConfiguration)>,
    /// The window has a zero size: nothing to draw.
    minimized: bool,
    vsync: bool,
    globals: wgpu::Buffer,
    globals_bind: wgpu::BindGroup,
    fill: wgpu::RenderPipeline,
    wire: wgpu::RenderPipeline,
    wire_mode: WireframeMode,
    /// The textured fill pipeline, its texture's bind group layout and sampler.
    textured: wgpu::RenderPipeline,
    texture_layout: wgpu::BindGroupLayout,
    sampler: wgpu::Sampler,
    /// The textures set, by material slot, with their bind groups.
    textures: Vec<Option<(wgpu::Texture, wgpu::BindGroup)>>,
    /// Vertex colours tint the textures.
    tint: bool,
    overlay: OverlayGpu,
    readback: Option<(wgpu::Buffer, u64)>,
}

fn no_adapter(detail: &str) -> Error {
    Error::Usage(format!("no GPU adapter found: install a Vulkan driver (Mesa lavapipe: apt-get install mesa-vulkan-drivers){detail}"))
}

/// Backend sets to try in order: `WGPU_BACKEND`'s when set, else the
/// native ones, then GL.
fn backend_sets() -> Vec<wgpu::Backends> {
    match wgpu::Backends::from_env() {
        Some(b) => vec![b],
        None => vec![wgpu::Backends::VULKAN | wgpu::Backends::METAL | wgpu::Backends::DX12, wgpu::Backends::GL],
    }
}

fn instance(backends: wgpu::Backends) -> wgpu::Instance {
    wgpu::Instance::new(&wgpu::InstanceDescriptor { backends, ..wgpu::InstanceDescriptor::from_env_or_default() })
}

fn request_device(adapter: &wgpu::Adapter) -> Result<(wgpu::Device, wgpu::Queue)> {
    let features = adapter.features() & wgpu::Features::POLYGON_MODE_LINE;
    let limits = wgpu::Limits::downlevel_defaults().using_resolution(adapter.limits());
    // Large nodes want large buffers: take what the adapter offers.
    let limits = wgpu::Limits {
        max_buffer_size: adapter.limits().max_buffer_size,
        max_storage_buffer_binding_size: adapter.limits().max_storage_buffer_binding_size,
        ..limits
    };
    pollster::block_on(adapter.request_device(&wgpu::DeviceDescriptor {
        label: Some("octolod"),
        required_features: features,
        required_limits: limits,
        memory_hints: wgpu::MemoryHints::Performance,
        trace: wgpu::Trace::Off,
    }))
    .map_err(|e| Error::Usage(format!("GPU adapter '{}': cannot create a device: {e}", adapter.get_info().name)))
}

impl Renderer {
    /// An offscreen renderer of `width` x `height` pixels.
    pub fn headless(width: u32, height: u32) -> Result<Renderer> {
        Renderer::headless_with(width, height, RendererOptions::default())
    }

    pub fn headless_with(width: u32, height: u32, opts: RendererOptions) -> Result<Renderer> {
        let mut errors = Vec::new();
        for backends in backend_sets() {
            let instance = instance(backends);
            match pollster::block_on(wgpu::util::initialize_adapter_from_env_or_default(&instance, None)) {
                Ok(adapter) => {
                    let (device, queue) = request_device(&adapter)?;
                    return Renderer::new(instance, adapter, device, queue, OFFSCREEN_FORMAT, width, height, None, opts);
                }
                Err(e) => errors.push(e.to_string()),
            }
        }
        Err(no_adapter(&format!(" ({})", errors.join("; "))))
    }

    /// A renderer presenting to `window`, sized to its inner size.
    pub fn for_window(window: Arc<winit::window::Window>) -> Result<Renderer> {
        Renderer::for_window_with(window, RendererOptions::default())
    }

    pub fn for_window_with(window: Arc<winit::window::Window>, opts: RendererOptions) -> Result<Renderer> {
        let size = window.inner_size();
        let mut errors = Vec::new();
        for backends in backend_sets() {
            let instance = instance(backends);
            let surface = match instance.create_surface(window.clone()) {
                Ok(s) => s,
                Err(e) => {
                    errors.push(format!("cannot create a surface: {e}"));
                    continue;
                }
            };
            let adapter = match pollster::block_on(wgpu::util::initialize_adapter_from_env_or_default(&instance, Some(&surface))) {
                Ok(a) => a,
                Err(e) => {
                    errors.push(e.to_string());
                    continue;
                }
            };
            let (device, queue) = request_device(&adapter)?;
            let caps = surface.get_capabilities(&adapter);
            let format = caps
                .formats
                .iter()
                .copied()
                .find(|f| matches!(f, wgpu::TextureFormat::Bgra8UnormSrgb | wgpu::TextureFormat::Rgba8UnormSrgb))
                .or_else(|| caps.formats.iter().copied().find(|f| f.is_srgb()))
                .or_else(|| caps.formats.first().copied())
                .ok_or_else(|| Error::Usage(format!("GPU adapter '{}' cannot present to this window", adapter.get_info().name)))?;
            let config = wgpu::SurfaceConfiguration {
                usage: wgpu::TextureUsages::RENDER_ATTACHMENT,
                format,
                width: size.width.max(1),
                height: size.height.max(1),
                present_mode: present_mode(&caps.present_modes, opts.vsync),
                desired_maximum_frame_latency: 2,
                alpha_mode: caps.alpha_modes.first().copied().unwrap_or(wgpu::CompositeAlphaMode::Auto),
                view_formats: vec![],
            };
            if size.width > 0 && size.height > 0 {
                surface.configure(&device, &config);
            }
            return Renderer::new(instance, adapter, device, queue, format, size.width.max(1), size.height.max(1), Some((surface, config)), opts);
        }
        Err(no_adapter(&format!(" ({})", errors.join("; "))))
    }

    #[allow(clippy::too_many_arguments)]
    fn new(
        instance: wgpu::Instance,
        adapter: wgpu::Adapter,
        device: wgpu::Device,
        queue: wgpu::Queue,
        format: wgpu::TextureFormat,
        width: u32,
        height: u32,
        surface: Option<(wgpu::Surface<'static>, wgpu::SurfaceConfiguration)>,
        opts: RendererOptions,
    ) -> Result<Renderer> {
        let max = device.limits().max_texture_dimension_2d;
        if width == 0 || height == 0 || width > max || height > max {
            return Err(Error::Usage(format!("image size {width}x{height} is outside 1..={max} pixels per side")));
        }
        let wire_mode = if device.features().contains(wgpu::Features::POLYGON_MODE_LINE) && !opts.line_list_wireframe {
            WireframeMode::PolygonLine
        } else {
            WireframeMode::LineList
        };

        let globals = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("globals"),
            size: std::mem::size_of::<Globals>() as u64,
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let globals_layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor { label: Some("globals"), entries: &[uniform_entry(0)] });
        let globals_bind = device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("globals"),
            layout: &globals_layout,
            entries: &[wgpu::BindGroupEntry { binding: 0, resource: globals.as_entire_binding() }],
        });
        let shader = device.create_shader_module(wgpu::include_wgsl!("shader.wgsl"));
        let layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("mesh"),
            bind_group_layouts: &[&globals_layout],
            push_constant_ranges: &[],
        });
        let texture_layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("texture"),
            entries: &[
                texture_entry(0, true),
                wgpu::BindGroupLayoutEntry {
                    binding: 1,
                    visibility: wgpu::ShaderStages::FRAGMENT,
                    ty: wgpu::BindingType::Sampler(wgpu::SamplerBindingType::Filtering),
                    count: None,
                },
            ],
        });
        let textured_layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("textured mesh"),
            bind_group_layouts: &[&globals_layout, &texture_layout],
            push_constant_ranges: &[],
        });
        let anisotropic = adapter.get_downlevel_capabilities().flags.contains(wgpu::DownlevelFlags::ANISOTROPIC_FILTERING);
        let sampler = device.create_sampler(&wgpu::SamplerDescriptor {
            label: Some("texture"),
            address_mode_u: wgpu::AddressMode::Repeat,
            address_mode_v: wgpu::AddressMode::Repeat,
            mag_filter: wgpu::FilterMode::Linear,
            min_filter: wgpu::FilterMode::Linear,
            mipmap_filter: wgpu::FilterMode::Linear,
            anisotropy_clamp: if anisotropic { 16 } else { 1 },
            ..Default::default()
        });
        let attributes = wgpu::vertex_attr_array![0 => Float32x3, 1 => Float32x3, 2 => Unorm8x4];
        let vertex_layout = wgpu::VertexBufferLayout {
            array_stride: std::mem::size_of::<GpuVertex>() as u64,
            step_mode: wgpu::VertexStepMode::Vertex,
            attributes: &attributes,
        };
        let uv_attributes = wgpu::vertex_attr_array![3 => Float32x2];
        let uv_layout = wgpu::VertexBufferLayout { array_stride: 8, step_mode: wgpu::VertexStepMode::Vertex, attributes: &uv_attributes };
        let both_layouts = [vertex_layout.clone(), uv_layout];
        let mesh_pipeline = |label: &str, topology: wgpu::PrimitiveTopology, polygon_mode: wgpu::PolygonMode| {
            let textured = label == "textured";
            device.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
                label: Some(label),
                layout: Some(if textured { &textured_layout } else { &layout }),
                vertex: wgpu::VertexState {
                    module: &shader,
                    entry_point: Some(if textured { "vs_tex" } else { "vs_main" }),
                    compilation_options: Default::default(),
                    buffers: if textured { &both_layouts } else { std::slice::from_ref(&vertex_layout) },
                },
                primitive: wgpu::PrimitiveState {
                    topology,
                    strip_index_format: None,
                    front_face: wgpu::FrontFace::Ccw,
                    cull_mode: opts.cull_back_faces.then_some(wgpu::Face::Back),
                    unclipped_depth: false,
                    polygon_mode,
                    conservative: false,
                },
                depth_stencil: Some(wgpu::DepthStencilState {
                    format: DEPTH_FORMAT,
                    depth_write_enabled: true,
                    depth_compare: wgpu::CompareFunction::Less,
                    stencil: Default::default(),
                    bias: Default::default(),
                }),
                multisample: wgpu::MultisampleState::default(),
                fragment: Some(wgpu::FragmentState {
                    module: &shader,
                    entry_point: Some(if textured { "fs_tex" } else { "fs_main" }),
                    compilation_options: Default::default(),
                    targets: &[Some(wgpu::ColorTargetState { format, blend: None, write_mask: wgpu::ColorWrites::ALL })],
                }),
                multiview: None,
                cache: None,
            })
        };
        let fill = mesh_pipeline("fill", wgpu::PrimitiveTopology::TriangleList, wgpu::PolygonMode::Fill);
        let textured = mesh_pipeline("textured", wgpu::PrimitiveTopology::TriangleList, wgpu::PolygonMode::Fill);
        let wire = match wire_mode {
            WireframeMode::PolygonLine => mesh_pipeline("wire", wgpu::PrimitiveTopology::TriangleList, wgpu::PolygonMode::Line),
            WireframeMode::LineList => mesh_pipeline("wire-lines", wgpu::PrimitiveTopology::LineList, wgpu::PolygonMode::Fill),
        };

        let overlay = OverlayGpu::new(&device, format);
        let color = surface.is_none().then(|| color_target(&device, format, width, height));
        let depth = depth_target(&device, width, height);
        Ok(Renderer {
            _instance: instance,
            adapter,
            device,
            queue,
            format,
            width,
            height,
            color,
            depth,
            minimized: surface.as_ref().is_some_and(|_| width == 0 || height == 0),
            surface,
            vsync: opts.vsync,
            globals,
            globals_bind,
            fill,
            wire,
            wire_mode,
            textured,
            texture_layout,
            sampler,
            textures: Vec::new(),
            tint: false,
            overlay,
            readback: None,
        })
    }

    /// Name, backend and device type of the adapter in use.
    pub fn adapter_info(&self) -> wgpu::AdapterInfo {
        self.adapter.get_info()
    }
    pub fn wireframe_mode(&self) -> WireframeMode {
        self.wire_mode
    }
    pub fn size(&self) -> (u32, u32) {
        (self.width, self.height)
    }
    pub fn format(&self) -> wgpu::TextureFormat {
        self.format
    }
    pub fn device(&self) -> &wgpu::Device {
        &self.device
    }
    /// The present mode of the window surface, if any.
    pub fn present_mode(&self) -> Option<wgpu::PresentMode> {
        self.surface.as_ref().map(|(_, c)| c.present_mode)
    }

    /// Resizes the render targets (and reconfigures the surface). A zero
    /// size (minimised window) is remembered and drawing is skipped.
    pub fn resize(&mut self, width: u32, height: u32) {
        self.minimized = self.surface.is_some() && (width == 0 || height == 0);
        if let Some((surface, config)) = &mut self.surface {
            config.width = width.max(1);
            config.height = height.max(1);
            if width > 0 && height > 0 {
                surface.configure(&self.device, config);
            }
        }
        let max = self.device.limits().max_texture_dimension_2d;
        let (w, h) = (width.clamp(1, max), height.clamp(1, max));
        if (w, h) == (self.width, self.height) {
            return;
        }
        self.width = w;
        self.height = h;
        self.depth = depth_target(&self.device, w, h);
        if self.color.is_some() {
            self.color = Some(color_target(&self.device, self.format, w, h));
        }
    }

    /// Switches vsync on the window surface (no-op offscreen).
    pub fn set_vsync(&mut self, vsync: bool) {
        self.vsync = vsync;
        if let Some((surface, config)) = &mut self.surface {
            let caps = surface.get_capabilities(&self.adapter);
            config.present_mode = present_mode(&caps.present_modes, vsync);
            surface.configure(&self.device, config);
        }
    }
    pub fn vsync(&self) -> bool {
        self.vsync
    }

    /// Sets the textures meshes with uvs are drawn with, by material slot
    /// (see the module doc; an empty slot draws its triangles shaded):
    /// every level of each chain whose sides the device allows (finer
    /// ones are skipped). `tint`: vertex colours multiply them. Gives the
    /// bytes the GPU holds for them.
    pub fn set_textures<'a>(&mut self, slots: impl IntoIterator<Item = Option<&'a MipChain>>, tint: bool) -> Result<u64> {
        let mut textures = Vec::new();
        let mut bytes = 0;
        for chain in slots {
            textures.push(match chain {
                Some(c) => {
                    let (t, b) = self.upload_texture(c)?;
                    bytes += b;
                    Some(t)
                }
                None => None,
            });
        }
        self.textures = textures;
        self.tint = tint;
        Ok(bytes)
    }

    /// [`Renderer::set_textures`] with one texture, slot 0.
    pub fn set_texture(&mut self, chain: &MipChain, tint: bool) -> Result<u64> {
        self.set_textures([Some(chain)], tint)
    }

    /// One texture on the GPU and its bind group, and its bytes.
    fn upload_texture(&self, chain: &MipChain) -> Result<((wgpu::Texture, wgpu::BindGroup), u64)> {
        let max = self.device.limits().max_texture_dimension_2d;
        let levels: Vec<&crate::view::texture::MipLevel> = chain.levels.iter().skip_while(|l| l.width > max || l.height > max).collect();
        let Some(first) = levels.first() else {
            return Err(Error::Usage(format!("texture {}: no level fits the device ({max} texels a side)", chain.name)));
        };
        let texture = self.device.create_texture(&wgpu::TextureDescriptor {
            label: Some("texture"),
            size: wgpu::Extent3d { width: first.width, height: first.height, depth_or_array_layers: 1 },
            mip_level_count: levels.len() as u32,
            sample_count: 1,
            dimension: wgpu::TextureDimension::D2,
            format: wgpu::TextureFormat::Rgba8UnormSrgb,
            usage: wgpu::TextureUsages::TEXTURE_BINDING | wgpu::TextureUsages::COPY_DST,
            view_formats: &[],
        });
        for (k, l) in levels.iter().enumerate() {
            self.queue.write_texture(
                wgpu::TexelCopyTextureInfo { texture: &texture, mip_level: k as u32, origin: wgpu::Origin3d::ZERO, aspect: wgpu::TextureAspect::All },
                &l.rgba,
                wgpu::TexelCopyBufferLayout { offset: 0, bytes_per_row: Some(l.width * 4), rows_per_image: Some(l.height) },
                wgpu::Extent3d { width: l.width, height: l.height, depth_or_array_layers: 1 },
            );
        }
        let view = texture.create_view(&Default::default());
        let bind = self.device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("texture"),
            layout: &self.texture_layout,
            entries: &[
                wgpu::BindGroupEntry { binding: 0, resource: wgpu::BindingResource::TextureView(&view) },
                wgpu::BindGroupEntry { binding: 1, resource: wgpu::BindingResource::Sampler(&self.sampler) },
            ],
        });
        let bytes = levels.iter().map(|l| l.rgba.len() as u64).sum();
        Ok(((texture, bind), bytes))
    }

    /// Whether any texture is set.
    pub fn has_texture(&self) -> bool {
        self.textures.iter().any(Option::is_some)
    }

    /// Uploads a mesh. Empty meshes own no buffers and draw nothing.
    pub fn upload(&self, m: &DrawMesh) -> GpuMesh {
        if m.indices.is_empty() || m.vertices.is_empty() {
            return GpuMesh { vertices: None, uvs: None, indices: None, lines: None, materials: Vec::new(), index_count: 0, line_index_count: 0, bytes: 0 };
        }
        let vertices = self.device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("vertices"),
            contents: bytemuck::cast_slice(&m.vertices),
            usage: wgpu::BufferUsages::VERTEX,
        });
        let indices = self.device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("indices"),
            contents: bytemuck::cast_slice(&m.indices),
            usage: wgpu::BufferUsages::INDEX,
        });
        let index_count = (m.indices.len() / 3 * 3) as u32;
        let (lines, line_index_count) = match self.wire_mode {
            WireframeMode::PolygonLine => (None, 0),
            WireframeMode::LineList => {
                let lines = line_list(&m.indices[..index_count as usize]);
                let buf = self.device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
                    label: Some("lines"),
                    contents: bytemuck::cast_slice(&lines),
                    usage: wgpu::BufferUsages::INDEX,
                });
                (Some(buf), lines.len() as u32)
            }
        };
        let uvs = (m.uvs.len() == m.vertices.len()).then(|| {
            self.device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some("uvs"),
                contents: bytemuck::cast_slice(&m.uvs),
                usage: wgpu::BufferUsages::VERTEX,
            })
        });
        let bytes = vertices.size() + indices.size() + lines.as_ref().map_or(0, |b| b.size()) + uvs.as_ref().map_or(0, |b| b.size());
        let materials = if uvs.is_some() { m.materials.clone() } else { Vec::new() };
        GpuMesh { vertices: Some(vertices), uvs, indices: Some(indices), lines, materials, index_count, line_index_count, bytes }
    }

    fn write_globals(&self, p: &DrawParams) {
        let light = if p.light_dir.length_squared() > 0.0 { p.light_dir.normalize().extend(1.0) } else { glam::Vec4::ZERO };
        let g = Globals {
            view_proj: p.view_proj.to_cols_array_2d(),
            eye: p.eye.extend(1.0).to_array(),
            light: light.to_array(),
            params: [AMBIENT, if self.format.is_srgb() { 0.0 } else { 1.0 }, if self.tint { 1.0 } else { 0.0 }, 0.0],
        };
        self.queue.write_buffer(&self.globals, 0, bytemuck::bytes_of(&g));
    }

    fn clear_color(&self, clear: [f64; 4]) -> wgpu::Color {
        // A non-sRGB (surface) target gets the encoded value, so the window
        // looks like the offscreen renders.
        let c = |v: f64| if self.format.is_srgb() { v.clamp(0.0, 1.0) } else { linear_to_srgb(v) };
        wgpu::Color { r: c(clear[0]), g: c(clear[1]), b: c(clear[2]), a: clear[3].clamp(0.0, 1.0) }
    }

    fn encode_scene(&self, enc: &mut wgpu::CommandEncoder, view: &wgpu::TextureView, p: &DrawParams, meshes: &[DrawItem<GpuMesh>]) {
        self.encode_scene_pass(enc, view, p, meshes, true)
    }

    /// One scene pass; `clear` false draws over what the target holds
    /// (colour and depth), for frames drawn in several batches.
    fn encode_scene_pass(&self, enc: &mut wgpu::CommandEncoder, view: &wgpu::TextureView, p: &DrawParams, meshes: &[DrawItem<GpuMesh>], clear: bool) {
        let color_load = if clear { wgpu::LoadOp::Clear(self.clear_color(p.clear)) } else { wgpu::LoadOp::Load };
        let depth_load = if clear { wgpu::LoadOp::Clear(1.0) } else { wgpu::LoadOp::Load };
        let mut pass = enc.begin_render_pass(&wgpu::RenderPassDescriptor {
            label: Some("scene"),
            color_attachments: &[Some(wgpu::RenderPassColorAttachment {
                view,
                depth_slice: None,
                resolve_target: None,
                ops: wgpu::Operations { load: color_load, store: wgpu::StoreOp::Store },
            })],
            depth_stencil_attachment: Some(wgpu::RenderPassDepthStencilAttachment {
                view: &self.depth.view,
                depth_ops: Some(wgpu::Operations { load: depth_load, store: wgpu::StoreOp::Store }),
                stencil_ops: None,
            }),
            timestamp_writes: None,
            occlusion_query_set: None,
        });
        pass.set_bind_group(0, &self.globals_bind, &[]);
        let textured = p.textured && !p.wireframe && self.has_texture();
        let mut current: Option<Pipe> = None;
        let mut bound: Option<usize> = None;
        for item in meshes {
            let m = item.mesh;
            let (Some(vb), Some(ib)) = (&m.vertices, &m.indices) else { continue };
            let uvs = m.uvs.as_ref().filter(|_| textured);
            // Indices per triangle: 3, or 6 in a line list (three edges).
            let (ib, count, per) = match (p.wireframe, self.wire_mode, &m.lines) {
                (true, WireframeMode::LineList, Some(lb)) => (lb, m.line_index_count, 6),
                (true, WireframeMode::LineList, None) => continue,
                _ => (ib, m.index_count, 3),
            };
            if count == 0 {
                continue;
            }
            pass.set_vertex_buffer(0, vb.slice(..));
            if let Some(ub) = uvs {
                pass.set_vertex_buffer(1, ub.slice(..));
            }
            pass.set_index_buffer(ib.slice(..), wgpu::IndexFormat::Uint32);
            let whole = [MaterialRun { first: 0, count: u32::MAX, material: 0 }];
            // Shaded, a mesh's ranges are drawn whole.
            let runs: &[MaterialRun] = if m.materials.is_empty() || uvs.is_none() { &whole } else { &m.materials };
            for r in &item.ranges {
                for (tris, material) in split_by_runs(r.clone(), runs) {
                    let (a, b) = ((tris.start * per).min(count), (tris.end * per).min(count));
                    if a >= b {
                        continue;
                    }
                    let slot = uvs.and_then(|_| self.textures.get(material as usize)?.as_ref().map(|(_, bind)| (material as usize, bind)));
                    let pipe = match (slot.is_some(), p.wireframe) {
                        (true, _) => Pipe::Textured,
                        (false, true) => Pipe::Wire,
                        (false, false) => Pipe::Fill,
                    };
                    if current != Some(pipe) {
                        pass.set_pipeline(match pipe {
                            Pipe::Textured => &self.textured,
                            Pipe::Wire => &self.wire,
                            Pipe::Fill => &self.fill,
                        });
                        current = Some(pipe);
                        bound = None;
                    }
                    if let Some((k, bind)) = slot {
                        if bound != Some(k) {
                            pass.set_bind_group(1, bind, &[]);
                            bound = Some(k);
                        }
                    }
                    pass.draw_indexed(a..b, 0, 0..1);
                }
            }
        }
    }

    fn encode_overlay(&mut self, enc: &mut wgpu::CommandEncoder, view: &wgpu::TextureView, overlay: Option<&OverlayImage>) {
        let Some(img) = overlay else { return };
        if img.width == 0 || img.height == 0 || img.rgba.len() != (img.width as usize * img.height as usize * 4) {
            return;
        }
        let max = self.device.limits().max_texture_dimension_2d;
        if img.width > max || img.height > max {
            return;
        }
        self.overlay.update(&self.device, &self.queue, img);
        let rect = OverlayRect {
            origin: [OVERLAY_MARGIN as f32; 2],
            size: [img.width as f32, img.height as f32],
            screen: [self.width as f32, self.height as f32],
            pad: [0.0; 2],
        };
        self.queue.write_buffer(&self.overlay.rect, 0, bytemuck::bytes_of(&rect));
        let Some((_, bind)) = &self.overlay.current else { return };
        let mut pass = enc.begin_render_pass(&wgpu::RenderPassDescriptor {
            label: Some("overlay"),
            color_attachments: &[Some(wgpu::RenderPassColorAttachment {
                view,
                depth_slice: None,
                resolve_target: None,
                ops: wgpu::Operations { load: wgpu::LoadOp::Load, store: wgpu::StoreOp::Store },
            })],
            depth_stencil_attachment: None,
            timestamp_writes: None,
            occlusion_query_set: None,
        });
        pass.set_pipeline(&self.overlay.pipeline);
        pass.set_bind_group(0, bind, &[]);
        pass.draw(0..4, 0..1);
    }

    /// Renders offscreen and returns the frame as tightly packed RGBA8,
    /// `width * height * 4` bytes, top row first.
    pub fn render_offscreen(&mut self, p: &DrawParams, meshes: &[DrawItem<GpuMesh>]) -> Result<Vec<u8>> {
        self.render_offscreen_overlay(p, meshes, None)
    }

    /// Renders a frame too large to hold at once: `next_batch` hands out
    /// meshes until it returns None; each batch is drawn over the previous
    /// ones (sharing the depth buffer) and dropped before the next is asked
    /// for, so only one batch is resident. Same image as drawing them all.
    pub fn render_offscreen_batched(&mut self, p: &DrawParams, next_batch: &mut dyn FnMut(&Renderer) -> Result<Option<Vec<GpuMesh>>>) -> Result<Vec<u8>> {
        let Some(color) = &self.color else {
            return Err(Error::Usage("render_offscreen_batched needs a headless renderer".into()));
        };
        let view = color.view.clone();
        self.write_globals(p);
        let mut first = true;
        loop {
            let batch = next_batch(self)?;
            let done = batch.is_none();
            let meshes = batch.unwrap_or_default();
            if done && !first {
                break;
            }
            let refs: Vec<DrawItem<GpuMesh>> = meshes.iter().map(|m| DrawItem::whole(m, m.triangles())).collect();
            let mut enc = self.device.create_command_encoder(&wgpu::CommandEncoderDescriptor { label: Some("batch") });
            self.encode_scene_pass(&mut enc, &view, p, &refs, first);
            self.queue.submit([enc.finish()]);
            first = false;
            drop(refs);
            drop(meshes);
            let _ = self.device.poll(wgpu::PollType::Wait);
            if done {
                break;
            }
        }
        self.render_offscreen_keep()
    }

    /// Reads back the offscreen target as it is (no drawing).
    fn render_offscreen_keep(&mut self) -> Result<Vec<u8>> {
        self.readback_frame(None)
    }

    /// [`Renderer::render_offscreen`] with an optional overlay on top.
    pub fn render_offscreen_overlay(&mut self, p: &DrawParams, meshes: &[DrawItem<GpuMesh>], overlay: Option<&OverlayImage>) -> Result<Vec<u8>> {
        self.write_globals(p);
        self.readback_frame(Some((p, meshes, overlay)))
    }

    /// Draws (when given a scene) and reads the offscreen target back.
    fn readback_frame(&mut self, scene: Option<Scene<'_>>) -> Result<Vec<u8>> {
        let Some(color) = &self.color else {
            return Err(Error::Usage("render_offscreen needs a headless renderer".into()));
        };
        let color_tex = color._texture.clone();
        let color_view = color.view.clone();
        let (w, h) = (self.width, self.height);
        let row = w as u64 * 4;
        let padded = row.div_ceil(wgpu::COPY_BYTES_PER_ROW_ALIGNMENT as u64) * wgpu::COPY_BYTES_PER_ROW_ALIGNMENT as u64;
        let size = padded * h as u64;
        if self.readback.as_ref().is_none_or(|(_, s)| *s != size) {
            let buf = self.device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("readback"),
                size,
                usage: wgpu::BufferUsages::COPY_DST | wgpu::BufferUsages::MAP_READ,
                mapped_at_creation: false,
            });
            self.readback = Some((buf, size));
        }
        let mut enc = self.device.create_command_encoder(&wgpu::CommandEncoderDescriptor { label: Some("offscreen") });
        if let Some((p, meshes, overlay)) = scene {
            self.encode_scene(&mut enc, &color_view, p, meshes);
            self.encode_overlay(&mut enc, &color_view, overlay);
        }
        let (buf, _) = self.readback.as_ref().expect("readback buffer");
        enc.copy_texture_to_buffer(
            wgpu::TexelCopyTextureInfo { texture: &color_tex, mip_level: 0, origin: wgpu::Origin3d::ZERO, aspect: wgpu::TextureAspect::All },
            wgpu::TexelCopyBufferInfo {
                buffer: buf,
                layout: wgpu::TexelCopyBufferLayout { offset: 0, bytes_per_row: Some(padded as u32), rows_per_image: Some(h) },
            },
            wgpu::Extent3d { width: w, height: h, depth_or_array_layers: 1 },
        );
        self.queue.submit([enc.finish()]);
        let slice = buf.slice(..);
        let (tx, rx) = std::sync::mpsc::channel();
        slice.map_async(wgpu::MapMode::Read, move |r| {
            let _ = tx.send(r);
        });
        self.device.poll(wgpu::PollType::Wait).map_err(|e| Error::Usage(format!("GPU: waiting for the frame failed: {e}")))?;
        rx.recv()
            .map_err(|_| Error::Usage("GPU: frame readback was dropped".into()))?
            .map_err(|e| Error::Usage(format!("GPU: cannot map the frame for reading: {e}")))?;
        let mut out = Vec::with_capacity((row * h as u64) as usize);
        {
            let data = slice.get_mapped_range();
            for y in 0..h as usize {
                let start = y * padded as usize;
                out.extend_from_slice(&data[start..start + row as usize]);
            }
        }
        buf.unmap();
        if matches!(self.format, wgpu::TextureFormat::Bgra8Unorm | wgpu::TextureFormat::Bgra8UnormSrgb) {
            for px in out.chunks_exact_mut(4) {
                px.swap(0, 2);
            }
        }
        Ok(out)
    }

    /// Renders one frame to the window surface and presents it. Returns
    /// `Ok(false)` when no frame was presented: minimised window, or a
    /// transient surface error (lost/outdated surfaces are reconfigured for
    /// the next frame; timeouts are skipped). Only running out of memory is
    /// an error.
    pub fn render_to_surface(&mut self, p: &DrawParams, meshes: &[DrawItem<GpuMesh>], overlay: Option<&OverlayImage>) -> Result<bool> {
        let Some((surface, config)) = &self.surface else {
            return Err(Error::Usage("render_to_surface needs a window renderer".into()));
        };
        if self.minimized {
            return Ok(false);
        }
        let frame = match surface.get_current_texture() {
            Ok(f) => f,
            Err(wgpu::SurfaceError::Lost | wgpu::SurfaceError::Outdated) => {
                surface.configure(&self.device, config);
                return Ok(false);
            }
            Err(wgpu::SurfaceError::Timeout | wgpu::SurfaceError::Other) => return Ok(false),
            Err(wgpu::SurfaceError::OutOfMemory) => return Err(Error::Usage("GPU: out of memory acquiring a frame".into())),
        };
        let suboptimal = frame.suboptimal;
        let view = frame.texture.create_view(&wgpu::TextureViewDescriptor::default());
        self.write_globals(p);
        let mut enc = self.device.create_command_encoder(&wgpu::CommandEncoderDescriptor { label: Some("frame") });
        self.encode_scene(&mut enc, &view, p, meshes);
        self.encode_overlay(&mut enc, &view, overlay);
        self.queue.submit([enc.finish()]);
        frame.present();
        if suboptimal {
            if let Some((surface, config)) = &self.surface {
                surface.configure(&self.device, config);
            }
        }
        Ok(true)
    }
}

fn present_mode(modes: &[wgpu::PresentMode], vsync: bool) -> wgpu::PresentMode {
    if vsync {
        return wgpu::PresentMode::Fifo;
    }
    [wgpu::PresentMode::Mailbox, wgpu::PresentMode::Immediate].into_iter().find(|m| modes.contains(m)).unwrap_or(wgpu::PresentMode::Fifo)
}

/// A mesh pipeline.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Pipe {
    Fill,
    Wire,
    Textured,
}

/// The parts of triangle range `r` in each of `runs` (sorted, disjoint),
/// with their material; parts of `r` outside every run are dropped.
fn split_by_runs(r: std::ops::Range<u32>, runs: &[MaterialRun]) -> impl Iterator<Item = (std::ops::Range<u32>, u16)> + '_ {
    // The first run that ends after r starts.
    let from = runs.partition_point(|x| x.first.saturating_add(x.count) <= r.start);
    runs[from..].iter().take_while(move |x| x.first < r.end).filter_map(move |x| {
        let (a, b) = (x.first.max(r.start), x.first.saturating_add(x.count).min(r.end));
        (a < b).then_some((a..b, x.material))
    })
}

/// Edges of each triangle as a line list (shared edges appear twice; the
/// cost of deduplicating is not worth it for a fallback path).
fn line_list(tris: &[u32]) -> Vec<u32> {
    let mut out = Vec::with_capacity(tris.len() * 2);
    for t in tris.chunks_exact(3) {
        out.extend_from_slice(&[t[0], t[1], t[1], t[2], t[2], t[0]]);
    }
    out
}

fn color_target(device: &wgpu::Device, format: wgpu::TextureFormat, w: u32, h: u32) -> Target {
    let texture = device.create_texture(&wgpu::TextureDescriptor {
        label: Some("color"),
        size: wgpu::Extent3d { width: w, height: h, depth_or_array_layers: 1 },
        mip_level_count: 1,
        sample_count: 1,
        dimension: wgpu::TextureDimension::D2,
        format,
        usage: wgpu::TextureUsages::RENDER_ATTACHMENT | wgpu::TextureUsages::COPY_SRC,
        view_formats: &[],
    });
    let view = texture.create_view(&Default::default());
    Target { _texture: texture, view }
}

fn depth_target(device: &wgpu::Device, w: u32, h: u32) -> Target {
    let texture = device.create_texture(&wgpu::TextureDescriptor {
        label: Some("depth"),
        size: wgpu::Extent3d { width: w, height: h, depth_or_array_layers: 1 },
        mip_level_count: 1,
        sample_count: 1,
        dimension: wgpu::TextureDimension::D2,
        format: DEPTH_FORMAT,
        usage: wgpu::TextureUsages::RENDER_ATTACHMENT,
        view_formats: &[],
    });
    let view = texture.create_view(&Default::default());
    Target { _texture: texture, view }
}

/// A uniform buffer visible to both shader stages.
fn uniform_entry(binding: u32) -> wgpu::BindGroupLayoutEntry {
    wgpu::BindGroupLayoutEntry {
        binding,
        visibility: wgpu::ShaderStages::VERTEX_FRAGMENT,
        ty: wgpu::BindingType::Buffer { ty: wgpu::BufferBindingType::Uniform, has_dynamic_offset: false, min_binding_size: None },
        count: None,
    }
}

/// A 2D float texture read by the fragment stage.
fn texture_entry(binding: u32, filterable: bool) -> wgpu::BindGroupLayoutEntry {
    wgpu::BindGroupLayoutEntry {
        binding,
        visibility: wgpu::ShaderStages::FRAGMENT,
        ty: wgpu::BindingType::Texture {
            sample_type: wgpu::TextureSampleType::Float { filterable },
            view_dimension: wgpu::TextureViewDimension::D2,
            multisampled: false,
        },
        count: None,
    }
}

impl OverlayGpu {
    fn new(device: &wgpu::Device, format: wgpu::TextureFormat) -> OverlayGpu {
        let layout =
            device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor { label: Some("overlay"), entries: &[uniform_entry(0), texture_entry(1, false)] });
        let shader = device.create_shader_module(wgpu::include_wgsl!("overlay.wgsl"));
        let pl = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("overlay"),
            bind_group_layouts: &[&layout],
            push_constant_ranges: &[],
        });
        let pipeline = device.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
            label: Some("overlay"),
            layout: Some(&pl),
            vertex: wgpu::VertexState { module: &shader, entry_point: Some("vs_overlay"), compilation_options: Default::default(), buffers: &[] },
            primitive: wgpu::PrimitiveState { topology: wgpu::PrimitiveTopology::TriangleStrip, ..Default::default() },
            depth_stencil: None,
            multisample: wgpu::MultisampleState::default(),
            fragment: Some(wgpu::FragmentState {
                module: &shader,
                entry_point: Some("fs_overlay"),
                compilation_options: Default::default(),
                targets: &[Some(wgpu::ColorTargetState { format, blend: Some(wgpu::BlendState::ALPHA_BLENDING), write_mask: wgpu::ColorWrites::ALL })],
            }),
            multiview: None,
            cache: None,
        });
        let rect = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("overlay rect"),
            size: std::mem::size_of::<OverlayRect>() as u64,
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        OverlayGpu { pipeline, layout, rect, srgb_target: format.is_srgb(), current: None }
    }

    /// Uploads `img` unless it is the image already on the GPU; a texture of
    /// the same size is rewritten in place, another size gets a new one.
    fn update(&mut self, device: &wgpu::Device, queue: &wgpu::Queue, img: &OverlayImage) {
        if self.current.as_ref().is_some_and(|(cur, _)| cur == img) {
            return;
        }
        let texture = device.create_texture(&wgpu::TextureDescriptor {
            label: Some("overlay"),
            size: wgpu::Extent3d { width: img.width, height: img.height, depth_or_array_layers: 1 },
            mip_level_count: 1,
            sample_count: 1,
            dimension: wgpu::TextureDimension::D2,
            // Bytes pass through unchanged to a non-sRGB target.
            format: if self.srgb_target { wgpu::TextureFormat::Rgba8UnormSrgb } else { wgpu::TextureFormat::Rgba8Unorm },
            usage: wgpu::TextureUsages::TEXTURE_BINDING | wgpu::TextureUsages::COPY_DST,
            view_formats: &[],
        });
        queue.write_texture(
            wgpu::TexelCopyTextureInfo { texture: &texture, mip_level: 0, origin: wgpu::Origin3d::ZERO, aspect: wgpu::TextureAspect::All },
            &img.rgba,
            wgpu::TexelCopyBufferLayout { offset: 0, bytes_per_row: Some(img.width * 4), rows_per_image: Some(img.height) },
            wgpu::Extent3d { width: img.width, height: img.height, depth_or_array_layers: 1 },
        );
        let view = texture.create_view(&Default::default());
        let bind = device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("overlay"),
            layout: &self.layout,
            entries: &[
                wgpu::BindGroupEntry { binding: 0, resource: self.rect.as_entire_binding() },
                wgpu::BindGroupEntry { binding: 1, resource: wgpu::BindingResource::TextureView(&view) },
            ],
        });
        self.current = Some((img.clone(), bind));
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn line_list_has_three_edges_per_triangle() {
        assert_eq!(line_list(&[0, 1, 2, 2, 1, 3]), vec![0, 1, 1, 2, 2, 0, 2, 1, 1, 3, 3, 2]);
    }

    #[test]
    fn drawn_ranges_split_at_material_runs() {
        let r = |first, count, material| MaterialRun { first, count, material };
        let runs = [r(0, 4, 0), r(4, 2, 1), r(6, 3, 0), r(9, 1, 7)];
        let parts = |range: std::ops::Range<u32>| split_by_runs(range, &runs).collect::<Vec<_>>();
        assert_eq!(parts(0..10), vec![(0..4, 0), (4..6, 1), (6..9, 0), (9..10, 7)]);
        assert_eq!(parts(3..7), vec![(3..4, 0), (4..6, 1), (6..7, 0)]);
        assert_eq!(parts(4..6), vec![(4..6, 1)]);
        assert_eq!(parts(5..5), vec![]);
        // Beyond the runs: nothing.
        assert_eq!(parts(9..20), vec![(9..10, 7)]);
        assert_eq!(parts(10..20), vec![]);
        let whole = [r(0, u32::MAX, 0)];
        assert_eq!(split_by_runs(7..9, &whole).collect::<Vec<_>>(), vec![(7..9, 0)]);
    }

    #[test]
    fn clear_bytes_and_present_modes() {
        assert_eq!(clear_rgba8([0.0, 1.0, 0.5, 2.0]), [0, 255, 188, 255]);
        for k in 0..=255u8 {
            let c = srgb_to_linear(k as f64 / 255.0);
            assert_eq!(clear_rgba8([c, c, c, 1.0]), [k, k, k, 255]);
        }
        assert_eq!(present_mode(&[wgpu::PresentMode::Fifo, wgpu::PresentMode::Mailbox], false), wgpu::PresentMode::Mailbox);
        assert_eq!(present_mode(&[wgpu::PresentMode::Fifo, wgpu::PresentMode::Mailbox], true), wgpu::PresentMode::Fifo);
        assert_eq!(present_mode(&[wgpu::PresentMode::Fifo], false), wgpu::PresentMode::Fifo);
    }
}
