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

pub use assets::{MAX_TEXELS, TexelAssets, TexelPipelines};
pub use prepare::{TexelFrame, prepare};
pub use scene::{SpeciesVolume, TexelScene};
pub use settings::{TexelMode, TexelSettings, TexelStats};

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
        },
    )
}
