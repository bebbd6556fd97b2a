//! Octahedral maps of view directions, for octahedral impostors: a direction becomes a point
//! of the unit square (`uv`), the square is cut into a grid of frames, and any direction is
//! drawn from the 3 frames of the grid triangle it falls in, with barycentric weights.
//!
//! Two layouts, in the object's frame (y up):
//! - [`OctaLayout::Full`]: the whole sphere. The upper hemisphere fills the diamond in the
//!   middle of the square (+Y at its centre), the lower one the four corner triangles (-Y
//!   at the four corners); the square's border is folded onto itself (the point (0, v) is
//!   the direction of (0, 1 - v), and likewise on every side).
//! - [`OctaLayout::Hemi`]: the upper hemisphere alone, turned 45° so it fills the square
//!   (+Y at the centre, the horizon on the border, +X, -Z, -X, +Z at the corners).
//!   Directions below the horizon are drawn as the horizon direction above them.
//!
//! Frame `(i, j)` of `n` per side is the view along the direction at grid point
//! `uv = (i, j) / (n - 1)`, so the first and last rows and columns lie on the square's
//! border: in the full layout the frames on the border repeat the directions of their
//! mirror images there, which keeps the blend continuous across the folds; in the hemi
//! layout they are the horizon views. In the atlas frame `(i, j)` is the tile at column
//! `i`, row `j`.
//!
//! Every function takes any direction (zero or NaN reads as +Y) and any uv (clamped to the
//! square); nothing here panics.

use glam::{Vec2, Vec3};

/// Which directions an octahedral map covers.
#[derive(
    Clone, Copy, Debug, Default, PartialEq, Eq, Hash, serde::Deserialize, serde::Serialize,
)]
#[serde(rename_all = "kebab-case")]
pub enum OctaLayout {
    /// The whole sphere: trees seen from below (from the ground, every crown's centre is
    /// above the eye) have frames of their own.
    #[default]
    Full,
    /// The upper hemisphere: frames twice as dense for the same count, none from below.
    Hemi,
}

impl OctaLayout {
    /// The tag a baked file stores: 0 full, 1 hemi.
    pub fn tag(self) -> u32 {
        match self {
            OctaLayout::Full => 0,
            OctaLayout::Hemi => 1,
        }
    }

    /// The layout of a stored tag, if any.
    pub fn from_tag(tag: u32) -> Option<Self> {
        match tag {
            0 => Some(OctaLayout::Full),
            1 => Some(OctaLayout::Hemi),
            _ => None,
        }
    }

    /// "full" or "hemi", as a scene file writes it.
    pub fn name(self) -> &'static str {
        match self {
            OctaLayout::Full => "full",
            OctaLayout::Hemi => "hemi",
        }
    }

    /// The point of the unit square that `dir` maps to.
    pub fn dir_to_uv(self, dir: Vec3) -> Vec2 {
        let d = usable(dir);
        match self {
            OctaLayout::Full => {
                let p = d / (d.x.abs() + d.y.abs() + d.z.abs());
                let e = if p.y >= 0.0 {
                    Vec2::new(p.x, p.z)
                } else {
                    Vec2::new((1.0 - p.z.abs()) * sign(p.x), (1.0 - p.x.abs()) * sign(p.z))
                };
                (e * 0.5 + 0.5).clamp(Vec2::ZERO, Vec2::ONE)
            }
            OctaLayout::Hemi => {
                let h = Vec3::new(d.x, d.y.max(0.0), d.z);
                // A direction straight down has no horizon direction above it: +X's.
                let h = if h.x == 0.0 && h.y == 0.0 && h.z == 0.0 {
                    Vec3::X
                } else {
                    h
                };
                let p = h / (h.x.abs() + h.y + h.z.abs());
                let e = Vec2::new(p.x + p.z, p.x - p.z);
                (e * 0.5 + 0.5).clamp(Vec2::ZERO, Vec2::ONE)
            }
        }
    }

    /// The unit direction at the point `uv` of the unit square (clamped to it).
    pub fn uv_to_dir(self, uv: Vec2) -> Vec3 {
        let uv = if uv.is_finite() { uv } else { Vec2::splat(0.5) };
        let e = uv.clamp(Vec2::ZERO, Vec2::ONE) * 2.0 - 1.0;
        match self {
            OctaLayout::Full => {
                let y = 1.0 - e.x.abs() - e.y.abs();
                let (x, z) = if y >= 0.0 {
                    (e.x, e.y)
                } else {
                    ((1.0 - e.y.abs()) * sign(e.x), (1.0 - e.x.abs()) * sign(e.y))
                };
                Vec3::new(x, y, z).normalize_or(Vec3::Y)
            }
            OctaLayout::Hemi => {
                let x = 0.5 * (e.x + e.y);
                let z = 0.5 * (e.x - e.y);
                let y = (1.0 - x.abs() - z.abs()).max(0.0);
                Vec3::new(x, y, z).normalize_or(Vec3::Y)
            }
        }
    }
}

