//! Helpers of the sphere's tests: a small deterministic random generator, the direction
//! sets, brute-force references and the checks every lookup must pass.

use std::f64::consts::PI;

use glam::{DVec3, Vec3};

use super::{Blend, DirectionSet};

/// splitmix64: tiny deterministic PRNG for the tests.
pub(super) struct Rng(pub(super) u64);

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
    pub(super) fn direction(&mut self) -> Vec3 {
        let z = 2.0 * self.unit() - 1.0;
        let phi = 2.0 * PI * self.unit();
        let r = (1.0 - z * z).max(0.0).sqrt();
        DVec3::new(r * phi.cos(), r * phi.sin(), z).as_vec3()
    }
}

pub(super) fn all_sets() -> Vec<DirectionSet> {
    (0..=DirectionSet::MAX_LEVEL)
        .map(|l| DirectionSet::with_level(l).unwrap())
        .collect()
}

/// How far `d` is inside triangle `t`: the smallest signed sine of the angle from `d` to the
/// triangle's edge great circles (negative: outside).
pub(super) fn containment(set: &DirectionSet, t: usize, d: Vec3) -> f64 {
    let d = d.as_dvec3().normalize_or_zero();
    let [a, b, c] = set.triangles()[t].map(|i| set.directions()[i as usize].as_dvec3());
    [(a, b), (b, c), (c, a)]
        .iter()
        .map(|&(p, q)| d.dot(p.cross(q).normalize_or_zero()))
        .fold(f64::INFINITY, f64::min)
}

/// Brute force: the triangle that contains `d` deepest, its depth, and the best depth among
/// all other triangles.
pub(super) fn brute_locate(set: &DirectionSet, d: Vec3) -> (usize, f64, f64) {
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
pub(super) fn check_locate(set: &DirectionSet, d: Vec3) -> bool {
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

pub(super) fn slerp(a: Vec3, b: Vec3, t: f64) -> Vec3 {
    let (a, b) = (a.as_dvec3(), b.as_dvec3());
    let angle = a.dot(b).clamp(-1.0, 1.0).acos();
    let s = angle.sin();
    (a * (((1.0 - t) * angle).sin() / s) + b * ((t * angle).sin() / s)).as_vec3()
}

pub(super) fn edges(set: &DirectionSet) -> Vec<(u32, u32)> {
    let mut e: Vec<(u32, u32)> = set
        .triangles()
        .iter()
        .flat_map(|&[a, b, c]| [(a, b), (b, c), (c, a)])
        .filter(|(p, q)| p < q)
        .collect();
    e.sort_unstable();
    e
}

pub(super) fn check_blend(set: &DirectionSet, d: Vec3) -> Blend {
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
