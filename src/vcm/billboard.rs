//! Objects drawn into visibility cube maps as the `btf` method draws them: each one a
//! billboard facing the cube's centre, its opacity the blend of the 3 nearest views'
//! sky-lit images' alpha, mip-filtered to the cube's texel. The bake draws them onto whole
//! cubes ([`super::CubeRaster`]); the forest cells' shading casts single rays through the
//! trees that share a cell ([`super::ray_opacity`]).

use glam::{Mat3, Mat4, Vec2, Vec3};

use crate::sphere::{Blend, DirectionSet, billboard_axes};

use super::Occluder;

/// One level's sky-lit images as occluders: each view's alpha with its mip chain.
pub struct AlphaSet {
    views: DirectionSet,
    view_axes: Vec<(Vec3, Vec3)>,
    /// [view][mip] alpha, res_mip² values.
    mips: Vec<Vec<Vec<f32>>>,
    res: u32,
    pub center: Vec3,
    pub radius: f32,
}

impl AlphaSet {
    /// One level's occluders from its sky-lit images: the first `views` RGBA8 images of
    /// `resolution`² pixels each in `images` (one per direction of
    /// [`DirectionSet::with_count`]`(views)`, their alpha the coverage), the object's bounding
    /// sphere at `center` with `radius`. The baked file's sets come through
    /// `AlphaSet::new` (in `format`), which checks their lengths first. Err says what is
    /// wrong: a view count no direction set has, or too few bytes.
    pub fn from_sky_lit(
        views: u32,
        resolution: u32,
        images: &[u8],
        center: Vec3,
        radius: f32,
    ) -> Result<Self, String> {
        let dirs = DirectionSet::with_count(views as usize).map_err(|e| e.to_string())?;
        let res = resolution.max(1);
        let n = (res * res) as usize;
        if images.len() / (n * 4) < views as usize {
            return Err(format!(
                "{} bytes hold fewer than {views} images of {res}² pixels",
                images.len()
            ));
        }
        // The sky-lit images (the first of each view's two): their alpha is the coverage.
        let mips = images
            .chunks_exact(n * 4)
            .take(views as usize)
            .map(|img| {
                let mut level: Vec<f32> = img
                    .chunks_exact(4)
                    .map(|p| f32::from(p[3]) / 255.0)
                    .collect();
                let mut side = res as usize;
                let mut chain = Vec::new();
                loop {
                    let next = if side > 1 {
                        Some(halve(&level, side))
                    } else {
                        None
                    };
                    chain.push(level);
                    match next {
                        Some(l) => {
                            level = l;
                            side /= 2;
                        }
                        None => break,
                    }
                }
                chain
            })
            .collect();
        let view_axes = dirs
            .directions()
            .iter()
            .map(|&v| billboard_axes(v))
            .collect();
        Ok(Self {
            views: dirs,
            view_axes,
            mips,
            res,
            center,
            radius,
        })
    }

    /// Alpha of view `v` at `uv` (0..1 over the image), filtered over `texels` texels.
    fn alpha(&self, v: usize, uv: Vec2, texels: f32) -> f32 {
        let chain = &self.mips[v];
        let level = if texels > 1.0 {
            (texels.log2().round() as usize).min(chain.len() - 1)
        } else {
            0
        };
        let side = (self.res as usize >> level).max(1);
        let img = &chain[level];
        let s = side as f32;
        let fx = (uv.x * s - 0.5).clamp(0.0, s - 1.0);
        let fy = (uv.y * s - 0.5).clamp(0.0, s - 1.0);
        let (x0, y0) = (fx as usize, fy as usize);
        let (x1, y1) = ((x0 + 1).min(side - 1), (y0 + 1).min(side - 1));
        let (a, b) = (fx - x0 as f32, fy - y0 as f32);
        let at = |x: usize, y: usize| img[y * side + x];
        let top = at(x0, y0) + (at(x1, y0) - at(x0, y0)) * a;
        let bottom = at(x0, y1) + (at(x1, y1) - at(x0, y1)) * a;
        top + (bottom - top) * b
    }
}

/// A 2x2 box filter of a `side`² image.
fn halve(img: &[f32], side: usize) -> Vec<f32> {
    let h = (side / 2).max(1);
    let mut out = vec![0.0; h * h];
    for y in 0..h {
        for x in 0..h {
            let at = |xx: usize, yy: usize| img[yy.min(side - 1) * side + xx.min(side - 1)];
            out[y * h + x] = 0.25
                * (at(2 * x, 2 * y)
                    + at(2 * x + 1, 2 * y)
                    + at(2 * x, 2 * y + 1)
                    + at(2 * x + 1, 2 * y + 1));
        }
    }
    out
}

/// One object's billboard as the cube's centre sees it.
pub struct Billboard<'a> {
    set: &'a AlphaSet,
    blend: Blend,
    center: Vec3,
    right: Vec3,
    up: Vec3,
    obj_right: Vec3,
    obj_up: Vec3,
}

impl<'a> Billboard<'a> {
    /// The billboard of `set` placed by `m` (object to cube frame), facing `eye`; None for a
    /// degenerate transform.
    pub fn facing(set: &'a AlphaSet, m: Mat4, eye: Vec3) -> Option<Self> {
        let scale = m.x_axis.truncate().length();
        if !(scale > 0.0 && scale.is_finite()) {
            return None;
        }
        let rot = Mat3::from_mat4(m) * (1.0 / scale);
        let center = m.transform_point3(set.center);
        let radius = set.radius * scale;
        let v_obj = rot.transpose() * (eye - center).normalize_or(Vec3::Y);
        let (r, u) = billboard_axes(v_obj);
        Some(Self {
            set,
            blend: set.views.blend(v_obj),
            center,
            right: rot * r * radius,
            up: rot * u * radius,
            obj_right: r,
            obj_up: u,
        })
    }
}

impl Occluder for Billboard<'_> {
    fn center(&self) -> Vec3 {
        self.center
    }
    fn right(&self) -> Vec3 {
        self.right
    }
    fn up(&self) -> Vec3 {
        self.up
    }
    fn opacity(&self, s: f32, t: f32, footprint: f32) -> f32 {
        let p = s * self.obj_right + t * self.obj_up;
        let texels = footprint * 0.5 * self.set.res as f32;
        let mut a = 0.0;
        for k in 0..3 {
            let w = self.blend.weight[k];
            if w <= 0.0 {
                continue;
            }
            let v = self.blend.index[k] as usize;
            let (r, u) = self.set.view_axes[v];
            let uv = Vec2::new(p.dot(r), -p.dot(u)) * 0.5 + 0.5;
            a += w * self.set.alpha(v, uv, texels);
        }
        a
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn halving_averages_blocks() {
        let img = [
            0.0, 1.0, 0.0, 1.0, 1.0, 1.0, 0.0, 0.0, 0.5, 0.5, 1.0, 1.0, 0.5, 0.5, 1.0, 1.0,
        ];
        assert_eq!(halve(&img, 4), vec![0.75, 0.25, 0.5, 1.0]);
    }
}
