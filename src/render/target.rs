//! Offscreen render targets and readback: a colour texture the render core can draw into
//! without a window, read back to an `RgbaImage` (rows padded to 256 bytes on the GPU side,
//! unpadded here), plus the box-filter downsampling used for supersampled reference frames.

use image::RgbaImage;

use super::GpuContext;
pub use crate::color::{linear_to_srgb, srgb_lut, srgb_to_linear};
use crate::{Error, Result};

/// Colour format of offscreen targets: 8-bit sRGB, so shaders write linear values and the
/// PNG holds display values, as on a window surface.
pub const OFFSCREEN_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Rgba8UnormSrgb;

/// Largest side of an offscreen target, supersampling included.
pub const MAX_TARGET_SIDE: u32 = 16384;

/// Checks a requested image size before anything is allocated for it.
pub fn check_size(width: u32, height: u32, ctx: Option<&GpuContext>) -> Result<()> {
    if width == 0 || height == 0 {
        return Err(Error::BadSize {
            width,
            height,
            reason: "both sides must be at least 1 pixel",
        });
    }
    let max = ctx
        .map(|c| c.device.limits().max_texture_dimension_2d)
        .unwrap_or(MAX_TARGET_SIDE)
        .min(MAX_TARGET_SIDE);
    if width > max || height > max {
        return Err(Error::BadSize {
            width,
            height,
            reason: "a side is larger than the GPU allows (at most 16384, or the adapter's limit; lower --size or --supersample)",
        });
    }
    Ok(())
}

/// A colour texture to render into and read back.
pub struct OffscreenTarget {
    pub texture: wgpu::Texture,
    pub view: wgpu::TextureView,
    pub width: u32,
    pub height: u32,
}

impl OffscreenTarget {
    pub fn new(ctx: &GpuContext, width: u32, height: u32) -> Result<Self> {
        check_size(width, height, Some(ctx))?;
        let texture = ctx.checked("creating the offscreen target", || {
            super::pipelines::target_texture(
                &ctx.device,
                "offscreen colour",
                glam::UVec3::new(width, height, 1),
                OFFSCREEN_FORMAT,
                wgpu::TextureUsages::RENDER_ATTACHMENT | wgpu::TextureUsages::COPY_SRC,
            )
        })?;
        let view = texture.create_view(&wgpu::TextureViewDescriptor::default());
        Ok(Self {
            texture,
            view,
            width,
            height,
        })
    }

    /// Copies the texture back to the CPU (blocking).
    pub fn read(&self, ctx: &GpuContext) -> Result<RgbaImage> {
        read_texture_rgba8(ctx, &self.texture, self.width, self.height)
    }
}

/// Reads an RGBA8 (or BGRA8, swizzled back) 2D texture into an image, blocking until done.
pub fn read_texture_rgba8(
    ctx: &GpuContext,
    texture: &wgpu::Texture,
    width: u32,
    height: u32,
) -> Result<RgbaImage> {
    let unpadded = width as usize * 4;
    let padded = unpadded.div_ceil(wgpu::COPY_BYTES_PER_ROW_ALIGNMENT as usize)
        * wgpu::COPY_BYTES_PER_ROW_ALIGNMENT as usize;
    let size = padded as u64 * u64::from(height);
    let buffer = ctx.checked("allocating the readback buffer", || {
        ctx.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("readback"),
            size,
            usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        })
    })?;
    let mut encoder = ctx
        .device
        .create_command_encoder(&wgpu::CommandEncoderDescriptor {
            label: Some("readback"),
        });
    encoder.copy_texture_to_buffer(
        wgpu::TexelCopyTextureInfo {
            texture,
            mip_level: 0,
            origin: wgpu::Origin3d::ZERO,
            aspect: wgpu::TextureAspect::All,
        },
        wgpu::TexelCopyBufferInfo {
            buffer: &buffer,
            layout: wgpu::TexelCopyBufferLayout {
                offset: 0,
                bytes_per_row: Some(padded as u32),
                rows_per_image: Some(height),
            },
        },
        wgpu::Extent3d {
            width,
            height,
            depth_or_array_layers: 1,
        },
    );
    ctx.queue.submit([encoder.finish()]);
    let bytes = map_read(ctx, &buffer)?;
    let mut pixels = Vec::with_capacity(unpadded * height as usize);
    for row in bytes.chunks_exact(padded) {
        pixels.extend_from_slice(&row[..unpadded]);
    }
    let bgra = matches!(
        texture.format(),
        wgpu::TextureFormat::Bgra8Unorm | wgpu::TextureFormat::Bgra8UnormSrgb
    );
    if bgra {
        for px in pixels.chunks_exact_mut(4) {
            px.swap(0, 2);
        }
    }
    RgbaImage::from_raw(width, height, pixels)
        .ok_or_else(|| Error::Gpu("readback returned fewer bytes than the image needs".into()))
}

