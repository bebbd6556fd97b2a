//! The `texel` method: every tree as a volumetric texel, its species' baked volumes
//! (`bake::texel`) in one 3D texture, drawn with slices parallel to the screen
//! (Decaudin-Neyret 2009; `shaders/texel.wgsl`). Per frame, on the CPU ([`prepare`]): each
//! visible tree's box, its slice count from the criteria of [`crate::slices`] (the box's
//! depth along the view against d0 metres and d1 pixels), the mip level its voxels project
//! to, the 3 nearest baked lights of the sun in its frame with their weights, the tree-level
//! VCM factors at its box corners; sorted back to front. On the GPU: one instanced draw of
//! boxes (a second for the boxes the eye is inside, drawn from their far faces).
//!
//! The seeds' own way, three axis stacks of 2D slices with pre-composited levels, is
//! [`stacks`] (`--texel-mode stacks`). Beyond `tile_distance`, the trees of a whole
//! forest-cover tile are drawn as one volume that follows the ground ([`tiles`]).

pub mod polygons;
pub mod stacks;
pub mod tiles;

use std::collections::HashMap;

use glam::{Mat3, Mat4, UVec3, Vec3};

use crate::format::{Baked, TexelVolume};
use crate::model::World;
use crate::model::mesh::Aabb;
use crate::render::GpuContext;
use crate::render::frame::FrameStats;
use crate::render::method::btf::{BtfScene, PrepareView};
use crate::render::target::{linear_to_srgb, srgb_lut};
use crate::render::world_gpu::{TreeGpu, WorldGpu};
use crate::slices::{self, SliceBounds};
use crate::sphere::DirectionSet;
use crate::{Error, Result};

/// How the volumes are sliced.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum TexelMode {
    /// Slices parallel to the screen through a 3D texture (Decaudin-Neyret 2009).
    #[default]
    Slices3d,
    /// The seeds' three axis stacks of 2D slices, the one most facing the eye drawn, with
    /// power-of-two pre-composited levels (Meyer-Neyret 1998).
    Stacks,
    /// The slices of `Slices3d` cut out of each box as polygons and blended one by one
    /// (Decaudin-Neyret's own drawing), to compare with the ray march.
    Polygons,
}

impl TexelMode {
    pub fn name(self) -> &'static str {
        match self {
            TexelMode::Slices3d => "slices3d",
            TexelMode::Stacks => "stacks",
            TexelMode::Polygons => "polygons",
        }
    }

    pub fn parse(s: &str) -> Option<TexelMode> {
        match s {
            "slices3d" => Some(TexelMode::Slices3d),
            "stacks" => Some(TexelMode::Stacks),
            "polygons" => Some(TexelMode::Polygons),
            _ => None,
        }
    }
}

/// The `texel` method's knobs.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct TexelSettings {
    pub mode: TexelMode,
    pub bounds: SliceBounds,
    /// Shade with the trees' visibility cube maps (when the bake has them).
    pub vcm: bool,
    /// Show each texel's slice count as a colour.
    pub show_slices: bool,
    /// Draw the trees of tiles wholly beyond `tile_distance` as forest-cover tiles.
    pub tiles: bool,
    /// Distance (m) from the eye to a tile's nearest point beyond which it is drawn as
    /// one volume.
    pub tile_distance: f32,
}

impl Default for TexelSettings {
    fn default() -> Self {
        Self {
            mode: TexelMode::Slices3d,
            bounds: SliceBounds::default(),
            vcm: true,
            show_slices: false,
            tiles: true,
            tile_distance: 400.0,
        }
    }
}

/// What the `texel` method did in a frame.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize)]
pub struct TexelStats {
    pub texel_mode: TexelMode,
    /// Trees drawn as texels.
    pub texels: u32,
    /// Forest-cover tiles drawn.
    pub tiles: u32,
    /// Trees those tiles stand for (not counted in `texels`).
    pub tiled_trees: u32,
    pub slices_mean: f32,
    pub slices_max: u32,
    /// Bytes of the volumes on the GPU, mipmaps included (with the stack atlas, once the
    /// stacks mode has drawn).
    pub texel_bytes: u64,
    /// Texels left out because the instance buffer was full (the farthest).
    pub dropped: u32,
}

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

/// Where one species' volumes lie, in its frame and in the 3D texture.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SpeciesVolume {
    pub box_min: Vec3,
    pub box_size: Vec3,
    pub voxel: f32,
    pub dims: UVec3,
    /// uvw of volume 0's first voxel corner, uvw extent of one volume, w between volumes.
    pub atlas_origin: Vec3,
    pub atlas_extent: Vec3,
    pub volume_dw: f32,
}

/// What the `texel` method knows of a scene on the CPU.
pub struct TexelScene {
    species: Vec<Option<SpeciesVolume>>,
    lights: DirectionSet,
    /// The 3D texture's size in voxels and its mip levels.
    atlas: UVec3,
    mips: u32,
    /// Per species, where each of its volumes starts in the texture (voxels).
    slots: Vec<Vec<UVec3>>,
}

/// Slot sizes are rounded up to a multiple of this, so that the mip levels of one volume
/// never mix with its neighbours'.
const SLOT_ALIGN: u32 = 8;
/// Mip levels of the volumes (level k halves each side k times; 8 = 2^3).
const MIPS: u32 = 4;

