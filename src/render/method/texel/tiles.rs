//! Forest-cover tiles for the far field (Meyer-Neyret 1998, Decaudin-Neyret 2004): the
//! terrain cut into square tiles; each tile's box follows the ground,
//! p = b(u, w) + (lo + v·H)·up, with b the terrain bilinear between the tile's four
//! corners, and holds the volume of the trees that stand in it. Far away, one tile's
//! ray march replaces the boxes of all its trees.
//!
//! A tile's volume is made from the trees' own baked volumes (`bake::texel`, themselves
//! baked from the geometry), not from a new voxelisation of the geometry: every tile voxel
//! takes 2 x 2 x 2 samples of the trees whose boxes hold them, from each species' volume
//! box-filtered to about a quarter of the tile's voxel, the trees' opacities combined as
//! 1 - Π(1 - α). A filtered alpha is the mean coverage of one species voxel's depth; the
//! tile voxel is deeper, so its alpha is 1 - (1 - α)^(tile voxel / tree voxel). The
//! volumes are built when the tiles first draw (about a second for 1,000 trees), lit like
//! the trees' (one volume per baked light and one by the sky, each tree's self-shadowing
//! only: trees do not shade each other inside a tile).

use glam::{Mat4, UVec3, Vec2, Vec3, Vec4};

use crate::format::TexelVolume;
use crate::model::Terrain;
use crate::model::mesh::Aabb;
use crate::render::pipelines::{
    FILTERABLE, sampled_rgba8_texture, sampler_entry, storage_buffer_of, storage_entry,
    texture_entry, write_growing, write_rgba8,
};
use crate::render::target::{linear_to_srgb, srgb_lut};
use crate::render::world_gpu::TreeGpu;

/// Side of a tile (m).
pub const TILE_SIZE: f32 = 64.0;
/// Voxels of a tile volume across (x, z) and up (y).
pub const TILE_DIMS: UVec3 = UVec3::new(16, 8, 16);

/// One tile: where it lies and which trees stand in it.
#[derive(Clone, Debug, PartialEq)]
pub struct Tile {
    /// The tile's lowest (x, z) corner and side (m).
    pub origin: Vec2,
    pub size: f32,
    /// Terrain height at its corners: (x0, z0), (x1, z0), (x0, z1), (x1, z1).
    pub corners: [f32; 4],
    /// The volume spans lo..lo + height above the bilinear ground.
    pub lo: f32,
    pub height: f32,
    /// Trees whose trunks stand in the tile (indices into the scene's trees).
    pub trees: Vec<u32>,
}

impl Tile {
    /// The bilinear ground at (u, w) in 0..1 across the tile.
    pub fn ground(&self, u: f32, w: f32) -> f32 {
        let [a, b, c, d] = self.corners;
        let lo = a + (b - a) * u;
        let hi = c + (d - c) * u;
        lo + (hi - lo) * w
    }

    /// The world point of tile coordinates (u, v, w), each 0..1.
    pub fn world(&self, uvw: Vec3) -> Vec3 {
        let x = self.origin.x + uvw.x * self.size;
        let z = self.origin.y + uvw.z * self.size;
        Vec3::new(
            x,
            self.ground(uvw.x, uvw.z) + self.lo + uvw.y * self.height,
            z,
        )
    }

    /// The world box holding the tile's volume.
    pub fn bounds(&self) -> Aabb {
        let (lo_b, hi_b) = self
            .corners
            .iter()
            .fold((f32::INFINITY, f32::NEG_INFINITY), |(a, b), &c| {
                (a.min(c), b.max(c))
            });
        Aabb::new(
            Vec3::new(self.origin.x, lo_b + self.lo, self.origin.y),
            Vec3::new(
                self.origin.x + self.size,
                hi_b + self.lo + self.height,
                self.origin.y + self.size,
            ),
        )
    }

    /// Side of a cube of the same volume as one voxel (m): what a voxel's alpha is a
    /// thickness of.
    pub fn voxel(&self) -> f32 {
        let d = TILE_DIMS.as_vec3();
        (self.size / d.x * self.height / d.y * self.size / d.z).cbrt()
    }
}

