//! The world on the GPU: each species' trunk, limb and twig meshes with the transforms of
//! their parts in the tree frame (the hierarchy as the model keeps it), the terrain, and a
//! per-frame buffer of tree instances filled from the culled lists.

use glam::{Mat4, Vec3};
use wgpu::util::DeviceExt;

use super::GpuContext;
use super::camera::Frustum;
use super::pipelines::MeshPipelines;
use super::terrain_maps::TerrainMaps;
use crate::model::World;
use crate::model::mesh::{Aabb, Mesh};
use crate::model::terrain_lod::{ChunkedTerrain, TerrainLayout, TerrainView};
use crate::{Error, Result};

mod species;
use species::SpeciesUpload;

/// Largest forest the GPU buffers are sized for: the scene file's own limit.
pub const MAX_TREES: usize = crate::model::params::MAX_TREES as usize;

/// One tree instance as `instancing.wgsl` reads it (`struct TreeInstance`).
#[repr(C)]
#[derive(Clone, Copy, Debug, bytemuck::Pod, bytemuck::Zeroable)]
pub struct TreeGpu {
    pub model: [[f32; 4]; 4],
    pub tint: [f32; 4],
}

/// A part set's uniform as `instancing.wgsl` reads it (`struct PartSet`).
#[repr(C)]
#[derive(Clone, Copy, Debug, bytemuck::Pod, bytemuck::Zeroable)]
pub struct PartSetGpu {
    /// Parts per tree: instance `i` of a draw is part `i % count` of tree `i / count`.
    pub count: u32,
    /// Fragments whose texture alpha is below this are discarded (0: none are).
    pub alpha_cutoff: f32,
    /// 1: the fragments sample the set's texture; 0: they skip it (white, nothing
    /// discarded), as every procedural part does.
    /// 2: the terrain, whose coarse levels read its maps ([`TerrainMaps`]).
    pub textured: u32,
    pub _pad2: u32,
    /// Where the world falls in the terrain's maps ([`TerrainMaps::placement`]).
    pub terrain_map: [f32; 4],
}

/// How a part set is drawn: two-sided (leaves, needles, double-sided materials: no
/// culling) or not, its vertex colours times `texture` (the 1x1 white one for untextured
/// parts), and discarded below `alpha_cutoff`.
#[derive(Clone, Copy)]
pub struct PartLook<'a> {
    pub two_sided: bool,
    pub texture: &'a wgpu::TextureView,
    pub sampler: &'a wgpu::Sampler,
    pub alpha_cutoff: f32,
    /// The texture is a material's (not the white one) or the alpha test is on.
    pub textured: bool,
    /// The terrain's normals and heights (the white texture for every other part set).
    pub normals: &'a wgpu::TextureView,
    /// The terrain's: `texture` and `normals` are its maps, read where a coarse level is
    /// drawn, placed so.
    pub terrain_map: Option<[f32; 4]>,
}

pub struct GpuMesh {
    pub vertices: wgpu::Buffer,
    pub indices: wgpu::Buffer,
    pub index_count: u32,
}

impl GpuMesh {
    fn new(ctx: &GpuContext, label: &str, mesh: &Mesh) -> Option<Self> {
        if mesh.indices.is_empty() || mesh.vertices.is_empty() {
            return None;
        }
        let vertices = ctx
            .device
            .create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some(&format!("{label} vertices")),
                contents: bytemuck::cast_slice(&mesh.vertices),
                usage: wgpu::BufferUsages::VERTEX,
            });
        let indices = ctx
            .device
            .create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some(&format!("{label} indices")),
                contents: bytemuck::cast_slice(&mesh.indices),
                usage: wgpu::BufferUsages::INDEX,
            });
        Some(Self {
            vertices,
            indices,
            index_count: mesh.indices.len() as u32,
        })
    }

    pub fn triangles(&self) -> u64 {
        u64::from(self.index_count / 3)
    }

    pub fn bytes(&self) -> u64 {
        self.vertices.size() + self.indices.size()
    }
}

