//! The bake's octahedral impostors on the GPU: every species' albedo and normal-depth
//! atlases as two texture arrays (one layer per species, the stored mips), the records'
//! buffer, the knobs' uniform, and the pipeline that draws them.

use glam::{UVec3, Vec3};

use super::prepare::{ImpostorGpu, ImpostorParams, SpeciesImpostor};
use super::settings::{ImpostorSettings, ImpostorStats};
use crate::format::{Baked, Impostor};
use crate::model::World;
use crate::render::GpuContext;
use crate::render::pipelines::{
    FILTERABLE, Layouts, buffer_entry, sampler_entry, storage_buffer_of, storage_entry,
    texture_entry, write_growing,
};
use crate::sphere::OctaLayout;
use crate::{Error, Result};

/// What the `impostor` method draws from.
pub struct ImpostorAssets {
    pub species: Vec<SpeciesImpostor>,
    params: ImpostorParams,
    params_buffer: wgpu::Buffer,
    records: wgpu::Buffer,
    layout: wgpu::BindGroupLayout,
    bind_group: wgpu::BindGroup,
    albedo: wgpu::TextureView,
    normal: wgpu::TextureView,
    sampler: wgpu::Sampler,
    /// The pipeline, for a target format and with or without the parallax point's depth.
    pipeline: Option<(wgpu::TextureFormat, bool, wgpu::RenderPipeline)>,
    /// Bytes of both atlases on the GPU.
    pub bytes: u64,
}

/// The one layout every species' impostor must share (they are layers of one array).
fn same_layout(a: &Impostor, b: &Impostor) -> bool {
    (a.layout, a.frames, a.resolution, a.mip_levels)
        == (b.layout, b.frames, b.resolution, b.mip_levels)
}

/// Each of the `n` species' impostor in `baked`, refused where one is missing or where
/// they do not share one layout.
fn impostors_by_species(baked: &Baked, n: usize) -> Result<Vec<&Impostor>> {
    let mut by_species: Vec<Option<&Impostor>> = vec![None; n];
    for imp in &baked.impostors {
        if let Some(slot) = by_species.get_mut(imp.species as usize) {
            *slot = Some(imp);
        }
    }
    let Some(Some(first)) = by_species.first().copied() else {
        return Err(Error::BadInput(
            "this bake has no octahedral impostors: set `[bake] impostor_frames` (e.g. 12) in the scene file and bake again".into(),
        ));
    };
    let mut list = Vec::with_capacity(n);
    for (sp, imp) in by_species.iter().enumerate() {
        let imp = imp.ok_or_else(|| {
            Error::BadInput(format!(
                "the bake has no impostor for species {sp}: bake the scene again"
            ))
        })?;
        if !same_layout(first, imp) {
            return Err(Error::BadInput(format!(
                "the impostor of species {sp} has another layout than species 0's: bake the scene again"
            )));
        }
        list.push(imp);
    }
    Ok(list)
}

/// The side of the atlases of `n` species' impostors laid out as `first`, refused where
/// this GPU cannot hold them or their stored levels do not halve evenly.
fn atlas_side(ctx: &GpuContext, first: &Impostor, n: usize) -> Result<u32> {
    let side = first.frames * first.resolution;
    let limits = ctx.device.limits();
    if side > limits.max_texture_dimension_2d || n as u32 > limits.max_texture_array_layers {
        return Err(Error::BadInput(format!(
            "the impostor atlases need {n} layers of {side}² but this GPU allows {} of {}²; bake with fewer impostor frames or a smaller impostor_resolution",
            limits.max_texture_array_layers, limits.max_texture_dimension_2d
        )));
    }
    // Each stored level is the texture's level of the same index.
    for m in 0..first.mip_levels {
        let (_, level_side) = first.level(m).ok_or_else(|| {
            Error::BadInput("an impostor record's levels do not match its size".into())
        })?;
        if level_side != (side >> m).max(1) {
            return Err(Error::BadInput(format!(
                "the impostor frames of {} px do not halve evenly down to level {m}: bake with a power-of-two impostor_resolution",
                first.resolution
            )));
        }
    }
    Ok(side)
}

