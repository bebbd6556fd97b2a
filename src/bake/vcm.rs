//! The VCM bake: visibility cube maps at the 8 corners of every object's bounding box at
//! every level, each against the objects of its own level only (Meyer 2001, §6.1.2):
//! - a twig against the sibling twigs of the reference main branch (species data; the
//!   trunk's own leader twigs against each other);
//! - a main branch against the sibling main branches of the reference tree (species data);
//! - a tree instance against the other trees within [`TREE_RANGE`] and the terrain (scene
//!   data, one per instance), or, with `[bake] tree_vcm = "cells"` (the default), a forest
//!   cell against the trees outside it and the terrain (one per cell with trees; see
//!   [`crate::vcm::cells`]).
//!
//! The occluders are drawn as the `btf` method draws them: each one a billboard facing the
//! cube's centre, its opacity the blend of the 3 nearest views' sky-lit images' alpha
//! (mip-filtered to the cube's texel), composited multiplicatively in software by
//! [`crate::vcm::CubeRaster`]. The terrain is drawn from a horizon map around each corner.
//!
//! Stored per cube: opacity bytes, and the mean opacity that weights the sky term. For twigs
//! and main branches the mean is over all 6 faces (the thesis' rule). For trees it is over
//! the directions above the horizontal only: the terrain hides the lower half everywhere,
//! and the BTF's sky-lit images already take no light from below.

use glam::{Mat4, Vec2, Vec3};
use rayon::prelude::*;

use crate::format::{BtfImageSet, VCM_CELL_SPECIES, VcmSet};
use crate::model::mesh::Aabb;
use crate::model::{Level, PerLevel, TreeVcm, World};
use crate::vcm::billboard::{AlphaSet, Billboard};
use crate::vcm::cells::{ForestCells, cell_resolution};
use crate::vcm::{CORNERS, CubeRaster, GROUND_CLEARANCE, Horizon, corner};
use crate::{Error, Result};

/// Trees whose bounding sphere lies farther than this (m) from a tree's corner are not drawn
/// into its cube maps (beyond it a tree covers well under a texel of a 32² face).
pub const TREE_RANGE: f32 = 250.0;

/// Azimuth samples of the terrain horizon around each corner (4 faces x 32 texels).
const HORIZON_AZIMUTHS: usize = 128;

/// The progress stages of the tree-level cube maps (what [`super::BakeTimes`] times).
pub const TREE_STAGE: &str = "tree VCMs";
pub const CELL_STAGE: &str = "forest cell VCMs";

/// Instances per parallel batch between progress reports.
const BATCH: usize = 64;

/// Objects whose 8 cube maps the bake makes (species objects, then trees or forest cells),
/// for progress and the estimate.
pub fn object_count(world: &World) -> u64 {
    species_object_count(world) + tree_object_count(world)
}

/// Twigs and main branches of every species.
pub fn species_object_count(world: &World) -> u64 {
    world
        .species
        .iter()
        .map(|t| (t.tree_branches.len() + t.branch_twigs.len() + t.tree_twigs.len()) as u64)
        .sum()
}

/// Tree-level objects: tree instances, or forest cells with trees.
pub fn tree_object_count(world: &World) -> u64 {
    match world.tree_vcm {
        TreeVcm::PerTree => world.forest.instances.len() as u64,
        TreeVcm::Cells => ForestCells::new(world).len() as u64,
    }
}

/// Face resolution of the tree-level cube maps of a bake at `vcm_resolution`.
pub fn tree_resolution(world: &World, vcm_resolution: u32) -> u32 {
    match world.tree_vcm {
        TreeVcm::PerTree => vcm_resolution,
        TreeVcm::Cells => cell_resolution(vcm_resolution),
    }
}

/// One occluder placed in the cube's frame: its image set, its placement, and the sphere
/// around its billboard (for skipping it where everything behind is already opaque).
#[derive(Clone, Copy)]
struct Placed<'a> {
    set: &'a AlphaSet,
    m: Mat4,
    center: Vec3,
    reach: f32,
}

impl<'a> Placed<'a> {
    fn new(set: &'a AlphaSet, m: Mat4) -> Self {
        let scale = m.x_axis.truncate().length();
        Self {
            set,
            m,
            center: m.transform_point3(set.center),
            // The billboard's corners lie √2 radii from its centre.
            reach: set.radius * scale * std::f32::consts::SQRT_2 * 1.001,
        }
    }
}

