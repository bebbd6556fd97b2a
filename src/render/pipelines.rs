//! Bind group layouts and render pipelines of the geometry method, built once per colour
//! format (a window surface is often BGRA, offscreen targets RGBA), and the small builders
//! every pass shares: layout entries, storage buffers, sampled RGBA8 textures, the
//! `geometry.wgsl` mesh pipelines.

use super::{DEPTH_FORMAT, SHADOW_FORMAT, shaders};
use crate::model::mesh::Vertex;

/// Layouts shared by every pipeline.
pub struct Layouts {
    pub frame: wgpu::BindGroupLayout,
    pub shadow_frame: wgpu::BindGroupLayout,
    pub trees: wgpu::BindGroupLayout,
    pub parts: wgpu::BindGroupLayout,
}

/// A layout entry for a buffer of kind `ty` seen by `visibility`.
pub(crate) fn buffer_entry(
    binding: u32,
    visibility: wgpu::ShaderStages,
    ty: wgpu::BufferBindingType,
) -> wgpu::BindGroupLayoutEntry {
    wgpu::BindGroupLayoutEntry {
        binding,
        visibility,
        ty: wgpu::BindingType::Buffer {
            ty,
            has_dynamic_offset: false,
            min_binding_size: None,
        },
        count: None,
    }
}

fn uniform_entry(binding: u32, visibility: wgpu::ShaderStages) -> wgpu::BindGroupLayoutEntry {
    buffer_entry(binding, visibility, wgpu::BufferBindingType::Uniform)
}

/// A layout entry for a read-only storage buffer seen by `visibility`.
pub(crate) fn storage_entry(
    binding: u32,
    visibility: wgpu::ShaderStages,
) -> wgpu::BindGroupLayoutEntry {
    buffer_entry(
        binding,
        visibility,
        wgpu::BufferBindingType::Storage { read_only: true },
    )
}

/// The sample type of a colour texture read through a filtering sampler.
pub(crate) const FILTERABLE: wgpu::TextureSampleType =
    wgpu::TextureSampleType::Float { filterable: true };

/// A layout entry for a (single-sampled) texture the fragment stage reads.
pub(crate) fn texture_entry(
    binding: u32,
    sample_type: wgpu::TextureSampleType,
    view_dimension: wgpu::TextureViewDimension,
) -> wgpu::BindGroupLayoutEntry {
    wgpu::BindGroupLayoutEntry {
        binding,
        visibility: wgpu::ShaderStages::FRAGMENT,
        ty: wgpu::BindingType::Texture {
            sample_type,
            view_dimension,
            multisampled: false,
        },
        count: None,
    }
}

/// A layout entry for a sampler the fragment stage uses.
pub(crate) fn sampler_entry(
    binding: u32,
    ty: wgpu::SamplerBindingType,
) -> wgpu::BindGroupLayoutEntry {
    wgpu::BindGroupLayoutEntry {
        binding,
        visibility: wgpu::ShaderStages::FRAGMENT,
        ty: wgpu::BindingType::Sampler(ty),
        count: None,
    }
}

/// A storage buffer of `size` bytes the queue writes into.
pub(crate) fn storage_buffer(device: &wgpu::Device, label: &str, size: u64) -> wgpu::Buffer {
    device.create_buffer(&wgpu::BufferDescriptor {
        label: Some(label),
        size,
        usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST,
        mapped_at_creation: false,
    })
}

/// A storage buffer the queue writes into, room for `count` (at least one) `T`s.
pub(crate) fn storage_buffer_of<T>(
    device: &wgpu::Device,
    label: &str,
    count: usize,
) -> wgpu::Buffer {
    storage_buffer(
        device,
        label,
        (count.max(1) * std::mem::size_of::<T>()) as u64,
    )
}

/// Writes `items` at the start of `buffer`, first replacing it (labelled `label`) by a
/// storage buffer with room for the next power of two of them when they do not fit; says
/// whether it did (a bind group holding the old buffer must then be made again).
pub(crate) fn write_growing<T: bytemuck::Pod>(
    ctx: &super::GpuContext,
    buffer: &mut wgpu::Buffer,
    label: &str,
    items: &[T],
) -> bool {
    let bytes: &[u8] = bytemuck::cast_slice(items);
    let grown = bytes.len() as u64 > buffer.size();
    if grown {
        *buffer = storage_buffer_of::<T>(&ctx.device, label, items.len().next_power_of_two());
    }
    if !bytes.is_empty() {
        ctx.queue.write_buffer(buffer, 0, bytes);
    }
    grown
}

