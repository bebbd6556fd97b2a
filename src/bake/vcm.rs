//! The VCM bake: visibility cube maps at the 8 corners of every object's bounding box at
//! every level, each against the objects of its own level only (Meyer 2001, §6.1.2):
//! - a twig against the sibling twigs of the reference main branch (species data; the
//!   trunk's own leader twigs against each other);
//! - a main branch against the sibling main branches of the reference tree (species data);
//! - a tree instance against the other trees within [`TREE_RANGE`] and the terrain (scene
//!   data, one per instance).
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

use glam::{Mat3, Mat4, Vec2, Vec3};
use rayon::prelude::*;

use crate::format::{BtfImageSet, VcmSet};
use crate::model::mesh::Aabb;
use crate::model::{Level, PerLevel, World};
use crate::sphere::{Blend, DirectionSet, billboard_axes};
use crate::vcm::{CORNERS, CubeRaster, Horizon, Occluder, corner};
use crate::{Error, Result};

/// Trees whose bounding sphere lies farther than this (m) from a tree's corner are not drawn
/// into its cube maps (beyond it a tree covers well under a texel of a 32² face).
pub const TREE_RANGE: f32 = 250.0;

/// Azimuth samples of the terrain horizon around each corner (4 faces x 32 texels).
const HORIZON_AZIMUTHS: usize = 128;

/// Corners are kept this far (m) above the terrain, so a box corner that dips into a slope
/// still sees the sky the tree's foot sees.
const GROUND_CLEARANCE: f32 = 0.05;

/// Instances per parallel batch between progress reports.
const BATCH: usize = 64;

/// One level's sky-lit images as occluders: each view's alpha with its mip chain.
struct AlphaSet {
    views: DirectionSet,
    view_axes: Vec<(Vec3, Vec3)>,
    /// [view][mip] alpha, res_mip² values.
    mips: Vec<Vec<Vec<f32>>>,
    res: u32,
    center: Vec3,
    radius: f32,
}

impl AlphaSet {
    fn new(set: &BtfImageSet) -> Result<Self> {
        let views = DirectionSet::with_count(set.views as usize)
            .map_err(|e| Error::BadInput(format!("BTF set: {e}")))?;
        let res = set.resolution.max(1);
        let n = (res * res) as usize;
        if set.ambient.len() != set.views as usize * n * 4 {
            return Err(Error::BadInput(format!(
                "BTF set of species {} level {:?}: sky images hold {} bytes, expected {}",
                set.species,
                set.level,
                set.ambient.len(),
                set.views as usize * n * 4
            )));
        }
        let mips = set
            .ambient
            .chunks_exact(n * 4)
            .map(|img| {
                let mut level: Vec<f32> = img
                    .chunks_exact(4)
                    .map(|p| f32::from(p[3]) / 255.0)
                    .collect();
                let mut side = res as usize;
                let mut chain = Vec::new();
                loop {
                    let next = if side > 1 {
                        Some(halve(&level, side))
                    } else {
                        None
                    };
                    chain.push(level);
                    match next {
                        Some(l) => {
                            level = l;
                            side /= 2;
                        }
                        None => break,
                    }
                }
                chain
            })
            .collect();
        let view_axes = views
            .directions()
            .iter()
            .map(|&v| billboard_axes(v))
            .collect();
        Ok(Self {
            views,
            view_axes,
            mips,
            res,
            center: Vec3::from(set.center),
            radius: set.radius,
        })
    }

    /// Alpha of view `v` at `uv` (0..1 over the image), filtered over `texels` texels.
    fn alpha(&self, v: usize, uv: Vec2, texels: f32) -> f32 {
        let chain = &self.mips[v];
        let level = if texels > 1.0 {
            (texels.log2().round() as usize).min(chain.len() - 1)
        } else {
            0
        };
        let side = (self.res as usize >> level).max(1);
        let img = &chain[level];
        let s = side as f32;
        let fx = (uv.x * s - 0.5).clamp(0.0, s - 1.0);
        let fy = (uv.y * s - 0.5).clamp(0.0, s - 1.0);
        let (x0, y0) = (fx as usize, fy as usize);
        let (x1, y1) = ((x0 + 1).min(side - 1), (y0 + 1).min(side - 1));
        let (a, b) = (fx - x0 as f32, fy - y0 as f32);
        let at = |x: usize, y: usize| img[y * side + x];
        let top = at(x0, y0) + (at(x1, y0) - at(x0, y0)) * a;
        let bottom = at(x0, y1) + (at(x1, y1) - at(x0, y1)) * a;
        top + (bottom - top) * b
    }
}

/// A 2x2 box filter of a `side`² image.
fn halve(img: &[f32], side: usize) -> Vec<f32> {
    let h = (side / 2).max(1);
    let mut out = vec![0.0; h * h];
    for y in 0..h {
        for x in 0..h {
            let at = |xx: usize, yy: usize| img[yy.min(side - 1) * side + xx.min(side - 1)];
            out[y * h + x] = 0.25
                * (at(2 * x, 2 * y)
                    + at(2 * x + 1, 2 * y)
                    + at(2 * x, 2 * y + 1)
                    + at(2 * x + 1, 2 * y + 1));
        }
    }
    out
}

/// One object's billboard as the cube's centre sees it.
struct Billboard<'a> {
    set: &'a AlphaSet,
    blend: Blend,
    center: Vec3,
    right: Vec3,
    up: Vec3,
    obj_right: Vec3,
    obj_up: Vec3,
}