/// The cube maps at the 8 corners of the box `bounds` placed by `m`, with `occluders` (each
/// an image set and its placement) and optionally the terrain.
fn bake_corners(
    raster: &mut CubeRaster,
    bounds: &Aabb,
    m: Mat4,
    occluders: &[Placed<'_>],
    terrain: Option<&crate::model::Terrain>,
) -> (Vec<u8>, [f32; CORNERS]) {
    let res = raster.resolution() as usize;
    let mut opacity = Vec::with_capacity(CORNERS * 6 * res * res);
    let mut mean = [0.0; CORNERS];
    for (k, mean) in mean.iter_mut().enumerate() {
        let mut eye = m.transform_point3(corner(bounds, k));
        raster.clear();
        if let Some(t) = terrain {
            eye.y = eye.y.max(t.height_at(eye.x, eye.z) + GROUND_CLEARANCE);
            let half = 0.5 * t.size;
            let horizon = Horizon::new(
                eye,
                HORIZON_AZIMUTHS,
                0.5 * t.cell_size(),
                t.size * 1.5,
                |x, z| x.abs() <= half && z.abs() <= half,
                |x, z| t.height_at(x, z),
            );
            raster.draw_terrain(&horizon);
        }
        for o in occluders {
            if raster.covered(eye, o.center, o.reach) {
                continue;
            }
            if let Some(b) = Billboard::facing(o.set, o.m, eye) {
                raster.draw(eye, &b);
            }
        }
        *mean = raster.finish(&mut opacity, terrain.is_some());
    }
    (opacity, mean)
}

/// Bakes every VCM of `world` from its BTF image sets (`btf` must hold every species' baked
/// levels: [`super::baked_levels`]). Species data first (per species: main branches, then twigs: the reference
/// branch's, then the trunk's leader twigs), then one set per tree instance, in order.
pub fn bake_vcm(
    world: &World,
    btf: &[BtfImageSet],
    res: u32,
    progress: &mut dyn FnMut(u64, &str),
) -> Result<Vec<VcmSet>> {
    let find = |species: usize, level: Level| -> Result<AlphaSet> {
        let set = btf
            .iter()
            .find(|s| s.species as usize == species && s.level == level)
            .ok_or_else(|| {
                Error::BadInput(format!(
                    "the VCM bake needs the {} BTF of species {species}",
                    level.name()
                ))
            })?;
        AlphaSet::new(set)
    };
    let mut alpha: Vec<PerLevel<AlphaSet>> = Vec::new();
    for (s, tree) in world.species.iter().enumerate() {
        // A species without finer levels (an imported tree whose file gives none) has no
        // parts that read them: its tree level stands in.
        let finer = |level: Level| {
            if tree.has_hierarchy() {
                find(s, level)
            } else {
                find(s, Level::Tree)
            }
        };
        alpha.push(PerLevel {
            twig: finer(Level::Twig)?,
            branch: finer(Level::Branch)?,
            tree: find(s, Level::Tree)?,
        });
    }
    let mut out = Vec::new();
    let mut done = 0u64;

    // Species data: siblings inside one reference object.
    for (s, tree) in world.species.iter().enumerate() {
        let PerLevel { twig, branch, .. } = &alpha[s];
        let groups: [(&[Mat4], &Aabb, &AlphaSet, Level, u32); 3] = [
            (
                &tree.tree_branches,
                &tree.branch_bounds,
                branch,
                Level::Branch,
                0,
            ),
            (&tree.branch_twigs, &tree.twig_bounds, twig, Level::Twig, 0),
            (
                &tree.tree_twigs,
                &tree.twig_bounds,
                twig,
                Level::Twig,
                tree.branch_twigs.len() as u32,
            ),
        ];
        for (parts, bounds, set, level, first_owner) in groups {
            let sets: Vec<VcmSet> = parts
                .par_iter()
                .enumerate()
                .map_init(
                    || CubeRaster::new(res),
                    |raster, (i, m)| {
                        let occluders: Vec<Placed> = parts
                            .iter()
                            .enumerate()
                            .filter(|&(k, _)| k != i)
                            .map(|(_, o)| Placed::new(set, *o))
                            .collect();
                        let (opacity, mean_opacity) =
                            bake_corners(raster, bounds, *m, &occluders, None);
                        VcmSet {
                            encoding: crate::format::MapEncoding::R8,
                            species: s as u32,
                            owner: first_owner + i as u32,
                            level,
                            resolution: res,
                            opacity,
                            mean_opacity,
                        }
                    },
                )
                .collect();
            done += sets.len() as u64;
            out.extend(sets);
            progress(done, &format!("{} VCMs", tree.name));
        }
    }

    // Scene data: each tree instance (or forest cell) against the trees around it and the
    // terrain.
    match world.tree_vcm {
        TreeVcm::PerTree => bake_trees(world, &alpha, res, done, progress, &mut out)?,
        TreeVcm::Cells => bake_cells(world, &alpha, res, done, progress, &mut out)?,
    }
    Ok(out)
}

/// The forest as the tree-level bake draws it: every tree's placement and billboard
/// radius, and a grid to find the trees near a point.
struct Surroundings<'a> {
    world: &'a World,
    alpha: &'a [PerLevel<AlphaSet>],
    grid: Grid,
    /// Per tree: its world placement and the radius of its billboard.
    placed: Vec<(Mat4, f32)>,
    max_radius: f32,
}

