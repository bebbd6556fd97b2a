//! The far canopy's map, on the CPU: the forest seen from straight above, baked from the
//! trees it stands for.
//!
//! Each prototype's footprint is its full geometry rasterised from above (which ground
//! points its triangles cover, and the height of the highest one there). Every placed tree
//! splats its footprint, turned and scaled as it stands, into a square grid of texels over
//! the terrain (1 m where the square allows): per texel the share of it the crowns cover
//! (their coverages combined as 1 - Π(1 - c), crowns overlapping at random), and which
//! tree is highest there, the one seen from above. Clearings, where no crown reaches,
//! stay empty. Coarser levels halve the grid: coverage is averaged, and each texel keeps
//! the tree of its most covered child, so that a texel far away shows one of the trees it
//! holds rather than a blend no tree has.
//!
//! The lid is the surface the canopy is drawn on: a coarser grid of heights, each vertex at
//! the ground plus nearly the height of the highest crown around it, so that it follows
//! the stands' outline, rises at their edges and lies on the ground in clearings.

use glam::{Mat4, Vec2, Vec3};

use crate::model::mesh::Mesh;
use crate::model::{Terrain, World};

/// Side of a footprint sample (m, in the tree's frame).
const FOOTPRINT_CELL: f32 = 0.1;
/// Most footprint samples per side (a tree up to 51 m across at 0.1 m).
const FOOTPRINT_MAX: usize = 512;
/// Finest texel of the map (m; a little less, for a power-of-two side), and most texels
/// per side.
pub const MAP_TEXEL: f32 = 1.0;
pub const MAP_MAX_SIDE: u32 = 2048;
/// Sub-samples per texel side when a tree splats its footprint.
const SPLAT_SAMPLES: u32 = 3;
/// Map texels per lid cell side.
pub const LID_TEXELS: u32 = 4;
/// The lid sits at this share of the highest crown's height above the ground around it:
/// seen from the side, a forest's outline is its trees' tips, and a lid at the crowns'
/// mean height (a third of a cone's) would cut them off.
const LID_FILL: f32 = 0.9;
/// The lid stays at least this far above the ground, so that it never fights the terrain
/// for depth.
const LID_LIFT: f32 = 0.5;

/// One prototype seen from above, in its tree frame (+Y up).
#[derive(Clone, Debug, PartialEq)]
pub struct Footprint {
    /// The (x, z) corner of sample (0, 0), the side of a sample (m) and the samples per
    /// side.
    origin: Vec2,
    cell: f32,
    w: usize,
    h: usize,
    /// Per sample: the height (y) of the highest triangle covering it, NaN where none does.
    top: Vec<f32>,
}

