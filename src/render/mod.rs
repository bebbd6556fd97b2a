//! The render core: draws a frame of the forest into any `TextureView`, from a plain
//! [`FrameDesc`]. It never sees a window, so the viewer, the `render` command and the tests
//! all drive the same code.
//!
//! Each method is one module of [`method`]: a CPU prepare step (culling, LOD, expansion,
//! sorting, shading factors) and the draws it encodes. This file keeps what every method
//! shares: the targets, the timestamps, the frame uniforms and bind group, the shadow
//! cascades' textures, the ground maps (allocated when a method first needs them), the sky
//! and the terrain. Per frame: cull trees against the view, let the method prepare, upload
//! the instance lists once, rebuild the sun-dependent state if the sun moved, draw the
//! cascades, then sky, terrain and the method's trees.

pub mod camera;
pub mod context;
pub mod frame;
mod frame_bindings;
pub mod ground;
pub mod measure;
pub mod method;
mod pipelines;
pub mod scale;
pub mod self_shadow;
pub mod shaders;
pub mod shadow;
pub mod sky_visibility;
pub mod target;
pub mod timing;
pub mod voxelize;
pub mod world_gpu;

use std::collections::HashMap;

use image::RgbaImage;

pub use camera::{Camera, Frustum, OrthoView};
pub use context::{AdapterPreference, GpuContext};
pub use frame::{FrameDesc, FrameStats, Method, Reference, ShadowSettings, Sky, Stage, Sun};
pub use ground::{GROUND_FORMAT, GROUND_MAP_SIZE, GROUND_PREVIEW_SIZE};
pub use method::btf;
pub use target::{OFFSCREEN_FORMAT, OffscreenTarget};

use frame::FrameUniforms;
use frame_bindings::{DepthTarget, FrameBindings};
use ground::{GroundBillboards, GroundMaps, GroundTextures};
use method::geometry::{GeometryFrame, GeometryMethod};
use pipelines::{ColorPipelines, Layouts};
use shadow::{CASCADES, CascadeMaps, Cascades};
use sky_visibility::{SkyVisibility, SkyVolume};
use timing::GpuTimer;
use world_gpu::WorldGpu;

use crate::model::World;
use crate::{Error, Result};

pub const DEPTH_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Depth32Float;
pub const SHADOW_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Depth32Float;

/// Largest shadow-map side accepted.
pub const MAX_SHADOW_MAP: u32 = 8192;

/// Where a frame goes: a view of a colour texture, its format and size.
#[derive(Clone, Copy, Debug)]
pub struct FrameTarget<'a> {
    pub view: &'a wgpu::TextureView,
    pub format: wgpu::TextureFormat,
    pub width: u32,
    pub height: u32,
}

/// One frame's CPU work, by method.
enum Prepared {
    Geometry(GeometryFrame),
    Btf(btf::BtfFrame),
    /// The `billboard` method's records (drawn like `btf`'s, with no parts as geometry).
    Billboard(btf::BtfFrame),
    Texel(method::texel::TexelFrame),
}

