//! The `btf` method's far canopy: past the distance where a typical crown is narrower than
//! a few pixels on screen (the `canopy_px` knob), the forest is drawn as one layer over the
//! ground, whose cost follows the pixels it covers rather than the trees it stands for.
//!
//! - [`map`] bakes, on the CPU at load, the forest seen from above from the trees' own
//!   geometry: per texel the crowns' coverage and the tree seen there, and the lid (the
//!   surface it is drawn on).
//! - The far trees' build pass (`btf_far_canopy.wgsl`) lights each tree past the band's
//!   start as its tree-level billboard would be on average this frame (the BTF images'
//!   means, its VCM factors), and fades its billboard out across the band.
//! - `canopy.wgsl` draws the lid in tiles of [`TILE_CELLS`]² cells, each pixel taking the
//!   colours of the trees the map shows there, faded in across the same band. It needs the
//!   far trees on the GPU (`gpu_far`): without them there is no canopy and every tree is a
//!   billboard.

pub mod map;

use glam::{Vec2, Vec3};

use self::map::{CanopyMap, LID_TEXELS};
use super::far::CanopyFrame;
use super::settings::BtfSettings;
use crate::Result;
use crate::model::mesh::Aabb;
use crate::render::GpuContext;
use crate::render::camera::Frustum;
use crate::render::pipelines::{
    FILTERABLE, buffer_entry, sampler_entry, storage_buffer_of, storage_entry, write_growing,
    write_texels,
};

/// The mean of an sRGB-encoded RGBA8 image (`lut` decoding its bytes): linear colour
/// (premultiplied as stored) and coverage. A far tree's colour is made of its images' means.
pub fn image_mean(rgba: &[u8], lut: &[f32]) -> [f32; 4] {
    let mut sum = [0.0f64; 4];
    for px in rgba.chunks_exact(4) {
        for c in 0..3 {
            sum[c] += f64::from(lut[usize::from(px[c])]);
        }
        sum[3] += f64::from(px[3]) / 255.0;
    }
    let n = (rgba.len() / 4).max(1) as f64;
    sum.map(|v| (v / n) as f32)
}

/// Lid cells per tile side: a tile of 16 x 16 cells of 4 m is 64 m across.
pub const TILE_CELLS: u32 = 16;

/// The canopy pass's uniforms (`Canopy` in `canopy.wgsl`).
#[repr(C)]
#[derive(Clone, Copy, Debug, bytemuck::Pod, bytemuck::Zeroable)]
pub struct CanopyGpuParams {
    pub origin: [f32; 2],
    pub texel: f32,
    pub side: u32,
    pub levels: u32,
    pub lid_side: u32,
    pub lid_texels: u32,
    pub tile_cells: u32,
    pub near: f32,
    pub far: f32,
    pub show_overlay: u32,
    pub _pad0: u32,
    pub overlay: [f32; 3],
    pub _pad1: u32,
}

/// One tile of the lid that crowns cover: its first cell and its box.
#[derive(Clone, Copy, Debug)]
struct Tile {
    cell: [u32; 2],
    bounds: Aabb,
}

/// The canopy's GPU state: the map's levels, the lid, the tiles drawn this frame.
pub struct CanopyGpu {
    params: CanopyGpuParams,
    uniform: wgpu::Buffer,
    _cover: wgpu::Texture,
    _tree: wgpu::Texture,
    _lid: wgpu::Texture,
    cover_view: wgpu::TextureView,
    tree_view: wgpu::TextureView,
    lid_view: wgpu::TextureView,
    sampler: wgpu::Sampler,
    layout: wgpu::BindGroupLayout,
    /// Tiles that hold crowns.
    tiles: Vec<Tile>,
    /// This frame's tiles, their count, and the bind group over them and the colours.
    tile_buffer: wgpu::Buffer,
    drawn: u32,
    bind_group: Option<wgpu::BindGroup>,
    pipeline: Option<(wgpu::TextureFormat, wgpu::RenderPipeline)>,
    /// A typical crown's width (m).
    pub crown_width: f32,
    /// GPU bytes of the map and the lid.
    pub bytes: u64,
    /// The trees that stand in the map.
    pub trees: u32,
}

