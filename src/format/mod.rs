//! The `.canopy` file: everything one bake produces (BTF image sets, visibility cube maps,
//! texel volumes, octahedral impostors, surfel trees),
//! in one versioned, checksummed file that the viewer caches and validates on load.
//!
//! The byte layout is documented here, beside the constants it names; the data types,
//! the error, reading, writing, planning, checking and BC coding are modules of their own.
//!
//! # Byte layout (format version 9)
//!
//! All integers are little-endian, `f32` is IEEE 754 binary32 (little-endian bits). Offsets
//! are in bytes. There is no padding anywhere.
//!
//! ```text
//! HEADER (84 + 28*N bytes)
//!   off  size  field
//!    0     8   magic           "CANOPY\r\n" (43 41 4E 4F 50 59 0D 0A); the CR LF pair catches
//!                              a file whose line endings were converted in transfer
//!    8     4   version         u32, 9 (a reader also takes 7 and 8: see the end of this
//!                              layout)
//!   12     4   section_count   u32 N, at most MAX_SECTIONS (4096)
//!   16     8   file_size       u64, total length of the file in bytes, header included
//!   24     8   scene_hash      u64, hash of the scene text + bake settings (from the caller)
//!   32     4   views           u32, one of 6, 18, 66, 258 (twig and   \
//!                              main-branch sets)                     |
//!   36     4   lights          u32, one of 6, 18, 66, 258           |
//!   40     4   resolution      u32, one of 32, 64, 128              | BakeSettings
//!   44     4   supersample     u32, 1..=8                           |
//!   48     4   vcm_resolution  u32, 8..=128                         |
//!   52     4   texel_resolution u32, 0 (no texel volumes) or 16..=256: voxels along the
//!                              longest side of each species' box    |
//!   56     4   tree_views      u32, one of 6, 18, 66, 258 (tree-    |
//!                              level sets)                          |
//!   60     4   impostor_frames u32, 0 (no impostors) or 4..=32:     |
//!                              frames per side of each species'     |
//!                              octahedral impostor                  |
//!   64     4   impostor_resolution u32, one of 16, 32, 64, 128, 256 |
//!                              (pixels a frame side)                |
//!   68     4   impostor_layout u32, 0 = full sphere, 1 = upper     |
//!                              hemisphere (`crate::sphere::OctaLayout`)
//!   72     4   compress        u32, 0 or 1: the bake stores its     |
//!                              BTF images in BC7 and its cube maps in BC4 (each record
//!                              says how it is stored: the reader goes by the records)
//!   76     4   surfel_budget   u32, 0 (no surfel trees) or          /
//!                              1,000..=4,000,000: level-0 surfels each species is sampled
//!                              with (about)
//!   80  28*N   section table, one 28-byte entry per section, in file order:
//!                +0  u32 kind      1 = BTF image sets, 2 = VCM sets, 3 = texel volumes,
//!                                  4 = impostors, 5 = surfel trees (0 and others invalid)
//!                +4  u32 crc32     CRC-32 (IEEE, as crc32fast) of the payload as stored
//!                +8  u64 length    bytes of the payload as stored, 1..=MAX_SECTION_BYTES
//!                                  (1 GiB)
//!               +16  u32 packing   0 = stored as it is, 1 = DEFLATE (RFC 1951, raw, no
//!                                  zlib or gzip wrapper)
//!               +20  u64 plain_length  bytes of the payload once inflated,
//!                                  4..=MAX_SECTION_BYTES; equal to length when packing is 0
//!   80+28N  4  header_crc      u32, CRC-32 of header bytes [0, 80+28N)
//!
//! PAYLOADS: the N section payloads as stored, back to back in table order, starting right
//! after header_crc; their lengths sum to exactly file_size - (84 + 28N) and the file ends
//! there. A deflated payload is one DEFLATE stream that inflates to exactly plain_length
//! bytes and ends exactly at the payload's end.
//!
//! Version 8 has no surfel_budget word (its table starts at 76, its header is 80 + 28*N
//! bytes) and no surfel trees; version 7 is version 8 with 16-byte table entries (kind,
//! crc32, length), every payload stored as it is (its header is 80 + 16*N bytes). [`read`]
//! takes all three (the older ones with a surfel budget of 0); [`write_atomic`] writes
//! version 9 with every section that shrinks deflated.
//!
//! SECTION PAYLOAD (any kind, as inflated)
//!    0     4   record_count    u32 R
//!    4     ..  R records of the section's kind, back to back, filling the payload exactly
//!
//! BTF IMAGE SET RECORD (kind 1; 56 bytes + image data)
//!    0     4   species         u32
//!    4     1   level           u8, 0 = twig, 1 = branch, 2 = tree
//!    5     1   encoding        u8, 0 = RGBA8 (level 0 only), 1 = BC7 (each image its mip
//!                              chain, see below)
//!    6     2   reserved        must be 0
//!    8     4   views           u32, one of 6, 18, 66, 258
//!   12     4   lights          u32, one of 6, 18, 66, 258
//!   16     4   resolution      u32, one of 32, 64, 128
//!   20    12   center          3 x f32, finite (bounding-sphere centre, object frame)
//!   32     4   radius          f32, finite, > 0
//!   36     4   texel_size      f32, finite, > 0
//!   40     8   direct_len      u64, must equal views*lights*I, I the bytes of one image:
//!                              resolution²*4 (RGBA8), or its BC7 chain (below)
//!   48     D   direct          premultiplied images, view-major: image (v, l) at
//!                              (v*lights + l) * I
//!   48+D   8   ambient_len     u64, must equal 2*views*I
//!   56+D   A   ambient         premultiplied: the sky-lit image of each view, then
//!                              the ground-lit image of each view (v at v, and at views + v)
//!
//!   A BC7 image is its mip chain, level 0 first, down to the level of 4 texels a side
//!   (`bc::bc_mip_levels`: resolution 64 has 64, 32, 16, 8, 4); level m is
//!   (resolution >> m)² / 16 blocks of 16 bytes, row by row, each made from the RGBA8
//!   level m (level 0 the baked image, each next one its 2x2 box filter in linear light,
//!   as the viewer makes the mips of an RGBA8 set), so I = sum of (resolution >> m)² bytes.
//!
//! VCM SET RECORD (kind 2; 56 bytes + opacity data)
//!    0     4   species         u32; 0xFFFFFFFF (VCM_CELL_SPECIES, level tree) marks the cube
//!                              maps of a forest cell (`crate::vcm::cells`)
//!    4     4   owner           u32, the object within its level: the tree instance (or the
//!                              forest cell); the main branch of the species' tree; the
//!                              twig of its reference main branch, numbered on past them
//!                              through the trunk's twigs
//!    8     1   level           u8, 0 = twig, 1 = branch, 2 = tree
//!    9     1   encoding        u8, 0 = R8, 1 = BC4
//!   10     2   reserved        must be 0
//!   12     4   resolution      u32, 8..=128
//!   16    32   mean_opacity    8 x f32, finite, in [0, 1], one per corner
//!   48     8   opacity_len     u64, must equal 8*6*F, F the bytes of one face:
//!                              resolution² (R8) or ceil(resolution/4)² * 8 (BC4)
//!   56     O   opacity         8 corners x 6 cube faces, each face res rows of res texels
//!                              (see `crate::vcm` for the layout): a byte per texel (R8), or
//!                              the face's BC4 blocks row by row, a face whose side is not a
//!                              multiple of 4 padded with its last row and column
//!
//! TEXEL VOLUME RECORD (kind 3; 44 bytes + voxel data)
//!    0     4   species         u32
//!    4     4   lights          u32, one of 6, 18, 66, 258
//!    8    12   dims            3 x u32 (x, y, z voxels), each 1..=256
//!   20    12   box_min         3 x f32, finite (the volume's lowest corner, object frame)
//!   32     4   voxel           f32, finite, > 0: side of one (cubic) voxel, m
//!   36     8   voxels_len      u64, must equal (lights+1)*x*y*z*4
//!   44     V   voxels          RGBA8 premultiplied, lights+1 volumes back to back: volume k
//!                              (k < lights) lit by light sample k alone (sun only, self-
//!                              shadowed), volume `lights` by the sky alone; in a volume,
//!                              voxel (i, j, k) at ((k*y + j)*x + i)*4, j = 0 the lowest row;
//!                              alpha is the coverage of one voxel-thick slab
//!
//! IMPOSTOR RECORD (kind 4; 52 bytes + atlas data)
//!    0     4   species         u32
//!    4     4   layout          u32, 0 = full sphere, 1 = upper hemisphere
//!    8     4   frames          u32, 4..=32 frames per side (frame (i, j) looks from the
//!                              direction `crate::sphere::OctaGrid` gives it)
//!   12     4   resolution      u32, one of 16, 32, 64, 128, 256: pixels a frame side
//!   16     4   mip_levels      u32, 1..=log2(resolution) - 1 (the smallest frame is at
//!                              least 4 pixels a side)
//!   20    12   center          3 x f32, finite (bounding-sphere centre, object frame)
//!   32     4   radius          f32, finite, > 0: a frame shows a square of side 2*radius
//!                              centred on the centre, seen from its direction, with the
//!                              image axes `crate::sphere::billboard_axes` gives
//!   36     8   albedo_len      u64, must equal the atlas bytes: the sum over levels m of
//!                              (frames * (resolution >> m))² * 4
//!   44     C   albedo          RGBA8 atlases, level 0 first: unlit colour (sRGB, not
//!                              premultiplied) and coverage in alpha; in level m, frame
//!                              (i, j) is the tile of (resolution >> m)² pixels at column i,
//!                              row j, rows top to bottom; colour spread into uncovered
//!                              texels from the covered ones of the same frame; each level
//!                              made from the one above frame by frame, so no texel mixes
//!                              two frames
//!   44+C   8   normal_depth_len u64, must equal albedo_len
//!   52+C   C   normal_depth    RGBA8 atlases as albedo: the surface normal in the object
//!                              frame as rgb = n * 0.5 + 0.5 (linear bytes), and in alpha
//!                              the depth from the frame's plane, 0 at the bounding
//!                              sphere's side towards the frame's camera, 0.5 at its
//!                              centre, 1 at its far side; spread like the albedo
//!
//! SURFEL TREE RECORD (kind 5; 80 bytes + data): one species' LDC tree (Guennebaud and
//! Paulin 2002), `crate::format::SurfelSet`
//!    0     4   species         u32
//!    4     4   levels          u32 L, 1..=16 (level l's spacing is spacing * 2^l)
//!    8     4   nodes           u32 M, >= 1: blocks of the octree
//!   12     4   surfels         u32 S, >= 1
//!   16    24   box             min then max, 3 x f32 each, finite, max >= min: the tree's
//!                              bounds, which the surfels' positions are quantised in
//!   40     4   spacing         f32, finite, > 0: level 0's surfel spacing (m)
//!   44    12   density_origin  3 x f32, finite: the density volume's lowest corner
//!   56     4   density_voxel   f32, finite, > 0: its voxel's side (m)
//!   60    12   density_dims    3 x u32 (x, y, z voxels), each 1..=64
//!   72     8   data_len        u64, must equal 8*L + 72*M + 12*S + 4*x*y*z
//!   80     ..  levels          per level, finest first: gain f32 in [1, 16] (its coverages
//!                              were raised to 1 - (1 - c)^gain), surfels u32 (they sum to S)
//!          ..  nodes           M x 72 bytes: level u32 (< L), first u32, count u32 (>= 1;
//!                              first + count <= S), children u32 (0..=8; 0 at level 0),
//!                              bounds 6 x f32 (min, max; finite), 8 child slots u32: the
//!                              first `children` each a node of level `level - 1`, the rest
//!                              0xFFFFFFFF. The nodes of level L-1 are the roots
//!          ..  surfels         S x 3 u32, grouped by node: w0 = x | y << 14 | (z & 15) << 28,
//!                              w1 = z >> 4 | nu << 10 | nv << 18 | openness << 26,
//!                              w2 = r | g << 8 | b << 16 | foliage << 24 | coverage << 25;
//!                              x, y, z 14 bits each, the position within the box in steps of
//!                              (max - min) / 16383; (nu, nv) bytes of the normal's
//!                              octahedral map (`crate::sphere::OctaLayout::Full`, n/255);
//!                              openness 6 bits (n/63, the share of the sky its tree leaves
//!                              open); r, g, b the square root of the linear albedo (n/255);
//!                              foliage 1 bit; coverage 7 bits (n/127, the share of its
//!                              cell it covers)
//!          ..  density         x*y*z f32, finite, >= 0: extinction (1/m), voxel (i, j, k)
//!                              at (k*y + j)*x + i
//! ```
//!
//! A set's own views, lights and resolution are checked against the allowed values but need
//! not equal the header's settings (nor need an impostor's layout, frames and resolution).
//! A BTF set of one `(species, level)` appears at most once, a texel volume or an impostor
//! of one species too, a surfel tree too. Records of one kind keep their order across
//! sections; the writer puts all BTF sections first, then the VCM sections, the texel
//! volumes, the impostors and the surfel trees, packing records greedily so no section exceeds [`MAX_SECTION_BYTES`] (one
//! record must fit in one section). A reader accepts the sections of every kind in any
//! order.
//!
//! # Reading
//!
//! Every length is checked against a hard limit and against the bytes actually left before
//! anything is sized from it, so a truncated or corrupt file gives a [`FormatError`], never
//! a panic, an endless loop or an allocation beyond the file's own size (plus a few KiB).
//! In a deflated section the bytes left are the ones its entry promises, so there a record's
//! data is allocated as it inflates (in steps of 4 MiB), never more than has come out.
//! Order of checks: magic, version, fixed header, section count, header checksum, file size,
//! scene hash (with [`read_expecting`]), settings, table entries; then per section: its
//! records (sizes against the section), its checksum. When a section fails to decode (or to
//! inflate), its checksum is still checked first, so a flipped byte reports a checksum
//! mismatch. [`read`] streams the file, inflating as it goes: the decoded data is the only
//! large allocation.
//!
//!
//! # Writing
//!
//! [`write_atomic`] validates, then writes through [`crate::atomic_file`]: a temporary file
//! in the target's directory, synced and renamed over the target, so the target is either
//! the old file or the complete new one; the temporary file is removed on error.
//!
//! # Files
//!
//! This file holds the constants; `records.rs` the data types (what a bake holds, its
//! records), `settings.rs` the bake settings, `section.rs` the section table's tags and
//! `error.rs` the error; `check.rs` validates them, `plan.rs` sizes records and packs them
//! into sections, `write.rs` encodes and `read.rs` decodes. The public paths are all here
//! (`crate::format::read`, `crate::format::Baked`, ...).

