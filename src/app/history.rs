//! The last few hundred frames' CPU and GPU frame times, for the panel's plot. A ring buffer
//! of fixed capacity: the viewer pushes a frame's times each frame, the plot reads them as
//! points against "frames ago", so the axis stays still while the curve scrolls. Where the
//! GPU timed each pass, the plot stacks them under the GPU line: where the frame goes.

use std::collections::VecDeque;

use crate::render::timing::PassTimes;

/// How many frames the panel's plot shows.
pub const HISTORY_FRAMES: usize = 300;

/// One frame's times, ms.
#[derive(Clone, Copy, Debug, PartialEq)]
struct FrameTimes {
    cpu_ms: f64,
    /// None where the GPU time was not (yet) measured: no timestamp queries, or the first
    /// frames before a readback arrived.
    gpu_ms: Option<f64>,
    /// The GPU time of each pass (empty where not measured).
    passes: PassTimes,
}

/// The most recent frames' times, oldest first, at most `capacity` of them.
#[derive(Clone, Debug)]
pub struct FrameTimeHistory {
    frames: VecDeque<FrameTimes>,
    capacity: usize,
}

impl Default for FrameTimeHistory {
    fn default() -> Self {
        Self::with_capacity(HISTORY_FRAMES)
    }
}

impl FrameTimeHistory {
    /// A history keeping the last `capacity` frames (at least one).
    pub fn with_capacity(capacity: usize) -> Self {
        let capacity = capacity.max(1);
        Self {
            frames: VecDeque::with_capacity(capacity),
            capacity,
        }
    }

    /// Records a frame; the oldest one goes when the history is full.
    pub fn push(&mut self, cpu_ms: f64, gpu_ms: Option<f64>) {
        if self.frames.len() == self.capacity {
            self.frames.pop_front();
        }
        self.frames.push_back(FrameTimes {
            cpu_ms,
            gpu_ms,
            passes: PassTimes::default(),
        });
    }

    /// Records a frame with its GPU time per pass.
    pub fn push_with_passes(&mut self, cpu_ms: f64, gpu_ms: Option<f64>, passes: PassTimes) {
        self.push(cpu_ms, gpu_ms);
        if let Some(f) = self.frames.back_mut() {
            f.passes = passes;
        }
    }

    /// The passes of the frames kept, in the order they first ran.
    pub fn pass_names(&self) -> Vec<&'static str> {
        let mut names = Vec::new();
        for p in self.frames.iter().flat_map(|f| f.passes.iter()) {
            if !names.contains(&p.name) {
                names.push(p.name);
            }
        }
        names
    }

    /// The pass that took the largest share of the GPU time over the frames kept that timed
    /// their passes, with that share (0..1): what to lighten first.
    pub fn dominant_pass(&self) -> Option<(&'static str, f64)> {
        let names = self.pass_names();
        let total: f64 = self
            .frames
            .iter()
            .flat_map(|f| f.passes.iter())
            .map(|p| p.ms)
            .sum();
        if total.is_nan() || total <= 0.0 {
            return None;
        }
        names
            .into_iter()
            .map(|name| {
                let ms: f64 = self
                    .frames
                    .iter()
                    .flat_map(|f| f.passes.iter())
                    .filter(|p| p.name == name)
                    .map(|p| p.ms)
                    .sum();
                (name, ms / total)
            })
            .max_by(|a, b| a.1.total_cmp(&b.1))
    }

    /// The passes stacked, in the order of [`Self::pass_names`]: per pass, the frames that
    /// timed passes as (frames ago, bottom, top) of its band, ms.
    pub fn pass_bands(&self) -> Vec<(&'static str, Vec<[f64; 3]>)> {
        let names = self.pass_names();
        let newest = self.frames.len() as f64 - 1.0;
        let mut bands: Vec<(&'static str, Vec<[f64; 3]>)> =
            names.iter().map(|&n| (n, Vec::new())).collect();
        for (i, f) in self.frames.iter().enumerate() {
            if f.passes.is_empty() {
                continue;
            }
            let mut bottom = 0.0;
            for (name, band) in &mut bands {
                let top = bottom + f.passes.get(name).unwrap_or(0.0);
                band.push([i as f64 - newest, bottom, top]);
                bottom = top;
            }
        }
        bands
    }

    pub fn len(&self) -> usize {
        self.frames.len()
    }

    pub fn is_empty(&self) -> bool {
        self.frames.is_empty()
    }

    pub fn capacity(&self) -> usize {
        self.capacity
    }

    /// Whether any frame kept has a GPU time (the plot draws the GPU line only then).
    pub fn has_gpu(&self) -> bool {
        self.frames.iter().any(|f| f.gpu_ms.is_some())
    }

    /// `[frames ago, ms]` of the CPU time, oldest first: the newest frame is at 0, older ones
    /// at negative x.
    pub fn cpu_points(&self) -> Vec<[f64; 2]> {
        self.points(|f| Some(f.cpu_ms))
    }

    /// `[frames ago, ms]` of the frames that have a GPU time, oldest first.
    pub fn gpu_points(&self) -> Vec<[f64; 2]> {
        self.points(|f| f.gpu_ms)
    }

    fn points(&self, value: impl Fn(&FrameTimes) -> Option<f64>) -> Vec<[f64; 2]> {
        let newest = self.frames.len() as f64 - 1.0;
        self.frames
            .iter()
            .enumerate()
            .filter_map(|(i, f)| value(f).map(|ms| [i as f64 - newest, ms]))
            .collect()
    }
}

