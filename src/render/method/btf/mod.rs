//! The `btf` method: every tree as BTF billboards of its chosen level (Meyer, Neyret, Poulin
//! 2001). Per frame, on the CPU ([`prepare`]): each visible tree's level by the texel
//! criterion, expanded into billboards (the tree; its main branches; or its twigs, at their
//! instance transforms), each billboard's 3 nearest view and light samples in its object
//! frame with their weights, small weights culled, sorted back to front. On the GPU (this
//! file): one instanced draw samples a single texture array holding every image set.

mod atlas;
mod atlas_fill;
mod billboard;
pub mod far;
pub mod far_canopy;
mod front_to_back;
pub mod knobs;
pub mod light_blend;
pub mod method;
mod pipelines_btf;
pub mod prepare;
pub mod settings;

use std::collections::HashMap;

use glam::Vec3;

pub use crate::render::consts::ATLAS_SIDE;
pub use atlas::{BC7_ON_CPU_ADAPTERS, atlas_layers};
use atlas_fill::{Atlas, allocate_atlas, upload_images};
pub use billboard::{BillboardGpu, BillboardMode, NO_LIGHT_BLEND};
pub use prepare::{
    BtfFrame, BtfScene, LevelChoice, NearDrawGpu, PrepareView, SortedBillboards, choose_level,
};
pub use settings::{
    BtfSettings, BtfStats, CANOPY_COLOR, FETCHES_AT_MOST, GEOMETRY_COLOR, LOD_COLORS, PlaneMode,
};

use crate::Result;
use crate::format::Baked;
use crate::lod::LevelTexels;
use crate::model::World;
use crate::render::GpuContext;
use crate::render::camera::Frustum;
use crate::render::frame::FrameStats;
use crate::render::method::interface::DrawCx;
use crate::render::pipelines::storage_buffer_of;
use crate::render::timing::PassSpans;
use crate::render::world_gpu::{PartKind, TreeRun, WorldGpu};
use pipelines_btf::{btf_layout, make_bind_group};

/// Draws made in the main pass after a BTF frame's meshes and before its billboards.
pub(crate) type Between<'a> = &'a mut dyn FnMut(&mut wgpu::RenderPass<'_>, &mut FrameStats);

/// The BTF image sets on the GPU and the per-frame billboard buffer.
pub struct BtfAssets {
    scene: BtfScene,
    _texture: wgpu::Texture,
    texture_view: wgpu::TextureView,
    sampler: wgpu::Sampler,
    view_axes: wgpu::Buffer,
    layout: wgpu::BindGroupLayout,
    billboards: wgpu::Buffer,
    capacity: usize,
    max_capacity: usize,
    bind_group: wgpu::BindGroup,
    pipelines: HashMap<wgpu::TextureFormat, wgpu::RenderPipeline>,
    opacity_pipeline: Option<wgpu::RenderPipeline>,
    /// The billboards' pipeline into the trees' layer.
    layer_pipeline: Option<wgpu::RenderPipeline>,
    sun_billboards: wgpu::Buffer,
    sun_capacity: usize,
    sun_bind_group: wgpu::BindGroup,
    /// The far trees' GPU work, made on the first frame that wants it (None after that
    /// when the GPU cannot hold it).
    far: Option<Option<far::FarGpu>>,
    /// The tree level's light blends, in the texture array's last layers (None where the
    /// GPU cannot hold them).
    light_blend: Option<light_blend::LightBlend>,
    /// Every baked image's mean (premultiplied linear colour, coverage), for the canopy.
    means: Vec<[f32; 4]>,
    /// The forest seen from above, for the far canopy, until a frame wants it on the GPU.
    canopy_map: Option<far_canopy::map::CanopyMap>,
    canopy: Option<far_canopy::CanopyGpu>,
    /// The tile compositor, built the first time a frame asks for it.
    compositor: Option<crate::render::compositor::Compositor>,
    /// Bytes of the texture array, mipmaps included.
    pub bytes: u64,
}

/// One frame's request to [`BtfAssets::prepare`], as its parts take it.
struct FrameRequest<'a> {
    world: &'a WorldGpu,
    view: PrepareView<'a>,
    settings: &'a BtfSettings,
    trees_on: bool,
    hybrid: bool,
    lights: [Vec3; 3],
}

