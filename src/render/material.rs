//! The textures of imported trees' materials on the GPU: each base-colour image uploaded
//! once with its mip chain (made here on the CPU), and the 1x1 white texture that every
//! untextured part set (the procedural species, the terrain) samples, so that one shader
//! path serves both and multiplies procedural colours by exactly 1.

use crate::model::gltf::Rgba8Image;

use super::GpuContext;
use super::pipelines;

/// The sampler of material textures: repeating (texture coordinates of cards often leave
/// 0..1), trilinear.
pub fn sampler(ctx: &GpuContext) -> wgpu::Sampler {
    ctx.device.create_sampler(&wgpu::SamplerDescriptor {
        label: Some("material texture"),
        address_mode_u: wgpu::AddressMode::Repeat,
        address_mode_v: wgpu::AddressMode::Repeat,
        address_mode_w: wgpu::AddressMode::Repeat,
        mag_filter: wgpu::FilterMode::Linear,
        min_filter: wgpu::FilterMode::Linear,
        mipmap_filter: wgpu::MipmapFilterMode::Linear,
        ..Default::default()
    })
}

/// A 1x1 opaque white texture: what untextured parts sample.
pub fn white(ctx: &GpuContext) -> wgpu::TextureView {
    upload(
        ctx,
        "white",
        &Rgba8Image {
            width: 1,
            height: 1,
            pixels: vec![255; 4],
        },
    )
}

/// Uploads `image` (sRGB) with every mip level down to 1x1.
pub fn upload(ctx: &GpuContext, label: &str, image: &Rgba8Image) -> wgpu::TextureView {
    let levels = mip_chain(image);
    let texture = pipelines::sampled_rgba8_texture(
        &ctx.device,
        label,
        wgpu::TextureDimension::D2,
        glam::UVec3::new(image.width, image.height, 1),
        levels.len() as u32 + 1,
    );
    let write = |level: u32, img: &Rgba8Image| {
        pipelines::write_rgba8(
            &ctx.queue,
            &texture,
            level,
            glam::UVec3::ZERO,
            &img.pixels,
            glam::UVec3::new(img.width, img.height, 1),
        );
    };
    write(0, image);
    for (i, img) in levels.iter().enumerate() {
        write(i as u32 + 1, img);
    }
    texture.create_view(&wgpu::TextureViewDescriptor::default())
}

/// The mip levels below `image`, each half the one above (rounded down, at least 1): 2x2
/// boxes averaged in linear light, colour weighted by alpha so that the cut-away texels of
/// a card do not bleed their colour into its edge.
pub fn mip_chain(image: &Rgba8Image) -> Vec<Rgba8Image> {
    let to_linear = crate::color::srgb_lut();
    let mut out: Vec<Rgba8Image> = Vec::new();
    let mut prev = image.clone();
    while prev.width > 1 || prev.height > 1 {
        let (w, h) = ((prev.width / 2).max(1), (prev.height / 2).max(1));
        let mut pixels = Vec::with_capacity((w * h * 4) as usize);
        for y in 0..h {
            for x in 0..w {
                let mut c = [0.0f32; 3];
                let mut a = 0.0f32;
                let mut n = 0.0f32;
                for (dx, dy) in [(0, 0), (1, 0), (0, 1), (1, 1)] {
                    let sx = (2 * x + dx).min(prev.width - 1);
                    let sy = (2 * y + dy).min(prev.height - 1);
                    let i = ((sy * prev.width + sx) * 4) as usize;
                    let p = &prev.pixels[i..i + 4];
                    let pa = f32::from(p[3]) / 255.0;
                    for k in 0..3 {
                        c[k] += to_linear[p[k] as usize] * pa;
                    }
                    a += pa;
                    n += 1.0;
                }
                for ck in c {
                    let lin = if a > 0.0 { ck / a } else { 0.0 };
                    pixels.push(crate::color::linear_to_srgb(lin));
                }
                pixels.push((a / n * 255.0 + 0.5) as u8);
            }
        }
        let next = Rgba8Image {
            width: w,
            height: h,
            pixels,
        };
        out.push(next.clone());
        prev = next;
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_chain_ends_at_one_texel_and_keeps_the_mean_alpha() {
        // 4x2: left half opaque red, right half cut away.
        let mut pixels = Vec::new();
        for _y in 0..2 {
            for x in 0..4 {
                pixels.extend(if x < 2 {
                    [255, 0, 0, 255]
                } else {
                    [0, 0, 255, 0]
                });
            }
        }
        let chain = mip_chain(&Rgba8Image {
            width: 4,
            height: 2,
            pixels,
        });
        let sizes: Vec<(u32, u32)> = chain.iter().map(|m| (m.width, m.height)).collect();
        assert_eq!(sizes, [(2, 1), (1, 1)]);
        assert_eq!(chain[0].pixels, [255, 0, 0, 255, 0, 0, 0, 0]);
        // The last texel: half covered, and red (the cut-away blue does not bleed in).
        assert_eq!(chain[1].pixels[..3], [255, 0, 0]);
        assert!((i32::from(chain[1].pixels[3]) - 128).abs() <= 1);
    }
}
