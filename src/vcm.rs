//! Visibility cube maps (Meyer 2001, §5.2): the opacity of everything around a point, seen
//! from it on the 6 faces of a cube, `res`² texels per face, one byte per texel. This module
//! is the pure-CPU core: the face layout, sampling in a direction, trilinear interpolation
//! between the 8 corners of a box, and a small software renderer that draws textured quads
//! (billboards) and a terrain horizon onto a cube, compositing their opacities. The bake
//! (`bake::vcm`) decides which objects are drawn into which cube; the renderer
//! (`render::vcm_shading`) reads the cubes in the sun's direction.
//!
//! The thesis drew the scene onto the faces with its billboard renderer and read alpha back
//! in software. Here the billboards are drawn in software directly: 32² texels per face are
//! too few for a GPU round trip per face to pay, and the software path bakes a 1,000-tree
//! forest in seconds on two cores.
//!
//! Face layout: face `f` looks along axis `a = f / 2` (x, y, z), towards + for even `f` and
//! − for odd `f`. Its texel `(i, j)` (column, row) is centred on the direction whose
//! component `a` is ±1 and whose components `(a + 1) % 3` and `(a + 2) % 3` are
//! `x = (i + 0.5) / res * 2 − 1` and `y = (j + 0.5) / res * 2 − 1`. Corner `k` of a box has
//! bit 0 set for max x, bit 1 for max y, bit 2 for max z.

use glam::Vec3;

use crate::model::mesh::Aabb;

pub mod billboard;
pub mod cells;

/// Tree-level cube maps sit at least this far (m) above the terrain, so a box corner that
/// dips into a slope still sees the sky the tree's foot sees.
pub const GROUND_CLEARANCE: f32 = 0.05;

/// Faces of a cube map.
pub const FACES: usize = 6;
/// Cube maps per object, one at each corner of its bounding box (points outside it take the
/// value of its nearest face). The box is not inset: cube maps at its octants' centres
/// measured farther from the geometry on the dense test stand than at its corners.
pub const CORNERS: usize = 8;

/// The axis, sign and the two in-face axes of face `f`.
#[inline]
fn face_axes(face: usize) -> (usize, f32, usize, usize) {
    let a = face / 2;
    let sign = if face.is_multiple_of(2) { 1.0 } else { -1.0 };
    (a, sign, (a + 1) % 3, (a + 2) % 3)
}

/// The unit direction through the centre of texel `(i, j)` of face `face`.
pub fn texel_direction(face: usize, i: u32, j: u32, res: u32) -> Vec3 {
    let (a, sign, b, c) = face_axes(face);
    let r = res.max(1) as f32;
    let mut d = [0.0f32; 3];
    d[a] = sign;
    d[b] = (i as f32 + 0.5) / r * 2.0 - 1.0;
    d[c] = (j as f32 + 0.5) / r * 2.0 - 1.0;
    Vec3::from(d).normalize()
}

/// The face a direction falls on and its in-face coordinates in [-1, 1]; None for a zero or
/// non-finite direction.
pub fn face_coords(dir: Vec3) -> Option<(usize, f32, f32)> {
    if !dir.is_finite() {
        return None;
    }
    let abs = dir.abs();
    let a = if abs.x >= abs.y && abs.x >= abs.z {
        0
    } else if abs.y >= abs.z {
        1
    } else {
        2
    };
    let m = abs[a];
    if m <= 0.0 {
        return None;
    }
    let face = 2 * a + usize::from(dir[a] < 0.0);
    let (_, _, b, c) = face_axes(face);
    Some((face, dir[b] / m, dir[c] / m))
}

/// Opacity in [0, 1] of one cube map (`6 * res²` bytes) in direction `dir`, bilinear inside
/// the face (clamped at its edges). A zero direction reads as visible.
pub fn sample(map: &[u8], res: u32, dir: Vec3) -> f32 {
    let r = res as usize;
    if map.len() < FACES * r * r {
        return 0.0;
    }
    sample_with(res, dir, |face, i, j| map[(face * r + j) * r + i])
}

