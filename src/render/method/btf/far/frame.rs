//! A frame of the far trees: finding the near trees for the CPU, taking their records and
//! draws, the compute passes, and the draws of the sorted billboards.

use super::super::billboard::{BillboardGpu, BillboardMode};
use super::super::prepare::{BtfScene, NearDrawGpu, PrepareView, SortedBillboards};
use super::super::settings::{BtfSettings, PlaneMode};
use super::readback::read_buffer;
use super::{
    CANOPY_BAND, CanopyFrame, DRAW_WORDS, FarGpu, FarParamsGpu, FarShadeGpu, SORT_ARGS_AT,
    WORKGROUP, layer_batches, sort_steps,
};
use crate::Result;
use crate::model::Level;
use crate::model::mesh::Aabb;
use crate::render::GpuContext;
use crate::render::timing::PassSpans;
use crate::render::vcm_shading::VcmShading;
use crate::render::world_gpu::TreeGpu;

impl FarGpu {
    /// The frame's near trees in view, per species in tree order, for the CPU to prepare;
    /// every other tree is left to the GPU. Uploads the near trees' bits, and the trees'
    /// VCM factors when the sun moved since the last upload (the milliseconds spent on
    /// those are returned too: the sun update's share). With `trees_on` false there are no
    /// trees at all. [`Self::upload_near`] then takes the near trees' records.
    #[allow(clippy::too_many_arguments)]
    pub fn prepare(
        &mut self,
        ctx: &GpuContext,
        scene: &BtfScene,
        trees: &[TreeGpu],
        bounds: &[Aabb],
        view: &PrepareView,
        settings: &BtfSettings,
        trees_on: bool,
        canopy: Option<&CanopyFrame>,
    ) -> (Vec<Vec<u32>>, f64) {
        self.frame = None;
        self.pending = None;
        self.canopy_band = None;
        let mut near = vec![Vec::new(); scene.species_count()];
        let count = self.tree_count as u32;
        if !trees_on || count == 0 {
            return (near, 0.0);
        }
        // The near trees: those in the grid's cells within the near radius, by the exact
        // test; their bits are set whether in view or not (the GPU skips them all).
        let bound = BtfScene::far_bound(settings);
        let radius = scene.near_radius(view.focal_px, bound, self.max_scale);
        // The canopy starts where a typical crown is narrower than its pixel bound on
        // screen, and never among the near trees, which the CPU prepares.
        let band = canopy.and_then(|c| {
            let near = (c.crown_width * view.focal_px / c.below_px).max(radius);
            (near.is_finite() && near > 0.0).then_some((near, near * (1.0 + CANOPY_BAND)))
        });
        self.canopy_band = band;
        let mut bits = vec![0u32; self.tree_count.div_ceil(32).max(1)];
        let cam = view.camera.position;
        self.grid.for_each_near(cam, radius, |t| {
            let i = t as usize;
            let (Some(&sp), Some(data)) = (self.species.get(i), trees.get(i)) else {
                return;
            };
            if scene.is_near(sp as usize, data, view, bound) {
                bits[i / 32] |= 1 << (i % 32);
                if let (Some(list), Some(b)) = (near.get_mut(sp as usize), bounds.get(i))
                    && view.frustum.intersects(b)
                {
                    list.push(t);
                }
            }
        });
        for list in &mut near {
            list.sort_unstable();
        }
        let vcm = scene.vcm().filter(|_| settings.vcm);
        let mut shade_ms = 0.0;
        if let Some(v) = vcm
            && (self.shade_sun.is_none() || self.shade_sun != v.sun())
        {
            shade_ms = self.upload_shades(ctx, v);
        }
        let mut planes = [[0.0f32; 4]; 6];
        for (p, q) in planes.iter_mut().zip(&view.frustum.planes) {
            *p = q.to_array();
        }
        let (overlay, mode) = settings
            .overlay(Level::Tree)
            .unwrap_or(([1.0; 3], BillboardMode::Images));
        let overlay_of = |l| settings.overlay(l).map_or([1.0; 3], |o| o.0);
        self.pending = Some(FarParamsGpu {
            camera: cam.to_array(),
            count,
            forward: view.camera.forward().to_array(),
            plane_count: view.frustum.planes.len().min(6) as u32,
            to_sun: view.to_sun.to_array(),
            weight_threshold: settings.weight_threshold,
            planes,
            overlay,
            mode: mode as u32,
            overlay_twig: overlay_of(Level::Twig),
            overlay_branch: overlay_of(Level::Branch),
            light_gain: settings.light_gain,
            plane_mode: match settings.planes {
                PlaneMode::Single => 1,
                PlaneMode::Crossed => 3,
            },
            vcm: match vcm {
                None => 0,
                Some(_) if settings.vcm_sky => 1,
                Some(_) => 2,
            },
            light_bins: if settings.light_blend {
                scene.light_bins()
            } else {
                0
            },
            canopy_near: band.map_or(0.0, |b| b.0),
            canopy_far: band.map_or(0.0, |b| b.1),
            sun_color: canopy.map_or([0.0; 3], |c| c.lights[0].to_array()),
            sky_ambient: canopy.map_or([0.0; 3], |c| c.lights[1].to_array()),
            ground_ambient: canopy.map_or([0.0; 3], |c| c.lights[2].to_array()),
            layer_batches: layer_batches(settings, ctx.indirect_first_instance),
            ..self.base
        });
        self.bits = bits;
        (near, shade_ms)
    }

