//! The seeds' way of drawing a volumetric texel (`--texel-mode stacks`; Meyer-Neyret 1998
//! as Babahenini et al. state it, ../shared/seeds/DIGEST.md section 7): each volume cut
//! into three stacks of 2D slices, one per axis; per frame, per texel, the stack most
//! facing the eye (largest |V·axis|) is drawn back to front as textured quads, with
//! n = max(C1, C2) slices rounded up to a power of two ([`crate::slices::stack_slices`]).
//! A stack of N slices keeps pre-composited levels: level k holds N / 2^k slices, each the
//! Porter-Duff "over" of 2^k neighbours, built pairwise from level k - 1, once for each
//! viewing order (over is not commutative: seen from the other side the same slices
//! composite differently). Drawing n slices then costs n quads, not N.
//!
//! Everything lives in one 2D texture (the stack atlas): per species and axis a group of
//! equal tiles (the slice's two other sides, padded to 8 texels so that the atlas' 4 mip
//! levels never mix two tiles), per volume (each baked light, then the sky) the N slices
//! of level 0, then order 0's levels 1.., then order 1's. Order 0 is the eye on the axis'
//! negative side, so that lower slices are in front.
//!
//! The price the seeds name: three copies of every volume, and with the levels of both
//! orders about three times that again ([`StackAtlas::bytes`]); the slice direction
//! switches as the view turns (the pop `tests/texel.rs` measures).

use glam::{UVec2, UVec3};

use crate::format::TexelVolume;
use crate::render::pipelines::{
    FILTERABLE, sampled_rgba8_texture, sampler_entry, storage_buffer_of, storage_entry,
    texture_entry, write_growing, write_rgba8,
};
use crate::render::target::{linear_to_srgb, srgb_lut};
use crate::{Error, Result};

/// A premultiplied RGBA sample in linear light.
pub type Rgba = [f32; 4];

/// Porter-Duff "over" of premultiplied colours: `front` over `back`.
pub fn over(front: Rgba, back: Rgba) -> Rgba {
    let k = 1.0 - front[3];
    [
        front[0] + k * back[0],
        front[1] + k * back[1],
        front[2] + k * back[2],
        front[3] + k * back[3],
    ]
}

/// The next pre-composited level: slice j of the result is slices 2j and 2j + 1 of
/// `level` composited, the lower one in front when `low_in_front` (the eye on the axis'
/// negative side), the higher one otherwise. An odd last slice is kept as it is.
pub fn halve(level: &[Vec<Rgba>], low_in_front: bool) -> Vec<Vec<Rgba>> {
    level
        .chunks(2)
        .map(|pair| match pair {
            [a, b] => a
                .iter()
                .zip(b)
                .map(|(&lo, &hi)| {
                    if low_in_front {
                        over(lo, hi)
                    } else {
                        over(hi, lo)
                    }
                })
                .collect(),
            [a] => a.clone(),
            _ => Vec::new(),
        })
        .collect()
}

/// Tiles one volume of a stack of `n` slices (n a power of two) holds: level 0, then
/// levels 1..=log2(n) for each of the two orders.
pub fn tiles_per_volume(n: u32) -> u32 {
    n + 2 * (n - 1)
}

/// Where level `level` of viewing order `order` (0 or 1) starts among one volume's tiles
/// (level 0 is shared by both orders).
pub fn level_offset(n: u32, order: u32, level: u32) -> u32 {
    if level == 0 {
        return 0;
    }
    // Levels 1..level of one order hold n/2 + ... + n/2^(level-1) = n - n/2^(level-1).
    n + order * (n - 1) + (n - (n >> (level - 1)))
}

/// The two in-plane axes of a slice across `axis` (the lower first).
pub fn plane_axes(axis: usize) -> (usize, usize) {
    match axis {
        0 => (1, 2),
        1 => (0, 2),
        _ => (0, 1),
    }
}

/// One species' stack along one axis in the atlas.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct StackGroup {
    pub axis: usize,
    /// Slices at full resolution: the volume's side along the axis, rounded up to a power
    /// of two (the slices past the volume are empty).
    pub slices: u32,
    /// Texels of one tile (padded) and of its used part (the volume's two other sides).
    pub tile: UVec2,
    pub used: UVec2,
    /// The atlas texel where the group's first tile lies; tiles run in rows of `cols`.
    pub origin: UVec2,
    pub cols: u32,
    /// Volumes of the species (lights + 1).
    pub volumes: u32,
}