/// Bilinear opacity in direction `dir` of a cube map whose texel `(i, j)` of face `face`
/// is `texel(face, i, j)`.
pub fn sample_with(res: u32, dir: Vec3, mut texel: impl FnMut(usize, usize, usize) -> u8) -> f32 {
    let Some((face, x, y)) = face_coords(dir) else {
        return 0.0;
    };
    let r = res as usize;
    if r == 0 {
        return 0.0;
    }
    let last = (res - 1) as f32;
    let fx = ((x + 1.0) * 0.5 * res as f32 - 0.5).clamp(0.0, last);
    let fy = ((y + 1.0) * 0.5 * res as f32 - 0.5).clamp(0.0, last);
    let (i0, j0) = (fx as usize, fy as usize);
    let (i1, j1) = ((i0 + 1).min(r - 1), (j0 + 1).min(r - 1));
    let (u, v) = (fx - i0 as f32, fy - j0 as f32);
    let mut at = |i: usize, j: usize| f32::from(texel(face, i, j)) / 255.0;
    let (a00, a10, a01, a11) = (at(i0, j0), at(i1, j0), at(i0, j1), at(i1, j1));
    let top = a00 + (a10 - a00) * u;
    let bottom = a01 + (a11 - a01) * u;
    top + (bottom - top) * v
}

/// Corner `k` (0..8) of a box.
pub fn corner(b: &Aabb, k: usize) -> Vec3 {
    Vec3::new(
        if k & 1 != 0 { b.max.x } else { b.min.x },
        if k & 2 != 0 { b.max.y } else { b.min.y },
        if k & 4 != 0 { b.max.z } else { b.min.z },
    )
}

/// Trilinear interpolation of the 8 corner values at box coordinates `u` (0 at the box's
/// min corner, 1 at its max corner; clamped to the box).
pub fn trilinear(values: &[f32; CORNERS], u: Vec3) -> f32 {
    let u = u.clamp(Vec3::ZERO, Vec3::ONE);
    let u = if u.is_finite() { u } else { Vec3::splat(0.5) };
    let lerp = |a: f32, b: f32, t: f32| a + (b - a) * t;
    let x00 = lerp(values[0], values[1], u.x);
    let x10 = lerp(values[2], values[3], u.x);
    let x01 = lerp(values[4], values[5], u.x);
    let x11 = lerp(values[6], values[7], u.x);
    lerp(lerp(x00, x10, u.y), lerp(x01, x11, u.y), u.z)
}

/// The box coordinates of `p` in `b` (see [`trilinear`]).
pub fn box_coords(b: &Aabb, p: Vec3) -> Vec3 {
    (p - b.min) / (b.max - b.min).max(Vec3::splat(1e-6))
}

/// An occluder drawn onto a cube: a quad with an opacity image. The quad covers
/// `center + s * right + t * up` for `s, t` in [-1, 1] (`right` and `up` are half-sides).
pub trait Occluder {
    fn center(&self) -> Vec3;
    fn right(&self) -> Vec3;
    fn up(&self) -> Vec3;
    /// Opacity in [0, 1] at quad coordinates `(s, t)`, filtered over `footprint` (the size
    /// of one cube texel there, in quad coordinates).
    fn opacity(&self, s: f32, t: f32, footprint: f32) -> f32;
}

/// A uniformly opaque (or uniformly translucent) quad: walls in tests, and a simple stand-in
/// anywhere one is needed.
#[derive(Clone, Copy, Debug)]
pub struct PlainQuad {
    pub center: Vec3,
    pub right: Vec3,
    pub up: Vec3,
    pub alpha: f32,
}

impl Occluder for PlainQuad {
    fn center(&self) -> Vec3 {
        self.center
    }
    fn right(&self) -> Vec3 {
        self.right
    }
    fn up(&self) -> Vec3 {
        self.up
    }
    fn opacity(&self, _: f32, _: f32, _: f32) -> f32 {
        self.alpha
    }
}

