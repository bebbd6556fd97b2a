//! The tree level's light blends: fewer image reads per fragment. A billboard blends its 3
//! nearest light samples' images with weights that depend on the sun's direction in its
//! object frame alone; for a tree-level billboard that is the sun and the tree's yaw. So
//! when the sun moves, each tree-level image set (one per prototype) gets, per view sample
//! and per yaw bin, the blend of its 3 lights' images made once on the GPU
//! (`shaders/light_blend.wgsl`, every mip level blended from the same level: the mips are
//! box filters, linear, so that is exact), and a tree-level billboard reads that one image
//! per view instead of three: 3 x (blend + sky + ground) = 9 reads instead of 15.
//!
//! One compute pass makes them all, a dispatch per mip level, writing the array through a
//! plain RGBA8 storage view (the array is `Rgba8Unorm`, sampled through sRGB views; the
//! shader encodes each texel to its nearest 8-bit sRGB code).
//!
//! The blends live in the BTF texture array itself, in layers after the baked images, so
//! that the fragment shader reads a tree-level billboard's blend and a finer billboard's 3
//! lights through the same loop (1 turn or 3): lavapipe, like any SIMD rasteriser without
//! real branches, runs both sides of an `if` but only the loop turns some fragment takes.
//! A blend is the light weights normalised to sum to 1 (so it stays within an 8-bit
//! image); the billboard scales it back by their sum (the light gain). What is quantised:
//! a tree's yaw, to the nearest of [`LIGHT_BINS`] bins (the sun's direction in its frame
//! turns by up to half a bin), and the blend's own 8-bit sRGB texels.

use std::sync::atomic::{AtomicBool, Ordering};

use glam::Vec3;

use super::prepare::BtfScene;
use super::settings::BtfSettings;
use crate::render::GpuContext;
use crate::render::consts::ATLAS_SIDE;
use crate::render::timing::PassSpans;
use crate::sphere::{Blend, DirectionSet};

/// Yaw bins of the light blends. docs/results/btf.md (2026-11-27, "Light blends") has the
/// picture's change and the memory at 4, 8 and 16 bins.
pub const LIGHT_BINS: u32 = 16;

/// One blended image as `light_blend.wgsl` reads it (`BlendImage`): the BTF images of its 3
/// lights and their weights, summing to 1.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
pub struct BlendImageGpu {
    pub source: [u32; 4],
    pub weight: [f32; 4],
}

/// The light samples and weights a billboard blends for the sun at `l_obj` in its object
/// frame: the 3 nearest, culled below the threshold, brightened by the light gain (as the
/// CPU's and the GPU's records have them).
pub fn light_weights(lights: &DirectionSet, l_obj: Vec3, settings: &BtfSettings) -> Blend {
    let mut lb = lights.blend(l_obj);
    lb.cull(settings.weight_threshold);
    let strength = settings.light_gain.clamp(0.0, 1.0);
    if strength > 0.0 {
        let gain = lights.light_gain(&lb, l_obj).powf(strength);
        lb.weight = lb.weight.map(|w| w * gain);
    }
    lb
}

/// The yaw bin, of `bins`, of the sun's direction `l_obj` in an object's frame: its azimuth
/// about the object's up axis (y), counted from the sun's own in the world, to the nearest
/// bin (`yaw_bin` in `btf_far.wgsl`). For a tree turned by yaw alone, the sun in its frame is
/// [`bin_direction`] of its bin to within half a bin.
pub fn yaw_bin(l_obj: Vec3, to_sun: Vec3, bins: u32) -> u32 {
    let bins = bins.max(1) as i32;
    let a = l_obj.z.atan2(l_obj.x) - to_sun.z.atan2(to_sun.x);
    let b = (a / std::f32::consts::TAU * bins as f32).round_ties_even() as i32;
    b.rem_euclid(bins) as u32
}

/// The sun's direction in the frame of an object of yaw bin `bin` of `bins`: `to_sun`
/// turned about the up axis by the bin's angle, its elevation kept (`bin_direction` in
/// `btf_far.wgsl`).
pub fn bin_direction(to_sun: Vec3, bin: u32, bins: u32) -> Vec3 {
    let phi = to_sun.z.atan2(to_sun.x) + std::f32::consts::TAU * bin as f32 / bins.max(1) as f32;
    let h = (to_sun.x * to_sun.x + to_sun.z * to_sun.z).sqrt();
    Vec3::new(h * phi.cos(), to_sun.y, h * phi.sin())
}

/// What the blends were last made for: the sun and the knobs that change the weights.
#[derive(Clone, Copy, Debug, PartialEq)]
struct BlendKey {
    to_sun: Vec3,
    light_gain: f32,
    weight_threshold: f32,
}

