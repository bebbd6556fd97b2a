//! Tree-level cube maps one set per forest cell ([`crate::vcm::cells`]): a tree's 8 corner
//! factors are the cell's cube maps read at the tree's corners, times the rays through the
//! billboards of the trees sharing its cell.

use glam::{Mat4, Vec3};
use rayon::prelude::*;

use super::maps::ObjectVcm;
use crate::vcm::billboard::{AlphaSet, Billboard};
use crate::vcm::cells::ForestCells;
use crate::vcm::{self, CORNERS};

/// The tree-level cube maps of a forest laid out in cells, and what a tree needs to read
/// them: its corners in the world, and its cell mates' billboards.
pub(super) struct CellShading {
    pub(super) cells: ForestCells,
    pub(super) res: u32,
    pub(super) maps: Vec<ObjectVcm>,
    /// Per species: the tree level's sky-lit images as occluders.
    pub(super) alpha: Vec<AlphaSet>,
    /// Per tree: its placement, and its box's 8 corners in the world (kept above the
    /// terrain as the bake keeps cube maps).
    pub(super) trees: Vec<(u32, Mat4, [Vec3; CORNERS])>,
}

impl CellShading {
    /// Sun visibility at every tree's 8 corners: the cell's cube maps read trilinearly,
    /// times the sun ray through the cell mates' billboards. A cell mate is drawn as its
    /// billboard seen along the sun's direction (its shadow's outline; the cube bake turns
    /// each billboard to the cube's centre, which for a tree in the sun's direction is
    /// nearly the same view), so its 3 views' blend is found once per tree, not per ray.
    pub(super) fn direct(&self, to_sun: Vec3, out: &mut [[f32; CORNERS]]) {
        let cell_direct: Vec<[f32; CORNERS]> = self
            .maps
            .par_iter()
            .map(|m| m.direct(self.res, to_sun))
            .collect();
        let facing_sun: Vec<Option<Billboard>> = self
            .trees
            .par_iter()
            .map(|(species, m, _)| {
                let centre = m.transform_point3(self.alpha.get(*species as usize)?.center);
                Billboard::facing(self.alpha.get(*species as usize)?, *m, centre - to_sun)
            })
            .collect();
        out.par_iter_mut().enumerate().for_each(|(t, d)| {
            let c = self.cells.of_tree[t] as usize;
            let cell = &self.cells.cells[c];
            let corners = &self.trees[t].2;
            *d = std::array::from_fn(|k| {
                let p = corners[k];
                let mut v = vcm::trilinear(&cell_direct[c], vcm::box_coords(&cell.bounds, p));
                for &o in &cell.trees {
                    if o as usize == t {
                        continue;
                    }
                    if let Some(b) = &facing_sun[o as usize] {
                        v *= 1.0 - vcm::ray_opacity(p, to_sun, b, self.res);
                    }
                }
                v
            });
        });
    }

    /// Sky visibility at every tree's 8 corners: the cell's mean visibility, read
    /// trilinearly, times the share of that visible sky the cell mates leave open. The
    /// share is sampled in [`SKY_SAMPLES`] directions over the upper hemisphere: in each,
    /// the cell's cubes (interpolated at the corner) times the ray through the cell mates'
    /// billboards (seen along it), against the cell's cubes alone.
    pub(super) fn sky(&self) -> Vec<[f32; CORNERS]> {
        let dirs: Vec<Vec3> = crate::sphere::DirectionSet::with_count(SKY_SAMPLES)
            .map(|set| {
                set.directions()
                    .iter()
                    .copied()
                    .filter(|d| d.y > 0.1)
                    .collect()
            })
            .unwrap_or_default();
        let per_cell: Vec<Vec<(u32, [f32; CORNERS])>> = self
            .cells
            .cells
            .par_iter()
            .zip(&self.maps)
            .map(|(cell, map)| {
                // The cell's 8 cubes in every direction, and its trees' billboards along it.
                let far: Vec<[f32; CORNERS]> =
                    dirs.iter().map(|&d| map.direct(self.res, d)).collect();
                let boards: Vec<Vec<Option<Billboard>>> = if cell.trees.len() > 1 {
                    dirs.iter()
                        .map(|&d| {
                            cell.trees
                                .iter()
                                .map(|&o| {
                                    let (species, m, _) = &self.trees[o as usize];
                                    let a = self.alpha.get(*species as usize)?;
                                    Billboard::facing(a, *m, m.transform_point3(a.center) - d)
                                })
                                .collect()
                        })
                        .collect()
                } else {
                    Vec::new()
                };
                cell.trees
                    .iter()
                    .enumerate()
                    .map(|(i, &t)| {
                        let corners = &self.trees[t as usize].2;
                        let sky = std::array::from_fn(|k| {
                            let u = vcm::box_coords(&cell.bounds, corners[k]);
                            let mean = vcm::trilinear(&map.sky, u);
                            if boards.is_empty() {
                                return mean;
                            }
                            let (mut open, mut left) = (0.0f32, 0.0f32);
                            for (di, &d) in dirs.iter().enumerate() {
                                let vf = vcm::trilinear(&far[di], u);
                                let mut vn = 1.0;
                                for (j, b) in boards[di].iter().enumerate() {
                                    if j != i
                                        && let Some(b) = b
                                    {
                                        vn *= 1.0 - vcm::ray_opacity(corners[k], d, b, self.res);
                                    }
                                }
                                open += vf;
                                left += vf * vn;
                            }
                            if open > 1e-6 {
                                mean * left / open
                            } else {
                                mean
                            }
                        });
                        (t, sky)
                    })
                    .collect()
            })
            .collect();
        let mut out = vec![[1.0; CORNERS]; self.trees.len()];
        for (t, sky) in per_cell.into_iter().flatten() {
            if let Some(o) = out.get_mut(t as usize) {
                *o = sky;
            }
        }
        out
    }
}

/// Directions over the whole sphere of which those above 0.1 rad or so sample the cell
/// mates' share of the sky (28 of them).
const SKY_SAMPLES: usize = 66;
