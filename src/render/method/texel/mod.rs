//! The `texel` method: every tree as a volumetric texel, its species' baked volumes
//! (`bake::texel`) in one 3D texture, drawn with slices parallel to the screen
//! (Decaudin-Neyret 2009; `shaders/texel.wgsl`). Per frame, on the CPU ([`prepare`]): each
//! visible tree's box, its slice count from the criteria of [`crate::slices`] (the box's
//! depth along the view on screen against d0 and d1 pixels), the mip level its voxels project
//! to, the 3 nearest baked lights of the sun in its frame with their weights, the tree-level
//! VCM factors at its box corners; sorted back to front. On the GPU: one instanced draw of
//! boxes (a second for the boxes the eye is inside, drawn from their far faces).
//!
//! The seeds' own way, three axis stacks of 2D slices with pre-composited levels, is
//! [`stacks`] (`--texel-mode stacks`). Beyond `tile_distance`, the trees of a whole
//! forest-cover tile are drawn as one volume that follows the ground ([`tiles`]).

mod assets;
pub mod knobs;
pub mod method;
pub mod polygons;
mod prepare;
mod scene;
pub mod settings;
pub mod stacks;
pub mod tiles;

pub use assets::{MAX_TEXELS, PendingTexel, TexelAssets, TexelPipelines};
pub use prepare::{TexelFrame, prepare};
pub use scene::{SpeciesVolume, TexelScene};
pub use settings::{TexelMode, TexelSettings, TexelStats};

use std::collections::HashMap;

/// One texel as `texel.wgsl` reads it (`struct Texel`), byte for byte.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
pub struct TexelGpu {
    pub model: [[f32; 4]; 4],
    pub world_to_object: [[f32; 4]; 4],
    pub box_min: [f32; 3],
    pub spacing: f32,
    pub box_size: [f32; 3],
    pub voxel: f32,
    pub atlas_origin: [f32; 3],
    pub volume_dw: f32,
    pub atlas_extent: [f32; 3],
    pub lod: f32,
    pub light_index: [u32; 3],
    pub mode: u32,
    pub light_weight: [f32; 3],
    pub lights: u32,
    pub tint: [f32; 3],
    pub scale: f32,
    pub vcm_min: [f32; 3],
    pub max_steps: f32,
    pub vcm_inv_size: [f32; 3],
    pub slices: f32,
    pub vcm_direct: [[f32; 4]; 2],
    pub vcm_sky: [[f32; 4]; 2],
}

/// A pipeline drawing `vertex` and `fragment` of texel.wgsl into one `format` target over
/// what is behind (premultiplied "over"), faces `cull`ed, depth-tested against the terrain
/// (reversed Z) and never written: what the stacks, tiles and polygons draw with.
pub(crate) fn over_pipeline(
    device: &wgpu::Device,
    layouts: [&wgpu::BindGroupLayout; 2],
    label: &str,
    (vertex, fragment): (&str, &str),
    format: wgpu::TextureFormat,
    cull: Option<wgpu::Face>,
) -> wgpu::RenderPipeline {
    crate::render::pipelines::blended_pipeline(
        device,
        crate::render::pipelines::Blended {
            label,
            layouts,
            source: crate::render::shaders::texel(),
            vertex,
            fragment,
            format,
            blend: wgpu::BlendComponent {
                src_factor: wgpu::BlendFactor::One,
                dst_factor: wgpu::BlendFactor::OneMinusSrcAlpha,
                operation: wgpu::BlendOperation::Add,
            },
            cull,
            depth: (crate::render::DEPTH_FORMAT, wgpu::CompareFunction::Greater),
            depth_write: false,
        },
    )
}

/// The layout of bindings 0 to 2 of the texel group (see [`texel_entries`]).
pub(crate) fn texel_layout_entries() -> [wgpu::BindGroupLayoutEntry; 3] {
    use crate::render::pipelines::{FILTERABLE, sampler_entry, storage_entry, texture_entry};
    [
        storage_entry(0, wgpu::ShaderStages::VERTEX_FRAGMENT),
        texture_entry(1, FILTERABLE, wgpu::TextureViewDimension::D3),
        sampler_entry(2, wgpu::SamplerBindingType::Filtering),
    ]
}

