//! Where a forest stands: the density field of `[forest] density` with `[forest.stands]`.
//!
//! A seeded noise field over the terrain is cut at the level that leaves `cover` of the
//! land in stands; the rest is clearings. Valley floors (the lowest `meadows` of the
//! relief) are meadows and never stands. Inside a stand the density rises from 0 at its
//! border to full `edge` metres in (a chamfer distance transform over the cells), so a
//! stand has an edge of young, sparse trees rather than a wall. The field is sampled on
//! cells of about 2 m; queries are bilinear between cell centres.

use glam::Vec2;

use super::params::StandParams;
use super::rng::mix64;
use super::terrain::{Terrain, fbm};

/// Largest number of cells per side of the field.
const MAX_CELLS: usize = 1024;
/// Cell side aimed at (m).
const CELL_M: f32 = 2.0;
/// Octaves of the stand noise: stands have ragged borders, not blobs.
const STAND_OCTAVES: u32 = 4;

/// What covers the land in a cell.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Cover {
    /// In a stand (its density factor may still be below 1 near its edge).
    Stand,
    /// A clearing: the noise field is below its cut.
    Clearing,
    /// A meadow on a valley floor.
    Meadow,
}

/// The density factor (0..=1) of every cell of the terrain.
#[derive(Clone, Debug)]
pub struct StandMap {
    /// World x (and z) of the first cell's lower corner.
    origin: f32,
    /// Cell side (m).
    cell: f32,
    /// Cells per side.
    cells: usize,
    /// Density factor per cell, row-major (z rows, x columns).
    factor: Vec<f32>,
    /// Cover per cell.
    cover: Vec<Cover>,
    /// Edge width (m): a stand cell at least this far from its border is at full density.
    edge: f32,
    /// Distance of each cell's centre from the nearest cell that is not a stand (m).
    inside: Vec<f32>,
    /// The noise and its cut, to continue the stands past the square.
    field: StandField,
}

/// The stand noise and the level it was cut at: where the stands lie, evaluable anywhere
/// (past the terrain's square too, for the far forest cover of
/// [`crate::model::far_cover`]). Inside the square it agrees with [`StandMap::cover_at`]
/// up to the map's 2 m cells.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct StandField {
    noise_seed: u64,
    /// Wavelength of the noise (m).
    size: f32,
    /// Noise level at and above which the land is a stand.
    cut: f32,
    /// Valley floors below this fraction of the relief are meadows.
    meadows: f32,
    /// The terrain square's height range, for the meadows.
    lo: f32,
    hi: f32,
}

impl StandField {
    /// The stand noise at `(x, z)`.
    fn noise(&self, x: f32, z: f32) -> f32 {
        stand_noise(self.noise_seed, self.size, x, z)
    }

    /// How much of the land around `(x, z)` (ground height `ground`) is in stands, 0..=1,
    /// seen at a footprint of `footprint` metres: 0 or 1 where the footprint is small
    /// against the stands, a soft edge as it grows, and the field's `share` of stands
    /// once it spans several of them (so that far, coarse cells average rather than alias).
    pub fn stand_weight(&self, x: f32, z: f32, ground: f32, footprint: f32, share: f32) -> f32 {
        if self.meadows > 0.0 && normalise(ground, self.lo, self.hi) < self.meadows {
            return 0.0;
        }
        if !self.cut.is_finite() {
            return if self.cut < 0.0 { 1.0 } else { 0.0 };
        }
        let r = (footprint / self.size).max(0.0);
        // The noise's amplitude is about 0.5: a soft edge a fraction of it wide.
        let soft = (0.6 * r).clamp(1e-3, 0.5);
        let sharp = smoothstep(self.cut - soft, self.cut + soft, self.noise(x, z));
        let blur = smoothstep(0.25, 1.0, r);
        sharp + (share - sharp) * blur
    }
}

/// The lowest and highest height of the terrain's grid.
pub fn height_range(terrain: &Terrain) -> (f32, f32) {
    terrain
        .heights
        .iter()
        .fold((f32::INFINITY, f32::NEG_INFINITY), |(a, b), &h| {
            (a.min(h), b.max(h))
        })
}