impl StackGroup {
    pub fn per_volume(&self) -> u32 {
        tiles_per_volume(self.slices)
    }

    /// The atlas texel where tile `index` of the group starts.
    pub fn tile_origin(&self, index: u32) -> UVec2 {
        self.origin + UVec2::new(index % self.cols, index / self.cols) * self.tile
    }
}

/// Slice tiles are multiples of this, and so are group origins: 4 mip levels never mix.
const TILE_ALIGN: u32 = 8;
/// Mip levels of the stack atlas.
pub const STACK_MIPS: u32 = 4;
/// The atlas' width (or the GPU's limit, if smaller).
const ATLAS_WIDTH: u32 = 4096;

/// The layout of every species' three stacks in one 2D texture.
#[derive(Clone, Debug, PartialEq)]
pub struct StackAtlas {
    pub size: UVec2,
    /// Per species (by index), its groups along x, y and z.
    pub groups: Vec<Option<[StackGroup; 3]>>,
}

impl StackAtlas {
    /// The layout for `volumes` (`species` of the scene), or an error naming what does not
    /// fit a `max_dim`-texel texture.
    pub fn new(volumes: &[TexelVolume], species: usize, max_dim: u32) -> Result<Self> {
        // The narrowest power-of-two width (from ATLAS_WIDTH) whose height fits.
        let mut width = ATLAS_WIDTH.min(max_dim) / TILE_ALIGN * TILE_ALIGN;
        loop {
            match Self::with_width(volumes, species, max_dim, width) {
                Err(e) if width * 2 <= max_dim => {
                    log::debug!("{e}; trying a wider atlas");
                    width *= 2;
                }
                other => return other,
            }
        }
    }

    fn with_width(
        volumes: &[TexelVolume],
        species: usize,
        max_dim: u32,
        width: u32,
    ) -> Result<Self> {
        let mut groups = vec![None; species];
        let mut height = 0u32;
        for t in volumes {
            let s = t.species as usize;
            if s >= species {
                continue;
            }
            let dims = UVec3::from(t.dims);
            let round = |v: u32| v.div_ceil(TILE_ALIGN) * TILE_ALIGN;
            let make = |axis: usize, height: &mut u32| -> Result<StackGroup> {
                let (u, v) = plane_axes(axis);
                let used = UVec2::new(dims[u], dims[v]);
                let tile = used.map(round);
                let slices = dims[axis].max(1).next_power_of_two();
                let cols = (width / tile.x.max(1)).max(1);
                let count = tiles_per_volume(slices) * (t.lights + 1);
                let rows = count.div_ceil(cols);
                let origin = UVec2::new(0, *height);
                *height = height.saturating_add(rows.saturating_mul(tile.y));
                if tile.x > width {
                    return Err(Error::BadInput(format!(
                        "a texel slice {} texels wide does not fit the GPU's {max_dim}-texel textures",
                        tile.x
                    )));
                }
                Ok(StackGroup {
                    axis,
                    slices,
                    tile,
                    used,
                    origin,
                    cols,
                    volumes: t.lights + 1,
                })
            };
            groups[s] = Some([
                make(0, &mut height)?,
                make(1, &mut height)?,
                make(2, &mut height)?,
            ]);
        }
        if height > max_dim {
            return Err(Error::BadInput(format!(
                "the texel stacks need a {width}x{height} texture but this GPU allows {max_dim} per side; bake with a lower texel_resolution or use --texel-mode slices3d"
            )));
        }
        Ok(Self {
            size: UVec2::new(width, height.max(1)),
            groups,
        })
    }

    /// Bytes of the atlas with its mip levels.
    pub fn bytes(&self) -> u64 {
        (0..STACK_MIPS)
            .map(|l| {
                let d = (self.size >> l).max(UVec2::ONE);
                u64::from(d.x) * u64::from(d.y) * 4
            })
            .sum()
    }

