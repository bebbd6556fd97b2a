//! The viewer: a winit window with a wgpu surface, the render core drawing the 3D view into
//! the surface texture, and egui on top. Thin by design: input goes to [`fly`], the panel is
//! [`panel`], drawing is the render core's.

pub mod bench_view;
pub mod fly;
pub mod gallery;
pub mod heap;
pub mod history;
pub mod panel;
pub mod reload;
pub mod soak;

use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use winit::application::ApplicationHandler;
use winit::event::{ElementState, MouseButton, MouseScrollDelta, WindowEvent};
use winit::event_loop::{ActiveEventLoop, ControlFlow, EventLoop};
use winit::keyboard::{KeyCode, ModifiersState, PhysicalKey};
use winit::window::{Window, WindowId};

use crate::model::World;
use crate::render::sky_visibility::{SKY_DIRECTIONS, SkyVolume};
use crate::render::{AdapterPreference, FrameDesc, GpuContext, Method, Renderer};
use crate::scene::Scene;
use crate::{Error, Result};
use bench_view::BenchWindow;
use fly::{FlyController, FlyKey};
use panel::{PanelActions, PanelStats};

/// Options of `canopy view` beyond the scene.
#[derive(Clone, Debug)]
pub struct ViewOptions {
    /// Take a screenshot of the 3D view to this path after `after_frames` frames, then quit
    /// (for scripts and CI).
    pub screenshot: Option<PathBuf>,
    pub after_frames: u32,
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
        fatal: None,
        sun_slider_held: false,
        bench: BenchWindow::default(),
        gallery: gallery::Gallery::default(),
        watch: scene_path.map(reload::Watch::new),
        rebake: None,
        sky_job: None,
        soak: script.map(|script| SoakRun {
            script,
            started: None,
            frames: 0,
            next_action: 0,
            samples: Vec::new(),
            warm_at: None,
            resident: soak::Range::default(),
            device: soak::Range::default(),
        }),
        scale_chosen: false,
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

/// What File → Open or a file dropped on the window brings.
pub enum Opened {
    /// A scene file, parsed and its world built.
    Scene(Box<Scene>, Box<World>),
    /// A baked file of the scene on show.
    Baked(Box<crate::format::Baked>),
}

/// Opens `path` for the viewer showing `current`: a `.toml` scene, or a `.canopy` bake of
/// `current` (one of another scene, a corrupt or truncated one is refused with its reason;
/// it is never re-baked, since the user chose that file).
pub fn open_file(path: &Path, current: &Scene) -> Result<Opened> {
    let ext = path
        .extension()
        .map(|e| e.to_string_lossy().to_ascii_lowercase())
        .unwrap_or_default();
    match ext.as_str() {
        "toml" => {
            let scene = Scene::load(path)?;
            let world = scene.build_world()?;
            Ok(Opened::Scene(Box::new(scene), Box::new(world)))
        }
        "canopy" => Ok(Opened::Baked(Box::new(crate::bake::open_baked(
            path, current,
        )?))),
        _ => Err(Error::BadInput(format!(
            "cannot open {}: the viewer opens scene files (.toml) and baked files (.canopy)",
            path.display()
        ))),
    }
}

/// The frame actually drawn (and saved by a screenshot): until its bake is ready, the btf
/// method shows terrain and sky only (and the bake's progress), which stays responsive even
/// on a software renderer.
fn shown_frame(frame: &FrameDesc, has_btf: bool) -> FrameDesc {
    let mut shown = *frame;
    if shown.method.needs_bake() && !has_btf {
        shown.method = Method::Geometry;
        shown.trees = false;
    }
    shown
}

/// The time from one frame's start to the next while the first bake runs and the view has
/// no trees to show: four times the frame's cost, so that the viewer takes a quarter of
/// the cores at most (on a software renderer the bake and the view share them: the
/// example forest's first bake took 395 s in a viewer drawing all the time, against 248 s
/// for `canopy bake`, both debug builds on 2 cores), but at least 5 frames a second where
/// frames are cheap, and one a second at worst, so that the progress and the panel stay
/// alive.
fn pause_while_baking(frame_cost: Duration) -> Duration {
    (frame_cost * 4).clamp(Duration::from_millis(200), Duration::from_secs(1))
}

struct Running {
    window: Arc<Window>,
    surface: wgpu::Surface<'static>,
    config: wgpu::SurfaceConfiguration,
    /// Format of the view the 3D scene is drawn through (sRGB where the surface allows).
    scene_format: wgpu::TextureFormat,
    ctx: GpuContext,
    renderer: Renderer,
    egui_state: egui_winit::State,
    egui_renderer: egui_wgpu::Renderer,
    /// Draws the 3D view at the render scale and stretches it over the window.
    upscaler: crate::render::scale::Upscaler,
}

/// A bake running on its own thread and GPU device, so the viewer stays responsive.
struct BakeJob {
    progress: Arc<Mutex<crate::bake::Progress>>,
    /// What the bake costs, estimated before it starts (shown under its progress bar).
    estimate: Option<String>,
    started: Instant,
    handle: std::thread::JoinHandle<Result<(crate::format::Baked, crate::bake::Source)>>,
}

impl BakeJob {
    /// Loads `scene`'s bake from the cache, or bakes it, on its own thread.
    fn start(scene: &Scene, world: &World) -> Self {
        let settings = crate::bake::cache::settings_of(scene);
        let estimate = crate::bake::estimate::estimate(&settings, world)
            .ok()
            .map(|e| {
                format!(
                    "if not cached: about {:.0} s, {:.0} MB file, {:.0} MB of memory",
                    e.seconds,
                    e.file_bytes as f64 / 1e6,
                    e.memory_bytes as f64 / 1e6
                )
            });
        let progress = Arc::new(Mutex::new(crate::bake::Progress {
            done: 0,
            total: 1,
            what: "starting".into(),
        }));
        let sink = progress.clone();
        let scene = scene.clone();
        let world = world.clone();
        let handle = std::thread::spawn(move || {
            let ctx = GpuContext::headless(AdapterPreference::Default)?;
            crate::bake::load_or_bake(&ctx, &scene, &world, &mut |p| {
                if let Ok(mut slot) = sink.lock() {
                    *slot = p.clone();
                }
            })
        });
        Self {
            progress,
            estimate,
            started: Instant::now(),
            handle,
        }
    }
}

/// A soak script's run: its clock starts once the bake is on show.
struct SoakRun {
    script: soak::Script,
    started: Option<Instant>,
    frames: u64,
    next_action: usize,
    samples: Vec<soak::Sample>,
    /// When every action had run [`soak::WARM_CYCLES`] times (what is built on first use
    /// is built by then, however slow the frames).
    warm_at: Option<f64>,
    /// Resident memory read every frame since the last sample: its floor and its peak.
    resident: soak::Range,
    /// The device's allocated bytes (wgpu's allocator) read every frame since the last
    /// sample.
    device: soak::Range,
}

/// An edit of the scene file that changes the bake: its bake runs while the old scene
/// stays on show.
struct Rebake {
    job: BakeJob,
    scene: Scene,
    world: World,
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
    /// The view is drawn less often while the first bake runs ([`pause_while_baking`]).
    paused_for_bake: bool,
    frames: u64,
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
    /// For tests: destroy the device at this frame (`CANOPY_TEST_LOSE_DEVICE_AT_FRAME`), to
    /// check that the viewer recovers.
    lose_device_at: Option<u64>,
}

impl App {
    /// The GPU side of the viewer: its window (`window`, or a new one), surface, device and
    /// renderer.
    fn start(
        &mut self,
        event_loop: &ActiveEventLoop,
        window: Option<Arc<Window>>,
    ) -> Result<Running> {
        let window = match window {
            Some(w) => w,
            None => {
                let attrs = Window::default_attributes()
                    .with_title(self.title.clone())
                    .with_inner_size(winit::dpi::LogicalSize::new(1280.0, 720.0));
                Arc::new(
                    event_loop
                        .create_window(attrs)
                        .map_err(|e| Error::Window(e.to_string()))?,
                )
            }
        };
        let instance = wgpu::Instance::new(crate::render::context::instance_descriptor(Some(
            Box::new(event_loop.owned_display_handle()),
        )));
        let surface = instance.create_surface(window.clone())?;
        let ctx = GpuContext::for_surface(instance, &surface, AdapterPreference::Default)?;
        let size = window.inner_size();
        let mut config = surface
            .get_default_config(&ctx.adapter, size.width.max(1), size.height.max(1))
            .ok_or_else(|| {
                Error::Gpu("the window surface is not supported by the adapter".into())
            })?;
        // The 3D view is drawn through an sRGB view (the render core writes linear colour),
        // egui through a plain one (it blends in gamma space), both on the same texture.
        let caps = surface.get_capabilities(&ctx.adapter);
        let plain = caps
            .formats
            .iter()
            .copied()
            .find(|f| !f.is_srgb() && f.add_srgb_suffix().is_srgb())
            .unwrap_or(config.format);
        config.format = plain;
        let scene_format = plain.add_srgb_suffix();
        config.view_formats = if scene_format == plain {
            vec![]
        } else {
            vec![scene_format]
        };
        config.present_mode = wgpu::PresentMode::AutoVsync;
        if size.width > 0 && size.height > 0 {
            surface.configure(&ctx.device, &config);
        }
        let renderer = Renderer::new(&ctx, &self.world)?;
        let egui_ctx = egui::Context::default();
        let egui_state = egui_winit::State::new(
            egui_ctx,
            egui::ViewportId::ROOT,
            &window,
            Some(window.scale_factor() as f32),
            None,
            Some(ctx.device.limits().max_texture_dimension_2d as usize),
        );
        let egui_renderer =
            egui_wgpu::Renderer::new(&ctx.device, config.format, Default::default());
        self.stats.adapter = ctx.adapter_name();
        self.stats.trees_total = self.world.forest.instances.len();
        if self.options.render_scale.is_none() && !self.scale_chosen {
            // A software renderer starts on the automatic render scale.
            let software = ctx.adapter.get_info().device_type == wgpu::DeviceType::Cpu;
            self.frame.render_scale = crate::render::scale::RenderScale::for_adapter(software);
            self.scale_chosen = true;
        }
        let upscaler = crate::render::scale::Upscaler::new(&ctx);
        Ok(Running {
            upscaler,
            window,
            surface,
            config,
            scene_format,
            ctx,
            renderer,
            egui_state,
            egui_renderer,
        })
    }