    /// Uploads every tree's VCM factors for the sun of `v`; the milliseconds it took.
    fn upload_shades(&mut self, ctx: &GpuContext, v: &VcmShading) -> f64 {
        let t0 = std::time::Instant::now();
        let shades: Vec<FarShadeGpu> = v
            .tree_factors(self.tree_count)
            .map(|(d, s)| FarShadeGpu {
                direct: [[d[0], d[1], d[2], d[3]], [d[4], d[5], d[6], d[7]]],
                sky: [[s[0], s[1], s[2], s[3]], [s[4], s[5], s[6], s[7]]],
            })
            .collect();
        ctx.queue
            .write_buffer(&self.frame_words, 0, bytemuck::cast_slice(&shades));
        self.shade_sun = v.sun();
        t0.elapsed().as_secs_f64() * 1e3
    }

    /// Takes the near trees' records made on the CPU (in any order: they are sorted with
    /// the far ones) and the near draws for `near_build` to expand into `draw_slots`
    /// billboards, and readies the frame's passes; false (and no frame) when the trees'
    /// slots and the CPU's records do not fit one storage binding, the expanded ones two
    /// ([`Self::expand_limit`]), or [`Self::prepare`] found no trees.
    pub fn upload_near(
        &mut self,
        ctx: &GpuContext,
        near: &SortedBillboards,
        draws: &[NearDrawGpu],
        draw_slots: u64,
    ) -> Result<bool> {
        let Some(mut params) = self.pending.take() else {
            return Ok(false);
        };
        let near_count = near.len() as u64;
        let slots = self.tree_count as u64 + near_count;
        let total = slots + draw_slots;
        // One binding's records each (the trees' and the CPU's, and those expanded), and
        // one dispatch's workgroups over the sort's keys and over the expanded slots.
        let groups = total
            .max(2)
            .next_power_of_two()
            .div_ceil(u64::from(WORKGROUP))
            .max(draw_slots.div_ceil(u64::from(WORKGROUP)));
        let draw_words = u64::from(self.base.draws_at) + 4 * draws.len() as u64;
        if slots > self.limit
            || draw_slots > self.expand_limit()
            || groups > u64::from(self.max_groups)
            || draw_words * 4 > ctx.device.limits().max_storage_buffer_binding_size
        {
            log::debug!(
                "the GPU cannot take this frame's billboards: {slots} slots of trees and CPU \
                 records, {draw_slots} to expand ({} draws), {groups} workgroups; one binding \
                 holds {} records, the expanded ones {}, one dispatch {} workgroups",
                draws.len(),
                self.limit,
                self.expand_limit(),
                self.max_groups
            );
            return Ok(false);
        }
        self.reserve(ctx, near_count, draw_slots, draws.len() as u64)?;
        let record = std::mem::size_of::<BillboardGpu>() as u64;
        if let Some(size) = wgpu::BufferSize::new(near_count * record)
            && let Some(mut view) =
                ctx.queue
                    .write_buffer_with(&self.records, self.tree_count as u64 * record, size)
        {
            near.write_unsorted(view.slice(..));
        }
        ctx.queue.write_buffer(
            &self.frame_words,
            u64::from(self.base.bits_at) * 4,
            bytemuck::cast_slice(&self.bits),
        );
        if !draws.is_empty() {
            ctx.queue.write_buffer(
                &self.frame_words,
                u64::from(self.base.draws_at) * 4,
                bytemuck::cast_slice(draws),
            );
        }
        let keys = total.max(2).next_power_of_two() as u32;
        params.near_count = near_count as u32;
        params.near_draws = draws.len() as u32;
        params.near_slots = draw_slots as u32;
        params.sort_n = keys;
        params.limit = self.sorted_slots.min(self.limit) as u32;
        ctx.queue
            .write_buffer(&self.params, 0, bytemuck::bytes_of(&params));
        ctx.queue.write_buffer(
            &self.draw_args,
            0,
            bytemuck::cast_slice(&[6u32, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0]),
        );
        ctx.queue
            .write_buffer(&self.draw_args, SORT_ARGS_AT * 4, bytemuck::bytes_of(&0u32));
        self.frame = Some((keys, total as u32, draw_slots as u32));
        self.batches = params.layer_batches;
        Ok(true)
    }

