//! The tile compositor: a frame's billboards composited in compute, by screen tiles, front
//! to back, instead of rasterised (`shaders/compositor.wgsl`).
//!
//! The raster path draws every billboard's quad: over the example forest that is 64
//! fragments a pixel, and on a CPU rasteriser setting up those tiny quads is itself most of
//! the frame. Here a `setup` pass finds each billboard's pixel rectangle and sets its bit in
//! each 16x16-pixel tile that rectangle meets (a bit per billboard per tile: each tile's
//! list comes out in the billboards' order, front to back, without a sort), and one
//! workgroup per tile goes through its bits in order and composites each billboard "under"
//! at each pixel, in float, stopping a pixel where it lets through less than `stop_below`. The result goes
//! into the trees' layer ([`super::layer`]), which is then put over the frame as the raster
//! layer is: the same sum, without the rasteriser, shading only what is seen.
//!
//! The billboards are any buffer of billboard records bound as the `btf` pass binds them
//! (group 1, `billboard.wgsl`), with their count in a word of a storage buffer: the CPU's
//! sorted records (the count written here) or the far trees' sorted records on the GPU (the
//! count their passes wrote).

use super::GpuContext;
use super::frame_bindings::DepthTarget;
use super::layer::{LAYER_FORMAT, TreeLayer};
use super::pipelines::{buffer_entry, storage_entry};
use super::timing::PassSpans;

/// Pixels on a tile's side (`TILE` in `compositor.wgsl`).
pub const TILE: u32 = 16;

/// The default [`CompositorSettings::stop_below`]: a pixel stops where what is behind it
/// would add less than 1/256 of its own colour (below one step of an 8-bit output).
pub const STOP_BELOW: f32 = 1.0 / 256.0;

/// The default [`CompositorKnobs::full_above`]: every layer in full (measured below).
pub const FULL_ABOVE: f32 = 0.0;

/// What the compositor's knobs ask of a frame.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CompositorKnobs {
    /// A pixel stops where it lets through less than this (0: never).
    pub stop_below: f32,
    /// Layers are shaded in full while the pixel lets through more than this, behind by
    /// their heaviest view sample alone (0: every layer in full).
    pub full_above: f32,
}

/// Words of the counters buffer (`COUNTER_*` in `compositor.wgsl`).
const COUNTER_WORDS: usize = 6;

/// What the composite counted in a frame (read back with [`Compositor::read_counters`]).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct CompositorCounters {
    /// Billboard layers shaded, summed over the pixels.
    pub layers: u32,
    /// Billboards tested at a pixel (those whose rectangle meets its tile), summed.
    pub tests: u32,
    /// Pixels that stopped before their tile's list ended.
    pub pixels_stopped: u32,
    /// Tiles all of whose pixels stopped before their list ended.
    pub tiles_stopped: u32,
    /// Tiles composited (each tile once).
    pub tiles: u32,
}

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct ParamsGpu {
    size: [u32; 2],
    tiles: [u32; 2],
    stop_below: f32,
    count_word: u32,
    capacity: u32,
    full_above: f32,
    _pad: [u32; 3],
    words: u32,
}

/// Where a frame's billboards are: their bind group (group 1 of the `btf` pass), the
/// buffer and word that hold their count, and the most there may be.
pub struct CompositorInput<'a> {
    pub records: &'a wgpu::BindGroup,
    pub count: (&'a wgpu::Buffer, u32),
    pub max_records: u32,
}

/// The compositor's pipelines and buffers (the per-billboard rectangles grow with the
/// frames).
pub struct Compositor {
    /// Group 2 of `setup` (the tile bits written) and of `composite` (read).
    layouts: [wgpu::BindGroupLayout; 2],
    setup: wgpu::ComputePipeline,
    composite: wgpu::ComputePipeline,
    params: wgpu::Buffer,
    counters: wgpu::Buffer,
    /// The count of the CPU's records ([`Self::set_cpu_count`]).
    cpu_count: wgpu::Buffer,
    rects: wgpu::Buffer,
    rect_capacity: u64,
    /// A bit per billboard per tile, grown as frames need (None before the first).
    tile_bits: std::sync::Mutex<Option<wgpu::Buffer>>,
}

/// Bytes of the tile bits: `capacity` bits, in whole words, and their summary (a bit per
/// word), for each tile.
fn tile_bits_bytes(tiles: [u32; 2], capacity: u32) -> u64 {
    let words = u64::from(capacity.div_ceil(32));
    u64::from(tiles[0]) * u64::from(tiles[1]) * (words + words.div_ceil(32)) * 4
}

