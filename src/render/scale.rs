//! Render scale: the 3D view drawn at a fraction of the window's size and stretched over it
//! (`shaders/blit.wgsl`), as games do on slow machines; and the automatic mode that holds
//! a target frame time by lowering the fraction when frames are slow and raising it back
//! when there is room.

use super::GpuContext;
use super::pipelines::{FILTERABLE, sampler_entry, target_texture, texture_entry, wgsl_module};
use crate::Result;

/// The smallest fraction of the window the 3D view is drawn at.
pub const MIN_SCALE: f32 = 0.25;

/// The render scale's knobs.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RenderScale {
    /// Fraction of the window's width and height the 3D view is drawn at (MIN_SCALE..=1).
    pub scale: f32,
    /// Adjust `scale` every frame to hold `target_ms`.
    pub auto: bool,
    /// The frame time the automatic mode aims at (ms).
    pub target_ms: f32,
}

impl Default for RenderScale {
    fn default() -> Self {
        Self {
            scale: 1.0,
            auto: false,
            target_ms: 100.0,
        }
    }
}

impl RenderScale {
    /// The default for an adapter: on a software renderer automatic, starting from the
    /// smallest scale (a CPU cannot draw the forest at window size interactively, and a
    /// first frame at window size takes it most of a minute) and rising while frames are
    /// quick; full size otherwise.
    pub fn for_adapter(software: bool) -> Self {
        Self {
            auto: software,
            scale: if software { MIN_SCALE } else { 1.0 },
            ..Self::default()
        }
    }
}

/// The size the 3D view is drawn at for a `width` x `height` window.
pub fn scaled_size(width: u32, height: u32, scale: f32) -> (u32, u32) {
    let s = if scale.is_finite() {
        scale.clamp(MIN_SCALE, 1.0)
    } else {
        1.0
    };
    let f = |v: u32| ((v as f32 * s).round() as u32).clamp(1, v.max(1));
    (f(width), f(height))
}

/// The scales the automatic mode steps between, largest first. A ladder rather than a
/// continuous factor: every change re-creates the 3D view's targets, and a factor that
/// drifts with the machine's load makes a new size each time (the allocator keeps blocks
/// of the old ones: a one-hour soak beside other work grew by steps of 30-40 MB).
pub const AUTO_SCALES: [f32; 10] = [1.0, 0.9, 0.8, 0.7, 0.6, 0.5, 0.42, 0.35, 0.3, MIN_SCALE];

/// The automatic mode's next scale after a frame of `frame_ms`. When the frame took more
/// than 10 % over the target: down the ladder of [`AUTO_SCALES`] to the rung where the frame,
/// its cost taken as following its pixels, would take about the target (at least one rung),
/// so that a frame of many seconds does not take many more to recover. When it took under
/// 70 % of the target: one rung up (the gap keeps it from hunting). A scale between rungs
/// (set by the slider) goes to the nearest rung first.
pub fn next_scale(scale: f32, frame_ms: f32, target_ms: f32) -> f32 {
    if !(frame_ms.is_finite() && frame_ms > 0.0 && target_ms > 0.0) {
        return scale;
    }
    let rung = AUTO_SCALES
        .iter()
        .enumerate()
        .min_by(|a, b| (a.1 - scale).abs().total_cmp(&(b.1 - scale).abs()))
        .map_or(0, |(i, _)| i);
    let last = AUTO_SCALES.len() - 1;
    let next = if frame_ms > 1.1 * target_ms {
        let fits = AUTO_SCALES[rung] * (target_ms / frame_ms).sqrt();
        let to = AUTO_SCALES.iter().position(|&s| s <= fits).unwrap_or(last);
        to.max(rung + 1).min(last)
    } else if frame_ms < 0.7 * target_ms {
        rung.saturating_sub(1)
    } else {
        rung
    };
    AUTO_SCALES[next]
}

