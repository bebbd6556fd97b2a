//! The `btf` billboards' render pipelines: the main view's (premultiplied "over") and the
//! ground alpha map's (transmittance multiplied), both over `billboard.wgsl`'s quad.

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
        (crate::render::SHADOW_FORMAT, wgpu::CompareFunction::Less),
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
