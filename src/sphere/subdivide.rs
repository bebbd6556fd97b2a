//! Builds a [`DirectionSet`]: the octahedron subdivided 0 to 3 times, with the tables the
//! lookup descends (split and barycentric matrices, nearest-sample candidates).

use std::collections::HashMap;

use glam::{DVec3, Mat3A, Vec3};

use super::{DirectionSet, SphereError};

impl DirectionSet {
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
    use crate::sphere::test_support::{all_sets, edges};
    use std::f64::consts::PI;

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
}
