//! The viewer: a winit window with a wgpu surface, the render core drawing the 3D view into
//! the surface texture, and egui on top. Thin by design: input goes to [`fly`], the panel is
//! [`panel`], drawing is the render core's.
//!
//! This file holds the viewer's state and starts it. `events` takes winit's events, `gpu`
//! makes the surface, device and renderer (again when the device is lost), `redraw` draws a
//! frame in named steps, `ui` runs and paints the panel and carries out what it asks,
//! `background` tends the bake, the re-bake and the sky visibility, `open` opens scenes and
//! bakes, `screenshot` saves the view and `soak_run` runs a soak script.

pub mod bench_view;
pub mod fly;
pub mod gallery;
pub mod heap;
pub mod history;
pub mod panel;
pub mod reload;
pub mod soak;

mod background;
mod events;
mod gpu;
mod open;
mod redraw;
mod screenshot;
mod soak_run;
mod ui;

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use winit::event_loop::{ActiveEventLoop, ControlFlow, EventLoop};
use winit::keyboard::ModifiersState;

use crate::model::World;
use crate::render::sky_visibility::SkyVolume;
use crate::render::{FrameDesc, Method};
use crate::scene::Scene;
use crate::{Error, Result};
use background::{BakeJob, Rebake};
use bench_view::BenchWindow;
use fly::FlyController;
use gpu::Running;
use panel::PanelStats;
use soak_run::SoakRun;

pub use open::{Opened, open_file};

/// Options of `canopy view` beyond the scene.
#[derive(Clone, Debug)]
pub struct ViewOptions {
    /// Take a screenshot of the 3D view to this path after `after_frames` frames, then quit
    /// (for scripts and CI).
    pub screenshot: Option<PathBuf>,
    pub after_frames: u32,
    /// Count `after_frames` from the end of the bake.
    pub wait_bake: bool,
    /// The method the viewer starts with.
    pub method: Method,
    /// A baked file to use instead of the cache (checked before the window opens).
    pub baked: Option<PathBuf>,
    /// A soak script to run, then quit (see [`soak`]).
    pub script: Option<PathBuf>,
    /// The render scale to start with (none: automatic on a software renderer, else 1).
    pub render_scale: Option<crate::render::scale::RenderScale>,
}

impl Default for ViewOptions {
    fn default() -> Self {
        Self {
            screenshot: None,
            after_frames: 3,
            wait_bake: false,
            method: Method::Btf,
            baked: None,
            script: None,
            render_scale: None,
        }
    }
}

/// Opens the viewer on a scene file, or on the embedded example forest at real density
/// ([`Scene::viewer_scene`]).
pub fn run(scene: Option<&Path>) -> Result<()> {
    run_with(scene, ViewOptions::default())
}

pub fn run_with(scene_path: Option<&Path>, options: ViewOptions) -> Result<()> {
    // Before any thread allocates: a viewer runs for hours (see `heap`).
    heap::limit_arenas();
    let scene = match scene_path {
        Some(p) => Scene::load(p)?,
        None => Scene::viewer_scene(),
    };
    let world = scene.build_world()?;
    // A named baked file is checked before the window opens: a wrong one is refused.
    let preloaded = match &options.baked {
        Some(path) => Some((crate::bake::open_baked(path, &scene)?, path.clone())),
        None => None,
    };
    let script = match &options.script {
        Some(p) => Some(soak::Script::load(p)?),
        None => None,
    };
    let title = match scene_path {
        Some(p) => format!("canopy: {}", p.display()),
        None => "canopy: example forest (36,000 trees)".to_string(),
    };
    let event_loop = EventLoop::new().map_err(|e| {
        Error::Window(format!(
            "{e}; the viewer needs a display (set DISPLAY or WAYLAND_DISPLAY, or use `canopy render`)"
        ))
    })?;
    event_loop.set_control_flow(ControlFlow::Poll);
    let mut frame = FrameDesc::from_scene(&scene);
    frame.method = options.method;
    if let Some(s) = options.render_scale {
        frame.render_scale = s;
    }
    let mut app = App {
        heap: heap::Upkeep::default(),
        frame,
        scene,
        world,
        bake_job: None,
        bake_failed: false,
        preloaded,
        title,
        options,
        running: None,
        fly: FlyController::default(),
        modifiers: ModifiersState::empty(),
        cursor: None,
        stats: PanelStats::default(),
        message: None,
        last_frame: Instant::now(),
        frame_cost: Duration::ZERO,
        paused_for_bake: false,
        frames: 0,
        timeline: Timeline::new(),
        fatal: None,
        sun_slider_held: false,
        bench: BenchWindow::default(),
        gallery: gallery::Gallery::default(),
        watch: scene_path.map(reload::Watch::new),
        rebake: None,
        sky_job: None,
        soak: script.map(SoakRun::new),
        scale_chosen: false,
        memory_at: None,
        lose_device_at: std::env::var("CANOPY_TEST_LOSE_DEVICE_AT_FRAME")
            .ok()
            .and_then(|v| v.parse().ok()),
    };
    event_loop
        .run_app(&mut app)
        .map_err(|e| Error::Window(e.to_string()))?;
    match app.fatal {
        Some(e) => Err(e),
        None => Ok(()),
    }
}

