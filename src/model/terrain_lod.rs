//! The terrain as chunks with coarser levels, for the camera's view: the heightfield cut
//! into square chunks of [`CHUNK_CELLS`] cells, each with [`TERRAIN_LODS`] index ranges
//! (every 1st, 2nd, 4th, 8th grid point a side) and the largest height error of each level
//! against the full grid. A chunk drawn coarser than its neighbour leaves a crack along
//! their common edge; every chunk's edges hang a skirt down into the ground (both windings)
//! that closes it. The horizon ring stays one range, always drawn whole.
//!
//! Layout of the index buffer: the horizon ring, every chunk's surface at level 0, every
//! chunk's skirts at level 0, then every chunk at level 1 with its skirts, and so on. The
//! horizon and level 0's surfaces together (`full`) are [`Terrain::mesh`]'s triangles, in
//! one range.

use std::collections::HashMap;
use std::ops::Range;

use glam::Vec3;

use super::mesh::{Aabb, Mesh};
use super::terrain::Terrain;

/// Levels of detail per chunk: a grid point every 1, 2, 4 and 8 points.
pub const TERRAIN_LODS: usize = 4;

/// A level's grid points are at most this many pixels apart on screen where it is drawn.
/// A coarse level is shaded from the terrain's maps (the full grid's colours, normals and
/// heights, `render::terrain_maps`), so its spacing costs no detail inside the chunk; what
/// bounds it is the height error (`tolerance_px`) and this, which keeps a coarse level's
/// outline near (docs/results/terrain.md).
pub const SPACING_PX: f32 = 16.0;

/// Sectors of the compass the horizon ring is cut into.
pub const HORIZON_SECTORS: usize = 16;

/// Cells along a chunk's side (a multiple of the coarsest level's step).
pub const CHUNK_CELLS: usize = 32;

/// One chunk: its box (skirts excluded), its levels' index ranges and the largest vertical
/// distance (m) between each level's surface and the full grid's points inside it.
#[derive(Clone, Debug, PartialEq)]
pub struct TerrainChunk {
    pub bounds: Aabb,
    /// Each level's surface, with its skirts from level 1 on.
    pub ranges: [Range<u32>; TERRAIN_LODS],
    /// Level 0's skirts (drawn with it when the chunks are drawn by level).
    pub skirts0: Range<u32>,
    pub error: [f32; TERRAIN_LODS],
}

/// Which ranges of the terrain's index buffer draw what.
#[derive(Clone, Debug, PartialEq)]
pub struct TerrainLayout {
    pub chunks: Vec<TerrainChunk>,
    /// The horizon ring's indices, by sector of the compass, with their bounds (none
    /// without a ring).
    pub horizon: Vec<(Aabb, Range<u32>)>,
    /// The horizon and every chunk at level 0.
    pub full: Range<u32>,
    /// The grid's spacing (m).
    pub cell: f32,
}

/// What of the terrain a view draws: each chunk's level (None: out of view) and whether
/// each sector of the horizon ring is in view.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct TerrainView {
    pub chunks: Vec<Option<usize>>,
    pub horizon: Vec<bool>,
}

/// The terrain mesh with its level and skirt vertices appended, and its layout.
#[derive(Clone, Debug)]
pub struct ChunkedTerrain {
    pub mesh: Mesh,
    pub layout: TerrainLayout,
}

impl TerrainLayout {
    /// The level of each chunk for a view from `eye` with a focal length of `focal_px`
    /// pixels: the coarsest whose height error projects below `tolerance_px` and whose grid
    /// points fall at most [`SPACING_PX`] apart at the chunk's nearest point. A tolerance
    /// of 0 (or NaN) keeps every chunk at level 0.
    pub fn levels(&self, eye: Vec3, focal_px: f32, tolerance_px: f32) -> Vec<usize> {
        if !(tolerance_px > 0.0 && focal_px > 0.0) {
            return vec![0; self.chunks.len()];
        }
        self.chunks
            .iter()
            .map(|c| {
                let d = eye.distance(eye.clamp(c.bounds.min, c.bounds.max));
                (0..TERRAIN_LODS)
                    .rev()
                    .find(|&l| {
                        c.error[l] * focal_px <= tolerance_px * d
                            && (1 << l) as f32 * self.cell * focal_px <= SPACING_PX * d
                    })
                    .unwrap_or(0)
            })
            .collect()
    }

