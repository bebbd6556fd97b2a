//! Sky visibility for the reference render: how much of the sky each shaded point sees.
//!
//! The sky is a hemisphere of light. A point inside a stand sees less of it than a point in
//! a clearing, because trees (and hills) hide part of it. The reference estimates the
//! visible fraction V with the canopy model of forest light studies (Beer–Lambert through
//! the leaf area, as in the gap-fraction methods): the trees' triangles are binned into a
//! grid of cells as extinction, σ = G·A/volume (A the one-sided area of leaves and needles
//! with G = 0.5, the projection of randomly oriented flat elements; a quarter of the bark's
//! surface, the mean projection of a convex body); cells under the terrain are opaque. For
//! each of `count` directions over the upper hemisphere, cosine-weighted about the vertical
//! so that each carries the same share of an upward patch's sky light, the transmittance
//! from every cell to the sky is swept down the grid layer by layer (T = T_above ·
//! exp(−∫σ ds)), and V of a cell is the mean over the directions. The shader reads V
//! trilinearly at each shaded point.
//!
//! A first version drew one directional depth map of the whole scene per direction (exact
//! hiding, like a shadow map): on lavapipe one map of the default forest (753 trees, 61 M
//! triangles) took about 30 s, so 64 directions ≈ half an hour per reference renderer; the
//! volume takes seconds. Nothing here depends on the sun or the camera: it is built once
//! per world (on the first reference frame) and kept.

use glam::{Mat4, Vec3};
use rayon::prelude::*;

use super::GpuContext;
use crate::Result;
use crate::model::World;
use crate::model::mesh::{Aabb, Mesh};

pub use super::consts::SKY_DIRECTIONS;

/// Most cells of a scene's sky visibility grid: the cell side grows with the scene to stay
/// under it (the default forest: 3.7 m cells, 5 s on 2 cores).
pub const MAX_CELLS: usize = 2_000_000;
/// Smallest cell side (m) over a scene.
pub const MIN_CELL: f32 = 0.5;
/// The same for one object in the studio (the bake), where the grid is built per level.
pub const MAX_CELLS_STUDIO: usize = 200_000;
pub const MIN_CELL_STUDIO: f32 = 0.25;

/// Projection factor of randomly oriented flat leaves (Ross G-function, spherical).
const G_LEAF: f32 = 0.5;
/// Mean projected area over surface area of a convex body (Cauchy): bark.
const G_BARK: f32 = 0.25;

/// `count` unit directions over the upper hemisphere, cosine-weighted about +Y and
/// stratified: a Hammersley point set lifted from the unit disc (Malley's method), so that
/// every direction carries the same share of an upward patch's sky light. Deterministic.
pub fn directions(count: u32) -> Vec<Vec3> {
    let n = count.max(1);
    (0..n)
        .map(|i| {
            let u = (i as f32 + 0.5) / n as f32;
            let v = radical_inverse(i);
            let r = u.sqrt();
            let phi = std::f32::consts::TAU * v;
            let y = (1.0 - u).max(0.0).sqrt();
            Vec3::new(r * phi.cos(), y, r * phi.sin()).normalize()
        })
        .collect()
}

/// Van der Corput radical inverse in base 2.
fn radical_inverse(i: u32) -> f32 {
    (f64::from(i.reverse_bits()) / 4_294_967_296.0) as f32
}