/// Which parts of a tree a [`PartSet`] draws.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PartKind {
    Trunk,
    Limbs,
    Twigs,
}

/// Every part of a tree.
pub(crate) const ALL_PARTS: [PartKind; 3] = [PartKind::Trunk, PartKind::Limbs, PartKind::Twigs];

/// A mesh drawn once per part of a tree: the trunk (one part), the limbs (one per main
/// branch) or the twigs (one per twig of the whole tree).
pub struct PartSet {
    pub kind: PartKind,
    pub mesh: GpuMesh,
    pub count: u32,
    pub bind_group: wgpu::BindGroup,
    /// Leaves, needles and double-sided imported materials: drawn two-sided, after the rest.
    pub foliage: bool,
    /// Its fragments are alpha-tested against a texture (an imported tree's cards): the
    /// depth-only passes need a fragment stage for it.
    pub cutout: bool,
}

impl PartSet {
    fn new(
        ctx: &GpuContext,
        layout: &wgpu::BindGroupLayout,
        kind: PartKind,
        label: &str,
        mesh: &Mesh,
        parts: &[Mat4],
        look: PartLook<'_>,
    ) -> Option<Self> {
        let mesh = GpuMesh::new(ctx, label, mesh)?;
        if parts.is_empty() {
            return None;
        }
        let matrices: Vec<[[f32; 4]; 4]> = parts.iter().map(|m| m.to_cols_array_2d()).collect();
        let parts_buf = ctx
            .device
            .create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some(&format!("{label} parts")),
                contents: bytemuck::cast_slice(&matrices),
                usage: wgpu::BufferUsages::STORAGE,
            });
        let params = ctx
            .device
            .create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some(&format!("{label} part set")),
                contents: bytemuck::bytes_of(&PartSetGpu {
                    count: parts.len() as u32,
                    alpha_cutoff: look.alpha_cutoff,
                    textured: if look.terrain_map.is_some() {
                        2
                    } else {
                        u32::from(look.textured)
                    },
                    terrain_map: look.terrain_map.unwrap_or_default(),
                    ..bytemuck::Zeroable::zeroed()
                }),
                usage: wgpu::BufferUsages::UNIFORM,
            });
        let bind_group = ctx.device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some(label),
            layout,
            entries: &[
                wgpu::BindGroupEntry {
                    binding: 0,
                    resource: parts_buf.as_entire_binding(),
                },
                wgpu::BindGroupEntry {
                    binding: 1,
                    resource: params.as_entire_binding(),
                },
                wgpu::BindGroupEntry {
                    binding: 2,
                    resource: wgpu::BindingResource::TextureView(look.texture),
                },
                wgpu::BindGroupEntry {
                    binding: 3,
                    resource: wgpu::BindingResource::Sampler(look.sampler),
                },
                wgpu::BindGroupEntry {
                    binding: 4,
                    resource: wgpu::BindingResource::TextureView(look.normals),
                },
            ],
        });
        Some(Self {
            kind,
            mesh,
            count: parts.len() as u32,
            bind_group,
            foliage: look.two_sided,
            cutout: look.textured && look.alpha_cutoff > 0.0,
        })
    }

    /// Triangles drawn for one tree.
    pub fn triangles_per_tree(&self) -> u64 {
        self.mesh.triangles() * u64::from(self.count)
    }
}

/// One species' three part sets, drawn in this order.
pub struct SpeciesGpu {
    pub name: String,
    pub parts: Vec<PartSet>,
}

impl SpeciesGpu {
    pub fn triangles_per_tree(&self) -> u64 {
        self.parts.iter().map(PartSet::triangles_per_tree).sum()
    }
}

/// A contiguous run of one species' trees in the per-frame instance buffer.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct TreeRun {
    pub species: usize,
    pub first: u32,
    pub count: u32,
}

