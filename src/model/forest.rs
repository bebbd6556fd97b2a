//! Forest placement: seeded dart throwing with a minimum spacing between trunks
//! (grid-accelerated, bounded number of attempts), each tree standing on the terrain with a
//! species drawn by weight, a yaw, a scale and a foliage tint.
//!
//! Either `count` trees spread evenly, or `density` trees per hectare modulated by the
//! stand field of `[forest.stands]` (see [`super::stands`]): a dart is kept with the
//! probability of the local density factor f, and its spacing is `min_spacing / sqrt(f)`
//! (at most twice `min_spacing`), so that dart throwing packs every part of the forest to
//! the same fraction of its saturation and the density follows f. The number of trees is
//! the density times the integral of f.

use glam::{Mat4, Vec2, Vec3};

use super::ModelError;
use super::params::{ForestParams, MAX_TREES};
use super::rng::{Rng, mix64};
use super::stands::{StandField, StandMap, height_range, normalise};
use super::terrain::{Terrain, fbm};

/// Largest number of grid cells per side of the placement acceleration grid.
const MAX_GRID: usize = 1024;
/// Dart-throwing attempts per requested tree (plus a fixed allowance).
const ATTEMPTS_PER_TREE: u64 = 60;
/// Where the density is below full, the spacing widens by 1/sqrt(f), at most this much.
const MAX_SPACING_STRETCH: f32 = 2.0;
/// Wavelength of the species patches of `mix_high` (m).
const PATCH_SIZE_M: f32 = 120.0;
/// How far the patch noise moves the height at which species change (fraction of the
/// relief, per unit of noise).
const PATCH_STRENGTH: f32 = 0.35;
/// The band of (height + patch) over which the weights go from `mix` to `mix_high`.
const PATCH_BAND: (f32, f32) = (0.35, 0.65);

/// One tree of the forest.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TreeInstance {
    /// Index into the world's species list.
    pub species: u32,
    /// Base of the trunk, on the terrain surface (m).
    pub position: Vec3,
    /// Rotation about +Y (radians).
    pub yaw: f32,
    /// Uniform scale (1 = the species' size).
    pub scale: f32,
    /// Multiplicative foliage colour variation around 1.0.
    pub tint: Vec3,
}

impl TreeInstance {
    /// Tree frame to world: translate * rotate_y(yaw) * uniform scale.
    pub fn transform(&self) -> Mat4 {
        Mat4::from_translation(self.position)
            * Mat4::from_rotation_y(self.yaw)
            * Mat4::from_scale(Vec3::splat(self.scale))
    }
}

/// All placed trees.
#[derive(Clone, Debug, Default)]
pub struct Forest {
    /// The trees, in placement order.
    pub instances: Vec<TreeInstance>,
    /// Where the stands lie, when placed by `[forest.stands]`: the far forest cover
    /// continues them past the square.
    pub stands: Option<StandField>,
}

/// Uniform grid over the placement square; each cell is at least `min_spacing` wide, so any
/// neighbour closer than the spacing is in the 3x3 cells around a point.
struct Grid {
    origin: f32,
    cell: f32,
    cells: usize,
    head: Vec<u32>,
    next: Vec<u32>,
}

impl Grid {
    fn new(origin: f32, span: f32, min_spacing: f32) -> Grid {
        let cell = min_spacing.max(span / MAX_GRID as f32).max(1e-6);
        let cells = ((span / cell).ceil() as usize).clamp(1, MAX_GRID);
        Grid {
            origin,
            cell,
            cells,
            head: vec![u32::MAX; cells * cells],
            next: Vec::new(),
        }
    }

    fn cell_of(&self, p: Vec2) -> (usize, usize) {
        let c = |v: f32| (((v - self.origin) / self.cell).max(0.0) as usize).min(self.cells - 1);
        (c(p.x), c(p.y))
    }

    fn is_free(&self, points: &[Vec2], p: Vec2, min_sq: f32) -> bool {
        let (ci, cj) = self.cell_of(p);
        for j in cj.saturating_sub(1)..=(cj + 1).min(self.cells - 1) {
            for i in ci.saturating_sub(1)..=(ci + 1).min(self.cells - 1) {
                let mut k = self.head[j * self.cells + i];
                while k != u32::MAX {
                    if points[k as usize].distance_squared(p) < min_sq {
                        return false;
                    }
                    k = self.next[k as usize];
                }
            }
        }
        true
    }

    fn insert(&mut self, index: u32, p: Vec2) {
        let (i, j) = self.cell_of(p);
        let slot = j * self.cells + i;
        self.next.push(self.head[slot]);
        self.head[slot] = index;
    }
}