/// A species' projected area (m², already times G) binned in its own frame: (centre, area).
pub fn area_points(tree: &crate::model::TreeModel, bin: f32) -> Vec<(Vec3, f32)> {
    let mut bins: std::collections::HashMap<[i32; 3], (Vec3, f32)> = Default::default();
    let mut add = |mesh: &Mesh, m: Mat4| {
        for t in mesh.indices.chunks_exact(3) {
            let v = |i: u32| &mesh.vertices[i as usize];
            let (a, b, c) = (v(t[0]), v(t[1]), v(t[2]));
            let pa = m.transform_point3(Vec3::from(a.position));
            let pb = m.transform_point3(Vec3::from(b.position));
            let pc = m.transform_point3(Vec3::from(c.position));
            let area = 0.5 * (pb - pa).cross(pc - pa).length();
            let g = if a.foliage > 0.5 { G_LEAF } else { G_BARK };
            let centre = (pa + pb + pc) / 3.0;
            let key = (centre / bin).floor().as_ivec3().to_array();
            let e = bins.entry(key).or_insert((Vec3::ZERO, 0.0));
            e.0 += centre * area * g;
            e.1 += area * g;
        }
    };
    add(&tree.trunk, Mat4::IDENTITY);
    for b in &tree.tree_branches {
        add(&tree.branch_limb, *b);
    }
    for t in tree.twigs_in_tree_frame() {
        add(&tree.twig, t);
    }
    bins.into_values()
        .filter(|(_, a)| *a > 0.0)
        .map(|(c, a)| (c / a, a))
        .collect()
}

/// The box a sky visibility grid covers: every tree, and the terrain when `terrain` (the
/// scene's bounds as the renderer has them), or the trees alone.
pub fn bounds_of(world: &World, terrain: bool) -> Aabb {
    let start = if terrain {
        world.terrain.bounds()
    } else {
        Aabb::EMPTY
    };
    world.forest.instances.iter().fold(start, |b, t| {
        world
            .species
            .get(t.species as usize)
            .map_or(b, |m| b.union(m.tree_bounds.transformed(t.transform())))
    })
}

/// The grid of sky visibility over a box: V per cell, 0 (sky hidden) to 1 (all open).
#[derive(Clone, Debug)]
pub struct SkyVolume {
    /// Corner of cell (0, 0, 0).
    pub origin: Vec3,
    /// Side of a cell (m).
    pub cell: f32,
    /// Cells along x, y, z.
    pub dims: [usize; 3],
    /// V per cell, y layers outermost, then z rows, then x: `(j * nz + k) * nx + i`.
    pub values: Vec<f32>,
}

impl SkyVolume {
    /// Sky visibility of `world` over `bounds` (its trees, and its terrain when `terrain`;
    /// without terrain it is one object in the studio, on a finer grid), from `count`
    /// directions.
    /// The grid [`Self::compute`] uses over `bounds`: its origin, cell side and cells along
    /// x, y, z.
    pub fn grid(bounds: &Aabb, terrain: bool) -> (Vec3, f32, [usize; 3]) {
        let ext = bounds.extent().max(Vec3::splat(1e-3));
        let volume = ext.x * ext.y * ext.z;
        let (max_cells, min_cell) = if terrain {
            (MAX_CELLS, MIN_CELL)
        } else {
            (MAX_CELLS_STUDIO, MIN_CELL_STUDIO)
        };
        let cell = (volume / max_cells as f32).cbrt().max(min_cell);
        // One cell of margin on every side, and the grid's top above everything.
        let origin = bounds.min - Vec3::splat(cell);
        let n = |e: f32| ((e / cell).ceil() as usize + 2).max(2);
        (origin, cell, [n(ext.x), n(ext.y), n(ext.z)])
    }