/// A shader module from WGSL `source`.
pub(crate) fn wgsl_module(device: &wgpu::Device, label: &str, source: &str) -> wgpu::ShaderModule {
    device.create_shader_module(wgpu::ShaderModuleDescriptor {
        label: Some(label),
        source: wgpu::ShaderSource::Wgsl(source.into()),
    })
}

/// An sRGB RGBA8 texture of `size` (width, height, depth or layers) with `mips` levels,
/// sampled by shaders and filled by the queue.
pub(crate) fn sampled_rgba8_texture(
    device: &wgpu::Device,
    label: &str,
    dimension: wgpu::TextureDimension,
    size: glam::UVec3,
    mips: u32,
) -> wgpu::Texture {
    texture(
        device,
        label,
        dimension,
        size,
        mips,
        wgpu::TextureFormat::Rgba8UnormSrgb,
        wgpu::TextureUsages::TEXTURE_BINDING | wgpu::TextureUsages::COPY_DST,
    )
}

/// A 2D texture of `size` (width, height, layers) and one level, for drawing into.
pub(crate) fn target_texture(
    device: &wgpu::Device,
    label: &str,
    size: glam::UVec3,
    format: wgpu::TextureFormat,
    usage: wgpu::TextureUsages,
) -> wgpu::Texture {
    texture(
        device,
        label,
        wgpu::TextureDimension::D2,
        size,
        1,
        format,
        usage,
    )
}

pub(crate) fn texture(
    device: &wgpu::Device,
    label: &str,
    dimension: wgpu::TextureDimension,
    size: glam::UVec3,
    mips: u32,
    format: wgpu::TextureFormat,
    usage: wgpu::TextureUsages,
) -> wgpu::Texture {
    device.create_texture(&wgpu::TextureDescriptor {
        label: Some(label),
        size: extent(size),
        mip_level_count: mips,
        sample_count: 1,
        dimension,
        format,
        usage,
        view_formats: &[],
    })
}

/// Writes tightly packed RGBA8 `data` of `size` texels into mip `level` of `texture` at
/// `origin`.
pub(crate) fn write_rgba8(
    queue: &wgpu::Queue,
    texture: &wgpu::Texture,
    level: u32,
    origin: glam::UVec3,
    data: &[u8],
    size: glam::UVec3,
) {
    write_texels(queue, texture, level, origin, data, size, 4);
}

/// Writes tightly packed `data` of `size` texels of `texel_bytes` each into mip `level` of
/// `texture` at `origin`.
pub(crate) fn write_texels(
    queue: &wgpu::Queue,
    texture: &wgpu::Texture,
    level: u32,
    origin: glam::UVec3,
    data: &[u8],
    size: glam::UVec3,
    texel_bytes: u32,
) {
    queue.write_texture(
        wgpu::TexelCopyTextureInfo {
            texture,
            mip_level: level,
            origin: wgpu::Origin3d {
                x: origin.x,
                y: origin.y,
                z: origin.z,
            },
            aspect: wgpu::TextureAspect::All,
        },
        data,
        wgpu::TexelCopyBufferLayout {
            offset: 0,
            bytes_per_row: Some(texel_bytes * size.x),
            rows_per_image: Some(size.y),
        },
        extent(size),
    );
}

fn extent(size: glam::UVec3) -> wgpu::Extent3d {
    wgpu::Extent3d {
        width: size.x,
        height: size.y,
        depth_or_array_layers: size.z,
    }
}

