//! The viewer's "Bench results" window: the charts and summary table of a `canopy bench`
//! output folder. [`BenchView::load`] reads a folder without a window (tested alone);
//! [`BenchWindow`] keeps the folder field, the textures and the last error between frames.

use std::path::{Path, PathBuf};

use image::RgbaImage;

/// The folder `canopy bench` writes to when no `--out` is given.
pub const DEFAULT_BENCH_DIR: &str = "bench-out";

/// One configuration's line of the summary table; a figure the summary lacks (or holds as
/// null, as JSON writes NaN) is None.
#[derive(Clone, Debug, PartialEq)]
pub struct BenchRow {
    pub label: String,
    pub median_ms: Option<f64>,
    pub speedup_vs_geometry: Option<f64>,
    pub mean_flip: Option<f64>,
    pub p95_flip: Option<f64>,
    pub flicker_ratio: Option<f64>,
}

/// A bench output folder, read: the decoded charts and the summary's rows.
#[derive(Clone, Debug)]
pub struct BenchView {
    pub dir: PathBuf,
    /// `chart.png`: speed against accuracy.
    pub chart: RgbaImage,
    /// `flight.png` (FLIP and frame time along the flight), when the folder has one.
    pub flight: Option<RgbaImage>,
    /// What the run was (scene, frames, size, device), from the summary.
    pub run: String,
    pub rows: Vec<BenchRow>,
}

impl BenchView {
    /// Reads `dir/chart.png`, `dir/flight.png` (if present) and `dir/summary.json`. The
    /// error names the file that is missing or unreadable, and how to make it.
    pub fn load(dir: &Path) -> Result<Self, String> {
        let remedy = format!("run `canopy bench --out {}`", dir.display());
        if !dir.is_dir() {
            return Err(format!(
                "the folder {} does not exist; {remedy} to make it",
                dir.display()
            ));
        }
        let chart_path = dir.join("chart.png");
        if !chart_path.is_file() {
            return Err(format!(
                "{} is missing; {remedy} to write it",
                chart_path.display()
            ));
        }
        let chart = read_png(&chart_path, &remedy)?;
        let flight_path = dir.join("flight.png");
        let flight = if flight_path.is_file() {
            Some(read_png(&flight_path, &remedy)?)
        } else {
            None
        };
        let summary_path = dir.join("summary.json");
        let text = std::fs::read_to_string(&summary_path).map_err(|e| {
            format!(
                "{} cannot be read ({e}); {remedy} to write it",
                summary_path.display()
            )
        })?;
        let (run, rows) = parse_summary(&text).map_err(|e| {
            format!(
                "{} is not a bench summary ({e}); {remedy} again",
                summary_path.display()
            )
        })?;
        Ok(Self {
            dir: dir.to_path_buf(),
            chart,
            flight,
            run,
            rows,
        })
    }
}

fn read_png(path: &Path, remedy: &str) -> Result<RgbaImage, String> {
    image::ImageReader::open(path)
        .map_err(|e| format!("{} cannot be opened ({e})", path.display()))?
        .with_guessed_format()
        .map_err(|e| format!("{} cannot be read ({e})", path.display()))?
        .decode()
        .map(|img| img.to_rgba8())
        .map_err(|e| {
            format!(
                "{} is not a readable PNG ({e}); {remedy} again",
                path.display()
            )
        })
}

/// The run line and the rows of a `summary.json`.
fn parse_summary(text: &str) -> Result<(String, Vec<BenchRow>), String> {
    let summary = crate::bench::report::Summary::parse(text)?;
    let rows = summary
        .configurations
        .into_iter()
        .map(|c| BenchRow {
            label: c.label,
            median_ms: Some(c.median_ms),
            speedup_vs_geometry: c.speedup_vs_geometry,
            mean_flip: Some(c.mean_flip),
            p95_flip: Some(c.p95_flip),
            flicker_ratio: Some(c.flicker_ratio),
        })
        .collect();
    let r = &summary.run;
    let run = format!(
        "{}, flight {}: {} frames at {}x{} on {}",
        r.scene, r.flight, r.frames, r.width, r.height, r.device
    );
    Ok((run, rows))
}

/// What the window asks of the shell this frame.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct BenchWindowActions {
    /// Pick the folder with a file dialog (the shell owns dialogs), then [`BenchWindow::load`].
    pub browse: bool,
}

/// A loaded folder with its charts uploaded as egui textures.
struct Shown {
    view: BenchView,
    chart: egui::TextureHandle,
    flight: Option<egui::TextureHandle>,
}

