//! Block compression of baked images: BC7 for RGBA images, BC4 for one-channel maps. Both
//! cut an image into 4x4 texel blocks (16 bytes a BC7 block, 8 a BC4 block); an image whose
//! sides are not multiples of 4 is padded by repeating its last row and column, and the
//! padding is dropped again on decoding. Encoding is `intel_tex_2` (Intel's ISPC texture
//! compressor, prebuilt for x86_64 and aarch64); decoding is `bcdec_rs`, for an adapter
//! without BC textures, for what the CPU reads (cube maps, image means, occluders) and for
//! the tests.
//!
//! A BTF image is stored as its mip chain, each level encoded on its own, down to the level
//! of 4 texels a side ([`bc_mip_levels`]): an image's square in the atlas is then a whole
//! number of blocks at every level, so no block mixes two images.

/// Texels a side of one block.
pub const BLOCK_SIDE: u32 = 4;
/// Bytes of one BC7 block (4x4 RGBA texels).
pub const BC7_BLOCK_BYTES: usize = 16;
/// Bytes of one BC4 block (4x4 one-channel texels).
pub const BC4_BLOCK_BYTES: usize = 8;

/// Blocks along a side of `side` texels.
pub fn blocks_along(side: u32) -> u32 {
    side.div_ceil(BLOCK_SIDE)
}

/// Bytes of a BC7 image of `w` x `h` texels.
pub fn bc7_bytes(w: u32, h: u32) -> u64 {
    u64::from(blocks_along(w)) * u64::from(blocks_along(h)) * BC7_BLOCK_BYTES as u64
}

/// Bytes of a BC4 image of `w` x `h` texels.
pub fn bc4_bytes(w: u32, h: u32) -> u64 {
    u64::from(blocks_along(w)) * u64::from(blocks_along(h)) * BC4_BLOCK_BYTES as u64
}

/// Mip levels a block-compressed square image of side `res` stores: level 0 down to the
/// level of [`BLOCK_SIDE`] texels (1 for an image of 4 texels or fewer).
pub fn bc_mip_levels(res: u32) -> u32 {
    let mut levels = 1;
    while (res >> levels) >= BLOCK_SIDE {
        levels += 1;
    }
    levels
}

/// Bytes of one square image's BC7 mip chain ([`bc_mip_levels`] levels).
pub fn bc7_chain_bytes(res: u32) -> u64 {
    (0..bc_mip_levels(res))
        .map(|m| bc7_bytes(res >> m, res >> m))
        .sum()
}

/// The texels of `w` x `h` `data` (`channels` bytes a texel) padded to whole blocks by
/// repeating the last column and row; borrowed when no padding is needed.
fn padded(data: &[u8], w: u32, h: u32, channels: usize) -> (std::borrow::Cow<'_, [u8]>, u32, u32) {
    let (pw, ph) = (blocks_along(w) * BLOCK_SIDE, blocks_along(h) * BLOCK_SIDE);
    if (pw, ph) == (w, h) {
        return (std::borrow::Cow::Borrowed(data), w, h);
    }
    let mut out = Vec::with_capacity(pw as usize * ph as usize * channels);
    for y in 0..ph {
        let sy = y.min(h.saturating_sub(1)) as usize;
        for x in 0..pw {
            let sx = x.min(w.saturating_sub(1)) as usize;
            let at = (sy * w as usize + sx) * channels;
            out.extend_from_slice(&data[at..at + channels]);
        }
    }
    (std::borrow::Cow::Owned(out), pw, ph)
}

/// Which of Intel's BC7 settings the bake uses: the "ultra fast" alpha profile. On the BTF
/// stand's images it is 6 times faster than "fast" and 30 times faster than "slow", for an
/// RMSE of 1.77 against their 1.67 and 1.65 (docs/results/bake.md, "Block-compressed", 2026-11-27).
fn bc7_settings() -> intel_tex_2::bc7::EncodeSettings {
    intel_tex_2::bc7::alpha_ultra_fast_settings()
}