impl Layouts {
    pub fn new(device: &wgpu::Device) -> Self {
        let vf = wgpu::ShaderStages::VERTEX_FRAGMENT;
        let frame = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("frame"),
            entries: &[
                // Seen by the tile compositor's compute passes too.
                uniform_entry(0, vf | wgpu::ShaderStages::COMPUTE),
                texture_entry(
                    1,
                    wgpu::TextureSampleType::Depth,
                    wgpu::TextureViewDimension::D2Array,
                ),
                sampler_entry(2, wgpu::SamplerBindingType::Comparison),
                texture_entry(3, FILTERABLE, wgpu::TextureViewDimension::D2),
                sampler_entry(4, wgpu::SamplerBindingType::Filtering),
                texture_entry(
                    5,
                    wgpu::TextureSampleType::Depth,
                    wgpu::TextureViewDimension::D2Array,
                ),
                // The reference's sky visibility volume and its placement.
                texture_entry(6, FILTERABLE, wgpu::TextureViewDimension::D3),
                uniform_entry(7, wgpu::ShaderStages::FRAGMENT),
                // The overdraw view's counters (src/render/overdraw.rs).
                buffer_entry(
                    8,
                    wgpu::ShaderStages::FRAGMENT | wgpu::ShaderStages::COMPUTE,
                    wgpu::BufferBindingType::Storage { read_only: false },
                ),
            ],
        });
        let shadow_frame = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("shadow frame"),
            entries: &[uniform_entry(0, vf)],
        });
        let trees = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("trees"),
            entries: &[storage_entry(0, wgpu::ShaderStages::VERTEX)],
        });
        let parts = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("parts"),
            entries: &[
                storage_entry(0, wgpu::ShaderStages::VERTEX),
                uniform_entry(1, vf),
                // An imported tree's material texture (1x1 white for every other part).
                texture_entry(2, FILTERABLE, wgpu::TextureViewDimension::D2),
                sampler_entry(3, wgpu::SamplerBindingType::Filtering),
                // The terrain's normals and heights (1x1 white for every other part).
                texture_entry(4, FILTERABLE, wgpu::TextureViewDimension::D2),
            ],
        });
        Self {
            frame,
            shadow_frame,
            trees,
            parts,
        }
    }
}

/// The depth bias of every map the sun's view draws for shadows (cascades, per-tree maps).
pub(crate) const SHADOW_BIAS: wgpu::DepthBiasState = wgpu::DepthBiasState {
    constant: 2,
    slope_scale: 1.5,
    clamp: 0.0,
};

/// The shadow pipelines (independent of the colour format): depth only, biased; the
/// first without a fragment stage (untextured parts, the terrain), the second with the
/// parts' alpha test (an imported tree's cards).
pub fn shadow_pipelines(
    device: &wgpu::Device,
    layouts: &Layouts,
) -> (wgpu::RenderPipeline, wgpu::RenderPipeline) {
    let view = |label, cutout| LightView {
        label,
        compare: wgpu::CompareFunction::LessEqual,
        bias: SHADOW_BIAS,
        cutout,
        ..LightView::shadow_frame(layouts)
    };
    (
        light_view_pipeline(device, &view("shadow", false)),
        light_view_pipeline(device, &view("shadow, cut out", true)),
    )
}

/// The terrain into the ground shadow maps: white in the alpha map, and its depth kept as
/// the terrain's own shadow map.
pub fn ground_terrain_pipeline(device: &wgpu::Device, layouts: &Layouts) -> wgpu::RenderPipeline {
    light_view_pipeline(
        device,
        &LightView {
            label: "ground terrain",
            compare: wgpu::CompareFunction::Less,
            depth_format: super::GROUND_DEPTH_FORMAT,
            fragment: Some(LightFragment {
                entry: "fs_white",
                source: Some(shaders::ground_map()),
                format: super::GROUND_FORMAT,
            }),
            ..LightView::shadow_frame(layouts)
        },
    )
}

/// A pipeline drawing meshes from the sun with a vertex stage of `shadow.wgsl`, nothing
/// culled: depth only, or with a fragment stage writing one colour target.
pub(crate) struct LightView<'a> {
    pub label: &'a str,
    pub groups: [Option<&'a wgpu::BindGroupLayout>; 4],
    pub vertex: &'a str,
    pub compare: wgpu::CompareFunction,
    pub bias: wgpu::DepthBiasState,
    /// The depth target's format.
    pub depth_format: wgpu::TextureFormat,
    pub fragment: Option<LightFragment<'a>>,
    /// Without `fragment`: the parts' alpha test as the fragment stage (false: none, for
    /// what has no texture to cut out).
    pub cutout: bool,
}

/// The fragment stage of a [`LightView`]: its entry point in `source` (None: `shadow.wgsl`
/// itself) and the format of its one target.
pub(crate) struct LightFragment<'a> {
    pub entry: &'a str,
    pub source: Option<String>,
    pub format: wgpu::TextureFormat,
}

