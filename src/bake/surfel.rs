//! Each species' surfel tree, the `surfel` method's LDC tree (Guennebaud and Paulin 2002):
//! its triangles sampled into three orthogonal layered depth images at the finest spacing,
//! coarser levels merged from finer ones, and each surfel's openness to the sky from the
//! tree's own density (the sampling is the method's: `render::method::surfel::sample`).
//!
//! Cost: about a second a species of 250,000 level-0 surfels on 2 cores, a second or two
//! of a bake that takes minutes (docs/results/surfel.md).

use crate::format::{BakeSettings, SurfelSet};
use crate::model::World;
use crate::render::method::surfel::method::MIN_SPACING;
use crate::render::method::surfel::sample::sample_tree;

/// Progress steps of the surfel bake of `world`: one per species.
pub fn step_count(settings: &BakeSettings, world: &World) -> u64 {
    if settings.surfel_budget > 0 {
        world.species.len() as u64
    } else {
        0
    }
}

/// Bytes of one species' surfel tree of `budget` level-0 surfels, about: its levels add a
/// third (each a quarter of the one below), its nodes and density volume a little more.
pub fn record_bytes(budget: u32) -> u64 {
    let surfels = u64::from(budget) * 4 / 3;
    crate::format::surfel_record_bytes(12, (surfels / 64) as u32, surfels, [32, 32, 32])
}

/// Every species of `world` sampled into its surfel tree with `settings`' budget (none
/// when it is 0); `progress` sees (species done, what).
pub fn bake_surfels(
    world: &World,
    settings: &BakeSettings,
    progress: &mut dyn FnMut(u64, &str),
) -> Vec<SurfelSet> {
    if settings.surfel_budget == 0 {
        return Vec::new();
    }
    world
        .species
        .iter()
        .enumerate()
        .map(|(i, tree)| {
            progress(i as u64, &format!("{} surfels", tree.name));
            let set = SurfelSet {
                species: i as u32,
                ..sample_tree(tree, settings.surfel_budget, MIN_SPACING).set
            };
            progress(i as u64 + 1, &format!("{} surfels", tree.name));
            set
        })
        .collect()
}