    /// The index ranges that draw the horizon's sectors and the chunks in `view`, each
    /// chunk at its level, neighbours in the buffer merged.
    pub fn ranges(&self, view: &TerrainView) -> Vec<Range<u32>> {
        let mut out: Vec<Range<u32>> = Vec::new();
        let mut push = |r: Range<u32>| {
            if r.is_empty() {
                return;
            }
            match out.last_mut() {
                Some(last) if last.end == r.start => last.end = r.end,
                _ => out.push(r),
            }
        };
        for ((_, r), seen) in self.horizon.iter().zip(&view.horizon) {
            if *seen {
                push(r.clone());
            }
        }
        for (c, l) in self.chunks.iter().zip(&view.chunks) {
            match *l {
                Some(0) => {
                    push(c.ranges[0].clone());
                    push(c.skirts0.clone());
                }
                Some(l) => push(c.ranges[l.min(TERRAIN_LODS - 1)].clone()),
                None => {}
            }
        }
        out
    }
}

/// Grid points along one side of a chunk from `a` to `b` (inclusive) every `step`, the
/// last always `b`.
fn samples(a: usize, b: usize, step: usize) -> Vec<usize> {
    let mut s: Vec<usize> = (a..=b).step_by(step.max(1)).collect();
    if s.last() != Some(&b) {
        s.push(b);
    }
    s
}

impl Terrain {
    /// [`Terrain::mesh`] cut into chunks with their levels and skirts.
    pub fn chunked(&self) -> ChunkedTerrain {
        let base = self.mesh();
        let res = self.resolution.max(2) as usize;
        let cells = res - 1;
        let grid_indices = cells * cells * 6;
        let mut mesh = Mesh {
            vertices: base.vertices,
            indices: Vec::new(),
        };
        let horizon_src = base.indices.get(grid_indices..).unwrap_or(&[]);
        let horizon = horizon_sectors(&mut mesh, horizon_src);
        let horizon_end = mesh.indices.len() as u32;
        let ringed = !horizon.is_empty();

        let heights = &self.heights;
        let h = |i: usize, j: usize| heights[j * res + i];

        // The chunks' corners in grid points.
        let n = cells.div_ceil(CHUNK_CELLS);
        let spans: Vec<(usize, usize)> = (0..n)
            .map(|k| (k * CHUNK_CELLS, ((k + 1) * CHUNK_CELLS).min(cells)))
            .collect();

        // The largest error of each level, and the skirts' depth: the largest error of any
        // chunk at any level, plus a metre.
        let errors = chunk_errors(&h, &spans);
        let skirt_depth = errors
            .iter()
            .flat_map(|e| e.iter().copied())
            .fold(0.0f32, f32::max)
            + 1.0;

        let mut levels = LevelMesh::new(mesh, res, skirt_depth);
        // Level 0's surfaces first (with the horizon, the terrain whole: `full`), then its
        // skirts, then each coarser level with its skirts chunk by chunk.
        let mut ranges: Vec<[Range<u32>; TERRAIN_LODS]> = vec![Default::default(); n * n];
        let mut skirts0: Vec<Range<u32>> = vec![0..0; n * n];
        let mut passes: Vec<(usize, bool, bool)> = vec![(0, true, false), (0, false, true)];
        passes.extend((1..TERRAIN_LODS).map(|l| (l, true, true)));
        let mut level0_end = horizon_end;
        for (l, surface, skirts) in passes {
            let step = 1usize << l;
            for (cj, &(j0, j1)) in spans.iter().enumerate() {
                for (ci, &(i0, i1)) in spans.iter().enumerate() {
                    let start = levels.mesh.indices.len() as u32;
                    let xs = samples(i0, i1, step);
                    let zs = samples(j0, j1, step);
                    if surface {
                        levels.surface(&h, l, &xs, &zs);
                    }
                    if skirts {
                        // The square's own border needs one only where the horizon ring
                        // meets it (at full detail); without a ring it would show.
                        let inner = |k: usize| ringed || (k != 0 && k != cells);
                        levels.skirts(l, (&xs, &zs), (i0, i1), (j0, j1), inner);
                    }
                    let range = start..levels.mesh.indices.len() as u32;
                    match (l, surface) {
                        (0, true) => {
                            level0_end = range.end;
                            ranges[cj * n + ci][0] = range;
                        }
                        (0, false) => skirts0[cj * n + ci] = range,
                        _ => ranges[cj * n + ci][l] = range,
                    }
                }
            }
        }
        let full = 0..level0_end;
        let mesh = levels.finish();

        let half = 0.5 * self.size;
        let step = self.cell_size();
        let mut chunks = Vec::with_capacity(n * n);
        for (cj, &(j0, j1)) in spans.iter().enumerate() {
            for (ci, &(i0, i1)) in spans.iter().enumerate() {
                chunks.push(TerrainChunk {
                    bounds: chunk_bounds(&h, (half, step), (i0, i1), (j0, j1)),
                    ranges: ranges[cj * n + ci].clone(),
                    skirts0: skirts0[cj * n + ci].clone(),
                    error: errors[cj * n + ci],
                });
            }
        }
        ChunkedTerrain {
            mesh,
            layout: TerrainLayout {
                chunks,
                horizon,
                full,
                cell: step,
            },
        }
    }
}

