//! Grows a [`TreeModel`] from [`SpeciesParams`] and a seed: the twig, the main branch and
//! the trunk with their instance transforms, all deterministic for the parameters and seed.

use std::f32::consts::{FRAC_PI_2, PI, TAU};

use glam::{Mat4, Vec3};

use super::TreeModel;
use crate::model::ModelError;
use crate::model::mesh::{Mesh, Vertex};
use crate::model::rng::Rng;
use crate::model::species::{CrownShape, FoliageKind, SpeciesParams, TwigArrangement};

/// The golden angle in radians: successive items rotated by it never line up.
const GOLDEN_ANGLE: f32 = 2.399_963_3;
/// Rings along a main branch's limb.
const LIMB_SEGMENTS: usize = 6;
/// Rings along the trunk.
const TRUNK_SEGMENTS: usize = 10;
/// How far the trunk reaches below the ground (m), so that it does not float on slopes.
const TRUNK_SINK: f32 = 0.4;

impl TreeModel {
    /// Grows the prototype of a species. Deterministic for `(params, seed)`; the parameters
    /// are validated first.
    pub fn generate(params: &SpeciesParams, seed: u64) -> Result<TreeModel, ModelError> {
        params
            .check()
            .map_err(|e| ModelError::invalid("species parameters", e))?;
        let twig = build_twig(params, &mut Rng::derive(seed, 1));
        let (branch_limb, branch_twigs) = build_branch(params, &mut Rng::derive(seed, 2));
        let twig_bounds = twig.bounds();
        let branch_bounds = branch_twigs.iter().fold(branch_limb.bounds(), |b, m| {
            b.union(twig.bounds_transformed(*m))
        });
        // How far the branch prototype reaches along its own axis: instances are scaled so
        // that this reach meets the crown envelope.
        let reach = branch_bounds.max.z.max(params.branch_length);
        let (trunk, tree_branches, tree_twigs) =
            build_tree(params, &mut Rng::derive(seed, 3), reach);

        let mut tree_bounds = trunk.bounds();
        for b in &tree_branches {
            tree_bounds = tree_bounds.union(branch_limb.bounds_transformed(*b));
            for t in &branch_twigs {
                tree_bounds = tree_bounds.union(twig.bounds_transformed(*b * *t));
            }
        }
        for t in &tree_twigs {
            tree_bounds = tree_bounds.union(twig.bounds_transformed(*t));
        }

        Ok(TreeModel {
            name: match params.foliage {
                FoliageKind::Needles => "conifer".to_owned(),
                FoliageKind::Leaves => "broadleaf".to_owned(),
            },
            foliage: params.foliage,
            foliage_per_twig: params.foliage_per_twig,
            twig,
            branch_limb,
            branch_twigs,
            trunk,
            tree_branches,
            tree_twigs,
            twig_bounds,
            branch_bounds,
            tree_bounds,
            surfaces: None,
            levels_note: None,
            variant: 0,
        })
    }
}

#[inline]
fn lerp(a: f32, b: f32, t: f32) -> f32 {
    a + (b - a) * t
}

/// A transform whose columns are the given axes (scaled uniformly) and origin.
fn frame(x: Vec3, y: Vec3, z: Vec3, origin: Vec3, scale: f32) -> Mat4 {
    Mat4::from_cols(
        (x * scale).extend(0.0),
        (y * scale).extend(0.0),
        (z * scale).extend(0.0),
        origin.extend(1.0),
    )
}

/// A unit vector perpendicular to `dir` that is as close as possible to `hint`.
fn perpendicular(dir: Vec3, hint: Vec3) -> Vec3 {
    (hint - dir * hint.dot(dir))
        .try_normalize()
        .or_else(|| dir.any_orthonormal_vector().try_normalize())
        .unwrap_or(Vec3::X)
}

/// Colour of one leaf or needle: the main colour mixed towards the alternative colour by
/// `mix` and brightened or darkened by up to `variation`.
fn foliage_color(p: &SpeciesParams, mix: f32, rng: &mut Rng) -> Vec3 {
    let base = Vec3::from(p.foliage_color);
    let alt = Vec3::from(p.foliage_color_alt);
    let brightness = 1.0 + 0.5 * p.foliage_variation * rng.signed();
    let hue = Vec3::new(
        1.0 + 0.12 * p.foliage_variation * rng.signed(),
        1.0,
        1.0 + 0.12 * p.foliage_variation * rng.signed(),
    );
    (base.lerp(alt, mix.clamp(0.0, 1.0)) * brightness * hue).clamp(Vec3::ZERO, Vec3::ONE)
}