/// The terrain's horizon around a point: for each of `azimuths` directions, the tangent of
/// the highest elevation angle at which the terrain is seen (a horizon map, as the thesis
/// suggests for terrain shadows).
pub struct Horizon {
    tans: Vec<f32>,
}

impl Horizon {
    /// Marches `height` outwards from `origin` along each azimuth, from `first_step` metres
    /// growing by 5% per step, while `inside(x, z)` holds and up to `max_distance`.
    pub fn new(
        origin: Vec3,
        azimuths: usize,
        first_step: f32,
        max_distance: f32,
        inside: impl Fn(f32, f32) -> bool,
        height: impl Fn(f32, f32) -> f32,
    ) -> Self {
        let n = azimuths.max(4);
        let first = first_step.max(1e-3);
        let tans = (0..n)
            .map(|k| {
                let phi = k as f32 / n as f32 * std::f32::consts::TAU;
                let (sx, sz) = (phi.sin(), phi.cos());
                let mut best = f32::NEG_INFINITY;
                let mut d = first;
                while d <= max_distance {
                    let (x, z) = (origin.x + sx * d, origin.z + sz * d);
                    if !inside(x, z) {
                        break;
                    }
                    best = best.max((height(x, z) - origin.y) / d);
                    d = (d * 1.05).max(d + first);
                }
                best
            })
            .collect();
        Self { tans }
    }

    /// True when the terrain hides direction `dir`.
    pub fn hides(&self, dir: Vec3) -> bool {
        let flat = (dir.x * dir.x + dir.z * dir.z).sqrt();
        if flat <= 1e-9 {
            return dir.y < 0.0 && self.tans.iter().any(|t| t.is_finite());
        }
        let n = self.tans.len();
        let phi = dir.x.atan2(dir.z).rem_euclid(std::f32::consts::TAU);
        let f = phi / std::f32::consts::TAU * n as f32;
        let k0 = (f as usize).min(n - 1);
        let k1 = (k0 + 1) % n;
        let w = f - k0 as f32;
        let (a, b) = (self.tans[k0], self.tans[k1]);
        let horizon = match (a.is_finite(), b.is_finite()) {
            (true, true) => a + (b - a) * w,
            (true, false) => a,
            (false, true) => b,
            (false, false) => return false,
        };
        dir.y / flat < horizon
    }
}

/// Transmittance below which a texel is stored as fully opaque (opacity byte 255, since
/// bytes are rounded); drawing more in front or behind cannot change it, so it is skipped.
const SATURATED: f32 = 0.5 / 255.0;

/// A cube map being drawn: transmittance per texel, starting fully visible.
pub struct CubeRaster {
    res: u32,
    dirs: Vec<Vec3>,
    transmittance: Vec<f32>,
}

impl CubeRaster {
    pub fn new(res: u32) -> Self {
        let res = res.max(1);
        let mut dirs = Vec::with_capacity(FACES * (res * res) as usize);
        for face in 0..FACES {
            for j in 0..res {
                for i in 0..res {
                    dirs.push(texel_direction(face, i, j, res));
                }
            }
        }
        let n = dirs.len();
        Self {
            res,
            dirs,
            transmittance: vec![1.0; n],
        }
    }

    pub fn resolution(&self) -> u32 {
        self.res
    }

    /// Back to fully visible.
    pub fn clear(&mut self) {
        self.transmittance.fill(1.0);
    }

