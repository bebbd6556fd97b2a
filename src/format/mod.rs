//! The `.canopy` file: everything one bake produces (BTF image sets, visibility cube maps,
//! texel volumes, octahedral impostors),
//! in one versioned, checksummed file that the viewer caches and validates on load.
//!
//! Over 800 lines: 188 of them are these docs (the byte layout, 145 lines, kept beside the
//! types it describes, and how it is read and written); reading, writing, planning,
//! checking and BC coding are modules of their own.
//!
//! # Byte layout (format version 8)
//!
//! All integers are little-endian, `f32` is IEEE 754 binary32 (little-endian bits). Offsets
//! are in bytes. There is no padding anywhere.
//!
//! ```text
//! HEADER (80 + 28*N bytes)
//!   off  size  field
//!    0     8   magic           "CANOPY\r\n" (43 41 4E 4F 50 59 0D 0A); the CR LF pair catches
//!                              a file whose line endings were converted in transfer
//!    8     4   version         u32, 8 (a reader also takes 7: see the end of this layout)
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
//!   72     4   compress        u32, 0 or 1: the bake stores its     /
//!                              BTF images in BC7 and its cube maps in BC4 (each record
//!                              says how it is stored: the reader goes by the records)
//!   76  28*N   section table, one 28-byte entry per section, in file order:
//!                +0  u32 kind      1 = BTF image sets, 2 = VCM sets, 3 = texel volumes,
//!                                  4 = impostors (0 and others invalid)
//!                +4  u32 crc32     CRC-32 (IEEE, as crc32fast) of the payload as stored
//!                +8  u64 length    bytes of the payload as stored, 1..=MAX_SECTION_BYTES
//!                                  (1 GiB)
//!               +16  u32 packing   0 = stored as it is, 1 = DEFLATE (RFC 1951, raw, no
//!                                  zlib or gzip wrapper)
//!               +20  u64 plain_length  bytes of the payload once inflated,
//!                                  4..=MAX_SECTION_BYTES; equal to length when packing is 0
//!   76+28N  4  header_crc      u32, CRC-32 of header bytes [0, 76+28N)
//!
//! PAYLOADS: the N section payloads as stored, back to back in table order, starting right
//! after header_crc; their lengths sum to exactly file_size - (80 + 28N) and the file ends
//! there. A deflated payload is one DEFLATE stream that inflates to exactly plain_length
//! bytes and ends exactly at the payload's end.
//!
//! Version 7 differs only in the section table: 16-byte entries (kind, crc32, length), every
//! payload stored as it is; so its header is 80 + 16*N bytes. [`read`] takes both;
//! [`write_atomic`] writes version 8 with every section that shrinks deflated.
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
//! ```
//!
//! A set's own views, lights and resolution are checked against the allowed values but need
//! not equal the header's settings (nor need an impostor's layout, frames and resolution).
//! A BTF set of one `(species, level)` appears at most once, a texel volume or an impostor
//! of one species too. Records of one kind keep their order across sections; the writer
//! puts all BTF sections first, then the VCM sections, the texel volumes and the
//! impostors, packing records greedily so no section exceeds [`MAX_SECTION_BYTES`] (one
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
//! This file holds the constants, the error and the data types; `check.rs` validates them,
//! `plan.rs` sizes records and packs them into sections, `write.rs` encodes and `read.rs`
//! decodes. The public paths are all here (`crate::format::read`, ...).

use std::io;
use std::ops::RangeInclusive;
use std::path::PathBuf;

use crate::model::Level;
use crate::sphere::OctaLayout;

pub mod bc;
mod check;
mod packed;
mod plan;
mod read;
#[cfg(test)]
pub(crate) mod test_support;
mod write;

pub use packed::PackedBytes;
pub use plan::{
    btf_record_bytes, file_bytes_for, impostor_record_bytes, texel_record_bytes, vcm_record_bytes,
};
pub use read::{SectionInfo, from_bytes, read, read_expecting, sections, version_of};
pub use write::{to_bytes, to_bytes_packed, write_atomic, write_atomic_packed};

