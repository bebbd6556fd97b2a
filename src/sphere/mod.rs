//! Sampled directions on the unit sphere for the BTF images, and the per-frame lookup of the 3
//! samples to blend for an arbitrary view or light direction.
//!
//! A BTF stores one image per sampled view direction (and per sampled light direction). The
//! samples are the vertices of an octahedron subdivided 0 to 3 times (6, 18, 66 or 258
//! directions). At render time a direction is located in its enclosing spherical triangle and the
//! triangle's 3 samples are blended with normalised barycentric weights: they are >= 0, sum to 1,
//! reproduce a sampled direction exactly and vary continuously with the direction.
//!
//! Lookup is O(level) and branch-free: the octant picks the level-0 triangle and every
//! subdivision level picks one of 4 children from the signs of 3 dot products with precomputed
//! great-circle normals. `blend` is latency-bound; `blend_many` interleaves several directions
//! and is about 3-4 times cheaper per direction, so prefer it for per-billboard work.
//!
//! Inputs need not be normalised. A zero, NaN or otherwise unusable direction is treated as +Y;
//! a direction with infinite components points along the infinite components. Nothing here panics.
//!
//! The set and its lookup tables are built in `subdivide`; `locate` finds a direction's
//! triangle and nearest sample, `blend` its weights; `gpu` lays the tables out for a copy on
//! the GPU and `billboard` holds the image axes shared by the bake and the billboards.
//! `octa` is the other way to sample directions, for octahedral impostors: a square grid
//! of frames on an octahedral map of the sphere or of its upper half.

mod billboard;
mod blend;
mod gpu;
mod locate;
mod octa;
mod subdivide;
#[cfg(test)]
mod test_support;

use glam::{Mat3A, Vec3};

pub use billboard::billboard_axes;
pub use blend::Blend;
pub use gpu::DirectionRows;
pub use octa::{Frame, FrameBlend, OctaGrid, OctaLayout};

/// Why a [`DirectionSet`] could not be built.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum SphereError {
    /// The requested number of directions is not one an octahedron subdivision produces.
    #[error(
        "unsupported direction count {count}: a direction set has 6, 18, 66 or 258 directions \
         (octahedron subdivided 0, 1, 2 or 3 times)"
    )]
    BadCount {
        /// The count that was asked for.
        count: usize,
    },
    /// The requested subdivision level is above [`DirectionSet::MAX_LEVEL`].
    #[error("unsupported subdivision level {level}: the level must be 0, 1, 2 or 3")]
    BadLevel {
        /// The level that was asked for.
        level: u32,
    },
}

/// The most [`DirectionSet::light_gain`] brightens a blend of light samples.
pub const MAX_LIGHT_GAIN: f32 = 2.0;

/// Sampled directions on the unit sphere: the vertices of an octahedron subdivided `level`
/// times (each triangle split into 4 at edge midpoints pushed onto the sphere).
/// level 0: 6 directions / 8 triangles, 1: 18 / 32, 2: 66 / 128, 3: 258 / 512.
///
/// Directions 0..6 are +X, -X, +Y, -Y, +Z, -Z in that order; each further direction is the
/// midpoint of an edge of the previous level, so the directions of level `l` are a prefix of the
/// directions of level `l + 1`.
///
/// Triangles are listed in descent order: level-0 triangle `o` is the octant with
/// `o = (x < 0) | (y < 0) << 1 | (z < 0) << 2`, and the children of triangle `t` at one level are
/// `4t..4t + 4` at the next one (corner at the first, second, third vertex, then the middle).
#[derive(Clone, Debug)]
pub struct DirectionSet {
    level: u32,
    directions: Vec<Vec3>,
    /// Triangles of the finest level, counter-clockwise seen from outside.
    triangles: Vec<[u32; 3]>,
    /// Per triangle `[A, B, C]` of the finest level, the matrix with rows `B x C, C x A, A x B`:
    /// `bary[t] * d` are the (unnormalised) barycentric coordinates of the ray through `d`.
    bary: Vec<Mat3A>,
    /// For triangle `t` of level `l < level`, at `8 * (4^l - 1) / 3 + t` (the levels one after
    /// the other, in descent order): the matrix whose rows are
    /// the normals `ca x ab, ab x bc, bc x ca` of the middle child's edges (`ab, bc, ca` are the
    /// edge midpoints). Row `i` negative means `d` lies in the corner child at vertex `i`; all
    /// three >= 0 means the middle child.
    splits: Vec<Mat3A>,
    /// Candidate samples for [`DirectionSet::nearest`] per triangle of the finest level:
    /// `near[near_start[t]..near_start[t + 1]]`, ascending (the triangle's vertices and their
    /// neighbours).
    near: Vec<u32>,
    near_start: Vec<u32>,
}

impl DirectionSet {
    /// Direction counts of levels 0, 1, 2 and 3.
    pub const COUNTS: [usize; 4] = [6, 18, 66, 258];
    /// Highest supported subdivision level.
    pub const MAX_LEVEL: u32 = 3;

    /// Number of subdivisions of the octahedron (0..=3).
    pub fn level(&self) -> u32 {
        self.level
    }

    /// Number of sampled directions.
    pub fn len(&self) -> usize {
        self.directions.len()
    }

    /// Always false: every set has at least 6 directions.
    pub fn is_empty(&self) -> bool {
        self.directions.is_empty()
    }

    /// The sampled unit directions; 0..6 are +X, -X, +Y, -Y, +Z, -Z.
    pub fn directions(&self) -> &[Vec3] {
        &self.directions
    }

    /// The spherical triangles (indices into [`Self::directions`]), counter-clockwise seen from
    /// outside, in descent order (see the type's documentation).
    pub fn triangles(&self) -> &[[u32; 3]] {
        &self.triangles
    }
}
