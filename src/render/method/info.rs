//! What the rest of the program asks of a method without drawing with it, declared once in
//! the method's own module ([`MethodInfo`]) and found through [`super::info`]: the command
//! line's names and help, the viewer's buttons and statistics grid, whether `render --json`
//! and the bench measure a sun move for it, and whether it needs a bake.

use crate::render::frame::{FrameDesc, FrameStats};

/// One row of a method's statistics: a label and its value, as the viewer's panel shows
/// them.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct StatRow {
    pub label: &'static str,
    pub value: String,
}

impl StatRow {
    pub fn new(label: &'static str, value: impl Into<String>) -> Self {
        Self {
            label,
            value: value.into(),
        }
    }
}

/// A method's description.
pub struct MethodInfo {
    /// Its name on the command line, in the viewer and in the bench's files.
    pub name: &'static str,
    /// One line on what it draws (`--method`'s help lists it).
    pub summary: &'static str,
    /// It draws baked images, and needs a bake.
    pub needs_bake: bool,
    /// It keeps state that follows the sun (VCM reads, light blends, ground maps), rebuilt
    /// when the sun moves: `render --json` and the bench time a sun move for it.
    pub follows_sun: bool,
    /// Its statistics of the last frame `stats` (drawn as `frame` asked), as rows.
    pub stat_rows: fn(&FrameStats, &FrameDesc) -> Vec<StatRow>,
}

/// For a method with no statistics of its own.
pub fn no_rows(_: &FrameStats, _: &FrameDesc) -> Vec<StatRow> {
    Vec::new()
}

/// `n` for reading at a glance: as is below a thousand, then in thousands or millions.
pub fn format_count(n: u64) -> String {
    match n {
        0..1_000 => n.to_string(),
        1_000..1_000_000 => format!("{:.1} k", n as f64 / 1e3),
        _ => format!("{:.2} M", n as f64 / 1e6),
    }
}

/// `bytes` in megabytes, one decimal.
pub fn format_mb(bytes: u64) -> String {
    format!("{:.1} MB", bytes as f64 / 1e6)
}