impl TexelScene {
    /// The layout of `baked`'s texel volumes for `world`, or an error naming what does not
    /// fit (a species without volumes, a light count unlike the bake's, too large a
    /// texture for `max_dim`).
    pub fn new(baked: &Baked, world: &World, max_dim: u32) -> Result<Self> {
        let lights = baked.settings.lights;
        let mut species = vec![None; world.species.len()];
        let mut volumes: Vec<&TexelVolume> = Vec::new();
        for t in &baked.texels {
            let s = t.species as usize;
            if s >= species.len() {
                return Err(Error::BadInput(format!(
                    "the bake has a texel volume for species {s} but the scene has {}",
                    species.len()
                )));
            }
            if t.lights != lights {
                return Err(Error::BadInput(format!(
                    "a texel volume has {} lights where the bake has {lights}",
                    t.lights
                )));
            }
            volumes.push(t);
        }
        if volumes.len() != world.species.len() {
            return Err(Error::BadInput(format!(
                "the bake has texel volumes for {} of the scene's {} species: bake again with texel_resolution above 0",
                volumes.len(),
                world.species.len()
            )));
        }
        let round = |v: u32| v.div_ceil(SLOT_ALIGN) * SLOT_ALIGN;
        let slot = volumes
            .iter()
            .fold(UVec3::ZERO, |m, t| m.max(UVec3::from(t.dims)))
            .map(round);
        let per_species = lights + 1;
        let count = volumes.len() as u32 * per_species;
        // Volumes along w, then further columns along u; a species' volumes never straddle
        // two columns (the shader steps between them along w), so a column holds whole
        // species (three species of three variants need 3 columns of 2048).
        let species_per_column = max_dim / (slot.z.max(1) * per_species);
        if species_per_column == 0 {
            return Err(Error::BadInput(format!(
                "the {per_species} texel volumes of one species need {} voxels along one side but this GPU allows {max_dim}; bake with a lower texel_resolution or fewer lights",
                slot.z * per_species
            )));
        }
        let per_column = species_per_column * per_species;
        let columns = count.div_ceil(per_column);
        let atlas = UVec3::new(slot.x * columns, slot.y, slot.z * count.min(per_column));
        if atlas.max_element() > max_dim {
            return Err(Error::BadInput(format!(
                "the texel volumes need a {}x{}x{} texture but this GPU allows {max_dim} per side; bake with a lower texel_resolution",
                atlas.x, atlas.y, atlas.z
            )));
        }
        let lights_set = DirectionSet::with_count(lights as usize)
            .map_err(|e| Error::BadInput(e.to_string()))?;
        let mut slots = vec![Vec::new(); world.species.len()];
        let size = atlas.as_vec3();
        for (k, t) in volumes.iter().enumerate() {
            let s = t.species as usize;
            let mut starts = Vec::with_capacity(per_species as usize);
            for v in 0..per_species {
                let i = k as u32 * per_species + v;
                starts.push(UVec3::new(
                    (i / per_column) * slot.x,
                    0,
                    (i % per_column) * slot.z,
                ));
            }
            let dims = UVec3::from(t.dims);
            let first = starts[0];
            // A species' volumes sit in one column when they fit; otherwise w steps are
            // not uniform and the shader's volume_dw would be wrong.
            if starts.iter().any(|p| p.x != first.x) {
                return Err(Error::BadInput(format!(
                    "the texel volumes of species {s} do not fit one column of a {max_dim}-voxel texture; bake with a lower texel_resolution"
                )));
            }
            species[s] = Some(SpeciesVolume {
                box_min: Vec3::from(t.box_min),
                box_size: dims.as_vec3() * t.voxel,
                voxel: t.voxel,
                dims,
                atlas_origin: first.as_vec3() / size,
                atlas_extent: dims.as_vec3() / size,
                volume_dw: slot.z as f32 / size.z,
            });
            slots[s] = starts;
        }
        Ok(Self {
            species,
            lights: lights_set,
            atlas,
            mips: MIPS,
            slots,
        })
    }

    pub fn species(&self, s: usize) -> Option<&SpeciesVolume> {
        self.species.get(s).and_then(|v| v.as_ref())
    }

    /// The 3D texture's side in voxels.
    pub fn atlas_size(&self) -> UVec3 {
        self.atlas
    }

    /// Bytes of the 3D texture with its mip levels.
    pub fn texture_bytes(&self) -> u64 {
        (0..self.mips)
            .map(|l| {
                let d = (self.atlas >> l).max(UVec3::ONE);
                u64::from(d.x) * u64::from(d.y) * u64::from(d.z) * 4
            })
            .sum()
    }

