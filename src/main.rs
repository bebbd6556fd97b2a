//! The `canopy` command: the viewer (default), and window-free commands that render a frame
//! to PNG, compare two images with FLIP, and describe a scene's trees.

use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::Instant;

use anyhow::Context as _;
use clap::{Parser, Subcommand};
use glam::Vec3;

use canopy::bake::report::BakeReport;
use canopy::model::summary::WorldSummary;
use canopy::progress;
use canopy::render::btf::PlaneMode;
use canopy::render::measure::{self, FrameReport, MeasureOptions};
use canopy::render::method::texel::{TexelMode, TexelSettings};
use canopy::render::{AdapterPreference, Camera, FrameDesc, GpuContext, Method, Renderer};
use canopy::scene::Scene;
use canopy::slices::SliceBounds;

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
    /// Open the viewer on a scene file (default: the embedded example forest of 36,000 trees).
    View {
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
        /// Method to start with (btf shows terrain and sky until its bake is ready).
        #[arg(long, default_value = "btf", value_parser = parse_method)]
        method: Method,
        /// Use this baked file (from `canopy bake --out`) instead of the cache; it must have
        /// been baked from the scene, and is never re-baked.
        #[arg(long)]
        baked: Option<PathBuf>,
        /// The 3D view's resolution as a fraction of the window (0.25..=1), or `auto` to
        /// hold a frame time by lowering it (the default on a software renderer).
        #[arg(long, value_parser = parse_render_scale)]
        render_scale: Option<canopy::render::scale::RenderScale>,
        /// Run a soak script (camera moves, sun sweeps, method and knob changes, resizes,
        /// screenshots; memory sampled), then quit; fails if memory grew over 5 %.
        #[arg(long)]
        script: Option<PathBuf>,
    },
    /// Render one frame to a PNG, no window needed.
    Render(RenderArgs),
    /// Bake the BTF image sets of a scene (default: into the cache the viewer and `render` use).
    Bake {
        /// Scene file (TOML). Omit for the embedded default forest (1,000 trees).
        scene: Option<PathBuf>,
        /// Write the baked file here instead of the cache.
        #[arg(long)]
        out: Option<PathBuf>,
        /// Prefer the CPU (software) adapter.
        #[arg(long)]
        cpu: bool,
        /// Print one JSON object describing the bake on stdout.
        #[arg(long)]
        json: bool,
    },
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
        /// Split the error by pixel class, from an image of A's classes (`render --method
        /// geometry --pixel-classes`, same camera and size), with B's mean linear
        /// luminance over A's in each class.
        #[arg(long)]
        classes: Option<PathBuf>,
    },
    /// Speed against accuracy along a flight: every method (and every swept btf knob value)
    /// timed and compared with the geometry ground truth, frame by frame; writes
    /// results.csv, summary.json, chart.png, flight.png and each configuration's worst frame.
    Bench(BenchArgs),
    /// Model no more than a scene needs: measure a grid of btf knobs (LOD scale, weight
    /// threshold, fade band, planes) along a flight and pick the cheapest meeting
    /// --max-error (mean FLIP) and --max-flicker; --write stores it as the scene's [render].
    Tune(TuneArgs),
    /// Describe a scene: species, triangles per level, trees, terrain, bake estimate;
    /// --map draws where the trees stand, seen from above.
    Info {
        scene: Option<PathBuf>,
        #[arg(long)]
        json: bool,
        /// Write a map of the scene from above (terrain, stands, clearings, meadows, every
        /// tree's crown in its species' colour) as a PNG.
        #[arg(long, value_name = "MAP.png")]
        map: Option<PathBuf>,
        /// The map's side in pixels (16..8192).
        #[arg(long, default_value_t = 1024, value_name = "PX")]
        map_size: u32,
    },
}

