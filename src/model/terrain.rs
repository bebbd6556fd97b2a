//! The terrain: a square heightfield centred on the origin (Y up), generated from seeded
//! fractal gradient noise (fBm), with bilinear height queries, normals, and a coloured
//! triangle mesh (grass, darker in valleys, earth and rock on steep slopes).

use glam::{Vec2, Vec3};
use rayon::prelude::*;

use super::ModelError;
use super::far_cover::{Canopy, FarCover};
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
    /// The same hills continued to the horizon (`[terrain] horizon`), for the mesh only,
    /// with the forest continued on them as a canopy surface once the forest is placed.
    pub far: Option<FarField>,
}

/// How far the horizon ring reaches from the centre (m): past the distance where the
/// default fog (0.0006 per metre) hides 99 % of anything (7.7 km), from anywhere on a
/// terrain of up to 1.5 km.
pub const HORIZON_REACH_M: f32 = 8_500.0;

/// Segments along each side of the horizon ring's squares.
const HORIZON_SIDE_SEGMENTS: usize = 64;

/// The noise of the heightfield, to continue it past its square.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FarField {
    seed: u64,
    feature_size: f32,
    octaves: u32,
    roughness: f32,
    /// The square's normalisation: height = (noise - lo) * scale.
    lo: f32,
    scale: f32,
    /// The forest continued past the square (set by [`Terrain::set_far_cover`]).
    cover: Option<FarCover>,
}

/// How wide the horizon ring's cells are at `(x, z)` (m): its squares of half side `h` have
/// [`HORIZON_SIDE_SEGMENTS`] segments a side.
fn ring_cell(x: f32, z: f32) -> f32 {
    2.0 * x.abs().max(z.abs()) / HORIZON_SIDE_SEGMENTS as f32
}

impl FarField {
    /// The continued heightfield at `(x, z)`, on the square's scale (it may leave
    /// 0..relief out there).
    pub fn height(&self, x: f32, z: f32) -> f32 {
        let n = fbm(
            self.seed,
            Vec2::new(x, z) / self.feature_size,
            self.octaves,
            self.roughness,
        );
        (n - self.lo) * self.scale
    }

    /// The forest's canopy at `(x, z)` over ground `ground`, if the forest continues here.
    pub fn canopy(&self, x: f32, z: f32, ground: f32) -> Option<Canopy> {
        self.cover.map(|c| c.at(x, z, ground, ring_cell(x, z)))
    }

    /// The drawn surface at `(x, z)`: the hills, raised by the forest's canopy.
    pub fn surface(&self, x: f32, z: f32) -> f32 {
        let ground = self.height(x, z);
        ground + self.canopy(x, z, ground).map_or(0.0, |c| c.raise)
    }

    /// The hills' normal (central differences `d` apart).
    fn normal(&self, x: f32, z: f32, d: f32) -> Vec3 {
        let hx = (self.height(x + d, z) - self.height(x - d, z)) / (2.0 * d);
        let hz = (self.height(x, z + d) - self.height(x, z - d)) / (2.0 * d);
        Vec3::new(-hx, 1.0, -hz).try_normalize().unwrap_or(Vec3::Y)
    }
}