/// The trees by tile over a terrain, and which tile each tree stands in.
#[derive(Clone, Debug, PartialEq)]
pub struct TileGrid {
    pub tiles: Vec<Tile>,
    /// Per tree, its tile (an index into `tiles`), if it stands in one that has a volume.
    pub tile_of: Vec<Option<u32>>,
}

impl TileGrid {
    /// Tiles of [`TILE_SIZE`] over `terrain` holding `trees` (world transforms, with
    /// `bounds` their world boxes); only tiles with trees are kept.
    pub fn new(terrain: &Terrain, trees: &[TreeGpu], bounds: &[Aabb]) -> Self {
        let n = (terrain.size / TILE_SIZE).ceil().clamp(1.0, 4096.0) as usize;
        let half = 0.5 * terrain.size;
        let mut members: Vec<Vec<u32>> = vec![Vec::new(); n * n];
        let cell = |x: f32, z: f32| -> Option<usize> {
            let i = ((x + half) / TILE_SIZE).floor();
            let j = ((z + half) / TILE_SIZE).floor();
            if !(i >= 0.0 && j >= 0.0 && (i as usize) < n && (j as usize) < n) {
                return None;
            }
            Some(j as usize * n + i as usize)
        };
        for (t, tree) in trees.iter().enumerate() {
            let m = Mat4::from_cols_array_2d(&tree.model);
            let p = m.w_axis;
            if let Some(c) = cell(p.x, p.z) {
                members[c].push(t as u32);
            }
        }
        let mut tiles = Vec::new();
        let mut tile_of = vec![None; trees.len()];
        for (c, list) in members.into_iter().enumerate() {
            if list.is_empty() {
                continue;
            }
            let origin = Vec2::new(
                (c % n) as f32 * TILE_SIZE - half,
                (c / n) as f32 * TILE_SIZE - half,
            );
            let corners = [
                terrain.height_at(origin.x, origin.y),
                terrain.height_at(origin.x + TILE_SIZE, origin.y),
                terrain.height_at(origin.x, origin.y + TILE_SIZE),
                terrain.height_at(origin.x + TILE_SIZE, origin.y + TILE_SIZE),
            ];
            let mut tile = Tile {
                origin,
                size: TILE_SIZE,
                corners,
                lo: 0.0,
                height: 1.0,
                trees: list,
            };
            // Heights of the tile's trees above the bilinear ground, over their footprint.
            let (mut lo, mut hi) = (0.0f32, 1.0f32);
            for &t in &tile.trees {
                let b = bounds[t as usize];
                let ground = [
                    (b.min.x, b.min.z),
                    (b.max.x, b.min.z),
                    (b.min.x, b.max.z),
                    (b.max.x, b.max.z),
                ]
                .map(|(x, z)| {
                    let u = ((x - origin.x) / TILE_SIZE).clamp(0.0, 1.0);
                    let w = ((z - origin.y) / TILE_SIZE).clamp(0.0, 1.0);
                    tile.ground(u, w)
                });
                let g_lo = ground.iter().cloned().fold(f32::INFINITY, f32::min);
                let g_hi = ground.iter().cloned().fold(f32::NEG_INFINITY, f32::max);
                lo = lo.min(b.min.y - g_hi);
                hi = hi.max(b.max.y - g_lo);
            }
            tile.lo = lo.max(-50.0);
            tile.height = (hi - tile.lo).clamp(1.0, 500.0);
            let index = tiles.len() as u32;
            for &t in &tile.trees {
                tile_of[t as usize] = Some(index);
            }
            tiles.push(tile);
        }
        Self { tiles, tile_of }
    }
}

/// One species' volumes in linear light, filtered down `level` times (each halving).
struct Filtered {
    dims: UVec3,
    box_min: Vec3,
    /// Side of one filtered voxel, and of the baked voxel, in the tree's frame.
    voxel: f32,
    baked_voxel: f32,
    /// Per volume, premultiplied linear RGBA.
    volumes: Vec<Vec<Vec4>>,
}

