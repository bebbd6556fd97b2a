//! The render core: draws a frame of the forest into any `TextureView`, from a plain
//! [`FrameDesc`]. It never sees a window, so the viewer, the `render` command and the tests
//! all drive the same code. Per frame: cull trees against the view and each shadow cascade,
//! upload the instance lists once, draw the shadow cascades, then sky, terrain and trees.

pub mod btf;
pub mod camera;
pub mod context;
pub mod frame;
pub mod measure;
mod pipelines;
pub mod shaders;
pub mod shading;
pub mod shadow;
pub mod target;
pub mod timing;
pub mod world_gpu;

use std::collections::HashMap;

use image::RgbaImage;

pub use camera::{Camera, Frustum, OrthoView};
pub use context::{AdapterPreference, GpuContext};
pub use frame::{FrameDesc, FrameStats, Method, ShadowSettings, Sky, Stage, Sun};
pub use target::{OFFSCREEN_FORMAT, OffscreenTarget};

use frame::FrameUniforms;
use pipelines::{ColorPipelines, Layouts};
use shadow::{CASCADES, Cascades};
use timing::GpuTimer;
use world_gpu::{PartKind, TreeRun, WorldGpu};

use crate::model::World;
use crate::{Error, Result};

pub const DEPTH_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Depth32Float;
pub const SHADOW_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Depth32Float;

/// Format of the ground alpha shadow map (transmittance).
pub const GROUND_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::R8Unorm;
/// Side of the ground shadow maps (alpha and terrain depth), covering the whole scene
/// (about 0.35 m per texel on the default square kilometre).
pub const GROUND_MAP_SIZE: u32 = 4096;
/// Side of the ground shadow maps while the user holds the sun (`FrameDesc::sun_held`):
/// a sixteenth of the texels, so that dragging the sun does not stall a software
/// renderer; the full map follows on the first frame after the sun is let go.
pub const GROUND_PREVIEW_SIZE: u32 = 1024;

/// Largest shadow-map side accepted.
pub const MAX_SHADOW_MAP: u32 = 8192;

struct ShadowMaps {
    size: u32,
    /// One view per cascade, to render into.
    layer_views: Vec<wgpu::TextureView>,
    frame_bind_group: wgpu::BindGroup,
}

/// The ground shadow maps of the image-based methods, both seen from the sun over the whole
/// scene and rebuilt only when the sun moves: the trees' transmittance (the alpha shadow
/// map; the terrain is drawn white into it, so it hides the trees behind it but casts
/// nothing) and the terrain's depth (its own shadows: a hill shading a valley). They are
/// drawn in one pass, into the top-left `size` x `size` texels of the textures.
struct GroundShadow {
    view: wgpu::TextureView,
    depth_view: wgpu::TextureView,
    sampler: wgpu::Sampler,
    uniforms: wgpu::Buffer,
    bind_group: wgpu::BindGroup,
    terrain_pipeline: wgpu::RenderPipeline,
    light_view_proj: glam::Mat4,
    /// World size (m) of one texel of the maps as last built.
    texel_world: f32,
    /// Side of the textures.
    capacity: u32,
    /// What the maps hold now (None: nothing yet).
    built: Option<GroundKey>,
}

/// What a ground map was built for.
#[derive(Clone, Copy, Debug, PartialEq)]
struct GroundKey {
    to_sun: glam::Vec3,
    /// The trees are in it (not while only terrain and sky are shown).
    trees: bool,
    /// Side of the part of the textures in use.
    size: u32,
}

