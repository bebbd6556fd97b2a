//! The BTF texture array's packing: images [`ATLAS_SIDE`]² to a layer, each with its own
//! mip chain inside its square; its format (BC7 or RGBA8); and the upload of one image.

use std::sync::atomic::{AtomicBool, Ordering};

use glam::UVec3;

use super::far_canopy;
use crate::format::{BtfImageSet, ImageEncoding, bc};
use crate::render::GpuContext;
use crate::render::consts::ATLAS_SIDE;
use crate::render::pipelines::write_rgba8;

/// Texture layers holding `images` images.
pub fn atlas_layers(images: u64) -> u64 {
    images.div_ceil(u64::from(ATLAS_SIDE * ATLAS_SIDE))
}

/// How the BTF texture array holds its images.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) struct AtlasFormat {
    /// BC7 blocks as the file stores them (else RGBA8).
    pub bc7: bool,
    /// Mip levels of the array.
    pub mips: u32,
}

impl AtlasFormat {
    /// The format for image sets of side `res` stored as `encodings`, on a GPU that has BC
    /// textures (`bc_textures`) or not: BC7 when every set is BC7 and the GPU has them;
    /// mips down to 4 texels an image when any set is BC7 (what a BC7 set stores), else
    /// down to one texel.
    pub fn choose(res: u32, encodings: &[ImageEncoding], bc_textures: bool) -> Self {
        let any_bc7 = encodings.contains(&ImageEncoding::Bc7);
        let all_bc7 = any_bc7 && encodings.iter().all(|&e| e == ImageEncoding::Bc7);
        let mips = if any_bc7 {
            bc::bc_mip_levels(res)
        } else {
            res.max(1).ilog2() + 1
        };
        Self {
            bc7: all_bc7 && bc_textures,
            mips,
        }
    }

    pub fn texture_format(self) -> wgpu::TextureFormat {
        if self.bc7 {
            wgpu::TextureFormat::Bc7RgbaUnormSrgb
        } else {
            wgpu::TextureFormat::Rgba8UnormSrgb
        }
    }
}

/// When set, a CPU (software) adapter gets the BC7 images as BC7 textures too. Off by
/// default: lavapipe samples BC7 in software, 15 times slower than RGBA8 (the default
/// forest's billboards took 28.6 s a frame against 1.8 s, docs/results/bake.md,
/// 2026-11-27), so a CPU adapter gets them decoded on load. The tests set it to compare
/// the GPU's BC7 sampling with the decoded images. Read when a bake is attached.
pub static BC7_ON_CPU_ADAPTERS: AtomicBool = AtomicBool::new(false);

/// Whether the BTF array may be BC7 on this context: the device has BC textures and is
/// not a software renderer (unless [`BC7_ON_CPU_ADAPTERS`]). Says once in the log when
/// BC7 images will be decoded on load instead, and why.
pub(super) fn bc7_textures(ctx: &GpuContext) -> bool {
    let has_bc = ctx
        .device
        .features()
        .contains(wgpu::Features::TEXTURE_COMPRESSION_BC);
    let cpu = ctx.adapter.get_info().device_type == wgpu::DeviceType::Cpu;
    let allowed = has_bc && (!cpu || BC7_ON_CPU_ADAPTERS.load(Ordering::Relaxed));
    if !allowed && !SAID_DECODED.swap(true, Ordering::Relaxed) {
        log::info!(
            "btf: BC7 images are decoded to RGBA8 on load ({})",
            if has_bc {
                "a software renderer samples BC7 slowly"
            } else {
                "this GPU has no BC textures"
            }
        );
    }
    allowed
}

/// Set once the viewer has said that BC7 images are decoded on load.
static SAID_DECODED: AtomicBool = AtomicBool::new(false);

