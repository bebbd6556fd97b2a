//! `canopy bench` from its parsed arguments: load the scene (and its bake when a method
//! needs one), resolve the flight, run every configuration with a progress bar, write the
//! outputs.

use std::path::PathBuf;
use std::time::Instant;

use super::flight::{Flight, FlightContext};
use super::report::{self, RunInfo};
use super::run::{self, BenchOptions, BenchResults, BenchStep, Config, Sweep};
use super::truth_key::scene_content;
use crate::render::btf::BtfSettings;
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
    world: &crate::model::World,
) -> Result<(Flight, usize, Vec<Config>)> {
    let flight = Flight::resolve(&req.flight, &FlightContext::from_world(world))?;
    let n = req.frames.unwrap_or(flight.default_frames);
    if !(2..=MAX_BENCH_FRAMES).contains(&n) {
        return Err(Error::BadInput(format!(
            "--frames {n}: a bench needs 2 to {MAX_BENCH_FRAMES} frames (the temporal figures compare consecutive frames)"
        )));
    }
    let configs = run::configurations(&req.methods, &req.sweeps, BtfSettings::default())?;
    Ok((flight, n, configs))
}

/// Runs the whole bench of `req`.
pub fn run_command(req: &BenchRequest) -> Result<BenchOutcome> {
    let started = Instant::now();
    let scene = match &req.scene {
        Some(p) => Scene::load(p)?,
        None => Scene::default_scene(),
    };
    let world = scene.build_world()?;
    let (flight, n, configs) = plan(req, &world)?;
    crate::render::target::check_size(
        req.width.saturating_mul(req.truth_supersample.max(1)),
        req.height.saturating_mul(req.truth_supersample.max(1)),
        None,
    )?;
    let ctx = GpuContext::headless(req.adapter)?;
    let mut renderer = Renderer::new(&ctx, &world)?;
    if configs.iter().any(|c| c.method.needs_bake()) {
        let bar = bar(
            req.progress,
            0,
            "baking {msg:24} [{bar:30}] {pos}/{len} steps ({eta} left)",
        );
        let baked = crate::bake::load_or_bake(&ctx, &scene, &world, &mut |p| {
            bar.set_length(p.total);
            bar.set_position(p.done);
            bar.set_message(p.what.clone());
        });
        bar.finish_and_clear();
        renderer.attach_btf(&ctx, &baked?.0, &world)?;
    }
    let frames = flight.frames(n);
    let opts = BenchOptions {
        width: req.width,
        height: req.height,
        truth_supersample: req.truth_supersample.max(1),
        repeats: req.repeats.max(1),
        cache_dir: crate::bake::cache::cache_dir(),
        scene_content: scene_content(&scene),
    };
    let base = FrameDesc::from_scene(&scene);
    let total = (n * (configs.len() + 1)) as u64;
    let bar = bar(
        req.progress,
        total,
        "bench {msg:40} [{bar:30}] {pos}/{len} renders ({eta} left)",
    );
    let frames_total = n;
    let results = run::run(
        &ctx,
        &mut renderer,
        &base,
        &frames,
        &configs,
        &opts,
        &mut |step| match step {
            BenchStep::Truth { frame, cached } => {
                bar.set_message(format!(
                    "frame {}/{frames_total}: truth {}",
                    frame + 1,
                    if cached { "(cached)" } else { "rendered" }
                ));
                bar.inc(1);
            }
            BenchStep::Config { frame, label } => {
                bar.set_message(format!("frame {}/{frames_total}: {label}", frame + 1));
                bar.inc(1);
            }
            BenchStep::FrameDone { .. } => {}
        },
    )?;
    bar.finish_and_clear();
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

fn bar(show: bool, len: u64, template: &str) -> indicatif::ProgressBar {
    if !show {
        return indicatif::ProgressBar::hidden();
    }
    let bar = indicatif::ProgressBar::new(len);
    bar.set_style(
        indicatif::ProgressStyle::with_template(template)
            .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
    );
    bar
}