impl<'a> Surroundings<'a> {
    fn new(world: &'a World, alpha: &'a [PerLevel<AlphaSet>]) -> Self {
        let instances = &world.forest.instances;
        let placed: Vec<(Mat4, f32)> = instances
            .iter()
            .map(|t| {
                let r = alpha
                    .get(t.species as usize)
                    .map_or(0.0, |a| a.tree.radius * t.scale);
                (t.transform(), r)
            })
            .collect();
        Self {
            world,
            alpha,
            grid: Grid::new(instances.iter().map(|t| t.position), TREE_RANGE / 4.0),
            max_radius: placed.iter().map(|p| p.1).fold(0.0f32, f32::max),
            placed,
        }
    }

    /// The trees (as occluders) within `range` of `p` that `keep` accepts, nearest first:
    /// in a dense stand they make the texels towards the horizon opaque, and the farther
    /// trees drawn there are then skipped ([`CubeRaster::covered`]).
    fn neighbours(
        &self,
        p: Vec3,
        range: f32,
        near: &mut Vec<u32>,
        keep: impl Fn(usize) -> bool,
    ) -> Vec<Placed<'a>> {
        let instances = &self.world.forest.instances;
        near.clear();
        self.grid.near(p, range, near);
        let mut by_distance: Vec<(f32, u32)> = near
            .iter()
            .filter(|&&j| keep(j as usize))
            .filter_map(|&j| {
                let d = instances[j as usize].position.distance(p);
                (d <= range).then_some((d, j))
            })
            .collect();
        by_distance.sort_unstable_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
        by_distance
            .iter()
            .filter_map(|&(_, j)| {
                let o = &instances[j as usize];
                self.alpha
                    .get(o.species as usize)
                    .map(|a| Placed::new(&a.tree, self.placed[j as usize].0))
            })
            .collect()
    }
}

/// One set per tree instance, against the other trees within [`TREE_RANGE`] of it.
fn bake_trees(
    world: &World,
    alpha: &[PerLevel<AlphaSet>],
    res: u32,
    mut done: u64,
    progress: &mut dyn FnMut(u64, &str),
    out: &mut Vec<VcmSet>,
) -> Result<()> {
    let instances = &world.forest.instances;
    let around = Surroundings::new(world, alpha);
    for (b, chunk) in instances.chunks(BATCH).enumerate() {
        let sets: Vec<VcmSet> = chunk
            .par_iter()
            .enumerate()
            .map_init(
                || (CubeRaster::new(res), Vec::new()),
                |(raster, near), (k, inst)| {
                    let i = b * BATCH + k;
                    let Some(model) = world.species.get(inst.species as usize) else {
                        return Err(Error::BadInput(format!(
                            "tree {i} has species {} of {}",
                            inst.species,
                            world.species.len()
                        )));
                    };
                    let (m, r) = around.placed[i];
                    let occluders = around.neighbours(
                        inst.position,
                        TREE_RANGE + r + around.max_radius,
                        near,
                        |j| {
                            j != i
                                && instances[j].position.distance(inst.position)
                                    <= TREE_RANGE + r + around.placed[j].1
                        },
                    );
                    let (opacity, mean_opacity) = bake_corners(
                        raster,
                        &model.tree_bounds,
                        m,
                        &occluders,
                        Some(&world.terrain),
                    );
                    Ok(VcmSet {
                        encoding: crate::format::MapEncoding::R8,
                        species: inst.species,
                        owner: i as u32,
                        level: Level::Tree,
                        resolution: res,
                        opacity,
                        mean_opacity,
                    })
                },
            )
            .collect::<Result<_>>()?;
        done += sets.len() as u64;
        out.extend(sets);
        progress(done, TREE_STAGE);
    }
    Ok(())
}