/// BC7 blocks of a `w` x `h` RGBA8 image (rows top to bottom, blocks row by row).
///
/// # Panics
/// If `rgba` holds fewer than `w * h * 4` bytes.
pub fn encode_bc7(rgba: &[u8], w: u32, h: u32) -> Vec<u8> {
    assert!(rgba.len() >= w as usize * h as usize * 4, "short image");
    let (data, pw, ph) = padded(rgba, w, h, 4);
    let surface = intel_tex_2::RgbaSurface {
        data: &data,
        width: pw,
        height: ph,
        stride: pw * 4,
    };
    intel_tex_2::bc7::compress_blocks(&bc7_settings(), &surface)
}

/// A set of cube maps stored a byte a texel re-encoded in BC4, face by face (a set already
/// in BC4 is left as it is).
pub fn compress_vcm(set: &mut super::VcmSet) {
    if set.encoding != super::MapEncoding::R8 {
        return;
    }
    let res = set.resolution;
    let n = (res * res) as usize;
    set.opacity = set
        .opacity
        .chunks_exact(n.max(1))
        .flat_map(|face| encode_bc4(face, res, res))
        .collect();
    set.encoding = super::MapEncoding::Bc4;
}

/// BC4 blocks of a `w` x `h` one-channel image.
///
/// # Panics
/// If `r` holds fewer than `w * h` bytes.
pub fn encode_bc4(r: &[u8], w: u32, h: u32) -> Vec<u8> {
    assert!(r.len() >= w as usize * h as usize, "short image");
    let (data, pw, ph) = padded(r, w, h, 1);
    let surface = intel_tex_2::RSurface {
        data: &data,
        width: pw,
        height: ph,
        stride: pw,
    };
    intel_tex_2::bc4::compress_blocks(&surface)
}

/// Decodes blocks of `block_bytes` each into a `w` x `h` image of `channels` bytes a
/// texel, with `decode_block` writing one block's 4x4 texels at a row pitch in bytes;
/// None when `blocks` is not the size such an image has.
fn decode(
    blocks: &[u8],
    w: u32,
    h: u32,
    channels: usize,
    block_bytes: usize,
    decode_block: impl Fn(&[u8], &mut [u8], usize),
) -> Option<Vec<u8>> {
    let (bw, bh) = (blocks_along(w) as usize, blocks_along(h) as usize);
    if blocks.len() != bw.checked_mul(bh)?.checked_mul(block_bytes)? {
        return None;
    }
    let (w, h) = (w as usize, h as usize);
    let mut out = vec![0u8; w * h * channels];
    let pitch = BLOCK_SIDE as usize * channels;
    let mut texels = [0u8; 16 * 4];
    for (i, block) in blocks.chunks_exact(block_bytes).enumerate() {
        let (bx, by) = (i % bw * 4, i / bw * 4);
        decode_block(block, &mut texels[..16 * channels], pitch);
        for y in 0..4.min(h - by) {
            let n = 4.min(w - bx) * channels;
            let src = &texels[y * pitch..y * pitch + n];
            let at = ((by + y) * w + bx) * channels;
            out[at..at + n].copy_from_slice(src);
        }
    }
    Some(out)
}

/// The `w` x `h` RGBA8 image that BC7 `blocks` hold, or None when `blocks` has not the
/// size such an image has.
pub fn decode_bc7(blocks: &[u8], w: u32, h: u32) -> Option<Vec<u8>> {
    decode(blocks, w, h, 4, BC7_BLOCK_BYTES, |b, out, pitch| {
        bcdec_rs::bc7(b, out, pitch)
    })
}

/// The `w` x `h` one-channel image that BC4 `blocks` hold, or None when `blocks` has not
/// the size such an image has.
pub fn decode_bc4(blocks: &[u8], w: u32, h: u32) -> Option<Vec<u8>> {
    decode(blocks, w, h, 1, BC4_BLOCK_BYTES, |b, out, pitch| {
        bcdec_rs::bc4(b, out, pitch, false)
    })
}

