//! The texel bake's voxelisation on the GPU: the geometry method's shading drawn from an
//! orthographic view with `fs_voxel` (shaders/geometry.wgsl), which adds every fragment's
//! pixel and lit colour to the voxel of a grid it lies in (no depth test: hidden surfaces
//! count; bark's back faces are culled as in every pass). One pass gives what one pass per
//! voxel-thick slab (near and far planes around it) would: the same pixels covered (a
//! mask per voxel, so two surfaces over one pixel cover it once); the colour is the mean
//! of every surface in the voxel where the slab's picture keeps the nearest.

use glam::{UVec3, Vec3};

use super::meshes::{MeshPasses, encode_cascades};
use super::method::geometry::GeometryFrame;
use super::pipelines::{GeometryPass, Layouts, MeshDepth, buffer_entry};
use super::{FrameDesc, FrameStats, GpuContext, Stage, target};
use crate::{Error, Result};

/// Fixed-point scale of the colour sums (1.0 = this many units).
pub const COLOR_SCALE: f32 = 1024.0;

/// The uniform block `VoxelGrid` of geometry.wgsl.
#[repr(C)]
#[derive(Clone, Copy, Debug, bytemuck::Pod, bytemuck::Zeroable)]
struct VoxelGridUniform {
    box_min: [f32; 3],
    voxel: f32,
    dims: [u32; 3],
    scale: f32,
    ss: u32,
    _pad: [u32; 3],
}

/// Largest grid voxelised in one pass (24 bytes per voxel: 96 MiB).
pub const MAX_VOXELS: u64 = 1 << 22;
/// Most pixels per voxel side (the coverage mask has 64 bits).
pub const MAX_SUPERSAMPLE: u32 = 8;
/// Words per voxel: fragments, red, green, blue, coverage mask (2).
const WORDS: usize = 6;

/// The voxel pipelines (bark with its back faces culled, as the colour pass draws it, and
/// two-sided foliage) and their bind group layout (group 3), built once per renderer.
pub struct VoxelPipeline {
    opaque: wgpu::RenderPipeline,
    foliage: wgpu::RenderPipeline,
    layout: wgpu::BindGroupLayout,
}

impl VoxelPipeline {
    pub fn new(device: &wgpu::Device, layouts: &Layouts) -> Self {
        let fragment = wgpu::ShaderStages::FRAGMENT;
        let layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("voxel grid"),
            entries: &[
                buffer_entry(0, fragment, wgpu::BufferBindingType::Uniform),
                buffer_entry(
                    1,
                    fragment,
                    wgpu::BufferBindingType::Storage { read_only: false },
                ),
            ],
        });
        let pass = GeometryPass::new(device, layouts, "voxelise", Some(&layout));
        // Every face, hidden or not: each is in some slab.
        let depth = MeshDepth {
            write: false,
            compare: wgpu::CompareFunction::Always,
        };
        let pipeline =
            |cull_mode| pass.pipeline(device, "voxelise", cull_mode, "fs_voxel", &[], depth);
        Self {
            opaque: pipeline(Some(wgpu::Face::Back)),
            foliage: pipeline(None),
            layout,
        }
    }

    pub fn meshes(&self) -> super::pipelines::MeshPipelines<'_> {
        super::pipelines::MeshPipelines {
            opaque: &self.opaque,
            foliage: &self.foliage,
        }
    }
}

/// A grid of voxels the GPU adds fragments into, and its sums read back.
pub struct VoxelTarget {
    pub dims: UVec3,
    sums: wgpu::Buffer,
    readback: wgpu::Buffer,
    pub(super) bind_group: wgpu::BindGroup,
    bytes: u64,
}

/// What one voxel received: fragments, their summed colour, and the pixels they covered.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct VoxelSum {
    pub fragments: u32,
    /// Linear colour summed over the fragments.
    pub color: Vec3,
    /// Of the voxel's ss x ss pixels, those covered by at least one fragment.
    pub covered: u32,
    /// Which of them (bit y * ss + x).
    pub mask: u64,
}

