//! The ground shadow maps of the image-based methods, both seen from the sun over the whole
//! scene and rebuilt only when the sun moves: the trees' transmittance (the alpha shadow
//! map; the terrain is drawn white into it, so it hides the trees behind it but casts
//! nothing) and the terrain's depth (its own shadows: a hill shading a valley). They are
//! drawn in one pass, into the top-left `size` x `size` texels of the textures.
//!
//! The maps are allocated only when a method first asks for them (the `geometry` method and
//! the bake's studio renderers never do); until then the frame binds a 1x1 placeholder.

use super::GpuContext;
use super::method::kind::Method;
use super::pipelines::{self, Layouts};
use super::shadow::Cascades;
use super::timing::{GpuTimer, PassSpans};
use super::uniforms::FrameUniforms;
use super::world_gpu::WorldGpu;
use crate::Result;

/// Format of the ground alpha shadow map (transmittance).
pub const GROUND_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::R8Unorm;
/// Format of the ground terrain depth map: 16 bits (steps of about 2 cm over the default
/// square kilometre's depth from the sun, against a lookup offset of 1.5 texels, about
/// 0.4 m), half the bytes of the cascades' 32-bit floats: 33.5 MB at 4096².
pub const GROUND_DEPTH_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Depth16Unorm;
/// Largest side of the ground shadow maps (alpha and terrain depth), which cover the whole
/// scene: the default square kilometre's (about 0.35 m per texel).
pub const GROUND_MAP_SIZE: u32 = 4096;
/// Smallest side of the ground shadow maps (a small scene's).
pub const GROUND_MIN_SIZE: u32 = 1024;
/// The texel the ground maps aim for (m): the default square kilometre's at
/// [`GROUND_MAP_SIZE`]. A smaller scene gets smaller maps of texels at least this fine.
pub const GROUND_TEXEL_M: f32 = 0.35;

/// Side of the ground shadow maps for a scene whose bounding sphere is `diameter_m` wide
/// (the maps cover it): the power of two that gives texels of at most [`GROUND_TEXEL_M`],
/// between [`GROUND_MIN_SIZE`] and [`GROUND_MAP_SIZE`] (and the device's `max_dim`). Their
/// cost, a pass over every texel with each tree's billboard drawn into them, follows it:
/// a stand 80 m wide draws a sixteenth of the default scene's texels, and its texels are
/// still 4x finer.
pub fn ground_map_side(diameter_m: f32, max_dim: u32) -> u32 {
    let want = if diameter_m.is_finite() && diameter_m > 0.0 {
        (diameter_m / GROUND_TEXEL_M)
            .ceil()
            .min(GROUND_MAP_SIZE as f32) as u32
    } else {
        GROUND_MAP_SIZE
    };
    want.next_power_of_two()
        .clamp(GROUND_MIN_SIZE, GROUND_MAP_SIZE)
        .min(max_dim)
}

/// Side of the ground shadow maps while the user holds the sun (`FrameDesc::sun_held`), for
/// maps of side `full`: a sixteenth of the texels (at least 256 a side), so that dragging
/// the sun does not stall a software renderer; the full maps follow on the first frame after
/// the sun is let go.
pub fn ground_preview_side(full: u32) -> u32 {
    (full / 4).max(256).min(full)
}

/// What a ground map was built for.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GroundKey {
    pub to_sun: glam::Vec3,
    /// The trees are in it (not while only terrain and sky are shown).
    pub trees: bool,
    /// The method whose trees cast (its casters' kind: billboards, texel boxes).
    pub casters: Method,
    /// Side of the part of the textures in use.
    pub size: u32,
    /// A hash of the trees left out of the alpha map (`hybrid`'s geometry trees, which
    /// cast their own shadows through cascades); 0 when none are.
    pub excluded: u64,
}

/// The textures the colour passes sample (the maps, or the placeholders).
pub struct GroundTextures {
    /// Transmittance, as the ground pass draws it and the colour passes sample it.
    pub alpha: wgpu::TextureView,
    /// The terrain depth as the ground pass draws into it.
    depth: wgpu::TextureView,
    /// The same texture as a one-layer array, as the colour passes sample it.
    pub depth_sampled: wgpu::TextureView,
    /// Side of the textures.
    capacity: u32,
}