/// The box of the chunk `is` x `js` (skirts excluded), the grid's corner at `-half` and
/// its points `step` apart.
fn chunk_bounds(
    h: &impl Fn(usize, usize) -> f32,
    (half, step): (f32, f32),
    (i0, i1): (usize, usize),
    (j0, j1): (usize, usize),
) -> Aabb {
    let mut lo = f32::INFINITY;
    let mut hi = f32::NEG_INFINITY;
    for j in j0..=j1 {
        for i in i0..=i1 {
            lo = lo.min(h(i, j));
            hi = hi.max(h(i, j));
        }
    }
    Aabb::new(
        Vec3::new(-half + i0 as f32 * step, lo, -half + j0 as f32 * step),
        Vec3::new(-half + i1 as f32 * step, hi, -half + j1 as f32 * step),
    )
}

/// Appends the horizon ring's triangles `horizon_src` to `mesh`'s indices by the sector of
/// the compass their centre lies in, so that the sectors behind the camera are not drawn;
/// each sector's bounds and index range.
fn horizon_sectors(mesh: &mut Mesh, horizon_src: &[u32]) -> Vec<(Aabb, Range<u32>)> {
    let mut by_sector: Vec<Vec<u32>> = vec![Vec::new(); HORIZON_SECTORS];
    for t in horizon_src.chunks_exact(3) {
        let c = t
            .iter()
            .map(|&v| Vec3::from(mesh.vertices[v as usize].position))
            .sum::<Vec3>()
            / 3.0;
        let turn = (c.z.atan2(c.x) / std::f32::consts::TAU).rem_euclid(1.0);
        let k = ((turn * HORIZON_SECTORS as f32) as usize).min(HORIZON_SECTORS - 1);
        by_sector[k].extend_from_slice(t);
    }
    let mut horizon = Vec::new();
    for tris in by_sector.iter().filter(|t| !t.is_empty()) {
        let start = mesh.indices.len() as u32;
        let bounds = Aabb::from_points(
            tris.iter()
                .map(|&v| Vec3::from(mesh.vertices[v as usize].position)),
        );
        mesh.indices.extend_from_slice(tris);
        horizon.push((bounds, start..mesh.indices.len() as u32));
    }
    horizon
}