/// One set per forest cell with trees, against the trees outside the cell within
/// [`TREE_RANGE`] of its box, at the cells' resolution ([`cell_resolution`]).
fn bake_cells(
    world: &World,
    alpha: &[PerLevel<AlphaSet>],
    res: u32,
    mut done: u64,
    progress: &mut dyn FnMut(u64, &str),
    out: &mut Vec<VcmSet>,
) -> Result<()> {
    let instances = &world.forest.instances;
    if let Some((i, t)) = instances
        .iter()
        .enumerate()
        .find(|(_, t)| t.species as usize >= world.species.len())
    {
        return Err(Error::BadInput(format!(
            "tree {i} has species {} of {}",
            t.species,
            world.species.len()
        )));
    }
    let res = cell_resolution(res);
    let cells = ForestCells::new(world);
    let around = Surroundings::new(world, alpha);
    let order: Vec<usize> = (0..cells.len()).collect();
    for chunk in order.chunks(BATCH) {
        let sets: Vec<VcmSet> = chunk
            .par_iter()
            .map_init(
                || (CubeRaster::new(res), Vec::new()),
                |(raster, near), &c| {
                    let cell = &cells.cells[c];
                    let center = cells.center(c);
                    let half = 0.5 * (cell.bounds.max - cell.bounds.min).length();
                    let occluders = around.neighbours(
                        center,
                        TREE_RANGE + half + around.max_radius,
                        near,
                        |j| cells.of_tree[j] as usize != c,
                    );
                    let (opacity, mean_opacity) = bake_corners(
                        raster,
                        &cell.bounds,
                        Mat4::IDENTITY,
                        &occluders,
                        Some(&world.terrain),
                    );
                    VcmSet {
                        encoding: crate::format::MapEncoding::R8,
                        species: VCM_CELL_SPECIES,
                        owner: c as u32,
                        level: Level::Tree,
                        resolution: res,
                        opacity,
                        mean_opacity,
                    }
                },
            )
            .collect();
        done += sets.len() as u64;
        out.extend(sets);
        progress(done, CELL_STAGE);
    }
    Ok(())
}

/// A uniform grid over the ground plane for neighbour queries.
struct Grid {
    origin: Vec2,
    cell: f32,
    n: usize,
    cells: Vec<Vec<u32>>,
}

impl Grid {
    fn new(points: impl Iterator<Item = Vec3> + Clone, cell: f32) -> Self {
        let (lo, hi) = points.clone().fold(
            (Vec2::splat(f32::MAX), Vec2::splat(f32::MIN)),
            |(lo, hi), p| (lo.min(Vec2::new(p.x, p.z)), hi.max(Vec2::new(p.x, p.z))),
        );
        let (lo, hi) = if lo.x <= hi.x {
            (lo, hi)
        } else {
            (Vec2::ZERO, Vec2::ZERO)
        };
        let extent = (hi - lo).max_element().max(1.0);
        // At most 512 x 512 cells, however large the terrain.
        let cell = cell.max(extent / 512.0).max(1.0);
        let n = (extent / cell) as usize + 1;
        let mut cells = vec![Vec::new(); n * n];
        for (i, p) in points.enumerate() {
            let (x, z) = Self::index(lo, cell, n, Vec2::new(p.x, p.z));
            cells[z * n + x].push(i as u32);
        }
        Self {
            origin: lo,
            cell,
            n,
            cells,
        }
    }

    fn index(origin: Vec2, cell: f32, n: usize, p: Vec2) -> (usize, usize) {
        let g = ((p - origin) / cell).max(Vec2::ZERO);
        ((g.x as usize).min(n - 1), (g.y as usize).min(n - 1))
    }

    /// Appends the points of every cell within `range` of `p` (a superset of the points
    /// within range).
    fn near(&self, p: Vec3, range: f32, out: &mut Vec<u32>) {
        let c = Vec2::new(p.x, p.z);
        let (x0, z0) = Self::index(self.origin, self.cell, self.n, c - range);
        let (x1, z1) = Self::index(self.origin, self.cell, self.n, c + range);
        for z in z0..=z1 {
            for x in x0..=x1 {
                out.extend_from_slice(&self.cells[z * self.n + x]);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_grid_finds_every_neighbour_in_range() {
        let pts: Vec<Vec3> = (0..400)
            .map(|i| {
                Vec3::new(
                    (i % 20) as f32 * 13.0 - 120.0,
                    0.0,
                    (i / 20) as f32 * 11.0 - 90.0,
                )
            })
            .collect();
        let grid = Grid::new(pts.iter().copied(), 20.0);
        for &p in pts.iter().step_by(37) {
            let mut near = Vec::new();
            grid.near(p, 50.0, &mut near);
            for (i, q) in pts.iter().enumerate() {
                if (*q - p).length() <= 50.0 {
                    assert!(near.contains(&(i as u32)), "{p} misses {q}");
                }
            }
        }
    }
}