    /// Draws `quad` as seen from `origin`: every texel whose ray meets the quad is multiplied
    /// by the quad's transmittance there (order does not matter).
    pub fn draw(&mut self, origin: Vec3, quad: &impl Occluder) {
        let (c, r, u) = (quad.center(), quad.right(), quad.up());
        let (rr, uu) = (r.length_squared(), u.length_squared());
        let n = r.cross(u);
        if !(rr > 0.0 && uu > 0.0 && n.length_squared() > 0.0 && c.is_finite()) {
            return;
        }
        let q = c - origin;
        let radius = (rr + uu).sqrt();
        let q_n = q.dot(n);
        if q_n.abs() <= 1e-12 * n.length() {
            // The eye lies in the quad's plane: it is seen edge-on.
            return;
        }
        let res = self.res as usize;
        let texel_angle = 2.0 / self.res as f32;
        let side = rr.sqrt().max(uu.sqrt());
        for face in 0..FACES {
            let Some((i0, i1, j0, j1)) = face_range(face, q, radius, self.res) else {
                continue;
            };
            let base = face * res * res;
            for j in j0..=j1 {
                let row = base + j * res;
                for i in i0..=i1 {
                    let k = row + i;
                    if self.transmittance[k] < SATURATED {
                        // Already stored as fully opaque; nothing behind can change that.
                        continue;
                    }
                    let Some((s, tt, t)) = hit(self.dirs[k], q, n, q_n, r, u, rr, uu) else {
                        continue;
                    };
                    let footprint = texel_angle * t / side;
                    let a = quad.opacity(s, tt, footprint).clamp(0.0, 1.0);
                    self.transmittance[k] *= 1.0 - a;
                }
            }
        }
    }

    /// True when every texel a sphere of `radius` at `center` could cover, seen from
    /// `origin`, is already stored as fully opaque: drawing anything inside it would change
    /// nothing, so the caller may skip building it. Cheap next to a draw.
    pub fn covered(&self, origin: Vec3, center: Vec3, radius: f32) -> bool {
        let q = center - origin;
        if !(q.is_finite() && radius.is_finite()) || q.length() <= radius {
            return false;
        }
        let res = self.res as usize;
        (0..FACES).all(|face| {
            let Some((i0, i1, j0, j1)) = face_range(face, q, radius, self.res) else {
                return true;
            };
            let base = face * res * res;
            (j0..=j1).all(|j| {
                self.transmittance[base + j * res + i0..=base + j * res + i1]
                    .iter()
                    .all(|&t| t < SATURATED)
            })
        })
    }

    /// Makes every texel the terrain hides fully opaque.
    pub fn draw_terrain(&mut self, horizon: &Horizon) {
        for (t, d) in self.transmittance.iter_mut().zip(&self.dirs) {
            if horizon.hides(*d) {
                *t = 0.0;
            }
        }
    }

    /// Opacity of the texel in direction `dir` (nearest texel).
    pub fn opacity_at(&self, dir: Vec3) -> f32 {
        let Some((face, x, y)) = face_coords(dir) else {
            return 0.0;
        };
        let r = self.res as usize;
        let i = (((x + 1.0) * 0.5 * self.res as f32) as usize).min(r - 1);
        let j = (((y + 1.0) * 0.5 * self.res as f32) as usize).min(r - 1);
        1.0 - self.transmittance[face * r * r + j * r + i]
    }

    /// Appends the opacity bytes (`6 * res²`, face-major) and returns the mean opacity over
    /// all texels, or, with `upper_only`, over the texels above the horizontal (y > 0).
    pub fn finish(&self, out: &mut Vec<u8>, upper_only: bool) -> f32 {
        let mut sum = 0.0f64;
        let mut n = 0u32;
        for (t, d) in self.transmittance.iter().zip(&self.dirs) {
            let a = (1.0 - t).clamp(0.0, 1.0);
            out.push((a * 255.0).round() as u8);
            if !upper_only || d.y > 0.0 {
                sum += f64::from(a);
                n += 1;
            }
        }
        if n == 0 {
            0.0
        } else {
            (sum / f64::from(n)) as f32
        }
    }
}

