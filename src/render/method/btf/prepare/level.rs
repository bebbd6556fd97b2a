//! Which level of the hierarchy a tree is drawn at, and how far a finer level (or, for
//! `hybrid`, the geometry) fades in over it.

use super::*;

/// The level a tree is drawn at, and the finer level fading in over it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LevelChoice {
    /// The coarsest level whose texels project below the LOD scale.
    pub level: Level,
    /// The next finer level and its opacity, inside the cross-fade band before the bound.
    pub fading_in: Option<(Level, f32)>,
}

impl LevelChoice {
    /// The levels to draw with their opacities (they sum to 1).
    pub fn draws(self) -> impl Iterator<Item = (Level, f32)> {
        let fade = self.fading_in.map_or(0.0, |(_, f)| f);
        std::iter::once((self.level, 1.0 - fade)).chain(self.fading_in)
    }
}

/// How much of a tree `hybrid` draws as geometry (0 = none, 1 = all of it): the twig
/// level is the finest image level, valid while its texel projects below the LOD scale;
/// past that the tree is geometry, faded in over the last `lod_fade` fraction before the
/// bound as the finer levels are (so that the bound itself changes nothing).
pub fn geometry_fade(
    texels: &LevelTexels,
    scale: f32,
    focal_px: f32,
    z: f32,
    settings: &BtfSettings,
) -> f32 {
    let px = lod::projected_px(texels[Level::Twig] * scale, focal_px, z);
    band(px, settings.lod_scale, settings.lod_fade)
}

/// How much of a tree's tree level `hybrid` draws as its impostor (0 = none, 1 = all):
/// all where the tree-level texel projects below the start of the band before
/// `impostor_px` (its last `lod_fade` fraction), none from `impostor_px` up, linear
/// between; none while `impostor_px` is 0, all while it is `lod_scale` or more (the
/// tree level's own fade band is then the impostor's).
pub fn impostor_share(
    texels: &LevelTexels,
    scale: f32,
    focal_px: f32,
    z: f32,
    settings: &BtfSettings,
) -> f32 {
    let bound = settings.impostor_px;
    if bound.is_nan() || bound <= 0.0 {
        return 0.0;
    }
    if bound >= settings.lod_scale {
        return 1.0;
    }
    let px = lod::projected_px(texels[Level::Tree] * scale, focal_px, z);
    1.0 - band(px, bound, settings.lod_fade)
}

/// Where `px` stands in the band before `bound` (its last `lod_fade` fraction): 1 at the
/// bound and above, 0 at the band's start and below (and for NaN), linear between; a step
/// at the bound without a band.
fn band(px: f32, bound: f32, lod_fade: f32) -> f32 {
    let start = bound * (1.0 - lod_fade.clamp(0.0, 1.0));
    if px >= bound {
        1.0
    } else if px > start {
        ((px - start) / (bound - start).max(1e-6)).clamp(0.0, 1.0)
    } else {
        0.0
    }
}

/// Chooses the level of a tree of `scale` whose centre is `z` from the eye. While the chosen
/// level's texel is within the last `lod_fade` fraction of the bound, the next finer level
/// fades in over it, so that the switch at the bound itself changes nothing.
pub fn choose_level(
    texels: &LevelTexels,
    scale: f32,
    focal_px: f32,
    z: f32,
    settings: &BtfSettings,
) -> LevelChoice {
    let level = lod::choose(texels, scale, focal_px, z, settings.lod_scale);
    let px = lod::projected_px(texels[level] * scale, focal_px, z);
    // The band's value is the finer level's share.
    let fade = band(px, settings.lod_scale, settings.lod_fade);
    let fading_in = level
        .finer()
        .filter(|_| settings.lod_fade > 0.0 && fade > 0.0)
        .map(|finer| (finer, fade));
    LevelChoice { level, fading_in }
}