/// The largest error of each level of each chunk (rows of `spans` by z, then by x).
fn chunk_errors(
    h: &impl Fn(usize, usize) -> f32,
    spans: &[(usize, usize)],
) -> Vec<[f32; TERRAIN_LODS]> {
    let mut errors = Vec::with_capacity(spans.len() * spans.len());
    for &(j0, j1) in spans {
        for &(i0, i1) in spans {
            let mut e = [0.0f32; TERRAIN_LODS];
            for (l, el) in e.iter_mut().enumerate().skip(1) {
                *el = level_error(h, (i0, i1), (j0, j1), 1 << l);
            }
            errors.push(e);
        }
    }
    errors
}

/// The terrain mesh while its levels' surfaces and skirts are appended, with the vertices
/// made for them.
struct LevelMesh {
    mesh: Mesh,
    res: usize,
    skirt_depth: f32,
    /// A lowered copy of every grid point on a chunk line (made on first use).
    skirt_of: HashMap<u32, u32>,
    /// Each coarser level's copy of a grid point, by level and grid point.
    level_of: HashMap<(usize, usize, usize), u32>,
    /// The largest error of the coarse quads around each coarse vertex.
    quad_lift: HashMap<u32, f32>,
}

impl LevelMesh {
    fn new(mesh: Mesh, res: usize, skirt_depth: f32) -> Self {
        LevelMesh {
            mesh,
            res,
            skirt_depth,
            skirt_of: HashMap::new(),
            level_of: HashMap::new(),
            quad_lift: HashMap::new(),
        }
    }

    /// The lowered copy of vertex `v`, made on first use.
    fn skirt_vertex(&mut self, v: u32) -> u32 {
        let mesh = &mut self.mesh;
        let skirt_depth = self.skirt_depth;
        *self.skirt_of.entry(v).or_insert_with(|| {
            let mut copy = mesh.vertices[v as usize];
            copy.position[1] -= skirt_depth;
            mesh.vertices.push(copy);
            (mesh.vertices.len() - 1) as u32
        })
    }

    /// Level l's vertex at grid point (i, j): the grid's own at level 0; coarser, a copy
    /// at the same place whose normal and colour are the grid's filtered over the
    /// level's spacing (tent weights), as a texture's coarser mip would hold them, so
    /// that a coarse chunk shows the average of the detail it skips.
    fn at(&mut self, l: usize, i: usize, j: usize) -> u32 {
        let res = self.res;
        let mesh = &mut self.mesh;
        let own = (j * res + i) as u32;
        if l == 0 {
            return own;
        }
        *self.level_of.entry((l, i, j)).or_insert_with(|| {
            let step = 1i64 << l;
            let mut normal = Vec3::ZERO;
            let mut color = Vec3::ZERO;
            let mut weight = 0.0f32;
            for dj in 1 - step..step {
                for di in 1 - step..step {
                    let (x, z) = (i as i64 + di, j as i64 + dj);
                    if x < 0 || z < 0 || x >= res as i64 || z >= res as i64 {
                        continue;
                    }
                    let w = (1.0 - di.abs() as f32 / step as f32)
                        * (1.0 - dj.abs() as f32 / step as f32);
                    let v = &mesh.vertices[z as usize * res + x as usize];
                    normal += w * Vec3::from(v.normal);
                    color += w * Vec3::from(v.color);
                    weight += w;
                }
            }
            let mut v = mesh.vertices[own as usize];
            v.normal = normal.try_normalize().unwrap_or(Vec3::Y).to_array();
            v.color = (color / weight.max(1e-6)).to_array();
            mesh.vertices.push(v);
            (mesh.vertices.len() - 1) as u32
        })
    }

    /// Level `l`'s surface over the grid points `xs` x `zs`.
    fn surface(&mut self, h: &impl Fn(usize, usize) -> f32, l: usize, xs: &[usize], zs: &[usize]) {
        for w in zs.windows(2) {
            for u in xs.windows(2) {
                let v00 = self.at(l, u[0], w[0]);
                let v10 = self.at(l, u[1], w[0]);
                let v01 = self.at(l, u[0], w[1]);
                let v11 = self.at(l, u[1], w[1]);
                self.mesh
                    .indices
                    .extend_from_slice(&[v00, v01, v10, v10, v01, v11]);
                if l > 0 {
                    let e = quad_error(h, (u[0], u[1]), (w[0], w[1]));
                    for v in [v00, v10, v01, v11] {
                        let slot = self.quad_lift.entry(v).or_insert(0.0);
                        *slot = slot.max(e);
                    }
                }
            }
        }
    }

