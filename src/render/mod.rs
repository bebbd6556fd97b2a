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
//! (Just over 800 lines: [`Renderer::render`] is the frame's one sequence of passes and
//! reads best whole.)

pub mod camera;
pub mod consts;
pub mod context;
pub mod frame;
mod frame_bindings;
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
pub mod voxelize;
pub mod world_gpu;

use std::collections::HashMap;

use image::RgbaImage;

pub use camera::{Camera, Frustum, OrthoView};
pub use context::{AdapterPreference, GpuContext};
pub use frame::{
    FrameDesc, FrameStats, Method, Reference, ShadowSettings, Sky, Stage, StudioOutput, Sun,
};
pub use ground::{GROUND_DEPTH_FORMAT, GROUND_FORMAT, GROUND_MAP_SIZE, GROUND_PREVIEW_SIZE};
pub use method::btf;
pub use target::{OFFSCREEN_FORMAT, OffscreenTarget};

use frame_bindings::{DepthTarget, FrameBindings};
use ground::{GroundBillboards, GroundMaps, GroundTextures};
use meshes::{MeshPasses, encode_cascades, studio_cascades_key};
use method::{AfterCx, Bake, DrawCx, Plan, PrepareCx, PrepareView, RenderMethod, SunWork};
use pipelines::{ColorPipelines, Layouts};
use shadow::{CascadeMaps, Cascades};
use sky_visibility::SkyVisibility;
use timing::{GpuTimer, PassSpans};
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
            bake: Bake::default(),
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
        self.bake = Bake::load(ctx, baked, world)?;
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

    /// Bytes of BTF images on the GPU (0 without a bake).
    pub fn btf_bytes(&self) -> u64 {
        self.bake.btf.as_ref().map_or(0, |b| b.bytes)
    }

    /// GPU bytes of the btf method's far-tree buffers (0 until the GPU builds far trees).
    pub fn far_bytes(&self) -> u64 {
        self.bake.btf.as_ref().map_or(0, |b| b.far_bytes())
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

    /// Draws `frame` into `target` and submits the work. With `measure_gpu`, waits for the
    /// GPU and returns its frame time in the stats; otherwise the time arrives a few frames
    /// later in [`Self::last_gpu_ms`].
    ///
    /// The steps: the method's CPU work, the reference's own tree maps, the frame uniforms
    /// and the ground shadow maps (when the sun moved), then one encoder with the method's
    /// compute passes, the sun cascades, the main pass (sky, then the method's draws) and
    /// the reference's trees; after the submission, the timings and what the method counted.
    pub fn render(
        &mut self,
        ctx: &GpuContext,
        frame: &FrameDesc,
        target: FrameTarget<'_>,
        measure_gpu: bool,
    ) -> Result<FrameStats> {
        let FrameTarget {
            view: target,
            format,
            width,
            height,
        } = target;
        target::check_size(width, height, Some(ctx))?;
        if ctx.is_lost() {
            return Err(Error::Gpu("the GPU device was lost; restart canopy".into()));
        }
        let frame = &self.effective_frame(frame)?;
        let studio = frame.stage == Stage::Studio;
        let index = self
            .methods
            .iter()
            .position(|m| m.method() == frame.method)
            .ok_or_else(|| {
                Error::BadInput(format!("no method {} is registered", frame.method.name()))
            })?;
        self.methods[index].check(&self.bake)?;
        // Image-based trees are not geometry, so their shadows on the ground come from the
        // alpha shadow map, and the terrain's own shadows from the terrain depth drawn with
        // it, both rebuilt only when the sun moves.
        let ground_on = self.methods[index].shades_ground()
            && frame.ground_shadows
            && frame.sun.elevation_deg > 0.0
            && !studio;
        if ground_on && self.ground.is_none() {
            self.ground = Some(GroundMaps::new(ctx, &self.layouts)?);
        }
        self.ensure_depth(ctx, width, height)?;
        let overdraw_view = frame.overdraw.filter(|_| !studio);
        let pixels = u64::from(width) * u64::from(height);
        if overdraw_view.is_some() && self.overdraw.pixels() < pixels {
            self.overdraw = overdraw::OverdrawCounts::new(ctx, pixels)?;
        }
        // Pipelines count fragments only while the view is on (`frame.wgsl`): built again
        // when it turns on or off.
        let counting = overdraw_view.is_some();
        if counting != self.counting {
            self.counting = counting;
            self.color_pipelines.clear();
            if let Some(s) = self.self_shadow.as_mut() {
                s.forget_pipelines();
            }
            self.bake.forget_pipelines();
        }
        shaders::set_counting(counting);
        if !self.color_pipelines.contains_key(&format) {
            let p = ctx.checked("building the render pipelines", || {
                ColorPipelines::new(&ctx.device, &self.layouts, format)
            })?;
            self.color_pipelines.insert(format, p);
        }

        // The method's CPU work. Work that follows the sun, not the camera (the VCM reads
        // there, the ground maps below) is timed as the sun update.
        let prepare_start = std::time::Instant::now();
        let aspect = width as f32 / height as f32;
        let cam = &frame.camera;
        let frustum = cam.frustum(aspect);
        let method = &mut self.methods[index];
        let terrain_levels = (method.shades_ground() && frame.terrain_px > 0.0).then(|| {
            self.world.terrain_view(
                &frustum,
                cam.position,
                cam.focal_px(height),
                frame.terrain_px,
            )
        });
        let visible = if frame.trees && !method.culls_itself(&self.bake, frame) {
            self.world.cull(&frustum)
        } else {
            vec![Vec::new(); self.world.species.len()]
        };
        let plan = method.prepare(
            &mut self.bake,
            PrepareCx {
                ctx,
                world: &self.world,
                frame,
                view: PrepareView {
                    camera: cam,
                    focal_px: cam.focal_px(height),
                    to_sun: frame.sun.direction(),
                    frustum: &frustum,
                },
                aspect,
                visible,
            },
        )?;
        method.ensure_pipelines(&mut self.bake, ctx, &self.layouts, format)?;
        let casts = plan.casters.is_some() || plan.self_shadowed.is_some();
        self.frames_without_casters = if casts {
            0
        } else {
            self.frames_without_casters.saturating_add(1)
        };
        let held = self.bindings.as_ref().map(|b| b.cascades.size);
        let side = shadow::cascade_side(frame.shadows.map_size, held, self.frames_without_casters);
        self.ensure_bindings(ctx, side)?;
        if plan.layer {
            let layer = self
                .layer
                .get_or_insert_with(|| layer::TreeLayer::new(&ctx.device));
            layer.ensure(ctx, width, height, format)?;
        }
        let self_batches = self.prepare_self_shadow(ctx, frame, &plan, format)?;
        let prepare_ms = prepare_start.elapsed().as_secs_f64() * 1e3 - plan.sun.ms;

        // The uniforms, with the ground maps rebuilt first when the sun moved.
        let sky_hidden = frame.reference_drawn().is_some() || self.ground_sky_applies(frame);
        let mut uniforms =
            self.frame_uniforms_for(frame, aspect, &plan.cascades, plan.shadows_on, sky_hidden);
        uniforms.hybrid_cascades = u32::from(plan.geometry_tree_cascades && plan.shadows_on);
        if let Some(view) = overdraw_view {
            uniforms.overdraw = [1, width, height, view.index()];
        }
        let mut sun = plan.sun;
        if ground_on {
            self.update_ground(
                ctx,
                index,
                frame,
                &plan,
                &mut uniforms,
                measure_gpu,
                &mut sun,
            );
        }
        ctx.queue
            .write_buffer(&self.frame_uniforms, 0, bytemuck::bytes_of(&uniforms));
        self.meshes
            .write_uniforms(ctx, &uniforms, &plan.cascades, plan.shadows_on);

        let mut stats = FrameStats {
            width,
            height,
            prepare_ms: prepare_ms.max(0.0),
            sun_update: sun.moved,
            sun_update_ms: sun.moved.then_some(sun.ms),
            ground_map_size: self
                .ground
                .as_ref()
                .filter(|_| ground_on)
                .and_then(|g| g.built_size()),
            ..Default::default()
        };
        let spans = self
            .timer
            .as_mut()
            .map_or_else(PassSpans::off, GpuTimer::begin);
        let self_shadow = self.self_shadow.as_ref().filter(|_| self_batches.is_some());
        let studio_key = plan
            .studio_casters
            .as_ref()
            .filter(|_| self_shadow.is_none())
            .map(|c| studio_cascades_key(&plan.cascades, frame.shadows.map_size, c));
        let keep = studio_key.is_some() && self.studio_cascades == studio_key;
        let (Some(bindings), Some(depth), Some(pipes)) = (
            &self.bindings,
            &self.depth,
            self.color_pipelines.get(&format),
        ) else {
            return Err(Error::Gpu("render targets were not created".into()));
        };
        let method = &self.methods[index];
        let mut encoder = ctx
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                label: Some("frame"),
            });
        // Each pass is timed as a span of its own (see `timing`): the method's compute
        // passes, the cascades, then the main pass split into the sky, the terrain and the
        // method's draws where the adapter can time inside a pass.
        if overdraw_view.is_some() {
            self.overdraw.clear(&mut encoder, width, height);
        }
        method.encode_compute(&self.bake, &mut encoder, &spans);
        encode_cascades(
            &mut encoder,
            bindings,
            &self.meshes,
            &self.world,
            plan.casters.as_deref().filter(|_| !keep),
            plan.terrain_casts,
            self_shadow,
            keep,
            &spans,
            &mut stats,
        );
        // The reference's trees are drawn after the main pass, batch by batch.
        let batches = self_batches.as_deref().unwrap_or(&[]);
        {
            let main = spans.open(if studio || !spans.splits_passes() {
                "main pass"
            } else {
                "sky"
            });
            let mut pass = depth.color_pass(
                &mut encoder,
                "main",
                target,
                Some(if studio {
                    wgpu::Color::TRANSPARENT
                } else {
                    wgpu::Color::BLACK
                }),
                !batches.is_empty() || plan.layer,
                spans.render_writes(main, true, true),
            );
            pass.set_bind_group(0, &bindings.bind_group, &[]);
            if !studio {
                pass.set_pipeline(&pipes.sky);
                pass.draw(0..3, 0..1);
                stats.draw_calls += 1;
            }
            pass.set_bind_group(1, &self.world.trees_bind_group(), &[]);
            if !studio {
                // Instance 0 of every method's upload is the terrain's.
                spans.mark(&mut pass, "terrain");
                let (tris, calls) = match &terrain_levels {
                    Some(levels) => {
                        pass.set_pipeline(pipes.meshes().opaque);
                        self.world.draw_terrain_levels(&mut pass, levels)
                    }
                    None => {
                        let (tris, _, calls) =
                            self.world
                                .draw(&mut pass, &[], Some(pipes.meshes()), true, &[]);
                        (tris, calls)
                    }
                };
                stats.triangles += tris;
                stats.draw_calls += calls;
            }
            spans.mark(&mut pass, method.method().name());
            let cx = DrawCx {
                world: &self.world,
                pipes,
                frame_group: &bindings.bind_group,
                trees_after: !batches.is_empty(),
                spans: &spans,
            };
            method.draw(&self.bake, &mut pass, &cx, &mut stats);
        }
        if plan.layer
            && let Some(layer) = &self.layer
        {
            let cx = AfterCx {
                frame_group: &bindings.bind_group,
                depth,
                layer,
                target,
                format,
                spans: &spans,
            };
            method.draw_after(&self.bake, &mut encoder, &cx, &mut stats);
        }
        if let Some(ss) = self_shadow.filter(|_| !batches.is_empty()) {
            ss.draw_trees(
                &mut encoder,
                &self.world,
                &bindings.bind_group,
                (target, format, depth),
                batches,
                &spans,
                &mut stats,
            )?;
        }
        if overdraw_view.is_some() {
            let heat = spans.open("overdraw view");
            let mut pass = encoder.begin_render_pass(&wgpu::RenderPassDescriptor {
                label: Some("overdraw view"),
                color_attachments: &[Some(wgpu::RenderPassColorAttachment {
                    view: target,
                    depth_slice: None,
                    resolve_target: None,
                    ops: wgpu::Operations {
                        load: wgpu::LoadOp::Load,
                        store: wgpu::StoreOp::Store,
                    },
                })],
                depth_stencil_attachment: None,
                timestamp_writes: spans.render_writes(heat, true, true),
                occlusion_query_set: None,
                multiview_mask: None,
            });
            pass.set_pipeline(&pipes.overdraw);
            pass.set_bind_group(0, &bindings.bind_group, &[]);
            pass.draw(0..3, 0..1);
        }
        if let Some(t) = &mut self.timer {
            t.resolve(spans, &mut encoder);
        }
        ctx.queue.submit([encoder.finish()]);
        self.studio_cascades = studio_key;

        if let Some(t) = &mut self.timer {
            t.after_submit();
            if let Some(timing) = t.collect(ctx, measure_gpu).filter(|_| measure_gpu) {
                stats.gpu_ms = Some(timing.frame_ms);
                stats.passes = timing.passes;
            }
        }
        self.methods[index].finish(&self.bake, ctx, measure_gpu, &mut stats);
        if overdraw_view.is_some() && measure_gpu {
            stats.overdraw = Some(self.overdraw.means(ctx, width, height)?);
        }
        if let Some(t) = self.ground.as_mut().and_then(|g| g.timer.as_mut()) {
            t.collect(ctx, measure_gpu);
        }
        if let Some(e) = ctx.take_error() {
            return Err(Error::Gpu(e));
        }
        Ok(stats)
    }

    /// Rebuilds the ground shadow maps when the sun moved (or the trees or casters changed),
    /// from the method's casters seen from the sun, and sets their uniforms; submitted on
    /// their own so that their cost can be timed (blocking, when measuring), as sun work.
    #[allow(clippy::too_many_arguments)]
    fn update_ground(
        &mut self,
        ctx: &GpuContext,
        index: usize,
        frame: &FrameDesc,
        plan: &Plan,
        uniforms: &mut FrameUniforms,
        measure_gpu: bool,
        sun: &mut SunWork,
    ) {
        let Some(ground) = self.ground.as_mut() else {
            return;
        };
        let excluded_key = plan.ground_excluded.iter().fold(0u64, |h, &t| {
            (h ^ u64::from(t) ^ 0x9e37_79b9_7f4a_7c15).wrapping_mul(0x0100_0000_01b3)
        });
        let (want, rebuild) = ground.wanted(
            frame.sun.direction(),
            frame.trees,
            frame.method,
            frame.sun_held,
            excluded_key,
        );
        if rebuild {
            let t0 = std::time::Instant::now();
            let casters = if want.trees {
                self.methods[index].ground_casters(
                    &mut self.bake,
                    ctx,
                    &self.layouts,
                    &self.world,
                    want.to_sun,
                    &plan.ground_excluded,
                )
            } else {
                None
            };
            let billboards = casters.as_ref().map(|c| GroundBillboards {
                pipeline: &c.pipeline,
                bind_group: &c.bind_group,
                count: c.count,
                vertices: c.vertices,
            });
            ground.build(ctx, &self.world, uniforms, want, billboards);
            if measure_gpu {
                let _ = ctx.device.poll(wgpu::PollType::wait_indefinitely());
            }
            sun.moved = true;
            sun.ms += t0.elapsed().as_secs_f64() * 1e3;
        }
        ground.apply(uniforms, frame.shadows.enabled);
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
