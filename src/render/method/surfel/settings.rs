//! The `surfel` method's knobs and what it reports of a frame.

/// The `surfel` method's knobs.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct SurfelSettings {
    /// Each block is drawn at the coarsest level whose surfel spacing projects to at most
    /// this many pixels (finer where the finest level is coarser than that).
    pub surfel_px: f32,
    /// Surfels up to this many of their level's spacings behind their pixel's nearest one
    /// are averaged into the pixel.
    pub tolerance: f32,
    /// Fill the holes between surfels by pull-push.
    pub fill: bool,
    /// Shade with the trees' visibility cube maps.
    pub vcm: bool,
    /// Multiplies each tree's own extinction between a surfel and the sun (and that
    /// between it and the sky, baked as its openness); 0: no self-shadowing.
    pub self_shadow: f32,
    /// Colour each surfel by its level.
    pub show_lod: bool,
    /// A tree whose finest surfels project above this many pixels at its nearest point is
    /// drawn as geometry, faded in over the last fifth before it; 0: never.
    pub geometry_px: f32,
}

impl Default for SurfelSettings {
    fn default() -> Self {
        Self {
            surfel_px: 1.0,
            tolerance: 2.0,
            fill: true,
            vcm: true,
            self_shadow: 1.0,
            show_lod: false,
            geometry_px: 2.0,
        }
    }
}

/// What the `surfel` method did in a frame.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize)]
pub struct SurfelStats {
    /// Trees with at least one block splatted.
    pub trees: u32,
    /// Blocks splatted.
    pub blocks: u32,
    /// Surfels splatted (each twice: the depth pass, then the colour pass).
    pub surfels: u64,
    /// The finest and coarsest level splatted.
    pub finest: u32,
    pub coarsest: u32,
    /// Bytes of every species' surfels on the GPU.
    pub surfel_bytes: u64,
    /// Surfels of every species, every level.
    pub surfels_held: u64,
    /// Trees drawn as geometry (their finest surfels past `geometry_px`), whole or fading
    /// in.
    pub geometry_trees: u32,
}