impl GroundShadow {
    fn new(ctx: &GpuContext, layouts: &Layouts, uniform_size: u64) -> Result<Self> {
        let size = GROUND_MAP_SIZE.min(ctx.device.limits().max_texture_dimension_2d);
        let extent = wgpu::Extent3d {
            width: size,
            height: size,
            depth_or_array_layers: 1,
        };
        let (color, depth) = ctx.checked("allocating the ground shadow maps", || {
            let color = ctx.device.create_texture(&wgpu::TextureDescriptor {
                label: Some("ground alpha shadow map"),
                size: extent,
                mip_level_count: 1,
                sample_count: 1,
                dimension: wgpu::TextureDimension::D2,
                format: GROUND_FORMAT,
                usage: wgpu::TextureUsages::RENDER_ATTACHMENT
                    | wgpu::TextureUsages::TEXTURE_BINDING,
                view_formats: &[],
            });
            let depth = ctx.device.create_texture(&wgpu::TextureDescriptor {
                label: Some("ground terrain depth map"),
                size: extent,
                mip_level_count: 1,
                sample_count: 1,
                dimension: wgpu::TextureDimension::D2,
                format: SHADOW_FORMAT,
                usage: wgpu::TextureUsages::RENDER_ATTACHMENT
                    | wgpu::TextureUsages::TEXTURE_BINDING,
                view_formats: &[],
            });
            (color, depth)
        })?;
        let uniforms = ctx.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("ground shadow uniforms"),
            size: uniform_size,
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let bind_group = ctx.device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("ground shadow"),
            layout: &layouts.shadow_frame,
            entries: &[wgpu::BindGroupEntry {
                binding: 0,
                resource: uniforms.as_entire_binding(),
            }],
        });
        let terrain_pipeline = ctx.checked("building the ground shadow pipeline", || {
            pipelines::ground_terrain_pipeline(&ctx.device, layouts)
        })?;
        Ok(Self {
            view: color.create_view(&Default::default()),
            depth_view: depth.create_view(&Default::default()),
            sampler: ctx.device.create_sampler(&wgpu::SamplerDescriptor {
                label: Some("ground shadow"),
                mag_filter: wgpu::FilterMode::Linear,
                min_filter: wgpu::FilterMode::Linear,
                ..Default::default()
            }),
            uniforms,
            bind_group,
            terrain_pipeline,
            light_view_proj: glam::Mat4::IDENTITY,
            texel_world: 0.0,
            capacity: size,
            built: None,
        })
    }

    /// The key of the maps `frame` needs, and whether the ones held must be rebuilt for
    /// it: the sun moved, the trees came or went, or the sun was let go after a preview.
    fn wanted(&self, to_sun: glam::Vec3, trees: bool, held: bool) -> (GroundKey, bool) {
        let size = if held {
            GROUND_PREVIEW_SIZE.min(self.capacity)
        } else {
            self.capacity
        };
        let want = GroundKey {
            to_sun,
            trees,
            size,
        };
        let rebuild = match self.built {
            None => true,
            Some(k) => k.to_sun != to_sun || k.trees != trees || (!held && k.size != size),
        };
        (want, rebuild)
    }

    /// The `ground_params` uniform: alpha map on, terrain depth on, world size of one
    /// texel, and the fraction of the textures in use.
    fn params(&self, terrain_depth: bool) -> [f32; 4] {
        let size = self.built.map_or(self.capacity, |k| k.size);
        [
            1.0,
            if terrain_depth { 1.0 } else { 0.0 },
            self.texel_world,
            size as f32 / self.capacity.max(1) as f32,
        ]
    }
}

struct DepthTarget {
    size: (u32, u32),
    view: wgpu::TextureView,
}

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
    shadow_pipeline: wgpu::RenderPipeline,
    color_pipelines: HashMap<wgpu::TextureFormat, ColorPipelines>,
    frame_uniforms: wgpu::Buffer,
    shadow_uniforms: Vec<(wgpu::Buffer, wgpu::BindGroup)>,
    shadow_sampler: wgpu::Sampler,
    shadows: Option<ShadowMaps>,
    depth: Option<DepthTarget>,
    timer: Option<GpuTimer>,
    /// Timestamps around the ground shadow maps' pass, the GPU side of a sun move.
    ground_timer: Option<GpuTimer>,
    btf: Option<btf::BtfAssets>,
    ground: GroundShadow,
}

