//! Forest cover past the baked forest: what stands for trees on the horizon ring.
//!
//! The trees of a scene stand on its square; past it the terrain continues to the horizon
//! (`[terrain] horizon`) with no trees. So that a dense forest does not end at a line of
//! bare hills, the ring carries the forest on as a canopy surface: where the stand noise
//! of `[forest.stands]` continues (or everywhere, for a forest placed by count), the
//! ground is raised by the canopy's height and coloured like it, in proportion to how much
//! of the land the crowns cover.
//!
//! Everything is measured from the placed forest, not assumed: the trees are binned by the
//! height of the ground they stand on (so firs on the heights and broadleaves in the
//! valleys stay so), and per bin the crowns' area against the stand land under it gives
//! the cover (1 - e^-(crown area / land), crowns overlapping at random), their heights the
//! canopy's, and their foliage colour (the prototype's mean needle or leaf albedo times
//! the tree's tint) the canopy's colour. A savanna of scattered trees gets a faint tint;
//! a stand at 600 trees per hectare a closed, raised canopy.
//!
//! It is a stand-in for far trees only: seen from the fog's distance a closed canopy reads
//! as a green, bumpy surface. Seen from near (the ring's first cells are 16 m) it is a
//! flat-topped plateau, which is why it starts low at the square's border and rises over
//! [`RISE_M`].

use glam::Vec3;

use super::forest::Forest;
use super::rng::{hash2, unit_f32};
use super::stands::{StandField, height_range, normalise};
use super::terrain::Terrain;
use super::tree::TreeModel;

/// Height bins of the measured forest.
const BINS: usize = 8;
/// Samples per side of the square when measuring how much of it is stand land.
const LAND_SAMPLES: usize = 128;
/// The canopy surface sits at this fraction of the trees' mean height: the crowns' tops
/// are cones and domes, not a lid.
const CANOPY_FILL: f32 = 0.75;
/// A canopy seen from afar is darker than its leaves: the gaps between them are shade.
/// Chosen so that the ring's forest meets the baked trees seen from 1-2 km in brightness.
const CANOPY_SHADE: f32 = 0.5;
/// Crowns and gaps speckle a canopy: each vertex's colour varies by up to this much.
const CANOPY_SPECKLE: f32 = 0.35;
/// Past the square's border the canopy rises from nothing to full over this distance (m),
/// so that the last baked trees do not face a wall.
pub const RISE_M: f32 = 150.0;

/// The canopy of one height bin.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
struct Bin {
    /// Fraction of the stand land covered by crowns (0..1).
    cover: f32,
    /// Mean tree height (m).
    height: f32,
    /// Mean foliage albedo (linear RGB).
    colour: Vec3,
}

/// The measured forest, to continue past the square.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FarCover {
    bins: [Bin; BINS],
    /// Where the stands lie (`None`: a forest placed by count stands everywhere).
    stands: Option<StandField>,
    /// Share of the square's land in stands.
    share: f32,
    /// The square's height range (the bins' scale) and half side.
    lo: f32,
    hi: f32,
    half: f32,
}

/// The canopy at one point of the ring.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Canopy {
    /// Fraction of the land covered by crowns (0..1).
    pub cover: f32,
    /// How far the canopy raises the surface (m).
    pub raise: f32,
    /// The canopy's colour (linear RGB), to blend over the ground's by `cover`.
    pub colour: Vec3,
}

/// Mean albedo of a prototype's needles or leaves (its twig's foliage vertices).
fn foliage_albedo(tree: &TreeModel) -> Vec3 {
    let (sum, n) = tree
        .twig
        .vertices
        .iter()
        .filter(|v| v.foliage > 0.5)
        .fold((Vec3::ZERO, 0u32), |(s, n), v| {
            (s + Vec3::from(v.color), n + 1)
        });
    if n == 0 {
        Vec3::new(0.05, 0.09, 0.03)
    } else {
        sum / n as f32
    }
}