#[derive(clap::Args)]
struct BenchArgs {
    /// Scene file (TOML). Omit for the embedded default forest (1,000 trees).
    scene: Option<PathBuf>,
    /// A built-in flight (overview, walk, approach, sunset, orbit) or a flight file (TOML).
    #[arg(long, default_value = "walk")]
    flight: String,
    /// Methods to measure, comma-separated.
    #[arg(long, value_delimiter = ',', value_parser = parse_method, default_value = "geometry,btf,billboard,texel,hybrid")]
    methods: Vec<Method>,
    /// Sweep a knob: KEY=V1,V2,... (btf and hybrid: lod_scale, weight_threshold, lod_fade, planes,
    /// vcm, light_gain, gpu_far, gpu_near; texel: slice_d0, slice_d1, max_slices, texel_mode, texel_tiles, tile_distance;
    /// all three: ground_sky); repeat for a grid.
    #[arg(long, value_parser = parse_sweep)]
    sweep: Vec<canopy::bench::run::Sweep>,
    /// Image size, WIDTHxHEIGHT.
    #[arg(long, value_parser = parse_size, default_value = "640x360")]
    size: (u32, u32),
    /// Frames of the flight (default: the flight's own).
    #[arg(long)]
    frames: Option<usize>,
    /// Output folder.
    #[arg(long, default_value = "bench-out")]
    out: PathBuf,
    /// Samples per pixel side of the ground truth.
    #[arg(long, default_value_t = 2, value_parser = clap::value_parser!(u32).range(1..=4))]
    truth_supersample: u32,
    /// Timed renders per frame and configuration (the median is kept).
    #[arg(long, default_value_t = 3, value_parser = clap::value_parser!(u32).range(1..=50))]
    repeats: u32,
    /// Print the summary as JSON on stdout.
    #[arg(long)]
    json: bool,
    /// Prefer the CPU (software) adapter.
    #[arg(long)]
    cpu: bool,
}

#[derive(clap::Args)]
struct TuneArgs {
    /// Scene file (TOML). Omit for the embedded default forest (1,000 trees).
    scene: Option<PathBuf>,
    /// Largest mean FLIP against the truth along the flight.
    #[arg(long)]
    max_error: f64,
    /// Largest flicker ratio (the method's mean frame-to-frame change over the truth's).
    #[arg(long, default_value_t = canopy::bench::tune::DEFAULT_MAX_FLICKER)]
    max_flicker: f64,
    /// A built-in flight (overview, walk, approach, sunset, orbit) or a flight file (TOML).
    #[arg(long, default_value = "walk")]
    flight: String,
    /// Frames of the flight.
    #[arg(long, default_value_t = 8)]
    frames: usize,
    /// Image size, WIDTHxHEIGHT.
    #[arg(long, value_parser = parse_size, default_value = "320x180")]
    size: (u32, u32),
    /// Samples per pixel side of the ground truth.
    #[arg(long, default_value_t = 2, value_parser = clap::value_parser!(u32).range(1..=4))]
    truth_supersample: u32,
    /// Timed renders per frame and configuration (the median is kept).
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u32).range(1..=50))]
    repeats: u32,
    /// Write the chosen settings as the scene file's [render] table (and, with --bake, its
    /// [bake] views, lights and resolution).
    #[arg(long)]
    write: bool,
    /// Search the bake too: views 6/18 x lights 6/18 x resolution 32/64 (8 bakes, each
    /// cached), each with LOD scale 0.5–4 x weight threshold 0/0.2.
    #[arg(long)]
    bake: bool,
    /// Print the result as JSON on stdout.
    #[arg(long)]
    json: bool,
    /// Prefer the CPU (software) adapter.
    #[arg(long)]
    cpu: bool,
}