    fn fail(&mut self, event_loop: &ActiveEventLoop, e: Error) {
        log::error!("{e}");
        self.fatal = Some(e);
        event_loop.exit();
    }

    fn key(&mut self, code: KeyCode, pressed: bool) -> bool {
        let k = match code {
            KeyCode::KeyW | KeyCode::ArrowUp => FlyKey::Forward,
            KeyCode::KeyS | KeyCode::ArrowDown => FlyKey::Back,
            KeyCode::KeyA | KeyCode::ArrowLeft => FlyKey::Left,
            KeyCode::KeyD | KeyCode::ArrowRight => FlyKey::Right,
            KeyCode::KeyQ => FlyKey::Down,
            KeyCode::KeyE => FlyKey::Up,
            KeyCode::ShiftLeft | KeyCode::ShiftRight => FlyKey::Fast,
            _ => return false,
        };
        self.fly.key(k, pressed);
        true
    }

    /// Renders the 3D view offscreen at window resolution and writes it to `path`.
    fn screenshot(&mut self, path: &Path) {
        let Some(r) = &mut self.running else { return };
        let (w, h) = (r.config.width, r.config.height);
        // Full-resolution ground shadows, even in the middle of a sun drag.
        let mut frame = shown_frame(&self.frame, r.renderer.has_btf());
        frame.sun_held = false;
        let result = r
            .renderer
            .render_image(&r.ctx, &frame, w, h, 1)
            .and_then(|(img, _)| crate::imageio::save_png(path, &img));
        self.message = Some(match result {
            Ok(()) => (format!("saved {}", path.display()), false),
            Err(e) => (e.to_string(), true),
        });
    }

