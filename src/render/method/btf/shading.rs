//! VCM shading at render time (Meyer 2001, §5.2 and Algorithm 6.1's `Calcul_Ombre`). When
//! the sun moves, every tree instance's 8 cube maps are read once in the sun's direction.
//! The finer levels' cube maps are species data, read per drawn tree in the sun's direction
//! in their own parent's frame (a main branch's in the tree frame, a twig's in its main
//! branch's frame), since each instance turns the species' tree differently.
//!
//! A billboard gets its own level's 8 corner factors, interpolated trilinearly per pixel in
//! the shader, and the product of the levels above it evaluated once at its centre: a twig
//! billboard b(p)·c(centre)·d(centre), a main-branch billboard c(p)·d(centre), a tree
//! billboard d(p). (The thesis interpolated all of them at the 4 billboard vertices; inside
//! one billboard the coarser levels vary little, its own level most.) The same products of
//! the cube maps' mean visibility (1 − mean opacity) weight the sky term.
//!
//! Over 800 lines: its tests are the last 380 (the reads against their decoded bytes and the
//! checks of every set against the scene belong beside the reader they test).
//!
//! Tree-level cube maps come one set per tree, or one per forest cell
//! ([`crate::vcm::cells`]): then a tree's 8 corner factors are the cell's cube maps read
//! at the tree's corners (trilinearly), times the sun ray from each corner through the
//! billboards of the trees sharing its cell.
//!
//! Over 800 lines, about a third of them its tests: the cube maps' loading and checks,
//! their reads (a byte a texel, or BC4 blocks as stored), the per-level reads and the cell
//! variant share one set of types.

use glam::{Mat3, Mat4, Vec3};
use rayon::prelude::*;

use crate::format::{Baked, VCM_CELL_SPECIES};
use crate::model::mesh::Aabb;
use crate::model::{Level, PerLevel, World};
use crate::vcm::billboard::{AlphaSet, Billboard};
use crate::vcm::cells::ForestCells;
use crate::vcm::{self, CORNERS, FACES};
use crate::{Error, Result};

/// One object's 8 cube maps and the sky visibility at its corners.
struct ObjectVcm {
    opacity: Maps,
    sky: [f32; CORNERS],
}

/// An object's 8 cube maps, corner by corner: a byte a texel, or each face's BC4 blocks as
/// the bake stored them (the tree level's and the forest cells', read only when the sun
/// moves: half the bytes, the same values).
enum Maps {
    R8(Vec<u8>),
    Bc4(Vec<u8>),
}

impl Maps {
    fn bytes(&self) -> u64 {
        match self {
            Maps::R8(b) | Maps::Bc4(b) => b.len() as u64,
        }
    }
}

/// The tree-level cube maps of a forest laid out in cells, and what a tree needs to read
/// them: its corners in the world, and its cell mates' billboards.
struct CellShading {
    cells: ForestCells,
    res: u32,
    maps: Vec<ObjectVcm>,
    /// Per species: the tree level's sky-lit images as occluders.
    alpha: Vec<AlphaSet>,
    /// Per tree: its placement, and its box's 8 corners in the world (kept above the
    /// terrain as the bake keeps cube maps).
    trees: Vec<(u32, Mat4, [Vec3; CORNERS])>,
}