/// The first 8 bytes of every `.canopy` file.
pub const MAGIC: [u8; 8] = *b"CANOPY\r\n";
/// The `species` of a VCM set that holds a forest cell's cube maps (level tree, owner the
/// cell's index in `crate::vcm::cells::ForestCells`), not one tree's.
pub const VCM_CELL_SPECIES: u32 = u32::MAX;
/// The format version this code writes.
pub const VERSION: u32 = 8;
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
const FIXED_HEADER_BYTES: usize = 76;
/// Words of the settings in the header (from offset 32).
const SETTINGS_WORDS: usize = 11;
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

/// Everything that can go wrong reading or writing a `.canopy` file. Every variant but
/// [`FormatError::Io`] means the file (or the data given to write) is unusable and the
/// scene must be baked again; see [`FormatError::needs_rebake`].
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum FormatError {
    /// The operating system refused a read, write, sync or rename.
    #[error("{action} {}: {source}", path.display())]
    Io {
        path: PathBuf,
        /// What was being done, e.g. "could not open".
        action: &'static str,
        #[source]
        source: io::Error,
    },

    /// The file does not start with [`MAGIC`].
    #[error(
        "not a canopy file: it starts with \"{}\" where a .canopy file starts with \"CANOPY\\r\\n\" \
         (a file whose line endings were converted in transfer looks like this too); \
         give a file written by `canopy bake`, or re-bake with `canopy bake`",
        found.escape_ascii()
    )]
    NotCanopy {
        /// The first bytes of the file (up to 8).
        found: Vec<u8>,
    },

    /// The file has another format version.
    #[error(
        "the .canopy file has format version {found}, but this canopy reads versions \
         {oldest} to {supported}; re-bake with `canopy bake`"
    )]
    UnsupportedVersion {
        found: u32,
        oldest: u32,
        supported: u32,
    },

    /// The file ends before something it declares.
    #[error(
        "the .canopy file is truncated: {what} needs {needed} bytes but only {available} are \
         there (an interrupted copy or download?); copy it again or re-bake with `canopy bake`"
    )]
    Truncated {
        what: String,
        needed: u64,
        available: u64,
    },

    /// A checksum does not match its bytes.
    #[error(
        "the .canopy file is corrupt: the checksum of the {section} does not match its bytes \
         (stored {stored:08x}, computed {computed:08x}); re-bake with `canopy bake`"
    )]
    ChecksumMismatch {
        /// "header", or "section 3 (btf image sets)".
        section: String,
        stored: u32,
        computed: u32,
    },

    /// A size or count is beyond what the format allows.
    #[error(
        "size out of range: {field} is {value}, over the limit of {limit} (a corrupt file, or a \
         bake too large for the format); re-bake with `canopy bake`, with fewer views or lights \
         or a lower resolution if the bake itself is too large"
    )]
    AbsurdSize {
        field: String,
        value: u64,
        limit: u64,
    },

    /// A section (or the data given to write) does not decode to what its header promises.
    #[error(
        "malformed canopy data in {section}: {reason}; re-bake with `canopy bake` \
         (a bake that produces this is a bug)"
    )]
    MalformedContent { section: String, reason: String },

    /// A bake setting is outside the allowed values.
    #[error(
        "invalid bake setting {field} = {value} (allowed: {allowed}); fix the bake settings \
         and re-bake with `canopy bake`"
    )]
    InvalidSettings {
        field: &'static str,
        value: u32,
        allowed: &'static str,
    },

    /// The file was baked from another scene or with other settings.
    #[error(
        "the .canopy file was baked for another scene or other bake settings (scene hash \
         {found:016x}, expected {expected:016x}); re-bake with `canopy bake`"
    )]
    SceneMismatch { found: u64, expected: u64 },
}

impl FormatError {
    /// True when the file exists but cannot be used as it is (corrupt, truncated, stale,
    /// another version): a cache should bake again and overwrite it. False for I/O errors.
    pub fn needs_rebake(&self) -> bool {
        !matches!(self, FormatError::Io { .. })
    }

    /// True for an I/O error saying the file does not exist.
    pub fn is_not_found(&self) -> bool {
        matches!(self, FormatError::Io { source, .. } if source.kind() == io::ErrorKind::NotFound)
    }
}