impl FarCover {
    /// Measures the forest placed on `terrain`; `None` when it has no trees.
    pub fn measure(terrain: &Terrain, species: &[TreeModel], forest: &Forest) -> Option<FarCover> {
        if forest.instances.is_empty() || terrain.size.is_nan() || terrain.size <= 0.0 {
            return None;
        }
        let (lo, hi) = height_range(terrain);
        if !(lo.is_finite() && hi.is_finite()) {
            return None;
        }
        let bin_of = |h: f32| ((normalise(h, lo, hi) * BINS as f32) as usize).min(BINS - 1);
        let half = 0.5 * terrain.size;
        // Stand land per bin, sampled on a grid over the square.
        let mut land = [0u32; BINS];
        let mut in_stands = 0u32;
        let step = terrain.size / LAND_SAMPLES as f32;
        for j in 0..LAND_SAMPLES {
            for i in 0..LAND_SAMPLES {
                let x = -half + (i as f32 + 0.5) * step;
                let z = -half + (j as f32 + 0.5) * step;
                let h = terrain.height_at(x, z);
                let stand = forest
                    .stands
                    .as_ref()
                    .map_or(1.0, |f| f.stand_weight(x, z, h, 0.0, 0.0));
                if stand >= 0.5 {
                    land[bin_of(h)] += 1;
                    in_stands += 1;
                }
            }
        }
        let cell_area = step * step;
        let albedo: Vec<Vec3> = species.iter().map(foliage_albedo).collect();
        let mut crown = [0.0f64; BINS];
        let mut height = [0.0f64; BINS];
        let mut colour = [Vec3::ZERO; BINS];
        for t in &forest.instances {
            let Some(model) = species.get(t.species as usize) else {
                continue;
            };
            let b = model.tree_bounds;
            let r = 0.25 * ((b.max.x - b.min.x) + (b.max.z - b.min.z)) * t.scale;
            let area = std::f32::consts::PI * r * r;
            let k = bin_of(t.position.y);
            crown[k] += f64::from(area);
            height[k] += f64::from(area * b.max.y * t.scale);
            colour[k] += albedo
                .get(t.species as usize)
                .copied()
                .unwrap_or(Vec3::ZERO)
                * t.tint
                * area;
        }
        let mut bins = [Bin::default(); BINS];
        for k in 0..BINS {
            if crown[k] > 0.0 && land[k] > 0 {
                let ratio = crown[k] / (f64::from(land[k]) * f64::from(cell_area));
                bins[k] = Bin {
                    cover: (1.0 - (-ratio).exp()) as f32,
                    height: (height[k] / crown[k]) as f32,
                    colour: colour[k] / crown[k] as f32,
                };
            }
        }
        // Bins with no trees (heights the square has little of; the ring's hills also
        // leave its range) take the canopy of the nearest bin with some.
        let filled: Vec<usize> = (0..BINS).filter(|k| crown[*k] > 0.0).collect();
        if filled.is_empty() {
            return None;
        }
        for k in 0..BINS {
            if crown[k] <= 0.0 {
                let near = *filled.iter().min_by_key(|f| f.abs_diff(k)).unwrap_or(&k);
                bins[k] = bins[near];
            }
        }
        Some(FarCover {
            bins,
            stands: forest.stands,
            share: in_stands as f32 / (LAND_SAMPLES * LAND_SAMPLES) as f32,
            lo,
            hi,
            half,
        })
    }

    /// The canopy at `(x, z)` over ground at `ground`, for a surface whose cells are
    /// `footprint` metres across there (stands blur into their share as cells grow).
    pub fn at(&self, x: f32, z: f32, ground: f32, footprint: f32) -> Canopy {
        // Bins are linear between their centres.
        let t = normalise(ground, self.lo, self.hi) * BINS as f32 - 0.5;
        let k0 = (t.floor().max(0.0) as usize).min(BINS - 1);
        let k1 = (k0 + 1).min(BINS - 1);
        let f = (t - k0 as f32).clamp(0.0, 1.0);
        let (a, b) = (self.bins[k0], self.bins[k1]);
        let stand = self
            .stands
            .as_ref()
            .map_or(1.0, |s| s.stand_weight(x, z, ground, footprint, self.share));
        let cover = (a.cover + (b.cover - a.cover) * f) * stand;
        let height = a.height + (b.height - a.height) * f;
        let out = (x.abs().max(z.abs()) - self.half).max(0.0);
        let rise = (out / RISE_M).min(1.0);
        let speckle = unit_f32(hash2(0xCA_70_B1, x.round() as i32, z.round() as i32));
        Canopy {
            cover,
            raise: CANOPY_FILL * height * cover * rise * (2.0 - rise),
            colour: a.colour.lerp(b.colour, f)
                * CANOPY_SHADE
                * (1.0 + CANOPY_SPECKLE * (2.0 * speckle - 1.0)),
        }
    }