#[derive(clap::Args)]
struct RenderArgs {
    /// Scene file (TOML). Omit for the embedded default forest (1,000 trees).
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
    /// btf / billboard: use this baked file (from `canopy bake --out`) instead of the cache;
    /// it must have been baked from this scene, and is never re-baked.
    #[arg(long)]
    baked: Option<PathBuf>,
    /// geometry: draw the reference the bench measures against (sky hidden by trees and
    /// hills, sun shadows over the whole scene from 4096² cascades); slower.
    #[arg(long)]
    reference: bool,
    /// geometry: draw each pixel's class instead of its colour (sky black, ground red,
    /// trees nearer than 100 m green, farther blue), for `compare --classes`.
    #[arg(long)]
    pixel_classes: bool,
    /// geometry --reference: directions over the sky whose depth maps give the sky
    /// visibility.
    #[arg(long, default_value_t = canopy::render::sky_visibility::SKY_DIRECTIONS,
          value_parser = clap::value_parser!(u32).range(1..=1024), requires = "reference")]
    sky_directions: u32,
    /// With --reference: side in texels of each tree's own sun map (its shadows on
    /// itself, fine at any distance); 0: none, the cascades alone (the reference before
    /// session 15).
    #[arg(long, default_value_t = canopy::render::self_shadow::SELF_MAP_SIZE,
          value_parser = clap::value_parser!(u32).range(0..=8192), requires = "reference")]
    self_map: u32,
    /// btf: a level is used while its largest texel projects below this many pixels
    /// (default: the scene's [render] table, else 1).
    #[arg(long, value_parser = parse_positive)]
    lod_scale: Option<f32>,
    /// btf: images whose blending weight is below this are skipped, 0..1 (default: the
    /// scene's [render] table, else 0).
    #[arg(long, value_parser = parse_unit)]
    weight_threshold: Option<f32>,
    /// btf: one camera-facing plane per billboard, or three crossed planes (default: the
    /// scene's [render] table, else single).
    #[arg(long, value_parser = parse_planes)]
    planes: Option<PlaneMode>,
    /// btf: colour billboards by level (twig red, main branch yellow, tree blue).
    #[arg(long)]
    show_lod: bool,
    /// btf: tree shadows on the ground (alpha shadow map) and terrain self-shadows: on or off.
    #[arg(long, default_value = "on", value_parser = parse_on_off, action = clap::ArgAction::Set)]
    ground_shadows: bool,
    /// btf, hybrid, texel: the ground sees the sky only where the trees leave it open (the
    /// reference's sky visibility, computed once before the first frame): on or off.
    #[arg(long, default_value = "on", value_parser = parse_on_off, action = clap::ArgAction::Set)]
    ground_sky: bool,
    /// btf: shade billboards by the visibility cube maps (trees shading each other): on or off.
    #[arg(long, default_value = "on", value_parser = parse_on_off, action = clap::ArgAction::Set)]
    vcm: bool,
    /// btf: weight the sky light by the cube maps' mean visibility too: on or off (off: the
    /// cube maps shade the sun light only).
    #[arg(long, default_value = "on", value_parser = parse_on_off, action = clap::ArgAction::Set)]
    vcm_sky: bool,
    /// btf: how far to brighten the blend of the 3 nearest light samples towards the sun's
    /// strength (their weighted directions fall short of it, to 1/sqrt(3) with 6 lights),
    /// 0..1: 0 = the plain blend, 1 = the whole gain (default: 0.5)
    #[arg(long, value_parser = parse_unit)]
    light_gain: Option<f32>,
    /// btf, hybrid: build the billboards of the trees far enough to be one tree-level
    /// billboard each on the GPU (compute passes), the CPU preparing only the near trees:
    /// on or off.
    #[arg(long, default_value = "on", value_parser = parse_on_off, action = clap::ArgAction::Set)]
    gpu_far: bool,
    /// btf, hybrid, with --gpu-far on: expand the near trees' billboards on the GPU too (the
    /// CPU choosing their levels and cross-fades only): on or off.
    #[arg(long, default_value = "on", value_parser = parse_on_off, action = clap::ArgAction::Set)]
    gpu_near: bool,
    /// btf: draw the VCM sun factor alone, in grey (white = fully lit).
    #[arg(long)]
    show_shadow: bool,
    /// btf: cross-fade band before each level's bound, as a fraction of it, 0 = pop
    /// (default: the scene's [render] table, else 0.2).
    #[arg(long, value_parser = parse_unit)]
    lod_fade: Option<f32>,
    /// texel: how volumes are sliced (slices3d: parallel to the screen through a 3D
    /// texture; stacks: the seeds' three axis stacks of 2D slices with pre-composited
    /// power-of-two levels; polygons: slices3d's slices drawn as polygons).
    #[arg(long, default_value = "slices3d", value_parser = parse_texel_mode)]
    texel_mode: TexelMode,
    /// texel: largest visible depth between slices, metres (criterion C1).
    #[arg(long, default_value_t = SliceBounds::default().d0, value_parser = parse_positive)]
    slice_d0: f32,
    /// texel: largest projected spacing between slices, pixels (criterion C2).
    #[arg(long, default_value_t = SliceBounds::default().d1, value_parser = parse_positive)]
    slice_d1: f32,
    /// texel: most slices per texel.
    #[arg(long, default_value_t = SliceBounds::default().max_slices,
          value_parser = clap::value_parser!(u32).range(1..=1024))]
    max_slices: u32,
    /// texel: colour each texel by its slice count (blue 1, green about 11, red 128 or more).
    #[arg(long)]
    show_slices: bool,
    /// texel: draw the trees of far tiles as forest-cover tiles (on or off).
    #[arg(long, default_value = "on", value_parser = parse_on_off, action = clap::ArgAction::Set)]
    texel_tiles: bool,
    /// texel: distance (m) beyond which a whole tile is drawn as one forest-cover volume.
    #[arg(long, default_value_t = TexelSettings::default().tile_distance, value_parser = parse_positive)]
    tile_distance: f32,
    /// Prefer the CPU (software) adapter.
    #[arg(long)]
    cpu: bool,
    /// Print one JSON object with the frame's statistics on stdout.
    #[arg(long)]
    json: bool,
}

