//! The terrain: a square heightfield centred on the origin (Y up), generated from seeded
//! fractal gradient noise (fBm), with bilinear height queries, normals, and a coloured
//! triangle mesh (grass, darker in valleys, earth and rock on steep slopes).

use glam::{Vec2, Vec3};
use rayon::prelude::*;

use super::ModelError;
use super::mesh::{Aabb, Mesh, Vertex};
use super::params::{TERRAIN_RESOLUTION, TerrainParams};
use super::rng::{hash2, mix64, unit_f32};

/// A square heightfield centred on the origin. Heights run from 0 (the lowest point) to
/// `relief` (the highest).
#[derive(Clone, Debug)]
pub struct Terrain {
    /// Side length (m).
    pub size: f32,
    /// Vertices per side (at least 2).
    pub resolution: u32,
    /// `resolution * resolution` heights (m), row-major: z rows (from -size/2), x columns
    /// (from -size/2).
    pub heights: Vec<f32>,
}

/// Perlin-style gradient noise in roughly -0.7..0.7, lattice spacing 1.
fn gradient_noise(seed: u64, p: Vec2) -> f32 {
    let cell = p.floor();
    let f = p - cell;
    let (ix, iy) = (cell.x as i32, cell.y as i32);
    let grad = |dx: i32, dy: i32| -> f32 {
        let h = hash2(seed, ix.wrapping_add(dx), iy.wrapping_add(dy));
        let a = unit_f32(h) * std::f32::consts::TAU;
        let g = Vec2::new(a.cos(), a.sin());
        g.dot(f - Vec2::new(dx as f32, dy as f32))
    };
    let fade = |t: f32| t * t * t * (t * (t * 6.0 - 15.0) + 10.0);
    let (u, v) = (fade(f.x), fade(f.y));
    let a = grad(0, 0) + (grad(1, 0) - grad(0, 0)) * u;
    let b = grad(0, 1) + (grad(1, 1) - grad(0, 1)) * u;
    a + (b - a) * v
}

/// Value noise in 0..1, lattice spacing 1 (used for colour patches).
fn value_noise(seed: u64, p: Vec2) -> f32 {
    let cell = p.floor();
    let f = p - cell;
    let (ix, iy) = (cell.x as i32, cell.y as i32);
    let val = |dx: i32, dy: i32| unit_f32(hash2(seed, ix.wrapping_add(dx), iy.wrapping_add(dy)));
    let s = |t: f32| t * t * (3.0 - 2.0 * t);
    let (u, v) = (s(f.x), s(f.y));
    let a = val(0, 0) + (val(1, 0) - val(0, 0)) * u;
    let b = val(0, 1) + (val(1, 1) - val(0, 1)) * u;
    a + (b - a) * v
}

/// Fractal sum of `octaves` gradient-noise layers, each twice the frequency and `gain`
/// times the amplitude of the previous, rotated to hide the lattice.
fn fbm(seed: u64, p: Vec2, octaves: u32, gain: f32) -> f32 {
    let rot = glam::Mat2::from_angle(0.6435); // a 3-4-5 triangle's angle
    let mut q = p;
    let mut amp = 1.0;
    let mut sum = 0.0;
    for o in 0..octaves {
        let s = mix64(seed ^ u64::from(o).wrapping_mul(0x9E37_79B9_7F4A_7C15));
        let offset = Vec2::new(unit_f32(s) * 97.0, unit_f32(mix64(s)) * 97.0);
        sum += amp * gradient_noise(s, q + offset);
        q = rot * q * 2.0;
        amp *= gain;
    }
    sum
}

fn smoothstep(e0: f32, e1: f32, x: f32) -> f32 {
    let t = ((x - e0) / (e1 - e0)).clamp(0.0, 1.0);
    t * t * (3.0 - 2.0 * t)
}

impl Terrain {
    /// Generates the heightfield (validates the parameters first; rows in parallel).
    pub fn generate(p: &TerrainParams) -> Result<Terrain, ModelError> {
        p.check().map_err(|e| ModelError::invalid("terrain", e))?;
        let res = p.resolution as usize;
        let step = p.size / (res - 1) as f32;
        let half = 0.5 * p.size;
        let mut heights = vec![0.0f32; res * res];
        heights
            .par_chunks_mut(res)
            .enumerate()
            .for_each(|(j, row)| {
                let z = -half + j as f32 * step;
                for (i, h) in row.iter_mut().enumerate() {
                    let x = -half + i as f32 * step;
                    *h = fbm(
                        p.seed,
                        Vec2::new(x, z) / p.feature_size,
                        p.octaves,
                        p.roughness,
                    );
                }
            });
        let (lo, hi) = heights
            .iter()
            .fold((f32::INFINITY, f32::NEG_INFINITY), |(a, b), &h| {
                (a.min(h), b.max(h))
            });
        let span = hi - lo;
        for h in &mut heights {
            *h = if span > 1e-9 {
                (*h - lo) / span * p.relief
            } else {
                0.0
            };
        }
        Ok(Terrain {
            size: p.size,
            resolution: p.resolution,
            heights,
        })
    }