/// Level 0: the twig stem and its leaves or needles.
fn build_twig(p: &SpeciesParams, rng: &mut Rng) -> Mesh {
    let mut m = Mesh::default();
    let len = p.twig_length;
    let bark = Vec3::from(p.bark_color);
    m.add_tube(
        &[Vec3::ZERO, Vec3::Z * len],
        &[p.twig_radius, p.twig_radius * 0.35],
        3,
        (bark * 1.2).min(Vec3::ONE),
    );
    let n = p.foliage_per_twig;
    let per = match p.foliage {
        FoliageKind::Needles => 4,
        FoliageKind::Leaves => 6,
    };
    m.vertices.reserve(n as usize * per);
    m.indices.reserve(n as usize * (per - 2) * 3);
    let angle = p.foliage_angle.to_radians();
    for i in 0..n {
        let u = ((i as f32 + 0.5 + 0.4 * rng.signed()) / n as f32).clamp(0.0, 1.0);
        let z = len * (0.03 + 0.95 * u);
        let theta = match p.foliage {
            // Needles all around the twig except straight below (a flattened bottle-brush).
            FoliageKind::Needles => {
                let f = (i as f32 * 0.618_034 + 0.08 * rng.signed()).rem_euclid(1.0);
                lerp(-1.2, PI + 1.2, f)
            }
            FoliageKind::Leaves => i as f32 * GOLDEN_ANGLE + 0.4 * rng.signed(),
        };
        let radial = Vec3::new(theta.cos(), theta.sin(), 0.0);
        let a = (angle + 0.17 * rng.signed()).clamp(0.05, PI - 0.05);
        let dir = (radial * a.sin() + Vec3::Z * a.cos()).normalize_or_zero();
        let start = Vec3::new(0.0, 0.0, z) + radial * (p.twig_radius * 0.6);
        match p.foliage {
            FoliageKind::Needles => {
                // Slightly shorter towards the tip; light new growth near the tip.
                let length =
                    p.foliage_length * (1.0 - 0.35 * u * u * u) * (1.0 + 0.15 * rng.signed());
                let mix = p.foliage_variation * (0.6 * rng.f32()) + 0.8 * u.powi(6);
                let color = foliage_color(p, mix, rng);
                add_needle(&mut m, start, dir, radial, length, p.foliage_width, color);
            }
            FoliageKind::Leaves => {
                let size = 1.0 + 0.2 * rng.signed();
                let mix = (rng.f32() * rng.f32() * 2.0 * p.foliage_variation).min(1.0);
                let color = foliage_color(p, mix, rng);
                let roll = 0.7 * rng.signed();
                add_leaf(
                    &mut m,
                    start,
                    dir,
                    roll,
                    p.foliage_length * size,
                    p.foliage_width * size,
                    color,
                );
            }
        }
    }
    m
}

/// A needle: a thin rhombus folded along its midrib (2 triangles, 4 vertices).
fn add_needle(
    m: &mut Mesh,
    start: Vec3,
    dir: Vec3,
    radial: Vec3,
    length: f32,
    width: f32,
    color: Vec3,
) {
    // Width direction as horizontal as possible in the twig frame, so that the flat side
    // of the needle faces up and out.
    let w = dir
        .cross(Vec3::Y)
        .try_normalize()
        .unwrap_or_else(|| perpendicular(dir, Vec3::X));
    let mut n = w.cross(dir).normalize_or_zero();
    if n.dot(Vec3::Y * 0.5 + radial) < 0.0 {
        n = -n;
    }
    let hw = 0.5 * width;
    let mid = start + dir * (length * 0.45);
    let b = start;
    let t = start + dir * length;
    let l = mid + w * hw + n * (hw * 0.6);
    let r = mid - w * hw + n * (hw * 0.6);
    let face = |a: Vec3, b2: Vec3, c: Vec3| {
        let f = (b2 - a).cross(c - a).normalize_or_zero();
        if f.dot(n) < 0.0 { -f } else { f }
    };
    let nl = face(b, t, l);
    let nr = face(b, r, t);
    let dark = color * 0.8;
    let ib = m.push_vertex(Vertex::new(b, n, dark, 1.0));
    let it = m.push_vertex(Vertex::new(t, n, color, 1.0));
    let il = m.push_vertex(Vertex::new(l, nl, color, 1.0));
    let ir = m.push_vertex(Vertex::new(r, nr, color, 1.0));
    m.push_triangle_facing(ib, it, il, nl);
    m.push_triangle_facing(ib, ir, it, nr);
}