impl Filtered {
    fn new(t: &TexelVolume, level: u32, lut: &[f32]) -> Self {
        let dims = UVec3::from(t.dims);
        let per = (dims.x * dims.y * dims.z) as usize;
        let mut volumes: Vec<Vec<Vec4>> = (0..=t.lights as usize)
            .map(|v| {
                t.voxels
                    .get(v * per * 4..(v + 1) * per * 4)
                    .unwrap_or(&[])
                    .chunks_exact(4)
                    .map(|p| {
                        Vec4::new(
                            lut[p[0] as usize],
                            lut[p[1] as usize],
                            lut[p[2] as usize],
                            f32::from(p[3]) / 255.0,
                        )
                    })
                    .collect()
            })
            .collect();
        let mut d = dims;
        for _ in 0..level {
            let next = (d + 1) / 2;
            for vol in volumes.iter_mut() {
                let mut out = vec![Vec4::ZERO; (next.x * next.y * next.z) as usize];
                for z in 0..next.z {
                    for y in 0..next.y {
                        for x in 0..next.x {
                            let mut acc = Vec4::ZERO;
                            // Outside the volume counts as empty: the mean covers the
                            // whole filtered voxel.
                            for (dx, dy, dz) in CORNERS {
                                let (sx, sy, sz) = (2 * x + dx, 2 * y + dy, 2 * z + dz);
                                if sx < d.x
                                    && sy < d.y
                                    && sz < d.z
                                    && let Some(v) = vol.get(((sz * d.y + sy) * d.x + sx) as usize)
                                {
                                    acc += *v;
                                }
                            }
                            out[((z * next.y + y) * next.x + x) as usize] = acc / 8.0;
                        }
                    }
                }
                *vol = out;
            }
            d = next;
        }
        Self {
            dims: d,
            box_min: Vec3::from(t.box_min),
            voxel: t.voxel * (1u32 << level) as f32,
            baked_voxel: t.voxel,
            volumes,
        }
    }

    /// Volume `v` at `p` (tree frame), trilinear; zero outside.
    fn sample(&self, v: usize, p: Vec3) -> Vec4 {
        let g = (p - self.box_min) / self.voxel - 0.5;
        let d = self.dims.as_ivec3();
        if g.cmplt(Vec3::splat(-1.0)).any() || g.cmpgt(d.as_vec3()).any() {
            return Vec4::ZERO;
        }
        let base = g.floor();
        let f = g - base;
        let b = base.as_ivec3();
        let Some(vol) = self.volumes.get(v) else {
            return Vec4::ZERO;
        };
        let mut acc = Vec4::ZERO;
        for (dx, dy, dz) in CORNERS {
            let c = b + glam::IVec3::new(dx as i32, dy as i32, dz as i32);
            if c.cmplt(glam::IVec3::ZERO).any() || c.cmpge(d).any() {
                continue;
            }
            let w = (if dx == 1 { f.x } else { 1.0 - f.x })
                * (if dy == 1 { f.y } else { 1.0 - f.y })
                * (if dz == 1 { f.z } else { 1.0 - f.z });
            acc += vol[((c.z * d.y + c.y) * d.x + c.x) as usize] * w;
        }
        acc
    }
}

/// Samples per tile voxel side.
const SUB: u32 = 2;

const CORNERS: [(u32, u32, u32); 8] = [
    (0, 0, 0),
    (1, 0, 0),
    (0, 1, 0),
    (1, 1, 0),
    (0, 0, 1),
    (1, 0, 1),
    (0, 1, 1),
    (1, 1, 1),
];