/// The point at `t` (0..1) along the perimeter of the square of half-side `h` centred on
/// the origin, counter-clockwise seen from above from its (-h, -h) corner.
fn perimeter(t: f32, h: f32) -> Vec2 {
    let s = (t.rem_euclid(1.0)) * 4.0;
    let side = (s.floor() as u32).min(3);
    let f = s - side as f32;
    let a = -h + 2.0 * h * f;
    match side {
        0 => Vec2::new(a, -h),
        1 => Vec2::new(h, a),
        2 => Vec2::new(-a, h),
        _ => Vec2::new(-h, -a),
    }
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
pub(crate) fn fbm(seed: u64, p: Vec2, octaves: u32, gain: f32) -> f32 {
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
        let far = p.horizon.then_some(FarField {
            seed: p.seed,
            feature_size: p.feature_size,
            octaves: p.octaves,
            roughness: p.roughness,
            lo,
            scale: if span > 1e-9 { p.relief / span } else { 0.0 },
            cover: None,
        });
        Ok(Terrain {
            size: p.size,
            resolution: p.resolution,
            heights,
            far,
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
            far: None,
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

    /// Continues the forest past the square on the horizon ring (no effect without one).
    pub fn set_far_cover(&mut self, cover: Option<FarCover>) {
        if let Some(far) = &mut self.far {
            far.cover = cover;
        }
    }

    /// The horizon ring's forest cover, if it has one.
    pub fn far_cover(&self) -> Option<&FarCover> {
        self.far.as_ref().and_then(|f| f.cover.as_ref())
    }

    /// The ground's height at `p`'s `(x, z)` (as [`Terrain::height_at`]) when `p` lies below
    /// it, as a camera placed under the hills; None when `p` is on or above the ground.
    pub fn ground_above(&self, p: Vec3) -> Option<f32> {
        let ground = self.height_at(p.x, p.z);
        (p.y < ground).then_some(ground)
    }

    /// Height at world `(x, z)`, bilinear between grid vertices; outside the square the
    /// horizon's drawn surface (hills and the far forest's canopy) where there is one, else
    /// clamped to the edge.
    pub fn height_at(&self, x: f32, z: f32) -> f32 {
        let half = 0.5 * self.size;
        if let Some(far) = &self.far
            && (x.abs() > half || z.abs() > half)
            && x.is_finite()
            && z.is_finite()
        {
            return far.surface(x, z);
        }
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
        let color_seed = 0xC0_10_55_EE_D5;
        let mut vertices = Vec::with_capacity(res * res);
        for j in 0..res {
            for i in 0..res {
                let x = -half + i as f32 * step;
                let z = -half + j as f32 * step;
                let y = self.grid(i, j);
                let n = self.grid_normal(i, j);
                let slope = (1.0 - n.y * n.y).max(0.0).sqrt() / n.y.max(1e-3); // tan of the slope angle
                let h01 = (y - lo) / span;
                let patches = value_noise(color_seed, Vec2::new(x, z) / 37.0);
                let speck = unit_f32(hash2(color_seed, i as i32, j as i32));
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
        let mut mesh = Mesh { vertices, indices };
        if let Some(far) = &self.far {
            self.add_horizon(far, &mut mesh, |p, y, n| {
                let slope = (1.0 - n.y * n.y).max(0.0).sqrt() / n.y.max(1e-3);
                let h01 = ((y - lo) / span).clamp(0.0, 1.0);
                let patches = value_noise(color_seed, p / 37.0);
                let mut c = valley.lerp(grass, smoothstep(0.0, 0.6, h01));
                c = c.lerp(
                    dry,
                    (0.7 * smoothstep(0.22, 0.45, slope) + 0.35 * smoothstep(0.55, 0.9, patches))
                        .min(1.0),
                );
                c.lerp(rock, smoothstep(0.5, 0.8, slope))
                    .clamp(Vec3::ZERO, Vec3::ONE)
            });
        }
        mesh
    }

    /// Side length of the horizon ring's outer square (m); the square's own side without one.
    pub fn drawn_size(&self) -> f32 {
        if self.far.is_some() {
            (2.0 * HORIZON_REACH_M).max(self.size)
        } else {
            self.size
        }
    }

    /// Appends the horizon ring: squares growing outward from the heightfield's border to
    /// [`HORIZON_REACH_M`], each with [`HORIZON_SIDE_SEGMENTS`] segments a side and as far
    /// from the last as its segments are long, the first one zipped to the border's own
    /// vertices (no crack). Heights come from `far`, colours from `colour(xz, y, normal)`.
    fn add_horizon(
        &self,
        far: &FarField,
        mesh: &mut Mesh,
        colour: impl Fn(Vec2, f32, Vec3) -> Vec3,
    ) {
        let res = self.resolution.max(2) as usize;
        let half = 0.5 * self.size;
        let reach = HORIZON_REACH_M;
        if !(half > 0.0 && half < reach) {
            return;
        }
        // The border of the grid, counter-clockwise from the (-h, -h) corner, and each
        // vertex's place along the perimeter (0..1).
        let n = res - 1;
        let mut border: Vec<(u32, f32)> = Vec::with_capacity(4 * n);
        let idx = |i: usize, j: usize| (j * res + i) as u32;
        for k in 0..n {
            border.push((idx(k, 0), k as f32 / (4 * n) as f32));
        }
        for k in 0..n {
            border.push((idx(n, k), (n + k) as f32 / (4 * n) as f32));
        }
        for k in 0..n {
            border.push((idx(n - k, n), (2 * n + k) as f32 / (4 * n) as f32));
        }
        for k in 0..n {
            border.push((idx(0, n - k), (3 * n + k) as f32 / (4 * n) as f32));
        }
        let m = HORIZON_SIDE_SEGMENTS;
        let per_ring = 4 * m;
        let grow = 1.0 + 2.0 / m as f32;
        let push_ring = |mesh: &mut Mesh, h: f32| -> u32 {
            let first = mesh.vertices.len() as u32;
            let d = 2.0 * h / m as f32;
            for k in 0..per_ring {
                let p = perimeter(k as f32 / per_ring as f32, h);
                let ground = far.height(p.x, p.y);
                let canopy = far.canopy(p.x, p.y, ground);
                let y = ground + canopy.map_or(0.0, |c| c.raise);
                // Lit and coloured by the hills' slopes, not by the canopy's edges: a stand's
                // border rises over one ring cell, and lit as a slope it reads as a cliff.
                let nrm = far.normal(p.x, p.y, d);
                let mut c = colour(p, ground, nrm);
                if let Some(canopy) = canopy {
                    c = c.lerp(canopy.colour, canopy.cover.clamp(0.0, 1.0));
                }
                mesh.vertices
                    .push(Vertex::new(Vec3::new(p.x, y, p.y), nrm, c, 0.0));
            }
            first
        };
        // Every triangle faces up: wound counter-clockwise seen from above.
        let push_tri = |mesh: &mut Mesh, a: u32, b: u32, c: u32| {
            let v = |i: u32| mesh.vertices[i as usize].position;
            let up = (Vec3::from(v(b)) - Vec3::from(v(a)))
                .cross(Vec3::from(v(c)) - Vec3::from(v(a)))
                .y;
            if up >= 0.0 {
                mesh.indices.extend_from_slice(&[a, b, c]);
            } else {
                mesh.indices.extend_from_slice(&[a, c, b]);
            }
        };
        // The first ring, zipped to the border: advance along whichever perimeter is behind.
        let mut h = half * grow;
        let mut inner = push_ring(mesh, h);
        let (mut a, mut b) = (0usize, 0usize);
        while a < border.len() || b < per_ring {
            let ta = if a < border.len() { border[a].1 } else { 1.0 };
            let tb = if b < per_ring {
                b as f32 / per_ring as f32
            } else {
                1.0
            };
            let a0 = border[a % border.len()].0;
            let b0 = inner + (b % per_ring) as u32;
            if ta <= tb && a < border.len() {
                let a1 = border[(a + 1) % border.len()].0;
                push_tri(mesh, a0, a1, b0);
                a += 1;
            } else {
                let b1 = inner + ((b + 1) % per_ring) as u32;
                push_tri(mesh, a0, b1, b0);
                b += 1;
            }
        }
        // Then ring after ring, quads between equal counts.
        while h < reach {
            h = (h * grow).min(reach);
            let outer = push_ring(mesh, h);
            for k in 0..per_ring as u32 {
                let k1 = (k + 1) % per_ring as u32;
                push_tri(mesh, inner + k, inner + k1, outer + k);
                push_tri(mesh, inner + k1, outer + k1, outer + k);
            }
            inner = outer;
        }
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
    fn a_point_below_the_ground_gets_the_ground_height_there() {
        let t = terrain(65);
        let (x, z) = (120.0, -75.0);
        let h = t.height_at(x, z);
        assert!(h > 1.0, "hills here: {h}");
        assert_eq!(t.ground_above(Vec3::new(x, h - 0.5, z)), Some(h));
        assert_eq!(t.ground_above(Vec3::new(x, -1000.0, z)), Some(h));
        // On or above the ground, or not a point at all: nothing to say.
        assert_eq!(t.ground_above(Vec3::new(x, h, z)), None);
        assert_eq!(t.ground_above(Vec3::new(x, h + 0.5, z)), None);
        assert_eq!(t.ground_above(Vec3::new(x, f32::NAN, z)), None);
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
    fn the_horizon_ring_continues_the_hills_without_a_crack() {
        let p = TerrainParams {
            horizon: true,
            ..params(65)
        };
        let t = Terrain::generate(&p).unwrap();
        let plain = terrain(65).mesh();
        let m = t.mesh();
        assert_eq!(
            m.vertices[..plain.vertices.len()],
            plain.vertices[..],
            "the square is unchanged"
        );
        let grid_indices = plain.indices.len();
        // Every border vertex of the grid is a corner of a ring triangle: no crack.
        let n = 64usize;
        let ring: std::collections::HashSet<u32> =
            m.indices[grid_indices..].iter().copied().collect();
        for k in 0..=n {
            for (i, j) in [(k, 0), (n, k), (k, n), (0, k)] {
                assert!(
                    ring.contains(&((j * 65 + i) as u32)),
                    "border vertex {i},{j}"
                );
            }
        }
        // Every ring triangle faces up and the ring reaches the horizon.
        for tri in m.indices[grid_indices..].chunks(3) {
            let v = |i: u32| Vec3::from(m.vertices[i as usize].position);
            let up = (v(tri[1]) - v(tri[0])).cross(v(tri[2]) - v(tri[0])).y;
            assert!(up >= 0.0, "{tri:?}");
        }
        let reach = m
            .vertices
            .iter()
            .map(|v| v.position[0].abs().max(v.position[2].abs()))
            .fold(0.0f32, f32::max);
        assert!((reach - HORIZON_REACH_M).abs() < 1.0, "{reach}");
        assert_eq!(t.drawn_size(), 2.0 * HORIZON_REACH_M);
        // The hills go on: the first ring's heights continue the border's (within the
        // relief's slope over one ring step), and far away they still vary.
        let far = t.far.unwrap();
        let at_border = t.height_at(500.0, 0.0);
        assert!((far.height(500.0, 0.0) - at_border).abs() < 0.5);
        let samples: Vec<f32> = (0..50)
            .map(|k| far.height(3000.0 + 97.0 * k as f32, 2500.0))
            .collect();
        let (lo, hi) = samples
            .iter()
            .fold((f32::MAX, f32::MIN), |(a, b), &h| (a.min(h), b.max(h)));
        assert!(hi - lo > 5.0, "hills far away: {lo}..{hi}");
        // Without the option, no ring.
        assert_eq!(terrain(65).mesh().indices.len(), grid_indices);
    }

    #[test]
    fn hand_made_inconsistent_terrain_does_not_panic() {
        let t = Terrain {
            far: None,
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