use std::ops::RangeInclusive;

use crate::model::Level;
use crate::sphere::OctaLayout;

pub mod bc;
mod check;
mod error;
mod packed;
mod plan;
mod read;
mod records;
mod section;
mod settings;
mod surfel;
#[cfg(test)]
pub(crate) mod test_support;
mod write;

pub use error::FormatError;
pub use packed::PackedBytes;
pub use plan::{
    btf_record_bytes, file_bytes_for, impostor_record_bytes, surfel_record_bytes,
    texel_record_bytes, vcm_record_bytes,
};
pub use read::{SectionInfo, from_bytes, read, read_expecting, sections, version_of};
pub use records::{
    Baked, BtfImageSet, ImageEncoding, Impostor, MapEncoding, TexelVolume, VcmSet,
    impostor_mip_levels,
};
pub use section::{Packing, SectionKind};
pub use settings::BakeSettings;
pub use surfel::{
    MAX_SURFEL_LEVELS, SURFEL_BUDGET_RANGE, SURFEL_DENSITY_DIM_RANGE, SURFEL_WORDS, Surfel,
    SurfelDensity, SurfelNode, SurfelSet, pack_surfel, unpack_surfel,
};
pub use write::{to_bytes, to_bytes_packed, write_atomic, write_atomic_packed};

