//! The `canopy` command: the viewer (default), and window-free commands that render a frame
//! to PNG, compare two images with FLIP, and describe a scene's trees.

use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::Instant;

use anyhow::Context as _;
use clap::{Parser, Subcommand};
use glam::Vec3;

use canopy::model::World;
use canopy::render::{AdapterPreference, Camera, FrameDesc, GpuContext, Method, Renderer};
use canopy::scene::Scene;

#[derive(Parser)]
#[command(
    name = "canopy",
    version,
    about = "Fly over a forest in real time; measure every stand-in against full geometry"
)]
struct Cli {
    #[command(subcommand)]
    command: Option<Command>,
}

#[derive(Subcommand)]
enum Command {
    /// Open the viewer on a scene file (default: the embedded default forest).
    View {
        /// Scene file (TOML). Omit for the embedded default forest.
        scene: Option<PathBuf>,
        /// Write a screenshot of the 3D view to this PNG after --after-frames frames, then
        /// quit (for scripts and CI).
        #[arg(long)]
        screenshot: Option<PathBuf>,
        /// Frames to render before the --screenshot is taken.
        #[arg(long, default_value_t = 3, requires = "screenshot")]
        after_frames: u32,
    },
    /// Render one frame to a PNG, no window needed.
    Render(RenderArgs),
    /// Mean FLIP and percentiles between two images (A is the reference).
    Compare {
        a: PathBuf,
        b: PathBuf,
        /// Print one JSON object instead of text.
        #[arg(long)]
        json: bool,
        /// Also write the FLIP error map (magma colours) to this PNG.
        #[arg(long)]
        diff: Option<PathBuf>,
    },
    /// Describe a scene: species, triangles per level, trees, terrain.
    Info {
        scene: Option<PathBuf>,
        #[arg(long)]
        json: bool,
    },
}

#[derive(clap::Args)]
struct RenderArgs {
    /// Scene file (TOML). Omit for the embedded default forest.
    scene: Option<PathBuf>,
    /// Output PNG.
    #[arg(long)]
    out: PathBuf,
    /// Rendering method.
    #[arg(long, default_value = "geometry", value_parser = parse_method)]
    method: Method,
    /// Image size, WIDTHxHEIGHT.
    #[arg(long, default_value = "1280x720", value_parser = parse_size)]
    size: (u32, u32),
    /// Camera position X,Y,Z in metres (default: the scene's start camera).
    #[arg(long, value_parser = parse_vec3, allow_hyphen_values = true, requires = "look_at")]
    camera: Option<Vec3>,
    /// Point the camera looks at, X,Y,Z in metres.
    #[arg(long, value_parser = parse_vec3, allow_hyphen_values = true, requires = "camera")]
    look_at: Option<Vec3>,
    /// Sun azimuth and elevation in degrees, AZ,EL (default: the scene's sun).
    #[arg(long, value_parser = parse_sun, allow_hyphen_values = true)]
    sun: Option<(f32, f32)>,
    /// Render N times larger on each side and average down (ground-truth anti-aliasing).
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u32).range(1..=8))]
    supersample: u32,
    /// Frames rendered to time (the median is reported).
    #[arg(long, default_value_t = 5, value_parser = clap::value_parser!(u32).range(1..=1000))]
    frames: u32,
    /// Side of each shadow cascade's map, in texels.
    #[arg(long, default_value_t = 2048, value_parser = clap::value_parser!(u32).range(16..=8192))]
    shadow_map: u32,
    /// Prefer the CPU (software) adapter.
    #[arg(long)]
    cpu: bool,
    /// Print one JSON object with the frame's statistics on stdout.
    #[arg(long)]
    json: bool,
}

fn parse_method(s: &str) -> Result<Method, String> {
    Method::parse(s).ok_or_else(|| {
        let names: Vec<_> = Method::ALL.iter().map(|m| m.name()).collect();
        format!(
            "unknown method {s:?}; expected one of: {}",
            names.join(", ")
        )
    })
}

fn parse_floats<const N: usize>(s: &str, what: &str) -> Result<[f32; N], String> {
    let parts: Vec<&str> = s.split(',').map(str::trim).collect();
    if parts.len() != N {
        return Err(format!(
            "expected {what} ({N} comma-separated numbers), got {s:?}"
        ));
    }
    let mut out = [0.0; N];
    for (o, p) in out.iter_mut().zip(&parts) {
        let v: f32 = p
            .parse()
            .map_err(|_| format!("{p:?} is not a number (in {s:?})"))?;
        if !v.is_finite() {
            return Err(format!("{p:?} is not a finite number (in {s:?})"));
        }
        *o = v;
    }
    Ok(out)
}

