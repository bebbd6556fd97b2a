//! The texel bake (Meyer-Neyret 1998, as the seeds build their reference volumes): each
//! species' whole tree as RGBA volumes in its box, made from the geometry by rendering
//! slabs. An orthographic camera whose near and far planes bound one voxel-thick slab
//! photographs the tree, supersampled so that alpha is the coverage of that slab; the
//! slab images stacked are one volume. Lit as the BTF images are: one volume per baked
//! light direction (sun only, self-shadowed by the whole tree, since the shadow map sees
//! all of it) and one lit by the sky alone (its own leaves hiding part of the sky), so the
//! sun can move at render time.
//!
//! A slab photographed along one axis misses the surfaces parallel to that axis (a wall
//! seen edge-on covers nothing), so the slabs are taken along all three axes, as the seeds'
//! three stacks are, and from both sides of each (a leaf shows the side that faces the
//! camera, lit or not; bark facing away is culled), and merged per voxel: the largest
//! coverage, with the coverage-weighted mean colour of the six views.
//!
//! Rendering each slab on its own (near and far planes around it) costs one render of the
//! whole tree per slab, shot and side: a fir at 64 voxels took 148 s on lavapipe from one
//! side. [`bake_volume`] instead draws each view once and lets every fragment add its
//! pixel's coverage and colour to the voxel it lies in (`render::voxelize`): every slab in
//! one pass. The coverage is the same (each voxel keeps a mask of its pixels covered); the
//! colour is the mean of every surface in the voxel where the slab picture keeps the
//! nearest, so the two agree exactly where a pixel sees one surface per slab (tests/
//! texel.rs checks it against [`bake_volume_by_slabs`]).

use glam::{UVec3, Vec3};

use crate::color::{linear_to_srgb, srgb_lut};
use crate::format::TexelVolume;
use crate::model::World;
use crate::model::mesh::Aabb;
use crate::model::params::{TexelParams, TexelSource};
use crate::model::tree::TreeModel;
use crate::render::sky_visibility::SKY_DIRECTIONS;
use crate::render::{Camera, GpuContext, Renderer};
use crate::sphere::DirectionSet;
use crate::{Error, Result};

use super::{studio_frame, studio_shots, studio_world};

/// Where a species' volume lies: its box (object frame), grid and voxel side.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TexelGrid {
    pub box_min: Vec3,
    pub dims: UVec3,
    pub voxel: f32,
}

impl TexelGrid {
    /// The grid over `bounds` with `resolution` cubic voxels along its longest side, centred
    /// on the bounds (a little larger than them on the other sides).
    pub fn around(bounds: &Aabb, resolution: u32) -> Option<TexelGrid> {
        if bounds.is_empty() || resolution == 0 {
            return None;
        }
        let extent = bounds.extent();
        let longest = extent.max_element();
        if !(longest.is_finite() && longest > 0.0) {
            return None;
        }
        let voxel = longest / resolution as f32;
        let dims = (extent / voxel)
            .ceil()
            .as_uvec3()
            .clamp(UVec3::ONE, UVec3::splat(resolution));
        let size = dims.as_vec3() * voxel;
        Some(TexelGrid {
            box_min: bounds.center() - 0.5 * size,
            dims,
            voxel,
        })
    }

    pub fn box_max(&self) -> Vec3 {
        self.box_min + self.dims.as_vec3() * self.voxel
    }

    /// Voxels in one volume.
    pub fn voxel_count(&self) -> usize {
        (self.dims.x * self.dims.y * self.dims.z) as usize
    }
}

/// The grid of a species' tree at `resolution`.
pub fn grid_of(tree: &TreeModel, resolution: u32) -> Option<TexelGrid> {
    TexelGrid::around(&tree.tree_bounds, resolution)
}

/// Voxelisation passes a texel bake of `world` makes with `lights` light samples (per
/// species, 3 axes x 2 sides x (lights + the sky)): what its progress counts.
pub fn step_count(world: &World, resolution: u32, lights: u32) -> u64 {
    let per_species = 6 * (u64::from(lights) + 1);
    world
        .species
        .iter()
        .filter(|t| grid_of(t, resolution).is_some())
        .count() as u64
        * per_species
}