impl BtfAssets {
    /// Drops the render pipelines built so far (they are built again on next use).
    pub fn forget_pipelines(&mut self) {
        self.pipelines.clear();
        self.opacity_pipeline = None;
        self.layer_pipeline = None;
        self.compositor = None;
        if let Some(c) = self.canopy.as_mut() {
            c.forget_pipeline();
        }
    }

    /// What it keeps on the CPU: the visibility cube maps (read there, as in the
    /// thesis), every image's mean and the far canopy's map until it is uploaded.
    pub fn cpu_parts(&self, out: &mut Vec<crate::render::memory::MemoryPart>) {
        use crate::render::memory::{MemoryPart, vec_bytes};
        let mut push = |name: &str, bytes: u64| {
            if bytes > 0 {
                out.push(MemoryPart {
                    name: name.into(),
                    bytes,
                    count: 1,
                });
            }
        };
        push("visibility cube maps (CPU)", self.scene.vcm_bytes());
        push("BTF image means (CPU)", vec_bytes(&self.means));
        push(
            "far canopy map (CPU)",
            self.canopy_map.as_ref().map_or(0, |m| m.bytes()),
        );
    }

    pub fn new(ctx: &GpuContext, baked: &Baked, world: &World) -> Result<Self> {
        let mut scene = BtfScene::new(baked, world)?;
        let atlas = allocate_atlas(ctx, &scene, baked)?;
        let (bytes, means) = upload_images(ctx, &scene, baked, &atlas);
        let Atlas {
            texture,
            format,
            layers,
            blends,
            ..
        } = atlas;
        let t0 = std::time::Instant::now();
        let canopy_map = far_canopy::map::CanopyMap::of_world(world);
        log::debug!(
            "btf: the far canopy's map in {:.0} ms",
            t0.elapsed().as_secs_f64() * 1e3
        );
        let texture_view = texture.create_view(&wgpu::TextureViewDescriptor {
            format: Some(format.texture_format()),
            usage: Some(wgpu::TextureUsages::TEXTURE_BINDING),
            dimension: Some(wgpu::TextureViewDimension::D2Array),
            ..Default::default()
        });
        let blend = (blends > 0).then(|| {
            let first = (layers * u64::from(ATLAS_SIDE * ATLAS_SIDE)) as u32;
            scene.set_light_blend(light_blend::LIGHT_BINS, first);
            light_blend::LightBlend::new(ctx, &texture, layers as u32, blends as u32)
        });
        let sampler = ctx.device.create_sampler(&wgpu::SamplerDescriptor {
            label: Some("btf"),
            address_mode_u: wgpu::AddressMode::ClampToEdge,
            address_mode_v: wgpu::AddressMode::ClampToEdge,
            mag_filter: wgpu::FilterMode::Linear,
            min_filter: wgpu::FilterMode::Linear,
            mipmap_filter: wgpu::MipmapFilterMode::Linear,
            ..Default::default()
        });
        let axes = scene.view_axes();
        let view_axes = wgpu::util::DeviceExt::create_buffer_init(
            &ctx.device,
            &wgpu::util::BufferInitDescriptor {
                label: Some("btf view axes"),
                contents: bytemuck::cast_slice(&axes),
                usage: wgpu::BufferUsages::STORAGE,
            },
        );
        let layout = btf_layout(&ctx.device);
        let stride = std::mem::size_of::<BillboardGpu>();
        let limits = ctx.device.limits();
        let max_capacity = (limits
            .max_storage_buffer_binding_size
            .min(limits.max_buffer_size)
            / stride as u64) as usize;
        let capacity = 1024.min(max_capacity);
        let billboards = billboard_buffer(ctx, capacity);
        let bind_group = make_bind_group(
            ctx,
            &layout,
            &billboards,
            &view_axes,
            &texture_view,
            &sampler,
        );
        let sun_capacity = world.forest.instances.len().clamp(1, max_capacity);
        let sun_billboards = billboard_buffer(ctx, sun_capacity);
        let sun_bind_group = make_bind_group(
            ctx,
            &layout,
            &sun_billboards,
            &view_axes,
            &texture_view,
            &sampler,
        );
        Ok(Self {
            scene,
            _texture: texture,
            texture_view,
            sampler,
            view_axes,
            layout,
            billboards,
            capacity,
            max_capacity,
            bind_group,
            pipelines: HashMap::new(),
            opacity_pipeline: None,
            layer_pipeline: None,
            sun_billboards,
            sun_capacity,
            sun_bind_group,
            far: None,
            light_blend: blend,
            means,
            canopy_map,
            canopy: None,
            compositor: None,
            bytes,
        })
    }

