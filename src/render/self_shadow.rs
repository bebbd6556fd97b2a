//! The reference's sun shadows per tree. View-fitted cascades grow to tens of centimetres a
//! texel a few hundred metres out, and a tree stops shadowing its own needles there (light
//! leaks through the crown, backlit crowns glow). So each tree the reference draws gets its
//! own sun map, a square around its bounding sphere alone, as fine at a kilometre as at ten
//! metres (`Reference::self_map_size` texels a side, about 1 cm for a 20 m fir at 2048), and
//! the cascades keep, per texel, which tree is nearest the sun there (`tree_key` in
//! `instancing.wgsl`): a tree's fragment leaves its own texels out of the cascades (its
//! self-shadow would count twice, once through coarse texels) and takes the rest (other
//! trees, the terrain) from them.
//!
//! The maps are drawn in batches of `layers` trees into one depth array, each batch's trees
//! drawn into the frame right after their maps, so that memory stays `layers` maps whatever
//! the forest's size.
//!
//! One case is lost: another tree between this tree's own nearest texel and the fragment
//! (crowns grown into each other) does not shade it. Its own needles nearer the sun hide
//! the texel; only the nearest caster is kept.

use std::collections::HashMap;

use glam::{Mat4, Vec3};

use super::frame::FrameStats;
use super::frame_bindings::DepthTarget;
use super::pipelines::{
    GeometryPass, Layouts, LightFragment, LightView, MeshDepth, MeshPipelines, SHADOW_BIAS,
    light_view_pipeline, storage_buffer_of, storage_entry, texture_entry,
};
use super::shadow::{CASCADES, Cascades, layered_target};
use super::timing::PassSpans;
use super::world_gpu::{TreeRun, WorldGpu};
use super::{GpuContext, SHADOW_FORMAT};
use crate::{Error, Result};

/// Texel format of the cascades' tree keys.
pub const KEY_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::R32Uint;

pub use super::consts::SELF_MAP_SIZE;

/// Trees whose maps are drawn at once (layers of the map array), at most.
pub const SELF_MAP_LAYERS: u32 = 32;

/// Bytes the map array may take: its layers are as many as fit, up to [`SELF_MAP_LAYERS`]
/// (32 at 2048², 8 at 4096²).
pub const SELF_MAP_BUDGET: u64 = 512 << 20;

/// Layers of maps of `size` texels a side that fit [`SELF_MAP_BUDGET`] (at least 1).
pub fn layers_for(size: u32) -> u32 {
    let per_layer = u64::from(size) * u64::from(size) * 4;
    (SELF_MAP_BUDGET / per_layer.max(1)).clamp(1, u64::from(SELF_MAP_LAYERS)) as u32
}

/// One tree's sun map as `shadow.wgsl` and `geometry.wgsl` read it (`struct SelfLight`).
#[repr(C)]
#[derive(Clone, Copy, Debug, bytemuck::Pod, bytemuck::Zeroable)]
pub struct SelfLightGpu {
    pub matrix: [[f32; 4]; 4],
    pub texel_world: f32,
    pub layer: u32,
    pub _pad0: u32,
    pub _pad1: u32,
}

/// The light matrix of a tree of world `bounds`'s own map seen from `to_sun`, `size`
/// texels a side, and the world size of one texel.
pub fn tree_light(bounds: &crate::model::mesh::Aabb, to_sun: Vec3, size: u32) -> (Mat4, f32) {
    let c = Cascades::fit_sphere(
        to_sun,
        bounds.center(),
        0.5 * bounds.extent().length(),
        size,
    );
    (c.matrices[0], c.texel_world[0])
}