    /// The whole texture's level 0 then each mip level (RGBA8, sRGB, premultiplied), box
    /// filtered in linear light. Slots are multiples of 8 voxels, so no level mixes two
    /// volumes.
    pub fn atlas_levels(&self, baked: &Baked) -> Vec<(UVec3, Vec<u8>)> {
        let a = self.atlas;
        let mut level0 = vec![0u8; (a.x * a.y * a.z * 4) as usize];
        for t in &baked.texels {
            let Some(starts) = self.slots.get(t.species as usize) else {
                continue;
            };
            let d = UVec3::from(t.dims);
            let per = (d.x * d.y * d.z * 4) as usize;
            for (v, start) in starts.iter().enumerate() {
                let Some(src) = t.voxels.get(v * per..(v + 1) * per) else {
                    continue;
                };
                for z in 0..d.z {
                    for y in 0..d.y {
                        let from = (((z * d.y + y) * d.x) * 4) as usize;
                        let to =
                            ((((start.z + z) * a.y + start.y + y) * a.x + start.x) * 4) as usize;
                        let row = (d.x * 4) as usize;
                        level0[to..to + row].copy_from_slice(&src[from..from + row]);
                    }
                }
            }
        }
        let mut levels = vec![(a, level0)];
        let lut = srgb_lut();
        for _ in 1..self.mips {
            let Some((size, prev)) = levels.last() else {
                break;
            };
            let next = (*size >> 1u32).max(UVec3::ONE);
            let mut out = vec![0u8; (next.x * next.y * next.z * 4) as usize];
            for z in 0..next.z {
                for y in 0..next.y {
                    for x in 0..next.x {
                        let mut acc = [0.0f32; 4];
                        let mut n = 0.0;
                        for dz in 0..2 {
                            for dy in 0..2 {
                                for dx in 0..2 {
                                    let (sx, sy, sz) = (2 * x + dx, 2 * y + dy, 2 * z + dz);
                                    if sx >= size.x || sy >= size.y || sz >= size.z {
                                        continue;
                                    }
                                    let i = (((sz * size.y + sy) * size.x + sx) * 4) as usize;
                                    for c in 0..3 {
                                        acc[c] += lut[prev[i + c] as usize];
                                    }
                                    acc[3] += f32::from(prev[i + 3]) / 255.0;
                                    n += 1.0;
                                }
                            }
                        }
                        let o = (((z * next.y + y) * next.x + x) * 4) as usize;
                        for c in 0..3 {
                            out[o + c] = linear_to_srgb(acc[c] / n);
                        }
                        out[o + 3] = (acc[3] / n * 255.0 + 0.5) as u8;
                    }
                }
            }
            levels.push((next, out));
        }
        levels
    }
}

/// One frame's texels, back to front, and the count of those the eye is inside (the last
/// `inside` records).
pub struct TexelFrame {
    pub records: Vec<TexelGpu>,
    pub inside: u32,
    pub stats: TexelStats,
    /// In the stacks mode, each record's stack (same order) and the quads to draw.
    pub stacks: Vec<stacks::StackGpu>,
    pub quads: Vec<[u32; 2]>,
    /// Forest-cover tiles to draw first, back to front.
    pub tiles: Vec<tiles::TileGpu>,
    /// In the polygons mode, the slices' triangles, back to front.
    pub polygons: Vec<polygons::PolyVertex>,
}

/// The texels of the trees in `visible` (per species, indices into `trees`): slice counts,
/// lights, VCM factors (from `vcm`, the `btf` method's scene, when given), back to front,
/// at most `max` of them (the nearest kept). With `stack_atlas` (the stacks mode), each
/// texel's stack and level too.
#[allow(clippy::too_many_arguments)]
pub fn prepare(
    scene: &TexelScene,
    trees: &[TreeGpu],
    visible: &[Vec<u32>],
    view: &PrepareView,
    settings: &TexelSettings,
    vcm: Option<&BtfScene>,
    stack_atlas: Option<&stacks::StackAtlas>,
    max: usize,
) -> TexelFrame {
    let bounds = settings.bounds.sanitized();
    let cam = view.camera.position;
    let forward = view.camera.forward();
    let mut stats = TexelStats {
        texel_mode: settings.mode,
        ..Default::default()
    };
    let mut sorted: Vec<(f32, bool, TexelGpu, Option<stacks::StackGpu>)> = Vec::new();
    for (sp, list) in visible.iter().enumerate() {
        let Some(vol) = scene.species(sp) else {
            continue;
        };
        for &t in list {
            let Some(data) = trees.get(t as usize) else {
                continue;
            };
            let m = Mat4::from_cols_array_2d(&data.model);
            let scale = m.x_axis.truncate().length();
            if !(scale > 0.0 && scale.is_finite()) {
                continue;
            }
            let local = Aabb::new(vol.box_min, vol.box_min + vol.box_size);
            let world_box = local.transformed(m);
            if !view.frustum.intersects(&world_box) {
                continue;
            }
            let inv = m.inverse();
            // The box's depth along the view: its extent along the forward axis.
            let rot = Mat3::from_mat4(m);
            let f_obj = (rot.transpose() * forward) / scale;
            let depth = (vol.box_size * f_obj.abs()).element_sum() * scale;
            let center = m.transform_point3(local.center());
            let z = (center - cam).dot(forward).max(view.camera.near.max(0.1));
            let stack = stack_atlas.and_then(|a| {
                let eye_to_box = inv.transform_vector3(center - cam);
                a.choose(sp, eye_to_box, vol.voxel, scale, z, view.focal_px, &bounds)
            });
            let n = match &stack {
                Some(c) => c.slices,
                None if stack_atlas.is_some() => continue,
                None => slices::screen_slices(view.focal_px, depth, z, &bounds),
            };
            let spacing = depth / n as f32;
            // The mip level where one voxel covers about a pixel.
            let voxel_px = view.focal_px * vol.voxel * scale / z;
            let lod = (1.0 / voxel_px.max(1e-6))
                .log2()
                .clamp(0.0, (scene.mips - 1) as f32);
            let sun_obj = (rot.transpose() * view.to_sun).normalize_or(Vec3::Y);
            let blend = scene.lights.blend(sun_obj);
            let mut record = TexelGpu {
                model: m.to_cols_array_2d(),
                world_to_object: inv.to_cols_array_2d(),
                box_min: vol.box_min.to_array(),
                spacing,
                box_size: vol.box_size.to_array(),
                voxel: vol.voxel,
                atlas_origin: vol.atlas_origin.to_array(),
                volume_dw: vol.volume_dw,
                atlas_extent: vol.atlas_extent.to_array(),
                lod,
                light_index: blend.index,
                mode: u32::from(settings.show_slices),
                light_weight: blend.weight,
                lights: scene.lights.len() as u32,
                tint: [data.tint[0], data.tint[1], data.tint[2]],
                scale,
                vcm_min: vol.box_min.to_array(),
                max_steps: (n + 2) as f32,
                vcm_inv_size: (1.0 / vol.box_size).to_array(),
                slices: n as f32,
                vcm_direct: [[1.0; 4]; 2],
                vcm_sky: [[1.0; 4]; 2],
            };
            if let Some((shade, b)) = vcm
                .filter(|_| settings.vcm)
                .and_then(|v| v.tree_shade(t as usize, sp, &m))
            {
                let d = shade.direct;
                let k = shade.sky;
                record.vcm_min = b.min.to_array();
                record.vcm_inv_size = (1.0 / (b.max - b.min).max(Vec3::splat(1e-6))).to_array();
                record.vcm_direct = [[d[0], d[1], d[2], d[3]], [d[4], d[5], d[6], d[7]]];
                record.vcm_sky = [[k[0], k[1], k[2], k[3]], [k[4], k[5], k[6], k[7]]];
            }
            // The eye inside the box (with a margin for the near plane): drawn from its far
            // faces.
            let eye_obj = inv.transform_point3(cam);
            let margin = Vec3::splat(view.camera.near.max(0.1) * 2.0 / scale);
            let inside =
                eye_obj.cmpge(local.min - margin).all() && eye_obj.cmple(local.max + margin).all();
            stats.texels += 1;
            stats.slices_max = stats.slices_max.max(n);
            stats.slices_mean += n as f32;
            // Stacks have no inside: their quads are drawn in depth order whatever the eye.
            let inside = inside && stack.is_none();
            sorted.push((
                (center - cam).dot(forward),
                inside,
                record,
                stack.map(|c| c.record),
            ));
        }
    }
    // Back to front; the boxes the eye is inside last (they are the nearest).
    sorted.sort_by(|a, b| a.1.cmp(&b.1).then(b.0.total_cmp(&a.0)));
    if sorted.len() > max {
        stats.dropped = (sorted.len() - max) as u32;
        // The farthest outside boxes go first.
        sorted.drain(..sorted.len() - max);
    }
    if stats.texels > 0 {
        stats.slices_mean /= stats.texels as f32;
    }
    let inside = sorted.iter().filter(|s| s.1).count() as u32;
    let stack_records: Vec<stacks::StackGpu> = sorted.iter().filter_map(|s| s.3).collect();
    let quads = stacks::quads(&stack_records);
    TexelFrame {
        records: sorted.into_iter().map(|s| s.2).collect(),
        inside,
        stats,
        stacks: stack_records,
        quads,
        tiles: Vec::new(),
        polygons: Vec::new(),
    }
}

