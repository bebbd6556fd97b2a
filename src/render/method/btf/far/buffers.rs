//! The far trees' sized buffers: their growth to a frame's needs, their shrinking once a
//! window of frames needed far less, and the bind groups over them.

use super::super::billboard::BillboardGpu;
use super::{FarGpu, SortStepGpu, sort_steps};
use crate::Result;
use crate::render::GpuContext;

/// A record buffer is given back only above this size.
const SHRINK_MIN_BYTES: u64 = 4 << 20;

/// The frames and the seconds a window of [`ShrinkWindow`] spans, both at least.
const SHRINK_FRAMES: u32 = 8;
const SHRINK_SECONDS: f64 = 5.0;

/// The most slots each record buffer needed over a window of frames (near records in
/// their two bindings, records, sorted): a larger frame's buffers are given back once a
/// whole window needed a quarter of them or less.
pub(super) struct ShrinkWindow {
    began: std::time::Instant,
    frames: u32,
    peak: [u64; 4],
    /// The window's length, at least (frames, seconds), and the smallest buffer given
    /// back.
    frames_min: u32,
    seconds_min: f64,
    min_bytes: u64,
}

impl ShrinkWindow {
    pub(super) fn new() -> Self {
        Self {
            began: std::time::Instant::now(),
            frames: 0,
            peak: [0; 4],
            frames_min: SHRINK_FRAMES,
            seconds_min: SHRINK_SECONDS,
            min_bytes: SHRINK_MIN_BYTES,
        }
    }

    /// Adds a frame's needs; at the window's end returns its peaks and begins the next.
    fn observe(&mut self, needs: [u64; 4]) -> Option<[u64; 4]> {
        for (p, n) in self.peak.iter_mut().zip(needs) {
            *p = (*p).max(n);
        }
        self.frames += 1;
        if self.frames < self.frames_min || self.began.elapsed().as_secs_f64() < self.seconds_min {
            return None;
        }
        let peak = self.peak;
        self.began = std::time::Instant::now();
        self.frames = 0;
        self.peak = [0; 4];
        Some(peak)
    }
}

impl FarGpu {
    /// Grows the buffers for a frame of `near` records made on the CPU (after the trees'
    /// slots), `expanded` slots of `near_build` and `draws` near draws (after the shades
    /// and bits), and the sort's keys and steps to them all, rebinding what changed.
    pub(super) fn reserve(
        &mut self,
        ctx: &GpuContext,
        near: u64,
        expanded: u64,
        draws: u64,
    ) -> Result<()> {
        let slots = self.tree_count as u64 + near;
        let total = slots + expanded;
        let keys = u32::try_from(total.max(2))
            .ok()
            .and_then(u32::checked_next_power_of_two)
            .ok_or_else(|| crate::Error::Gpu("too many billboards to sort".into()))?;
        let sorted = total.min(self.limit);
        let words = u64::from(self.base.draws_at) + 4 * draws;
        let [first, second] = self.near_split(expanded);
        let needs = [first, second, slots, sorted];
        let shrunk = match self.shrink.observe(needs) {
            Some(peak) => self.shrink_to(ctx, peak)?,
            None => false,
        };
        if !shrunk
            && slots <= self.record_slots
            && first <= self.near_slots[0]
            && second <= self.near_slots[1]
            && keys <= self.key_slots
            && sorted <= self.sorted_slots
            && words <= self.frame_word_slots
        {
            return Ok(());
        }
        let max_words = ctx.device.limits().max_storage_buffer_binding_size / 4;
        if words > self.frame_word_slots {
            self.grow_frame_words(ctx, (words, draws), max_words)?;
        }
        for (k, need) in needs.into_iter().enumerate() {
            if need > self.record_buffer_slots(k) {
                self.set_record_buffer(ctx, k, need)?;
            }
        }
        if keys > self.key_slots {
            self.grow_keys(ctx, keys)?;
        }
        self.rebind(ctx);
        Ok(())
    }