use section::{level_from_tag, level_tag};

/// The first 8 bytes of every `.canopy` file.
pub const MAGIC: [u8; 8] = *b"CANOPY\r\n";
/// The `species` of a VCM set that holds a forest cell's cube maps (level tree, owner the
/// cell's index in `crate::vcm::cells::ForestCells`), not one tree's.
pub const VCM_CELL_SPECIES: u32 = u32::MAX;
/// The format version this code writes.
pub const VERSION: u32 = 9;
/// The oldest format version this code reads (its section table has no packing: every
/// payload is stored as it is).
pub const OLDEST_VERSION: u32 = 7;
/// Ambient images per view in a BTF image set: lit by the sky alone, then by the light the
/// ground sends up alone (the two halves of the renderer's hemispherical ambient).
pub const AMBIENT_IMAGES_PER_VIEW: u32 = 2;
/// Most sections a file may have.
pub const MAX_SECTIONS: u32 = 4096;
/// Largest payload of one section (1 GiB).
pub const MAX_SECTION_BYTES: u64 = 1 << 30;
/// Allowed numbers of view and of light directions (octahedron subdivisions).
pub const DIRECTION_COUNTS: [u32; 4] = [6, 18, 66, 258];
/// Allowed BTF image resolutions (square images).
pub const BTF_RESOLUTIONS: [u32; 3] = [32, 64, 128];
/// Allowed supersampling factors.
pub const SUPERSAMPLE_RANGE: RangeInclusive<u32> = 1..=8;
/// Allowed visibility-cube-map face resolutions.
pub const VCM_RESOLUTION_RANGE: RangeInclusive<u32> = 8..=128;
/// Bounding-box corners per VCM set.
pub const VCM_CORNERS: usize = 8;
/// Allowed texel resolutions (voxels along a box's longest side); 0 means no texels.
pub const TEXEL_RESOLUTION_RANGE: RangeInclusive<u32> = 16..=256;
/// Allowed voxel counts along each axis of a texel volume.
pub const TEXEL_DIM_RANGE: RangeInclusive<u32> = 1..=256;
/// Cube faces per visibility cube map.
pub const CUBE_FACES: usize = 6;
/// Allowed impostor frames per side; 0 in the settings means no impostors.
pub const IMPOSTOR_FRAMES_RANGE: RangeInclusive<u32> = 4..=32;
/// Allowed impostor frame sides (pixels).
pub const IMPOSTOR_RESOLUTIONS: [u32; 5] = [16, 32, 64, 128, 256];
/// The smallest frame side an impostor's mip chain goes down to (pixels).
pub const IMPOSTOR_MIN_MIP_SIDE: u32 = 4;

