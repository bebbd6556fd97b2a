//! The `impostor` method's knobs and what it reports of a frame.

/// The `impostor` method's knobs.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct ImpostorSettings {
    /// The alpha test's threshold; dithered over [c - s, c + s] with s = min(c, 1 - c), so
    /// that at 0.5 a pixel is drawn with the chance of its coverage.
    pub alpha_cutoff: f32,
    /// Each frame's point is moved to the depth the frame stored.
    pub parallax: bool,
    /// Self-shadowing from the impostor's own frames: the light's extinction per radius of
    /// crown between a point and the surface the frame nearest the sun (or the zenith) sees
    /// first; 0: none.
    pub self_shadow: f32,
    /// Write the depth of the blended point (moved by the parallax) instead of the quad's:
    /// exact where impostors cross, but the depth test then runs after the shader, so
    /// hidden fragments are shaded too.
    pub parallax_depth: bool,
    /// Shade with the trees' visibility cube maps (when the bake has them).
    pub vcm: bool,
    /// Colour every impostor by the LOD overlay's colour.
    pub show_lod: bool,
    /// A tree whose impostor texels project above this many pixels is drawn as geometry
    /// (faded in over the last [`GEOMETRY_FADE`] of the bound); 0: never.
    pub geometry_px: f32,
}

/// The fraction of `geometry_px` before it over which a tree's geometry fades in.
pub const GEOMETRY_FADE: f32 = 0.2;

impl Default for ImpostorSettings {
    fn default() -> Self {
        Self {
            alpha_cutoff: 0.5,
            parallax: true,
            self_shadow: 64.0,
            parallax_depth: false,
            vcm: true,
            show_lod: false,
            geometry_px: 2.0,
        }
    }
}

/// What the `impostor` method did in a frame.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize)]
pub struct ImpostorStats {
    /// Trees drawn as impostors.
    pub impostors: u32,
    /// Trees drawn as geometry (their impostor magnified past `geometry_px`), whole or
    /// fading in.
    pub geometry_trees: u32,
    /// Frames per side and pixels a frame side of the bake's impostors.
    pub frames: u32,
    pub frame_px: u32,
    /// Bytes of the atlases on the GPU (both maps, every species, mips included).
    pub atlas_bytes: u64,
}

/// The LOD overlay's colour of an impostor (white; geometry is magenta).
pub const IMPOSTOR_COLOR: [f32; 3] = [0.95, 0.95, 0.95];