    /// Reads every tree's cube maps in the sun's direction if it moved; true if it did.
    pub fn update_sun(&mut self, to_sun: Vec3) -> bool {
        self.scene.update_sun(to_sun)
    }

    /// Sets the tree level's light blends for the sun `to_sun` if it (or a knob that
    /// changes their weights) moved since they were made; true if so. Their draw is
    /// encoded by [`Self::encode_light_blend`].
    pub fn update_light_blend(
        &mut self,
        ctx: &GpuContext,
        to_sun: Vec3,
        settings: &BtfSettings,
    ) -> bool {
        match self.light_blend.as_mut() {
            Some(b) => b.update(ctx, &self.scene, to_sun, settings),
            None => false,
        }
    }

    /// The light blends' compute pass, when their weights changed, timed through `spans`.
    pub fn encode_light_blend(&self, encoder: &mut wgpu::CommandEncoder, spans: &PassSpans) {
        if let Some(b) = &self.light_blend {
            b.encode(encoder, spans);
        }
    }

    /// GPU bytes of the tree level's light blends (0 where there are none).
    pub fn light_blend_bytes(&self) -> u64 {
        self.light_blend.as_ref().map_or(0, |b| b.bytes)
    }

    /// Bytes of visibility cube maps held in main memory.
    pub fn vcm_bytes(&self) -> u64 {
        self.scene.vcm_bytes()
    }

    /// Face resolution of the visibility cube maps (None without them).
    pub fn vcm_resolution(&self) -> Option<u32> {
        self.scene.vcm_resolution()
    }

    /// What the method knows of the scene on the CPU.
    pub fn scene(&self) -> &BtfScene {
        &self.scene
    }

    /// Chooses levels, builds and sorts the billboards ([`BtfScene::prepare`]) and uploads
    /// them. With [`BtfSettings::gpu_far`], only the near trees are prepared here: those
    /// far enough to be one tree-level billboard each are left to the GPU ([`far`]; their
    /// records are built in [`Self::encode_far`]) and `visible` is not needed (None: the
    /// renderer skips its cull). Returns the frame and the milliseconds spent uploading the
    /// trees' VCM factors after the sun moved. Where the GPU cannot take the far trees
    /// (no room for their buffers, too many billboards for one binding), the CPU prepares
    /// every tree.
    #[allow(clippy::too_many_arguments)]
    pub fn prepare(
        &mut self,
        ctx: &GpuContext,
        world: &WorldGpu,
        visible: Option<&[Vec<u32>]>,
        trees_on: bool,
        camera: &crate::render::Camera,
        focal_px: f32,
        to_sun: Vec3,
        frustum: &Frustum,
        settings: &BtfSettings,
        hybrid: bool,
        lights: [Vec3; 3],
    ) -> (BtfFrame, f64) {
        let view = PrepareView {
            camera,
            focal_px,
            to_sun,
            frustum,
        };
        if settings.gpu_far && self.far.is_none() {
            // Without it (no room, no trees, a GPU that cannot) the CPU prepares every tree.
            self.far = Some(
                far::FarGpu::new(
                    ctx,
                    &self.scene,
                    &world.tree_data,
                    &world.tree_species,
                    &world.tree_bounds,
                    &self.layout,
                    (&self.view_axes, &self.texture_view, &self.sampler),
                    &self.means,
                )
                .unwrap_or_else(|e| {
                    log::warn!("the far trees stay on the CPU: {e}");
                    None
                }),
            );
        }
        let request = FrameRequest {
            world,
            view,
            settings,
            trees_on,
            hybrid,
            lights,
        };
        if let Some(frame) = self.prepare_far(ctx, &request) {
            return frame;
        }
        if let Some(Some(f)) = self.far.as_mut() {
            f.clear();
        }
        let culled;
        let visible = match visible {
            Some(v) => v,
            None => {
                culled = if trees_on {
                    world.cull(frustum)
                } else {
                    vec![Vec::new(); world.species.len()]
                };
                &culled[..]
            }
        };
        (self.prepare_on_cpu(ctx, &request, visible), 0.0)
    }