/// Draws the history as a small plot: CPU and (when measured) GPU frame time, ms, against
/// frames ago, with a legend in small type, and under the GPU line each pass's time stacked
/// (where the GPU timed passes). Fixed axes (no drag or zoom), so it reads the same every frame and
/// the panel's scroll wheel keeps scrolling the panel.
pub fn plot(ui: &mut egui::Ui, history: &FrameTimeHistory) {
    use egui_plot::{Corner, FilledArea, Legend, Line, Plot};
    let bands = history.pass_bands();
    Plot::new("frame time history")
        // Room for the passes' legend (a dozen entries in small type) beside the newest
        // frames, which are drawn on the right.
        .height(if bands.is_empty() { 120.0 } else { 230.0 })
        .legend(
            Legend::default()
                .position(Corner::LeftTop)
                .text_style(egui::TextStyle::Small),
        )
        .include_x(-(history.capacity() as f64 - 1.0))
        .include_x(0.0)
        .include_y(0.0)
        .y_axis_label("ms")
        .allow_drag(false)
        .allow_zoom(false)
        .allow_scroll(false)
        .allow_boxed_zoom(false)
        .allow_double_click_reset(false)
        .show(ui, |plot| {
            for (k, (name, band)) in bands.iter().enumerate() {
                let xs: Vec<f64> = band.iter().map(|b| b[0]).collect();
                let lo: Vec<f64> = band.iter().map(|b| b[1]).collect();
                let hi: Vec<f64> = band.iter().map(|b| b[2]).collect();
                plot.add(FilledArea::new(*name, &xs, &lo, &hi).fill_color(pass_color(k)));
            }
            plot.line(
                Line::new("CPU frame", history.cpu_points())
                    .color(egui::Color32::from_rgb(90, 160, 255)),
            );
            if history.has_gpu() {
                plot.line(
                    Line::new("GPU frame", history.gpu_points())
                        .color(egui::Color32::from_rgb(250, 150, 60)),
                );
            }
        });
}