impl VoxelTarget {
    /// A grid of `dims` voxels of side `voxel` from `box_min` (world frame of the pass),
    /// drawn at `ss` pixels per voxel side.
    pub fn new(
        ctx: &GpuContext,
        pipeline: &VoxelPipeline,
        box_min: Vec3,
        dims: UVec3,
        voxel: f32,
        ss: u32,
    ) -> Result<Self> {
        if !(1..=MAX_SUPERSAMPLE).contains(&ss) {
            return Err(Error::BadInput(format!(
                "voxelising at {ss} pixels per voxel side: give 1 to {MAX_SUPERSAMPLE}"
            )));
        }
        let count = u64::from(dims.x) * u64::from(dims.y) * u64::from(dims.z);
        if count == 0 || count > MAX_VOXELS {
            return Err(Error::BadInput(format!(
                "a voxel grid of {}x{}x{} is outside 1..={MAX_VOXELS} voxels",
                dims.x, dims.y, dims.z
            )));
        }
        let bytes = count * (WORDS as u64) * 4;
        let device = &ctx.device;
        let sums = ctx.checked("allocating the voxel sums", || {
            device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("voxel sums"),
                size: bytes,
                usage: wgpu::BufferUsages::STORAGE
                    | wgpu::BufferUsages::COPY_SRC
                    | wgpu::BufferUsages::COPY_DST,
                mapped_at_creation: false,
            })
        })?;
        let readback = ctx.checked("allocating the voxel readback", || {
            device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("voxel readback"),
                size: bytes,
                usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
                mapped_at_creation: false,
            })
        })?;
        let uniform = VoxelGridUniform {
            box_min: box_min.to_array(),
            voxel,
            dims: dims.to_array(),
            scale: COLOR_SCALE,
            ss,
            _pad: [0; 3],
        };
        let grid = wgpu::util::DeviceExt::create_buffer_init(
            device,
            &wgpu::util::BufferInitDescriptor {
                label: Some("voxel grid"),
                contents: bytemuck::bytes_of(&uniform),
                usage: wgpu::BufferUsages::UNIFORM,
            },
        );
        let bind_group = device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("voxel grid"),
            layout: &pipeline.layout,
            entries: &[
                wgpu::BindGroupEntry {
                    binding: 0,
                    resource: grid.as_entire_binding(),
                },
                wgpu::BindGroupEntry {
                    binding: 1,
                    resource: sums.as_entire_binding(),
                },
            ],
        });
        Ok(Self {
            dims,
            sums,
            readback,
            bind_group,
            bytes,
        })
    }

    /// Zeroes the sums (encoded before a pass).
    pub(super) fn clear(&self, encoder: &mut wgpu::CommandEncoder) {
        encoder.clear_buffer(&self.sums, 0, None);
    }

    /// Copies the sums for [`Self::read`] (encoded after a pass).
    pub(super) fn copy_out(&self, encoder: &mut wgpu::CommandEncoder) {
        encoder.copy_buffer_to_buffer(&self.sums, 0, &self.readback, 0, self.bytes);
    }

    /// The sums of the last pass, x fastest, then y, then z.
    pub fn read(&self, ctx: &GpuContext) -> Result<Vec<VoxelSum>> {
        let data = super::target::map_read(ctx, &self.readback)?;
        let words: Vec<u32> = data
            .chunks_exact(4)
            .map(|b| u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
            .collect();
        Ok(words
            .chunks_exact(WORDS)
            .map(|w| VoxelSum {
                fragments: w[0],
                color: Vec3::new(w[1] as f32, w[2] as f32, w[3] as f32) / COLOR_SCALE,
                covered: w[4].count_ones() + w[5].count_ones(),
                mask: u64::from(w[4]) | (u64::from(w[5]) << 32),
            })
            .collect())
    }
}

impl super::Renderer {
    /// A voxel grid for [`Self::voxelize`] (building the voxel pipeline on first use).
    pub fn voxel_target(
        &mut self,
        ctx: &GpuContext,
        box_min: glam::Vec3,
        dims: glam::UVec3,
        voxel: f32,
        ss: u32,
    ) -> Result<VoxelTarget> {
        if self.voxel_pipeline.is_none() {
            let p = ctx.checked("building the voxel pipeline", || {
                VoxelPipeline::new(&ctx.device, &self.layouts)
            })?;
            self.voxel_pipeline = Some(p);
        }
        let Some(p) = &self.voxel_pipeline else {
            return Err(Error::Gpu("the voxel pipeline was not built".into()));
        };
        VoxelTarget::new(ctx, p, box_min, dims, voxel, ss)
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
        target: &VoxelTarget,
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
        self.meshes
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
            &self.meshes,
            &self.world,
            casters,
            !studio,
            None,
            false,
            &super::timing::PassSpans::off(),
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
            pass.set_bind_group(1, &self.world.trees_bind_group(), &[]);
            pass.set_bind_group(3, &target.bind_group, &[]);
            MeshPasses::draw_with(&mut pass, &self.world, &runs[0], voxel.meshes(), !studio);
        }
        target.copy_out(&mut encoder);
        ctx.queue.submit([encoder.finish()]);
        if let Some(e) = ctx.take_error() {
            return Err(Error::Gpu(e));
        }
        Ok(())
    }
}
