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

/// Loads a PNG (or any format `image` reads) as 8-bit RGB, dropping alpha.
pub fn load_rgb(path: &Path) -> Result<RgbImage> {
    let img = image::open(path).map_err(|source| Error::ReadImage {
        path: path.to_path_buf(),
        source,
    })?;
    Ok(img.to_rgb8())
}

/// Compares two image files; names them in the error if their sizes differ.
pub fn compare_files(reference: &Path, test: &Path) -> Result<FlipResult> {
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
    flip(&a, &b)
}

#[cfg(test)]
mod tests {
    use super::*;

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
