//! Finding a direction on the sphere: its enclosing triangle by hierarchical descent and its
//! nearest sample, for any input (unusable directions are sanitised first).

use glam::{Vec3, Vec3A};

use super::DirectionSet;

impl DirectionSet {
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

    /// Descent for finite, non-zero directions, `N` at a time: the `N` dependency chains are
    /// interleaved so that the CPU can overlap them.
    #[inline]
    pub(super) fn locate_lanes<const N: usize>(&self, d: [Vec3A; N]) -> [usize; N] {
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

/// A finite direction of moderate length (no need for unit length: descent and normalised
/// barycentric weights are scale-invariant; very long or short vectors are rescaled so that
/// products neither overflow nor underflow). NaN or zero becomes +Y; infinite components win
/// over finite ones.
pub(super) fn sanitize(d: Vec3) -> Vec3A {
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sphere::test_support::{Rng, all_sets, check_blend, check_locate, edges, slerp};

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