    /// Opens a scene or a bake chosen with File → Open or dropped on the window; what
    /// cannot be opened is reported in the panel and the scene on show stays.
    fn open(&mut self, path: &Path) {
        if self.running.is_none() {
            return;
        }
        match open_file(path, &self.scene) {
            Ok(Opened::Scene(scene, world)) => self.show_scene(
                *scene,
                *world,
                &path.display().to_string(),
                Some(reload::Watch::new(path)),
            ),
            Ok(Opened::Baked(baked)) => {
                // Attached on the next frame, as a bake named with --baked is.
                self.bake_job = None;
                self.preloaded = Some((*baked, path.to_path_buf()));
            }
            Err(e) => self.message = Some((e.to_string(), true)),
        }
    }

    /// Opens the embedded example scene `name` (the scene menu); its bake comes from the
    /// cache or is made in the background, as for any scene.
    fn open_example(&mut self, name: &str) {
        let opened = match Scene::example(name) {
            None => Err(Error::BadInput(format!("no example scene named `{name}`"))),
            Some(scene) => scene.map_err(Error::from).and_then(|scene| {
                let world = scene.build_world()?;
                Ok((scene, world))
            }),
        };
        match opened {
            Ok((scene, world)) => {
                self.show_scene(scene, world, &format!("example scene `{name}`"), None)
            }
            Err(e) => self.message = Some((e.to_string(), true)),
        }
    }

    /// Puts `scene` on show in place of the current one (the method kept, its bake started
    /// from the cache or in the background), watching its file where it has one.
    fn show_scene(
        &mut self,
        scene: Scene,
        world: World,
        label: &str,
        watch: Option<reload::Watch>,
    ) {
        let Some(r) = &mut self.running else { return };
        match Renderer::new(&r.ctx, &world) {
            Ok(renderer) => {
                let (method, render_scale) = (self.frame.method, self.frame.render_scale);
                r.renderer = renderer;
                self.scene = scene;
                self.world = world;
                self.frame = FrameDesc::from_scene(&self.scene);
                // The method and the render scale are the viewer's, not the scene's.
                self.frame.method = method;
                self.frame.render_scale = render_scale;
                // A bake still running for the old scene is left to finish unseen.
                self.bake_job = None;
                self.bake_failed = false;
                self.preloaded = None;
                self.title = format!("canopy: {label}");
                r.window.set_title(&self.title);
                self.watch = watch;
                self.rebake = None;
                self.stats.trees_total = self.world.forest.instances.len();
                self.gallery.reset();
                self.message = Some((format!("opened {label}"), false));
            }
            Err(e) => self.message = Some((format!("cannot open {label}: {e}"), true)),
        }
    }

