//! The section tags of the table (kind, packing) and the byte that stores a level.

use super::*;

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
    /// [`SurfelSet`] records.
    Surfel = 5,
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
            5 => Some(SectionKind::Surfel),
            _ => None,
        }
    }

    pub fn name(self) -> &'static str {
        match self {
            SectionKind::Btf => "btf image sets",
            SectionKind::Vcm => "vcm sets",
            SectionKind::Texel => "texel volumes",
            SectionKind::Impostor => "impostors",
            SectionKind::Surfel => "surfel trees",
        }
    }
}

/// The byte that stores `level` in a record: 0 twig, 1 branch, 2 tree.
pub(super) fn level_tag(level: Level) -> u8 {
    match level {
        Level::Twig => 0,
        Level::Branch => 1,
        Level::Tree => 2,
    }
}

/// The level stored as `tag`, if any.
pub(super) fn level_from_tag(tag: u8) -> Option<Level> {
    match tag {
        0 => Some(Level::Twig),
        1 => Some(Level::Branch),
        2 => Some(Level::Tree),
        _ => None,
    }
}
