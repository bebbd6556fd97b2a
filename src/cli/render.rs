//! `canopy render`: one frame of a scene to a PNG, timed, no window needed.

use std::path::PathBuf;
use std::time::Instant;

use anyhow::Context as _;
use glam::Vec3;

use super::args::{adapter, load_scene, parse_size, parse_sun, parse_vec3};

/// `--show-overdraw`'s value.
fn parse_overdraw(s: &str) -> Result<crate::render::overdraw::OverdrawView, String> {
    crate::render::overdraw::OverdrawView::parse(s)
        .ok_or_else(|| format!("`{s}`: give fragments or reads"))
}
use crate::progress;
use crate::render::measure::{self, FrameReport, MeasureOptions};
use crate::render::{Camera, FrameDesc, GpuContext, Method, Renderer};

#[derive(clap::Args)]
pub struct RenderArgs {
    /// Scene file (TOML). Omit for the embedded default forest (1,000 trees).
    scene: Option<PathBuf>,
    /// Output PNG.
    #[arg(long)]
    out: PathBuf,
    /// Rendering method.
    #[arg(long, value_enum, default_value_t = Method::Geometry)]
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
    #[arg(long, default_value_t = crate::render::sky_visibility::SKY_DIRECTIONS,
          value_parser = clap::value_parser!(u32).range(1..=1024), requires = "reference")]
    sky_directions: u32,
    /// With --reference: side in texels of each tree's own sun map (its shadows on
    /// itself, fine at any distance); 0: none, the cascades alone.
    #[arg(long, default_value_t = crate::render::self_shadow::SELF_MAP_SIZE,
          value_parser = clap::value_parser!(u32).range(0..=8192), requires = "reference")]
    self_map: u32,
    /// Draw the overdraw view instead of the picture: per pixel, the fragments shaded
    /// (fragments) or the images they read (reads), as a heat map with its scale; the JSON
    /// gets fragments_per_pixel and reads_per_pixel.
    #[arg(long, value_parser = parse_overdraw)]
    show_overdraw: Option<crate::render::overdraw::OverdrawView>,
    #[command(flatten)]
    knobs: super::knobs::KnobArgs,
    /// Prefer the CPU (software) adapter.
    #[arg(long)]
    cpu: bool,
    #[command(flatten)]
    bc7: super::args::Bc7Textures,
    /// Print one JSON object with the frame's statistics on stdout.
    #[arg(long)]
    json: bool,
}