/// The window's state between frames.
pub struct BenchWindow {
    pub open: bool,
    /// The folder field.
    pub folder: String,
    shown: Option<Shown>,
    error: Option<String>,
}

impl Default for BenchWindow {
    fn default() -> Self {
        Self {
            open: false,
            folder: DEFAULT_BENCH_DIR.to_string(),
            shown: None,
            error: None,
        }
    }
}

impl BenchWindow {
    /// Opens the window, loading the folder the first time.
    pub fn open(&mut self, ctx: &egui::Context) {
        self.open = true;
        if self.shown.is_none() && self.error.is_none() {
            self.load(ctx);
        }
    }

    /// Reads the folder in the field; shows its contents, or what is wrong with it.
    pub fn load(&mut self, ctx: &egui::Context) {
        match BenchView::load(Path::new(self.folder.trim())) {
            Ok(view) => {
                let texture = |name: &str, img: &RgbaImage| {
                    let size = [img.width() as usize, img.height() as usize];
                    ctx.load_texture(
                        name,
                        egui::ColorImage::from_rgba_unmultiplied(size, img.as_raw()),
                        egui::TextureOptions::LINEAR,
                    )
                };
                self.shown = Some(Shown {
                    chart: texture("bench chart", &view.chart),
                    flight: view.flight.as_ref().map(|f| texture("bench flight", f)),
                    view,
                });
                self.error = None;
            }
            Err(e) => {
                self.shown = None;
                self.error = Some(e);
            }
        }
    }

    /// The error of the last load, if it failed.
    pub fn error(&self) -> Option<&str> {
        self.error.as_deref()
    }

    /// Draws the window when open.
    pub fn show(&mut self, ctx: &egui::Context) -> BenchWindowActions {
        let mut actions = BenchWindowActions::default();
        let mut open = self.open;
        let mut load = false;
        egui::Window::new("Bench results")
            .open(&mut open)
            .default_size([760.0, 640.0])
            .resizable(true)
            .vscroll(true)
            .show(ctx, |ui| {
                ui.horizontal(|ui| {
                    let name = ui.label("Folder");
                    let field = ui
                        .text_edit_singleline(&mut self.folder)
                        .labelled_by(name.id);
                    if field.lost_focus() && ui.input(|i| i.key_pressed(egui::Key::Enter)) {
                        load = true;
                    }
                    if ui.button("Browse…").clicked() {
                        actions.browse = true;
                    }
                    if ui.button("Load").clicked() {
                        load = true;
                    }
                });
                if let Some(e) = &self.error {
                    ui.colored_label(egui::Color32::from_rgb(230, 80, 70), e);
                }
                if let Some(shown) = &self.shown {
                    contents(ui, shown);
                }
            });
        self.open = open;
        if load {
            self.load(ctx);
        }
        actions
    }
}