/// The albedo and normal-depth atlases of `side`² with `list`'s impostors written in, one
/// layer each, and their bytes.
fn upload_atlases(
    ctx: &GpuContext,
    list: &[&Impostor],
    side: u32,
) -> Result<(wgpu::Texture, wgpu::Texture, u64)> {
    let n = list.len();
    let first = list[0];
    let make = |label: &str, format: wgpu::TextureFormat| {
        ctx.checked("allocating the impostor atlases", || {
            ctx.device.create_texture(&wgpu::TextureDescriptor {
                label: Some(label),
                size: wgpu::Extent3d {
                    width: side,
                    height: side,
                    depth_or_array_layers: n as u32,
                },
                mip_level_count: first.mip_levels,
                sample_count: 1,
                dimension: wgpu::TextureDimension::D2,
                format,
                usage: wgpu::TextureUsages::TEXTURE_BINDING | wgpu::TextureUsages::COPY_DST,
                view_formats: &[],
            })
        })
    };
    let albedo = make("impostor albedo", wgpu::TextureFormat::Rgba8UnormSrgb)?;
    let normal = make("impostor normal depth", wgpu::TextureFormat::Rgba8Unorm)?;
    let mut bytes = 0u64;
    for (layer, imp) in list.iter().enumerate() {
        for m in 0..imp.mip_levels {
            let Some((at, s)) = imp.level(m) else {
                continue;
            };
            let len = 4 * (s as usize) * (s as usize);
            for (texture, data) in [(&albedo, &imp.albedo), (&normal, &imp.normal_depth)] {
                let level = data.get(at..at + len).ok_or_else(|| {
                    Error::BadInput(format!(
                        "the impostor of species {layer} is shorter than its levels: bake the scene again"
                    ))
                })?;
                crate::render::pipelines::write_rgba8(
                    &ctx.queue,
                    texture,
                    m,
                    UVec3::new(0, 0, layer as u32),
                    level,
                    UVec3::new(s, s, 1),
                );
                bytes += len as u64;
            }
        }
    }
    Ok((albedo, normal, bytes))
}

impl ImpostorAssets {
    /// Drops the pipeline built so far.
    pub fn forget_pipeline(&mut self) {
        self.pipeline = None;
    }

    /// Uploads `baked`'s impostors for `world`'s species; fails with what to do when the
    /// bake has none or not one per species.
    pub fn new(ctx: &GpuContext, baked: &Baked, world: &World) -> Result<Self> {
        let n = world.species.len();
        let list = impostors_by_species(baked, n)?;
        let first = list[0];
        let side = atlas_side(ctx, first, n)?;
        let (albedo, normal, bytes) = upload_atlases(ctx, &list, side)?;
        let array = |t: &wgpu::Texture| {
            t.create_view(&wgpu::TextureViewDescriptor {
                dimension: Some(wgpu::TextureViewDimension::D2Array),
                ..Default::default()
            })
        };
        let sampler = ctx.device.create_sampler(&wgpu::SamplerDescriptor {
            label: Some("impostor"),
            address_mode_u: wgpu::AddressMode::ClampToEdge,
            address_mode_v: wgpu::AddressMode::ClampToEdge,
            mag_filter: wgpu::FilterMode::Linear,
            min_filter: wgpu::FilterMode::Linear,
            mipmap_filter: wgpu::MipmapFilterMode::Linear,
            ..Default::default()
        });
        let params = ImpostorParams {
            frames: first.frames,
            octa_layout: match first.layout {
                OctaLayout::Full => 0,
                OctaLayout::Hemi => 1,
            },
            resolution: first.resolution,
            mips: first.mip_levels.max(1),
            alpha_cutoff: ImpostorSettings::default().alpha_cutoff,
            parallax: 1,
            self_shadow: ImpostorSettings::default().self_shadow,
            _pad: 0,
        };
        let params_buffer = wgpu::util::DeviceExt::create_buffer_init(
            &ctx.device,
            &wgpu::util::BufferInitDescriptor {
                label: Some("impostor params"),
                contents: bytemuck::bytes_of(&params),
                usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            },
        );
        let records = storage_buffer_of::<ImpostorGpu>(&ctx.device, "impostors", 1024);
        let layout = bind_group_layout(&ctx.device);
        let (albedo, normal) = (array(&albedo), array(&normal));
        let bind_group = bind_group(
            ctx,
            &layout,
            (&records, &params_buffer),
            (&albedo, &normal),
            &sampler,
        );
        let species = list
            .iter()
            .enumerate()
            .map(|(layer, imp)| SpeciesImpostor {
                layer: layer as u32,
                center: Vec3::from(imp.center),
                radius: imp.radius,
                texel: 2.0 * imp.radius / imp.resolution.max(1) as f32,
            })
            .collect();
        Ok(Self {
            species,
            params,
            params_buffer,
            records,
            layout,
            bind_group,
            albedo,
            normal,
            sampler,
            pipeline: None,
            bytes,
        })
    }

    /// Frames per side and pixels a frame side.
    pub fn grid(&self) -> (u32, u32) {
        (self.params.frames, self.params.resolution)
    }