    pub fn compute(world: &World, bounds: &Aabb, terrain: bool, count: u32) -> Self {
        let (origin, cell, dims) = Self::grid(bounds, terrain);
        let [nx, ny, nz] = dims;
        let cells = nx * ny * nz;
        let cell_volume = cell * cell * cell;

        // Extinction per cell from every tree's binned area, splatted trilinearly.
        let mut sigma = vec![0.0f32; cells];
        let per_species: Vec<Vec<(Vec3, f32)>> = world
            .species
            .par_iter()
            .map(|t| area_points(t, 0.5 * cell.min(1.0)))
            .collect();
        for tree in &world.forest.instances {
            let Some(points) = per_species.get(tree.species as usize) else {
                continue;
            };
            let m = tree.transform();
            let s2 = tree.scale * tree.scale;
            for &(p, a) in points {
                let g = (m.transform_point3(p) - origin) / cell - Vec3::splat(0.5);
                splat(&mut sigma, dims, g, a * s2 / cell_volume);
            }
        }

        // Cells whose centre lies under the terrain hide everything.
        let solid: Vec<bool> = if terrain {
            let mut s = vec![false; cells];
            for k in 0..nz {
                for i in 0..nx {
                    let x = origin.x + (i as f32 + 0.5) * cell;
                    let z = origin.z + (k as f32 + 0.5) * cell;
                    let h = world.terrain.height_at(x, z);
                    for j in 0..ny {
                        if origin.y + (j as f32 + 0.5) * cell < h {
                            s[(j * nz + k) * nx + i] = true;
                        }
                    }
                }
            }
            s
        } else {
            Vec::new()
        };

        let dirs = directions(count);
        let sum = dirs
            .par_iter()
            .fold(
                || vec![0.0f32; cells],
                |mut acc, &d| {
                    sweep(&sigma, &solid, dims, cell, d, &mut acc);
                    acc
                },
            )
            .reduce(
                || vec![0.0f32; cells],
                |mut a, b| {
                    a.iter_mut().zip(&b).for_each(|(x, y)| *x += y);
                    a
                },
            );
        let inv = 1.0 / dirs.len() as f32;
        let mut values: Vec<f32> = sum.into_iter().map(|v| (v * inv).clamp(0.0, 1.0)).collect();
        // A cell under the terrain takes the value of the first open cell above it, so that
        // reading between cell centres at the surface does not blend in the hill's inside.
        if terrain {
            for k in 0..nz {
                for i in 0..nx {
                    let mut open_above = 1.0;
                    for j in (0..ny).rev() {
                        let idx = (j * nz + k) * nx + i;
                        if solid[idx] {
                            values[idx] = open_above;
                        } else {
                            open_above = values[idx];
                        }
                    }
                }
            }
        }
        Self {
            origin,
            cell,
            dims,
            values,
        }
    }

    /// V at a world point, trilinear between cell centres (1 outside the grid's sides and
    /// above it; the nearest layer below it).
    pub fn at(&self, p: Vec3) -> f32 {
        let [nx, ny, nz] = self.dims;
        let g = (p - self.origin) / self.cell - Vec3::splat(0.5);
        if g.x < -0.5 || g.z < -0.5 || g.x > nx as f32 - 0.5 || g.z > nz as f32 - 0.5 {
            return 1.0;
        }
        if g.y > ny as f32 - 0.5 {
            return 1.0;
        }
        let g = g.clamp(
            Vec3::ZERO,
            Vec3::new((nx - 1) as f32, (ny - 1) as f32, (nz - 1) as f32),
        );
        let (i0, j0, k0) = (g.x as usize, g.y as usize, g.z as usize);
        let (i1, j1, k1) = (
            (i0 + 1).min(nx - 1),
            (j0 + 1).min(ny - 1),
            (k0 + 1).min(nz - 1),
        );
        let f = g - Vec3::new(i0 as f32, j0 as f32, k0 as f32);
        let v = |i: usize, j: usize, k: usize| self.values[(j * nz + k) * nx + i];
        let lerp = |a: f32, b: f32, t: f32| a + (b - a) * t;
        let x00 = lerp(v(i0, j0, k0), v(i1, j0, k0), f.x);
        let x10 = lerp(v(i0, j1, k0), v(i1, j1, k0), f.x);
        let x01 = lerp(v(i0, j0, k1), v(i1, j0, k1), f.x);
        let x11 = lerp(v(i0, j1, k1), v(i1, j1, k1), f.x);
        lerp(lerp(x00, x10, f.y), lerp(x01, x11, f.y), f.z)
    }
}

