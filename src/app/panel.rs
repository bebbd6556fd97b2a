//! The egui side panel: stats and a frame-time plot, method, sun and shadow controls,
//! screenshot buttons, the bench results button. Pure UI over plain state, so it is tested
//! headless with egui_kittest.

use crate::render::knob::{KnobKind, KnobValue};
use crate::render::method::info::{format_count, format_mb};
use crate::render::{FrameDesc, Method};

/// What the panel shows that the app measured.
#[derive(Clone, Debug, Default)]
pub struct PanelStats {
    pub cpu_frame_ms: f64,
    /// The size the 3D view was drawn at (the render scale applied).
    pub render_size: (u32, u32),
    pub gpu_frame_ms: Option<f64>,
    pub trees_drawn: u32,
    pub trees_total: usize,
    pub triangles: u64,
    pub shadow_triangles: u64,
    pub draw_calls: u32,
    pub adapter: String,
    pub camera_speed: f32,
    /// The last frame's statistics, as its method reports them.
    pub frame: crate::render::FrameStats,
    /// Bytes of BTF images on the GPU.
    pub btf_bytes: u64,
    /// Bytes of visibility cube maps in main memory.
    pub vcm_bytes: u64,
    /// Face resolution of the visibility cube maps, when loaded.
    pub vcm_resolution: Option<u32>,
    /// What the last sun move cost on the CPU (VCM reads, submitting the ground shadow
    /// maps), ms.
    pub sun_update_ms: Option<f64>,
    /// The GPU time of the last ground shadow maps' pass, ms (timestamp queries).
    pub sun_update_gpu_ms: Option<f64>,
    /// A bake running in the background: done, total, what, and the seconds it has left.
    pub bake_progress: Option<(u64, u64, String, Option<f64>)>,
    /// That bake's estimated cost, in words.
    pub bake_estimate: Option<String>,
    /// The trees are drawn from that bake's tree levels while it makes the rest.
    pub bake_partial: bool,
    /// The view is drawn less often until the bake is done, to leave it the cores.
    pub paused_for_bake: bool,
    /// The last frames' CPU and GPU times, for the plot.
    pub history: super::history::FrameTimeHistory,
    /// Where the memory is (refreshed every few seconds).
    pub memory: Option<crate::render::memory::MemoryReport>,
}

/// What the user asked for this frame.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct PanelActions {
    pub screenshot: bool,
    pub screenshot_as: bool,
    /// A sun slider is being dragged (the ground shadow maps may be previewed).
    pub sun_held: bool,
    /// Open the bench results window.
    pub open_bench: bool,
    /// Pick a scene or a bake to open.
    pub open_file: bool,
    /// Open the species gallery window.
    pub open_gallery: bool,
    /// Open the embedded example scene of this name (the scene menu).
    pub open_example: Option<&'static str>,
}

/// Draws the panel's contents into `ui`, editing `frame` in place.
pub fn controls(
    ui: &mut egui::Ui,
    frame: &mut FrameDesc,
    stats: &PanelStats,
    message: Option<&(String, bool)>,
) -> PanelActions {
    let mut actions = PanelActions::default();
    ui.heading("canopy");
    frame_stats(ui, stats);
    ui.separator();

    ui.label("Method");
    ui.horizontal(|ui| {
        for m in Method::ALL {
            ui.selectable_value(&mut frame.method, *m, m.name())
                .on_hover_text(crate::render::method::info(*m).summary);
        }
    });
    if let Some(progress) = &stats.bake_progress {
        bake_progress(ui, stats, progress);
    }
    knob_controls(ui, frame);
    method_stats(ui, frame, stats);
    ui.separator();

    actions.sun_held = sun_controls(ui, frame);
    ui.separator();

    view_controls(ui, frame, stats);
    ui.separator();

    file_buttons(ui, &mut actions);
    if let Some((text, is_error)) = message {
        if *is_error {
            ui.colored_label(egui::Color32::from_rgb(230, 80, 70), text);
        } else {
            ui.label(text);
        }
    }
    ui.separator();
    ui.small("WASD move · Q/E down/up · Shift faster · wheel: speed · right drag: look");
    actions
}

