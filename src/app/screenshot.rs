//! Screenshots: the frame actually drawn, rendered offscreen at window resolution and saved
//! (F12, the panel's buttons, a soak script, `--screenshot` then quit).

use std::path::Path;

use winit::event_loop::ActiveEventLoop;

use super::App;
use crate::Error;
use crate::render::{FrameDesc, Method};

/// The frame actually drawn (and saved by a screenshot): until its bake is ready, the btf
/// method shows terrain and sky only (and the bake's progress), which stays responsive even
/// on a software renderer.
pub(super) fn shown_frame(frame: &FrameDesc, has_btf: bool) -> FrameDesc {
    let mut shown = *frame;
    if shown.method.needs_bake() && !has_btf {
        shown.method = Method::Geometry;
        shown.trees = false;
    }
    shown
}

impl App {
    /// Renders the 3D view offscreen at window resolution and writes it to `path`.
    pub(super) fn screenshot(&mut self, path: &Path) {
        let Some(r) = &mut self.running else { return };
        let (w, h) = (r.config.width, r.config.height);
        // Full-resolution ground shadows, even in the middle of a sun drag.
        let mut frame = shown_frame(&self.frame, r.renderer.has_btf());
        frame.sun_held = false;
        let result = r
            .renderer
            .render_image(&r.ctx, &frame, w, h, 1)
            .and_then(|(img, _)| crate::imageio::save_png(path, &img));
        self.message = Some(match result {
            Ok(()) => (format!("saved {}", path.display()), false),
            Err(e) => (e.to_string(), true),
        });
    }

    /// With `--screenshot`: once `--after-frames` frames are drawn, saves the view and quits
    /// (with the error when it could not be saved).
    pub(super) fn take_scripted_screenshot(&mut self, event_loop: &ActiveEventLoop) {
        let from = if self.options.wait_bake {
            // Counted from the bake's end (or a failed bake, which ends the wait too).
            match self.timeline.bake_done_at {
                Some(f) => f,
                None if self.bake_failed => 0,
                None => return,
            }
        } else {
            0
        };
        if let Some(path) = self.options.screenshot.clone()
            && self.frames >= from + u64::from(self.options.after_frames.max(1))
        {
            self.screenshot(&path);
            match self.message.take() {
                Some((m, true)) => self.fail(event_loop, Error::WriteImage { path, reason: m }),
                Some((m, false)) => {
                    println!("{m}");
                    event_loop.exit();
                }
                None => event_loop.exit(),
            }
        }
    }
}