    /// The atlas' level 0 then its mip levels (RGBA8, sRGB, premultiplied), every slice of
    /// every level of `volumes` in its tile.
    pub fn levels(&self, volumes: &[TexelVolume]) -> Vec<(UVec2, Vec<u8>)> {
        let lut = srgb_lut();
        let w = self.size.x as usize;
        let mut level0 = vec![0u8; w * self.size.y as usize * 4];
        for t in volumes {
            let Some(Some(groups)) = self.groups.get(t.species as usize) else {
                continue;
            };
            let dims = UVec3::from(t.dims);
            let per = (dims.x * dims.y * dims.z * 4) as usize;
            for g in groups {
                for vol in 0..g.volumes {
                    let Some(src) = t.voxels.get(vol as usize * per..(vol as usize + 1) * per)
                    else {
                        continue;
                    };
                    let base = vol * g.per_volume();
                    let mut put = |index: u32, slice: &[Rgba]| {
                        let o = g.tile_origin(base + index);
                        for y in 0..g.used.y {
                            for x in 0..g.used.x {
                                let c = slice[(y * g.used.x + x) as usize];
                                let i = ((o.y + y) as usize * w + (o.x + x) as usize) * 4;
                                for k in 0..3 {
                                    level0[i + k] = linear_to_srgb(c[k]);
                                }
                                level0[i + 3] = (c[3].clamp(0.0, 1.0) * 255.0 + 0.5) as u8;
                            }
                        }
                    };
                    let first = stack_slices(src, dims, g, &lut);
                    for (j, s) in first.iter().enumerate() {
                        put(j as u32, s);
                    }
                    for order in 0..2u32 {
                        let mut level = first.clone();
                        let mut k = 1;
                        while level.len() > 1 {
                            level = halve(&level, order == 0);
                            let off = level_offset(g.slices, order, k);
                            for (j, s) in level.iter().enumerate() {
                                put(off + j as u32, s);
                            }
                            k += 1;
                        }
                    }
                }
            }
        }
        let mut levels = vec![(self.size, level0)];
        for _ in 1..STACK_MIPS {
            let Some((size, prev)) = levels.last() else {
                break;
            };
            let next = downsample(*size, prev, &lut);
            levels.push(next);
        }
        levels
    }
}

/// The full-resolution slices of one volume (voxels x fastest, RGBA8 sRGB premultiplied)
/// across `g.axis`, in linear light, padded with empty slices to `g.slices`.
fn stack_slices(src: &[u8], dims: UVec3, g: &StackGroup, lut: &[f32]) -> Vec<Vec<Rgba>> {
    let (u, v) = plane_axes(g.axis);
    (0..g.slices)
        .map(|j| {
            let mut slice = vec![[0.0f32; 4]; (g.used.x * g.used.y) as usize];
            if j >= dims[g.axis] {
                return slice;
            }
            for pv in 0..g.used.y {
                for pu in 0..g.used.x {
                    let mut p = UVec3::ZERO;
                    p[g.axis] = j;
                    p[u] = pu;
                    p[v] = pv;
                    let i = (((p.z * dims.y + p.y) * dims.x + p.x) * 4) as usize;
                    slice[(pv * g.used.x + pu) as usize] = [
                        lut[src[i] as usize],
                        lut[src[i + 1] as usize],
                        lut[src[i + 2] as usize],
                        f32::from(src[i + 3]) / 255.0,
                    ];
                }
            }
            slice
        })
        .collect()
}

/// A 2D RGBA8 sRGB premultiplied image halved in each side, box filtered in linear light.
fn downsample(size: UVec2, prev: &[u8], lut: &[f32]) -> (UVec2, Vec<u8>) {
    let next = (size >> 1u32).max(UVec2::ONE);
    let mut out = vec![0u8; (next.x * next.y * 4) as usize];
    for y in 0..next.y {
        for x in 0..next.x {
            let mut acc = [0.0f32; 4];
            let mut n = 0.0;
            for (sx, sy) in [(0, 0), (1, 0), (0, 1), (1, 1)] {
                let (px, py) = (2 * x + sx, 2 * y + sy);
                if px >= size.x || py >= size.y {
                    continue;
                }
                let i = ((py * size.x + px) * 4) as usize;
                for c in 0..3 {
                    acc[c] += lut[prev[i + c] as usize];
                }
                acc[3] += f32::from(prev[i + 3]) / 255.0;
                n += 1.0;
            }
            let o = ((y * next.x + x) * 4) as usize;
            for c in 0..3 {
                out[o + c] = linear_to_srgb(acc[c] / n);
            }
            out[o + 3] = (acc[3] / n * 255.0 + 0.5) as u8;
        }
    }
    (next, out)
}