/// One axis the slabs are stacked along: the camera looks down `-axis` with `up` as the
/// image's up.
struct SlabAxis {
    axis: usize,
    up: Vec3,
}

const AXES: [SlabAxis; 3] = [
    SlabAxis {
        axis: 0,
        up: Vec3::Y,
    },
    SlabAxis {
        axis: 1,
        up: Vec3::NEG_Z,
    },
    SlabAxis {
        axis: 2,
        up: Vec3::Y,
    },
];

/// Per volume and voxel, what the three axes saw: premultiplied linear colour summed over
/// them, their coverage summed (the colour's weight) and the largest coverage.
struct Accumulator {
    voxels: usize,
    color: Vec<Vec3>,
    weight: Vec<f32>,
    alpha: Vec<f32>,
}

impl Accumulator {
    fn new(volumes: usize, voxels: usize) -> Self {
        Self {
            voxels,
            color: vec![Vec3::ZERO; volumes * voxels],
            weight: vec![0.0; volumes * voxels],
            alpha: vec![0.0; volumes * voxels],
        }
    }

    /// Voxel `i` of volume `v` seen by one axis: `coverage` and premultiplied linear colour.
    fn add(&mut self, v: usize, i: usize, coverage: f32, premultiplied: Vec3) {
        if coverage <= 0.0 {
            return;
        }
        let k = v * self.voxels + i;
        self.color[k] += premultiplied;
        self.weight[k] += coverage;
        self.alpha[k] = self.alpha[k].max(coverage);
    }

    /// RGBA8 (sRGB colour, premultiplied): the coverage-weighted mean colour of what the
    /// axes saw, at the largest coverage.
    fn into_rgba(self) -> Vec<u8> {
        let mut out = vec![0u8; self.weight.len() * 4];
        for (k, px) in out.chunks_exact_mut(4).enumerate() {
            if self.weight[k] <= 0.0 {
                continue;
            }
            let c = self.color[k] * (self.alpha[k] / self.weight[k]);
            px[0] = linear_to_srgb(c.x);
            px[1] = linear_to_srgb(c.y);
            px[2] = linear_to_srgb(c.z);
            px[3] = (self.alpha[k] * 255.0 + 0.5) as u8;
        }
        out
    }
}

/// Voxel colouring as Babahenini et al. implement it: every pixel of a depth image writes
/// its colour, opaque, into the voxel at its depth. The depth images are the voxelisation
/// passes' own views (one down each axis from either side, `ss` pixels per voxel side):
/// per pixel, the nearest voxel along the view whose coverage mask holds that pixel is
/// where its depth lies. Per volume and voxel: the colour seen there (premultiplied linear,
/// weighted by the pixels that landed on it) and their weight.
struct Colouring {
    voxels: usize,
    color: Vec<Vec3>,
    weight: Vec<f32>,
}

impl Colouring {
    fn new(volumes: usize, voxels: usize) -> Self {
        Self {
            voxels,
            color: vec![Vec3::ZERO; volumes * voxels],
            weight: vec![0.0; volumes * voxels],
        }
    }

    /// One view of volume `v`: `samples` of the grid seen down `axis` from its + side
    /// (`side` 1) or - side; each pixel lands on the first voxel along the view that
    /// covers it.
    fn add_view(
        &mut self,
        v: usize,
        grid: &TexelGrid,
        axis: usize,
        side: f32,
        samples: &[crate::render::voxelize::VoxelSum],
        per_pixel: f32,
    ) {
        let (u, w) = match axis {
            0 => (1, 2),
            1 => (0, 2),
            _ => (0, 1),
        };
        let d = grid.dims;
        for cw in 0..d[w] {
            for cu in 0..d[u] {
                let mut seen = 0u64;
                for step in 0..d[axis] {
                    let layer = if side > 0.0 { d[axis] - 1 - step } else { step };
                    let mut cell = glam::IVec3::ZERO;
                    cell[axis] = layer as i32;
                    cell[u] = cu as i32;
                    cell[w] = cw as i32;
                    let Some(i) = index_of(grid, cell) else {
                        continue;
                    };
                    let s = &samples[i];
                    let new = s.mask & !seen;
                    if new != 0 && s.fragments > 0 {
                        let weight = new.count_ones() as f32 * per_pixel;
                        let k = v * self.voxels + i;
                        self.color[k] += s.color / s.fragments as f32 * weight;
                        self.weight[k] += weight;
                    }
                    seen |= s.mask;
                }
            }
        }
    }

