//! `canopy bench`: every method timed and compared with the ground truth along a flight;
//! the report files go to `--out`.

use std::path::PathBuf;

use super::args::{adapter, parse_size, parse_sweep};
use crate::render::Method;

#[derive(clap::Args)]
pub struct BenchArgs {
    /// Scene file (TOML). Omit for the embedded default forest (1,000 trees).
    scene: Option<PathBuf>,
    /// A built-in flight (overview, walk, approach, sunset, orbit) or a flight file (TOML).
    #[arg(long, default_value = "walk")]
    flight: String,
    /// Methods to measure, comma-separated (default: every method).
    #[arg(
        long,
        value_enum,
        value_delimiter = ',',
        default_values_t = Method::ALL.to_vec()
    )]
    methods: Vec<Method>,
    /// Sweep a knob: KEY=V1,V2,... with KEY any knob of `render --help`'s "Method knobs"
    /// (written with `_`: lod_scale, vcm, texel_mode, ...); each method that reads it runs
    /// once per value; repeat for a grid.
    #[arg(long, value_parser = parse_sweep)]
    sweep: Vec<crate::bench::run::Sweep>,
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
    #[command(flatten)]
    bc7: super::args::Bc7Textures,
}

pub fn bench(args: BenchArgs) -> anyhow::Result<()> {
    args.bc7.apply();
    let (width, height) = args.size;
    let req = crate::bench::command::BenchRequest {
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
    let outcome = crate::bench::command::run_command(&req)?;
    let (run, results) = (&outcome.run, &outcome.results);
    if args.json {
        println!("{}", crate::bench::report::summary_json(run, results));
        return Ok(());
    }
    print!("{}", crate::bench::report::summary_table(results));
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