/// The runs of one list cut into batches of at most `per_batch` trees, in order.
pub fn batches(runs: &[TreeRun], per_batch: u32) -> Vec<Vec<TreeRun>> {
    let per_batch = per_batch.max(1);
    let mut out: Vec<Vec<TreeRun>> = Vec::new();
    let mut room = 0u32;
    for run in runs {
        let (mut first, mut left) = (run.first, run.count);
        while left > 0 {
            if room == 0 {
                out.push(Vec::new());
                room = per_batch;
            }
            let n = left.min(room);
            if let Some(b) = out.last_mut() {
                b.push(TreeRun {
                    species: run.species,
                    first,
                    count: n,
                });
            }
            first += n;
            left -= n;
            room -= n;
        }
    }
    out
}

/// The per-tree maps, the cascades' keys and the pipelines that draw and read them.
pub struct SelfShadow {
    pub size: u32,
    pub layers: u32,
    map_views: Vec<wgpu::TextureView>,
    map_array: wgpu::TextureView,
    lights: wgpu::Buffer,
    lights_group: wgpu::BindGroup,
    reference_layout: wgpu::BindGroupLayout,
    /// The cascades' key textures (their side, one view per cascade, the array), and the
    /// main passes' group 3 that binds them.
    keys: Option<(u32, Vec<wgpu::TextureView>, wgpu::BindGroup)>,
    /// Depth only: untextured parts, then parts with an alpha test.
    map_pipelines: (wgpu::RenderPipeline, wgpu::RenderPipeline),
    keyed_pipeline: wgpu::RenderPipeline,
    /// The main passes' pipelines of the reference's trees, per colour format.
    color: HashMap<wgpu::TextureFormat, (wgpu::RenderPipeline, wgpu::RenderPipeline)>,
}

