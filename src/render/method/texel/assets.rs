//! The texel volumes on the GPU, the per-frame instance buffer, the pipelines and the draws.

use std::collections::HashMap;

use glam::{Mat4, UVec3, Vec3};

use super::prepare::{TexelFrame, prepare};
use super::scene::TexelScene;
use super::{TexelGpu, TexelMode, TexelSettings, polygons, stacks, tiles};
use crate::format::{Baked, PackedBytes, TexelVolume};
use crate::model::World;
use crate::render::GpuContext;
use crate::render::frame::FrameStats;
use crate::render::method::view::PrepareView;
use crate::render::pipelines::{
    Blended, blended_pipeline, sampled_rgba8_texture, storage_buffer_of, write_rgba8,
};
use crate::render::timing::PassSpans;
use crate::render::vcm_shading::TreeShades;
use crate::render::world_gpu::WorldGpu;
use crate::slices::{self};
use crate::{Error, Result};

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
    /// The baked volumes, kept deflated to build the stack atlas or the forest-cover
    /// tiles the first time they draw.
    volumes: PackedVolumes,
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

/// Baked texel volumes with their voxels deflated ([`PackedBytes`]): about a thirteenth of
/// their 18 MB for the example forest, the volumes being mostly air. Unpacked for the
/// upload, the stack atlas and the forest-cover tiles.
struct PackedVolumes(Vec<(TexelVolume, PackedBytes)>);

impl PackedVolumes {
    fn pack(volumes: &[TexelVolume]) -> Self {
        use rayon::prelude::*;
        Self(
            volumes
                .par_iter()
                .map(|v| (header_of(v, Vec::new()), PackedBytes::pack(&v.voxels)))
                .collect(),
        )
    }

    fn unpack(&self) -> Result<Vec<TexelVolume>> {
        self.0
            .iter()
            .map(|(header, voxels)| {
                let voxels = voxels.unpack().map_err(|e| {
                    Error::Gpu(format!(
                        "the texel volumes kept in memory could not be read again: {e}"
                    ))
                })?;
                Ok(header_of(header, voxels))
            })
            .collect()
    }

    /// Bytes held.
    fn bytes(&self) -> u64 {
        self.0.iter().map(|(_, v)| v.held_bytes()).sum()
    }
}

/// `v` with `voxels` in place of its own.
fn header_of(v: &TexelVolume, voxels: Vec<u8>) -> TexelVolume {
    TexelVolume {
        species: v.species,
        lights: v.lights,
        dims: v.dims,
        box_min: v.box_min,
        voxel: v.voxel,
        voxels,
    }
}

/// A bake's texel volumes checked against the scene, and what their upload needs, until a
/// frame first draws them: a bake attached for another method keeps them on the CPU only,
/// deflated (the GPU's copy, with its mips and padding, is about four times larger than
/// the volumes, and they deflate to about a thirteenth).
pub struct PendingTexel {
    /// The bake's settings (its parts left out).
    baked: Baked,
    volumes: PackedVolumes,
    species_count: usize,
    /// Placed trees (the sun's records are sized by them).
    trees: usize,
    terrain: crate::model::Terrain,
}

impl PendingTexel {
    /// The texel volumes of `baked` for `world`, or what is wrong with them; `max_dim` is
    /// the GPU's largest 3D texture side.
    pub fn new(baked: &Baked, world: &World, max_dim: u32) -> Result<Self> {
        TexelScene::new(baked, world.species.len(), max_dim)?;
        Ok(Self {
            baked: Baked {
                scene_hash: baked.scene_hash,
                settings: baked.settings,
                btf: Vec::new(),
                vcm: Vec::new(),
                texels: Vec::new(),
                impostors: Vec::new(),
                surfels: Vec::new(),
            },
            volumes: PackedVolumes::pack(&baked.texels),
            species_count: world.species.len(),
            trees: world.forest.instances.len(),
            terrain: world.terrain.clone(),
        })
    }

    /// Bytes of volumes it holds (deflated).
    pub fn bytes(&self) -> u64 {
        self.volumes.bytes()
    }
}

/// Most texels drawn in one frame.
pub const MAX_TEXELS: usize = 1 << 17;

impl TexelAssets {
    /// Drops the render pipelines built so far (they are built again on next use).
    pub fn forget_pipelines(&mut self) {
        self.pipelines.clear();
        self.opacity_pipeline = None;
        if let Some(s) = self.stacks.as_mut() {
            s.pass.forget_pipelines();
        }
        if let Some(t) = self.tiles.as_mut() {
            t.pass.forget_pipelines();
        }
    }

