//! A tree sampled into Guennebaud and Paulin's LDC tree (2002): three orthogonal layered
//! depth images (LDIs) at the finest spacing, each pixel a list of surfels where the
//! pixel's ray meets the tree's triangles; each coarser level made from the one below at
//! twice the spacing, a 2x2 group of pixels becoming one whose surfels are the children's
//! matched by depth and averaged (position, normal, colour); every level cut into blocks of
//! `BLOCK`³ cells, the octree's nodes, down to one block for the whole tree.
//!
//! Each triangle is sampled in the LDI whose axis it faces most (the paper's LDIs each hold
//! every surface; drawn with partial coverage, a surface held three times would cover its
//! pixels up to three times). A triangle narrower than the spacing may fall between the
//! pixels' rays; it then gets one surfel at its centroid, weighted by the share of the
//! pixel it covers, so that needles and small leaves keep their share of the crown.

use std::collections::HashMap;

use glam::{Mat3, Mat4, Vec2, Vec3};

use crate::format::{Surfel, SurfelDensity, SurfelNode, SurfelSet, pack_surfel};
use crate::model::TreeModel;
use crate::model::gltf::Material;
use crate::model::mesh::{Aabb, Mesh};

/// Cells on a block's side at every level (the paper's b).
pub const BLOCK: u32 = 8;
/// Most levels of a tree (the finest spacing's side then spans at most BLOCK · 2^(MAX-1)).
pub const MAX_LEVELS: usize = crate::format::MAX_SURFEL_LEVELS as usize;

/// A tree's LDC tree: the set as the file stores it and the method draws it, and its
/// surfels unpacked (those `set.words` holds packed), grouped by node.
#[derive(Clone, Debug, PartialEq)]
pub struct SurfelTree {
    pub set: SurfelSet,
    pub surfels: Vec<Surfel>,
}

/// Voxels on the longest side of a tree's density volume.
pub const DENSITY_SIDE: u32 = 32;

/// A tree's surfaces over `bounds` as a volume of extinction coefficients (1/m): each
/// voxel's surface area (from the level-0 surfels and the area each stands for) times a
/// half (the mean share of a randomly turned leaf's area a ray sees) over the voxel's
/// volume.
fn density_of(bounds: &Aabb, surfels: &[(Surfel, f32)]) -> SurfelDensity {
    let ext = bounds.extent().max(Vec3::splat(1e-3));
    let voxel = ext.max_element() / DENSITY_SIDE as f32;
    let dims = (ext / voxel)
        .ceil()
        .as_uvec3()
        .clamp(glam::UVec3::ONE, glam::UVec3::splat(DENSITY_SIDE))
        .to_array();
    let mut sigma = vec![0.0f32; (dims[0] * dims[1] * dims[2]) as usize];
    let volume = voxel * voxel * voxel;
    for (s, area) in surfels {
        let v = ((s.position - bounds.min) / voxel)
            .max(Vec3::ZERO)
            .as_uvec3();
        let v = v.min(glam::UVec3::from(dims) - 1);
        sigma[((v.z * dims[1] + v.y) * dims[0] + v.x) as usize] += 0.5 * area / volume;
    }
    SurfelDensity {
        origin: bounds.min,
        voxel,
        dims,
        sigma,
    }
}

/// Sky directions the openness is averaged over (cosine-distributed on the upper
/// hemisphere).
const SKY_DIRECTIONS: u32 = 32;