fn parse_vec3(s: &str) -> Result<Vec3, String> {
    parse_floats::<3>(s, "X,Y,Z").map(Vec3::from)
}

fn parse_sun(s: &str) -> Result<(f32, f32), String> {
    let [az, el] = parse_floats::<2>(s, "AZIMUTH,ELEVATION in degrees")?;
    if !(-90.0..=90.0).contains(&el) {
        return Err(format!("sun elevation {el} is outside -90..90 degrees"));
    }
    Ok((az, el))
}

fn parse_size(s: &str) -> Result<(u32, u32), String> {
    let (w, h) = s
        .split_once(['x', 'X'])
        .ok_or_else(|| format!("expected WIDTHxHEIGHT, e.g. 1280x720, got {s:?}"))?;
    let w: u32 = w
        .trim()
        .parse()
        .map_err(|_| format!("bad width in {s:?}"))?;
    let h: u32 = h
        .trim()
        .parse()
        .map_err(|_| format!("bad height in {s:?}"))?;
    if w == 0 || h == 0 || w > 16384 || h > 16384 {
        return Err(format!("size {w}x{h} must be between 1x1 and 16384x16384"));
    }
    Ok((w, h))
}

fn load_scene(path: Option<&Path>) -> canopy::Result<Scene> {
    match path {
        Some(p) => Ok(Scene::load(p)?),
        None => Ok(Scene::default_scene()),
    }
}

fn main() -> ExitCode {
    env_logger::Builder::from_env(env_logger::Env::default().default_filter_or("warn")).init();
    let cli = Cli::parse();
    let result = match cli.command {
        None => canopy::app::run(None).map_err(anyhow::Error::from),
        Some(Command::View {
            scene,
            screenshot,
            after_frames,
        }) => canopy::app::run_with(
            scene.as_deref(),
            canopy::app::ViewOptions {
                screenshot,
                after_frames,
            },
        )
        .map_err(anyhow::Error::from),
        Some(Command::Render(args)) => render(args),
        Some(Command::Compare { a, b, json, diff }) => compare(&a, &b, json, diff.as_deref()),
        Some(Command::Info { scene, json }) => info(scene.as_deref(), json),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            let bad_input = e
                .downcast_ref::<canopy::Error>()
                .is_some_and(canopy::Error::is_bad_input);
            ExitCode::from(if bad_input { 2 } else { 1 })
        }
    }
}

fn render(args: RenderArgs) -> anyhow::Result<()> {
    let scene = load_scene(args.scene.as_deref())?;
    let world = World::build(&scene).map_err(canopy::Error::from)?;
    let mut frame = FrameDesc::from_scene(&scene);
    frame.method = args.method;
    frame.shadows.map_size = args.shadow_map;
    if let (Some(pos), Some(target)) = (args.camera, args.look_at) {
        frame.camera = Camera::look_at(pos, target, frame.camera.fov_y_deg);
    }
    if let Some((az, el)) = args.sun {
        frame.sun.azimuth_deg = az;
        frame.sun.elevation_deg = el;
    }
    let (w, h) = args.size;
    canopy::render::target::check_size(
        w.saturating_mul(args.supersample),
        h.saturating_mul(args.supersample),
        None,
    )?;
    let pref = if args.cpu {
        AdapterPreference::Cpu
    } else {
        AdapterPreference::Default
    };
    let ctx = GpuContext::headless(pref)?;
    let mut renderer = Renderer::new(&ctx, &world)?;

    let progress = indicatif::ProgressBar::new(u64::from(args.frames) + 1);
    progress.set_style(
        indicatif::ProgressStyle::with_template("{msg} [{bar:30}] {pos}/{len} frames ({elapsed})")
            .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
    );
    progress.set_message(format!("rendering {w}x{h} with {}", args.method.name()));
    // The first frame builds pipelines and is not timed; the image comes from the last.
    let mut image = None;
    let mut stats = None;
    let mut times = Vec::new();
    for i in 0..=args.frames {
        let t0 = Instant::now();
        let (img, s) = renderer.render_image(&ctx, &frame, w, h, args.supersample)?;
        let wall = t0.elapsed().as_secs_f64() * 1e3;
        if i > 0 {
            times.push(s.gpu_ms.unwrap_or(wall));
        }
        image = Some(img);
        stats = Some(s);
        progress.inc(1);
    }
    progress.finish_and_clear();
    let (Some(image), Some(stats)) = (image, stats) else {
        anyhow::bail!("no frame was rendered");
    };
    canopy::imageio::save_png(&args.out, &image)?;
    times.sort_by(f64::total_cmp);
    let frame_ms = times[times.len() / 2];
    let source = if stats.gpu_ms.is_some() {
        "gpu-timestamps"
    } else {
        "cpu-wall-clock"
    };
    if args.json {
        let json = serde_json::json!({
            "method": args.method.name(),
            "width": w,
            "height": h,
            "supersample": args.supersample,
            "frame_ms": frame_ms,
            "frame_ms_source": source,
            "frames_timed": times.len(),
            "trees_drawn": stats.trees_drawn,
            "triangles": stats.triangles,
            "shadow_casters": stats.shadow_casters,
            "shadow_triangles": stats.shadow_triangles,
            "draw_calls": stats.draw_calls,
            "adapter": ctx.adapter_name(),
            "out": args.out.display().to_string(),
        });
        println!("{json}");
    } else {
        println!(
            "wrote {} ({w}x{h}, {}): {frame_ms:.2} ms/frame ({source}, median of {}), {} trees, {} triangles, on {}",
            args.out.display(),
            args.method.name(),
            times.len(),
            stats.trees_drawn,
            stats.triangles,
            ctx.adapter_name()
        );
    }
    Ok(())
}

