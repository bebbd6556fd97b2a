//! What a bake made, as `canopy bake` prints it (and `--json` serializes it).

use std::path::Path;

use serde::Serialize;

use super::BakeTimes;
use crate::format::Baked;
use crate::model::World;

/// A bake written to a file.
#[derive(Clone, Debug, Serialize)]
pub struct BakeReport {
    pub out: String,
    /// Size of the written file.
    pub file_bytes: u64,
    pub btf_bytes: u64,
    pub vcm_bytes: u64,
    /// Visibility cube map sets (one per object).
    pub vcm_sets: usize,
    pub vcm_resolution: u32,
    /// The tree-level share: forest cells (or trees) with cube maps, their face resolution,
    /// bytes and seconds.
    pub tree_vcm_sets: usize,
    pub tree_vcm_cells: bool,
    pub tree_vcm_resolution: u32,
    pub tree_vcm_bytes: u64,
    pub tree_vcm_seconds: f64,
    pub seconds: f64,
    pub btf_seconds: f64,
    pub vcm_seconds: f64,
    pub texel_seconds: f64,
    /// Voxels along each species' longest side (0: no texels baked).
    pub texel_resolution: u32,
    /// How the volumes were made (`[texel] source`: slabs or voxel-colouring).
    pub texel_source: String,
    /// Bytes of texel volumes (all lights and the sky).
    pub texel_bytes: u64,
    /// One per species' texel volumes.
    pub texels: Vec<TexelReport>,
    /// The impostors' section: frames per side (0: none baked), pixels a frame side, the
    /// layout (`full` or `hemi`), mip levels, bytes (both atlases, every level) and
    /// seconds.
    pub impostor_frames: u32,
    pub impostor_resolution: u32,
    pub impostor_layout: &'static str,
    pub impostor_mip_levels: u32,
    pub impostor_bytes: u64,
    pub impostor_seconds: f64,
    /// One per species' impostor.
    pub impostors: Vec<ImpostorReport>,
    /// The surfel trees: level-0 surfels a species is sampled with (0: none baked), bytes
    /// (whole records) and seconds.
    pub surfel_budget: u32,
    pub surfel_bytes: u64,
    pub surfel_seconds: f64,
    /// One per species' surfel tree.
    pub surfels: Vec<SurfelReport>,
    /// Views of the twig and main-branch sets, and of the tree-level ones.
    pub views: u32,
    pub tree_views: u32,
    pub lights: u32,
    pub resolution: u32,
    pub supersample: u32,
    /// Whether the images are block-compressed (BTF BC7, cube maps BC4), and the seconds
    /// that took for each.
    pub compressed: bool,
    pub compress_btf_seconds: f64,
    pub compress_vcm_seconds: f64,
    /// Seconds to write the file (deflating its sections).
    pub write_seconds: f64,
    /// The file's sections: kind, bytes in the file and bytes of data (inflated).
    pub sections: Vec<SectionReport>,
    /// One per BTF image set.
    pub sets: Vec<SetReport>,
}

/// One section of the written file in a [`BakeReport`].
#[derive(Clone, Debug, Serialize)]
pub struct SectionReport {
    pub kind: &'static str,
    pub deflated: bool,
    pub file_bytes: u64,
    pub data_bytes: u64,
}

/// One species' texel volumes in a [`BakeReport`].
#[derive(Clone, Debug, Serialize)]
pub struct TexelReport {
    pub species: String,
    pub dims: [u32; 3],
    pub voxel_m: f32,
    /// Volumes: one per light and one lit by the sky.
    pub volumes: u32,
    pub bytes: usize,
    /// Seconds its volumes took to bake.
    pub seconds: f64,
}

/// One species' impostor in a [`BakeReport`].
#[derive(Clone, Debug, Serialize)]
pub struct ImpostorReport {
    pub species: String,
    /// Both atlases, every level.
    pub bytes: usize,
    /// The bounding sphere its frames frame.
    pub radius_m: f32,
    /// Seconds its frames took to bake.
    pub seconds: f64,
}

/// One species' surfel tree in a [`BakeReport`].
#[derive(Clone, Debug, Serialize)]
pub struct SurfelReport {
    pub species: String,
    /// Surfels of every level, and of level 0.
    pub surfels: u64,
    pub level0_surfels: u32,
    pub levels: usize,
    /// Level 0's spacing.
    pub spacing_m: f32,
    /// The whole record.
    pub bytes: u64,
    pub seconds: f64,
}

/// One BTF image set of a [`BakeReport`].
#[derive(Clone, Debug, Serialize)]
pub struct SetReport {
    pub species: String,
    pub level: &'static str,
    /// Bytes of its images (direct and sky-lit).
    pub bytes: usize,
    /// Its billboard's radius.
    pub radius_m: f32,
    /// Its largest texel.
    pub texel_m: f32,
    /// Seconds its images took to bake.
    pub seconds: f64,
}