/// Per voxel of `d`, the share of the sky the volume leaves open from its centre: the
/// transmittance along [`SKY_DIRECTIONS`] cosine-distributed directions of the upper
/// hemisphere, a voxel a step from half a voxel out, averaged.
fn openness_volume(d: &SurfelDensity) -> Vec<f32> {
    use rayon::prelude::*;
    // A Fibonacci spiral over the disc, lifted onto the hemisphere (cosine-distributed).
    let dirs: Vec<Vec3> = (0..SKY_DIRECTIONS)
        .map(|k| {
            let r = ((k as f32 + 0.5) / SKY_DIRECTIONS as f32).sqrt();
            let a = k as f32 * 2.399_963;
            Vec3::new(r * a.cos(), (1.0 - r * r).max(0.0).sqrt(), r * a.sin())
        })
        .collect();
    let [nx, ny, nz] = d.dims;
    let dims = Vec3::new(nx as f32, ny as f32, nz as f32);
    (0..nx * ny * nz)
        .into_par_iter()
        .map(|i| {
            let c = Vec3::new(
                (i % nx) as f32,
                ((i / nx) % ny) as f32,
                (i / (nx * ny)) as f32,
            ) + 0.5;
            let mut open = 0.0;
            for dir in &dirs {
                let mut x = c + 0.5 * *dir;
                let mut tau = 0.0;
                while x.cmpge(Vec3::ZERO).all() && x.cmplt(dims).all() {
                    let v = x.as_uvec3();
                    tau += d.sigma[((v.z * ny + v.y) * nx + v.x) as usize];
                    x += *dir;
                }
                open += (-tau * d.voxel).exp();
            }
            open / SKY_DIRECTIONS as f32
        })
        .collect()
}

/// The value of the voxel volume `values` (laid out as `d`) at `p` (tree frame),
/// trilinear between voxel centres.
fn trilinear(d: &SurfelDensity, values: &[f32], p: Vec3) -> f32 {
    let [nx, ny, nz] = d.dims;
    let hi = Vec3::new(nx as f32, ny as f32, nz as f32) - 1.0;
    let x = ((p - d.origin) / d.voxel - 0.5).clamp(Vec3::ZERO, hi);
    let i0 = x.floor().as_uvec3();
    let i1 = (i0 + 1).min(glam::UVec3::new(nx - 1, ny - 1, nz - 1));
    let f = x - x.floor();
    let at = |i: u32, j: u32, k: u32| values[((k * ny + j) * nx + i) as usize];
    let lerp = |a: f32, b: f32, t: f32| a + (b - a) * t;
    let plane = |k: u32| {
        lerp(
            lerp(at(i0.x, i0.y, k), at(i1.x, i0.y, k), f.x),
            lerp(at(i0.x, i1.y, k), at(i1.x, i1.y, k), f.x),
            f.y,
        )
    };
    lerp(plane(i0.z), plane(i1.z), f.z)
}

/// A triangle to sample, in the tree frame.
struct Tri {
    p: [Vec3; 3],
    n: [Vec3; 3],
    c: [Vec3; 3],
    uv: [Vec2; 3],
    foliage: bool,
    material: Option<u32>,
}

/// Every triangle of `tree` in the tree frame, with its material where the tree has them.
fn triangles(tree: &TreeModel) -> Vec<Tri> {
    let surfaces = tree.surfaces.as_deref();
    let mut out = Vec::new();
    let mut part =
        |mesh: &Mesh, ranges: Option<&[crate::model::tree::SurfaceRange]>, at: &[Mat4]| {
            let tris = mesh.indices.len() / 3;
            let mut material: Vec<Option<u32>> = vec![None; tris];
            for r in ranges.unwrap_or(&[]) {
                let first = (r.first / 3) as usize;
                let last = (first + (r.count / 3) as usize).min(tris);
                for m in material.iter_mut().take(last).skip(first) {
                    *m = Some(r.material);
                }
            }
            for m in at {
                let linear = Mat3::from_mat4(*m);
                let nm = if linear.determinant().abs() > 1e-30 {
                    linear.inverse().transpose()
                } else {
                    linear
                };
                for (t, idx) in mesh.indices.chunks_exact(3).enumerate() {
                    let Some(v) = idx
                        .iter()
                        .map(|&i| mesh.vertices.get(i as usize))
                        .collect::<Option<Vec<_>>>()
                    else {
                        continue;
                    };
                    out.push(Tri {
                        p: [0, 1, 2].map(|k| m.transform_point3(Vec3::from(v[k].position))),
                        n: [0, 1, 2].map(|k| (nm * Vec3::from(v[k].normal)).normalize_or_zero()),
                        c: [0, 1, 2].map(|k| Vec3::from(v[k].color)),
                        uv: [0, 1, 2].map(|k| Vec2::from(v[k].uv)),
                        foliage: v[0].foliage > 0.5,
                        material: material[t],
                    });
                }
            }
        };
    part(
        &tree.trunk,
        surfaces.map(|s| s.trunk.as_slice()),
        &[Mat4::IDENTITY],
    );
    part(
        &tree.branch_limb,
        surfaces.map(|s| s.limb.as_slice()),
        &tree.tree_branches,
    );
    part(
        &tree.twig,
        surfaces.map(|s| s.twig.as_slice()),
        &tree.twigs_in_tree_frame(),
    );
    out
}

