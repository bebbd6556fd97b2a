//! The render core: draws a frame of the forest into any `TextureView`, from a plain
//! [`FrameDesc`]. It never sees a window, so the viewer, the `render` command and the tests
//! all drive the same code.
//!
//! Each method is one module of [`method`] behind one interface ([`method::RenderMethod`]):
//! its CPU prepare step, the casters it gives the ground maps, its compute passes and its
//! draws. This file keeps what every method shares and runs a frame's steps through the
//! method the frame names ([`Renderer::render`]): the targets, the timestamps, the frame
//! uniforms and bind group, the sun cascades, the ground maps (allocated when a method
//! first needs them), the sky, the terrain and the reference's sky visibility and tree maps.
//! A frame's run, step by step, is in `frame_run.rs`; the reference's parts of the
//! renderer in `reference.rs`.

pub mod camera;
pub mod compositor;
pub mod consts;
pub mod context;
pub mod frame;
mod frame_bindings;
mod frame_run;
pub mod geometry_trees;
pub mod ground;
pub mod knob;
pub mod layer;
pub mod material;
pub mod measure;
pub mod memory;
mod meshes;
pub mod method;
pub mod overdraw;
mod pipelines;
mod reference;
pub mod scale;
pub mod self_shadow;
pub mod shaders;
pub mod shadow;
pub mod sky_visibility;
pub mod target;
pub mod terrain_maps;
pub mod timing;
pub mod uniforms;
pub mod vcm_shading;
pub mod voxelize;
pub mod world_gpu;

use std::collections::HashMap;

use image::RgbaImage;

pub use camera::{Camera, Frustum, OrthoView};
pub use context::{AdapterPreference, GpuContext};
pub use frame::{
    FrameDesc, FrameStats, Method, Reference, ShadowSettings, Sky, Stage, StudioOutput, Sun,
};
pub use ground::{
    GROUND_DEPTH_FORMAT, GROUND_FORMAT, GROUND_MAP_SIZE, ground_map_side, ground_preview_side,
};
pub use target::{OFFSCREEN_FORMAT, OffscreenTarget};

use frame_bindings::{DepthTarget, FrameBindings};
use ground::{GroundMaps, GroundTextures};
use meshes::MeshPasses;
use method::{Bake, RenderMethod};
use pipelines::{ColorPipelines, Layouts};
use shadow::{CascadeMaps, Cascades};
use sky_visibility::SkyVisibility;
use timing::GpuTimer;
use uniforms::FrameUniforms;
use world_gpu::WorldGpu;

use crate::model::World;
use crate::{Error, Result};

pub use consts::{DEPTH_FORMAT, MAX_SHADOW_MAP, SHADOW_FORMAT};

/// Where a frame goes: a view of a colour texture, its format and size.
#[derive(Clone, Copy, Debug)]
pub struct FrameTarget<'a> {
    pub view: &'a wgpu::TextureView,
    pub format: wgpu::TextureFormat,
    pub width: u32,
    pub height: u32,
}

/// Owns the GPU side of a world and the pipelines; created once, then asked for frames.
pub struct Renderer {
    layouts: Layouts,
    world: WorldGpu,
    color_pipelines: HashMap<wgpu::TextureFormat, ColorPipelines>,
    /// The pipelines built so far count fragments for the overdraw view.
    counting: bool,
    frame_uniforms: wgpu::Buffer,
    shadow_sampler: wgpu::Sampler,
    ground_sampler: wgpu::Sampler,
    bindings: Option<FrameBindings>,
    depth: Option<DepthTarget>,
    /// The trees' layer, made for the first frame that draws into it.
    layer: Option<layer::TreeLayer>,
    timer: Option<GpuTimer>,
    /// The sun cascades' pass and the main pass's mesh draws.
    meshes: MeshPasses,
    /// One of each method ([`method::registry`]).
    methods: Vec<Box<dyn RenderMethod>>,
    /// What the attached bake gives the image-based methods.
    bake: Bake,
    /// The ground shadow maps, once a method has used them.
    ground: Option<GroundMaps>,
    /// What group 0 binds in their place until then.
    ground_placeholder: GroundTextures,
    /// The reference's sky visibility, once [`Self::prepare_reference`] computed it.
    sky_vis: Option<SkyVisibility>,
    sky_placeholder: SkyVisibility,
    /// The overdraw view's counters (a one-pixel placeholder until the view is first on).
    overdraw: overdraw::OverdrawCounts,
    /// The texel bake's voxelisation pipeline, once asked for.
    voxel_pipeline: Option<voxelize::VoxelPipeline>,
    /// The reference's per-tree sun maps, once a reference frame used them.
    self_shadow: Option<self_shadow::SelfShadow>,
    /// What the cascade maps hold when the last frame drew them in the studio (its
    /// matrices, map size and casters, as bytes): a studio frame with the same key keeps
    /// them (the bake takes every view under one light in a row). None after any other
    /// frame, which clears or redraws them.
    studio_cascades: Option<Vec<u8>>,
    /// Frames in a row whose plan drew nothing into the cascades ([`shadow::cascade_side`]).
    frames_without_casters: u32,
    /// Unique among the renderers of this process (see [`Self::id`]).
    id: u64,
}