impl Renderer {
    pub fn new(ctx: &GpuContext, world: &World) -> Result<Self> {
        let device = &ctx.device;
        let layouts = Layouts::new(device);
        let world_gpu = WorldGpu::new(ctx, world, &layouts.trees, &layouts.parts)?;
        let shadow_pipeline = ctx.checked("building the shadow pipeline", || {
            pipelines::shadow_pipeline(device, &layouts)
        })?;
        let uniform_size = std::mem::size_of::<FrameUniforms>() as u64;
        let frame_uniforms = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("frame uniforms"),
            size: uniform_size,
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let shadow_uniforms = (0..CASCADES)
            .map(|i| {
                let buf = device.create_buffer(&wgpu::BufferDescriptor {
                    label: Some(&format!("shadow cascade {i} uniforms")),
                    size: uniform_size,
                    usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
                    mapped_at_creation: false,
                });
                let bg = device.create_bind_group(&wgpu::BindGroupDescriptor {
                    label: Some("shadow cascade"),
                    layout: &layouts.shadow_frame,
                    entries: &[wgpu::BindGroupEntry {
                        binding: 0,
                        resource: buf.as_entire_binding(),
                    }],
                });
                (buf, bg)
            })
            .collect();
        let shadow_sampler = device.create_sampler(&wgpu::SamplerDescriptor {
            label: Some("shadow comparison"),
            mag_filter: wgpu::FilterMode::Linear,
            min_filter: wgpu::FilterMode::Linear,
            compare: Some(wgpu::CompareFunction::LessEqual),
            ..Default::default()
        });
        let ground = GroundShadow::new(ctx, &layouts, uniform_size)?;
        Ok(Self {
            ground,
            layouts,
            world: world_gpu,
            shadow_pipeline,
            color_pipelines: HashMap::new(),
            frame_uniforms,
            shadow_uniforms,
            shadow_sampler,
            shadows: None,
            depth: None,
            timer: GpuTimer::new(ctx),
            ground_timer: GpuTimer::new(ctx),
            btf: None,
        })
    }

    /// Loads baked BTF image sets for the `btf` method (replacing any loaded before).
    pub fn attach_btf(
        &mut self,
        ctx: &GpuContext,
        baked: &crate::format::Baked,
        world: &World,
    ) -> Result<()> {
        self.btf = Some(btf::BtfAssets::new(ctx, baked, world)?);
        self.ground.built = None;
        Ok(())
    }

    pub fn has_btf(&self) -> bool {
        self.btf.is_some()
    }

    /// Texel sizes of a species' three levels, from the attached bake.
    pub fn btf_texels(&self, species: usize) -> Option<crate::lod::LevelTexels> {
        self.btf.as_ref().and_then(|b| b.texel_sizes(species))
    }

    /// Bytes of BTF images on the GPU (0 without a bake).
    pub fn btf_bytes(&self) -> u64 {
        self.btf.as_ref().map_or(0, |b| b.bytes)
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
        self.ground_timer.as_ref().and_then(|t| t.last_ms)
    }

