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
//!
//! Tree-level cube maps come one set per tree, or one per forest cell
//! ([`crate::vcm::cells`]): then a tree's 8 corner factors are the cell's cube maps read
//! at the tree's corners (trilinearly), times the sun ray from each corner through the
//! billboards of the trees sharing its cell.
//!
//! The cube maps as held and their reads are in `maps.rs`, the forest cells' variant in
//! `cells.rs`, their loading and checks against the scene in `load.rs`.

use glam::{Mat3, Mat4, Vec3};

use crate::model::PerLevel;
use crate::model::mesh::Aabb;
use crate::vcm::{self, CORNERS};

mod cells;
mod load;
mod maps;
#[cfg(test)]
mod tests;

use cells::CellShading;
use maps::ObjectVcm;

/// One object's 8 cube maps' bytes (a byte a texel) and its sky visibility at its corners.
pub(crate) type ObjectMaps<'a> = (std::borrow::Cow<'a, [u8]>, [f32; CORNERS]);

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

/// Where a method finds a tree's visibility cube map factors for the current sun without
/// knowing who holds them (the bake's BTF scene does).
pub trait TreeShades {
    /// Tree instance `t` (of `species`, placed by `model`): its tree-level factors at the 8
    /// corners of its species' tree box, and that box in the object frame; None without
    /// visibility cube maps.
    fn tree_shade(&self, t: usize, species: usize, model: &Mat4) -> Option<(Shade, Aabb)>;
}

/// `shade(t, species, model)`: tree `t`'s tree-level VCM factors and the box they are
/// given over (None: unshaded), as a method's CPU work asks for them.
pub type TreeShade<'a> = dyn FnMut(usize, usize, &Mat4) -> Option<(Shade, Aabb)> + 'a;

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
    pub fn resolution(&self) -> u32 {
        self.res
    }

    /// Species `sp`'s cube maps for the GPU: per main branch, then per twig (the reference
    /// branch's, then the trunk's), its 8 maps' bytes (`8 × 6 × res²`, corner by corner)
    /// and its sky visibility at the corners.
    pub(crate) fn species_maps(&self, sp: usize) -> [Vec<ObjectMaps<'_>>; 2] {
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
            let opacity = (0..CORNERS * vcm::FACES * (res * res) as usize)
                .map(|_| {
                    rng ^= rng << 13;
                    rng ^= rng >> 17;
                    rng ^= rng << 5;
                    (rng >> 24) as u8
                })
                .collect();
            let sky = std::array::from_fn(|k| 0.3 + 0.08 * k as f32);
            ObjectVcm {
                opacity: maps::Maps::R8(opacity),
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