    /// [`Self::prepare`] with the far trees on the GPU, where it takes them (None where it
    /// does not): the near trees prepared here, the far canopy's tiles chosen. Where the
    /// near trees' records do not fit, the frame is the CPU's alone.
    fn prepare_far(
        &mut self,
        ctx: &GpuContext,
        request: &FrameRequest<'_>,
    ) -> Option<(BtfFrame, f64)> {
        let &FrameRequest {
            world,
            ref view,
            settings,
            trees_on,
            hybrid,
            lights,
        } = request;
        let f = self
            .far
            .as_mut()
            .and_then(Option::as_mut)
            .filter(|_| settings.gpu_far)?;
        let t0 = std::time::Instant::now();
        // The far canopy, on the GPU the first time the knob asks for it (once: the
        // map is not kept on the CPU).
        if settings.far_canopy
            && let Some(m) = self.canopy_map.take()
        {
            self.canopy = far_canopy::CanopyGpu::new(ctx, &m, &self.sampler)
                .map_err(|e| log::warn!("no far canopy: {e}"))
                .ok();
        }
        let canopy_frame = self.canopy.as_ref().and_then(|c| c.frame(settings, lights));
        let (near, shade_ms) = f.prepare(
            ctx,
            &self.scene,
            &world.tree_data,
            &world.tree_bounds,
            view,
            settings,
            trees_on,
            canopy_frame.as_ref(),
        );
        let canopy_tiles = match (f.canopy_band(), self.canopy.as_mut()) {
            (Some(band), Some(c)) if trees_on => c.prepare(
                ctx,
                view.camera.position,
                view.frustum,
                band,
                settings.show_lod.then_some(CANOPY_COLOR),
                f.canopy_colours(),
            ),
            _ => 0,
        };
        log::debug!(
            "btf prepare: far canopy {:?} m, {canopy_tiles} tiles",
            f.canopy_band()
        );
        let t1 = std::time::Instant::now();
        // Unsorted: the GPU sorts them with the far trees' billboards. With `gpu_near`
        // the CPU only chooses their levels, and the GPU expands them.
        let (mut out, records, draws, slots) = if settings.gpu_near {
            self.scene.prepare_near(
                &world.tree_data,
                &world.tree_species,
                &near,
                view,
                settings,
                hybrid,
                f.expand_limit(),
            )
        } else {
            let (out, records) =
                self.scene
                    .prepare_sorted(&world.tree_data, &near, view, settings, 0, hybrid);
            (out, records, Vec::new(), 0)
        };
        let t2 = std::time::Instant::now();
        let uploaded = f.upload_near(ctx, &records, &draws, slots);
        let ms = |a: std::time::Instant, b: std::time::Instant| (b - a).as_secs_f64() * 1e3;
        log::debug!(
            "btf prepare: near trees found in {:.2} ms (VCM factors uploaded in {shade_ms:.2}), \
             {} near trees' levels in {:.2} ms ({} CPU records, {} draws, {slots} slots), \
             uploaded in {:.2} ms",
            ms(t0, t1) - shade_ms,
            near.iter().map(Vec::len).sum::<usize>(),
            ms(t1, t2),
            records.len(),
            draws.len(),
            ms(t2, std::time::Instant::now()),
        );
        match uploaded {
            Ok(true) => {
                out.far = true;
                out.layer_batches = f.layer_batches();
                out.compositor = (settings.compositor && out.layer_batches > 0)
                    .then_some(settings.compositor_knobs());
                out.stats.canopy_tiles = canopy_tiles;
                return Some((out, shade_ms));
            }
            Ok(false) => {}
            Err(e) => log::warn!("this frame's trees stay on the CPU: {e}"),
        }
        if !trees_on {
            return Some((out, shade_ms));
        }
        // Too many near billboards for one binding (or one dispatch) with the trees'
        // slots: this frame is the CPU's alone, which keeps the nearest.
        let all = world.cull(view.frustum);
        Some((self.prepare_on_cpu(ctx, request, &all), shade_ms))
    }