    fn ensure_shadow_maps(&mut self, ctx: &GpuContext, size: u32) -> Result<()> {
        let size = size.clamp(
            16,
            MAX_SHADOW_MAP.min(ctx.device.limits().max_texture_dimension_2d),
        );
        if self.shadows.as_ref().is_some_and(|s| s.size == size) {
            return Ok(());
        }
        let texture = ctx.checked("allocating the shadow maps", || {
            ctx.device.create_texture(&wgpu::TextureDescriptor {
                label: Some("shadow cascades"),
                size: wgpu::Extent3d {
                    width: size,
                    height: size,
                    depth_or_array_layers: CASCADES as u32,
                },
                mip_level_count: 1,
                sample_count: 1,
                dimension: wgpu::TextureDimension::D2,
                format: SHADOW_FORMAT,
                usage: wgpu::TextureUsages::RENDER_ATTACHMENT
                    | wgpu::TextureUsages::TEXTURE_BINDING,
                view_formats: &[],
            })
        })?;
        let array_view = texture.create_view(&wgpu::TextureViewDescriptor {
            dimension: Some(wgpu::TextureViewDimension::D2Array),
            ..Default::default()
        });
        let layer_views = (0..CASCADES as u32)
            .map(|i| {
                texture.create_view(&wgpu::TextureViewDescriptor {
                    dimension: Some(wgpu::TextureViewDimension::D2),
                    base_array_layer: i,
                    array_layer_count: Some(1),
                    ..Default::default()
                })
            })
            .collect();
        let frame_bind_group = ctx.device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("frame"),
            layout: &self.layouts.frame,
            entries: &[
                wgpu::BindGroupEntry {
                    binding: 0,
                    resource: self.frame_uniforms.as_entire_binding(),
                },
                wgpu::BindGroupEntry {
                    binding: 1,
                    resource: wgpu::BindingResource::TextureView(&array_view),
                },
                wgpu::BindGroupEntry {
                    binding: 2,
                    resource: wgpu::BindingResource::Sampler(&self.shadow_sampler),
                },
                wgpu::BindGroupEntry {
                    binding: 3,
                    resource: wgpu::BindingResource::TextureView(&self.ground.view),
                },
                wgpu::BindGroupEntry {
                    binding: 4,
                    resource: wgpu::BindingResource::Sampler(&self.ground.sampler),
                },
                wgpu::BindGroupEntry {
                    binding: 5,
                    resource: wgpu::BindingResource::TextureView(&self.ground.depth_view),
                },
            ],
        });
        self.shadows = Some(ShadowMaps {
            size,
            layer_views,
            frame_bind_group,
        });
        Ok(())
    }

    fn ensure_depth(&mut self, ctx: &GpuContext, width: u32, height: u32) -> Result<()> {
        if self
            .depth
            .as_ref()
            .is_some_and(|d| d.size == (width, height))
        {
            return Ok(());
        }
        let texture = ctx.checked("allocating the depth buffer", || {
            ctx.device.create_texture(&wgpu::TextureDescriptor {
                label: Some("depth"),
                size: wgpu::Extent3d {
                    width,
                    height,
                    depth_or_array_layers: 1,
                },
                mip_level_count: 1,
                sample_count: 1,
                dimension: wgpu::TextureDimension::D2,
                format: DEPTH_FORMAT,
                usage: wgpu::TextureUsages::RENDER_ATTACHMENT,
                view_formats: &[],
            })
        })?;
        self.depth = Some(DepthTarget {
            size: (width, height),
            view: texture.create_view(&Default::default()),
        });
        Ok(())
    }

    /// Draws `frame` into `target` and submits the work. With `measure_gpu`, waits for the GPU and returns its frame time in
    /// the stats; otherwise the time arrives a few frames later in [`Self::last_gpu_ms`].
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
        self.ensure_depth(ctx, width, height)?;
        self.ensure_shadow_maps(ctx, frame.shadows.map_size)?;
        if !self.color_pipelines.contains_key(&format) {
            let p = ctx.checked("building the render pipelines", || {
                ColorPipelines::new(&ctx.device, &self.layouts, format)
            })?;
            self.color_pipelines.insert(format, p);
        }

        let aspect = width as f32 / height as f32;
        let cam = &frame.camera;
        let studio = frame.stage == Stage::Studio;
        let sun_up = frame.sun.elevation_deg > 0.0;
        let is_btf = frame.method == Method::Btf;
        if is_btf && self.btf.is_none() {
            return Err(Error::BadInput(
                "the btf method needs baked BTF images: run `canopy bake` (the viewer bakes on first use)".into(),
            ));
        }
        // The geometry method's depth cascades follow the camera and are drawn every frame.
        // The btf method has none: its trees are not geometry, so their shadows on the
        // ground come from the alpha shadow map, and the terrain's own shadows from the
        // terrain depth drawn with it, both rebuilt only when the sun moves.
        let shadows_on = frame.shadows.enabled && (sun_up || studio) && !is_btf;
        let ground_on = is_btf && frame.ground_shadows && sun_up && !studio;
        let terrain_depth_on = ground_on && frame.shadows.enabled;
        let cascades = if shadows_on && studio {
            let b = &self.world.forest_bounds;
            Cascades::fit_sphere(
                frame.sun.direction(),
                b.center(),
                0.5 * b.extent().length(),
                frame.shadows.map_size,
            )
        } else if shadows_on {
            Cascades::fit(
                cam,
                aspect,
                frame.sun.direction(),
                &frame.shadows,
                &self.world.scene_bounds,
            )
        } else {
            Cascades::none()
        };

        // Cull: the camera's list, then each cascade's casters. The btf method turns the
        // camera's list into billboards plus the trunks and limbs of the nearer trees.
        let frustum = cam.frustum(aspect);
        let visible = if frame.trees {
            self.world.cull(&frustum)
        } else {
            vec![Vec::new(); self.world.species.len()]
        };
        let mut btf_frame = None;
        let to_sun = frame.sun.direction();
        // Work that follows the sun, not the camera: the VCM reads (here) and the ground
        // alpha shadow map (below).
        let mut sun_update_ms = 0.0;
        let mut sun_moved = false;
        let lists = if let (true, Some(b)) = (is_btf, self.btf.as_mut()) {
            if frame.btf.vcm && frame.trees {
                let t0 = std::time::Instant::now();
                if b.update_sun(to_sun) {
                    sun_moved = true;
                    sun_update_ms += t0.elapsed().as_secs_f64() * 1e3;
                }
            }
            let bf = b.prepare(
                ctx,
                &self.world,
                &visible,
                cam,
                cam.focal_px(height),
                frame.sun.direction(),
                &frustum,
                &frame.btf,
            );
            let lists = vec![bf.trunk_only.clone(), bf.trunk_and_limbs.clone()];
            btf_frame = Some(bf);
            lists
        } else {
            let mut lists = vec![visible];
            if shadows_on {
                for m in &cascades.matrices {
                    lists.push(if frame.trees {
                        self.world.cull(&Frustum::from_ortho(*m))
                    } else {
                        vec![Vec::new(); self.world.species.len()]
                    });
                }
            }
            lists
        };
        let runs = self.world.upload_lists(ctx, &lists);

        let mut uniform_frame = *frame;
        uniform_frame.shadows.enabled = shadows_on;
        let mut uniforms = FrameUniforms::new(&uniform_frame, aspect, &cascades);

        // The ground shadow maps follow the sun, not the camera. They are submitted on their
        // own so that their cost can be timed (blocking, when measuring).
        if ground_on {
            let (want, rebuild) = self.ground.wanted(to_sun, frame.trees, frame.sun_held);
            if rebuild {
                let t0 = std::time::Instant::now();
                self.build_ground(ctx, &uniforms, want);
                if measure_gpu {
                    let _ = ctx.device.poll(wgpu::PollType::wait_indefinitely());
                }
                sun_moved = true;
                sun_update_ms += t0.elapsed().as_secs_f64() * 1e3;
            }
        }
        let mut encoder = ctx
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                label: Some("frame"),
            });
        if ground_on {
            uniforms.ground_light_view_proj = self.ground.light_view_proj.to_cols_array_2d();
            uniforms.ground_params = self.ground.params(terrain_depth_on);
            if terrain_depth_on {
                uniforms.sun_dir[3] = 1.0;
            }
        }
        ctx.queue
            .write_buffer(&self.frame_uniforms, 0, bytemuck::bytes_of(&uniforms));
        if shadows_on {
            for (i, (buf, _)) in self.shadow_uniforms.iter().enumerate() {
                let u = uniforms.for_light(cascades.matrices[i]);
                ctx.queue.write_buffer(buf, 0, bytemuck::bytes_of(&u));
            }
        }

        let mut stats = FrameStats {
            width,
            height,
            sun_update: sun_moved,
            sun_update_ms: sun_moved.then_some(sun_update_ms),
            ground_map_size: if ground_on {
                self.ground.built.map(|k| k.size)
            } else {
                None
            },
            ..Default::default()
        };
        let btf_pipeline = match (is_btf, self.btf.as_mut()) {
            (true, Some(b)) => Some(b.pipeline(&ctx.device, &self.layouts.frame, format).clone()),
            _ => None,
        };
        let queries = self.timer.as_mut().and_then(|t| t.begin()).cloned();
        let (Some(shadows), Some(depth), Some(pipes)) = (
            &self.shadows,
            &self.depth,
            self.color_pipelines.get(&format),
        ) else {
            return Err(Error::Gpu("render targets were not created".into()));
        };

        let cascades_drawn = if shadows_on { CASCADES } else { 0 };
        for c in 0..CASCADES {
            // Cleared even when off, so a stale map never shades a frame.
            let first = c == 0;
            let ts = queries
                .as_ref()
                .filter(|_| first)
                .map(|q| wgpu::RenderPassTimestampWrites {
                    query_set: q,
                    beginning_of_pass_write_index: Some(0),
                    end_of_pass_write_index: None,
                });
            let mut pass = encoder.begin_render_pass(&wgpu::RenderPassDescriptor {
                label: Some("shadow cascade"),
                color_attachments: &[],
                depth_stencil_attachment: Some(wgpu::RenderPassDepthStencilAttachment {
                    view: &shadows.layer_views[c],
                    depth_ops: Some(wgpu::Operations {
                        load: wgpu::LoadOp::Clear(1.0),
                        store: wgpu::StoreOp::Store,
                    }),
                    stencil_ops: None,
                }),
                timestamp_writes: ts,
                occlusion_query_set: None,
                multiview_mask: None,
            });
            if c >= cascades_drawn {
                continue;
            }
            pass.set_pipeline(&self.shadow_pipeline);
            pass.set_bind_group(0, &self.shadow_uniforms[c].1, &[]);
            pass.set_bind_group(1, &self.world.trees_bind_group, &[]);
            let (tris, casters, calls) = draw_world(
                &mut pass,
                &self.world,
                &runs[c + 1],
                None,
                !studio,
                &[PartKind::Trunk, PartKind::Limbs, PartKind::Twigs],
            );
            stats.shadow_triangles += tris;
            stats.shadow_casters += casters;
            stats.draw_calls += calls;
        }

        {
            let ts = queries.as_ref().map(|q| wgpu::RenderPassTimestampWrites {
                query_set: q,
                beginning_of_pass_write_index: None,
                end_of_pass_write_index: Some(1),
            });
            let mut pass = encoder.begin_render_pass(&wgpu::RenderPassDescriptor {
                label: Some("main"),
                color_attachments: &[Some(wgpu::RenderPassColorAttachment {
                    view: target,
                    depth_slice: None,
                    resolve_target: None,
                    ops: wgpu::Operations {
                        load: wgpu::LoadOp::Clear(if studio {
                            wgpu::Color::TRANSPARENT
                        } else {
                            wgpu::Color::BLACK
                        }),
                        store: wgpu::StoreOp::Store,
                    },
                })],
                depth_stencil_attachment: Some(wgpu::RenderPassDepthStencilAttachment {
                    view: &depth.view,
                    depth_ops: Some(wgpu::Operations {
                        load: wgpu::LoadOp::Clear(0.0),
                        store: wgpu::StoreOp::Discard,
                    }),
                    stencil_ops: None,
                }),
                timestamp_writes: ts,
                occlusion_query_set: None,
                multiview_mask: None,
            });
            pass.set_bind_group(0, &shadows.frame_bind_group, &[]);
            if !studio {
                pass.set_pipeline(&pipes.sky);
                pass.draw(0..3, 0..1);
                stats.draw_calls += 1;
            }
            pass.set_bind_group(1, &self.world.trees_bind_group, &[]);
            if let Some(bf) = &btf_frame {
                let (t0, _, c0) = draw_world(
                    &mut pass,
                    &self.world,
                    &runs[0],
                    Some(pipes),
                    !studio,
                    &[PartKind::Trunk],
                );
                let (t1, _, c1) = draw_world(
                    &mut pass,
                    &self.world,
                    &runs[1],
                    Some(pipes),
                    false,
                    &[PartKind::Trunk, PartKind::Limbs],
                );
                stats.triangles = t0 + t1 + 2 * u64::from(bf.billboards);
                stats.trees_drawn = bf.stats.trees_per_level.iter().sum();
                stats.draw_calls += c0 + c1;
                if let (Some(b), Some(pipeline)) = (&self.btf, &btf_pipeline)
                    && bf.billboards > 0
                {
                    pass.set_pipeline(pipeline);
                    pass.set_bind_group(1, b.bind_group(), &[]);
                    pass.draw(0..6, 0..bf.billboards);
                    stats.draw_calls += 1;
                }
                stats.btf = Some(bf.stats);
            } else {
                let (tris, trees, calls) = draw_world(
                    &mut pass,
                    &self.world,
                    &runs[0],
                    Some(pipes),
                    !studio,
                    &[PartKind::Trunk, PartKind::Limbs, PartKind::Twigs],
                );
                stats.triangles = tris;
                stats.trees_drawn = trees;
                stats.draw_calls += calls;
            }
        }
        if let Some(t) = &self.timer {
            t.resolve(&mut encoder);
        }
        ctx.queue.submit([encoder.finish()]);
        if let Some(t) = &mut self.timer {
            t.after_submit();
            stats.gpu_ms = t.collect(ctx, measure_gpu).filter(|_| measure_gpu);
        }
        if let Some(t) = &mut self.ground_timer {
            t.collect(ctx, measure_gpu);
        }
        if let Some(e) = ctx.take_error() {
            return Err(Error::Gpu(e));
        }
        Ok(stats)
    }

    /// Draws the ground shadow maps for `key` from the sun: the terrain (white, with depth),
    /// then, with the trees, every tree's tree-level billboard as the sun sees it,
    /// multiplying the transmittance. Submits the pass.
    fn build_ground(&mut self, ctx: &GpuContext, uniforms: &FrameUniforms, key: GroundKey) {
        let b_box = &self.world.scene_bounds;
        let light = Cascades::fit_sphere(
            key.to_sun,
            b_box.center(),
            0.5 * b_box.extent().length(),
            key.size,
        );
        self.ground.light_view_proj = light.matrices[0];
        self.ground.texel_world = light.texel_world[0];
        let light_uniforms = uniforms.for_light(self.ground.light_view_proj);
        ctx.queue.write_buffer(
            &self.ground.uniforms,
            0,
            bytemuck::bytes_of(&light_uniforms),
        );
        let billboards = match self.btf.as_mut() {
            Some(b) if key.trees => {
                let n = b.prepare_sun(ctx, &self.world, key.to_sun);
                let pipeline = b
                    .opacity_pipeline(&ctx.device, &self.layouts.shadow_frame)
                    .clone();
                Some((n, pipeline))
            }
            _ => None,
        };
        let queries = self.ground_timer.as_mut().and_then(|t| t.begin()).cloned();
        let mut encoder = ctx
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                label: Some("ground shadow maps"),
            });
        let mut pass = encoder.begin_render_pass(&wgpu::RenderPassDescriptor {
            label: Some("ground shadow maps"),
            color_attachments: &[Some(wgpu::RenderPassColorAttachment {
                view: &self.ground.view,
                depth_slice: None,
                resolve_target: None,
                ops: wgpu::Operations {
                    load: wgpu::LoadOp::Clear(wgpu::Color::WHITE),
                    store: wgpu::StoreOp::Store,
                },
            })],
            depth_stencil_attachment: Some(wgpu::RenderPassDepthStencilAttachment {
                view: &self.ground.depth_view,
                depth_ops: Some(wgpu::Operations {
                    load: wgpu::LoadOp::Clear(1.0),
                    store: wgpu::StoreOp::Store,
                }),
                stencil_ops: None,
            }),
            timestamp_writes: queries.as_ref().map(|q| wgpu::RenderPassTimestampWrites {
                query_set: q,
                beginning_of_pass_write_index: Some(0),
                end_of_pass_write_index: Some(1),
            }),
            occlusion_query_set: None,
            multiview_mask: None,
        });
        let side = key.size as f32;
        pass.set_viewport(0.0, 0.0, side, side, 0.0, 1.0);
        pass.set_scissor_rect(0, 0, key.size, key.size);
        pass.set_pipeline(&self.ground.terrain_pipeline);
        pass.set_bind_group(0, &self.ground.bind_group, &[]);
        pass.set_bind_group(1, &self.world.trees_bind_group, &[]);
        draw_world(&mut pass, &self.world, &[], None, true, &[]);
        if let (Some((n, pipeline)), Some(b)) = (&billboards, &self.btf)
            && *n > 0
        {
            pass.set_pipeline(pipeline);
            pass.set_bind_group(1, b.sun_bind_group(), &[]);
            pass.draw(0..6, 0..*n);
        }
        drop(pass);
        if let Some(t) = &self.ground_timer {
            t.resolve(&mut encoder);
        }
        ctx.queue.submit([encoder.finish()]);
        if let Some(t) = &mut self.ground_timer {
            t.after_submit();
        }
        self.ground.built = Some(key);
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