/// The colour and alpha of `material`'s texture at `uv` (nearest texel, repeated), linear.
fn texel(material: &Material, uv: Vec2) -> Option<(Vec3, f32)> {
    let t = material.texture.as_ref()?;
    if t.width == 0 || t.height == 0 {
        return None;
    }
    let x = (uv.x.rem_euclid(1.0) * t.width as f32) as u32 % t.width;
    let y = (uv.y.rem_euclid(1.0) * t.height as f32) as u32 % t.height;
    let at = ((y * t.width + x) * 4) as usize;
    let px = t.pixels.get(at..at + 4)?;
    let c = Vec3::new(
        crate::color::srgb_to_linear(px[0]),
        crate::color::srgb_to_linear(px[1]),
        crate::color::srgb_to_linear(px[2]),
    );
    Some((c, f32::from(px[3]) / 255.0))
}

/// One surfel of an LDI: its pixel, the pixel of the level below it came from (its own at
/// level 0), its depth along the axis, its weight (the level-0 cells it covers) and what it
/// holds.
#[derive(Clone, Copy)]
struct Entry {
    pixel: u32,
    src: u32,
    depth: f32,
    weight: f32,
    s: Surfel,
}

/// One of the three LDIs of a level.
struct Ldi {
    axis: usize,
    dims: [u32; 2],
    entries: Vec<Entry>,
}

/// The axes across an LDI along `axis`.
fn across(axis: usize) -> (usize, usize) {
    ((axis + 1) % 3, (axis + 2) % 3)
}

/// The surfel of `tri` at barycentric `b`, or None where its material's alpha test drops it.
fn surfel_at(tri: &Tri, b: Vec3, materials: &[Material]) -> Option<Surfel> {
    let position = tri.p[0] * b.x + tri.p[1] * b.y + tri.p[2] * b.z;
    let mut normal = (tri.n[0] * b.x + tri.n[1] * b.y + tri.n[2] * b.z).normalize_or_zero();
    if normal == Vec3::ZERO {
        normal = (tri.p[1] - tri.p[0])
            .cross(tri.p[2] - tri.p[0])
            .normalize_or(Vec3::Y);
    }
    if tri.foliage && normal.y < 0.0 {
        normal = -normal;
    }
    let mut albedo = tri.c[0] * b.x + tri.c[1] * b.y + tri.c[2] * b.z;
    if let Some(m) = tri.material.and_then(|m| materials.get(m as usize)) {
        let uv = tri.uv[0] * b.x + tri.uv[1] * b.y + tri.uv[2] * b.z;
        if let Some((c, a)) = texel(m, uv) {
            if a * m.base_color[3] < m.alpha_cutoff {
                return None;
            }
            albedo *= c;
        }
    }
    Some(Surfel {
        position,
        normal,
        albedo,
        foliage: tri.foliage,
        coverage: 1.0,
        openness: 1.0,
    })
}

