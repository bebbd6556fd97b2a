//! Bind group layouts and render pipelines of the geometry method, built once per colour
//! format (a window surface is often BGRA, offscreen targets RGBA).

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

fn storage_entry(binding: u32) -> wgpu::BindGroupLayoutEntry {
    buffer_entry(
        binding,
        wgpu::ShaderStages::VERTEX,
        wgpu::BufferBindingType::Storage { read_only: true },
    )
}

impl Layouts {
    pub fn new(device: &wgpu::Device) -> Self {
        let vf = wgpu::ShaderStages::VERTEX_FRAGMENT;
        let frame = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("frame"),
            entries: &[
                uniform_entry(0, vf),
                wgpu::BindGroupLayoutEntry {
                    binding: 1,
                    visibility: wgpu::ShaderStages::FRAGMENT,
                    ty: wgpu::BindingType::Texture {
                        sample_type: wgpu::TextureSampleType::Depth,
                        view_dimension: wgpu::TextureViewDimension::D2Array,
                        multisampled: false,
                    },
                    count: None,
                },
                wgpu::BindGroupLayoutEntry {
                    binding: 2,
                    visibility: wgpu::ShaderStages::FRAGMENT,
                    ty: wgpu::BindingType::Sampler(wgpu::SamplerBindingType::Comparison),
                    count: None,
                },
                wgpu::BindGroupLayoutEntry {
                    binding: 3,
                    visibility: wgpu::ShaderStages::FRAGMENT,
                    ty: wgpu::BindingType::Texture {
                        sample_type: wgpu::TextureSampleType::Float { filterable: true },
                        view_dimension: wgpu::TextureViewDimension::D2,
                        multisampled: false,
                    },
                    count: None,
                },
                wgpu::BindGroupLayoutEntry {
                    binding: 4,
                    visibility: wgpu::ShaderStages::FRAGMENT,
                    ty: wgpu::BindingType::Sampler(wgpu::SamplerBindingType::Filtering),
                    count: None,
                },
                wgpu::BindGroupLayoutEntry {
                    binding: 5,
                    visibility: wgpu::ShaderStages::FRAGMENT,
                    ty: wgpu::BindingType::Texture {
                        sample_type: wgpu::TextureSampleType::Depth,
                        view_dimension: wgpu::TextureViewDimension::D2Array,
                        multisampled: false,
                    },
                    count: None,
                },
                // The reference's sky visibility volume and its placement.
                wgpu::BindGroupLayoutEntry {
                    binding: 6,
                    visibility: wgpu::ShaderStages::FRAGMENT,
                    ty: wgpu::BindingType::Texture {
                        sample_type: wgpu::TextureSampleType::Float { filterable: true },
                        view_dimension: wgpu::TextureViewDimension::D3,
                        multisampled: false,
                    },
                    count: None,
                },
                uniform_entry(7, wgpu::ShaderStages::FRAGMENT),
                // The overdraw view's counters (src/render/overdraw.rs).
                buffer_entry(
                    8,
                    wgpu::ShaderStages::FRAGMENT,
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
            entries: &[storage_entry(0)],
        });
        let parts = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("parts"),
            entries: &[
                storage_entry(0),
                uniform_entry(1, wgpu::ShaderStages::VERTEX),
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

/// The shadow pipeline (independent of the colour format): depth only, biased.
pub fn shadow_pipeline(device: &wgpu::Device, layouts: &Layouts) -> wgpu::RenderPipeline {
    light_view_pipeline(
        device,
        &LightView {
            label: "shadow",
            compare: wgpu::CompareFunction::LessEqual,
            bias: SHADOW_BIAS,
            ..LightView::shadow_frame(layouts)
        },
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
    pub fragment: Option<LightFragment<'a>>,
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
            fragment: None,
        }
    }
}

pub(crate) fn light_view_pipeline(
    device: &wgpu::Device,
    p: &LightView<'_>,
) -> wgpu::RenderPipeline {
    let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
        label: Some("shadow.wgsl"),
        source: wgpu::ShaderSource::Wgsl(shaders::shadow().into()),
    });
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
        f.source.as_ref().map(|source| {
            device.create_shader_module(wgpu::ShaderModuleDescriptor {
                label: Some(f.entry),
                source: wgpu::ShaderSource::Wgsl(source.as_str().into()),
            })
        })
    });
    let targets = p.fragment.as_ref().map(|f| {
        [Some(wgpu::ColorTargetState {
            format: f.format,
            blend: None,
            write_mask: wgpu::ColorWrites::ALL,
        })]
    });
    device.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
        label: Some(p.label),
        layout: Some(&layout),
        vertex: wgpu::VertexState {
            module: &module,
            entry_point: Some(p.vertex),
            compilation_options: Default::default(),
            buffers: &[Some(vertex_layout())],
        },
        primitive: wgpu::PrimitiveState {
            cull_mode: None,
            ..Default::default()
        },
        depth_stencil: Some(wgpu::DepthStencilState {
            format: SHADOW_FORMAT,
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
                compilation_options: Default::default(),
                targets,
            }),
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
        let geometry = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("geometry.wgsl"),
            source: wgpu::ShaderSource::Wgsl(shaders::geometry().into()),
        });
        let sky = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("sky.wgsl"),
            source: wgpu::ShaderSource::Wgsl(shaders::sky().into()),
        });
        let layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("geometry"),
            bind_group_layouts: &[
                Some(&layouts.frame),
                Some(&layouts.trees),
                Some(&layouts.parts),
            ],
            immediate_size: 0,
        });
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
            mesh_pipeline(
                device, &layout, &geometry, label, cull_mode, fragment, &target,
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
                compilation_options: Default::default(),
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
                compilation_options: Default::default(),
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
                compilation_options: Default::default(),
                buffers: &[],
            },
            primitive: Default::default(),
            depth_stencil: None,
            multisample: Default::default(),
            fragment: Some(wgpu::FragmentState {
                module: &overdraw_module,
                entry_point: Some("fs_overdraw"),
                compilation_options: Default::default(),
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

/// A pipeline drawing meshes of `geometry.wgsl` (`vs_main` and `fragment`) into one colour
/// target, depth-tested and written (reversed Z: nearer is larger).
pub(crate) fn mesh_pipeline(
    device: &wgpu::Device,
    layout: &wgpu::PipelineLayout,
    module: &wgpu::ShaderModule,
    label: &str,
    cull_mode: Option<wgpu::Face>,
    fragment: &str,
    target: &[Option<wgpu::ColorTargetState>],
) -> wgpu::RenderPipeline {
    device.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
        label: Some(label),
        layout: Some(layout),
        vertex: wgpu::VertexState {
            module,
            entry_point: Some("vs_main"),
            compilation_options: Default::default(),
            buffers: &[Some(vertex_layout())],
        },
        primitive: wgpu::PrimitiveState {
            cull_mode,
            ..Default::default()
        },
        depth_stencil: Some(wgpu::DepthStencilState {
            format: DEPTH_FORMAT,
            depth_write_enabled: Some(true),
            depth_compare: Some(wgpu::CompareFunction::Greater),
            stencil: Default::default(),
            bias: Default::default(),
        }),
        multisample: Default::default(),
        fragment: Some(wgpu::FragmentState {
            module,
            entry_point: Some(fragment),
            compilation_options: Default::default(),
            targets: target,
        }),
        multiview_mask: None,
        cache: None,
    })
}