pub struct WorldGpu {
    /// The terrain: its index buffer holds every chunk at every level
    /// ([`crate::model::terrain_lod`]); `terrain_layout` says which range is which.
    pub terrain: PartSet,
    pub terrain_layout: TerrainLayout,
    pub species: Vec<SpeciesGpu>,
    /// Per tree: species, world transform + tint, world bounds.
    pub tree_species: Vec<u32>,
    pub tree_data: Vec<TreeGpu>,
    pub tree_bounds: Vec<Aabb>,
    pub scene_bounds: Aabb,
    /// Bounds of the trees alone (the object, in the bake's studio).
    pub forest_bounds: Aabb,
    /// The frame's tree instances: made at the size of the lists drawn so far and grown
    /// when a frame's lists pass it (the cascades' lists come only with trees drawn as
    /// geometry), to at most [`Self::capacity`].
    instances: std::sync::Mutex<TreeInstances>,
    trees_layout: wgpu::BindGroupLayout,
    /// Most instance records a frame holds: the terrain's identity, the camera's list and
    /// one list per shadow cascade.
    capacity: usize,
    /// Bytes of mesh and part data on the GPU.
    pub mesh_bytes: u64,
}

impl WorldGpu {
    pub fn new(
        ctx: &GpuContext,
        world: &World,
        trees_layout: &wgpu::BindGroupLayout,
        parts_layout: &wgpu::BindGroupLayout,
    ) -> Result<Self> {
        let n = world.forest.instances.len();
        if n > MAX_TREES {
            return Err(Error::BadInput(format!(
                "the forest has {n} trees; canopy draws at most {MAX_TREES}"
            )));
        }
        let white = super::material::white(ctx);
        let sampler = super::material::sampler(ctx);
        let plain = PartLook {
            two_sided: false,
            texture: &white,
            sampler: &sampler,
            alpha_cutoff: 0.0,
            textured: false,
            normals: &white,
            terrain_map: None,
        };
        let ChunkedTerrain {
            mesh: terrain_mesh,
            layout: terrain_layout,
        } = world.terrain.chunked();
        let maps = TerrainMaps::new(ctx, &world.terrain, &terrain_mesh)
            .ok_or_else(|| Error::BadInput("the terrain's mesh is shorter than its grid".into()))?;
        let terrain = PartSet::new(
            ctx,
            parts_layout,
            PartKind::Trunk,
            "terrain",
            &terrain_mesh,
            &[Mat4::IDENTITY],
            PartLook {
                texture: &maps.color,
                normals: &maps.normal,
                terrain_map: Some(maps.placement),
                ..plain
            },
        )
        .ok_or_else(|| Error::BadInput("the terrain has no triangles".into()))?;
        let mut mesh_bytes = terrain.mesh.bytes() + maps.bytes;
        let mut species = Vec::with_capacity(world.species.len());
        let mut upload = SpeciesUpload {
            ctx,
            parts_layout,
            plain,
            white: &white,
            sampler: &sampler,
            uploaded: Vec::new(),
        };
        for tree in &world.species {
            let s = upload.species(tree);
            mesh_bytes += s
                .parts
                .iter()
                .map(|p| p.mesh.bytes() + 64 * u64::from(p.count))
                .sum::<u64>();
            species.push(s);
        }

        let PlacedTrees {
            species: tree_species,
            data: tree_data,
            bounds: tree_bounds,
            scene_bounds,
            forest_bounds,
        } = place_trees(world)?;

        // Terrain identity + the camera list + one list per shadow cascade.
        let capacity = 1 + (1 + super::consts::CASCADES) * n.max(1);
        // Room for the camera's list at first.
        let instances = TreeInstances::new(ctx, trees_layout, 1 + n.max(1))?;
        Ok(Self {
            terrain,
            terrain_layout,
            species,
            tree_species,
            tree_data,
            tree_bounds,
            scene_bounds,
            forest_bounds,
            instances: std::sync::Mutex::new(instances),
            trees_layout: trees_layout.clone(),
            capacity,
            mesh_bytes,
        })
    }

    /// Indices of the trees inside `frustum`, grouped by species (in species order).
    pub fn cull(&self, frustum: &Frustum) -> Vec<Vec<u32>> {
        let mut by_species = vec![Vec::new(); self.species.len()];
        for (i, b) in self.tree_bounds.iter().enumerate() {
            if frustum.intersects(b) {
                by_species[self.tree_species[i] as usize].push(i as u32);
            }
        }
        by_species
    }