/// The next [`Renderer::id`].
static NEXT_RENDERER_ID: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(1);

impl Renderer {
    pub fn new(ctx: &GpuContext, world: &World) -> Result<Self> {
        let device = &ctx.device;
        let layouts = Layouts::new(device);
        let world_gpu = WorldGpu::new(ctx, world, &layouts.trees, &layouts.parts)?;
        let frame_uniforms = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("frame uniforms"),
            size: std::mem::size_of::<FrameUniforms>() as u64,
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let shadow_sampler = device.create_sampler(&wgpu::SamplerDescriptor {
            label: Some("shadow comparison"),
            mag_filter: wgpu::FilterMode::Linear,
            min_filter: wgpu::FilterMode::Linear,
            compare: Some(wgpu::CompareFunction::LessEqual),
            ..Default::default()
        });
        Ok(Self {
            meshes: MeshPasses::new(ctx, &layouts)?,
            methods: method::registry(),
            bake: Bake::unbaked(world),
            ground_placeholder: GroundTextures::placeholder(ctx)?,
            sky_vis: None,
            sky_placeholder: SkyVisibility::placeholder(ctx)?,
            overdraw: overdraw::OverdrawCounts::new(ctx, 1)?,
            ground_sampler: ground::ground_sampler(ctx),
            ground: None,
            layouts,
            world: world_gpu,
            color_pipelines: HashMap::new(),
            counting: false,
            frame_uniforms,
            shadow_sampler,
            bindings: None,
            depth: None,
            layer: None,
            timer: GpuTimer::new(ctx),
            voxel_pipeline: None,
            self_shadow: None,
            studio_cascades: None,
            frames_without_casters: 0,
            id: NEXT_RENDERER_ID.fetch_add(1, std::sync::atomic::Ordering::Relaxed),
        })
    }

    /// Loads a bake for the image-based methods (replacing any loaded before): its BTF
    /// image sets and visibility cube maps, and its texel volumes when it has them.
    pub fn attach_btf(
        &mut self,
        ctx: &GpuContext,
        baked: &crate::format::Baked,
        world: &World,
    ) -> Result<()> {
        let mut bake = Bake::load(ctx, baked, world)?;
        bake.surfels = std::mem::take(&mut self.bake.surfels).with_bake(baked);
        self.bake = bake;
        if let Some(g) = &mut self.ground {
            g.invalidate();
        }
        Ok(())
    }

    pub fn has_btf(&self) -> bool {
        self.bake.btf.is_some()
    }

    /// The attached bake has texel volumes (the `texel` method can draw).
    pub fn has_texels(&self) -> bool {
        self.bake.has_texels()
    }

    /// Names this renderer among the process's (work started for one renderer, such as a
    /// sky volume computed on another thread, is not handed to its successor).
    pub fn id(&self) -> u64 {
        self.id
    }

    /// Bytes of texel volumes on the GPU (0 without them).
    pub fn texel_bytes(&self) -> u64 {
        self.bake.texel.as_ref().map_or(0, |t| t.total_bytes())
    }

    /// Texel sizes of a species' three levels, from the attached bake.
    pub fn btf_texels(&self, species: usize) -> Option<crate::lod::LevelTexels> {
        self.bake.btf.as_ref().and_then(|b| b.texel_sizes(species))
    }

