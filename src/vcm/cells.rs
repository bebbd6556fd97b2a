//! Forest cells: tree-level visibility cube maps whose number grows with the forest's area,
//! not its tree count.
//!
//! The thesis gives every tree instance its own 8 corner cube maps, each drawn with every
//! other tree but the instance itself (48 KB a tree at 32² per face: 5 GB for 100,000
//! trees). Here the ground is cut into square cells about a tree's width and a bit more; a
//! cell's box holds the boxes of the trees standing in it, and its 8 corners carry cube maps
//! drawn with every tree *outside* the cell (and the terrain). The trees of one cell share
//! them. What the cell's cubes leave out — the few trees standing in the same cell — is
//! added back per tree when the sun moves: a single ray from each of the tree's own corners
//! towards the sun, through the billboards of its cell mates (not its own, as with the
//! per-tree cubes). So a tree is never shaded by itself, its nearest neighbours are seen
//! exactly along the sun ray, and the farther forest through the cell's cubes,
//! interpolated trilinearly at the tree's corners.
//!
//! The sky term (mean visibility over the upper hemisphere) is the cell's, interpolated at
//! the tree's corners, times the share of it the cell mates leave open, sampled in a few
//! dozen directions when the cube maps are loaded.

use std::collections::BTreeMap;

use glam::Vec3;

use crate::model::World;
use crate::model::mesh::Aabb;

/// A cell's side, in mean tree widths (the widest horizontal extent of a tree's box), where
/// the forest is dense.
pub const CELL_TREE_WIDTHS: f32 = 1.25;
/// Trees a cell holds on average where the forest is sparse: cells grow (up to the range's
/// largest side) until this many trees stand on one cell's area at the forest's typical
/// density, so that sparse trees share their cube maps too.
pub const CELL_SPARSE_TREES: f32 = 2.0;
/// Trees sampled for the forest's typical density, and the neighbour that measures it.
const DENSITY_SAMPLES: usize = 256;
const DENSITY_NEIGHBOUR: usize = 4;
/// The bounds of a cell's side (m).
pub const CELL_SIDE_RANGE: (f32, f32) = (6.0, 40.0);

/// One cell of the forest and the trees standing in it.
#[derive(Clone, Debug, PartialEq)]
pub struct Cell {
    /// The union of its trees' boxes (world frame): its cube maps sit at the 8 corners.
    pub bounds: Aabb,
    /// Tree instances standing in the cell (their trunk's foot), in instance order.
    pub trees: Vec<u32>,
}

/// The cells of a forest: only those where trees stand, row by row.
#[derive(Clone, Debug, PartialEq)]
pub struct ForestCells {
    /// Side of a cell (m).
    pub side: f32,
    pub cells: Vec<Cell>,
    /// Per tree instance: the index of its cell.
    pub of_tree: Vec<u32>,
}

/// Tree `i`'s box in the world frame (its species' tree box, placed).
pub fn tree_world_box(world: &World, i: usize) -> Option<Aabb> {
    let inst = world.forest.instances.get(i)?;
    let model = world.species.get(inst.species as usize)?;
    let m = inst.transform();
    Some(Aabb::from_points(
        model
            .tree_bounds
            .corners()
            .iter()
            .map(|&c| m.transform_point3(c)),
    ))
}

/// The forest's typical density (trees per m²): the median over sampled trees of
/// k / (π r²), r the distance to its k-th nearest neighbour ([`DENSITY_NEIGHBOUR`]); 0 for
/// a forest of fewer trees than that.
pub fn typical_density(world: &World) -> f32 {
    let trees = &world.forest.instances;
    if trees.len() <= DENSITY_NEIGHBOUR {
        return 0.0;
    }
    let step = trees.len().div_ceil(DENSITY_SAMPLES).max(1);
    let mut densities: Vec<f32> = trees
        .iter()
        .step_by(step)
        .map(|t| {
            let mut nearest = [f32::INFINITY; DENSITY_NEIGHBOUR + 1];
            for o in trees {
                let d =
                    (o.position.x - t.position.x).powi(2) + (o.position.z - t.position.z).powi(2);
                if d < nearest[DENSITY_NEIGHBOUR] {
                    nearest[DENSITY_NEIGHBOUR] = d;
                    nearest.sort_unstable_by(f32::total_cmp);
                }
            }
            // nearest[0] is the tree itself.
            let r2 = nearest[DENSITY_NEIGHBOUR].max(1e-6);
            DENSITY_NEIGHBOUR as f32 / (std::f32::consts::PI * r2)
        })
        .collect();
    densities.sort_unstable_by(f32::total_cmp);
    densities[densities.len() / 2]
}

impl ForestCells {
    /// The side of `world`'s cells: [`CELL_TREE_WIDTHS`] mean tree widths, or where the
    /// forest is sparse the side on which [`CELL_SPARSE_TREES`] trees stand at its typical
    /// density, within [`CELL_SIDE_RANGE`].
    pub fn side_for(world: &World) -> f32 {
        let trees = &world.forest.instances;
        let widths: f64 = trees
            .iter()
            .filter_map(|t| {
                let b = world.species.get(t.species as usize)?.tree_bounds;
                let e = b.max - b.min;
                Some(f64::from(e.x.max(e.z) * t.scale))
            })
            .sum();
        let mean = if trees.is_empty() {
            0.0
        } else {
            (widths / trees.len() as f64) as f32
        };
        let side =
            (CELL_TREE_WIDTHS * mean).max((CELL_SPARSE_TREES / typical_density(world)).sqrt());
        // Too few trees to measure a density (infinite side): the largest cells.
        if side.is_nan() {
            CELL_SIDE_RANGE.0
        } else {
            side.clamp(CELL_SIDE_RANGE.0, CELL_SIDE_RANGE.1)
        }
    }