impl<'a> LightView<'a> {
    /// `vs_shadow` with the frame uniforms of a light (`shadow_frame`), the trees and the
    /// parts; depth only, unbiased.
    pub fn shadow_frame(layouts: &'a Layouts) -> Self {
        Self {
            label: "light view",
            groups: [
                Some(&layouts.shadow_frame),
                Some(&layouts.trees),
                Some(&layouts.parts),
                None,
            ],
            vertex: "vs_shadow",
            compare: wgpu::CompareFunction::LessEqual,
            bias: Default::default(),
            depth_format: SHADOW_FORMAT,
            fragment: None,
            cutout: true,
        }
    }
}

pub(crate) fn light_view_pipeline(
    device: &wgpu::Device,
    p: &LightView<'_>,
) -> wgpu::RenderPipeline {
    let module = wgsl_module(device, "shadow.wgsl", &shaders::shadow());
    let groups = match p.groups.iter().rposition(Option::is_some) {
        Some(last) => &p.groups[..=last],
        None => &p.groups[..0],
    };
    let layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
        label: Some(p.label),
        bind_group_layouts: groups,
        immediate_size: 0,
    });
    let fragment_module = p.fragment.as_ref().and_then(|f| {
        f.source
            .as_ref()
            .map(|source| wgsl_module(device, f.entry, source))
    });
    let targets = p.fragment.as_ref().map(|f| {
        [Some(wgpu::ColorTargetState {
            format: f.format,
            blend: None,
            write_mask: wgpu::ColorWrites::ALL,
        })]
    });
    // Depth only: the parts' alpha test (an imported tree's cards), no target.
    let cutout = wgpu::FragmentState {
        module: &module,
        entry_point: Some("fs_shadow_cutout"),
        compilation_options: crate::render::shaders::frame_options(),
        targets: &[],
    };
    device.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
        label: Some(p.label),
        layout: Some(&layout),
        vertex: wgpu::VertexState {
            module: &module,
            entry_point: Some(p.vertex),
            compilation_options: crate::render::shaders::frame_options(),
            buffers: &[Some(vertex_layout())],
        },
        primitive: wgpu::PrimitiveState {
            cull_mode: None,
            ..Default::default()
        },
        depth_stencil: Some(wgpu::DepthStencilState {
            format: p.depth_format,
            depth_write_enabled: Some(true),
            depth_compare: Some(p.compare),
            stencil: Default::default(),
            bias: p.bias,
        }),
        multisample: Default::default(),
        fragment: p
            .fragment
            .as_ref()
            .zip(targets.as_ref())
            .map(|(f, targets)| wgpu::FragmentState {
                module: fragment_module.as_ref().unwrap_or(&module),
                entry_point: Some(f.entry),
                compilation_options: crate::render::shaders::frame_options(),
                targets,
            })
            .or(p.cutout.then_some(cutout)),
        multiview_mask: None,
        cache: None,
    })
}

/// The two pipelines a pass draws meshes with: bark and ground (back faces culled), and
/// foliage (two-sided).
#[derive(Clone, Copy)]
pub struct MeshPipelines<'a> {
    pub opaque: &'a wgpu::RenderPipeline,
    pub foliage: &'a wgpu::RenderPipeline,
}

/// Pipelines that draw into a colour target of one format.
pub struct ColorPipelines {
    pub opaque: wgpu::RenderPipeline,
    pub foliage: wgpu::RenderPipeline,
    /// The same two, dithering each tree by its opacity (`hybrid`'s cross-fade; kept apart
    /// so that the other draws keep their early depth test).
    pub faded_opaque: wgpu::RenderPipeline,
    pub faded_foliage: wgpu::RenderPipeline,
    pub sky: wgpu::RenderPipeline,
    /// The overdraw view's heat map over the finished frame (no depth).
    pub overdraw: wgpu::RenderPipeline,
}