/// The light blends on the GPU: every prototype's tree-level blends, in the BTF texture
/// array's layers from `first_layer` on, image
/// [`BtfScene::light_blend_first`]`(prototype, bin) + view`.
pub struct LightBlend {
    images: wgpu::Buffer,
    /// One a mip level: the images, the baked layers read, that level of the blends'
    /// layers written, and the level's uniform.
    bind_groups: Vec<wgpu::BindGroup>,
    pipeline: wgpu::ComputePipeline,
    /// The blends' texels a side, per mip level.
    sides: Vec<u32>,
    /// The blends' layers.
    layers: u32,
    /// Blended images.
    count: u32,
    /// Whether the blends must be made again (set when the sun moved, cleared once
    /// encoded).
    pending: AtomicBool,
    made_for: Option<BlendKey>,
    /// Bytes of the blends' layers, mips included.
    pub bytes: u64,
}

/// The view format the blends' layers are written through: the array's own format,
/// [`BLEND_ARRAY_FORMAT`], is read as sRGB through [`BLEND_SAMPLE_FORMAT`] views.
pub const BLEND_ARRAY_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Rgba8Unorm;
/// The format every sampling view of an array with blends has (the baked images' bytes
/// are 8-bit sRGB).
pub const BLEND_SAMPLE_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Rgba8UnormSrgb;

impl LightBlend {
    /// The blends of `count` images in `texture` (the BTF atlas, `mips` levels, format
    /// [`BLEND_ARRAY_FORMAT`] with `STORAGE_BINDING` and [`BLEND_SAMPLE_FORMAT`] views),
    /// from layer `first_layer` on, read from its layers before.
    pub fn new(ctx: &GpuContext, texture: &wgpu::Texture, first_layer: u32, count: u32) -> Self {
        let per_layer = ATLAS_SIDE * ATLAS_SIDE;
        let layers = count.div_ceil(per_layer).max(1);
        let mips = texture.mip_level_count();
        let side = texture.width();
        let sides: Vec<u32> = (0..mips).map(|m| (side >> m).max(1)).collect();
        let bytes = sides
            .iter()
            .map(|&s| u64::from(s).pow(2) * 4 * u64::from(layers))
            .sum();
        // The baked images alone: the blends' own layers are written.
        let sources = texture.create_view(&wgpu::TextureViewDescriptor {
            label: Some("btf baked images"),
            format: Some(BLEND_SAMPLE_FORMAT),
            usage: Some(wgpu::TextureUsages::TEXTURE_BINDING),
            dimension: Some(wgpu::TextureViewDimension::D2Array),
            base_array_layer: 0,
            array_layer_count: Some(first_layer.max(1)),
            ..Default::default()
        });
        let images = ctx.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("btf light blend weights"),
            size: u64::from(count.max(1)) * std::mem::size_of::<BlendImageGpu>() as u64,
            usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let stride = u64::from(ctx.device.limits().min_uniform_buffer_offset_alignment).max(16);
        let levels = ctx.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("btf light blend levels"),
            size: stride * u64::from(mips.max(1)),
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        for mip in 0..mips {
            ctx.queue.write_buffer(
                &levels,
                stride * u64::from(mip),
                bytemuck::cast_slice(&[count, mip, 0, 0]),
            );
        }
        let compute = wgpu::ShaderStages::COMPUTE;
        let layout = ctx
            .device
            .create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
                label: Some("btf light blend"),
                entries: &[
                    wgpu::BindGroupLayoutEntry {
                        binding: 0,
                        visibility: compute,
                        ty: wgpu::BindingType::Buffer {
                            ty: wgpu::BufferBindingType::Storage { read_only: true },
                            has_dynamic_offset: false,
                            min_binding_size: None,
                        },
                        count: None,
                    },
                    wgpu::BindGroupLayoutEntry {
                        binding: 1,
                        visibility: compute,
                        ty: wgpu::BindingType::Texture {
                            sample_type: wgpu::TextureSampleType::Float { filterable: true },
                            view_dimension: wgpu::TextureViewDimension::D2Array,
                            multisampled: false,
                        },
                        count: None,
                    },
                    wgpu::BindGroupLayoutEntry {
                        binding: 2,
                        visibility: compute,
                        ty: wgpu::BindingType::StorageTexture {
                            access: wgpu::StorageTextureAccess::WriteOnly,
                            format: BLEND_ARRAY_FORMAT,
                            view_dimension: wgpu::TextureViewDimension::D2Array,
                        },
                        count: None,
                    },
                    wgpu::BindGroupLayoutEntry {
                        binding: 3,
                        visibility: compute,
                        ty: wgpu::BindingType::Buffer {
                            ty: wgpu::BufferBindingType::Uniform,
                            has_dynamic_offset: false,
                            min_binding_size: wgpu::BufferSize::new(16),
                        },
                        count: None,
                    },
                ],
            });
        let bind_groups = (0..mips)
            .map(|mip| {
                let target = texture.create_view(&wgpu::TextureViewDescriptor {
                    label: Some("btf light blend target"),
                    format: Some(BLEND_ARRAY_FORMAT),
                    dimension: Some(wgpu::TextureViewDimension::D2Array),
                    base_mip_level: mip,
                    mip_level_count: Some(1),
                    base_array_layer: first_layer,
                    array_layer_count: Some(layers),
                    ..Default::default()
                });
                ctx.device.create_bind_group(&wgpu::BindGroupDescriptor {
                    label: Some("btf light blend"),
                    layout: &layout,
                    entries: &[
                        wgpu::BindGroupEntry {
                            binding: 0,
                            resource: images.as_entire_binding(),
                        },
                        wgpu::BindGroupEntry {
                            binding: 1,
                            resource: wgpu::BindingResource::TextureView(&sources),
                        },
                        wgpu::BindGroupEntry {
                            binding: 2,
                            resource: wgpu::BindingResource::TextureView(&target),
                        },
                        wgpu::BindGroupEntry {
                            binding: 3,
                            resource: wgpu::BindingResource::Buffer(wgpu::BufferBinding {
                                buffer: &levels,
                                offset: stride * u64::from(mip),
                                size: wgpu::BufferSize::new(16),
                            }),
                        },
                    ],
                })
            })
            .collect();
        Self {
            images,
            bind_groups,
            pipeline: build_pipeline(&ctx.device, &layout),
            sides,
            layers,
            count,
            pending: AtomicBool::new(false),
            made_for: None,
            bytes,
        }
    }

    /// Sets the blends' weights for the sun `to_sun` and the knobs of `settings` if they
    /// changed since they were last made (the blends follow in [`Self::encode`]); true if
    /// so.
    pub fn update(
        &mut self,
        ctx: &GpuContext,
        scene: &BtfScene,
        to_sun: Vec3,
        settings: &BtfSettings,
    ) -> bool {
        let key = BlendKey {
            to_sun,
            light_gain: settings.light_gain,
            weight_threshold: settings.weight_threshold,
        };
        if self.made_for == Some(key) {
            return false;
        }
        let data = blend_images(scene, to_sun, settings);
        if data.len() != self.count as usize {
            return false;
        }
        ctx.queue
            .write_buffer(&self.images, 0, bytemuck::cast_slice(&data));
        self.made_for = Some(key);
        self.pending.store(true, Ordering::Relaxed);
        true
    }

    /// Makes the blends if their weights changed: one compute pass, timed as `light
    /// blend`, a dispatch per mip level.
    pub fn encode(&self, encoder: &mut wgpu::CommandEncoder, spans: &PassSpans) {
        if !self.pending.swap(false, Ordering::Relaxed) {
            return;
        }
        let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
            label: Some("light blend"),
            timestamp_writes: spans.compute_pass("light blend"),
        });
        pass.set_pipeline(&self.pipeline);
        for (bind_group, &side) in self.bind_groups.iter().zip(&self.sides) {
            pass.set_bind_group(0, bind_group, &[]);
            pass.dispatch_workgroups(side.div_ceil(8), side.div_ceil(8), self.layers);
        }
    }
}

