//! The near trees' frame when the GPU builds the billboards ([`super::super::far`]): the
//! CPU's level choices as draws, within the GPU's room.

use super::*;

impl BtfScene {
    /// The near trees' frame for the GPU ([`super::far`]): their draws
    /// ([`Self::prepare_draws`]), at most `budget` slots of them; past that, the farthest
    /// trees' billboards are made here instead (unsorted), so that nothing goes missing.
    /// `species[t]` is tree `t`'s species.
    #[allow(clippy::too_many_arguments)]
    pub fn prepare_near(
        &self,
        trees: &[TreeGpu],
        species: &[u32],
        near: &[Vec<u32>],
        view: &PrepareView,
        settings: &BtfSettings,
        hybrid: bool,
        budget: u64,
    ) -> (BtfFrame, SortedBillboards, Vec<NearDrawGpu>, u64) {
        let (mut frame, draws, slots) = self.prepare_draws(trees, near, view, settings, hybrid);
        if slots <= budget {
            return (frame, SortedBillboards::default(), draws, slots);
        }
        // The trees by distance, each with its draws' slots (a tree's draws are together).
        let cam = view.camera.position;
        let count_of = |k: usize| {
            draws.get(k + 1).map_or(slots, |n| u64::from(n.first)) - u64::from(draws[k].first)
        };
        let mut by_tree: Vec<(f32, u32, u64)> = Vec::new();
        for (k, d) in draws.iter().enumerate() {
            let count = count_of(k);
            match by_tree.last_mut() {
                Some(last) if last.1 == d.tree => last.2 += count,
                _ => {
                    let sp = species.get(d.tree as usize).copied().unwrap_or(u32::MAX);
                    let dist = trees
                        .get(d.tree as usize)
                        .and_then(|data| self.tree_center(sp as usize, data))
                        .map_or(f32::INFINITY, |c| c.distance_squared(cam));
                    by_tree.push((dist, d.tree, count));
                }
            }
        }
        by_tree.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
        // The nearest trees while they fit; every tree from the first that does not is left.
        let mut used = 0u64;
        let mut full = false;
        let mut kept = Vec::new();
        let mut rest = vec![Vec::new(); self.species.len()];
        for &(_, t, count) in &by_tree {
            full |= used + count > budget;
            if !full {
                used += count;
                kept.push(t);
            } else if let Some(list) = species
                .get(t as usize)
                .and_then(|&sp| rest.get_mut(sp as usize))
            {
                list.push(t);
            }
        }
        kept.sort_unstable();
        for list in &mut rest {
            list.sort_unstable();
        }
        let mut gpu = Vec::with_capacity(draws.len());
        let mut at = 0u64;
        for (k, d) in draws.iter().enumerate() {
            if kept.binary_search(&d.tree).is_ok() {
                gpu.push(NearDrawGpu {
                    first: at as u32,
                    ..*d
                });
                at += count_of(k);
            }
        }
        // Their levels, lists and tree counts are in `frame` already: only the billboards
        // made here are new.
        let (cpu, records) = self.prepare_sorted(trees, &rest, view, settings, 0, hybrid);
        for level in Level::ALL {
            frame.stats.billboards[level] += cpu.stats.billboards[level];
        }
        frame.stats.images_sampled += cpu.stats.images_sampled;
        frame.stats.fetches_saved += cpu.stats.fetches_saved;
        frame.stats.light_blended += cpu.stats.light_blended;
        frame.billboards = cpu.billboards;
        (frame, records, gpu, at)
    }
}