/// Everything one bake produces.
#[derive(Clone, Debug, PartialEq)]
pub struct Baked {
    /// Hash of the scene file text + bake settings (computed by the caller).
    pub scene_hash: u64,
    pub settings: BakeSettings,
    pub btf: Vec<BtfImageSet>,
    /// Visibility cube maps.
    pub vcm: Vec<VcmSet>,
    /// Texel volumes, one per species (none when the settings' texel resolution is 0).
    pub texels: Vec<TexelVolume>,
    /// Octahedral impostors, one per species (none when the settings' impostor frames
    /// are 0).
    pub impostors: Vec<Impostor>,
}

/// The bake parameters stored in the header.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BakeSettings {
    /// View directions per twig and main-branch BTF set: one of [`DIRECTION_COUNTS`].
    pub views: u32,
    /// View directions per tree-level BTF set: one of [`DIRECTION_COUNTS`].
    pub tree_views: u32,
    /// Light directions per BTF set: one of [`DIRECTION_COUNTS`].
    pub lights: u32,
    /// BTF image resolution: one of [`BTF_RESOLUTIONS`].
    pub resolution: u32,
    /// Supersampling factor: in [`SUPERSAMPLE_RANGE`].
    pub supersample: u32,
    /// VCM face resolution: in [`VCM_RESOLUTION_RANGE`].
    pub vcm_resolution: u32,
    /// Voxels along the longest side of each species' texel volume: 0 (no texels) or in
    /// [`TEXEL_RESOLUTION_RANGE`].
    pub texel_resolution: u32,
    /// Frames per side of each species' octahedral impostor: 0 (none) or in
    /// [`IMPOSTOR_FRAMES_RANGE`].
    pub impostor_frames: u32,
    /// Pixels a side of one impostor frame: one of [`IMPOSTOR_RESOLUTIONS`].
    pub impostor_resolution: u32,
    /// The directions the impostor frames cover.
    pub impostor_layout: OctaLayout,
    /// Whether the bake block-compresses its BTF images (BC7) and cube maps (BC4).
    pub compress: bool,
}

/// The billboard images of one species at one level.
#[derive(Clone, Debug, PartialEq)]
pub struct BtfImageSet {
    pub species: u32,
    pub level: Level,
    pub views: u32,
    pub lights: u32,
    pub resolution: u32,
    /// Billboard frame: the object's bounding-sphere centre (object frame) and radius; an
    /// image covers a square of side 2*radius centred on the centre, seen from its view
    /// direction.
    pub center: [f32; 3],
    pub radius: f32,
    /// Largest world size of one texel of this level's images (G_max in the thesis' LOD
    /// criterion).
    pub texel_size: f32,
    /// How `direct` and `ambient` hold their images.
    pub encoding: ImageEncoding,
    /// Premultiplied, views*lights images of resolution², view-major: image (v, l) starts
    /// at (v*lights + l) * [`Self::image_bytes`].
    pub direct: Vec<u8>,
    /// Premultiplied, [`AMBIENT_IMAGES_PER_VIEW`] x views images of resolution²: each
    /// view's image under the sky light only, then each view's under the ground's light
    /// only.
    pub ambient: Vec<u8>,
}

/// How a BTF set stores each image.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum ImageEncoding {
    /// RGBA8 sRGB, level 0 alone (the viewer makes the mips).
    #[default]
    Rgba8,
    /// BC7, the mip chain down to 4 texels a side ([`bc::bc7_chain_bytes`]).
    Bc7,
}

impl ImageEncoding {
    /// The byte that stores it in a record.
    pub fn tag(self) -> u8 {
        match self {
            ImageEncoding::Rgba8 => 0,
            ImageEncoding::Bc7 => 1,
        }
    }

    /// The encoding stored as `tag`, if any.
    pub fn from_tag(tag: u8) -> Option<Self> {
        match tag {
            0 => Some(ImageEncoding::Rgba8),
            1 => Some(ImageEncoding::Bc7),
            _ => None,
        }
    }
}

