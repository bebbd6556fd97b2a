//! The `.canopy` file: everything one bake produces (BTF image sets, visibility cube maps,
//! texel volumes),
//! in one versioned, checksummed file that the viewer caches and validates on load.
//!
//! # Byte layout (format version 5)
//!
//! All integers are little-endian, `f32` is IEEE 754 binary32 (little-endian bits). Offsets
//! are in bytes. There is no padding anywhere.
//!
//! ```text
//! HEADER (64 + 16*N bytes)
//!   off  size  field
//!    0     8   magic           "CANOPY\r\n" (43 41 4E 4F 50 59 0D 0A); the CR LF pair catches
//!                              a file whose line endings were converted in transfer
//!    8     4   version         u32, 5
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
//!   56     4   tree_views      u32, one of 6, 18, 66, 258 (tree-   /
//!                              level sets)
//!   60  16*N   section table, one 16-byte entry per section, in file order:
//!                +0  u32 kind      1 = BTF image sets, 2 = VCM sets, 3 = texel volumes
//!                                  (0 and others invalid)
//!                +4  u32 crc32     CRC-32 (IEEE, as crc32fast) of the section's payload
//!                +8  u64 length    payload length in bytes, 4..=MAX_SECTION_BYTES (1 GiB)
//!   60+16N  4  header_crc      u32, CRC-32 of header bytes [0, 60+16N)
//!
//! PAYLOADS: the N section payloads, back to back in table order, starting right after
//! header_crc; their lengths sum to exactly file_size - (64 + 16N) and the file ends there.
//!
//! SECTION PAYLOAD (either kind)
//!    0     4   record_count    u32 R
//!    4     ..  R records of the section's kind, back to back, filling the payload exactly
//!
//! BTF IMAGE SET RECORD (kind 1; 56 bytes + image data)
//!    0     4   species         u32
//!    4     1   level           u8, 0 = twig, 1 = branch, 2 = tree
//!    5     3   reserved        must be 0
//!    8     4   views           u32, one of 6, 18, 66, 258
//!   12     4   lights          u32, one of 6, 18, 66, 258
//!   16     4   resolution      u32, one of 32, 64, 128
//!   20    12   center          3 x f32, finite (bounding-sphere centre, object frame)
//!   32     4   radius          f32, finite, > 0
//!   36     4   texel_size      f32, finite, > 0
//!   40     8   direct_len      u64, must equal views*lights*resolution²*4
//!   48     D   direct          RGBA8 premultiplied, view-major: image (v, l) at
//!                              (v*lights + l) * resolution² * 4
//!   48+D   8   ambient_len     u64, must equal 2*views*resolution²*4
//!   56+D   A   ambient         RGBA8 premultiplied: the sky-lit image of each view, then
//!                              the ground-lit image of each view (v at v, and at views + v)
//!
//! VCM SET RECORD (kind 2; 56 bytes + opacity data)
//!    0     4   species         u32; 0xFFFFFFFF (VCM_CELL_SPECIES, level tree) marks the cube
//!                              maps of a forest cell (`crate::vcm::cells`)
//!    4     4   owner           u32, the object within its level: the tree instance (or the
//!                              forest cell); the main branch of the species' tree; the
//!                              twig of its reference main branch, numbered on past them
//!                              through the trunk's twigs
//!    8     1   level           u8, 0 = twig, 1 = branch, 2 = tree
//!    9     3   reserved        must be 0
//!   12     4   resolution      u32, 8..=128
//!   16    32   mean_opacity    8 x f32, finite, in [0, 1], one per corner
//!   48     8   opacity_len     u64, must equal 8*6*resolution²
//!   56     O   opacity         u8 per texel: 8 corners x 6 cube faces x resolution², each
//!                              face res rows of res texels (see `crate::vcm` for the layout)
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
//! ```
//!
//! A set's own views, lights and resolution are checked against the allowed values but need
//! not equal the header's settings. A BTF set of one `(species, level)` appears at most once,
//! a texel volume of one species too. Records of one kind keep their
//! order across sections; the writer puts all BTF sections first, then all VCM sections,
//! packing records greedily so no section exceeds [`MAX_SECTION_BYTES`] (one record must
//! fit in one section). A reader accepts the sections of both kinds in any order.
//!
//! # Reading
//!
//! Every length is checked against a hard limit and against the bytes actually left before
//! anything is sized from it, so a truncated or corrupt file gives a [`FormatError`], never
//! a panic, an endless loop or an allocation beyond the file's own size (plus a few KiB).
//! Order of checks: magic, version, fixed header, section count, header checksum, file size,
//! scene hash (with [`read_expecting`]), settings, table entries; then per section: its
//! records (sizes against the section), its checksum. When a section fails to decode, its
//! checksum is still checked first, so a flipped byte reports a checksum mismatch.
//! [`read`] streams the file: the decoded data is the only large allocation.
//!
//! # Writing
//!
//! [`write_atomic`] validates, writes a temporary file in the target's directory, fsyncs it
//! and renames it over the target (then fsyncs the directory on Unix), so the target is
//! either the old file or the complete new one; the temporary file is removed on error.

use std::collections::HashSet;
use std::fs::{self, File, OpenOptions};
use std::io::{self, BufReader, BufWriter, Read, Write};
use std::ops::RangeInclusive;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};

use crate::model::Level;

/// The first 8 bytes of every `.canopy` file.
pub const MAGIC: [u8; 8] = *b"CANOPY\r\n";
/// The `species` of a VCM set that holds a forest cell's cube maps (level tree, owner the
/// cell's index in `crate::vcm::cells::ForestCells`), not one tree's.
pub const VCM_CELL_SPECIES: u32 = u32::MAX;
/// The format version this code writes and the only one it reads.
pub const VERSION: u32 = 5;
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

/// Bytes of the header before the section table.
const FIXED_HEADER_BYTES: usize = 60;
/// Bytes of one section-table entry.
const SECTION_ENTRY_BYTES: usize = 16;
/// Bytes of a section payload before its records (the record count).
const SECTION_PREFIX_BYTES: u64 = 4;
/// Bytes of a BTF record besides its image data.
const BTF_RECORD_FIXED_BYTES: u64 = 56;
/// Bytes of a VCM record besides its opacity data.
const VCM_RECORD_FIXED_BYTES: u64 = 56;
/// Fixed part of a texel volume record (before the voxels).
const TEXEL_RECORD_FIXED_BYTES: u64 = 44;

const SETTINGS_DIRECTIONS: &str = "6, 18, 66 or 258";
const SETTINGS_RESOLUTIONS: &str = "32, 64 or 128";
const SETTINGS_SUPERSAMPLE: &str = "1 to 8";
const SETTINGS_VCM_RESOLUTION: &str = "8 to 128";
const SETTINGS_TEXEL_RESOLUTION: &str = "0 (none) or 16 to 256";

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
        "the .canopy file has format version {found}, but this canopy reads version {supported}; \
         re-bake with `canopy bake`"
    )]
    UnsupportedVersion { found: u32, supported: u32 },

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
    /// RGBA8 premultiplied, views*lights images of resolution², view-major: image (v, l)
    /// starts at ((v*lights + l) * res*res*4).
    pub direct: Vec<u8>,
    /// RGBA8 premultiplied, [`AMBIENT_IMAGES_PER_VIEW`] x views images of resolution²:
    /// each view's image under the sky light only, then each view's under the ground's
    /// light only.
    pub ambient: Vec<u8>,
}

/// The visibility cube maps at the 8 bounding-box corners of one object.
#[derive(Clone, Debug, PartialEq)]
pub struct VcmSet {
    pub species: u32,
    /// The object within its level (see the record layout above).
    pub owner: u32,
    pub level: Level,
    pub resolution: u32,
    /// 8 corners x 6 faces x resolution² opacity bytes, corner-major then face-major.
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
}

impl SectionKind {
    /// The kind with this tag, if any.
    pub fn from_u32(tag: u32) -> Option<SectionKind> {
        match tag {
            1 => Some(SectionKind::Btf),
            2 => Some(SectionKind::Vcm),
            3 => Some(SectionKind::Texel),
            _ => None,
        }
    }

    fn name(self) -> &'static str {
        match self {
            SectionKind::Btf => "btf image sets",
            SectionKind::Vcm => "vcm sets",
            SectionKind::Texel => "texel volumes",
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
    /// View directions of the image sets of `level`: the tree level has its own count.
    pub fn views_of(&self, level: Level) -> u32 {
        match level {
            Level::Tree => self.tree_views,
            Level::Twig | Level::Branch => self.views,
        }
    }

    /// Checks every field against its allowed values.
    pub fn validate(&self) -> Result<(), FormatError> {
        let bad = |field, value, allowed| {
            Err(FormatError::InvalidSettings {
                field,
                value,
                allowed,
            })
        };
        if !DIRECTION_COUNTS.contains(&self.views) {
            return bad("views", self.views, SETTINGS_DIRECTIONS);
        }
        if !DIRECTION_COUNTS.contains(&self.tree_views) {
            return bad("tree_views", self.tree_views, SETTINGS_DIRECTIONS);
        }
        if !DIRECTION_COUNTS.contains(&self.lights) {
            return bad("lights", self.lights, SETTINGS_DIRECTIONS);
        }
        if !BTF_RESOLUTIONS.contains(&self.resolution) {
            return bad("resolution", self.resolution, SETTINGS_RESOLUTIONS);
        }
        if !SUPERSAMPLE_RANGE.contains(&self.supersample) {
            return bad("supersample", self.supersample, SETTINGS_SUPERSAMPLE);
        }
        if !VCM_RESOLUTION_RANGE.contains(&self.vcm_resolution) {
            return bad(
                "vcm_resolution",
                self.vcm_resolution,
                SETTINGS_VCM_RESOLUTION,
            );
        }
        if self.texel_resolution != 0 && !TEXEL_RESOLUTION_RANGE.contains(&self.texel_resolution) {
            return bad(
                "texel_resolution",
                self.texel_resolution,
                SETTINGS_TEXEL_RESOLUTION,
            );
        }
        Ok(())
    }
}

impl BtfImageSet {
    /// The length `direct` must have: views*lights*resolution²*4, or None on overflow.
    pub fn expected_direct_len(&self) -> Option<u64> {
        image_bytes(self.resolution)?
            .checked_mul(u64::from(self.views))?
            .checked_mul(u64::from(self.lights))
    }

