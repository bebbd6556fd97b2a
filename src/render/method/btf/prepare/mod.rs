//! The `btf` method's CPU work, without a GPU. [`BtfScene`] is what the method knows of the
//! scene (per species: each level's image set and billboard frame, the part transforms a
//! tree expands into, the texel sizes; the view and light direction sets; the VCM shading).
//! [`BtfScene::prepare`] turns a frame's visible trees into billboard records: it chooses
//! each tree's level by the texel criterion (with the cross-fade band), expands it into the
//! billboards of that level, finds each billboard's view and light directions in its object
//! frame with their 3 nearest samples, culls small weights, adds the VCM factors and sorts
//! everything back to front.

use std::collections::HashMap;

use glam::{Mat3, Mat4, Vec3};

use super::billboard::{BillboardGpu, BillboardMode, SetInfo};
use super::settings::{BtfSettings, BtfStats, FETCHES_AT_MOST, PlaneMode};
use crate::format::{Baked, BtfImageSet};
use crate::lod::{self, LevelTexels};
use crate::model::mesh::Aabb;
use crate::model::{Level, PerLevel, World};
use crate::render::vcm_shading::{ObjectFrame, ObjectMaps, Shade, VcmShading};
use crate::render::world_gpu::TreeGpu;
use crate::sphere::{DirectionSet, billboard_axes};
use crate::vcm::CORNERS;
use crate::{Error, Result};

/// Per species: the part transforms that finer levels expand a tree into.
struct SpeciesParts {
    branches: Vec<Mat4>,
    /// Twigs of the reference main branch, in the branch frame.
    branch_twigs: Vec<Mat4>,
    trunk_twigs: Vec<Mat4>,
    sets: PerLevel<SetInfo>,
    texels: LevelTexels,
    bounds: Aabb,
    /// The sets' bounds and billboard centres, for the VCM shading.
    frames: PerLevel<ObjectFrame>,
    /// The bake holds its twig and main-branch sets. Without them a tree is drawn whole as
    /// geometry where its tree level is too coarse, cross-faded over the tree level's band.
    finer: bool,
    /// Its finer levels are still coming (a bake still running, which hands its tree levels
    /// over first; an imported tree without a hierarchy has none to come): until then its
    /// tree level is drawn down to [`PENDING_LOD_SCALE`] times the LOD scale, so that far
    /// fewer trees are geometry.
    pending: bool,
}

/// How much coarser than the LOD scale a tree level is drawn while its species' finer
/// levels are still being baked.
pub const PENDING_LOD_SCALE: f32 = 4.0;

/// What the `btf` method knows of a scene on the CPU.
pub struct BtfScene {
    species: Vec<SpeciesParts>,
    /// Each level's view samples (the tree level has its own count, `[bake] tree_views`).
    views: PerLevel<DirectionSet>,
    lights: DirectionSet,
    vcm: Option<VcmShading>,
    /// Indices into the baked image sets, species by species, each finest level first: the
    /// order of the sets in the texture array.
    order: Vec<usize>,
    /// Each set's first texture layer (in `order`'s order): a set takes views x lights
    /// direct images, then views sky-lit and views ground-lit images.
    bases: Vec<u32>,
    /// Texture layers every set together takes.
    layers: u32,
    resolution: u32,
    /// Yaw bins of the tree level's light blends ([`super::light_blend`]) on the GPU; 0
    /// while there are none.
    light_bins: u32,
    /// Their first image in the texture array (after every set's).
    light_blend_first: u32,
}

impl crate::render::vcm_shading::TreeShades for BtfScene {
    fn tree_shade(&self, t: usize, species: usize, model: &Mat4) -> Option<(Shade, Aabb)> {
        let parts = self.species.get(species)?;
        let vcm = self.vcm.as_ref()?;
        let shade = vcm.for_tree(t, species, model, &parts.frames).tree();
        Some((shade, parts.frames.tree.bounds))
    }
}