/// How a VCM set stores its opacity.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum MapEncoding {
    /// A byte per texel.
    #[default]
    R8,
    /// BC4, each face on its own ([`bc::bc4_bytes`]).
    Bc4,
}

impl MapEncoding {
    /// The byte that stores it in a record.
    pub fn tag(self) -> u8 {
        match self {
            MapEncoding::R8 => 0,
            MapEncoding::Bc4 => 1,
        }
    }

    /// The encoding stored as `tag`, if any.
    pub fn from_tag(tag: u8) -> Option<Self> {
        match tag {
            0 => Some(MapEncoding::R8),
            1 => Some(MapEncoding::Bc4),
            _ => None,
        }
    }
}

/// The visibility cube maps at the 8 bounding-box corners of one object.
#[derive(Clone, Debug, PartialEq)]
pub struct VcmSet {
    pub species: u32,
    /// The object within its level (see the record layout above).
    pub owner: u32,
    pub level: Level,
    pub resolution: u32,
    /// How `opacity` holds its faces.
    pub encoding: MapEncoding,
    /// 8 corners x 6 faces of resolution² opacity texels, corner-major then face-major:
    /// a byte each ([`MapEncoding::R8`]), or each face's BC4 blocks.
    pub opacity: Vec<u8>,
    /// Mean opacity of each corner's cube map, in [0, 1].
    pub mean_opacity: [f32; 8],
}

/// One species' whole tree as RGBA volumes in its box (object frame): one per baked light
/// and one lit by the sky.
#[derive(Clone, Debug, PartialEq)]
pub struct TexelVolume {
    pub species: u32,
    /// Light samples (the BTF's direction set of this count).
    pub lights: u32,
    /// Voxels along x, y, z.
    pub dims: [u32; 3],
    /// Lowest corner of the volume in the object frame.
    pub box_min: [f32; 3],
    /// Side of one cubic voxel (m).
    pub voxel: f32,
    /// RGBA8 premultiplied, lights+1 volumes (see the record layout above).
    pub voxels: Vec<u8>,
}

/// One species' whole tree as an octahedral impostor: a grid of orthographic views of the
/// tree level, unlit colour with coverage and normal with depth, each frame with its own
/// mip chain (see the record layout above).
#[derive(Clone, Debug, PartialEq)]
pub struct Impostor {
    pub species: u32,
    pub layout: OctaLayout,
    /// Frames per side.
    pub frames: u32,
    /// Pixels a frame side at level 0.
    pub resolution: u32,
    /// Levels stored, level 0 included.
    pub mip_levels: u32,
    /// Bounding-sphere centre (object frame) and radius: what every frame frames.
    pub center: [f32; 3],
    pub radius: f32,
    /// RGBA8 atlases, level 0 first: sRGB albedo, coverage in alpha.
    pub albedo: Vec<u8>,
    /// RGBA8 atlases as `albedo`: normal * 0.5 + 0.5, depth in alpha.
    pub normal_depth: Vec<u8>,
}

/// The kind tag of a section.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[repr(u32)]
pub enum SectionKind {
    /// [`BtfImageSet`] records.
    Btf = 1,
    /// [`VcmSet`] records.
    Vcm = 2,
    /// [`TexelVolume`] records.
    Texel = 3,
    /// [`Impostor`] records.
    Impostor = 4,
}

/// How a section's payload is stored in the file.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Packing {
    /// As it is.
    Plain = 0,
    /// As one raw DEFLATE stream (RFC 1951).
    Deflate = 1,
}

impl Packing {
    /// The packing with this tag, if any.
    pub fn from_u32(tag: u32) -> Option<Packing> {
        match tag {
            0 => Some(Packing::Plain),
            1 => Some(Packing::Deflate),
            _ => None,
        }
    }
}

impl SectionKind {
    /// The kind with this tag, if any.
    pub fn from_u32(tag: u32) -> Option<SectionKind> {
        match tag {
            1 => Some(SectionKind::Btf),
            2 => Some(SectionKind::Vcm),
            3 => Some(SectionKind::Texel),
            4 => Some(SectionKind::Impostor),
            _ => None,
        }
    }