    /// The btf method needs a bake: start one in the background, or attach a finished one.
    fn tend_bake(&mut self) {
        let Some(r) = &mut self.running else { return };
        if let Some((baked, path)) = self.preloaded.take() {
            self.message = Some(match r.renderer.attach_btf(&r.ctx, &baked, &self.world) {
                Ok(()) => (format!("BTF images from {}", path.display()), false),
                Err(e) => {
                    self.bake_failed = true;
                    (format!("cannot use {}: {e}", path.display()), true)
                }
            });
            return;
        }
        // The bake starts with the viewer (from the cache when it can), whatever the method.
        if !r.renderer.has_btf() && self.bake_job.is_none() && !self.bake_failed {
            self.bake_job = Some(BakeJob::start(&self.scene, &self.world));
        }
        self.stats.bake_progress = self
            .bake_job
            .as_ref()
            .or(self.rebake.as_ref().map(|r| &r.job))
            .and_then(|j| {
                j.progress.lock().ok().map(|p| {
                    let left = crate::progress::seconds_left(&p, j.started.elapsed());
                    (p.done, p.total, p.what.clone(), left)
                })
            });
        self.stats.bake_estimate = self
            .bake_job
            .as_ref()
            .or(self.rebake.as_ref().map(|r| &r.job))
            .and_then(|j| j.estimate.clone());
        if self
            .bake_job
            .as_ref()
            .is_some_and(|j| j.handle.is_finished())
        {
            let Some(job) = self.bake_job.take() else {
                return;
            };
            self.stats.bake_progress = None;
            let result = job
                .handle
                .join()
                .unwrap_or_else(|_| Err(Error::Gpu("the bake thread stopped unexpectedly".into())))
                .and_then(|(baked, source)| {
                    r.renderer.attach_btf(&r.ctx, &baked, &self.world)?;
                    Ok(source)
                });
            self.message = Some(match result {
                Ok(crate::bake::Source::Cache) => {
                    ("BTF images loaded from the cache".into(), false)
                }
                Ok(crate::bake::Source::Baked {
                    not_cached: Some(why),
                    ..
                }) => (
                    format!(
                        "baked, but the bake could not be cached ({why}); it is used from memory and will be baked again next time"
                    ),
                    true,
                ),
                Ok(crate::bake::Source::Baked { replaced: None, .. }) => {
                    ("BTF images baked and cached".into(), false)
                }
                Ok(crate::bake::Source::Baked {
                    replaced: Some(why),
                    ..
                }) => (
                    format!("the cached bake could not be used ({why}); baked again"),
                    false,
                ),
                Err(e) => {
                    self.bake_failed = true;
                    self.frame.method = Method::Geometry;
                    (format!("bake failed: {e}"), true)
                }
            });
        }
        self.stats.btf_bytes = r.renderer.btf_bytes();
        self.stats.vcm_bytes = r.renderer.vcm_bytes();
        self.stats.vcm_resolution = r.renderer.vcm_resolution();
    }

    /// Looks at the scene file and applies an edit (see [`reload`]); finishes a re-bake.
    fn tend_reload(&mut self) {
        let Some(r) = &mut self.running else { return };
        if let Some(w) = self.watch.as_mut()
            && let Some(text) = w.poll()
        {
            let origin = w.path.display().to_string();
            let edit = match text {
                Ok(text) => reload::classify(&self.scene, &text, &origin),
                Err(why) => reload::Reload::Broken(why),
            };
            match edit {
                reload::Reload::Unchanged => {}
                reload::Reload::Frame(new) => {
                    reload::apply_frame_edit(&self.scene, &new, &mut self.frame);
                    self.scene = *new;
                    log::info!("applied the edit of {origin}");
                    self.message = Some((format!("applied the edit of {origin}"), false));
                }
                reload::Reload::Rebake(new, world) => {
                    log::info!("{origin} changes what is baked: baking it");
                    self.rebake = Some(Rebake {
                        job: BakeJob::start(&new, &world),
                        scene: *new,
                        world: *world,
                    });
                    self.message = Some((
                        format!(
                            "{origin} changes what is baked: baking it; the old scene stays until then"
                        ),
                        false,
                    ));
                }
                reload::Reload::Broken(why) => {
                    log::warn!("{why} (the last good scene stays)");
                    self.message = Some((format!("{why} (the last good scene stays)"), true));
                }
            }
        }
        if !self
            .rebake
            .as_ref()
            .is_some_and(|b| b.job.handle.is_finished())
        {
            return;
        }
        let Some(done) = self.rebake.take() else {
            return;
        };
        let result = done
            .job
            .handle
            .join()
            .unwrap_or_else(|_| Err(Error::Gpu("the bake thread stopped unexpectedly".into())))
            .and_then(|(baked, _)| {
                let mut renderer = Renderer::new(&r.ctx, &done.world)?;
                renderer.attach_btf(&r.ctx, &baked, &done.world)?;
                Ok(renderer)
            });
        match result {
            Ok(renderer) => {
                r.renderer = renderer;
                reload::apply_frame_edit(&self.scene, &done.scene, &mut self.frame);
                self.scene = done.scene;
                self.world = done.world;
                self.bake_job = None;
                self.bake_failed = false;
                self.stats.trees_total = self.world.forest.instances.len();
                self.gallery.reset();
                log::info!("the edited scene is baked and on show");
                self.message = Some(("the edited scene is baked and on show".into(), false));
            }
            Err(e) => {
                self.message = Some((
                    format!("the edited scene could not be baked: {e} (the last good scene stays)"),
                    true,
                ));
            }
        }
    }