/// Bytes of the header before the section table.
const FIXED_HEADER_BYTES: usize = 80;
/// Bytes of the header before the section table in a version-7 or version-8 file (no
/// surfel budget).
const FIXED_HEADER_BYTES_V8: usize = 76;
/// Words of the settings in the header (from offset 32).
const SETTINGS_WORDS: usize = 12;
/// Bytes of one section-table entry.
const SECTION_ENTRY_BYTES: usize = 28;
/// Bytes of one section-table entry in a version-7 file.
const SECTION_ENTRY_BYTES_V7: usize = 16;
/// Bytes of a section payload before its records (the record count).
const SECTION_PREFIX_BYTES: u64 = 4;
/// Bytes of a BTF record besides its image data.
const BTF_RECORD_FIXED_BYTES: u64 = 56;
/// Bytes of a VCM record besides its opacity data.
const VCM_RECORD_FIXED_BYTES: u64 = 56;
/// Fixed part of a texel volume record (before the voxels).
const TEXEL_RECORD_FIXED_BYTES: u64 = 44;
/// Bytes of an impostor record besides its atlases.
const IMPOSTOR_RECORD_FIXED_BYTES: u64 = 52;

const SETTINGS_DIRECTIONS: &str = "6, 18, 66 or 258";
const SETTINGS_RESOLUTIONS: &str = "32, 64 or 128";
const SETTINGS_SUPERSAMPLE: &str = "1 to 8";
const SETTINGS_VCM_RESOLUTION: &str = "8 to 128";
const SETTINGS_TEXEL_RESOLUTION: &str = "0 (none) or 16 to 256";
const SETTINGS_IMPOSTOR_FRAMES: &str = "0 (none) or 4 to 32";
const SETTINGS_IMPOSTOR_RESOLUTION: &str = "16, 32, 64, 128 or 256";
const SETTINGS_IMPOSTOR_LAYOUT: &str = "0 (full) or 1 (hemi)";
const SETTINGS_COMPRESS: &str = "0 (no) or 1 (yes)";
const SETTINGS_SURFEL_BUDGET: &str = "0 (none) or 1000 to 4000000";

