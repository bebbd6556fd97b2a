//! `canopy bench` from its parsed arguments: load the scene (and its bake when a method
//! needs one), resolve the flight, run every configuration with a progress bar, write the
//! outputs.

use std::path::{Path, PathBuf};
use std::time::Instant;

use super::flight::{Flight, FlightContext};
use super::report::{self, RunInfo};
use super::run::{self, BenchOptions, BenchResults, BenchStep, Config, Sweep};
use super::truth_key::scene_content;
use super::tune::{
    BakeChoice, TuneTarget, bake_candidates, bake_knob_candidates, candidates_for, choose,
    with_render_table, with_table_keys,
};
use crate::model::World;
use crate::progress::{BAKE_BAR, bar, show_bake};
use crate::render::{AdapterPreference, FrameDesc, GpuContext, Method, Renderer};
use crate::scene::Scene;
use crate::{Error, Result};

/// What `canopy bench` was asked.
#[derive(Clone, Debug)]
pub struct BenchRequest {
    /// Scene file; `None` for the embedded default forest.
    pub scene: Option<PathBuf>,
    /// A built-in flight's name or a flight file.
    pub flight: String,
    pub methods: Vec<Method>,
    pub sweeps: Vec<Sweep>,
    pub width: u32,
    pub height: u32,
    /// Frames of the flight (default: the flight's own).
    pub frames: Option<usize>,
    pub out: PathBuf,
    pub truth_supersample: u32,
    pub repeats: u32,
    pub adapter: AdapterPreference,
    /// Draw a progress bar on stderr.
    pub progress: bool,
}

/// What a finished bench measured and where it wrote it.
pub struct BenchOutcome {
    pub run: RunInfo,
    pub results: BenchResults,
    pub written: Vec<PathBuf>,
}

/// Most frames a bench renders per flight.
pub const MAX_BENCH_FRAMES: usize = 10_000;

/// The flight's frames and the configurations of `req`, checked before anything renders.
pub fn plan(
    req: &BenchRequest,
    scene: &Scene,
    world: &World,
) -> Result<(Flight, usize, Vec<Config>)> {
    let flight = Flight::resolve(&req.flight, &FlightContext::from_world(world))?;
    let n = req.frames.unwrap_or(flight.default_frames);
    if !(2..=MAX_BENCH_FRAMES).contains(&n) {
        return Err(Error::BadInput(format!(
            "--frames {n}: a bench needs 2 to {MAX_BENCH_FRAMES} frames (the temporal figures compare consecutive frames)"
        )));
    }
    // The knobs start from the scene's frame (its `[render]` table over the defaults).
    let configs = run::configurations(&req.methods, &req.sweeps, &FrameDesc::from_scene(scene))?;
    Ok((flight, n, configs))
}

/// Reads the scene (the default forest for `None`) and builds its world.
fn load(scene: Option<&Path>) -> Result<(Scene, World)> {
    let scene = match scene {
        Some(p) => Scene::load(p)?,
        None => Scene::default_scene(),
    };
    let world = scene.build_world()?;
    Ok((scene, world))
}

/// A GPU context and a renderer for `world`, ready for reference frames (the truth), with
/// the scene's bake attached when `bake`.
fn renderer(
    scene: &Scene,
    world: &World,
    adapter: AdapterPreference,
    bake: Option<&Path>,
    progress: bool,
) -> Result<(GpuContext, Renderer)> {
    let ctx = GpuContext::headless(adapter)?;
    let mut renderer = Renderer::new(&ctx, world)?;
    let directions = crate::render::Reference::default().sky_directions;
    renderer.prepare_reference_with(&ctx, world, directions, true, |_| {
        crate::bake::sky_cache::sky_volume(scene, world, directions, true)
    })?;
    if let Some(cache_dir) = bake {
        attach_bake(
            &ctx,
            &mut renderer,
            scene,
            world,
            cache_dir,
            &bar(progress, 0, BAKE_BAR),
        )?;
    }
    Ok((ctx, renderer))
}

/// Loads `scene`'s bake from the cache in `cache_dir` or bakes it there (its progress on
/// `bar`) and attaches it.
fn attach_bake(
    ctx: &GpuContext,
    renderer: &mut Renderer,
    scene: &Scene,
    world: &World,
    cache_dir: &Path,
    bar: &indicatif::ProgressBar,
) -> Result<()> {
    let path = crate::bake::cache::cache_path_in(cache_dir, scene);
    let baked = crate::bake::load_or_bake_at(&path, ctx, scene, world, &mut |p| show_bake(bar, p));
    bar.finish_and_clear();
    renderer.attach_btf(ctx, &baked?.0, world)
}

