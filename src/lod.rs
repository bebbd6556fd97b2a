//! Level-of-detail choice for the BTF hierarchy (Meyer 2001, §3.2 and ch. 6): a level is
//! valid while its largest texel projects below `lod_scale` pixels, G_max · f_px / z <
//! lod_scale, and each tree takes the coarsest valid level. Pure arithmetic, so the
//! distances at which a tree switches level can be predicted and tested.

use crate::model::{Level, PerLevel};

/// Texel sizes (m, at scale 1) of one species' three levels.
pub type LevelTexels = PerLevel<f32>;

/// Projected size in pixels of a texel of `texel` metres at distance `z`.
pub fn projected_px(texel: f32, focal_px: f32, z: f32) -> f32 {
    texel * focal_px / z.max(1e-3)
}

/// Distance beyond which `level` is valid: G · f_px / lod_scale.
pub fn valid_beyond(texel: f32, focal_px: f32, lod_scale: f32) -> f32 {
    texel * focal_px / lod_scale.max(1e-6)
}

/// The coarsest valid level for a tree of `scale` at distance `z`; the twig level when none
/// is valid (up close the finest level is used, and blurs).
pub fn choose(texels: &LevelTexels, scale: f32, focal_px: f32, z: f32, lod_scale: f32) -> Level {
    for level in [Level::Tree, Level::Branch] {
        if projected_px(texels[level] * scale, focal_px, z) < lod_scale {
            return level;
        }
    }
    Level::Twig
}

#[cfg(test)]
mod tests {
    use super::*;

    const T: LevelTexels = LevelTexels {
        twig: 0.02,
        branch: 0.06,
        tree: 0.3,
    };

    #[test]
    fn approaching_a_tree_goes_tree_then_branch_then_twig_where_predicted() {
        let f = 600.0;
        let tree_from = valid_beyond(T.tree, f, 1.0); // 180 m
        let branch_from = valid_beyond(T.branch, f, 1.0); // 36 m
        assert!((tree_from - 180.0).abs() < 1e-3 && (branch_from - 36.0).abs() < 1e-3);
        assert_eq!(choose(&T, 1.0, f, tree_from * 1.01, 1.0), Level::Tree);
        assert_eq!(choose(&T, 1.0, f, tree_from * 0.99, 1.0), Level::Branch);
        assert_eq!(choose(&T, 1.0, f, branch_from * 1.01, 1.0), Level::Branch);
        assert_eq!(choose(&T, 1.0, f, branch_from * 0.99, 1.0), Level::Twig);
        assert_eq!(choose(&T, 1.0, f, 0.5, 1.0), Level::Twig);
    }

    #[test]
    fn a_larger_lod_scale_or_smaller_tree_keeps_coarse_levels_closer() {
        let f = 600.0;
        assert_eq!(choose(&T, 1.0, f, 100.0, 1.0), Level::Branch);
        assert_eq!(choose(&T, 1.0, f, 100.0, 2.0), Level::Tree);
        assert_eq!(choose(&T, 0.5, f, 100.0, 1.0), Level::Tree);
    }
}
