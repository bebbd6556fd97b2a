//! The weights of a direction's 3 samples ([`Blend`]): normalised barycentric coordinates,
//! their culling, and the gain that restores a blend of light samples' length.

use glam::{Vec3, Vec3A};

use super::locate::sanitize;
use super::{DirectionSet, MAX_LIGHT_GAIN};

/// Normalised weights below this are snapped to 0 (and the rest renormalised), so that a sampled
/// direction gets exactly weight 1 and a direction on an edge gives the opposite vertex exactly 0
/// despite rounding. The resulting jump (< 1e-6) is far below anything visible.
const SNAP: f32 = 1e-6;

impl DirectionSet {
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sphere::test_support::{Rng, all_sets, check_blend, edges, slerp};
    use glam::DVec3;
    use std::f64::consts::PI;

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
}