/// Every tile's volumes (lights + 1 per tile, [`TILE_DIMS`], RGBA8 sRGB premultiplied,
/// x fastest), from the species' baked `volumes` and the trees.
pub fn tile_volumes(
    grid: &TileGrid,
    trees: &[TreeGpu],
    species_of: &[u32],
    bounds: &[Aabb],
    volumes: &[TexelVolume],
) -> Vec<Vec<u8>> {
    let lut = srgb_lut();
    let lights = volumes.first().map_or(0, |t| t.lights) as usize;
    // Each species filtered to about a tile voxel (at the trees' mean scale, 1).
    let tile_voxel = grid
        .tiles
        .first()
        .map_or(4.0, |t| t.size / TILE_DIMS.x as f32);
    let mut filtered: Vec<Option<Filtered>> = Vec::new();
    for t in volumes {
        let s = t.species as usize;
        if filtered.len() <= s {
            filtered.resize_with(s + 1, || None);
        }
        let level = (tile_voxel / t.voxel / 4.0).log2().round().clamp(0.0, 4.0) as u32;
        filtered[s] = Some(Filtered::new(t, level, &lut));
    }
    let inverse: Vec<Mat4> = trees
        .iter()
        .map(|t| Mat4::from_cols_array_2d(&t.model).inverse())
        .collect();
    let d = TILE_DIMS;
    let n = (d.x * d.y * d.z) as usize;
    let mut out = Vec::with_capacity(grid.tiles.len());
    for tile in &grid.tiles {
        let column = tile.bounds();
        // The trees whose boxes reach into the tile's column (its own and its neighbours').
        let near: Vec<u32> = (0..trees.len() as u32)
            .filter(|&t| {
                let b = bounds[t as usize];
                b.max.x >= column.min.x
                    && b.min.x <= column.max.x
                    && b.max.z >= column.min.z
                    && b.min.z <= column.max.z
            })
            .collect();
        let mut data = vec![0u8; n * (lights + 1) * 4];
        let tile_voxel = tile.voxel();
        for k in 0..d.y {
            for j in 0..d.z {
                for i in 0..d.x {
                    let mut sum = vec![Vec4::ZERO; lights + 1];
                    for sub in 0..SUB * SUB * SUB {
                        let at = Vec3::new(
                            (sub % SUB) as f32,
                            (sub / SUB % SUB) as f32,
                            (sub / (SUB * SUB)) as f32,
                        );
                        let uvw =
                            (UVec3::new(i, k, j).as_vec3() + (at + 0.5) / SUB as f32) / d.as_vec3();
                        let p = tile.world(uvw);
                        // Per volume: premultiplied colour and transmittance over the trees.
                        let mut color = vec![Vec3::ZERO; lights + 1];
                        let mut transmit = 1.0f32;
                        let mut alpha_sum = 0.0f32;
                        for &t in &near {
                            let b = bounds[t as usize];
                            if p.cmplt(b.min).any() || p.cmpgt(b.max).any() {
                                continue;
                            }
                            let Some(Some(f)) = filtered.get(species_of[t as usize] as usize)
                            else {
                                continue;
                            };
                            let m = &inverse[t as usize];
                            let q = m.transform_point3(p);
                            let scale = 1.0 / m.x_axis.truncate().length().max(1e-6);
                            let sky = f.sample(lights, q);
                            if sky.w <= 1e-4 {
                                continue;
                            }
                            // The filtered alpha covers one baked voxel's depth of the tree
                            // (scaled); the tile voxel is this much deeper.
                            let depth = tile_voxel / (f.baked_voxel * scale);
                            let a = 1.0 - (1.0 - sky.w.min(0.999)).powf(depth);
                            for (v, c) in color.iter_mut().enumerate() {
                                let s = if v == lights { sky } else { f.sample(v, q) };
                                // Unpremultiplied by the filtered alpha, weighted by the
                                // deeper one.
                                *c += s.truncate() / sky.w * a;
                            }
                            transmit *= 1.0 - a;
                            alpha_sum += a;
                        }
                        let alpha = 1.0 - transmit;
                        if alpha_sum > 0.0 {
                            for (v, c) in color.iter().enumerate() {
                                sum[v] += (*c * (alpha / alpha_sum)).extend(alpha);
                            }
                        }
                    }
                    // x fastest, then y, then z (as the species volumes).
                    let i_voxel = ((j * d.y + k) * d.x + i) as usize;
                    for (v, s) in sum.iter().enumerate() {
                        let s = *s / (SUB * SUB * SUB) as f32;
                        let o = (v * n + i_voxel) * 4;
                        data[o] = linear_to_srgb(s.x);
                        data[o + 1] = linear_to_srgb(s.y);
                        data[o + 2] = linear_to_srgb(s.z);
                        data[o + 3] = (s.w.clamp(0.0, 1.0) * 255.0 + 0.5) as u8;
                    }
                }
            }
        }
        out.push(data);
    }
    out
}