impl BakeReport {
    /// The report of `baked`, a bake of `world` that took `times`, written to `path`.
    pub fn new(path: &Path, baked: &Baked, times: &BakeTimes, world: &World) -> Self {
        let settings = &baked.settings;
        let sets = baked
            .btf
            .iter()
            .map(|s| {
                let species = world
                    .species
                    .get(s.species as usize)
                    .map(|t| t.name.clone())
                    .unwrap_or_default();
                SetReport {
                    seconds: times.stage(&format!("{species} {}", s.level.name())),
                    species,
                    level: s.level.name(),
                    bytes: s.direct.len() + s.ambient.len(),
                    radius_m: s.radius,
                    texel_m: s.texel_size,
                }
            })
            .collect();
        let name = |s: u32| {
            world
                .species
                .get(s as usize)
                .map(|t| t.name.clone())
                .unwrap_or_default()
        };
        let texels = baked
            .texels
            .iter()
            .map(|t| TexelReport {
                species: name(t.species),
                dims: t.dims,
                voxel_m: t.voxel,
                volumes: t.lights + 1,
                bytes: t.voxels.len(),
                seconds: times.stage(&format!("{} texel volume", name(t.species))),
            })
            .collect();
        let impostors = baked
            .impostors
            .iter()
            .map(|i| ImpostorReport {
                species: name(i.species),
                bytes: i.albedo.len() + i.normal_depth.len(),
                radius_m: i.radius,
                seconds: times.stage(&format!("{} impostor", name(i.species))),
            })
            .collect();
        let surfels = baked
            .surfels
            .iter()
            .map(|t| SurfelReport {
                species: name(t.species),
                surfels: t.surfel_count(),
                level0_surfels: t.per_level.first().copied().unwrap_or(0),
                levels: t.levels(),
                spacing_m: t.spacing0,
                bytes: t.record_bytes(),
                seconds: times.stage(&format!("{} surfels", name(t.species))),
            })
            .collect();
        let tree_sets: Vec<&crate::format::VcmSet> = baked
            .vcm
            .iter()
            .filter(|v| v.level == crate::model::Level::Tree)
            .collect();
        let tree_vcm_cells = tree_sets
            .iter()
            .any(|v| v.species == crate::format::VCM_CELL_SPECIES);
        Self {
            tree_vcm_sets: tree_sets.len(),
            tree_vcm_cells,
            tree_vcm_resolution: tree_sets.first().map_or(0, |v| v.resolution),
            tree_vcm_bytes: tree_sets.iter().map(|v| v.opacity.len() as u64).sum(),
            tree_vcm_seconds: times.stage(if tree_vcm_cells {
                super::vcm::CELL_STAGE
            } else {
                super::vcm::TREE_STAGE
            }),
            out: path.display().to_string(),
            file_bytes: std::fs::metadata(path).map(|m| m.len()).unwrap_or(0),
            btf_bytes: baked.btf_bytes(),
            vcm_bytes: baked.vcm_bytes(),
            vcm_sets: baked.vcm.len(),
            vcm_resolution: settings.vcm_resolution,
            seconds: times.seconds,
            btf_seconds: times.btf_seconds,
            vcm_seconds: times.vcm_seconds,
            texel_seconds: times.texel_seconds,
            texel_resolution: settings.texel_resolution,
            texel_source: "slabs".into(),
            texel_bytes: baked.texel_bytes(),
            texels,
            impostor_frames: settings.impostor_frames,
            impostor_resolution: settings.impostor_resolution,
            impostor_layout: settings.impostor_layout.name(),
            impostor_mip_levels: baked.impostors.first().map_or(0, |i| i.mip_levels),
            impostor_bytes: baked.impostor_bytes(),
            impostor_seconds: times.impostor_seconds,
            impostors,
            surfel_budget: settings.surfel_budget,
            surfel_bytes: baked.surfel_bytes(),
            surfel_seconds: times.surfel_seconds,
            surfels,
            views: settings.views,
            tree_views: settings.tree_views,
            lights: settings.lights,
            resolution: settings.resolution,
            supersample: settings.supersample,
            compressed: settings.compress,
            compress_btf_seconds: times.compress.btf_seconds,
            compress_vcm_seconds: times.compress.vcm_seconds,
            write_seconds: times.write_seconds,
            sections: crate::format::sections(path)
                .unwrap_or_default()
                .iter()
                .map(|s| SectionReport {
                    kind: s.kind.name(),
                    deflated: s.packing == crate::format::Packing::Deflate,
                    file_bytes: s.stored_bytes,
                    data_bytes: s.data_bytes,
                })
                .collect(),
            sets,
        }
    }
}