    /// The length `ambient` must have: 2*views*resolution²*4, or None on overflow.
    pub fn expected_ambient_len(&self) -> Option<u64> {
        image_bytes(self.resolution)?
            .checked_mul(u64::from(self.views))?
            .checked_mul(u64::from(AMBIENT_IMAGES_PER_VIEW))
    }

    /// What is wrong with this set's fields given its image lengths, if anything.
    fn problem(&self, direct_len: u64, ambient_len: u64) -> Option<String> {
        if !DIRECTION_COUNTS.contains(&self.views) {
            return Some(format!(
                "views is {}, not {SETTINGS_DIRECTIONS}",
                self.views
            ));
        }
        if !DIRECTION_COUNTS.contains(&self.lights) {
            return Some(format!(
                "lights is {}, not {SETTINGS_DIRECTIONS}",
                self.lights
            ));
        }
        if !BTF_RESOLUTIONS.contains(&self.resolution) {
            return Some(format!(
                "resolution is {}, not {SETTINGS_RESOLUTIONS}",
                self.resolution
            ));
        }
        if let Some(i) = self.center.iter().position(|c| !c.is_finite()) {
            return Some(format!("center[{i}] is {}, not finite", self.center[i]));
        }
        if !(self.radius.is_finite() && self.radius > 0.0) {
            return Some(format!("radius is {}, not finite and > 0", self.radius));
        }
        if !(self.texel_size.is_finite() && self.texel_size > 0.0) {
            return Some(format!(
                "texel_size is {}, not finite and > 0",
                self.texel_size
            ));
        }
        let expected = self.expected_direct_len();
        if expected != Some(direct_len) {
            return Some(format!(
                "direct holds {direct_len} bytes, expected {} ({} views x {} lights x {}² x 4)",
                show_len(expected),
                self.views,
                self.lights,
                self.resolution
            ));
        }
        let expected = self.expected_ambient_len();
        if expected != Some(ambient_len) {
            return Some(format!(
                "ambient holds {ambient_len} bytes, expected {} ({AMBIENT_IMAGES_PER_VIEW} x {} views x {}² x 4)",
                show_len(expected),
                self.views,
                self.resolution
            ));
        }
        None
    }
}

impl crate::vcm::billboard::AlphaSet {
    /// A BTF set's sky-lit images as occluders (see
    /// [`AlphaSet::from_sky_lit`](crate::vcm::billboard::AlphaSet::from_sky_lit)), after
    /// checking that its ambient images hold what its fields say. Defined here rather than
    /// in `vcm`, which sits below this file format.
    pub fn new(set: &BtfImageSet) -> crate::Result<Self> {
        let expected = set.expected_ambient_len();
        if expected != Some(set.ambient.len() as u64) {
            return Err(crate::Error::BadInput(format!(
                "BTF set of species {} level {:?}: ambient images hold {} bytes, expected {:?}",
                set.species,
                set.level,
                set.ambient.len(),
                expected
            )));
        }
        Self::from_sky_lit(
            set.views,
            set.resolution,
            &set.ambient,
            glam::Vec3::from(set.center),
            set.radius,
        )
        .map_err(|e| crate::Error::BadInput(format!("BTF set: {e}")))
    }
}

impl VcmSet {
    /// The length `opacity` must have: 8*6*resolution², or None on overflow.
    pub fn expected_opacity_len(&self) -> Option<u64> {
        u64::from(self.resolution)
            .checked_mul(u64::from(self.resolution))?
            .checked_mul((VCM_CORNERS * CUBE_FACES) as u64)
    }

    /// What is wrong with this set's fields given its opacity length, if anything.
    fn problem(&self, opacity_len: u64) -> Option<String> {
        if !VCM_RESOLUTION_RANGE.contains(&self.resolution) {
            return Some(format!(
                "resolution is {}, not {SETTINGS_VCM_RESOLUTION}",
                self.resolution
            ));
        }
        if let Some(i) = self
            .mean_opacity
            .iter()
            .position(|m| !(m.is_finite() && (0.0..=1.0).contains(m)))
        {
            return Some(format!(
                "mean_opacity[{i}] is {}, not in [0, 1]",
                self.mean_opacity[i]
            ));
        }
        let expected = self.expected_opacity_len();
        if expected != Some(opacity_len) {
            return Some(format!(
                "opacity holds {opacity_len} bytes, expected {} (8 corners x 6 faces x {}²)",
                show_len(expected),
                self.resolution
            ));
        }
        None
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

    /// What is wrong with this volume's fields given its data length, if anything.
    fn problem(&self, voxels_len: u64) -> Option<String> {
        if !DIRECTION_COUNTS.contains(&self.lights) {
            return Some(format!(
                "lights is {}, not {SETTINGS_DIRECTIONS}",
                self.lights
            ));
        }
        if let Some(i) = self.dims.iter().position(|d| !TEXEL_DIM_RANGE.contains(d)) {
            return Some(format!("dims[{i}] is {}, not 1 to 256", self.dims[i]));
        }
        if let Some(i) = self.box_min.iter().position(|c| !c.is_finite()) {
            return Some(format!("box_min[{i}] is {}, not finite", self.box_min[i]));
        }
        if !(self.voxel.is_finite() && self.voxel > 0.0) {
            return Some(format!("voxel is {}, not finite and > 0", self.voxel));
        }
        let expected = self.expected_voxels_len();
        if expected != Some(voxels_len) {
            return Some(format!(
                "voxels holds {voxels_len} bytes, expected {} ({} lights + sky x {}x{}x{} x 4)",
                show_len(expected),
                self.lights,
                self.dims[0],
                self.dims[1],
                self.dims[2]
            ));
        }
        None
    }
}

impl Baked {
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

    /// Checks everything [`write_atomic`] checks before writing: the settings, every set
    /// (sizes, finite floats, ...), no BTF `(species, level)` twice, and that the data fits
    /// the format's limits.
    pub fn validate(&self) -> Result<(), FormatError> {
        self.validate_for(MAX_SECTION_BYTES)
    }