    /// Prepares the trees of `visible` on the CPU, sorted, and uploads their billboards.
    fn prepare_on_cpu(
        &mut self,
        ctx: &GpuContext,
        request: &FrameRequest<'_>,
        visible: &[Vec<u32>],
    ) -> BtfFrame {
        let (mut out, sorted) = self.scene.prepare_sorted(
            &request.world.tree_data,
            visible,
            &request.view,
            request.settings,
            self.max_capacity,
            request.hybrid,
        );
        out.layer_batches = front_to_back::cpu_layer_batches(request.settings, sorted.len());
        out.compositor = (request.settings.compositor && out.layer_batches > 0)
            .then_some(request.settings.compositor_knobs());
        self.upload_sorted(ctx, &sorted, out.layer_batches > 0);
        out
    }

    /// Builds the tile compositor (once) and makes room in it for `bf`'s billboards, where
    /// `bf` goes through it.
    pub fn ensure_compositor(
        &mut self,
        ctx: &GpuContext,
        frame_layout: &wgpu::BindGroupLayout,
        bf: &BtfFrame,
    ) {
        if bf.compositor.is_none() {
            return;
        }
        let layout = &self.layout;
        let c = self.compositor.get_or_insert_with(|| {
            crate::render::compositor::Compositor::new(&ctx.device, frame_layout, layout)
        });
        let records = match self.far.as_ref().and_then(Option::as_ref) {
            Some(f) if bf.far => f.sorted_capacity(),
            _ => u64::from(bf.billboards),
        };
        c.reserve(ctx, records);
    }

    /// The tile compositor (None before a frame asked for it).
    pub fn compositor(&self) -> Option<&crate::render::compositor::Compositor> {
        self.compositor.as_ref()
    }

    /// Whether this frame's far trees go to the GPU (the renderer then needs no cull).
    pub fn takes_far(&self, settings: &BtfSettings) -> bool {
        settings.gpu_far && !matches!(self.far, Some(None))
    }

    /// After the frame's submission: adds the far billboards drawn (the latest count read
    /// back; this frame's when `wait`) to `stats`.
    pub fn add_far_stats(&self, ctx: &GpuContext, wait: bool, stats: &mut FrameStats) {
        let Some(Some(f)) = &self.far else {
            return;
        };
        if !f.has_frame() {
            return;
        }
        let Some([n, twigs, branches, trees, images, saved, blended, canopy]) = f.drawn(ctx, wait)
        else {
            return;
        };
        use crate::model::Level;
        let near = twigs + branches + trees;
        if let Some(b) = stats.btf.as_mut() {
            b.trees_per_level[Level::Tree] += n;
            b.billboards[Level::Tree] += n + trees;
            b.billboards[Level::Branch] += branches;
            b.billboards[Level::Twig] += twigs;
            b.gpu_billboards += n + near;
            b.images_sampled += u64::from(images);
            b.fetches_saved += u64::from(saved);
            b.light_blended += blended;
            b.canopy_trees += canopy;
        }
        stats.trees_drawn += n;
        stats.triangles += 2 * u64::from(n + near);
    }

    /// The far trees' compute passes of the frame last prepared, timed through `spans`.
    pub fn encode_far(&self, encoder: &mut wgpu::CommandEncoder, spans: &PassSpans) {
        if let Some(f) = self.far.as_ref().and_then(Option::as_ref) {
            f.encode(encoder, spans);
        }
    }

    /// GPU bytes of the far trees' buffers (0 until used).
    /// Builds the far canopy's pipeline for `format` (when the canopy is on the GPU).
    pub fn ensure_canopy_pipeline(
        &mut self,
        device: &wgpu::Device,
        frame_layout: &wgpu::BindGroupLayout,
        format: wgpu::TextureFormat,
    ) {
        if let Some(c) = self.canopy.as_mut() {
            c.ensure_pipeline(device, frame_layout, format);
        }
    }