/// The frame's times and counts, the frame-time plot, the adapter and the memory.
fn frame_stats(ui: &mut egui::Ui, stats: &PanelStats) {
    egui::Grid::new("stats").num_columns(2).show(ui, |ui| {
        ui.label("frame (CPU)");
        ui.label(format!("{:.1} ms", stats.cpu_frame_ms));
        ui.end_row();
        ui.label("frame (GPU)");
        ui.label(match stats.gpu_frame_ms {
            Some(ms) => format!("{ms:.2} ms"),
            None => "n/a".to_string(),
        });
        ui.end_row();
        ui.label("trees drawn");
        ui.label(format!("{} / {}", stats.trees_drawn, stats.trees_total));
        ui.end_row();
        ui.label("triangles");
        ui.label(format_count(stats.triangles));
        ui.end_row();
        ui.label("shadow triangles");
        ui.label(format_count(stats.shadow_triangles));
        ui.end_row();
        ui.label("draw calls");
        ui.label(stats.draw_calls.to_string());
        ui.end_row();
        ui.label("speed");
        ui.label(format!("{:.1} m/s", stats.camera_speed));
        ui.end_row();
    });
    super::history::plot(ui, &stats.history);
    if let Some((name, share)) = stats.history.dominant_pass() {
        ui.label(format!(
            "most of the GPU frame: {name} ({:.0} %)",
            100.0 * share
        ))
        .on_hover_text(
            "the pass that took the largest share of the GPU time over the plotted frames",
        );
    }
    ui.small(&stats.adapter);
    if let Some(m) = &stats.memory {
        memory(ui, m);
    }
}

/// A bake running in the background: what it does, a progress bar, its estimate.
fn bake_progress(
    ui: &mut egui::Ui,
    stats: &PanelStats,
    (done, total, what, left): &(u64, u64, String, Option<f64>),
) {
    let f = if *total > 0 {
        *done as f32 / *total as f32
    } else {
        0.0
    };
    ui.label(match left {
        Some(s) => format!("baking BTF images: {what}, about {s:.0} s left"),
        None => format!("baking BTF images: {what}"),
    });
    ui.add(egui::ProgressBar::new(f).show_percentage());
    if let Some(e) = &stats.bake_estimate {
        ui.small(e);
    }
    if stats.bake_partial {
        ui.small(format!(
            "drawn from the tree levels baked so far (nearer trees as geometry); still coming: {}; texel and impostor draw when it is done",
            crate::bake::stages::STILL_COMING
        ));
    }
    if stats.paused_for_bake {
        ui.small("until it is done, the view is drawn less often, to leave the bake the cores");
    }
}

/// What the frame's method did last frame (its rows, [`crate::render::method::info`]), and
/// what its bake holds.
fn method_stats(ui: &mut egui::Ui, frame: &FrameDesc, stats: &PanelStats) {
    let info = crate::render::method::info(frame.method);
    let rows = (info.stat_rows)(&stats.frame, frame);
    if rows.is_empty() && !info.follows_sun {
        return;
    }
    egui::Grid::new("method stats")
        .num_columns(2)
        .show(ui, |ui| {
            for row in &rows {
                ui.label(row.label);
                ui.label(&row.value);
                ui.end_row();
            }
            if !info.follows_sun {
                return;
            }
            ui.label("BTF memory");
            ui.label(format_mb(stats.btf_bytes));
            ui.end_row();
            ui.label("VCM");
            ui.label(match stats.vcm_resolution {
                Some(r) => format!("{r}² x 6 faces x 8 corners, {}", format_mb(stats.vcm_bytes)),
                None => "not baked".to_string(),
            });
            ui.end_row();
            ui.label("sun update");
            ui.label(match (stats.sun_update_ms, stats.sun_update_gpu_ms) {
                (Some(cpu), Some(gpu)) => format!("{cpu:.1} ms CPU + {gpu:.1} ms GPU"),
                (Some(cpu), None) => format!("{cpu:.1} ms CPU"),
                (None, _) => "n/a".to_string(),
            });
            ui.end_row();
        });
}

