//! The parameter blocks of a scene that the model generators take: the terrain, the species
//! entries, the forest placement and the bake sampling, with their defaults and their
//! checks. The scene loader deserialises a scene file into these and locates their errors in
//! the file; nothing here knows about files.

use serde::{Deserialize, Serialize};

use super::species::{SpeciesParams, preset};
use super::{FieldError, ModelError, check};

/// Largest number of trees.
pub const MAX_TREES: u32 = 100_000;
/// Largest number of species.
pub const MAX_SPECIES: usize = 64;
/// Terrain resolution limits (vertices per side).
pub const TERRAIN_RESOLUTION: (u32, u32) = (2, 4097);

/// `[bake]`: the sampling of the BTF image sets.
#[derive(Clone, Copy, Debug, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields, default)]
pub struct BakeParams {
    /// View directions per twig and main-branch image set: 6, 18, 66 or 258 (default 18).
    pub views: u32,
    /// View directions per tree-level image set: 6, 18, 66 or 258 (default 66). The tree
    /// level is what most of a forest is drawn at, and blending 3 views 45° apart (18)
    /// smears its crowns into ghosts; 66 views, 22° apart, is what the thesis pairs with a
    /// single plane.
    pub tree_views: u32,
    /// Light directions per view: 6, 18, 66 or 258 (default 6).
    pub lights: u32,
    /// Image side in texels: 32, 64 or 128 (default 64).
    pub resolution: u32,
    /// Supersampling per side when rendering the images (1..=8, default 4): alpha is coverage.
    pub supersample: u32,
    /// Voxels along the longest side of each species' texel volume (the `texel` method):
    /// 0 bakes none, else 16..=256 (default 64).
    pub texel_resolution: u32,
    /// How the trees' own visibility cube maps are laid out: `cells` (default), cube maps
    /// shared by the trees of one forest cell, whose memory grows with the forest's area;
    /// or `per-tree`, 8 cube maps for every tree (the thesis' layout, 48 KB a tree).
    pub tree_vcm: TreeVcm,
    /// Frames per side of each species' octahedral impostor (the `impostor` method): 0
    /// bakes none, else 4..=32 (default 12, see docs/results/bake.md and impostor.md).
    pub impostor_frames: u32,
    /// Pixels a side of one impostor frame: 16, 32, 64, 128 or 256 (default 64).
    pub impostor_resolution: u32,
    /// The directions the impostor frames cover: `full` (default, the whole sphere: from
    /// the ground every crown is seen from below its centre) or `hemi` (the upper half).
    pub impostor_layout: crate::sphere::OctaLayout,
    /// Block-compress what the bake stores (default true): the BTF images in BC7 (each mip
    /// level encoded at bake time) and the visibility cube maps in BC4, a quarter and a
    /// half of their uncompressed bytes. `false` keeps them RGBA8 and R8.
    pub compress: bool,
    /// Level-0 surfels each species' LDC tree is sampled with, about (the `surfel`
    /// method): 0 bakes none (the method then samples them when it first draws), else
    /// 1000..=4000000 (default 250000; the coarser levels add about a third).
    pub surfel_budget: u32,
}

/// The layout of the tree-level visibility cube maps (see `crate::vcm::cells`).
#[derive(Clone, Copy, Debug, Default, Deserialize, Serialize, PartialEq, Eq)]
#[serde(rename_all = "kebab-case")]
pub enum TreeVcm {
    /// Cube maps at the corners of forest cells, shared by the cell's trees; the cell mates
    /// are added per tree along the sun ray.
    #[default]
    Cells,
    /// Cube maps at the 8 corners of every tree (the thesis' layout).
    PerTree,
}

impl Default for BakeParams {
    fn default() -> Self {
        Self {
            views: 18,
            tree_views: 66,
            lights: 6,
            resolution: 64,
            supersample: 4,
            texel_resolution: 64,
            tree_vcm: TreeVcm::Cells,
            impostor_frames: 12,
            impostor_resolution: 64,
            impostor_layout: crate::sphere::OctaLayout::Full,
            compress: true,
            surfel_budget: 250_000,
        }
    }
}

/// Direction counts the bake accepts (octahedron subdivisions).
pub const BAKE_DIRECTIONS: [u32; 4] = [6, 18, 66, 258];
/// Image sides the bake accepts.
pub const BAKE_RESOLUTIONS: [u32; 3] = [32, 64, 128];
/// Impostor frame sides the bake accepts.
pub const BAKE_IMPOSTOR_RESOLUTIONS: [u32; 5] = [16, 32, 64, 128, 256];

