//! `canopy tune`: the cheapest btf knobs (and, with `--bake`, bake settings) that meet an
//! error and flicker target along a flight.

use std::path::PathBuf;

use super::args::{adapter, parse_size};

#[derive(clap::Args)]
pub struct TuneArgs {
    /// Scene file (TOML). Omit for the embedded default forest (1,000 trees).
    scene: Option<PathBuf>,
    /// Largest mean FLIP against the truth along the flight.
    #[arg(long)]
    max_error: f64,
    /// Largest flicker ratio (the method's mean frame-to-frame change over the truth's).
    #[arg(long, default_value_t = crate::bench::tune::DEFAULT_MAX_FLICKER)]
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
    /// The method whose knobs are searched: btf, or impostor (measured and reported only:
    /// the scene file has no table for its knobs).
    #[arg(long, value_enum, default_value_t = crate::render::Method::Btf)]
    method: crate::render::Method,
    /// Print the result as JSON on stdout.
    #[arg(long)]
    json: bool,
    /// Prefer the CPU (software) adapter.
    #[arg(long)]
    cpu: bool,
}

pub fn tune(args: TuneArgs) -> anyhow::Result<()> {
    let target = crate::bench::tune::TuneTarget::new(args.max_error, args.max_flicker)?;
    let req = crate::bench::command::TuneRequest {
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
        method: args.method,
        cache_dir: crate::bake::cache::cache_dir(),
    };
    let o = crate::bench::command::run_tune(&req)?;
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