    /// Draws the terrain (when asked) and the parts of `kinds` of the trees of `runs`; with
    /// no colour pipelines it is a pass from the sun (its pipeline already set). Opaque parts
    /// of every species first, then foliage, so the pipeline switches twice only. Returns
    /// (triangles, trees, draw calls).
    pub(crate) fn draw(
        &self,
        pass: &mut wgpu::RenderPass<'_>,
        runs: &[TreeRun],
        pipes: Option<MeshPipelines<'_>>,
        terrain: bool,
        kinds: &[PartKind],
    ) -> (u64, u32, u32) {
        self.draw_by(pass, runs, terrain, kinds, |foliage, _| {
            pipes.map(|p| if foliage { p.foliage } else { p.opaque })
        })
    }

    /// [`Self::draw`] into a depth-only pass from the sun: each part set with `plain` (no
    /// fragment stage) or, where it is alpha-tested, `cutout`.
    pub(crate) fn draw_depth(
        &self,
        pass: &mut wgpu::RenderPass<'_>,
        runs: &[TreeRun],
        (plain, cutout): (&wgpu::RenderPipeline, &wgpu::RenderPipeline),
        terrain: bool,
        kinds: &[PartKind],
    ) -> (u64, u32, u32) {
        self.draw_by(pass, runs, terrain, kinds, |_, set| {
            Some(if set.is_some_and(|s| s.cutout) {
                cutout
            } else {
                plain
            })
        })
    }