impl CanopyGpu {
    /// Drops the pipeline built so far.
    pub fn forget_pipeline(&mut self) {
        self.pipeline = None;
    }

    /// Uploads `map`; its coverage is read through `sampler` (linear, clamped, mipmapped:
    /// the BTF images' own).
    pub fn new(ctx: &GpuContext, map: &CanopyMap, sampler: &wgpu::Sampler) -> Result<Self> {
        let side = map.levels.first().map_or(1, |l| l.side);
        let max = ctx.device.limits().max_texture_dimension_2d;
        if side > max || map.lid_side > max {
            return Err(crate::Error::BadInput(format!(
                "the far canopy's map needs {side}² texels but this GPU allows {max}"
            )));
        }
        let levels = map.levels.len() as u32;
        let texture = |label: &str, format: wgpu::TextureFormat, side: u32, mips: u32| {
            ctx.device.create_texture(&wgpu::TextureDescriptor {
                label: Some(label),
                size: wgpu::Extent3d {
                    width: side,
                    height: side,
                    depth_or_array_layers: 1,
                },
                mip_level_count: mips,
                sample_count: 1,
                dimension: wgpu::TextureDimension::D2,
                format,
                usage: wgpu::TextureUsages::TEXTURE_BINDING | wgpu::TextureUsages::COPY_DST,
                view_formats: &[],
            })
        };
        let (cover, tree, lid) = ctx.checked("allocating the far canopy's map", || {
            (
                texture("canopy cover", wgpu::TextureFormat::R8Unorm, side, levels),
                texture("canopy trees", wgpu::TextureFormat::R32Uint, side, levels),
                texture("canopy lid", wgpu::TextureFormat::R32Float, map.lid_side, 1),
            )
        })?;
        let mut bytes = 0u64;
        for (i, l) in map.levels.iter().enumerate() {
            write_level(ctx, &cover, i as u32, l.side, &l.cover, 1);
            write_level(
                ctx,
                &tree,
                i as u32,
                l.side,
                bytemuck::cast_slice(&l.tree),
                4,
            );
            bytes += 5 * u64::from(l.side) * u64::from(l.side);
        }
        write_level(
            ctx,
            &lid,
            0,
            map.lid_side,
            bytemuck::cast_slice(&map.lid),
            4,
        );
        bytes += 4 * map.lid.len() as u64;
        let view = |t: &wgpu::Texture| t.create_view(&wgpu::TextureViewDescriptor::default());
        let params = CanopyGpuParams {
            origin: map.origin.to_array(),
            texel: map.texel,
            side,
            levels,
            lid_side: map.lid_side,
            lid_texels: LID_TEXELS,
            tile_cells: TILE_CELLS,
            near: 0.0,
            far: 0.0,
            show_overlay: 0,
            _pad0: 0,
            overlay: [1.0; 3],
            _pad1: 0,
        };
        let uniform = ctx.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("canopy params"),
            size: std::mem::size_of::<CanopyGpuParams>() as u64,
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        Ok(Self {
            params,
            uniform,
            cover_view: view(&cover),
            tree_view: view(&tree),
            lid_view: view(&lid),
            _cover: cover,
            _tree: tree,
            _lid: lid,
            sampler: sampler.clone(),
            layout: layout(&ctx.device),
            tiles: tiles_of(map),
            tile_buffer: storage_buffer_of::<[u32; 2]>(&ctx.device, "canopy tiles", 64),
            drawn: 0,
            bind_group: None,
            pipeline: None,
            crown_width: map.crown_width,
            bytes,
            trees: map.trees,
        })
    }

    /// What the far trees' build pass needs for a frame with `settings` lit by `lights`
    /// (sun, sky, ground); None when the knobs leave the canopy out.
    pub fn frame(&self, settings: &BtfSettings, lights: [Vec3; 3]) -> Option<CanopyFrame> {
        (settings.far_canopy && self.crown_width > 0.0 && settings.canopy_px > 0.0).then_some(
            CanopyFrame {
                crown_width: self.crown_width,
                below_px: settings.canopy_px,
                lights,
            },
        )
    }