impl ColorPipelines {
    pub fn meshes(&self) -> MeshPipelines<'_> {
        MeshPipelines {
            opaque: &self.opaque,
            foliage: &self.foliage,
        }
    }

    pub fn faded_meshes(&self) -> MeshPipelines<'_> {
        MeshPipelines {
            opaque: &self.faded_opaque,
            foliage: &self.faded_foliage,
        }
    }

    pub fn new(device: &wgpu::Device, layouts: &Layouts, format: wgpu::TextureFormat) -> Self {
        let geometry = GeometryPass::new(device, layouts, "geometry", None);
        let sky = wgsl_module(device, "sky.wgsl", &shaders::sky());
        let sky_layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("sky"),
            bind_group_layouts: &[Some(&layouts.frame)],
            immediate_size: 0,
        });
        let target = [Some(wgpu::ColorTargetState {
            format,
            blend: None,
            write_mask: wgpu::ColorWrites::ALL,
        })];
        let mesh_pipeline = |label: &str, cull_mode: Option<wgpu::Face>, fragment: &str| {
            geometry.pipeline(
                device,
                label,
                cull_mode,
                fragment,
                &target,
                MeshDepth::TESTED,
            )
        };
        let opaque = mesh_pipeline("geometry opaque", Some(wgpu::Face::Back), "fs_main");
        let foliage = mesh_pipeline("geometry foliage", None, "fs_main");
        let faded_opaque = mesh_pipeline("faded opaque", Some(wgpu::Face::Back), "fs_faded");
        let faded_foliage = mesh_pipeline("faded foliage", None, "fs_faded");
        let sky = device.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
            label: Some("sky"),
            layout: Some(&sky_layout),
            vertex: wgpu::VertexState {
                module: &sky,
                entry_point: Some("vs_sky"),
                compilation_options: crate::render::shaders::frame_options(),
                buffers: &[],
            },
            primitive: Default::default(),
            depth_stencil: Some(wgpu::DepthStencilState {
                format: DEPTH_FORMAT,
                depth_write_enabled: Some(false),
                depth_compare: Some(wgpu::CompareFunction::Always),
                stencil: Default::default(),
                bias: Default::default(),
            }),
            multisample: Default::default(),
            fragment: Some(wgpu::FragmentState {
                module: &sky,
                entry_point: Some("fs_sky"),
                compilation_options: crate::render::shaders::frame_options(),
                targets: &target,
            }),
            multiview_mask: None,
            cache: None,
        });
        let overdraw_module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("overdraw.wgsl"),
            source: wgpu::ShaderSource::Wgsl(shaders::overdraw().into()),
        });
        let overdraw = device.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
            label: Some("overdraw"),
            layout: Some(&sky_layout),
            vertex: wgpu::VertexState {
                module: &overdraw_module,
                entry_point: Some("vs_sky"),
                compilation_options: crate::render::shaders::frame_options(),
                buffers: &[],
            },
            primitive: Default::default(),
            depth_stencil: None,
            multisample: Default::default(),
            fragment: Some(wgpu::FragmentState {
                module: &overdraw_module,
                entry_point: Some("fs_overdraw"),
                compilation_options: crate::render::shaders::frame_options(),
                targets: &target,
            }),
            multiview_mask: None,
            cache: None,
        });
        Self {
            opaque,
            faded_opaque,
            faded_foliage,
            foliage,
            sky,
            overdraw,
        }
    }
}

/// `geometry.wgsl` and a pipeline layout over the frame, the trees, the parts and, for some
/// passes, a fourth group: what every pass drawing the forest's meshes builds on.
pub(crate) struct GeometryPass {
    module: wgpu::ShaderModule,
    layout: wgpu::PipelineLayout,
}

/// How a mesh pipeline uses the depth buffer.
#[derive(Clone, Copy)]
pub(crate) struct MeshDepth {
    pub write: bool,
    pub compare: wgpu::CompareFunction,
}

impl MeshDepth {
    /// Tested and written, reversed Z: nearer is larger.
    pub const TESTED: Self = Self {
        write: true,
        compare: wgpu::CompareFunction::Greater,
    };
}