/// A leaf: a flat, slightly pointed oval (4 triangles, 6 vertices) with one normal.
fn add_leaf(m: &mut Mesh, start: Vec3, dir: Vec3, roll: f32, length: f32, width: f32, color: Vec3) {
    // Blade normal: towards the twig's upper side, rolled about the leaf axis.
    let n0 = perpendicular(dir, Vec3::Y);
    let n = (n0 * roll.cos() + dir.cross(n0) * roll.sin()).normalize_or_zero();
    let w = dir.cross(n).normalize_or_zero();
    // A short bare stalk, then the blade.
    let b = start + dir * (0.12 * length);
    let outline = [
        (0.0, 0.0),
        (0.28, -0.5),
        (0.66, -0.42),
        (1.0, 0.0),
        (0.66, 0.42),
        (0.28, 0.5),
    ];
    let base = m.vertices.len() as u32;
    for (k, (along, across)) in outline.iter().enumerate() {
        let pos = b + dir * (along * length) + w * (across * width);
        let c = if k == 0 { color * 0.85 } else { color };
        m.push_vertex(Vertex::new(pos, n, c, 1.0));
    }
    for k in 1..5 {
        m.push_triangle_facing(base, base + k, base + k + 1, n);
    }
}

/// Level 1: the limb (a drooping tapered tube) and its twig instances.
fn build_branch(p: &SpeciesParams, rng: &mut Rng) -> (Mesh, Vec<Mat4>) {
    let len = p.branch_length;
    let drop = len * p.branch_droop.to_radians().tan() * 0.5;
    let curve = |t: f32| Vec3::new(0.0, -drop * t * t, len * t);
    let tangent = |t: f32| {
        Vec3::new(0.0, -2.0 * drop * t, len)
            .try_normalize()
            .unwrap_or(Vec3::Z)
    };
    let centres: Vec<Vec3> = (0..=LIMB_SEGMENTS)
        .map(|k| curve(k as f32 / LIMB_SEGMENTS as f32))
        .collect();
    let radii: Vec<f32> = (0..=LIMB_SEGMENTS)
        .map(|k| p.branch_radius * (1.0 - 0.8 * k as f32 / LIMB_SEGMENTS as f32))
        .collect();
    let mut limb = Mesh::default();
    limb.add_tube(&centres, &radii, p.branch_sides, Vec3::from(p.bark_color));

    let n = p.twigs_per_branch;
    let twig_angle = p.twig_angle.to_radians();
    let mut twigs = Vec::with_capacity(n as usize);
    for j in 0..n {
        let terminal = j + 1 == n;
        let t = if terminal {
            1.0
        } else {
            let f = (j as f32 + 0.5 + 0.3 * rng.signed()) / (n - 1) as f32;
            lerp(p.twig_start, 0.96, f.clamp(0.0, 1.0))
        };
        let pos = curve(t);
        let tan = tangent(t);
        let up = perpendicular(tan, Vec3::Y);
        let side = up.cross(tan); // (side, up, tan) is right-handed
        let dir = if terminal {
            tan
        } else {
            let lateral = match p.twig_arrangement {
                TwigArrangement::Planar => {
                    let s = if j % 2 == 0 { 1.0 } else { -1.0 };
                    // To the sides, hanging down a little and spread up and down, so that
                    // the branch has some thickness seen edge-on.
                    let tilt = (-20.0 + 25.0 * rng.signed()).to_radians();
                    side * (s * tilt.cos()) + up * tilt.sin()
                }
                TwigArrangement::Spiral => {
                    let r = j as f32 * GOLDEN_ANGLE + 0.3 * rng.signed();
                    side * r.cos() + up * r.sin()
                }
            };
            let a = twig_angle + 0.14 * rng.signed();
            (tan * a.cos() + lateral * a.sin())
                .try_normalize()
                .unwrap_or(tan)
        };
        // Roll each twig a little about its own axis so sprays are not all coplanar.
        let roll = 0.35 * rng.signed();
        let up0 = perpendicular(dir, up);
        let twig_up = (up0 * roll.cos() + dir.cross(up0) * roll.sin()).normalize_or_zero();
        let twig_x = twig_up.cross(dir);
        let scale = lerp(1.0, p.twig_tip_scale, t) * (1.0 + 0.08 * rng.signed());
        twigs.push(frame(twig_x, twig_up, dir, pos, scale));
    }
    (limb, twigs)
}