    /// Makes the frame words anew with room for `words` (of which `draws` near draws) and
    /// more, within `max_words`, and copies the shades and bits already written this frame.
    fn grow_frame_words(
        &mut self,
        ctx: &GpuContext,
        (words, draws): (u64, u64),
        max_words: u64,
    ) -> Result<()> {
        use wgpu::BufferUsages as U;
        let word_slots = (u64::from(self.base.draws_at) + 4 * grow_slots(draws))
            .min(max_words)
            .max(words);
        let bigger = ctx.checked("allocating the near draws' buffer", || {
            buffer(
                ctx,
                "far frame words",
                word_slots * 4,
                U::STORAGE | U::COPY_DST | U::COPY_SRC,
            )
        })?;
        // The shades and bits already written this frame come along.
        let mut encoder = ctx
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                label: Some("far frame words"),
            });
        encoder.copy_buffer_to_buffer(&self.frame_words, 0, &bigger, 0, self.frame_word_slots * 4);
        ctx.queue.submit([encoder.finish()]);
        self.frame_words = bigger;
        self.frame_word_slots = word_slots;
        Ok(())
    }

    /// Makes the sort's keys anew for `keys` (a power of two), and its steps for them.
    fn grow_keys(&mut self, ctx: &GpuContext, keys: u32) -> Result<()> {
        use wgpu::BufferUsages as U;
        let steps_list = sort_steps(keys);
        let mut step_bytes =
            vec![0u8; (steps_list.len().max(1) as u64 * self.step_stride) as usize];
        for (i, &(k, j)) in steps_list.iter().enumerate() {
            let at = i * self.step_stride as usize;
            let s = SortStepGpu { k, j, _pad: [0; 2] };
            step_bytes[at..at + std::mem::size_of::<SortStepGpu>()]
                .copy_from_slice(bytemuck::bytes_of(&s));
        }
        let (keys_buf, steps) = ctx.checked("allocating the sort's keys", || {
            (
                buffer(
                    ctx,
                    "far keys",
                    u64::from(keys) * 8,
                    U::STORAGE | U::COPY_DST,
                ),
                wgpu::util::DeviceExt::create_buffer_init(
                    &ctx.device,
                    &wgpu::util::BufferInitDescriptor {
                        label: Some("far sort steps"),
                        contents: &step_bytes,
                        usage: U::UNIFORM,
                    },
                ),
            )
        })?;
        self.keys = keys_buf;
        self.steps = steps;
        self.key_slots = keys;
        Ok(())
    }

    /// Makes the three bind groups anew over the buffers held now.
    fn rebind(&mut self, ctx: &GpuContext) {
        let (bind_group, step_bind_group, draw_bind_group) = bind_groups(
            ctx,
            [&self.layouts[0], &self.layouts[1], &self.draw_layout],
            [
                &self.params,
                &self.near_records[1],
                &self.tables,
                &self.canopy_colours,
            ],
            [
                &self.near_records[0],
                &self.frame_words,
                &self.records,
                &self.keys,
                &self.draw_args,
                &self.sorted,
            ],
            &self.steps,
            &self.draw_resources,
        );
        self.bind_group = bind_group;
        self.step_bind_group = step_bind_group;
        self.draw_bind_group = draw_bind_group;
    }

    /// Replaces the record buffers whose slots pass four times what the last window of
    /// frames needed at most (`peak`, in the order of [`ShrinkWindow::observe`]) by ones
    /// sized to that peak; true if any was. Each frame writes them whole before reading,
    /// so nothing is copied.
    fn shrink_to(&mut self, ctx: &GpuContext, peak: [u64; 4]) -> Result<bool> {
        let record = std::mem::size_of::<BillboardGpu>() as u64;
        let mut shrunk = false;
        for (k, peak) in peak.into_iter().enumerate() {
            let slots = self.record_buffer_slots(k);
            if slots * record >= self.shrink.min_bytes && slots > 4 * grow_slots(peak) {
                self.set_record_buffer(ctx, k, peak)?;
                shrunk = true;
            }
        }
        if shrunk {
            log::debug!(
                "btf: far trees' record buffers shrunk to {} MB",
                self.bytes() as f64 / 1e6
            );
        }
        Ok(shrunk)
    }

    /// The slots of record buffer `k`: the near records' two bindings, the records, the
    /// sorted ones.
    fn record_buffer_slots(&self, k: usize) -> u64 {
        match k {
            0 | 1 => self.near_slots[k],
            2 => self.record_slots,
            _ => self.sorted_slots,
        }
    }

    /// Makes record buffer `k` (as [`Self::record_buffer_slots`]) anew with room for
    /// `need` slots and half as much again, within one binding's records.
    fn set_record_buffer(&mut self, ctx: &GpuContext, k: usize, need: u64) -> Result<()> {
        use wgpu::BufferUsages as U;
        let record = std::mem::size_of::<BillboardGpu>() as u64;
        let room = if k < 2 { self.near_room } else { self.limit };
        let slots = grow_slots(need).min(room.max(need));
        let (what, label, usage) = match k {
            0 | 1 => ("the near trees' records", "near records", U::STORAGE),
            2 => (
                "the billboards' records",
                "far records",
                U::STORAGE | U::COPY_DST,
            ),
            _ => (
                "the sorted billboards",
                "far sorted",
                U::STORAGE | U::COPY_SRC,
            ),
        };
        let made = ctx.checked(&format!("allocating {what}"), || {
            buffer(ctx, label, slots * record, usage)
        })?;
        match k {
            0 | 1 => {
                self.near_records[k] = made;
                self.near_slots[k] = slots;
            }
            2 => {
                self.records = made;
                self.record_slots = slots;
            }
            _ => {
                self.sorted = made;
                self.sorted_slots = slots;
            }
        }
        Ok(())
    }

    /// The slots of `expanded` near billboards each binding takes: the first `near_room`,
    /// the second the rest.
    fn near_split(&self, expanded: u64) -> [u64; 2] {
        [
            expanded.min(self.near_room),
            expanded.saturating_sub(self.near_room),
        ]
    }

    /// Most billboards `near_build` can expand in one frame (two storage bindings'
    /// records).
    pub fn expand_limit(&self) -> u64 {
        2 * self.near_room
    }

    /// Gives the first binding of the near records room for `slots` only (tests: the
    /// second binding then takes the rest without frames of 524,288 slots).
    #[cfg(test)]
    pub(crate) fn set_near_room(&mut self, slots: u64) {
        self.near_room = slots.clamp(1, self.limit);
        self.base.near_room = self.near_room as u32;
    }

    /// Grows the record buffers for `expanded` near slots, and ends the window of frames
    /// that gives them back at every frame, for any size (tests).
    #[cfg(test)]
    pub(crate) fn grow_then_shrink_each_frame(&mut self, ctx: &GpuContext, expanded: u64) {
        self.reserve(ctx, 0, expanded, 0).unwrap();
        self.shrink.frames_min = 1;
        self.shrink.seconds_min = 0.0;
        self.shrink.min_bytes = 0;
        self.shrink.peak = [0; 4];
    }
}