/// Draws the terrain (when asked) and the trees of `runs`; with no colour pipelines it is the shadow pass
/// (one pipeline already set). Returns (triangles, trees, draw calls).
fn draw_world(
    pass: &mut wgpu::RenderPass<'_>,
    world: &WorldGpu,
    runs: &[TreeRun],
    pipes: Option<&ColorPipelines>,
    terrain: bool,
    kinds: &[PartKind],
) -> (u64, u32, u32) {
    let mut tris = 0u64;
    let mut calls = 0u32;
    let mut trees = 0u32;
    if let Some(p) = pipes {
        pass.set_pipeline(&p.opaque);
    }
    let mut draw =
        |pass: &mut wgpu::RenderPass<'_>, set: &world_gpu::PartSet, first: u32, n: u32| {
            pass.set_bind_group(2, &set.bind_group, &[]);
            pass.set_vertex_buffer(0, set.mesh.vertices.slice(..));
            pass.set_index_buffer(set.mesh.indices.slice(..), wgpu::IndexFormat::Uint32);
            let start = first * set.count;
            pass.draw_indexed(0..set.mesh.index_count, 0, start..start + n * set.count);
            tris += set.mesh.triangles() * u64::from(n) * u64::from(set.count);
            calls += 1;
        };
    if terrain {
        draw(pass, &world.terrain, 0, 1);
    }
    // Opaque parts of every species first, then foliage, to switch pipelines twice only.
    for foliage in [false, true] {
        if let Some(p) = pipes {
            pass.set_pipeline(if foliage { &p.foliage } else { &p.opaque });
        }
        for run in runs {
            for set in world.species[run.species]
                .parts
                .iter()
                .filter(|s| s.foliage == foliage && kinds.contains(&s.kind))
            {
                draw(pass, set, run.first, run.count);
            }
        }
    }
    for run in runs {
        trees += run.count;
    }
    (tris, trees, calls)
}