    /// Fraction of the land covered by crowns in the densest height bin (for `info`).
    pub fn max_cover(&self) -> f32 {
        self.bins.iter().map(|b| b.cover).fold(0.0, f32::max)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::{ForestParams, SpeciesEntry, StandParams, TerrainParams, World};

    fn world(count: Option<u32>, density: Option<f32>, stands: bool) -> World {
        let terrain = TerrainParams {
            size: 300.0,
            resolution: 65,
            horizon: true,
            ..TerrainParams::default()
        };
        let species = vec![SpeciesEntry::from_preset("fir", "fir", 1)];
        let forest = ForestParams {
            count,
            density,
            seed: 5,
            min_spacing: 2.5,
            mix: vec![1.0],
            stands: stands.then_some(StandParams {
                cover: 0.6,
                size: 120.0,
                edge: 5.0,
                meadows: 0.0,
            }),
            ..ForestParams::default()
        };
        World::build(&terrain, &species, &forest).unwrap()
    }

    #[test]
    fn a_dense_stand_closes_its_canopy_and_a_savanna_does_not() {
        let dense = world(None, Some(800.0), false);
        let sparse = world(Some(9), None, false);
        let d = FarCover::measure(&dense.terrain, &dense.species, &dense.forest).unwrap();
        let s = FarCover::measure(&sparse.terrain, &sparse.species, &sparse.forest).unwrap();
        assert!(d.max_cover() > 0.9, "dense cover {}", d.max_cover());
        assert!(s.max_cover() < 0.1, "sparse cover {}", s.max_cover());
        // Past the border's rise, the dense canopy stands at most of a fir's height.
        let far = d.at(700.0, 10.0, dense.terrain.height_at(700.0, 10.0), 20.0);
        let fir_height = dense.species[0].tree_bounds.max.y;
        assert!(
            far.raise > 0.5 * fir_height && far.raise < fir_height * 1.3,
            "raise {} for firs of {fir_height} m",
            far.raise
        );
        // At the border it has not risen yet.
        let border = d.at(150.0, 0.0, dense.terrain.height_at(150.0, 0.0), 20.0);
        assert!(border.raise < 1e-3, "{border:?}");
        // No trees, no cover.
        let empty = World::lone(dense.species[0].clone(), 10.0);
        let none = Forest::default();
        assert!(FarCover::measure(&empty.terrain, &empty.species, &none).is_none());
    }

    #[test]
    fn the_cover_follows_the_stands_past_the_square() {
        let w = world(None, Some(600.0), true);
        let c = FarCover::measure(&w.terrain, &w.species, &w.forest).unwrap();
        let field = w.forest.stands.unwrap();
        // Along a line past the square, the canopy is there where the stand noise says
        // stand, and not where it says clearing.
        let (mut stand, mut clearing) = (0, 0);
        for k in 0..400 {
            let x = 400.0 + 2.0 * k as f32;
            let z = -37.0;
            let g = w.terrain.height_at(x, z);
            let sharp = field.stand_weight(x, z, g, 0.0, 0.0);
            let canopy = c.at(x, z, g, 0.0);
            if sharp > 0.99 {
                stand += 1;
                assert!(canopy.cover > 0.5, "at {x}: {canopy:?}");
            } else if sharp < 0.01 {
                clearing += 1;
                assert!(canopy.cover < 0.05, "at {x}: {canopy:?}");
            }
        }
        assert!(
            stand > 20 && clearing > 20,
            "{stand} stand, {clearing} clearing"
        );
        // Far out, cells of hundreds of metres average to the stands' share.
        let g = w.terrain.height_at(5000.0, 5000.0);
        let coarse = c.at(5000.0, 5000.0, g, 400.0);
        let want = c.max_cover() * c.share;
        assert!(
            (coarse.cover - want).abs() < 0.25 * c.max_cover(),
            "{coarse:?} vs {want}"
        );
    }
}