    pub fn name(self) -> &'static str {
        match self {
            SectionKind::Btf => "btf image sets",
            SectionKind::Vcm => "vcm sets",
            SectionKind::Texel => "texel volumes",
            SectionKind::Impostor => "impostors",
        }
    }
}

/// The byte that stores `level` in a record: 0 twig, 1 branch, 2 tree.
fn level_tag(level: Level) -> u8 {
    match level {
        Level::Twig => 0,
        Level::Branch => 1,
        Level::Tree => 2,
    }
}

/// The level stored as `tag`, if any.
fn level_from_tag(tag: u8) -> Option<Level> {
    match tag {
        0 => Some(Level::Twig),
        1 => Some(Level::Branch),
        2 => Some(Level::Tree),
        _ => None,
    }
}

impl BakeSettings {
    /// The settings as the header stores them, in its order (what the scene hash folds in
    /// too).
    pub fn header_words(&self) -> [u32; SETTINGS_WORDS] {
        [
            self.views,
            self.lights,
            self.resolution,
            self.supersample,
            self.vcm_resolution,
            self.texel_resolution,
            self.tree_views,
            self.impostor_frames,
            self.impostor_resolution,
            self.impostor_layout.tag(),
            u32::from(self.compress),
        ]
    }

    /// The settings from the header's words (see [`Self::header_words`]), or the layout
    /// tag when it names no layout.
    pub fn from_header_words(w: [u32; SETTINGS_WORDS]) -> Result<Self, FormatError> {
        let Some(impostor_layout) = OctaLayout::from_tag(w[9]) else {
            return Err(FormatError::InvalidSettings {
                field: "impostor_layout",
                value: w[9],
                allowed: SETTINGS_IMPOSTOR_LAYOUT,
            });
        };
        let compress = match w[10] {
            0 => false,
            1 => true,
            value => {
                return Err(FormatError::InvalidSettings {
                    field: "compress",
                    value,
                    allowed: SETTINGS_COMPRESS,
                });
            }
        };
        Ok(Self {
            views: w[0],
            lights: w[1],
            resolution: w[2],
            supersample: w[3],
            vcm_resolution: w[4],
            texel_resolution: w[5],
            tree_views: w[6],
            impostor_frames: w[7],
            impostor_resolution: w[8],
            impostor_layout,
            compress,
        })
    }

    /// View directions of the image sets of `level`: the tree level has its own count.
    pub fn views_of(&self, level: Level) -> u32 {
        match level {
            Level::Tree => self.tree_views,
            Level::Twig | Level::Branch => self.views,
        }
    }
}

impl BtfImageSet {
    /// Bytes of one image as the set stores it: resolution²*4 (RGBA8) or its BC7 mip
    /// chain; None on overflow or a resolution the format does not allow.
    pub fn image_bytes(&self) -> Option<u64> {
        match self.encoding {
            ImageEncoding::Rgba8 => image_bytes(self.resolution),
            ImageEncoding::Bc7 => BTF_RESOLUTIONS
                .contains(&self.resolution)
                .then(|| bc::bc7_chain_bytes(self.resolution)),
        }
    }

    /// The length `direct` must have: views*lights*[`Self::image_bytes`], or None on
    /// overflow.
    pub fn expected_direct_len(&self) -> Option<u64> {
        self.image_bytes()?
            .checked_mul(u64::from(self.views))?
            .checked_mul(u64::from(self.lights))
    }

    /// The length `ambient` must have: 2*views*[`Self::image_bytes`], or None on overflow.
    pub fn expected_ambient_len(&self) -> Option<u64> {
        self.image_bytes()?
            .checked_mul(u64::from(self.views))?
            .checked_mul(u64::from(AMBIENT_IMAGES_PER_VIEW))
    }

    /// Every image as stored, direct images first, then the ambient ones (the order the
    /// viewer numbers them in).
    pub fn images(&self) -> impl Iterator<Item = &[u8]> {
        let n = self.image_bytes().unwrap_or(0).max(1) as usize;
        self.direct
            .chunks_exact(n)
            .chain(self.ambient.chunks_exact(n))
    }