fn parse_render_scale(s: &str) -> Result<canopy::render::scale::RenderScale, String> {
    use canopy::render::scale::{MIN_SCALE, RenderScale};
    if s == "auto" {
        return Ok(RenderScale {
            auto: true,
            ..RenderScale::default()
        });
    }
    match s.parse::<f32>() {
        Ok(v) if (MIN_SCALE..=1.0).contains(&v) => Ok(RenderScale {
            scale: v,
            auto: false,
            ..RenderScale::default()
        }),
        _ => Err(format!(
            "{s:?} is not a render scale: give a fraction in {MIN_SCALE}..=1, or auto"
        )),
    }
}

fn parse_texel_mode(s: &str) -> Result<TexelMode, String> {
    TexelMode::parse(s)
        .ok_or_else(|| format!("unknown texel mode {s:?}; expected slices3d, stacks or polygons"))
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

fn parse_on_off(s: &str) -> Result<bool, String> {
    match s {
        "on" => Ok(true),
        "off" => Ok(false),
        _ => Err(format!("expected on or off, got {s:?}")),
    }
}

fn parse_planes(s: &str) -> Result<PlaneMode, String> {
    PlaneMode::parse(s)
        .ok_or_else(|| format!("unknown plane mode {s:?}; expected single or crossed"))
}

fn parse_positive(s: &str) -> Result<f32, String> {
    let v: f32 = s.parse().map_err(|_| format!("{s:?} is not a number"))?;
    if v.is_finite() && v > 0.0 && v <= 1000.0 {
        Ok(v)
    } else {
        Err(format!("{v} must be above 0 and at most 1000"))
    }
}

fn parse_unit(s: &str) -> Result<f32, String> {
    let v: f32 = s.parse().map_err(|_| format!("{s:?} is not a number"))?;
    if (0.0..=1.0).contains(&v) {
        Ok(v)
    } else {
        Err(format!("{v} must be between 0 and 1"))
    }
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
    // Output piped into a program that stops reading (`canopy info | head -1`) ends the
    // process quietly, as for any command-line tool, instead of a panic in println!.
    #[cfg(unix)]
    // SAFETY: restores the default disposition of SIGPIPE before any thread starts.
    unsafe {
        libc::signal(libc::SIGPIPE, libc::SIG_DFL);
    }
    env_logger::Builder::from_env(env_logger::Env::default().default_filter_or("warn")).init();
    let cli = Cli::parse();
    let result = match cli.command {
        None => canopy::app::run(None).map_err(anyhow::Error::from),
        Some(Command::View {
            scene,
            screenshot,
            after_frames,
            method,
            baked,
            script,
            render_scale,
        }) => canopy::app::run_with(
            scene.as_deref(),
            canopy::app::ViewOptions {
                screenshot,
                after_frames,
                method,
                baked,
                script,
                render_scale,
            },
        )
        .map_err(anyhow::Error::from),
        Some(Command::Render(args)) => render(args),
        Some(Command::Bake {
            scene,
            out,
            cpu,
            json,
        }) => bake(scene.as_deref(), out.as_deref(), cpu, json),
        Some(Command::Compare {
            a,
            b,
            json,
            diff,
            classes,
        }) => compare(&a, &b, json, diff.as_deref(), classes.as_deref()),
        Some(Command::Info {
            scene,
            json,
            map,
            map_size,
        }) => info(scene.as_deref(), json, map.as_deref(), map_size),
        Some(Command::Bench(args)) => bench(args),
        Some(Command::Tune(args)) => tune(args),
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
    let world = scene.build_world().map_err(canopy::Error::from)?;
    let mut frame = FrameDesc::from_scene(&scene);
    frame.method = args.method;
    frame.shadows.map_size = args.shadow_map;
    frame.ground_shadows = args.ground_shadows;
    frame.ground_sky = args.ground_sky;
    if args.pixel_classes {
        if args.method != Method::Geometry {
            return Err(canopy::Error::BadInput(
                "--pixel-classes draws the geometry's pixel classes; use --method geometry".into(),
            )
            .into());
        }
        frame.pixel_classes = true;
    }
    if args.reference {
        if args.method != Method::Geometry {
            return Err(canopy::Error::BadInput(
                "--reference draws the geometry method as the truth; drop it or use --method geometry"
                    .into(),
            )
            .into());
        }
        frame.reference = Some(canopy::render::Reference {
            sky_directions: args.sky_directions,
            self_map_size: args.self_map,
            ..Default::default()
        });
    }
    if let (Some(pos), Some(target)) = (args.camera, args.look_at) {
        frame.camera = Camera::look_at(pos, target, frame.camera.fov_y_deg);
    }
    let eye = frame.camera.position;
    if let Some(ground) = world.terrain.ground_above(eye) {
        eprintln!(
            "warning: the camera is {:.1} m below the terrain (ground at y = {ground:.1} m there)",
            ground - eye.y
        );
    }
    if let Some((az, el)) = args.sun {
        frame.sun.azimuth_deg = az;
        frame.sun.elevation_deg = el;
    }
    let start = frame.btf;
    frame.btf = canopy::render::btf::BtfSettings {
        lod_scale: args.lod_scale.unwrap_or(start.lod_scale),
        weight_threshold: args.weight_threshold.unwrap_or(start.weight_threshold),
        planes: args.planes.unwrap_or(start.planes),
        show_lod: args.show_lod,
        lod_fade: args.lod_fade.unwrap_or(start.lod_fade),
        vcm: args.vcm,
        show_shadow: args.show_shadow,
        vcm_sky: args.vcm_sky,
        light_gain: args.light_gain.unwrap_or(start.light_gain),
        gpu_far: args.gpu_far,
        gpu_near: args.gpu_near,
    };
    frame.texel = TexelSettings {
        mode: args.texel_mode,
        bounds: SliceBounds {
            d0: args.slice_d0,
            d1: args.slice_d1,
            max_slices: args.max_slices,
        },
        vcm: args.vcm,
        show_slices: args.show_slices,
        tiles: args.texel_tiles,
        tile_distance: args.tile_distance,
    };
    let (w, h) = args.size;
    canopy::render::target::check_size(
        w.saturating_mul(args.supersample),
        h.saturating_mul(args.supersample),
        None,
    )?;
    let ctx = GpuContext::headless(adapter(args.cpu))?;
    let mut renderer = Renderer::new(&ctx, &world)?;
    if frame.ground_sky && (args.method.is_btf() || args.method == Method::Texel) {
        let t0 = Instant::now();
        renderer.prepare_sky(&ctx, &world)?;
        log::info!(
            "the ground's sky visibility in {:.1} s",
            t0.elapsed().as_secs_f64()
        );
    }
    if let Some(r) = frame.reference {
        let t0 = Instant::now();
        renderer.prepare_reference(&ctx, &world, r.sky_directions, true)?;
        log::info!(
            "sky visibility from {} directions in {:.1} s",
            r.sky_directions,
            t0.elapsed().as_secs_f64()
        );
    }
    if let Some(path) = &args.baked {
        if !args.method.needs_bake() {
            return Err(canopy::Error::BadInput(format!(
                "--baked is for the methods that draw baked images (btf, billboard, texel, hybrid), not {}",
                args.method.name()
            ))
            .into());
        }
        let baked = canopy::bake::open_baked(path, &scene)?;
        renderer.attach_btf(&ctx, &baked, &world)?;
    } else if args.method.needs_bake() {
        let bar = progress::bar(true, 0, progress::BAKE_BAR);
        let baked =
            canopy::bake::load_or_bake(&ctx, &scene, &world, &mut |p| progress::show_bake(&bar, p));
        bar.finish_and_clear();
        renderer.attach_btf(&ctx, &baked?.0, &world)?;
    }

    let opts = MeasureOptions {
        frames: args.frames,
        supersample: args.supersample,
    };
    let bar = progress::bar(
        true,
        u64::from(args.frames) + 1,
        "{msg} [{bar:30}] {pos}/{len} frames ({elapsed})",
    );
    bar.set_message(format!("rendering {w}x{h} with {}", args.method.name()));
    let m =
        measure::measure_frame_with(&mut renderer, &ctx, &frame, w, h, &opts, &mut || bar.inc(1));
    bar.finish_and_clear();
    let m = m?;
    canopy::imageio::save_png(&args.out, &m.image)?;
    if args.json {
        let mut report = FrameReport::new(&m, &frame, &opts, &renderer, &ctx);
        report.out = Some(args.out.display().to_string());
        println!(
            "{}",
            serde_json::to_string(&report).context("encoding JSON")?
        );
    } else {
        println!(
            "wrote {} ({w}x{h}, {}): {:.2} ms/frame ({}, median of {}), CPU prepare {:.2} ms, {} trees, {} triangles, on {}",
            args.out.display(),
            args.method.name(),
            m.frame_ms,
            m.source.name(),
            m.frames_timed,
            m.prepare_ms,
            m.stats.trees_drawn,
            m.stats.triangles,
            ctx.adapter_name()
        );
    }
    Ok(())
}

fn parse_sweep(s: &str) -> Result<canopy::bench::run::Sweep, String> {
    canopy::bench::run::Sweep::parse(s).map_err(|e| e.to_string())
}

fn bench(args: BenchArgs) -> anyhow::Result<()> {
    let (width, height) = args.size;
    let req = canopy::bench::command::BenchRequest {
        scene: args.scene,
        flight: args.flight,
        methods: args.methods,
        sweeps: args.sweep,
        width,
        height,
        frames: args.frames,
        out: args.out,
        truth_supersample: args.truth_supersample,
        repeats: args.repeats,
        adapter: adapter(args.cpu),
        progress: true,
    };
    let outcome = canopy::bench::command::run_command(&req)?;
    let (run, results) = (&outcome.run, &outcome.results);
    if args.json {
        println!("{}", canopy::bench::report::summary_json(run, results));
        return Ok(());
    }
    print!("{}", canopy::bench::report::summary_table(results));
    println!(
        "{} frames of `{}` at {width}x{height} on {} ({}); truth: {} rendered, {} cached; {:.0} s",
        run.frames,
        run.flight,
        run.device,
        run.time_source.name(),
        run.truth_rendered,
        run.truth_cached,
        run.seconds
    );
    for p in &outcome.written {
        println!("wrote {}", p.display());
    }
    Ok(())
}

fn tune(args: TuneArgs) -> anyhow::Result<()> {
    let target = canopy::bench::tune::TuneTarget::new(args.max_error, args.max_flicker)?;
    let req = canopy::bench::command::TuneRequest {
        scene: args.scene,
        flight: args.flight,
        target,
        width: args.size.0,
        height: args.size.1,
        frames: args.frames,
        truth_supersample: args.truth_supersample,
        repeats: args.repeats,
        adapter: adapter(args.cpu),
        progress: true,
        write: args.write,
        bake: args.bake,
    };
    let o = canopy::bench::command::run_tune(&req)?;
    if args.json {
        println!("{}", o.json(&target));
    } else {
        print!("{}", o.text(&target));
    }
    if o.chosen.is_none() {
        anyhow::bail!("no configuration meets the target; loosen --max-error or --max-flicker");
    }
    Ok(())
}

fn adapter(cpu: bool) -> AdapterPreference {
    if cpu {
        AdapterPreference::Cpu
    } else {
        AdapterPreference::Default
    }
}

fn bake(
    scene_path: Option<&Path>,
    out: Option<&Path>,
    cpu: bool,
    json: bool,
) -> anyhow::Result<()> {
    let scene = load_scene(scene_path)?;
    let world = scene.build_world().map_err(canopy::Error::from)?;
    // Refused before any work when the file or this machine cannot hold it.
    let settings = canopy::bake::cache::settings_of(&scene);
    let e = canopy::bake::estimate::check(&settings, &world)?;
    eprintln!("{}", estimate_line(&e));
    let ctx = GpuContext::headless(adapter(cpu))?;
    let path = out
        .map(Path::to_path_buf)
        .unwrap_or_else(|| canopy::bake::cache::cache_path(&scene));
    let bar = progress::bar(true, 0, progress::BAKE_BAR);
    let baked = canopy::bake::bake_to(&path, &ctx, &scene, &world, &mut |p| {
        progress::show_bake(&bar, p)
    });
    bar.finish_and_clear();
    let (baked, times) = baked?;
    let mut r = BakeReport::new(&path, &baked, &times, &world);
    r.texel_source = match scene.texel.source {
        canopy::scene::TexelSource::Slabs => "slabs",
        canopy::scene::TexelSource::VoxelColouring => "voxel-colouring",
    }
    .into();
    if json {
        println!("{}", serde_json::to_string(&r).context("encoding JSON")?);
    } else {
        println!(
            "baked {} image sets ({} views, {} at the tree level, x {} lights + 2 sky and ground images, {}x{} texels) in {:.1} s",
            r.sets.len(),
            r.views,
            r.tree_views,
            r.lights,
            r.resolution,
            r.resolution,
            r.seconds
        );
        println!(
            "  btf {:.1} s; {} visibility cube map sets (8 corners x 6 faces x {}² each for twigs and main branches), {} bytes, {:.1} s",
            r.btf_seconds, r.vcm_sets, r.vcm_resolution, r.vcm_bytes, r.vcm_seconds
        );
        println!(
            "  of which tree level: {} {} at {}² a face, {} bytes, {:.1} s",
            r.tree_vcm_sets,
            if r.tree_vcm_cells {
                "forest cells"
            } else {
                "trees"
            },
            r.tree_vcm_resolution,
            r.tree_vcm_bytes,
            r.tree_vcm_seconds
        );
        for s in &r.sets {
            println!(
                "  {:<12} {:<12} {} bytes, radius {:.2} m, texel {:.3} m, {:.1} s",
                s.species, s.level, s.bytes, s.radius_m, s.texel_m, s.seconds
            );
        }
        if r.texels.is_empty() {
            println!("  no texel volumes (texel_resolution = 0)");
        } else {
            println!(
                "  texel volumes ({} voxels on the longest side, {} lights + sky each, from {}): {} bytes, {:.1} s",
                r.texel_resolution, r.lights, r.texel_source, r.texel_bytes, r.texel_seconds
            );
        }
        for t in &r.texels {
            println!(
                "  {:<12} {}x{}x{} voxels of {:.3} m, {} volumes, {} bytes, {:.1} s",
                t.species,
                t.dims[0],
                t.dims[1],
                t.dims[2],
                t.voxel_m,
                t.volumes,
                t.bytes,
                t.seconds
            );
        }
        println!("wrote {} ({} bytes)", r.out, r.file_bytes);
    }
    Ok(())
}

fn compare(
    a: &Path,
    b: &Path,
    json: bool,
    diff: Option<&Path>,
    classes: Option<&Path>,
) -> anyhow::Result<()> {
    let compared = canopy::metrics::compare_files(a, b)?;
    let r = &compared.result;
    if let Some(d) = diff {
        let img = image::DynamicImage::ImageRgb8(r.error_image()).to_rgba8();
        canopy::imageio::save_png(d, &img)?;
    }
    let by_class = match classes {
        Some(path) => {
            let mask = canopy::metrics::load_rgb(path)?;
            Some(canopy::metrics::by_class(
                r,
                &compared.reference,
                &compared.test,
                &mask,
            )?)
        }
        None => None,
    };
    let s = r.stats;
    if json {
        #[derive(serde::Serialize)]
        struct Json<'a> {
            #[serde(flatten)]
            stats: canopy::metrics::FlipStats,
            #[serde(skip_serializing_if = "Option::is_none")]
            classes: Option<&'a [canopy::metrics::ClassFlip]>,
        }
        let j = Json {
            stats: s,
            classes: by_class.as_deref(),
        };
        println!("{}", serde_json::to_string(&j).context("encoding JSON")?);
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
        for c in by_class.iter().flatten() {
            println!(
                "  {:<11} {:>5.1} % of pixels, mean {:.4}, p90 {:.4}, share of the error {:>5.1} %, \
                 luminance {:.3} of A's",
                c.class.name(),
                c.pixel_fraction * 100.0,
                c.stats.mean,
                c.stats.p90,
                c.error_share * 100.0,
                c.luminance_ratio()
            );
        }
    }
    Ok(())
}

/// One line with a bake's estimated time, file size and memory.
fn estimate_line(e: &canopy::bake::estimate::Estimate) -> String {
    format!(
        "bake estimate: about {:.0} s on a software renderer, a {:.1} MB file ({:.1} MB BTF images, {:.1} MB visibility cube maps, {:.1} MB texel volumes), about {:.0} MB of memory to view",
        e.seconds,
        e.file_bytes as f64 / 1e6,
        e.btf_bytes as f64 / 1e6,
        e.vcm_bytes as f64 / 1e6,
        e.texel_bytes as f64 / 1e6,
        e.memory_bytes as f64 / 1e6
    )
}

/// How the trees' own visibility cube maps are laid out and what they weigh.
fn tree_vcm_line(e: &canopy::bake::estimate::Estimate, world: &canopy::model::World) -> String {
    let per_1000 = if world.forest.instances.is_empty() {
        0.0
    } else {
        e.tree_vcm_bytes as f64 / world.forest.instances.len() as f64 * 1000.0 / 1e6
    };
    let layout = match world.tree_vcm {
        canopy::model::TreeVcm::PerTree => format!("{} trees' own cube maps", e.tree_vcm_objects),
        canopy::model::TreeVcm::Cells => format!(
            "{} forest cells of {:.1} m",
            e.tree_vcm_objects,
            canopy::vcm::cells::ForestCells::side_for(world)
        ),
    };
    format!(
        "tree-level visibility cube maps: {layout}, {:.1} MB ({per_1000:.2} MB per 1,000 trees)",
        e.tree_vcm_bytes as f64 / 1e6
    )
}

fn info(scene: Option<&Path>, json: bool, map: Option<&Path>, map_size: u32) -> anyhow::Result<()> {
    if !(16..=canopy::forest_map::MAX_MAP_SIZE).contains(&map_size) {
        return Err(canopy::Error::BadInput(format!(
            "--map-size must be between 16 and {}, found {map_size}",
            canopy::forest_map::MAX_MAP_SIZE
        ))
        .into());
    }
    let scene = load_scene(scene)?;
    let t0 = Instant::now();
    let world = scene.build_world().map_err(canopy::Error::from)?;
    if let Some(path) = map {
        let img = canopy::forest_map::draw(&world, &scene.species, &scene.forest, map_size);
        canopy::imageio::save_png(path, &img)?;
        eprintln!("map written to {}", path.display());
    }
    let r = WorldSummary::new(&world, t0.elapsed().as_secs_f64() * 1e3);
    let settings = canopy::bake::cache::settings_of(&scene);
    // A bake the format cannot hold is reported here, not refused: `info` only describes.
    let estimate = canopy::bake::estimate::estimate(&settings, &world);
    if json {
        #[derive(serde::Serialize)]
        struct Info<'a> {
            #[serde(flatten)]
            world: &'a WorldSummary,
            bake_estimate: Option<canopy::bake::estimate::Estimate>,
            bake_refused: Option<String>,
        }
        let info = Info {
            world: &r,
            bake_estimate: estimate.as_ref().ok().copied(),
            bake_refused: estimate.as_ref().err().map(|e| e.to_string()),
        };
        println!("{}", serde_json::to_string(&info).context("encoding JSON")?);
    } else {
        println!(
            "{} trees on a {} m terrain ({}x{} heights), built in {:.0} ms",
            r.trees, r.terrain.size_m, r.terrain.resolution, r.terrain.resolution, r.build_ms
        );
        if let Some(c) = r.terrain.far_forest_cover {
            println!(
                "  past the square, the forest goes on to the horizon as a canopy surface (crowns cover up to {:.0} % of its stands)",
                100.0 * c
            );
        }
        for s in &r.species {
            println!(
                "  {:<10} {} trees; triangles: twig {}, main branch {}, tree {}; {} main branches, {} twigs, {} leaves/needles, {:.1} m tall, crown {:.0} % covered from the side",
                s.name,
                s.trees,
                s.triangles.twig,
                s.triangles.main_branch,
                s.triangles.tree,
                s.main_branches,
                s.twigs,
                s.leaves,
                s.height_m,
                100.0 * s.crown_coverage
            );
        }
        match &estimate {
            Ok(e) => {
                println!("{}", estimate_line(e));
                println!("  {}", tree_vcm_line(e, &world));
            }
            Err(e) => println!("bake refused: {e}"),
        }
    }
    Ok(())
}