impl Compositor {
    /// The compositor over billboards bound as `records_layout` describes (group 1), with
    /// the frame's group 0 (`frame_layout`).
    pub fn new(
        device: &wgpu::Device,
        frame_layout: &wgpu::BindGroupLayout,
        records_layout: &wgpu::BindGroupLayout,
    ) -> Self {
        let compute = wgpu::ShaderStages::COMPUTE;
        let rw = wgpu::BufferBindingType::Storage { read_only: false };
        let shared = [
            buffer_entry(0, compute, wgpu::BufferBindingType::Uniform),
            storage_entry(1, compute),
            buffer_entry(2, compute, rw),
            wgpu::BindGroupLayoutEntry {
                binding: 3,
                visibility: compute,
                ty: wgpu::BindingType::Texture {
                    sample_type: wgpu::TextureSampleType::Depth,
                    view_dimension: wgpu::TextureViewDimension::D2,
                    multisampled: false,
                },
                count: None,
            },
            wgpu::BindGroupLayoutEntry {
                binding: 4,
                visibility: compute,
                ty: wgpu::BindingType::StorageTexture {
                    access: wgpu::StorageTextureAccess::WriteOnly,
                    format: LAYER_FORMAT,
                    view_dimension: wgpu::TextureViewDimension::D2,
                },
                count: None,
            },
            buffer_entry(5, compute, rw),
        ];
        // The tile bits: written (atomically) by `setup`, read by `composite`.
        let layout_with = |bits: wgpu::BindGroupLayoutEntry| {
            let mut entries = shared.to_vec();
            entries.push(bits);
            device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
                label: Some("compositor"),
                entries: &entries,
            })
        };
        let layouts = [
            layout_with(buffer_entry(6, compute, rw)),
            layout_with(storage_entry(7, compute)),
        ];
        let module =
            super::pipelines::wgsl_module(device, "compositor.wgsl", &super::shaders::compositor());
        let pipeline = |entry: &str, layout: &wgpu::BindGroupLayout| {
            let pipeline_layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
                label: Some("compositor"),
                bind_group_layouts: &[Some(frame_layout), Some(records_layout), Some(layout)],
                immediate_size: 0,
            });
            device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
                label: Some(entry),
                layout: Some(&pipeline_layout),
                module: &module,
                entry_point: Some(entry),
                compilation_options: super::shaders::frame_options(),
                cache: None,
            })
        };
        let setup = pipeline("setup", &layouts[0]);
        let composite = pipeline("composite", &layouts[1]);
        let buffer = |label: &str, size: u64, usage: wgpu::BufferUsages| {
            device.create_buffer(&wgpu::BufferDescriptor {
                label: Some(label),
                size,
                usage,
                mapped_at_creation: false,
            })
        };
        use wgpu::BufferUsages as U;
        let params = buffer(
            "compositor params",
            std::mem::size_of::<ParamsGpu>() as u64,
            U::UNIFORM | U::COPY_DST,
        );
        let counters = buffer(
            "compositor counters",
            (COUNTER_WORDS * 4) as u64,
            U::STORAGE | U::COPY_DST | U::COPY_SRC,
        );
        let cpu_count = buffer("compositor count", 4, U::STORAGE | U::COPY_DST);
        let rects = buffer("compositor rects", 8, U::STORAGE);
        Self {
            layouts,
            setup,
            composite,
            params,
            counters,
            cpu_count,
            rects,
            rect_capacity: 1,
            tile_bits: std::sync::Mutex::new(None),
        }
    }

    /// The buffer holding the count of records the CPU sorted, after writing `count` to it.
    pub fn set_cpu_count(&self, ctx: &GpuContext, count: u32) -> &wgpu::Buffer {
        ctx.queue
            .write_buffer(&self.cpu_count, 0, bytemuck::bytes_of(&count));
        &self.cpu_count
    }

    /// Makes room for `records` billboards' rectangles (none past the GPU's limits: the
    /// farthest are then left out, as the raster path's buffers leave them out).
    pub fn reserve(&mut self, ctx: &GpuContext, records: u64) {
        let limits = ctx.device.limits();
        let most = limits
            .max_storage_buffer_binding_size
            .min(limits.max_buffer_size)
            / 8;
        let want = records.clamp(1, most.max(1));
        if want > self.rect_capacity {
            let capacity = (want * 3 / 2).min(most.max(1));
            self.rects = ctx.device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("compositor rects"),
                size: capacity * 8,
                usage: wgpu::BufferUsages::STORAGE,
                mapped_at_creation: false,
            });
            self.rect_capacity = capacity;
        }
    }

    /// The tile bits, grown to `need` bytes if they are smaller; None (with the reason
    /// logged) where the GPU cannot hold them.
    fn tile_bits(&self, ctx: &GpuContext, need: u64) -> Option<wgpu::Buffer> {
        let mut bits = self.tile_bits.lock().unwrap_or_else(|e| e.into_inner());
        if bits.as_ref().is_none_or(|b| b.size() < need) {
            let limits = ctx.device.limits();
            if need
                > limits
                    .max_storage_buffer_binding_size
                    .min(limits.max_buffer_size)
            {
                log::warn!(
                    "the tile compositor needs {need} bytes of tile bits, more than one GPU \
                     binding holds: no billboards drawn (turn it off, --compositor off, or \
                     draw a smaller image)"
                );
                return None;
            }
            let made = ctx.checked("allocating the compositor's tile bits", || {
                ctx.device.create_buffer(&wgpu::BufferDescriptor {
                    label: Some("compositor tile bits"),
                    size: need.max(4),
                    usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST,
                    mapped_at_creation: false,
                })
            });
            match made {
                Ok(b) => *bits = Some(b),
                Err(e) => {
                    log::warn!("{e}");
                    return None;
                }
            }
        }
        bits.clone()
    }

    /// Composites `input`'s billboards into `layer` against the frame's `depth`, then puts
    /// the layer over the frame's `target` (of `format`); timed as `tiles: setup`,
    /// `tiles: composite` and `billboards` (the layer over the frame).
    #[allow(clippy::too_many_arguments)]
    pub fn encode(
        &self,
        ctx: &GpuContext,
        encoder: &mut wgpu::CommandEncoder,
        frame_group: &wgpu::BindGroup,
        input: &CompositorInput<'_>,
        (depth, layer): (&DepthTarget, &TreeLayer),
        (target, format): (&wgpu::TextureView, wgpu::TextureFormat),
        knobs: CompositorKnobs,
        spans: &PassSpans,
    ) {
        let Some(layer_view) = layer.view() else {
            return;
        };
        let (width, height) = depth.size;
        let tiles = [width.div_ceil(TILE), height.div_ceil(TILE)];
        let capacity = (input.max_records as u64).min(self.rect_capacity) as u32;
        let bits_bytes = tile_bits_bytes(tiles, capacity);
        let Some(bits) = self.tile_bits(ctx, bits_bytes) else {
            return;
        };
        let params = ParamsGpu {
            size: [width, height],
            tiles,
            stop_below: knobs.stop_below.max(0.0),
            count_word: input.count.1,
            capacity,
            full_above: knobs.full_above.max(0.0),
            _pad: [0; 3],
            words: capacity.div_ceil(32),
        };
        ctx.queue
            .write_buffer(&self.params, 0, bytemuck::bytes_of(&params));
        encoder.clear_buffer(&self.counters, 0, None);
        if bits_bytes > 0 {
            encoder.clear_buffer(&bits, 0, Some(bits_bytes));
        }
        let group = |k: usize| {
            let bits_entry = wgpu::BindGroupEntry {
                binding: 6 + k as u32,
                resource: bits.as_entire_binding(),
            };
            ctx.device.create_bind_group(&wgpu::BindGroupDescriptor {
                label: Some("compositor"),
                layout: &self.layouts[k],
                entries: &[
                    wgpu::BindGroupEntry {
                        binding: 0,
                        resource: self.params.as_entire_binding(),
                    },
                    wgpu::BindGroupEntry {
                        binding: 1,
                        resource: input.count.0.as_entire_binding(),
                    },
                    wgpu::BindGroupEntry {
                        binding: 2,
                        resource: self.rects.as_entire_binding(),
                    },
                    wgpu::BindGroupEntry {
                        binding: 3,
                        resource: wgpu::BindingResource::TextureView(&depth.view),
                    },
                    wgpu::BindGroupEntry {
                        binding: 4,
                        resource: wgpu::BindingResource::TextureView(layer_view),
                    },
                    wgpu::BindGroupEntry {
                        binding: 5,
                        resource: self.counters.as_entire_binding(),
                    },
                    bits_entry,
                ],
            })
        };
        {
            let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
                label: Some("tiles: setup"),
                timestamp_writes: spans.compute_pass("tiles: setup"),
            });
            pass.set_bind_group(0, frame_group, &[]);
            pass.set_bind_group(1, input.records, &[]);
            pass.set_bind_group(2, &group(0), &[]);
            pass.set_pipeline(&self.setup);
            let groups = capacity.div_ceil(64).max(1);
            let most = ctx.device.limits().max_compute_workgroups_per_dimension;
            pass.dispatch_workgroups(groups.min(most), 1, 1);
        }
        {
            let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
                label: Some("tiles: composite"),
                timestamp_writes: spans.compute_pass("tiles: composite"),
            });
            pass.set_bind_group(0, frame_group, &[]);
            pass.set_bind_group(1, input.records, &[]);
            pass.set_bind_group(2, &group(1), &[]);
            pass.set_pipeline(&self.composite);
            let most = ctx.device.limits().max_compute_workgroups_per_dimension;
            pass.dispatch_workgroups((tiles[0] * tiles[1]).min(most), 1, 1);
        }
        let span = spans.open("billboards");
        layer.composite(
            encoder,
            target,
            format,
            spans.render_writes(span, true, true),
        );
    }

    /// What the last frame's composite counted (blocking; for tests and tools).
    pub fn read_counters(&self, ctx: &GpuContext) -> crate::Result<CompositorCounters> {
        let bytes = super::target::read_buffer(ctx, &self.counters, (COUNTER_WORDS * 4) as u64)?;
        let w: Vec<u32> = bytemuck::pod_collect_to_vec(&bytes);
        Ok(CompositorCounters {
            layers: w[1],
            tests: w[2],
            pixels_stopped: w[3],
            tiles_stopped: w[4],
            tiles: w[5],
        })
    }
}
