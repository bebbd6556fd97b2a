//! Image comparison: NVIDIA's FLIP (through `nv-flip`) between a reference and a test image,
//! summarised as the mean and percentiles of the per-pixel error. Every stand-in is judged
//! against the full-geometry render with these numbers.

use std::path::Path;

use image::RgbImage;

use crate::{Error, Result};

/// Pixels per degree of visual angle FLIP assumes: the default of the FLIP paper
/// (a 0.7 m viewing distance from a 24" 4K monitor, about 67 ppd).
pub const PIXELS_PER_DEGREE: f32 = nv_flip::DEFAULT_PIXELS_PER_DEGREE;

/// Summary of a FLIP error map. All values are in 0..=1; 0 means identical.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct FlipStats {
    pub mean: f32,
    pub p50: f32,
    pub p90: f32,
    pub p99: f32,
    pub max: f32,
}

/// The per-pixel FLIP error map plus its summary.
pub struct FlipResult {
    pub stats: FlipStats,
    pub width: u32,
    pub height: u32,
    pub errors: Vec<f32>,
}

impl FlipResult {
    /// The error map coloured with the magma ramp FLIP uses, for eyes rather than numbers.
    pub fn error_image(&self) -> RgbImage {
        let map = nv_flip::FlipImageFloat::with_data(self.width, self.height, &self.errors);
        let coloured = map.apply_color_lut(&nv_flip::magma_lut());
        RgbImage::from_raw(self.width, self.height, coloured.to_vec())
            .unwrap_or_else(|| RgbImage::new(self.width, self.height))
    }
}

/// FLIP between two images of the same size (`reference` is the ground truth).
pub fn flip(reference: &RgbImage, test: &RgbImage) -> Result<FlipResult> {
    if reference.dimensions() != test.dimensions() {
        let (aw, ah) = reference.dimensions();
        let (bw, bh) = test.dimensions();
        return Err(Error::ImageSizeMismatch {
            a: "reference".into(),
            aw,
            ah,
            b: "test".into(),
            bw,
            bh,
        });
    }
    let (width, height) = reference.dimensions();
    if width == 0 || height == 0 {
        return Err(Error::BadSize {
            width,
            height,
            reason: "FLIP needs at least one pixel",
        });
    }
    let r = nv_flip::FlipImageRgb8::with_data(width, height, reference.as_raw());
    let t = nv_flip::FlipImageRgb8::with_data(width, height, test.as_raw());
    let map = nv_flip::flip(r, t, PIXELS_PER_DEGREE);
    let errors = map.to_vec();
    let stats = summarise(&errors);
    Ok(FlipResult {
        stats,
        width,
        height,
        errors,
    })
}

/// Mean and percentiles (nearest rank) of a list of per-pixel errors.
pub fn summarise(errors: &[f32]) -> FlipStats {
    if errors.is_empty() {
        return FlipStats {
            mean: 0.0,
            p50: 0.0,
            p90: 0.0,
            p99: 0.0,
            max: 0.0,
        };
    }
    let mut sorted: Vec<f32> = errors
        .iter()
        .map(|e| if e.is_finite() { *e } else { 1.0 })
        .collect();
    sorted.sort_by(f32::total_cmp);
    let pick = |p: f64| {
        let rank = ((p * sorted.len() as f64).ceil() as usize).clamp(1, sorted.len());
        sorted[rank - 1]
    };
    let mean = (sorted.iter().map(|&e| f64::from(e)).sum::<f64>() / sorted.len() as f64) as f32;
    FlipStats {
        mean,
        p50: pick(0.50),
        p90: pick(0.90),
        p99: pick(0.99),
        max: sorted[sorted.len() - 1],
    }
}

/// What a pixel of the truth shows (`render --pixel-classes` draws them).
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum PixelClass {
    Sky,
    Ground,
    NearTrees,
    FarTrees,
}

impl PixelClass {
    pub const ALL: [PixelClass; 4] = [
        PixelClass::Sky,
        PixelClass::Ground,
        PixelClass::NearTrees,
        PixelClass::FarTrees,
    ];

    pub fn name(self) -> &'static str {
        match self {
            PixelClass::Sky => "sky",
            PixelClass::Ground => "ground",
            PixelClass::NearTrees => "near trees",
            PixelClass::FarTrees => "far trees",
        }
    }

    /// The class of a pixel of a class image: its strongest channel (black: sky).
    pub fn of(p: [u8; 3]) -> PixelClass {
        let [r, g, b] = p;
        if r.max(g).max(b) < 128 {
            PixelClass::Sky
        } else if r >= g && r >= b {
            PixelClass::Ground
        } else if g >= b {
            PixelClass::NearTrees
        } else {
            PixelClass::FarTrees
        }
    }
}