impl CellShading {
    /// Sun visibility at every tree's 8 corners: the cell's cube maps read trilinearly,
    /// times the sun ray through the cell mates' billboards. A cell mate is drawn as its
    /// billboard seen along the sun's direction (its shadow's outline; the cube bake turns
    /// each billboard to the cube's centre, which for a tree in the sun's direction is
    /// nearly the same view), so its 3 views' blend is found once per tree, not per ray.
    fn direct(&self, to_sun: Vec3, out: &mut [[f32; CORNERS]]) {
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
    fn sky(&self) -> Vec<[f32; CORNERS]> {
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

/// The same as [`vcm::sample`] for a cube map stored as each face's BC4 blocks (`6 *
/// bc4_bytes(res, res)` bytes, as the bake writes them): the texels read are decoded from
/// their blocks, so the map stays at half a byte a texel.
fn sample_bc4(blocks: &[u8], res: u32, dir: Vec3) -> f32 {
    use crate::format::bc;
    let face_bytes = bc::bc4_bytes(res, res) as usize;
    if blocks.len() < FACES * face_bytes {
        return 0.0;
    }
    let along = bc::blocks_along(res) as usize;
    // The 4 texels of a bilinear read fall in 1 to 4 blocks: each is decoded once.
    let mut last: Option<(usize, [u8; 16])> = None;
    vcm::sample_with(res, dir, |face, i, j| {
        let at = face * face_bytes + ((j / 4) * along + i / 4) * bc::BC4_BLOCK_BYTES;
        let texels = match last {
            Some((a, t)) if a == at => t,
            _ => {
                let t = bc::decode_bc4_block(&blocks[at..at + bc::BC4_BLOCK_BYTES]);
                last = Some((at, t));
                t
            }
        };
        texels[(j % 4) * 4 + i % 4]
    })
}

impl ObjectVcm {
    /// Sun visibility (1 − opacity) at the 8 corners for `to_sun` in the cube maps' frame.
    fn direct(&self, res: u32, to_sun: Vec3) -> [f32; CORNERS] {
        let read = |maps: &[u8], n: usize, sample: fn(&[u8], u32, Vec3) -> f32| {
            std::array::from_fn(|k| {
                maps.get(k * n..(k + 1) * n)
                    .map_or(1.0, |m| 1.0 - sample(m, res, to_sun))
            })
        };
        match &self.opacity {
            Maps::R8(m) => read(m, FACES * (res * res) as usize, vcm::sample),
            Maps::Bc4(b) => read(
                b,
                FACES * crate::format::bc::bc4_bytes(res, res) as usize,
                sample_bc4,
            ),
        }
    }

    /// The 8 maps a byte a texel.
    fn r8(&self, res: u32) -> std::borrow::Cow<'_, [u8]> {
        use crate::format::bc;
        match &self.opacity {
            Maps::R8(m) => std::borrow::Cow::Borrowed(m),
            Maps::Bc4(b) => std::borrow::Cow::Owned(
                b.chunks_exact(bc::bc4_bytes(res, res).max(1) as usize)
                    .flat_map(|face| bc::decode_bc4(face, res, res).unwrap_or_default())
                    .collect(),
            ),
        }
    }
}

/// One object's 8 cube maps' bytes (a byte a texel) and its sky visibility at its corners.
pub(super) type ObjectMaps<'a> = (std::borrow::Cow<'a, [u8]>, [f32; CORNERS]);

/// The factors one billboard is shaded with.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Shade {
    /// Sun visibility of the billboard's own object at its 8 box corners.
    pub direct: [f32; CORNERS],
    /// Sky visibility of the same corners.
    pub sky: [f32; CORNERS],
    /// Product of the coarser levels' sun visibility at the billboard's centre.
    pub parent_direct: f32,
    /// Product of the coarser levels' sky visibility at the billboard's centre.
    pub parent_sky: f32,
}

impl Shade {
    /// No shading: every factor 1.
    pub const NONE: Shade = Shade {
        direct: [1.0; CORNERS],
        sky: [1.0; CORNERS],
        parent_direct: 1.0,
        parent_sky: 1.0,
    };

    /// The same sun factors with the sky left unhidden.
    pub fn without_sky(self) -> Shade {
        Shade {
            sky: [1.0; CORNERS],
            parent_sky: 1.0,
            ..self
        }
    }

    /// The sun factor at box coordinates `u` of the billboard's own object.
    pub fn direct_at(&self, u: Vec3) -> f32 {
        vcm::trilinear(&self.direct, u) * self.parent_direct
    }
}

/// A level's factors at one point: (sun, sky).
pub type Factors = ([f32; CORNERS], [f32; CORNERS]);

fn at(f: &Factors, bounds: &Aabb, p: Vec3) -> (f32, f32) {
    let u = vcm::box_coords(bounds, p);
    (vcm::trilinear(&f.0, u), vcm::trilinear(&f.1, u))
}

/// Every VCM of a scene, ready to be read in the sun's direction.
pub struct VcmShading {
    res: u32,
    /// Per species: main branches, then twigs (the reference branch's, then the trunk's).
    branches: Vec<Vec<ObjectVcm>>,
    twigs: Vec<Vec<ObjectVcm>>,
    /// Per tree instance, when the bake made one set per tree.
    trees: Vec<ObjectVcm>,
    /// When the bake made one set per forest cell instead.
    cells: Option<CellShading>,
    /// Per tree instance: sun visibility at its corners, for `sun`.
    tree_direct: Vec<[f32; CORNERS]>,
    /// Per tree instance: sky visibility at its corners.
    tree_sky: Vec<[f32; CORNERS]>,
    sun: Option<Vec3>,
    /// Bytes of cube-map data held (in main memory, as in the thesis; never on the GPU).
    pub bytes: u64,
}