fn contents(ui: &mut egui::Ui, shown: &Shown) {
    let view = &shown.view;
    ui.label(format!("{}: {}", view.dir.display(), view.run));
    let figure = |v: Option<f64>, digits: usize| v.map_or("-".into(), |v| format!("{v:.digits$}"));
    egui::Grid::new("bench summary")
        .num_columns(6)
        .striped(true)
        .show(ui, |ui| {
            for title in [
                "configuration",
                "median ms",
                "speed-up",
                "mean FLIP",
                "p95 FLIP",
                "flicker",
            ] {
                ui.strong(title);
            }
            ui.end_row();
            for r in &view.rows {
                ui.label(&r.label);
                ui.label(figure(r.median_ms, 2));
                ui.label(
                    r.speedup_vs_geometry
                        .map_or("-".into(), |x| format!("{x:.2}x")),
                );
                ui.label(figure(r.mean_flip, 4));
                ui.label(figure(r.p95_flip, 4));
                ui.label(figure(r.flicker_ratio, 2));
                ui.end_row();
            }
        });
    ui.separator();
    // Scaled to the window's width, keeping the aspect ratio.
    let width = ui.available_width();
    ui.add(egui::Image::new(&shown.chart).max_width(width));
    if let Some(flight) = &shown.flight {
        ui.add(egui::Image::new(flight).max_width(width));
    } else {
        ui.label("no flight.png in this folder");
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A fresh folder under the system's temporary one.
    fn scratch(name: &str) -> PathBuf {
        let dir =
            std::env::temp_dir().join(format!("canopy-bench-view-{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        dir
    }

    fn tiny_png(path: &Path, w: u32, h: u32) {
        RgbaImage::from_pixel(w, h, image::Rgba([10, 200, 30, 255]))
            .save(path)
            .unwrap();
    }

    /// A `summary.json` as `bench` writes it (its run, and two configurations, one with
    /// its btf knobs beside it).
    const SUMMARY: &str = r#"{
        "scene": "tests/data/btf.toml", "flight": "overview", "frames": 3,
        "width": 96, "height": 64, "truth_supersample": 2, "repeats": 1,
        "device": "llvmpipe", "time_source": "gpu-timestamps",
        "truth_rendered": 3, "truth_cached": 0, "seconds": 12.5,
        "configurations": [
            {"label": "geometry", "method": "geometry", "median_ms": 8.5,
             "median_prepare_ms": 0.1, "speedup_vs_geometry": 1.0,
             "mean_flip": 0.01, "p95_flip": 0.05, "flicker_ratio": 1.1,
             "worst_pop": null, "worst_frame": 0, "worst_frame_flip": 0.02,
             "settings": null},
            {"label": "btf lod 2", "method": "btf", "median_ms": 2.0,
             "median_prepare_ms": 0.4, "speedup_vs_geometry": null,
             "mean_flip": 0.08, "p95_flip": 0.2, "flicker_ratio": 1.6,
             "worst_pop": {"frame": 2, "excess": 0.03}, "worst_frame": 2,
             "worst_frame_flip": 0.1,
             "settings": {"lod_scale": 2.0, "weight_threshold": 0.1, "lod_fade": 0.2,
                          "planes": "single", "vcm": true}}
        ]
    }"#;

    #[test]
    fn a_bench_folder_loads_its_charts_and_rows() {
        let dir = scratch("ok");
        tiny_png(&dir.join("chart.png"), 3, 2);
        std::fs::write(dir.join("summary.json"), SUMMARY).unwrap();
        let view = BenchView::load(&dir).unwrap();
        assert_eq!(view.chart.dimensions(), (3, 2));
        assert_eq!(view.chart.get_pixel(1, 1).0, [10, 200, 30, 255]);
        assert!(view.flight.is_none(), "flight.png is optional");
        assert_eq!(view.rows.len(), 2);
        assert_eq!(
            view.rows[1],
            BenchRow {
                label: "btf lod 2".into(),
                median_ms: Some(2.0),
                speedup_vs_geometry: None,
                mean_flip: Some(0.08),
                p95_flip: Some(0.2),
                flicker_ratio: Some(1.6),
            }
        );
        assert!(
            view.run.contains("3 frames at 96x64 on llvmpipe"),
            "{}",
            view.run
        );

        tiny_png(&dir.join("flight.png"), 4, 1);
        let view = BenchView::load(&dir).unwrap();
        assert_eq!(view.flight.map(|f| f.dimensions()), Some((4, 1)));
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn a_missing_folder_says_how_to_make_it() {
        let dir = std::env::temp_dir().join("canopy-bench-view-does-not-exist");
        let e = BenchView::load(&dir).unwrap_err();
        assert!(e.contains("does not exist"), "{e}");
        assert!(e.contains("run `canopy bench --out"), "{e}");
    }

    #[test]
    fn a_missing_chart_is_named() {
        let dir = scratch("no-chart");
        std::fs::write(dir.join("summary.json"), SUMMARY).unwrap();
        let e = BenchView::load(&dir).unwrap_err();
        assert!(e.contains("chart.png is missing"), "{e}");
        assert!(e.contains("canopy bench --out"), "{e}");
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn corrupt_files_are_named() {
        let dir = scratch("corrupt");
        tiny_png(&dir.join("chart.png"), 2, 2);
        std::fs::write(dir.join("summary.json"), "{\"configurations\": [").unwrap();
        let e = BenchView::load(&dir).unwrap_err();
        assert!(e.contains("summary.json is not a bench summary"), "{e}");

        std::fs::write(dir.join("summary.json"), "{\"scene\": \"x\"}").unwrap();
        let e = BenchView::load(&dir).unwrap_err();
        assert!(
            e.contains("summary.json") && e.contains("missing field"),
            "{e}"
        );

        std::fs::remove_file(dir.join("summary.json")).unwrap();
        let e = BenchView::load(&dir).unwrap_err();
        assert!(e.contains("summary.json cannot be read"), "{e}");

        std::fs::write(dir.join("summary.json"), SUMMARY).unwrap();
        std::fs::write(dir.join("chart.png"), b"\x89PNG\r\n\x1a\nnot really").unwrap();
        let e = BenchView::load(&dir).unwrap_err();
        assert!(e.contains("chart.png is not a readable PNG"), "{e}");
        let _ = std::fs::remove_dir_all(&dir);
    }
}