    /// The RGBA8 level 0 of one stored image (from [`Self::images`]): itself, or its BC7
    /// level 0 decoded; None when it has not the size of one image.
    pub fn rgba(&self, image: &[u8]) -> Option<std::borrow::Cow<'_, [u8]>> {
        let res = self.resolution;
        match self.encoding {
            ImageEncoding::Rgba8 => (Some(image.len() as u64) == image_bytes(res))
                .then(|| std::borrow::Cow::Owned(image.to_vec())),
            ImageEncoding::Bc7 => {
                let levels = bc::bc7_levels(image, res)?;
                bc::decode_bc7(levels.first()?.1, res, res).map(std::borrow::Cow::Owned)
            }
        }
    }

    /// The ambient images as RGBA8 level 0 (decoded when BC7), None when they do not hold
    /// what the set's fields say.
    pub fn ambient_rgba(&self) -> Option<std::borrow::Cow<'_, [u8]>> {
        if self.expected_ambient_len() != Some(self.ambient.len() as u64) {
            return None;
        }
        match self.encoding {
            ImageEncoding::Rgba8 => Some(std::borrow::Cow::Borrowed(&self.ambient)),
            ImageEncoding::Bc7 => {
                let n = self.image_bytes()? as usize;
                let mut out = Vec::with_capacity(
                    self.ambient.len() / n.max(1) * image_bytes(self.resolution)? as usize,
                );
                for image in self.ambient.chunks_exact(n) {
                    out.extend_from_slice(&self.rgba(image)?);
                }
                Some(std::borrow::Cow::Owned(out))
            }
        }
    }
}

impl crate::vcm::billboard::AlphaSet {
    /// A BTF set's sky-lit images as occluders (see
    /// [`AlphaSet::from_sky_lit`](crate::vcm::billboard::AlphaSet::from_sky_lit)), after
    /// checking that its ambient images hold what its fields say. Defined here rather than
    /// in `vcm`, which sits below this file format.
    pub fn new(set: &BtfImageSet) -> crate::Result<Self> {
        let Some(ambient) = set.ambient_rgba() else {
            return Err(crate::Error::BadInput(format!(
                "BTF set of species {} level {:?}: ambient images hold {} bytes, expected {:?}",
                set.species,
                set.level,
                set.ambient.len(),
                set.expected_ambient_len()
            )));
        };
        Self::from_sky_lit(
            set.views,
            set.resolution,
            &ambient,
            glam::Vec3::from(set.center),
            set.radius,
        )
        .map_err(|e| crate::Error::BadInput(format!("BTF set: {e}")))
    }
}

impl VcmSet {
    /// Bytes of one face as stored: resolution² (R8) or its BC4 blocks; None on overflow.
    pub fn face_bytes(&self) -> Option<u64> {
        match self.encoding {
            MapEncoding::R8 => u64::from(self.resolution).checked_mul(u64::from(self.resolution)),
            MapEncoding::Bc4 => {
                let blocks = u64::from(bc::blocks_along(self.resolution));
                blocks
                    .checked_mul(blocks)?
                    .checked_mul(bc::BC4_BLOCK_BYTES as u64)
            }
        }
    }

    /// The length `opacity` must have: 8*6*[`Self::face_bytes`], or None on overflow.
    pub fn expected_opacity_len(&self) -> Option<u64> {
        self.face_bytes()?
            .checked_mul((VCM_CORNERS * CUBE_FACES) as u64)
    }

    /// The opacity a byte per texel (decoded when BC4), None when `opacity` does not hold
    /// what the set's fields say.
    pub fn opacity_r8(&self) -> Option<std::borrow::Cow<'_, [u8]>> {
        if self.expected_opacity_len() != Some(self.opacity.len() as u64) {
            return None;
        }
        match self.encoding {
            MapEncoding::R8 => Some(std::borrow::Cow::Borrowed(&self.opacity)),
            MapEncoding::Bc4 => {
                let res = self.resolution;
                let face = self.face_bytes()? as usize;
                let mut out =
                    Vec::with_capacity(VCM_CORNERS * CUBE_FACES * res as usize * res as usize);
                for blocks in self.opacity.chunks_exact(face.max(1)) {
                    out.extend_from_slice(&bc::decode_bc4(blocks, res, res)?);
                }
                Some(std::borrow::Cow::Owned(out))
            }
        }
    }
}