impl VcmShading {
    /// The cube maps of `baked`, checked against `world`: every tree instance, main branch
    /// and twig needs its set. None when the bake holds no cube maps at all.
    pub fn new(baked: &Baked, world: &World) -> Result<Option<Self>> {
        if baked.vcm.is_empty() {
            return Ok(None);
        }
        let res = baked.settings.vcm_resolution;
        let bad = |m: String| {
            Error::BadInput(format!(
                "baked visibility cube maps do not fit the scene: {m}; re-bake with `canopy bake`"
            ))
        };
        let mut branches: Vec<Vec<Option<ObjectVcm>>> = world
            .species
            .iter()
            .map(|t| (0..t.tree_branches.len()).map(|_| None).collect())
            .collect();
        let mut twigs: Vec<Vec<Option<ObjectVcm>>> = world
            .species
            .iter()
            .map(|t| {
                (0..t.branch_twigs.len() + t.tree_twigs.len())
                    .map(|_| None)
                    .collect()
            })
            .collect();
        let mut trees: Vec<Option<ObjectVcm>> =
            (0..world.forest.instances.len()).map(|_| None).collect();
        let cell_sets = baked
            .vcm
            .iter()
            .any(|s| s.species == VCM_CELL_SPECIES && s.level == Level::Tree);
        let cells = cell_sets.then(|| ForestCells::new(world));
        let mut cell_maps: Vec<Option<ObjectVcm>> = (0..cells.as_ref().map_or(0, ForestCells::len))
            .map(|_| None)
            .collect();
        let mut cell_res = None;
        let mut bytes = 0u64;
        // BC4 sets stay as stored: a read decodes the blocks it falls in. The GPU's tables
        // get the finer levels' maps a byte a texel, decoded when they are made
        // (`species_maps`).
        let maps =
            |set: &crate::format::VcmSet| {
                if set.encoding == crate::format::MapEncoding::Bc4
                    && set.expected_opacity_len() == Some(set.opacity.len() as u64)
                {
                    return Ok(Maps::Bc4(set.opacity.clone()));
                }
                set.opacity_r8().map(|o| Maps::R8(o.into_owned())).ok_or_else(|| {
                bad(format!(
                    "the cube maps of {} {} hold {} bytes, not what resolution {} in {:?} has",
                    set.level.name(),
                    set.owner,
                    set.opacity.len(),
                    set.resolution,
                    set.encoding
                ))
            })
            };
        for set in &baked.vcm {
            if set.species == VCM_CELL_SPECIES && set.level == Level::Tree {
                if *cell_res.get_or_insert(set.resolution) != set.resolution {
                    return Err(bad(format!(
                        "forest cells have cube maps of resolutions {} and {}",
                        cell_res.unwrap_or_default(),
                        set.resolution
                    )));
                }
                let o = set.owner as usize;
                let Some(slot) = cell_maps.get_mut(o) else {
                    return Err(bad(format!(
                        "no forest cell {o} in this scene ({} cells)",
                        cell_maps.len()
                    )));
                };
                if slot.is_some() {
                    return Err(bad(format!("forest cell {o} has two sets")));
                }
                let opacity = maps(set)?;
                bytes += opacity.bytes();
                *slot = Some(ObjectVcm {
                    opacity,
                    sky: set.mean_opacity.map(|m| 1.0 - m),
                });
                continue;
            }
            if set.resolution != res {
                return Err(bad(format!(
                    "a set has resolution {} but the file says {res}",
                    set.resolution
                )));
            }
            let sp = set.species as usize;
            let o = set.owner as usize;
            let slot = match set.level {
                Level::Tree => trees
                    .get_mut(o)
                    .filter(|_| world.forest.instances[o].species == set.species),
                Level::Branch => branches.get_mut(sp).and_then(|v| v.get_mut(o)),
                Level::Twig => twigs.get_mut(sp).and_then(|v| v.get_mut(o)),
            };
            let Some(slot) = slot else {
                return Err(bad(format!(
                    "no {} {o} of species {sp} in this scene",
                    set.level.name()
                )));
            };
            if slot.is_some() {
                return Err(bad(format!(
                    "the {} {o} of species {sp} has two sets",
                    set.level.name()
                )));
            }
            let opacity = maps(set)?;
            bytes += opacity.bytes();
            *slot = Some(ObjectVcm {
                opacity,
                sky: set.mean_opacity.map(|m| 1.0 - m),
            });
        }
        let missing = |what: &str| bad(format!("the {what} has no cube maps"));
        let take_all = |v: Vec<Option<ObjectVcm>>, what: &str| {
            v.into_iter()
                .map(|o| o.ok_or_else(|| missing(what)))
                .collect::<Result<Vec<_>>>()
        };
        let (trees, cells) = match cells {
            None => (take_all(trees, "tree")?, None),
            Some(cells) => {
                if let Some(t) = trees.iter().position(Option::is_some) {
                    return Err(bad(format!(
                        "tree {t} has its own cube maps and the forest cells too"
                    )));
                }
                let maps = take_all(cell_maps, "forest cell")?;
                let alpha = (0..world.species.len())
                    .map(|s| {
                        let set = baked
                            .btf
                            .iter()
                            .find(|b| b.species as usize == s && b.level == Level::Tree)
                            .ok_or_else(|| {
                                bad(format!("species {s} has no tree-level BTF images"))
                            })?;
                        AlphaSet::new(set)
                    })
                    .collect::<Result<Vec<_>>>()?;
                let tree_corners = (0..world.forest.instances.len())
                    .map(|t| {
                        let inst = &world.forest.instances[t];
                        let m = inst.transform();
                        let bounds = world
                            .species
                            .get(inst.species as usize)
                            .ok_or_else(|| bad(format!("tree {t} has no species")))?
                            .tree_bounds;
                        let corners = std::array::from_fn(|k| {
                            let mut p = m.transform_point3(vcm::corner(&bounds, k));
                            p.y =
                                p.y.max(world.terrain.height_at(p.x, p.z) + vcm::GROUND_CLEARANCE);
                            p
                        });
                        Ok((inst.species, m, corners))
                    })
                    .collect::<Result<Vec<_>>>()?;
                (
                    Vec::new(),
                    Some(CellShading {
                        cells,
                        res: cell_res.unwrap_or(res),
                        maps,
                        alpha,
                        trees: tree_corners,
                    }),
                )
            }
        };
        let branches = branches
            .into_iter()
            .map(|v| take_all(v, "main branch"))
            .collect::<Result<Vec<_>>>()?;
        let twigs = twigs
            .into_iter()
            .map(|v| take_all(v, "twig"))
            .collect::<Result<Vec<_>>>()?;
        let tree_count = world.forest.instances.len();
        let tree_sky = match &cells {
            Some(c) => c.sky(),
            None => trees.iter().map(|t| t.sky).collect(),
        };
        Ok(Some(Self {
            res,
            tree_direct: vec![[1.0; CORNERS]; tree_count],
            tree_sky,
            branches,
            twigs,
            trees,
            cells,
            sun: None,
            bytes,
        }))
    }