impl SelfShadow {
    /// Maps of `size` texels a side, `layers` at a time, for a world of `slots` tree slots.
    pub fn new(
        ctx: &GpuContext,
        layouts: &Layouts,
        size: u32,
        layers: u32,
        slots: usize,
    ) -> Result<Self> {
        let device = &ctx.device;
        let size = size.clamp(16, device.limits().max_texture_dimension_2d);
        let layers = layers.clamp(1, device.limits().max_texture_array_layers);
        let (map_array, map_views) =
            layered_target(ctx, "per-tree sun maps", size, layers, SHADOW_FORMAT)?;
        let lights = ctx.checked("allocating the per-tree sun matrices", || {
            storage_buffer_of::<SelfLightGpu>(device, "per-tree sun matrices", slots)
        })?;
        let storage = |visibility| storage_entry(2, visibility);
        let lights_layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("per-tree sun matrices"),
            entries: &[storage(wgpu::ShaderStages::VERTEX)],
        });
        let array_entry = |binding, sample_type| {
            texture_entry(binding, sample_type, wgpu::TextureViewDimension::D2Array)
        };
        let reference_layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("reference sun maps"),
            entries: &[
                storage(wgpu::ShaderStages::FRAGMENT),
                array_entry(3, wgpu::TextureSampleType::Depth),
                array_entry(4, wgpu::TextureSampleType::Uint),
            ],
        });
        let lights_group = device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("per-tree sun matrices"),
            layout: &lights_layout,
            entries: &[wgpu::BindGroupEntry {
                binding: 2,
                resource: lights.as_entire_binding(),
            }],
        });
        let (map_pipelines, keyed_pipeline) =
            ctx.checked("building the per-tree sun map pipelines", || {
                // Biased as the cascades are.
                let base = || LightView {
                    bias: SHADOW_BIAS,
                    ..LightView::shadow_frame(layouts)
                };
                let map = |label, cutout| {
                    light_view_pipeline(
                        device,
                        &LightView {
                            label,
                            groups: [
                                None,
                                Some(&layouts.trees),
                                Some(&layouts.parts),
                                Some(&lights_layout),
                            ],
                            vertex: "vs_self_shadow",
                            cutout,
                            ..base()
                        },
                    )
                };
                (
                    (
                        map("per-tree sun map", false),
                        map("per-tree sun map, cut out", true),
                    ),
                    light_view_pipeline(
                        device,
                        &LightView {
                            label: "keyed shadow cascade",
                            vertex: "vs_shadow_keyed",
                            fragment: Some(LightFragment {
                                entry: "fs_shadow_keyed",
                                source: None,
                                format: KEY_FORMAT,
                            }),
                            ..base()
                        },
                    ),
                )
            })?;
        Ok(Self {
            size,
            layers,
            map_views,
            map_array,
            lights,
            lights_group,
            reference_layout,
            keys: None,
            map_pipelines,
            keyed_pipeline,
            color: HashMap::new(),
        })
    }

    /// Bytes of GPU memory the maps, the keys and the matrices take.
    pub fn bytes(&self) -> u64 {
        let maps = u64::from(self.size) * u64::from(self.size) * 4 * u64::from(self.layers);
        let keys = self.keys.as_ref().map_or(0, |(s, ..)| {
            u64::from(*s) * u64::from(*s) * 4 * CASCADES as u64
        });
        maps + keys + self.lights.size()
    }

    /// Makes the cascades' key textures match cascade maps of `size` texels a side.
    pub fn ensure_keys(&mut self, ctx: &GpuContext, size: u32) -> Result<()> {
        if self.keys.as_ref().is_some_and(|(s, ..)| *s == size) {
            return Ok(());
        }
        self.keys = None;
        let device = &ctx.device;
        let (array, views) =
            layered_target(ctx, "cascade tree keys", size, CASCADES as u32, KEY_FORMAT)?;
        let group = device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("reference sun maps"),
            layout: &self.reference_layout,
            entries: &[
                wgpu::BindGroupEntry {
                    binding: 2,
                    resource: self.lights.as_entire_binding(),
                },
                wgpu::BindGroupEntry {
                    binding: 3,
                    resource: wgpu::BindingResource::TextureView(&self.map_array),
                },
                wgpu::BindGroupEntry {
                    binding: 4,
                    resource: wgpu::BindingResource::TextureView(&array),
                },
            ],
        });
        self.keys = Some((size, views, group));
        Ok(())
    }

    /// The keyed cascade pipeline and cascade `c`'s key view to draw into (after
    /// [`Self::ensure_keys`]).
    pub fn cascade_keys(&self, c: usize) -> Option<(&wgpu::RenderPipeline, &wgpu::TextureView)> {
        let (_, views, _) = self.keys.as_ref()?;
        Some((&self.keyed_pipeline, views.get(c)?))
    }

    /// Writes the light matrix of every tree of the camera's `runs` (slots in the tree
    /// buffer, `trees` the world's tree index of each, per species as uploaded) seen from
    /// `to_sun`, each in the layer of its batch; the batches.
    pub fn write_lights(
        &self,
        ctx: &GpuContext,
        world: &WorldGpu,
        runs: &[TreeRun],
        trees: &[Vec<u32>],
        to_sun: Vec3,
    ) -> Vec<Vec<TreeRun>> {
        let top = runs.iter().map(|r| r.first + r.count).max().unwrap_or(0) as usize;
        let mut lights = vec![<SelfLightGpu as bytemuck::Zeroable>::zeroed(); top];
        let mut n = 0u32;
        for run in runs {
            let Some(list) = trees.get(run.species) else {
                continue;
            };
            for (i, &t) in list.iter().take(run.count as usize).enumerate() {
                let Some(b) = world.tree_bounds.get(t as usize) else {
                    continue;
                };
                let (m, texel) = tree_light(b, to_sun, self.size);
                lights[run.first as usize + i] = SelfLightGpu {
                    matrix: m.to_cols_array_2d(),
                    texel_world: texel,
                    layer: n % self.layers,
                    _pad0: 0,
                    _pad1: 0,
                };
                n += 1;
            }
        }
        let fits = (top * std::mem::size_of::<SelfLightGpu>()) as u64 <= self.lights.size();
        if fits && top > 0 {
            ctx.queue
                .write_buffer(&self.lights, 0, bytemuck::cast_slice(&lights));
        }
        batches(runs, self.layers)
    }

    /// Draws the maps of `batch`'s trees, one layer each in order, timed as one span,
    /// `tree sun maps`.
    pub fn encode_maps(
        &self,
        encoder: &mut wgpu::CommandEncoder,
        world: &WorldGpu,
        batch: &[TreeRun],
        spans: &PassSpans,
    ) -> u64 {
        let mut tris = 0;
        let one_by_one: Vec<TreeRun> = batch
            .iter()
            .flat_map(|r| {
                (0..r.count).map(move |i| TreeRun {
                    species: r.species,
                    first: r.first + i,
                    count: 1,
                })
            })
            .collect();
        let n = one_by_one.len().min(self.map_views.len());
        let span = spans.open("tree sun maps");
        for (i, (run, view)) in one_by_one.into_iter().zip(&self.map_views).enumerate() {
            let mut pass = encoder.begin_render_pass(&wgpu::RenderPassDescriptor {
                label: Some("per-tree sun map"),
                color_attachments: &[],
                depth_stencil_attachment: Some(wgpu::RenderPassDepthStencilAttachment {
                    view,
                    depth_ops: Some(wgpu::Operations {
                        load: wgpu::LoadOp::Clear(1.0),
                        store: wgpu::StoreOp::Store,
                    }),
                    stencil_ops: None,
                }),
                timestamp_writes: spans.render_writes(span, i == 0, i + 1 == n),
                occlusion_query_set: None,
                multiview_mask: None,
            });
            pass.set_bind_group(1, &world.trees_bind_group(), &[]);
            pass.set_bind_group(3, &self.lights_group, &[]);
            let (plain, cutout) = &self.map_pipelines;
            tris += world
                .draw_depth(
                    &mut pass,
                    &[run],
                    (plain, cutout),
                    false,
                    &super::world_gpu::ALL_PARTS,
                )
                .0;
        }
        tris
    }

    /// Draws the reference's trees into `target` (of `format`, over `depth`, after the
    /// frame's main pass): each of `batches` (from [`Self::write_lights`]) its trees' maps,
    /// then its trees, timed as `tree sun maps` and `reference trees` through `spans`.
    #[allow(clippy::too_many_arguments)]
    pub fn draw_trees(
        &self,
        encoder: &mut wgpu::CommandEncoder,
        world: &WorldGpu,
        frame_group: &wgpu::BindGroup,
        (target, format, depth): (&wgpu::TextureView, wgpu::TextureFormat, &DepthTarget),
        batches: &[Vec<TreeRun>],
        spans: &PassSpans,
        stats: &mut FrameStats,
    ) -> Result<()> {
        let Some((trees, group)) = self.pipelines(format) else {
            return Err(Error::Gpu(
                "the reference's tree pipelines were not built".into(),
            ));
        };
        for (i, batch) in batches.iter().enumerate() {
            stats.shadow_triangles += self.encode_maps(encoder, world, batch, spans);
            let last = i + 1 == batches.len();
            let mut pass = depth.color_pass(
                encoder,
                "reference trees",
                target,
                None,
                !last,
                spans.render_pass("reference trees"),
            );
            pass.set_bind_group(0, frame_group, &[]);
            pass.set_bind_group(1, &world.trees_bind_group(), &[]);
            pass.set_bind_group(3, group, &[]);
            let (tris, drawn, calls) = world.draw(
                &mut pass,
                batch,
                Some(trees),
                false,
                &super::world_gpu::ALL_PARTS,
            );
            stats.triangles += tris;
            stats.trees_drawn += drawn;
            stats.draw_calls += calls;
        }
        Ok(())
    }

    /// Drops the colour pipelines built so far.
    pub fn forget_pipelines(&mut self) {
        self.color.clear();
    }

    /// Builds the reference trees' pipelines for a target of `format`, once.
    pub fn ensure_pipelines(
        &mut self,
        ctx: &GpuContext,
        layouts: &Layouts,
        format: wgpu::TextureFormat,
    ) -> Result<()> {
        if !self.color.contains_key(&format) {
            let p = ctx.checked("building the reference's tree pipelines", || {
                reference_pipelines(&ctx.device, layouts, &self.reference_layout, format)
            })?;
            self.color.insert(format, p);
        }
        Ok(())
    }

    /// The reference trees' pipelines for a target of `format` and group 3 to bind with
    /// them; None before [`Self::ensure_pipelines`] and [`Self::ensure_keys`].
    pub fn pipelines(
        &self,
        format: wgpu::TextureFormat,
    ) -> Option<(MeshPipelines<'_>, &wgpu::BindGroup)> {
        let (opaque, foliage) = self.color.get(&format)?;
        let (_, _, group) = self.keys.as_ref()?;
        Some((MeshPipelines { opaque, foliage }, group))
    }
}