/// The stack a texel is drawn with: the axis most facing the eye and the viewing order,
/// for `view_dir` (from the eye toward the box, in the object frame).
pub fn facing_axis(view_dir: glam::Vec3) -> (usize, u32) {
    let a = view_dir.abs();
    let axis = if a.x >= a.y && a.x >= a.z {
        0
    } else if a.y >= a.z {
        1
    } else {
        2
    };
    // Looking along +axis, the lower slices are nearer: order 0.
    (axis, u32::from(view_dir[axis] < 0.0))
}

/// One texel's stack as `texel.wgsl` reads it (`struct Stack`), byte for byte.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
pub struct StackGpu {
    pub origin: [f32; 2],
    pub tile: [f32; 2],
    pub used: [f32; 2],
    pub texels: [f32; 2],
    pub axis: u32,
    pub cols: u32,
    pub per_volume: u32,
    pub level_offset: u32,
    pub level: u32,
    pub order: u32,
    pub slices: u32,
    pub pad: u32,
}

/// How a texel is drawn as a stack this frame.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct StackChoice {
    pub record: StackGpu,
    /// Slices drawn (n), of the stack's full count.
    pub slices: u32,
}

impl StackAtlas {
    /// The stack `species`' texel is drawn with, seen along `view_dir` (object frame, from
    /// the eye toward the box) at view depth `z`: the facing axis and order, and the level
    /// holding n = max(C1, C2) slices (H the stack's height in metres, `scale` object to
    /// world), no more than the stack has.
    #[allow(clippy::too_many_arguments)]
    pub fn choose(
        &self,
        species: usize,
        view_dir: glam::Vec3,
        voxel: f32,
        scale: f32,
        z: f32,
        focal_px: f32,
        bounds: &crate::slices::SliceBounds,
    ) -> Option<StackChoice> {
        let groups = self.groups.get(species)?.as_ref()?;
        let dir = view_dir.normalize_or_zero();
        if dir == glam::Vec3::ZERO {
            return None;
        }
        let (axis, order) = facing_axis(dir);
        let g = &groups[axis];
        let angle = dir[axis].abs().clamp(0.0, 1.0).acos();
        let h = g.slices as f32 * voxel * scale;
        let n = crate::slices::stack_slices(focal_px, h, angle, z, bounds).min(g.slices);
        let level = (g.slices / n.max(1)).ilog2();
        let size = self.size.as_vec2();
        Some(StackChoice {
            record: StackGpu {
                origin: (g.origin.as_vec2() / size).to_array(),
                tile: (g.tile.as_vec2() / size).to_array(),
                used: (g.used.as_vec2() / size).to_array(),
                texels: g.used.as_vec2().to_array(),
                axis: axis as u32,
                cols: g.cols,
                per_volume: g.per_volume(),
                level_offset: level_offset(g.slices, order, level),
                level,
                order,
                slices: g.slices >> level,
                pad: 0,
            },
            slices: g.slices >> level,
        })
    }
}

/// The quads of a frame's stacks, back to front: per texel (already back to front), its
/// slices from the far end of its stack (order 0 draws high slices first).
pub fn quads(stacks: &[StackGpu]) -> Vec<[u32; 2]> {
    let mut out = Vec::with_capacity(stacks.iter().map(|s| s.slices as usize).sum());
    for (i, s) in stacks.iter().enumerate() {
        let i = i as u32;
        if s.order == 0 {
            out.extend((0..s.slices).rev().map(|j| [i, j]));
        } else {
            out.extend((0..s.slices).map(|j| [i, j]));
        }
    }
    out
}

/// Stack quads, both faces.
const STACKS: super::OverStyle = super::OverStyle {
    label: "texel.wgsl stacks",
    entry_points: ("vs_stack", "fs_stack"),
    cull: None,
    draw: super::OverDraw::Instances(6),
};

/// The stack atlas on the GPU, with the frame's stack records and quads.
pub struct StackAssets {
    pub atlas: StackAtlas,
    _texture: wgpu::Texture,
    view: wgpu::TextureView,
    records: wgpu::Buffer,
    quads: wgpu::Buffer,
    pub(super) pass: super::OverPass,
    /// Bytes of the atlas with its mip levels.
    pub bytes: u64,
}

