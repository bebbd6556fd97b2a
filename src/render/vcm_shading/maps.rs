//! One object's 8 cube maps as held in memory (a byte a texel, or BC4 blocks as stored) and
//! their reads in the sun's direction.

use glam::Vec3;

use crate::vcm::{self, CORNERS, FACES};

/// One object's 8 cube maps and the sky visibility at its corners.
pub(super) struct ObjectVcm {
    pub(super) opacity: Maps,
    pub(super) sky: [f32; CORNERS],
}

/// An object's 8 cube maps, corner by corner: a byte a texel, or each face's BC4 blocks as
/// the bake stored them (the tree level's and the forest cells', read only when the sun
/// moves: half the bytes, the same values).
pub(super) enum Maps {
    R8(Vec<u8>),
    Bc4(Vec<u8>),
}

impl Maps {
    pub(super) fn bytes(&self) -> u64 {
        match self {
            Maps::R8(b) | Maps::Bc4(b) => b.len() as u64,
        }
    }
}

/// The same as [`vcm::sample`] for a cube map stored as each face's BC4 blocks (`6 *
/// bc4_bytes(res, res)` bytes, as the bake writes them): the texels read are decoded from
/// their blocks, so the map stays at half a byte a texel.
pub(super) fn sample_bc4(blocks: &[u8], res: u32, dir: Vec3) -> f32 {
    use crate::format::bc;
    let face_bytes = bc::bc4_bytes(res, res) as usize;
    if blocks.len() < FACES * face_bytes {
        return 0.0;
    }
    let along = bc::blocks_along(res) as usize;
    // The 4 texels of a bilinear read fall in 1 to 4 blocks: each is decoded once.
    let mut last: Option<(usize, [u8; 16])> = None;
    vcm::sample_with(res, dir, |face, i, j| {
        let at = face * face_bytes + ((j / 4) * along + i / 4) * bc::BC4_BLOCK_BYTES;
        let texels = match last {
            Some((a, t)) if a == at => t,
            _ => {
                let t = bc::decode_bc4_block(&blocks[at..at + bc::BC4_BLOCK_BYTES]);
                last = Some((at, t));
                t
            }
        };
        texels[(j % 4) * 4 + i % 4]
    })
}

impl ObjectVcm {
    /// Sun visibility (1 − opacity) at the 8 corners for `to_sun` in the cube maps' frame.
    pub(super) fn direct(&self, res: u32, to_sun: Vec3) -> [f32; CORNERS] {
        let read = |maps: &[u8], n: usize, sample: fn(&[u8], u32, Vec3) -> f32| {
            std::array::from_fn(|k| {
                maps.get(k * n..(k + 1) * n)
                    .map_or(1.0, |m| 1.0 - sample(m, res, to_sun))
            })
        };
        match &self.opacity {
            Maps::R8(m) => read(m, FACES * (res * res) as usize, vcm::sample),
            Maps::Bc4(b) => read(
                b,
                FACES * crate::format::bc::bc4_bytes(res, res) as usize,
                sample_bc4,
            ),
        }
    }

    /// The 8 maps a byte a texel.
    pub(super) fn r8(&self, res: u32) -> std::borrow::Cow<'_, [u8]> {
        use crate::format::bc;
        match &self.opacity {
            Maps::R8(m) => std::borrow::Cow::Borrowed(m),
            Maps::Bc4(b) => std::borrow::Cow::Owned(
                b.chunks_exact(bc::bc4_bytes(res, res).max(1) as usize)
                    .flat_map(|face| bc::decode_bc4(face, res, res).unwrap_or_default())
                    .collect(),
            ),
        }
    }
}