    /// What it keeps on the CPU: the baked volumes deflated (for the stack atlas and the
    /// forest-cover tiles, built the first time they draw) and the terrain (for the tiles).
    pub fn cpu_parts(&self, out: &mut Vec<crate::render::memory::MemoryPart>) {
        use crate::render::memory::{MemoryPart, vec_bytes};
        let volumes = self.volumes.bytes();
        for (name, bytes) in [
            ("texel volumes as baked, deflated (CPU)", volumes),
            (
                "terrain heights for the texel tiles (CPU)",
                vec_bytes(&self.terrain.heights),
            ),
        ] {
            if bytes > 0 {
                out.push(MemoryPart {
                    name: name.into(),
                    bytes,
                    count: 1,
                });
            }
        }
    }

    /// The volumes of `pending` on the GPU.
    pub fn new(ctx: &GpuContext, pending: PendingTexel) -> Result<Self> {
        let PendingTexel {
            mut baked,
            volumes,
            species_count,
            trees,
            terrain,
        } = pending;
        baked.texels = volumes.unpack()?;
        let max_dim = ctx.device.limits().max_texture_dimension_3d;
        let scene = TexelScene::new(&baked, species_count, max_dim)?;
        let size = scene.atlas_size();
        let texture = ctx.checked("allocating the texel volumes", || {
            sampled_rgba8_texture(
                &ctx.device,
                "texel volumes",
                wgpu::TextureDimension::D3,
                size,
                scene.mips,
            )
        })?;
        for (level, (d, data)) in scene.atlas_levels(&baked).iter().enumerate() {
            write_rgba8(&ctx.queue, &texture, level as u32, UVec3::ZERO, data, *d);
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
                entries: &super::texel_layout_entries(),
            });
        let capacity = 64;
        let records = record_buffer(ctx, capacity);
        let bind_group = make_bind_group(ctx, &layout, &records, &view, &sampler);
        let sun_capacity = trees.clamp(1, MAX_TEXELS);
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
            volumes,
            species_count,
            stacks: None,
            stack_problem: None,
            terrain,
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
            let made = self
                .volumes
                .unpack()
                .and_then(|v| tiles::TileAssets::new(ctx, &self.terrain, world, &v));
            match made {
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
            let made = self
                .volumes
                .unpack()
                .and_then(|v| stacks::StackAssets::new(ctx, &v, self.species_count));
            match made {
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
        vcm: Option<&dyn TreeShades>,
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
            blended_pipeline(
                device,
                Blended {
                    label: "texel.wgsl",
                    layouts: [shadow_frame, layout],
                    source: crate::render::shaders::texel(),
                    vertex: "vs_texel",
                    fragment: "fs_texel_opacity",
                    format: crate::render::GROUND_FORMAT,
                    blend: transmit,
                    cull: None,
                    depth: (
                        crate::render::GROUND_DEPTH_FORMAT,
                        wgpu::CompareFunction::Less,
                    ),
                    depth_write: false,
                },
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
            .map(|s| s.pass.pipeline(device, frame_layout, format).clone());
        let tile = self
            .tiles
            .as_mut()
            .map(|t| t.pass.pipeline(device, frame_layout, format).clone());
        let polygon = self
            .polygons
            .as_mut()
            .map(|p| p.pass.pipeline(device, frame_layout, format).clone());
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
        self.pipelines.entry(format).or_insert_with(|| {
            [wgpu::Face::Back, wgpu::Face::Front].map(|cull| {
                super::over_pipeline(
                    device,
                    [frame_layout, layout],
                    "texel.wgsl",
                    ("vs_texel", "fs_texel"),
                    format,
                    Some(cull),
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
        spans: &PassSpans,
        stats: &mut FrameStats,
    ) {
        let n = frame.records.len() as u32;
        spans.rename("texel tiles");
        if let (Some(t), Some(p), false) = (&self.tiles, &pipelines.tile, frame.tiles.is_empty()) {
            // The far tiles first: everything else is nearer.
            let count = frame.tiles.len() as u32;
            t.pass.draw(pass, p, count);
            stats.draw_calls += 1;
            stats.triangles += u64::from(count) * 12;
        }
        spans.mark(pass, "texels");
        if frame.stats.texel_mode == TexelMode::Polygons {
            if let (Some(p), Some(pipe)) = (&self.polygons, &pipelines.polygon) {
                let vertices = frame.polygons.len() as u32;
                p.pass.draw(pass, pipe, vertices);
                stats.draw_calls += u32::from(vertices > 0);
                stats.trees_drawn = n;
                stats.triangles += u64::from(vertices / 3);
            }
            return;
        }
        if frame.stats.texel_mode == TexelMode::Stacks {
            if let (Some(s), Some(p)) = (&self.stacks, &pipelines.stack) {
                let quads = frame.quads.len() as u32;
                s.pass.draw(pass, p, quads);
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
    storage_buffer_of::<TexelGpu>(&ctx.device, "texels", capacity)
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
        entries: &super::texel_entries(records, view, sampler),
    })
}