impl StackAssets {
    pub fn new(
        ctx: &crate::render::GpuContext,
        volumes: &[TexelVolume],
        species: usize,
    ) -> Result<Self> {
        let max_dim = ctx.device.limits().max_texture_dimension_2d;
        let atlas = StackAtlas::new(volumes, species, max_dim)?;
        let levels = atlas.levels(volumes);
        let texture = ctx.checked("allocating the texel stacks", || {
            sampled_rgba8_texture(
                &ctx.device,
                "texel stacks",
                wgpu::TextureDimension::D2,
                atlas.size.extend(1),
                STACK_MIPS,
            )
        })?;
        for (level, (d, data)) in levels.iter().enumerate() {
            write_rgba8(
                &ctx.queue,
                &texture,
                level as u32,
                UVec3::ZERO,
                data,
                d.extend(1),
            );
        }
        let view = texture.create_view(&Default::default());
        let vf = wgpu::ShaderStages::VERTEX_FRAGMENT;
        let pass = super::OverPass::new(
            &ctx.device,
            "texel stacks",
            &[
                storage_entry(0, vf),
                sampler_entry(2, wgpu::SamplerBindingType::Filtering),
                texture_entry(3, FILTERABLE, wgpu::TextureViewDimension::D2),
                storage_entry(4, vf),
                storage_entry(5, vf),
            ],
            &STACKS,
        );
        Ok(Self {
            bytes: atlas.bytes(),
            atlas,
            _texture: texture,
            view,
            records: storage_buffer_of::<StackGpu>(&ctx.device, "texel stack records", 64),
            quads: storage_buffer_of::<[u32; 2]>(&ctx.device, "texel stack quads", 1024),
            pass,
        })
    }