    /// GPU bytes of the far canopy's map (0 before it is first drawn).
    pub fn canopy_bytes(&self) -> u64 {
        self.canopy.as_ref().map_or(0, |c| c.bytes)
    }

    pub fn far_bytes(&self) -> u64 {
        self.far
            .as_ref()
            .and_then(Option::as_ref)
            .map_or(0, far::FarGpu::bytes)
    }

    /// Uploads a frame's billboards, copied from their chunks straight into the upload
    /// (growing the buffer if needed).
    fn upload_sorted(&mut self, ctx: &GpuContext, sorted: &SortedBillboards, front_to_back: bool) {
        self.reserve(ctx, sorted.len());
        let n = sorted.len().min(self.capacity);
        let size = (n * std::mem::size_of::<BillboardGpu>()) as u64;
        let Some(size) = wgpu::BufferSize::new(size) else {
            return;
        };
        // None only where the write is invalid, which wgpu reports to the device's error
        // handler (as `write_buffer` would).
        if let Some(mut view) = ctx.queue.write_buffer_with(&self.billboards, 0, size) {
            sorted.write(view.slice(..), front_to_back);
        }
    }

    /// Grows the billboard buffer to hold `count` records (up to the GPU's limit).
    fn reserve(&mut self, ctx: &GpuContext, count: usize) {
        if count > self.capacity {
            self.capacity = (count * 3 / 2).min(self.max_capacity);
            self.billboards = billboard_buffer(ctx, self.capacity);
            self.bind_group = make_bind_group(
                ctx,
                &self.layout,
                &self.billboards,
                &self.view_axes,
                &self.texture_view,
                &self.sampler,
            );
        }
    }

    /// The frame's draws in the main pass: the trunks (and limbs) of the trees drawn at the
    /// finer levels as geometry (`runs`: trunk only, then trunk and limbs; the terrain with
    /// the first when asked), the trees drawn wholly as geometry (`hybrid`'s, and those of a
    /// species without finer levels: `runs[2]` trunk and limbs, `runs[3]` twigs fading),
    /// `between` (what is opaque and not geometry: `hybrid`'s impostors), then every
    /// billboard in one instanced draw, back to front.
    #[allow(clippy::too_many_arguments)]
    pub(crate) fn draw_main(
        &self,
        pass: &mut wgpu::RenderPass<'_>,
        cx: &DrawCx<'_>,
        runs: &[Vec<TreeRun>],
        pipeline: Option<&wgpu::RenderPipeline>,
        bf: &BtfFrame,
        stats: &mut FrameStats,
        between: Between<'_>,
    ) {
        let (world, pipes) = (cx.world, cx.pipes);
        // The trees drawn as meshes (trunks and limbs, `hybrid`'s whole trees), then the
        // billboards, timed apart.
        cx.spans.rename("near trees");
        let (t0, _, c0) = world.draw(
            pass,
            &runs[0],
            Some(pipes.meshes()),
            false,
            &[PartKind::Trunk],
        );
        let (t1, _, c1) = world.draw(
            pass,
            &runs[1],
            Some(pipes.meshes()),
            false,
            &[PartKind::Trunk, PartKind::Limbs],
        );
        // The trees drawn whole (`hybrid`'s past the twig level, a species without finer
        // levels), with their own shadows: trunk and limbs whole, twigs faded in.
        let mut hybrid = |list: usize, kinds: &[PartKind]| match runs.get(list) {
            Some(r) => world.draw(pass, r, Some(pipes.faded_meshes()), false, kinds),
            None => (0, 0, 0),
        };
        let (t2a, _, c2a) = hybrid(2, &[PartKind::Trunk, PartKind::Limbs]);
        let (t2b, _, c2b) = hybrid(3, &[PartKind::Twigs]);
        let (t2, c2) = (t2a + t2b, c2a + c2b);
        stats.triangles += t0 + t1 + t2 + 2 * u64::from(bf.billboards);
        stats.trees_drawn = bf.stats.trees_per_level.iter().sum::<u32>() + bf.stats.geometry_trees;
        stats.draw_calls += c0 + c1 + c2;
        between(pass, stats);
        // The far canopy under the billboards that fade into it.
        if bf.far
            && bf.stats.canopy_tiles > 0
            && let Some(c) = &self.canopy
        {
            cx.spans.mark(pass, "far canopy");
            if c.draw(pass) {
                stats.draw_calls += 1;
            }
        }
        stats.btf = Some(bf.stats);
        if bf.layer_batches > 0 {
            // Drawn front to back after the main pass (`draw_layer`).
            return;
        }
        cx.spans.mark(pass, "billboards");
        // Sorted on the GPU with the far trees' billboards, or on the CPU.
        if let Some(pipeline) = pipeline
            && bf.far
            && let Some(Some(f)) = &self.far
        {
            pass.set_pipeline(pipeline);
            if f.draw(pass) {
                stats.draw_calls += 1;
            }
        } else if let Some(pipeline) = pipeline
            && bf.billboards > 0
        {
            pass.set_pipeline(pipeline);
            pass.set_bind_group(1, &self.bind_group, &[]);
            pass.draw(0..6, 0..bf.billboards);
            stats.draw_calls += 1;
        }
    }

