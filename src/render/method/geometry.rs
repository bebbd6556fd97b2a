//! The `geometry` method: every leaf, needle and branch as triangles, lit by the sun
//! through cascaded shadow maps that follow the camera and are drawn every frame, and by the
//! hemispherical sky. The ground truth every other method is measured against.

use super::super::frame::{FrameDesc, FrameStats, FrameUniforms, Stage};
use super::super::pipelines::{self, ColorPipelines, Layouts};
use super::super::shadow::{CASCADES, Cascades};
use super::super::world_gpu::{PartKind, TreeRun, WorldGpu};
use super::super::{Frustum, GpuContext};
use crate::Result;

pub(crate) const ALL_PARTS: [PartKind; 3] = [PartKind::Trunk, PartKind::Limbs, PartKind::Twigs];

/// The pipelines and buffers of the method's shadow cascades.
pub struct GeometryMethod {
    shadow_pipeline: wgpu::RenderPipeline,
    /// Per cascade: the frame uniforms with the cascade's light matrix, and their group 0.
    cascade_uniforms: Vec<(wgpu::Buffer, wgpu::BindGroup)>,
}

/// The CPU side of one frame: where the cascades are and what each one draws.
#[derive(Clone, Debug)]
pub struct GeometryFrame {
    pub cascades: Cascades,
    /// The cascades are drawn and sampled (shadows enabled and a sun to cast them).
    pub shadows_on: bool,
    /// Trees per species: the camera's, then each cascade's casters (when on).
    pub lists: Vec<Vec<Vec<u32>>>,
}

impl GeometryFrame {
    /// Fits the cascades to the view (in the studio: around the object, from any sun
    /// direction) and culls each cascade's casters. `visible` is the camera's list. CPU only.
    pub fn prepare(
        world: &WorldGpu,
        frame: &FrameDesc,
        aspect: f32,
        visible: Vec<Vec<u32>>,
    ) -> Self {
        let studio = frame.stage == Stage::Studio;
        let shadows_on = frame.shadows.enabled && (frame.sun.elevation_deg > 0.0 || studio);
        let cascades = if shadows_on && studio {
            let b = &world.forest_bounds;
            Cascades::fit_sphere(
                frame.sun.direction(),
                b.center(),
                0.5 * b.extent().length(),
                frame.shadows.map_size,
            )
        } else if shadows_on {
            Cascades::fit(
                &frame.camera,
                aspect,
                frame.sun.direction(),
                &frame.shadows,
                &world.scene_bounds,
            )
        } else {
            Cascades::none()
        };
        let mut lists = vec![visible];
        if shadows_on {
            // The studio's one map serves every pixel (cascade 0, its split at infinity):
            // the other cascades are never read, so nothing is drawn into them.
            let used = if studio { 1 } else { cascades.matrices.len() };
            for m in cascades.matrices.iter().take(used) {
                lists.push(if frame.trees {
                    world.cull(&Frustum::from_ortho(*m))
                } else {
                    vec![Vec::new(); world.species.len()]
                });
            }
        }
        Self {
            cascades,
            shadows_on,
            lists,
        }
    }
}

impl GeometryMethod {
    pub fn new(ctx: &GpuContext, layouts: &Layouts) -> Result<Self> {
        let device = &ctx.device;
        let shadow_pipeline = ctx.checked("building the shadow pipeline", || {
            pipelines::shadow_pipeline(device, layouts)
        })?;
        let cascade_uniforms = (0..CASCADES)
            .map(|i| {
                let buf = device.create_buffer(&wgpu::BufferDescriptor {
                    label: Some(&format!("shadow cascade {i} uniforms")),
                    size: std::mem::size_of::<FrameUniforms>() as u64,
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
        Ok(Self {
            shadow_pipeline,
            cascade_uniforms,
        })
    }

    /// Uploads each cascade's uniforms (the frame's, seen from the cascade's light), when
    /// the cascades are on.
    pub fn write_uniforms(
        &self,
        ctx: &GpuContext,
        uniforms: &FrameUniforms,
        cascades: &Cascades,
        shadows_on: bool,
    ) {
        if !shadows_on {
            return;
        }
        for (i, (buf, _)) in self.cascade_uniforms.iter().enumerate() {
            let u = uniforms.for_light(cascades.matrices[i]);
            ctx.queue.write_buffer(buf, 0, bytemuck::bytes_of(&u));
        }
    }

    /// Draws cascade `c`'s casters (`runs` of its list) into its pass, with the shadow
    /// pipeline or `pipeline` (the reference's, which keeps the trees' keys too).
    #[allow(clippy::too_many_arguments)]
    pub fn draw_cascade(
        &self,
        pass: &mut wgpu::RenderPass<'_>,
        c: usize,
        world: &WorldGpu,
        runs: &[TreeRun],
        terrain: bool,
        pipeline: Option<&wgpu::RenderPipeline>,
        stats: &mut FrameStats,
    ) {
        pass.set_pipeline(pipeline.unwrap_or(&self.shadow_pipeline));
        pass.set_bind_group(0, &self.cascade_uniforms[c].1, &[]);
        pass.set_bind_group(1, &world.trees_bind_group, &[]);
        let (tris, casters, calls) = world.draw(pass, runs, None, terrain, &ALL_PARTS);
        stats.shadow_triangles += tris;
        stats.shadow_casters += casters;
        stats.draw_calls += calls;
    }

    /// Draws the trees of `runs` whole (and the terrain when asked) with `pipes` (the
    /// texel bake's voxelisation).
    pub fn draw_with(
        pass: &mut wgpu::RenderPass<'_>,
        world: &WorldGpu,
        runs: &[TreeRun],
        pipes: pipelines::MeshPipelines<'_>,
        terrain: bool,
    ) {
        world.draw(pass, runs, Some(pipes), terrain, &ALL_PARTS);
    }

    /// Draws the camera's trees (`runs`), whole, and the terrain when asked, in the main
    /// pass.
    pub fn draw_main(
        pass: &mut wgpu::RenderPass<'_>,
        world: &WorldGpu,
        runs: &[TreeRun],
        pipes: &ColorPipelines,
        terrain: bool,
        stats: &mut FrameStats,
    ) {
        let (tris, trees, calls) =
            world.draw(pass, runs, Some(pipes.meshes()), terrain, &ALL_PARTS);
        stats.triangles = tris;
        stats.trees_drawn = trees;
        stats.draw_calls += calls;
    }
}