/// The sun and sky sliders; true while a slider that moves the sun is dragged.
fn sun_controls(ui: &mut egui::Ui, frame: &mut FrameDesc) -> bool {
    ui.label("Sun (Ctrl + left drag in the view)");
    // Time of day: the sun rises in the east at 6 h, culminates in the south at noon (60°
    // up) and sets in the west at 18 h. Read back from the azimuth, so it follows drags.
    let mut hour = (6.0 + (frame.sun.azimuth_deg - 90.0) / 15.0).clamp(6.0, 18.0);
    let day = ui.add(egui::Slider::new(&mut hour, 6.0..=18.0).text("time of day h"));
    if day.changed() {
        let (az, el) = sun_at_hour(hour);
        frame.sun.azimuth_deg = az;
        frame.sun.elevation_deg = el;
    }
    let azimuth =
        ui.add(egui::Slider::new(&mut frame.sun.azimuth_deg, 0.0..=360.0).text("azimuth °"));
    let elevation =
        ui.add(egui::Slider::new(&mut frame.sun.elevation_deg, -10.0..=90.0).text("elevation °"));
    let sun_held = day.dragged() || azimuth.dragged() || elevation.dragged();
    ui.add(egui::Slider::new(&mut frame.sun.intensity, 0.0..=10.0).text("sun intensity"));
    ui.add(egui::Slider::new(&mut frame.sky.intensity, 0.0..=4.0).text("sky intensity"));
    sun_held
}

/// Shadows, fog, field of view, render scale and the overdraw view.
fn view_controls(ui: &mut egui::Ui, frame: &mut FrameDesc, stats: &PanelStats) {
    ui.checkbox(&mut frame.shadows.enabled, "sun shadows");
    ui.add_enabled_ui(frame.shadows.enabled, |ui| {
        egui::ComboBox::from_label("shadow map")
            .selected_text(frame.shadows.map_size.to_string())
            .show_ui(ui, |ui| {
                for s in [512u32, 1024, 2048, 4096] {
                    ui.selectable_value(&mut frame.shadows.map_size, s, s.to_string());
                }
            });
        ui.add(
            egui::Slider::new(&mut frame.shadows.distance, 50.0..=2000.0).text("shadow distance m"),
        );
    });
    ui.add(egui::Slider::new(&mut frame.fog_density, 0.0..=0.005).text("fog"));
    ui.add(egui::Slider::new(&mut frame.camera.fov_y_deg, 20.0..=100.0).text("field of view °"));
    let rs = &mut frame.render_scale;
    ui.add_enabled(
        !rs.auto,
        egui::Slider::new(&mut rs.scale, crate::render::scale::MIN_SCALE..=1.0)
            .text("render scale"),
    )
    .on_hover_text("the 3D view drawn at this fraction of the window and stretched over it");
    ui.horizontal(|ui| {
        ui.checkbox(&mut rs.auto, "automatic, hold");
        ui.add(
            egui::DragValue::new(&mut rs.target_ms)
                .range(5.0..=1000.0)
                .suffix(" ms"),
        );
    });
    ui.horizontal(|ui| {
        use crate::render::overdraw::OverdrawView;
        ui.label("overdraw view")
            .on_hover_text("per pixel, the fragments shaded (scale 0, 1, 2 ... 256) or the images they read (0, 8, 16 ... 2048), as a heat map");
        ui.selectable_value(&mut frame.overdraw, None, "off");
        for v in OverdrawView::ALL {
            ui.selectable_value(&mut frame.overdraw, Some(v), v.name());
        }
    });
    if stats.render_size != (0, 0) {
        ui.label(format!(
            "3D view drawn at {} x {}",
            stats.render_size.0, stats.render_size.1
        ));
    }
}

/// The screenshot, open, example scene, bench results and gallery buttons.
fn file_buttons(ui: &mut egui::Ui, actions: &mut PanelActions) {
    ui.horizontal(|ui| {
        if ui.button("Screenshot (F12)").clicked() {
            actions.screenshot = true;
        }
        if ui.button("Save as…").clicked() {
            actions.screenshot_as = true;
        }
    });
    ui.horizontal(|ui| {
        if ui
            .button("Open…")
            .on_hover_text(
                "a scene (.toml) or a bake of this scene (.canopy); or drop one on the window",
            )
            .clicked()
        {
            actions.open_file = true;
        }
        ui.menu_button("Example scenes", |ui| {
            for (name, what, _) in crate::scene::EXAMPLE_SCENES {
                if ui.button(*name).on_hover_text(*what).clicked() {
                    actions.open_example = Some(*name);
                    ui.close();
                }
            }
        })
        .response
        .on_hover_text("the scenes built into canopy");
        if ui.button("Bench results…").clicked() {
            actions.open_bench = true;
        }
    });
    if ui
        .button("Species gallery…")
        .on_hover_text(
            "each prototype alone, from a distance you choose, with its triangles and bake size",
        )
        .clicked()
    {
        actions.open_gallery = true;
    }
}