    pub fn resolution(&self) -> u32 {
        self.res
    }

    /// Species `sp`'s cube maps for the GPU: per main branch, then per twig (the reference
    /// branch's, then the trunk's), its 8 maps' bytes (`8 × 6 × res²`, corner by corner)
    /// and its sky visibility at the corners.
    pub(super) fn species_maps(&self, sp: usize) -> [Vec<ObjectMaps<'_>>; 2] {
        fn objects(v: Option<&Vec<ObjectVcm>>, res: u32) -> Vec<ObjectMaps<'_>> {
            v.map_or(Vec::new(), |v| {
                v.iter().map(|o| (o.r8(res), o.sky)).collect()
            })
        }
        [
            objects(self.branches.get(sp), self.res),
            objects(self.twigs.get(sp), self.res),
        ]
    }

    /// Reads every tree instance's cube maps in the direction `to_sun` (world) if the sun
    /// moved. Returns whether it did.
    pub fn set_sun(&mut self, to_sun: Vec3) -> bool {
        if self.sun == Some(to_sun) {
            return false;
        }
        let res = self.res;
        match &self.cells {
            Some(cells) => cells.direct(to_sun, &mut self.tree_direct),
            None => {
                for (d, t) in self.tree_direct.iter_mut().zip(&self.trees) {
                    *d = t.direct(res, to_sun);
                }
            }
        }
        self.sun = Some(to_sun);
        true
    }

    /// Tree instance `t`'s factors for the current sun.
    fn tree(&self, t: usize) -> Factors {
        match (self.tree_direct.get(t), self.tree_sky.get(t)) {
            (Some(d), Some(sky)) => (*d, *sky),
            _ => ([1.0; CORNERS], [1.0; CORNERS]),
        }
    }

    /// Every tree instance's tree-level factors (sun, sky) at its box corners, for the sun
    /// of the last [`Self::set_sun`], in instance order (`count` of them; 1 for an instance
    /// the cube maps do not cover).
    pub fn tree_factors(&self, count: usize) -> impl Iterator<Item = Factors> + '_ {
        (0..count).map(|t| self.tree(t))
    }

    /// The sun the cube maps were last read for.
    pub fn sun(&self) -> Option<Vec3> {
        self.sun
    }

    /// The shading of every billboard of one tree instance, at each level.
    pub fn for_tree<'a>(
        &'a self,
        t: usize,
        species: usize,
        model: &'a Mat4,
        frames: &'a PerLevel<ObjectFrame>,
    ) -> TreeShading<'a> {
        let scale = model.x_axis.truncate().length().max(1e-12);
        let rot = Mat3::from_mat4(*model) * (1.0 / scale);
        let sun = self.sun.unwrap_or(Vec3::Y);
        TreeShading {
            vcm: self,
            species,
            tree: self.tree(t),
            sun_tree: (rot.transpose() * sun).normalize_or(Vec3::Y),
            frames,
        }
    }
}