    /// One frame of the soak script: the next action, a memory sample when due, and at
    /// the end the report and the verdict.
    fn tend_soak(&mut self, event_loop: &ActiveEventLoop) {
        let (Some(run), Some(r)) = (self.soak.as_mut(), self.running.as_ref()) else {
            return;
        };
        let gpu_bytes = r.renderer.btf_bytes() + r.renderer.texel_bytes() + r.renderer.mesh_bytes();
        run.resident.add(soak::resident_bytes());
        if let Some(b) = r.ctx.device_allocated_bytes() {
            run.device.add(b);
        }
        let sample = |t: f64, resident: &mut soak::Range, device: &mut soak::Range| {
            let (heap_used_bytes, heap_free_bytes) = heap::heap_bytes();
            let (floor, peak) = resident.take();
            soak::Sample {
                seconds: t,
                resident_bytes: floor,
                resident_peak_bytes: peak,
                gpu_bytes,
                device_peak_bytes: device.take().1,
                heap_free_bytes,
                heap_used_bytes,
            }
        };
        let Some(started) = run.started else {
            // The clock starts once the one-off background work is on show: the bake, and
            // the ground's sky visibility (`tend_sky`), whose allocations are not growth.
            let baked = r.renderer.has_btf() || self.bake_failed;
            if baked && (r.renderer.has_sky() || !self.frame.ground_sky) {
                run.started = Some(Instant::now());
                run.samples
                    .push(sample(0.0, &mut run.resident, &mut run.device));
            }
            return;
        };
        let t = started.elapsed().as_secs_f64();
        run.frames += 1;
        let mut action = None;
        if run.frames % u64::from(run.script.every_frames) == 0 && !run.script.actions.is_empty() {
            action = Some(run.script.actions[run.next_action % run.script.actions.len()]);
            run.next_action += 1;
        }
        let cycles = soak::WARM_CYCLES * run.script.actions.len().max(1);
        if run.warm_at.is_none() && (run.next_action >= cycles || run.script.actions.is_empty()) {
            run.warm_at = Some(t);
        }
        if t >= soak::next_due(&run.samples, run.script.sample_seconds) {
            run.samples
                .push(sample(t, &mut run.resident, &mut run.device));
        }
        let judged = soak::judgeable(&run.samples, run.script.sample_seconds, run.warm_at);
        // The script's length, and past it until the growth can be judged (a slow machine
        // warms up later), but never past `MAX_STRETCH` times the length.
        let done = t >= run.script.seconds && judged || t >= run.script.seconds * soak::MAX_STRETCH;
        if done && !judged && run.samples.last().is_some_and(|s| s.seconds < t) {
            run.samples
                .push(sample(t, &mut run.resident, &mut run.device));
        }
        if done {
            let Some(run) = self.soak.take() else { return };
            let csv = soak::csv(&run.samples);
            print!("{csv}");
            if let Some(path) = &run.script.report
                && let Err(e) = std::fs::write(path, &csv)
            {
                self.fail(
                    event_loop,
                    Error::Io {
                        path: path.clone(),
                        source: e,
                    },
                );
                return;
            }
            let after = soak::baseline_after(run.script.sample_seconds, run.warm_at);
            match soak::growth(&run.samples, after) {
                None => {
                    self.fail(
                        event_loop,
                        Error::BadInput(format!(
                            "soak: no two samples after the warm-up ({} s, every action run {} times, and an interval whose resident peak rose by at most {:.0} %) within {:.0} s: memory still rising, or run longer",
                            run.script.sample_seconds,
                            soak::WARM_CYCLES,
                            soak::SETTLED * 100.0,
                            run.script.seconds * soak::MAX_STRETCH
                        )),
                    );
                }
                Some((res, gpu)) if res > soak::MAX_GROWTH || gpu > soak::MAX_GROWTH => {
                    self.fail(
                        event_loop,
                        Error::BadInput(format!(
                            "soak: memory grew after the warm-up ({:.0} s): resident {:+.1} %, GPU {:+.1} % (at most {:.0} %)",
                            after,
                            res * 100.0,
                            gpu * 100.0,
                            soak::MAX_GROWTH * 100.0
                        )),
                    );
                }
                Some((res, gpu)) => {
                    println!(
                        "soak: {} frames; after the warm-up ({:.0} s) resident memory {:+.1} %, GPU memory {:+.1} %",
                        run.frames,
                        after,
                        res * 100.0,
                        gpu * 100.0
                    );
                    event_loop.exit();
                }
            }
            return;
        }
        match action {
            Some(soak::Action::Fly) => {
                let c = &mut self.frame.camera;
                c.position += c.forward() * 3.0;
                c.yaw += 5f32.to_radians();
            }
            Some(soak::Action::Sun) => {
                self.frame.sun.azimuth_deg = (self.frame.sun.azimuth_deg + 7.0) % 360.0;
            }
            Some(soak::Action::Method(m)) => self.frame.method = m,
            Some(soak::Action::TexelMode(m)) => self.frame.texel.mode = m,
            Some(soak::Action::LodScale(v)) => self.frame.btf.lod_scale = v,
            Some(soak::Action::Resize(w, h)) => {
                let _ = r
                    .window
                    .request_inner_size(winit::dpi::PhysicalSize::new(w, h));
            }
            Some(soak::Action::Screenshot) => {
                let path =
                    std::env::temp_dir().join(format!("canopy-soak-{}.png", std::process::id()));
                self.screenshot(&path);
            }
            None => {}
        }
    }