/// Level 0: the three LDIs of `tris` over `bounds` at `spacing`.
fn sample_level0(tris: &[Tri], bounds: &Aabb, spacing: f32, materials: &[Material]) -> [Ldi; 3] {
    let ext = bounds.extent();
    [0, 1, 2].map(|axis| {
        let (a, b) = across(axis);
        let dims = [
            ((ext[a] / spacing).ceil() as u32).max(1),
            ((ext[b] / spacing).ceil() as u32).max(1),
        ];
        let mut entries = Vec::new();
        for tri in tris {
            let q = tri.p.map(|p| {
                Vec2::new(
                    (p[a] - bounds.min[a]) / spacing,
                    (p[b] - bounds.min[b]) / spacing,
                )
            });
            let area = (q[1] - q[0]).perp_dot(q[2] - q[0]);
            let face = (tri.p[1] - tri.p[0]).cross(tri.p[2] - tri.p[0]);
            let facing = face.abs();
            let dominant = facing[axis] >= facing[a] && facing[axis] >= facing[b];
            // Each triangle in the LDI it faces most: the three LDIs hold each surface once.
            if !dominant {
                continue;
            }
            let mut hits = 0usize;
            if area.abs() > 1e-12 {
                let lo = q[0].min(q[1]).min(q[2]);
                let hi = q[0].max(q[1]).max(q[2]);
                let i0 = (lo.x - 0.5).ceil().max(0.0) as u32;
                let j0 = (lo.y - 0.5).ceil().max(0.0) as u32;
                let i1 = ((hi.x - 0.5).floor() as i64).min(i64::from(dims[0]) - 1);
                let j1 = ((hi.y - 0.5).floor() as i64).min(i64::from(dims[1]) - 1);
                for j in i64::from(j0)..=j1 {
                    for i in i64::from(i0)..=i1 {
                        let c = Vec2::new(i as f32 + 0.5, j as f32 + 0.5);
                        let w0 = (q[2] - q[1]).perp_dot(c - q[1]) / area;
                        let w1 = (q[0] - q[2]).perp_dot(c - q[2]) / area;
                        let w2 = 1.0 - w0 - w1;
                        if w0 < 0.0 || w1 < 0.0 || w2 < 0.0 {
                            continue;
                        }
                        let bary = Vec3::new(w0, w1, w2);
                        if let Some(s) = surfel_at(tri, bary, materials) {
                            hits += 1;
                            entries.push(Entry {
                                pixel: j as u32 * dims[0] + i as u32,
                                src: j as u32 * dims[0] + i as u32,
                                depth: s.position[axis],
                                weight: 1.0,
                                s,
                            });
                        }
                    }
                }
            }
            if hits == 0 && facing[axis] > 0.0 {
                let bary = Vec3::splat(1.0 / 3.0);
                if let Some(s) = surfel_at(tri, bary, materials) {
                    let c = (q[0] + q[1] + q[2]) / 3.0;
                    let i = (c.x.max(0.0) as u32).min(dims[0] - 1);
                    let j = (c.y.max(0.0) as u32).min(dims[1] - 1);
                    entries.push(Entry {
                        pixel: j * dims[0] + i,
                        src: j * dims[0] + i,
                        depth: s.position[axis],
                        weight: (area.abs() * 0.5).min(1.0),
                        s,
                    });
                }
            }
        }
        entries.sort_by(|x, y| x.pixel.cmp(&y.pixel).then(x.depth.total_cmp(&y.depth)));
        // Surfels of one pixel closer in depth than the spacing are one surface (the many
        // needles of a twig that fall in one pixel).
        Ldi {
            axis,
            dims,
            entries: cluster(&entries, spacing, 1.0, 1.0),
        }
    })
}

/// `sorted` (by pixel, then depth) with each pixel's surfels less than `spacing` apart in
/// depth merged. A merged surfel covers what its parts cover: those from one pixel of the
/// level below (`below` level-0 cells) overlap as independent layers (the share left open
/// is the product of theirs), those from different pixels add up, to at most `cells` (the
/// level-0 cells of its own pixel).
fn cluster(sorted: &[Entry], spacing: f32, cells: f32, below: f32) -> Vec<Entry> {
    let mut out = Vec::new();
    let mut k = 0;
    while k < sorted.len() {
        let start = sorted[k];
        let mut end = k + 1;
        while end < sorted.len()
            && sorted[end].pixel == start.pixel
            && sorted[end].depth - start.depth < spacing
        {
            end += 1;
        }
        let group = &sorted[k..end];
        let mut e = merge(group);
        if group.len() > 1 {
            let mut open: Vec<(u32, f32)> = Vec::new();
            for x in group {
                let share = 1.0 - (x.weight / below).min(1.0);
                match open.iter_mut().find(|(src, _)| *src == x.src) {
                    Some(o) => o.1 *= share,
                    None => open.push((x.src, share)),
                }
            }
            e.weight = open.iter().map(|(_, o)| (1.0 - o) * below).sum();
        }
        e.weight = e.weight.min(cells);
        e.src = e.pixel;
        out.push(e);
        k = end;
    }
    out
}