/// The texel volumes on the GPU and the per-frame instance buffer.
pub struct TexelAssets {
    scene: TexelScene,
    _texture: wgpu::Texture,
    view: wgpu::TextureView,
    sampler: wgpu::Sampler,
    layout: wgpu::BindGroupLayout,
    records: wgpu::Buffer,
    capacity: usize,
    bind_group: wgpu::BindGroup,
    pipelines: HashMap<wgpu::TextureFormat, [wgpu::RenderPipeline; 2]>,
    /// Every tree's texel seen from the sun, for the ground alpha shadow map.
    sun_records: wgpu::Buffer,
    sun_capacity: usize,
    sun_bind_group: wgpu::BindGroup,
    opacity_pipeline: Option<wgpu::RenderPipeline>,
    /// Bytes of the 3D texture, mipmaps included.
    pub bytes: u64,
    /// The baked volumes, kept to build the stack atlas the first time the stacks mode
    /// draws (most sessions never do).
    volumes: Vec<TexelVolume>,
    species_count: usize,
    stacks: Option<stacks::StackAssets>,
    /// Why the stack atlas could not be built (the slices3d mode still draws).
    stack_problem: Option<String>,
    /// The terrain, kept to build the forest-cover tiles the first time they draw.
    terrain: crate::model::Terrain,
    tiles: Option<tiles::TileAssets>,
    tile_problem: Option<String>,
    polygons: Option<polygons::PolyAssets>,
}

/// The render pipelines of the `texel` method for one target format: boxes seen from
/// outside and from inside (slices3d), and stack quads (stacks, once built).
#[derive(Clone)]
pub struct TexelPipelines {
    pub boxes: [wgpu::RenderPipeline; 2],
    pub stack: Option<wgpu::RenderPipeline>,
    pub tile: Option<wgpu::RenderPipeline>,
    pub polygon: Option<wgpu::RenderPipeline>,
}

/// Most texels drawn in one frame.
pub const MAX_TEXELS: usize = 1 << 17;