    /// [`Baked::validate`] with the section size limit as a parameter.
    fn validate_for(&self, section_limit: u64) -> Result<(), FormatError> {
        self.settings.validate()?;
        for (i, set) in self.btf.iter().enumerate() {
            if let Some(reason) = set.problem(set.direct.len() as u64, set.ambient.len() as u64) {
                return Err(FormatError::MalformedContent {
                    section: format!("btf set {i} (species {}, {:?})", set.species, set.level),
                    reason,
                });
            }
        }
        for (i, set) in self.vcm.iter().enumerate() {
            if let Some(reason) = set.problem(set.opacity.len() as u64) {
                return Err(FormatError::MalformedContent {
                    section: format!("vcm set {i} (owner {}, {:?})", set.owner, set.level),
                    reason,
                });
            }
        }
        for (i, t) in self.texels.iter().enumerate() {
            if let Some(reason) = t.problem(t.voxels.len() as u64) {
                return Err(FormatError::MalformedContent {
                    section: format!("texel volume {i} (species {})", t.species),
                    reason,
                });
            }
        }
        check_unique_btf(&self.btf)?;
        check_unique_texels(&self.texels)?;
        let plans = plan_sections(self, section_limit);
        if let Some(p) = plans.iter().find(|p| p.len > section_limit) {
            return Err(FormatError::AbsurdSize {
                field: format!("the size of {} record {}", p.kind.name(), p.first),
                value: p.len - SECTION_PREFIX_BYTES,
                limit: section_limit.saturating_sub(SECTION_PREFIX_BYTES),
            });
        }
        if plans.len() > MAX_SECTIONS as usize {
            return Err(FormatError::AbsurdSize {
                field: "section count".into(),
                value: plans.len() as u64,
                limit: u64::from(MAX_SECTIONS),
            });
        }
        Ok(())
    }
}

fn image_bytes(resolution: u32) -> Option<u64> {
    u64::from(resolution)
        .checked_mul(u64::from(resolution))?
        .checked_mul(4)
}

fn show_len(len: Option<u64>) -> String {
    len.map_or_else(|| "more than 2^64".to_owned(), |l| l.to_string())
}

/// The first record whose `key` was seen before, as malformed content (`what` names a
/// record; `of` what the repeated key means).
fn check_unique<T, K: std::hash::Hash + Eq>(
    records: &[T],
    key: impl Fn(&T) -> K,
    what: impl Fn(usize, &T) -> String,
    of: &str,
) -> Result<(), FormatError> {
    let mut seen = HashSet::with_capacity(records.len());
    for (i, r) in records.iter().enumerate() {
        if !seen.insert(key(r)) {
            return Err(FormatError::MalformedContent {
                section: what(i, r),
                reason: format!("{of} appears twice"),
            });
        }
    }
    Ok(())
}

fn check_unique_texels(volumes: &[TexelVolume]) -> Result<(), FormatError> {
    check_unique(
        volumes,
        |t| t.species,
        |i, t| format!("texel volume {i} (species {})", t.species),
        "a texel volume of this species",
    )
}

fn check_unique_btf(sets: &[BtfImageSet]) -> Result<(), FormatError> {
    check_unique(
        sets,
        |s| (s.species, s.level),
        |i, s| format!("btf set {i} (species {}, {:?})", s.species, s.level),
        "a btf set of this species and level",
    )
}

// ---------------------------------------------------------------------------------------
// Writing
// ---------------------------------------------------------------------------------------

/// One section the writer will emit: `count` records of `kind` starting at record `first`.
#[derive(Debug)]
struct PlannedSection {
    kind: SectionKind,
    first: usize,
    count: usize,
    /// Payload length in bytes.
    len: u64,
}

fn btf_record_len(set: &BtfImageSet) -> u64 {
    BTF_RECORD_FIXED_BYTES + set.direct.len() as u64 + set.ambient.len() as u64
}

fn vcm_record_len(set: &VcmSet) -> u64 {
    VCM_RECORD_FIXED_BYTES + set.opacity.len() as u64
}

fn texel_record_len(t: &TexelVolume) -> u64 {
    TEXEL_RECORD_FIXED_BYTES + t.voxels.len() as u64
}

/// Bytes of a BTF image-set record of these sizes.
pub fn btf_record_bytes(views: u32, lights: u32, resolution: u32) -> u64 {
    let image = u64::from(resolution).pow(2) * 4;
    let per_view = u64::from(lights) + u64::from(AMBIENT_IMAGES_PER_VIEW);
    BTF_RECORD_FIXED_BYTES + u64::from(views) * per_view * image
}

/// Bytes of a VCM set record (8 corners x 6 faces) of this face resolution.
pub fn vcm_record_bytes(resolution: u32) -> u64 {
    VCM_RECORD_FIXED_BYTES + 8 * 6 * u64::from(resolution).pow(2)
}

/// Bytes of a texel volume record with `lights` light volumes (and the sky's) of `dims`.
pub fn texel_record_bytes(lights: u32, dims: [u32; 3]) -> u64 {
    let voxels: u64 = dims.iter().map(|&d| u64::from(d)).product();
    TEXEL_RECORD_FIXED_BYTES + (u64::from(lights) + 1) * voxels * 4
}

/// The length of the file the writer makes of records of these sizes (each list in file
/// order: BTF sets, VCM sets, texel volumes), or `Err` with the size of a record too
/// large for any section ([`MAX_SECTION_BYTES`]).
pub fn file_bytes_for(btf: &[u64], vcm: &[u64], texel: &[u64]) -> Result<u64, u64> {
    if let Some(&big) = btf
        .iter()
        .chain(vcm)
        .chain(texel)
        .find(|&&s| s.saturating_add(SECTION_PREFIX_BYTES) > MAX_SECTION_BYTES)
    {
        return Err(big);
    }
    let mut plans = Vec::new();
    for (kind, sizes) in [
        (SectionKind::Btf, btf),
        (SectionKind::Vcm, vcm),
        (SectionKind::Texel, texel),
    ] {
        pack(kind, sizes.iter().copied(), MAX_SECTION_BYTES, &mut plans);
    }
    let payloads: u64 = plans.iter().map(|p| p.len).sum();
    Ok((FIXED_HEADER_BYTES + SECTION_ENTRY_BYTES * plans.len() + 4) as u64 + payloads)
}

/// Packs records into sections greedily, each at most `limit` bytes unless one record alone
/// is larger (which [`Baked::validate`] rejects).
fn plan_sections(baked: &Baked, limit: u64) -> Vec<PlannedSection> {
    let mut plans = Vec::new();
    pack(
        SectionKind::Btf,
        baked.btf.iter().map(btf_record_len),
        limit,
        &mut plans,
    );
    pack(
        SectionKind::Vcm,
        baked.vcm.iter().map(vcm_record_len),
        limit,
        &mut plans,
    );
    pack(
        SectionKind::Texel,
        baked.texels.iter().map(texel_record_len),
        limit,
        &mut plans,
    );
    plans
}

fn pack(
    kind: SectionKind,
    sizes: impl Iterator<Item = u64>,
    limit: u64,
    out: &mut Vec<PlannedSection>,
) {
    let mut current: Option<PlannedSection> = None;
    for (i, size) in sizes.enumerate() {
        match &mut current {
            Some(c) if c.len.saturating_add(size) <= limit && c.count < u32::MAX as usize => {
                c.count += 1;
                c.len += size;
            }
            _ => {
                out.extend(current.take());
                current = Some(PlannedSection {
                    kind,
                    first: i,
                    count: 1,
                    len: SECTION_PREFIX_BYTES.saturating_add(size),
                });
            }
        }
    }
    out.extend(current);
}

/// A `Write` that only computes a CRC-32 of what goes through it.
struct CrcWriter(crc32fast::Hasher);

impl Write for CrcWriter {
    fn write(&mut self, buf: &[u8]) -> io::Result<usize> {
        self.0.update(buf);
        Ok(buf.len())
    }

    fn flush(&mut self) -> io::Result<()> {
        Ok(())
    }
}

fn write_section_payload<W: Write>(
    w: &mut W,
    baked: &Baked,
    plan: &PlannedSection,
) -> io::Result<()> {
    // `pack` keeps count <= u32::MAX.
    w.write_all(&(plan.count as u32).to_le_bytes())?;
    let range = plan.first..plan.first + plan.count;
    match plan.kind {
        SectionKind::Btf => {
            for s in &baked.btf[range] {
                w.write_all(&s.species.to_le_bytes())?;
                w.write_all(&[level_tag(s.level), 0, 0, 0])?;
                w.write_all(&s.views.to_le_bytes())?;
                w.write_all(&s.lights.to_le_bytes())?;
                w.write_all(&s.resolution.to_le_bytes())?;
                for c in s.center {
                    w.write_all(&c.to_le_bytes())?;
                }
                w.write_all(&s.radius.to_le_bytes())?;
                w.write_all(&s.texel_size.to_le_bytes())?;
                w.write_all(&(s.direct.len() as u64).to_le_bytes())?;
                w.write_all(&s.direct)?;
                w.write_all(&(s.ambient.len() as u64).to_le_bytes())?;
                w.write_all(&s.ambient)?;
            }
        }
        SectionKind::Vcm => {
            for s in &baked.vcm[range] {
                w.write_all(&s.species.to_le_bytes())?;
                w.write_all(&s.owner.to_le_bytes())?;
                w.write_all(&[level_tag(s.level), 0, 0, 0])?;
                w.write_all(&s.resolution.to_le_bytes())?;
                for m in s.mean_opacity {
                    w.write_all(&m.to_le_bytes())?;
                }
                w.write_all(&(s.opacity.len() as u64).to_le_bytes())?;
                w.write_all(&s.opacity)?;
            }
        }
        SectionKind::Texel => {
            for t in &baked.texels[range] {
                w.write_all(&t.species.to_le_bytes())?;
                w.write_all(&t.lights.to_le_bytes())?;
                for d in t.dims {
                    w.write_all(&d.to_le_bytes())?;
                }
                for c in t.box_min {
                    w.write_all(&c.to_le_bytes())?;
                }
                w.write_all(&t.voxel.to_le_bytes())?;
                w.write_all(&(t.voxels.len() as u64).to_le_bytes())?;
                w.write_all(&t.voxels)?;
            }
        }
    }
    Ok(())
}

/// An encoding ready to be written: the header (checksums filled in) and the section plan.
struct Encoding<'a> {
    baked: &'a Baked,
    header: Vec<u8>,
    plans: Vec<PlannedSection>,
    file_size: u64,
}

impl<'a> Encoding<'a> {
    /// Plans the sections and computes every checksum (one pass over the data, no copy).
    fn new(baked: &'a Baked, section_limit: u64) -> Encoding<'a> {
        let plans = plan_sections(baked, section_limit);
        let header_len = FIXED_HEADER_BYTES + SECTION_ENTRY_BYTES * plans.len() + 4;
        let file_size = plans
            .iter()
            .fold(header_len as u64, |acc, p| acc.saturating_add(p.len));
        let s = &baked.settings;
        let mut header = Vec::with_capacity(header_len);
        header.extend_from_slice(&MAGIC);
        header.extend_from_slice(&VERSION.to_le_bytes());
        header.extend_from_slice(&(plans.len() as u32).to_le_bytes());
        header.extend_from_slice(&file_size.to_le_bytes());
        header.extend_from_slice(&baked.scene_hash.to_le_bytes());
        for v in [
            s.views,
            s.lights,
            s.resolution,
            s.supersample,
            s.vcm_resolution,
            s.texel_resolution,
            s.tree_views,
        ] {
            header.extend_from_slice(&v.to_le_bytes());
        }
        for plan in &plans {
            let mut crc = CrcWriter(crc32fast::Hasher::new());
            // Writing into a CrcWriter cannot fail.
            let _ = write_section_payload(&mut crc, baked, plan);
            header.extend_from_slice(&(plan.kind as u32).to_le_bytes());
            header.extend_from_slice(&crc.0.finalize().to_le_bytes());
            header.extend_from_slice(&plan.len.to_le_bytes());
        }
        let crc = crc32fast::hash(&header);
        header.extend_from_slice(&crc.to_le_bytes());
        Encoding {
            baked,
            header,
            plans,
            file_size,
        }
    }

    fn write_to<W: Write>(&self, w: &mut W) -> io::Result<()> {
        w.write_all(&self.header)?;
        for plan in &self.plans {
            write_section_payload(w, self.baked, plan)?;
        }
        Ok(())
    }

    fn into_bytes(self) -> Vec<u8> {
        let mut out = Vec::with_capacity(usize::try_from(self.file_size).unwrap_or(0));
        // Writing into a Vec cannot fail.
        let _ = self.write_to(&mut out);
        out
    }
}

/// Encodes `baked` as the bytes of a `.canopy` file. It encodes what it is given without
/// validating it (a file made from invalid data fails to read); [`write_atomic`] validates
/// first, and [`Baked::validate`] is there for callers of this function.
pub fn to_bytes(baked: &Baked) -> Vec<u8> {
    Encoding::new(baked, MAX_SECTION_BYTES).into_bytes()
}

/// Validates `baked` and writes it to `path` atomically: into a temporary file in the same
/// directory, fsynced, then renamed over `path`. On error `path` is untouched (the old file,
/// if any, stays) and the temporary file is removed.
pub fn write_atomic(path: impl AsRef<Path>, baked: &Baked) -> Result<(), FormatError> {
    write_atomic_with_hook(path.as_ref(), baked, MAX_SECTION_BYTES, |_| Ok(()))
}

static TEMP_COUNTER: AtomicU64 = AtomicU64::new(0);

/// The temporary file `write_atomic` writes before renaming it to `path`.
fn temp_path_for(path: &Path) -> Result<PathBuf, FormatError> {
    let Some(name) = path.file_name() else {
        return Err(FormatError::Io {
            path: path.to_owned(),
            action: "could not write",
            source: io::Error::new(io::ErrorKind::InvalidInput, "the path has no file name"),
        });
    };
    let dir = match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d,
        _ => Path::new("."),
    };
    let n = TEMP_COUNTER.fetch_add(1, Ordering::Relaxed);
    Ok(dir.join(format!(
        ".{}.tmp-{}-{n}",
        name.to_string_lossy(),
        std::process::id()
    )))
}

/// [`write_atomic`] with the section size limit as a parameter and a hook run on the
/// complete, synced temporary file just before the rename (tests use it to simulate a
/// crash).
fn write_atomic_with_hook(
    path: &Path,
    baked: &Baked,
    section_limit: u64,
    before_rename: impl FnOnce(&Path) -> io::Result<()>,
) -> Result<(), FormatError> {
    baked.validate_for(section_limit)?;
    let encoding = Encoding::new(baked, section_limit);
    let temp = temp_path_for(path)?;
    let io_error = |action| {
        move |source| FormatError::Io {
            path: path.to_owned(),
            action,
            source,
        }
    };
    let file = OpenOptions::new()
        .write(true)
        .create_new(true)
        .open(&temp)
        .map_err(io_error("could not create a temporary file next to"))?;
    let result = (|| {
        let mut writer = BufWriter::new(file);
        encoding
            .write_to(&mut writer)
            .map_err(io_error("could not write"))?;
        let file = writer
            .into_inner()
            .map_err(|e| io_error("could not write")(e.into_error()))?;
        file.sync_all().map_err(io_error("could not sync"))?;
        drop(file);
        before_rename(&temp).map_err(io_error("could not write"))?;
        fs::rename(&temp, path).map_err(io_error("could not replace"))
    })();
    if let Err(e) = result {
        let _ = fs::remove_file(&temp);
        return Err(e);
    }
    // Make the rename itself durable; best effort (not every filesystem allows it).
    #[cfg(unix)]
    if let Some(dir) = temp.parent()
        && let Ok(d) = File::open(dir)
    {
        let _ = d.sync_all();
    }
    Ok(())
}

// ---------------------------------------------------------------------------------------
// Reading
// ---------------------------------------------------------------------------------------

/// Reads and validates a `.canopy` file.
pub fn read(path: impl AsRef<Path>) -> Result<Baked, FormatError> {
    read_file(path.as_ref(), None)
}

/// Like [`read`], but fails with [`FormatError::SceneMismatch`] when the file was baked
/// for another scene hash (checked right after the header, before the data is read).
pub fn read_expecting(path: impl AsRef<Path>, scene_hash: u64) -> Result<Baked, FormatError> {
    read_file(path.as_ref(), Some(scene_hash))
}

/// Decodes and validates the bytes of a `.canopy` file.
pub fn from_bytes(bytes: &[u8]) -> Result<Baked, FormatError> {
    let mut input = Input {
        reader: bytes,
        pos: 0,
        len: bytes.len() as u64,
        path: Path::new("<memory>"),
    };
    decode(&mut input, None)
}

fn read_file(path: &Path, expected_hash: Option<u64>) -> Result<Baked, FormatError> {
    let io_error = |action| {
        move |source| FormatError::Io {
            path: path.to_owned(),
            action,
            source,
        }
    };
    let file = File::open(path).map_err(io_error("could not open"))?;
    let len = file.metadata().map_err(io_error("could not read"))?.len();
    let mut input = Input {
        reader: BufReader::new(file),
        pos: 0,
        len,
        path,
    };
    decode(&mut input, expected_hash)
}

/// A reader that knows how many bytes it has left.
struct Input<'p, R> {
    reader: R,
    pos: u64,
    len: u64,
    path: &'p Path,
}

