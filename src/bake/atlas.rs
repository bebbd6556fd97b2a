//! The impostor bake's image work on the CPU: a frame's supersampled pictures resolved to
//! its two maps (unlit colour with coverage, normal with depth), colour, normal and depth
//! spread into the uncovered texels so that filtering never reads the background, each
//! frame's own mip chain, and the atlases the frames are laid into (see the impostor
//! record in [`crate::format`] for the layout).

use glam::Vec3;

use crate::color::{linear_to_srgb, srgb_lut};
use crate::format::Impostor;
use crate::sphere::Frame;
use crate::{Error, Result};

/// One frame's two maps, `side` x `side` RGBA8 texels, rows top to bottom: `albedo` is
/// sRGB colour (not premultiplied) with coverage in alpha; `normal_depth` the normal as
/// `n * 0.5 + 0.5` (linear bytes) with depth in alpha.
#[derive(Clone, Debug, PartialEq)]
pub struct FrameMaps {
    pub side: u32,
    pub albedo: Vec<u8>,
    pub normal_depth: Vec<u8>,
}

fn unit_to_byte(x: f32) -> u8 {
    (x.clamp(0.0, 1.0) * 255.0 + 0.5) as u8
}

fn normal_of(px: &[u8]) -> Vec3 {
    Vec3::new(px[0].into(), px[1].into(), px[2].into()) / 255.0 * 2.0 - 1.0
}

fn normal_bytes(n: Vec3) -> [u8; 3] {
    let e = n * 0.5 + 0.5;
    [unit_to_byte(e.x), unit_to_byte(e.y), unit_to_byte(e.z)]
}

/// Sums of what a texel's samples hold, weighted: linear colour, normal, depth.
#[derive(Clone, Copy, Default)]
struct Sums {
    color: Vec3,
    normal: Vec3,
    depth: f32,
    weight: f32,
    /// The first normal added, for samples whose normals cancel out.
    first_normal: Option<Vec3>,
}

impl Sums {
    fn add(&mut self, lut: &[f32], albedo: &[u8], nd: &[u8], w: f32) {
        self.color += w * Vec3::new(
            lut[albedo[0] as usize],
            lut[albedo[1] as usize],
            lut[albedo[2] as usize],
        );
        let n = normal_of(nd);
        self.normal += w * n;
        self.depth += w * f32::from(nd[3]) / 255.0;
        self.weight += w;
        self.first_normal.get_or_insert(n);
    }

    /// The mean colour and normal-depth bytes, with `alpha` as the colour's alpha.
    fn write(&self, alpha: u8, albedo: &mut [u8], nd: &mut [u8]) {
        let w = self.weight.max(1e-12);
        let c = self.color / w;
        albedo.copy_from_slice(&[
            linear_to_srgb(c.x),
            linear_to_srgb(c.y),
            linear_to_srgb(c.z),
            alpha,
        ]);
        let n = self
            .normal
            .try_normalize()
            .or(self.first_normal)
            .unwrap_or(Vec3::Z);
        let [r, g, b] = normal_bytes(n);
        nd.copy_from_slice(&[r, g, b, unit_to_byte(self.depth / w)]);
    }
}