impl BakeParams {
    pub fn check(&self) -> Result<(), FieldError> {
        for (key, v) in [
            ("views", self.views),
            ("tree_views", self.tree_views),
            ("lights", self.lights),
        ] {
            if !BAKE_DIRECTIONS.contains(&v) {
                return Err(FieldError::new(key, "must be one of 6, 18, 66, 258").with_found(v));
            }
        }
        if !BAKE_RESOLUTIONS.contains(&self.resolution) {
            return Err(FieldError::new("resolution", "must be one of 32, 64, 128")
                .with_found(self.resolution));
        }
        check::range_u32("supersample", self.supersample, 1, 8)?;
        if self.texel_resolution != 0 {
            check::range_u32("texel_resolution", self.texel_resolution, 16, 256)?;
        }
        if self.impostor_frames != 0 {
            check::range_u32("impostor_frames", self.impostor_frames, 4, 32)?;
        }
        if self.surfel_budget != 0 {
            check::range_u32("surfel_budget", self.surfel_budget, 1_000, 4_000_000)?;
        }
        if !BAKE_IMPOSTOR_RESOLUTIONS.contains(&self.impostor_resolution) {
            return Err(FieldError::new(
                "impostor_resolution",
                "must be one of 16, 32, 64, 128, 256",
            )
            .with_found(self.impostor_resolution));
        }
        Ok(())
    }
}

/// Where the texel bake's volumes come from.
#[derive(Clone, Copy, Debug, Default, Deserialize, Serialize, PartialEq, Eq)]
#[serde(rename_all = "kebab-case")]
pub enum TexelSource {
    /// Every surface's coverage and colour in the voxel it lies in, seen along the three
    /// axes from both sides (the seeds' slab rendering, in one pass per view).
    #[default]
    Slabs,
    /// Babahenini et al.'s voxel colouring: each pixel of `views` depth images writes its
    /// colour into the voxel of its depth, opaque (what their paper implements).
    VoxelColouring,
}

/// `[texel]`: how the texel volumes are made (their resolution is `[bake]
/// texel_resolution`).
#[derive(Clone, Copy, Debug, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields, default)]
pub struct TexelParams {
    /// `slabs` (default) or `voxel-colouring`.
    pub source: TexelSource,
    /// Depth images of voxel colouring (k): 6, one down each axis from either side, as in
    /// Babahenini et al.'s 6-image result.
    pub views: u32,
}

impl Default for TexelParams {
    fn default() -> Self {
        Self {
            source: TexelSource::Slabs,
            views: 6,
        }
    }
}

/// Depth-image counts voxel colouring accepts.
pub const VOXEL_COLOURING_VIEWS: [u32; 1] = [6];

impl TexelParams {
    pub fn check(&self) -> Result<(), FieldError> {
        if !VOXEL_COLOURING_VIEWS.contains(&self.views) {
            return Err(FieldError::new(
                "views",
                "must be 6 (one depth image down each axis from either side; other counts need depth images off the axes, not built)",
            )
            .with_found(self.views));
        }
        Ok(())
    }
}

fn default_feature_size() -> f32 {
    400.0
}
fn default_octaves() -> u32 {
    5
}
fn default_roughness() -> f32 {
    0.5
}
fn default_tint_variation() -> f32 {
    0.15
}

/// `[terrain]`: a square heightfield centred on the origin.
#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct TerrainParams {
    /// Side length (m).
    pub size: f32,
    /// Grid vertices per side (2..=4097).
    pub resolution: u32,
    /// Noise seed.
    pub seed: u64,
    /// Height difference between the lowest and highest point (m); heights run 0..relief.
    pub relief: f32,
    /// Wavelength of the largest hills (m). Optional, default 400.
    #[serde(default = "default_feature_size")]
    pub feature_size: f32,
    /// Noise octaves (1..=12). Optional, default 5.
    #[serde(default = "default_octaves")]
    pub octaves: u32,
    /// Amplitude ratio between successive octaves (0..=1; higher is rougher). Optional,
    /// default 0.5.
    #[serde(default = "default_roughness")]
    pub roughness: f32,
    /// Optional, default false: continue the same hills, coarser, to
    /// [`crate::model::terrain::HORIZON_REACH_M`] from the centre, so that no edge of the
    /// world shows (drawn only; trees, shadow maps and bakes keep to the square).
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub horizon: bool,
}

impl Default for TerrainParams {
    fn default() -> Self {
        TerrainParams {
            size: 1000.0,
            resolution: 257,
            seed: 1,
            relief: 60.0,
            feature_size: default_feature_size(),
            octaves: default_octaves(),
            roughness: default_roughness(),
            horizon: false,
        }
    }
}