/// The level above `ldi` (spacing `spacing`, twice its own; `cells` level-0 cells a
/// pixel): each 2x2 group of pixels one pixel, whose surfels are the children's matched by
/// depth (a cluster spans less than `spacing` along the axis) and averaged by weight.
fn parent(ldi: &Ldi, spacing: f32, cells: f32) -> Ldi {
    let dims = [ldi.dims[0].div_ceil(2), ldi.dims[1].div_ceil(2)];
    let mut moved: Vec<Entry> = ldi
        .entries
        .iter()
        .map(|e| {
            let (i, j) = (e.pixel % ldi.dims[0], e.pixel / ldi.dims[0]);
            Entry {
                pixel: (j / 2) * dims[0] + i / 2,
                src: e.pixel,
                ..*e
            }
        })
        .collect();
    moved.sort_by(|x, y| x.pixel.cmp(&y.pixel).then(x.depth.total_cmp(&y.depth)));
    Ldi {
        axis: ldi.axis,
        dims,
        entries: cluster(&moved, spacing, cells, cells / 4.0),
    }
}

/// The weighted mean of `group` (one pixel's surfels matched by depth).
fn merge(group: &[Entry]) -> Entry {
    if let [one] = group {
        return *one;
    }
    let total: f32 = group.iter().map(|e| e.weight).sum::<f32>().max(1e-12);
    let mut position = Vec3::ZERO;
    let mut normal = Vec3::ZERO;
    let mut albedo = Vec3::ZERO;
    let mut foliage = 0.0;
    let mut depth = 0.0;
    for e in group {
        let w = e.weight / total;
        position += e.s.position * w;
        normal += e.s.normal * e.weight;
        albedo += e.s.albedo * w;
        foliage += if e.s.foliage { w } else { 0.0 };
        depth += e.depth * w;
    }
    Entry {
        pixel: group[0].pixel,
        src: group[0].src,
        depth,
        weight: total,
        s: Surfel {
            position,
            normal: normal.normalize_or(group[0].s.normal),
            albedo,
            foliage: foliage >= 0.5,
            coverage: 1.0,
            openness: 1.0,
        },
    }
}

/// `c` raised by `gain`: the coverage of `gain` layers of coverage `c`.
fn gained(c: f32, gain: f32) -> f32 {
    if gain == 1.0 || c >= 1.0 {
        c
    } else {
        1.0 - (1.0 - c).powf(gain)
    }
}

/// How much of the tree's silhouettes along the three axes `ldis` cover, drawn as the
/// splatting draws a level whose spacing is a pixel: per LDI pixel, what its surfels
/// leave open (each 1 - its coverage, raised by `gain`, seen along the axis) multiplied;
/// in the level's cells (`cells` level-0 cells each).
fn silhouette(ldis: &[Ldi; 3], cells: f32, gain: f32) -> f64 {
    let mut covered = 0.0f64;
    for ldi in ldis {
        let mut k = 0;
        while k < ldi.entries.len() {
            let pixel = ldi.entries[k].pixel;
            let mut open = 1.0f64;
            while k < ldi.entries.len() && ldi.entries[k].pixel == pixel {
                let e = &ldi.entries[k];
                let n = e.s.normal.abs();
                let seen = (n[ldi.axis] / n.max_element().max(0.3)).min(1.0);
                let c = gained((e.weight / cells).min(1.0), gain) * seen;
                open *= f64::from(1.0 - c);
                k += 1;
            }
            covered += 1.0 - open;
        }
    }
    covered * f64::from(cells)
}

