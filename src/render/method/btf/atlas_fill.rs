//! The BTF texture array for [`super::BtfAssets::new`]: allocated for the scene's images
//! (and the tree level's light blends where they fit), then filled with every baked image.

use super::atlas::{self, AtlasFormat, upload_image};
use super::{ATLAS_SIDE, BtfScene, atlas_layers, light_blend};
use crate::format::Baked;
use crate::render::GpuContext;
use crate::{Error, Result};

/// The texture array as allocated.
pub(super) struct Atlas {
    pub(super) texture: wgpu::Texture,
    pub(super) format: AtlasFormat,
    /// The scene's images.
    pub(super) images: u64,
    /// Texture layers of the baked images.
    pub(super) layers: u64,
    /// The tree level's light blends in the layers after them (0: none).
    pub(super) blends: u64,
}

/// The texture array for `scene`'s images, refused where this GPU cannot hold them.
pub(super) fn allocate_atlas(ctx: &GpuContext, scene: &BtfScene, baked: &Baked) -> Result<Atlas> {
    let res = scene.resolution();
    let images = scene.layer_count();
    let layers = atlas_layers(images);
    let max_layers = u64::from(ctx.device.limits().max_texture_array_layers);
    if layers > max_layers {
        return Err(Error::BadInput(format!(
            "the BTF needs {images} images ({layers} texture layers of {} each) but this GPU allows {max_layers} layers; bake with fewer views or lights, or fewer species variants",
            ATLAS_SIDE * ATLAS_SIDE
        )));
    }
    let side = res * ATLAS_SIDE;
    if side > ctx.device.limits().max_texture_dimension_2d {
        return Err(Error::BadInput(format!(
            "the BTF atlas needs {side}² texture layers but this GPU allows {}; bake at a lower resolution",
            ctx.device.limits().max_texture_dimension_2d
        )));
    }
    // Each image has its own mip chain inside its square: down to one texel, or to 4
    // texels for BC7 images (`AtlasFormat::choose`).
    let encodings: Vec<_> = scene.image_sets(baked).map(|(_, s)| s.encoding).collect();
    let format = AtlasFormat::choose(res, &encodings, atlas::bc7_textures(ctx));
    // The tree level's light blends take layers after the baked images, where the GPU
    // allows them and the array can be drawn into (a BC7 array cannot).
    let blends = if format.bc7 {
        log::info!(
            "tree-level billboards blend their lights themselves: the BTF images are BC7, which cannot be drawn into"
        );
        0
    } else {
        scene.light_blend_count(light_blend::LIGHT_BINS)
    };
    let blend_layers = atlas_layers(blends);
    let allocate =
        |blend_layers: u64| atlas::allocate_array(ctx, format, side, layers, blend_layers);
    let fits = blend_layers > 0 && layers + blend_layers <= max_layers && layers > 0;
    let (texture, blends) = match fits.then(|| allocate(blend_layers)) {
        Some(Ok(t)) => (t, blends),
        other => {
            if let Some(Err(e)) = other {
                log::warn!("tree-level billboards blend their lights themselves: {e}");
            } else if blend_layers > 0 {
                log::warn!(
                    "tree-level billboards blend their lights themselves: the light blends' {blend_layers} layers pass this GPU's {max_layers}"
                );
            }
            (allocate(0)?, 0)
        }
    };
    Ok(Atlas {
        texture,
        format,
        images,
        layers,
        blends,
    })
}

/// Writes every baked image of `scene` into `atlas`; the bytes written and every image's
/// mean (premultiplied linear colour, coverage).
pub(super) fn upload_images(
    ctx: &GpuContext,
    scene: &BtfScene,
    baked: &Baked,
    atlas: &Atlas,
) -> (u64, Vec<[f32; 4]>) {
    let Atlas {
        texture,
        format,
        images,
        ..
    } = atlas;
    let mut bytes = 0u64;
    let mut means = vec![[0.0f32; 4]; *images as usize];
    let lut = crate::color::srgb_lut();
    // wgpu holds each write's staging copy until the GPU has done it: submitted every
    // `FLUSH_BYTES`, the staging copies of the whole array (107 MB for the example
    // forest's images decoded to RGBA8) are never held at once.
    const FLUSH_BYTES: u64 = 16 << 20;
    let mut unflushed = 0u64;
    for (base, set) in scene.image_sets(baked) {
        for (i, img) in set.images().enumerate() {
            let (b, mean) = upload_image(ctx, texture, base + i as u32, set, img, *format, &lut);
            bytes += b;
            unflushed += b;
            if unflushed >= FLUSH_BYTES {
                ctx.queue.submit(std::iter::empty());
                let _ = ctx.device.poll(wgpu::PollType::wait_indefinitely());
                unflushed = 0;
            }
            if let Some(m) = means.get_mut((base + i as u32) as usize) {
                *m = mean;
            }
        }
    }
    (bytes, means)
}