/// Where the ray from the eye along unit `d` meets the plane of a quad (`q` its centre
/// relative to the eye, `n` = right × up, `q_n` = q · n): its quad coordinates (s, t) and
/// distance, or None when it misses the quad or meets its plane behind the eye.
#[inline]
#[allow(clippy::too_many_arguments)]
fn hit(
    d: Vec3,
    q: Vec3,
    n: Vec3,
    q_n: f32,
    r: Vec3,
    u: Vec3,
    rr: f32,
    uu: f32,
) -> Option<(f32, f32, f32)> {
    let denom = d.dot(n);
    if denom == 0.0 {
        return None;
    }
    let t = q_n / denom;
    if t <= 0.0 {
        return None;
    }
    let p = d * t - q;
    let s = p.dot(r) / rr;
    let tt = p.dot(u) / uu;
    if s.abs() > 1.0 || tt.abs() > 1.0 {
        return None;
    }
    Some((s, tt, t))
}

/// The opacity a quad puts on one ray from `origin` along `dir`, filtered as a cube of
/// `res`² texels per face would filter it ([`CubeRaster::draw`] for a single texel).
pub fn ray_opacity(origin: Vec3, dir: Vec3, quad: &impl Occluder, res: u32) -> f32 {
    let (c, r, u) = (quad.center(), quad.right(), quad.up());
    let (rr, uu) = (r.length_squared(), u.length_squared());
    let n = r.cross(u);
    let d = dir.normalize_or_zero();
    if !(rr > 0.0 && uu > 0.0 && n.length_squared() > 0.0 && c.is_finite()) || d == Vec3::ZERO {
        return 0.0;
    }
    let q = c - origin;
    let q_n = q.dot(n);
    if q_n.abs() <= 1e-12 * n.length() {
        return 0.0;
    }
    let Some((s, tt, t)) = hit(d, q, n, q_n, r, u, rr, uu) else {
        return 0.0;
    };
    let side = rr.sqrt().max(uu.sqrt());
    let footprint = 2.0 / res.max(1) as f32 * t / side;
    quad.opacity(s, tt, footprint).clamp(0.0, 1.0)
}

/// The texel rectangle (columns i0..=i1, rows j0..=j1) of face `face` that a sphere of
/// `radius` at `q` (relative to the eye) can cover, or None if it misses the face.
fn face_range(face: usize, q: Vec3, radius: f32, res: u32) -> Option<(usize, usize, usize, usize)> {
    let (a, sign, b, c) = face_axes(face);
    let depth = sign * q[a];
    if depth + radius <= 0.0 {
        return None;
    }
    // Every direction of the face has depth >= |its b and c components|: a sphere wholly
    // beyond one of the 4 side planes of the face's pyramid misses it.
    let side = radius * std::f32::consts::SQRT_2;
    if depth - q[b] < -side || depth + q[b] < -side || depth - q[c] < -side || depth + q[c] < -side
    {
        return None;
    }
    let last = res as usize - 1;
    let whole = Some((0, last, 0, last));
    if depth - radius <= 1e-4 {
        // The sphere reaches behind the eye's plane: it may cover any texel of the face.
        return whole;
    }
    let span = |x: f32| {
        let lo = ((x - radius) / (depth - radius)).min((x - radius) / (depth + radius));
        let hi = ((x + radius) / (depth - radius)).max((x + radius) / (depth + radius));
        (lo, hi)
    };
    let (x0, x1) = span(q[b]);
    let (y0, y1) = span(q[c]);
    if x0 > 1.0 || x1 < -1.0 || y0 > 1.0 || y1 < -1.0 {
        return None;
    }
    let to_texel = |v: f32| (((v + 1.0) * 0.5 * res as f32).floor().max(0.0) as usize).min(last);
    Some((to_texel(x0), to_texel(x1), to_texel(y0), to_texel(y1)))
}

#[cfg(test)]
mod tests {
    use super::*;

    const RES: u32 = 32;

    fn finish(r: &CubeRaster) -> (Vec<u8>, f32) {
        let mut out = Vec::new();
        let mean = r.finish(&mut out, false);
        (out, mean)
    }