impl TexelAssets {
    pub fn new(ctx: &GpuContext, baked: &Baked, world: &World) -> Result<Self> {
        let max_dim = ctx.device.limits().max_texture_dimension_3d;
        let scene = TexelScene::new(baked, world, max_dim)?;
        let size = scene.atlas_size();
        let texture = ctx.checked("allocating the texel volumes", || {
            ctx.device.create_texture(&wgpu::TextureDescriptor {
                label: Some("texel volumes"),
                size: wgpu::Extent3d {
                    width: size.x,
                    height: size.y,
                    depth_or_array_layers: size.z,
                },
                mip_level_count: scene.mips,
                sample_count: 1,
                dimension: wgpu::TextureDimension::D3,
                format: wgpu::TextureFormat::Rgba8UnormSrgb,
                usage: wgpu::TextureUsages::TEXTURE_BINDING | wgpu::TextureUsages::COPY_DST,
                view_formats: &[],
            })
        })?;
        for (level, (d, data)) in scene.atlas_levels(baked).iter().enumerate() {
            ctx.queue.write_texture(
                wgpu::TexelCopyTextureInfo {
                    texture: &texture,
                    mip_level: level as u32,
                    origin: wgpu::Origin3d::ZERO,
                    aspect: wgpu::TextureAspect::All,
                },
                data,
                wgpu::TexelCopyBufferLayout {
                    offset: 0,
                    bytes_per_row: Some(4 * d.x),
                    rows_per_image: Some(d.y),
                },
                wgpu::Extent3d {
                    width: d.x,
                    height: d.y,
                    depth_or_array_layers: d.z,
                },
            );
        }
        let view = texture.create_view(&Default::default());
        let sampler = ctx.device.create_sampler(&wgpu::SamplerDescriptor {
            label: Some("texel volumes"),
            address_mode_u: wgpu::AddressMode::ClampToEdge,
            address_mode_v: wgpu::AddressMode::ClampToEdge,
            address_mode_w: wgpu::AddressMode::ClampToEdge,
            mag_filter: wgpu::FilterMode::Linear,
            min_filter: wgpu::FilterMode::Linear,
            mipmap_filter: wgpu::MipmapFilterMode::Linear,
            ..Default::default()
        });
        let layout = ctx
            .device
            .create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
                label: Some("texel"),
                entries: &[
                    crate::render::pipelines::buffer_entry(
                        0,
                        wgpu::ShaderStages::VERTEX_FRAGMENT,
                        wgpu::BufferBindingType::Storage { read_only: true },
                    ),
                    wgpu::BindGroupLayoutEntry {
                        binding: 1,
                        visibility: wgpu::ShaderStages::FRAGMENT,
                        ty: wgpu::BindingType::Texture {
                            sample_type: wgpu::TextureSampleType::Float { filterable: true },
                            view_dimension: wgpu::TextureViewDimension::D3,
                            multisampled: false,
                        },
                        count: None,
                    },
                    wgpu::BindGroupLayoutEntry {
                        binding: 2,
                        visibility: wgpu::ShaderStages::FRAGMENT,
                        ty: wgpu::BindingType::Sampler(wgpu::SamplerBindingType::Filtering),
                        count: None,
                    },
                ],
            });
        let capacity = 64;
        let records = record_buffer(ctx, capacity);
        let bind_group = make_bind_group(ctx, &layout, &records, &view, &sampler);
        let sun_capacity = world.forest.instances.len().clamp(1, MAX_TEXELS);
        let sun_records = record_buffer(ctx, sun_capacity);
        let sun_bind_group = make_bind_group(ctx, &layout, &sun_records, &view, &sampler);
        Ok(Self {
            sun_records,
            sun_capacity,
            sun_bind_group,
            opacity_pipeline: None,
            bytes: scene.texture_bytes(),
            scene,
            _texture: texture,
            view,
            sampler,
            layout,
            records,
            capacity,
            bind_group,
            pipelines: HashMap::new(),
            volumes: baked.texels.clone(),
            species_count: world.species.len(),
            stacks: None,
            stack_problem: None,
            terrain: world.terrain.clone(),
            tiles: None,
            tile_problem: None,
            polygons: None,
        })
    }

    /// Bytes of the volumes on the GPU: the 3D texture, and the stack atlas once built.
    pub fn total_bytes(&self) -> u64 {
        self.bytes
            + self.stacks.as_ref().map_or(0, |s| s.bytes)
            + self.tiles.as_ref().map_or(0, |t| t.bytes)
    }

    /// Builds the forest-cover tiles if they are not yet (or says why they cannot be).
    fn ensure_tiles(&mut self, ctx: &GpuContext, world: &WorldGpu) -> Result<()> {
        if let Some(p) = &self.tile_problem {
            return Err(Error::BadInput(format!(
                "the forest-cover tiles cannot be built: {p}"
            )));
        }
        if self.tiles.is_none() {
            match tiles::TileAssets::new(ctx, &self.terrain, world, &self.volumes) {
                Ok(t) => self.tiles = Some(t),
                Err(e) => {
                    self.tile_problem = Some(e.to_string());
                    return Err(Error::BadInput(format!(
                        "the forest-cover tiles cannot be built: {e}"
                    )));
                }
            }
        }
        Ok(())
    }

    /// The tiles wholly beyond `settings.tile_distance` in view, back to front, and the
    /// trees they stand for (per tree, whether a drawn tile holds it).
    fn frame_tiles(
        &self,
        world: &WorldGpu,
        view: &PrepareView,
        settings: &TexelSettings,
    ) -> (Vec<tiles::TileGpu>, Vec<bool>, u32) {
        let Some(t) = self.tiles.as_ref() else {
            return (Vec::new(), Vec::new(), 0);
        };
        let bounds = settings.bounds.sanitized();
        let cam = view.camera.position;
        let forward = view.camera.forward();
        let blend = self.scene.lights.blend(view.to_sun.normalize_or(Vec3::Y));
        let mut drawn = vec![false; t.grid.tiles.len()];
        let mut sorted = Vec::new();
        for (i, tile) in t.grid.tiles.iter().enumerate() {
            let b = tile.bounds();
            let nearest = cam.clamp(b.min, b.max);
            if (nearest - cam).length() < settings.tile_distance || !view.frustum.intersects(&b) {
                continue;
            }
            drawn[i] = true;
            let extent = b.max - b.min;
            let depth = (extent * forward.abs()).element_sum();
            let z = (b.center() - cam)
                .dot(forward)
                .max(view.camera.near.max(0.1));
            // The criteria, but no more than two slices per tile voxel along the view:
            // finer slices would sample the same voxels again.
            let per_voxel = (2.0 * depth * tiles::TILE_DIMS.x as f32 / tile.size).ceil();
            let n = slices::screen_slices(view.focal_px, depth, z, &bounds)
                .min(per_voxel.max(1.0) as u32);
            sorted.push((z, t.record(i, depth / n as f32, n, &blend)));
        }
        sorted.sort_by(|a, b| b.0.total_cmp(&a.0));
        let mut skip = vec![false; world.tree_data.len()];
        let mut tiled = 0;
        for (tree, tile) in t.grid.tile_of.iter().enumerate() {
            if let Some(k) = tile
                && drawn.get(*k as usize).copied().unwrap_or(false)
                && let Some(s) = skip.get_mut(tree)
            {
                *s = true;
                tiled += 1;
            }
        }
        (sorted.into_iter().map(|s| s.1).collect(), skip, tiled)
    }

    /// Builds the stack atlas if it is not yet (or says why it cannot be).
    fn ensure_stacks(&mut self, ctx: &GpuContext) -> Result<()> {
        if let Some(p) = &self.stack_problem {
            return Err(Error::BadInput(format!(
                "the texel stacks cannot be built: {p}"
            )));
        }
        if self.stacks.is_none() {
            match stacks::StackAssets::new(ctx, &self.volumes, self.species_count) {
                Ok(s) => self.stacks = Some(s),
                Err(e) => {
                    self.stack_problem = Some(e.to_string());
                    return Err(Error::BadInput(format!(
                        "the texel stacks cannot be built: {e}"
                    )));
                }
            }
        }
        Ok(())
    }

    pub fn scene(&self) -> &TexelScene {
        &self.scene
    }

    /// Prepares the frame's texels and uploads them (growing the buffer when needed).
    pub fn prepare_frame(
        &mut self,
        ctx: &GpuContext,
        world: &WorldGpu,
        visible: &[Vec<u32>],
        view: &PrepareView,
        settings: &TexelSettings,
        vcm: Option<&BtfScene>,
    ) -> Result<TexelFrame> {
        if settings.mode == TexelMode::Stacks {
            self.ensure_stacks(ctx)?;
        }
        if settings.tiles {
            self.ensure_tiles(ctx, world)?;
        }
        let (tile_records, skip, tiled) = if settings.tiles {
            self.frame_tiles(world, view, settings)
        } else {
            (Vec::new(), Vec::new(), 0)
        };
        let kept: Vec<Vec<u32>>;
        let visible = if skip.iter().any(|&s| s) {
            kept = visible
                .iter()
                .map(|list| {
                    list.iter()
                        .copied()
                        .filter(|&t| !skip.get(t as usize).copied().unwrap_or(false))
                        .collect()
                })
                .collect();
            &kept[..]
        } else {
            visible
        };
        let atlas = match settings.mode {
            TexelMode::Stacks => self.stacks.as_ref().map(|s| &s.atlas),
            TexelMode::Slices3d | TexelMode::Polygons => None,
        };
        let mut f = prepare(
            &self.scene,
            &world.tree_data,
            visible,
            view,
            settings,
            vcm,
            atlas,
            MAX_TEXELS,
        );
        f.stats.texel_bytes = self.total_bytes();
        f.stats.tiles = tile_records.len() as u32;
        f.stats.tiled_trees = tiled;
        if let Some(t) = self.tiles.as_mut() {
            t.upload(ctx, &tile_records, &self.sampler);
        }
        f.tiles = tile_records;
        if settings.mode == TexelMode::Polygons {
            let mut vertices = Vec::new();
            let cam = view.camera.position;
            let forward = view.camera.forward();
            for (i, r) in f.records.iter().enumerate() {
                let m = Mat4::from_cols_array_2d(&r.model);
                let polys = polygons::slice_polygons(
                    &m,
                    Vec3::from(r.box_min),
                    Vec3::from(r.box_size),
                    cam,
                    forward,
                    r.spacing,
                    r.max_steps as usize,
                );
                polygons::triangles(&polys, i as u32, &mut vertices);
            }
            let p = self
                .polygons
                .get_or_insert_with(|| polygons::PolyAssets::new(ctx));
            p.upload(ctx, &vertices, &self.records, &self.view, &self.sampler);
            f.polygons = vertices;
        }
        if f.records.len() > self.capacity {
            self.capacity = f.records.len().next_power_of_two().min(MAX_TEXELS);
            self.records = record_buffer(ctx, self.capacity);
            self.bind_group =
                make_bind_group(ctx, &self.layout, &self.records, &self.view, &self.sampler);
        }
        if !f.records.is_empty() {
            ctx.queue
                .write_buffer(&self.records, 0, bytemuck::cast_slice(&f.records));
        }
        if let Some(s) = self
            .stacks
            .as_mut()
            .filter(|_| settings.mode == TexelMode::Stacks)
        {
            s.upload(ctx, &f.stacks, &f.quads, &self.records, &self.sampler);
        }
        Ok(f)
    }

    /// Every tree's texel for the ground alpha shadow map (the sun's 3 nearest lights do not
    /// matter there: only opacity is read), uploaded; returns how many.
    pub fn prepare_sun(&mut self, ctx: &GpuContext, world: &WorldGpu) -> u32 {
        let mut out = Vec::with_capacity(world.tree_data.len().min(self.sun_capacity));
        for (data, &sp) in world.tree_data.iter().zip(&world.tree_species) {
            if out.len() >= self.sun_capacity {
                break;
            }
            let Some(vol) = self.scene.species(sp as usize) else {
                continue;
            };
            let m = Mat4::from_cols_array_2d(&data.model);
            let scale = m.x_axis.truncate().length();
            if !(scale > 0.0 && scale.is_finite()) {
                continue;
            }
            let d = vol.dims;
            out.push(TexelGpu {
                model: m.to_cols_array_2d(),
                world_to_object: m.inverse().to_cols_array_2d(),
                box_min: vol.box_min.to_array(),
                spacing: vol.voxel * scale,
                box_size: vol.box_size.to_array(),
                voxel: vol.voxel,
                atlas_origin: vol.atlas_origin.to_array(),
                volume_dw: vol.volume_dw,
                atlas_extent: vol.atlas_extent.to_array(),
                lod: 0.0,
                light_index: [0; 3],
                mode: 0,
                light_weight: [1.0, 0.0, 0.0],
                lights: self.scene.lights.len() as u32,
                tint: [1.0; 3],
                scale,
                vcm_min: vol.box_min.to_array(),
                // A ray crosses at most the sum of the sides in voxels.
                max_steps: (d.x + d.y + d.z) as f32,
                vcm_inv_size: (1.0 / vol.box_size).to_array(),
                slices: 0.0,
                vcm_direct: [[1.0; 4]; 2],
                vcm_sky: [[1.0; 4]; 2],
            });
        }
        if !out.is_empty() {
            ctx.queue
                .write_buffer(&self.sun_records, 0, bytemuck::cast_slice(&out));
        }
        out.len() as u32
    }

    /// The pipeline multiplying the texels' transmittance into the ground alpha map.
    pub fn opacity_pipeline(
        &mut self,
        device: &wgpu::Device,
        shadow_frame: &wgpu::BindGroupLayout,
    ) -> &wgpu::RenderPipeline {
        let layout = &self.layout;
        self.opacity_pipeline.get_or_insert_with(|| {
            // dst = dst * (1 - alpha): transmittance multiplies.
            let transmit = wgpu::BlendComponent {
                src_factor: wgpu::BlendFactor::Zero,
                dst_factor: wgpu::BlendFactor::OneMinusSrcAlpha,
                operation: wgpu::BlendOperation::Add,
            };
            texel_pipeline(
                device,
                [shadow_frame, layout],
                "fs_texel_opacity",
                crate::render::GROUND_FORMAT,
                transmit,
                None,
                (crate::render::SHADOW_FORMAT, wgpu::CompareFunction::Less),
            )
        })
    }

    pub fn sun_bind_group(&self) -> &wgpu::BindGroup {
        &self.sun_bind_group
    }

    /// The pipelines for `format`: boxes seen from outside (front faces) and from inside
    /// (far faces), and the stacks' when the atlas is built.
    pub fn pipelines(
        &mut self,
        device: &wgpu::Device,
        frame_layout: &wgpu::BindGroupLayout,
        format: wgpu::TextureFormat,
    ) -> TexelPipelines {
        let stack = self
            .stacks
            .as_mut()
            .map(|s| s.pipeline(device, frame_layout, format).clone());
        let tile = self
            .tiles
            .as_mut()
            .map(|t| t.pipeline(device, frame_layout, format).clone());
        let polygon = self
            .polygons
            .as_mut()
            .map(|p| p.pipeline(device, frame_layout, format).clone());
        TexelPipelines {
            boxes: self.box_pipelines(device, frame_layout, format).clone(),
            stack,
            tile,
            polygon,
        }
    }

    fn box_pipelines(
        &mut self,
        device: &wgpu::Device,
        frame_layout: &wgpu::BindGroupLayout,
        format: wgpu::TextureFormat,
    ) -> &[wgpu::RenderPipeline; 2] {
        let layout = &self.layout;
        // Premultiplied "over".
        let over = wgpu::BlendComponent {
            src_factor: wgpu::BlendFactor::One,
            dst_factor: wgpu::BlendFactor::OneMinusSrcAlpha,
            operation: wgpu::BlendOperation::Add,
        };
        // Reversed Z; tested against the terrain, never written.
        let depth = (crate::render::DEPTH_FORMAT, wgpu::CompareFunction::Greater);
        self.pipelines.entry(format).or_insert_with(|| {
            [wgpu::Face::Back, wgpu::Face::Front].map(|cull| {
                texel_pipeline(
                    device,
                    [frame_layout, layout],
                    "fs_texel",
                    format,
                    over,
                    Some(cull),
                    depth,
                )
            })
        })
    }

    /// Draws the frame's texels (the pass has group 0 bound).
    pub fn draw(
        &self,
        pass: &mut wgpu::RenderPass<'_>,
        pipelines: &TexelPipelines,
        frame: &TexelFrame,
        stats: &mut FrameStats,
    ) {
        let n = frame.records.len() as u32;
        if let (Some(t), Some(p), false) = (&self.tiles, &pipelines.tile, frame.tiles.is_empty()) {
            // The far tiles first: everything else is nearer.
            let count = frame.tiles.len() as u32;
            t.draw(pass, p, count);
            stats.draw_calls += 1;
            stats.triangles += u64::from(count) * 12;
        }
        if frame.stats.texel_mode == TexelMode::Polygons {
            if let (Some(p), Some(pipe)) = (&self.polygons, &pipelines.polygon) {
                let vertices = frame.polygons.len() as u32;
                p.draw(pass, pipe, vertices);
                stats.draw_calls += u32::from(vertices > 0);
                stats.trees_drawn = n;
                stats.triangles += u64::from(vertices / 3);
            }
            return;
        }
        if frame.stats.texel_mode == TexelMode::Stacks {
            if let (Some(s), Some(p)) = (&self.stacks, &pipelines.stack) {
                let quads = frame.quads.len() as u32;
                s.draw(pass, p, quads);
                stats.draw_calls += u32::from(quads > 0);
                stats.trees_drawn = n;
                stats.triangles += u64::from(quads) * 2;
            }
            return;
        }
        let pipelines = &pipelines.boxes;
        let outside = n - frame.inside.min(n);
        pass.set_bind_group(1, &self.bind_group, &[]);
        if outside > 0 {
            pass.set_pipeline(&pipelines[0]);
            pass.draw(0..36, 0..outside);
            stats.draw_calls += 1;
        }
        if outside < n {
            pass.set_pipeline(&pipelines[1]);
            pass.draw(0..36, outside..n);
            stats.draw_calls += 1;
        }
        stats.trees_drawn = n;
        stats.triangles += u64::from(n) * 12;
    }
}