/// Height `h` as a fraction of the range `lo..hi` (0.5 on a flat terrain).
pub fn normalise(h: f32, lo: f32, hi: f32) -> f32 {
    if hi - lo > 1e-6 {
        ((h - lo) / (hi - lo)).clamp(0.0, 1.0)
    } else {
        0.5
    }
}

/// The stand noise of wavelength `size` at `(x, z)`: the map's cells and the field past
/// the square read the same sum.
fn stand_noise(seed: u64, size: f32, x: f32, z: f32) -> f32 {
    fbm(seed, Vec2::new(x, z) / size, STAND_OCTAVES, 0.5)
}

fn smoothstep(e0: f32, e1: f32, x: f32) -> f32 {
    if e1 <= e0 {
        return if x >= e0 { 1.0 } else { 0.0 };
    }
    let t = ((x - e0) / (e1 - e0)).clamp(0.0, 1.0);
    t * t * (3.0 - 2.0 * t)
}

impl StandMap {
    /// The stand field of `p` over `terrain`, seeded by the forest's `seed`.
    pub fn build(p: &StandParams, seed: u64, terrain: &Terrain) -> StandMap {
        let size = terrain.size.max(1e-3);
        let cells = ((size / CELL_M).ceil() as usize).clamp(16, MAX_CELLS);
        let cell = size / cells as f32;
        let origin = -0.5 * size;
        let (lo, hi) = height_range(terrain);
        let noise_seed = mix64(seed ^ 0x5354_414E_4453); // "STANDS"
        let centre = |i: usize| origin + (i as f32 + 0.5) * cell;
        let mut noise = Vec::with_capacity(cells * cells);
        let mut meadow = Vec::with_capacity(cells * cells);
        for j in 0..cells {
            for i in 0..cells {
                let (x, z) = (centre(i), centre(j));
                noise.push(stand_noise(noise_seed, p.size, x, z));
                meadow.push(
                    p.meadows > 0.0 && normalise(terrain.height_at(x, z), lo, hi) < p.meadows,
                );
            }
        }
        // The cut: the level above which `cover` of all cells lie, among the cells that
        // are not meadows (meadows take their share of the clearings first).
        let total = cells * cells;
        let wanted = (p.cover * total as f32).round() as usize;
        let mut open: Vec<f32> = noise
            .iter()
            .zip(&meadow)
            .filter(|(_, m)| !**m)
            .map(|(n, _)| *n)
            .collect();
        let cut = if wanted == 0 {
            f32::INFINITY
        } else if wanted >= open.len() {
            f32::NEG_INFINITY
        } else {
            let k = open.len() - wanted;
            open.select_nth_unstable_by(k, f32::total_cmp);
            open[k]
        };
        let cover: Vec<Cover> = noise
            .iter()
            .zip(&meadow)
            .map(|(n, m)| {
                if *m {
                    Cover::Meadow
                } else if *n >= cut {
                    Cover::Stand
                } else {
                    Cover::Clearing
                }
            })
            .collect();
        let field = StandField {
            noise_seed,
            size: p.size,
            cut,
            meadows: p.meadows,
            lo,
            hi,
        };
        let inside = chamfer_inside(&cover, cells, cell);
        let factor = inside
            .iter()
            .zip(&cover)
            .map(|(d, c)| match c {
                Cover::Stand => smoothstep(0.0, p.edge, *d),
                _ => 0.0,
            })
            .collect();
        StandMap {
            origin,
            cell,
            cells,
            factor,
            cover,
            edge: p.edge,
            inside,
            field,
        }
    }

    /// The noise and its cut, to continue the stands past the square.
    pub fn field(&self) -> StandField {
        self.field
    }

    fn index(&self, x: f32, z: f32) -> Option<usize> {
        let gx = (x - self.origin) / self.cell;
        let gz = (z - self.origin) / self.cell;
        if !(gx.is_finite() && gz.is_finite()) {
            return None;
        }
        let c = |g: f32| (g.max(0.0) as usize).min(self.cells - 1);
        Some(c(gz) * self.cells + c(gx))
    }