    fn wall(center: Vec3, right: Vec3, up: Vec3) -> PlainQuad {
        PlainQuad {
            center,
            right,
            up,
            alpha: 1.0,
        }
    }

    #[test]
    fn texel_directions_and_face_coords_agree() {
        for face in 0..FACES {
            for (i, j) in [(0, 0), (5, 17), (31, 31), (16, 3)] {
                let d = texel_direction(face, i, j, RES);
                let (f, x, y) = face_coords(d).unwrap();
                assert_eq!(f, face);
                let ii = ((x + 1.0) * 0.5 * RES as f32) as u32;
                let jj = ((y + 1.0) * 0.5 * RES as f32) as u32;
                assert_eq!((ii, jj), (i, j), "face {face}");
            }
        }
        assert!(face_coords(Vec3::ZERO).is_none());
        assert!(face_coords(Vec3::new(f32::NAN, 0.0, 1.0)).is_none());
    }

    #[test]
    fn a_point_in_empty_space_sees_everything() {
        let r = CubeRaster::new(RES);
        let (bytes, mean) = finish(&r);
        assert_eq!(bytes.len(), FACES * (RES * RES) as usize);
        assert!(bytes.iter().all(|&b| b == 0));
        assert_eq!(mean, 0.0);
    }

    #[test]
    fn a_point_inside_a_closed_box_is_fully_occluded() {
        let mut r = CubeRaster::new(RES);
        let o = Vec3::new(0.3, -0.2, 0.1); // off-centre inside a 2 m box
        for a in 0..3 {
            for s in [-1.0f32, 1.0] {
                let mut n = Vec3::ZERO;
                n[a] = s;
                let mut right = Vec3::ZERO;
                right[(a + 1) % 3] = 1.0;
                let mut up = Vec3::ZERO;
                up[(a + 2) % 3] = 1.0;
                r.draw(o, &wall(n, right, up));
            }
        }
        let (bytes, mean) = finish(&r);
        assert!(bytes.iter().all(|&b| b == 255), "{:?}", &bytes[..16]);
        assert_eq!(mean, 1.0);
    }

    #[test]
    fn a_point_beside_one_wall_is_half_occluded() {
        let mut r = CubeRaster::new(RES);
        // A huge wall 0.5 m away, filling the +x half of the directions.
        r.draw(
            Vec3::ZERO,
            &wall(Vec3::new(0.5, 0.0, 0.0), Vec3::Z * 1.0e5, Vec3::Y * 1.0e5),
        );
        let (bytes, mean) = finish(&r);
        assert!((mean - 0.5).abs() < 0.01, "mean {mean}");
        let map = &bytes[..];
        assert!(sample(map, RES, Vec3::X) > 0.99);
        assert!(sample(map, RES, -Vec3::X) < 0.01);
        assert!(sample(map, RES, Vec3::new(0.3, 1.0, 0.2)) > 0.99);
        assert!(sample(map, RES, Vec3::new(-0.3, 1.0, 0.2)) < 0.01);
    }

    #[test]
    fn a_translucent_quad_composites_multiplicatively() {
        let mut r = CubeRaster::new(RES);
        let q = PlainQuad {
            center: Vec3::new(0.0, 0.0, 3.0),
            right: Vec3::X,
            up: Vec3::Y,
            alpha: 0.5,
        };
        r.draw(Vec3::ZERO, &q);
        assert!((r.opacity_at(Vec3::Z) - 0.5).abs() < 1e-6);
        let behind = PlainQuad {
            center: Vec3::new(0.0, 0.0, 6.0),
            ..q
        };
        r.draw(Vec3::ZERO, &behind);
        assert!((r.opacity_at(Vec3::Z) - 0.75).abs() < 1e-6);
        // Nothing beside it, nothing behind the eye.
        assert_eq!(r.opacity_at(Vec3::X), 0.0);
        assert_eq!(r.opacity_at(-Vec3::Z), 0.0);
        // The quad covers 2x2 m at 3 m: atan(1/3) = 18.4 degrees each side.
        assert!(r.opacity_at(Vec3::new(0.25, 0.0, 1.0)) > 0.0);
        assert_eq!(r.opacity_at(Vec3::new(0.45, 0.0, 1.0)), 0.0);
    }