/// The offscreen texture the scaled 3D view is drawn into, and the pass that stretches it
/// over the window.
pub struct Upscaler {
    texture: Option<(
        wgpu::Texture,
        wgpu::TextureView,
        (u32, u32),
        wgpu::TextureFormat,
    )>,
    sampler: wgpu::Sampler,
    layout: wgpu::BindGroupLayout,
    pipelines: std::collections::HashMap<wgpu::TextureFormat, wgpu::RenderPipeline>,
}

impl Upscaler {
    pub fn new(ctx: &GpuContext) -> Self {
        let sampler = ctx.device.create_sampler(&wgpu::SamplerDescriptor {
            label: Some("render scale"),
            mag_filter: wgpu::FilterMode::Linear,
            min_filter: wgpu::FilterMode::Linear,
            ..Default::default()
        });
        let layout = ctx
            .device
            .create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
                label: Some("render scale"),
                entries: &[
                    texture_entry(0, FILTERABLE, wgpu::TextureViewDimension::D2),
                    sampler_entry(1, wgpu::SamplerBindingType::Filtering),
                ],
            });
        Self {
            texture: None,
            sampler,
            layout,
            pipelines: Default::default(),
        }
    }

    /// The texture to draw the scaled view into: `size`, in `format` (re-made when either
    /// changes).
    pub fn target(
        &mut self,
        ctx: &GpuContext,
        size: (u32, u32),
        format: wgpu::TextureFormat,
    ) -> Result<&wgpu::TextureView> {
        super::target::check_size(size.0, size.1, Some(ctx))?;
        let stale = self
            .texture
            .as_ref()
            .is_none_or(|t| t.2 != size || t.3 != format);
        if stale {
            let texture = ctx.checked("allocating the scaled view", || {
                target_texture(
                    &ctx.device,
                    "render scale",
                    glam::UVec3::new(size.0, size.1, 1),
                    format,
                    wgpu::TextureUsages::RENDER_ATTACHMENT | wgpu::TextureUsages::TEXTURE_BINDING,
                )
            })?;
            let view = texture.create_view(&Default::default());
            self.texture = Some((texture, view, size, format));
        }
        match &self.texture {
            Some(t) => Ok(&t.1),
            None => Err(crate::Error::Gpu("the scaled view was not created".into())),
        }
    }

    /// Stretches the last `target` over `dst` (of `format`), and submits.
    pub fn blit(&mut self, ctx: &GpuContext, dst: &wgpu::TextureView, format: wgpu::TextureFormat) {
        let Some((_, src, _, _)) = &self.texture else {
            return;
        };
        let layout = &self.layout;
        let pipeline = self.pipelines.entry(format).or_insert_with(|| {
            let module = wgsl_module(&ctx.device, "blit.wgsl", &super::shaders::blit());
            let pl = ctx
                .device
                .create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
                    label: Some("render scale"),
                    bind_group_layouts: &[Some(layout)],
                    immediate_size: 0,
                });
            ctx.device
                .create_render_pipeline(&wgpu::RenderPipelineDescriptor {
                    label: Some("render scale"),
                    layout: Some(&pl),
                    vertex: wgpu::VertexState {
                        module: &module,
                        entry_point: Some("vs_blit"),
                        compilation_options: Default::default(),
                        buffers: &[],
                    },
                    primitive: Default::default(),
                    depth_stencil: None,
                    multisample: Default::default(),
                    fragment: Some(wgpu::FragmentState {
                        module: &module,
                        entry_point: Some("fs_blit"),
                        compilation_options: Default::default(),
                        targets: &[Some(format.into())],
                    }),
                    multiview_mask: None,
                    cache: None,
                })
        });
        let bind_group = ctx.device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("render scale"),
            layout: &self.layout,
            entries: &[
                wgpu::BindGroupEntry {
                    binding: 0,
                    resource: wgpu::BindingResource::TextureView(src),
                },
                wgpu::BindGroupEntry {
                    binding: 1,
                    resource: wgpu::BindingResource::Sampler(&self.sampler),
                },
            ],
        });
        let mut encoder = ctx
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                label: Some("render scale"),
            });
        {
            let mut pass = encoder.begin_render_pass(&wgpu::RenderPassDescriptor {
                label: Some("render scale"),
                color_attachments: &[Some(wgpu::RenderPassColorAttachment {
                    view: dst,
                    depth_slice: None,
                    resolve_target: None,
                    ops: wgpu::Operations {
                        load: wgpu::LoadOp::Clear(wgpu::Color::BLACK),
                        store: wgpu::StoreOp::Store,
                    },
                })],
                depth_stencil_attachment: None,
                timestamp_writes: None,
                occlusion_query_set: None,
                multiview_mask: None,
            });
            pass.set_pipeline(pipeline);
            pass.set_bind_group(0, &bind_group, &[]);
            pass.draw(0..3, 0..1);
        }
        ctx.queue.submit([encoder.finish()]);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_scaled_size_is_the_fraction_within_bounds() {
        assert_eq!(scaled_size(1280, 720, 0.5), (640, 360));
        assert_eq!(scaled_size(1280, 720, 1.0), (1280, 720));
        assert_eq!(
            scaled_size(1280, 720, 0.01),
            (320, 180),
            "at least MIN_SCALE"
        );
        assert_eq!(scaled_size(1280, 720, f32::NAN), (1280, 720));
        assert_eq!(scaled_size(1, 1, 0.25), (1, 1));
    }

    #[test]
    fn the_automatic_mode_lowers_the_scale_when_frames_are_slow_and_raises_it_back() {
        let mut s = 1.0;
        // A frame 4 times over the target: straight to the rung of a quarter of the
        // pixels (half the side).
        s = next_scale(s, 200.0, 50.0);
        assert_eq!(s, 0.5);
        // Just over it: one rung down.
        assert_eq!(next_scale(0.5, 56.0, 50.0), 0.42);
        // A first frame of a minute: to the floor at once.
        assert_eq!(next_scale(1.0, 60_000.0, 100.0), MIN_SCALE);
        // Twice the target at 0.8: 0.8 / sqrt(2) = 0.57, the rung under it 0.5.
        assert_eq!(next_scale(0.8, 100.0, 50.0), 0.5);
        for _ in 0..100 {
            s = next_scale(s, 200.0, 50.0);
        }
        assert_eq!(s, MIN_SCALE);
        // Within the band it holds; fast frames raise it back to 1, a rung a frame.
        assert_eq!(next_scale(0.6, 45.0, 50.0), 0.6);
        assert_eq!(next_scale(0.25, 10.0, 50.0), 0.3);
        // A slider's scale between rungs joins the ladder.
        assert_eq!(next_scale(0.63, 45.0, 50.0), 0.6);
        assert_eq!(next_scale(0.63, 60.0, 50.0), 0.5);
        for _ in 0..100 {
            s = next_scale(s, 10.0, 50.0);
        }
        assert_eq!(s, 1.0);
        assert_eq!(next_scale(0.5, f32::NAN, 50.0), 0.5);
        assert!(RenderScale::for_adapter(true).auto && !RenderScale::for_adapter(false).auto);
        assert_eq!(RenderScale::for_adapter(true).scale, MIN_SCALE);
        assert_eq!(RenderScale::for_adapter(false).scale, 1.0);
    }

    #[test]
    fn a_load_that_comes_and_goes_makes_few_sizes() {
        // Frame times swinging with the machine's load, 10,000 frames: the automatic mode
        // visits at most the ladder's sizes, so the view's targets come in at most 10
        // sizes per window size, however long it runs.
        let mut s = 1.0;
        let mut sizes = std::collections::HashSet::new();
        let mut x = 12345u32;
        for _ in 0..10_000 {
            x = x.wrapping_mul(1_103_515_245).wrapping_add(12345);
            let ms = 20.0 + (x >> 16) as f32 % 200.0;
            s = next_scale(s, ms, 100.0);
            sizes.insert(scaled_size(1280, 720, s));
        }
        assert!(sizes.len() <= AUTO_SCALES.len(), "{} sizes", sizes.len());
        assert!(sizes.len() >= 3, "it moved: {sizes:?}");
    }
}
