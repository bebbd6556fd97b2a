//! The BTF texture array's packing: images [`ATLAS_SIDE`]² to a layer, each with its own
//! mip chain inside its square, and the upload of one image.

use glam::UVec3;

use super::far_canopy;
use crate::render::GpuContext;
use crate::render::consts::ATLAS_SIDE;
use crate::render::pipelines::write_rgba8;

/// Texture layers holding `images` images.
pub fn atlas_layers(images: u64) -> u64 {
    images.div_ceil(u64::from(ATLAS_SIDE * ATLAS_SIDE))
}

/// Uploads image `index` and its mip chain (box-filtered in linear light) into its square
/// of the atlas. Returns the bytes uploaded and the image's mean (its last level: linear
/// colour, premultiplied as stored, and coverage).
pub(super) fn upload_image(
    ctx: &GpuContext,
    texture: &wgpu::Texture,
    index: u32,
    res: u32,
    rgba: &[u8],
    mips: u32,
    lut: &[f32],
) -> (u64, [f32; 4]) {
    let per_layer = ATLAS_SIDE * ATLAS_SIDE;
    let layer = index / per_layer;
    let slot = index % per_layer;
    let (cx, cy) = (slot % ATLAS_SIDE, slot / ATLAS_SIDE);
    let Some(mut img) = image::RgbaImage::from_raw(res, res, rgba.to_vec()) else {
        return (0, [0.0; 4]);
    };
    let mut bytes = 0u64;
    for level in 0..mips {
        let (w, h) = img.dimensions();
        write_rgba8(
            &ctx.queue,
            texture,
            level,
            UVec3::new(cx * w, cy * h, layer),
            img.as_raw(),
            UVec3::new(w, h, 1),
        );
        bytes += u64::from(4 * w * h);
        if w > 1 {
            img = crate::render::target::downsample(&img, 2);
        }
    }
    (bytes, far_canopy::image_mean(rgba, lut))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn three_species_of_three_variants_fit_the_usual_layer_limit() {
        // 9 prototypes x 3 levels x 18 views x (6 lights + sky): 3,402 images, over the
        // 2,048 layers most GPUs allow for one image per layer.
        let images = 9 * 3 * 18 * 7;
        assert_eq!(images, 3402);
        assert_eq!(atlas_layers(images), 213);
        // 8 variants of 3 species at the default sampling: 9,072 images.
        assert_eq!(atlas_layers(24 * 3 * 18 * 7), 567);
        assert_eq!(atlas_layers(0), 0);
        assert_eq!(atlas_layers(16), 1);
        assert_eq!(atlas_layers(17), 2);
    }
}