/// The viewer's first start, as it happens: logged (`RUST_LOG=canopy=info`) so that a
/// script can tell when the first trees were drawn and when the bake was done.
struct Timeline {
    started: Instant,
    /// A frame with trees has been drawn.
    trees_seen: bool,
    /// The frame count when the bake was attached (made, read from the cache or named).
    bake_done_at: Option<u64>,
}

impl Timeline {
    fn new() -> Self {
        Timeline {
            started: Instant::now(),
            trees_seen: false,
            bake_done_at: None,
        }
    }

    fn seconds(&self) -> f64 {
        self.started.elapsed().as_secs_f64()
    }

    /// Notes a drawn frame that had `trees` trees in it.
    fn frame_drawn(&mut self, trees: u32) {
        if trees > 0 && !self.trees_seen {
            self.trees_seen = true;
            log::info!(
                "timeline: the first frame with trees, {:.1} s after the viewer started",
                self.seconds()
            );
        }
    }

    /// Notes that the whole bake is attached, at frame `frames`.
    fn bake_done(&mut self, frames: u64) {
        if self.bake_done_at.is_none() {
            self.bake_done_at = Some(frames);
            log::info!(
                "timeline: the bake is done and attached, {:.1} s after the viewer started",
                self.seconds()
            );
        }
    }
}

struct App {
    /// Gives the C heap's free pages back every few seconds.
    heap: heap::Upkeep,
    frame: FrameDesc,
    scene: Scene,
    world: World,
    bake_job: Option<BakeJob>,
    bake_failed: bool,
    /// The baked file named with `--baked`, until it is attached.
    preloaded: Option<(crate::format::Baked, PathBuf)>,
    title: String,
    options: ViewOptions,
    running: Option<Running>,
    fly: FlyController,
    modifiers: ModifiersState,
    cursor: Option<(f64, f64)>,
    stats: PanelStats,
    /// Last screenshot result: text, and whether it is an error.
    message: Option<(String, bool)>,
    last_frame: Instant,
    /// How long the last redraw took (CPU, and the GPU where it waited for it).
    frame_cost: Duration,
    /// The view is drawn less often while the first bake runs (`events::pause_while_baking`).
    paused_for_bake: bool,
    frames: u64,
    /// When the first trees and the bake came, logged for scripts and measurements.
    timeline: Timeline,
    fatal: Option<Error>,
    /// A sun slider was being dragged in the last frame's panel.
    sun_slider_held: bool,
    /// The "Bench results" window.
    bench: BenchWindow,
    /// The species gallery window.
    gallery: gallery::Gallery,
    /// The scene file, watched for edits (none for an embedded scene).
    watch: Option<reload::Watch>,
    rebake: Option<Rebake>,
    /// The ground's sky visibility, computed on its own thread for the renderer of the
    /// given id (`Renderer::id`).
    sky_job: Option<(u64, std::thread::JoinHandle<SkyVolume>)>,
    /// The soak script being run.
    soak: Option<SoakRun>,
    /// The render scale's start was set (from the adapter or `--render-scale`).
    scale_chosen: bool,
    /// When the panel's memory report was last made.
    memory_at: Option<Instant>,
    /// For tests: destroy the device at this frame (`CANOPY_TEST_LOSE_DEVICE_AT_FRAME`), to
    /// check that the viewer recovers.
    lose_device_at: Option<u64>,
}

impl App {
    fn fail(&mut self, event_loop: &ActiveEventLoop, e: Error) {
        log::error!("{e}");
        self.fatal = Some(e);
        event_loop.exit();
    }
}
