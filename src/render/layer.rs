//! The trees' layer: a method's blended trees drawn front to back into a transparent
//! target of their own after the main pass, then put over the frame once
//! (`shaders/layer.wgsl`).
//!
//! Drawn back to front over the frame, every blended fragment is shaded however much is
//! already in front of it: over a dense stand a ray crosses 100 crowns and the last 90 add
//! almost nothing. Front to back ("under": each fragment adds what the layer in front of it
//! still lets through) the picture is the same sum, and between batches of trees a pixel
//! the layer has made opaque gets the near plane's depth, so the early depth test skips
//! every farther tree's fragments there.

use std::collections::HashMap;

use super::frame_bindings::DepthTarget;
use super::pipelines::{target_texture, texture_entry, wgsl_module};
use super::{DEPTH_FORMAT, GpuContext};
use crate::Result;

/// The layer's format: linear light with its alpha, in half floats (the sum of a hundred
/// fragments keeps its precision).
pub const LAYER_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Rgba16Float;

/// Premultiplied "under": the layer gains the fragment times what the layer lets through,
/// `L += (1 - L_alpha) F` (colour and alpha alike).
pub const UNDER: wgpu::BlendComponent = wgpu::BlendComponent {
    src_factor: wgpu::BlendFactor::OneMinusDstAlpha,
    dst_factor: wgpu::BlendFactor::One,
    operation: wgpu::BlendOperation::Add,
};

/// The layer's target (sized to the frame), its bind group and its two full-screen passes.
pub struct TreeLayer {
    layout: wgpu::BindGroupLayout,
    module: wgpu::ShaderModule,
    pipeline_layout: wgpu::PipelineLayout,
    opaque: wgpu::RenderPipeline,
    composite: HashMap<wgpu::TextureFormat, wgpu::RenderPipeline>,
    target: Option<LayerTarget>,
}

struct LayerTarget {
    size: (u32, u32),
    view: wgpu::TextureView,
    bind_group: wgpu::BindGroup,
}