impl<R: Read> Input<'_, R> {
    fn available(&self) -> u64 {
        self.len - self.pos
    }

    /// Fills `buf`, or fails with `Truncated` (checked before reading).
    fn fill(&mut self, buf: &mut [u8], what: &str) -> Result<(), FormatError> {
        let needed = buf.len() as u64;
        if needed > self.available() {
            return Err(FormatError::Truncated {
                what: what.to_owned(),
                needed,
                available: self.available(),
            });
        }
        self.reader
            .read_exact(buf)
            .map_err(|source| FormatError::Io {
                path: self.path.to_owned(),
                action: "could not read",
                source,
            })?;
        self.pos += needed;
        Ok(())
    }

    fn array<const N: usize>(&mut self, what: &str) -> Result<[u8; N], FormatError> {
        let mut a = [0; N];
        self.fill(&mut a, what)?;
        Ok(a)
    }
}

fn u32_at(bytes: &[u8], at: usize) -> u32 {
    let mut a = [0; 4];
    a.copy_from_slice(&bytes[at..at + 4]);
    u32::from_le_bytes(a)
}

fn u64_at(bytes: &[u8], at: usize) -> u64 {
    let mut a = [0; 8];
    a.copy_from_slice(&bytes[at..at + 8]);
    u64::from_le_bytes(a)
}

fn decode<R: Read>(
    input: &mut Input<'_, R>,
    expected_hash: Option<u64>,
) -> Result<Baked, FormatError> {
    // Magic: a short file that matches so far is truncated, anything else is not ours.
    let mut magic = [0u8; 8];
    let got = input.available().min(8) as usize;
    input.fill(&mut magic[..got], "the magic bytes")?;
    if magic[..got] != MAGIC[..got] {
        return Err(FormatError::NotCanopy {
            found: magic[..got].to_vec(),
        });
    }
    if got < MAGIC.len() {
        return Err(FormatError::Truncated {
            what: "the magic bytes".into(),
            needed: MAGIC.len() as u64,
            available: got as u64,
        });
    }
    let version_bytes = input.array::<4>("the format version")?;
    let version = u32::from_le_bytes(version_bytes);
    if version != VERSION {
        return Err(FormatError::UnsupportedVersion {
            found: version,
            supported: VERSION,
        });
    }

    // The rest of the fixed header; `rest` starts at file offset 12.
    let rest = input.array::<{ FIXED_HEADER_BYTES - 12 }>("the header")?;
    let section_count = u32_at(&rest, 0);
    if section_count > MAX_SECTIONS {
        return Err(FormatError::AbsurdSize {
            field: "section count".into(),
            value: section_count.into(),
            limit: MAX_SECTIONS.into(),
        });
    }
    let table_len = section_count as usize * SECTION_ENTRY_BYTES;
    if table_len as u64 + 4 > input.available() {
        return Err(FormatError::Truncated {
            what: format!("the section table ({section_count} entries) and header checksum"),
            needed: table_len as u64 + 4,
            available: input.available(),
        });
    }
    let mut table = vec![0u8; table_len];
    input.fill(&mut table, "the section table")?;
    let stored = u32::from_le_bytes(input.array::<4>("the header checksum")?);
    let mut hasher = crc32fast::Hasher::new();
    hasher.update(&magic);
    hasher.update(&version_bytes);
    hasher.update(&rest);
    hasher.update(&table);
    let computed = hasher.finalize();
    if stored != computed {
        return Err(FormatError::ChecksumMismatch {
            section: "header".into(),
            stored,
            computed,
        });
    }

    // The header is intact: check what it says.
    let header_len = input.pos;
    let file_size = u64_at(&rest, 4);
    if file_size > input.len {
        return Err(FormatError::Truncated {
            what: "the whole file (size from its header)".into(),
            needed: file_size,
            available: input.len,
        });
    }
    if file_size < input.len {
        return Err(FormatError::MalformedContent {
            section: "the file".into(),
            reason: format!(
                "{} unexpected bytes follow the declared end of the file ({file_size} bytes)",
                input.len - file_size
            ),
        });
    }
    let scene_hash = u64_at(&rest, 12);
    if let Some(expected) = expected_hash
        && expected != scene_hash
    {
        return Err(FormatError::SceneMismatch {
            found: scene_hash,
            expected,
        });
    }
    let settings = BakeSettings {
        views: u32_at(&rest, 20),
        lights: u32_at(&rest, 24),
        resolution: u32_at(&rest, 28),
        supersample: u32_at(&rest, 32),
        vcm_resolution: u32_at(&rest, 36),
        texel_resolution: u32_at(&rest, 40),
        tree_views: u32_at(&rest, 44),
    };
    settings.validate()?;

    let mut entries = Vec::with_capacity(section_count as usize);
    let mut total: u64 = 0;
    for (i, entry) in table.chunks_exact(SECTION_ENTRY_BYTES).enumerate() {
        let tag = u32_at(entry, 0);
        let crc = u32_at(entry, 4);
        let len = u64_at(entry, 8);
        let Some(kind) = SectionKind::from_u32(tag) else {
            return Err(FormatError::MalformedContent {
                section: format!("section {i}"),
                reason: format!("unknown section kind {tag} (known: 1 = btf, 2 = vcm, 3 = texel)"),
            });
        };
        if len > MAX_SECTION_BYTES {
            return Err(FormatError::AbsurdSize {
                field: format!("the length of section {i} ({})", kind.name()),
                value: len,
                limit: MAX_SECTION_BYTES,
            });
        }
        if len < SECTION_PREFIX_BYTES {
            return Err(FormatError::MalformedContent {
                section: format!("section {i} ({})", kind.name()),
                reason: format!("its length is {len}, too short for a record count"),
            });
        }
        // At most 4096 * 2^30: cannot overflow.
        total += len;
        entries.push((kind, crc, len));
    }
    if total != file_size - header_len {
        return Err(FormatError::MalformedContent {
            section: "the section table".into(),
            reason: format!(
                "the sections hold {total} bytes but the file has {} bytes after the header",
                file_size - header_len
            ),
        });
    }

    let mut baked = Baked {
        scene_hash,
        settings,
        btf: Vec::new(),
        vcm: Vec::new(),
        texels: Vec::new(),
    };
    for (i, &(kind, stored, len)) in entries.iter().enumerate() {
        let name = format!("section {i} ({})", kind.name());
        let mut section = Section {
            input: &mut *input,
            remaining: len,
            hasher: crc32fast::Hasher::new(),
            name: &name,
        };
        let mut result = match kind {
            SectionKind::Btf => decode_btf(&mut section, &mut baked.btf),
            SectionKind::Vcm => decode_vcm(&mut section, &mut baked.vcm),
            SectionKind::Texel => decode_texels(&mut section, &mut baked.texels),
        };
        if result.is_ok() && section.remaining != 0 {
            result = Err(section.malformed(format!(
                "{} bytes are left after the last record",
                section.remaining
            )));
        }
        match result {
            Ok(()) => {}
            // The content does not decode: unless it is corrupt, report that.
            Err(FormatError::MalformedContent { .. }) => section.drain()?,
            Err(e) => return Err(e),
        }
        let computed = section.hasher.finalize();
        if stored != computed {
            return Err(FormatError::ChecksumMismatch {
                section: name,
                stored,
                computed,
            });
        }
        result?;
    }
    check_unique_btf(&baked.btf)?;
    check_unique_texels(&baked.texels)?;
    Ok(baked)
}

