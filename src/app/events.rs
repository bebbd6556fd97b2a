//! winit's events: the window's start, input (to the fly camera, or egui where it wants it),
//! resizes, dropped files, redraws, and the pace of frames while the first bake runs.

use std::path::Path;
use std::time::{Duration, Instant};

use winit::application::ApplicationHandler;
use winit::event::{ElementState, MouseButton, MouseScrollDelta, WindowEvent};
use winit::event_loop::{ActiveEventLoop, ControlFlow};
use winit::keyboard::{KeyCode, PhysicalKey};
use winit::window::WindowId;

use super::App;
use super::fly::FlyKey;

/// The time from one frame's start to the next while the first bake runs: four times the
/// frame's cost, so that the viewer takes a quarter of the cores at most (on a software
/// renderer the bake and the view share them: the example forest's first bake took 395 s
/// in a viewer drawing all the time, against 248 s for `canopy bake`, both debug builds on
/// 2 cores), but at least 5 frames a second where frames are cheap (terrain and sky), and
/// one every 10 s at worst (the forest drawn from the bake's first tree levels), so that
/// the progress and the panel stay alive.
fn pause_while_baking(frame_cost: Duration) -> Duration {
    (frame_cost * 4).clamp(Duration::from_millis(200), Duration::from_secs(10))
}

impl App {
    fn key(&mut self, code: KeyCode, pressed: bool) -> bool {
        let k = match code {
            KeyCode::KeyW | KeyCode::ArrowUp => FlyKey::Forward,
            KeyCode::KeyS | KeyCode::ArrowDown => FlyKey::Back,
            KeyCode::KeyA | KeyCode::ArrowLeft => FlyKey::Left,
            KeyCode::KeyD | KeyCode::ArrowRight => FlyKey::Right,
            KeyCode::KeyQ => FlyKey::Down,
            KeyCode::KeyE => FlyKey::Up,
            KeyCode::ShiftLeft | KeyCode::ShiftRight => FlyKey::Fast,
            _ => return false,
        };
        self.fly.key(k, pressed);
        true
    }
}

impl ApplicationHandler for App {
    fn resumed(&mut self, event_loop: &ActiveEventLoop) {
        if self.running.is_some() {
            return;
        }
        match self.start(event_loop, None) {
            Ok(r) => {
                r.window.request_redraw();
                self.running = Some(r);
            }
            Err(e) => self.fail(event_loop, e),
        }
    }

    fn window_event(&mut self, event_loop: &ActiveEventLoop, _id: WindowId, event: WindowEvent) {
        let Some(r) = &mut self.running else { return };
        let consumed = r.egui_state.on_window_event(&r.window, &event).consumed;
        let egui_pointer = r.egui_state.egui_ctx().egui_wants_pointer_input();
        let egui_keys = r.egui_state.egui_ctx().egui_wants_keyboard_input();
        match event {
            WindowEvent::CloseRequested => event_loop.exit(),
            WindowEvent::Resized(size) => {
                r.config.width = size.width;
                r.config.height = size.height;
                if size.width > 0 && size.height > 0 {
                    r.surface.configure(&r.ctx.device, &r.config);
                }
            }
            WindowEvent::Focused(false) => self.fly.release_all(),
            WindowEvent::ModifiersChanged(m) => self.modifiers = m.state(),
            WindowEvent::KeyboardInput { event, .. } => {
                let pressed = event.state == ElementState::Pressed;
                if let PhysicalKey::Code(code) = event.physical_key {
                    if code == KeyCode::F12 && pressed && !event.repeat {
                        let path = crate::imageio::timestamped_path(Path::new("screenshots"));
                        self.screenshot(&path);
                    } else if code == KeyCode::Escape && pressed {
                        self.fly.release_all();
                    } else if !egui_keys || !pressed {
                        self.key(code, pressed);
                    }
                }
            }
            WindowEvent::MouseInput { state, button, .. } => {
                let pressed = state == ElementState::Pressed;
                match button {
                    MouseButton::Right => {
                        self.fly.set_looking(pressed && !(consumed && egui_pointer))
                    }
                    MouseButton::Left => {
                        let ctrl = self.modifiers.control_key();
                        self.fly.set_dragging_sun(pressed && ctrl && !egui_pointer);
                    }
                    _ => {}
                }
            }
            WindowEvent::CursorMoved { position, .. } => {
                if let Some((x, y)) = self.cursor {
                    let (dx, dy) = ((position.x - x) as f32, (position.y - y) as f32);
                    self.fly
                        .mouse_moved(dx, dy, &mut self.frame.camera, &mut self.frame.sun);
                }
                self.cursor = Some((position.x, position.y));
            }
            WindowEvent::MouseWheel { delta, .. } if !egui_pointer => {
                let notches = match delta {
                    MouseScrollDelta::LineDelta(_, y) => y,
                    MouseScrollDelta::PixelDelta(p) => (p.y / 40.0) as f32,
                };
                self.fly.wheel(notches);
            }
            WindowEvent::DroppedFile(path) => self.open(&path),
            WindowEvent::RedrawRequested => {
                let start = Instant::now();
                self.redraw(event_loop);
                self.frame_cost = start.elapsed();
            }
            _ => {}
        }
    }

    fn about_to_wait(&mut self, event_loop: &ActiveEventLoop) {
        let Some(r) = &self.running else { return };
        // While the first bake runs the view is drawn less often, leaving the cores to the
        // bake: terrain and sky at first, then the trees of the tree levels it hands over.
        let baking = self.bake_job.is_some() && self.frame.method.needs_bake();
        self.paused_for_bake = baking;
        if self.paused_for_bake {
            let next = self.last_frame + pause_while_baking(self.frame_cost);
            if Instant::now() < next {
                event_loop.set_control_flow(ControlFlow::WaitUntil(next));
                return;
            }
        }
        event_loop.set_control_flow(ControlFlow::Poll);
        r.window.request_redraw();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn while_the_first_bake_runs_the_view_takes_a_quarter_of_the_time_at_most() {
        let ms = Duration::from_millis;
        // A costly frame waits three times its cost after it, within 10 s at most.
        assert_eq!(pause_while_baking(ms(150)), ms(600));
        assert_eq!(pause_while_baking(ms(2000)), ms(8000));
        assert_eq!(pause_while_baking(ms(4000)), Duration::from_secs(10));
        // A cheap one still draws 5 frames a second, not hundreds.
        assert_eq!(pause_while_baking(ms(2)), ms(200));
    }
}
