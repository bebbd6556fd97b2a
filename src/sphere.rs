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

use std::collections::HashMap;

use glam::{DVec3, Mat3A, Vec3, Vec3A};

/// Normalised weights below this are snapped to 0 (and the rest renormalised), so that a sampled
/// direction gets exactly weight 1 and a direction on an edge gives the opposite vertex exactly 0
/// despite rounding. The resulting jump (< 1e-6) is far below anything visible.
const SNAP: f32 = 1e-6;

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

    /// The set with `count` directions: 6, 18, 66 or 258.
    pub fn with_count(count: usize) -> Result<Self, SphereError> {
        match Self::COUNTS.iter().position(|&c| c == count) {
            Some(level) => Self::with_level(level as u32),
            None => Err(SphereError::BadCount { count }),
        }
    }

    /// The octahedron subdivided `level` times (0..=3).
    pub fn with_level(level: u32) -> Result<Self, SphereError> {
        if level > Self::MAX_LEVEL {
            return Err(SphereError::BadLevel { level });
        }
        // Directions are kept as the f32 values that get stored, widened to f64, so that every
        // derived normal is computed from exactly the stored directions.
        let mut dirs: Vec<DVec3> = vec![
            DVec3::X,
            DVec3::NEG_X,
            DVec3::Y,
            DVec3::NEG_Y,
            DVec3::Z,
            DVec3::NEG_Z,
        ];
        let mut tris: Vec<[u32; 3]> = (0..8).map(octant_triangle).collect();
        let mut midpoints: HashMap<(u32, u32), u32> = HashMap::new();
        let mut splits = Vec::new();
        for _ in 0..level {
            let mut children = Vec::with_capacity(tris.len() * 4);
            for &[a, b, c] in &tris {
                let ab = midpoint(&mut dirs, &mut midpoints, a, b);
                let bc = midpoint(&mut dirs, &mut midpoints, b, c);
                let ca = midpoint(&mut dirs, &mut midpoints, c, a);
                children.extend([[a, ab, ca], [ab, b, bc], [ca, bc, c], [ab, bc, ca]]);
                let (pab, pbc, pca) = (dirs[ab as usize], dirs[bc as usize], dirs[ca as usize]);
                splits.push(rows(
                    cross32(pca, pab),
                    cross32(pab, pbc),
                    cross32(pbc, pca),
                ));
            }
            tris = children;
        }

        let bary = tris
            .iter()
            .map(|t| {
                let [a, b, c] = t.map(|i| dirs[i as usize]);
                rows(cross32(b, c), cross32(c, a), cross32(a, b))
            })
            .collect();

        // Neighbour lists, then per triangle the union of its vertices' closed neighbourhoods.
        let mut neighbours: Vec<Vec<u32>> = vec![Vec::new(); dirs.len()];
        for t in &tris {
            for &v in t {
                neighbours[v as usize].extend_from_slice(t);
            }
        }
        let mut near = Vec::new();
        let mut near_start = Vec::with_capacity(tris.len() + 1);
        near_start.push(0);
        for t in &tris {
            let mut cand: Vec<u32> = t
                .iter()
                .flat_map(|&v| neighbours[v as usize].iter().copied())
                .collect();
            cand.sort_unstable();
            cand.dedup();
            near.extend_from_slice(&cand);
            near_start.push(near.len() as u32);
        }

        Ok(Self {
            level,
            directions: dirs.iter().map(|d| d.as_vec3()).collect(),
            triangles: tris,
            bary,
            splits,
            near,
            near_start,
        })
    }

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

    /// The 3 sample directions of the spherical triangle that contains `d` and their weights:
    /// weights >= 0, sum to 1, exactly (1,0,0) at a sample direction (the index of that sample in slot 0),
    /// continuous as `d` moves (across triangle edges too: on an edge the opposite vertex has weight 0).
    /// Use normalised barycentric coordinates of the ray through d with the triangle's plane
    /// (solve d = a*A + b*B + c*C, then divide by a+b+c).
    ///
    /// The slots are sorted by decreasing weight; the indices are always the 3 vertices of
    /// triangle [`Self::locate`]`(d)`, also those with weight 0.
    pub fn blend(&self, d: Vec3) -> Blend {
        let d = sanitize(d);
        let [t] = self.locate_lanes([d]);
        self.blend_in(t, d)
    }

    /// How much a blend of light samples must be brightened to light like `d` itself. The
    /// blend of unit directions, sum of w_i l_i, is a chord inside the sphere: shorter than
    /// `d` (down to 1/sqrt(3) of it between the 6 samples, 0.82 between the 18). Whatever
    /// responds linearly to the light direction (a diffuse or translucent leaf lit on one
    /// side by every sample) comes out of the blended images darker by that length along
    /// `d`; this is its inverse, at least 1 and at most [`MAX_LIGHT_GAIN`] (a blend culled
    /// to one far sample).
    pub fn light_gain(&self, b: &Blend, d: Vec3) -> f32 {
        let d = d.normalize_or_zero();
        let sum: Vec3 = (0..3)
            .filter_map(|i| Some(*self.directions.get(b.index[i] as usize)? * b.weight[i]))
            .sum();
        let along = sum.dot(d);
        if along > 0.0 && along.is_finite() {
            (1.0 / along).clamp(1.0, MAX_LIGHT_GAIN)
        } else {
            1.0
        }
    }

    /// [`Self::blend`] for many directions: `out[i] = self.blend(dirs[i])` for every `i` below
    /// the shorter length (the rest of `out` is left alone). Directions are processed a few at a
    /// time, interleaved, which hides most of the latency of the descent: cheaper per direction
    /// than separate calls.
    pub fn blend_many(&self, dirs: &[Vec3], out: &mut [Blend]) {
        const LANES: usize = 4;
        let n = dirs.len().min(out.len());
        let (dirs, out) = (&dirs[..n], &mut out[..n]);
        let mut dir_chunks = dirs.chunks_exact(LANES);
        let mut out_chunks = out.chunks_exact_mut(LANES);
        for (dc, oc) in (&mut dir_chunks).zip(&mut out_chunks) {
            let d: [Vec3A; LANES] = std::array::from_fn(|i| sanitize(dc[i]));
            let t = self.locate_lanes(d);
            for i in 0..LANES {
                oc[i] = self.blend_in(t[i], d[i]);
            }
        }
        for (d, o) in dir_chunks
            .remainder()
            .iter()
            .zip(out_chunks.into_remainder())
        {
            *o = self.blend(*d);
        }
    }

    /// The blend of a finite, non-zero `d` in triangle `t`.
    #[inline]
    fn blend_in(&self, t: usize, d: Vec3A) -> Blend {
        let raw = (self.bary[t] * d).max(Vec3A::ZERO);
        Blend::from_raw(self.triangles[t], raw)
    }

    /// Index of the triangle containing d, found by hierarchical descent (octant → child triangle at
    /// each subdivision level, O(level) work) — the same answer as a brute-force search over all
    /// triangles (test this on many random directions, including exactly on edges and vertices).
    ///
    /// On an edge or a vertex several triangles contain `d`; any one of them may be returned.
    pub fn locate(&self, d: Vec3) -> usize {
        let [t] = self.locate_lanes([sanitize(d)]);
        t
    }

    /// Index of the sample nearest to d (largest dot product).
    ///
    /// Ties go to the smallest index. O(1): only the samples around [`Self::locate`]`(d)` are
    /// compared.
    pub fn nearest(&self, d: Vec3) -> usize {
        let d = sanitize(d);
        let [t] = self.locate_lanes([d]);
        let (start, end) = (self.near_start[t] as usize, self.near_start[t + 1] as usize);
        let mut best = 0;
        let mut best_dot = f32::NEG_INFINITY;
        let d = Vec3::from(d);
        for &i in &self.near[start..end] {
            let dot = self.directions[i as usize].dot(d);
            if dot > best_dot {
                best_dot = dot;
                best = i as usize;
            }
        }
        best
    }

    /// The tables of [`Self::blend`] and [`Self::light_gain`] as rows of 4 words, for a copy
    /// on the GPU: the descent's split matrices (3 rows of float bits each, the levels one
    /// after the other), the finest triangles' barycentric matrices (3 rows each), the
    /// triangles (one row of indices each) and the directions (one row each; `w` unused).
    pub fn gpu_rows(&self) -> DirectionRows {
        let mat = |m: &Mat3A| {
            let t = m.transpose();
            [t.x_axis, t.y_axis, t.z_axis].map(|r| [r.x, r.y, r.z, 0.0].map(f32::to_bits))
        };
        DirectionRows {
            splits: self.splits.iter().flat_map(mat).collect(),
            bary: self.bary.iter().flat_map(mat).collect(),
            triangles: self
                .triangles
                .iter()
                .map(|t| [t[0], t[1], t[2], 0])
                .collect(),
            directions: self
                .directions
                .iter()
                .map(|d| [d.x, d.y, d.z, 0.0].map(f32::to_bits))
                .collect(),
        }
    }

    /// Descent for finite, non-zero directions, `N` at a time: the `N` dependency chains are
    /// interleaved so that the CPU can overlap them.
    #[inline]
    fn locate_lanes<const N: usize>(&self, d: [Vec3A; N]) -> [usize; N] {
        /// Child for each combination of "outside" bits, 2 bits per entry: the lowest set bit, or
        /// 3 (middle) for none. Inside the parent at most one bit is set; if rounding sets more,
        /// the lowest wins. Entries 0..8: 3, 0, 1, 0, 2, 0, 1, 0.
        const CHILD: usize = 0x1213;
        // The octant: bit 0 x < 0, bit 1 y < 0, bit 2 z < 0 (-0.0 counts as positive).
        let mut t = d.map(|d| d.cmplt(Vec3A::ZERO).bitmask() as usize);
        let mut offset = 0;
        let mut count = 8;
        // Branch-free per level: the child is unpredictable from call to call.
        for _ in 0..self.level {
            for i in 0..N {
                let m = self.splits[offset + t[i]];
                let outside = (m * d[i]).cmplt(Vec3A::ZERO).bitmask() as usize;
                t[i] = 4 * t[i] + ((CHILD >> (2 * (outside & 7))) & 3);
            }
            offset += count;
            count *= 4;
        }
        t
    }
}