    /// The draws of [`Self::draw`], each part set (None: the terrain) with the pipeline
    /// `pipeline_of(foliage, set)` gives (None: the one already set), set only when it
    /// changes.
    fn draw_by<'p>(
        &self,
        pass: &mut wgpu::RenderPass<'_>,
        runs: &[TreeRun],
        terrain: bool,
        kinds: &[PartKind],
        mut pipeline_of: impl FnMut(bool, Option<&PartSet>) -> Option<&'p wgpu::RenderPipeline>,
    ) -> (u64, u32, u32) {
        let mut tris = 0u64;
        let mut calls = 0u32;
        let mut trees = 0u32;
        let mut current: Option<&wgpu::RenderPipeline> = None;
        let mut use_pipeline =
            |pass: &mut wgpu::RenderPass<'_>, p: Option<&'p wgpu::RenderPipeline>| {
                if let Some(p) = p
                    && !current.is_some_and(|c| std::ptr::eq(c, p))
                {
                    pass.set_pipeline(p);
                    current = Some(p);
                }
            };
        use_pipeline(pass, pipeline_of(false, None));
        if terrain {
            self.bind_terrain(pass);
            let full = self.terrain_layout.full.clone();
            tris += u64::from(full.len() as u32 / 3);
            pass.draw_indexed(full, 0, 0..1);
            calls += 1;
        }
        let mut draw = |pass: &mut wgpu::RenderPass<'_>, set: &PartSet, first: u32, n: u32| {
            pass.set_bind_group(2, &set.bind_group, &[]);
            pass.set_vertex_buffer(0, set.mesh.vertices.slice(..));
            pass.set_index_buffer(set.mesh.indices.slice(..), wgpu::IndexFormat::Uint32);
            let start = first * set.count;
            pass.draw_indexed(0..set.mesh.index_count, 0, start..start + n * set.count);
            tris += set.mesh.triangles() * u64::from(n) * u64::from(set.count);
            calls += 1;
        };
        // Opaque parts of every species first, then foliage, to switch pipelines twice only.
        for foliage in [false, true] {
            for run in runs {
                for set in self.species[run.species]
                    .parts
                    .iter()
                    .filter(|s| s.foliage == foliage && kinds.contains(&s.kind))
                {
                    use_pipeline(pass, pipeline_of(foliage, Some(set)));
                    draw(pass, set, run.first, run.count);
                }
            }
        }
        for run in runs {
            trees += run.count;
        }
        (tris, trees, calls)
    }

    /// Binds the terrain's part set, vertices and indices.
    fn bind_terrain(&self, pass: &mut wgpu::RenderPass<'_>) {
        let set = &self.terrain;
        pass.set_bind_group(2, &set.bind_group, &[]);
        pass.set_vertex_buffer(0, set.mesh.vertices.slice(..));
        pass.set_index_buffer(set.mesh.indices.slice(..), wgpu::IndexFormat::Uint32);
    }

    /// What of the terrain a view from `eye` draws: the chunks and horizon sectors in
    /// `frustum`, each chunk at its level ([`TerrainLayout::levels`]).
    pub fn terrain_view(
        &self,
        frustum: &Frustum,
        eye: Vec3,
        focal_px: f32,
        tolerance_px: f32,
    ) -> TerrainView {
        let layout = &self.terrain_layout;
        let levels = layout.levels(eye, focal_px, tolerance_px);
        TerrainView {
            chunks: layout
                .chunks
                .iter()
                .zip(levels)
                .map(|(c, l)| frustum.intersects(&c.bounds).then_some(l))
                .collect(),
            horizon: layout
                .horizon
                .iter()
                .map(|(b, _)| frustum.intersects(b))
                .collect(),
        }
    }

    /// Draws the terrain for the camera (its pipeline and groups 0 and 1 set by the
    /// caller): the horizon ring's sectors and the chunks in `view`, each chunk at its
    /// level, neighbouring ranges merged into one draw. Returns (triangles, draw calls).
    pub fn draw_terrain_levels(
        &self,
        pass: &mut wgpu::RenderPass<'_>,
        view: &TerrainView,
    ) -> (u64, u32) {
        self.bind_terrain(pass);
        let mut tris = 0u64;
        let mut calls = 0u32;
        for r in self.terrain_layout.ranges(view) {
            tris += u64::from(r.len() as u32 / 3);
            pass.draw_indexed(r, 0, 0..1);
            calls += 1;
        }
        (tris, calls)
    }

    /// Builds the instance list for this frame: index 0 is the terrain's identity, then each
    /// list's trees by species. Returns the runs of each list. Uploads once per frame.
    pub fn upload_lists(&self, ctx: &GpuContext, lists: &[Vec<Vec<u32>>]) -> Vec<Vec<TreeRun>> {
        self.upload_lists_faded(ctx, lists, &[], None)
    }

    /// [`Self::upload_lists`], then the `faded` lists, whose trees carry an opacity (per
    /// species: tree index and opacity, written in the instance's `tint.w`; the faded
    /// pipelines dither a tree below 1 away in that fraction of its pixels) and, when given,
    /// a foliage tint in place of their own.
    pub fn upload_lists_faded(
        &self,
        ctx: &GpuContext,
        lists: &[Vec<Vec<u32>>],
        faded: &[&[Vec<(u32, f32)>]],
        tint: Option<[f32; 3]>,
    ) -> Vec<Vec<TreeRun>> {
        let mut data = Vec::new();
        data.push(TreeGpu {
            model: Mat4::IDENTITY.to_cols_array_2d(),
            tint: Vec3::ONE.extend(1.0).to_array(),
        });
        let mut runs = Vec::with_capacity(lists.len() + faded.len());
        for list in lists {
            let records = list
                .iter()
                .map(|trees| trees.iter().map(|&t| self.tree_data[t as usize]));
            runs.push(append_runs(&mut data, self.capacity, records));
        }
        for list in faded {
            let records = list.iter().map(|trees| {
                trees.iter().map(|&(t, opacity)| {
                    let mut d = self.tree_data[t as usize];
                    if let Some(c) = tint {
                        d.tint[..3].copy_from_slice(&c);
                    }
                    d.tint[3] = opacity.clamp(0.0, 1.0);
                    d
                })
            });
            runs.push(append_runs(&mut data, self.capacity, records));
        }
        let mut instances = self
            .instances
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner);
        if data.len() > instances.capacity {
            // Half as much again, so that lists growing a little each frame do not make
            // the buffer again every frame.
            let room = (data.len() + data.len() / 2).min(self.capacity);
            match TreeInstances::new(ctx, &self.trees_layout, room) {
                Ok(grown) => *instances = grown,
                Err(e) => {
                    // The runs that do not fit are left out of this frame.
                    let room = instances.capacity;
                    log::warn!("the tree instances keep {room} records: {e}");
                    data.truncate(room);
                    for list in &mut runs {
                        list.retain(|r| r.first as usize + r.count as usize <= room);
                    }
                }
            }
        }
        ctx.queue
            .write_buffer(&instances.buffer, 0, bytemuck::cast_slice(&data));
        runs
    }

    /// The bind group of the frame's tree instances, as [`Self::upload_lists`] left them.
    pub fn trees_bind_group(&self) -> wgpu::BindGroup {
        self.instances
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
            .bind_group
            .clone()
    }
}