impl GroundTextures {
    fn new(ctx: &GpuContext, size: u32) -> Result<Self> {
        let usage = wgpu::TextureUsages::RENDER_ATTACHMENT | wgpu::TextureUsages::TEXTURE_BINDING;
        let (color, depth) = ctx.checked("allocating the ground shadow maps", || {
            let texture = |label, format| {
                pipelines::target_texture(
                    &ctx.device,
                    label,
                    glam::UVec3::new(size, size, 1),
                    format,
                    usage,
                )
            };
            (
                texture("ground alpha shadow map", GROUND_FORMAT),
                texture("ground terrain depth map", GROUND_DEPTH_FORMAT),
            )
        })?;
        Ok(Self {
            alpha: color.create_view(&Default::default()),
            depth: depth.create_view(&Default::default()),
            depth_sampled: depth.create_view(&wgpu::TextureViewDescriptor {
                dimension: Some(wgpu::TextureViewDimension::D2Array),
                ..Default::default()
            }),
            capacity: size,
        })
    }

    /// Whether these are the 1x1 placeholders.
    pub fn is_placeholder(&self) -> bool {
        self.capacity == 1
    }

    /// The 1x1 textures bound while no method has asked for the maps.
    pub fn placeholder(ctx: &GpuContext) -> Result<Self> {
        Self::new(ctx, 1)
    }
}

/// Billboards drawn into the alpha map: a pipeline, its group-1 bind group, and how many.
pub struct GroundBillboards<'a> {
    pub pipeline: &'a wgpu::RenderPipeline,
    pub bind_group: &'a wgpu::BindGroup,
    pub count: u32,
    /// Vertices per instance (6 for a billboard's quad, 36 for a texel's box).
    pub vertices: u32,
}

/// The ground shadow maps and what they were last built for.
pub struct GroundMaps {
    pub textures: GroundTextures,
    uniforms: wgpu::Buffer,
    bind_group: wgpu::BindGroup,
    terrain_pipeline: wgpu::RenderPipeline,
    light_view_proj: glam::Mat4,
    /// World size (m) of one texel of the maps as last built.
    texel_world: f32,
    /// Half the side of the square they cover (the scene's bounds), as last built.
    half: f32,
    /// What the maps hold now (None: nothing yet).
    built: Option<GroundKey>,
    /// Timestamps around the pass, the GPU side of a sun move.
    pub timer: Option<GpuTimer>,
}