/// Slots for `n` and half as much again, so that a growing frame does not rebind every
/// time.
pub(super) fn grow_slots(n: u64) -> u64 {
    (n + n / 2).max(1024)
}

pub(super) fn buffer(
    ctx: &GpuContext,
    label: &str,
    size: u64,
    usage: wgpu::BufferUsages,
) -> wgpu::Buffer {
    ctx.device.create_buffer(&wgpu::BufferDescriptor {
        label: Some(label),
        size: size.max(16),
        usage,
        mapped_at_creation: false,
    })
}

/// The compute bind groups (fixed buffers: params, trees, tables; sized ones: near records,
/// frame words, records, keys, draw arguments, sorted), the sort step's, and the draw's.
pub(super) fn bind_groups(
    ctx: &GpuContext,
    layouts: [&wgpu::BindGroupLayout; 3],
    fixed: [&wgpu::Buffer; 4],
    sized: [&wgpu::Buffer; 6],
    steps: &wgpu::Buffer,
    draw: &(wgpu::Buffer, wgpu::TextureView, wgpu::Sampler),
) -> (wgpu::BindGroup, wgpu::BindGroup, wgpu::BindGroup) {
    let compute = ctx.device.create_bind_group(&wgpu::BindGroupDescriptor {
        label: Some("btf far"),
        layout: layouts[0],
        entries: &[
            entry(0, fixed[0]),
            entry(1, fixed[1]),
            entry(2, sized[0]),
            entry(3, fixed[2]),
            entry(4, sized[1]),
            entry(5, sized[2]),
            entry(6, sized[3]),
            entry(7, sized[4]),
            entry(8, sized[5]),
            entry(9, fixed[3]),
        ],
    });
    let step = ctx.device.create_bind_group(&wgpu::BindGroupDescriptor {
        label: Some("btf far sort step"),
        layout: layouts[1],
        entries: &[wgpu::BindGroupEntry {
            binding: 0,
            resource: wgpu::BindingResource::Buffer(wgpu::BufferBinding {
                buffer: steps,
                offset: 0,
                size: wgpu::BufferSize::new(std::mem::size_of::<SortStepGpu>() as u64),
            }),
        }],
    });
    let billboards = ctx.device.create_bind_group(&wgpu::BindGroupDescriptor {
        label: Some("btf far billboards"),
        layout: layouts[2],
        entries: &[
            entry(0, sized[5]),
            entry(1, &draw.0),
            wgpu::BindGroupEntry {
                binding: 2,
                resource: wgpu::BindingResource::TextureView(&draw.1),
            },
            wgpu::BindGroupEntry {
                binding: 3,
                resource: wgpu::BindingResource::Sampler(&draw.2),
            },
        ],
    });
    (compute, step, billboards)
}

pub(super) fn entry(binding: u32, b: &wgpu::Buffer) -> wgpu::BindGroupEntry<'_> {
    wgpu::BindGroupEntry {
        binding,
        resource: b.as_entire_binding(),
    }
}
