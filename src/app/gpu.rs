//! The viewer's GPU side: the window's surface, the device, the renderer and egui's
//! renderer, made at start and again when the device is lost, and the surface's next
//! texture.

use std::sync::Arc;

use winit::event_loop::ActiveEventLoop;
use winit::window::Window;

use super::App;
use crate::render::{AdapterPreference, GpuContext, Renderer};
use crate::{Error, Result};

pub(super) struct Running {
    pub(super) window: Arc<Window>,
    pub(super) surface: wgpu::Surface<'static>,
    pub(super) config: wgpu::SurfaceConfiguration,
    /// Format of the view the 3D scene is drawn through (sRGB where the surface allows).
    pub(super) scene_format: wgpu::TextureFormat,
    pub(super) ctx: GpuContext,
    pub(super) renderer: Renderer,
    pub(super) egui_state: egui_winit::State,
    pub(super) egui_renderer: egui_wgpu::Renderer,
    /// Draws the 3D view at the render scale and stretches it over the window.
    pub(super) upscaler: crate::render::scale::Upscaler,
}

impl Running {
    /// The surface's next texture to draw into; none this frame when the window is hidden or
    /// the surface had to be configured again.
    pub(super) fn next_texture(&mut self) -> Option<wgpu::SurfaceTexture> {
        match self.surface.get_current_texture() {
            wgpu::CurrentSurfaceTexture::Success(t)
            | wgpu::CurrentSurfaceTexture::Suboptimal(t) => Some(t),
            wgpu::CurrentSurfaceTexture::Timeout | wgpu::CurrentSurfaceTexture::Occluded => None,
            wgpu::CurrentSurfaceTexture::Outdated | wgpu::CurrentSurfaceTexture::Lost => {
                self.surface.configure(&self.ctx.device, &self.config);
                None
            }
            other => {
                log::warn!("could not get the next frame: {other:?}");
                None
            }
        }
    }
}

impl App {
    /// The GPU side of the viewer: its window (`window`, or a new one), surface, device and
    /// renderer.
    pub(super) fn start(
        &mut self,
        event_loop: &ActiveEventLoop,
        window: Option<Arc<Window>>,
    ) -> Result<Running> {
        let window = match window {
            Some(w) => w,
            None => {
                let attrs = Window::default_attributes()
                    .with_title(self.title.clone())
                    .with_inner_size(winit::dpi::LogicalSize::new(1280.0, 720.0));
                Arc::new(
                    event_loop
                        .create_window(attrs)
                        .map_err(|e| Error::Window(e.to_string()))?,
                )
            }
        };
        let instance = wgpu::Instance::new(crate::render::context::instance_descriptor(Some(
            Box::new(event_loop.owned_display_handle()),
        )));
        let surface = instance.create_surface(window.clone())?;
        let ctx = GpuContext::for_surface(instance, &surface, AdapterPreference::Default)?;
        let size = window.inner_size();
        let mut config = surface
            .get_default_config(&ctx.adapter, size.width.max(1), size.height.max(1))
            .ok_or_else(|| {
                Error::Gpu("the window surface is not supported by the adapter".into())
            })?;
        // The 3D view is drawn through an sRGB view (the render core writes linear colour),
        // egui through a plain one (it blends in gamma space), both on the same texture.
        let caps = surface.get_capabilities(&ctx.adapter);
        let plain = caps
            .formats
            .iter()
            .copied()
            .find(|f| !f.is_srgb() && f.add_srgb_suffix().is_srgb())
            .unwrap_or(config.format);
        config.format = plain;
        let scene_format = plain.add_srgb_suffix();
        config.view_formats = if scene_format == plain {
            vec![]
        } else {
            vec![scene_format]
        };
        config.present_mode = wgpu::PresentMode::AutoVsync;
        if size.width > 0 && size.height > 0 {
            surface.configure(&ctx.device, &config);
        }
        let renderer = Renderer::new(&ctx, &self.world)?;
        let egui_ctx = egui::Context::default();
        let egui_state = egui_winit::State::new(
            egui_ctx,
            egui::ViewportId::ROOT,
            &window,
            Some(window.scale_factor() as f32),
            None,
            Some(ctx.device.limits().max_texture_dimension_2d as usize),
        );
        let egui_renderer =
            egui_wgpu::Renderer::new(&ctx.device, config.format, Default::default());
        self.stats.adapter = ctx.adapter_name();
        self.stats.trees_total = self.world.forest.instances.len();
        if self.options.render_scale.is_none() && !self.scale_chosen {
            // A software renderer starts on the automatic render scale.
            let software = ctx.adapter.get_info().device_type == wgpu::DeviceType::Cpu;
            self.frame.render_scale = crate::render::scale::RenderScale::for_adapter(software);
            self.scale_chosen = true;
        }
        let upscaler = crate::render::scale::Upscaler::new(&ctx);
        Ok(Running {
            upscaler,
            window,
            surface,
            config,
            scene_format,
            ctx,
            renderer,
            egui_state,
            egui_renderer,
        })
    }

    /// Checks the device before a frame (destroying it first at the frame
    /// `CANOPY_TEST_LOSE_DEVICE_AT_FRAME` names). A lost device is replaced by a new device,
    /// surface and renderer; the bake comes back from the cache (or is baked again) as at
    /// start. Returns whether the device was lost: nothing is drawn in that frame.
    pub(super) fn device_lost(&mut self, event_loop: &ActiveEventLoop) -> bool {
        let Some(r) = &mut self.running else {
            return false;
        };
        if self.lose_device_at == Some(self.frames) {
            self.lose_device_at = None;
            r.ctx.device.destroy();
            let _ = r.ctx.device.poll(wgpu::PollType::Poll);
        }
        if !r.ctx.is_lost() {
            return false;
        }
        log::warn!("the GPU device was lost: creating a new one");
        let window = r.window.clone();
        self.running = None;
        self.bake_job = None;
        self.rebake = None;
        match self.start(event_loop, Some(window)) {
            Ok(r) => {
                r.window.request_redraw();
                self.running = Some(r);
                self.message = Some((
                    "the GPU device was lost and has been created again; reloading the bake"
                        .into(),
                    true,
                ));
            }
            Err(e) => self.fail(
                event_loop,
                Error::Gpu(format!(
                    "the GPU device was lost and a new one could not be created ({e}); restart canopy"
                )),
            ),
        }
        true
    }
}