/// One tile as `texel.wgsl` reads it (`struct Tile`), byte for byte.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
pub struct TileGpu {
    pub origin: [f32; 2],
    pub size: f32,
    pub lo: f32,
    pub corners: [f32; 4],
    pub height: f32,
    pub voxel: f32,
    pub spacing: f32,
    pub max_steps: f32,
    pub atlas_origin: [f32; 3],
    pub volume_dw: f32,
    pub atlas_extent: [f32; 3],
    pub lights: u32,
    pub light_index: [u32; 3],
    pub slices: f32,
    pub light_weight: [f32; 3],
    pub pad0: f32,
    pub box_min: [f32; 3],
    pub pad1: f32,
    pub box_max: [f32; 3],
    pub pad2: f32,
}

/// Tile boxes, front faces.
const TILES: super::OverStyle = super::OverStyle {
    label: "texel.wgsl tiles",
    entry_points: ("vs_tile", "fs_tile"),
    cull: Some(wgpu::Face::Back),
    draw: super::OverDraw::Instances(36),
};

/// The tiles on the GPU: their volumes in one 3D texture (a tile's volumes one after the
/// other along w, tiles along u then v), and the frame's records.
pub struct TileAssets {
    pub grid: TileGrid,
    /// uvw of each tile's first voxel corner.
    origins: Vec<Vec3>,
    extent: Vec3,
    volume_dw: f32,
    lights: u32,
    _texture: wgpu::Texture,
    view: wgpu::TextureView,
    records: wgpu::Buffer,
    pub(super) pass: super::OverPass,
    /// Bytes of the tile volumes on the GPU.
    pub bytes: u64,
}

impl TileAssets {
    /// Builds the tiles of `trees` over `terrain` from the species' `volumes` and uploads
    /// them.
    pub fn new(
        ctx: &crate::render::GpuContext,
        terrain: &Terrain,
        world: &crate::render::world_gpu::WorldGpu,
        volumes: &[TexelVolume],
    ) -> crate::Result<Self> {
        let lights = volumes.first().map_or(0, |t| t.lights);
        let t0 = std::time::Instant::now();
        let grid = TileGrid::new(terrain, &world.tree_data, &world.tree_bounds);
        let data = tile_volumes(
            &grid,
            &world.tree_data,
            &world.tree_species,
            &world.tree_bounds,
            volumes,
        );
        log::info!(
            "built {} forest-cover tiles in {:.2} s",
            grid.tiles.len(),
            t0.elapsed().as_secs_f64()
        );
        let max_dim = ctx.device.limits().max_texture_dimension_3d;
        let d = TILE_DIMS;
        let per_u = (max_dim / d.x).max(1);
        let count = grid.tiles.len().max(1) as u32;
        let atlas = UVec3::new(
            d.x * count.min(per_u),
            d.y * count.div_ceil(per_u),
            d.z * (lights + 1),
        );
        if atlas.max_element() > max_dim {
            return Err(crate::Error::BadInput(format!(
                "{} forest-cover tiles need a {}x{}x{} texture but this GPU allows {max_dim} per side; turn tiles off (--texel-tiles off)",
                grid.tiles.len(),
                atlas.x,
                atlas.y,
                atlas.z
            )));
        }
        let texture = ctx.checked("allocating the forest-cover tiles", || {
            sampled_rgba8_texture(
                &ctx.device,
                "forest-cover tiles",
                wgpu::TextureDimension::D3,
                atlas,
                1,
            )
        })?;
        let size = atlas.as_vec3();
        let mut origins = Vec::with_capacity(grid.tiles.len());
        for (t, vols) in data.iter().enumerate() {
            let t = t as u32;
            let at = UVec3::new((t % per_u) * d.x, (t / per_u) * d.y, 0);
            origins.push(at.as_vec3() / size);
            write_rgba8(
                &ctx.queue,
                &texture,
                0,
                at,
                vols,
                d.with_z(d.z * (lights + 1)),
            );
        }
        let view = texture.create_view(&Default::default());
        let pass = super::OverPass::new(
            &ctx.device,
            "forest-cover tiles",
            &[
                sampler_entry(2, wgpu::SamplerBindingType::Filtering),
                storage_entry(6, wgpu::ShaderStages::VERTEX_FRAGMENT),
                texture_entry(7, FILTERABLE, wgpu::TextureViewDimension::D3),
            ],
            &TILES,
        );
        Ok(Self {
            bytes: u64::from(atlas.x) * u64::from(atlas.y) * u64::from(atlas.z) * 4,
            grid,
            origins,
            extent: d.as_vec3() / size,
            volume_dw: d.z as f32 / size.z,
            lights,
            _texture: texture,
            view,
            records: storage_buffer_of::<TileGpu>(&ctx.device, "forest-cover tiles", 64),
            pass,
        })
    }