impl GroundMaps {
    /// Maps sized for `world`'s scene ([`ground_map_side`]).
    pub fn new(ctx: &GpuContext, layouts: &Layouts, world: &WorldGpu) -> Result<Self> {
        let size = ground_map_side(
            world.scene_bounds.extent().length(),
            ctx.device.limits().max_texture_dimension_2d,
        );
        let textures = GroundTextures::new(ctx, size)?;
        let uniforms = ctx.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("ground shadow uniforms"),
            size: std::mem::size_of::<FrameUniforms>() as u64,
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
            textures,
            uniforms,
            bind_group,
            terrain_pipeline,
            light_view_proj: glam::Mat4::IDENTITY,
            texel_world: 0.0,
            half: 0.0,
            built: None,
            timer: GpuTimer::new(ctx),
        })
    }

    /// Forgets what the maps hold, so the next frame that uses them rebuilds them.
    pub fn invalidate(&mut self) {
        self.built = None;
    }

    /// Side (texels) of the part of the maps in use, once built.
    pub fn built_size(&self) -> Option<u32> {
        self.built.map(|k| k.size)
    }

    /// The key of the maps a frame needs, and whether the ones held must be rebuilt for
    /// it: the sun moved, the trees came or went, the trees left out changed, or the sun
    /// was let go after a preview.
    pub fn wanted(
        &self,
        to_sun: glam::Vec3,
        trees: bool,
        casters: Method,
        held: bool,
        excluded: u64,
    ) -> (GroundKey, bool) {
        let capacity = self.textures.capacity;
        let size = if held {
            ground_preview_side(capacity)
        } else {
            capacity
        };
        let want = GroundKey {
            to_sun,
            trees,
            casters,
            size,
            excluded,
        };
        let rebuild = match self.built {
            None => true,
            Some(k) => {
                k.to_sun != to_sun
                    || k.trees != trees
                    || k.casters != casters
                    || k.excluded != excluded
                    || (!held && k.size != size)
            }
        };
        (want, rebuild)
    }

    /// Sets the ground maps' uniforms: the light matrix, alpha map on, terrain depth on,
    /// world size of one texel, and the fraction of the textures in use.
    pub fn apply(&self, uniforms: &mut FrameUniforms, terrain_depth: bool) {
        let capacity = self.textures.capacity;
        let size = self.built.map_or(capacity, |k| k.size);
        uniforms.ground_light_view_proj = self.light_view_proj.to_cols_array_2d();
        uniforms.ground_alpha_on = 1;
        uniforms.terrain_depth_on = u32::from(terrain_depth);
        uniforms.ground_texel_world = self.texel_world;
        uniforms.ground_half = self.half;
        uniforms.ground_uv_scale = size as f32 / capacity.max(1) as f32;
        if terrain_depth {
            uniforms.shadows_on = 1;
        }
    }

    /// Draws the maps for `key` from the sun: the terrain (white, with depth), then the
    /// `billboards`, multiplying the transmittance. Submits the pass.
    pub fn build(
        &mut self,
        ctx: &GpuContext,
        world: &WorldGpu,
        uniforms: &FrameUniforms,
        key: GroundKey,
        billboards: Option<GroundBillboards<'_>>,
    ) {
        let b_box = &world.scene_bounds;
        let light = Cascades::fit_sphere(
            key.to_sun,
            b_box.center(),
            0.5 * b_box.extent().length(),
            key.size,
        );
        self.light_view_proj = light.matrices[0];
        self.texel_world = light.texel_world[0];
        self.half = [b_box.min.x, b_box.max.x, b_box.min.z, b_box.max.z]
            .iter()
            .fold(0.0f32, |m, v| m.max(v.abs()));
        let light_uniforms = uniforms.for_light(self.light_view_proj);
        ctx.queue
            .write_buffer(&self.uniforms, 0, bytemuck::bytes_of(&light_uniforms));
        let spans = self
            .timer
            .as_mut()
            .map_or_else(PassSpans::off, GpuTimer::begin);
        let mut encoder = ctx
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                label: Some("ground shadow maps"),
            });
        let mut pass = encoder.begin_render_pass(&wgpu::RenderPassDescriptor {
            label: Some("ground shadow maps"),
            color_attachments: &[Some(wgpu::RenderPassColorAttachment {
                view: &self.textures.alpha,
                depth_slice: None,
                resolve_target: None,
                ops: wgpu::Operations {
                    load: wgpu::LoadOp::Clear(wgpu::Color::WHITE),
                    store: wgpu::StoreOp::Store,
                },
            })],
            depth_stencil_attachment: Some(wgpu::RenderPassDepthStencilAttachment {
                view: &self.textures.depth,
                depth_ops: Some(wgpu::Operations {
                    load: wgpu::LoadOp::Clear(1.0),
                    store: wgpu::StoreOp::Store,
                }),
                stencil_ops: None,
            }),
            timestamp_writes: spans.render_pass("ground maps"),
            occlusion_query_set: None,
            multiview_mask: None,
        });
        let side = key.size as f32;
        pass.set_viewport(0.0, 0.0, side, side, 0.0, 1.0);
        pass.set_scissor_rect(0, 0, key.size, key.size);
        pass.set_pipeline(&self.terrain_pipeline);
        pass.set_bind_group(0, &self.bind_group, &[]);
        pass.set_bind_group(1, &world.trees_bind_group(), &[]);
        world.draw(&mut pass, &[], None, true, &[]);
        if let Some(b) = billboards.filter(|b| b.count > 0) {
            pass.set_pipeline(b.pipeline);
            pass.set_bind_group(1, b.bind_group, &[]);
            pass.draw(0..b.vertices, 0..b.count);
        }
        drop(pass);
        if let Some(t) = &mut self.timer {
            t.resolve(spans, &mut encoder);
        }
        ctx.queue.submit([encoder.finish()]);
        if let Some(t) = &mut self.timer {
            t.after_submit();
        }
        self.built = Some(key);
    }
}

/// The linear sampler of the alpha map.
pub fn ground_sampler(ctx: &GpuContext) -> wgpu::Sampler {
    ctx.device.create_sampler(&wgpu::SamplerDescriptor {
        label: Some("ground shadow"),
        mag_filter: wgpu::FilterMode::Linear,
        min_filter: wgpu::FilterMode::Linear,
        ..Default::default()
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_maps_follow_the_scene_between_their_bounds() {
        // The default square kilometre (its bounding sphere about 1.42 km across) keeps the
        // largest maps; an 80 m stand gets the smallest, with finer texels.
        assert_eq!(ground_map_side(1420.0, 16384), GROUND_MAP_SIZE);
        assert_eq!(ground_map_side(5000.0, 16384), GROUND_MAP_SIZE);
        assert_eq!(ground_map_side(115.0, 16384), GROUND_MIN_SIZE);
        let side = ground_map_side(500.0, 16384);
        assert_eq!(side, 2048);
        assert!(500.0 / side as f32 <= GROUND_TEXEL_M);
        assert_eq!(ground_map_side(1420.0, 2048), 2048, "the device's limit");
        assert_eq!(ground_map_side(f32::NAN, 16384), GROUND_MAP_SIZE);
        assert_eq!(ground_preview_side(4096), 1024);
        assert_eq!(ground_preview_side(1024), 256);
        assert_eq!(ground_preview_side(128), 128);
    }
}