/// Adds `value` at grid point `g` (cell-centre units) to its 8 neighbours, trilinearly.
fn splat(grid: &mut [f32], [nx, ny, nz]: [usize; 3], g: Vec3, value: f32) {
    if !g.is_finite() {
        return;
    }
    let g0 = g.floor();
    let f = g - g0;
    for (dj, wy) in [(0, 1.0 - f.y), (1, f.y)] {
        for (dk, wz) in [(0, 1.0 - f.z), (1, f.z)] {
            for (di, wx) in [(0, 1.0 - f.x), (1, f.x)] {
                let (i, j, k) = (g0.x as i64 + di, g0.y as i64 + dj, g0.z as i64 + dk);
                if i < 0 || j < 0 || k < 0 || i >= nx as i64 || j >= ny as i64 || k >= nz as i64 {
                    continue;
                }
                grid[(j as usize * nz + k as usize) * nx + i as usize] += value * wx * wy * wz;
            }
        }
    }
}

/// Transmittance towards the sky along `d` from every cell, added to `acc`: top layer
/// first; each cell's ray goes up one layer to a point between the cell centres above
/// (bilinear; open sky past the grid's sides), through σ sampled along the way.
fn sweep(sigma: &[f32], solid: &[bool], dims: [usize; 3], cell: f32, d: Vec3, acc: &mut [f32]) {
    let [nx, ny, nz] = dims;
    let layer = nx * nz;
    let (ox, oz) = (d.x / d.y, d.z / d.y);
    let ds = cell / d.y;
    // Samples of σ along one layer's step: about one per cell crossed.
    let steps = (ox.abs().max(oz.abs()).ceil() as usize).clamp(1, 64);
    let mut above = vec![1.0f32; layer];
    let mut here = vec![0.0f32; layer];
    // σ at fractional (x, z) in layer j (0 outside).
    let sigma_at = |j: usize, x: f32, z: f32| -> f32 {
        bilinear(&sigma[j * layer..(j + 1) * layer], nx, nz, x, z, 0.0)
    };
    for j in (0..ny).rev() {
        for k in 0..nz {
            for i in 0..nx {
                let idx = k * nx + i;
                if !solid.is_empty() && solid[j * layer + idx] {
                    here[idx] = 0.0;
                    continue;
                }
                let (x, z) = (i as f32, k as f32);
                let t_up = if j + 1 < ny {
                    bilinear(&above, nx, nz, x + ox, z + oz, 1.0)
                } else {
                    1.0
                };
                let mut tau = 0.0;
                for s in 0..steps {
                    let t = (s as f32 + 0.5) / steps as f32;
                    let (sx, sz) = (x + ox * t, z + oz * t);
                    let lo = sigma_at(j, sx, sz);
                    let hi = if j + 1 < ny {
                        sigma_at(j + 1, sx, sz)
                    } else {
                        0.0
                    };
                    tau += lo + (hi - lo) * t;
                }
                here[idx] = t_up * (-tau * ds / steps as f32).exp();
            }
        }
        for (a, h) in acc[j * layer..(j + 1) * layer].iter_mut().zip(&here) {
            *a += h;
        }
        std::mem::swap(&mut above, &mut here);
    }
}

/// Bilinear read of an nx x nz layer at fractional cell coordinates; `outside` past its sides.
fn bilinear(layer: &[f32], nx: usize, nz: usize, x: f32, z: f32, outside: f32) -> f32 {
    if !(x > -1.0 && z > -1.0 && x < nx as f32 && z < nz as f32) {
        return outside;
    }
    let (x0, z0) = (x.floor(), z.floor());
    let (fx, fz) = (x - x0, z - z0);
    let (x0, z0) = (x0 as i64, z0 as i64);
    let v = |i: i64, k: i64| -> f32 {
        if i < 0 || k < 0 || i >= nx as i64 || k >= nz as i64 {
            outside
        } else {
            layer[k as usize * nx + i as usize]
        }
    };
    let a = v(x0, z0) + (v(x0 + 1, z0) - v(x0, z0)) * fx;
    let b = v(x0, z0 + 1) + (v(x0 + 1, z0 + 1) - v(x0, z0 + 1)) * fx;
    a + (b - a) * fz
}

/// The volume's placement as the fragment shader reads it (`SkyVolume` in geometry.wgsl).
#[repr(C)]
#[derive(Clone, Copy, Debug, bytemuck::Pod, bytemuck::Zeroable)]
pub struct SkyVolumeGpu {
    /// Corner of the grid; w unused.
    pub origin: [f32; 4],
    /// 1 / the grid's size along x, z, y (texture u, v, w); w unused.
    pub inv_size: [f32; 4],
}