    /// `stats` with the atlases' layout and bytes filled in.
    pub fn with_atlas(&self, stats: ImpostorStats) -> ImpostorStats {
        let (frames, frame_px) = self.grid();
        ImpostorStats {
            frames,
            frame_px,
            atlas_bytes: self.bytes,
            ..stats
        }
    }

    /// Most records one frame can hold (`device`'s storage-buffer limit).
    pub fn max_records(device: &wgpu::Device) -> usize {
        device.limits().max_storage_buffer_binding_size as usize
            / std::mem::size_of::<ImpostorGpu>()
    }

    /// Uploads the frame's records and the knobs the shader reads.
    pub fn upload(&mut self, ctx: &GpuContext, records: &[ImpostorGpu], s: &ImpostorSettings) {
        if write_growing(ctx, &mut self.records, "impostors", records) {
            self.bind_group = bind_group(
                ctx,
                &self.layout,
                (&self.records, &self.params_buffer),
                (&self.albedo, &self.normal),
                &self.sampler,
            );
        }
        let params = ImpostorParams {
            alpha_cutoff: s.alpha_cutoff.clamp(0.0, 1.0),
            parallax: u32::from(s.parallax),
            self_shadow: s.self_shadow.max(0.0),
            ..self.params
        };
        if params != self.params {
            self.params = params;
            ctx.queue
                .write_buffer(&self.params_buffer, 0, bytemuck::bytes_of(&params));
        }
    }

    /// The pipeline for `format`, writing the parallax point's depth or the quad's
    /// (`parallax_depth`), built once per choice.
    pub fn ensure_pipeline(
        &mut self,
        device: &wgpu::Device,
        layouts: &Layouts,
        format: wgpu::TextureFormat,
        parallax_depth: bool,
    ) {
        if self
            .pipeline
            .as_ref()
            .is_some_and(|(f, d, _)| *f == format && *d == parallax_depth)
        {
            return;
        }
        let pipeline = crate::render::pipelines::blended_pipeline(
            device,
            crate::render::pipelines::Blended {
                label: "impostor.wgsl",
                layouts: [&layouts.frame, &self.layout],
                source: crate::render::shaders::impostor(),
                vertex: "vs_impostor",
                fragment: if parallax_depth {
                    "fs_impostor"
                } else {
                    "fs_impostor_quad"
                },
                format,
                blend: wgpu::BlendComponent::REPLACE,
                cull: None,
                depth: (crate::render::DEPTH_FORMAT, wgpu::CompareFunction::Greater),
                depth_write: true,
            },
        );
        self.pipeline = Some((format, parallax_depth, pipeline));
    }

    /// Draws `count` records (group 0 bound by the caller).
    pub fn draw(&self, pass: &mut wgpu::RenderPass<'_>, count: u32) {
        let Some((_, _, pipeline)) = &self.pipeline else {
            return;
        };
        if count == 0 {
            return;
        }
        pass.set_pipeline(pipeline);
        pass.set_bind_group(1, &self.bind_group, &[]);
        pass.draw(0..6, 0..count);
    }
}

fn bind_group_layout(device: &wgpu::Device) -> wgpu::BindGroupLayout {
    device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
        label: Some("impostor"),
        entries: &[
            storage_entry(0, wgpu::ShaderStages::VERTEX_FRAGMENT),
            buffer_entry(
                1,
                wgpu::ShaderStages::VERTEX_FRAGMENT,
                wgpu::BufferBindingType::Uniform,
            ),
            texture_entry(2, FILTERABLE, wgpu::TextureViewDimension::D2Array),
            texture_entry(3, FILTERABLE, wgpu::TextureViewDimension::D2Array),
            sampler_entry(4, wgpu::SamplerBindingType::Filtering),
        ],
    })
}

fn bind_group(
    ctx: &GpuContext,
    layout: &wgpu::BindGroupLayout,
    (records, params): (&wgpu::Buffer, &wgpu::Buffer),
    (albedo, normal): (&wgpu::TextureView, &wgpu::TextureView),
    sampler: &wgpu::Sampler,
) -> wgpu::BindGroup {
    ctx.device.create_bind_group(&wgpu::BindGroupDescriptor {
        label: Some("impostor"),
        layout,
        entries: &[
            wgpu::BindGroupEntry {
                binding: 0,
                resource: records.as_entire_binding(),
            },
            wgpu::BindGroupEntry {
                binding: 1,
                resource: params.as_entire_binding(),
            },
            wgpu::BindGroupEntry {
                binding: 2,
                resource: wgpu::BindingResource::TextureView(albedo),
            },
            wgpu::BindGroupEntry {
                binding: 3,
                resource: wgpu::BindingResource::TextureView(normal),
            },
            wgpu::BindGroupEntry {
                binding: 4,
                resource: wgpu::BindingResource::Sampler(sampler),
            },
        ],
    })
}