    /// The density factor at world `(x, z)`: bilinear between cell centres, 0..=1; 0
    /// wherever the cell is not a stand, so that no tree stands in a clearing or meadow.
    pub fn factor_at(&self, x: f32, z: f32) -> f32 {
        if self.cover_at(x, z) != Cover::Stand {
            return 0.0;
        }
        let n = self.cells as f32;
        let gx = ((x - self.origin) / self.cell - 0.5).clamp(0.0, n - 1.0);
        let gz = ((z - self.origin) / self.cell - 0.5).clamp(0.0, n - 1.0);
        if !(gx.is_finite() && gz.is_finite()) {
            return 0.0;
        }
        let last = self.cells.saturating_sub(2);
        let i = (gx.floor() as usize).min(last);
        let j = (gz.floor() as usize).min(last);
        let (u, v) = (gx - i as f32, gz - j as f32);
        let i1 = (i + 1).min(self.cells - 1);
        let j1 = (j + 1).min(self.cells - 1);
        let f = |i: usize, j: usize| self.factor[j * self.cells + i];
        let a = f(i, j) + (f(i1, j) - f(i, j)) * u;
        let b = f(i, j1) + (f(i1, j1) - f(i, j1)) * u;
        a + (b - a) * v
    }

    /// What covers the land at world `(x, z)` (its cell's cover).
    pub fn cover_at(&self, x: f32, z: f32) -> Cover {
        self.index(x, z).map_or(Cover::Clearing, |k| self.cover[k])
    }

    /// Whether `(x, z)` lies deep inside a stand: at least `edge` plus `margin` metres from
    /// its border, where the density is full all around.
    pub fn is_interior(&self, x: f32, z: f32, margin: f32) -> bool {
        self.index(x, z).is_some_and(|k| {
            self.cover[k] == Cover::Stand && self.inside[k] >= self.edge + margin + self.cell
        })
    }

    /// The integral of the density factor over the square `lo..lo+span` on both axes
    /// (m²): multiplied by the density per m², the expected number of trees there.
    pub fn integral(&self, lo: f32, span: f32) -> f64 {
        let hi = lo + span;
        let mut sum = 0.0f64;
        for j in 0..self.cells {
            let z = self.origin + (j as f32 + 0.5) * self.cell;
            if z < lo || z > hi {
                continue;
            }
            for i in 0..self.cells {
                let x = self.origin + (i as f32 + 0.5) * self.cell;
                if x < lo || x > hi {
                    continue;
                }
                sum += f64::from(self.factor[j * self.cells + i]);
            }
        }
        sum * f64::from(self.cell) * f64::from(self.cell)
    }

    /// Share of the land in stands, clearings and meadows.
    pub fn shares(&self) -> [f32; 3] {
        let mut c = [0usize; 3];
        for k in &self.cover {
            c[match k {
                Cover::Stand => 0,
                Cover::Clearing => 1,
                Cover::Meadow => 2,
            }] += 1;
        }
        let n = self.cover.len().max(1) as f32;
        c.map(|v| v as f32 / n)
    }
}