/// The sky visibility on the GPU: a 3D texture (x, z, y as u, v, w) and its placement.
pub struct SkyVisibility {
    pub count: u32,
    pub cell: f32,
    /// Bytes of the 3D texture (one per cell).
    pub bytes: u64,
    pub view: wgpu::TextureView,
    pub placement: wgpu::Buffer,
}

fn texture_3d(ctx: &GpuContext, dims: [u32; 3], data: &[u8]) -> Result<wgpu::TextureView> {
    let size = wgpu::Extent3d {
        width: dims[0],
        height: dims[1],
        depth_or_array_layers: dims[2],
    };
    let texture = ctx.checked("allocating the sky visibility volume", || {
        ctx.device.create_texture(&wgpu::TextureDescriptor {
            label: Some("sky visibility"),
            size,
            mip_level_count: 1,
            sample_count: 1,
            dimension: wgpu::TextureDimension::D3,
            format: wgpu::TextureFormat::R8Unorm,
            usage: wgpu::TextureUsages::TEXTURE_BINDING | wgpu::TextureUsages::COPY_DST,
            view_formats: &[],
        })
    })?;
    ctx.queue.write_texture(
        texture.as_image_copy(),
        data,
        wgpu::TexelCopyBufferLayout {
            offset: 0,
            bytes_per_row: Some(dims[0]),
            rows_per_image: Some(dims[1]),
        },
        size,
    );
    Ok(texture.create_view(&Default::default()))
}

fn placement_buffer(ctx: &GpuContext, p: SkyVolumeGpu) -> wgpu::Buffer {
    let buf = ctx.device.create_buffer(&wgpu::BufferDescriptor {
        label: Some("sky visibility placement"),
        size: std::mem::size_of::<SkyVolumeGpu>() as u64,
        usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
        mapped_at_creation: false,
    });
    ctx.queue.write_buffer(&buf, 0, bytemuck::bytes_of(&p));
    buf
}

impl SkyVisibility {
    /// Uploads `volume` (computed from `count` directions).
    pub fn upload(ctx: &GpuContext, volume: &SkyVolume, count: u32) -> Result<Self> {
        let [nx, ny, nz] = volume.dims;
        let max = ctx.device.limits().max_texture_dimension_3d as usize;
        if nx > max || ny > max || nz > max {
            return Err(crate::Error::Gpu(format!(
                "the sky visibility grid ({nx}x{ny}x{nz}) exceeds the adapter's 3D texture limit ({max})"
            )));
        }
        // Layers (y) outermost in memory, so the texture's depth is y.
        let data: Vec<u8> = volume
            .values
            .iter()
            .map(|v| (v * 255.0).round() as u8)
            .collect();
        let view = texture_3d(ctx, [nx as u32, nz as u32, ny as u32], &data)?;
        let size = Vec3::new(nx as f32, nz as f32, ny as f32) * volume.cell;
        let placement = placement_buffer(
            ctx,
            SkyVolumeGpu {
                origin: volume.origin.extend(0.0).to_array(),
                inv_size: (Vec3::ONE / size).extend(0.0).to_array(),
            },
        );
        Ok(Self {
            count,
            cell: volume.cell,
            bytes: data.len() as u64,
            view,
            placement,
        })
    }

