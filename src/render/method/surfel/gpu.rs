//! The `surfel` method on the GPU: every species' surfels in one buffer (12 bytes each),
//! the frame's blocks and trees, the per-pixel buffers the splatting and pull-push passes
//! share (`shaders/surfel.wgsl`), and the passes themselves.

use crate::format::{SURFEL_WORDS, SurfelSet};
use crate::render::GpuContext;
use crate::render::frame_bindings::DepthTarget;
use crate::render::layer::{LAYER_FORMAT, TreeLayer};
use crate::render::pipelines::{Layouts, buffer_entry};
use crate::render::timing::PassSpans;
use crate::{Error, Result};

/// `SurfelParams` of surfel.wgsl.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, bytemuck::Pod, bytemuck::Zeroable)]
pub struct SurfelParams {
    pub size: [u32; 2],
    pub half_size: [u32; 2],
    pub quarter_size: [u32; 2],
    pub items: u32,
    pub row: u32,
    pub fill: u32,
    pub mode: u32,
    /// Pixels per metre at one metre from the camera (0: orthographic, every surfel drawn).
    pub focal_px: f32,
    /// Multiplies the trees' own extinction (0: no self-shadowing).
    pub self_shadow: f32,
}

/// `SurfelTreeGpu` of surfel.wgsl: one drawn tree (its surfels packed as the file stores
/// them: `crate::format::pack_surfel`).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, bytemuck::Pod, bytemuck::Zeroable)]
pub struct SurfelTreeGpu {
    pub model: [[f32; 4]; 4],
    pub qmin: [f32; 3],
    /// The tree's index in the world (seeds its surfels' coverage dither).
    pub instance: u32,
    pub qsize: [f32; 3],
    pub scale: f32,
    pub tint: [f32; 3],
    pub _pad0: f32,
    pub vcm_min: [f32; 3],
    pub _pad1: f32,
    pub vcm_inv_size: [f32; 3],
    pub _pad2: f32,
    pub vcm_direct: [[f32; 4]; 2],
    pub vcm_sky: [[f32; 4]; 2],
    /// The species' density volume: its corner (tree frame), voxel side, size in voxels
    /// and where it starts in the volumes' buffer.
    pub vol_origin: [f32; 3],
    pub vol_voxel: f32,
    pub vol_dims: [u32; 3],
    pub vol_offset: u32,
}

/// `SurfelItem` of surfel.wgsl: one block of one tree.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
pub struct SurfelItem {
    pub tree: u32,
    pub first: u32,
    pub count: u32,
    pub tolerance: f32,
    pub level: u32,
    /// The level's spacing in the world (m).
    pub spacing: f32,
    pub _pad: [u32; 2],
}

/// Every species' LDC tree on the GPU (their nodes kept on the CPU for the traversal).
pub struct SurfelAssets {
    /// Per species: its LDC tree (surfels and density dropped once uploaded) and where its
    /// surfels start in the buffer.
    pub species: Vec<(SurfelSet, u32)>,
    /// Where each species' density volume starts in `volumes`.
    pub volume_offsets: Vec<u32>,
    pub surfels: wgpu::Buffer,
    pub volumes: wgpu::Buffer,
    pub bytes: u64,
    pub count: u64,
}