/// The tree instance buffer and its bind group.
struct TreeInstances {
    buffer: wgpu::Buffer,
    bind_group: wgpu::BindGroup,
    /// Records it holds.
    capacity: usize,
}

impl TreeInstances {
    fn new(ctx: &GpuContext, layout: &wgpu::BindGroupLayout, capacity: usize) -> Result<Self> {
        let buffer = ctx.checked("allocating the tree instance buffer", || {
            ctx.device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("tree instances"),
                size: (capacity.max(1) * std::mem::size_of::<TreeGpu>()) as u64,
                usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST,
                mapped_at_creation: false,
            })
        })?;
        let bind_group = ctx.device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("tree instances"),
            layout,
            entries: &[wgpu::BindGroupEntry {
                binding: 0,
                resource: buffer.as_entire_binding(),
            }],
        });
        Ok(Self {
            buffer,
            bind_group,
            capacity: capacity.max(1),
        })
    }
}

/// Every tree of `world` placed: its species, instance record and bounds, and the bounds
/// of the scene and of the trees alone.
struct PlacedTrees {
    species: Vec<u32>,
    data: Vec<TreeGpu>,
    bounds: Vec<Aabb>,
    scene_bounds: Aabb,
    forest_bounds: Aabb,
}

/// Places every tree of `world`, refused where one refers to a species the scene lacks.
fn place_trees(world: &World) -> Result<PlacedTrees> {
    let n = world.forest.instances.len();
    let mut tree_species = Vec::with_capacity(n);
    let mut tree_data = Vec::with_capacity(n);
    let mut tree_bounds = Vec::with_capacity(n);
    let mut scene_bounds = world.terrain.bounds();
    let mut forest_bounds = Aabb::EMPTY;
    for inst in &world.forest.instances {
        let Some(model) = world.species.get(inst.species as usize) else {
            return Err(Error::BadInput(format!(
                "a tree refers to species {} but the scene has {}",
                inst.species,
                world.species.len()
            )));
        };
        let m = inst.transform();
        let b = model.tree_bounds.transformed(m);
        scene_bounds = scene_bounds.union(b);
        forest_bounds = forest_bounds.union(b);
        tree_species.push(inst.species);
        tree_data.push(TreeGpu {
            model: m.to_cols_array_2d(),
            tint: inst.tint.extend(1.0).to_array(),
        });
        tree_bounds.push(b);
    }
    Ok(PlacedTrees {
        species: tree_species,
        data: tree_data,
        bounds: tree_bounds,
        scene_bounds,
        forest_bounds,
    })
}

/// Appends one list's instance records to `data`, species by species, each species' run
/// only while it fits in `capacity`; its runs.
fn append_runs<I: ExactSizeIterator<Item = TreeGpu>>(
    data: &mut Vec<TreeGpu>,
    capacity: usize,
    per_species: impl Iterator<Item = I>,
) -> Vec<TreeRun> {
    let mut runs = Vec::new();
    for (species, trees) in per_species.enumerate() {
        if trees.len() == 0 || data.len() + trees.len() > capacity {
            continue;
        }
        runs.push(TreeRun {
            species,
            first: data.len() as u32,
            count: trees.len() as u32,
        });
        data.extend(trees);
    }
    runs
}