/// The runner's options, the sizes checked.
fn options(
    scene: &Scene,
    (width, height): (u32, u32),
    truth_supersample: u32,
    repeats: u32,
    cache_dir: &Path,
) -> Result<BenchOptions> {
    crate::render::target::check_size(
        width.saturating_mul(truth_supersample.max(1)),
        height.saturating_mul(truth_supersample.max(1)),
        None,
    )?;
    Ok(BenchOptions {
        width,
        height,
        truth_supersample: truth_supersample.max(1),
        repeats: repeats.max(1),
        cache_dir: cache_dir.to_path_buf(),
        scene_content: scene_content(scene),
        reference: Some(crate::render::Reference::default()),
    })
}

/// What every measurement of a command shares: the GPU, the scene and the frames along
/// its flight, the bench options, and the progress bar's switch and name.
struct Measure<'a> {
    ctx: &'a GpuContext,
    scene: &'a Scene,
    frames: &'a [super::flight::FlightFrame],
    opts: &'a BenchOptions,
    progress: bool,
    what: &'a str,
}

/// Runs `configs` along `m`'s frames from the scene's frame, with a progress bar.
fn measure(m: &Measure<'_>, renderer: &mut Renderer, configs: &[Config]) -> Result<BenchResults> {
    let Measure {
        ctx,
        scene,
        frames,
        opts,
        progress,
        what,
    } = *m;
    let n = frames.len();
    let base = FrameDesc::from_scene(scene);
    let total = (n * (configs.len() + 1)) as u64;
    let bar = bar(
        progress,
        total,
        &format!("{what} {{msg:40}} [{{bar:30}}] {{pos}}/{{len}} renders ({{eta}} left)"),
    );
    let results = run::run(
        ctx,
        renderer,
        &base,
        frames,
        configs,
        opts,
        &mut |step| match step {
            BenchStep::Truth { frame, cached } => {
                bar.set_message(format!(
                    "frame {}/{n}: truth {}",
                    frame + 1,
                    if cached { "(cached)" } else { "rendered" }
                ));
                bar.inc(1);
            }
            BenchStep::Config { frame, label } => {
                bar.set_message(format!("frame {}/{n}: {label}", frame + 1));
                bar.inc(1);
            }
            BenchStep::FrameDone { .. } => {}
        },
    )?;
    bar.finish_and_clear();
    Ok(results)
}

/// Runs the whole bench of `req`.
pub fn run_command(req: &BenchRequest) -> Result<BenchOutcome> {
    let started = Instant::now();
    let (scene, world) = load(req.scene.as_deref())?;
    let (flight, n, configs) = plan(req, &scene, &world)?;
    let cache_dir = crate::bake::cache::cache_dir();
    let opts = options(
        &scene,
        (req.width, req.height),
        req.truth_supersample,
        req.repeats,
        &cache_dir,
    )?;
    let bake = configs.iter().any(|c| c.method.needs_bake());
    let (ctx, mut renderer) = renderer(
        &scene,
        &world,
        req.adapter,
        bake.then_some(cache_dir.as_path()),
        req.progress,
    )?;
    let frames = flight.frames(n);
    let m = Measure {
        ctx: &ctx,
        scene: &scene,
        frames: &frames,
        opts: &opts,
        progress: req.progress,
        what: "bench",
    };
    // A method the bake cannot draw (a scene baked without impostors or volumes) is left
    // out with the reason, the others measured.
    let configs: Vec<Config> = configs
        .into_iter()
        .filter(|c| match renderer.can_draw(c.method) {
            Ok(()) => true,
            Err(e) => {
                eprintln!("bench: {} left out: {e}", c.label);
                false
            }
        })
        .collect();
    if configs.is_empty() {
        return Err(Error::BadInput(
            "no method of --methods can draw this scene's bake".into(),
        ));
    }
    let results = measure(&m, &mut renderer, &configs)?;
    let run = RunInfo {
        scene: req
            .scene
            .as_ref()
            .map_or("(default forest)".into(), |p| p.display().to_string()),
        flight: flight.name.clone(),
        frames: n,
        width: req.width,
        height: req.height,
        truth_supersample: opts.truth_supersample,
        repeats: opts.repeats,
        device: ctx.adapter_name(),
        time_source: results.time_source,
        truth_rendered: results.truth_rendered,
        truth_cached: results.truth_cached,
        seconds: started.elapsed().as_secs_f64(),
    };
    let written = report::write_all(&req.out, &run, &results)?;
    Ok(BenchOutcome {
        run,
        results,
        written,
    })
}