/// A frame's maps from its pictures drawn `ss` times larger (`side * ss` a side, RGBA8):
/// `albedo` (sRGB, alpha 0 or 1: the studio's background or a surface) and `normal_depth`
/// (bytes as the maps hold them, alpha the depth). Coverage is the share of covered
/// samples; colour (averaged in linear light), normal and depth are the means over the
/// covered samples alone.
pub fn resolve(albedo: &[u8], normal_depth: &[u8], side: u32, ss: u32) -> Result<FrameMaps> {
    let big = (side * ss) as usize;
    if albedo.len() != big * big * 4 || normal_depth.len() != albedo.len() {
        return Err(Error::Gpu(format!(
            "an impostor frame came back as {} and {} bytes, not {big}² pixels",
            albedo.len(),
            normal_depth.len()
        )));
    }
    let lut = srgb_lut();
    let n = side as usize;
    let ss = ss as usize;
    let mut out = FrameMaps {
        side,
        albedo: vec![0; n * n * 4],
        normal_depth: vec![0; n * n * 4],
    };
    for y in 0..n {
        for x in 0..n {
            let mut sums = Sums::default();
            let mut coverage = 0.0;
            for dy in 0..ss {
                for dx in 0..ss {
                    let i = ((y * ss + dy) * big + x * ss + dx) * 4;
                    let a = f32::from(albedo[i + 3]) / 255.0;
                    if a > 0.0 {
                        sums.add(&lut, &albedo[i..i + 4], &normal_depth[i..i + 4], a);
                        coverage += a;
                    }
                }
            }
            let o = (y * n + x) * 4;
            if sums.weight > 0.0 {
                let alpha = unit_to_byte(coverage / (ss * ss) as f32);
                sums.write(
                    alpha,
                    &mut out.albedo[o..o + 4],
                    &mut out.normal_depth[o..o + 4],
                );
            }
        }
    }
    Ok(out)
}

/// Spreads colour, normal and depth from the covered texels (alpha > 0) into the others,
/// ring by ring: each uncovered texel next to a filled one takes the mean of its filled
/// neighbours (8-connected), then the next ring. Coverage is left as it is. A frame with
/// nothing covered is left as it is.
pub fn dilate(maps: &mut FrameMaps) {
    let n = maps.side as usize;
    let lut = srgb_lut();
    let mut filled: Vec<bool> = (0..n * n).map(|i| maps.albedo[i * 4 + 3] > 0).collect();
    if !filled.iter().any(|&f| f) {
        return;
    }
    let neighbours = |i: usize| {
        let (x, y) = ((i % n) as isize, (i / n) as isize);
        (-1..=1isize)
            .flat_map(move |dy| (-1..=1isize).map(move |dx| (x + dx, y + dy)))
            .filter(move |&(px, py)| {
                (px, py) != (x, y) && px >= 0 && py >= 0 && px < n as isize && py < n as isize
            })
            .map(move |(px, py)| py as usize * n + px as usize)
    };
    let mut ring: Vec<usize> = (0..n * n)
        .filter(|&i| !filled[i] && neighbours(i).any(|j| filled[j]))
        .collect();
    let mut queued = vec![false; n * n];
    while !ring.is_empty() {
        // Every texel of the ring from the texels filled before it.
        let values: Vec<([u8; 4], [u8; 4])> = ring
            .iter()
            .map(|&i| {
                let mut sums = Sums::default();
                for j in neighbours(i).filter(|&j| filled[j]) {
                    let (a, d) = (&maps.albedo[j * 4..j * 4 + 4], &maps.normal_depth[j * 4..]);
                    sums.add(&lut, a, &d[..4], 1.0);
                }
                let (mut a, mut d) = ([0u8; 4], [0u8; 4]);
                sums.write(0, &mut a, &mut d);
                (a, d)
            })
            .collect();
        let mut next = Vec::new();
        for (&i, (a, d)) in ring.iter().zip(values) {
            maps.albedo[i * 4..i * 4 + 3].copy_from_slice(&a[..3]);
            maps.normal_depth[i * 4..i * 4 + 4].copy_from_slice(&d);
            filled[i] = true;
        }
        for &i in &ring {
            for j in neighbours(i) {
                if !filled[j] && !queued[j] {
                    queued[j] = true;
                    next.push(j);
                }
            }
        }
        ring = next;
    }
}