/// The payload of one section: reads never go past its end, and everything read is hashed.
struct Section<'a, 'p, R> {
    input: &'a mut Input<'p, R>,
    remaining: u64,
    hasher: crc32fast::Hasher,
    name: &'a str,
}

impl<R: Read> Section<'_, '_, R> {
    fn malformed(&self, reason: String) -> FormatError {
        FormatError::MalformedContent {
            section: self.name.to_owned(),
            reason,
        }
    }

    fn fill(&mut self, buf: &mut [u8], what: &str) -> Result<(), FormatError> {
        let needed = buf.len() as u64;
        if needed > self.remaining {
            return Err(self.malformed(format!(
                "{what} needs {needed} bytes but the section has only {} left",
                self.remaining
            )));
        }
        self.input.fill(buf, self.name)?;
        self.hasher.update(buf);
        self.remaining -= needed;
        Ok(())
    }

    fn array<const N: usize>(&mut self, what: &str) -> Result<[u8; N], FormatError> {
        let mut a = [0; N];
        self.fill(&mut a, what)?;
        Ok(a)
    }

    fn u32(&mut self, what: &str) -> Result<u32, FormatError> {
        self.array(what).map(u32::from_le_bytes)
    }

    fn u64(&mut self, what: &str) -> Result<u64, FormatError> {
        self.array(what).map(u64::from_le_bytes)
    }

    fn f32(&mut self, what: &str) -> Result<f32, FormatError> {
        self.array(what).map(f32::from_le_bytes)
    }

    /// The level byte and the 3 reserved bytes after it.
    fn level(&mut self) -> Result<Level, FormatError> {
        let [tag, r0, r1, r2] = self.array("a level")?;
        if [r0, r1, r2] != [0; 3] {
            return Err(self.malformed(format!(
                "the reserved bytes after a level are {:?}, not zero",
                [r0, r1, r2]
            )));
        }
        level_from_tag(tag).ok_or_else(|| {
            self.malformed(format!(
                "level {tag} is not 0 (twig), 1 (branch) or 2 (tree)"
            ))
        })
    }

    /// A byte vector of `len` bytes, checked against the section before allocating.
    fn bytes(&mut self, len: u64, what: &str) -> Result<Vec<u8>, FormatError> {
        if len > self.remaining {
            return Err(self.malformed(format!(
                "{what} needs {len} bytes but the section has only {} left",
                self.remaining
            )));
        }
        // len <= remaining <= MAX_SECTION_BYTES, so it fits in usize.
        let mut v = vec![0; len as usize];
        self.fill(&mut v, what)?;
        Ok(v)
    }

    /// Reads a record count, checked against the smallest record size.
    fn record_count(&mut self, min_record: u64) -> Result<u32, FormatError> {
        let count = self.u32("the record count")?;
        if u64::from(count) > self.remaining / min_record {
            return Err(self.malformed(format!(
                "{count} records cannot fit in the {} bytes left",
                self.remaining
            )));
        }
        Ok(count)
    }

    /// Consumes (and hashes) the rest of the section.
    fn drain(&mut self) -> Result<(), FormatError> {
        let mut buf = [0u8; 8192];
        while self.remaining > 0 {
            let n = self.remaining.min(buf.len() as u64) as usize;
            self.fill(&mut buf[..n], "the rest of the section")?;
        }
        Ok(())
    }
}

fn decode_btf<R: Read>(
    s: &mut Section<'_, '_, R>,
    out: &mut Vec<BtfImageSet>,
) -> Result<(), FormatError> {
    let count = s.record_count(BTF_RECORD_FIXED_BYTES)?;
    for index in 0..count {
        let mut set = BtfImageSet {
            species: s.u32("species")?,
            level: s.level()?,
            views: s.u32("views")?,
            lights: s.u32("lights")?,
            resolution: s.u32("resolution")?,
            center: [s.f32("center")?, s.f32("center")?, s.f32("center")?],
            radius: s.f32("radius")?,
            texel_size: s.f32("texel_size")?,
            direct: Vec::new(),
            ambient: Vec::new(),
        };
        let direct_len = s.u64("direct length")?;
        // The ambient length comes after the direct images; check what is known so far.
        let ambient_len = set.expected_ambient_len().unwrap_or(0);
        if let Some(reason) = set.problem(direct_len, ambient_len) {
            return Err(s.malformed(format!(
                "btf record {index} (species {}, {:?}): {reason}",
                set.species, set.level
            )));
        }
        set.direct = s.bytes(direct_len, "the direct images")?;
        let ambient_len = s.u64("ambient length")?;
        // Everything else was checked above.
        let expected = set.expected_ambient_len();
        if expected != Some(ambient_len) {
            return Err(s.malformed(format!(
                "btf record {index} (species {}, {:?}): ambient holds {ambient_len} bytes, \
                 expected {}",
                set.species,
                set.level,
                show_len(expected)
            )));
        }
        set.ambient = s.bytes(ambient_len, "the ambient images")?;
        out.push(set);
    }
    Ok(())
}

fn decode_vcm<R: Read>(
    s: &mut Section<'_, '_, R>,
    out: &mut Vec<VcmSet>,
) -> Result<(), FormatError> {
    let count = s.record_count(VCM_RECORD_FIXED_BYTES)?;
    for index in 0..count {
        let mut set = VcmSet {
            species: s.u32("species")?,
            owner: s.u32("owner")?,
            level: s.level()?,
            resolution: s.u32("resolution")?,
            opacity: Vec::new(),
            mean_opacity: [0.0; 8],
        };
        for m in &mut set.mean_opacity {
            *m = s.f32("mean_opacity")?;
        }
        let opacity_len = s.u64("opacity length")?;
        if let Some(reason) = set.problem(opacity_len) {
            return Err(s.malformed(format!(
                "vcm record {index} (owner {}, {:?}): {reason}",
                set.owner, set.level
            )));
        }
        set.opacity = s.bytes(opacity_len, "the opacity maps")?;
        out.push(set);
    }
    Ok(())
}