/// The gain (1 to 16) that makes the silhouettes of a coarser level's `ldis` cover
/// `target` (level 0's, in level-0 cells): a merged surfel that stands for surfaces
/// overlapping in its cell covers their union, which a level made of coarser cells
/// under-counts where crowns are deep.
fn calibration(ldis: &[Ldi; 3], cells: f32, target: f64) -> f32 {
    if cells <= 1.0 || silhouette(ldis, cells, 1.0) >= target {
        return 1.0;
    }
    let (mut lo, mut hi) = (1.0f32, 16.0f32);
    if silhouette(ldis, cells, hi) <= target {
        return hi;
    }
    for _ in 0..24 {
        let mid = 0.5 * (lo + hi);
        if silhouette(ldis, cells, mid) < target {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    0.5 * (lo + hi)
}

/// About how many level-0 surfels `tris` give at `spacing`: their areas across the axes
/// they face most, in pixels (triangles smaller than a pixel share their pixels once
/// merged by depth).
fn expected_count(tris: &[Tri], spacing: f32) -> f64 {
    tris.iter()
        .map(|t| {
            let face = (t.p[1] - t.p[0]).cross(t.p[2] - t.p[0]) * 0.5;
            f64::from(face.abs().max_element()) / f64::from(spacing * spacing)
        })
        .sum()
}

/// The finest spacing that gives about `budget` level-0 surfels (never below `min`).
fn spacing_for(tris: &[Tri], budget: u32, min: f32, bounds: &Aabb) -> f32 {
    let ext = bounds.extent().max_element().max(1e-3);
    let (mut lo, mut hi) = (min.max(ext / 65_535.0), ext);
    if expected_count(tris, lo) <= f64::from(budget) {
        return lo;
    }
    for _ in 0..30 {
        let mid = (lo * hi).sqrt();
        if expected_count(tris, mid) > f64::from(budget) {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    hi
}

/// Every species of `species` sampled into its LDC tree (about `budget` level-0 surfels
/// each, no finer than `min_spacing`), in parallel; each set numbered by its species.
pub fn sample_species(species: &[TreeModel], budget: u32, min_spacing: f32) -> Vec<SurfelSet> {
    use rayon::prelude::*;
    species
        .par_iter()
        .enumerate()
        .map(|(i, t)| SurfelSet {
            species: i as u32,
            ..sample_tree(t, budget, min_spacing).set
        })
        .collect()
}

/// `tree` sampled into an LDC tree of about `budget` surfels at its finest level, no finer
/// than `min_spacing` (m).
pub fn sample_tree(tree: &TreeModel, budget: u32, min_spacing: f32) -> SurfelTree {
    let tris = triangles(tree);
    let materials: &[Material] = tree
        .surfaces
        .as_deref()
        .map_or(&[], |s| s.materials.as_slice());
    let bounds = tree.tree_bounds;
    let spacing0 = spacing_for(&tris, budget.max(1), min_spacing, &bounds);
    sample_triangles(&tris, materials, bounds, spacing0)
}

/// The LDC tree of `tris` over `bounds` with level-0 spacing `spacing0`.
fn sample_triangles(
    tris: &[Tri],
    materials: &[Material],
    bounds: Aabb,
    spacing0: f32,
) -> SurfelTree {
    let mut levels: Vec<[Ldi; 3]> = vec![sample_level0(tris, &bounds, spacing0, materials)];
    let cells = |spacing: f32| (bounds.extent().max_element() / spacing).ceil() as u32;
    while levels.len() < MAX_LEVELS && cells(spacing0 * (1 << (levels.len() - 1)) as f32) > BLOCK {
        let spacing = spacing0 * (1 << levels.len()) as f32;
        let below = levels.last().expect("level 0");
        let cells = (1u64 << (2 * levels.len())) as f32;
        levels.push([0, 1, 2].map(|a| parent(&below[a], spacing, cells)));
    }
    let mut surfels: Vec<Surfel> = Vec::new();
    let mut nodes: Vec<SurfelNode> = Vec::new();
    let mut per_level = Vec::new();
    let mut gains = Vec::new();
    // The surface each level-0 surfel stands for: its share of a cell, over the cosine
    // between its normal and its LDI's axis.
    let cell = spacing0 * spacing0;
    let areas: Vec<(Surfel, f32)> = levels[0]
        .iter()
        .flat_map(|ldi| {
            ldi.entries.iter().map(move |e| {
                let cos = e.s.normal[ldi.axis].abs().max(0.3);
                (e.s, e.weight.min(1.0) * cell / cos)
            })
        })
        .collect();
    let density = density_of(&bounds, &areas);
    let open = openness_volume(&density);
    // Nodes level by level, finest first, so that a node's children are known when it is
    // made; each level's blocks are cells of BLOCK · spacing from the bounds' corner.
    let target = silhouette(&levels[0], 1.0, 1.0);
    let mut below: HashMap<[u32; 3], u32> = HashMap::new();
    for (l, ldis) in levels.iter().enumerate() {
        let gain = calibration(ldis, (1u64 << (2 * l)) as f32, target);
        gains.push(gain);
        let side = BLOCK as f32 * spacing0 * (1u32 << l) as f32;
        let key = |p: Vec3| {
            let c = ((p - bounds.min) / side).max(Vec3::ZERO);
            [c.x as u32, c.y as u32, c.z as u32]
        };
        // A surfel's weight counts level-0 cells; a cell of level l holds 4^l of them.
        let cells = (1u64 << (2 * l)) as f32;
        let mut all: Vec<(Surfel, [u32; 3])> = ldis
            .iter()
            .flat_map(|ldi| {
                ldi.entries.iter().map(|e| {
                    let s = Surfel {
                        coverage: gained((e.weight / cells).min(1.0), gain),
                        openness: trilinear(&density, &open, e.s.position),
                        ..e.s
                    };
                    (s, key(e.s.position))
                })
            })
            .collect();
        all.sort_by_key(|(_, k)| (k[2], k[1], k[0]));
        per_level.push(all.len() as u32);
        let mut here: HashMap<[u32; 3], u32> = HashMap::new();
        let mut k = 0;
        while k < all.len() {
            let block = all[k].1;
            let mut end = k;
            let first = surfels.len() as u32;
            let mut b = Aabb::EMPTY;
            while end < all.len() && all[end].1 == block {
                surfels.push(all[end].0);
                b = b.including(all[end].0.position);
                end += 1;
            }
            let pad = Vec3::splat(0.5 * spacing0 * (1u32 << l) as f32);
            let children = if l == 0 {
                Vec::new()
            } else {
                let mut c = Vec::new();
                for d in 0..8u32 {
                    let child = [
                        2 * block[0] + (d & 1),
                        2 * block[1] + ((d >> 1) & 1),
                        2 * block[2] + ((d >> 2) & 1),
                    ];
                    if let Some(&n) = below.get(&child) {
                        c.push(n);
                    }
                }
                c
            };
            here.insert(block, nodes.len() as u32);
            nodes.push(SurfelNode {
                level: l as u32,
                bounds: Aabb::new(b.min - pad, b.max + pad),
                first,
                count: (end - k) as u32,
                children,
            });
            k = end;
        }
        below = here;
    }
    let (qmin, qsize) = (bounds.min, bounds.extent());
    let words = surfels
        .iter()
        .flat_map(|s| pack_surfel(s, qmin, qsize))
        .collect();
    let roots = SurfelSet::roots_of(&nodes, per_level.len());
    debug_assert_eq!(roots.len(), below.len());
    SurfelTree {
        set: SurfelSet {
            species: 0,
            bounds,
            spacing0,
            gains,
            per_level,
            nodes,
            roots,
            words,
            density,
        },
        surfels,
    }
}

#[cfg(test)]
mod tests;