/// The frame's next mip level (half the side, at least 1): each texel from its 2 x 2
/// block, coverage the mean, colour (in linear light), normal and depth weighted by
/// coverage, or plain means where the block is all uncovered (its dilated values).
pub fn mip_down(maps: &FrameMaps) -> FrameMaps {
    let n = maps.side as usize;
    let h = (n / 2).max(1);
    let lut = srgb_lut();
    let mut out = FrameMaps {
        side: h as u32,
        albedo: vec![0; h * h * 4],
        normal_depth: vec![0; h * h * 4],
    };
    for y in 0..h {
        for x in 0..h {
            let block: Vec<usize> = [(0, 0), (1, 0), (0, 1), (1, 1)]
                .iter()
                .map(|&(dx, dy)| ((2 * y + dy).min(n - 1) * n + (2 * x + dx).min(n - 1)) * 4)
                .collect();
            let coverage: f32 = block
                .iter()
                .map(|&i| f32::from(maps.albedo[i + 3]) / 255.0)
                .sum();
            let mut sums = Sums::default();
            for &i in &block {
                let w = if coverage > 0.0 {
                    f32::from(maps.albedo[i + 3]) / 255.0
                } else {
                    1.0
                };
                if w > 0.0 {
                    let (a, d) = (&maps.albedo[i..i + 4], &maps.normal_depth[i..i + 4]);
                    sums.add(&lut, a, d, w);
                }
            }
            let o = (y * h + x) * 4;
            sums.write(
                unit_to_byte(coverage / 4.0),
                &mut out.albedo[o..o + 4],
                &mut out.normal_depth[o..o + 4],
            );
        }
    }
    out
}

/// The two atlases of an impostor, every level, being filled frame by frame.
pub struct Atlas {
    frames: u32,
    resolution: u32,
    mip_levels: u32,
    pub albedo: Vec<u8>,
    pub normal_depth: Vec<u8>,
}

impl Atlas {
    /// Empty (zeroed) atlases of `frames` x `frames` frames of `resolution` pixels, with
    /// `mip_levels` levels.
    pub fn new(frames: u32, resolution: u32, mip_levels: u32) -> Result<Self> {
        let len = Impostor::atlas_bytes(frames, resolution, mip_levels)
            .and_then(|l| usize::try_from(l).ok())
            .ok_or_else(|| Error::BadInput("the impostor atlas is too large".into()))?;
        Ok(Self {
            frames,
            resolution,
            mip_levels,
            albedo: vec![0; len],
            normal_depth: vec![0; len],
        })
    }