    /// This frame's tiles: those holding crowns, in `frustum`, reaching past the band's
    /// start `band.0` from `eye`; `overlay` colours every pixel (the LOD view). Returns how
    /// many are drawn.
    pub fn prepare(
        &mut self,
        ctx: &GpuContext,
        eye: Vec3,
        frustum: &Frustum,
        band: (f32, f32),
        overlay: Option<[f32; 3]>,
        colours: &wgpu::Buffer,
    ) -> u32 {
        let drawn: Vec<[u32; 2]> = self
            .tiles
            .iter()
            .filter(|t| farthest(&t.bounds, eye) > band.0 && frustum.intersects(&t.bounds))
            .map(|t| t.cell)
            .collect();
        self.params.near = band.0;
        self.params.far = band.1;
        self.params.show_overlay = u32::from(overlay.is_some());
        self.params.overlay = overlay.unwrap_or([1.0; 3]);
        ctx.queue
            .write_buffer(&self.uniform, 0, bytemuck::bytes_of(&self.params));
        let grown = write_growing(ctx, &mut self.tile_buffer, "canopy tiles", &drawn);
        if grown || self.bind_group.is_none() {
            self.bind_group = Some(self.make_bind_group(ctx, colours));
        }
        self.drawn = drawn.len() as u32;
        self.drawn
    }

    fn make_bind_group(&self, ctx: &GpuContext, colours: &wgpu::Buffer) -> wgpu::BindGroup {
        let tex = |binding, view| wgpu::BindGroupEntry {
            binding,
            resource: wgpu::BindingResource::TextureView(view),
        };
        ctx.device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("canopy"),
            layout: &self.layout,
            entries: &[
                wgpu::BindGroupEntry {
                    binding: 0,
                    resource: self.uniform.as_entire_binding(),
                },
                tex(1, &self.cover_view),
                tex(2, &self.tree_view),
                tex(3, &self.lid_view),
                wgpu::BindGroupEntry {
                    binding: 4,
                    resource: wgpu::BindingResource::Sampler(&self.sampler),
                },
                wgpu::BindGroupEntry {
                    binding: 5,
                    resource: colours.as_entire_binding(),
                },
                wgpu::BindGroupEntry {
                    binding: 6,
                    resource: self.tile_buffer.as_entire_binding(),
                },
            ],
        })
    }

    /// Builds the pipeline for `format` if it has none for it.
    pub fn ensure_pipeline(
        &mut self,
        device: &wgpu::Device,
        frame_layout: &wgpu::BindGroupLayout,
        format: wgpu::TextureFormat,
    ) {
        if self.pipeline.as_ref().is_some_and(|p| p.0 == format) {
            return;
        }
        let over = wgpu::BlendComponent {
            src_factor: wgpu::BlendFactor::One,
            dst_factor: wgpu::BlendFactor::OneMinusSrcAlpha,
            operation: wgpu::BlendOperation::Add,
        };
        let pipeline = crate::render::pipelines::blended_pipeline(
            device,
            crate::render::pipelines::Blended {
                label: "canopy.wgsl",
                layouts: [frame_layout, &self.layout],
                source: crate::render::shaders::canopy(),
                vertex: "vs_canopy",
                fragment: "fs_canopy",
                format,
                blend: over,
                cull: None,
                depth: (crate::render::DEPTH_FORMAT, wgpu::CompareFunction::Greater),
                depth_write: false,
            },
        );
        self.pipeline = Some((format, pipeline));
    }

    /// Draws this frame's tiles (the frame's bind group 0 set); false when there are none.
    pub fn draw(&self, pass: &mut wgpu::RenderPass<'_>) -> bool {
        let (Some((_, pipeline)), Some(bind_group)) = (&self.pipeline, &self.bind_group) else {
            return false;
        };
        if self.drawn == 0 {
            return false;
        }
        pass.set_pipeline(pipeline);
        pass.set_bind_group(1, bind_group, &[]);
        pass.draw(0..6 * TILE_CELLS * TILE_CELLS, 0..self.drawn);
        true
    }
}