impl GeometryPass {
    pub fn new(
        device: &wgpu::Device,
        layouts: &Layouts,
        label: &str,
        group3: Option<&wgpu::BindGroupLayout>,
    ) -> Self {
        let module = wgsl_module(device, "geometry.wgsl", &shaders::geometry());
        let groups = [
            Some(&layouts.frame),
            Some(&layouts.trees),
            Some(&layouts.parts),
            group3,
        ];
        let count = if group3.is_some() { 4 } else { 3 };
        let layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some(label),
            bind_group_layouts: &groups[..count],
            immediate_size: 0,
        });
        Self { module, layout }
    }

    /// A pipeline drawing meshes with `vs_main` and `fragment` into `targets`, faces
    /// `cull_mode`d, using depth as `depth` says.
    pub fn pipeline(
        &self,
        device: &wgpu::Device,
        label: &str,
        cull_mode: Option<wgpu::Face>,
        fragment: &str,
        targets: &[Option<wgpu::ColorTargetState>],
        depth: MeshDepth,
    ) -> wgpu::RenderPipeline {
        device.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
            label: Some(label),
            layout: Some(&self.layout),
            vertex: wgpu::VertexState {
                module: &self.module,
                entry_point: Some("vs_main"),
                compilation_options: crate::render::shaders::frame_options(),
                buffers: &[Some(vertex_layout())],
            },
            primitive: wgpu::PrimitiveState {
                cull_mode,
                ..Default::default()
            },
            depth_stencil: Some(wgpu::DepthStencilState {
                format: DEPTH_FORMAT,
                depth_write_enabled: Some(depth.write),
                depth_compare: Some(depth.compare),
                stencil: Default::default(),
                bias: Default::default(),
            }),
            multisample: Default::default(),
            fragment: Some(wgpu::FragmentState {
                module: &self.module,
                entry_point: Some(fragment),
                compilation_options: crate::render::shaders::frame_options(),
                targets,
            }),
            multiview_mask: None,
            cache: None,
        })
    }
}

/// A pipeline drawing procedural instances (no vertex buffers) over the frame, blended
/// into one colour target and depth-tested (depth-written where `depth_write`): the
/// image-based methods' billboards, impostors and texel boxes, into the view or into the
/// ground alpha map.
pub struct Blended<'a> {
    /// Label, and the name of the WGSL module.
    pub label: &'a str,
    pub layouts: [&'a wgpu::BindGroupLayout; 2],
    pub source: String,
    pub vertex: &'a str,
    pub fragment: &'a str,
    pub format: wgpu::TextureFormat,
    pub blend: wgpu::BlendComponent,
    pub cull: Option<wgpu::Face>,
    pub depth: (wgpu::TextureFormat, wgpu::CompareFunction),
    /// Depth is written too (an alpha-tested, opaque draw).
    pub depth_write: bool,
}

pub fn blended_pipeline(device: &wgpu::Device, p: Blended<'_>) -> wgpu::RenderPipeline {
    let module = wgsl_module(device, p.label, &p.source);
    let layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
        label: Some(p.fragment),
        bind_group_layouts: &[Some(p.layouts[0]), Some(p.layouts[1])],
        immediate_size: 0,
    });
    device.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
        label: Some(p.fragment),
        layout: Some(&layout),
        vertex: wgpu::VertexState {
            module: &module,
            entry_point: Some(p.vertex),
            compilation_options: crate::render::shaders::frame_options(),
            buffers: &[],
        },
        primitive: wgpu::PrimitiveState {
            cull_mode: p.cull,
            ..Default::default()
        },
        depth_stencil: Some(wgpu::DepthStencilState {
            format: p.depth.0,
            depth_write_enabled: Some(p.depth_write),
            depth_compare: Some(p.depth.1),
            stencil: Default::default(),
            bias: Default::default(),
        }),
        multisample: Default::default(),
        fragment: Some(wgpu::FragmentState {
            module: &module,
            entry_point: Some(p.fragment),
            compilation_options: crate::render::shaders::frame_options(),
            targets: &[Some(wgpu::ColorTargetState {
                format: p.format,
                blend: Some(wgpu::BlendState {
                    color: p.blend,
                    alpha: p.blend,
                }),
                write_mask: wgpu::ColorWrites::ALL,
            })],
        }),
        multiview_mask: None,
        cache: None,
    })
}

/// Vertex buffer layout of `model::mesh::Vertex`.
pub fn vertex_layout() -> wgpu::VertexBufferLayout<'static> {
    const ATTRS: [wgpu::VertexAttribute; 5] = wgpu::vertex_attr_array![
        0 => Float32x3,
        1 => Float32x3,
        2 => Float32x3,
        3 => Float32,
        4 => Float32x2,
    ];
    wgpu::VertexBufferLayout {
        array_stride: std::mem::size_of::<Vertex>() as u64,
        step_mode: wgpu::VertexStepMode::Vertex,
        attributes: &ATTRS,
    }
}