impl<'a> Billboard<'a> {
    /// The billboard of `set` placed by `m` (object to cube frame), facing `eye`; None for a
    /// degenerate transform.
    fn facing(set: &'a AlphaSet, m: Mat4, eye: Vec3) -> Option<Self> {
        let scale = m.x_axis.truncate().length();
        if !(scale > 0.0 && scale.is_finite()) {
            return None;
        }
        let rot = Mat3::from_mat4(m) * (1.0 / scale);
        let center = m.transform_point3(set.center);
        let radius = set.radius * scale;
        let v_obj = rot.transpose() * (eye - center).normalize_or(Vec3::Y);
        let (r, u) = billboard_axes(v_obj);
        Some(Self {
            set,
            blend: set.views.blend(v_obj),
            center,
            right: rot * r * radius,
            up: rot * u * radius,
            obj_right: r,
            obj_up: u,
        })
    }
}

impl Occluder for Billboard<'_> {
    fn center(&self) -> Vec3 {
        self.center
    }
    fn right(&self) -> Vec3 {
        self.right
    }
    fn up(&self) -> Vec3 {
        self.up
    }
    fn opacity(&self, s: f32, t: f32, footprint: f32) -> f32 {
        let p = s * self.obj_right + t * self.obj_up;
        let texels = footprint * 0.5 * self.set.res as f32;
        let mut a = 0.0;
        for k in 0..3 {
            let w = self.blend.weight[k];
            if w <= 0.0 {
                continue;
            }
            let v = self.blend.index[k] as usize;
            let (r, u) = self.set.view_axes[v];
            let uv = Vec2::new(p.dot(r), -p.dot(u)) * 0.5 + 0.5;
            a += w * self.set.alpha(v, uv, texels);
        }
        a
    }
}

/// Objects of one level per parallel job: how many cubes the whole bake makes, for progress.
pub fn object_count(world: &World) -> u64 {
    let species: u64 = world
        .species
        .iter()
        .map(|t| (t.tree_branches.len() + t.branch_twigs.len() + t.tree_twigs.len()) as u64)
        .sum();
    species + world.forest.instances.len() as u64
}

/// The cube maps at the 8 corners of the box `bounds` placed by `m`, with `occluders` (each
/// an image set and its placement) and optionally the terrain.
fn bake_corners(
    raster: &mut CubeRaster,
    bounds: &Aabb,
    m: Mat4,
    occluders: &[(&AlphaSet, Mat4)],
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
        for (set, om) in occluders {
            if let Some(b) = Billboard::facing(set, *om, eye) {
                raster.draw(eye, &b);
            }
        }
        *mean = raster.finish(&mut opacity, terrain.is_some());
    }
    (opacity, mean)
}

/// Bakes every VCM of `world` from its BTF image sets (`btf` must hold every species' three
/// levels). Species data first (per species: main branches, then twigs: the reference
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
    for s in 0..world.species.len() {
        alpha.push(PerLevel {
            twig: find(s, Level::Twig)?,
            branch: find(s, Level::Branch)?,
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
                        let occluders: Vec<(&AlphaSet, Mat4)> = parts
                            .iter()
                            .enumerate()
                            .filter(|&(k, _)| k != i)
                            .map(|(_, o)| (set, *o))
                            .collect();
                        let (opacity, mean_opacity) =
                            bake_corners(raster, bounds, *m, &occluders, None);
                        VcmSet {
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

    // Scene data: each tree instance against its neighbours and the terrain.
    let instances = &world.forest.instances;
    let grid = Grid::new(instances.iter().map(|t| t.position), TREE_RANGE / 4.0);
    let placed: Vec<(Mat4, f32)> = instances
        .iter()
        .map(|t| {
            let r = alpha
                .get(t.species as usize)
                .map_or(0.0, |a| a.tree.radius * t.scale);
            (t.transform(), r)
        })
        .collect();
    let max_radius = placed.iter().map(|p| p.1).fold(0.0f32, f32::max);
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
                    let (m, r) = placed[i];
                    near.clear();
                    grid.near(inst.position, TREE_RANGE + r + max_radius, near);
                    // Nearest first: in a dense stand they make the texels towards the
                    // horizon opaque, and the farther trees drawn there are then skipped.
                    near.sort_by(|&a, &b| {
                        let d = |j: u32| {
                            instances[j as usize]
                                .position
                                .distance_squared(inst.position)
                        };
                        d(a).total_cmp(&d(b))
                    });
                    let occluders: Vec<(&AlphaSet, Mat4)> = near
                        .iter()
                        .filter(|&&j| j as usize != i)
                        .filter_map(|&j| {
                            let o = &instances[j as usize];
                            let (om, or) = placed[j as usize];
                            let close =
                                (o.position - inst.position).length() <= TREE_RANGE + r + or;
                            alpha
                                .get(o.species as usize)
                                .filter(|_| close)
                                .map(|a| (&a.tree, om))
                        })
                        .collect();
                    let (opacity, mean_opacity) = bake_corners(
                        raster,
                        &model.tree_bounds,
                        m,
                        &occluders,
                        Some(&world.terrain),
                    );
                    Ok(VcmSet {
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
        progress(done, "tree VCMs");
    }
    Ok(out)
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

    #[test]
    fn halving_averages_blocks() {
        let img = [
            0.0, 1.0, 0.0, 1.0, 1.0, 1.0, 0.0, 0.0, 0.5, 0.5, 1.0, 1.0, 0.5, 0.5, 1.0, 1.0,
        ];
        assert_eq!(halve(&img, 4), vec![0.75, 0.25, 0.5, 1.0]);
    }
}