/// One level's object in its own frame: its bounds (the VCM box) and its billboard centre.
#[derive(Clone, Copy, Debug)]
pub struct ObjectFrame {
    pub bounds: Aabb,
    pub center: Vec3,
}

/// The shading of one tree instance's billboards.
pub struct TreeShading<'a> {
    vcm: &'a VcmShading,
    species: usize,
    tree: Factors,
    sun_tree: Vec3,
    frames: &'a PerLevel<ObjectFrame>,
}

impl TreeShading<'_> {
    /// The tree billboard: d per pixel.
    pub fn tree(&self) -> Shade {
        Shade {
            direct: self.tree.0,
            sky: self.tree.1,
            parent_direct: 1.0,
            parent_sky: 1.0,
        }
    }

    fn branch_factors(&self, i: usize) -> Factors {
        self.vcm
            .branches
            .get(self.species)
            .and_then(|v| v.get(i))
            .map_or(([1.0; CORNERS], [1.0; CORNERS]), |o| {
                (o.direct(self.vcm.res, self.sun_tree), o.sky)
            })
    }

    fn twig_factors(&self, j: usize, sun: Vec3) -> Factors {
        self.vcm
            .twigs
            .get(self.species)
            .and_then(|v| v.get(j))
            .map_or(([1.0; CORNERS], [1.0; CORNERS]), |o| {
                (o.direct(self.vcm.res, sun), o.sky)
            })
    }

    /// Main branch `i` (placed by `branch` in the tree frame): c per pixel, d at its centre.
    pub fn branch(&self, i: usize, branch: &Mat4) -> Shade {
        let c = self.branch_factors(i);
        let centre = branch.transform_point3(self.frames.branch.center);
        let (d, d_sky) = at(&self.tree, &self.frames.tree.bounds, centre);
        Shade {
            direct: c.0,
            sky: c.1,
            parent_direct: d,
            parent_sky: d_sky,
        }
    }

    /// The trunk's twig `k` (placed by `twig` in the tree frame; twig VCM `index`): b per
    /// pixel, d at its centre.
    pub fn trunk_twig(&self, index: usize, twig: &Mat4) -> Shade {
        let b = self.twig_factors(index, self.sun_tree);
        let centre = twig.transform_point3(self.frames.twig.center);
        let (d, d_sky) = at(&self.tree, &self.frames.tree.bounds, centre);
        Shade {
            direct: b.0,
            sky: b.1,
            parent_direct: d,
            parent_sky: d_sky,
        }
    }

    /// The twigs of main branch `i`: calls `emit(j, shade)` for each twig `j` of `twigs`
    /// (their transforms in the branch frame): b per pixel, c·d at its centre.
    pub fn branch_twigs(
        &self,
        i: usize,
        branch: &Mat4,
        twigs: &[Mat4],
        mut emit: impl FnMut(usize, Shade),
    ) {
        let c = self.branch_factors(i);
        let scale = branch.x_axis.truncate().length().max(1e-12);
        let rot = Mat3::from_mat4(*branch) * (1.0 / scale);
        let sun_branch = (rot.transpose() * self.sun_tree).normalize_or(Vec3::Y);
        for (j, t) in twigs.iter().enumerate() {
            let b = self.twig_factors(j, sun_branch);
            let in_branch = t.transform_point3(self.frames.twig.center);
            let (cc, c_sky) = at(&c, &self.frames.branch.bounds, in_branch);
            let (d, d_sky) = at(
                &self.tree,
                &self.frames.tree.bounds,
                branch.transform_point3(in_branch),
            );
            emit(
                j,
                Shade {
                    direct: b.0,
                    sky: b.1,
                    parent_direct: cc * d,
                    parent_sky: c_sky * d_sky,
                },
            );
        }
    }
}