    /// RGBA8 (sRGB colour): opaque where any pixel landed, its mean colour.
    fn into_rgba(self) -> Vec<u8> {
        let mut out = vec![0u8; self.weight.len() * 4];
        for (k, px) in out.chunks_exact_mut(4).enumerate() {
            if self.weight[k] <= 0.0 {
                continue;
            }
            let c = self.color[k] / self.weight[k];
            px[0] = linear_to_srgb(c.x);
            px[1] = linear_to_srgb(c.y);
            px[2] = linear_to_srgb(c.z);
            px[3] = 255;
        }
        out
    }
}

/// One axis' view of the grid: the camera looking down it from outside the box, the image's
/// right and up axes, and the image's size in voxels.
struct AxisView {
    forward: Vec3,
    right: Vec3,
    up: Vec3,
    w: u32,
    h: u32,
    eye: Vec3,
    margin: f32,
}

impl AxisView {
    /// The view down `ax` from the +axis side (`side` 1) or the -axis side (-1).
    fn new(grid: &TexelGrid, ax: &SlabAxis, side: f32) -> Self {
        let a = ax.axis;
        let forward = -axis_vec(a) * side;
        let right = forward.cross(ax.up);
        let size = grid.dims.as_vec3() * grid.voxel;
        let centre = grid.box_min + 0.5 * size;
        let margin = grid.voxel;
        Self {
            forward,
            right,
            up: ax.up,
            w: dim_along(grid, right).max(1),
            h: dim_along(grid, ax.up).max(1),
            eye: centre + axis_vec(a) * side * (0.5 * size[a] + margin),
            margin,
        }
    }

    fn camera(&self, grid: &TexelGrid) -> Camera {
        Camera::orthographic(
            self.eye,
            self.forward,
            self.up,
            0.5 * self.h as f32 * grid.voxel,
        )
    }
}

/// Bakes the volumes of `tree` (one species' whole tree) on `grid`, lit by each of
/// `lights` and by the sky: per axis, side and shot, one voxelisation pass (every slab at
/// once, see [`crate::render::voxelize`]) at `supersample` pixels per voxel side.
/// `progress` is told each pass.
pub fn bake_volume(
    ctx: &GpuContext,
    tree: &TreeModel,
    species: u32,
    grid: &TexelGrid,
    lights: &DirectionSet,
    supersample: u32,
    progress: &mut dyn FnMut(),
) -> Result<TexelVolume> {
    bake_volume_from(
        ctx,
        tree,
        species,
        grid,
        lights,
        supersample,
        TexelSource::Slabs,
        progress,
    )
}