/// Picks a species by `weights` with a uniform draw `u` in 0..1; never a zero-weight one.
fn pick_species(weights: &[f32], u: f32) -> u32 {
    let total: f32 = weights.iter().sum();
    let mut pick = u * total;
    let mut species = 0u32;
    for (i, w) in weights.iter().enumerate() {
        species = i as u32;
        if pick < *w {
            break;
        }
        pick -= w;
    }
    // Never pick a zero-weight species through rounding at the end of the list.
    while weights.get(species as usize).is_some_and(|w| *w <= 0.0) && species > 0 {
        species -= 1;
    }
    species
}

/// Where between `mix` (0) and `mix_high` (1) a tree at `q` draws its species: the ground's
/// height over the relief, moved up or down by a patch noise so that species meet in
/// patches and tongues rather than along contour lines.
fn species_height(terrain: &Terrain, (lo, hi): (f32, f32), patch_seed: u64, q: Vec2) -> f32 {
    let patch = fbm(patch_seed, q / PATCH_SIZE_M, 3, 0.5);
    let t = normalise(terrain.height_at(q.x, q.y), lo, hi) + PATCH_STRENGTH * patch;
    // Steepened around mid-height, so that most trees stand in a patch of one kind.
    let t = ((t - PATCH_BAND.0) / (PATCH_BAND.1 - PATCH_BAND.0)).clamp(0.0, 1.0);
    t * t * (3.0 - 2.0 * t)
}

impl Forest {
    /// Places `p.count` trees, or `p.density` trees per hectare over the stand field, on
    /// `terrain`, choosing among `species_count` species by the weights in `p.mix` (and
    /// `p.mix_high`). Deterministic for its inputs. Fails with
    /// [`ModelError::ForestDoesNotFit`] when the trees cannot be placed at the spacing.
    pub fn place(
        p: &ForestParams,
        terrain: &Terrain,
        species_count: usize,
    ) -> Result<Forest, ModelError> {
        Forest::place_variants(p, terrain, &vec![1; species_count])
    }