impl TreeLayer {
    pub fn new(device: &wgpu::Device) -> Self {
        let layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("trees' layer"),
            entries: &[texture_entry(
                0,
                wgpu::TextureSampleType::Float { filterable: false },
                wgpu::TextureViewDimension::D2,
            )],
        });
        let module = wgsl_module(device, "layer.wgsl", &super::shaders::layer());
        let pipeline_layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("trees' layer"),
            bind_group_layouts: &[Some(&layout)],
            immediate_size: 0,
        });
        // Depth only: the near plane where the layer is opaque (the rest discarded).
        let opaque = device.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
            label: Some("trees' layer: opaque pixels"),
            layout: Some(&pipeline_layout),
            vertex: wgpu::VertexState {
                module: &module,
                entry_point: Some("vs_layer"),
                compilation_options: Default::default(),
                buffers: &[],
            },
            primitive: Default::default(),
            depth_stencil: Some(wgpu::DepthStencilState {
                format: DEPTH_FORMAT,
                depth_write_enabled: Some(true),
                depth_compare: Some(wgpu::CompareFunction::Always),
                stencil: Default::default(),
                bias: Default::default(),
            }),
            multisample: Default::default(),
            fragment: Some(wgpu::FragmentState {
                module: &module,
                entry_point: Some("fs_opaque"),
                compilation_options: Default::default(),
                targets: &[],
            }),
            multiview_mask: None,
            cache: None,
        });
        Self {
            layout,
            module,
            pipeline_layout,
            opaque,
            composite: HashMap::new(),
            target: None,
        }
    }

    /// Makes the layer `width` x `height` and the pass that puts it over a `format` frame.
    pub fn ensure(
        &mut self,
        ctx: &GpuContext,
        width: u32,
        height: u32,
        format: wgpu::TextureFormat,
    ) -> Result<()> {
        if self
            .target
            .as_ref()
            .is_none_or(|t| t.size != (width, height))
        {
            let texture = ctx.checked("allocating the trees' layer", || {
                target_texture(
                    &ctx.device,
                    "trees' layer",
                    glam::UVec3::new(width, height, 1),
                    LAYER_FORMAT,
                    // Written by the tile compositor too.
                    wgpu::TextureUsages::RENDER_ATTACHMENT
                        | wgpu::TextureUsages::TEXTURE_BINDING
                        | wgpu::TextureUsages::STORAGE_BINDING,
                )
            })?;
            let view = texture.create_view(&Default::default());
            let bind_group = ctx.device.create_bind_group(&wgpu::BindGroupDescriptor {
                label: Some("trees' layer"),
                layout: &self.layout,
                entries: &[wgpu::BindGroupEntry {
                    binding: 0,
                    resource: wgpu::BindingResource::TextureView(&view),
                }],
            });
            self.target = Some(LayerTarget {
                size: (width, height),
                view,
                bind_group,
            });
        }
        if !self.composite.contains_key(&format) {
            let p = ctx.checked("building the trees' layer pipeline", || {
                self.composite_pipeline(&ctx.device, format)
            })?;
            self.composite.insert(format, p);
        }
        Ok(())
    }

    fn composite_pipeline(
        &self,
        device: &wgpu::Device,
        format: wgpu::TextureFormat,
    ) -> wgpu::RenderPipeline {
        device.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
            label: Some("trees' layer over the frame"),
            layout: Some(&self.pipeline_layout),
            vertex: wgpu::VertexState {
                module: &self.module,
                entry_point: Some("vs_layer"),
                compilation_options: Default::default(),
                buffers: &[],
            },
            primitive: Default::default(),
            depth_stencil: None,
            multisample: Default::default(),
            fragment: Some(wgpu::FragmentState {
                module: &self.module,
                entry_point: Some("fs_composite"),
                compilation_options: Default::default(),
                targets: &[Some(wgpu::ColorTargetState {
                    format,
                    // Premultiplied "over".
                    blend: Some(wgpu::BlendState::PREMULTIPLIED_ALPHA_BLENDING),
                    write_mask: wgpu::ColorWrites::ALL,
                })],
            }),
            multiview_mask: None,
            cache: None,
        })
    }

    /// A pass drawing one batch of trees into the layer (cleared when `first`) against the
    /// frame's `depth` (kept for the next batch).
    pub fn batch_pass<'e>(
        &self,
        encoder: &'e mut wgpu::CommandEncoder,
        depth: &DepthTarget,
        first: bool,
        timestamp_writes: Option<wgpu::RenderPassTimestampWrites<'_>>,
    ) -> Option<wgpu::RenderPass<'e>> {
        let target = self.target.as_ref()?;
        Some(encoder.begin_render_pass(&wgpu::RenderPassDescriptor {
            label: Some("trees' layer: batch"),
            color_attachments: &[Some(wgpu::RenderPassColorAttachment {
                view: &target.view,
                depth_slice: None,
                resolve_target: None,
                ops: wgpu::Operations {
                    load: if first {
                        wgpu::LoadOp::Clear(wgpu::Color::TRANSPARENT)
                    } else {
                        wgpu::LoadOp::Load
                    },
                    store: wgpu::StoreOp::Store,
                },
            })],
            depth_stencil_attachment: Some(kept_depth(depth)),
            timestamp_writes,
            occlusion_query_set: None,
            multiview_mask: None,
        }))
    }

    /// The layer's texture (None before [`Self::ensure`]).
    pub fn view(&self) -> Option<&wgpu::TextureView> {
        self.target.as_ref().map(|t| &t.view)
    }

    /// Gives the pixels the layer has made opaque the near plane's depth.
    pub fn mark_opaque(&self, encoder: &mut wgpu::CommandEncoder, depth: &DepthTarget) {
        let Some(target) = &self.target else {
            return;
        };
        let mut pass = encoder.begin_render_pass(&wgpu::RenderPassDescriptor {
            label: Some("trees' layer: opaque pixels"),
            color_attachments: &[],
            depth_stencil_attachment: Some(kept_depth(depth)),
            timestamp_writes: None,
            occlusion_query_set: None,
            multiview_mask: None,
        });
        pass.set_pipeline(&self.opaque);
        pass.set_bind_group(0, &target.bind_group, &[]);
        pass.draw(0..3, 0..1);
    }

    /// Puts the layer over the frame's colour `target` (of `format`, as
    /// [`Self::ensure`] was given).
    pub fn composite(
        &self,
        encoder: &mut wgpu::CommandEncoder,
        target: &wgpu::TextureView,
        format: wgpu::TextureFormat,
        timestamp_writes: Option<wgpu::RenderPassTimestampWrites<'_>>,
    ) {
        let (Some(layer), Some(pipeline)) = (&self.target, self.composite.get(&format)) else {
            return;
        };
        let mut pass = encoder.begin_render_pass(&wgpu::RenderPassDescriptor {
            label: Some("trees' layer over the frame"),
            color_attachments: &[Some(wgpu::RenderPassColorAttachment {
                view: target,
                depth_slice: None,
                resolve_target: None,
                ops: wgpu::Operations {
                    load: wgpu::LoadOp::Load,
                    store: wgpu::StoreOp::Store,
                },
            })],
            depth_stencil_attachment: None,
            timestamp_writes,
            occlusion_query_set: None,
            multiview_mask: None,
        });
        pass.set_pipeline(pipeline);
        pass.set_bind_group(0, &layer.bind_group, &[]);
        pass.draw(0..3, 0..1);
    }
}

/// The frame's depth, loaded and kept for the next pass.
fn kept_depth(depth: &DepthTarget) -> wgpu::RenderPassDepthStencilAttachment<'_> {
    wgpu::RenderPassDepthStencilAttachment {
        view: &depth.view,
        depth_ops: Some(wgpu::Operations {
            load: wgpu::LoadOp::Load,
            store: wgpu::StoreOp::Store,
        }),
        stencil_ops: None,
    }
}