impl Footprint {
    /// The footprint of a tree mesh in its tree frame; an empty mesh covers nothing.
    pub fn of(mesh: &Mesh) -> Self {
        let (mut lo, mut hi) = (Vec2::splat(f32::INFINITY), Vec2::splat(f32::NEG_INFINITY));
        for v in &mesh.vertices {
            let p = Vec2::new(v.position[0], v.position[2]);
            if p.is_finite() {
                lo = lo.min(p);
                hi = hi.max(p);
            }
        }
        if !(lo.x <= hi.x && lo.y <= hi.y) {
            return Self {
                origin: Vec2::ZERO,
                cell: FOOTPRINT_CELL,
                w: 0,
                h: 0,
                top: Vec::new(),
            };
        }
        let cell = FOOTPRINT_CELL.max((hi - lo).max_element() / FOOTPRINT_MAX as f32);
        let w = (((hi.x - lo.x) / cell).ceil() as usize).clamp(1, FOOTPRINT_MAX + 1);
        let h = (((hi.y - lo.y) / cell).ceil() as usize).clamp(1, FOOTPRINT_MAX + 1);
        let mut top = vec![f32::NAN; w * h];
        let at = |i: u32| {
            mesh.vertices.get(i as usize).map_or(Vec3::ZERO, |v| {
                let p = Vec3::from(v.position);
                Vec3::new((p.x - lo.x) / cell, p.y, (p.z - lo.y) / cell)
            })
        };
        for tri in mesh.indices.chunks_exact(3) {
            let [a, b, c] = [at(tri[0]), at(tri[1]), at(tri[2])];
            let (a2, b2, c2) = (
                Vec2::new(a.x, a.z),
                Vec2::new(b.x, b.z),
                Vec2::new(c.x, c.z),
            );
            let area = (b2 - a2).perp_dot(c2 - a2);
            // A triangle seen edge-on from above (a trunk's side, a vertical leaf) covers
            // its edge: it still hides the ground along it.
            let min = a2.min(b2).min(c2);
            let max = a2.max(b2).max(c2);
            let x0 = (min.x - 0.5).ceil().max(0.0) as usize;
            let x1 = ((max.x - 0.5).floor() as isize).min(w as isize - 1);
            let y0 = (min.y - 0.5).ceil().max(0.0) as usize;
            let y1 = ((max.y - 0.5).floor() as isize).min(h as isize - 1);
            if x1 < x0 as isize || y1 < y0 as isize || area.abs() < 1e-9 {
                // Smaller than a sample: it marks the sample it lies in.
                let m = (a2 + b2 + c2) / 3.0;
                let (i, j) = (m.x.floor(), m.y.floor());
                if i >= 0.0 && j >= 0.0 && (i as usize) < w && (j as usize) < h {
                    let k = j as usize * w + i as usize;
                    let y = a.y.max(b.y).max(c.y);
                    top[k] = if top[k].is_nan() { y } else { top[k].max(y) };
                }
                continue;
            }
            let s = area.signum();
            for y in y0..=y1 as usize {
                for x in x0..=x1 as usize {
                    let p = Vec2::new(x as f32 + 0.5, y as f32 + 0.5);
                    let e0 = (c2 - b2).perp_dot(p - b2) * s;
                    let e1 = (a2 - c2).perp_dot(p - c2) * s;
                    let e2 = (b2 - a2).perp_dot(p - a2) * s;
                    if e0 >= 0.0 && e1 >= 0.0 && e2 >= 0.0 {
                        let inv = 1.0 / area.abs();
                        let yy = (e0 * a.y + e1 * b.y + e2 * c.y) * inv;
                        let k = y * w + x;
                        top[k] = if top[k].is_nan() { yy } else { top[k].max(yy) };
                    }
                }
            }
        }
        Self {
            origin: lo,
            cell,
            w,
            h,
            top,
        }
    }

    /// The height of the highest triangle over tree-frame point `(x, z)`, if one covers it.
    pub fn top_at(&self, p: Vec2) -> Option<f32> {
        if self.w == 0 {
            return None;
        }
        let q = (p - self.origin) / self.cell;
        let (i, j) = (q.x.floor(), q.y.floor());
        if !(i >= 0.0 && j >= 0.0 && (i as usize) < self.w && (j as usize) < self.h) {
            return None;
        }
        let y = self.top[j as usize * self.w + i as usize];
        (!y.is_nan()).then_some(y)
    }

    /// The share of the footprint's box its triangles cover.
    pub fn cover(&self) -> f32 {
        let n = self.w * self.h;
        if n == 0 {
            return 0.0;
        }
        self.top.iter().filter(|y| !y.is_nan()).count() as f32 / n as f32
    }

    /// The footprint's box in the tree frame: (x, z) min and max.
    pub fn bounds(&self) -> (Vec2, Vec2) {
        let size = Vec2::new(self.w as f32, self.h as f32) * self.cell;
        (self.origin, self.origin + size)
    }
}

/// One level of the map: coverage and the tree seen from above, per texel, row by row
/// (rows along +z).
#[derive(Clone, Debug, PartialEq)]
pub struct MapLevel {
    pub side: u32,
    /// Coverage, 0..255.
    pub cover: Vec<u8>,
    /// The tree seen there, plus one (0: none).
    pub tree: Vec<u32>,
}

/// The forest seen from above over a terrain square, and the lid it is drawn on.
#[derive(Clone, Debug, PartialEq)]
pub struct CanopyMap {
    /// The (x, z) corner of texel (0, 0), and the side of a texel at level 0 (m).
    pub origin: Vec2,
    pub texel: f32,
    /// Level 0 first, each level half the side of the one before, down to one texel.
    pub levels: Vec<MapLevel>,
    /// Lid vertices per side, and their world heights, row by row; one lid cell spans
    /// [`LID_TEXELS`] texels of level 0.
    pub lid_side: u32,
    pub lid: Vec<f32>,
    /// The trees that stand in the map (those whose footprints reach the square).
    pub trees: u32,
    /// The median width of their crowns (m): the footprint's widest side, scaled.
    pub crown_width: f32,
}