    /// [`Forest::place`] for species of `variants[i]` prototypes each: a tree draws its
    /// species by `mix`, then one of its variants uniformly; its `species` is the index of
    /// that prototype, counting every species' variants in order. A species of one variant
    /// draws nothing more, so such scenes place as before.
    pub fn place_variants(
        p: &ForestParams,
        terrain: &Terrain,
        variants: &[u32],
    ) -> Result<Forest, ModelError> {
        let species_count = variants.len();
        let first: Vec<u32> = variants
            .iter()
            .scan(0u32, |acc, v| {
                let at = *acc;
                *acc += (*v).max(1);
                Some(at)
            })
            .collect();
        p.check(species_count)
            .map_err(|e| ModelError::invalid("forest", e))?;
        super::check::positive("size", terrain.size)
            .map_err(|e| ModelError::invalid("terrain", e))?;
        let half = 0.5 * terrain.size;
        // Keep trunks a little inside the terrain's edge.
        let margin = (0.5 * p.min_spacing).min(0.25 * terrain.size);
        let lo = -half + margin;
        let span = 2.0 * (half - margin);
        let stands = p
            .stands
            .as_ref()
            .filter(|_| p.density.is_some())
            .map(|st| StandMap::build(st, p.seed, terrain));
        let (n, asked_by) = match (p.count, p.density) {
            (Some(c), _) => (c as usize, "forest.count"),
            (None, Some(d)) => {
                let area = stands
                    .as_ref()
                    .map_or(f64::from(span) * f64::from(span), |m| m.integral(lo, span));
                let expected = (f64::from(d) / 10_000.0 * area).round();
                if expected > f64::from(MAX_TREES) {
                    return Err(ModelError::invalid(
                        "forest",
                        super::FieldError::new(
                            "density",
                            format!(
                                "gives {expected} trees on this terrain, more than the {MAX_TREES} allowed; \
                                 lower forest.density{}",
                                if stands.is_some() { " or forest.stands.cover" } else { "" }
                            ),
                        )
                        .with_found(d),
                    ));
                }
                (expected as usize, "forest.density")
            }
            (None, None) => (0, "forest.count"),
        };
        if n == 0 {
            return Ok(Forest::default());
        }
        let stretch = if stands.is_some() {
            MAX_SPACING_STRETCH
        } else {
            1.0
        };
        let mut grid = Grid::new(lo, span, p.min_spacing * stretch);
        let min_sq = p.min_spacing * p.min_spacing;
        let mut points: Vec<Vec2> = Vec::with_capacity(n);
        let mut rng = Rng::derive(p.seed, 0);
        let max_attempts = n as u64 * ATTEMPTS_PER_TREE + 1000;
        let mut attempts = 0u64;
        while points.len() < n && attempts < max_attempts {
            attempts += 1;
            let q = Vec2::new(lo + span * rng.f32(), lo + span * rng.f32());
            let spacing_sq = match &stands {
                None => min_sq,
                Some(m) => {
                    let f = m.factor_at(q.x, q.y);
                    if rng.f32() >= f {
                        continue;
                    }
                    min_sq * (1.0 / f).min(stretch * stretch)
                }
            };
            if grid.is_free(&points, q, spacing_sq) {
                grid.insert(points.len() as u32, q);
                points.push(q);
            }
        }
        if points.len() < n {
            return Err(ModelError::ForestDoesNotFit {
                placed: points.len() as u32,
                requested: n as u32,
                min_spacing: p.min_spacing,
                size: terrain.size,
                attempts,
                asked_by,
            });
        }

        // Attributes come from their own stream, so positions do not depend on them.
        let mut rng = Rng::derive(p.seed, 1);
        let patch_seed = mix64(p.seed ^ 0x0050_4154_4348_4553); // "PATCHES"
        let range = height_range(terrain);
        let mut weights = p.mix.clone();
        let instances = points
            .iter()
            .map(|q| {
                if let Some(high) = &p.mix_high {
                    let t = species_height(terrain, range, patch_seed, *q);
                    for ((w, a), b) in weights.iter_mut().zip(&p.mix).zip(high) {
                        *w = a + (b - a) * t;
                    }
                }
                let entry = pick_species(&weights, rng.f32()) as usize;
                let k = variants.get(entry).copied().unwrap_or(1).max(1);
                let variant = if k > 1 { rng.below(k) } else { 0 };
                let species = first.get(entry).copied().unwrap_or(0) + variant;
                let yaw_draw = rng.f32() * std::f32::consts::TAU;
                let yaw = if p.random_yaw { yaw_draw } else { 0.0 };
                let scale = p.scale_min + (p.scale_max - p.scale_min) * rng.f32();
                let tv = p.tint_variation;
                let brightness = 1.0 + tv * rng.signed();
                let tint = Vec3::new(
                    brightness * (1.0 + 0.3 * tv * rng.signed()),
                    brightness,
                    brightness * (1.0 + 0.3 * tv * rng.signed()),
                )
                .max(Vec3::ZERO);
                // Stand on the lowest ground around the trunk so it never floats on a slope.
                let r = 0.4 * scale;
                let y = [(0.0, 0.0), (r, 0.0), (-r, 0.0), (0.0, r), (0.0, -r)]
                    .iter()
                    .map(|(dx, dz)| terrain.height_at(q.x + dx, q.y + dz))
                    .fold(f32::INFINITY, f32::min);
                TreeInstance {
                    species,
                    position: Vec3::new(q.x, y, q.y),
                    yaw,
                    scale,
                    tint,
                }
            })
            .collect();
        Ok(Forest {
            instances,
            stands: stands.as_ref().map(StandMap::field),
        })
    }

