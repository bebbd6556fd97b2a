//! `canopy view` (and `canopy` alone): the viewer window.

use std::path::PathBuf;

use super::args::parse_render_scale;
use crate::app::ViewOptions;
use crate::render::Method;
use crate::render::scale::RenderScale;

#[derive(clap::Args)]
pub struct ViewArgs {
    /// Scene file (TOML). Omit for the embedded example forest at real density
    /// (assets/scenes/forest.toml; its first bake takes about 5 minutes on 2 cores).
    scene: Option<PathBuf>,
    /// Write a screenshot of the 3D view to this PNG after --after-frames frames, then
    /// quit (for scripts and CI).
    #[arg(long)]
    screenshot: Option<PathBuf>,
    /// Frames to render before the --screenshot is taken.
    #[arg(long, default_value_t = 3, requires = "screenshot")]
    after_frames: u32,
    /// With --screenshot: count the frames from the end of the bake (made or read from
    /// the cache), so that the screenshot shows the finished bake's trees.
    #[arg(long, requires = "screenshot")]
    wait_bake: bool,
    /// Method to start with (btf shows terrain and sky until its bake is ready).
    #[arg(long, value_enum, default_value_t = Method::Btf)]
    method: Method,
    /// Use this baked file (from `canopy bake --out`) instead of the cache; it must have
    /// been baked from the scene, and is never re-baked.
    #[arg(long)]
    baked: Option<PathBuf>,
    /// The 3D view's resolution as a fraction of the window (0.25..=1), or `auto` to
    /// hold a frame time by lowering it (the default on a software renderer).
    #[arg(long, value_parser = parse_render_scale)]
    render_scale: Option<RenderScale>,
    /// Run a soak script (camera moves, sun sweeps, method and knob changes, resizes,
    /// screenshots; memory sampled), then quit; fails if memory grew over 5 %.
    #[arg(long)]
    script: Option<PathBuf>,
    #[command(flatten)]
    bc7: super::args::Bc7Textures,
}

/// Opens the viewer with these options.
pub fn view(args: ViewArgs) -> anyhow::Result<()> {
    args.bc7.apply();
    let options = ViewOptions {
        screenshot: args.screenshot,
        after_frames: args.after_frames,
        wait_bake: args.wait_bake,
        method: args.method,
        baked: args.baked,
        script: args.script,
        render_scale: args.render_scale,
    };
    Ok(crate::app::run_with(args.scene.as_deref(), options)?)
}
