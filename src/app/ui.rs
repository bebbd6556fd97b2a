//! The panel and its windows (egui) over the 3D view: run and painted each frame, and what
//! they ask for (screenshots, opening files and examples, the bench and gallery windows)
//! carried out.

use std::path::Path;

use super::App;
use super::bench_view::BenchWindowActions;
use super::gallery;
use super::panel::{self, PanelActions};

/// What the panel and its windows asked for in one frame.
#[derive(Default)]
pub(super) struct PanelRequests {
    /// The side panel's.
    pub(super) actions: PanelActions,
    /// The "Bench results" window's.
    pub(super) bench: BenchWindowActions,
    /// The gallery's choice of a prototype and a view to draw.
    pub(super) gallery: Option<gallery::Choice>,
}

impl App {
    /// Runs the panel and its windows for this frame and paints them into `view` over the
    /// 3D view; returns what they asked for.
    pub(super) fn draw_panel(&mut self, view: &wgpu::TextureView) -> PanelRequests {
        let Some(r) = &mut self.running else {
            return PanelRequests::default();
        };
        let raw = r.egui_state.take_egui_input(&r.window);
        let mut actions = PanelActions::default();
        let frame = &mut self.frame;
        let stats = &self.stats;
        let message = self.message.as_ref();
        let bench = &mut self.bench;
        let mut bench_actions = Default::default();
        let gallery = &mut self.gallery;
        let mut gallery_wants = None;
        // The list is small (one entry per prototype) and only built while the window is open.
        let protos = if gallery.open {
            gallery::PrototypeInfo::of_world(
                &self.world,
                &crate::bake::cache::settings_of(&self.scene),
            )
        } else {
            Vec::new()
        };
        let mut out = r.egui_state.egui_ctx().run_ui(raw, |ui| {
            egui::Panel::right("controls")
                .default_size(280.0)
                .show(ui, |ui| {
                    egui::ScrollArea::vertical().show(ui, |ui| {
                        actions = panel::controls(ui, frame, stats, message);
                    });
                });
            bench_actions = bench.show(ui.ctx());
            gallery_wants = gallery.show(ui.ctx(), &protos);
        });
        r.egui_state
            .handle_platform_output(&r.window, out.platform_output);
        let ppp = out.pixels_per_point;
        let jobs = r.egui_state.egui_ctx().tessellate(out.shapes, ppp);
        let screen = egui_wgpu::ScreenDescriptor {
            size_in_pixels: [r.config.width, r.config.height],
            pixels_per_point: ppp,
        };
        // Every delta must be applied (egui asserts so when they are dropped).
        let mut textures = std::mem::take(&mut out.textures_delta);
        for (id, deltas) in textures.set.drain() {
            for delta in deltas {
                r.egui_renderer
                    .update_texture(&r.ctx.device, &r.ctx.queue, id, &delta);
            }
        }
        let mut encoder = r
            .ctx
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                label: Some("egui"),
            });
        let extra = r.egui_renderer.update_buffers(
            &r.ctx.device,
            &r.ctx.queue,
            &mut encoder,
            &jobs,
            &screen,
        );
        {
            let pass = encoder.begin_render_pass(&wgpu::RenderPassDescriptor {
                label: Some("egui"),
                color_attachments: &[Some(wgpu::RenderPassColorAttachment {
                    view,
                    depth_slice: None,
                    resolve_target: None,
                    ops: wgpu::Operations {
                        load: wgpu::LoadOp::Load,
                        store: wgpu::StoreOp::Store,
                    },
                })],
                depth_stencil_attachment: None,
                timestamp_writes: None,
                occlusion_query_set: None,
                multiview_mask: None,
            });
            let mut pass = pass.forget_lifetime();
            r.egui_renderer.render(&mut pass, &jobs, &screen);
        }
        r.ctx
            .queue
            .submit(extra.into_iter().chain(std::iter::once(encoder.finish())));
        for id in textures.free.drain() {
            r.egui_renderer.free_texture(&id);
        }
        PanelRequests {
            actions,
            bench: bench_actions,
            gallery: gallery_wants,
        }
    }

    /// Carries out what the panel and its windows asked for.
    pub(super) fn apply_panel_requests(&mut self, requests: PanelRequests) {
        let Some(r) = &mut self.running else { return };
        if requests.actions.open_bench {
            self.bench.open(r.egui_state.egui_ctx());
        }
        if requests.actions.open_gallery {
            self.gallery.open = true;
        }
        if let Some(choice) = requests.gallery {
            // Drawn once per choice (a fraction of a second on a software renderer).
            match self.world.species.get(choice.prototype) {
                Some(tree) => {
                    let picture = gallery::render_prototype(
                        &r.ctx,
                        tree,
                        &self.frame,
                        choice.distance,
                        choice.method,
                    );
                    match picture {
                        Ok(img) => self
                            .gallery
                            .set_picture(r.egui_state.egui_ctx(), choice, &img),
                        Err(e) => self.gallery.set_error(choice, e.to_string()),
                    }
                }
                None => self.gallery.set_error(choice, "no such prototype".into()),
            }
        }
        if requests.bench.browse {
            let mut dialog = rfd::FileDialog::new().set_title("Bench results folder");
            let current = Path::new(self.bench.folder.trim());
            if current.is_dir() {
                dialog = dialog.set_directory(current);
            }
            if let Some(dir) = dialog.pick_folder() {
                self.bench.folder = dir.display().to_string();
                self.bench.load(r.egui_state.egui_ctx());
            }
        }
        if requests.actions.screenshot {
            let path = crate::imageio::timestamped_path(Path::new("screenshots"));
            self.screenshot(&path);
        }
        if requests.actions.screenshot_as {
            let picked = rfd::FileDialog::new()
                .add_filter("PNG image", &["png"])
                .set_file_name("canopy.png")
                .save_file();
            if let Some(path) = picked {
                self.screenshot(&path);
            }
        }
        if let Some(name) = requests.actions.open_example {
            self.open_example(name);
        }
        if requests.actions.open_file {
            let picked = rfd::FileDialog::new()
                .set_title("Open a scene or a bake")
                .add_filter("scene or bake", &["toml", "canopy"])
                .pick_file();
            if let Some(path) = picked {
                self.open(&path);
            }
        }
    }
}