/// Uploads `image`, one image of `set` as stored, with its mip chain into square `index`
/// of the atlas: BC7 blocks as they are, BC7 decoded to RGBA8 where the texture is RGBA8,
/// or RGBA8 with its mips made here (box-filtered in linear
/// light). Returns the bytes uploaded and the image's mean (linear colour, premultiplied
/// as stored, and coverage, over its level 0).
pub(super) fn upload_image(
    ctx: &GpuContext,
    texture: &wgpu::Texture,
    index: u32,
    set: &BtfImageSet,
    image: &[u8],
    format: AtlasFormat,
    lut: &[f32],
) -> (u64, [f32; 4]) {
    let res = set.resolution;
    let per_layer = ATLAS_SIDE * ATLAS_SIDE;
    let layer = index / per_layer;
    let slot = index % per_layer;
    let (cx, cy) = (slot % ATLAS_SIDE, slot / ATLAS_SIDE);
    let Some(rgba) = set.rgba(image) else {
        return (0, [0.0; 4]);
    };
    let mean = far_canopy::image_mean(&rgba, lut);
    let mut bytes = 0u64;
    match set.encoding {
        ImageEncoding::Bc7 => {
            let Some(levels) = bc::bc7_levels(image, res) else {
                return (0, mean);
            };
            for (level, (side, blocks)) in levels.into_iter().enumerate().take(format.mips as usize)
            {
                let origin = UVec3::new(cx * side, cy * side, layer);
                let size = UVec3::new(side, side, 1);
                if format.bc7 {
                    write_blocks(ctx, texture, level as u32, origin, blocks, size);
                    bytes += blocks.len() as u64;
                } else if let Some(decoded) = bc::decode_bc7(blocks, side, side) {
                    write_rgba8(&ctx.queue, texture, level as u32, origin, &decoded, size);
                    bytes += decoded.len() as u64;
                }
            }
        }
        ImageEncoding::Rgba8 => {
            let Some(mut img) = image::RgbaImage::from_raw(res, res, rgba.into_owned()) else {
                return (0, mean);
            };
            for level in 0..format.mips {
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
        }
    }
    (bytes, mean)
}

/// The BTF texture array: `layers` of baked images and `blend_layers` of light blends,
/// `side` texels square, in `format`. With blends the array is
/// [`BLEND_ARRAY_FORMAT`](super::light_blend::BLEND_ARRAY_FORMAT), written through plain
/// RGBA8 storage views (sRGB cannot be a storage format), and every view that samples it
/// reads it as sRGB.
pub fn allocate_array(
    ctx: &GpuContext,
    format: AtlasFormat,
    side: u32,
    layers: u64,
    blend_layers: u64,
) -> crate::Result<wgpu::Texture> {
    use super::light_blend::{BLEND_ARRAY_FORMAT, BLEND_SAMPLE_FORMAT};
    let mut usage = wgpu::TextureUsages::TEXTURE_BINDING | wgpu::TextureUsages::COPY_DST;
    let (texture_format, view_formats) = if blend_layers > 0 {
        usage |= wgpu::TextureUsages::STORAGE_BINDING;
        (BLEND_ARRAY_FORMAT, &[BLEND_SAMPLE_FORMAT][..])
    } else {
        (format.texture_format(), &[][..])
    };
    ctx.checked("allocating the BTF texture array", || {
        ctx.device.create_texture(&wgpu::TextureDescriptor {
            label: Some("btf images"),
            size: wgpu::Extent3d {
                width: side,
                height: side,
                depth_or_array_layers: (layers + blend_layers).max(1) as u32,
            },
            mip_level_count: format.mips,
            sample_count: 1,
            dimension: wgpu::TextureDimension::D2,
            format: texture_format,
            usage,
            view_formats,
        })
    })
}

/// Writes BC7 `blocks` of `size` texels (whole blocks) into mip `level` at `origin`.
fn write_blocks(
    ctx: &GpuContext,
    texture: &wgpu::Texture,
    level: u32,
    origin: UVec3,
    blocks: &[u8],
    size: UVec3,
) {
    ctx.queue.write_texture(
        wgpu::TexelCopyTextureInfo {
            texture,
            mip_level: level,
            origin: wgpu::Origin3d {
                x: origin.x,
                y: origin.y,
                z: origin.z,
            },
            aspect: wgpu::TextureAspect::All,
        },
        blocks,
        wgpu::TexelCopyBufferLayout {
            offset: 0,
            bytes_per_row: Some(bc::blocks_along(size.x) * bc::BC7_BLOCK_BYTES as u32),
            rows_per_image: Some(bc::blocks_along(size.y)),
        },
        wgpu::Extent3d {
            width: size.x,
            height: size.y,
            depth_or_array_layers: 1,
        },
    );
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_atlas_is_bc7_only_when_every_set_is_and_the_gpu_has_it() {
        use ImageEncoding::{Bc7, Rgba8};
        let f = AtlasFormat::choose(64, &[Bc7, Bc7], true);
        assert_eq!(f, AtlasFormat { bc7: true, mips: 5 });
        assert_eq!(f.texture_format(), wgpu::TextureFormat::Bc7RgbaUnormSrgb);
        // Decoded on load: RGBA8, but the mips the file has.
        assert_eq!(
            AtlasFormat::choose(64, &[Bc7, Bc7], false),
            AtlasFormat {
                bc7: false,
                mips: 5
            }
        );
        assert_eq!(
            AtlasFormat::choose(64, &[Bc7, Rgba8], true),
            AtlasFormat {
                bc7: false,
                mips: 5
            }
        );
        // RGBA8 sets keep the whole chain, down to one texel.
        assert_eq!(
            AtlasFormat::choose(64, &[Rgba8], true),
            AtlasFormat {
                bc7: false,
                mips: 7
            }
        );
        // Every stored level of an image is a whole number of blocks: its square in the
        // atlas starts and ends on block edges, so no block mixes two images.
        for res in crate::format::BTF_RESOLUTIONS {
            let f = AtlasFormat::choose(res, &[Bc7], true);
            for m in 0..f.mips {
                assert_eq!((res >> m) % bc::BLOCK_SIDE, 0, "res {res} level {m}");
            }
        }
    }

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