/// `dir` normalised; +Y for a zero or NaN direction, and an infinite one along its
/// infinite components.
fn usable(dir: Vec3) -> Vec3 {
    let d = if dir.is_finite() {
        dir
    } else {
        Vec3::select(dir.is_nan_mask(), Vec3::ZERO, dir)
            .map(|c| if c.is_infinite() { c.signum() } else { 0.0 })
    };
    d.normalize_or(Vec3::Y)
}

/// -1 or 1 (0 counts as positive, so the folds are one-sided and never a zero vector).
fn sign(x: f32) -> f32 {
    if x < 0.0 { -1.0 } else { 1.0 }
}

/// The frames of an octahedral impostor: `frames` x `frames` views on a layout's square.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct OctaGrid {
    pub layout: OctaLayout,
    /// Frames per side, at least 2.
    pub frames: u32,
}

/// One frame of a grid: column `i`, row `j` (the atlas tile, and the index `j * n + i`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct Frame {
    pub i: u32,
    pub j: u32,
}

/// The 3 frames a direction is drawn from and their weights (>= 0, summing to 1).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FrameBlend {
    pub frames: [Frame; 3],
    pub weights: [f32; 3],
}

impl OctaGrid {
    /// A grid of `frames` per side (fewer than 2 is read as 2).
    pub fn new(layout: OctaLayout, frames: u32) -> Self {
        Self {
            layout,
            frames: frames.max(2),
        }
    }

    /// Number of frames.
    pub fn len(&self) -> usize {
        (self.frames as usize).pow(2)
    }

    /// Always false: a grid has at least 2 x 2 frames.
    pub fn is_empty(&self) -> bool {
        false
    }

    /// Frame number `index` (row-major: `j * frames + i`), clamped to the grid.
    pub fn frame(&self, index: usize) -> Frame {
        let n = self.frames as usize;
        let k = index.min(n * n - 1);
        Frame {
            i: (k % n) as u32,
            j: (k / n) as u32,
        }
    }

    /// The row-major index of `f`.
    pub fn index(&self, f: Frame) -> usize {
        f.j as usize * self.frames as usize + f.i as usize
    }

    /// The point of the square at the centre of frame `f`'s view.
    pub fn frame_uv(&self, f: Frame) -> Vec2 {
        let last = (self.frames - 1) as f32;
        Vec2::new(
            f.i.min(self.frames - 1) as f32,
            f.j.min(self.frames - 1) as f32,
        ) / last
    }

    /// The unit direction frame `f` looks from (from the object towards its camera).
    pub fn frame_dir(&self, f: Frame) -> Vec3 {
        self.layout.uv_to_dir(self.frame_uv(f))
    }

    /// Every frame's direction, row-major.
    pub fn directions(&self) -> Vec<Vec3> {
        (0..self.len())
            .map(|k| self.frame_dir(self.frame(k)))
            .collect()
    }