    /// Level `l`'s skirts along the four edges of the chunk `is` x `js` (its grid points
    /// `xs` and `zs` at that level), where `inner` says an edge's line needs one.
    fn skirts(
        &mut self,
        l: usize,
        (xs, zs): (&[usize], &[usize]),
        (i0, i1): (usize, usize),
        (j0, j1): (usize, usize),
        inner: impl Fn(usize) -> bool,
    ) {
        // Along the four edges, both windings.
        let edges: [(bool, Vec<u32>); 4] = [
            (inner(j0), xs.iter().map(|&i| self.at(l, i, j0)).collect()),
            (inner(j1), xs.iter().map(|&i| self.at(l, i, j1)).collect()),
            (inner(i0), zs.iter().map(|&j| self.at(l, i0, j)).collect()),
            (inner(i1), zs.iter().map(|&j| self.at(l, i1, j)).collect()),
        ];
        for (_, edge) in edges.iter().filter(|(needed, _)| *needed) {
            for pair in edge.windows(2) {
                let (a, b) = (pair[0], pair[1]);
                let a2 = self.skirt_vertex(a);
                let b2 = self.skirt_vertex(b);
                self.mesh
                    .indices
                    .extend_from_slice(&[a, b, a2, b, b2, a2, a, a2, b, b, a2, b2]);
            }
        }
    }

    /// The mesh with its level and skirt vertices' uvs set.
    fn finish(mut self) -> Mesh {
        // What `shaders/geometry.wgsl` reads in a terrain vertex's uv: in x, 0 at level 0
        // and -(1 + e) at a coarser level, e being the height error of the coarse quads
        // around the vertex, by which its point is raised for the terrain's own shadows (a
        // surface that cuts below the hills would be shadowed by them in the terrain's
        // depth map), the sign saying that the vertex is a coarse level's (shaded from the
        // terrain's maps, which keep the detail its grid points skip);
        // in y, how far a skirt hangs below the edge it hangs from, which it is shaded as.
        for &v in self.level_of.values() {
            let e = self.quad_lift.get(&v).copied().unwrap_or(0.0);
            self.mesh.vertices[v as usize].uv[0] = -(1.0 + e);
        }
        for (&top, &skirt) in &self.skirt_of {
            let edge = self.mesh.vertices[top as usize].uv;
            self.mesh.vertices[skirt as usize].uv = [edge[0], self.skirt_depth];
        }
        self.mesh
    }
}

/// The largest vertical distance between the grid points of the chunk `is` x `js` and the
/// surface of its level with a point every `step`.
fn level_error(
    h: &impl Fn(usize, usize) -> f32,
    (i0, i1): (usize, usize),
    (j0, j1): (usize, usize),
    step: usize,
) -> f32 {
    let xs = samples(i0, i1, step);
    let zs = samples(j0, j1, step);
    let mut worst = 0.0f32;
    for w in zs.windows(2) {
        for u in xs.windows(2) {
            worst = worst.max(quad_error(h, (u[0], u[1]), (w[0], w[1])));
        }
    }
    worst
}

/// The largest vertical distance between the grid points of the quad from grid point
/// (i0, j0) to (i1, j1) and its two triangles, split as [`Terrain::mesh`] splits its
/// cells (along the diagonal from +x to +z).
fn quad_error(
    h: &impl Fn(usize, usize) -> f32,
    (i0, i1): (usize, usize),
    (j0, j1): (usize, usize),
) -> f32 {
    let (h00, h10, h01, h11) = (h(i0, j0), h(i1, j0), h(i0, j1), h(i1, j1));
    let mut worst = 0.0f32;
    for j in j0..=j1 {
        for i in i0..=i1 {
            let s = (i - i0) as f32 / (i1 - i0).max(1) as f32;
            let t = (j - j0) as f32 / (j1 - j0).max(1) as f32;
            let coarse = if s + t <= 1.0 {
                h00 + s * (h10 - h00) + t * (h01 - h00)
            } else {
                h11 + (1.0 - s) * (h01 - h11) + (1.0 - t) * (h10 - h11)
            };
            worst = worst.max((coarse - h(i, j)).abs());
        }
    }
    worst
}