/// A [`DirectionSet`]'s tables as rows of 4 words ([`DirectionSet::gpu_rows`]).
#[derive(Clone, Debug, Default)]
pub struct DirectionRows {
    pub splits: Vec<[u32; 4]>,
    pub bary: Vec<[u32; 4]>,
    pub triangles: Vec<[u32; 4]>,
    pub directions: Vec<[u32; 4]>,
}

/// Image axes of the billboard seen from `view` (a unit vector from the object towards the
/// viewer): (right, up). The bake's camera and the billboards at render time use the same
/// rule, so an image lands on its plane the way it was taken.
pub fn billboard_axes(view: Vec3) -> (Vec3, Vec3) {
    let v = view.normalize_or(Vec3::Z);
    let hint = if v.y.abs() > 0.999 { Vec3::Z } else { Vec3::Y };
    let right = hint.cross(v).normalize_or(Vec3::X);
    let up = v.cross(right).normalize_or(Vec3::Y);
    (right, up)
}

/// The samples to blend for one direction: `weight[i]` belongs to sample `index[i]`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Blend {
    /// Sample indices (into [`DirectionSet::directions`]); always valid, also where the weight is 0.
    pub index: [u32; 3],
    /// Weights, >= 0, summing to 1. [`DirectionSet::blend`] sorts them in decreasing order.
    pub weight: [f32; 3],
}