fn compare(a: &Path, b: &Path, json: bool, diff: Option<&Path>) -> anyhow::Result<()> {
    let r = canopy::metrics::compare_files(a, b)?;
    if let Some(d) = diff {
        let img = image::DynamicImage::ImageRgb8(r.error_image()).to_rgba8();
        canopy::imageio::save_png(d, &img)?;
    }
    let s = r.stats;
    if json {
        println!("{}", serde_json::to_string(&s).context("encoding JSON")?);
    } else {
        println!(
            "FLIP {} vs {}: mean {:.4}, p50 {:.4}, p90 {:.4}, p99 {:.4}, max {:.4}",
            a.display(),
            b.display(),
            s.mean,
            s.p50,
            s.p90,
            s.p99,
            s.max
        );
    }
    Ok(())
}

fn info(scene: Option<&Path>, json: bool) -> anyhow::Result<()> {
    let scene = load_scene(scene)?;
    let t0 = Instant::now();
    let world = World::build(&scene).map_err(canopy::Error::from)?;
    let build_ms = t0.elapsed().as_secs_f64() * 1e3;
    let species: Vec<_> = world
        .species
        .iter()
        .map(|t| {
            let tri = t.triangle_counts();
            let parts = t.counts();
            let trees = world
                .forest
                .instances
                .iter()
                .filter(|i| {
                    world
                        .species
                        .get(i.species as usize)
                        .is_some_and(|s| s.name == t.name)
                })
                .count();
            serde_json::json!({
                "name": t.name,
                "trees": trees,
                "triangles": { "twig": tri.twig, "main_branch": tri.branch, "tree": tri.tree },
                "main_branches": parts.main_branches,
                "twigs": parts.twigs,
                "leaves": parts.foliage,
                "height_m": t.tree_bounds.max.y - t.tree_bounds.min.y,
            })
        })
        .collect();
    let report = serde_json::json!({
        "trees": world.forest.instances.len(),
        "terrain": { "size_m": world.terrain.size, "resolution": world.terrain.resolution },
        "species": species,
        "build_ms": build_ms,
    });
    if json {
        println!("{report}");
    } else {
        println!(
            "{} trees on a {} m terrain ({}x{} heights), built in {build_ms:.0} ms",
            world.forest.instances.len(),
            world.terrain.size,
            world.terrain.resolution,
            world.terrain.resolution
        );
        for s in report["species"].as_array().into_iter().flatten() {
            println!(
                "  {:<10} {:>5} trees; triangles: twig {}, main branch {}, tree {}; {} main branches, {} twigs, {} leaves/needles, {:.1} m tall",
                s["name"].as_str().unwrap_or("?"),
                s["trees"],
                s["triangles"]["twig"],
                s["triangles"]["main_branch"],
                s["triangles"]["tree"],
                s["main_branches"],
                s["twigs"],
                s["leaves"],
                s["height_m"].as_f64().unwrap_or(0.0)
            );
        }
    }
    Ok(())
}