    /// Number of trees of each species (`species_count` entries).
    pub fn species_histogram(&self, species_count: usize) -> Vec<usize> {
        let mut h = vec![0; species_count];
        for t in &self.instances {
            if let Some(c) = h.get_mut(t.species as usize) {
                *c += 1;
            }
        }
        h
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::params::{StandParams, TerrainParams};
    use crate::model::stands::Cover;

    fn terrain() -> Terrain {
        let p = TerrainParams {
            size: 400.0,
            resolution: 65,
            seed: 5,
            relief: 30.0,
            feature_size: 150.0,
            ..TerrainParams::default()
        };
        match Terrain::generate(&p) {
            Ok(t) => t,
            Err(e) => panic!("{e}"),
        }
    }

    fn params(count: u32) -> ForestParams {
        ForestParams {
            count: Some(count),
            seed: 9,
            min_spacing: 6.0,
            mix: vec![0.6, 0.4],
            scale_min: 0.8,
            scale_max: 1.2,
            random_yaw: true,
            tint_variation: 0.15,
            ..ForestParams::default()
        }
    }

    #[test]
    fn places_the_count_with_spacing_on_the_ground() {
        let t = terrain();
        let f = match Forest::place(&params(500), &t, 2) {
            Ok(f) => f,
            Err(e) => panic!("{e}"),
        };
        assert_eq!(f.instances.len(), 500);
        for (i, a) in f.instances.iter().enumerate() {
            assert!(a.position.x.abs() <= 200.0 && a.position.z.abs() <= 200.0);
            let ground = t.height_at(a.position.x, a.position.z);
            assert!(a.position.y <= ground + 1e-4 && a.position.y > ground - 1.0);
            assert!((0.8..=1.2).contains(&a.scale));
            assert!(a.species < 2);
            assert!((0.0..std::f32::consts::TAU).contains(&a.yaw));
            assert!(a.tint.min_element() > 0.7 && a.tint.max_element() < 1.3);
            for b in &f.instances[i + 1..] {
                let d = Vec2::new(a.position.x - b.position.x, a.position.z - b.position.z);
                assert!(d.length() >= 6.0 - 1e-4, "trees {d} apart");
            }
        }
        let h = f.species_histogram(2);
        assert!((250..=350).contains(&h[0]), "{h:?}");
        // Spread over the whole terrain, not a clump: every quadrant has trees.
        for (sx, sz) in [(1.0, 1.0), (1.0, -1.0), (-1.0, 1.0), (-1.0, -1.0)] {
            let q = f
                .instances
                .iter()
                .filter(|t| t.position.x * sx > 0.0 && t.position.z * sz > 0.0)
                .count();
            assert!(q > 80, "quadrant has {q}");
        }
    }

    #[test]
    fn deterministic() {
        let t = terrain();
        let a = Forest::place(&params(200), &t, 2)
            .map(|f| f.instances)
            .unwrap_or_default();
        let b = Forest::place(&params(200), &t, 2)
            .map(|f| f.instances)
            .unwrap_or_default();
        assert_eq!(a.len(), 200);
        assert_eq!(a, b);
        let mut p = params(200);
        p.seed = 10;
        let c = Forest::place(&p, &t, 2)
            .map(|f| f.instances)
            .unwrap_or_default();
        assert_ne!(a, c);
    }

    #[test]
    fn too_many_trees_is_a_clear_error() {
        let t = terrain();
        // 400 m square at 6 m spacing holds roughly 2,500 by dart throwing, not 5,000.
        let e = Forest::place(&params(5000), &t, 2).err();
        let Some(ModelError::ForestDoesNotFit {
            placed, requested, ..
        }) = &e
        else {
            panic!("expected ForestDoesNotFit, got {e:?}");
        };
        assert_eq!(*requested, 5000);
        assert!(*placed > 1000 && *placed < 5000);
        let msg = e.map(|e| e.to_string()).unwrap_or_default();
        assert!(
            msg.contains("forest.count")
                && msg.contains("forest.min_spacing")
                && msg.contains("only"),
            "{msg}"
        );
    }

    #[test]
    fn zero_weight_species_is_never_chosen_and_yaw_can_be_fixed() {
        let t = terrain();
        let mut p = params(300);
        p.mix = vec![0.0, 1.0, 0.0];
        p.random_yaw = false;
        let f = Forest::place(&p, &t, 3)
            .map(|f| f.instances)
            .unwrap_or_default();
        assert_eq!(f.len(), 300);
        assert!(f.iter().all(|t| t.species == 1 && t.yaw == 0.0));
    }

    fn dense(seed: u64) -> ForestParams {
        ForestParams {
            count: None,
            density: Some(500.0),
            seed,
            min_spacing: 2.5,
            mix: vec![0.1, 0.9],
            mix_high: Some(vec![0.9, 0.1]),
            stands: Some(StandParams {
                cover: 0.6,
                size: 150.0,
                edge: 15.0,
                meadows: 0.12,
            }),
            ..ForestParams::default()
        }
    }

    #[test]
    fn density_holds_inside_stands_and_clearings_stay_empty() {
        let t = terrain();
        let p = dense(21);
        let f = match Forest::place(&p, &t, 2) {
            Ok(f) => f,
            Err(e) => panic!("{e}"),
        };
        let Some(st) = &p.stands else {
            panic!("stands")
        };
        let map = StandMap::build(st, p.seed, &t);
        // The interior of the stands (full density all around), measured on a 1 m grid.
        let mut interior_m2 = 0u32;
        for j in 0..400 {
            for i in 0..400 {
                let (x, z) = (-199.5 + i as f32, -199.5 + j as f32);
                if map.is_interior(x, z, 0.0) {
                    interior_m2 += 1;
                }
            }
        }
        assert!(interior_m2 > 20_000, "interior {interior_m2} m2");
        let inside = f
            .instances
            .iter()
            .filter(|t| map.is_interior(t.position.x, t.position.z, 0.0))
            .count();
        let per_ha = inside as f32 / interior_m2 as f32 * 10_000.0;
        // Measured: 484 trees per hectare asked 500 (3,733 trees).
        assert!((per_ha - 500.0).abs() <= 50.0, "{per_ha} trees/ha");
        // None in a clearing or a meadow.
        for t in &f.instances {
            let c = map.cover_at(t.position.x, t.position.z);
            assert_eq!(c, Cover::Stand, "a tree at {} in {c:?}", t.position);
        }
        // Clearings and meadows both exist.
        let [stand, clearing, meadow] = map.shares();
        assert!(
            stand > 0.5 && clearing > 0.05 && meadow > 0.005,
            "{stand} {clearing} {meadow}"
        );
        // Spacing: never closer than min_spacing.
        let pts: Vec<Vec2> = f
            .instances
            .iter()
            .map(|t| Vec2::new(t.position.x, t.position.z))
            .collect();
        for (i, a) in pts.iter().enumerate().step_by(7) {
            for b in &pts[i + 1..] {
                assert!(a.distance(*b) >= 2.5 - 1e-4);
            }
        }
        // Firs (species 0) on the heights, broadleaves in the valleys.
        let (lo, hi) = height_range(&t);
        let mean_h = |s: u32| {
            let hs: Vec<f32> = f
                .instances
                .iter()
                .filter(|t| t.species == s)
                .map(|t| normalise(t.position.y, lo, hi))
                .collect();
            hs.iter().sum::<f32>() / hs.len().max(1) as f32
        };
        // Measured: firs at 0.619 of the relief on average, broadleaves at 0.455.
        assert!(mean_h(0) > mean_h(1) + 0.1, "{} {}", mean_h(0), mean_h(1));
    }

    #[test]
    fn density_is_deterministic_by_seed() {
        let t = terrain();
        let place = |seed| {
            Forest::place(&dense(seed), &t, 2)
                .map(|f| f.instances)
                .unwrap_or_default()
        };
        let a = place(4);
        assert!(a.len() > 1000, "{}", a.len());
        assert_eq!(a, place(4));
        assert_ne!(a, place(5));
    }

    #[test]
    fn uniform_density_gives_its_count_and_too_dense_is_refused() {
        let t = terrain();
        let p = ForestParams {
            count: None,
            density: Some(100.0),
            min_spacing: 4.0,
            ..params(0)
        };
        let f = Forest::place(&p, &t, 2)
            .map(|f| f.instances.len())
            .unwrap_or(0);
        // 396 m of the 400 m square inside the 2 m margin: 15.68 ha.
        assert_eq!(f, (100.0f32 * 396.0 * 396.0 / 10_000.0).round() as usize);
        // Too dense for the spacing: the error names the density.
        let p = ForestParams {
            density: Some(2000.0),
            ..p
        };
        let e = Forest::place(&p, &t, 2)
            .err()
            .map(|e| e.to_string())
            .unwrap_or_default();
        assert!(e.contains("forest.density") && e.contains("only"), "{e}");
        // More than the format allows.
        let big = Terrain::flat(20_000.0, 2);
        let p = ForestParams {
            density: Some(5.0),
            min_spacing: 1.0,
            ..p
        };
        let e = Forest::place(&p, &big, 2)
            .err()
            .map(|e| e.to_string())
            .unwrap_or_default();
        assert!(e.contains("forest.density") && e.contains("100000"), "{e}");
    }

    #[test]
    fn transform_is_translate_rotate_scale() {
        let t = TreeInstance {
            species: 0,
            position: Vec3::new(1.0, 2.0, 3.0),
            yaw: std::f32::consts::FRAC_PI_2,
            scale: 2.0,
            tint: Vec3::ONE,
        };
        let m = t.transform();
        let p = m.transform_point3(Vec3::new(1.0, 1.0, 0.0));
        // +X rotated 90 degrees about Y is -Z.
        assert!((p - Vec3::new(1.0, 4.0, 1.0)).length() < 1e-5, "{p}");
    }

    #[test]
    fn invalid_parameters_are_rejected() {
        let t = terrain();
        let e = Forest::place(&params(10), &t, 3)
            .err()
            .map(|e| e.to_string())
            .unwrap_or_default();
        assert!(e.contains("mix"), "{e}");
        let mut p = params(10);
        p.count = Some(1_000_000);
        let e = Forest::place(&p, &t, 2)
            .err()
            .map(|e| e.to_string())
            .unwrap_or_default();
        assert!(e.contains("count"), "{e}");
    }
}