/// FLIP over the pixels of one class, and how bright the two images are there.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct ClassFlip {
    pub class: PixelClass,
    /// Of all pixels.
    pub pixel_fraction: f64,
    pub stats: FlipStats,
    /// This class's part of the whole image's summed error.
    pub error_share: f64,
    /// Mean linear luminance ([`linear_luminance`]) of the reference (A) over the class.
    pub reference_luminance: f64,
    /// The same for the compared image (B).
    pub luminance: f64,
}

impl ClassFlip {
    /// The compared image's mean linear luminance over the reference's in this class (1
    /// where both are black): below 1, B is darker there.
    pub fn luminance_ratio(&self) -> f64 {
        if self.reference_luminance > 0.0 {
            self.luminance / self.reference_luminance
        } else if self.luminance > 0.0 {
            f64::INFINITY
        } else {
            1.0
        }
    }
}

/// The linear luminance of an sRGB pixel (the sRGB curve undone, Rec. 709 weights), 0..1.
pub fn linear_luminance(p: [u8; 3]) -> f64 {
    let linear = |v: u8| f64::from(crate::color::srgb_to_linear(v));
    0.2126 * linear(p[0]) + 0.7152 * linear(p[1]) + 0.0722 * linear(p[2])
}

/// `result` (FLIP of `test` against `reference`) split by the classes in `classes`, all
/// four images of one size; the classes no pixel has are left out.
pub fn by_class(
    result: &FlipResult,
    reference: &RgbImage,
    test: &RgbImage,
    classes: &RgbImage,
) -> Result<Vec<ClassFlip>> {
    for (name, img) in [
        ("class image", classes),
        ("reference image", reference),
        ("compared image", test),
    ] {
        if img.dimensions() != (result.width, result.height) {
            let (bw, bh) = img.dimensions();
            return Err(Error::ImageSizeMismatch {
                a: "compared images".into(),
                aw: result.width,
                ah: result.height,
                b: name.into(),
                bw,
                bh,
            });
        }
    }
    let total: f64 = result.errors.iter().map(|&e| f64::from(e)).sum();
    let n = result.errors.len().max(1) as f64;
    let mut out = Vec::new();
    for class in PixelClass::ALL {
        let mut errors = Vec::new();
        let (mut lum_a, mut lum_b) = (0.0, 0.0);
        for (((&e, c), a), b) in result
            .errors
            .iter()
            .zip(classes.pixels())
            .zip(reference.pixels())
            .zip(test.pixels())
        {
            if PixelClass::of(c.0) == class {
                errors.push(e);
                lum_a += linear_luminance(a.0);
                lum_b += linear_luminance(b.0);
            }
        }
        if errors.is_empty() {
            continue;
        }
        let sum: f64 = errors.iter().map(|&e| f64::from(e)).sum();
        let count = errors.len() as f64;
        out.push(ClassFlip {
            class,
            pixel_fraction: count / n,
            stats: summarise(&errors),
            error_share: if total > 0.0 { sum / total } else { 0.0 },
            reference_luminance: lum_a / count,
            luminance: lum_b / count,
        });
    }
    Ok(out)
}

/// Loads a PNG (or any format `image` reads) as 8-bit RGB, dropping alpha.
pub fn load_rgb(path: &Path) -> Result<RgbImage> {
    let img = image::open(path).map_err(|source| Error::ReadImage {
        path: path.to_path_buf(),
        source,
    })?;
    Ok(img.to_rgb8())
}

/// Two image files compared: FLIP of the second against the first, and both images (for
/// [`by_class`]).
pub struct Compared {
    pub result: FlipResult,
    pub reference: RgbImage,
    pub test: RgbImage,
}

