//! The bake parameters a `.canopy` header stores, and their header words.

use super::*;

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
    /// Level-0 surfels each species' LDC tree is sampled with (about): 0 (no surfel trees)
    /// or in [`SURFEL_BUDGET_RANGE`].
    pub surfel_budget: u32,
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
            self.surfel_budget,
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
            surfel_budget: w[11],
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