/// The 16 texels (row by row) of one BC4 block of [`BC4_BLOCK_BYTES`] bytes.
///
/// # Panics
/// If `block` is shorter than a block.
pub fn decode_bc4_block(block: &[u8]) -> [u8; 16] {
    let mut texels = [0u8; 16];
    bcdec_rs::bc4(
        &block[..BC4_BLOCK_BYTES],
        &mut texels,
        BLOCK_SIDE as usize,
        false,
    );
    texels
}

/// The levels of one image's BC7 mip chain (see [`bc7_chain_bytes`]): (side, blocks) from
/// level 0 down, or None when `chain` has not the size of a chain of side `res`.
pub fn bc7_levels(chain: &[u8], res: u32) -> Option<Vec<(u32, &[u8])>> {
    if chain.len() as u64 != bc7_chain_bytes(res) {
        return None;
    }
    let mut at = 0usize;
    let levels = (0..bc_mip_levels(res))
        .map(|m| {
            let side = res >> m;
            let n = bc7_bytes(side, side) as usize;
            let level = (side, &chain[at..at + n]);
            at += n;
            level
        })
        .collect();
    Some(levels)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A smooth gradient with a hard-edged disc of coverage: what a BTF image looks like
    /// at a small scale (smooth colour inside, a cut-out edge).
    fn test_image(w: u32, h: u32) -> Vec<u8> {
        let mut v = Vec::with_capacity((w * h * 4) as usize);
        for y in 0..h {
            for x in 0..w {
                let (fx, fy) = (x as f32 / w as f32, y as f32 / h as f32);
                let inside = (fx - 0.5).powi(2) + (fy - 0.5).powi(2) < 0.16;
                let a = if inside { 255 } else { 0 };
                let c = |t: f32| if inside { (t * 255.0) as u8 } else { 0 };
                v.extend_from_slice(&[c(fx), c(fy), c(0.5 * (fx + fy)), a]);
            }
        }
        v
    }

    #[test]
    fn mip_levels_stop_at_one_block() {
        for (res, levels) in [(4, 1), (8, 2), (32, 4), (64, 5), (128, 6), (2, 1)] {
            assert_eq!(bc_mip_levels(res), levels, "{res}");
        }
        // 64: 64² + 32² + 16² + 8² + 4² texels at a byte each.
        assert_eq!(bc7_chain_bytes(64), 4096 + 1024 + 256 + 64 + 16);
    }

    #[test]
    fn bc7_round_trip_is_close() {
        let img = test_image(32, 32);
        let blocks = encode_bc7(&img, 32, 32);
        assert_eq!(blocks.len() as u64, bc7_bytes(32, 32));
        let back = decode_bc7(&blocks, 32, 32).unwrap();
        let max = img
            .iter()
            .zip(&back)
            .map(|(a, b)| a.abs_diff(*b))
            .max()
            .unwrap();
        assert!(max <= 24, "largest error {max}");
        assert_eq!(decode_bc7(&blocks[1..], 32, 32), None);
    }

    #[test]
    fn odd_sizes_are_padded_and_cropped() {
        let img = test_image(10, 6);
        let blocks = encode_bc7(&img, 10, 6);
        assert_eq!(blocks.len(), 3 * 2 * BC7_BLOCK_BYTES);
        let back = decode_bc7(&blocks, 10, 6).unwrap();
        assert_eq!(back.len(), img.len());
        let r: Vec<u8> = (0..9 * 9).map(|i| (i * 3 % 256) as u8).collect();
        let blocks = encode_bc4(&r, 9, 9);
        assert_eq!(blocks.len(), 3 * 3 * BC4_BLOCK_BYTES);
        let back = decode_bc4(&blocks, 9, 9).unwrap();
        assert_eq!(back.len(), r.len());
    }

    #[test]
    fn bc4_keeps_flat_and_two_valued_blocks_exact() {
        // Cube maps are mostly 0 or 255 with soft edges: blocks of one or two values
        // must come back exactly.
        let mut r = vec![0u8; 16 * 16];
        for (i, v) in r.iter_mut().enumerate() {
            *v = if (i % 16) < 6 { 255 } else { 0 };
        }
        let back = decode_bc4(&encode_bc4(&r, 16, 16), 16, 16).unwrap();
        assert_eq!(back, r);
    }
}
