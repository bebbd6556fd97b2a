//! `canopy export`: one species of a scene written as a glTF 2.0 binary file.

use std::path::PathBuf;

use super::args::load_scene;
use crate::Error;

#[derive(clap::Args)]
pub struct ExportArgs {
    /// Scene file (TOML). Omit for the embedded default forest.
    scene: Option<PathBuf>,
    /// The species to write (its `name` in the scene).
    #[arg(long)]
    species: String,
    /// Output file (.glb).
    #[arg(long)]
    out: PathBuf,
}

pub fn export(args: ExportArgs) -> anyhow::Result<()> {
    let scene = load_scene(args.scene.as_deref())?;
    let Some(index) = scene.species.iter().position(|s| s.name == args.species) else {
        let names: Vec<&str> = scene.species.iter().map(|s| s.name.as_str()).collect();
        return Err(Error::BadInput(format!(
            "the scene has no species `{}`; it has: {}",
            args.species,
            names.join(", ")
        ))
        .into());
    };
    if args.out.extension().and_then(|e| e.to_str()) != Some("glb") {
        return Err(Error::BadInput(format!(
            "{}: canopy writes binary glTF; name the file .glb",
            args.out.display()
        ))
        .into());
    }
    let world = scene.build_world()?;
    let tree = &world.species[index];
    let bytes = crate::model::gltf::export::export_glb(tree)
        .map_err(|e| Error::BadInput(format!("species `{}`: {e}", args.species)))?;
    crate::atomic_file::write_atomic(&args.out, |w| w.write_all(&bytes))
        .map_err(|e| Error::BadInput(e.to_string()))?;
    let counts = tree.triangle_counts();
    println!(
        "wrote {} ({} bytes): species `{}`, {} triangles ({} main branches, {} twigs)",
        args.out.display(),
        bytes.len(),
        args.species,
        counts.tree,
        tree.tree_branches.len(),
        tree.tree_branches.len() * tree.branch_twigs.len() + tree.tree_twigs.len(),
    );
    Ok(())
}