pub use crate::render::method::view::PrepareView;
use expand::{GPU_SPECIES_ROWS, PREPARE_CHUNK, Prepared, Pusher, expand};
pub use expand::{NearDrawGpu, SortedBillboards};

mod expand;
mod level;
mod near;
pub use level::{LevelChoice, choose_level, geometry_fade, impostor_share};

/// One frame's billboards and the trees the `btf` method draws partly as geometry.
pub struct BtfFrame {
    /// Per species: trees at the main-branch level (their trunk is geometry).
    pub trunk_only: Vec<Vec<u32>>,
    /// Per species: trees at the twig level (trunk and limbs are geometry).
    pub trunk_and_limbs: Vec<Vec<u32>>,
    /// `hybrid` only, per species: trees drawn as geometry (their twig texels project above
    /// the bound; not in the two lists above), each with the opacity its twigs fade in at
    /// (1 = whole; its trunk and limbs are always whole).
    pub twigs: Vec<Vec<(u32, f32)>>,
    /// `hybrid` with `impostor_px`, per species: the trees whose tree level is drawn as an
    /// impostor instead of billboards (or cross-fading with them), each with the
    /// impostor's opacity.
    pub impostors: Vec<Vec<(u32, f32)>>,
    /// The billboard records, back to front.
    pub records: Vec<BillboardGpu>,
    /// Billboards drawn (`records.len()` until the records are handed to the GPU).
    pub billboards: u32,
    /// The GPU builds the far trees' tree-level billboards ([`super::far`]) and sorts
    /// them with these, drawing them all (the far ones are not counted in `billboards` nor
    /// `stats` until read back).
    pub far: bool,
    /// The billboards are drawn front to back into the trees' layer in this many batches
    /// (0: back to front over the frame, in the main pass).
    pub layer_batches: u32,
    /// The billboards, front to back, go through the tile compositor instead of batches,
    /// with these knobs.
    pub compositor: Option<crate::render::compositor::CompositorKnobs>,
    pub stats: BtfStats,
}

impl BtfScene {
    /// Checks that the bake fits the scene (every species has its three levels, every set
    /// the file's sizes) and gathers the billboard frames and part transforms.
    pub fn new(baked: &Baked, world: &World) -> Result<Self> {
        let bad = |m: String| {
            Error::BadInput(format!(
                "baked BTF data does not fit the scene: {m}; re-bake with `canopy bake`"
            ))
        };
        let s = &baked.settings;
        let lights = DirectionSet::with_count(s.lights as usize).map_err(|e| bad(e.to_string()))?;
        let mut index: HashMap<(u32, Level), usize> = HashMap::new();
        for (i, set) in baked.btf.iter().enumerate() {
            if set.views != s.views_of(set.level)
                || set.lights != s.lights
                || set.resolution != s.resolution
            {
                return Err(bad(format!(
                    "image set {i} has other sizes than the file's settings"
                )));
            }
            index.insert((set.species, set.level), i);
        }
        let views = PerLevel::try_from_fn(|l| {
            DirectionSet::with_count(s.views_of(l) as usize).map_err(|e| bad(e.to_string()))
        })?;
        let per_view = s.lights + crate::format::AMBIENT_IMAGES_PER_VIEW;
        let mut layers = 0u32;
        let mut bases = Vec::new();
        let mut order = Vec::new();
        let mut species = Vec::new();
        for (sp, tree) in world.species.iter().enumerate() {
            let level_bounds = PerLevel {
                twig: tree.twig_bounds,
                branch: tree.branch_bounds,
                tree: tree.tree_bounds,
            };
            let mut sets = level_bounds.map(|bounds| SetInfo {
                layer_base: 0,
                prototype: sp as u32,
                center: Vec3::ZERO,
                radius: 1.0,
                bounds,
            });
            let mut texels = LevelTexels::default();
            // The tree level is needed: the prototype's own, or (a bake still running, which
            // hands over its first variants' tree levels first) its entry's first variant's.
            // The finer two come together or not at all.
            let has = |level: Level| index.contains_key(&(sp as u32, level));
            let stand_in = world.first_variant(sp) as u32;
            let tree_set = index
                .get(&(sp as u32, Level::Tree))
                .or_else(|| index.get(&(stand_in, Level::Tree)))
                .copied()
                .ok_or_else(|| bad(format!("species {sp} has no tree-level images")))?;
            let finer = has(Level::Twig) && has(Level::Branch);
            if !finer && (has(Level::Twig) || has(Level::Branch)) {
                return Err(bad(format!(
                    "species {sp} has one of its twig and main-branch levels but not the other"
                )));
            }
            for level in Level::ALL {
                let found = match level {
                    Level::Tree => Some(tree_set),
                    _ => index.get(&(sp as u32, level)).copied(),
                };
                let Some(i) = found else {
                    // Not baked yet: never chosen over geometry (texel 0).
                    texels[level] = 0.0;
                    continue;
                };
                let set = &baked.btf[i];
                sets[level] = SetInfo {
                    layer_base: layers,
                    prototype: sp as u32,
                    center: Vec3::from(set.center),
                    radius: set.radius,
                    bounds: level_bounds[level],
                };
                texels[level] = set.texel_size;
                bases.push(layers);
                layers = layers.saturating_add(set.views.saturating_mul(per_view));
                order.push(i);
            }
            species.push(SpeciesParts {
                branches: tree.tree_branches.clone(),
                branch_twigs: tree.branch_twigs.clone(),
                trunk_twigs: tree.tree_twigs.clone(),
                frames: sets.map(|s| ObjectFrame {
                    bounds: s.bounds,
                    center: s.center,
                }),
                sets,
                texels,
                bounds: tree.tree_bounds,
                finer,
                pending: !finer && tree.has_hierarchy(),
            });
        }
        Ok(Self {
            species,
            views,
            lights,
            vcm: VcmShading::new(baked, world)?,
            order,
            bases,
            layers,
            resolution: s.resolution,
            light_bins: 0,
            light_blend_first: 0,
        })
    }