/// What `canopy tune` was asked.
#[derive(Clone, Debug)]
pub struct TuneRequest {
    pub scene: Option<PathBuf>,
    pub flight: String,
    pub target: TuneTarget,
    pub width: u32,
    pub height: u32,
    pub frames: usize,
    pub truth_supersample: u32,
    pub repeats: u32,
    pub adapter: AdapterPreference,
    pub progress: bool,
    /// Write the chosen knobs as the scene file's `[render]` table.
    pub write: bool,
    /// Search the bake's views, lights and resolution too (each bake cached).
    pub bake: bool,
    /// The method whose knobs are searched (`btf` or `impostor`).
    pub method: Method,
    /// Where bakes are read and written (the CLI's: `bake::cache::cache_dir()`).
    pub cache_dir: PathBuf,
}

/// What `canopy tune` found.
pub struct TuneOutcome {
    pub configs: Vec<Config>,
    pub results: BenchResults,
    /// Index of the chosen configuration; `None` when none meets the target.
    pub chosen: Option<usize>,
    pub seconds: f64,
    /// The scene file the `[render]` table was written to.
    pub written: Option<PathBuf>,
    pub device: String,
    /// With `--bake`: the bake of each configuration, and each bake's image bytes.
    pub bakes: Vec<Option<(BakeChoice, u64)>>,
}

/// Refuses a tune request that cannot run, before anything is loaded.
fn check_tune(req: &TuneRequest) -> Result<()> {
    if req.write && req.scene.is_none() {
        return Err(Error::BadInput(
            "--write needs a scene file: the embedded default forest cannot be changed; save it to a file first".into(),
        ));
    }
    let tuned = super::tune::tuned_methods();
    if !tuned.contains(&req.method) {
        let names: Vec<&str> = tuned.iter().map(|m| m.name()).collect();
        let list = match names.split_last() {
            Some((last, rest)) if !rest.is_empty() => format!("{} or {last}", rest.join(", ")),
            _ => names.join(""),
        };
        return Err(Error::BadInput(format!(
            "--method {}: tune searches the knobs of {list}",
            req.method.name()
        )));
    }
    if req.method != Method::Btf && (req.write || req.bake) {
        return Err(Error::BadInput(format!(
            "--write and --bake search and write btf's knobs and bake; with --method {} tune only measures and reports",
            req.method.name()
        )));
    }
    if !(2..=MAX_BENCH_FRAMES).contains(&req.frames) {
        return Err(Error::BadInput(format!(
            "--frames {}: tune needs 2 to {MAX_BENCH_FRAMES} frames",
            req.frames
        )));
    }
    Ok(())
}

/// Measures the tune grid along the flight and picks the cheapest configuration meeting
/// the target; writes it into the scene file when asked (atomically).
pub fn run_tune(req: &TuneRequest) -> Result<TuneOutcome> {
    let started = Instant::now();
    check_tune(req)?;
    let (scene, world) = load(req.scene.as_deref())?;
    let flight = Flight::resolve(&req.flight, &FlightContext::from_world(&world))?;
    let opts = options(
        &scene,
        (req.width, req.height),
        req.truth_supersample,
        req.repeats,
        &req.cache_dir,
    )?;
    let frames = flight.frames(req.frames);
    let (ctx, mut renderer) = renderer(
        &scene,
        &world,
        req.adapter,
        (!req.bake).then_some(req.cache_dir.as_path()),
        req.progress,
    )?;
    let base = FrameDesc::from_scene(&scene);
    let m = Measure {
        ctx: &ctx,
        scene: &scene,
        frames: &frames,
        opts: &opts,
        progress: req.progress,
        what: "tune",
    };
    let (results, bakes) = if req.bake {
        let mut all: Option<BenchResults> = None;
        let mut bakes = Vec::new();
        let choices = bake_candidates();
        let max_layers = u64::from(ctx.device.limits().max_texture_array_layers);
        for (k, b) in choices.iter().enumerate() {
            let layers = crate::render::method::btf::atlas_layers(
                world.species.len() as u64 * 3 * u64::from(b.views * b.lights + b.views),
            );
            if layers > max_layers {
                log::warn!(
                    "tune: skipping the bake of {} views x {} lights: {layers} texture layers, this GPU allows {max_layers}",
                    b.views,
                    b.lights
                );
                continue;
            }
            let mut s = scene.clone();
            // The tried view count at every level, the tree level's too.
            s.bake.views = b.views;
            s.bake.tree_views = b.views;
            s.bake.lights = b.lights;
            s.bake.resolution = b.resolution;
            let template = format!(
                "bake {}/{} ({}x{} at {}²) {{msg:24}} [{{bar:30}}] {{pos}}/{{len}} ({{eta}} left)",
                k + 1,
                choices.len(),
                b.views,
                b.lights,
                b.resolution
            );
            attach_bake(
                &ctx,
                &mut renderer,
                &s,
                &world,
                &req.cache_dir,
                &bar(req.progress, 0, &template),
            )?;
            let bytes = renderer.btf_bytes();
            let configs: Vec<Config> = bake_knob_candidates(&base)
                .into_iter()
                .map(|mut c| {
                    c.label = format!(
                        "{} views={} lights={} resolution={}",
                        c.label, b.views, b.lights, b.resolution
                    );
                    c
                })
                .collect();
            bakes.extend(configs.iter().map(|_| Some((*b, bytes))));
            let r = measure(&m, &mut renderer, &configs)?;
            match &mut all {
                Some(a) => a.append(r),
                None => all = Some(r),
            }
        }
        let all = all.ok_or_else(|| Error::BadInput("no bake to try".into()))?;
        (all, bakes)
    } else {
        let configs = candidates_for(req.method, &base);
        renderer.can_draw(req.method)?;
        let r = measure(&m, &mut renderer, &configs)?;
        let bakes = vec![None; r.configs.len()];
        (r, bakes)
    };
    let configs = results.configs.clone();
    let chosen = choose(&results.summaries, &req.target);
    let mut written = None;
    if let (true, Some(i), Some(path)) = (req.write, chosen, req.scene.as_ref()) {
        let text = std::fs::read_to_string(path).map_err(|e| {
            Error::BadInput(format!(
                "cannot read {} to write [render]: {e}",
                path.display()
            ))
        })?;
        let mut chosen = base;
        configs[i].knobs.apply_to(&mut chosen);
        let mut new = with_render_table(&text, &chosen.btf);
        if let Some((b, _)) = bakes[i] {
            new = with_table_keys(
                &new,
                "bake",
                &[
                    ("views", b.views.to_string()),
                    ("lights", b.lights.to_string()),
                    ("resolution", b.resolution.to_string()),
                ],
            );
        }
        // Check before replacing: the file must still parse as a scene.
        Scene::parse(&new, &path.display().to_string())?;
        report::write_text(path, &new)?;
        written = Some(path.clone());
    }
    Ok(TuneOutcome {
        configs,
        results,
        chosen,
        seconds: started.elapsed().as_secs_f64(),
        written,
        device: ctx.adapter_name(),
        bakes,
    })
}