impl CanopyMap {
    /// Bytes it holds on the CPU.
    pub fn bytes(&self) -> u64 {
        use crate::render::memory::vec_bytes;
        let levels: u64 = self
            .levels
            .iter()
            .map(|l| vec_bytes(&l.cover) + vec_bytes(&l.tree))
            .sum();
        levels + vec_bytes(&self.lid)
    }

    /// The map of `trees` (each a world transform and its prototype's index into
    /// `footprints`) over `terrain`'s square.
    pub fn new(terrain: &Terrain, trees: &[(Mat4, usize)], footprints: &[Footprint]) -> Self {
        let size = terrain.size.max(1.0);
        // A power of two, so that every level halves the one before exactly (whole lid
        // cells too).
        let side = ((size / MAP_TEXEL).ceil() as u32)
            .clamp(LID_TEXELS, MAP_MAX_SIDE)
            .next_power_of_two();
        let texel = size / side as f32;
        let origin = Vec2::splat(-0.5 * size);
        let n = side as usize;
        let mut clear = vec![1.0f32; n * n];
        let mut best_top = vec![f32::NEG_INFINITY; n * n];
        let mut tree = vec![0u32; n * n];
        let mut placed = 0u32;
        let mut widths = Vec::with_capacity(trees.len());
        let sub = SPLAT_SAMPLES as f32;
        for (t, (m, sp)) in trees.iter().enumerate() {
            let Some(fp) = footprints.get(*sp) else {
                continue;
            };
            let inv = m.inverse();
            if !inv.is_finite() || fp.w == 0 {
                continue;
            }
            // The footprint's box in the world.
            let (lo, hi) = fp.bounds();
            let corners = [
                Vec3::new(lo.x, 0.0, lo.y),
                Vec3::new(hi.x, 0.0, lo.y),
                Vec3::new(lo.x, 0.0, hi.y),
                Vec3::new(hi.x, 0.0, hi.y),
            ];
            let (mut wlo, mut whi) = (Vec2::splat(f32::INFINITY), Vec2::splat(f32::NEG_INFINITY));
            for c in corners {
                let p = m.transform_point3(c);
                wlo = wlo.min(Vec2::new(p.x, p.z));
                whi = whi.max(Vec2::new(p.x, p.z));
            }
            let i0 = ((wlo.x - origin.x) / texel).floor().max(0.0) as usize;
            let j0 = ((wlo.y - origin.y) / texel).floor().max(0.0) as usize;
            let i1 = (((whi.x - origin.x) / texel).floor() as isize).min(n as isize - 1);
            let j1 = (((whi.y - origin.y) / texel).floor() as isize).min(n as isize - 1);
            if i1 < i0 as isize || j1 < j0 as isize || !wlo.is_finite() || !whi.is_finite() {
                continue;
            }
            placed += 1;
            widths.push((hi - lo).max_element() * m.x_axis.truncate().length());
            for j in j0..=j1 as usize {
                for i in i0..=i1 as usize {
                    let mut hits = 0u32;
                    let mut high = f32::NEG_INFINITY;
                    for sj in 0..SPLAT_SAMPLES {
                        for si in 0..SPLAT_SAMPLES {
                            let x = origin.x + (i as f32 + (si as f32 + 0.5) / sub) * texel;
                            let z = origin.y + (j as f32 + (sj as f32 + 0.5) / sub) * texel;
                            let q = inv.transform_point3(Vec3::new(x, 0.0, z));
                            if let Some(y) = fp.top_at(Vec2::new(q.x, q.z)) {
                                hits += 1;
                                let w = m.transform_point3(Vec3::new(q.x, y, q.z)).y;
                                high = high.max(w);
                            }
                        }
                    }
                    if hits == 0 {
                        continue;
                    }
                    let k = j * n + i;
                    clear[k] *= 1.0 - hits as f32 / (sub * sub);
                    if high > best_top[k] {
                        best_top[k] = high;
                        tree[k] = t as u32 + 1;
                    }
                }
            }
        }
        let cover: Vec<u8> = clear
            .iter()
            .map(|c| ((1.0 - c) * 255.0).round().clamp(0.0, 255.0) as u8)
            .collect();
        widths.sort_by(f32::total_cmp);
        let crown_width = widths.get(widths.len() / 2).copied().unwrap_or(0.0);
        let lid = lid_heights(terrain, origin, texel, side, &cover, &best_top);
        let mut levels = vec![MapLevel { side, cover, tree }];
        while let Some(last) = levels.last()
            && last.side > 1
        {
            let next = halve(last);
            levels.push(next);
        }
        Self {
            origin,
            texel,
            levels,
            lid_side: side / LID_TEXELS + 1,
            lid,
            trees: placed,
            crown_width,
        }
    }