    /// The cells of `world`'s forest (deterministic: the same world gives the same cells,
    /// which is how a bake's cell cube maps are matched to a scene when it is drawn).
    pub fn new(world: &World) -> Self {
        let side = Self::side_for(world);
        let half = 0.5 * world.terrain.size;
        let mut by_key: BTreeMap<(i64, i64), Vec<u32>> = BTreeMap::new();
        for (i, t) in world.forest.instances.iter().enumerate() {
            let key = |v: f32| {
                let k = ((v + half) / side).floor();
                if k.is_finite() { k as i64 } else { 0 }
            };
            // Row-major: z first.
            by_key
                .entry((key(t.position.z), key(t.position.x)))
                .or_default()
                .push(i as u32);
        }
        let mut of_tree = vec![0u32; world.forest.instances.len()];
        let cells = by_key
            .into_values()
            .enumerate()
            .map(|(c, trees)| {
                let bounds = trees
                    .iter()
                    .filter_map(|&t| tree_world_box(world, t as usize))
                    .fold(Aabb::EMPTY, Aabb::union);
                for &t in &trees {
                    of_tree[t as usize] = c as u32;
                }
                Cell { bounds, trees }
            })
            .collect();
        Self {
            side,
            cells,
            of_tree,
        }
    }

    /// The number of cells with trees.
    pub fn len(&self) -> usize {
        self.cells.len()
    }

    pub fn is_empty(&self) -> bool {
        self.cells.is_empty()
    }

    /// The centre of a cell's box.
    pub fn center(&self, c: usize) -> Vec3 {
        let b = &self.cells[c].bounds;
        0.5 * (b.min + b.max)
    }
}

/// The face resolution of the cells' cube maps for a bake whose objects' cube maps have
/// `vcm_resolution`² texels a face: half as many per side (a quarter of the bytes), at
/// least 8.
pub fn cell_resolution(vcm_resolution: u32) -> u32 {
    (vcm_resolution / 2).max(8)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::{ForestParams, SpeciesEntry, TerrainParams};

    /// `count` trees of two species on 100 m of gentle hills, as tests/data/small.toml
    /// places them (its terrain and forest; the species from their presets).
    fn world(count: u32) -> World {
        let terrain = TerrainParams {
            size: 100.0,
            resolution: 33,
            seed: 3,
            relief: 8.0,
            feature_size: 60.0,
            octaves: 3,
            roughness: 0.5,
            ..TerrainParams::default()
        };
        let species = [
            SpeciesEntry::from_preset("fir", "fir", 1),
            SpeciesEntry::from_preset("broadleaf", "broadleaf", 2),
        ];
        let forest = ForestParams {
            count: Some(count),
            seed: 5,
            min_spacing: 7.0,
            mix: vec![0.5, 0.5],
            scale_min: 0.8,
            scale_max: 1.2,
            random_yaw: true,
            ..ForestParams::default()
        };
        World::build(&terrain, &species, &forest).unwrap()
    }

    #[test]
    fn every_tree_is_in_exactly_one_cell_whose_box_holds_its_box() {
        let w = world(60);
        let cells = ForestCells::new(&w);
        assert!(!cells.is_empty());
        let mut seen = vec![0u32; w.forest.instances.len()];
        for (c, cell) in cells.cells.iter().enumerate() {
            assert!(!cell.trees.is_empty(), "no empty cells are kept");
            for &t in &cell.trees {
                seen[t as usize] += 1;
                assert_eq!(cells.of_tree[t as usize], c as u32);
                let b = tree_world_box(&w, t as usize).unwrap();
                assert!(cell.bounds.min.cmple(b.min).all() && cell.bounds.max.cmpge(b.max).all());
            }
        }
        assert!(seen.iter().all(|&n| n == 1), "{seen:?}");
        // Trees of one cell stand within one side of each other.
        for cell in &cells.cells {
            for &a in &cell.trees {
                for &b in &cell.trees {
                    let (pa, pb) = (
                        w.forest.instances[a as usize].position,
                        w.forest.instances[b as usize].position,
                    );
                    assert!((pa.x - pb.x).abs() < cells.side && (pa.z - pb.z).abs() < cells.side);
                }
            }
        }
        assert_eq!(cells, ForestCells::new(&w), "deterministic");
    }

    #[test]
    fn the_side_follows_the_trees_and_stays_in_range() {
        let w = world(40);
        let side = ForestCells::side_for(&w);
        assert!((CELL_SIDE_RANGE.0..=CELL_SIDE_RANGE.1).contains(&side));
        let empty = world(0);
        assert_eq!(ForestCells::side_for(&empty), CELL_SIDE_RANGE.1);
        assert!(ForestCells::new(&empty).is_empty());
        assert_eq!(cell_resolution(32), 16);
        assert_eq!(cell_resolution(8), 8);
    }
}
