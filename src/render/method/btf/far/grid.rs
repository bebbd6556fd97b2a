//! A uniform grid over the trees' centres, for finding the near trees without visiting
//! every tree.

use glam::Vec3;

/// A uniform grid over the trees' centres in x and z, for finding the near trees without
/// visiting every tree.
pub(super) struct Grid {
    origin: [f32; 2],
    cell: f32,
    side: [usize; 2],
    /// Trees of cell `c`: `trees[start[c]..start[c + 1]]`, ascending.
    start: Vec<u32>,
    trees: Vec<u32>,
    /// Trees with no finite centre, always visited.
    loose: Vec<u32>,
}

impl Grid {
    /// At most this many cells a side.
    const MAX_SIDE: usize = 256;

    pub(super) fn new(centres: &[Option<Vec3>]) -> Self {
        let finite = |c: &Option<Vec3>| c.filter(|c| c.is_finite());
        let (mut lo, mut hi) = ([f32::INFINITY; 2], [f32::NEG_INFINITY; 2]);
        for c in centres.iter().filter_map(finite) {
            lo = [lo[0].min(c.x), lo[1].min(c.z)];
            hi = [hi[0].max(c.x), hi[1].max(c.z)];
        }
        if lo[0] > hi[0] {
            lo = [0.0; 2];
            hi = [0.0; 2];
        }
        // About 16 m cells, fewer over a wide forest.
        let extent = (hi[0] - lo[0]).max(hi[1] - lo[1]).max(1.0);
        let cell = (extent / Self::MAX_SIDE as f32).max(16.0);
        let side = [
            (((hi[0] - lo[0]) / cell) as usize + 1).min(Self::MAX_SIDE),
            (((hi[1] - lo[1]) / cell) as usize + 1).min(Self::MAX_SIDE),
        ];
        let cell_of = |c: Vec3| {
            let x = (((c.x - lo[0]) / cell) as usize).min(side[0] - 1);
            let z = (((c.z - lo[1]) / cell) as usize).min(side[1] - 1);
            z * side[0] + x
        };
        let mut counts = vec![0u32; side[0] * side[1] + 1];
        let mut loose = Vec::new();
        for (t, c) in centres.iter().enumerate() {
            match finite(c) {
                Some(c) => counts[cell_of(c) + 1] += 1,
                None => loose.push(t as u32),
            }
        }
        for k in 1..counts.len() {
            counts[k] += counts[k - 1];
        }
        let start = counts.clone();
        let mut trees = vec![0u32; centres.len() - loose.len()];
        for (t, c) in centres.iter().enumerate() {
            if let Some(c) = finite(c) {
                let k = cell_of(c);
                trees[counts[k] as usize] = t as u32;
                counts[k] += 1;
            }
        }
        Self {
            origin: lo,
            cell,
            side,
            start,
            trees,
            loose,
        }
    }

    /// Calls `f` with every tree whose cell lies within `radius` of `p` in x and z (and
    /// the loose ones).
    pub(super) fn for_each_near(&self, p: Vec3, radius: f32, mut f: impl FnMut(u32)) {
        for &t in &self.loose {
            f(t);
        }
        let range = |c: f32, o: f32, n: usize| {
            let a = ((c - radius - o) / self.cell).floor();
            let b = ((c + radius - o) / self.cell).floor();
            if !(a.is_finite() && b.is_finite()) || radius.is_nan() {
                // An infinite radius, or a camera far out: every cell.
                return 0..n;
            }
            let a = a.clamp(0.0, n as f32) as usize;
            let b = (b + 1.0).clamp(0.0, n as f32) as usize;
            a..b
        };
        let xs = range(p.x, self.origin[0], self.side[0]);
        for z in range(p.z, self.origin[1], self.side[1]) {
            for x in xs.clone() {
                let c = z * self.side[0] + x;
                for &t in &self.trees[self.start[c] as usize..self.start[c + 1] as usize] {
                    f(t);
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_grid_visits_every_tree_within_the_radius_once() {
        // Trees over 600 m with a cluster, one with no centre; cameras inside and outside.
        let mut rng = 3u32;
        let mut next = || {
            rng = rng.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
            (rng >> 8) as f32 / (1u32 << 24) as f32
        };
        let mut centres: Vec<Option<Vec3>> = (0..2000)
            .map(|_| {
                Some(Vec3::new(
                    next() * 600.0 - 300.0,
                    next() * 40.0,
                    next() * 600.0,
                ))
            })
            .collect();
        centres.extend((0..200).map(|_| Some(Vec3::new(next() * 3.0, 0.0, next() * 3.0))));
        centres.push(None);
        centres.push(Some(Vec3::new(f32::NAN, 0.0, 1.0)));
        let grid = Grid::new(&centres);
        for (cam, radius) in [
            (Vec3::new(0.0, 10.0, 100.0), 35.0),
            (Vec3::new(-290.0, 5.0, 590.0), 80.0),
            (Vec3::new(2000.0, 5.0, 0.0), 150.0),
            (Vec3::new(1.0, 2.0, 1.0), 0.5),
            (Vec3::new(0.0, 0.0, 0.0), f32::INFINITY),
        ] {
            let mut seen = vec![0u32; centres.len()];
            grid.for_each_near(cam, radius, |t| seen[t as usize] += 1);
            for (t, c) in centres.iter().enumerate() {
                assert!(seen[t] <= 1, "tree {t} visited twice");
                let within = match c {
                    Some(c) if c.is_finite() => {
                        (c.x - cam.x).abs() <= radius && (c.z - cam.z).abs() <= radius
                    }
                    _ => true,
                };
                if within {
                    assert_eq!(
                        seen[t], 1,
                        "tree {t} at {c:?} missed from {cam} within {radius}"
                    );
                }
            }
        }
    }
}