    /// The map of `world`'s forest, from each prototype's full geometry; None without trees.
    pub fn of_world(world: &World) -> Option<Self> {
        if world.forest.instances.is_empty() {
            return None;
        }
        let footprints: Vec<Footprint> = world
            .species
            .iter()
            .map(|s| Footprint::of(&s.flatten()))
            .collect();
        let trees: Vec<(Mat4, usize)> = world
            .forest
            .instances
            .iter()
            .map(|t| (t.transform(), t.species as usize))
            .collect();
        Some(Self::new(&world.terrain, &trees, &footprints))
    }

    /// Level 0's coverage (0..1) and tree (plus one) at world `(x, z)`; none outside.
    pub fn at(&self, x: f32, z: f32) -> Option<(f32, u32)> {
        let l = self.levels.first()?;
        let i = ((x - self.origin.x) / self.texel).floor();
        let j = ((z - self.origin.y) / self.texel).floor();
        if !(i >= 0.0 && j >= 0.0 && (i as u32) < l.side && (j as u32) < l.side) {
            return None;
        }
        let k = j as usize * l.side as usize + i as usize;
        Some((f32::from(l.cover[k]) / 255.0, l.tree[k]))
    }
}

/// The next level: coverage averaged, the most covered child's tree kept.
fn halve(l: &MapLevel) -> MapLevel {
    let side = l.side.div_ceil(2);
    let n = side as usize;
    let src = l.side as usize;
    let mut cover = vec![0u8; n * n];
    let mut tree = vec![0u32; n * n];
    for j in 0..n {
        for i in 0..n {
            let (mut sum, mut count, mut best, mut best_c) = (0u32, 0u32, 0u32, 0u8);
            for (di, dj) in [(0, 0), (1, 0), (0, 1), (1, 1)] {
                let (x, y) = (2 * i + di, 2 * j + dj);
                if x >= src || y >= src {
                    continue;
                }
                let k = y * src + x;
                sum += u32::from(l.cover[k]);
                count += 1;
                if l.tree[k] != 0 && (best == 0 || l.cover[k] > best_c) {
                    best = l.tree[k];
                    best_c = l.cover[k];
                }
            }
            cover[j * n + i] = (sum / count.max(1)) as u8;
            tree[j * n + i] = best;
        }
    }
    MapLevel { side, cover, tree }
}