    /// The image-based methods' ground sees the sky through the trees
    /// (`FrameDesc::ground_sky`): its volume is computed on its own thread for the renderer
    /// on show, and attached when done (a renderer replaced meanwhile gets its own).
    fn tend_sky(&mut self) {
        let Some(r) = &mut self.running else { return };
        if !self.frame.ground_sky || r.renderer.has_sky() {
            return;
        }
        match self.sky_job.take() {
            Some((id, job)) if id == r.renderer.id() && job.is_finished() => match job.join() {
                Ok(volume) => {
                    if let Err(e) = r.renderer.attach_sky(&r.ctx, &volume, SKY_DIRECTIONS) {
                        log::warn!("the ground's sky visibility could not be used: {e}");
                        self.frame.ground_sky = false;
                    }
                }
                Err(_) => {
                    log::warn!("the ground's sky visibility thread stopped unexpectedly");
                    self.frame.ground_sky = false;
                }
            },
            Some((id, job)) if id == r.renderer.id() => self.sky_job = Some((id, job)),
            // None yet, or one for a renderer no longer on show (left to finish unseen).
            _ => {
                let world = self.world.clone();
                let job = std::thread::spawn(move || {
                    let bounds = crate::render::sky_visibility::bounds_of(&world, true);
                    SkyVolume::compute(&world, &bounds, true, SKY_DIRECTIONS)
                });
                self.sky_job = Some((r.renderer.id(), job));
            }
        }
    }

    fn redraw(&mut self, event_loop: &ActiveEventLoop) {
        self.heap.tend();
        self.tend_bake();
        self.tend_sky();
        self.tend_reload();
        let now = Instant::now();
        let dt = now.duration_since(self.last_frame).as_secs_f32();
        self.last_frame = now;
        self.fly.update(&mut self.frame.camera, dt);
        // Stay above the ground.
        let p = self.frame.camera.position;
        let ground = self.world.terrain.height_at(p.x, p.z) + 1.5;
        if p.y < ground {
            self.frame.camera.position.y = ground;
        }
        let Some(r) = &mut self.running else { return };
        if r.config.width == 0 || r.config.height == 0 {
            return; // minimised
        }
        // Held by a Ctrl-drag in the view, or by a sun slider in the last frame's panel.
        self.frame.sun_held = self.fly.is_dragging_sun() || self.sun_slider_held;
        let frame = shown_frame(&self.frame, r.renderer.has_btf());
        if self.lose_device_at == Some(self.frames) {
            self.lose_device_at = None;
            r.ctx.device.destroy();
            let _ = r.ctx.device.poll(wgpu::PollType::Poll);
        }
        if r.ctx.is_lost() {
            // A new device, surface and renderer; the bake comes back from the cache (or is
            // baked again) as at start.
            log::warn!("the GPU device was lost: creating a new one");
            let window = r.window.clone();
            self.running = None;
            self.bake_job = None;
            self.rebake = None;
            match self.start(event_loop, Some(window)) {
                Ok(r) => {
                    r.window.request_redraw();
                    self.running = Some(r);
                    self.message = Some((
                        "the GPU device was lost and has been created again; reloading the bake"
                            .into(),
                        true,
                    ));
                }
                Err(e) => self.fail(
                    event_loop,
                    Error::Gpu(format!(
                        "the GPU device was lost and a new one could not be created ({e}); restart canopy"
                    )),
                ),
            }
            return;
        }
        let surface_texture = match r.surface.get_current_texture() {
            wgpu::CurrentSurfaceTexture::Success(t)
            | wgpu::CurrentSurfaceTexture::Suboptimal(t) => t,
            wgpu::CurrentSurfaceTexture::Timeout | wgpu::CurrentSurfaceTexture::Occluded => return,
            wgpu::CurrentSurfaceTexture::Outdated | wgpu::CurrentSurfaceTexture::Lost => {
                r.surface.configure(&r.ctx.device, &r.config);
                return;
            }
            other => {
                log::warn!("could not get the next frame: {other:?}");
                return;
            }
        };
        let view = surface_texture
            .texture
            .create_view(&wgpu::TextureViewDescriptor::default());
        let scene_view = surface_texture
            .texture
            .create_view(&wgpu::TextureViewDescriptor {
                format: Some(r.scene_format),
                ..Default::default()
            });
        // The 3D view at the render scale, stretched over the window when smaller.
        let (w, h) = (r.config.width, r.config.height);
        let (sw, sh) = crate::render::scale::scaled_size(w, h, frame.render_scale.scale);
        let scaled = (sw, sh) != (w, h);
        let drawn_into = if scaled {
            r.upscaler.target(&r.ctx, (sw, sh), r.scene_format).cloned()
        } else {
            Ok(scene_view.clone())
        };
        let result = drawn_into.and_then(|into| {
            r.renderer.render(
                &r.ctx,
                &frame,
                crate::render::FrameTarget {
                    view: &into,
                    format: r.scene_format,
                    width: sw,
                    height: sh,
                },
                false,
            )
        });
        if scaled {
            r.upscaler.blit(&r.ctx, &scene_view, r.scene_format);
        }
        self.stats.render_size = (sw, sh);
        match result {
            Ok(s) => {
                self.stats.trees_drawn = s.trees_drawn;
                self.stats.triangles = s.triangles;
                self.stats.shadow_triangles = s.shadow_triangles;
                self.stats.draw_calls = s.draw_calls;
                self.stats.btf = s.btf;
                self.stats.texel = s.texel;
                if s.sun_update_ms.is_some() {
                    self.stats.sun_update_ms = s.sun_update_ms;
                }
            }
            Err(e) => {
                self.message = Some((e.to_string(), true));
            }
        }
        self.stats.gpu_frame_ms = r.renderer.last_gpu_ms();
        // The whole frame's time, what the user waits for (the GPU's arrives frames late and
        // would overshoot); while the view waits for the bake, the frame's own cost.
        let frame_ms = if self.paused_for_bake {
            self.frame_cost.as_secs_f32() * 1e3
        } else {
            dt * 1e3
        };
        if self.frame.render_scale.auto {
            let s = &mut self.frame.render_scale;
            s.scale = crate::render::scale::next_scale(s.scale, frame_ms, s.target_ms);
        }
        self.stats.sun_update_gpu_ms = r.renderer.last_sun_update_gpu_ms();
        self.stats.paused_for_bake = self.paused_for_bake;
        self.stats.cpu_frame_ms = 0.9 * self.stats.cpu_frame_ms + 0.1 * f64::from(frame_ms);
        self.stats
            .history
            .push(f64::from(frame_ms), self.stats.gpu_frame_ms);
        self.stats.camera_speed = self.fly.speed;

        // egui on top of the 3D view.
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
                    view: &view,
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
        r.window.pre_present_notify();
        r.ctx.queue.present(surface_texture);
        self.frames += 1;
        self.sun_slider_held = actions.sun_held;

        if actions.open_bench {
            self.bench.open(r.egui_state.egui_ctx());
        }
        if actions.open_gallery {
            self.gallery.open = true;
        }
        if let Some(choice) = gallery_wants {
            // Drawn once per choice (a fraction of a second on a software renderer).
            match self.world.species.get(choice.0) {
                Some(tree) => {
                    match gallery::render_prototype(&r.ctx, tree, &self.frame, choice.1) {
                        Ok(img) => self
                            .gallery
                            .set_picture(r.egui_state.egui_ctx(), choice, &img),
                        Err(e) => self.gallery.set_error(choice, e.to_string()),
                    }
                }
                None => self.gallery.set_error(choice, "no such prototype".into()),
            }
        }
        if bench_actions.browse {
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
        if actions.screenshot {
            let path = crate::imageio::timestamped_path(Path::new("screenshots"));
            self.screenshot(&path);
        }
        if actions.screenshot_as {
            let picked = rfd::FileDialog::new()
                .add_filter("PNG image", &["png"])
                .set_file_name("canopy.png")
                .save_file();
            if let Some(path) = picked {
                self.screenshot(&path);
            }
        }
        if let Some(name) = actions.open_example {
            self.open_example(name);
        }
        if actions.open_file {
            let picked = rfd::FileDialog::new()
                .set_title("Open a scene or a bake")
                .add_filter("scene or bake", &["toml", "canopy"])
                .pick_file();
            if let Some(path) = picked {
                self.open(&path);
            }
        }
        self.tend_soak(event_loop);
        if let Some(path) = self.options.screenshot.clone()
            && self.frames >= u64::from(self.options.after_frames.max(1))
        {
            self.screenshot(&path);
            match self.message.take() {
                Some((m, true)) => self.fail(event_loop, Error::WriteImage { path, reason: m }),
                Some((m, false)) => {
                    println!("{m}");
                    event_loop.exit();
                }
                None => event_loop.exit(),
            }
        }
    }
}

impl ApplicationHandler for App {
    fn resumed(&mut self, event_loop: &ActiveEventLoop) {
        if self.running.is_some() {
            return;
        }
        match self.start(event_loop, None) {
            Ok(r) => {
                r.window.request_redraw();
                self.running = Some(r);
            }
            Err(e) => self.fail(event_loop, e),
        }
    }