/// Distance (m) from each stand cell's centre to the border with the nearest cell that is
/// not a stand, by a two-pass 8-neighbour chamfer (1, √2): within 8 % of the Euclidean
/// distance. Cells that are not stands are 0; a stand with no border anywhere is far.
fn chamfer_inside(cover: &[Cover], n: usize, cell: f32) -> Vec<f32> {
    const FAR: f32 = 1e9;
    let diag = std::f32::consts::SQRT_2;
    // In cells, from the neighbouring non-stand cell's centre.
    let mut d: Vec<f32> = cover
        .iter()
        .map(|c| if *c == Cover::Stand { FAR } else { 0.0 })
        .collect();
    let at = |i: usize, j: usize| j * n + i;
    for j in 0..n {
        for i in 0..n {
            let mut v = d[at(i, j)];
            if v == 0.0 {
                continue;
            }
            if i > 0 {
                v = v.min(d[at(i - 1, j)] + 1.0);
            }
            if j > 0 {
                v = v.min(d[at(i, j - 1)] + 1.0);
                if i > 0 {
                    v = v.min(d[at(i - 1, j - 1)] + diag);
                }
                if i + 1 < n {
                    v = v.min(d[at(i + 1, j - 1)] + diag);
                }
            }
            d[at(i, j)] = v;
        }
    }
    for j in (0..n).rev() {
        for i in (0..n).rev() {
            let mut v = d[at(i, j)];
            if v == 0.0 {
                continue;
            }
            if i + 1 < n {
                v = v.min(d[at(i + 1, j)] + 1.0);
            }
            if j + 1 < n {
                v = v.min(d[at(i, j + 1)] + 1.0);
                if i + 1 < n {
                    v = v.min(d[at(i + 1, j + 1)] + diag);
                }
                if i > 0 {
                    v = v.min(d[at(i - 1, j + 1)] + diag);
                }
            }
            d[at(i, j)] = v;
        }
    }
    // The border lies half a cell from the non-stand cell's centre.
    d.iter()
        .map(|v| {
            if *v >= FAR {
                FAR
            } else {
                ((v - 0.5) * cell).max(0.0)
            }
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::params::TerrainParams;

    fn terrain() -> Terrain {
        let p = TerrainParams {
            size: 600.0,
            resolution: 129,
            seed: 3,
            relief: 40.0,
            feature_size: 300.0,
            ..TerrainParams::default()
        };
        match Terrain::generate(&p) {
            Ok(t) => t,
            Err(e) => panic!("{e}"),
        }
    }

    #[test]
    fn cover_meadows_and_edges() {
        let t = terrain();
        let p = StandParams {
            cover: 0.6,
            size: 150.0,
            edge: 15.0,
            meadows: 0.15,
        };
        let m = StandMap::build(&p, 4, &t);
        let [stand, clearing, meadow] = m.shares();
        assert!((stand - 0.6).abs() < 0.01, "stands {stand}");
        assert!(meadow > 0.02 && clearing > 0.0, "{clearing} {meadow}");
        // Meadows lie on the lowest ground, stands never there.
        for j in 0..60 {
            for i in 0..60 {
                let (x, z) = (-295.0 + 10.0 * i as f32, -295.0 + 10.0 * j as f32);
                let (lo, hi) = height_range(&t);
                let h = normalise(t.height_at(x, z), lo, hi);
                match m.cover_at(x, z) {
                    Cover::Meadow => assert!(h < 0.15 + 0.02, "meadow at {h}"),
                    Cover::Stand => {
                        assert!(h >= 0.15 - 0.02, "stand at {h}");
                        let f = m.factor_at(x, z);
                        assert!((0.0..=1.0).contains(&f));
                    }
                    Cover::Clearing => assert!(m.factor_at(x, z) < 0.2),
                }
                if m.is_interior(x, z, 0.0) {
                    assert!((m.factor_at(x, z) - 1.0).abs() < 1e-4);
                }
            }
        }
        // The integral is the stands' area, less about half of each edge band.
        let all = m.integral(-300.0, 600.0);
        let area = 600.0f64 * 600.0;
        assert!(all < 0.6 * area && all > 0.3 * area, "{all}");
    }

    #[test]
    fn cover_extremes() {
        let t = terrain();
        let none = StandMap::build(
            &StandParams {
                cover: 0.0,
                ..StandParams::default()
            },
            1,
            &t,
        );
        assert_eq!(none.integral(-300.0, 600.0), 0.0);
        let all = StandMap::build(
            &StandParams {
                cover: 1.0,
                meadows: 0.0,
                edge: 0.0,
                ..StandParams::default()
            },
            1,
            &t,
        );
        let i = all.integral(-300.0, 600.0);
        assert!((i - 360_000.0).abs() < 1.0, "{i}");
        assert_eq!(all.factor_at(1e9, f32::NAN), 0.0);
    }

    #[test]
    fn chamfer_is_near_euclidean() {
        // One clearing cell in the middle of a 41x41 stand.
        let n = 41;
        let mut c = vec![Cover::Stand; n * n];
        c[20 * n + 20] = Cover::Clearing;
        let d = chamfer_inside(&c, n, 1.0);
        for (i, j) in [(30usize, 20usize), (30, 30), (35, 25), (20, 5)] {
            let e = (((i as f32 - 20.0).powi(2) + (j as f32 - 20.0).powi(2)).sqrt()) - 0.5;
            let got = d[j * n + i];
            assert!((got - e).abs() <= 0.09 * e + 0.01, "({i},{j}) {got} vs {e}");
        }
        assert_eq!(d[20 * n + 20], 0.0);
    }
}