/// The lid's vertex heights: ground plus [`LID_FILL`] of the highest covered texel's top
/// above it within one lid cell of the vertex.
fn lid_heights(
    terrain: &Terrain,
    origin: Vec2,
    texel: f32,
    side: u32,
    cover: &[u8],
    top: &[f32],
) -> Vec<f32> {
    let cells = side / LID_TEXELS;
    let verts = cells as usize + 1;
    let n = side as usize;
    let reach = LID_TEXELS as isize;
    let mut lid = vec![0.0f32; verts * verts];
    for vj in 0..verts {
        for vi in 0..verts {
            let x = origin.x + (vi as u32 * LID_TEXELS) as f32 * texel;
            let z = origin.y + (vj as u32 * LID_TEXELS) as f32 * texel;
            let ground = terrain.height_at(x, z);
            let (ci, cj) = (
                (vi as u32 * LID_TEXELS) as isize,
                (vj as u32 * LID_TEXELS) as isize,
            );
            let mut above = 0.0f32;
            for j in (cj - reach).max(0)..(cj + reach).min(n as isize) {
                for i in (ci - reach).max(0)..(ci + reach).min(n as isize) {
                    let k = j as usize * n + i as usize;
                    let c = f32::from(cover[k]) / 255.0;
                    if c > 0.0 && top[k].is_finite() {
                        let gx = origin.x + (i as f32 + 0.5) * texel;
                        let gz = origin.y + (j as f32 + 0.5) * texel;
                        above = above.max(top[k] - terrain.height_at(gx, gz));
                    }
                }
            }
            lid[vj * verts + vi] = ground + (LID_FILL * above).max(LID_LIFT);
        }
    }
    lid
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::mesh::Vertex;

    /// A flat square "crown" of side `s` at height `y`, centred on the trunk.
    fn square(s: f32, y: f32) -> Mesh {
        let mut m = Mesh::default();
        let h = 0.5 * s;
        for (x, z) in [(-h, -h), (h, -h), (h, h), (-h, h)] {
            m.push_vertex(Vertex::new(Vec3::new(x, y, z), Vec3::Y, Vec3::ONE, 1.0));
        }
        m.indices.extend_from_slice(&[0, 1, 2, 0, 2, 3]);
        m
    }

    #[test]
    fn a_footprint_covers_its_triangles_and_nothing_else() {
        let fp = Footprint::of(&square(4.0, 10.0));
        assert_eq!(fp.top_at(Vec2::ZERO), Some(10.0));
        assert_eq!(fp.top_at(Vec2::new(1.9, -1.9)), Some(10.0));
        assert_eq!(fp.top_at(Vec2::new(2.5, 0.0)), None);
        assert!(fp.cover() > 0.99, "{}", fp.cover());
    }

    #[test]
    fn trees_cover_their_crowns_and_clearings_stay_clear() {
        let terrain = Terrain::flat(64.0, 17);
        let fp = vec![Footprint::of(&square(4.0, 10.0))];
        // Two trees on the west half; the east half is a clearing.
        let trees = [
            (Mat4::from_translation(Vec3::new(-20.0, 0.0, 0.0)), 0),
            (
                Mat4::from_translation(Vec3::new(-10.0, 0.0, 5.0))
                    * Mat4::from_rotation_y(0.5)
                    * Mat4::from_scale(Vec3::splat(1.5)),
                0,
            ),
        ];
        let map = CanopyMap::new(&terrain, &trees, &fp);
        assert_eq!(map.trees, 2);
        assert!((map.crown_width - 6.0).abs() < 0.2, "{}", map.crown_width);
        assert_eq!(map.at(-20.0, 0.0).map(|c| c.1), Some(1));
        assert_eq!(map.at(-10.0, 5.0).map(|c| c.1), Some(2));
        assert!(map.at(-20.0, 0.0).unwrap().0 > 0.99);
        // The crowns' areas: 16 m² and (1.5 · 4)² = 36 m², within a texel's rim.
        let l = &map.levels[0];
        let area: f32 =
            l.cover.iter().map(|&c| f32::from(c) / 255.0).sum::<f32>() * map.texel * map.texel;
        assert!((area - 52.0).abs() < 6.0, "{area}");
        // The clearing: no coverage, no tree, and the lid on the ground.
        for j in 0..l.side as usize {
            for i in (l.side as usize / 2 + 2)..l.side as usize {
                let k = j * l.side as usize + i;
                assert_eq!((l.cover[k], l.tree[k]), (0, 0), "texel {i},{j}");
            }
        }
        let v = map.lid_side as usize;
        let east = map.lid[(v / 2) * v + v - 2];
        assert!((east - LID_LIFT).abs() < 1e-4, "{east}");
        // Over the first crown the lid stands at the crown's height, less its fill.
        let vi = ((-20.0 - map.origin.x) / (map.texel * LID_TEXELS as f32)).round() as usize;
        let vj = ((0.0 - map.origin.y) / (map.texel * LID_TEXELS as f32)).round() as usize;
        let h = map.lid[vj * v + vi];
        assert!((h - LID_FILL * 10.0).abs() < 1.0, "{h}");
    }

    #[test]
    fn coarser_levels_average_cover_and_keep_a_tree_they_hold() {
        let terrain = Terrain::flat(32.0, 9);
        let fp = vec![Footprint::of(&square(3.0, 5.0))];
        let trees = [(Mat4::from_translation(Vec3::new(4.0, 0.0, -4.0)), 0)];
        let map = CanopyMap::new(&terrain, &trees, &fp);
        let mean = |l: &MapLevel| {
            l.cover.iter().map(|&c| f64::from(c)).sum::<f64>() / l.cover.len() as f64
        };
        let m0 = mean(&map.levels[0]);
        for l in &map.levels[1..] {
            assert!(
                (mean(l) - m0).abs() < 0.05 * m0 + 1.0,
                "{} vs {m0}",
                mean(l)
            );
            assert!(l.tree.iter().all(|&t| t == 0 || t == 1));
            assert!(l.tree.contains(&1), "level of side {}", l.side);
        }
        assert_eq!(map.levels.last().unwrap().side, 1);
    }
}