impl SurfelAssets {
    pub fn new(ctx: &GpuContext, trees: Vec<SurfelSet>) -> Result<Self> {
        let count: u64 = trees.iter().map(SurfelSet::surfel_count).sum();
        let bytes = (count.max(1)) * (SURFEL_WORDS as u64) * 4;
        let limit = ctx.device.limits().max_storage_buffer_binding_size;
        if bytes > limit {
            return Err(Error::BadInput(format!(
                "the trees' surfels take {bytes} bytes, more than this GPU binds in one buffer ({limit}): lower `[bake] surfel_budget` in the scene file"
            )));
        }
        let mut words: Vec<u32> = Vec::with_capacity((count as usize) * SURFEL_WORDS);
        let mut species = Vec::with_capacity(trees.len());
        let mut sigma: Vec<f32> = Vec::new();
        let mut volume_offsets = Vec::with_capacity(trees.len());
        for mut t in trees {
            volume_offsets.push(sigma.len() as u32);
            sigma.extend_from_slice(&t.density.sigma);
            t.density.sigma = Vec::new();
            let base = (words.len() / SURFEL_WORDS) as u32;
            words.append(&mut t.words);
            species.push((t, base));
        }
        if words.is_empty() {
            words.extend_from_slice(&[0; SURFEL_WORDS]);
        }
        if sigma.is_empty() {
            sigma.push(0.0);
        }
        let surfels = ctx.checked("uploading the surfels", || {
            use wgpu::util::DeviceExt;
            ctx.device
                .create_buffer_init(&wgpu::util::BufferInitDescriptor {
                    label: Some("surfels"),
                    contents: bytemuck::cast_slice(&words),
                    usage: wgpu::BufferUsages::STORAGE,
                })
        })?;
        let volumes = ctx.checked("uploading the surfel density volumes", || {
            use wgpu::util::DeviceExt;
            ctx.device
                .create_buffer_init(&wgpu::util::BufferInitDescriptor {
                    label: Some("surfel density volumes"),
                    contents: bytemuck::cast_slice(&sigma),
                    usage: wgpu::BufferUsages::STORAGE,
                })
        })?;
        let bytes = bytes + sigma.len() as u64 * 4;
        Ok(Self {
            species,
            volume_offsets,
            surfels,
            volumes,
            bytes,
            count,
        })
    }
}

/// The splatting passes and the buffers they share, sized to the target.
pub struct Splatter {
    layout: wgpu::BindGroupLayout,
    init: wgpu::ComputePipeline,
    depth: wgpu::ComputePipeline,
    colour: wgpu::ComputePipeline,
    pull1: wgpu::ComputePipeline,
    pull2: wgpu::ComputePipeline,
    push: wgpu::ComputePipeline,
    params: wgpu::Buffer,
    state: std::sync::Mutex<SplatState>,
}

/// What the splatting passes hold between frames.
struct SplatState {
    items: Grown,
    trees: Grown,
    pixels: Option<PixelBuffers>,
}

/// A storage buffer grown to the largest size asked so far.
struct Grown {
    label: &'static str,
    buffer: Option<wgpu::Buffer>,
}

impl Grown {
    fn write(&mut self, ctx: &GpuContext, bytes: &[u8]) -> &wgpu::Buffer {
        let need = (bytes.len() as u64).max(16).next_power_of_two();
        if self.buffer.as_ref().is_none_or(|b| b.size() < need) {
            self.buffer = Some(ctx.device.create_buffer(&wgpu::BufferDescriptor {
                label: Some(self.label),
                size: need,
                usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST,
                mapped_at_creation: false,
            }));
        }
        let b = self.buffer.as_ref().expect("made above");
        if !bytes.is_empty() {
            ctx.queue.write_buffer(b, 0, bytes);
        }
        b
    }
}

/// The per-pixel buffers: nearest distance, colour sums, and the two coarser levels.
struct PixelBuffers {
    size: (u32, u32),
    nearest: wgpu::Buffer,
    sums: wgpu::Buffer,
    levels: wgpu::Buffer,
}

fn half(size: (u32, u32)) -> [u32; 2] {
    [size.0.div_ceil(2), size.1.div_ceil(2)]
}

fn quarter(size: (u32, u32)) -> [u32; 2] {
    [size.0.div_ceil(4), size.1.div_ceil(4)]
}

impl PixelBuffers {
    fn new(ctx: &GpuContext, size: (u32, u32)) -> Result<Self> {
        let pixels = u64::from(size.0) * u64::from(size.1);
        let h = half(size);
        let q = quarter(size);
        let level_pixels = u64::from(h[0]) * u64::from(h[1]) + u64::from(q[0]) * u64::from(q[1]);
        let buffer = |label: &str, bytes: u64| {
            ctx.device.create_buffer(&wgpu::BufferDescriptor {
                label: Some(label),
                size: bytes.max(16),
                usage: wgpu::BufferUsages::STORAGE,
                mapped_at_creation: false,
            })
        };
        ctx.checked("allocating the surfel buffers", || Self {
            size,
            nearest: buffer("surfel nearest", pixels * 4),
            sums: buffer("surfel sums", pixels * 16),
            levels: buffer("surfel levels", level_pixels * 32),
        })
    }