/// Owns the GPU side of a world and the pipelines; created once, then asked for frames.
pub struct Renderer {
    layouts: Layouts,
    world: WorldGpu,
    color_pipelines: HashMap<wgpu::TextureFormat, ColorPipelines>,
    frame_uniforms: wgpu::Buffer,
    shadow_sampler: wgpu::Sampler,
    ground_sampler: wgpu::Sampler,
    bindings: Option<FrameBindings>,
    depth: Option<DepthTarget>,
    timer: Option<GpuTimer>,
    geometry: GeometryMethod,
    btf: Option<btf::BtfAssets>,
    /// The bake's texel volumes, when it has them and they could be loaded.
    texel: Option<method::texel::TexelAssets>,
    /// Why the bake's texel volumes could not be loaded (the other methods still draw).
    texel_problem: Option<String>,
    /// The ground shadow maps, once a method has used them.
    ground: Option<GroundMaps>,
    /// What group 0 binds in their place until then.
    ground_placeholder: GroundTextures,
    /// The reference's sky visibility, once [`Self::prepare_reference`] computed it.
    sky_vis: Option<SkyVisibility>,
    sky_placeholder: SkyVisibility,
    /// The texel bake's voxelisation pipeline, once asked for.
    voxel_pipeline: Option<voxelize::VoxelPipeline>,
    /// The reference's per-tree sun maps, once a reference frame used them.
    self_shadow: Option<self_shadow::SelfShadow>,
    /// What the cascade maps hold when the last frame drew them in the studio (its
    /// matrices, map size and casters, as bytes): a studio frame with the same key keeps
    /// them (the bake takes every view under one light in a row). None after any other
    /// frame, which clears or redraws them.
    studio_cascades: Option<Vec<u8>>,
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
            geometry: GeometryMethod::new(ctx, &layouts)?,
            ground_placeholder: GroundTextures::placeholder(ctx)?,
            sky_vis: None,
            sky_placeholder: SkyVisibility::placeholder(ctx)?,
            ground_sampler: ground::ground_sampler(ctx),
            ground: None,
            layouts,
            world: world_gpu,
            color_pipelines: HashMap::new(),
            frame_uniforms,
            shadow_sampler,
            bindings: None,
            depth: None,
            timer: GpuTimer::new(ctx),
            btf: None,
            texel: None,
            texel_problem: None,
            voxel_pipeline: None,
            self_shadow: None,
            studio_cascades: None,
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
        self.btf = Some(btf::BtfAssets::new(ctx, baked, world)?);
        self.texel = None;
        self.texel_problem = None;
        if !baked.texels.is_empty() {
            // Volumes that cannot be loaded leave btf and billboard working.
            match method::texel::TexelAssets::new(ctx, baked, world) {
                Ok(t) => self.texel = Some(t),
                Err(e) => {
                    log::warn!("the texel method is unavailable: {e}");
                    self.texel_problem = Some(e.to_string());
                }
            }
        }
        if let Some(g) = &mut self.ground {
            g.invalidate();
        }
        Ok(())
    }

    pub fn has_btf(&self) -> bool {
        self.btf.is_some()
    }

    /// The attached bake has texel volumes (the `texel` method can draw).
    pub fn has_texels(&self) -> bool {
        self.texel.is_some()
    }

    /// The reference's sky visibility, once prepared: (directions, cell side in metres,
    /// bytes on the GPU).
    pub fn sky_visibility(&self) -> Option<(u32, f32, u64)> {
        self.sky_vis.as_ref().map(|s| (s.count, s.cell, s.bytes))
    }

    /// It has a sky visibility volume (the reference's, or the ground's).
    pub fn has_sky(&self) -> bool {
        self.sky_vis.is_some()
    }

    /// Names this renderer among the process's (work started for one renderer, such as a
    /// sky volume computed on another thread, is not handed to its successor).
    pub fn id(&self) -> u64 {
        self.id
    }

    /// Uploads a sky visibility `volume` of this renderer's world, computed from
    /// `directions` directions (e.g. on another thread, by [`SkyVolume::compute`]).
    pub fn attach_sky(
        &mut self,
        ctx: &GpuContext,
        volume: &SkyVolume,
        directions: u32,
    ) -> Result<()> {
        self.sky_vis = Some(SkyVisibility::upload(ctx, volume, directions.max(1))?);
        Ok(())
    }

    /// Bytes of texel volumes on the GPU (0 without them).
    pub fn texel_bytes(&self) -> u64 {
        self.texel.as_ref().map_or(0, |t| t.total_bytes())
    }

    /// Texel sizes of a species' three levels, from the attached bake.
    pub fn btf_texels(&self, species: usize) -> Option<crate::lod::LevelTexels> {
        self.btf.as_ref().and_then(|b| b.texel_sizes(species))
    }

    /// Bytes of BTF images on the GPU (0 without a bake).
    pub fn btf_bytes(&self) -> u64 {
        self.btf.as_ref().map_or(0, |b| b.bytes)
    }

    /// GPU bytes of the btf method's far-tree buffers (0 until the GPU builds far trees).
    pub fn far_bytes(&self) -> u64 {
        self.btf.as_ref().map_or(0, |b| b.far_bytes())
    }

    /// Bytes of visibility cube maps held in main memory (0 without them).
    pub fn vcm_bytes(&self) -> u64 {
        self.btf.as_ref().map_or(0, |b| b.vcm_bytes())
    }

    /// Face resolution of the visibility cube maps, when loaded.
    pub fn vcm_resolution(&self) -> Option<u32> {
        self.btf.as_ref().and_then(|b| b.vcm_resolution())
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
        ));
        Ok(())
    }

    /// Computes the reference's sky visibility of `world` (the world this renderer was made
    /// for) from `directions` directions: over the whole scene with its terrain, or over the
    /// trees alone in the studio (`terrain` false). Needed before reference frames; kept.
    pub fn prepare_reference(
        &mut self,
        ctx: &GpuContext,
        world: &World,
        directions: u32,
        terrain: bool,
    ) -> Result<()> {
        if world.forest.instances.len() != self.world.tree_bounds.len()
            || world.species.len() != self.world.species.len()
        {
            return Err(Error::BadInput(format!(
                "the reference's world ({} trees, {} species) is not this renderer's ({} trees, {} species)",
                world.forest.instances.len(),
                world.species.len(),
                self.world.tree_bounds.len(),
                self.world.species.len()
            )));
        }
        let bounds = sky_visibility::bounds_of(world, terrain);
        if bounds.is_empty() {
            return Err(Error::BadInput(
                "the reference needs something to draw: the world is empty".into(),
            ));
        }
        let volume = SkyVolume::compute(world, &bounds, terrain, directions.max(1));
        self.attach_sky(ctx, &volume, directions)
    }

    /// Computes the sky visibility of `world` (trees and terrain, the reference's 64
    /// directions) once, for the image-based methods' ground (`FrameDesc::ground_sky`); a
    /// no-op when the reference's is there already.
    pub fn prepare_sky(&mut self, ctx: &GpuContext, world: &World) -> Result<()> {
        if self.sky_vis.is_some() {
            return Ok(());
        }
        self.prepare_reference(ctx, world, sky_visibility::SKY_DIRECTIONS, true)
    }

    /// The image-based methods' ground sees the sky visibility in `frame`.
    pub fn ground_sky_applies(&self, frame: &FrameDesc) -> bool {
        frame.ground_sky
            && self.sky_vis.is_some()
            && frame.stage == Stage::World
            && (frame.method.is_btf() || frame.method == Method::Texel)
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

    /// Draws `frame` into `target` and submits the work. With `measure_gpu`, waits for the
    /// GPU and returns its frame time in the stats; otherwise the time arrives a few frames
    /// later in [`Self::last_gpu_ms`].
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
        let studio = frame.stage == Stage::Studio;
        let is_btf = frame.method.is_btf();
        let is_texel = frame.method == Method::Texel;
        // The reference: sky visibility, and sun cascades with larger maps reaching
        // every point of the scene.
        let reference = frame.reference.filter(|_| frame.method == Method::Geometry);
        let mut effective = *frame;
        if let Some(r) = reference {
            match &self.sky_vis {
                Some(s) if s.count == r.sky_directions.max(1) => {}
                Some(s) => {
                    return Err(Error::BadInput(format!(
                        "the reference frame asks for sky visibility from {} directions, the renderer has {}: call prepare_reference again",
                        r.sky_directions, s.count
                    )));
                }
                None => {
                    return Err(Error::BadInput(
                        "a reference frame needs the sky visibility: call Renderer::prepare_reference first".into(),
                    ));
                }
            }
            // (The studio's one shadow map is fitted to the object already.)
            if !studio {
                effective.shadows.map_size = frame.shadows.map_size.max(r.sun_map_size);
                let far = self
                    .world
                    .scene_bounds
                    .corners()
                    .iter()
                    .map(|c| c.distance(frame.camera.position))
                    .fold(0.0f32, f32::max);
                effective.shadows.distance = frame.shadows.distance.max(far);
            }
        }
        let frame = &effective;
        if frame.method.needs_bake() && self.btf.is_none() {
            return Err(Error::BadInput(format!(
                "the {} method needs baked BTF images: run `canopy bake` (the viewer bakes on first use)",
                frame.method.name()
            )));
        }
        if frame.method == Method::Texel && self.texel.is_none() {
            return Err(Error::BadInput(match &self.texel_problem {
                Some(p) => format!("the texel method cannot draw this bake's volumes: {p}"),
                None => "the texel method needs baked texel volumes, and this bake has none: set texel_resolution above 0 in the scene's [bake] table and bake again".into(),
            }));
        }
        // The btf method's trees are not geometry, so their shadows on the ground come from
        // the alpha shadow map, and the terrain's own shadows from the terrain depth drawn
        // with it, both rebuilt only when the sun moves.
        let ground_on = (is_btf || is_texel)
            && frame.ground_shadows
            && frame.sun.elevation_deg > 0.0
            && !studio;
        let terrain_depth_on = ground_on && frame.shadows.enabled;
        if ground_on && self.ground.is_none() {
            self.ground = Some(GroundMaps::new(ctx, &self.layouts)?);
        }
        self.ensure_depth(ctx, width, height)?;
        self.ensure_bindings(ctx, frame.shadows.map_size)?;
        if !self.color_pipelines.contains_key(&format) {
            let p = ctx.checked("building the render pipelines", || {
                ColorPipelines::new(&ctx.device, &self.layouts, format)
            })?;
            self.color_pipelines.insert(format, p);
        }

        // Cull, then the method's CPU work. Work that follows the sun, not the camera (the
        // VCM reads here, the ground maps below) is timed as the sun update.
        let prepare_start = std::time::Instant::now();
        let aspect = width as f32 / height as f32;
        let cam = &frame.camera;
        let frustum = cam.frustum(aspect);
        // btf and hybrid find their near trees themselves when the GPU takes the far ones.
        let btf_culls = matches!(frame.method, Method::Btf | Method::Hybrid)
            && self.btf.as_ref().is_some_and(|b| b.takes_far(&frame.btf));
        let visible = if frame.trees && !btf_culls {
            self.world.cull(&frustum)
        } else {
            vec![Vec::new(); self.world.species.len()]
        };
        let to_sun = frame.sun.direction();
        let mut sun_update_ms = 0.0;
        let mut sun_moved = false;
        let prepared = match (frame.method, self.btf.as_mut()) {
            (Method::Btf | Method::Hybrid, Some(b)) => {
                if frame.btf.vcm && frame.trees {
                    let t0 = std::time::Instant::now();
                    if b.update_sun(to_sun) {
                        sun_moved = true;
                        sun_update_ms += t0.elapsed().as_secs_f64() * 1e3;
                    }
                }
                let (bf, shade_ms) = b.prepare(
                    ctx,
                    &self.world,
                    (!btf_culls).then_some(&visible[..]),
                    frame.trees,
                    cam,
                    cam.focal_px(height),
                    to_sun,
                    &frustum,
                    &frame.btf,
                    frame.method == Method::Hybrid,
                );
                // The far trees' VCM factors, uploaded after the sun moved.
                sun_update_ms += shade_ms;
                Prepared::Btf(bf)
            }
            (Method::Billboard, Some(b)) => Prepared::Billboard(method::billboard::prepare_frame(
                b,
                ctx,
                &self.world,
                &visible,
                &btf::PrepareView {
                    camera: cam,
                    focal_px: cam.focal_px(height),
                    to_sun,
                    frustum: &frustum,
                },
            )),
            (Method::Texel, b) => {
                let vcm = match b {
                    Some(b) if frame.texel.vcm && frame.trees => {
                        let t0 = std::time::Instant::now();
                        if b.update_sun(to_sun) {
                            sun_moved = true;
                            sun_update_ms += t0.elapsed().as_secs_f64() * 1e3;
                        }
                        Some(b.scene())
                    }
                    _ => None,
                };
                match self.texel.as_mut() {
                    Some(t) => Prepared::Texel(t.prepare_frame(
                        ctx,
                        &self.world,
                        &visible,
                        &btf::PrepareView {
                            camera: cam,
                            focal_px: cam.focal_px(height),
                            to_sun,
                            frustum: &frustum,
                        },
                        &frame.texel,
                        vcm,
                    )?),
                    None => return Err(Error::Gpu("the texel volumes are not loaded".into())),
                }
            }
            _ => Prepared::Geometry(GeometryFrame::prepare(&self.world, frame, aspect, visible)),
        };
        let (runs, cascades, shadows_on) = match &prepared {
            Prepared::Geometry(g) => (
                self.world.upload_lists(ctx, &g.lists),
                g.cascades,
                g.shadows_on,
            ),
            Prepared::Btf(b) | Prepared::Billboard(b) => {
                let t0 = std::time::Instant::now();
                // `hybrid`'s geometry trees: whole trunks and limbs, fading twigs; they cast
                // and receive cascaded sun shadows fitted to them alone.
                let whole: Vec<Vec<(u32, f32)>> = b
                    .twigs
                    .iter()
                    .map(|l| l.iter().map(|&(t, _)| (t, 1.0)).collect())
                    .collect();
                let runs = self.world.upload_lists_faded(
                    ctx,
                    &[b.trunk_only.clone(), b.trunk_and_limbs.clone()],
                    &[&whole, &b.twigs],
                    frame.btf.show_lod.then_some(btf::GEOMETRY_COLOUR),
                );
                let cascades = self.geometry_tree_cascades(frame, &b.twigs);
                log::debug!(
                    "btf prepare: the trunks' and limbs' lists ({} and {} trees) in {:.2} ms",
                    b.trunk_only.iter().map(Vec::len).sum::<usize>(),
                    b.trunk_and_limbs.iter().map(Vec::len).sum::<usize>(),
                    t0.elapsed().as_secs_f64() * 1e3
                );
                let on = cascades.is_some();
                (runs, cascades.unwrap_or_else(Cascades::none), on)
            }
            // No tree parts as geometry; the list still holds the terrain's instance.
            Prepared::Texel(_) => (
                self.world
                    .upload_lists(ctx, &[vec![Vec::new(); self.world.species.len()]]),
                Cascades::none(),
                false,
            ),
        };
        // The reference's trees shade themselves through maps of their own, drawn in batches.
        let self_map_size = reference.map_or(0, |r| r.self_map_size);
        let self_batches = match &prepared {
            Prepared::Geometry(g) if g.shadows_on && self_map_size > 0 && !studio => {
                let ss = match self.self_shadow.take() {
                    Some(ss) if ss.size == self_map_size => ss,
                    _ => self_shadow::SelfShadow::new(
                        ctx,
                        &self.layouts,
                        self_map_size,
                        self_shadow::layers_for(self_map_size)
                            .min(self.world.tree_data.len().max(1) as u32),
                        self.world.tree_data.len() + 1,
                    )?,
                };
                let ss = self.self_shadow.insert(ss);
                ss.ensure_keys(ctx, frame.shadows.map_size)?;
                ss.ensure_pipelines(ctx, &self.layouts, format)?;
                let trees = g.lists.first().map_or(&[][..], |l| &l[..]);
                Some(ss.write_lights(ctx, &self.world, &runs[0], trees, to_sun))
            }
            _ => None,
        };
        // The sun-dependent VCM reads inside the prepare step are the sun update's.
        let prepare_ms = prepare_start.elapsed().as_secs_f64() * 1e3 - sun_update_ms;
        let sky_hidden = reference.is_some() || self.ground_sky_applies(frame);
        let mut uniforms =
            self.frame_uniforms_for(frame, aspect, &cascades, shadows_on, sky_hidden);
        if matches!(prepared, Prepared::Btf(_)) && shadows_on {
            uniforms.hybrid_cascades = 1;
        }

        // The ground shadow maps follow the sun, not the camera. They are submitted on their
        // own so that their cost can be timed (blocking, when measuring).
        if let Some(ground) = self.ground.as_mut().filter(|_| ground_on) {
            // `hybrid`'s geometry trees cast through their cascades, not the alpha map.
            let mut excluded: Vec<u32> = match &prepared {
                Prepared::Btf(b) if shadows_on => {
                    b.twigs.iter().flatten().map(|&(t, _)| t).collect()
                }
                _ => Vec::new(),
            };
            excluded.sort_unstable();
            let excluded_key = excluded.iter().fold(0u64, |h, &t| {
                (h ^ u64::from(t) ^ 0x9e37_79b9_7f4a_7c15).wrapping_mul(0x0100_0000_01b3)
            });
            let (want, rebuild) =
                ground.wanted(to_sun, frame.trees, is_texel, frame.sun_held, excluded_key);
            if rebuild {
                let t0 = std::time::Instant::now();
                // The trees' opacity from the sun: the texels' boxes, or the BTF billboards.
                let sun_casters = match (is_texel, self.texel.as_mut(), self.btf.as_mut()) {
                    _ if !want.trees => None,
                    (true, Some(t), _) => {
                        let count = t.prepare_sun(ctx, &self.world);
                        let pipeline = t
                            .opacity_pipeline(&ctx.device, &self.layouts.shadow_frame)
                            .clone();
                        Some((pipeline, count, t.sun_bind_group().clone(), 36))
                    }
                    (false, _, Some(b)) => {
                        let count = b.prepare_sun(ctx, &self.world, want.to_sun, &excluded);
                        let pipeline = b
                            .opacity_pipeline(&ctx.device, &self.layouts.shadow_frame)
                            .clone();
                        Some((pipeline, count, b.sun_bind_group().clone(), 6))
                    }
                    _ => None,
                };
                let billboards = sun_casters
                    .as_ref()
                    .map(|(pipeline, count, bind_group, v)| GroundBillboards {
                        pipeline,
                        bind_group,
                        count: *count,
                        vertices: *v,
                    });
                ground.build(ctx, &self.world, &uniforms, want, billboards);
                if measure_gpu {
                    let _ = ctx.device.poll(wgpu::PollType::wait_indefinitely());
                }
                sun_moved = true;
                sun_update_ms += t0.elapsed().as_secs_f64() * 1e3;
            }
            ground.apply(&mut uniforms, terrain_depth_on);
        }
        ctx.queue
            .write_buffer(&self.frame_uniforms, 0, bytemuck::bytes_of(&uniforms));
        self.geometry
            .write_uniforms(ctx, &uniforms, &cascades, shadows_on);

        let mut stats = FrameStats {
            width,
            height,
            prepare_ms: prepare_ms.max(0.0),
            sun_update: sun_moved,
            sun_update_ms: sun_moved.then_some(sun_update_ms),
            ground_map_size: self
                .ground
                .as_ref()
                .filter(|_| ground_on)
                .and_then(|g| g.built_size()),
            ..Default::default()
        };
        let btf_pipeline = match (&prepared, self.btf.as_mut()) {
            (Prepared::Btf(_) | Prepared::Billboard(_), Some(b)) => {
                Some(b.pipeline(&ctx.device, &self.layouts.frame, format).clone())
            }
            _ => None,
        };
        let texel_pipelines = match (&prepared, self.texel.as_mut()) {
            (Prepared::Texel(_), Some(t)) => Some(
                t.pipelines(&ctx.device, &self.layouts.frame, format)
                    .clone(),
            ),
            _ => None,
        };
        let queries = self.timer.as_mut().and_then(|t| t.begin()).cloned();
        let (Some(bindings), Some(depth), Some(pipes)) = (
            &self.bindings,
            &self.depth,
            self.color_pipelines.get(&format),
        ) else {
            return Err(Error::Gpu("render targets were not created".into()));
        };
        let mut encoder = ctx
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                label: Some("frame"),
            });
        let hybrid_casters;
        let casters = match &prepared {
            Prepared::Geometry(g) if g.shadows_on => Some(&runs[1..]),
            Prepared::Btf(_) if shadows_on => {
                // One map: the geometry trees, whole (the terrain has its own map).
                hybrid_casters = vec![runs[2].clone()];
                Some(&hybrid_casters[..])
            }
            _ => None,
        };
        let geometry_casts_terrain = matches!(prepared, Prepared::Geometry(_)) && !studio;
        let self_shadow = self.self_shadow.as_ref().filter(|_| self_batches.is_some());
        let studio_key = match &prepared {
            Prepared::Geometry(g) if studio && g.shadows_on && self_shadow.is_none() => Some(
                studio_cascades_key(&cascades, frame.shadows.map_size, &g.lists[1..]),
            ),
            _ => None,
        };
        let keep = studio_key.is_some() && self.studio_cascades == studio_key;
        // The far trees' compute passes open the frame (and its timing) when there are any.
        let far_first = match (&prepared, &self.btf) {
            (Prepared::Btf(bf), Some(b)) if bf.far => b.encode_far(&mut encoder, queries.as_ref()),
            _ => false,
        };
        encode_cascades(
            &mut encoder,
            bindings,
            &self.geometry,
            &self.world,
            casters.filter(|_| !keep),
            geometry_casts_terrain,
            self_shadow,
            keep,
            queries.as_ref().filter(|_| !far_first),
            &mut stats,
        );
        self.studio_cascades = studio_key;
        // The reference's trees are drawn after the main pass, batch by batch, which then
        // ends the frame's timing.
        let batches = self_batches.as_deref().unwrap_or(&[]);

        {
            let mut pass = depth.colour_pass(
                &mut encoder,
                "main",
                target,
                Some(if studio {
                    wgpu::Color::TRANSPARENT
                } else {
                    wgpu::Color::BLACK
                }),
                !batches.is_empty(),
                queries.as_ref().filter(|_| batches.is_empty()),
            );
            pass.set_bind_group(0, &bindings.bind_group, &[]);
            if !studio {
                pass.set_pipeline(&pipes.sky);
                pass.draw(0..3, 0..1);
                stats.draw_calls += 1;
            }
            pass.set_bind_group(1, &self.world.trees_bind_group, &[]);
            match (&prepared, &self.btf) {
                (Prepared::Btf(bf), Some(b)) => b.draw_main(
                    &mut pass,
                    &self.world,
                    &runs,
                    pipes,
                    btf_pipeline.as_ref(),
                    bf,
                    !studio,
                    &mut stats,
                ),
                (Prepared::Billboard(bf), Some(b)) => {
                    b.draw_main(
                        &mut pass,
                        &self.world,
                        &runs,
                        pipes,
                        btf_pipeline.as_ref(),
                        bf,
                        !studio,
                        &mut stats,
                    );
                    // The btf knobs do not apply.
                    stats.btf = None;
                }
                (Prepared::Texel(tf), _) => {
                    // The terrain, then the texels over it.
                    GeometryMethod::draw_main(
                        &mut pass,
                        &self.world,
                        &runs[0],
                        pipes,
                        !studio,
                        &mut stats,
                    );
                    if let (Some(t), Some(p)) = (&self.texel, &texel_pipelines) {
                        pass.set_bind_group(0, &bindings.bind_group, &[]);
                        t.draw(&mut pass, p, tf, &mut stats);
                    }
                    stats.texel = Some(tf.stats);
                }
                _ => GeometryMethod::draw_main(
                    &mut pass,
                    &self.world,
                    if batches.is_empty() { &runs[0] } else { &[] },
                    pipes,
                    !studio,
                    &mut stats,
                ),
            }
        }
        if let Some(ss) = self_shadow.filter(|_| !batches.is_empty()) {
            ss.draw_trees(
                &mut encoder,
                &self.world,
                &bindings.bind_group,
                (target, format, depth),
                batches,
                queries.as_ref(),
                &mut stats,
            )?;
        }
        if let Some(t) = &self.timer {
            t.resolve(&mut encoder);
        }
        ctx.queue.submit([encoder.finish()]);
        if let Some(t) = &mut self.timer {
            t.after_submit();
            stats.gpu_ms = t.collect(ctx, measure_gpu).filter(|_| measure_gpu);
        }
        if let (Prepared::Btf(bf), Some(b)) = (&prepared, &self.btf)
            && bf.far
        {
            b.add_far_stats(ctx, measure_gpu, &mut stats);
        }
        if let Some(t) = self.ground.as_mut().and_then(|g| g.timer.as_mut()) {
            t.collect(ctx, measure_gpu);
        }
        if let Some(e) = ctx.take_error() {
            return Err(Error::Gpu(e));
        }
        Ok(stats)
    }

    /// `hybrid`: one sun shadow map around the trees it draws as geometry (`trees`, per
    /// species; every cascade the same, the first one used), so that its texels stay
    /// small, reaching down past them to the lowest ground their shadows can fall on; None
    /// when there are none, shadows are off or the sun is down.
    fn geometry_tree_cascades(
        &self,
        frame: &FrameDesc,
        trees: &[Vec<(u32, f32)>],
    ) -> Option<Cascades> {
        if !frame.shadows.enabled || frame.sun.elevation_deg <= 0.0 {
            return None;
        }
        let bounds = trees
            .iter()
            .flatten()
            .filter_map(|&(t, _)| self.world.tree_bounds.get(t as usize))
            .fold(None, |u: Option<crate::model::mesh::Aabb>, b| {
                Some(u.map_or(*b, |u| u.union(*b)))
            })?;
        let to_sun = frame.sun.direction();
        let radius = 0.5 * bounds.extent().length();
        // The shadow of the top reaches the ground at most this far along the sun's ray.
        let scene = &self.world.scene_bounds;
        let drop = (bounds.max.y - scene.min.y).max(0.0);
        let below = (drop / to_sun.y.max(0.05)).min(2000.0);
        Some(Cascades::fit_sphere_reaching(
            to_sun,
            bounds.center(),
            radius,
            below,
            frame.shadows.map_size,
        ))
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

    /// A voxel grid for [`Self::voxelize`] (building the voxel pipeline on first use).
    pub fn voxel_target(
        &mut self,
        ctx: &GpuContext,
        box_min: glam::Vec3,
        dims: glam::UVec3,
        voxel: f32,
        ss: u32,
    ) -> Result<voxelize::VoxelTarget> {
        if self.voxel_pipeline.is_none() {
            let p = ctx.checked("building the voxel pipeline", || {
                voxelize::VoxelPipeline::new(&ctx.device, &self.layouts)
            })?;
            self.voxel_pipeline = Some(p);
        }
        let Some(p) = &self.voxel_pipeline else {
            return Err(Error::Gpu("the voxel pipeline was not built".into()));
        };
        voxelize::VoxelTarget::new(ctx, p, box_min, dims, voxel, ss)
    }

    /// The texel bake's voxelisation: the trees of `frame` (a `geometry` frame in the
    /// studio, orthographic) drawn at `width` x `height` pixels, every fragment added to the
    /// voxel of `target` it lies in (see [`voxelize`]). Sun shadows and the reference's
    /// sky visibility shade the fragments as in a frame.
    pub fn voxelize(
        &mut self,
        ctx: &GpuContext,
        frame: &FrameDesc,
        width: u32,
        height: u32,
        target: &voxelize::VoxelTarget,
    ) -> Result<()> {
        target::check_size(width, height, Some(ctx))?;
        if ctx.is_lost() {
            return Err(Error::Gpu("the GPU device was lost; restart canopy".into()));
        }
        self.ensure_depth(ctx, width, height)?;
        self.ensure_bindings(ctx, frame.shadows.map_size)?;
        let aspect = width as f32 / height as f32;
        let visible = self.world.cull(&frame.camera.frustum(aspect));
        let g = GeometryFrame::prepare(&self.world, frame, aspect, visible);
        let runs = self.world.upload_lists(ctx, &g.lists);
        let uniforms = self.frame_uniforms_for(
            frame,
            aspect,
            &g.cascades,
            g.shadows_on,
            frame.reference.is_some(),
        );
        ctx.queue
            .write_buffer(&self.frame_uniforms, 0, bytemuck::bytes_of(&uniforms));
        self.geometry
            .write_uniforms(ctx, &uniforms, &g.cascades, g.shadows_on);
        let (Some(bindings), Some(depth), Some(voxel)) =
            (&self.bindings, &self.depth, &self.voxel_pipeline)
        else {
            return Err(Error::Gpu("render targets were not created".into()));
        };
        let mut encoder = ctx
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                label: Some("voxelise"),
            });
        let mut stats = FrameStats::default();
        let casters = g.shadows_on.then_some(&runs[1..]);
        let studio = frame.stage == Stage::Studio;
        encode_cascades(
            &mut encoder,
            bindings,
            &self.geometry,
            &self.world,
            casters,
            !studio,
            None,
            false,
            None,
            &mut stats,
        );
        self.studio_cascades = None;
        target.clear(&mut encoder);
        {
            let mut pass = encoder.begin_render_pass(&wgpu::RenderPassDescriptor {
                label: Some("voxelise"),
                color_attachments: &[],
                depth_stencil_attachment: Some(wgpu::RenderPassDepthStencilAttachment {
                    view: &depth.view,
                    depth_ops: Some(wgpu::Operations {
                        load: wgpu::LoadOp::Clear(0.0),
                        store: wgpu::StoreOp::Discard,
                    }),
                    stencil_ops: None,
                }),
                timestamp_writes: None,
                occlusion_query_set: None,
                multiview_mask: None,
            });
            pass.set_bind_group(0, &bindings.bind_group, &[]);
            pass.set_bind_group(1, &self.world.trees_bind_group, &[]);
            pass.set_bind_group(3, &target.bind_group, &[]);
            GeometryMethod::draw_with(&mut pass, &self.world, &runs[0], voxel.meshes(), !studio);
        }
        target.copy_out(&mut encoder);
        ctx.queue.submit([encoder.finish()]);
        if let Some(e) = ctx.take_error() {
            return Err(Error::Gpu(e));
        }
        Ok(())
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