    fn window_event(&mut self, event_loop: &ActiveEventLoop, _id: WindowId, event: WindowEvent) {
        let Some(r) = &mut self.running else { return };
        let consumed = r.egui_state.on_window_event(&r.window, &event).consumed;
        let egui_pointer = r.egui_state.egui_ctx().egui_wants_pointer_input();
        let egui_keys = r.egui_state.egui_ctx().egui_wants_keyboard_input();
        match event {
            WindowEvent::CloseRequested => event_loop.exit(),
            WindowEvent::Resized(size) => {
                r.config.width = size.width;
                r.config.height = size.height;
                if size.width > 0 && size.height > 0 {
                    r.surface.configure(&r.ctx.device, &r.config);
                }
            }
            WindowEvent::Focused(false) => self.fly.release_all(),
            WindowEvent::ModifiersChanged(m) => self.modifiers = m.state(),
            WindowEvent::KeyboardInput { event, .. } => {
                let pressed = event.state == ElementState::Pressed;
                if let PhysicalKey::Code(code) = event.physical_key {
                    if code == KeyCode::F12 && pressed && !event.repeat {
                        let path = crate::imageio::timestamped_path(Path::new("screenshots"));
                        self.screenshot(&path);
                    } else if code == KeyCode::Escape && pressed {
                        self.fly.release_all();
                    } else if !egui_keys || !pressed {
                        self.key(code, pressed);
                    }
                }
            }
            WindowEvent::MouseInput { state, button, .. } => {
                let pressed = state == ElementState::Pressed;
                match button {
                    MouseButton::Right => {
                        self.fly.set_looking(pressed && !(consumed && egui_pointer))
                    }
                    MouseButton::Left => {
                        let ctrl = self.modifiers.control_key();
                        self.fly.set_dragging_sun(pressed && ctrl && !egui_pointer);
                    }
                    _ => {}
                }
            }
            WindowEvent::CursorMoved { position, .. } => {
                if let Some((x, y)) = self.cursor {
                    let (dx, dy) = ((position.x - x) as f32, (position.y - y) as f32);
                    self.fly
                        .mouse_moved(dx, dy, &mut self.frame.camera, &mut self.frame.sun);
                }
                self.cursor = Some((position.x, position.y));
            }
            WindowEvent::MouseWheel { delta, .. } if !egui_pointer => {
                let notches = match delta {
                    MouseScrollDelta::LineDelta(_, y) => y,
                    MouseScrollDelta::PixelDelta(p) => (p.y / 40.0) as f32,
                };
                self.fly.wheel(notches);
            }
            WindowEvent::DroppedFile(path) => self.open(&path),
            WindowEvent::RedrawRequested => {
                let start = Instant::now();
                self.redraw(event_loop);
                self.frame_cost = start.elapsed();
            }
            _ => {}
        }
    }