impl Blend {
    /// Drops entries whose weight is below `threshold` and renormalises the rest so they sum to 1
    /// (the thesis' image-weight culling); the largest weight always survives. Returns how many remain (1..=3).
    /// Dropped entries get weight 0 (keep their index valid).
    ///
    /// Slots are not reordered, so for a blend from [`DirectionSet::blend`] (sorted by decreasing
    /// weight) the survivors are the first `n` slots. A weight of exactly 0 is not below a
    /// threshold of 0, and when nothing is dropped the blend is left bit-for-bit unchanged.
    pub fn cull(&mut self, threshold: f32) -> usize {
        // Non-finite or negative weights count as 0.
        let w = self
            .weight
            .map(|x| if x.is_finite() { x.max(0.0) } else { 0.0 });
        let mut largest = 0;
        for i in 1..3 {
            if w[i] > w[largest] {
                largest = i;
            }
        }
        // A NaN threshold drops nothing.
        let threshold = if threshold.is_nan() { 0.0 } else { threshold };
        let keep: [bool; 3] = std::array::from_fn(|i| i == largest || w[i] >= threshold);
        let count = keep.iter().filter(|&&k| k).count();
        if count == 3 {
            return 3;
        }
        let sum: f32 = (0..3).filter(|&i| keep[i]).map(|i| w[i]).sum();
        for i in 0..3 {
            self.weight[i] = if !keep[i] {
                0.0
            } else if sum > 0.0 && sum.is_finite() {
                w[i] / sum
            } else if i == largest {
                1.0
            } else {
                0.0
            };
        }
        count
    }

    /// Total weight of sample `index` (0 if it is not in the blend).
    pub fn weight_of(&self, index: u32) -> f32 {
        (0..3)
            .filter(|&i| self.index[i] == index)
            .map(|i| self.weight[i])
            .sum()
    }

    /// Normalises non-negative raw barycentric coordinates, snaps tiny weights to 0 and sorts the
    /// slots by decreasing weight.
    fn from_raw(index: [u32; 3], raw: Vec3A) -> Self {
        let sum = raw.element_sum();
        let mut w: Vec3A = if sum > 0.0 && sum < f32::INFINITY {
            raw / sum
        } else {
            // Unreachable for a direction inside the triangle; keep the largest coordinate.
            if raw.x >= raw.y && raw.x >= raw.z {
                Vec3A::X
            } else if raw.y >= raw.z {
                Vec3A::Y
            } else {
                Vec3A::Z
            }
        };
        let small = w.cmplt(Vec3A::splat(SNAP));
        if (small & w.cmpgt(Vec3A::ZERO)).any() {
            w = Vec3A::select(small, Vec3A::ZERO, w);
            w /= w.element_sum();
        }
        // Sort by decreasing weight without branches (the order is unpredictable from call to
        // call): the bits of a non-negative f32 order like the value, so each slot becomes one
        // u64 key (weight bits, then index; indices differ, so keys do) and min/max sort them.
        let w = w.to_array();
        let key = |i: usize| u64::from(w[i].to_bits()) << 32 | u64::from(index[i]);
        let (a, b, c) = (key(0), key(1), key(2));
        let hi = a.max(b).max(c);
        let lo = a.min(b).min(c);
        let mid = a ^ b ^ c ^ hi ^ lo;
        let sorted = [hi, mid, lo];
        let w = sorted.map(|k| f32::from_bits((k >> 32) as u32));
        let sorted = sorted.map(|k| k as u32);
        Self {
            index: sorted,
            weight: w,
        }
    }
}

/// A finite direction of moderate length (no need for unit length: descent and normalised
/// barycentric weights are scale-invariant; very long or short vectors are rescaled so that
/// products neither overflow nor underflow). NaN or zero becomes +Y; infinite components win
/// over finite ones.
fn sanitize(d: Vec3) -> Vec3A {
    let d = Vec3A::from(d);
    if d.is_finite() {
        let m = d.abs().max_element();
        if (1e-15..=1e15).contains(&m) {
            d
        } else if m > 0.0 {
            // Not `d * m.recip()`: the reciprocal of a subnormal overflows.
            d / m
        } else {
            Vec3A::Y
        }
    } else if d.is_nan() {
        Vec3A::Y
    } else {
        Vec3A::select(d.abs().cmpeq(Vec3A::INFINITY), d.signum(), Vec3A::ZERO)
    }
}

/// The matrix with rows `a`, `b`, `c`: `rows(a, b, c) * d = (a . d, b . d, c . d)`.
fn rows(a: Vec3, b: Vec3, c: Vec3) -> Mat3A {
    Mat3A::from_cols(a.into(), b.into(), c.into()).transpose()
}