/// True when `q` (tree frame) is inside the crown envelope.
fn inside_crown(p: &SpeciesParams, q: Vec3) -> bool {
    let h = p.height;
    let yb = p.crown_base * h;
    let r = (q.x * q.x + q.z * q.z).sqrt();
    match p.crown {
        CrownShape::Conical => {
            if q.y > h || q.y < -h {
                return false;
            }
            let rad = p.crown_radius * ((h - q.y) / (h - yb).max(1e-3)).min(1.0);
            r <= rad
        }
        CrownShape::Rounded => {
            let lo = yb - 0.25 * (h - yb);
            let c = 0.5 * (lo + h);
            let a = (0.5 * (h - lo)).max(1e-3);
            let x = r / p.crown_radius;
            let y = (q.y - c) / a;
            x * x + y * y <= 1.0
        }
    }
}

/// Distance from `base` along `dir` to the crown envelope (0 when `base` is outside).
fn crown_distance(p: &SpeciesParams, base: Vec3, dir: Vec3) -> f32 {
    if !inside_crown(p, base) {
        return 0.0;
    }
    // The envelope is convex, so the ray leaves it once: bisect.
    let mut lo = 0.0;
    let mut hi = 4.0 * (p.height + p.crown_radius);
    for _ in 0..40 {
        let mid = 0.5 * (lo + hi);
        if inside_crown(p, base + dir * mid) {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    lo
}

/// Level 2: the trunk, the main-branch instances and the twigs on the trunk.
fn build_tree(p: &SpeciesParams, rng: &mut Rng, reach: f32) -> (Mesh, Vec<Mat4>, Vec<Mat4>) {
    let h = p.height;
    let trunk_end = p.trunk_height * h;
    let radius_at = |y: f32| {
        let f = (y / trunk_end).clamp(0.0, 1.0);
        lerp(p.trunk_radius, p.trunk_top_radius, f) * (1.0 + 0.3 * (-y.max(0.0) / 0.35).exp())
    };
    let mut centres = vec![Vec3::new(0.0, -TRUNK_SINK, 0.0)];
    let mut radii = vec![radius_at(0.0)];
    for k in 0..=TRUNK_SEGMENTS {
        // Denser rings near the ground for the root flare.
        let y = trunk_end * (k as f32 / TRUNK_SEGMENTS as f32).powf(1.5);
        centres.push(Vec3::new(0.0, y, 0.0));
        radii.push(radius_at(y));
    }
    let mut trunk = Mesh::default();
    trunk.add_tube(&centres, &radii, p.trunk_sides, Vec3::from(p.bark_color));

    let count = p.branch_count;
    let per = p.branches_per_whorl;
    let whorls = count.div_ceil(per);
    let spacing = (p.crown_top - p.crown_base) * h / whorls.max(1) as f32;
    let mut branches = Vec::with_capacity(count as usize);
    for b in 0..count {
        let k = b / per;
        let m = b % per;
        let f = if whorls > 1 {
            k as f32 / (whorls - 1) as f32
        } else {
            0.0
        };
        let jitter_y = if per == 1 {
            0.25 * spacing * rng.signed()
        } else {
            0.0
        };
        // Slightly closer together towards the top, where the branches are short.
        let y =
            (lerp(p.crown_base, p.crown_top, f.powf(0.85)) * h + jitter_y).clamp(0.0, trunk_end);
        let az = k as f32 * GOLDEN_ANGLE
            + m as f32 * TAU / per as f32
            + 0.2 * rng.signed() * (TAU / per as f32).min(1.0);
        let from_vertical = lerp(p.branch_angle_low, p.branch_angle_high, f) + 4.0 * rng.signed();
        let elev = FRAC_PI_2 - from_vertical.to_radians();
        let dir = Vec3::new(az.sin() * elev.cos(), elev.sin(), az.cos() * elev.cos());
        let base = Vec3::new(0.0, y, 0.0);
        // Fit the branch's reach to the envelope; short branches are shrunk a little less
        // than the envelope asks (fit^0.8) so that the top of the crown stays dense.
        let fit = crown_distance(p, base, dir) / reach.max(1e-3);
        let scale =
            fit.max(0.0).powf(0.8).clamp(p.branch_min_scale, 1.25) * (1.0 + 0.06 * rng.signed());
        let roll = 0.15 * rng.signed();
        branches.push(
            Mat4::from_translation(base)
                * Mat4::from_rotation_y(az)
                * Mat4::from_rotation_x(-elev)
                * Mat4::from_rotation_z(roll)
                * Mat4::from_scale(Vec3::splat(scale)),
        );
    }

    let mut twigs = Vec::with_capacity(p.leader_twigs as usize);
    for i in 0..p.leader_twigs {
        if i == 0 {
            // The leader: straight up from the end of the trunk.
            twigs.push(
                Mat4::from_translation(Vec3::new(0.0, trunk_end - 0.02 * h, 0.0))
                    * Mat4::from_rotation_x(-FRAC_PI_2),
            );
        } else {
            let az = i as f32 * TAU / (p.leader_twigs - 1) as f32 + 0.3 * rng.signed();
            let elev = (40.0 + 10.0 * rng.signed()).to_radians();
            let y = trunk_end - (0.03 + 0.02 * rng.f32()) * h;
            twigs.push(
                Mat4::from_translation(Vec3::new(0.0, y, 0.0))
                    * Mat4::from_rotation_y(az)
                    * Mat4::from_rotation_x(-elev)
                    * Mat4::from_scale(Vec3::splat(0.8)),
            );
        }
    }
    (trunk, branches, twigs)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::mesh::Aabb;
    use crate::model::species::preset;
    use crate::model::tree::PartCounts;

    fn model(name: &str) -> TreeModel {
        let p = preset(name).unwrap_or_default();
        match TreeModel::generate(&p, 7) {
            Ok(m) => m,
            Err(e) => panic!("{name}: {e}"),
        }
    }

    fn check_mesh(name: &str, m: &Mesh, foliage: Option<f32>) {
        assert_eq!(m.indices.len() % 3, 0);
        for v in &m.vertices {
            let p = Vec3::from(v.position);
            assert!(p.is_finite(), "{name}: position {p}");
            let n = Vec3::from(v.normal);
            assert!((n.length() - 1.0).abs() < 1e-3, "{name}: normal {n}");
            assert!(
                v.color.iter().all(|c| (0.0..=1.0).contains(c)),
                "{name}: colour {:?}",
                v.color
            );
            if let Some(f) = foliage {
                assert_eq!(v.foliage, f, "{name}");
            }
        }
        // Winding agrees with the normals: counter-clockwise seen from the normal's side.
        let mut bad = 0;
        for t in m.indices.chunks_exact(3) {
            assert!(
                t.iter().all(|&i| (i as usize) < m.vertices.len()),
                "{name}: index"
            );
            let p = |i: u32| Vec3::from(m.vertices[i as usize].position);
            let face = (p(t[1]) - p(t[0])).cross(p(t[2]) - p(t[0]));
            let vn: Vec3 = t
                .iter()
                .map(|&i| Vec3::from(m.vertices[i as usize].normal))
                .sum();
            if face.length() > 1e-12 && face.dot(vn) <= 0.0 {
                bad += 1;
            }
        }
        assert_eq!(bad, 0, "{name}: triangles wound against their normals");
    }

    #[test]
    fn fir_is_a_mature_fir_of_the_thesis_triangles() {
        let fir = model("fir");
        let c = fir.counts();
        let t = fir.triangle_counts();
        // Twice the thesis' 30 main branches and 300 twigs (with those, light passes through
        // the crown), in about its 120,000 polygons.
        assert_eq!(c.main_branches, 64);
        assert!((600..=700).contains(&c.twigs), "{c:?}");
        assert!((50_000..=65_000).contains(&c.foliage), "{c:?}");
        assert!((100_000..=130_000).contains(&t.tree), "{t:?}");
        assert_eq!(fir.branch_twigs.len(), 10);
        assert_eq!(fir.foliage, FoliageKind::Needles);
        let height = fir.tree_bounds.max.y;
        assert!((15.0..=20.0).contains(&height), "height {height}");
        // Needles are 2 triangles each, the stem 6.
        assert_eq!(t.twig, 2 * u64::from(fir.foliage_per_twig) + 6);
        assert_eq!(
            t.branch,
            fir.branch_limb.triangle_count() as u64 + 10 * t.twig
        );
    }

    /// Every preset's crown covers at least this share of its side silhouette's hull
    /// (mean of four azimuths): "from the side, foliage covers most of the crown". The
    /// presets measure about 0.65 (fir), 0.67 (broadleaf) and 0.61 (pine).
    const MIN_CROWN_COVERAGE: f32 = 0.55;

    #[test]
    fn every_preset_crown_is_covered_from_the_side() {
        use crate::model::silhouette::crown_coverage;
        for name in crate::model::PRESET_NAMES {
            let p = preset(name).unwrap_or_default();
            for seed in [1, 7, 11] {
                let Ok(m) = TreeModel::generate(&p, seed) else {
                    panic!("{name}");
                };
                let c = crown_coverage(&m);
                assert!(
                    c.mean >= MIN_CROWN_COVERAGE,
                    "{name} (seed {seed}): crown {:.3} covered from the side, below {MIN_CROWN_COVERAGE}: {c:?}",
                    c.mean
                );
            }
        }
        // The fir of the thesis' counts (30 main branches, 300 twigs in flat sprays, as the
        // preset was before) fails the bound: light passes through it.
        let thesis = SpeciesParams {
            crown_radius: 4.2,
            branch_count: 30,
            branch_length: 3.4,
            branch_min_scale: 0.25,
            twig_arrangement: TwigArrangement::Planar,
            twig_length: 1.5,
            twig_start: 0.12,
            twig_tip_scale: 0.6,
            foliage_per_twig: 140,
            foliage_length: 0.3,
            foliage_width: 0.045,
            foliage_angle: 65.0,
            ..SpeciesParams::default()
        };
        let Ok(m) = TreeModel::generate(&thesis, 1) else {
            panic!("thesis fir");
        };
        let c = crown_coverage(&m).mean;
        assert!(c < 0.35, "the thesis-count fir covers {c}");
    }

    #[test]
    fn broadleaf_is_a_rounded_leafy_tree() {
        let tree = model("broadleaf");
        let c = tree.counts();
        let t = tree.triangle_counts();
        assert!((20..=28).contains(&c.main_branches), "{c:?}");
        assert!((60_000..=110_000).contains(&t.tree), "{t:?}");
        assert_eq!(tree.foliage, FoliageKind::Leaves);
        // Leaves are 4 triangles each, the stem 6.
        assert_eq!(t.twig, 4 * u64::from(tree.foliage_per_twig) + 6);
        let height = tree.tree_bounds.max.y;
        assert!((10.0..=14.5).contains(&height), "height {height}");
        let ext = tree.tree_bounds.extent();
        assert!(ext.x > 6.0 && ext.z > 6.0, "crown too narrow: {ext}");
    }

    #[test]
    fn meshes_are_well_formed() {
        for name in ["fir", "broadleaf"] {
            let m = model(name);
            check_mesh(&format!("{name} trunk"), &m.trunk, Some(0.0));
            check_mesh(&format!("{name} limb"), &m.branch_limb, Some(0.0));
            check_mesh(&format!("{name} twig"), &m.twig, None);
            let leaves = m.twig.vertices.iter().filter(|v| v.foliage == 1.0).count();
            let per = if name == "fir" { 4 } else { 6 };
            assert_eq!(leaves, m.foliage_per_twig as usize * per);
            // The twig's stem is bark.
            assert!(m.twig.vertices.iter().any(|v| v.foliage == 0.0));
            // The twig grows along +Z from its base.
            assert!(m.twig_bounds.min.z > -0.05 && m.twig_bounds.max.z > 0.5);
            assert!(m.branch_bounds.max.z > 1.0);
        }
    }

    #[test]
    fn bounds_cover_the_flattened_tree() {
        for name in ["fir", "broadleaf"] {
            let m = model(name);
            let flat = m.flatten();
            assert_eq!(flat.triangle_count() as u64, m.triangle_counts().tree);
            let b = flat.bounds();
            assert!(
                (b.min - m.tree_bounds.min).abs().max_element() < 1e-3
                    && (b.max - m.tree_bounds.max).abs().max_element() < 1e-3,
                "{name}: {b:?} vs {:?}",
                m.tree_bounds
            );
            let branch = m.flatten_branch().bounds();
            assert!((branch.min - m.branch_bounds.min).abs().max_element() < 1e-4);
            assert!((branch.max - m.branch_bounds.max).abs().max_element() < 1e-4);
            assert_eq!(
                m.twigs_in_tree_frame().len() as u64,
                m.counts().twigs,
                "{name}"
            );
            // Every twig instance lies inside the tree bounds.
            for t in m.twigs_in_tree_frame() {
                let tb = m.twig_bounds.transformed(t);
                let grown = Aabb::new(m.tree_bounds.min - 0.5, m.tree_bounds.max + 0.5);
                assert!(grown.contains(tb.center()), "{name}");
            }
        }
    }

    #[test]
    fn generation_is_deterministic() {
        let p = SpeciesParams::default();
        let a = TreeModel::generate(&p, 11).ok();
        let b = TreeModel::generate(&p, 11).ok();
        let c = TreeModel::generate(&p, 12).ok();
        let (Some(a), Some(b), Some(c)) = (a, b, c) else {
            panic!("generation failed");
        };
        assert_eq!(a.twig.vertices, b.twig.vertices);
        assert_eq!(a.twig.indices, b.twig.indices);
        assert_eq!(a.branch_twigs, b.branch_twigs);
        assert_eq!(a.tree_branches, b.tree_branches);
        assert_eq!(a.tree_bounds, b.tree_bounds);
        assert_ne!(a.twig.vertices, c.twig.vertices);
        assert_ne!(a.tree_branches, c.tree_branches);
    }

    #[test]
    fn fir_silhouette_is_a_cone() {
        let fir = model("fir");
        let flat = fir.flatten();
        let h = fir.tree_bounds.max.y;
        let mut width = [0.0f32; 3];
        for v in &flat.vertices {
            let p = Vec3::from(v.position);
            let band = ((p.y / h * 3.0) as usize).min(2);
            width[band] = width[band].max((p.x * p.x + p.z * p.z).sqrt());
        }
        assert!(width[0] > width[1] && width[1] > width[2], "{width:?}");
        assert!(width[0] > 2.5 && width[0] < 6.0, "{width:?}");
    }

    #[test]
    fn branches_are_rigid_with_uniform_scale() {
        for name in ["fir", "broadleaf"] {
            let m = model(name);
            for b in m
                .tree_branches
                .iter()
                .chain(m.branch_twigs.iter())
                .chain(m.tree_twigs.iter())
            {
                let (sx, sy, sz) = (
                    b.x_axis.truncate().length(),
                    b.y_axis.truncate().length(),
                    b.z_axis.truncate().length(),
                );
                assert!((sx - sy).abs() < 1e-4 && (sy - sz).abs() < 1e-4, "{name}");
                assert!(b.x_axis.truncate().dot(b.y_axis.truncate()).abs() < 1e-4);
                assert!(glam::Mat3::from_mat4(*b).determinant() > 0.0);
            }
        }
    }

    #[test]
    fn invalid_parameters_are_rejected() {
        let p = SpeciesParams {
            branch_count: 100_000,
            ..SpeciesParams::default()
        };
        let err = TreeModel::generate(&p, 1).err().map(|e| e.to_string());
        let msg = err.unwrap_or_default();
        assert!(msg.contains("branch_count"), "{msg}");
    }

    #[test]
    fn zero_counts_are_allowed() {
        let p = SpeciesParams {
            branch_count: 0,
            twigs_per_branch: 0,
            leader_twigs: 0,
            foliage_per_twig: 0,
            ..SpeciesParams::default()
        };
        let m = TreeModel::generate(&p, 1);
        let Ok(m) = m else {
            panic!("zero counts rejected")
        };
        assert_eq!(m.counts(), PartCounts::default());
        assert!(!m.tree_bounds.is_empty());
    }
}
