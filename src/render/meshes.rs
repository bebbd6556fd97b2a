//! The mesh draws every method shares: the sun cascades' pass (its pipeline and per-cascade
//! uniforms) and the terrain's and trees' meshes in the main pass, whole or by part.

use super::frame_bindings::FrameBindings;
use super::pipelines::{self, ColorPipelines, Layouts};
use super::self_shadow;
use super::shadow::{CASCADES, Cascades};
use super::timing::PassSpans;
use super::uniforms::FrameUniforms;
use super::world_gpu::{self, ALL_PARTS, TreeRun, WorldGpu};
use super::{FrameStats, GpuContext};
use crate::Result;

/// The pipeline and buffers of the sun cascades' pass, and the main pass's mesh draws.
pub struct MeshPasses {
    /// Depth only: untextured parts and the terrain, then parts with an alpha test.
    shadow_pipelines: (wgpu::RenderPipeline, wgpu::RenderPipeline),
    /// Per cascade: the frame uniforms with the cascade's light matrix, and their group 0.
    cascade_uniforms: Vec<(wgpu::Buffer, wgpu::BindGroup)>,
}

impl MeshPasses {
    pub fn new(ctx: &GpuContext, layouts: &Layouts) -> Result<Self> {
        let device = &ctx.device;
        let shadow_pipelines = ctx.checked("building the shadow pipelines", || {
            pipelines::shadow_pipelines(device, layouts)
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
            shadow_pipelines,
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
        pass.set_bind_group(0, &self.cascade_uniforms[c].1, &[]);
        pass.set_bind_group(1, &world.trees_bind_group(), &[]);
        let (tris, casters, calls) = match pipeline {
            Some(p) => {
                pass.set_pipeline(p);
                world.draw(pass, runs, None, terrain, &ALL_PARTS)
            }
            None => {
                let (plain, cutout) = &self.shadow_pipelines;
                world.draw_depth(pass, runs, (plain, cutout), terrain, &ALL_PARTS)
            }
        };
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

    /// Draws the camera's trees (`runs`), whole, in the main pass (after the core's
    /// terrain).
    pub fn draw_main(
        pass: &mut wgpu::RenderPass<'_>,
        world: &WorldGpu,
        runs: &[TreeRun],
        pipes: &ColorPipelines,
        stats: &mut FrameStats,
    ) {
        let (tris, trees, calls) = world.draw(pass, runs, Some(pipes.meshes()), false, &ALL_PARTS);
        stats.triangles += tris;
        stats.trees_drawn = trees;
        stats.draw_calls += calls;
    }
}

/// The key of a studio frame's cascade maps: its matrices, their size and the trees drawn
/// into them (each cascade's tree lists, per species; the runs are uploaded from them).
pub(super) fn studio_cascades_key(
    cascades: &Cascades,
    map_size: u32,
    casters: &[Vec<Vec<u32>>],
) -> Vec<u8> {
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
/// as the last frame left them instead (nothing drawn). Timed as one span, `cascades`.
#[allow(clippy::too_many_arguments)]
pub(super) fn encode_cascades(
    encoder: &mut wgpu::CommandEncoder,
    bindings: &FrameBindings,
    meshes: &MeshPasses,
    world: &WorldGpu,
    casters: Option<&[Vec<world_gpu::TreeRun>]>,
    terrain: bool,
    keys: Option<&self_shadow::SelfShadow>,
    keep: bool,
    spans: &PassSpans,
    stats: &mut FrameStats,
) {
    let span = spans.open("cascades");
    for c in 0..CASCADES {
        let ts = spans.render_writes(span, c == 0, c + 1 == CASCADES);
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
            meshes.draw_cascade(
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