    #[test]
    fn the_drawing_order_does_not_change_the_bytes_even_past_opaque_texels() {
        // Near an opaque wall first (its texels are then skipped), or far translucent quads
        // first: the stored bytes are the same.
        let near = wall(Vec3::new(0.0, 0.0, 2.0), Vec3::X * 1.5, Vec3::Y * 1.5);
        let far: Vec<PlainQuad> = (0..4)
            .map(|k| PlainQuad {
                center: Vec3::new(-1.0 + k as f32, 0.5, 5.0 + k as f32),
                right: Vec3::X * 3.0,
                up: Vec3::Y * 1.2,
                alpha: 0.3 + 0.1 * k as f32,
            })
            .collect();
        let mut near_first = CubeRaster::new(RES);
        near_first.draw(Vec3::ZERO, &near);
        for q in &far {
            near_first.draw(Vec3::ZERO, q);
        }
        let mut far_first = CubeRaster::new(RES);
        for q in far.iter().rev() {
            far_first.draw(Vec3::ZERO, q);
        }
        far_first.draw(Vec3::ZERO, &near);
        let (a, mean_a) = finish(&near_first);
        let (b, mean_b) = finish(&far_first);
        assert_eq!(a, b);
        assert!((mean_a - mean_b).abs() < 1e-3, "{mean_a} vs {mean_b}");
        assert_eq!(near_first.opacity_at(Vec3::Z), 1.0);
        // Beside the wall, the far quads alone.
        let beside = near_first.opacity_at(Vec3::new(-0.78, 0.1, 1.0));
        assert!(beside > 0.0 && beside < 1.0, "{beside}");
    }

    #[test]
    fn a_single_ray_reads_what_the_cube_draws_and_covered_skips_only_what_is_hidden() {
        let q = PlainQuad {
            center: Vec3::new(0.0, 0.0, 3.0),
            right: Vec3::X,
            up: Vec3::Y,
            alpha: 0.4,
        };
        assert!((ray_opacity(Vec3::ZERO, Vec3::Z, &q, RES) - 0.4).abs() < 1e-6);
        assert_eq!(ray_opacity(Vec3::ZERO, -Vec3::Z, &q, RES), 0.0);
        assert_eq!(
            ray_opacity(Vec3::ZERO, Vec3::new(0.5, 0.0, 1.0), &q, RES),
            0.0
        );
        assert_eq!(ray_opacity(Vec3::ZERO, Vec3::ZERO, &q, RES), 0.0);
        // An opaque wall in front: a small sphere behind it is covered, one beside it not.
        let mut r = CubeRaster::new(RES);
        r.draw(
            Vec3::ZERO,
            &wall(Vec3::new(0.0, 0.0, 2.0), Vec3::X * 2.0, Vec3::Y * 2.0),
        );
        assert!(r.covered(Vec3::ZERO, Vec3::new(0.0, 0.0, 10.0), 1.0));
        assert!(!r.covered(Vec3::ZERO, Vec3::new(0.0, 0.0, 10.0), 9.0));
        assert!(!r.covered(Vec3::ZERO, Vec3::new(10.0, 0.0, 0.0), 1.0));
        assert!(!r.covered(Vec3::ZERO, Vec3::ZERO, 1.0), "around the eye");
    }