impl TerrainParams {
    /// Checks every field; the error names the field relative to `[terrain]`.
    pub fn check(&self) -> Result<(), FieldError> {
        check::positive("size", self.size)?;
        check::range("size", self.size, 0.0, 100_000.0)?;
        let (lo, hi) = TERRAIN_RESOLUTION;
        check::range_u32("resolution", self.resolution, lo, hi)?;
        check::range("relief", self.relief, 0.0, 10_000.0)?;
        check::range("feature_size", self.feature_size, 1.0, 1_000_000.0)?;
        check::range_u32("octaves", self.octaves, 1, 12)?;
        check::range("roughness", self.roughness, 0.0, 1.0)?;
        Ok(())
    }
}

/// `[[species]]`: one species, from a preset or with its own parameters.
#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct SpeciesEntry {
    /// Name shown in the UI and messages (unique in the scene).
    pub name: String,
    /// A built-in preset (`fir`, `broadleaf` or `pine`); exactly one of `preset` and `params`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub preset: Option<String>,
    /// Full species parameters (`[species.params]`); exactly one of `preset` and `params`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub params: Option<SpeciesParams>,
    /// A glTF 2.0 tree (`.gltf` with its buffers and images, or `.glb`), the path relative to
    /// the scene file; instead of `preset` and `params`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub gltf: Option<String>,
    /// More glTF files of the same species (relative to the scene file like `gltf`): each
    /// a variant of it, a prototype of its own; a tree of the species takes one at random.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub gltf_variants: Vec<String>,
    /// Uniform scale of a `gltf` tree (default 1: the file's metres).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub scale: Option<f32>,
    /// The up axis of a `gltf` tree: `y` (default, glTF's own) or `z`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub up: Option<super::gltf::UpAxis>,
    /// The folder `gltf` is relative to: the scene file's (set when a scene is loaded from a
    /// file; the working directory otherwise).
    #[serde(skip)]
    pub base_dir: Option<std::path::PathBuf>,
    /// Seed of the species generator.
    pub seed: u64,
    /// Prototypes of this species (1..=8, default 1), so that neighbours differ: variant 1
    /// is the species as given; each further one has its own seed and its height, crown
    /// radius, branch and twig counts and branch angle varied (by up to about 12 %). Each
    /// is baked as its own BTF and VCM set; a tree of the species takes one at random.
    #[serde(default = "one_variant", skip_serializing_if = "is_one_variant")]
    pub variants: u32,
}

/// Largest number of variants of one species.
pub const MAX_VARIANTS: u32 = 8;

fn one_variant() -> u32 {
    1
}

fn is_one_variant(v: &u32) -> bool {
    *v == 1
}

impl SpeciesEntry {
    /// An entry of one variant of the built-in preset `preset`.
    pub fn from_preset(name: &str, preset: &str, seed: u64) -> SpeciesEntry {
        SpeciesEntry {
            name: name.into(),
            preset: Some(preset.into()),
            params: None,
            gltf: None,
            gltf_variants: Vec::new(),
            scale: None,
            up: None,
            base_dir: None,
            seed,
            variants: 1,
        }
    }

    /// An entry of the glTF tree at `path` (relative to `base_dir`, or the working
    /// directory).
    pub fn from_gltf(name: &str, path: &str, base_dir: Option<&std::path::Path>) -> SpeciesEntry {
        SpeciesEntry {
            preset: None,
            gltf: Some(path.into()),
            base_dir: base_dir.map(std::path::Path::to_path_buf),
            ..SpeciesEntry::from_preset(name, "", 1)
        }
    }

    /// Where the `gltf` file of this entry is, if it has one.
    pub fn gltf_path(&self) -> Option<std::path::PathBuf> {
        self.gltf.as_ref().map(|g| self.relative(g))
    }

    /// Every glTF file of this entry: `gltf`, then its `gltf_variants` (none without `gltf`).
    pub fn gltf_paths(&self) -> Vec<std::path::PathBuf> {
        match &self.gltf {
            Some(g) => std::iter::once(g)
                .chain(&self.gltf_variants)
                .map(|g| self.relative(g))
                .collect(),
            None => Vec::new(),
        }
    }

    /// `path` relative to the scene file's folder.
    fn relative(&self, path: &str) -> std::path::PathBuf {
        match &self.base_dir {
            Some(d) => d.join(path),
            None => std::path::PathBuf::from(path),
        }
    }