    /// The memory now: the process's, the GPU's allocations by part (from the
    /// allocator's report) and what this renderer keeps on the CPU besides.
    pub fn memory_report(&self, ctx: &GpuContext) -> memory::MemoryReport {
        let mut cpu = Vec::new();
        if let Some(b) = &self.bake.btf {
            b.cpu_parts(&mut cpu);
        }
        if let Some(t) = &self.bake.texel {
            t.cpu_parts(&mut cpu);
        }
        if let Some(p) = &self.bake.texel_pending {
            cpu.push(memory::MemoryPart {
                name: "texel volumes as baked, deflated, not yet drawn (CPU)".into(),
                bytes: p.bytes(),
                count: 1,
            });
        }
        memory::MemoryReport::new(&ctx.device, cpu)
    }

    /// Bytes of the scene's data on the GPU: the bake's images, volumes and atlases (every
    /// method's) and the trees' and terrain's meshes.
    pub fn scene_bytes(&self) -> u64 {
        self.bake.gpu_bytes() + self.world.mesh_bytes
    }

    /// Bytes of BTF images on the GPU (0 without a bake).
    pub fn btf_bytes(&self) -> u64 {
        self.bake.btf.as_ref().map_or(0, |b| b.bytes)
    }

    /// GPU bytes of the btf method's far-tree buffers (0 until the GPU builds far trees).
    pub fn far_bytes(&self) -> u64 {
        self.bake.btf.as_ref().map_or(0, |b| b.far_bytes())
    }

    /// What the tile compositor counted in the last frame that went through it (blocking;
    /// None before any).
    pub fn compositor_counters(
        &self,
        ctx: &GpuContext,
    ) -> Result<Option<compositor::CompositorCounters>> {
        match self.bake.btf.as_ref().and_then(|b| b.compositor()) {
            Some(c) => c.read_counters(ctx).map(Some),
            None => Ok(None),
        }
    }

    /// GPU bytes of the btf method's far canopy (0 before it is first drawn).
    pub fn canopy_bytes(&self) -> u64 {
        self.bake.btf.as_ref().map_or(0, |b| b.canopy_bytes())
    }

    /// GPU bytes of the btf method's tree-level light blends (0 without them).
    pub fn light_blend_bytes(&self) -> u64 {
        self.bake.btf.as_ref().map_or(0, |b| b.light_blend_bytes())
    }

    /// Bytes of visibility cube maps held in main memory (0 without them).
    pub fn vcm_bytes(&self) -> u64 {
        self.bake.btf.as_ref().map_or(0, |b| b.vcm_bytes())
    }

    /// Face resolution of the visibility cube maps, when loaded.
    pub fn vcm_resolution(&self) -> Option<u32> {
        self.bake.btf.as_ref().and_then(|b| b.vcm_resolution())
    }

    /// Triangles of one tree of each species, by species name.
    pub fn triangles_per_species(&self) -> Vec<(String, u64)> {
        self.world
            .species
            .iter()
            .map(|s| (s.name.clone(), s.triangles_per_tree()))
            .collect()
    }

    /// Bytes of meshes and part transforms on the GPU.
    pub fn mesh_bytes(&self) -> u64 {
        self.world.mesh_bytes
    }

    /// The newest GPU frame time measured without blocking (the viewer's readout).
    pub fn last_gpu_ms(&self) -> Option<f64> {
        self.timer.as_ref().and_then(|t| t.last_ms)
    }

    /// The newest frame's GPU time per pass, measured without blocking (the viewer's plot).
    pub fn last_passes(&self) -> Option<timing::PassTimes> {
        self.timer.as_ref().and_then(|t| t.last).map(|t| t.passes)
    }

    /// GPU time of the newest ground shadow maps' pass (the GPU side of a sun move), from
    /// timestamp queries, when the adapter has them.
    pub fn last_sun_update_gpu_ms(&self) -> Option<f64> {
        self.ground
            .as_ref()
            .and_then(|g| g.timer.as_ref())
            .and_then(|t| t.last_ms)
    }