    #[test]
    fn a_quad_across_face_edges_is_drawn_on_every_face_it_touches() {
        let mut r = CubeRaster::new(RES);
        // A big wall in front, seen across the +z face and the 4 faces around it.
        r.draw(
            Vec3::ZERO,
            &wall(Vec3::new(0.0, 0.0, 1.0), Vec3::X * 50.0, Vec3::Y * 50.0),
        );
        for d in [
            Vec3::Z,
            Vec3::new(1.0, 0.0, 0.5),
            Vec3::new(-1.0, 0.0, 0.5),
            Vec3::new(0.0, 1.0, 0.5),
            Vec3::new(0.0, -1.0, 0.5),
        ] {
            assert_eq!(r.opacity_at(d), 1.0, "{d}");
        }
        assert_eq!(r.opacity_at(Vec3::new(1.0, 0.0, -0.5)), 0.0);
    }

    #[test]
    fn flat_terrain_hides_the_lower_half() {
        let origin = Vec3::new(0.0, 0.05, 0.0);
        let h = Horizon::new(
            origin,
            128,
            0.5,
            500.0,
            |x, z| x.abs() < 400.0 && z.abs() < 400.0,
            |_, _| 0.0,
        );
        let mut r = CubeRaster::new(RES);
        r.draw_terrain(&h);
        assert_eq!(r.opacity_at(-Vec3::Y), 1.0);
        assert_eq!(r.opacity_at(Vec3::new(1.0, -0.1, 0.0)), 1.0);
        assert_eq!(r.opacity_at(Vec3::new(1.0, 0.1, 0.3)), 0.0);
        let mut bytes = Vec::new();
        let all = r.finish(&mut bytes, false);
        assert!((all - 0.5).abs() < 0.02, "{all}");
        bytes.clear();
        assert_eq!(r.finish(&mut bytes, true), 0.0, "nothing above the horizon");
    }

    #[test]
    fn a_ridge_raises_the_horizon_on_its_side_only() {
        let origin = Vec3::new(0.0, 1.0, 0.0);
        // A 30 m wall of terrain from x = 20 m on.
        let h = Horizon::new(
            origin,
            128,
            0.5,
            500.0,
            |_, _| true,
            |x, _| if x > 20.0 { 30.0 } else { 0.0 },
        );
        assert!(
            h.hides(Vec3::new(1.0, 0.8, 0.0)),
            "towards the ridge, 39 degrees up"
        );
        assert!(!h.hides(Vec3::new(1.0, 1.6, 0.0)), "above it");
        assert!(!h.hides(Vec3::new(-1.0, 0.1, 0.0)), "away from it");
    }

    #[test]
    fn sampling_is_continuous_inside_a_face_and_reads_corners() {
        let mut map = vec![0u8; FACES * (RES * RES) as usize];
        // Face 0 (+x): a left-to-right ramp.
        for j in 0..RES as usize {
            for i in 0..RES as usize {
                map[j * RES as usize + i] = (i * 255 / (RES as usize - 1)) as u8;
            }
        }
        let mut prev = sample(&map, RES, Vec3::new(1.0, -0.9, 0.0));
        for k in 1..=180 {
            let y = -0.9 + 1.8 * k as f32 / 180.0;
            let v = sample(&map, RES, Vec3::new(1.0, y, 0.0));
            assert!((v - prev).abs() < 0.02, "step at {y}: {prev} -> {v}");
            prev = v;
        }
        assert_eq!(sample(&map, RES, -Vec3::X), 0.0);
    }

    #[test]
    fn trilinear_reproduces_corners_and_averages_the_middle() {
        let v = [0.0, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0];
        let b = Aabb::new(Vec3::ZERO, Vec3::new(2.0, 4.0, 8.0));
        for (k, want) in v.iter().enumerate() {
            assert!((trilinear(&v, box_coords(&b, corner(&b, k))) - want).abs() < 1e-6);
        }
        assert!((trilinear(&v, Vec3::splat(0.5)) - 3.5).abs() < 1e-6);
        // Clamped outside, and NaN-safe.
        assert_eq!(trilinear(&v, Vec3::splat(7.0)), 7.0);
        assert!(trilinear(&v, Vec3::splat(f32::NAN)).is_finite());
    }
}
