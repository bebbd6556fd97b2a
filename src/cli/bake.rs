//! `canopy bake`: a scene's BTF image sets, visibility cube maps, texel volumes and
//! octahedral impostors, into
//! the cache the viewer and `render` use or into `--out`.

use std::path::PathBuf;

use anyhow::Context as _;

use super::args::{adapter, load_scene};
use crate::bake::report::BakeReport;
use crate::progress;
use crate::render::GpuContext;

#[derive(clap::Args)]
pub struct BakeArgs {
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
}

pub fn bake(args: BakeArgs) -> anyhow::Result<()> {
    let BakeArgs {
        scene,
        out,
        cpu,
        json,
    } = args;
    let scene = load_scene(scene.as_deref())?;
    let world = scene.build_world().map_err(crate::Error::from)?;
    // Refused before any work when the file or this machine cannot hold it.
    let settings = crate::bake::cache::settings_of(&scene);
    let e = crate::bake::estimate::check(&settings, &world)?;
    eprintln!("{}", estimate_line(&e));
    let ctx = GpuContext::headless(adapter(cpu))?;
    let path = out.unwrap_or_else(|| crate::bake::cache::cache_path(&scene));
    let bar = progress::bar(true, 0, progress::BAKE_BAR);
    let baked = crate::bake::bake_to(&path, &ctx, &scene, &world, &mut |p| {
        progress::show_bake(&bar, p)
    });
    bar.finish_and_clear();
    let (baked, times) = baked?;
    let mut r = BakeReport::new(&path, &baked, &times, &world);
    r.texel_source = match scene.texel.source {
        crate::scene::TexelSource::Slabs => "slabs",
        crate::scene::TexelSource::VoxelColouring => "voxel-colouring",
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
        if r.impostors.is_empty() {
            println!("  no impostors (impostor_frames = 0)");
        } else {
            println!(
                "  impostors ({} x {} frames of {}² pixels, {} layout, {} mip levels, albedo + coverage and normal + depth): {} bytes, {:.1} s",
                r.impostor_frames,
                r.impostor_frames,
                r.impostor_resolution,
                r.impostor_layout,
                r.impostor_mip_levels,
                r.impostor_bytes,
                r.impostor_seconds
            );
        }
        for i in &r.impostors {
            println!(
                "  {:<12} impostor {} bytes, radius {:.2} m, {:.1} s",
                i.species, i.bytes, i.radius_m, i.seconds
            );
        }
        if r.surfels.is_empty() {
            println!("  no surfel trees (surfel_budget = 0)");
        } else {
            println!(
                "  surfel trees (about {} level-0 surfels a species, 12 bytes each): {} bytes, {:.1} s",
                r.surfel_budget, r.surfel_bytes, r.surfel_seconds
            );
        }
        for t in &r.surfels {
            println!(
                "  {:<12} {} surfels ({} at level 0, {:.1} mm apart), {} levels, {} bytes, {:.1} s",
                t.species,
                t.surfels,
                t.level0_surfels,
                t.spacing_m * 1e3,
                t.levels,
                t.bytes,
                t.seconds
            );
        }
        if r.compressed {
            println!(
                "  block-compressed: BTF images in BC7 (with their mips) {:.1} s, cube maps in BC4 {:.1} s",
                r.compress_btf_seconds, r.compress_vcm_seconds
            );
        } else {
            println!("  not block-compressed ([bake] compress = false)");
        }
        for s in &r.sections {
            println!(
                "  section {:<14} {:>11} bytes in the file{}",
                s.kind,
                s.file_bytes,
                if s.deflated {
                    format!(" ({} bytes deflated)", s.data_bytes)
                } else {
                    " (stored as it is)".into()
                }
            );
        }
        println!(
            "wrote {} ({} bytes, {:.1} s to write)",
            r.out, r.file_bytes, r.write_seconds
        );
    }
    Ok(())
}

/// One line with a bake's estimated time, file size and memory.
pub(super) fn estimate_line(e: &crate::bake::estimate::Estimate) -> String {
    format!(
        "bake estimate: about {:.0} s on a software renderer ({:.0} s of impostors), {:.1} MB of data ({:.1} MB BTF images, {:.1} MB visibility cube maps, {:.1} MB texel volumes, {:.1} MB impostors; the file holds it deflated, in less), about {:.0} MB of memory to view",
        e.seconds,
        e.impostor_seconds,
        e.file_bytes as f64 / 1e6,
        e.btf_bytes as f64 / 1e6,
        e.vcm_bytes as f64 / 1e6,
        e.texel_bytes as f64 / 1e6,
        e.impostor_bytes as f64 / 1e6,
        e.memory_bytes as f64 / 1e6
    )
}