    /// The record of tile `index` for a frame: `spacing` between slices, `slices` of them,
    /// lit by `blend` (the sun's 3 nearest baked lights, world frame).
    pub fn record(
        &self,
        index: usize,
        spacing: f32,
        slices: u32,
        blend: &crate::sphere::Blend,
    ) -> TileGpu {
        let tile = &self.grid.tiles[index];
        let b = tile.bounds();
        TileGpu {
            origin: tile.origin.to_array(),
            size: tile.size,
            lo: tile.lo,
            corners: tile.corners,
            height: tile.height,
            voxel: tile.voxel(),
            spacing,
            max_steps: (slices + 2) as f32,
            atlas_origin: self.origins[index].to_array(),
            volume_dw: self.volume_dw,
            atlas_extent: self.extent.to_array(),
            lights: self.lights,
            light_index: blend.index,
            slices: slices as f32,
            light_weight: blend.weight,
            pad0: 0.0,
            box_min: b.min.to_array(),
            pad1: 0.0,
            box_max: b.max.to_array(),
            pad2: 0.0,
        }
    }

    /// Uploads the frame's tiles (growing the buffer when needed).
    pub fn upload(
        &mut self,
        ctx: &crate::render::GpuContext,
        records: &[TileGpu],
        sampler: &wgpu::Sampler,
    ) {
        let grown = write_growing(ctx, &mut self.records, "forest-cover tiles", records);
        if grown || !self.pass.is_bound() {
            self.pass.bind(
                &ctx.device,
                "forest-cover tiles",
                &[
                    wgpu::BindGroupEntry {
                        binding: 2,
                        resource: wgpu::BindingResource::Sampler(sampler),
                    },
                    wgpu::BindGroupEntry {
                        binding: 6,
                        resource: self.records.as_entire_binding(),
                    },
                    wgpu::BindGroupEntry {
                        binding: 7,
                        resource: wgpu::BindingResource::TextureView(&self.view),
                    },
                ],
            );
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tree_at(x: f32, y: f32, z: f32) -> TreeGpu {
        TreeGpu {
            model: Mat4::from_translation(Vec3::new(x, y, z)).to_cols_array_2d(),
            tint: [1.0; 4],
        }
    }

    #[test]
    fn trees_fall_in_the_tile_under_their_trunk_and_boxes_follow_the_ground() {
        let mut terrain = Terrain::flat(256.0, 5);
        // A slope along x: height = x / 4.
        let n = terrain.resolution as usize;
        for j in 0..n {
            for i in 0..n {
                let x = -128.0 + 256.0 * i as f32 / (n - 1) as f32;
                terrain.heights[j * n + i] = x / 4.0;
            }
        }
        let trees = [tree_at(-100.0, -25.0, -100.0), tree_at(10.0, 2.5, 70.0)];
        let bounds: Vec<Aabb> = trees
            .iter()
            .map(|t| {
                let p = Mat4::from_cols_array_2d(&t.model).w_axis.truncate();
                Aabb::new(p - Vec3::new(2.0, 0.0, 2.0), p + Vec3::new(2.0, 20.0, 2.0))
            })
            .collect();
        let grid = TileGrid::new(&terrain, &trees, &bounds);
        assert_eq!(grid.tiles.len(), 2, "only tiles with trees");
        let a = &grid.tiles[grid.tile_of[0].unwrap() as usize];
        assert_eq!(a.origin, Vec2::new(-128.0, -128.0));
        assert_eq!(a.trees, vec![0]);
        // The ground under the tile is the slope: 16 m higher across it.
        assert!((a.corners[1] - a.corners[0] - 16.0).abs() < 1e-3);
        assert!((a.ground(0.5, 0.5) - (-96.0 / 4.0)).abs() < 1e-3);
        // The box holds the tree: its top 20 m above a ground that rises 1 m across it.
        let b = a.bounds();
        assert!(b.max.y >= -5.0 && b.min.y <= -25.5, "{b:?}");
        assert!(a.height >= 20.0 && a.height < 22.0, "{}", a.height);
        let top = a.world(Vec3::new(0.0, 1.0, 0.0));
        assert!((top.y - (a.corners[0] + a.lo + a.height)).abs() < 1e-4);
    }

    /// The box culls tiles (frustum, distance): it must hold every point of the tile's
    /// volume, and no more than the volume's extremes (a box too small drops tiles at the
    /// frame's edge, one too large draws tiles nobody sees).
    #[test]
    fn a_tiles_box_is_the_tightest_one_holding_its_volume() {
        let tile = Tile {
            origin: Vec2::new(-64.0, 128.0),
            size: TILE_SIZE,
            corners: [3.0, -2.0, 7.5, 1.0],
            lo: -0.5,
            height: 21.0,
            trees: vec![0],
        };
        let b = tile.bounds();
        let (mut lo, mut hi) = (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY));
        let steps = 8;
        for i in 0..=steps {
            for j in 0..=steps {
                for k in 0..=steps {
                    let uvw = Vec3::new(i as f32, j as f32, k as f32) / steps as f32;
                    let p = tile.world(uvw);
                    assert!(
                        p.cmpge(b.min - 1e-4).all() && p.cmple(b.max + 1e-4).all(),
                        "{p} at {uvw} outside {b:?}"
                    );
                    lo = lo.min(p);
                    hi = hi.max(p);
                }
            }
        }
        // The bilinear ground's extremes are at the corners: the sampled extremes are exact.
        assert!((lo - b.min).abs().max_element() < 1e-4, "{lo} vs {b:?}");
        assert!((hi - b.max).abs().max_element() < 1e-4, "{hi} vs {b:?}");
    }

    #[test]
    fn a_tile_volume_holds_its_trees_opacity_where_they_stand() {
        let terrain = Terrain::flat(128.0, 3);
        // A solid 8 m cube of species 0 (one light + sky), one voxel 1 m.
        let dims = [8u32, 8, 8];
        let mut voxels = Vec::new();
        for _ in 0..2 {
            for _ in 0..512 {
                voxels.extend([128u8, 128, 128, 255]);
            }
        }
        let volume = TexelVolume {
            species: 0,
            lights: 1,
            dims,
            box_min: [-4.0, 0.0, -4.0],
            voxel: 1.0,
            voxels,
        };
        let trees = [tree_at(-30.0, 0.0, -30.0)];
        let bounds = [Aabb::new(
            Vec3::new(-34.0, 0.0, -34.0),
            Vec3::new(-26.0, 8.0, -26.0),
        )];
        let grid = TileGrid::new(&terrain, &trees, &bounds);
        assert_eq!(grid.tiles.len(), 1);
        let vols = tile_volumes(&grid, &trees, &[0], &bounds, &[volume]);
        let d = TILE_DIMS;
        let n = (d.x * d.y * d.z) as usize;
        assert_eq!(vols[0].len(), n * 2 * 4);
        let tile = &grid.tiles[0];
        // The voxel at the cube's centre is opaque in both volumes; one far from it empty.
        let voxel_at = |p: Vec3| {
            let u = ((p.x - tile.origin.x) / tile.size * d.x as f32) as u32;
            let w = ((p.z - tile.origin.y) / tile.size * d.z as f32) as u32;
            let v = ((p.y - tile.ground(0.5, 0.5) - tile.lo) / tile.height * d.y as f32) as u32;
            ((w * d.y + v) * d.x + u) as usize
        };
        let centre = voxel_at(Vec3::new(-30.0, 4.0, -30.0));
        for v in 0..2 {
            assert!(vols[0][(v * n + centre) * 4 + 3] > 240, "volume {v}");
        }
        let far = voxel_at(Vec3::new(20.0, 4.0, 20.0));
        assert_eq!(vols[0][far * 4 + 3], 0);
    }
}