    /// Yaw bins of the tree level's light blends on the GPU (0: none; the billboards blend
    /// their light images themselves).
    pub fn light_bins(&self) -> u32 {
        self.light_bins
    }

    /// Says that the texture array holds light blends of `bins` yaw bins (0: none) from
    /// image `first` on.
    pub fn set_light_blend(&mut self, bins: u32, first: u32) {
        self.light_bins = bins;
        self.light_blend_first = first;
    }

    /// Light-blended images at `bins` yaw bins: one per prototype, bin and tree-level view.
    pub fn light_blend_count(&self, bins: u32) -> u64 {
        self.species.len() as u64 * u64::from(bins) * self.views.tree.len() as u64
    }

    /// The first light-blended image of prototype `sp`'s tree level at yaw bin `bin`
    /// (one per view sample follows).
    pub fn light_blend_first(&self, sp: u32, bin: u32) -> u32 {
        self.light_blend_first + (sp * self.light_bins + bin) * self.views.tree.len() as u32
    }

    /// Texture layers every image set together needs.
    pub fn layer_count(&self) -> u64 {
        u64::from(self.layers)
    }

    /// Side of every image, in texels.
    pub fn resolution(&self) -> u32 {
        self.resolution
    }

    /// Each image set with its first texture layer, in layer order.
    pub fn image_sets<'a>(&self, baked: &'a Baked) -> impl Iterator<Item = (u32, &'a BtfImageSet)> {
        self.order
            .iter()
            .zip(&self.bases)
            .filter_map(move |(&i, &base)| Some((base, baked.btf.get(i)?)))
    }

    /// Each view sample's billboard axes in its object frame (right, up; w = 0), as the
    /// shader's view-axes buffer holds them: those of the levels' largest view set, whose
    /// first directions are every smaller set's, in order (the octahedron's subdivisions
    /// only add directions), so one buffer serves every level.
    pub fn view_axes(&self) -> Vec<[f32; 4]> {
        [&self.views.twig, &self.views.branch, &self.views.tree]
            .into_iter()
            .max_by_key(|v| v.len())
            .map_or(&[][..], |v| v.directions())
            .iter()
            .flat_map(|&v| {
                let (r, u) = billboard_axes(v);
                [r.extend(0.0).to_array(), u.extend(0.0).to_array()]
            })
            .collect()
    }

    /// The tree level's view and light direction sets.
    pub fn tree_directions(&self) -> (&DirectionSet, &DirectionSet) {
        (&self.views.tree, &self.lights)
    }

    /// Species the scene holds.
    pub fn species_count(&self) -> usize {
        self.species.len()
    }

    /// One species' tree-level image set: its first texture layer, its billboard centre in
    /// the tree frame and its radius.
    pub fn tree_set(&self, species: usize) -> Option<(u32, Vec3, f32)> {
        let s = &self.species.get(species)?.sets.tree;
        Some((s.layer_base, s.center, s.radius))
    }

    /// The bound below which a tree's tree-level texels must project for the tree to be
    /// "far": drawn at the tree level alone, with no finer level fading in, which the GPU
    /// can build ([`super::far`]). It is the start of the fade band (the level's bound with
    /// no band), less 0.1 %, so that the CPU's own choice for a far tree would be the same.
    /// 0 (no tree is far) when the band covers the whole level.
    pub fn far_bound(settings: &BtfSettings) -> f32 {
        let fade = settings.lod_fade.clamp(0.0, 1.0);
        let bound = if settings.lod_fade > 0.0 {
            settings.lod_scale * (1.0 - fade)
        } else {
            settings.lod_scale
        } * 0.999;
        if bound > 0.0 && bound.is_finite() {
            bound
        } else {
            0.0
        }
    }

    /// Whether tree `data` of species `sp` is near: not far by [`Self::far_bound`] `bound`
    /// (also any tree of a species the scene lacks, or of no valid scale).
    pub fn is_near(&self, sp: usize, data: &TreeGpu, view: &PrepareView, bound: f32) -> bool {
        let Some(parts) = self.species.get(sp) else {
            return true;
        };
        let m = Mat4::from_cols_array_2d(&data.model);
        let scale = m.x_axis.truncate().length();
        let z = (m.transform_point3(parts.bounds.center()) - view.camera.position).length();
        !(bound > 0.0
            && scale > 0.0
            && lod::projected_px(parts.texels.tree * scale, view.focal_px, z) < bound)
    }

    /// The distance within which a tree of scale up to `max_scale` may be near (every tree
    /// farther away is far), measured to its bounds' centre; infinite when none is far.
    pub fn near_radius(&self, focal_px: f32, bound: f32, max_scale: f32) -> f32 {
        let texel = self
            .species
            .iter()
            .map(|p| p.texels.tree)
            .fold(0.0f32, f32::max);
        let r = texel * max_scale * focal_px / bound;
        if bound > 0.0 && r.is_finite() {
            // Past the bound's own rounding.
            r * 1.001 + 1e-3
        } else {
            f32::INFINITY
        }
    }

    /// The centre of tree `data`'s bounds (species `sp`) in the world, for the near search.
    pub fn tree_center(&self, sp: usize, data: &TreeGpu) -> Option<Vec3> {
        let parts = self.species.get(sp)?;
        Some(Mat4::from_cols_array_2d(&data.model).transform_point3(parts.bounds.center()))
    }

    /// What the GPU needs to build tree records ([`super::far`]): the rows of `btf_far.wgsl`'s
    /// `tables` (per species `SPECIES_ROWS` rows: each level's set; the part counts; the
    /// objects' first rows; the VCM boxes and centres; then every species' part transforms,
    /// its cube-map objects, and the maps' bytes, 16 a row), each level's view set, the
    /// light set, and the cube maps' face resolution (0 without them).
    pub(super) fn gpu_tables(
        &self,
    ) -> (Vec<[u32; 4]>, &PerLevel<DirectionSet>, &DirectionSet, u32) {
        let bits = |v: Vec3, w: f32| [v.x, v.y, v.z, w].map(f32::to_bits);
        let mut rows = Vec::with_capacity(GPU_SPECIES_ROWS * self.species.len());
        let mut mats_at = GPU_SPECIES_ROWS * self.species.len();
        let vcm = self.vcm.as_ref();
        let maps: Vec<[Vec<ObjectMaps>; 2]> = (0..self.species.len())
            .map(|sp| vcm.map_or([Vec::new(), Vec::new()], |v| v.species_maps(sp)))
            .collect();
        let mut objects_at = mats_at
            + self
                .species
                .iter()
                .map(|p| 4 * (p.branches.len() + p.branch_twigs.len() + p.trunk_twigs.len()))
                .sum::<usize>();
        for (parts, maps) in self.species.iter().zip(&maps) {
            for level in Level::ALL {
                let set = &parts.sets[level];
                // As `BillboardGpu::shade` places the billboard in its box.
                let record = BillboardGpu::UNSHADED.shade(&Shade::NONE, set);
                rows.push(bits(set.center, set.radius));
                let mut origin = bits(Vec3::from(record.vcm_box_origin), 0.0);
                origin[3] = set.layer_base;
                rows.push(origin);
                rows.push(bits(Vec3::from(record.vcm_box_scale), 0.0));
            }
            let (b, t, k) = (
                parts.branches.len(),
                parts.branch_twigs.len(),
                parts.trunk_twigs.len(),
            );
            rows.push([b as u32, t as u32, k as u32, mats_at as u32]);
            rows.push([
                objects_at as u32,
                (objects_at + 3 * maps[0].len().max(b)) as u32,
                0,
                0,
            ]);
            let f = &parts.frames;
            rows.push(bits(f.tree.bounds.min, 0.0));
            rows.push(bits(f.tree.bounds.max, 0.0));
            rows.push(bits(f.branch.bounds.min, 0.0));
            rows.push(bits(f.branch.bounds.max, 0.0));
            rows.push(bits(f.branch.center, 0.0));
            rows.push(bits(f.twig.center, 0.0));
            mats_at += 4 * (b + t + k);
            objects_at += 3 * (maps[0].len().max(b) + maps[1].len().max(t + k));
        }
        for parts in &self.species {
            for m in parts
                .branches
                .iter()
                .chain(&parts.branch_twigs)
                .chain(&parts.trunk_twigs)
            {
                for c in m.to_cols_array_2d() {
                    rows.push(c.map(f32::to_bits));
                }
            }
        }
        // The objects, then their maps.
        let res = vcm.map_or(0, |v| v.resolution());
        let map_bytes = CORNERS * crate::vcm::FACES * (res * res) as usize;
        let mut map_at = objects_at;
        let mut map_rows: Vec<[u32; 4]> = Vec::new();
        for (parts, maps) in self.species.iter().zip(&maps) {
            let counts = [
                parts.branches.len(),
                parts.branch_twigs.len() + parts.trunk_twigs.len(),
            ];
            for (list, count) in maps.iter().zip(counts) {
                for i in 0..list.len().max(count) {
                    let (row, sky) = match list.get(i) {
                        Some((bytes, sky)) if bytes.len() >= map_bytes && map_bytes > 0 => {
                            let at = map_at as u32;
                            for chunk in bytes[..map_bytes].chunks(16) {
                                let mut word = [0u8; 16];
                                word[..chunk.len()].copy_from_slice(chunk);
                                map_rows.push(bytemuck::cast(word));
                            }
                            map_at += map_bytes.div_ceil(16);
                            (at, *sky)
                        }
                        Some((_, sky)) => (u32::MAX, *sky),
                        None => (u32::MAX, [1.0; CORNERS]),
                    };
                    rows.push([row, 0, 0, 0]);
                    rows.push([sky[0], sky[1], sky[2], sky[3]].map(f32::to_bits));
                    rows.push([sky[4], sky[5], sky[6], sky[7]].map(f32::to_bits));
                }
            }
        }
        debug_assert_eq!(rows.len(), objects_at);
        rows.extend(map_rows);
        (rows, &self.views, &self.lights, res)
    }

    /// Billboards a tree of species `sp` makes at `level` (before the frustum test), as
    /// [`expand`] makes them: 1; the main branches and the trunk's twigs; every twig.
    pub fn part_count(&self, sp: usize, level: Level) -> u32 {
        let Some(p) = self.species.get(sp) else {
            return 0;
        };
        (match level {
            Level::Tree => 1,
            Level::Branch => p.branches.len() + p.trunk_twigs.len(),
            Level::Twig => p.branches.len() * p.branch_twigs.len() + p.trunk_twigs.len(),
        }) as u32
    }

    /// The cube maps, when the bake has them.
    pub(super) fn vcm(&self) -> Option<&VcmShading> {
        self.vcm.as_ref()
    }

    /// Reads every tree's cube maps in the sun's direction if it moved; true if it did.
    pub fn update_sun(&mut self, to_sun: Vec3) -> bool {
        self.vcm.as_mut().is_some_and(|v| v.set_sun(to_sun))
    }

    /// Bytes of visibility cube maps held in main memory.
    pub fn vcm_bytes(&self) -> u64 {
        self.vcm.as_ref().map_or(0, |v| v.bytes)
    }

    /// Face resolution of the visibility cube maps (None without them).
    pub fn vcm_resolution(&self) -> Option<u32> {
        self.vcm.as_ref().map(|v| v.resolution())
    }

    /// Texel sizes of one species' levels.
    pub fn texel_sizes(&self, species: usize) -> Option<LevelTexels> {
        self.species.get(species).map(|s| s.texels)
    }

    /// The billboards of the trees in `visible` (per species, indices into `trees`), back to
    /// front; past `max_billboards` the farthest are dropped (and counted). With `hybrid`,
    /// a tree whose twig texels project above the bound is geometry instead (cross-faded).
    pub fn prepare(
        &self,
        trees: &[TreeGpu],
        visible: &[Vec<u32>],
        view: &PrepareView,
        settings: &BtfSettings,
        max_billboards: usize,
        hybrid: bool,
    ) -> BtfFrame {
        let (mut frame, sorted) =
            self.prepare_sorted(trees, visible, view, settings, max_billboards, hybrid);
        frame.records = sorted.collect();
        frame
    }

    /// [`Self::prepare`], the records left in their chunks with their back-to-front order
    /// (`BtfFrame::records` empty, `billboards` their count): the GPU path copies them
    /// once, straight into the upload. With `max_billboards` 0 they are neither sorted nor
    /// dropped (the GPU sorts them with the far trees': [`super::far`]).
    pub fn prepare_sorted(
        &self,
        trees: &[TreeGpu],
        visible: &[Vec<u32>],
        view: &PrepareView,
        settings: &BtfSettings,
        max_billboards: usize,
        hybrid: bool,
    ) -> (BtfFrame, SortedBillboards) {
        let parts = self.prepare_chunks(trees, visible, view, settings, hybrid, false);
        let mut frame = self.joined(&parts, settings);
        // Each chunk's first record in the order made.
        let mut starts = Vec::with_capacity(parts.len());
        let mut keys: Vec<(f32, u32)> = Vec::new();
        for p in &parts {
            let start = keys.len();
            starts.push(start);
            keys.extend(
                p.depths
                    .iter()
                    .enumerate()
                    .map(|(k, &d)| (d, (start + k) as u32)),
            );
        }
        // Back to front (ties in the order made); keep the nearest ones when there are too
        // many: they matter most. The keys are sorted, not the 208-byte records, which are
        // then copied once, from their chunks. (Unless the GPU sorts them: `max_billboards`
        // 0 leaves them in the order made, all of them.)
        if max_billboards > 0 {
            use rayon::prelude::*;
            keys.par_sort_unstable_by(|a, b| b.0.total_cmp(&a.0).then(a.1.cmp(&b.1)));
            if keys.len() > max_billboards {
                frame.stats.dropped = (keys.len() - max_billboards) as u32;
                keys.drain(..keys.len() - max_billboards);
            }
        }
        frame.billboards = keys.len() as u32;
        (
            frame,
            SortedBillboards {
                records: parts.into_iter().map(|p| p.records).collect(),
                starts,
                keys,
            },
        )
    }

    /// The frame of the chunks `parts`, in order: their geometry lists and stats (no
    /// billboards yet).
    fn joined(&self, parts: &[Prepared], settings: &BtfSettings) -> BtfFrame {
        let mut frame = BtfFrame {
            trunk_only: vec![Vec::new(); self.species.len()],
            trunk_and_limbs: vec![Vec::new(); self.species.len()],
            twigs: vec![Vec::new(); self.species.len()],
            impostors: vec![Vec::new(); self.species.len()],
            billboards: 0,
            far: false,
            layer_batches: 0,
            compositor: None,
            records: Vec::new(),
            stats: BtfStats {
                vcm: self.vcm.is_some() && settings.vcm,
                ..BtfStats::default()
            },
        };
        for p in parts {
            frame.stats.add(&p.stats);
            for sp in 0..self.species.len() {
                frame.trunk_only[sp].extend_from_slice(&p.trunk_only[sp]);
                frame.trunk_and_limbs[sp].extend_from_slice(&p.trunk_and_limbs[sp]);
                frame.twigs[sp].extend_from_slice(&p.twigs[sp]);
                frame.impostors[sp].extend_from_slice(&p.impostors[sp]);
            }
        }
        frame
    }

    /// Every tree of `visible` prepared ([`Self::prepare_tree`]) in chunks that the threads
    /// take on their own; in order, the chunks give what one pass would.
    fn prepare_chunks(
        &self,
        trees: &[TreeGpu],
        visible: &[Vec<u32>],
        view: &PrepareView,
        settings: &BtfSettings,
        hybrid: bool,
        gpu: bool,
    ) -> Vec<Prepared> {
        use rayon::prelude::*;
        let vcm = self.vcm.as_ref().filter(|_| settings.vcm);
        let order: Vec<(usize, u32)> = visible
            .iter()
            .enumerate()
            .filter(|(sp, _)| *sp < self.species.len())
            .flat_map(|(sp, list)| list.iter().map(move |&t| (sp, t)))
            .collect();
        let chunk = order
            .len()
            .div_ceil(4 * rayon::current_num_threads().max(1))
            .max(PREPARE_CHUNK);
        order
            .par_chunks(chunk)
            .map(|trees_in| {
                let mut p = Prepared::new(self.species.len());
                for &(sp, t) in trees_in {
                    if let Some(data) = trees.get(t as usize) {
                        self.prepare_tree(&mut p, sp, t, data, view, settings, vcm, hybrid, gpu);
                    }
                }
                p
            })
            .collect()
    }

    /// [`Self::prepare`] with the billboards left to the GPU ([`super::far`]'s
    /// `near_build`): each tree's level choice, cross-fade and geometry lists as on the CPU,
    /// and one [`NearDrawGpu`] per level drawn, with the near slots their billboards take
    /// (their count). The frame's stats count trees, not billboards (read back later).
    pub fn prepare_draws(
        &self,
        trees: &[TreeGpu],
        visible: &[Vec<u32>],
        view: &PrepareView,
        settings: &BtfSettings,
        hybrid: bool,
    ) -> (BtfFrame, Vec<NearDrawGpu>, u64) {
        let parts = self.prepare_chunks(trees, visible, view, settings, hybrid, true);
        let frame = self.joined(&parts, settings);
        let mut draws = Vec::with_capacity(parts.iter().map(|p| p.draws.len()).sum());
        let mut slots = 0u64;
        for p in parts {
            // `first` holds the draw's count until here.
            for mut d in p.draws {
                let count = u64::from(d.first);
                d.first = slots.min(u64::from(u32::MAX)) as u32;
                slots += count;
                draws.push(d);
            }
        }
        (frame, draws, slots)
    }

    /// One visible tree's level choice and billboards, into `out`.
    #[allow(clippy::too_many_arguments)]
    fn prepare_tree(
        &self,
        out: &mut Prepared,
        sp: usize,
        t: u32,
        data: &TreeGpu,
        view: &PrepareView,
        settings: &BtfSettings,
        vcm: Option<&VcmShading>,
        hybrid: bool,
        gpu: bool,
    ) {
        let Some(parts) = self.species.get(sp) else {
            return;
        };
        let cam = view.camera.position;
        let m = Mat4::from_cols_array_2d(&data.model);
        let scale = m.x_axis.truncate().length();
        let z = (m.transform_point3(parts.bounds.center()) - cam).length();
        let pending = BtfSettings {
            lod_scale: settings.lod_scale * PENDING_LOD_SCALE,
            ..*settings
        };
        let chosen_by = if parts.pending { &pending } else { settings };
        let mut choice = choose_level(&parts.texels, scale, view.focal_px, z, chosen_by);
        // Only a tree at the twig level alone can be past it.
        let geometry = if !parts.finer {
            // Finer levels not baked yet: geometry instead, over the tree level's band.
            let fade = match choice {
                LevelChoice {
                    level: Level::Tree,
                    fading_in,
                } => fading_in.map_or(0.0, |(_, f)| f),
                _ => 1.0,
            };
            choice.fading_in = None;
            fade
        } else if hybrid && choice.level == Level::Twig {
            geometry_fade(&parts.texels, scale, view.focal_px, z, settings)
        } else {
            0.0
        };
        if geometry >= 1.0 {
            out.stats.geometry_trees += 1;
            out.twigs[sp].push((t, 1.0));
            return;
        }
        out.stats.trees_per_level[choice.level] += 1;
        if choice.fading_in.is_some() || geometry > 0.0 {
            out.stats.faded_trees += 1;
        }
        if geometry > 0.0 {
            out.twigs[sp].push((t, geometry));
        }
        if gpu {
            for (level, opacity) in choice.draws() {
                out.draws.push(NearDrawGpu {
                    tree: t,
                    level: level.index() as u32,
                    opacity: opacity * (1.0 - geometry),
                    first: self.part_count(sp, level),
                });
            }
        }
        let shading = vcm
            .filter(|_| !gpu)
            .map(|v| v.for_tree(t as usize, sp, &m, &parts.frames));
        let mut pusher = Pusher {
            scene: self,
            view,
            settings,
            records: &mut out.records,
            depths: &mut out.depths,
            stats: &mut out.stats,
            tint: (
                [data.tint[0], data.tint[1], data.tint[2]],
                BillboardMode::Images,
            ),
            opacity: 1.0,
        };
        for (level, opacity) in choice.draws().filter(|_| !gpu) {
            let mut opacity = opacity * (1.0 - geometry);
            if level == Level::Tree && hybrid {
                let share = impostor_share(&parts.texels, scale, view.focal_px, z, settings);
                if share > 0.0 {
                    pusher.stats.impostors += 1;
                    out.impostors[sp].push((t, opacity * share));
                }
                if share >= 1.0 {
                    continue;
                }
                opacity *= 1.0 - share;
            }
            pusher.opacity = opacity;
            if let Some(overlay) = settings.overlay(level) {
                pusher.tint = overlay;
            }
            expand(&mut pusher, parts, level, m, shading.as_ref());
        }
        // The finest level drawn decides which parts are geometry.
        match choice.draws().map(|(l, _)| l).min_by_key(|l| l.index()) {
            _ if geometry > 0.0 => {}
            Some(Level::Branch) => out.trunk_only[sp].push(t),
            Some(Level::Twig) => out.trunk_and_limbs[sp].push(t),
            _ => {}
        }
    }
}

#[cfg(test)]
pub(crate) mod tests;