#[cfg(test)]
impl VcmShading {
    /// Cube maps of pseudo-random opacity at face resolution `res`, per species for
    /// `objects[sp]` = (main branches, twigs) and for `trees` tree instances, each object's
    /// sky visibility pseudo-random too (for tests of code that reads them).
    pub(crate) fn synthetic(res: u32, objects: &[(usize, usize)], trees: usize) -> Self {
        let mut rng = 0x2545_f491u32;
        let mut object = || {
            let opacity = (0..CORNERS * FACES * (res * res) as usize)
                .map(|_| {
                    rng ^= rng << 13;
                    rng ^= rng >> 17;
                    rng ^= rng << 5;
                    (rng >> 24) as u8
                })
                .collect();
            let sky = std::array::from_fn(|k| 0.3 + 0.08 * k as f32);
            ObjectVcm {
                opacity: Maps::R8(opacity),
                sky,
            }
        };
        let branches = objects
            .iter()
            .map(|&(b, _)| (0..b).map(|_| object()).collect())
            .collect();
        let twigs = objects
            .iter()
            .map(|&(_, t)| (0..t).map(|_| object()).collect())
            .collect();
        let trees: Vec<ObjectVcm> = (0..trees).map(|_| object()).collect();
        Self {
            res,
            tree_direct: vec![[1.0; CORNERS]; trees.len()],
            tree_sky: trees.iter().map(|t| t.sky).collect(),
            branches,
            twigs,
            trees,
            cells: None,
            sun: None,
            bytes: 0,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_bc4_cube_map_reads_as_its_decoded_bytes() {
        use crate::format::bc;
        for res in [4u32, 8, 16, 6] {
            let n = (res * res) as usize;
            let faces: Vec<Vec<u8>> = (0..FACES)
                .map(|f| {
                    (0..n)
                        .map(|t| ((t * 37 + f * 91 + (t * t) % 17 * 11) % 256) as u8)
                        .collect()
                })
                .collect();
            let blocks: Vec<u8> = faces
                .iter()
                .flat_map(|f| bc::encode_bc4(f, res, res))
                .collect();
            let decoded: Vec<u8> = blocks
                .chunks_exact(bc::bc4_bytes(res, res) as usize)
                .flat_map(|b| bc::decode_bc4(b, res, res).unwrap())
                .collect();
            for k in 0..500 {
                let t = k as f32 * 0.61;
                let dir = Vec3::new(t.sin() * 1.3, (t * 0.7).cos(), (t * 1.9).sin() - 0.2);
                let (a, b) = (
                    vcm::sample(&decoded, res, dir),
                    sample_bc4(&blocks, res, dir),
                );
                assert_eq!(a, b, "res {res}, direction {dir}");
            }
            assert_eq!(sample_bc4(&blocks[..10], res, Vec3::X), 0.0);
        }
    }

    #[test]
    fn an_object_behind_a_wall_reads_dark_towards_it_only() {
        let res = 8;
        let mut raster = vcm::CubeRaster::new(res);
        raster.draw(
            Vec3::ZERO,
            &vcm::PlainQuad {
                center: Vec3::new(0.0, 0.0, 2.0),
                right: Vec3::X * 50.0,
                up: Vec3::Y * 50.0,
                alpha: 1.0,
            },
        );
        let mut one = Vec::new();
        raster.finish(&mut one, false);
        let opacity: Vec<u8> = (0..CORNERS).flat_map(|_| one.iter().copied()).collect();
        let o = ObjectVcm {
            opacity: Maps::R8(opacity),
            sky: [0.5; CORNERS],
        };
        assert_eq!(o.direct(res, Vec3::Z), [0.0; CORNERS]);
        assert_eq!(o.direct(res, -Vec3::Z), [1.0; CORNERS]);
    }

    fn lone_world() -> World {
        let mut scene =
            crate::scene::Scene::parse(crate::scene::SMALL_TEST_SCENE_TOML, "small.toml").unwrap();
        scene.forest.count = Some(1);
        scene.build_world().unwrap()
    }

    fn set(species: u32, owner: u32, level: Level) -> crate::format::VcmSet {
        crate::format::VcmSet {
            species,
            owner,
            level,
            encoding: crate::format::MapEncoding::R8,
            resolution: 8,
            opacity: vec![0; CORNERS * FACES * 64],
            mean_opacity: [0.0; CORNERS],
        }
    }

    fn baked(vcm: Vec<crate::format::VcmSet>) -> Baked {
        Baked {
            scene_hash: 0,
            settings: crate::format::BakeSettings {
                views: 6,
                tree_views: 6,
                lights: 6,
                resolution: 32,
                supersample: 1,
                vcm_resolution: 8,
                texel_resolution: 0,
                impostor_frames: 0,
                impostor_resolution: 64,
                impostor_layout: Default::default(),
                compress: false,
            },
            btf: Vec::new(),
            vcm,
            texels: Vec::new(),
            impostors: Vec::new(),
        }
    }

    /// Every set the world needs, for species `sp`'s tree at instance 0.
    fn complete(world: &World) -> Vec<crate::format::VcmSet> {
        let sp = world.forest.instances[0].species;
        let mut v = vec![set(sp, 0, Level::Tree)];
        for (s, t) in world.species.iter().enumerate() {
            let s = s as u32;
            v.extend((0..t.tree_branches.len() as u32).map(|i| set(s, i, Level::Branch)));
            let twigs = (t.branch_twigs.len() + t.tree_twigs.len()) as u32;
            v.extend((0..twigs).map(|i| set(s, i, Level::Twig)));
        }
        v
    }

    #[test]
    fn bc4_maps_are_kept_as_stored_and_read_as_their_decoded_bytes() {
        let world = lone_world();
        let mut bc4 = complete(&world);
        for (i, s) in bc4.iter_mut().enumerate() {
            for (t, o) in s.opacity.iter_mut().enumerate() {
                *o = ((t * 31 + i * 7 + (t / 64) * 50) % 256) as u8;
            }
            crate::format::bc::compress_vcm(s);
        }
        let decoded: Vec<crate::format::VcmSet> = bc4
            .iter()
            .map(|s| crate::format::VcmSet {
                encoding: crate::format::MapEncoding::R8,
                opacity: s.opacity_r8().unwrap().into_owned(),
                ..s.clone()
            })
            .collect();
        let r8: u64 = decoded.iter().map(|s| s.opacity.len() as u64).sum();
        let mut from_bc4 = VcmShading::new(&baked(bc4), &world).unwrap().unwrap();
        let mut from_r8 = VcmShading::new(&baked(decoded), &world).unwrap().unwrap();
        // Every level's maps stay BC4: half a byte a texel.
        assert_eq!(from_r8.bytes - from_bc4.bytes, r8 / 2);
        assert!(matches!(from_bc4.trees[0].opacity, Maps::Bc4(_)));
        assert!(matches!(from_bc4.branches[0][0].opacity, Maps::Bc4(_)));
        assert!(matches!(from_bc4.twigs[0][0].opacity, Maps::Bc4(_)));
        for sun in [
            Vec3::Y,
            Vec3::new(0.3, 0.8, -0.5),
            Vec3::new(-0.9, 0.2, 0.1),
        ] {
            from_bc4.set_sun(sun.normalize());
            from_r8.set_sun(sun.normalize());
            let a: Vec<Factors> = from_bc4.tree_factors(1).collect();
            let b: Vec<Factors> = from_r8.tree_factors(1).collect();
            assert_eq!(a, b);
            assert!(a[0].0.iter().any(|&v| v < 0.99), "{a:?}");
            for (x, y) in [
                (&from_bc4.branches[0], &from_r8.branches[0]),
                (&from_bc4.twigs[0], &from_r8.twigs[0]),
            ] {
                for (o, p) in x.iter().zip(y) {
                    assert_eq!(o.direct(8, sun.normalize()), p.direct(8, sun.normalize()));
                }
            }
        }
        for sp in 0..world.species.len() {
            let (a, b) = (from_bc4.species_maps(sp), from_r8.species_maps(sp));
            assert_eq!(a, b);
        }
    }

    #[test]
    fn cube_maps_that_do_not_fit_the_scene_are_refused() {
        let world = lone_world();
        let good = complete(&world);
        assert!(
            VcmShading::new(&baked(good.clone()), &world)
                .unwrap()
                .is_some()
        );
        assert!(
            VcmShading::new(&baked(Vec::new()), &world)
                .unwrap()
                .is_none()
        );
        let mut extra = good.clone();
        extra.push(set(0, 7, Level::Tree));
        let mut missing = good.clone();
        missing.remove(0);
        let mut twice = good.clone();
        twice.push(good[1].clone());
        for (v, want) in [
            (extra, "tree 7"),
            (missing, "no cube maps"),
            (twice, "two sets"),
        ] {
            let e = VcmShading::new(&baked(v), &world)
                .err()
                .map(|e| e.to_string())
                .unwrap_or_default();
            assert!(e.contains(want) && e.contains("re-bake"), "{e}");
        }
    }

    #[test]
    fn forest_cell_sets_that_do_not_fit_the_scene_are_refused() {
        let world = lone_world();
        let cells = ForestCells::new(&world).len() as u32;
        assert_eq!(cells, 1);
        let species_sets = || -> Vec<crate::format::VcmSet> { complete(&world)[1..].to_vec() };
        let cell = |owner: u32| crate::format::VcmSet {
            species: VCM_CELL_SPECIES,
            ..set(0, owner, Level::Tree)
        };
        let with = |extra: Vec<crate::format::VcmSet>| {
            let mut v = species_sets();
            v.extend(extra);
            VcmShading::new(&baked(v), &world)
                .err()
                .map(|e| e.to_string())
                .unwrap_or_default()
        };
        for (v, want) in [
            (vec![cell(0), cell(1)], "no forest cell 1"),
            (vec![cell(0), cell(0)], "forest cell 0 has two sets"),
            (
                vec![
                    cell(0),
                    set(world.forest.instances[0].species, 0, Level::Tree),
                ],
                "its own cube maps and the forest cells too",
            ),
            // A complete set, but no tree-level BTF images to draw the cell mates with.
            (vec![cell(0)], "no tree-level BTF images"),
        ] {
            let e = with(v);
            assert!(e.contains(want) && e.contains("re-bake"), "{want}: {e}");
        }
    }

    /// Two trees of one species in one forest cell, 16 m apart along x, with cube maps that
    /// see nothing and tree-level images of opaque discs: only the cell mate can shade.
    #[test]
    fn a_cell_mate_shades_a_tree_towards_the_sun_only() {
        let mut world = lone_world();
        let first = world.forest.instances[0];
        // The second 16 m east of the first (their boxes apart), or west where east is
        // another cell.
        let mut east = 1.0;
        for e in [1.0, -1.0] {
            let second = crate::model::TreeInstance {
                position: first.position + Vec3::new(16.0 * e, 0.0, 0.0),
                ..first
            };
            world.forest.instances = vec![first, second];
            east = e;
            if ForestCells::new(&world).len() == 1 {
                break;
            }
        }
        assert_eq!(ForestCells::new(&world).len(), 1, "both trees in one cell");
        let sp = first.species;
        let b = world.species[sp as usize].tree_bounds;
        let image = (32 * 32 * 4) as usize;
        // Every view an opaque disc of 0.4 the image's side across (a crown's outline).
        let mut ambient = vec![0u8; 2 * 6 * image];
        for (i, px) in ambient.chunks_exact_mut(4).enumerate() {
            let (x, y) = ((i % 32) as f32 - 15.5, ((i / 32) % 32) as f32 - 15.5);
            if x * x + y * y < 12.8 * 12.8 {
                px[3] = 255;
            }
        }
        let mut v = complete(&world)[1..].to_vec();
        v.push(crate::format::VcmSet {
            species: VCM_CELL_SPECIES,
            ..set(0, 0, Level::Tree)
        });
        let mut bake = baked(v);
        for (s, t) in world.species.iter().enumerate() {
            let b = t.tree_bounds;
            bake.btf.push(crate::format::BtfImageSet {
                species: s as u32,
                level: Level::Tree,
                encoding: crate::format::ImageEncoding::Rgba8,
                views: 6,
                lights: 6,
                resolution: 32,
                center: (0.5 * (b.min + b.max)).to_array(),
                radius: 0.5 * (b.max - b.min).length(),
                texel_size: 0.1,
                direct: vec![0; 36 * image],
                ambient: ambient.clone(),
            });
        }
        let mut shading = VcmShading::new(&bake, &world).unwrap().unwrap();
        let frames = PerLevel {
            twig: ObjectFrame {
                bounds: b,
                center: Vec3::ZERO,
            },
            branch: ObjectFrame {
                bounds: b,
                center: Vec3::ZERO,
            },
            tree: ObjectFrame {
                bounds: b,
                center: Vec3::ZERO,
            },
        };
        let lit = |shading: &VcmShading, t: usize| -> f32 {
            let m = world.forest.instances[t].transform();
            let s = shading.for_tree(t, sp as usize, &m, &frames).tree();
            s.direct.iter().sum::<f32>() / CORNERS as f32
        };
        // The sun low towards the second tree: the first tree's corners look through it.
        shading.set_sun(Vec3::new(east, 0.15, 0.0).normalize());
        let (a, b2) = (lit(&shading, 0), lit(&shading, 1));
        assert!(a < 0.8, "the tree behind its cell mate: {a}");
        assert!(b2 > 0.99, "the tree in front: {b2}");
        // The sun on the other side: the other way round.
        shading.set_sun(Vec3::new(-east, 0.15, 0.0).normalize());
        let (a, b2) = (lit(&shading, 0), lit(&shading, 1));
        assert!(a > 0.99 && b2 < 0.8, "{a} {b2}");
        // Straight above: at most the one corner of each box that reaches under the
        // other's crown.
        shading.set_sun(Vec3::Y);
        assert!(lit(&shading, 0) >= 0.85 && lit(&shading, 1) >= 0.85);
        // The sky: each hides a share of the other's.
        let sky = |t: usize| shading.tree_sky[t].iter().sum::<f32>() / CORNERS as f32;
        assert!(sky(0) < 0.99 && sky(1) < 0.99, "{} {}", sky(0), sky(1));
    }

    #[test]
    fn no_shading_is_one_everywhere() {
        assert_eq!(Shade::NONE.direct_at(Vec3::splat(0.3)), 1.0);
    }
}