#[cfg(test)]
mod tests {
    use super::*;
    use crate::format::test_support::*;

    #[test]
    fn level_tags_are_the_documented_bytes() {
        for (tag, level) in [(0, Level::Twig), (1, Level::Branch), (2, Level::Tree)] {
            assert_eq!(level_tag(level), tag);
            assert_eq!(level_from_tag(tag), Some(level));
        }
        assert_eq!(level_from_tag(3), None);
    }

    #[test]
    fn sizes_are_counted() {
        let baked = sample();
        assert_eq!(baked.btf_bytes(), 2 * (6 * 6 + 2 * 6) * 32 * 32 * 4);
        assert_eq!(baked.vcm_bytes(), 48 * 64 + 48 * 256);
        let set = &baked.btf[0];
        assert_eq!(set.expected_direct_len(), Some(set.direct.len() as u64));
        assert_eq!(set.expected_ambient_len(), Some(set.ambient.len() as u64));
        let huge = BtfImageSet {
            views: u32::MAX,
            lights: u32::MAX,
            resolution: u32::MAX,
            ..set.clone()
        };
        assert_eq!(huge.expected_direct_len(), None);
    }

    #[test]
    fn impostor_levels_are_laid_out_one_after_the_other() {
        let imp = impostor(0);
        assert_eq!(imp.level(0), Some((0, 64)));
        assert_eq!(imp.level(1), Some((64 * 64 * 4, 32)));
        assert_eq!(imp.level(2), None);
        assert_eq!(
            imp.expected_atlas_len(),
            Some((64 * 64 + 32 * 32) * 4),
            "every level, nothing between"
        );
        assert_eq!(Impostor::atlas_bytes(u32::MAX, u32::MAX, 3), None);
        // Down to frames of 4 pixels.
        for (res, levels) in [(16, 3), (32, 4), (64, 5), (128, 6), (256, 7)] {
            assert_eq!(impostor_mip_levels(res), levels, "{res}");
        }
    }
}
