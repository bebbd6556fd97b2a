//! The `texel` method's knobs and what it reports of a frame.

use crate::slices::SliceBounds;

/// How the volumes are sliced.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum TexelMode {
    /// Slices parallel to the screen through a 3D texture (Decaudin-Neyret 2009).
    #[default]
    Slices3d,
    /// The seeds' three axis stacks of 2D slices, the one most facing the eye drawn, with
    /// power-of-two pre-composited levels (Meyer-Neyret 1998).
    Stacks,
    /// The slices of `Slices3d` cut out of each box as polygons and blended one by one
    /// (Decaudin-Neyret's own drawing), to compare with the ray march.
    Polygons,
}

impl TexelMode {
    pub fn name(self) -> &'static str {
        match self {
            TexelMode::Slices3d => "slices3d",
            TexelMode::Stacks => "stacks",
            TexelMode::Polygons => "polygons",
        }
    }

    pub fn parse(s: &str) -> Option<TexelMode> {
        match s {
            "slices3d" => Some(TexelMode::Slices3d),
            "stacks" => Some(TexelMode::Stacks),
            "polygons" => Some(TexelMode::Polygons),
            _ => None,
        }
    }
}

/// The `texel` method's knobs.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct TexelSettings {
    pub mode: TexelMode,
    pub bounds: SliceBounds,
    /// Shade with the trees' visibility cube maps (when the bake has them).
    pub vcm: bool,
    /// Show each texel's slice count as a colour.
    pub show_slices: bool,
    /// Draw the trees of tiles wholly beyond `tile_distance` as forest-cover tiles.
    pub tiles: bool,
    /// Distance (m) from the eye to a tile's nearest point beyond which it is drawn as
    /// one volume.
    pub tile_distance: f32,
}

impl Default for TexelSettings {
    fn default() -> Self {
        Self {
            mode: TexelMode::Slices3d,
            bounds: SliceBounds::default(),
            vcm: true,
            show_slices: false,
            tiles: true,
            tile_distance: 400.0,
        }
    }
}

/// What the `texel` method did in a frame.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize)]
pub struct TexelStats {
    pub texel_mode: TexelMode,
    /// Trees drawn as texels.
    pub texels: u32,
    /// Forest-cover tiles drawn.
    pub tiles: u32,
    /// Trees those tiles stand for (not counted in `texels`).
    pub tiled_trees: u32,
    pub slices_mean: f32,
    pub slices_max: u32,
    /// Bytes of the volumes on the GPU, mipmaps included (with the stack atlas, once the
    /// stacks mode has drawn).
    pub texel_bytes: u64,
    /// Texels left out because the instance buffer was full (the farthest).
    pub dropped: u32,
}
