//! The bake's last step when `[bake] compress` is on: every BTF image becomes its BC7 mip
//! chain (each level made from the one above as the viewer makes RGBA8 mips, then encoded
//! on its own) and every cube map face its BC4 blocks (`crate::format::bc`). Sets are
//! spread over the machine's cores.

use std::sync::atomic::{AtomicUsize, Ordering};

use image::RgbaImage;

use crate::format::{Baked, BtfImageSet, ImageEncoding, bc};

/// Seconds the compression of a bake took, by part.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct CompressTimes {
    pub btf_seconds: f64,
    pub vcm_seconds: f64,
}

/// Compresses `baked` in place: RGBA8 BTF sets to BC7, R8 cube maps to BC4 (sets already
/// compressed are left as they are).
pub fn compress(baked: &mut Baked) -> CompressTimes {
    let t0 = std::time::Instant::now();
    for_each_parallel(&mut baked.btf, compress_btf);
    let btf_seconds = t0.elapsed().as_secs_f64();
    let t1 = std::time::Instant::now();
    for_each_parallel(&mut baked.vcm, bc::compress_vcm);
    CompressTimes {
        btf_seconds,
        vcm_seconds: t1.elapsed().as_secs_f64(),
    }
}

/// Runs `f` on every item, the items shared out over the available cores.
fn for_each_parallel<T: Send>(items: &mut [T], f: fn(&mut T)) {
    let workers = std::thread::available_parallelism()
        .map_or(1, |n| n.get())
        .min(items.len());
    if workers <= 1 {
        items.iter_mut().for_each(f);
        return;
    }
    let cells: Vec<std::sync::Mutex<&mut T>> =
        items.iter_mut().map(std::sync::Mutex::new).collect();
    let next = AtomicUsize::new(0);
    std::thread::scope(|scope| {
        for _ in 0..workers {
            scope.spawn(|| {
                loop {
                    let i = next.fetch_add(1, Ordering::Relaxed);
                    let Some(cell) = cells.get(i) else { break };
                    if let Ok(mut item) = cell.lock() {
                        f(&mut item);
                    }
                }
            });
        }
    });
}

/// The BC7 mip chain of one RGBA8 image of side `res` (see [`bc::bc7_chain_bytes`]).
pub fn bc7_chain(rgba: &[u8], res: u32) -> Vec<u8> {
    let mut out = Vec::with_capacity(bc::bc7_chain_bytes(res) as usize);
    let Some(mut img) = RgbaImage::from_raw(res, res, rgba.to_vec()) else {
        return out;
    };
    for level in 0..bc::bc_mip_levels(res) {
        if level > 0 {
            img = crate::render::target::downsample(&img, 2);
        }
        let (w, h) = img.dimensions();
        out.extend_from_slice(&bc::encode_bc7(img.as_raw(), w, h));
    }
    out
}

fn compress_btf(set: &mut BtfImageSet) {
    if set.encoding != ImageEncoding::Rgba8 {
        return;
    }
    let res = set.resolution;
    let n = (res * res * 4) as usize;
    let encode = |images: &[u8]| -> Vec<u8> {
        images
            .chunks_exact(n)
            .flat_map(|img| bc7_chain(img, res))
            .collect()
    };
    set.direct = encode(&set.direct);
    set.ambient = encode(&set.ambient);
    set.encoding = ImageEncoding::Bc7;
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::format::MapEncoding;
    use crate::format::test_support::sample;

    #[test]
    fn a_compressed_bake_is_valid_and_smaller() {
        let raw = sample();
        let mut baked = raw.clone();
        compress(&mut baked);
        baked.validate().unwrap();
        assert!(baked.btf.iter().all(|s| s.encoding == ImageEncoding::Bc7));
        assert!(baked.vcm.iter().all(|s| s.encoding == MapEncoding::Bc4));
        // BC7 with its mips: (1 + 1/4 + 1/16 + 1/64) / 4 of RGBA8 level 0 at 32².
        assert_eq!(baked.btf_bytes() * 4 * 64, raw.btf_bytes() * 85);
        assert_eq!(baked.vcm_bytes() * 2, raw.vcm_bytes());
        // Round trip through the file.
        let back = crate::format::from_bytes(&crate::format::to_bytes(&baked)).unwrap();
        assert_eq!(back, baked);
        // Compressing again changes nothing.
        let mut again = baked.clone();
        compress(&mut again);
        assert_eq!(again, baked);
    }
}