/// [`bake_volume`] with the volumes made the `source` way: the slabs' coverage and colour,
/// or voxel colouring from the same passes seen as depth images.
#[allow(clippy::too_many_arguments)]
pub fn bake_volume_from(
    ctx: &GpuContext,
    tree: &TreeModel,
    species: u32,
    grid: &TexelGrid,
    lights: &DirectionSet,
    supersample: u32,
    source: TexelSource,
    progress: &mut dyn FnMut(),
) -> Result<TexelVolume> {
    let studio = studio_world(tree.clone());
    let mut renderer = Renderer::new(ctx, &studio)?;
    renderer.prepare_reference(ctx, &studio, SKY_DIRECTIONS, false)?;
    let ss = supersample.clamp(1, crate::render::voxelize::MAX_SUPERSAMPLE);
    let shots = studio_shots(lights);
    let n = grid.voxel_count();
    let mut acc = Accumulator::new(shots.len(), n);
    let mut colouring = Colouring::new(shots.len(), n);
    let target = renderer.voxel_target(ctx, grid.box_min, grid.dims, grid.voxel, ss)?;
    let shadow_map = super::studio_shadow_map(grid.dims.max_element() * ss);
    let per_pixel = 1.0 / (ss * ss) as f32;
    for (ax, side) in AXES.iter().flat_map(|ax| [(ax, 1.0), (ax, -1.0)]) {
        let view = AxisView::new(grid, ax, side);
        let camera = view.camera(grid);
        for (v, &(sun, sky)) in shots.iter().enumerate() {
            let frame = studio_frame(camera, sun, sky, shadow_map);
            renderer.voxelize(ctx, &frame, view.w * ss, view.h * ss, &target)?;
            let samples = target.read(ctx)?;
            match source {
                TexelSource::Slabs => {
                    for (i, s) in samples.iter().enumerate() {
                        if s.fragments == 0 {
                            continue;
                        }
                        let coverage = s.covered as f32 * per_pixel;
                        acc.add(v, i, coverage, s.color / s.fragments as f32 * coverage);
                    }
                }
                TexelSource::VoxelColouring => {
                    colouring.add_view(v, grid, ax.axis, side, &samples, per_pixel)
                }
            }
            progress();
        }
    }
    let voxels = match source {
        TexelSource::Slabs => acc.into_rgba(),
        TexelSource::VoxelColouring => colouring.into_rgba(),
    };
    Ok(TexelVolume {
        species,
        lights: lights.len() as u32,
        dims: grid.dims.to_array(),
        box_min: grid.box_min.to_array(),
        voxel: grid.voxel,
        voxels,
    })
}

/// [`bake_volume`] the slow way the seeds describe it: one render per voxel-thick slab
/// (near and far planes around it) per axis and shot, from both sides of each axis (bark
/// is drawn with its back faces culled, so one side alone misses the bark facing away).
/// The reference the one-pass voxelisation is checked against (tests/texel.rs); too slow
/// for trees (a fir at 64 voxels from one side: 805 renders, 148 s on lavapipe, against
/// the voxelisation's 21 passes).
pub fn bake_volume_by_slabs(
    ctx: &GpuContext,
    tree: &TreeModel,
    species: u32,
    grid: &TexelGrid,
    lights: &DirectionSet,
    supersample: u32,
) -> Result<TexelVolume> {
    let studio = studio_world(tree.clone());
    let mut renderer = Renderer::new(ctx, &studio)?;
    renderer.prepare_reference(ctx, &studio, SKY_DIRECTIONS, false)?;
    let shots = studio_shots(lights);
    let n = grid.voxel_count();
    let mut acc = Accumulator::new(shots.len(), n);
    let lut = srgb_lut();
    let shadow_map = super::studio_shadow_map(grid.dims.max_element() * supersample);
    for (ax, side) in AXES.iter().flat_map(|ax| [(ax, 1.0), (ax, -1.0)]) {
        let a = ax.axis;
        let view = AxisView::new(grid, ax, side);
        let centre = grid.box_min + 0.5 * grid.dims.as_vec3() * grid.voxel;
        for layer in 0..grid.dims[a] {
            // The slab holds voxel layer `layer` along the axis (0 = lowest coordinate).
            let from_eye = if side > 0.0 {
                grid.dims[a] - layer
            } else {
                layer + 1
            };
            let far = view.margin + from_eye as f32 * grid.voxel;
            let camera = Camera::slab(
                view.eye,
                view.forward,
                view.up,
                0.5 * view.h as f32 * grid.voxel,
                far - grid.voxel,
                far,
            );
            for (v, &(sun, sky)) in shots.iter().enumerate() {
                let frame = studio_frame(camera, sun, sky, shadow_map);
                let (img, _) = renderer.render_image(ctx, &frame, view.w, view.h, supersample)?;
                for (px, py, p) in img.enumerate_pixels() {
                    let cov = f32::from(p.0[3]) / 255.0;
                    // The voxel under this pixel's centre.
                    let q = centre
                        + view.right * ((px as f32 + 0.5) - 0.5 * view.w as f32) * grid.voxel
                        + view.up * (0.5 * view.h as f32 - (py as f32 + 0.5)) * grid.voxel;
                    let mut cell = ((q - grid.box_min) / grid.voxel).floor().as_ivec3();
                    cell[a] = layer as i32;
                    if let Some(i) = index_of(grid, cell) {
                        let c = Vec3::new(
                            lut[p.0[0] as usize],
                            lut[p.0[1] as usize],
                            lut[p.0[2] as usize],
                        );
                        acc.add(v, i, cov, c);
                    }
                }
            }
        }
    }
    Ok(volume_of(species, lights, grid, acc))
}