    /// The cascades' maps at `size`, and group 0 binding them with the ground maps (or
    /// their placeholders); rebuilt when either changes.
    fn ensure_bindings(&mut self, ctx: &GpuContext, size: u32) -> Result<()> {
        let size = size.clamp(
            16,
            MAX_SHADOW_MAP.min(ctx.device.limits().max_texture_dimension_2d),
        );
        if self.bindings.as_ref().is_some_and(|b| {
            b.cascades.size == size
                && b.ground_maps == self.ground.is_some()
                && b.sky_volume == self.sky_vis.is_some()
                && b.overdraw_pixels == self.overdraw.pixels()
        }) {
            return Ok(());
        }
        let cascades = match self.bindings.take() {
            Some(b) if b.cascades.size == size => b.cascades,
            _ => CascadeMaps::new(ctx, size)?,
        };
        let ground = self
            .ground
            .as_ref()
            .map_or(&self.ground_placeholder, |g| &g.textures);
        let sky = match &self.sky_vis {
            Some(s) => (&s.view, &s.placement, true),
            None => (
                &self.sky_placeholder.view,
                &self.sky_placeholder.placement,
                false,
            ),
        };
        self.bindings = Some(FrameBindings::new(
            ctx,
            &self.layouts,
            &self.frame_uniforms,
            cascades,
            (&self.shadow_sampler, &self.ground_sampler),
            ground,
            sky,
            &self.overdraw,
        ));
        Ok(())
    }

    /// The image-based methods' ground sees the sky visibility in `frame`.
    pub fn ground_sky_applies(&self, frame: &FrameDesc) -> bool {
        frame.ground_sky
            && self.sky_vis.is_some()
            && frame.stage == Stage::World
            && self.method(frame.method).is_some_and(|m| m.shades_ground())
    }

    fn ensure_depth(&mut self, ctx: &GpuContext, width: u32, height: u32) -> Result<()> {
        if self
            .depth
            .as_ref()
            .is_none_or(|d| d.size != (width, height))
        {
            self.depth = Some(DepthTarget::new(ctx, width, height)?);
        }
        Ok(())
    }

    /// Fails with what to do when method `m` cannot draw with what is attached (nothing
    /// baked, no volumes or impostors in the bake).
    pub fn can_draw(&self, m: Method) -> Result<()> {
        match self.method(m) {
            Some(x) => x.check(&self.bake),
            None => Err(Error::BadInput(format!(
                "no method {} is registered",
                m.name()
            ))),
        }
    }

    /// The registered method that draws `m`.
    fn method(&self, m: Method) -> Option<&dyn RenderMethod> {
        self.methods
            .iter()
            .find(|x| x.method() == m)
            .map(|b| b.as_ref())
    }

    /// The uniforms of `frame` with its sun shadows on or off as prepared, and the sky
    /// visibility in them when `sky_hidden` (a reference frame, or an image-based method's
    /// ground).
    fn frame_uniforms_for(
        &self,
        frame: &FrameDesc,
        aspect: f32,
        cascades: &Cascades,
        shadows_on: bool,
        sky_hidden: bool,
    ) -> FrameUniforms {
        let mut uniform_frame = *frame;
        uniform_frame.shadows.enabled = shadows_on;
        let mut uniforms = FrameUniforms::new(&uniform_frame, aspect, cascades);
        if let Some(s) = self.sky_vis.as_ref().filter(|_| sky_hidden) {
            uniforms.sky_vis_count = s.count;
            uniforms.sky_vis_texel_world = s.cell;
        }
        uniforms
    }

    /// Renders one frame offscreen and reads it back; with `supersample` > 1, renders that
    /// many times larger on each side and averages down (coverage-correct ground truth).
    pub fn render_image(
        &mut self,
        ctx: &GpuContext,
        frame: &FrameDesc,
        width: u32,
        height: u32,
        supersample: u32,
    ) -> Result<(RgbaImage, FrameStats)> {
        let ss = supersample.max(1);
        let (w, h) = (width.saturating_mul(ss), height.saturating_mul(ss));
        target::check_size(w, h, Some(ctx))?;
        let target = OffscreenTarget::new(ctx, w, h)?;
        let stats = self.render(
            ctx,
            frame,
            FrameTarget {
                view: &target.view,
                format: OFFSCREEN_FORMAT,
                width: w,
                height: h,
            },
            true,
        )?;
        let img = target.read(ctx)?;
        Ok((target::downsample(&img, ss), stats))
    }
}