/// The colour of the `k`-th pass's band: distinct hues, half transparent.
fn pass_color(k: usize) -> egui::Color32 {
    const HUES: [(u8, u8, u8); 8] = [
        (120, 180, 90),
        (200, 120, 200),
        (90, 190, 190),
        (220, 200, 90),
        (230, 110, 100),
        (140, 140, 230),
        (170, 130, 90),
        (160, 160, 160),
    ];
    let (r, g, b) = HUES[k % HUES.len()];
    egui::Color32::from_rgba_unmultiplied(r, g, b, 150)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn points_run_from_oldest_to_newest_at_zero() {
        let mut h = FrameTimeHistory::with_capacity(4);
        assert!(h.is_empty() && h.cpu_points().is_empty());
        h.push(10.0, Some(4.0));
        h.push(11.0, None);
        h.push(12.0, Some(6.0));
        assert_eq!(h.len(), 3);
        assert_eq!(
            h.cpu_points(),
            vec![[-2.0, 10.0], [-1.0, 11.0], [0.0, 12.0]]
        );
        assert_eq!(h.gpu_points(), vec![[-2.0, 4.0], [0.0, 6.0]]);
        assert!(h.has_gpu());
    }

    #[test]
    fn a_full_history_drops_the_oldest_frame() {
        let mut h = FrameTimeHistory::with_capacity(3);
        for ms in 1..=5 {
            h.push(f64::from(ms), None);
        }
        assert_eq!(h.len(), 3);
        assert_eq!(h.capacity(), 3);
        assert_eq!(h.cpu_points(), vec![[-2.0, 3.0], [-1.0, 4.0], [0.0, 5.0]]);
    }

    #[test]
    fn without_gpu_times_there_is_no_gpu_line() {
        let mut h = FrameTimeHistory::default();
        assert_eq!(h.capacity(), HISTORY_FRAMES);
        for _ in 0..HISTORY_FRAMES + 10 {
            h.push(16.0, None);
        }
        assert_eq!(h.len(), HISTORY_FRAMES);
        assert!(!h.has_gpu());
        assert!(h.gpu_points().is_empty());
        // A GPU time pushed out again leaves no GPU line.
        h.push(16.0, Some(2.0));
        assert!(h.has_gpu());
        for _ in 0..HISTORY_FRAMES {
            h.push(16.0, None);
        }
        assert!(!h.has_gpu());
    }

    #[test]
    fn a_zero_capacity_keeps_one_frame() {
        let mut h = FrameTimeHistory::with_capacity(0);
        h.push(1.0, None);
        h.push(2.0, None);
        assert_eq!(h.cpu_points(), vec![[0.0, 2.0]]);
    }

    #[test]
    fn passes_stack_in_the_order_they_ran() {
        let mut h = FrameTimeHistory::with_capacity(4);
        let mut a = PassTimes::default();
        a.add("sky", 1.0);
        a.add("trees", 4.0);
        let mut b = PassTimes::default();
        b.add("far trees", 2.0);
        b.add("sky", 1.5);
        h.push_with_passes(10.0, Some(5.0), a);
        h.push(11.0, None);
        h.push_with_passes(12.0, Some(3.5), b);
        assert_eq!(h.pass_names(), ["sky", "trees", "far trees"]);
        let bands = h.pass_bands();
        // Frames without passes have no band; each band starts where the one below ends.
        assert_eq!(bands[0].1, vec![[-2.0, 0.0, 1.0], [0.0, 0.0, 1.5]]);
        assert_eq!(bands[1].1, vec![[-2.0, 1.0, 5.0], [0.0, 1.5, 1.5]]);
        assert_eq!(bands[2].1, vec![[-2.0, 5.0, 5.0], [0.0, 1.5, 3.5]]);
        assert!(FrameTimeHistory::default().pass_bands().is_empty());
        // trees: 4 of 1 + 4 + 2 + 1.5 = 8.5 ms.
        let (name, share) = h.dominant_pass().unwrap();
        assert_eq!(name, "trees");
        assert!((share - 4.0 / 8.5).abs() < 1e-9, "{share}");
        assert_eq!(FrameTimeHistory::default().dominant_pass(), None);
    }
}
