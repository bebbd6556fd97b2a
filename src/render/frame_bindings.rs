//! What every colour pass binds: the frame's group 0 (uniforms, the shadow cascades' maps,
//! the ground maps and their samplers, the reference's sky visibility) and the depth
//! buffer of the target's size.

use super::ground::GroundTextures;
use super::pipelines::Layouts;
use super::shadow::CascadeMaps;
use super::{DEPTH_FORMAT, GpuContext};
use crate::Result;

/// The cascades' maps and the frame's bind group (group 0 of every colour pass), which
/// binds them with the ground maps.
pub struct FrameBindings {
    pub cascades: CascadeMaps,
    pub bind_group: wgpu::BindGroup,
    /// It binds the ground maps (not their placeholders).
    pub ground_maps: bool,
    /// It binds the sky visibility (not its placeholder).
    pub sky_volume: bool,
    /// The pixels of the overdraw counters it binds.
    pub overdraw_pixels: u64,
}

/// The sky visibility group 0 binds: (3D texture, placement uniforms, not the placeholder).
pub type SkyBinding<'a> = (&'a wgpu::TextureView, &'a wgpu::Buffer, bool);

impl FrameBindings {
    /// Group 0 over `frame_uniforms`, the `cascades`, the `ground` textures and the
    /// (shadow comparison, ground) samplers and the `sky` visibility.
    #[allow(clippy::too_many_arguments)]
    pub fn new(
        ctx: &GpuContext,
        layouts: &Layouts,
        frame_uniforms: &wgpu::Buffer,
        cascades: CascadeMaps,
        samplers: (&wgpu::Sampler, &wgpu::Sampler),
        ground: &GroundTextures,
        sky: SkyBinding<'_>,
        overdraw: &super::overdraw::OverdrawCounts,
    ) -> Self {
        let bind_group = ctx.device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("frame"),
            layout: &layouts.frame,
            entries: &[
                wgpu::BindGroupEntry {
                    binding: 0,
                    resource: frame_uniforms.as_entire_binding(),
                },
                wgpu::BindGroupEntry {
                    binding: 1,
                    resource: wgpu::BindingResource::TextureView(&cascades.array_view),
                },
                wgpu::BindGroupEntry {
                    binding: 2,
                    resource: wgpu::BindingResource::Sampler(samplers.0),
                },
                wgpu::BindGroupEntry {
                    binding: 3,
                    resource: wgpu::BindingResource::TextureView(&ground.alpha),
                },
                wgpu::BindGroupEntry {
                    binding: 4,
                    resource: wgpu::BindingResource::Sampler(samplers.1),
                },
                wgpu::BindGroupEntry {
                    binding: 5,
                    resource: wgpu::BindingResource::TextureView(&ground.depth_sampled),
                },
                wgpu::BindGroupEntry {
                    binding: 6,
                    resource: wgpu::BindingResource::TextureView(sky.0),
                },
                wgpu::BindGroupEntry {
                    binding: 7,
                    resource: sky.1.as_entire_binding(),
                },
                wgpu::BindGroupEntry {
                    binding: 8,
                    resource: overdraw.buffer().as_entire_binding(),
                },
            ],
        });
        Self {
            cascades,
            bind_group,
            ground_maps: !ground.is_placeholder(),
            sky_volume: sky.2,
            overdraw_pixels: overdraw.pixels(),
        }
    }
}

/// The depth buffer of the main pass.
pub struct DepthTarget {
    pub size: (u32, u32),
    pub view: wgpu::TextureView,
}

impl DepthTarget {
    pub fn new(ctx: &GpuContext, width: u32, height: u32) -> Result<Self> {
        let texture = ctx.checked("allocating the depth buffer", || {
            super::pipelines::target_texture(
                &ctx.device,
                "depth",
                glam::UVec3::new(width, height, 1),
                DEPTH_FORMAT,
                // Read by the tile compositor.
                wgpu::TextureUsages::RENDER_ATTACHMENT | wgpu::TextureUsages::TEXTURE_BINDING,
            )
        })?;
        Ok(Self {
            size: (width, height),
            view: texture.create_view(&Default::default()),
        })
    }
}

impl DepthTarget {
    /// A pass drawing into `target` and this depth buffer: both cleared (the colour to
    /// `clear`, depth to the far plane) or, without `clear`, both loaded; the depth kept for
    /// a later pass when `keep_depth`; timed by `timestamp_writes` when given.
    pub fn color_pass<'e>(
        &self,
        encoder: &'e mut wgpu::CommandEncoder,
        label: &str,
        target: &wgpu::TextureView,
        clear: Option<wgpu::Color>,
        keep_depth: bool,
        timestamp_writes: Option<wgpu::RenderPassTimestampWrites<'_>>,
    ) -> wgpu::RenderPass<'e> {
        encoder.begin_render_pass(&wgpu::RenderPassDescriptor {
            label: Some(label),
            color_attachments: &[Some(wgpu::RenderPassColorAttachment {
                view: target,
                depth_slice: None,
                resolve_target: None,
                ops: wgpu::Operations {
                    load: clear.map_or(wgpu::LoadOp::Load, wgpu::LoadOp::Clear),
                    store: wgpu::StoreOp::Store,
                },
            })],
            depth_stencil_attachment: Some(wgpu::RenderPassDepthStencilAttachment {
                view: &self.view,
                depth_ops: Some(wgpu::Operations {
                    // Reversed Z: the far plane is 0.
                    load: clear.map_or(wgpu::LoadOp::Load, |_| wgpu::LoadOp::Clear(0.0)),
                    store: if keep_depth {
                        wgpu::StoreOp::Store
                    } else {
                        wgpu::StoreOp::Discard
                    },
                }),
                stencil_ops: None,
            }),
            timestamp_writes,
            occlusion_query_set: None,
            multiview_mask: None,
        })
    }
}
