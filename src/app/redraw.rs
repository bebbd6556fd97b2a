//! One frame of the viewer as a short sequence of named steps: the background work, the
//! camera, the 3D view, the frame's statistics, the panel, presenting, and what the panel and
//! the scripts ask for.

use std::time::Instant;

/// How often the panel's memory report is made again.
const MEMORY_REFRESH: std::time::Duration = std::time::Duration::from_secs(2);

use winit::event_loop::ActiveEventLoop;

use super::App;
use super::gpu::Running;
use super::screenshot::shown_frame;
use crate::render::FrameDesc;

impl App {
    /// Draws one frame: the 3D view with the panel on top.
    pub(super) fn redraw(&mut self, event_loop: &ActiveEventLoop) {
        self.tend_background();
        let dt = self.move_camera();
        let Some(r) = &mut self.running else { return };
        if r.config.width == 0 || r.config.height == 0 {
            return; // minimised
        }
        // Held by a Ctrl-drag in the view, or by a sun slider in the last frame's panel.
        self.frame.sun_held = self.fly.is_dragging_sun() || self.sun_slider_held;
        let frame = shown_frame(&self.frame, r.renderer.has_btf());
        if self.device_lost(event_loop) {
            return;
        }
        let Some(surface_texture) = self.running.as_mut().and_then(Running::next_texture) else {
            return;
        };
        self.draw_view(&frame, &surface_texture);
        self.update_frame_stats(dt);
        let view = surface_texture
            .texture
            .create_view(&wgpu::TextureViewDescriptor::default());
        let requests = self.draw_panel(&view);
        self.present(surface_texture);
        self.sun_slider_held = requests.actions.sun_held;
        self.apply_panel_requests(requests);
        self.tend_soak(event_loop);
        self.take_scripted_screenshot(event_loop);
    }

    /// Moves the camera by the input since the last frame, keeping it above the ground;
    /// returns the time since the last frame (s).
    fn move_camera(&mut self) -> f32 {
        let now = Instant::now();
        let dt = now.duration_since(self.last_frame).as_secs_f32();
        self.last_frame = now;
        self.fly.update(&mut self.frame.camera, dt);
        // Stay above the ground.
        let p = self.frame.camera.position;
        let ground = self.world.terrain.height_at(p.x, p.z) + 1.5;
        if p.y < ground {
            self.frame.camera.position.y = ground;
        }
        dt
    }

    /// Draws `frame`'s 3D view into the surface texture (through its sRGB view), at the
    /// render scale; the renderer's statistics go to the panel, an error to its message.
    fn draw_view(&mut self, frame: &FrameDesc, surface_texture: &wgpu::SurfaceTexture) {
        let Some(r) = &mut self.running else { return };
        let scene_view = surface_texture
            .texture
            .create_view(&wgpu::TextureViewDescriptor {
                format: Some(r.scene_format),
                ..Default::default()
            });
        // The 3D view at the render scale, stretched over the window when smaller.
        let (w, h) = (r.config.width, r.config.height);
        let (sw, sh) = crate::render::scale::scaled_size(w, h, frame.render_scale.scale);
        let scaled = (sw, sh) != (w, h);
        let drawn_into = if scaled {
            r.upscaler.target(&r.ctx, (sw, sh), r.scene_format).cloned()
        } else {
            Ok(scene_view.clone())
        };
        let result = drawn_into.and_then(|into| {
            r.renderer.render(
                &r.ctx,
                frame,
                crate::render::FrameTarget {
                    view: &into,
                    format: r.scene_format,
                    width: sw,
                    height: sh,
                },
                false,
            )
        });
        if scaled {
            r.upscaler.blit(&r.ctx, &scene_view, r.scene_format);
        }
        self.stats.render_size = (sw, sh);
        match result {
            Ok(s) => {
                self.stats.trees_drawn = s.trees_drawn;
                self.timeline.frame_drawn(s.trees_drawn);
                self.stats.triangles = s.triangles;
                self.stats.shadow_triangles = s.shadow_triangles;
                self.stats.draw_calls = s.draw_calls;
                self.stats.frame = s;
                if s.sun_update_ms.is_some() {
                    self.stats.sun_update_ms = s.sun_update_ms;
                }
                let stale = self.memory_at.is_none_or(|t| t.elapsed() >= MEMORY_REFRESH);
                if stale {
                    self.stats.memory = Some(r.renderer.memory_report(&r.ctx));
                    self.memory_at = Some(std::time::Instant::now());
                }
            }
            Err(e) => {
                self.message = Some((e.to_string(), true));
            }
        }
    }

    /// The frame's times (the GPU's, and the whole frame's `dt` seconds), the automatic
    /// render scale's next step and the panel's other statistics.
    fn update_frame_stats(&mut self, dt: f32) {
        let Some(r) = &self.running else { return };
        self.stats.gpu_frame_ms = r.renderer.last_gpu_ms();
        // The whole frame's time, what the user waits for (the GPU's arrives frames late and
        // would overshoot); while the view waits for the bake, the frame's own cost.
        let frame_ms = if self.paused_for_bake {
            self.frame_cost.as_secs_f32() * 1e3
        } else {
            dt * 1e3
        };
        if self.frame.render_scale.auto {
            let s = &mut self.frame.render_scale;
            s.scale = crate::render::scale::next_scale(s.scale, frame_ms, s.target_ms);
        }
        self.stats.sun_update_gpu_ms = r.renderer.last_sun_update_gpu_ms();
        self.stats.paused_for_bake = self.paused_for_bake;
        self.stats.cpu_frame_ms = 0.9 * self.stats.cpu_frame_ms + 0.1 * f64::from(frame_ms);
        let passes = r.renderer.last_passes().unwrap_or_default();
        self.stats
            .history
            .push_with_passes(f64::from(frame_ms), self.stats.gpu_frame_ms, passes);
        self.stats.camera_speed = self.fly.speed;
    }

    /// Shows the finished frame.
    fn present(&mut self, surface_texture: wgpu::SurfaceTexture) {
        let Some(r) = &self.running else { return };
        r.window.pre_present_notify();
        r.ctx.queue.present(surface_texture);
        self.frames += 1;
    }
}