pub fn render(args: RenderArgs) -> anyhow::Result<()> {
    use crate::render::sky_visibility::SKY_DIRECTIONS;
    let method = args.method;
    args.bc7.apply();
    let scene = load_scene(args.scene.as_deref())?;
    let world = scene.build_world().map_err(crate::Error::from)?;
    let frame = frame_of(&args, &scene, &world)?;
    let (w, h) = args.size;
    crate::render::target::check_size(
        w.saturating_mul(args.supersample),
        h.saturating_mul(args.supersample),
        None,
    )?;
    let named = named_bake(&args, &scene)?;
    let ctx = GpuContext::headless(adapter(args.cpu))?;
    log_memory(&ctx, "the GPU context is made");
    let mut renderer = Renderer::new(&ctx, &world)?;
    log_memory(&ctx, "the renderer is made");
    // The bake first: a bake that is refused (too large, not enough memory) is refused
    // before the sky visibility's seconds are spent.
    let named_file = named.is_some();
    attach_bake(&args, named, &ctx, &scene, &world, &mut renderer)?;
    if frame.ground_sky && canopy_shades_ground(method) {
        let t0 = Instant::now();
        renderer.prepare_sky_with(&ctx, &world, |bounds| {
            sky_volume(named_file, &scene, &world, bounds, SKY_DIRECTIONS)
        })?;
        log::info!(
            "the ground's sky visibility in {:.1} s",
            t0.elapsed().as_secs_f64()
        );
    }
    if let Some(r) = frame.reference {
        let t0 = Instant::now();
        renderer.prepare_reference_with(&ctx, &world, r.sky_directions, true, |bounds| {
            sky_volume(named_file, &scene, &world, bounds, r.sky_directions)
        })?;
        log::info!(
            "sky visibility from {} directions in {:.1} s",
            r.sky_directions,
            t0.elapsed().as_secs_f64()
        );
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
    bar.set_message(format!("rendering {w}x{h} with {}", method.name()));
    let m =
        measure::measure_frame_with(&mut renderer, &ctx, &frame, w, h, &opts, &mut || bar.inc(1));
    bar.finish_and_clear();
    let m = m?;
    log_memory(&ctx, "the frames are drawn");
    // Free heap pages given back before the memory is reported, as the viewer does every
    // few seconds (`app::heap`), so that the report says what viewing holds.
    crate::app::heap::trim();
    log_memory(&ctx, "the heap's free pages are given back");
    crate::imageio::save_png(&args.out, &m.image)?;
    if args.json {
        let mut report = FrameReport::new(&m, &frame, &opts, &renderer, &ctx);
        report.out = Some(args.out.display().to_string());
        report.memory = Some(renderer.memory_report(&ctx));
        println!(
            "{}",
            serde_json::to_string(&report).context("encoding JSON")?
        );
    } else {
        print_summary(&args, &m, &renderer, &ctx);
    }
    Ok(())
}

/// The frame `args` ask for in `scene`, refusing flags the method does not take; warns of
/// knobs the method does not read and of a camera under the terrain of `world`.
fn frame_of(
    args: &RenderArgs,
    scene: &crate::scene::Scene,
    world: &crate::model::World,
) -> anyhow::Result<FrameDesc> {
    let method = args.method;
    let mut frame = FrameDesc::from_scene(scene);
    frame.method = method;
    frame.shadows.map_size = args.shadow_map;
    args.knobs.apply_to(&mut frame);
    frame.overdraw = args.show_overdraw;
    let ignored = args.knobs.ignored_by(method);
    if !ignored.is_empty() {
        eprintln!(
            "warning: {} does not read {}",
            method.name(),
            ignored.join(", ")
        );
    }
    if args.pixel_classes {
        if method != Method::Geometry {
            return Err(crate::Error::BadInput(
                "--pixel-classes draws the geometry's pixel classes; use --method geometry".into(),
            )
            .into());
        }
        frame.pixel_classes = true;
    }
    if args.reference {
        if method != Method::Geometry {
            return Err(crate::Error::BadInput(
                "--reference draws the geometry method as the truth; drop it or use --method geometry"
                    .into(),
            )
            .into());
        }
        frame.reference = Some(crate::render::Reference {
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
    Ok(frame)
}

/// The sky visibility of `world` over `bounds` from `directions` directions: from the
/// cache (kept there when computed), unless the frame draws a named `--baked` file, whose
/// render writes nothing into the cache.
fn sky_volume(
    named: bool,
    scene: &crate::scene::Scene,
    world: &crate::model::World,
    bounds: &crate::model::mesh::Aabb,
    directions: u32,
) -> crate::render::sky_visibility::SkyVolume {
    if named {
        crate::render::sky_visibility::SkyVolume::compute(world, bounds, true, directions)
    } else {
        crate::bake::sky_cache::sky_volume(scene, world, directions, true)
    }
}

/// The `--baked` file, read and checked before any work (a file that cannot be used is
/// refused at once); None without the flag.
fn named_bake(
    args: &RenderArgs,
    scene: &crate::scene::Scene,
) -> anyhow::Result<Option<crate::format::Baked>> {
    let Some(path) = &args.baked else {
        return Ok(None);
    };
    if !args.method.needs_bake() {
        let baked: Vec<&str> = Method::ALL
            .iter()
            .filter(|m| m.needs_bake())
            .map(|m| m.name())
            .collect();
        return Err(crate::Error::BadInput(format!(
            "--baked is for the methods that draw baked images ({}), not {}",
            baked.join(", "),
            args.method.name()
        ))
        .into());
    }
    Ok(Some(crate::bake::open_baked(path, scene)?))
}

/// Gives `renderer` the bake its method draws: the `--baked` file (`named`), or the
/// cache's (baked first where it has none).
fn attach_bake(
    args: &RenderArgs,
    named: Option<crate::format::Baked>,
    ctx: &GpuContext,
    scene: &crate::scene::Scene,
    world: &crate::model::World,
    renderer: &mut Renderer,
) -> anyhow::Result<()> {
    if let Some(baked) = &named {
        renderer.attach_btf(ctx, baked, world)?;
    } else if args.method.needs_bake() {
        let bar = progress::bar(true, 0, progress::BAKE_BAR);
        let baked =
            crate::bake::load_or_bake(ctx, scene, world, &mut |p| progress::show_bake(&bar, p));
        bar.finish_and_clear();
        renderer.attach_btf(ctx, &baked?.0, world)?;
        log_memory(ctx, "the bake is attached");
    }
    Ok(())
}

/// Prints what the frame `m` took and drew, its passes' times and the memory, in words.
fn print_summary(
    args: &RenderArgs,
    m: &measure::FrameMeasurement,
    renderer: &Renderer,
    ctx: &GpuContext,
) {
    let (w, h) = args.size;
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
    if !m.passes.is_empty() {
        let passes: Vec<String> = m
            .passes
            .iter()
            .map(|p| format!("{} {:.2}", p.name, p.ms))
            .collect();
        println!("passes (GPU ms): {}", passes.join(", "));
    }
    println!("memory:");
    for line in renderer.memory_report(ctx).lines(1_000_000) {
        println!("  {line}");
    }
}

/// Says in the log (debug) how much memory is resident, and how much the GPU has
/// allocated, once `stage`.
fn log_memory(ctx: &GpuContext, stage: &str) {
    if log::log_enabled!(log::Level::Debug) {
        let gpu = ctx.device.generate_allocator_report();
        let (heap_used, heap_free) = crate::render::memory::heap_bytes();
        log::debug!(
            "{:.1} MB resident once {stage}; GPU allocations {:.1} MB in {:.1} MB of blocks; \
             C heap {:.1} MB in use, {:.1} MB held free",
            crate::render::memory::resident_bytes() as f64 / 1e6,
            gpu.as_ref().map_or(0, |r| r.total_allocated_bytes) as f64 / 1e6,
            gpu.as_ref().map_or(0, |r| r.total_reserved_bytes) as f64 / 1e6,
            heap_used as f64 / 1e6,
            heap_free as f64 / 1e6,
        );
        if let Some(r) = gpu
            .as_ref()
            .filter(|_| log::log_enabled!(log::Level::Trace))
        {
            for b in &r.blocks {
                let parts = &r.allocations[b.allocations.clone()];
                let used: u64 = parts.iter().map(|a| a.size).sum();
                let mut names: Vec<&str> = parts.iter().map(|a| a.name.as_str()).collect();
                names.dedup();
                log::trace!(
                    "GPU block of {:.1} MB, {:.1} MB used: {}",
                    b.size as f64 / 1e6,
                    used as f64 / 1e6,
                    names.join(", ")
                );
            }
        }
    }
}

/// The method's trees shade the ground through the ground maps and its ground sees the
/// sky visibility (made once before the first frame).
fn canopy_shades_ground(method: Method) -> bool {
    crate::render::method::registry()
        .iter()
        .any(|m| m.method() == method && m.shades_ground())
}