    /// A flat terrain at height 0 (resolution clamped to 2..=4097).
    pub fn flat(size: f32, resolution: u32) -> Terrain {
        let (lo, hi) = TERRAIN_RESOLUTION;
        let res = resolution.clamp(lo, hi);
        Terrain {
            size,
            resolution: res,
            heights: vec![0.0; (res as usize) * (res as usize)],
        }
    }

    /// Distance between neighbouring grid vertices (m).
    pub fn cell_size(&self) -> f32 {
        self.size / (self.resolution.max(2) - 1) as f32
    }

    /// Height of grid vertex `(i, j)`, clamped to the grid; 0 where `heights` is short (a
    /// hand-made terrain whose fields disagree).
    #[inline]
    fn grid(&self, i: usize, j: usize) -> f32 {
        let res = self.resolution.max(2) as usize;
        self.heights
            .get(j.min(res - 1) * res + i.min(res - 1))
            .copied()
            .unwrap_or(0.0)
    }

    /// Height at world `(x, z)`, bilinear between grid vertices, clamped to the edge outside
    /// the terrain.
    pub fn height_at(&self, x: f32, z: f32) -> f32 {
        let n = (self.resolution.max(2) - 1) as f32;
        let gx = ((x / self.size + 0.5) * n).clamp(0.0, n);
        let gz = ((z / self.size + 0.5) * n).clamp(0.0, n);
        if !(gx.is_finite() && gz.is_finite()) {
            return 0.0;
        }
        let last = self.resolution.max(2) as usize - 2;
        let i = (gx.floor() as usize).min(last);
        let j = (gz.floor() as usize).min(last);
        let (u, v) = (gx - i as f32, gz - j as f32);
        let a = self.grid(i, j) + (self.grid(i + 1, j) - self.grid(i, j)) * u;
        let b = self.grid(i, j + 1) + (self.grid(i + 1, j + 1) - self.grid(i, j + 1)) * u;
        a + (b - a) * v
    }

    /// Unit surface normal at world `(x, z)` (central differences over one cell).
    pub fn normal_at(&self, x: f32, z: f32) -> Vec3 {
        let d = self.cell_size();
        let hx = (self.height_at(x + d, z) - self.height_at(x - d, z)) / (2.0 * d);
        let hz = (self.height_at(x, z + d) - self.height_at(x, z - d)) / (2.0 * d);
        Vec3::new(-hx, 1.0, -hz).try_normalize().unwrap_or(Vec3::Y)
    }

    /// Normal at grid vertex `(i, j)` from the neighbouring vertices.
    fn grid_normal(&self, i: usize, j: usize) -> Vec3 {
        let d = self.cell_size();
        let res = self.resolution.max(2) as usize;
        let (i0, i1) = (i.saturating_sub(1), (i + 1).min(res - 1));
        let (j0, j1) = (j.saturating_sub(1), (j + 1).min(res - 1));
        let hx = (self.grid(i1, j) - self.grid(i0, j)) / ((i1 - i0).max(1) as f32 * d);
        let hz = (self.grid(i, j1) - self.grid(i, j0)) / ((j1 - j0).max(1) as f32 * d);
        Vec3::new(-hx, 1.0, -hz).try_normalize().unwrap_or(Vec3::Y)
    }

    /// Lowest and highest height.
    fn height_range(&self) -> (f32, f32) {
        self.heights
            .iter()
            .fold((f32::INFINITY, f32::NEG_INFINITY), |(a, b), &h| {
                (a.min(h), b.max(h))
            })
    }

    /// Bounds of the terrain surface.
    pub fn bounds(&self) -> Aabb {
        let (lo, hi) = self.height_range();
        if lo
            .partial_cmp(&hi)
            .is_none_or(|o| o == std::cmp::Ordering::Greater)
        {
            return Aabb::EMPTY;
        }
        let h = 0.5 * self.size;
        Aabb::new(Vec3::new(-h, lo, -h), Vec3::new(h, hi, h))
    }