    /// Uploads the frame's stacks and quads (growing the buffers when needed) and binds
    /// them with the texel records `texels` and `sampler`.
    pub fn upload(
        &mut self,
        ctx: &crate::render::GpuContext,
        stacks: &[StackGpu],
        quads: &[[u32; 2]],
        texels: &wgpu::Buffer,
        sampler: &wgpu::Sampler,
    ) {
        write_growing(ctx, &mut self.records, "texel stack records", stacks);
        write_growing(ctx, &mut self.quads, "texel stack quads", quads);
        self.pass.bind(
            &ctx.device,
            "texel stacks",
            &[
                wgpu::BindGroupEntry {
                    binding: 0,
                    resource: texels.as_entire_binding(),
                },
                wgpu::BindGroupEntry {
                    binding: 2,
                    resource: wgpu::BindingResource::Sampler(sampler),
                },
                wgpu::BindGroupEntry {
                    binding: 3,
                    resource: wgpu::BindingResource::TextureView(&self.view),
                },
                wgpu::BindGroupEntry {
                    binding: 4,
                    resource: self.records.as_entire_binding(),
                },
                wgpu::BindGroupEntry {
                    binding: 5,
                    resource: self.quads.as_entire_binding(),
                },
            ],
        );
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A little pseudo-random premultiplied sample.
    fn sample(seed: &mut u32) -> Rgba {
        let mut next = || {
            *seed = seed.wrapping_mul(1664525).wrapping_add(1013904223);
            (*seed >> 8) as f32 / (1u32 << 24) as f32
        };
        let a = next();
        [a * next(), a * next(), a * next(), a]
    }

    #[test]
    fn pairwise_levels_equal_compositing_one_by_one_in_both_orders() {
        let mut seed = 7;
        let n = 16;
        let pixels = 5;
        let slices: Vec<Vec<Rgba>> = (0..n)
            .map(|_| (0..pixels).map(|_| sample(&mut seed)).collect())
            .collect();
        for low_in_front in [true, false] {
            let mut level = slices.clone();
            let mut k = 0;
            while level.len() > 1 {
                level = halve(&level, low_in_front);
                k += 1;
                let step = 1usize << k;
                assert_eq!(level.len(), n / step);
                for (j, got) in level.iter().enumerate() {
                    for p in 0..pixels {
                        // The 2^k slices of the group, front to back, one by one.
                        let group: Vec<Rgba> =
                            (j * step..(j + 1) * step).map(|i| slices[i][p]).collect();
                        let ordered: Vec<Rgba> = if low_in_front {
                            group
                        } else {
                            group.into_iter().rev().collect()
                        };
                        let want = ordered.iter().fold([0.0; 4], |acc: Rgba, &s| over(acc, s));
                        for c in 0..4 {
                            assert!(
                                (got[p][c] - want[c]).abs() < 1e-5,
                                "order {low_in_front}, level {k}, slice {j}: {:?} vs {want:?}",
                                got[p]
                            );
                        }
                    }
                }
            }
        }
        // The two orders differ: over does not commute.
        let a = halve(&slices, true);
        let b = halve(&slices, false);
        assert_ne!(a, b);
    }

    #[test]
    fn tile_offsets_cover_each_volume_without_overlap() {
        for n in [1u32, 2, 8, 64] {
            let mut seen = vec![false; tiles_per_volume(n) as usize];
            let mut mark = |i: u32| {
                assert!(!seen[i as usize], "tile {i} twice for n = {n}");
                seen[i as usize] = true;
            };
            for j in 0..n {
                mark(level_offset(n, 0, 0) + j);
            }
            for order in 0..2 {
                for k in 1..=n.ilog2() {
                    for j in 0..(n >> k) {
                        mark(level_offset(n, order, k) + j);
                    }
                }
            }
            assert!(seen.iter().all(|&s| s), "n = {n}");
        }
    }

    #[test]
    fn the_facing_axis_is_the_largest_component() {
        assert_eq!(facing_axis(glam::Vec3::new(0.9, 0.1, -0.2)), (0, 0));
        assert_eq!(facing_axis(glam::Vec3::new(0.1, -0.9, 0.2)), (1, 1));
        assert_eq!(facing_axis(glam::Vec3::new(0.1, 0.2, -0.5)), (2, 1));
    }

    #[test]
    fn a_volume_packs_into_tiles_and_its_slices_land_where_the_layout_says() {
        // A 3 x 2 x 5 volume, one light (2 volumes): voxel (x, y, z) of volume v has alpha
        // 255 and red = 10 x + 20 y + 40 z + v (in sRGB bytes, so exact at level 0).
        let dims = [3u32, 2, 5];
        let mut voxels = Vec::new();
        for v in 0..2u32 {
            for z in 0..5 {
                for y in 0..2 {
                    for x in 0..3 {
                        voxels.extend([(10 * x + 20 * y + 40 * z + v) as u8, 0, 0, 255]);
                    }
                }
            }
        }
        let vol = TexelVolume {
            species: 0,
            lights: 1,
            dims,
            box_min: [0.0; 3],
            voxel: 1.0,
            voxels,
        };
        let atlas = StackAtlas::new(std::slice::from_ref(&vol), 1, 4096).unwrap();
        let levels = atlas.levels(std::slice::from_ref(&vol));
        assert_eq!(levels.len(), STACK_MIPS as usize);
        let (size, data) = &levels[0];
        let groups = atlas.groups[0].unwrap();
        // Along z: 5 slices padded to 8; slice 3 of volume 1, pixel (x 2, y 1).
        let g = groups[2];
        assert_eq!(g.slices, 8);
        let o = g.tile_origin(g.per_volume() + 3);
        let i = (((o.y + 1) * size.x + o.x + 2) * 4) as usize;
        assert_eq!(data[i], (10 * 2 + 20 + 40 * 3 + 1) as u8);
        assert_eq!(data[i + 3], 255);
        // Along x: slice 1, pixel (y 1, z 4) of volume 0.
        let g = groups[0];
        let o = g.tile_origin(1);
        let i = (((o.y + 4) * size.x + o.x + 1) * 4) as usize;
        assert_eq!(data[i], (10 + 20 + 160) as u8);
        // A padded slice (z = 6) is empty.
        let g = groups[2];
        let o = g.tile_origin(6);
        assert_eq!(data[((o.y * size.x + o.x) * 4 + 3) as usize], 0);
        // Opaque slices: level 1 of order 0 shows the lower slice, of order 1 the higher.
        let lo = g.tile_origin(level_offset(8, 0, 1) + 1);
        let hi = g.tile_origin(level_offset(8, 1, 1) + 1);
        let red = |o: UVec2| data[((o.y * size.x + o.x) * 4) as usize];
        assert_eq!(red(lo), (40 * 2) as u8);
        assert_eq!(red(hi), (40 * 3) as u8);
        assert!(atlas.bytes() > (size.x * size.y * 4) as u64);
    }
}