/// The canopy pass's bind group layout (`canopy.wgsl`'s group 1).
fn layout(device: &wgpu::Device) -> wgpu::BindGroupLayout {
    use wgpu::ShaderStages as S;
    let both = S::VERTEX | S::FRAGMENT;
    let texture = |binding, sample_type, visibility| wgpu::BindGroupLayoutEntry {
        binding,
        visibility,
        ty: wgpu::BindingType::Texture {
            sample_type,
            view_dimension: wgpu::TextureViewDimension::D2,
            multisampled: false,
        },
        count: None,
    };
    device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
        label: Some("canopy"),
        entries: &[
            buffer_entry(0, both, wgpu::BufferBindingType::Uniform),
            texture(1, FILTERABLE, S::FRAGMENT),
            texture(2, wgpu::TextureSampleType::Uint, S::FRAGMENT),
            texture(
                3,
                wgpu::TextureSampleType::Float { filterable: false },
                S::VERTEX,
            ),
            sampler_entry(4, wgpu::SamplerBindingType::Filtering),
            storage_entry(5, S::FRAGMENT),
            storage_entry(6, S::VERTEX),
        ],
    })
}

/// Writes one level of a square one-channel texture of `bytes_per` bytes a texel.
fn write_level(
    ctx: &GpuContext,
    texture: &wgpu::Texture,
    level: u32,
    side: u32,
    data: &[u8],
    bytes_per: u32,
) {
    let size = glam::UVec3::new(side, side, 1);
    write_texels(
        &ctx.queue,
        texture,
        level,
        glam::UVec3::ZERO,
        data,
        size,
        bytes_per,
    );
}

/// The tiles of the lid that hold crowns, with their boxes (the lid's heights over them).
fn tiles_of(map: &CanopyMap) -> Vec<Tile> {
    let Some(l0) = map.levels.first() else {
        return Vec::new();
    };
    let cells = map.lid_side.saturating_sub(1);
    let step = map.texel * LID_TEXELS as f32;
    let mut out = Vec::new();
    for tj in (0..cells).step_by(TILE_CELLS as usize) {
        for ti in (0..cells).step_by(TILE_CELLS as usize) {
            // Any covered texel in the tile?
            let (x0, z0) = (ti * LID_TEXELS, tj * LID_TEXELS);
            let (x1, z1) = (
                ((ti + TILE_CELLS) * LID_TEXELS).min(l0.side),
                ((tj + TILE_CELLS) * LID_TEXELS).min(l0.side),
            );
            let covered =
                (z0..z1).any(|z| (x0..x1).any(|x| l0.cover[(z * l0.side + x) as usize] > 0));
            if !covered {
                continue;
            }
            let (mut lo, mut hi) = (f32::INFINITY, f32::NEG_INFINITY);
            for j in tj..=(tj + TILE_CELLS).min(cells) {
                for i in ti..=(ti + TILE_CELLS).min(cells) {
                    let h = map.lid[(j * map.lid_side + i) as usize];
                    lo = lo.min(h);
                    hi = hi.max(h);
                }
            }
            let a = map.origin + Vec2::new(ti as f32, tj as f32) * step;
            let b = map.origin
                + Vec2::new(
                    (ti + TILE_CELLS).min(cells) as f32,
                    (tj + TILE_CELLS).min(cells) as f32,
                ) * step;
            out.push(Tile {
                cell: [ti, tj],
                bounds: Aabb::new(Vec3::new(a.x, lo, a.y), Vec3::new(b.x, hi, b.y)),
            });
        }
    }
    out
}

/// The distance from `eye` to the farthest corner of `b`.
fn farthest(b: &Aabb, eye: Vec3) -> f32 {
    b.corners()
        .iter()
        .map(|c| c.distance(eye))
        .fold(0.0, f32::max)
}