/// `geometry.wgsl`'s `fs_reference` as the opaque (back faces culled) and foliage
/// (two-sided) pipelines, with the reference's group 3.
fn reference_pipelines(
    device: &wgpu::Device,
    layouts: &Layouts,
    reference: &wgpu::BindGroupLayout,
    format: wgpu::TextureFormat,
) -> (wgpu::RenderPipeline, wgpu::RenderPipeline) {
    let pass = GeometryPass::new(device, layouts, "reference trees", Some(reference));
    let target = [Some(wgpu::ColorTargetState {
        format,
        blend: None,
        write_mask: wgpu::ColorWrites::ALL,
    })];
    let pipeline = |label: &str, cull_mode: Option<wgpu::Face>| {
        pass.pipeline(
            device,
            label,
            cull_mode,
            "fs_reference",
            &target,
            MeshDepth::TESTED,
        )
    };
    (
        pipeline("reference opaque", Some(wgpu::Face::Back)),
        pipeline("reference foliage", None),
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::mesh::Aabb;

    #[test]
    fn batches_keep_every_tree_once_in_order_and_no_batch_too_large() {
        let runs = [
            TreeRun {
                species: 0,
                first: 1,
                count: 5,
            },
            TreeRun {
                species: 2,
                first: 6,
                count: 9,
            },
        ];
        let b = batches(&runs, 4);
        assert_eq!(b.len(), 4);
        let mut slots = Vec::new();
        for batch in &b {
            assert!(batch.iter().map(|r| r.count).sum::<u32>() <= 4);
            for r in batch {
                let species = if r.first < 6 { 0 } else { 2 };
                assert_eq!(r.species, species, "{r:?}");
                slots.extend(r.first..r.first + r.count);
            }
        }
        assert_eq!(slots, (1..15).collect::<Vec<_>>());
        assert!(batches(&[], 4).is_empty());
    }

    #[test]
    fn the_map_array_stays_within_its_budget() {
        assert_eq!(layers_for(1024), SELF_MAP_LAYERS);
        assert_eq!(layers_for(4096), 8);
        assert_eq!(layers_for(8192), 2);
        for size in [16, 512, 2048, 4096, 8192, 16384] {
            let bytes = u64::from(size) * u64::from(size) * 4 * u64::from(layers_for(size));
            assert!(bytes <= SELF_MAP_BUDGET || layers_for(size) == 1, "{size}");
        }
    }

    #[test]
    fn a_trees_light_covers_its_bounds_at_the_asked_texel() {
        let b = Aabb {
            min: Vec3::new(10.0, 0.0, -3.0),
            max: Vec3::new(16.0, 20.0, 3.0),
        };
        let sun = crate::scene::sun_direction(135.0, 35.0);
        let (m, texel) = tree_light(&b, sun, 1024);
        let r = 0.5 * b.extent().length();
        assert!((texel - 2.0 * r / 1024.0).abs() < 1e-6);
        for c in b.corners() {
            let p = m.project_point3(c);
            assert!(p.x.abs() <= 1.0 && p.y.abs() <= 1.0, "{c} -> {p}");
            assert!((0.0..=1.0).contains(&p.z), "{c} -> {p}");
        }
    }
}