#[cfg(test)]
mod tests {
    use super::*;

    fn terrain(res: u32, height: impl Fn(usize, usize) -> f32) -> Terrain {
        let r = res as usize;
        Terrain {
            size: 100.0,
            resolution: res,
            heights: (0..r * r).map(|k| height(k % r, k / r)).collect(),
            far: None,
        }
    }

    fn triangles(indices: &[u32], vertices: &[crate::model::Vertex]) -> Vec<[[i64; 3]; 3]> {
        let key = |v: u32| {
            let p = vertices[v as usize].position;
            [p[0], p[1], p[2]].map(|x| (x * 1000.0).round() as i64)
        };
        let mut t: Vec<[[i64; 3]; 3]> = indices
            .chunks_exact(3)
            .map(|t| {
                let mut k = [key(t[0]), key(t[1]), key(t[2])];
                k.sort();
                k
            })
            .collect();
        t.sort();
        t
    }

    #[test]
    fn the_full_range_is_the_mesh() {
        let t = terrain(70, |i, j| ((i * 7 + j * 3) % 11) as f32);
        let c = t.chunked();
        let mesh = t.mesh();
        let full = &c.mesh.indices[c.layout.full.start as usize..c.layout.full.end as usize];
        assert_eq!(
            triangles(full, &c.mesh.vertices),
            triangles(&mesh.indices, &mesh.vertices)
        );
        // 69 cells: chunks of 32, 32 and 5.
        assert_eq!(c.layout.chunks.len(), 9);
    }

    #[test]
    fn a_spike_is_the_error_of_the_levels_that_skip_it() {
        // Flat but for one grid point (33, 33): odd, so every coarser level skips it.
        let t = terrain(65, |i, j| if (i, j) == (33, 33) { 5.0 } else { 1.0 });
        let c = t.chunked();
        for (k, chunk) in c.layout.chunks.iter().enumerate() {
            let holds = k == 3; // the chunk at cells 32..64 in x, 32..64 in z
            assert_eq!(chunk.error[0], 0.0);
            for l in 1..TERRAIN_LODS {
                let want = if holds { 4.0 } else { 0.0 };
                assert!(
                    (chunk.error[l] - want).abs() < 1e-5,
                    "chunk {k} level {l}: {:?}",
                    chunk.error
                );
            }
        }
    }

    #[test]
    fn levels_follow_distance_and_the_tolerance() {
        let t = terrain(129, |i, j| {
            (i as f32 * 0.3).sin() * 3.0 + (j as f32 * 0.2).cos() * 2.0
        });
        let c = t.chunked();
        let eye = Vec3::new(-50.0, 10.0, -50.0);
        // 100 m terrain, cells of 0.78 m: at a focal length of 100 px every level's
        // spacing stays within 4 px from 16 m on.
        let near = c.layout.levels(eye, 100.0, 0.5);
        assert_eq!(near[0], 0, "the chunk under the eye is full detail");
        let far = c.layout.levels(eye, 100.0, 50.0);
        assert!(far[15] > near[0], "{far:?}");
        assert!(far.iter().zip(&near).all(|(f, n)| f >= n));
        assert!(c.layout.levels(eye, 100.0, 0.0).iter().all(|&l| l == 0));
        assert!(
            c.layout
                .levels(eye, 100.0, f32::NAN)
                .iter()
                .all(|&l| l == 0)
        );
    }