fn volume_of(
    species: u32,
    lights: &DirectionSet,
    grid: &TexelGrid,
    acc: Accumulator,
) -> TexelVolume {
    TexelVolume {
        species,
        lights: lights.len() as u32,
        dims: grid.dims.to_array(),
        box_min: grid.box_min.to_array(),
        voxel: grid.voxel,
        voxels: acc.into_rgba(),
    }
}

/// The texel volumes of every species of `world` (none when `resolution` is 0).
pub fn bake_texels(
    ctx: &GpuContext,
    world: &World,
    resolution: u32,
    lights: u32,
    supersample: u32,
    how: &TexelParams,
    progress: &mut dyn FnMut(u64, &str),
) -> Result<Vec<TexelVolume>> {
    if resolution == 0 {
        return Ok(Vec::new());
    }
    let lights =
        DirectionSet::with_count(lights as usize).map_err(|e| Error::BadInput(e.to_string()))?;
    let mut out = Vec::with_capacity(world.species.len());
    let mut done = 0u64;
    for (s, tree) in world.species.iter().enumerate() {
        let Some(grid) = grid_of(tree, resolution) else {
            continue;
        };
        let what = format!("{} texel volume", tree.name);
        out.push(bake_volume_from(
            ctx,
            tree,
            s as u32,
            &grid,
            &lights,
            supersample,
            how.source,
            &mut || {
                done += 1;
                progress(done, &what);
            },
        )?);
    }
    Ok(out)
}

fn axis_vec(a: usize) -> Vec3 {
    match a {
        0 => Vec3::X,
        1 => Vec3::Y,
        _ => Vec3::Z,
    }
}

/// Voxels of `grid` along the (axis-aligned, unit) direction `d`.
fn dim_along(grid: &TexelGrid, d: Vec3) -> u32 {
    let a = d.abs();
    if a.x > 0.5 {
        grid.dims.x
    } else if a.y > 0.5 {
        grid.dims.y
    } else {
        grid.dims.z
    }
}

fn index_of(grid: &TexelGrid, cell: glam::IVec3) -> Option<usize> {
    let d = grid.dims.as_ivec3();
    if cell.cmplt(glam::IVec3::ZERO).any() || cell.cmpge(d).any() {
        return None;
    }
    Some(((cell.z * d.y + cell.y) * d.x + cell.x) as usize)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_grid_has_cubic_voxels_and_the_resolution_on_the_longest_side() {
        let b = Aabb::new(Vec3::new(-2.0, 0.0, -3.0), Vec3::new(2.0, 18.0, 3.0));
        let g = TexelGrid::around(&b, 64).unwrap();
        assert_eq!(g.dims, UVec3::new(15, 64, 22));
        assert!((g.voxel - 18.0 / 64.0).abs() < 1e-6);
        // It holds the bounds, centred.
        assert!(g.box_min.cmple(b.min).all() && g.box_max().cmpge(b.max).all());
        assert!((0.5 * (g.box_min + g.box_max()) - b.center()).length() < 1e-5);
        assert!(TexelGrid::around(&Aabb::EMPTY, 64).is_none());
        assert!(TexelGrid::around(&b, 0).is_none());
    }

    #[test]
    fn voxel_indices_are_x_fastest_and_refuse_cells_outside() {
        let g = TexelGrid {
            box_min: Vec3::ZERO,
            dims: UVec3::new(3, 4, 5),
            voxel: 1.0,
        };
        assert_eq!(
            index_of(&g, glam::IVec3::new(1, 2, 3)),
            Some((3 * 4 + 2) * 3 + 1)
        );
        assert_eq!(index_of(&g, glam::IVec3::new(3, 0, 0)), None);
        assert_eq!(index_of(&g, glam::IVec3::new(0, -1, 0)), None);
    }
}