    /// The 3 frames around `dir` and their barycentric weights in the grid cell's triangle:
    /// a cell of corners c, c+x, c+y, c+x+y is split along its c+x .. c+y diagonal.
    pub fn blend(&self, dir: Vec3) -> FrameBlend {
        self.blend_uv(self.layout.dir_to_uv(dir))
    }

    /// [`Self::blend`] at a point of the square.
    pub fn blend_uv(&self, uv: Vec2) -> FrameBlend {
        let last = self.frames - 1;
        let uv = if uv.is_finite() { uv } else { Vec2::splat(0.5) };
        let g = uv.clamp(Vec2::ZERO, Vec2::ONE) * last as f32;
        let c = g
            .floor()
            .min(Vec2::splat((last - 1) as f32))
            .max(Vec2::ZERO);
        let f = (g - c).clamp(Vec2::ZERO, Vec2::ONE);
        let (ci, cj) = (c.x as u32, c.y as u32);
        let at = |di: u32, dj: u32| Frame {
            i: ci + di,
            j: cj + dj,
        };
        if f.x + f.y <= 1.0 {
            FrameBlend {
                frames: [at(0, 0), at(1, 0), at(0, 1)],
                weights: [1.0 - f.x - f.y, f.x, f.y],
            }
        } else {
            FrameBlend {
                frames: [at(1, 1), at(0, 1), at(1, 0)],
                weights: [f.x + f.y - 1.0, 1.0 - f.x, 1.0 - f.y],
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sphere::test_support::Rng;

    const LAYOUTS: [OctaLayout; 2] = [OctaLayout::Full, OctaLayout::Hemi];

    fn upper(d: Vec3) -> Vec3 {
        Vec3::new(d.x, d.y.abs(), d.z)
    }

    #[test]
    fn mapping_and_inverse_round_trip() {
        let mut rng = Rng(7);
        for _ in 0..20_000 {
            let d = rng.direction();
            let full = OctaLayout::Full;
            let back = full.uv_to_dir(full.dir_to_uv(d));
            assert!(back.angle_between(d) < 1e-3, "full: {d} -> {back}");
            let hemi = OctaLayout::Hemi;
            let up = upper(d);
            let back = hemi.uv_to_dir(hemi.dir_to_uv(up));
            assert!(back.angle_between(up) < 1e-3, "hemi: {up} -> {back}");
        }
        // And the other way: every point of the square is some direction's point (for the
        // full layout up to the folds of its border, where two points are one direction).
        for layout in LAYOUTS {
            for a in 0..=40 {
                for b in 0..=40 {
                    let uv = Vec2::new(a as f32, b as f32) / 40.0;
                    let d = layout.uv_to_dir(uv);
                    assert!((d.length() - 1.0).abs() < 1e-5);
                    let again = layout.uv_to_dir(layout.dir_to_uv(d));
                    assert!(again.angle_between(d) < 1e-3, "{layout:?} {uv}");
                }
            }
        }
    }

    #[test]
    fn the_layouts_put_the_axes_where_the_docs_say() {
        let full = OctaLayout::Full;
        assert!(full.dir_to_uv(Vec3::Y).distance(Vec2::splat(0.5)) < 1e-6);
        for corner in [Vec2::ZERO, Vec2::X, Vec2::Y, Vec2::ONE] {
            assert!(full.uv_to_dir(corner).distance(-Vec3::Y) < 1e-6);
        }
        let hemi = OctaLayout::Hemi;
        assert!(hemi.dir_to_uv(Vec3::Y).distance(Vec2::splat(0.5)) < 1e-6);
        assert!(hemi.uv_to_dir(Vec2::ONE).distance(Vec3::X) < 1e-6);
        assert!(hemi.uv_to_dir(Vec2::ZERO).distance(-Vec3::X) < 1e-6);
        // Below the horizon reads as the horizon above it.
        let below = Vec3::new(0.6, -0.5, 0.2);
        let h = hemi.uv_to_dir(hemi.dir_to_uv(below));
        assert!(h.y.abs() < 1e-5 && h.angle_between(Vec3::new(0.6, 0.0, 0.2)) < 1e-3);
        for tag in 0..2 {
            assert_eq!(OctaLayout::from_tag(tag).map(OctaLayout::tag), Some(tag));
        }
        assert_eq!(OctaLayout::from_tag(2), None);
    }

    #[test]
    fn odd_inputs_give_usable_answers() {
        for layout in LAYOUTS {
            for d in [
                Vec3::ZERO,
                Vec3::NAN,
                Vec3::new(f32::INFINITY, 0.0, 0.0),
                -Vec3::Y,
            ] {
                let uv = layout.dir_to_uv(d);
                assert!(uv.is_finite() && uv.cmpge(Vec2::ZERO).all() && uv.cmple(Vec2::ONE).all());
                let b = OctaGrid::new(layout, 8).blend(d);
                assert!((b.weights.iter().sum::<f32>() - 1.0).abs() < 1e-5);
            }
            let d = layout.uv_to_dir(Vec2::new(f32::NAN, 3.0));
            assert!(d.is_finite());
        }
        assert_eq!(
            OctaLayout::Full.dir_to_uv(Vec3::new(f32::INFINITY, 0.0, 0.0)),
            OctaLayout::Full.dir_to_uv(Vec3::X)
        );
        assert_eq!(OctaGrid::new(OctaLayout::Full, 0).frames, 2);
    }

    #[test]
    fn weights_are_non_negative_and_sum_to_one() {
        let mut rng = Rng(11);
        for layout in LAYOUTS {
            for n in [2, 3, 8, 12, 16, 31] {
                let grid = OctaGrid::new(layout, n);
                for _ in 0..5_000 {
                    let b = grid.blend(rng.direction());
                    assert!(b.weights.iter().all(|&w| w >= 0.0), "{b:?}");
                    assert!((b.weights.iter().sum::<f32>() - 1.0).abs() < 1e-5, "{b:?}");
                    assert!(b.frames.iter().all(|f| f.i < n && f.j < n), "{b:?}");
                }
            }
        }
    }

    #[test]
    fn a_frames_own_direction_gives_that_frame_alone() {
        for layout in LAYOUTS {
            for n in [2, 5, 12, 16] {
                let grid = OctaGrid::new(layout, n);
                for k in 0..grid.len() {
                    let f = grid.frame(k);
                    assert_eq!(grid.index(f), k);
                    let b = grid.blend(grid.frame_dir(f));
                    let best = (0..3)
                        .max_by(|&a, &b2| b.weights[a].total_cmp(&b.weights[b2]))
                        .unwrap_or(0);
                    assert!(b.weights[best] > 1.0 - 1e-4, "{layout:?} {n} {f:?}: {b:?}");
                    // On the full layout's border a frame may be its mirror twin: same view.
                    let got = grid.frame_dir(b.frames[best]);
                    assert!(
                        got.angle_between(grid.frame_dir(f)) < 1e-4,
                        "{layout:?} {n} {f:?}: {b:?}"
                    );
                    if layout == OctaLayout::Hemi {
                        assert_eq!(b.frames[best], f);
                    }
                }
            }
        }
    }

    /// The blend seen as weights on view directions: the same view reached through two
    /// frames (the full layout's mirror twins on its border) adds up.
    fn weights_by_direction(grid: &OctaGrid, d: Vec3) -> Vec<(Vec3, f32)> {
        let b = grid.blend(d);
        let mut out: Vec<(Vec3, f32)> = Vec::new();
        for (f, w) in b.frames.iter().zip(b.weights) {
            let v = grid.frame_dir(*f);
            match out.iter_mut().find(|(u, _)| u.angle_between(v) < 1e-4) {
                Some((_, sum)) => *sum += w,
                None => out.push((v, w)),
            }
        }
        out.retain(|(_, w)| *w > 1e-6);
        out
    }

    /// Largest weight difference, over every view direction, between two blends.
    fn blend_distance(a: &[(Vec3, f32)], b: &[(Vec3, f32)]) -> f32 {
        let weight_in = |set: &[(Vec3, f32)], v: Vec3| {
            set.iter()
                .find(|(u, _)| u.angle_between(v) < 1e-4)
                .map_or(0.0, |(_, w)| *w)
        };
        a.iter()
            .chain(b)
            .map(|&(v, _)| (weight_in(a, v) - weight_in(b, v)).abs())
            .fold(0.0, f32::max)
    }

    #[test]
    fn the_blend_is_continuous_across_the_folds() {
        // Pairs of directions a hair apart on either side of each fold: the full layout's
        // border (lower hemisphere, x = 0 or z = 0) and the equator, the hemi layout's
        // horizon. The blend (weights per view direction) barely moves between them.
        let eps = 1e-4;
        let mut rng = Rng(3);
        for n in [4, 8, 12, 16] {
            let full = OctaGrid::new(OctaLayout::Full, n);
            let hemi = OctaGrid::new(OctaLayout::Hemi, n);
            for _ in 0..2_000 {
                let r = rng.direction();
                let (a, b) = (r.x.abs().max(0.05), r.z.abs().max(0.05));
                let y = -r.y.abs().max(0.05);
                let h = Vec3::new(r.x, 0.0, r.z).normalize_or(Vec3::X);
                let pairs = [
                    // Across x = 0 below the equator.
                    (Vec3::new(eps, y, b), Vec3::new(-eps, y, b)),
                    (Vec3::new(eps, y, -b), Vec3::new(-eps, y, -b)),
                    // Across z = 0 below the equator.
                    (Vec3::new(a, y, eps), Vec3::new(a, y, -eps)),
                    (Vec3::new(-a, y, eps), Vec3::new(-a, y, -eps)),
                    // Across the equator.
                    (h + eps * Vec3::Y, h - eps * Vec3::Y),
                ];
                for (p, q) in pairs {
                    let (p, q) = (p.normalize(), q.normalize());
                    let d = blend_distance(
                        &weights_by_direction(&full, p),
                        &weights_by_direction(&full, q),
                    );
                    assert!(d < 0.01, "full {n}: {p} / {q}: {d}");
                }
                if r.x * r.x + r.z * r.z < 0.01 {
                    continue;
                }
                let (p, q) = (
                    Vec3::new(r.x, eps, r.z).normalize_or(Vec3::X),
                    Vec3::new(r.x, -0.3, r.z).normalize_or(Vec3::X),
                );
                let d = blend_distance(
                    &weights_by_direction(&hemi, p),
                    &weights_by_direction(&hemi, q),
                );
                assert!(d < 0.01, "hemi {n}: {p} / {q}: {d}");
            }
        }
    }

    #[test]
    fn the_blend_moves_smoothly_along_a_path() {
        // A small step of the view moves the weights by a bounded amount everywhere: no
        // jump where the path crosses a cell, a diagonal or a fold.
        for layout in LAYOUTS {
            let grid = OctaGrid::new(layout, 12);
            let steps = 4_000;
            let mut prev: Option<Vec<(Vec3, f32)>> = None;
            for k in 0..=steps {
                let t = k as f32 / steps as f32 * std::f32::consts::TAU;
                let d = Vec3::new(t.cos(), 0.3 * (3.0 * t).sin(), t.sin() * 0.9 + 0.1);
                let w = weights_by_direction(&grid, d);
                if let Some(p) = &prev {
                    let jump = blend_distance(p, &w);
                    assert!(jump < 0.08, "{layout:?} at step {k}: {jump}");
                }
                prev = Some(w);
            }
        }
    }
}