    /// What group 0 binds when there is no volume: one open cell.
    pub fn placeholder(ctx: &GpuContext) -> Result<Self> {
        let view = texture_3d(ctx, [1, 1, 1], &[255])?;
        Ok(Self {
            count: 0,
            cell: 1.0,
            bytes: 1,
            view,
            placement: placement_buffer(
                ctx,
                SkyVolumeGpu {
                    origin: [0.0; 4],
                    inv_size: [1.0, 1.0, 1.0, 0.0],
                },
            ),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn directions_are_upward_unit_vectors_weighted_towards_the_zenith() {
        let d = directions(256);
        assert_eq!(d.len(), 256);
        assert!(
            d.iter()
                .all(|v| (v.length() - 1.0).abs() < 1e-4 && v.y > 0.0)
        );
        // Cosine weighting: the mean of cos(zenith angle) is 2/3 (uniform would give 1/2).
        let mean_y: f32 = d.iter().map(|v| v.y).sum::<f32>() / d.len() as f32;
        assert!((mean_y - 2.0 / 3.0).abs() < 0.01, "{mean_y}");
        let mean_h = d
            .iter()
            .fold(Vec3::ZERO, |a, v| a + Vec3::new(v.x, 0.0, v.z))
            / 256.0;
        assert!(mean_h.length() < 0.02, "{mean_h}");
    }

    /// A slab of uniform extinction σ and thickness t over open ground: under it a
    /// direction at zenith angle θ sees exp(−σt/cosθ); the cosine-weighted mean over the
    /// hemisphere is 2·E3(σt) (E3 the exponential integral of order 3).
    #[test]
    fn the_sweep_matches_the_slab_formula() {
        let (nx, ny, nz) = (120, 12, 120);
        let cell = 1.0;
        let sigma_v = 0.05;
        let mut sigma = vec![0.0f32; nx * ny * nz];
        // Layers 4..10 hold the slab (6 m thick).
        for j in 4..10 {
            for v in &mut sigma[j * nx * nz..(j + 1) * nx * nz] {
                *v = sigma_v;
            }
        }
        let dirs = directions(256);
        let mut acc = vec![0.0f32; nx * ny * nz];
        for &d in &dirs {
            sweep(&sigma, &[], [nx, ny, nz], cell, d, &mut acc);
        }
        // The centre column, layer 1 (under the slab, 2 layers below it).
        let (i, k) = (nx / 2, nz / 2);
        let v = acc[(nz + k) * nx + i] / dirs.len() as f32;
        // 2·E3(x) by numerical integration over μ = cosθ: 2 ∫ μ exp(−x/μ) dμ.
        let x = sigma_v * 6.0;
        let expect: f32 = (0..10_000)
            .map(|s| {
                let mu = (s as f32 + 0.5) / 10_000.0;
                2.0 * mu * (-x / mu).exp() / 10_000.0
            })
            .sum();
        // The grid is finite (60 m each side): the lowest directions leave it early, so
        // the sweep sees a little more sky than the infinite slab.
        assert!(
            v >= expect - 0.01 && v < expect + 0.04,
            "sweep {v}, slab {expect}"
        );
        // Above the slab everything is open.
        let top = acc[(11 * nz + k) * nx + i] / dirs.len() as f32;
        assert!((top - 1.0).abs() < 1e-4, "{top}");
    }

    #[test]
    fn solid_cells_hide_the_sky_and_a_wall_hides_its_side() {
        let (nx, ny, nz) = (40, 20, 40);
        let sigma = vec![0.0f32; nx * ny * nz];
        let mut solid = vec![false; nx * ny * nz];
        // A wall at x >= 20, full height.
        for j in 0..ny {
            for k in 0..nz {
                for i in 20..nx {
                    solid[(j * nz + k) * nx + i] = true;
                }
            }
        }
        let dirs = directions(128);
        let mut acc = vec![0.0f32; nx * ny * nz];
        for &d in &dirs {
            sweep(&sigma, &solid, [nx, ny, nz], 1.0, d, &mut acc);
        }
        let v = |i: usize, j: usize| acc[(j * nz + 20) * nx + i] / dirs.len() as f32;
        assert_eq!(v(25, 5), 0.0);
        // At the wall's foot about half the sky is hidden (a vertical wall hides the
        // half-space beyond it: half of the cosine-weighted hemisphere).
        let foot = v(19, 0);
        assert!(foot > 0.4 && foot < 0.62, "{foot}");
        // Far from the wall, more sky.
        assert!(v(2, 0) > foot + 0.2, "{} vs {foot}", v(2, 0));
    }
}
