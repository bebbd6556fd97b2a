//! Progress bars on the terminal for the commands' long work (bakes, benches); where
//! stderr is not a terminal (a log, CI), a bake's progress is written as a line every few
//! seconds instead.

use std::io::IsTerminal;
use std::sync::Mutex;
use std::time::{Duration, Instant};

use indicatif::{ProgressBar, ProgressStyle};

/// What a long piece of work (a bake step) reports: `done` of `total` steps, at `what`.
#[derive(Clone, Debug)]
pub struct Progress {
    pub done: u64,
    pub total: u64,
    pub what: String,
}

/// How often a bake's progress is logged where no bar can be drawn.
pub const LOG_EVERY: Duration = Duration::from_secs(5);

/// The bar of a bake.
pub const BAKE_BAR: &str = "baking {msg:24} [{bar:30}] {pos}/{len} steps ({eta} left)";

/// A bar of `len` steps drawn with `template`; hidden unless `show`.
pub fn bar(show: bool, len: u64, template: &str) -> ProgressBar {
    if !show {
        return ProgressBar::hidden();
    }
    let bar = ProgressBar::new(len);
    bar.set_style(
        ProgressStyle::with_template(template).unwrap_or_else(|_| ProgressStyle::default_bar()),
    );
    bar
}

/// Shows a bake's progress on `bar`, or, where stderr is not a terminal, logs it every
/// [`LOG_EVERY`] with the time left.
pub fn show_bake(bar: &ProgressBar, p: &Progress) {
    bar.set_length(p.total);
    bar.set_position(p.done);
    bar.set_message(p.what.clone());
    if !std::io::stderr().is_terminal() {
        static LAST: Mutex<Option<Instant>> = Mutex::new(None);
        let Ok(mut last) = LAST.lock() else { return };
        if last.is_none_or(|t| t.elapsed() >= LOG_EVERY) || p.done == p.total {
            *last = Some(Instant::now());
            eprintln!("{}", log_line(p, bar.elapsed()));
        }
    }
}

/// `baking STAGE: DONE/TOTAL steps (P %), about S s left`, the time left extrapolated
/// from the time so far.
pub fn log_line(p: &Progress, elapsed: Duration) -> String {
    let f = p.done as f64 / p.total.max(1) as f64;
    let left = match seconds_left(p, elapsed) {
        Some(s) => format!(", about {s:.0} s left"),
        None => String::new(),
    };
    format!(
        "baking {}: {}/{} steps ({:.0} %){left}",
        p.what,
        p.done,
        p.total,
        f * 100.0
    )
}

/// The seconds a bake has left, extrapolated from the time so far (`None` before its first
/// step).
pub fn seconds_left(p: &Progress, elapsed: Duration) -> Option<f64> {
    if p.done == 0 {
        return None;
    }
    let f = (p.done as f64 / p.total.max(1) as f64).min(1.0);
    Some(elapsed.as_secs_f64() * (1.0 - f) / f)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_log_line_says_the_stage_and_the_time_left() {
        let p = Progress {
            done: 25,
            total: 100,
            what: "vcm tree 12".into(),
        };
        let l = log_line(&p, Duration::from_secs(10));
        assert_eq!(
            l,
            "baking vcm tree 12: 25/100 steps (25 %), about 30 s left"
        );
        let none = Progress { done: 0, ..p };
        assert_eq!(seconds_left(&none, Duration::from_secs(10)), None);
        assert_eq!(
            log_line(&none, Duration::from_secs(10)),
            "baking vcm tree 12: 0/100 steps (0 %)"
        );
    }
}