impl TexelVolume {
    /// Voxels in one of its volumes, or None on overflow.
    pub fn voxel_count(&self) -> Option<u64> {
        u64::from(self.dims[0])
            .checked_mul(u64::from(self.dims[1]))?
            .checked_mul(u64::from(self.dims[2]))
    }

    /// The length `voxels` must have: (lights+1)*x*y*z*4, or None on overflow.
    pub fn expected_voxels_len(&self) -> Option<u64> {
        self.voxel_count()?
            .checked_mul(4)?
            .checked_mul(u64::from(self.lights).checked_add(1)?)
    }

    /// The volume's highest corner in the object frame.
    pub fn box_max(&self) -> [f32; 3] {
        std::array::from_fn(|i| self.box_min[i] + self.dims[i] as f32 * self.voxel)
    }
}

impl Impostor {
    /// The bytes of one atlas (`albedo` or `normal_depth`) of these sizes, every level
    /// included, or None on overflow.
    pub fn atlas_bytes(frames: u32, resolution: u32, mip_levels: u32) -> Option<u64> {
        let mut sum: u64 = 0;
        for m in 0..mip_levels.min(32) {
            let side = u64::from(frames).checked_mul(u64::from(resolution >> m))?;
            sum = sum.checked_add(side.checked_mul(side)?.checked_mul(4)?)?;
        }
        Some(sum)
    }

    /// The length `albedo` (and `normal_depth`) must have, or None on overflow.
    pub fn expected_atlas_len(&self) -> Option<u64> {
        Self::atlas_bytes(self.frames, self.resolution, self.mip_levels)
    }

    /// Byte offset and side (pixels) of level `m` in an atlas, if the record has it.
    pub fn level(&self, m: u32) -> Option<(usize, u32)> {
        if m >= self.mip_levels {
            return None;
        }
        let at = Self::atlas_bytes(self.frames, self.resolution, m)?;
        Some((
            usize::try_from(at).ok()?,
            self.frames * (self.resolution >> m),
        ))
    }
}

/// Levels of an impostor's mip chain for frames of `resolution` pixels: down to frames of
/// [`IMPOSTOR_MIN_MIP_SIDE`] pixels (1 for smaller frames).
pub fn impostor_mip_levels(resolution: u32) -> u32 {
    let min = IMPOSTOR_MIN_MIP_SIDE.max(1);
    let mut levels = 1;
    while (resolution >> levels) >= min {
        levels += 1;
    }
    levels
}

impl Baked {
    /// A bake of `scene_hash` with `settings` that holds nothing yet.
    pub fn empty(scene_hash: u64, settings: BakeSettings) -> Baked {
        Baked {
            scene_hash,
            settings,
            btf: Vec::new(),
            vcm: Vec::new(),
            texels: Vec::new(),
            impostors: Vec::new(),
        }
    }

    /// Bytes of BTF image data (direct + ambient) over all sets.
    pub fn btf_bytes(&self) -> u64 {
        self.btf
            .iter()
            .map(|s| s.direct.len() as u64 + s.ambient.len() as u64)
            .sum()
    }

    /// Bytes of VCM opacity data over all sets.
    pub fn vcm_bytes(&self) -> u64 {
        self.vcm.iter().map(|s| s.opacity.len() as u64).sum()
    }

    /// Bytes of texel voxels over all volumes.
    pub fn texel_bytes(&self) -> u64 {
        self.texels.iter().map(|t| t.voxels.len() as u64).sum()
    }

    /// Bytes of impostor atlases (both maps, every level) over all impostors.
    pub fn impostor_bytes(&self) -> u64 {
        self.impostors
            .iter()
            .map(|i| i.albedo.len() as u64 + i.normal_depth.len() as u64)
            .sum()
    }
}

fn image_bytes(resolution: u32) -> Option<u64> {
    u64::from(resolution)
        .checked_mul(u64::from(resolution))?
        .checked_mul(4)
}

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