/// Level-0 triangle of octant `o` (bit 0: x < 0, bit 1: y < 0, bit 2: z < 0), counter-clockwise
/// seen from outside.
fn octant_triangle(o: u32) -> [u32; 3] {
    let x = o & 1;
    let y = 2 + ((o >> 1) & 1);
    let z = 4 + ((o >> 2) & 1);
    if o.count_ones().is_multiple_of(2) {
        [x, y, z]
    } else {
        [x, z, y]
    }
}

/// Index of the normalised midpoint of directions `a` and `b`, created on first use.
fn midpoint(dirs: &mut Vec<DVec3>, cache: &mut HashMap<(u32, u32), u32>, a: u32, b: u32) -> u32 {
    let key = (a.min(b), a.max(b));
    if let Some(&i) = cache.get(&key) {
        return i;
    }
    // Adjacent directions are never antipodal, so the sum is never zero.
    let m = (dirs[a as usize] + dirs[b as usize]).normalize_or_zero();
    let i = dirs.len() as u32;
    dirs.push(m.as_vec3().as_dvec3());
    cache.insert(key, i);
    i
}

/// `a x b` in f64, rounded to f32.
fn cross32(a: DVec3, b: DVec3) -> Vec3 {
    a.cross(b).as_vec3()
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::f64::consts::PI;

    #[test]
    fn billboard_axes_are_orthonormal_everywhere() {
        for v in [
            Vec3::X,
            Vec3::Y,
            -Vec3::Y,
            Vec3::Z,
            Vec3::new(1.0, 2.0, 3.0).normalize_or_zero(),
        ] {
            let (r, u) = billboard_axes(v);
            assert!((r.length() - 1.0).abs() < 1e-5 && (u.length() - 1.0).abs() < 1e-5);
            assert!(r.dot(u).abs() < 1e-5 && r.dot(v).abs() < 1e-5 && u.dot(v).abs() < 1e-5);
            // right, up, view form a right-handed frame: the viewer sees right to the right.
            assert!((r.cross(u) - v).length() < 1e-4, "{v}");
        }
    }

    /// splitmix64: tiny deterministic PRNG for the tests.
    struct Rng(u64);

    impl Rng {
        fn next_u64(&mut self) -> u64 {
            self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
            let mut z = self.0;
            z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
            z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
            z ^ (z >> 31)
        }

        /// Uniform in [0, 1).
        fn unit(&mut self) -> f64 {
            (self.next_u64() >> 11) as f64 / (1u64 << 53) as f64
        }

        /// Uniform on the unit sphere.
        fn direction(&mut self) -> Vec3 {
            let z = 2.0 * self.unit() - 1.0;
            let phi = 2.0 * PI * self.unit();
            let r = (1.0 - z * z).max(0.0).sqrt();
            DVec3::new(r * phi.cos(), r * phi.sin(), z).as_vec3()
        }
    }

    fn all_sets() -> Vec<DirectionSet> {
        (0..=DirectionSet::MAX_LEVEL)
            .map(|l| DirectionSet::with_level(l).unwrap())
            .collect()
    }

    /// How far `d` is inside triangle `t`: the smallest signed sine of the angle from `d` to the
    /// triangle's edge great circles (negative: outside).
    fn containment(set: &DirectionSet, t: usize, d: Vec3) -> f64 {
        let d = d.as_dvec3().normalize_or_zero();
        let [a, b, c] = set.triangles()[t].map(|i| set.directions()[i as usize].as_dvec3());
        [(a, b), (b, c), (c, a)]
            .iter()
            .map(|&(p, q)| d.dot(p.cross(q).normalize_or_zero()))
            .fold(f64::INFINITY, f64::min)
    }

    /// Brute force: the triangle that contains `d` deepest, its depth, and the best depth among
    /// all other triangles.
    fn brute_locate(set: &DirectionSet, d: Vec3) -> (usize, f64, f64) {
        let mut best = (0, f64::NEG_INFINITY);
        let mut second = f64::NEG_INFINITY;
        for t in 0..set.triangles().len() {
            let s = containment(set, t, d);
            if s > best.1 {
                second = best.1;
                best = (t, s);
            } else if s > second {
                second = s;
            }
        }
        (best.0, best.1, second)
    }

    /// Checks `locate(d)` against brute force; returns whether the brute-force answer was unique
    /// (and therefore compared by index).
    fn check_locate(set: &DirectionSet, d: Vec3) -> bool {
        let t = set.locate(d);
        assert!(t < set.triangles().len());
        let (bt, best, second) = brute_locate(set, d);
        let got = containment(set, t, d);
        assert!(
            got >= best - 1e-6,
            "level {}: locate({d}) = {t} (depth {got:e}) but brute force {bt} (depth {best:e})",
            set.level()
        );
        assert!(
            got >= -1e-6,
            "locate({d}) = {t} does not contain it ({got:e})"
        );
        let unique = best - second > 1e-5;
        if unique {
            assert_eq!(t, bt, "level {}: locate({d})", set.level());
        }
        unique
    }

    fn slerp(a: Vec3, b: Vec3, t: f64) -> Vec3 {
        let (a, b) = (a.as_dvec3(), b.as_dvec3());
        let angle = a.dot(b).clamp(-1.0, 1.0).acos();
        let s = angle.sin();
        (a * (((1.0 - t) * angle).sin() / s) + b * ((t * angle).sin() / s)).as_vec3()
    }

    fn edges(set: &DirectionSet) -> Vec<(u32, u32)> {
        let mut e: Vec<(u32, u32)> = set
            .triangles()
            .iter()
            .flat_map(|&[a, b, c]| [(a, b), (b, c), (c, a)])
            .filter(|(p, q)| p < q)
            .collect();
        e.sort_unstable();
        e
    }

    fn check_blend(set: &DirectionSet, d: Vec3) -> Blend {
        let b = set.blend(d);
        let sum: f32 = b.weight.iter().sum();
        assert!((sum - 1.0).abs() < 1e-6, "blend({d}) sums to {sum}: {b:?}");
        assert!(b.weight.iter().all(|&w| w >= 0.0), "{b:?}");
        assert!(
            b.weight[0] >= b.weight[1] && b.weight[1] >= b.weight[2],
            "{b:?}"
        );
        let mut tri = set.triangles()[set.locate(d)];
        let mut idx = b.index;
        tri.sort_unstable();
        idx.sort_unstable();
        assert_eq!(tri, idx, "blend({d}) indices are not locate's triangle");
        b
    }

    #[test]
    fn counts_match_levels() {
        let tri_counts = [8, 32, 128, 512];
        for (l, set) in all_sets().iter().enumerate() {
            assert_eq!(set.level(), l as u32);
            assert_eq!(set.len(), DirectionSet::COUNTS[l]);
            assert!(!set.is_empty());
            assert_eq!(set.directions().len(), DirectionSet::COUNTS[l]);
            assert_eq!(set.triangles().len(), tri_counts[l]);
            let by_count = DirectionSet::with_count(DirectionSet::COUNTS[l]).unwrap();
            assert_eq!(by_count.level(), l as u32);
            assert_eq!(by_count.directions(), set.directions());
            assert_eq!(by_count.triangles(), set.triangles());
            // Euler characteristic of a sphere: V - E + F = 2.
            let e = edges(set).len();
            assert_eq!(set.len() + set.triangles().len(), e + 2);
        }
    }

    #[test]
    fn bad_counts_and_levels_are_errors() {
        for count in [0, 1, 5, 7, 17, 19, 65, 257, 259, 1026, usize::MAX] {
            let err = DirectionSet::with_count(count).unwrap_err();
            assert_eq!(err, SphereError::BadCount { count });
            let msg = err.to_string();
            assert!(msg.contains(&count.to_string()), "{msg}");
            assert!(msg.contains("6, 18, 66 or 258"), "{msg}");
        }
        for level in [4, 5, 100, u32::MAX] {
            let err = DirectionSet::with_level(level).unwrap_err();
            assert_eq!(err, SphereError::BadLevel { level });
            assert!(err.to_string().contains("0, 1, 2 or 3"));
        }
    }

    #[test]
    fn first_directions_are_octahedron_and_levels_nest() {
        let sets = all_sets();
        let octa = [
            Vec3::X,
            Vec3::NEG_X,
            Vec3::Y,
            Vec3::NEG_Y,
            Vec3::Z,
            Vec3::NEG_Z,
        ];
        for set in &sets {
            assert_eq!(&set.directions()[..6], &octa);
        }
        for pair in sets.windows(2) {
            let (coarse, fine) = (pair[0].directions(), pair[1].directions());
            assert_eq!(&fine[..coarse.len()], coarse);
        }
    }

    #[test]
    fn each_set_begins_with_every_smaller_set_in_order() {
        // The btf method keeps one view-axes buffer, the largest set's, for every level.
        let sets = all_sets();
        for (k, small) in sets.iter().enumerate() {
            for large in &sets[k..] {
                assert_eq!(
                    &large.directions()[..small.len()],
                    small.directions(),
                    "{} directions against {}",
                    small.len(),
                    large.len()
                );
            }
        }
    }

    #[test]
    fn directions_are_unit_and_distinct() {
        for set in all_sets() {
            let dirs = set.directions();
            for (i, d) in dirs.iter().enumerate() {
                assert!((d.length() - 1.0).abs() < 1e-6, "direction {i} = {d}");
                for (j, e) in dirs.iter().enumerate().skip(i + 1) {
                    // Level 3 samples are ~0.19 rad apart: cos < 0.99.
                    assert!(d.dot(*e) < 0.99, "directions {i} and {j} coincide: {d} {e}");
                }
            }
        }
    }

    #[test]
    fn triangles_are_ccw_and_cover_the_sphere() {
        for set in all_sets() {
            let dirs = set.directions();
            let mut area = 0.0;
            let mut used = vec![false; set.len()];
            let mut directed = Vec::new();
            for (t, &[a, b, c]) in set.triangles().iter().enumerate() {
                for v in [a, b, c] {
                    used[v as usize] = true;
                }
                assert!(a != b && b != c && c != a, "triangle {t} is degenerate");
                let [pa, pb, pc] = [a, b, c].map(|i| dirs[i as usize].as_dvec3());
                // Counter-clockwise seen from outside: the flat normal points away from the origin.
                let normal = (pb - pa).cross(pc - pa);
                assert!(normal.dot(pa + pb + pc) > 0.0, "triangle {t} is clockwise");
                let det = pa.dot(pb.cross(pc));
                assert!(det > 0.0, "triangle {t}: det {det}");
                // Van Oosterom & Strackee solid angle.
                let denom = 1.0 + pa.dot(pb) + pb.dot(pc) + pc.dot(pa);
                area += 2.0 * det.atan2(denom);
                directed.extend([(a, b), (b, c), (c, a)]);
            }
            assert!(
                (area - 4.0 * PI).abs() < 1e-3,
                "level {}: total area {area}",
                set.level()
            );
            assert!(used.iter().all(|&u| u), "unused direction");
            // Closed and consistently oriented: every directed edge once, and its reverse once.
            let n = directed.len();
            directed.sort_unstable();
            directed.dedup();
            assert_eq!(directed.len(), n, "a directed edge appears twice");
            for &(p, q) in &directed {
                assert!(
                    directed.binary_search(&(q, p)).is_ok(),
                    "edge {p}-{q} is open"
                );
            }
        }
    }

    #[test]
    fn locate_matches_brute_force_on_random_directions() {
        let mut rng = Rng(0x5EED_0001);
        for set in all_sets() {
            let mut unique = 0;
            let n = 20_000;
            for _ in 0..n {
                let d = rng.direction();
                if check_locate(&set, d) {
                    unique += 1;
                }
                // Unnormalised input must give the same triangle.
                assert_eq!(set.locate(d * 7.3), set.locate(d));
            }
            // Almost every random direction is strictly inside one triangle.
            assert!(
                unique > n * 99 / 100,
                "level {}: only {unique} unique",
                set.level()
            );
        }
    }

    #[test]
    fn locate_matches_brute_force_on_vertices_and_edges() {
        for set in all_sets() {
            let dirs = set.directions().to_vec();
            for &d in &dirs {
                check_locate(&set, d);
                check_locate(&set, -d);
            }
            for (a, b) in edges(&set) {
                let (pa, pb) = (dirs[a as usize], dirs[b as usize]);
                for t in [0.5, 0.25, 0.75, 1e-4, 0.9999, 1.0 / 3.0] {
                    check_locate(&set, slerp(pa, pb, t));
                }
                // Plain (unnormalised) midpoint and sum too.
                check_locate(&set, pa + pb);
            }
            for &[a, b, c] in set.triangles() {
                let [pa, pb, pc] = [a, b, c].map(|i| dirs[i as usize]);
                check_locate(&set, pa + pb + pc);
            }
            // Coordinate planes and axes, with signed zeros.
            for d in [
                Vec3::new(0.0, 0.6, 0.8),
                Vec3::new(-0.0, 0.6, 0.8),
                Vec3::new(0.6, -0.0, -0.8),
                Vec3::new(-0.6, 0.8, -0.0),
                Vec3::new(-0.0, -0.0, 1.0),
                Vec3::new(-0.0, -1.0, -0.0),
                Vec3::new(1.0, 1.0, 1.0),
                Vec3::new(-1.0, 1.0, -1.0),
            ] {
                check_locate(&set, d);
            }
        }
    }

    #[test]
    fn blend_weights_are_barycentric() {
        let mut rng = Rng(0x5EED_0002);
        for set in all_sets() {
            let mut worst = 0.0f64;
            for _ in 0..20_000 {
                let d = rng.direction();
                let b = check_blend(&set, d);
                // The weighted sum of the samples lies on the ray through d.
                let p: DVec3 = (0..3)
                    .map(|i| set.directions()[b.index[i] as usize].as_dvec3() * b.weight[i] as f64)
                    .sum();
                let sin = p
                    .normalize_or_zero()
                    .cross(d.as_dvec3().normalize_or_zero())
                    .length();
                worst = worst.max(sin);
                assert!(
                    sin < 1e-6,
                    "blend({d}) = {b:?} points elsewhere ({sin:e} rad)"
                );
                // Scale does not matter.
                let b2 = set.blend(d * 1e-20);
                for i in 0..3 {
                    assert!((b2.weight_of(b.index[i]) - b.weight[i]).abs() < 1e-5);
                }
            }
            println!(
                "level {}: largest angle off the ray {worst:e} rad",
                set.level()
            );
        }
    }

    #[test]
    fn blend_at_sample_direction_is_exact() {
        for set in all_sets() {
            for (i, &d) in set.directions().iter().enumerate() {
                for scaled in [d, d * 2.0, d * 0.37, d * 1e6] {
                    let b = check_blend(&set, scaled);
                    assert_eq!(b.index[0], i as u32, "blend({scaled}) = {b:?}");
                    assert_eq!(b.weight, [1.0, 0.0, 0.0], "blend({scaled}) = {b:?}");
                }
                assert_eq!(set.nearest(d), i);
            }
        }
    }

    #[test]
    fn light_gain_restores_the_length_the_blend_loses_between_samples() {
        let six = DirectionSet::with_count(6).unwrap();
        // At a sample the blend is the sample itself.
        for &d in six.directions() {
            assert_eq!(six.light_gain(&six.blend(d), d), 1.0);
        }
        // At the centre of an octant the 3 samples weigh 1/3 each: their sum is 1/sqrt(3)
        // long.
        let centre = Vec3::new(1.0, 1.0, -1.0).normalize();
        let b = six.blend(centre);
        let gain = six.light_gain(&b, centre);
        assert!((gain - 3f32.sqrt()).abs() < 1e-4, "{gain}");
        // In general, the blend times the gain reaches the unit sphere along d, and finer
        // sets need less of it.
        for set in all_sets() {
            let mut largest = 1.0f32;
            for i in 0..500 {
                let t = i as f32 * 0.7;
                let d = Vec3::new(t.sin() * (1.3 * t).cos(), (0.9 * t).cos(), t.cos() + 0.2)
                    .normalize();
                let b = set.blend(d);
                let gain = set.light_gain(&b, d);
                let sum: Vec3 = (0..3)
                    .map(|k| set.directions()[b.index[k] as usize] * b.weight[k])
                    .sum();
                assert!((sum.dot(d) * gain - 1.0).abs() < 1e-3, "{d}: {gain}");
                largest = largest.max(gain);
            }
            assert!(
                largest <= 3f32.sqrt() + 1e-4,
                "{} samples: {largest}",
                set.len()
            );
            if set.len() >= 18 {
                assert!(largest < 1.25, "{} samples: {largest}", set.len());
            }
        }
        // A blend culled to one far sample is brightened at most MAX_LIGHT_GAIN times.
        let mut culled = six.blend(centre);
        culled.cull(0.9);
        let gain = six.light_gain(&culled, centre);
        assert!((gain - 3f32.sqrt()).abs() < 1e-4, "{gain}");
        let far = Vec3::new(1.0, 0.05, 0.0).normalize();
        let one = Blend {
            index: [2, 0, 1],
            weight: [1.0, 0.0, 0.0],
        };
        assert_eq!(six.light_gain(&one, far), MAX_LIGHT_GAIN);
    }

    #[test]
    fn blend_on_edge_gives_opposite_vertex_zero() {
        for set in all_sets() {
            let dirs = set.directions();
            for (a, b) in edges(&set) {
                let (pa, pb) = (dirs[a as usize], dirs[b as usize]);
                for t in [0.5, 0.2, 0.7] {
                    let d = slerp(pa, pb, t);
                    let bl = check_blend(&set, d);
                    assert_eq!(bl.weight[2], 0.0, "blend({d}) on edge {a}-{b}: {bl:?}");
                    let (wa, wb) = (bl.weight_of(a), bl.weight_of(b));
                    assert!((wa + wb - 1.0).abs() < 1e-6, "{bl:?} not on {a}-{b}");
                    // The weight moves from a to b along the edge.
                    if t < 0.5 {
                        assert!(wa > wb);
                    } else if t > 0.5 {
                        assert!(wb > wa);
                    } else {
                        assert!((wa - wb).abs() < 1e-4);
                    }
                }
            }
        }
    }

    #[test]
    fn blend_is_continuous_along_great_circles() {
        // Largest allowed change of any sample's weight per step of 2*pi/10000 rad. The weight
        // gradient is about 1 / (triangle height), ~6/rad at level 3, i.e. < 0.004 per step.
        const BOUND: f32 = 0.01;
        let circles = [
            // The equator runs along octahedron edges and through 4 vertices.
            (DVec3::X, DVec3::Y),
            // Through +-X and the midpoints of the Y-Z edges.
            (DVec3::X, DVec3::new(0.0, 1.0, 1.0).normalize_or_zero()),
            // A generic circle.
            (
                DVec3::new(0.3, -0.5, 0.8).normalize_or_zero(),
                DVec3::new(0.3, -0.5, 0.8)
                    .cross(DVec3::new(0.7, 0.2, 0.1))
                    .normalize_or_zero(),
            ),
        ];
        let steps = 10_000;
        for set in all_sets() {
            let mut worst = 0.0f32;
            for &(u, v) in &circles {
                let at = |i: usize| {
                    let t = 2.0 * PI * i as f64 / steps as f64;
                    (u * t.cos() + v * t.sin()).as_vec3()
                };
                let mut prev = check_blend(&set, at(0));
                for i in 1..=steps {
                    let cur = check_blend(&set, at(i));
                    for idx in prev.index.iter().chain(cur.index.iter()) {
                        let change = (cur.weight_of(*idx) - prev.weight_of(*idx)).abs();
                        worst = worst.max(change);
                        assert!(
                            change < BOUND,
                            "level {}: step {i} changes sample {idx} by {change}: {prev:?} -> {cur:?}",
                            set.level()
                        );
                    }
                    prev = cur;
                }
            }
            println!(
                "level {}: largest weight change per step {worst}",
                set.level()
            );
        }
    }

    #[test]
    fn blend_many_matches_blend() {
        let mut rng = Rng(0x5EED_0006);
        let empty = Blend {
            index: [u32::MAX; 3],
            weight: [-1.0; 3],
        };
        for set in all_sets() {
            let mut dirs: Vec<Vec3> = (0..4_003).map(|_| rng.direction()).collect();
            dirs.extend_from_slice(set.directions());
            dirs.extend([Vec3::ZERO, Vec3::NAN, Vec3::new(0.0, 0.0, -f32::INFINITY)]);
            for (n_dirs, n_out) in [
                (0, 0),
                (1, 1),
                (3, 3),
                (5, 5),
                (7, 9),
                (9, 6),
                (dirs.len(), dirs.len()),
            ] {
                let mut out = vec![empty; n_out];
                set.blend_many(&dirs[dirs.len() - n_dirs..], &mut out);
                let n = n_dirs.min(n_out);
                for (i, o) in out.iter().enumerate() {
                    if i < n {
                        assert_eq!(*o, set.blend(dirs[dirs.len() - n_dirs + i]), "slot {i}");
                    } else {
                        assert_eq!(*o, empty, "slot {i} past the directions was written");
                    }
                }
            }
        }
    }

    #[test]
    fn cull_zero_threshold_changes_nothing() {
        let mut rng = Rng(0x5EED_0003);
        for set in all_sets() {
            for _ in 0..2_000 {
                let b = set.blend(rng.direction());
                let mut c = b;
                assert_eq!(c.cull(0.0), 3);
                assert_eq!(c, b);
            }
            let mut at_sample = set.blend(Vec3::Z);
            let before = at_sample;
            assert_eq!(at_sample.cull(0.0), 3);
            assert_eq!(at_sample, before);
        }
    }

    #[test]
    fn cull_drops_small_weights_and_renormalises() {
        let mut rng = Rng(0x5EED_0004);
        let mut seen = [0usize; 4];
        for set in all_sets() {
            for _ in 0..5_000 {
                let b = set.blend(rng.direction());
                let mut c = b;
                let n = c.cull(0.4);
                assert!(n == 1 || n == 2, "{b:?} -> {c:?} ({n})");
                seen[n] += 1;
                assert_eq!(c.index, b.index);
                let sum: f32 = c.weight.iter().sum();
                assert!((sum - 1.0).abs() < 1e-6, "{c:?}");
                // Survivors are the first n slots (blend sorts), the largest always survives.
                assert!(c.weight[..n].iter().all(|&w| w > 0.0), "{c:?}");
                assert!(c.weight[n..].iter().all(|&w| w == 0.0), "{c:?}");
                for i in 0..3 {
                    let kept = i == 0 || b.weight[i] >= 0.4;
                    assert_eq!(kept, i < n, "{b:?} -> {c:?}");
                    if kept {
                        let expect = b.weight[i] / b.weight[..n].iter().sum::<f32>();
                        assert!((c.weight[i] - expect).abs() < 1e-6);
                    }
                }
                // A threshold above every weight leaves only the largest, at weight 1.
                let mut one = b;
                assert_eq!(one.cull(1.5), 1);
                assert_eq!(one.weight, [1.0, 0.0, 0.0]);
                assert_eq!(one.index, b.index);
            }
        }
        assert!(seen[1] > 0 && seen[2] > 0, "{seen:?}");
        // Unsorted and broken blends: the largest survives, no panic.
        let mut b = Blend {
            index: [4, 7, 9],
            weight: [0.1, 0.3, 0.6],
        };
        assert_eq!(b.cull(0.25), 2);
        assert_eq!(b.weight[0], 0.0);
        assert!((b.weight[1] - 1.0 / 3.0).abs() < 1e-6 && (b.weight[2] - 2.0 / 3.0).abs() < 1e-6);
        let mut b = Blend {
            index: [1, 2, 3],
            weight: [f32::NAN, -1.0, f32::INFINITY],
        };
        let n = b.cull(0.5);
        assert!((1..=3).contains(&n));
        assert!(b.weight.iter().all(|w| w.is_finite()));
        let mut b = Blend {
            index: [1, 2, 3],
            weight: [0.0; 3],
        };
        assert_eq!(b.cull(0.5), 1);
        assert_eq!(b.weight, [1.0, 0.0, 0.0]);
    }

    #[test]
    fn nearest_matches_brute_force() {
        let mut rng = Rng(0x5EED_0005);
        for set in all_sets() {
            let brute = |d: Vec3| {
                let d = Vec3::from(sanitize(d));
                let mut best = (0, f32::NEG_INFINITY);
                for (i, v) in set.directions().iter().enumerate() {
                    if v.dot(d) > best.1 {
                        best = (i, v.dot(d));
                    }
                }
                best.0
            };
            let mut probes: Vec<Vec3> = (0..20_000).map(|_| rng.direction()).collect();
            let dirs = set.directions();
            for (a, b) in edges(&set) {
                probes.push(dirs[a as usize] + dirs[b as usize]);
                probes.push(slerp(dirs[a as usize], dirs[b as usize], 0.3));
            }
            for &[a, b, c] in set.triangles() {
                probes.push(dirs[a as usize] + dirs[b as usize] + dirs[c as usize]);
            }
            for d in probes {
                assert_eq!(
                    set.nearest(d),
                    brute(d),
                    "level {}: nearest({d})",
                    set.level()
                );
            }
        }
    }

    #[test]
    fn degenerate_inputs_do_not_panic() {
        let nan = f32::NAN;
        let inf = f32::INFINITY;
        for set in all_sets() {
            let up = set.blend(Vec3::Y);
            assert_eq!(up.index[0], 2);
            assert_eq!(up.weight, [1.0, 0.0, 0.0]);
            for d in [
                Vec3::ZERO,
                Vec3::new(-0.0, -0.0, -0.0),
                Vec3::splat(nan),
                Vec3::new(nan, 1.0, 0.0),
                Vec3::new(0.0, 0.0, nan),
                Vec3::new(nan, inf, 0.0),
            ] {
                assert_eq!(set.blend(d), up, "blend({d})");
                assert_eq!(set.locate(d), set.locate(Vec3::Y));
                assert_eq!(set.nearest(d), 2);
            }
            // Infinite components point the way; tiny and huge vectors keep their direction.
            assert_eq!(set.nearest(Vec3::new(inf, 3.0, -2.0)), 0);
            assert_eq!(set.nearest(Vec3::new(-inf, 0.0, 0.0)), 1);
            assert_eq!(set.nearest(Vec3::new(0.0, 0.0, -inf)), 5);
            let diag = set.blend(Vec3::new(1.0, 1.0, 1.0));
            assert_eq!(set.blend(Vec3::new(inf, inf, inf)), diag);
            assert_eq!(set.blend(Vec3::new(1e-40, 0.0, 0.0)).index[0], 0);
            assert_eq!(set.blend(Vec3::new(0.0, 0.0, -1e-45)).index[0], 5);
            assert_eq!(set.blend(Vec3::splat(f32::MAX)), diag);
            assert_eq!(set.blend(Vec3::splat(-f32::MAX)).weight, diag.weight);
            for d in [
                Vec3::new(f32::MIN_POSITIVE, -f32::MAX, 1.0),
                Vec3::new(inf, -inf, 0.0),
                Vec3::new(1e-30, 1e-30, -1e-30),
            ] {
                let b = check_blend(&set, d);
                assert!(b.weight.iter().all(|w| w.is_finite()));
                let _ = set.nearest(d);
            }
        }
    }
}