/// Sun azimuth and elevation (degrees) at `hour` on the time-of-day slider: east at 6 h,
/// south and 60° up at noon, west at 18 h.
pub fn sun_at_hour(hour: f32) -> (f32, f32) {
    let h = hour.clamp(6.0, 18.0);
    let az = 90.0 + (h - 6.0) * 15.0;
    let el = 60.0 * ((h - 6.0) / 12.0 * std::f32::consts::PI).sin();
    (az, el.max(0.5))
}

/// A control for each knob of the frame's method ([`crate::render::method::knobs_of`]):
/// a slider for a number, a checkbox for on/off, buttons for a choice.
fn knob_controls(ui: &mut egui::Ui, frame: &mut FrameDesc) {
    for k in crate::render::method::knobs_of(frame.method) {
        let enabled = (k.enabled)(frame);
        let value = k.get(frame);
        let mut next = value;
        ui.add_enabled_ui(enabled, |ui| match (k.kind, value) {
            (
                KnobKind::Number {
                    slider,
                    log,
                    integer,
                    ..
                },
                KnobValue::Number(mut v),
            ) => {
                let mut s = egui::Slider::new(&mut v, slider.0..=slider.1)
                    .logarithmic(log)
                    .text(k.label);
                if integer {
                    s = s.integer();
                }
                ui.add(s).on_hover_text(k.help);
                next = KnobValue::Number(v);
            }
            (KnobKind::Toggle { .. }, KnobValue::Toggle(mut on)) => {
                ui.checkbox(&mut on, k.label).on_hover_text(k.help);
                next = KnobValue::Toggle(on);
            }
            (KnobKind::Choice { names, .. }, KnobValue::Choice(mut c)) => {
                ui.horizontal(|ui| {
                    ui.label(k.label);
                    for n in names {
                        ui.selectable_value(&mut c, *n, *n).on_hover_text(k.help);
                    }
                });
                next = KnobValue::Choice(c);
            }
            _ => {}
        });
        if next != value {
            k.set(frame, next);
        }
    }
}

/// The memory section: resident memory, and the largest GPU and CPU parts.
fn memory(ui: &mut egui::Ui, m: &crate::render::memory::MemoryReport) {
    let mb = |b: u64| format!("{:.0} MB", b as f64 / 1e6);
    egui::CollapsingHeader::new(format!("memory: {} resident", mb(m.resident_bytes)))
        .id_salt("memory")
        .show(ui, |ui| {
            egui::Grid::new("memory parts")
                .num_columns(2)
                .show(ui, |ui| {
                    if let Some(a) = m.gpu_allocated_bytes {
                        ui.label("GPU allocations");
                        ui.label(mb(a));
                        ui.end_row();
                    }
                    let parts = m.gpu_parts.iter().map(|p| ("GPU", p));
                    let cpu = m.cpu_parts.iter().map(|p| ("CPU", p));
                    for (kind, p) in parts.take(8).chain(cpu) {
                        ui.label(format!("{kind}: {}", p.name));
                        ui.label(mb(p.bytes));
                        ui.end_row();
                    }
                });
        });
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn counts_are_readable() {
        assert_eq!(format_count(999), "999");
        assert_eq!(format_count(12_345), "12.3 k");
        assert_eq!(format_count(120_000_000), "120.00 M");
    }

    #[test]
    fn the_day_goes_from_east_over_south_to_west() {
        assert_eq!(sun_at_hour(6.0), (90.0, 0.5));
        let (az, el) = sun_at_hour(12.0);
        assert!((az - 180.0).abs() < 1e-4 && (el - 60.0).abs() < 1e-4);
        assert_eq!(sun_at_hour(18.0).0, 270.0);
        assert!(sun_at_hour(9.0).1 > sun_at_hour(7.0).1);
    }
}