    /// The frame's compute passes (timed through `spans`): `far trees` builds the far
    /// records and keys the near ones; `far sort` sorts them, gathers them and sets the
    /// draw's count. Nothing without a frame.
    pub fn encode(&self, encoder: &mut wgpu::CommandEncoder, spans: &PassSpans) {
        let Some((keys, slots, expanded)) = self.frame else {
            return;
        };
        let trees = self.tree_count as u32;
        encoder.clear_buffer(&self.keys, 0, Some(u64::from(keys) * 8));
        let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
            label: Some("btf far trees"),
            timestamp_writes: spans.compute_pass("far trees"),
        });
        pass.set_bind_group(0, &self.bind_group, &[]);
        pass.set_bind_group(1, &self.step_bind_group, &[0]);
        pass.set_pipeline(&self.build);
        pass.dispatch_workgroups(trees.div_ceil(WORKGROUP), 1, 1);
        if expanded > 0 {
            pass.set_pipeline(&self.near_build);
            pass.dispatch_workgroups(expanded.div_ceil(WORKGROUP), 1, 1);
        }
        let made_here = slots - trees - expanded;
        if made_here > 0 {
            pass.set_pipeline(&self.near_keys);
            pass.dispatch_workgroups(made_here.div_ceil(WORKGROUP), 1, 1);
        }
        drop(pass);
        // The keys are packed at the start; the sort runs over the next power of two
        // above their count, its dispatches sized on the GPU.
        let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
            label: Some("btf far sort"),
            timestamp_writes: spans.compute_pass("far sort"),
        });
        pass.set_bind_group(0, &self.bind_group, &[]);
        pass.set_pipeline(&self.sort_plan);
        pass.set_bind_group(1, &self.plan_bind_group, &[]);
        pass.dispatch_workgroups(1, 1, 1);
        pass.set_pipeline(&self.sort);
        for (i, _) in sort_steps(keys).iter().enumerate() {
            let offset = (i as u64 * self.step_stride) as u32;
            pass.set_bind_group(1, &self.step_bind_group, &[offset]);
            pass.dispatch_workgroups_indirect(&self.sort_args, 12 * i as u64);
        }
        pass.set_bind_group(1, &self.step_bind_group, &[0]);
        pass.set_pipeline(&self.gather);
        pass.dispatch_workgroups(slots.div_ceil(WORKGROUP), 1, 1);
        pass.set_pipeline(&self.finish);
        pass.dispatch_workgroups(1, 1, 1);
        drop(pass);
        self.count.copy(encoder, &self.draw_args);
    }

    /// After the frame's submission: how many billboards were made, by the latest frame
    /// read back (this one's when `wait`, blocking): the far trees', then the near trees'
    /// expanded here per level (twig, main branch, tree), then their image fetches per
    /// pixel summed and the fetches image-weight culling saved; None before any.
    pub fn drawn(&self, ctx: &GpuContext, wait: bool) -> Option<[u32; 8]> {
        self.count.collect(ctx, wait)
    }

    /// Draws every billboard of the frame, sorted (the btf pipeline already set).
    pub fn draw(&self, pass: &mut wgpu::RenderPass<'_>) -> bool {
        if self.frame.is_none() {
            return false;
        }
        pass.set_bind_group(1, &self.draw_bind_group, &[]);
        pass.draw_indirect(&self.draw_args, 0);
        true
    }

    /// Reads the last frame's sorted records back, back to front (for tests; blocking).
    pub fn read_sorted(&self, ctx: &GpuContext) -> Result<Vec<BillboardGpu>> {
        if self.frame.is_none() {
            return Ok(Vec::new());
        }
        let args = read_buffer(ctx, &self.draw_args, 16)?;
        let made = u64::from(u32::from_le_bytes([args[4], args[5], args[6], args[7]]));
        let record = std::mem::size_of::<BillboardGpu>() as u64;
        let bytes = read_buffer(ctx, &self.sorted, made * record)?;
        let mut records: Vec<BillboardGpu> = bytemuck::pod_collect_to_vec(&bytes);
        if self.layer_batches() > 0 {
            records.reverse();
        }
        Ok(records)
    }

    /// Records the sorted buffer may hold this frame.
    pub fn sorted_capacity(&self) -> u64 {
        self.sorted_slots.min(self.limit)
    }

    /// The sorted records for the tile compositor: their bind group (the btf pass's), and
    /// the buffer and word holding their count; None without a frame.
    pub fn compositor_records(&self) -> Option<(&wgpu::BindGroup, &wgpu::Buffer, u32)> {
        self.frame.as_ref()?;
        Some((&self.draw_bind_group, &self.draw_args, 1))
    }

    /// The batches this frame's billboards are drawn in, front to back, into the trees'
    /// layer (0: one draw, back to front over the frame).
    pub fn layer_batches(&self) -> u32 {
        self.batches
    }

    /// Draws batch `k` of [`Self::layer_batches`] (the btf pipeline for the layer already
    /// set).
    pub fn draw_batch(&self, pass: &mut wgpu::RenderPass<'_>, k: u32) {
        if self.frame.is_none() || k >= self.layer_batches() {
            return;
        }
        pass.set_bind_group(1, &self.draw_bind_group, &[]);
        pass.draw_indirect(&self.draw_args, (DRAW_WORDS + 4 * u64::from(k)) * 4);
    }
}