/// The key of a studio frame's cascade maps: its matrices, their size and the trees drawn
/// into them (each cascade's tree lists, per species; the runs are uploaded from them).
fn studio_cascades_key(cascades: &Cascades, map_size: u32, casters: &[Vec<Vec<u32>>]) -> Vec<u8> {
    let mut key: Vec<u8> =
        bytemuck::cast_slice(&cascades.matrices.map(|m| m.to_cols_array())).to_vec();
    key.extend_from_slice(&map_size.to_le_bytes());
    for list in casters.iter().flatten() {
        key.extend_from_slice(&(list.len() as u64).to_le_bytes());
        key.extend_from_slice(bytemuck::cast_slice(list));
    }
    key
}

/// The sun cascades' passes: each map cleared (even when off, so a stale map never shades a
/// frame) and, when `casters` holds each cascade's tree runs, drawn; with `keep`, loaded
/// as the last frame left them instead (nothing drawn). The first pass opens the frame's
/// GPU timer when there is one.
#[allow(clippy::too_many_arguments)]
fn encode_cascades(
    encoder: &mut wgpu::CommandEncoder,
    bindings: &FrameBindings,
    geometry: &GeometryMethod,
    world: &WorldGpu,
    casters: Option<&[Vec<world_gpu::TreeRun>]>,
    terrain: bool,
    keys: Option<&self_shadow::SelfShadow>,
    keep: bool,
    queries: Option<&wgpu::QuerySet>,
    stats: &mut FrameStats,
) {
    for c in 0..CASCADES {
        let ts = queries
            .filter(|_| c == 0)
            .map(|q| wgpu::RenderPassTimestampWrites {
                query_set: q,
                beginning_of_pass_write_index: Some(0),
                end_of_pass_write_index: None,
            });
        // The reference's cascades keep which tree is nearest the sun in each texel.
        let keyed = keys.and_then(|k| k.cascade_keys(c));
        let key_target = keyed.map(|(_, view)| wgpu::RenderPassColorAttachment {
            view,
            depth_slice: None,
            resolve_target: None,
            ops: wgpu::Operations {
                load: wgpu::LoadOp::Clear(wgpu::Color::TRANSPARENT),
                store: wgpu::StoreOp::Store,
            },
        });
        let color_attachments = if key_target.is_some() {
            std::slice::from_ref(&key_target)
        } else {
            &[]
        };
        let mut pass = encoder.begin_render_pass(&wgpu::RenderPassDescriptor {
            label: Some("shadow cascade"),
            color_attachments,
            depth_stencil_attachment: Some(wgpu::RenderPassDepthStencilAttachment {
                view: &bindings.cascades.layer_views[c],
                depth_ops: Some(wgpu::Operations {
                    load: if keep {
                        wgpu::LoadOp::Load
                    } else {
                        wgpu::LoadOp::Clear(1.0)
                    },
                    store: wgpu::StoreOp::Store,
                }),
                stencil_ops: None,
            }),
            timestamp_writes: ts,
            occlusion_query_set: None,
            multiview_mask: None,
        });
        if let Some(runs) = casters.and_then(|r| r.get(c)) {
            geometry.draw_cascade(
                &mut pass,
                c,
                world,
                runs,
                terrain,
                keyed.map(|k| k.0),
                stats,
            );
        }
    }
}