    /// The terrain as a triangle mesh: one vertex per grid point, two triangles per cell,
    /// counter-clockwise seen from above (front faces up). Colours: grass, darker in the
    /// valleys, dry earth on slopes, rock on steep slopes, with a little noise.
    pub fn mesh(&self) -> Mesh {
        let res = self.resolution.max(2) as usize;
        let step = self.cell_size();
        let half = 0.5 * self.size;
        let (lo, hi) = self.height_range();
        let span = (hi - lo).max(1e-3);
        let grass = Vec3::new(0.085, 0.12, 0.035);
        let valley = Vec3::new(0.05, 0.085, 0.028);
        let dry = Vec3::new(0.15, 0.125, 0.07);
        let rock = Vec3::new(0.2, 0.19, 0.175);
        let colour_seed = 0xC0_10_55_EE_D5;
        let mut vertices = Vec::with_capacity(res * res);
        for j in 0..res {
            for i in 0..res {
                let x = -half + i as f32 * step;
                let z = -half + j as f32 * step;
                let y = self.grid(i, j);
                let n = self.grid_normal(i, j);
                let slope = (1.0 - n.y * n.y).max(0.0).sqrt() / n.y.max(1e-3); // tan of the slope angle
                let h01 = (y - lo) / span;
                let patches = value_noise(colour_seed, Vec2::new(x, z) / 37.0);
                let speck = unit_f32(hash2(colour_seed, i as i32, j as i32));
                let mut c = valley.lerp(grass, smoothstep(0.0, 0.6, h01));
                c = c.lerp(
                    dry,
                    (0.7 * smoothstep(0.22, 0.45, slope) + 0.35 * smoothstep(0.55, 0.9, patches))
                        .min(1.0),
                );
                c = c.lerp(rock, smoothstep(0.5, 0.8, slope));
                c *= 0.92 + 0.16 * speck;
                vertices.push(Vertex::new(
                    Vec3::new(x, y, z),
                    n,
                    c.clamp(Vec3::ZERO, Vec3::ONE),
                    0.0,
                ));
            }
        }
        let mut indices = Vec::with_capacity((res - 1) * (res - 1) * 6);
        let r = res as u32;
        for j in 0..r - 1 {
            for i in 0..r - 1 {
                let v00 = j * r + i;
                let v10 = v00 + 1; // +x
                let v01 = v00 + r; // +z
                let v11 = v01 + 1;
                indices.extend_from_slice(&[v00, v01, v10, v10, v01, v11]);
            }
        }
        Mesh { vertices, indices }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn params(res: u32) -> TerrainParams {
        TerrainParams {
            size: 1000.0,
            resolution: res,
            seed: 3,
            relief: 60.0,
            ..TerrainParams::default()
        }
    }

    fn terrain(res: u32) -> Terrain {
        match Terrain::generate(&params(res)) {
            Ok(t) => t,
            Err(e) => panic!("{e}"),
        }
    }

    #[test]
    fn heights_span_the_relief() {
        let t = terrain(65);
        assert_eq!(t.heights.len(), 65 * 65);
        let b = t.bounds();
        assert!(
            (b.min.y - 0.0).abs() < 1e-4 && (b.max.y - 60.0).abs() < 1e-3,
            "{b:?}"
        );
        assert_eq!(b.min.x, -500.0);
        assert_eq!(b.max.z, 500.0);
    }

    #[test]
    fn deterministic_and_seeded() {
        let a = terrain(33);
        let b = terrain(33);
        assert_eq!(a.heights, b.heights);
        let mut p = params(33);
        p.seed = 4;
        let c = Terrain::generate(&p).map(|t| t.heights).unwrap_or_default();
        assert_ne!(a.heights, c);
    }

    #[test]
    fn has_hills_and_valleys() {
        // Real relief over 1 km: several separate highs and lows along a line, and slopes
        // steep enough for a ridge to shade a valley at a low sun.
        let t = terrain(129);
        let mut max_slope = 0.0f32;
        let mut extrema = 0;
        let mut prev = t.height_at(-500.0, 0.0);
        let mut prev_d = 0.0f32;
        for k in 1..=200 {
            let x = -500.0 + k as f32 * 5.0;
            let h = t.height_at(x, 0.0);
            let d = h - prev;
            if d * prev_d < 0.0 && d.abs() > 1e-3 {
                extrema += 1;
            }
            if d.abs() > 1e-3 {
                prev_d = d;
            }
            prev = h;
        }
        for j in 0..129 {
            for i in 0..129 {
                let n = t.grid_normal(i, j);
                max_slope = max_slope.max(n.y.acos().to_degrees());
            }
        }
        assert!(extrema >= 2, "only {extrema} extrema along x");
        assert!(max_slope > 15.0, "max slope {max_slope}");
    }

    #[test]
    fn height_at_interpolates_and_clamps() {
        let t = terrain(17);
        let step = t.cell_size();
        // Exact at grid vertices.
        for (i, j) in [(0usize, 0usize), (3, 5), (16, 16), (7, 0)] {
            let x = -500.0 + i as f32 * step;
            let z = -500.0 + j as f32 * step;
            assert!((t.height_at(x, z) - t.heights[j * 17 + i]).abs() < 1e-3);
        }
        // Midpoint of an edge is the average.
        let x = -500.0 + 2.5 * step;
        let z = -500.0 + 4.0 * step;
        let avg = 0.5 * (t.heights[4 * 17 + 2] + t.heights[4 * 17 + 3]);
        assert!((t.height_at(x, z) - avg).abs() < 1e-3);
        // Clamped outside.
        assert_eq!(t.height_at(-9000.0, -9000.0), t.heights[0]);
        assert_eq!(t.height_at(9000.0, 9000.0), t.heights[17 * 17 - 1]);
        assert!(t.height_at(f32::NAN, 0.0).is_finite());
    }

    #[test]
    fn normals_point_up_and_match_slope() {
        let mut t = Terrain::flat(100.0, 11);
        // A plane rising 0.5 m per metre along +x.
        for j in 0..11 {
            for i in 0..11 {
                t.heights[j * 11 + i] = 0.5 * (-50.0 + i as f32 * 10.0);
            }
        }
        let n = t.normal_at(0.0, 0.0);
        let expected = Vec3::new(-0.5, 1.0, 0.0).normalize_or_zero();
        assert!((n - expected).length() < 1e-4, "{n}");
        assert!((t.height_at(3.0, 7.0) - 1.5).abs() < 1e-4);
    }

    #[test]
    fn mesh_faces_up_and_is_indexed_correctly() {
        let t = terrain(33);
        let m = t.mesh();
        assert_eq!(m.vertices.len(), 33 * 33);
        assert_eq!(m.triangle_count(), 32 * 32 * 2);
        for tri in m.indices.chunks_exact(3) {
            let p = |i: u32| Vec3::from(m.vertices[i as usize].position);
            let n = (p(tri[1]) - p(tri[0])).cross(p(tri[2]) - p(tri[0]));
            assert!(n.y > 0.0, "triangle faces down");
        }
        for v in &m.vertices {
            assert_eq!(v.foliage, 0.0);
            assert!(v.normal[1] > 0.0);
            assert!(v.color.iter().all(|c| (0.0..=1.0).contains(c)));
            let p = Vec3::from(v.position);
            assert!((t.height_at(p.x, p.z) - p.y).abs() < 1e-3);
        }
        // Colours vary (noise, slope, height).
        let first = m.vertices[0].color;
        assert!(m.vertices.iter().any(|v| v.color != first));
        assert_eq!(m.bounds(), t.bounds());
    }

    #[test]
    fn steep_slopes_are_rocky_grey() {
        let mut t = Terrain::flat(100.0, 11);
        for j in 0..11 {
            for i in 0..11 {
                t.heights[j * 11 + i] = 1.5 * i as f32 * 10.0; // ~56 degrees
            }
        }
        let m = t.mesh();
        let c = Vec3::from(m.vertices[5 * 11 + 5].color);
        // Grey: the channels are close together.
        assert!(c.max_element() - c.min_element() < 0.04, "{c}");
        let flat = Terrain::flat(100.0, 11).mesh();
        let g = Vec3::from(flat.vertices[5 * 11 + 5].color);
        assert!(g.y > g.x && g.y > g.z, "flat ground is green: {g}");
    }

    #[test]
    fn hand_made_inconsistent_terrain_does_not_panic() {
        let t = Terrain {
            size: 10.0,
            resolution: 0,
            heights: Vec::new(),
        };
        assert_eq!(t.height_at(1.0, 2.0), 0.0);
        assert_eq!(t.normal_at(1.0, 2.0), Vec3::Y);
        assert_eq!(t.mesh().triangle_count(), 2);
        assert_eq!(Terrain::flat(10.0, 1_000_000).resolution, 4097);
    }

    #[test]
    fn bad_parameters_are_rejected() {
        let mut p = params(5000);
        let e = Terrain::generate(&p)
            .err()
            .map(|e| e.to_string())
            .unwrap_or_default();
        assert!(e.contains("resolution") && e.contains("5000"), "{e}");
        p.resolution = 17;
        p.size = f32::NAN;
        let e = Terrain::generate(&p)
            .err()
            .map(|e| e.to_string())
            .unwrap_or_default();
        assert!(e.contains("size"), "{e}");
    }
}
