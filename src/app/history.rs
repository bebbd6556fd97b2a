//! The last few hundred frames' CPU and GPU frame times, for the panel's plot. A ring buffer
//! of fixed capacity: the viewer pushes a frame's times each frame, the plot reads them as
//! points against "frames ago", so the axis stays still while the curve scrolls.

use std::collections::VecDeque;

/// How many frames the panel's plot shows.
pub const HISTORY_FRAMES: usize = 300;

/// One frame's times, ms.
#[derive(Clone, Copy, Debug, PartialEq)]
struct FrameTimes {
    cpu_ms: f64,
    /// None where the GPU time was not (yet) measured: no timestamp queries, or the first
    /// frames before a readback arrived.
    gpu_ms: Option<f64>,
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
        self.frames.push_back(FrameTimes { cpu_ms, gpu_ms });
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
/// frames ago, with a legend. Fixed axes (no drag or zoom), so it reads the same every frame
/// and the panel's scroll wheel keeps scrolling the panel.
pub fn plot(ui: &mut egui::Ui, history: &FrameTimeHistory) {
    use egui_plot::{Corner, Legend, Line, Plot};
    Plot::new("frame time history")
        .height(120.0)
        .legend(Legend::default().position(Corner::LeftTop))
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
}