/// Compares two image files; names them in the error if their sizes differ.
pub fn compare_files(reference: &Path, test: &Path) -> Result<Compared> {
    let a = load_rgb(reference)?;
    let b = load_rgb(test)?;
    if a.dimensions() != b.dimensions() {
        return Err(Error::ImageSizeMismatch {
            a: reference.display().to_string(),
            aw: a.width(),
            ah: a.height(),
            b: test.display().to_string(),
            bw: b.width(),
            bh: b.height(),
        });
    }
    Ok(Compared {
        result: flip(&a, &b)?,
        reference: a,
        test: b,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_error_splits_by_class_and_the_shares_add_up() {
        // 4x1 pixels: sky, ground, near trees, far trees; errors 0.1 .. 0.4.
        let classes =
            RgbImage::from_raw(4, 1, vec![0, 0, 0, 255, 0, 0, 0, 255, 0, 0, 0, 255]).unwrap();
        let r = FlipResult {
            stats: summarise(&[0.1, 0.2, 0.3, 0.4]),
            width: 4,
            height: 1,
            errors: vec![0.1, 0.2, 0.3, 0.4],
        };
        // The reference mid grey everywhere; the compared image white over the sky, the
        // same grey over the ground, black over the near trees and the far trees.
        let grey = RgbImage::from_pixel(4, 1, image::Rgb([128, 128, 128]));
        let mut test = grey.clone();
        test.put_pixel(0, 0, image::Rgb([255, 255, 255]));
        test.put_pixel(2, 0, image::Rgb([0, 0, 0]));
        test.put_pixel(3, 0, image::Rgb([0, 0, 0]));
        let c = by_class(&r, &grey, &test, &classes).unwrap();
        assert_eq!(
            c.iter().map(|c| c.class).collect::<Vec<_>>(),
            PixelClass::ALL.to_vec()
        );
        for (k, c) in c.iter().enumerate() {
            assert!((c.stats.mean - 0.1 * (k + 1) as f32).abs() < 1e-6);
            assert!((c.pixel_fraction - 0.25).abs() < 1e-9);
            assert!((c.error_share - 0.1 * (k + 1) as f64).abs() < 1e-6);
        }
        let total: f64 = c.iter().map(|c| c.error_share).sum();
        assert!((total - 1.0).abs() < 1e-9);
        // sRGB 128 is 0.216 linear: white is 4.6 times as bright.
        let ratios: Vec<f64> = c.iter().map(ClassFlip::luminance_ratio).collect();
        assert!((ratios[0] - 1.0 / 0.2159).abs() < 0.01, "{ratios:?}");
        assert!(
            (ratios[1] - 1.0).abs() < 1e-12 && ratios[2] == 0.0,
            "{ratios:?}"
        );
        assert!((c[1].reference_luminance - 0.2159).abs() < 1e-3);
        let small = RgbImage::new(2, 1);
        assert!(by_class(&r, &grey, &test, &small).is_err());
        assert!(by_class(&r, &small, &test, &classes).is_err());
        assert!(by_class(&r, &grey, &small, &classes).is_err());
    }

    #[test]
    fn luminance_is_linear_and_a_black_class_is_level() {
        assert_eq!(linear_luminance([0, 0, 0]), 0.0);
        assert!((linear_luminance([255, 255, 255]) - 1.0).abs() < 1e-12);
        // Green weighs most: 0.7152 of white.
        assert!((linear_luminance([0, 255, 0]) - 0.7152).abs() < 1e-12);
        let black = ClassFlip {
            class: PixelClass::Sky,
            pixel_fraction: 1.0,
            stats: summarise(&[0.0]),
            error_share: 0.0,
            reference_luminance: 0.0,
            luminance: 0.0,
        };
        assert_eq!(black.luminance_ratio(), 1.0);
    }

    #[test]
    fn identical_images_have_zero_error() {
        let img = RgbImage::from_fn(32, 32, |x, y| {
            image::Rgb([(x * 8) as u8, (y * 8) as u8, 90])
        });
        let r = flip(&img, &img).unwrap();
        assert_eq!(r.stats.mean, 0.0);
        assert_eq!(r.stats.max, 0.0);
    }

    #[test]
    fn different_images_have_positive_error_and_ordered_percentiles() {
        let a = RgbImage::from_pixel(32, 32, image::Rgb([20, 80, 20]));
        let mut b = a.clone();
        for y in 0..16 {
            for x in 0..32 {
                b.put_pixel(x, y, image::Rgb([230, 230, 240]));
            }
        }
        let s = flip(&a, &b).unwrap().stats;
        assert!(s.mean > 0.1, "{s:?}");
        assert!(s.p50 <= s.p90 && s.p90 <= s.p99 && s.p99 <= s.max, "{s:?}");
    }

    #[test]
    fn size_mismatch_is_an_error() {
        let a = RgbImage::new(4, 4);
        let b = RgbImage::new(4, 5);
        assert!(matches!(flip(&a, &b), Err(Error::ImageSizeMismatch { .. })));
    }

    #[test]
    fn percentiles_use_nearest_rank() {
        let errors: Vec<f32> = (1..=100).map(|i| i as f32 / 100.0).collect();
        let s = summarise(&errors);
        assert_eq!(s.p50, 0.50);
        assert_eq!(s.p90, 0.90);
        assert_eq!(s.p99, 0.99);
        assert_eq!(s.max, 1.0);
    }
}