/// Every blended image's 3 source images and normalised weights, for the sun `to_sun`:
/// prototype by prototype, bin by bin, view by view.
pub fn blend_images(scene: &BtfScene, to_sun: Vec3, settings: &BtfSettings) -> Vec<BlendImageGpu> {
    let bins = scene.light_bins();
    let (views, lights) = scene.tree_directions();
    let (views, light_count) = (views.len() as u32, lights.len() as u32);
    let mut out = Vec::new();
    for sp in 0..scene.species_count() {
        let Some((base, _, _)) = scene.tree_set(sp) else {
            continue;
        };
        for bin in 0..bins {
            let lb = light_weights(lights, bin_direction(to_sun, bin, bins), settings);
            let sum: f32 = lb.weight.iter().sum();
            let w = if sum > 0.0 && sum.is_finite() {
                lb.weight.map(|w| w / sum)
            } else {
                [1.0, 0.0, 0.0]
            };
            for v in 0..views {
                let first = base + v * light_count;
                out.push(BlendImageGpu {
                    source: [
                        first + lb.index[0],
                        first + lb.index[1],
                        first + lb.index[2],
                        0,
                    ],
                    weight: [w[0], w[1], w[2], 0.0],
                });
            }
        }
    }
    out
}

fn build_pipeline(device: &wgpu::Device, layout: &wgpu::BindGroupLayout) -> wgpu::ComputePipeline {
    let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
        label: Some("light_blend.wgsl"),
        source: wgpu::ShaderSource::Wgsl(crate::render::shaders::light_blend().into()),
    });
    let pipeline_layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
        label: Some("light blend"),
        bind_group_layouts: &[Some(layout)],
        immediate_size: 0,
    });
    device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
        label: Some("light blend"),
        layout: Some(&pipeline_layout),
        module: &module,
        entry_point: Some("cs_blend"),
        compilation_options: Default::default(),
        cache: None,
    })
}