    /// The prototypes this entry makes: one per glTF file, or `variants` grown ones.
    pub fn prototypes(&self) -> u32 {
        if self.gltf.is_some() {
            1 + self.gltf_variants.len() as u32
        } else {
            self.variants.max(1)
        }
    }

    /// How a `gltf` tree is placed: `scale` and `up`, defaulted.
    pub fn import_options(&self) -> super::gltf::ImportOptions {
        super::gltf::ImportOptions {
            scale: self.scale.unwrap_or(1.0),
            up: self.up.unwrap_or_default(),
        }
    }

    /// The parameters and seed of variant `v` (0 = the species as given).
    pub fn variant(&self, v: u32) -> Result<(SpeciesParams, u64), ModelError> {
        let base = self.try_params()?;
        if v == 0 {
            return Ok((base, self.seed));
        }
        let seed = super::rng::mix64(self.seed ^ u64::from(v).wrapping_mul(0x9E37_79B9_7F4A_7C15));
        let mut rng = super::rng::Rng::derive(seed, 7);
        let mut p = base;
        let vary = |x: f32, by: f32, rng: &mut super::rng::Rng| x * (1.0 + by * rng.signed());
        p.height = vary(p.height, 0.12, &mut rng);
        p.crown_radius = vary(p.crown_radius, 0.12, &mut rng);
        p.branch_count = (vary(p.branch_count as f32, 0.15, &mut rng).round() as u32).max(1);
        p.twigs_per_branch = vary(p.twigs_per_branch as f32, 0.1, &mut rng).round() as u32;
        let tilt = 5.0 * rng.signed();
        p.branch_angle_low = (p.branch_angle_low + tilt).clamp(1.0, 179.0);
        p.branch_angle_high = (p.branch_angle_high + tilt).clamp(1.0, 179.0);
        Ok((p, seed))
    }

    /// The species parameters: the inline `params`, or the preset's.
    pub fn try_params(&self) -> Result<SpeciesParams, ModelError> {
        match (&self.preset, &self.params) {
            (None, Some(p)) => Ok(p.clone()),
            (Some(name), None) => preset(name).ok_or_else(|| ModelError::UnknownPreset {
                name: self.name.clone(),
                preset: name.clone(),
            }),
            _ => Err(ModelError::AmbiguousSpecies {
                name: self.name.clone(),
            }),
        }
    }
}

/// `[forest]`: how the trees are placed.
#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct ForestParams {
    /// Number of trees (0..=100000), spread evenly. Exactly one of `count` and `density`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub count: Option<u32>,
    /// Trees per hectare inside a stand (where the stand noise allows full density); the
    /// number of trees follows from it. Exactly one of `count` and `density`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub density: Option<f32>,
    /// Placement seed.
    pub seed: u64,
    /// Minimum distance between two trunks (m); with `density`, the spacing at full
    /// density, widened (up to twice) where the local density is lower.
    pub min_spacing: f32,
    /// One weight per species (relative, >= 0); with `mix_high`, the weights on the
    /// lowest ground.
    pub mix: Vec<f32>,
    /// Optional: one weight per species on the highest ground; between, the weights
    /// follow the height (in patches, not in bands), e.g. firs on the heights and
    /// broadleaves in the valleys.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub mix_high: Option<Vec<f32>>,
    /// Smallest tree scale.
    pub scale_min: f32,
    /// Largest tree scale.
    pub scale_max: f32,
    /// Rotate each tree randomly about the vertical.
    pub random_yaw: bool,
    /// Per-tree foliage tint variation (0..=1). Optional, default 0.15.
    #[serde(default = "default_tint_variation")]
    pub tint_variation: f32,
    /// `[forest.stands]` (optional, with `density` only): stands, clearings, edges and
    /// meadows from a seeded noise field.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub stands: Option<StandParams>,
}

impl Default for ForestParams {
    fn default() -> Self {
        ForestParams {
            count: Some(1000),
            density: None,
            seed: 1,
            min_spacing: 6.0,
            mix: vec![0.6, 0.4],
            mix_high: None,
            scale_min: 0.8,
            scale_max: 1.2,
            random_yaw: true,
            tint_variation: default_tint_variation(),
            stands: None,
        }
    }
}

/// Largest density (trees per hectare): a trunk every 1.4 m.
pub const MAX_DENSITY: f32 = 5000.0;

