//! Progress bars on the terminal for the commands' long work (bakes, benches).

use indicatif::{ProgressBar, ProgressStyle};

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

/// Shows a bake's progress on `bar`.
pub fn show_bake(bar: &ProgressBar, p: &crate::bake::Progress) {
    bar.set_length(p.total);
    bar.set_position(p.done);
    bar.set_message(p.what.clone());
}