    fn about_to_wait(&mut self, event_loop: &ActiveEventLoop) {
        let Some(r) = &self.running else { return };
        // While the first bake runs there are no trees to show: the view is drawn less
        // often, leaving the cores to the bake.
        let baking = self.bake_job.is_some() && self.frame.method.needs_bake();
        self.paused_for_bake = baking && !r.renderer.has_btf();
        if self.paused_for_bake {
            let next = self.last_frame + pause_while_baking(self.frame_cost);
            if Instant::now() < next {
                event_loop.set_control_flow(ControlFlow::WaitUntil(next));
                return;
            }
        }
        event_loop.set_control_flow(ControlFlow::Poll);
        r.window.request_redraw();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn data(name: &str) -> PathBuf {
        Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("tests/data")
            .join(name)
    }

    fn tmp(name: &str) -> PathBuf {
        let dir = std::env::temp_dir().join(format!("canopy-open-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        dir.join(name)
    }

    #[test]
    fn while_the_first_bake_runs_the_view_takes_a_quarter_of_the_time_at_most() {
        let ms = Duration::from_millis;
        // A costly frame waits three times its cost after it, within a second at most.
        assert_eq!(pause_while_baking(ms(150)), ms(600));
        assert_eq!(pause_while_baking(ms(400)), Duration::from_secs(1));
        // A cheap one still draws 5 frames a second, not hundreds.
        assert_eq!(pause_while_baking(ms(2)), ms(200));
    }

    #[test]
    fn open_takes_scenes_and_bakes_of_the_scene_and_refuses_the_rest_with_the_reason() {
        let current = Scene::default_scene();
        match open_file(&data("lone_tree.toml"), &current) {
            Ok(Opened::Scene(scene, world)) => {
                assert_eq!(scene.forest.count, Some(1));
                assert_eq!(world.forest.instances.len(), 1);
            }
            Ok(Opened::Baked(_)) => panic!("a scene opened as a bake"),
            Err(e) => panic!("{e}"),
        }
        let err = |p: &Path| match open_file(p, &current) {
            Ok(_) => panic!("{} opened", p.display()),
            Err(e) => e.to_string(),
        };
        let e = err(&tmp("missing.toml"));
        assert!(e.contains("missing.toml"), "{e}");
        let e = err(Path::new("notes.txt"));
        assert!(e.contains(".toml") && e.contains(".canopy"), "{e}");
        // A scene with a typo: the file, line and key.
        let typo = tmp("typo.toml");
        let text = std::fs::read_to_string(data("lone_tree.toml"))
            .unwrap()
            .replace("count = 1", "cout = 1");
        std::fs::write(&typo, text).unwrap();
        let e = err(&typo);
        assert!(e.contains("typo.toml") && e.contains("cout"), "{e}");
        // A bake of another scene, and a truncated bake: refused, never re-baked.
        let baked = crate::format::Baked {
            scene_hash: 42,
            settings: crate::format::BakeSettings {
                views: 6,
                tree_views: 6,
                lights: 6,
                resolution: 32,
                supersample: 2,
                vcm_resolution: 8,
                texel_resolution: 0,
            },
            btf: Vec::new(),
            vcm: Vec::new(),
            texels: Vec::new(),
        };
        let other = tmp("other.canopy");
        crate::format::write_atomic(&other, &baked).unwrap();
        let e = err(&other);
        assert!(e.contains("another scene"), "{e}");
        let cut = tmp("cut.canopy");
        let bytes = std::fs::read(&other).unwrap();
        std::fs::write(&cut, &bytes[..bytes.len() / 2]).unwrap();
        let e = err(&cut);
        assert!(e.contains("cut.canopy"), "{e}");
        assert_eq!(std::fs::read(&cut).unwrap().len(), bytes.len() / 2);
        // The bake of the scene on show opens.
        let mine = crate::format::Baked {
            scene_hash: crate::bake::cache::scene_hash(&current),
            ..baked
        };
        let own = tmp("own.canopy");
        crate::format::write_atomic(&own, &mine).unwrap();
        assert!(matches!(open_file(&own, &current), Ok(Opened::Baked(_))));
    }
}
