//! The `btf` billboards' render pipelines: the main view's (premultiplied "over") and the
//! ground alpha map's (transmittance multiplied), both over `billboard.wgsl`'s quad; and
//! the bind group they read.

use crate::render::GpuContext;
use crate::render::pipelines::{FILTERABLE, sampler_entry, storage_entry, texture_entry};

pub(super) fn build_opacity_pipeline(
    device: &wgpu::Device,
    frame_layout: &wgpu::BindGroupLayout,
    btf_layout: &wgpu::BindGroupLayout,
) -> wgpu::RenderPipeline {
    // dst = dst * (1 - alpha): transmittance multiplies.
    let transmit = wgpu::BlendComponent {
        src_factor: wgpu::BlendFactor::Zero,
        dst_factor: wgpu::BlendFactor::OneMinusSrcAlpha,
        operation: wgpu::BlendOperation::Add,
    };
    billboard_pipeline(
        device,
        [frame_layout, btf_layout],
        ("ground_map.wgsl", crate::render::shaders::ground_map()),
        "fs_opacity",
        crate::render::GROUND_FORMAT,
        transmit,
        (
            crate::render::GROUND_DEPTH_FORMAT,
            wgpu::CompareFunction::Less,
        ),
    )
}

pub(super) fn build_pipeline(
    device: &wgpu::Device,
    frame_layout: &wgpu::BindGroupLayout,
    btf_layout: &wgpu::BindGroupLayout,
    format: wgpu::TextureFormat,
) -> wgpu::RenderPipeline {
    // Premultiplied "over": T = M + (1 - M_alpha) T0.
    let over = wgpu::BlendComponent {
        src_factor: wgpu::BlendFactor::One,
        dst_factor: wgpu::BlendFactor::OneMinusSrcAlpha,
        operation: wgpu::BlendOperation::Add,
    };
    // Reversed Z in the main view.
    billboard_pipeline(
        device,
        [frame_layout, btf_layout],
        ("btf.wgsl", crate::render::shaders::btf()),
        "fs_billboard",
        format,
        over,
        (crate::render::DEPTH_FORMAT, wgpu::CompareFunction::Greater),
    )
}

/// The billboards drawn front to back into the trees' layer ("under",
/// [`crate::render::layer`]), depth-tested against the frame's depth.
pub(super) fn build_layer_pipeline(
    device: &wgpu::Device,
    frame_layout: &wgpu::BindGroupLayout,
    btf_layout: &wgpu::BindGroupLayout,
) -> wgpu::RenderPipeline {
    billboard_pipeline(
        device,
        [frame_layout, btf_layout],
        ("btf.wgsl", crate::render::shaders::btf()),
        "fs_billboard",
        crate::render::layer::LAYER_FORMAT,
        crate::render::layer::UNDER,
        (crate::render::DEPTH_FORMAT, wgpu::CompareFunction::Greater),
    )
}

/// A pipeline drawing the billboards of `billboard.wgsl` with `fragment` of the module
/// `source` (named, source), blended by `blend`,
/// depth-tested (never written) against `depth`.
fn billboard_pipeline(
    device: &wgpu::Device,
    layouts: [&wgpu::BindGroupLayout; 2],
    source: (&str, String),
    fragment: &str,
    format: wgpu::TextureFormat,
    blend: wgpu::BlendComponent,
    depth: (wgpu::TextureFormat, wgpu::CompareFunction),
) -> wgpu::RenderPipeline {
    crate::render::pipelines::blended_pipeline(
        device,
        crate::render::pipelines::Blended {
            label: source.0,
            layouts,
            source: source.1,
            vertex: "vs_billboard",
            fragment,
            format,
            blend,
            cull: None,
            depth,
            depth_write: false,
        },
    )
}

/// The btf pass's bind group: billboards, view axes, the image atlas and its sampler (seen
/// by the tile compositor's compute passes too).
pub(super) fn btf_layout(device: &wgpu::Device) -> wgpu::BindGroupLayout {
    let all = wgpu::ShaderStages::VERTEX_FRAGMENT | wgpu::ShaderStages::COMPUTE;
    let compute_too = |mut e: wgpu::BindGroupLayoutEntry| {
        e.visibility |= wgpu::ShaderStages::COMPUTE;
        e
    };
    device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
        label: Some("btf"),
        entries: &[
            storage_entry(0, all),
            storage_entry(1, all),
            compute_too(texture_entry(
                2,
                FILTERABLE,
                wgpu::TextureViewDimension::D2Array,
            )),
            compute_too(sampler_entry(3, wgpu::SamplerBindingType::Filtering)),
        ],
    })
}

pub(super) fn make_bind_group(
    ctx: &GpuContext,
    layout: &wgpu::BindGroupLayout,
    billboards: &wgpu::Buffer,
    view_axes: &wgpu::Buffer,
    view: &wgpu::TextureView,
    sampler: &wgpu::Sampler,
) -> wgpu::BindGroup {
    ctx.device.create_bind_group(&wgpu::BindGroupDescriptor {
        label: Some("btf"),
        layout,
        entries: &[
            wgpu::BindGroupEntry {
                binding: 0,
                resource: billboards.as_entire_binding(),
            },
            wgpu::BindGroupEntry {
                binding: 1,
                resource: view_axes.as_entire_binding(),
            },
            wgpu::BindGroupEntry {
                binding: 2,
                resource: wgpu::BindingResource::TextureView(view),
            },
            wgpu::BindGroupEntry {
                binding: 3,
                resource: wgpu::BindingResource::Sampler(sampler),
            },
        ],
    })
}
