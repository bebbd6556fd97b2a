//! The `canopy` command line: the clap definitions of every command and the code that runs
//! each, one file per command (`args.rs` holds what they share). `main.rs` only parses and
//! calls [`run`]. The top layer beside `app`: it may use every module of the crate.

pub mod args;
pub mod bake;
pub mod bench;
pub mod compare;
pub mod export;
pub mod info;
pub mod knobs;
pub mod render;
pub mod tune;
pub mod view;

use clap::{Parser, Subcommand};

#[derive(Parser)]
#[command(
    name = "canopy",
    version,
    about = "Fly over a forest in real time; measure every stand-in against full geometry"
)]
pub struct Cli {
    #[command(subcommand)]
    pub command: Option<Command>,
}

#[derive(Subcommand)]
pub enum Command {
    /// Open the viewer on a scene file (default: the embedded example forest of 36,000 trees).
    View(view::ViewArgs),
    /// Render one frame to a PNG, no window needed.
    Render(render::RenderArgs),
    /// Bake a scene's BTF image sets, visibility cube maps, texel volumes, impostors and
    /// surfel trees (default: into the cache the viewer and `render` use).
    Bake(bake::BakeArgs),
    /// Mean FLIP and percentiles between two images (A is the reference).
    Compare(compare::CompareArgs),
    /// Speed against accuracy along a flight: every method (and every swept btf knob value)
    /// timed and compared with the geometry ground truth, frame by frame; writes
    /// results.csv, summary.json, chart.png, flight.png and each configuration's worst frame.
    Bench(bench::BenchArgs),
    /// Model no more than a scene needs: measure a grid of btf knobs (LOD scale, weight
    /// threshold, fade band, planes) along a flight and pick the cheapest meeting
    /// --max-error (mean FLIP) and --max-flicker; --write stores it as the scene's [render].
    Tune(tune::TuneArgs),
    /// Describe a scene: species, triangles per level, trees, terrain, bake estimate;
    /// --map draws where the trees stand, seen from above.
    Info(info::InfoArgs),
    /// Write one species of a scene as a glTF 2.0 binary file (.glb): its trunk, main
    /// branches and twigs as meshes placed by nodes, with its colours; it opens in Blender
    /// or an engine and comes back as a species (`gltf = "..."`).
    Export(export::ExportArgs),
}

/// Runs the command (the viewer on the example forest when none is given).
pub fn run(cli: Cli) -> anyhow::Result<()> {
    match cli.command {
        None => Ok(crate::app::run(None)?),
        Some(Command::View(args)) => view::view(args),
        Some(Command::Render(args)) => render::render(args),
        Some(Command::Bake(args)) => bake::bake(args),
        Some(Command::Compare(args)) => compare::compare(args),
        Some(Command::Info(args)) => info::info(args),
        Some(Command::Bench(args)) => bench::bench(args),
        Some(Command::Tune(args)) => tune::tune(args),
        Some(Command::Export(args)) => export::export(args),
    }
}

/// The process's exit code for a command's error: 2 when the input was bad (a scene file,
/// an argument), 1 otherwise.
pub fn exit_code(e: &anyhow::Error) -> u8 {
    let bad_input = e
        .downcast_ref::<crate::Error>()
        .is_some_and(crate::Error::is_bad_input);
    if bad_input { 2 } else { 1 }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_command_line_is_consistent() {
        use clap::CommandFactory as _;
        Cli::command().debug_assert();
    }
}