fn decode_texels<R: Read>(
    s: &mut Section<'_, '_, R>,
    out: &mut Vec<TexelVolume>,
) -> Result<(), FormatError> {
    let count = s.record_count(TEXEL_RECORD_FIXED_BYTES)?;
    for index in 0..count {
        let mut t = TexelVolume {
            species: s.u32("species")?,
            lights: s.u32("lights")?,
            dims: [s.u32("dims")?, s.u32("dims")?, s.u32("dims")?],
            box_min: [s.f32("box_min")?, s.f32("box_min")?, s.f32("box_min")?],
            voxel: s.f32("voxel")?,
            voxels: Vec::new(),
        };
        let len = s.u64("voxels length")?;
        if let Some(reason) = t.problem(len) {
            return Err(s.malformed(format!(
                "texel record {index} (species {}): {reason}",
                t.species
            )));
        }
        t.voxels = s.bytes(len, "the voxels")?;
        out.push(t);
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Counts the bytes allocated by the current thread while a closure runs, so tests can
    /// check that decoding never allocates from an unchecked size. Thread-local, so tests
    /// running in parallel do not disturb each other.
    mod alloc_track {
        use std::alloc::{GlobalAlloc, Layout, System};
        use std::cell::Cell;

        thread_local! {
            static ON: Cell<bool> = const { Cell::new(false) };
            static LIVE: Cell<isize> = const { Cell::new(0) };
            static PEAK: Cell<isize> = const { Cell::new(0) };
        }

        fn note(delta: isize) {
            let _ = ON.try_with(|on| {
                if on.get() {
                    let live = LIVE.get() + delta;
                    LIVE.set(live);
                    PEAK.set(PEAK.get().max(live));
                }
            });
        }

        pub struct Tracker;

        // SAFETY: forwards every call to `System` unchanged; only counts sizes.
        unsafe impl GlobalAlloc for Tracker {
            unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
                let p = unsafe { System.alloc(layout) };
                if !p.is_null() {
                    note(layout.size() as isize);
                }
                p
            }

            unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
                let p = unsafe { System.alloc_zeroed(layout) };
                if !p.is_null() {
                    note(layout.size() as isize);
                }
                p
            }

            unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
                unsafe { System.dealloc(ptr, layout) };
                note(-(layout.size() as isize));
            }

            unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
                let p = unsafe { System.realloc(ptr, layout, new_size) };
                if !p.is_null() {
                    note(new_size as isize - layout.size() as isize);
                }
                p
            }
        }

        /// Runs `f` and returns its result and the most bytes it held allocated at once.
        pub fn peak_during<T>(f: impl FnOnce() -> T) -> (T, usize) {
            LIVE.set(0);
            PEAK.set(0);
            ON.set(true);
            let out = f();
            ON.set(false);
            (out, PEAK.get().max(0) as usize)
        }
    }

    #[global_allocator]
    static TRACKER: alloc_track::Tracker = alloc_track::Tracker;
    use alloc_track::peak_during;

    /// Allowance for error messages, the section table and the like.
    const SMALL_OVERHEAD: usize = 64 * 1024;

    fn noise(seed: u32, len: usize) -> Vec<u8> {
        let mut x = seed.wrapping_mul(2_654_435_761).wrapping_add(12_345);
        (0..len)
            .map(|_| {
                x ^= x << 13;
                x ^= x >> 17;
                x ^= x << 5;
                (x >> 24) as u8
            })
            .collect()
    }

    fn settings() -> BakeSettings {
        BakeSettings {
            views: 6,
            tree_views: 6,
            lights: 6,
            resolution: 32,
            supersample: 2,
            vcm_resolution: 8,
            texel_resolution: 16,
        }
    }

    fn texel_volume(species: u32, dims: [u32; 3]) -> TexelVolume {
        let len = 7 * dims.iter().product::<u32>() as usize * 4;
        TexelVolume {
            species,
            lights: 6,
            dims,
            box_min: [-1.5, 0.0, -1.5],
            voxel: 0.25,
            voxels: noise(species + 200, len),
        }
    }

    #[test]
    fn level_tags_are_the_documented_bytes() {
        for (tag, level) in [(0, Level::Twig), (1, Level::Branch), (2, Level::Tree)] {
            assert_eq!(level_tag(level), tag);
            assert_eq!(level_from_tag(tag), Some(level));
        }
        assert_eq!(level_from_tag(3), None);
    }

    fn btf_set(species: u32, level: Level) -> BtfImageSet {
        let (views, lights, res) = (6u32, 6u32, 32u32);
        let image = (res * res * 4) as usize;
        BtfImageSet {
            species,
            level,
            views,
            lights,
            resolution: res,
            center: [0.5, -1.25, 3.0],
            radius: 2.5 + species as f32,
            texel_size: 0.01,
            direct: noise(species * 7 + 1, image * (views * lights) as usize),
            ambient: noise(
                species * 7 + 2,
                image * (views * AMBIENT_IMAGES_PER_VIEW) as usize,
            ),
        }
    }

    fn vcm_set(owner: u32, level: Level, resolution: u32) -> VcmSet {
        VcmSet {
            species: 0,
            owner,
            level,
            resolution,
            opacity: noise(owner + 100, 48 * (resolution * resolution) as usize),
            mean_opacity: [0.0, 0.125, 0.25, 0.375, 0.5, 0.625, 0.75, 1.0],
        }
    }

    /// Two BTF sets and two VCM sets (about 350 KB).
    fn sample() -> Baked {
        Baked {
            scene_hash: 0x0123_4567_89ab_cdef,
            settings: settings(),
            btf: vec![btf_set(0, Level::Twig), btf_set(1, Level::Tree)],
            vcm: vec![vcm_set(0, Level::Twig, 8), vcm_set(7, Level::Branch, 16)],
            texels: vec![texel_volume(0, [8, 16, 8])],
        }
    }

    #[test]
    fn the_file_size_is_known_from_the_record_sizes_alone() {
        for b in [sample(), small()] {
            let btf: Vec<u64> = b
                .btf
                .iter()
                .map(|s| btf_record_bytes(s.views, s.lights, s.resolution))
                .collect();
            let vcm: Vec<u64> = b
                .vcm
                .iter()
                .map(|s| vcm_record_bytes(s.resolution))
                .collect();
            let texel: Vec<u64> = b
                .texels
                .iter()
                .map(|t| texel_record_bytes(t.lights, t.dims))
                .collect();
            assert_eq!(
                file_bytes_for(&btf, &vcm, &texel),
                Ok(to_bytes(&b).len() as u64)
            );
        }
        // 258 views x 258 lights at 128² is one 4.4 GB record: no section holds it.
        let huge = btf_record_bytes(258, 258, 128);
        assert_eq!(file_bytes_for(&[huge], &[], &[]), Err(huge));
    }

    /// A few KB: two small VCM sets, no BTF.
    fn small() -> Baked {
        Baked {
            scene_hash: 42,
            settings: settings(),
            btf: Vec::new(),
            vcm: vec![vcm_set(3, Level::Twig, 8), vcm_set(4, Level::Tree, 8)],
            texels: vec![texel_volume(1, [2, 3, 2])],
        }
    }

    fn section_count(bytes: &[u8]) -> usize {
        u32_at(bytes, 12) as usize
    }

    fn header_end(bytes: &[u8]) -> usize {
        FIXED_HEADER_BYTES + SECTION_ENTRY_BYTES * section_count(bytes)
    }

    /// Recomputes the header checksum only.
    fn reseal_header(bytes: &mut [u8]) {
        let end = header_end(bytes);
        let crc = crc32fast::hash(&bytes[..end]);
        bytes[end..end + 4].copy_from_slice(&crc.to_le_bytes());
    }

    /// Recomputes every section checksum and the header checksum (sections must lie inside
    /// the bytes).
    fn reseal(bytes: &mut [u8]) {
        let mut pos = header_end(bytes) + 4;
        for i in 0..section_count(bytes) {
            let entry = FIXED_HEADER_BYTES + SECTION_ENTRY_BYTES * i;
            let len = u64_at(bytes, entry + 8) as usize;
            let crc = crc32fast::hash(&bytes[pos..pos + len]);
            bytes[entry + 4..entry + 8].copy_from_slice(&crc.to_le_bytes());
            pos += len;
        }
        reseal_header(bytes);
    }

    /// Offset of the first payload byte of section `i`.
    fn payload_start(bytes: &[u8], i: usize) -> usize {
        let mut pos = header_end(bytes) + 4;
        for j in 0..i {
            pos += u64_at(bytes, FIXED_HEADER_BYTES + SECTION_ENTRY_BYTES * j + 8) as usize;
        }
        pos
    }

    fn scratch_dir(name: &str) -> PathBuf {
        static N: AtomicU64 = AtomicU64::new(0);
        let dir = std::env::temp_dir().join(format!(
            "canopy-format-test-{}-{name}-{}",
            std::process::id(),
            N.fetch_add(1, Ordering::Relaxed)
        ));
        let _ = fs::remove_dir_all(&dir);
        fs::create_dir_all(&dir).unwrap();
        dir
    }

    fn dir_entries(dir: &Path) -> Vec<String> {
        let mut names: Vec<String> = fs::read_dir(dir)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        names.sort();
        names
    }

    #[test]
    fn round_trip_through_bytes() {
        let baked = sample();
        baked.validate().unwrap();
        let bytes = to_bytes(&baked);
        assert_eq!(bytes[..8], MAGIC);
        assert_eq!(u32_at(&bytes, 8), VERSION);
        assert_eq!(u64_at(&bytes, 16), bytes.len() as u64);
        assert_eq!(
            bytes.len() as u64,
            64 + 3 * 16
                + 3 * 4
                + 2 * 56
                + 2 * 56
                + 44
                + baked.btf_bytes()
                + baked.vcm_bytes()
                + baked.texel_bytes()
        );
        assert_eq!(to_bytes(&baked), bytes, "encoding is deterministic");
        let (back, peak) = peak_during(|| from_bytes(&bytes).unwrap());
        assert!(back == baked, "decoded data differs from what was encoded");
        assert!(
            peak <= bytes.len() + SMALL_OVERHEAD,
            "decoding {} bytes held {peak} bytes",
            bytes.len()
        );
    }

    #[test]
    fn empty_bake_round_trips() {
        let baked = Baked {
            scene_hash: 7,
            settings: settings(),
            btf: Vec::new(),
            vcm: Vec::new(),
            texels: Vec::new(),
        };
        let bytes = to_bytes(&baked);
        assert_eq!(bytes.len(), 64);
        assert_eq!(from_bytes(&bytes).unwrap(), baked);
    }

    #[test]
    fn records_split_over_several_sections_round_trip() {
        let baked = sample();
        // A limit that fits one BTF record per section and both VCM records in one.
        let limit = btf_record_len(&baked.btf[0]) + 4;
        let plans = plan_sections(&baked, limit);
        let kinds: Vec<_> = plans.iter().map(|p| (p.kind, p.count)).collect();
        assert_eq!(
            kinds,
            [
                (SectionKind::Btf, 1),
                (SectionKind::Btf, 1),
                (SectionKind::Vcm, 2),
                (SectionKind::Texel, 1)
            ]
        );
        let bytes = Encoding::new(&baked, limit).into_bytes();
        assert_eq!(section_count(&bytes), 4);
        assert!(from_bytes(&bytes).unwrap() == baked);

        // Sections of both kinds in any order decode too: put VCM first.
        let vcm_first = Baked {
            btf: Vec::new(),
            ..baked.clone()
        };
        let vcm_bytes = to_bytes(&vcm_first);
        assert_eq!(from_bytes(&vcm_bytes).unwrap(), vcm_first);
    }

    #[test]
    fn round_trip_through_a_file() {
        let dir = scratch_dir("roundtrip");
        let path = dir.join("forest.canopy");
        let baked = sample();
        write_atomic(&path, &baked).unwrap();
        assert_eq!(dir_entries(&dir), ["forest.canopy"], "no temp file left");
        let (back, peak) = peak_during(|| read(&path).unwrap());
        assert!(back == baked);
        let len = fs::metadata(&path).unwrap().len() as usize;
        assert!(
            peak <= len + SMALL_OVERHEAD,
            "reading {len} bytes held {peak}"
        );
        assert!(read_expecting(&path, baked.scene_hash).unwrap() == baked);

        // Overwriting an existing file works and leaves only the new one.
        let mut other = small();
        other.scene_hash = 99;
        write_atomic(&path, &other).unwrap();
        assert_eq!(read(&path).unwrap(), other);
        assert_eq!(dir_entries(&dir), ["forest.canopy"]);
        fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn flipped_payload_byte_is_a_checksum_mismatch() {
        let mut bytes = to_bytes(&sample());
        // In the middle of the first BTF set's direct images.
        let at = payload_start(&bytes, 0) + 4 + 48 + 1000;
        bytes[at] ^= 0x10;
        match from_bytes(&bytes) {
            Err(FormatError::ChecksumMismatch { section, .. }) => {
                assert_eq!(section, "section 0 (btf image sets)")
            }
            other => panic!("expected a checksum mismatch, got {other:?}"),
        }
        // And in the VCM section, inside a length field (the decode fails, the checksum
        // is still what is reported).
        let mut bytes = to_bytes(&sample());
        let at = payload_start(&bytes, 1) + 4 + 44 + 2;
        bytes[at] ^= 0x01;
        assert!(matches!(
            from_bytes(&bytes),
            Err(FormatError::ChecksumMismatch { section, .. }) if section == "section 1 (vcm sets)"
        ));
    }

    #[test]
    fn flipped_header_byte_is_a_checksum_mismatch() {
        let clean = to_bytes(&sample());
        // scene hash, settings, a section crc, a section length, the header crc itself
        for at in [24, 33, 48, 57, 60 + 5, 60 + 16 + 8, header_end(&clean) + 1] {
            let mut bytes = clean.clone();
            bytes[at] ^= 0x01;
            match from_bytes(&bytes) {
                Err(FormatError::ChecksumMismatch { section, .. }) => {
                    assert_eq!(section, "header", "byte {at}")
                }
                other => panic!("byte {at}: expected a header checksum mismatch, got {other:?}"),
            }
        }
    }

    #[test]
    fn every_flipped_byte_of_a_small_file_is_detected() {
        let clean = to_bytes(&small());
        let header_end = header_end(&clean) + 4;
        for at in 0..clean.len() {
            for mask in [0x01, 0x80] {
                let mut bytes = clean.clone();
                bytes[at] ^= mask;
                let (result, peak) = peak_during(|| from_bytes(&bytes));
                assert!(peak <= bytes.len() + SMALL_OVERHEAD);
                let ok = match (&result, at) {
                    (Err(FormatError::NotCanopy { .. }), 0..8) => true,
                    (Err(FormatError::UnsupportedVersion { .. }), 8..12) => true,
                    (
                        Err(
                            FormatError::AbsurdSize { .. }
                            | FormatError::Truncated { .. }
                            | FormatError::ChecksumMismatch { .. },
                        ),
                        12..16,
                    ) => true,
                    (Err(FormatError::ChecksumMismatch { section, .. }), _) if at < header_end => {
                        section == "header"
                    }
                    (Err(FormatError::ChecksumMismatch { section, .. }), _) => {
                        section.starts_with("section ")
                    }
                    _ => false,
                };
                assert!(ok, "byte {at} ^ {mask:#x}: {result:?}");
            }
        }
    }

    #[test]
    fn every_truncation_is_an_error() {
        for bytes in [to_bytes(&small()), to_bytes(&sample())] {
            for len in 0..bytes.len() {
                let prefix = &bytes[..len];
                let (result, peak) = peak_during(|| from_bytes(prefix));
                assert!(
                    matches!(result, Err(FormatError::Truncated { .. })),
                    "prefix of {len} bytes: {result:?}"
                );
                assert!(peak <= len + SMALL_OVERHEAD, "prefix of {len}: held {peak}");
            }
            assert!(from_bytes(&bytes).is_ok());
        }
    }

    /// Truncations whose header, lengths and checksums were all made consistent again, so
    /// only the record decoding can notice.
    #[test]
    fn truncation_with_a_consistent_header_is_an_error() {
        let bytes = to_bytes(&small());
        let head = header_end(&bytes) + 4;
        for len in head..bytes.len() {
            let mut cut = bytes[..len].to_vec();
            cut[16..24].copy_from_slice(&(len as u64).to_le_bytes());
            let mut left = (len - head) as u64;
            for i in 0..section_count(&cut) {
                let at = FIXED_HEADER_BYTES + SECTION_ENTRY_BYTES * i + 8;
                let section_len = u64_at(&cut, at).min(left);
                cut[at..at + 8].copy_from_slice(&section_len.to_le_bytes());
                left -= section_len;
            }
            reseal(&mut cut);
            let (result, peak) = peak_during(|| from_bytes(&cut));
            assert!(
                matches!(result, Err(FormatError::MalformedContent { .. })),
                "cut at {len}: {result:?}"
            );
            assert!(peak <= len + SMALL_OVERHEAD);
        }
    }

    #[test]
    fn wrong_magic_is_not_a_canopy_file() {
        let mut bytes = to_bytes(&small());
        bytes[0] = b'X';
        assert!(matches!(
            from_bytes(&bytes),
            Err(FormatError::NotCanopy { .. })
        ));
        assert!(matches!(
            from_bytes(b"PNG\x89 not at all"),
            Err(FormatError::NotCanopy { found }) if found == b"PNG\x89 not"
        ));
        // Line endings converted CRLF -> LF in transfer.
        let clean = to_bytes(&small());
        let mangled: Vec<u8> = clean[..6].iter().chain(&clean[7..]).copied().collect();
        let err = from_bytes(&mangled).unwrap_err();
        assert!(matches!(err, FormatError::NotCanopy { .. }), "{err:?}");
        assert!(err.to_string().contains("canopy bake"), "{err}");
        // A short file that is not ours is "not a canopy file", not "truncated".
        assert!(matches!(
            from_bytes(b"{}"),
            Err(FormatError::NotCanopy { .. })
        ));
    }

    #[test]
    fn wrong_version_is_unsupported() {
        for version in [0u32, 1, 2, 3, 4, 6, u32::MAX] {
            let mut bytes = to_bytes(&small());
            bytes[8..12].copy_from_slice(&version.to_le_bytes());
            reseal_header(&mut bytes);
            match from_bytes(&bytes) {
                Err(FormatError::UnsupportedVersion { found, supported }) => {
                    assert_eq!((found, supported), (version, VERSION))
                }
                other => panic!("version {version}: {other:?}"),
            }
        }
    }

    #[test]
    fn absurd_section_length_is_rejected_before_allocating() {
        let mut bytes = to_bytes(&sample());
        let at = FIXED_HEADER_BYTES + 8; // length of section 0
        bytes[at..at + 8].copy_from_slice(&0xFFFF_FFFF_FFFFu64.to_le_bytes());
        reseal_header(&mut bytes);
        let (result, peak) = peak_during(|| from_bytes(&bytes));
        match result {
            Err(FormatError::AbsurdSize {
                field,
                value,
                limit,
            }) => {
                assert!(field.contains("section 0"), "{field}");
                assert_eq!((value, limit), (0xFFFF_FFFF_FFFF, MAX_SECTION_BYTES));
            }
            other => panic!("expected an absurd size, got {other:?}"),
        }
        assert!(peak < SMALL_OVERHEAD, "held {peak} bytes");
    }

    #[test]
    fn absurd_section_count_is_rejected_before_allocating() {
        let mut bytes = to_bytes(&small());
        bytes[12..16].copy_from_slice(&u32::MAX.to_le_bytes());
        let (result, peak) = peak_during(|| from_bytes(&bytes));
        assert!(
            matches!(result, Err(FormatError::AbsurdSize { value, .. }) if value == u32::MAX as u64),
            "{result:?}"
        );
        assert!(peak < SMALL_OVERHEAD, "held {peak} bytes");
    }

    #[test]
    fn the_allocation_tracker_sees_allocations() {
        let (v, peak) = peak_during(|| vec![1u8; 10_000_000]);
        assert!(peak >= 10_000_000, "{peak}");
        drop(v);
        let ((), peak) = peak_during(|| ());
        assert_eq!(peak, 0);
    }

    #[test]
    fn a_record_claiming_huge_images_is_malformed_without_allocating() {
        // 258 views x 258 lights at 128²: a consistent 4.4 GB claim in a 350 KB file.
        let mut bytes = to_bytes(&sample());
        let record = payload_start(&bytes, 0) + 4;
        let direct_len: u64 = 258 * 258 * 128 * 128 * 4;
        bytes[record + 8..record + 12].copy_from_slice(&258u32.to_le_bytes());
        bytes[record + 12..record + 16].copy_from_slice(&258u32.to_le_bytes());
        bytes[record + 16..record + 20].copy_from_slice(&128u32.to_le_bytes());
        bytes[record + 40..record + 48].copy_from_slice(&direct_len.to_le_bytes());
        reseal(&mut bytes);
        let (result, peak) = peak_during(|| from_bytes(&bytes));
        assert!(
            matches!(&result, Err(FormatError::MalformedContent { reason, .. })
                if reason.contains(&direct_len.to_string())),
            "{result:?}"
        );
        assert!(peak < SMALL_OVERHEAD, "held {peak} bytes");
    }

    #[test]
    fn absurd_record_count_is_malformed_without_allocating() {
        let mut bytes = to_bytes(&small());
        let at = payload_start(&bytes, 0);
        bytes[at..at + 4].copy_from_slice(&u32::MAX.to_le_bytes());
        reseal(&mut bytes);
        let (result, peak) = peak_during(|| from_bytes(&bytes));
        assert!(
            matches!(&result, Err(FormatError::MalformedContent { reason, .. }) if reason.contains("records cannot fit")),
            "{result:?}"
        );
        assert!(peak < SMALL_OVERHEAD);
    }

    #[test]
    fn inconsistent_payload_with_valid_checksums_is_malformed() {
        // direct one byte short: to_bytes writes it faithfully, with correct checksums.
        let mut baked = sample();
        baked.btf[1].direct.pop();
        assert!(matches!(
            baked.validate(),
            Err(FormatError::MalformedContent { .. })
        ));
        let bytes = to_bytes(&baked);
        match from_bytes(&bytes) {
            Err(FormatError::MalformedContent { section, reason }) => {
                assert_eq!(section, "section 0 (btf image sets)");
                assert!(reason.contains("direct"), "{reason}");
            }
            other => panic!("expected malformed content, got {other:?}"),
        }

        // Ambient of the wrong size, radius not positive, texel size NaN, VCM too short,
        // mean opacity out of range: each caught on write and on read.
        // Texel volumes: voxels one byte short, a zero or huge dimension, a NaN corner, a
        // negative voxel, a light count that is no direction set.
        let breakers: [fn(&mut Baked); 11] = [
            |b| b.texels[0].voxels.pop().map_or((), drop),
            |b| b.texels[0].dims[1] = 0,
            |b| b.texels[0].dims[2] = 100_000,
            |b| b.texels[0].box_min[0] = f32::NAN,
            |b| b.texels[0].voxel = -0.25,
            |b| b.texels[0].lights = 5,
            |b| b.btf[0].ambient.extend([0; 4]),
            |b| b.btf[0].radius = 0.0,
            |b| b.btf[1].texel_size = f32::NAN,
            |b| b.vcm[1].opacity.truncate(10),
            |b| b.vcm[0].mean_opacity[3] = 1.5,
        ];
        for (i, breaker) in breakers.iter().enumerate() {
            let mut baked = sample();
            breaker(&mut baked);
            assert!(
                matches!(baked.validate(), Err(FormatError::MalformedContent { .. })),
                "breaker {i} on write"
            );
            let result = from_bytes(&to_bytes(&baked));
            assert!(
                matches!(result, Err(FormatError::MalformedContent { .. })),
                "breaker {i} on read: {result:?}"
            );
        }

        // A level byte that names no level, checksums recomputed.
        let mut bytes = to_bytes(&small());
        let at = payload_start(&bytes, 0) + 4 + 8; // record count, species, owner
        bytes[at] = 3;
        reseal(&mut bytes);
        assert!(matches!(
            from_bytes(&bytes),
            Err(FormatError::MalformedContent { reason, .. }) if reason.contains("level 3")
        ));

        // A record count lower than the records present: bytes left over in the section.
        let mut bytes = to_bytes(&small());
        let at = payload_start(&bytes, 0);
        bytes[at..at + 4].copy_from_slice(&1u32.to_le_bytes());
        reseal(&mut bytes);
        assert!(matches!(
            from_bytes(&bytes),
            Err(FormatError::MalformedContent { reason, .. }) if reason.contains("left after the last record")
        ));

        // The same species' texel volume twice.
        let mut baked = sample();
        baked.texels.push(baked.texels[0].clone());
        assert!(baked.validate().is_err());
        assert!(matches!(
            from_bytes(&to_bytes(&baked)),
            Err(FormatError::MalformedContent { reason, .. }) if reason.contains("twice")
        ));

        // The same BTF set twice.
        let mut baked = sample();
        baked.btf[1] = baked.btf[0].clone();
        assert!(baked.validate().is_err());
        assert!(matches!(
            from_bytes(&to_bytes(&baked)),
            Err(FormatError::MalformedContent { reason, .. }) if reason.contains("twice")
        ));
    }

    #[test]
    fn trailing_bytes_are_malformed() {
        let mut bytes = to_bytes(&small());
        bytes.extend_from_slice(b"junk");
        assert!(matches!(
            from_bytes(&bytes),
            Err(FormatError::MalformedContent { .. })
        ));
    }

    #[test]
    fn invalid_settings_are_rejected_on_write_and_read() {
        let dir = scratch_dir("settings");
        let path = dir.join("bad.canopy");
        type Change = fn(&mut BakeSettings);
        let cases: [(Change, &str); 8] = [
            (|s| s.views = 7, "views"),
            (|s| s.lights = 0, "lights"),
            (|s| s.resolution = 256, "resolution"),
            (|s| s.supersample = 0, "supersample"),
            (|s| s.supersample = 9, "supersample"),
            (|s| s.vcm_resolution = 4, "vcm_resolution"),
            (|s| s.texel_resolution = 8, "texel_resolution"),
            (|s| s.texel_resolution = 512, "texel_resolution"),
        ];
        for (change, name) in cases {
            let mut baked = small();
            change(&mut baked.settings);
            let err = write_atomic(&path, &baked).unwrap_err();
            assert!(
                matches!(err, FormatError::InvalidSettings { field, .. } if field == name),
                "{err:?}"
            );
            assert!(dir_entries(&dir).is_empty(), "nothing written");
            let err = from_bytes(&to_bytes(&baked)).unwrap_err();
            assert!(
                matches!(err, FormatError::InvalidSettings { field, .. } if field == name),
                "{err:?}"
            );
        }
        for good in DIRECTION_COUNTS {
            let mut s = settings();
            s.views = good;
            s.lights = good;
            s.validate().unwrap();
        }
        fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn read_expecting_another_hash_is_a_scene_mismatch() {
        let dir = scratch_dir("mismatch");
        let path = dir.join("a.canopy");
        let baked = small();
        write_atomic(&path, &baked).unwrap();
        let err = read_expecting(&path, baked.scene_hash ^ 1).unwrap_err();
        match &err {
            FormatError::SceneMismatch { found, expected } => {
                assert_eq!(
                    (*found, *expected),
                    (baked.scene_hash, baked.scene_hash ^ 1)
                )
            }
            other => panic!("expected a scene mismatch, got {other:?}"),
        }
        assert!(err.needs_rebake());
        assert!(err.to_string().contains("canopy bake"));
        fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn reading_a_missing_file_is_an_io_error_naming_it() {
        let dir = scratch_dir("missing");
        let path = dir.join("absent.canopy");
        let err = read(&path).unwrap_err();
        assert!(err.is_not_found(), "{err:?}");
        assert!(!err.needs_rebake());
        assert!(err.to_string().contains(&*path.to_string_lossy()), "{err}");
        fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn write_into_a_missing_directory_is_an_io_error_naming_the_path() {
        let dir = scratch_dir("nodir");
        let path = dir.join("no-such-dir").join("out.canopy");
        let err = write_atomic(&path, &small()).unwrap_err();
        match &err {
            FormatError::Io { path: p, .. } => assert_eq!(p, &path),
            other => panic!("expected an I/O error, got {other:?}"),
        }
        assert!(err.to_string().contains(&*path.to_string_lossy()), "{err}");
        assert!(dir_entries(&dir).is_empty(), "no temp file left");
        fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn write_under_a_regular_file_is_an_io_error_naming_the_path() {
        let dir = scratch_dir("underfile");
        let file = dir.join("plain.txt");
        fs::write(&file, b"hello").unwrap();
        let path = file.join("out.canopy");
        let err = write_atomic(&path, &small()).unwrap_err();
        assert!(
            matches!(&err, FormatError::Io { path: p, .. } if p == &path),
            "{err:?}"
        );
        assert!(err.to_string().contains(&*path.to_string_lossy()), "{err}");
        assert_eq!(dir_entries(&dir), ["plain.txt"]);
        assert_eq!(fs::read(&file).unwrap(), b"hello");
        fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn write_onto_a_directory_fails_and_cleans_up() {
        let dir = scratch_dir("ontodir");
        let target = dir.join("taken");
        fs::create_dir(&target).unwrap();
        let err = write_atomic(&target, &small()).unwrap_err();
        assert!(
            matches!(&err, FormatError::Io { path, .. } if path == &target),
            "{err:?}"
        );
        assert_eq!(dir_entries(&dir), ["taken"], "temp file removed");
        fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn interrupted_write_leaves_the_old_file_intact() {
        let dir = scratch_dir("interrupted");
        let path = dir.join("forest.canopy");
        let old = small();
        write_atomic(&path, &old).unwrap();
        let old_bytes = fs::read(&path).unwrap();

        let new = sample();
        let mut seen_temp = None;
        let err = write_atomic_with_hook(&path, &new, MAX_SECTION_BYTES, |temp| {
            // The complete new file sits next to the target, under another name.
            assert_eq!(temp.parent(), Some(dir.as_path()));
            assert_ne!(temp, path);
            assert!(from_bytes(&fs::read(temp)?).unwrap() == new);
            seen_temp = Some(temp.to_owned());
            Err(io::Error::other("simulated crash before rename"))
        })
        .unwrap_err();
        assert!(matches!(err, FormatError::Io { .. }), "{err:?}");
        let temp = seen_temp.expect("the hook ran");
        assert!(!temp.exists(), "temp file removed");
        assert_eq!(fs::read(&path).unwrap(), old_bytes, "old file untouched");
        assert_eq!(read(&path).unwrap(), old);
        assert_eq!(dir_entries(&dir), ["forest.canopy"]);

        // A crash that leaves the temp behind (no cleanup) still leaves the target intact.
        let stray = dir.join(".forest.canopy.tmp-crashed");
        fs::write(&stray, &to_bytes(&new)[..100]).unwrap();
        assert_eq!(read(&path).unwrap(), old);
        fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn temp_files_are_hidden_siblings_with_unique_names() {
        let a = temp_path_for(Path::new("/x/y/forest.canopy")).unwrap();
        let b = temp_path_for(Path::new("/x/y/forest.canopy")).unwrap();
        assert_eq!(a.parent(), Some(Path::new("/x/y")));
        assert!(
            a.file_name()
                .unwrap()
                .to_string_lossy()
                .starts_with(".forest.canopy.tmp-")
        );
        assert_ne!(a, b);
        assert_eq!(
            temp_path_for(Path::new("bare.canopy")).unwrap().parent(),
            Some(Path::new("."))
        );
        assert!(matches!(
            temp_path_for(Path::new("/")),
            Err(FormatError::Io { .. })
        ));
    }

    #[test]
    fn a_set_too_large_for_one_section_is_refused_on_write() {
        // A real case would be 258 views x 258 lights at 128² (4.4 GB in one record); the
        // same check with a small section limit.
        let dir = scratch_dir("toolarge");
        let path = dir.join("big.canopy");
        let baked = sample();
        let limit = btf_record_len(&baked.btf[0]) + 3;
        let err = write_atomic_with_hook(&path, &baked, limit, |_| Ok(())).unwrap_err();
        match err {
            FormatError::AbsurdSize { field, value, .. } => {
                assert!(field.contains("btf image sets record 0"), "{field}");
                assert_eq!(value, btf_record_len(&baked.btf[0]));
            }
            other => panic!("expected an absurd size, got {other:?}"),
        }
        assert!(dir_entries(&dir).is_empty(), "nothing written");
        // One more byte of room and it is written, one record per section.
        write_atomic_with_hook(&path, &baked, limit + 1, |_| Ok(())).unwrap();
        let bytes = fs::read(&path).unwrap();
        // Two btf sections, the vcm sets together, the texel volume.
        assert_eq!(section_count(&bytes), 4);
        assert!(from_bytes(&bytes).unwrap() == baked);
        fs::remove_dir_all(&dir).unwrap();
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
}