fn record_buffer(ctx: &GpuContext, capacity: usize) -> wgpu::Buffer {
    ctx.device.create_buffer(&wgpu::BufferDescriptor {
        label: Some("texels"),
        size: (capacity.max(1) * std::mem::size_of::<TexelGpu>()) as u64,
        usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST,
        mapped_at_creation: false,
    })
}

fn make_bind_group(
    ctx: &GpuContext,
    layout: &wgpu::BindGroupLayout,
    records: &wgpu::Buffer,
    view: &wgpu::TextureView,
    sampler: &wgpu::Sampler,
) -> wgpu::BindGroup {
    ctx.device.create_bind_group(&wgpu::BindGroupDescriptor {
        label: Some("texel"),
        layout,
        entries: &[
            wgpu::BindGroupEntry {
                binding: 0,
                resource: records.as_entire_binding(),
            },
            wgpu::BindGroupEntry {
                binding: 1,
                resource: wgpu::BindingResource::TextureView(view),
            },
            wgpu::BindGroupEntry {
                binding: 2,
                resource: wgpu::BindingResource::Sampler(sampler),
            },
        ],
    })
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

/// A pipeline drawing the texel boxes with `fragment` of texel.wgsl into one `format`
/// target blended by `blend`, faces `cull`ed, depth-tested (never written) against `depth`.
fn texel_pipeline(
    device: &wgpu::Device,
    layouts: [&wgpu::BindGroupLayout; 2],
    fragment: &str,
    format: wgpu::TextureFormat,
    blend: wgpu::BlendComponent,
    cull: Option<wgpu::Face>,
    depth: (wgpu::TextureFormat, wgpu::CompareFunction),
) -> wgpu::RenderPipeline {
    crate::render::pipelines::blended_pipeline(
        device,
        crate::render::pipelines::Blended {
            label: "texel.wgsl",
            layouts,
            source: crate::render::shaders::texel(),
            vertex: "vs_texel",
            fragment,
            format,
            blend,
            cull,
            depth,
        },
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::format::BakeSettings;
    use crate::model::{TreeModel, preset};

    /// Nine prototypes (three species of three variants) with 6 lights: 63 volumes of up
    /// to 64 voxels, more than one 2048-voxel column holds. Each species' volumes stay in
    /// one column, every slot is distinct and inside the texture.
    #[test]
    fn many_prototypes_pack_into_columns_of_whole_species() {
        let tree = TreeModel::generate(&preset("broadleaf").unwrap(), 1).unwrap();
        let mut world = World::lone(tree.clone(), 10.0);
        world.species = vec![tree; 9];
        let lights = 6;
        let dims = [58, 64, 58];
        let texels = (0..9)
            .map(|s| TexelVolume {
                species: s,
                lights,
                dims,
                box_min: [0.0; 3],
                voxel: 0.2,
                voxels: Vec::new(),
            })
            .collect();
        let baked = Baked {
            scene_hash: 0,
            settings: BakeSettings {
                views: 18,
                tree_views: 18,
                lights,
                resolution: 64,
                supersample: 4,
                vcm_resolution: 32,
                texel_resolution: 64,
            },
            btf: Vec::new(),
            vcm: Vec::new(),
            texels,
        };
        let scene = TexelScene::new(&baked, &world, 2048).unwrap();
        let atlas = scene.atlas_size();
        assert!(atlas.max_element() <= 2048, "{atlas}");
        let mut seen = std::collections::HashSet::new();
        for s in 0..9 {
            let starts = &scene.slots[s];
            assert_eq!(starts.len(), 7);
            assert!(starts.iter().all(|p| p.x == starts[0].x), "{starts:?}");
            for p in starts {
                assert!(seen.insert(*p), "slot {p} used twice");
                assert!(
                    (*p + UVec3::from(dims)).cmple(atlas).all(),
                    "{p} outside {atlas}"
                );
            }
        }
        // One species' volumes cannot fit at all: a clear error.
        let e = TexelScene::new(&baked, &world, 256)
            .err()
            .unwrap()
            .to_string();
        assert!(e.contains("texel_resolution"), "{e}");
    }
}