    fn bytes(&self) -> u64 {
        self.nearest.size() + self.sums.size() + self.levels.size()
    }
}

/// What one frame splats.
pub struct SplatInput<'a> {
    pub surfels: &'a wgpu::Buffer,
    pub volumes: &'a wgpu::Buffer,
    pub items: &'a [SurfelItem],
    pub trees: &'a [SurfelTreeGpu],
    pub fill: u32,
    pub mode: u32,
    pub focal_px: f32,
    pub self_shadow: f32,
}

impl Splatter {
    pub fn new(device: &wgpu::Device, layouts: &Layouts) -> Self {
        let compute = wgpu::ShaderStages::COMPUTE;
        let read = wgpu::BufferBindingType::Storage { read_only: true };
        let rw = wgpu::BufferBindingType::Storage { read_only: false };
        let layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("surfels"),
            entries: &[
                buffer_entry(0, compute, wgpu::BufferBindingType::Uniform),
                buffer_entry(1, compute, read),
                buffer_entry(2, compute, read),
                buffer_entry(3, compute, read),
                buffer_entry(4, compute, rw),
                buffer_entry(5, compute, rw),
                buffer_entry(6, compute, rw),
                wgpu::BindGroupLayoutEntry {
                    binding: 7,
                    visibility: compute,
                    ty: wgpu::BindingType::Texture {
                        sample_type: wgpu::TextureSampleType::Depth,
                        view_dimension: wgpu::TextureViewDimension::D2,
                        multisampled: false,
                    },
                    count: None,
                },
                buffer_entry(9, compute, read),
                wgpu::BindGroupLayoutEntry {
                    binding: 8,
                    visibility: compute,
                    ty: wgpu::BindingType::StorageTexture {
                        access: wgpu::StorageTextureAccess::WriteOnly,
                        format: LAYER_FORMAT,
                        view_dimension: wgpu::TextureViewDimension::D2,
                    },
                    count: None,
                },
            ],
        });
        let module = crate::render::pipelines::wgsl_module(
            device,
            "surfel.wgsl",
            &crate::render::shaders::surfel(),
        );
        let pipeline_layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("surfels"),
            bind_group_layouts: &[Some(&layouts.frame), Some(&layout)],
            immediate_size: 0,
        });
        let pipeline = |entry: &str| {
            device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
                label: Some(entry),
                layout: Some(&pipeline_layout),
                module: &module,
                entry_point: Some(entry),
                compilation_options: crate::render::shaders::frame_options(),
                cache: None,
            })
        };
        let params = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("surfel params"),
            size: std::mem::size_of::<SurfelParams>() as u64,
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        Self {
            init: pipeline("init"),
            depth: pipeline("depth"),
            colour: pipeline("colour"),
            pull1: pipeline("pull1"),
            pull2: pipeline("pull2"),
            push: pipeline("push"),
            layout,
            params,
            state: std::sync::Mutex::new(SplatState {
                items: Grown {
                    label: "surfel blocks",
                    buffer: None,
                },
                trees: Grown {
                    label: "surfel trees",
                    buffer: None,
                },
                pixels: None,
            }),
        }
    }

    /// Bytes of the per-pixel buffers.
    pub fn pixel_bytes(&self) -> u64 {
        self.state
            .lock()
            .map_or(0, |s| s.pixels.as_ref().map_or(0, PixelBuffers::bytes))
    }

    /// Uploads `input` and splats it against the frame's `depth` into `layer`, then puts
    /// the layer over the frame's `target`; timed as `surfels: splat`, `surfels: fill` and
    /// `surfels` (the layer over the frame).
    #[allow(clippy::too_many_arguments)]
    pub fn splat(
        &self,
        ctx: &GpuContext,
        encoder: &mut wgpu::CommandEncoder,
        frame_group: &wgpu::BindGroup,
        input: &SplatInput<'_>,
        (depth, layer): (&DepthTarget, &TreeLayer),
        (target, format): (&wgpu::TextureView, wgpu::TextureFormat),
        spans: &PassSpans,
    ) -> Result<()> {
        let Some(layer_view) = layer.view() else {
            return Ok(());
        };
        let mut state = self
            .state
            .lock()
            .map_err(|_| Error::Gpu("the surfel buffers are poisoned".into()))?;
        let state = &mut *state;
        let size = depth.size;
        if state.pixels.as_ref().is_none_or(|p| p.size != size) {
            state.pixels = None;
            state.pixels = Some(PixelBuffers::new(ctx, size)?);
        }
        let most = ctx.device.limits().max_compute_workgroups_per_dimension;
        let items = input.items.len() as u32;
        let row = most.min(items.max(1));
        let params = SurfelParams {
            size: [size.0, size.1],
            half_size: half(size),
            quarter_size: quarter(size),
            items,
            row,
            fill: input.fill,
            mode: input.mode,
            focal_px: input.focal_px,
            self_shadow: input.self_shadow,
        };
        ctx.queue
            .write_buffer(&self.params, 0, bytemuck::bytes_of(&params));
        let items_buf = state
            .items
            .write(ctx, bytemuck::cast_slice(input.items))
            .clone();
        let trees_buf = state
            .trees
            .write(ctx, bytemuck::cast_slice(input.trees))
            .clone();
        let px = state.pixels.as_ref().expect("made above");
        let surfels = input.surfels;
        fn entry(binding: u32, buffer: &wgpu::Buffer) -> wgpu::BindGroupEntry<'_> {
            wgpu::BindGroupEntry {
                binding,
                resource: buffer.as_entire_binding(),
            }
        }
        let group = ctx.device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("surfels"),
            layout: &self.layout,
            entries: &[
                entry(0, &self.params),
                entry(1, surfels),
                entry(2, &items_buf),
                entry(3, &trees_buf),
                entry(4, &px.nearest),
                entry(5, &px.sums),
                entry(6, &px.levels),
                wgpu::BindGroupEntry {
                    binding: 7,
                    resource: wgpu::BindingResource::TextureView(&depth.view),
                },
                wgpu::BindGroupEntry {
                    binding: 8,
                    resource: wgpu::BindingResource::TextureView(layer_view),
                },
                entry(9, input.volumes),
            ],
        });
        let (w, h) = px.size;
        let per_pixel =
            |pass: &mut wgpu::ComputePass<'_>, p: &wgpu::ComputePipeline, s: [u32; 2]| {
                pass.set_pipeline(p);
                pass.dispatch_workgroups(s[0].div_ceil(8), s[1].div_ceil(8), 1);
            };
        {
            let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
                label: Some("surfels: splat"),
                timestamp_writes: spans.compute_pass("surfels: splat"),
            });
            pass.set_bind_group(0, frame_group, &[]);
            pass.set_bind_group(1, &group, &[]);
            per_pixel(&mut pass, &self.init, [w, h]);
            if items > 0 {
                for p in [&self.depth, &self.colour] {
                    pass.set_pipeline(p);
                    pass.dispatch_workgroups(row, items.div_ceil(row), 1);
                }
            }
        }
        {
            let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
                label: Some("surfels: fill"),
                timestamp_writes: spans.compute_pass("surfels: fill"),
            });
            pass.set_bind_group(0, frame_group, &[]);
            pass.set_bind_group(1, &group, &[]);
            per_pixel(&mut pass, &self.pull1, half((w, h)));
            per_pixel(&mut pass, &self.pull2, quarter((w, h)));
            per_pixel(&mut pass, &self.push, [w, h]);
        }
        let span = spans.open("surfels");
        layer.composite(
            encoder,
            target,
            format,
            spans.render_writes(span, true, true),
        );
        Ok(())
    }
}