    /// Uploads a frame's billboard records (back to front), growing the buffer if needed.
    pub fn upload(&mut self, ctx: &GpuContext, records: &[BillboardGpu]) {
        self.reserve(ctx, records.len());
        let n = records.len().min(self.capacity);
        if n > 0 {
            ctx.queue
                .write_buffer(&self.billboards, 0, bytemuck::cast_slice(&records[..n]));
        }
    }

    /// Most billboards one frame can hold (the GPU's storage-buffer limit).
    pub fn max_billboards(&self) -> usize {
        self.max_capacity
    }

    /// Every tree's tree-level billboard as the sun sees it (for the ground alpha shadow
    /// map). Returns how many were uploaded.
    pub fn prepare_sun(
        &mut self,
        ctx: &GpuContext,
        world: &WorldGpu,
        to_sun: Vec3,
        excluded: &[u32],
    ) -> u32 {
        let out = self.scene.sun_billboards(
            &world.tree_data,
            &world.tree_species,
            to_sun,
            self.sun_capacity,
            excluded,
        );
        if !out.is_empty() {
            ctx.queue
                .write_buffer(&self.sun_billboards, 0, bytemuck::cast_slice(&out));
        }
        out.len() as u32
    }

    /// The opacity pipeline of the ground alpha shadow map.
    pub fn opacity_pipeline(
        &mut self,
        device: &wgpu::Device,
        light_frame_layout: &wgpu::BindGroupLayout,
    ) -> &wgpu::RenderPipeline {
        let layout = &self.layout;
        self.opacity_pipeline.get_or_insert_with(|| {
            pipelines_btf::build_opacity_pipeline(device, light_frame_layout, layout)
        })
    }

    pub fn sun_bind_group(&self) -> &wgpu::BindGroup {
        &self.sun_bind_group
    }

    pub fn pipeline(
        &mut self,
        device: &wgpu::Device,
        frame_layout: &wgpu::BindGroupLayout,
        format: wgpu::TextureFormat,
    ) -> &wgpu::RenderPipeline {
        let layout = &self.layout;
        self.pipelines
            .entry(format)
            .or_insert_with(|| pipelines_btf::build_pipeline(device, frame_layout, layout, format))
    }

    /// The billboards' pipeline into the trees' layer.
    pub fn layer_pipeline(
        &mut self,
        device: &wgpu::Device,
        frame_layout: &wgpu::BindGroupLayout,
    ) -> &wgpu::RenderPipeline {
        let layout = &self.layout;
        self.layer_pipeline.get_or_insert_with(|| {
            pipelines_btf::build_layer_pipeline(device, frame_layout, layout)
        })
    }

    pub fn bind_group(&self) -> &wgpu::BindGroup {
        &self.bind_group
    }

    /// Texel sizes of one species' levels, for tests and tools.
    pub fn texel_sizes(&self, species: usize) -> Option<LevelTexels> {
        self.scene.texel_sizes(species)
    }
}

fn billboard_buffer(ctx: &GpuContext, capacity: usize) -> wgpu::Buffer {
    storage_buffer_of::<BillboardGpu>(&ctx.device, "btf billboards", capacity)
}