/// `[forest.stands]`: where the forest stands. A seeded noise field over the terrain is cut
/// at the level that leaves `cover` of the land in stands; the rest is clearings. Density
/// rises from 0 at a stand's border to full `edge` metres inside. Valley floors (the
/// lowest `meadows` of the relief) are meadows: no trees.
#[derive(Clone, Copy, Debug, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields, default)]
pub struct StandParams {
    /// Fraction of the land in stands (0..=1, default 0.7).
    pub cover: f32,
    /// Wavelength of the stand noise (m, default 250): the size of stands and clearings.
    pub size: f32,
    /// Width of a stand's edge (m, default 20), over which density rises to full.
    pub edge: f32,
    /// Valley floors below this fraction of the relief are meadows (0..1, default 0.1).
    pub meadows: f32,
}

impl Default for StandParams {
    fn default() -> Self {
        StandParams {
            cover: 0.7,
            size: 250.0,
            edge: 20.0,
            meadows: 0.1,
        }
    }
}

impl StandParams {
    /// Checks every field; the error names the field relative to `[forest.stands]`.
    pub fn check(&self) -> Result<(), FieldError> {
        check::range("cover", self.cover, 0.0, 1.0)?;
        check::positive("size", self.size)?;
        check::range("size", self.size, 1.0, 100_000.0)?;
        check::range("edge", self.edge, 0.0, 10_000.0)?;
        check::range("meadows", self.meadows, 0.0, 1.0)?;
        Ok(())
    }
}

impl ForestParams {
    /// Checks every field for a scene of `species_count` species; the error names the
    /// field relative to `[forest]`.
    pub fn check(&self, species_count: usize) -> Result<(), FieldError> {
        match (self.count, self.density) {
            (Some(_), Some(_)) => {
                return Err(FieldError::new(
                    "density",
                    "give either `count` or `density`, not both",
                ));
            }
            (None, None) => {
                return Err(FieldError::new(
                    "count",
                    "missing required key (or give `density` in trees per hectare)",
                ));
            }
            (Some(count), None) => {
                check::range_u32("count", count, 0, MAX_TREES)?;
                if self.stands.is_some() {
                    return Err(FieldError::new(
                        "stands",
                        "[forest.stands] needs `density` (trees per hectare) instead of `count`",
                    ));
                }
            }
            (None, Some(d)) => check::range("density", d, 0.0, MAX_DENSITY)?,
        }
        if self.may_plant() && species_count == 0 {
            return Err(FieldError::new(
                if self.count.is_some() {
                    "count"
                } else {
                    "density"
                },
                "there are no species to plant",
            ));
        }
        check::positive("min_spacing", self.min_spacing)?;
        check::range("min_spacing", self.min_spacing, 0.0, 10_000.0)?;
        if self.mix.len() != species_count {
            return Err(FieldError::new(
                "mix",
                format!(
                    "needs one weight per species ({species_count} species), found {} weight{}",
                    self.mix.len(),
                    if self.mix.len() == 1 { "" } else { "s" }
                ),
            ));
        }
        for (i, w) in self.mix.iter().enumerate() {
            check::range(&format!("mix[{i}]"), *w, 0.0, 1e6)?;
        }
        if self.may_plant() && self.mix.iter().sum::<f32>() <= 0.0 {
            return Err(FieldError::new("mix", "at least one weight must be > 0"));
        }
        if let Some(high) = &self.mix_high {
            if high.len() != species_count {
                return Err(FieldError::new(
                    "mix_high",
                    format!(
                        "needs one weight per species ({species_count} species), found {} weight{}",
                        high.len(),
                        if high.len() == 1 { "" } else { "s" }
                    ),
                ));
            }
            for (i, w) in high.iter().enumerate() {
                check::range(&format!("mix_high[{i}]"), *w, 0.0, 1e6)?;
            }
            if self.may_plant() && high.iter().sum::<f32>() <= 0.0 {
                return Err(FieldError::new(
                    "mix_high",
                    "at least one weight must be > 0",
                ));
            }
        }
        if let Some(st) = &self.stands {
            st.check().map_err(|e| e.prefixed("stands"))?;
        }
        check::positive("scale_min", self.scale_min)?;
        check::range("scale_min", self.scale_min, 0.0, 100.0)?;
        check::positive("scale_max", self.scale_max)?;
        check::range("scale_max", self.scale_max, 0.0, 100.0)?;
        if self.scale_min > self.scale_max {
            return Err(FieldError::new(
                "scale_min",
                format!("must be <= scale_max ({})", self.scale_max),
            )
            .with_found(self.scale_min));
        }
        check::range("tint_variation", self.tint_variation, 0.0, 1.0)?;
        Ok(())
    }

    /// Whether this placement may plant any tree (a count or density above 0).
    pub fn may_plant(&self) -> bool {
        self.count.is_some_and(|c| c > 0) || self.density.is_some_and(|d| d > 0.0)
    }
}