impl TuneOutcome {
    /// The chosen configuration's summary.
    pub fn chosen_summary(&self) -> Option<&super::run::ConfigSummary> {
        self.chosen.map(|i| &self.results.summaries[i])
    }

    /// What `canopy tune --json` prints.
    pub fn json(&self, target: &TuneTarget) -> String {
        // The knobs tune varies, as chosen.
        let settings = self.chosen.map(|i| {
            let mut map = self.configs[i].knobs.to_map();
            map.retain(|name, _| {
                crate::render::method::knobs_named(name)
                    .iter()
                    .any(|k| !k.tune.is_empty())
            });
            map
        });
        let json = serde_json::json!({
            "max_error": target.max_error,
            "max_flicker": target.max_flicker,
            "configurations_tried": self.configs.len(),
            "frames": self.results.frames,
            "seconds": self.seconds,
            "device": self.device,
            "chosen": self.chosen_summary(),
            "settings": settings,
            "written": self.written,
            "bake": self.chosen.and_then(|i| self.bakes[i]).map(|(b, bytes)| serde_json::json!({
                "views": b.views,
                "lights": b.lights,
                "resolution": b.resolution,
                "image_bytes": bytes,
            })),
        });
        format!("{json:#}")
    }

    /// What `canopy tune` prints.
    pub fn text(&self, target: &TuneTarget) -> String {
        let mut out = format!(
            "tried {} configurations along {} frames in {:.0} s on {}\n",
            self.configs.len(),
            self.results.frames,
            self.seconds,
            self.device
        );
        match self.chosen_summary() {
            Some(s) => {
                out += &format!(
                    "chosen: {}: {:.2} ms median, mean FLIP {:.4} (target {}), flicker ratio {:.2} (target {})\n",
                    s.label,
                    s.median_ms,
                    s.mean_flip,
                    target.max_error,
                    s.flicker_ratio,
                    target.max_flicker
                );
                if let Some(Some((_, bytes))) = self.chosen.map(|i| self.bakes[i]) {
                    out += &format!("its bake's images: {:.1} MB\n", bytes as f64 / 1e6);
                }
            }
            None => {
                let best = self
                    .results
                    .summaries
                    .iter()
                    .min_by(|a, b| a.mean_flip.total_cmp(&b.mean_flip));
                out += &format!(
                    "no configuration meets mean FLIP {} and flicker {}; the most accurate: {}\n",
                    target.max_error,
                    target.max_flicker,
                    best.map_or("-".into(), |b| format!("{} at {:.4}", b.label, b.mean_flip))
                );
            }
        }
        if let Some(p) = &self.written {
            out += &format!("wrote [render] to {}\n", p.display());
        }
        out
    }
}