    /// Lays `maps` (level 0 of frame `f`, `resolution` a side) into every level: each level
    /// from the one above, within the frame alone.
    pub fn put(&mut self, f: Frame, maps: FrameMaps) -> Result<()> {
        if maps.side != self.resolution || f.i >= self.frames || f.j >= self.frames {
            return Err(Error::BadInput(format!(
                "frame ({}, {}) of {} pixels does not fit a {}-frame atlas of {} pixels",
                f.i, f.j, maps.side, self.frames, self.resolution
            )));
        }
        let mut level = maps;
        let mut offset = 0usize;
        for m in 0..self.mip_levels {
            if m > 0 {
                level = mip_down(&level);
            }
            let side = level.side as usize;
            let row = self.frames as usize * side;
            for y in 0..side {
                let dst = offset + ((f.j as usize * side + y) * row + f.i as usize * side) * 4;
                let src = y * side * 4;
                self.albedo[dst..dst + side * 4]
                    .copy_from_slice(&level.albedo[src..src + side * 4]);
                self.normal_depth[dst..dst + side * 4]
                    .copy_from_slice(&level.normal_depth[src..src + side * 4]);
            }
            offset += row * row * 4;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A frame of `side` with a covered disc of `r` texels in the middle: red albedo,
    /// normal +X, depth 0.25; the rest background (zero).
    fn disc(side: u32, r: f32) -> FrameMaps {
        let n = side as usize;
        let mut m = FrameMaps {
            side,
            albedo: vec![0; n * n * 4],
            normal_depth: vec![0; n * n * 4],
        };
        for y in 0..n {
            for x in 0..n {
                let c = (n as f32 - 1.0) / 2.0;
                if (x as f32 - c).hypot(y as f32 - c) <= r {
                    let i = (y * n + x) * 4;
                    m.albedo[i..i + 4].copy_from_slice(&[255, 0, 0, 255]);
                    m.normal_depth[i..i + 4].copy_from_slice(&[255, 128, 128, 64]);
                }
            }
        }
        m
    }

    #[test]
    fn resolving_averages_covered_samples_only() {
        // 2 x 2 samples into one texel: two covered (white and black), two background.
        let albedo = [255, 255, 255, 255, 0, 0, 0, 255, 9, 9, 9, 0, 9, 9, 9, 0];
        let nd = [255, 128, 128, 0, 128, 255, 128, 255, 0, 0, 0, 0, 0, 0, 0, 0];
        let m = resolve(&albedo, &nd, 1, 2).unwrap();
        // Half covered; colour the linear mean of white and black (sRGB 188); the normal
        // the normalised mean of +X and +Y; depth the mean of 0 and 1.
        assert_eq!(m.albedo, [188, 188, 188, 128]);
        let n = normal_of(&m.normal_depth);
        assert!(
            (n - Vec3::new(1.0, 1.0, 0.0).normalize()).length() < 0.02,
            "{n}"
        );
        assert_eq!(m.normal_depth[3], 128);
        assert!(
            resolve(&albedo, &nd, 2, 2).is_err(),
            "wrong sizes are refused"
        );
    }

    #[test]
    fn dilation_fills_every_texel_and_keeps_coverage() {
        let mut m = disc(16, 3.0);
        let before = m.clone();
        dilate(&mut m);
        for i in 0..16 * 16 {
            assert_eq!(
                m.albedo[i * 4 + 3],
                before.albedo[i * 4 + 3],
                "coverage kept"
            );
            assert_eq!(&m.albedo[i * 4..i * 4 + 3], [255, 0, 0], "texel {i}");
            assert_eq!(&m.normal_depth[i * 4..i * 4 + 4], [255, 128, 128, 64]);
        }
        // Nothing covered: nothing to spread.
        let mut empty = disc(8, -1.0);
        let was = empty.clone();
        dilate(&mut empty);
        assert_eq!(empty, was);
    }

    #[test]
    fn mips_keep_the_colour_of_a_dilated_frame_and_average_coverage() {
        let mut m = disc(16, 4.0);
        let covered: f32 = (0..256)
            .map(|i| f32::from(m.albedo[i * 4 + 3]) / 255.0)
            .sum();
        dilate(&mut m);
        let mut level = m;
        while level.side > 1 {
            level = mip_down(&level);
            let n = (level.side * level.side) as usize;
            for i in 0..n {
                // No background black bleeds in: the colour stays the disc's.
                assert_eq!(
                    &level.albedo[i * 4..i * 4 + 3],
                    [255, 0, 0],
                    "{}",
                    level.side
                );
                assert_eq!(level.normal_depth[i * 4 + 3], 64);
            }
            let mean: f32 = (0..n)
                .map(|i| f32::from(level.albedo[i * 4 + 3]) / 255.0)
                .sum::<f32>()
                / n as f32;
            assert!(
                (mean - covered / 256.0).abs() < 0.02,
                "{} {mean}",
                level.side
            );
        }
    }

    #[test]
    fn frames_keep_to_their_tiles_at_every_level() {
        // Two frames of a 2 x 2 atlas: one covered white, one left empty. No level of the
        // empty frame's tile sees the white one.
        let mut atlas = Atlas::new(2, 8, 3).unwrap();
        let n = 8 * 8 * 4;
        let white = FrameMaps {
            side: 8,
            albedo: vec![255; n],
            normal_depth: vec![200; n],
        };
        atlas.put(Frame { i: 1, j: 0 }, white).unwrap();
        let mut offset = 0;
        for side in [8usize, 4, 2] {
            let row = 2 * side;
            for y in 0..row {
                for x in 0..row {
                    let px = offset + (y * row + x) * 4;
                    let inside = x >= side && y < side;
                    let want = if inside { 255 } else { 0 };
                    assert_eq!(atlas.albedo[px], want, "level of {side}: ({x}, {y})");
                }
            }
            offset += row * row * 4;
        }
        assert_eq!(offset, atlas.albedo.len());
        assert!(atlas.put(Frame { i: 2, j: 0 }, disc(8, 1.0)).is_err());
        assert!(atlas.put(Frame { i: 0, j: 0 }, disc(4, 1.0)).is_err());
    }
}