/// Bindings 0 to 2 of the texel group (`texel.wgsl`'s `texels`, `volumes`, `volume_sampler`):
/// the records, the volumes and their sampler, which the polygons bind too.
pub(crate) fn texel_entries<'a>(
    records: &'a wgpu::Buffer,
    volumes: &'a wgpu::TextureView,
    sampler: &'a wgpu::Sampler,
) -> [wgpu::BindGroupEntry<'a>; 3] {
    [
        wgpu::BindGroupEntry {
            binding: 0,
            resource: records.as_entire_binding(),
        },
        wgpu::BindGroupEntry {
            binding: 1,
            resource: wgpu::BindingResource::TextureView(volumes),
        },
        wgpu::BindGroupEntry {
            binding: 2,
            resource: wgpu::BindingResource::Sampler(sampler),
        },
    ]
}

/// How an [`OverPass`] draws: its pipelines' label, texel.wgsl entry points (vertex,
/// fragment), culled faces, and what a count drawn counts.
pub(crate) struct OverStyle {
    pub label: &'static str,
    pub entry_points: (&'static str, &'static str),
    pub cull: Option<wgpu::Face>,
    pub draw: OverDraw,
}

/// What a count drawn counts: vertices of one instance (the polygons), or instances of a
/// fixed number of vertices (6 for a stack quad, 36 for a tile box).
#[derive(Clone, Copy)]
pub(crate) enum OverDraw {
    Vertices,
    Instances(u32),
}

/// What the stacks, tiles and polygons each draw with: their group 1 (its layout and the
/// frame's bind group once bound) and one [`over_pipeline`] per colour format.
pub(crate) struct OverPass {
    layout: wgpu::BindGroupLayout,
    bind_group: Option<wgpu::BindGroup>,
    pipelines: HashMap<wgpu::TextureFormat, wgpu::RenderPipeline>,
    style: &'static OverStyle,
}

impl OverPass {
    /// Drops the pipelines built so far.
    pub fn forget_pipelines(&mut self) {
        self.pipelines.clear();
    }

    /// A pass whose group 1 is `entries`, its layout and bind groups labelled `label`.
    pub fn new(
        device: &wgpu::Device,
        label: &str,
        entries: &[wgpu::BindGroupLayoutEntry],
        style: &'static OverStyle,
    ) -> Self {
        Self {
            layout: device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
                label: Some(label),
                entries,
            }),
            bind_group: None,
            pipelines: HashMap::new(),
            style,
        }
    }

    /// Binds `entries` as the frame's group 1.
    pub fn bind(&mut self, device: &wgpu::Device, label: &str, entries: &[wgpu::BindGroupEntry]) {
        self.bind_group = Some(device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some(label),
            layout: &self.layout,
            entries,
        }));
    }

    pub fn is_bound(&self) -> bool {
        self.bind_group.is_some()
    }

    /// The pipeline drawing into `format` (built on first use).
    pub fn pipeline(
        &mut self,
        device: &wgpu::Device,
        frame_layout: &wgpu::BindGroupLayout,
        format: wgpu::TextureFormat,
    ) -> &wgpu::RenderPipeline {
        let (layout, style) = (&self.layout, self.style);
        self.pipelines.entry(format).or_insert_with(|| {
            over_pipeline(
                device,
                [frame_layout, layout],
                style.label,
                style.entry_points,
                format,
                style.cull,
            )
        })
    }

    /// Draws `count` (vertices or instances, as the style says) with `pipeline` and the
    /// bound group 1 (the pass has group 0 bound); nothing when `count` is 0 or nothing is
    /// bound yet.
    pub fn draw(
        &self,
        pass: &mut wgpu::RenderPass<'_>,
        pipeline: &wgpu::RenderPipeline,
        count: u32,
    ) {
        if let (Some(bg), true) = (&self.bind_group, count > 0) {
            pass.set_pipeline(pipeline);
            pass.set_bind_group(1, bg, &[]);
            match self.style.draw {
                OverDraw::Vertices => pass.draw(0..count, 0..1),
                OverDraw::Instances(vertices) => pass.draw(0..vertices, 0..count),
            }
        }
    }
}