/// Maps a MAP_READ buffer and copies its contents out, blocking until the GPU is done.
pub fn map_read(ctx: &GpuContext, buffer: &wgpu::Buffer) -> Result<Vec<u8>> {
    let (tx, rx) = std::sync::mpsc::channel();
    buffer.map_async(wgpu::MapMode::Read, .., move |r| {
        let _ = tx.send(r);
    });
    ctx.device
        .poll(wgpu::PollType::wait_indefinitely())
        .map_err(|e| Error::Gpu(format!("waiting for the GPU: {e}")))?;
    match rx.recv() {
        Ok(Ok(())) => {}
        Ok(Err(e)) => return Err(Error::Gpu(format!("mapping a readback buffer: {e}"))),
        Err(_) => return Err(Error::Gpu("the GPU never answered a readback".into())),
    }
    let data = buffer
        .get_mapped_range(..)
        .map_err(|e| Error::Gpu(format!("reading a mapped buffer: {e}")))?
        .to_vec();
    buffer.unmap();
    Ok(data)
}

/// Averages each `factor` x `factor` block of an sRGB image in linear light: the
/// supersampled ground-truth frame becomes a coverage-correct one at the output size.
pub fn downsample(img: &RgbaImage, factor: u32) -> RgbaImage {
    if factor <= 1 {
        return img.clone();
    }
    let (w, h) = (img.width() / factor, img.height() / factor);
    let lut = srgb_lut();
    let n = (factor * factor) as f32;
    RgbaImage::from_fn(w, h, |x, y| {
        let mut acc = [0.0f32; 4];
        for dy in 0..factor {
            for dx in 0..factor {
                let p = img.get_pixel(x * factor + dx, y * factor + dy).0;
                for c in 0..3 {
                    acc[c] += lut[p[c] as usize];
                }
                acc[3] += f32::from(p[3]) / 255.0;
            }
        }
        image::Rgba([
            linear_to_srgb(acc[0] / n),
            linear_to_srgb(acc[1] / n),
            linear_to_srgb(acc[2] / n),
            (acc[3] / n * 255.0 + 0.5) as u8,
        ])
    })
}

/// The first `size` bytes of `buffer` (which allows copies from it), blocking.
pub(crate) fn read_buffer(
    ctx: &super::GpuContext,
    buffer: &wgpu::Buffer,
    size: u64,
) -> crate::Result<Vec<u8>> {
    if size == 0 {
        return Ok(Vec::new());
    }
    let staging = ctx.device.create_buffer(&wgpu::BufferDescriptor {
        label: Some("readback"),
        size,
        usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
        mapped_at_creation: false,
    });
    let mut encoder = ctx
        .device
        .create_command_encoder(&wgpu::CommandEncoderDescriptor {
            label: Some("readback"),
        });
    encoder.copy_buffer_to_buffer(buffer, 0, &staging, 0, size);
    ctx.queue.submit([encoder.finish()]);
    map_read(ctx, &staging)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn downsample_averages_in_linear_light() {
        // Half black, half white: the linear mean is 0.5, which is sRGB 188, not 128.
        let img = RgbaImage::from_fn(2, 2, |x, _| {
            if x == 0 {
                image::Rgba([0, 0, 0, 255])
            } else {
                image::Rgba([255, 255, 255, 255])
            }
        });
        let d = downsample(&img, 2);
        assert_eq!(d.dimensions(), (1, 1));
        assert_eq!(d.get_pixel(0, 0).0[0], 188);
    }

    #[test]
    fn zero_and_huge_sizes_are_rejected() {
        assert!(check_size(0, 10, None).is_err());
        assert!(check_size(10, 100_000, None).is_err());
        assert!(check_size(256, 256, None).is_ok());
    }
}