/// A pipeline drawing procedural instances (no vertex buffers) over the frame, blended
/// into one colour target and depth-tested, never depth-written: the image-based methods'
/// billboards and texel boxes, into the view or into the ground alpha map.
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
}

pub fn blended_pipeline(device: &wgpu::Device, p: Blended<'_>) -> wgpu::RenderPipeline {
    let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
        label: Some(p.label),
        source: wgpu::ShaderSource::Wgsl(p.source.into()),
    });
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
            compilation_options: Default::default(),
            buffers: &[],
        },
        primitive: wgpu::PrimitiveState {
            cull_mode: p.cull,
            ..Default::default()
        },
        depth_stencil: Some(wgpu::DepthStencilState {
            format: p.depth.0,
            depth_write_enabled: Some(false),
            depth_compare: Some(p.depth.1),
            stencil: Default::default(),
            bias: Default::default(),
        }),
        multisample: Default::default(),
        fragment: Some(wgpu::FragmentState {
            module: &module,
            entry_point: Some(p.fragment),
            compilation_options: Default::default(),
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
    const ATTRS: [wgpu::VertexAttribute; 4] = wgpu::vertex_attr_array![
        0 => Float32x3,
        1 => Float32x3,
        2 => Float32x3,
        3 => Float32,
    ];
    wgpu::VertexBufferLayout {
        array_stride: std::mem::size_of::<Vertex>() as u64,
        step_mode: wgpu::VertexStepMode::Vertex,
        attributes: &ATTRS,
    }
}