    /// Every edge point of every chunk at every level (but the square's border: no horizon
    /// ring here) has a skirt vertex under it, lower
    /// than the point by more than any level's error: whatever levels two neighbours are
    /// drawn at, the gap between their edges is closed.
    #[test]
    fn every_edge_point_of_every_level_has_a_skirt_deep_enough() {
        let t = terrain(70, |i, j| ((i * 13 + j * 7) % 17) as f32 * 0.5);
        let c = t.chunked();
        let worst = c
            .layout
            .chunks
            .iter()
            .flat_map(|ch| ch.error)
            .fold(0.0f32, f32::max);
        for ch in &c.layout.chunks {
            let (lo, hi) = (ch.bounds.min, ch.bounds.max);
            for l in 0..TERRAIN_LODS {
                let mut used: Vec<u32> =
                    c.mesh.indices[ch.ranges[l].start as usize..ch.ranges[l].end as usize].to_vec();
                if l == 0 {
                    used.extend_from_slice(
                        &c.mesh.indices[ch.skirts0.start as usize..ch.skirts0.end as usize],
                    );
                }
                let pos = |v: &u32| Vec3::from(c.mesh.vertices[*v as usize].position);
                let on_edge = |p: Vec3| {
                    (p.x - lo.x).abs() < 1e-3
                        || (p.x - hi.x).abs() < 1e-3
                        || (p.z - lo.z).abs() < 1e-3
                        || (p.z - hi.z).abs() < 1e-3
                };
                // The square's border has no skirt (no horizon ring here to meet).
                let border = |p: Vec3| p.x.abs() > 49.99 || p.z.abs() > 49.99;
                let edge: Vec<Vec3> = used
                    .iter()
                    .map(pos)
                    .filter(|p| on_edge(*p) && !border(*p) && p.y >= lo.y - 1e-3)
                    .collect();
                assert!(!edge.is_empty());
                for p in edge {
                    let under = used.iter().map(pos).any(|q| {
                        (q.x - p.x).abs() < 1e-3 && (q.z - p.z).abs() < 1e-3 && q.y < p.y - worst
                    });
                    assert!(under, "level {l}: no skirt under {p}");
                }
            }
        }
    }

    #[test]
    fn skirts_hang_below_every_level_and_are_shaded_from_their_edge() {
        let t = terrain(65, |i, j| ((i * 13 + j * 7) % 17) as f32 * 0.5);
        let c = t.chunked();
        let lowest = t.heights.iter().copied().fold(f32::INFINITY, f32::min);
        let worst = c
            .layout
            .chunks
            .iter()
            .flat_map(|ch| ch.error)
            .fold(0.0f32, f32::max);
        let mut skirts = 0;
        for v in &c.mesh.vertices {
            if v.position[1] < lowest - 1e-3 {
                skirts += 1;
                // Lifted back at least to the ground it hangs from when shaded.
                assert!(v.uv[1] >= worst, "{v:?}");
                assert!(v.position[1] + v.uv[1] >= lowest - 1e-3, "{v:?}");
            }
        }
        assert!(skirts > 0);
    }

    #[test]
    fn coarse_vertices_are_marked_and_carry_their_lift() {
        let t = terrain(65, |i, j| ((i * 13 + j * 7) % 17) as f32 * 0.5);
        let c = t.chunked();
        let res = 65 * 65;
        // The grid (level 0) is unmarked; every vertex after it that a coarser level's
        // surface uses is marked, its lift at least 0.
        assert!(c.mesh.vertices[..res].iter().all(|v| v.uv[0] == 0.0));
        let coarse: std::collections::HashSet<u32> = c
            .layout
            .chunks
            .iter()
            .flat_map(|ch| ch.ranges[1..].iter().cloned())
            .flat_map(|r| c.mesh.indices[r.start as usize..r.end as usize].to_vec())
            .collect();
        assert!(!coarse.is_empty());
        for v in coarse {
            assert!(v as usize >= res, "a coarse level draws grid vertex {v}");
            assert!(c.mesh.vertices[v as usize].uv[0] <= -1.0);
        }
        let level0 = &c.layout.chunks[0].ranges[0];
        for &v in &c.mesh.indices[level0.start as usize..level0.end as usize] {
            assert_eq!(c.mesh.vertices[v as usize].uv[0], 0.0);
        }
    }
}
