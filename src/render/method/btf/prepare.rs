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
use super::shading::{ObjectFrame, ObjectMaps, Shade, VcmShading};
use crate::format::{Baked, BtfImageSet};
use crate::lod::{self, LevelTexels};
use crate::model::mesh::Aabb;
use crate::model::{Level, PerLevel, World};
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
}

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
}

pub use crate::render::method::view::PrepareView;

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
    /// The billboard records, back to front.
    pub records: Vec<BillboardGpu>,
    /// Billboards drawn (`records.len()` until the records are handed to the GPU).
    pub billboards: u32,
    /// The GPU builds the far trees' tree-level billboards ([`super::far`]) and sorts
    /// them with these, drawing them all (the far ones are not counted in `billboards` nor
    /// `stats` until read back).
    pub far: bool,
    pub stats: BtfStats,
}

/// The level a tree is drawn at, and the finer level fading in over it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LevelChoice {
    /// The coarsest level whose texels project below the LOD scale.
    pub level: Level,
    /// The next finer level and its opacity, inside the cross-fade band before the bound.
    pub fading_in: Option<(Level, f32)>,
}

impl LevelChoice {
    /// The levels to draw with their opacities (they sum to 1).
    pub fn draws(self) -> impl Iterator<Item = (Level, f32)> {
        let fade = self.fading_in.map_or(0.0, |(_, f)| f);
        std::iter::once((self.level, 1.0 - fade)).chain(self.fading_in)
    }
}

/// How much of a tree `hybrid` draws as geometry (0 = none, 1 = all of it): the twig
/// level is the finest image level, valid while its texel projects below the LOD scale;
/// past that the tree is geometry, faded in over the last `lod_fade` fraction before the
/// bound as the finer levels are (so that the bound itself changes nothing).
pub fn geometry_fade(
    texels: &LevelTexels,
    scale: f32,
    focal_px: f32,
    z: f32,
    settings: &BtfSettings,
) -> f32 {
    let px = lod::projected_px(texels[Level::Twig] * scale, focal_px, z);
    let bound = settings.lod_scale;
    let start = bound * (1.0 - settings.lod_fade.clamp(0.0, 1.0));
    if px >= bound {
        1.0
    } else if settings.lod_fade > 0.0 && px > start {
        ((px - start) / (bound - start).max(1e-6)).clamp(0.0, 1.0)
    } else {
        0.0
    }
}

/// Chooses the level of a tree of `scale` whose centre is `z` from the eye. While the chosen
/// level's texel is within the last `lod_fade` fraction of the bound, the next finer level
/// fades in over it, so that the switch at the bound itself changes nothing.
pub fn choose_level(
    texels: &LevelTexels,
    scale: f32,
    focal_px: f32,
    z: f32,
    settings: &BtfSettings,
) -> LevelChoice {
    let level = lod::choose(texels, scale, focal_px, z, settings.lod_scale);
    let px = lod::projected_px(texels[level] * scale, focal_px, z);
    let start = settings.lod_scale * (1.0 - settings.lod_fade.clamp(0.0, 1.0));
    let fading_in = match level.finer() {
        Some(finer) if settings.lod_fade > 0.0 && px > start => {
            let fade = ((px - start) / (settings.lod_scale - start).max(1e-6)).clamp(0.0, 1.0);
            (fade > 0.0).then_some((finer, fade))
        }
        _ => None,
    };
    LevelChoice { level, fading_in }
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
                center: Vec3::ZERO,
                radius: 1.0,
                bounds,
            });
            let mut texels = LevelTexels::default();
            for level in Level::ALL {
                let i = index.get(&(sp as u32, level)).copied().ok_or_else(|| {
                    bad(format!("species {sp} level {} is missing", level.index()))
                })?;
                let set = &baked.btf[i];
                sets[level] = SetInfo {
                    layer_base: layers,
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
        })
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

    /// Tree instance `t`'s tree-level VCM shading for the current sun (its sun and sky
    /// factors at the 8 corners of its species' tree box) and that box in the object frame;
    /// None without visibility cube maps.
    pub fn tree_shade(&self, t: usize, species: usize, model: &Mat4) -> Option<(Shade, Aabb)> {
        let parts = self.species.get(species)?;
        let vcm = self.vcm.as_ref()?;
        let shade = vcm.for_tree(t, species, model, &parts.frames).tree();
        Some((shade, parts.frames.tree.bounds))
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
    pub fn tree_centre(&self, sp: usize, data: &TreeGpu) -> Option<Vec3> {
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
            billboards: 0,
            far: false,
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

    /// The near trees' frame for the GPU ([`super::far`]): their draws
    /// ([`Self::prepare_draws`]), at most `budget` slots of them; past that, the farthest
    /// trees' billboards are made here instead (unsorted), so that nothing goes missing.
    /// `species[t]` is tree `t`'s species.
    #[allow(clippy::too_many_arguments)]
    pub fn prepare_near(
        &self,
        trees: &[TreeGpu],
        species: &[u32],
        near: &[Vec<u32>],
        view: &PrepareView,
        settings: &BtfSettings,
        hybrid: bool,
        budget: u64,
    ) -> (BtfFrame, SortedBillboards, Vec<NearDrawGpu>, u64) {
        let (mut frame, draws, slots) = self.prepare_draws(trees, near, view, settings, hybrid);
        if slots <= budget {
            return (frame, SortedBillboards::default(), draws, slots);
        }
        // The trees by distance, each with its draws' slots (a tree's draws are together).
        let cam = view.camera.position;
        let count_of = |k: usize| {
            draws.get(k + 1).map_or(slots, |n| u64::from(n.first)) - u64::from(draws[k].first)
        };
        let mut by_tree: Vec<(f32, u32, u64)> = Vec::new();
        for (k, d) in draws.iter().enumerate() {
            let count = count_of(k);
            match by_tree.last_mut() {
                Some(last) if last.1 == d.tree => last.2 += count,
                _ => {
                    let sp = species.get(d.tree as usize).copied().unwrap_or(u32::MAX);
                    let dist = trees
                        .get(d.tree as usize)
                        .and_then(|data| self.tree_centre(sp as usize, data))
                        .map_or(f32::INFINITY, |c| c.distance_squared(cam));
                    by_tree.push((dist, d.tree, count));
                }
            }
        }
        by_tree.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
        // The nearest trees while they fit; every tree from the first that does not is left.
        let mut used = 0u64;
        let mut full = false;
        let mut kept = Vec::new();
        let mut rest = vec![Vec::new(); self.species.len()];
        for &(_, t, count) in &by_tree {
            full |= used + count > budget;
            if !full {
                used += count;
                kept.push(t);
            } else if let Some(list) = species
                .get(t as usize)
                .and_then(|&sp| rest.get_mut(sp as usize))
            {
                list.push(t);
            }
        }
        kept.sort_unstable();
        for list in &mut rest {
            list.sort_unstable();
        }
        let mut gpu = Vec::with_capacity(draws.len());
        let mut at = 0u64;
        for (k, d) in draws.iter().enumerate() {
            if kept.binary_search(&d.tree).is_ok() {
                gpu.push(NearDrawGpu {
                    first: at as u32,
                    ..*d
                });
                at += count_of(k);
            }
        }
        // Their levels, lists and tree counts are in `frame` already: only the billboards
        // made here are new.
        let (cpu, records) = self.prepare_sorted(trees, &rest, view, settings, 0, hybrid);
        for level in Level::ALL {
            frame.stats.billboards[level] += cpu.stats.billboards[level];
        }
        frame.stats.images_sampled += cpu.stats.images_sampled;
        frame.stats.fetches_saved += cpu.stats.fetches_saved;
        frame.billboards = cpu.billboards;
        (frame, records, gpu, at)
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
        let choice = choose_level(&parts.texels, scale, view.focal_px, z, settings);
        // Only a tree at the twig level alone can be past it.
        let geometry = if hybrid && choice.level == Level::Twig {
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
            pusher.opacity = opacity * (1.0 - geometry);
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

    /// Every tree's tree-level billboard as the sun sees it (for the ground alpha shadow
    /// map), at most `max` of them, but those in `excluded` (sorted tree indices).
    /// `tree_species[i]` is the species of `trees[i]`.
    pub fn sun_billboards(
        &self,
        trees: &[TreeGpu],
        tree_species: &[u32],
        to_sun: Vec3,
        max: usize,
        excluded: &[u32],
    ) -> Vec<BillboardGpu> {
        let mut out = Vec::with_capacity(trees.len().min(max));
        for (i, (data, &sp)) in trees.iter().zip(tree_species).enumerate() {
            if out.len() >= max {
                break;
            }
            if excluded.binary_search(&(i as u32)).is_ok() {
                continue;
            }
            let Some(parts) = self.species.get(sp as usize) else {
                continue;
            };
            let m = Mat4::from_cols_array_2d(&data.model);
            let scale = m.x_axis.truncate().length();
            if !(scale > 0.0 && scale.is_finite()) {
                continue;
            }
            let set = &parts.sets.tree;
            let rot = Mat3::from_mat4(m) * (1.0 / scale);
            let v_obj = rot.transpose() * to_sun;
            let vb = self.views.tree.blend(v_obj);
            let (r, u) = billboard_axes(v_obj);
            out.push(BillboardGpu {
                center: m.transform_point3(set.center).to_array(),
                radius: set.radius * scale,
                plane_right: (rot * r).normalize_or(Vec3::X).to_array(),
                plane_up: (rot * u).normalize_or(Vec3::Y).to_array(),
                obj_right: r.to_array(),
                obj_up: u.to_array(),
                view_index: vb.index,
                layer_base: set.layer_base,
                light_count: self.lights.len() as u32,
                view_weight: vb.weight,
                view_count: self.views.tree.len() as u32,
                tint: [1.0; 3],
                ..BillboardGpu::UNSHADED
            });
        }
        out
    }
}

/// One frame's billboard records in the chunks that made them, and their order back to
/// front.
#[derive(Default)]
pub struct SortedBillboards {
    records: Vec<Vec<BillboardGpu>>,
    /// Each chunk's first record, counting through the chunks in order.
    starts: Vec<usize>,
    /// Depth and record index (as counted in `starts`), back to front.
    keys: Vec<(f32, u32)>,
}

impl SortedBillboards {
    /// Records to draw.
    pub fn len(&self) -> usize {
        self.keys.len()
    }

    pub fn is_empty(&self) -> bool {
        self.keys.is_empty()
    }

    /// The `k`-th record back to front.
    fn get(&self, k: usize) -> &BillboardGpu {
        let i = self.keys[k].1 as usize;
        let c = self.starts.partition_point(|&s| s <= i) - 1;
        &self.records[c][i - self.starts[c]]
    }

    /// Every record, back to front.
    pub fn collect(&self) -> Vec<BillboardGpu> {
        use rayon::prelude::*;
        (0..self.len())
            .into_par_iter()
            .map(|k| *self.get(k))
            .collect()
    }

    /// Writes the records in the order made (chunk by chunk) into `out` as bytes, as many
    /// as it holds.
    pub fn write_unsorted(&self, mut out: wgpu::WriteOnly<'_, [u8]>) {
        const SIZE: usize = std::mem::size_of::<BillboardGpu>();
        let mut at = 0;
        for chunk in &self.records {
            let bytes: &[u8] = bytemuck::cast_slice(chunk);
            let n = bytes.len().min(out.len() - at);
            if n == 0 {
                break;
            }
            out.slice(at..at + n).copy_from_slice(&bytes[..n]);
            at += n;
        }
        debug_assert_eq!(at % SIZE, 0);
    }

    /// Writes the records back to front into `out` as bytes (as many as it holds).
    /// (`wgpu::WriteOnly` of a slice is not `Send`, so this runs on one thread.)
    pub fn write(&self, mut out: wgpu::WriteOnly<'_, [u8]>) {
        const SIZE: usize = std::mem::size_of::<BillboardGpu>();
        let count = (out.len() / SIZE).min(self.len());
        for k in 0..count {
            out.slice(k * SIZE..(k + 1) * SIZE)
                .copy_from_slice(bytemuck::bytes_of(self.get(k)));
        }
    }
}

/// Rows per species at the start of `btf_far.wgsl`'s `tables` (`SPECIES_ROWS` there).
pub(super) const GPU_SPECIES_ROWS: usize = 17;

/// One near tree's level for the GPU to expand into its billboards (`NearDraw` in
/// `btf_far.wgsl`): they take the near slots from `first`, [`BtfScene::part_count`] of them.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
pub struct NearDrawGpu {
    pub tree: u32,
    /// [`Level::index`].
    pub level: u32,
    /// The cross-fade's opacity of the level.
    pub opacity: f32,
    pub first: u32,
}

/// Fewest trees one thread prepares at a time.
const PREPARE_CHUNK: usize = 256;

/// What one chunk of trees made: their billboards in the order made, with their depths,
/// and the trees drawn partly or wholly as geometry, per species.
struct Prepared {
    records: Vec<BillboardGpu>,
    /// For the GPU to expand instead (`first` holding each one's billboard count).
    draws: Vec<NearDrawGpu>,
    depths: Vec<f32>,
    stats: BtfStats,
    trunk_only: Vec<Vec<u32>>,
    trunk_and_limbs: Vec<Vec<u32>>,
    twigs: Vec<Vec<(u32, f32)>>,
}

impl Prepared {
    fn new(species: usize) -> Self {
        Self {
            records: Vec::new(),
            draws: Vec::new(),
            depths: Vec::new(),
            stats: BtfStats::default(),
            trunk_only: vec![Vec::new(); species],
            trunk_and_limbs: vec![Vec::new(); species],
            twigs: vec![Vec::new(); species],
        }
    }
}

/// Expands one tree (model matrix `m`) at `level` into its billboards: the tree; its main
/// branches and the twigs on its trunk; or every twig, on the branches and on the trunk.
fn expand(
    p: &mut Pusher,
    parts: &SpeciesParts,
    level: Level,
    m: Mat4,
    shading: Option<&super::shading::TreeShading>,
) {
    let trunk_twigs = |p: &mut Pusher| {
        for (k, tw) in parts.trunk_twigs.iter().enumerate() {
            let shade = shading.map_or(Shade::NONE, |s| {
                s.trunk_twig(parts.branch_twigs.len() + k, tw)
            });
            p.push(m * *tw, &parts.sets.twig, Level::Twig, shade);
        }
    };
    match level {
        Level::Tree => {
            let shade = shading.map_or(Shade::NONE, |s| s.tree());
            p.push(m, &parts.sets.tree, Level::Tree, shade);
        }
        Level::Branch => {
            for (i, b) in parts.branches.iter().enumerate() {
                let shade = shading.map_or(Shade::NONE, |s| s.branch(i, b));
                p.push(m * *b, &parts.sets.branch, Level::Branch, shade);
            }
            trunk_twigs(p);
        }
        Level::Twig => {
            for (i, b) in parts.branches.iter().enumerate() {
                match shading {
                    Some(s) => s.branch_twigs(i, b, &parts.branch_twigs, |j, shade| {
                        p.push(
                            m * (*b * parts.branch_twigs[j]),
                            &parts.sets.twig,
                            Level::Twig,
                            shade,
                        )
                    }),
                    None => {
                        for tw in &parts.branch_twigs {
                            p.push(m * (*b * *tw), &parts.sets.twig, Level::Twig, Shade::NONE);
                        }
                    }
                }
            }
            trunk_twigs(p);
        }
    }
}

/// Builds the billboard records of one tree's parts.
struct Pusher<'a, 'v> {
    scene: &'a BtfScene,
    view: &'a PrepareView<'v>,
    settings: &'a BtfSettings,
    records: &'a mut Vec<BillboardGpu>,
    /// Each record's depth along the view.
    depths: &'a mut Vec<f32>,
    stats: &'a mut BtfStats,
    tint: ([f32; 3], BillboardMode),
    /// Opacity of the whole billboard (the cross-fade).
    opacity: f32,
}

impl Pusher<'_, '_> {
    /// One billboard of image set `set` at world transform `m`, unless it is outside the
    /// view: its view and light samples with culled weights, its VCM factors, its depth.
    fn push(&mut self, m: Mat4, set: &SetInfo, level: Level, shade: Shade) {
        let scale = m.x_axis.truncate().length();
        if !(scale > 0.0 && scale.is_finite()) {
            return;
        }
        let center = m.transform_point3(set.center);
        let radius = set.radius * scale;
        let sphere_box = Aabb {
            min: center - Vec3::splat(radius),
            max: center + Vec3::splat(radius),
        };
        if !self.view.frustum.intersects(&sphere_box) {
            return;
        }
        let shade = if self.settings.vcm_sky {
            shade
        } else {
            shade.without_sky()
        };
        let cam = self.view.camera.position;
        let rot = Mat3::from_mat4(m) * (1.0 / scale);
        let to_object = rot.transpose();
        let v_obj = to_object * (cam - center).normalize_or(Vec3::Y);
        let l_obj = to_object * self.view.to_sun;
        let scene = self.scene;
        let views = &scene.views[level];
        let mut vb = views.blend(v_obj);
        vb.cull(self.settings.weight_threshold);
        let mut lb = scene.lights.blend(l_obj);
        lb.cull(self.settings.weight_threshold);
        // The light weights carry the gain that brightens the blend towards the sun.
        let strength = self.settings.light_gain.clamp(0.0, 1.0);
        if strength > 0.0 {
            let gain = scene.lights.light_gain(&lb, l_obj).powf(strength);
            lb.weight = lb.weight.map(|w| w * gain);
        }
        let lights_used = lb.weight.iter().filter(|&&w| w > 0.0).count() as u64;
        let views_used = vb.weight.iter().filter(|&&w| w > 0.0).count() as u64;
        // Per view: its lights, its sky-lit and its ground-lit image.
        let fetches =
            views_used * (lights_used + u64::from(crate::format::AMBIENT_IMAGES_PER_VIEW));
        self.stats.images_sampled += fetches;
        self.stats.fetches_saved += FETCHES_AT_MOST - fetches.min(FETCHES_AT_MOST);
        self.stats.billboards[level] += 1;
        let depth = (center - cam).dot(self.view.camera.forward());
        // The quad faces the eye in both modes; with crossed planes it only bounds the
        // three planes, one facing each sampled view, which the fragment shader intersects.
        let (r, u) = billboard_axes(v_obj);
        let record = BillboardGpu {
            center: center.to_array(),
            radius,
            plane_right: (rot * r).normalize_or(Vec3::X).to_array(),
            planes: match self.settings.planes {
                PlaneMode::Single => 1,
                PlaneMode::Crossed => 3,
            },
            plane_up: (rot * u).normalize_or(Vec3::Y).to_array(),
            opacity: self.opacity,
            obj_right: r.to_array(),
            obj_up: u.to_array(),
            view_index: vb.index,
            layer_base: set.layer_base,
            light_index: lb.index,
            light_count: scene.lights.len() as u32,
            view_weight: vb.weight,
            view_count: views.len() as u32,
            light_weight: lb.weight,
            tint: self.tint.0,
            mode: self.tint.1 as u32,
            ..BillboardGpu::UNSHADED
        }
        .shade(&shade, set);
        self.records.push(record);
        self.depths.push(depth);
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use crate::render::btf::LOD_COLORS;
    use crate::render::camera::Camera;

    const BRANCHES: usize = 4;
    const BRANCH_TWIGS: usize = 5;
    const TRUNK_TWIGS: usize = 2;
    /// Texel sizes (m): the tree level is valid beyond 0.1·f/s, the branch level beyond
    /// 0.02·f/s (s the LOD scale).
    const TEXELS: LevelTexels = PerLevel {
        twig: 0.004,
        branch: 0.02,
        tree: 0.1,
    };
    const FOCAL: f32 = 500.0;

    fn aabb(min: [f32; 3], max: [f32; 3]) -> Aabb {
        Aabb {
            min: Vec3::from(min),
            max: Vec3::from(max),
        }
    }

    /// One species of 4 main branches of 5 twigs each and 2 twigs on the trunk; 18 view and
    /// 18 light samples; no cube maps.
    pub(crate) fn scene() -> BtfScene {
        let bounds = PerLevel {
            twig: aabb([-0.2, -0.2, 0.0], [0.2, 0.2, 0.4]),
            branch: aabb([-0.5, -0.5, 0.0], [0.5, 0.5, 3.0]),
            tree: aabb([-3.0, 0.0, -3.0], [3.0, 10.0, 3.0]),
        };
        let per_set = 18 * (18 + crate::format::AMBIENT_IMAGES_PER_VIEW);
        let sets = PerLevel::from_fn(|l| SetInfo {
            layer_base: l.index() as u32 * per_set,
            center: bounds[l].center(),
            radius: (bounds[l].max - bounds[l].min).length() / 2.0,
            bounds: bounds[l],
        });
        let branches = (0..BRANCHES)
            .map(|i| {
                Mat4::from_translation(Vec3::new(0.0, 3.0 + i as f32 * 1.5, 0.0))
                    * Mat4::from_rotation_y(i as f32 * 1.6)
                    * Mat4::from_rotation_x(1.2)
            })
            .collect();
        let branch_twigs = (0..BRANCH_TWIGS)
            .map(|j| Mat4::from_translation(Vec3::new(0.0, 0.0, 0.5 + j as f32 * 0.5)))
            .collect();
        let trunk_twigs = (0..TRUNK_TWIGS)
            .map(|k| Mat4::from_translation(Vec3::new(0.3, 1.0 + k as f32, 0.0)))
            .collect();
        BtfScene {
            species: vec![SpeciesParts {
                branches,
                branch_twigs,
                trunk_twigs,
                frames: sets.map(|s| ObjectFrame {
                    bounds: s.bounds,
                    center: s.center,
                }),
                sets,
                texels: TEXELS,
                bounds: bounds.tree,
            }],
            views: PerLevel::from_fn(|_| DirectionSet::with_count(18).unwrap()),
            lights: DirectionSet::with_count(18).unwrap(),
            vcm: None,
            order: vec![0, 1, 2],
            bases: vec![0, per_set, 2 * per_set],
            layers: 3 * per_set,
            resolution: 16,
        }
    }

    fn tree_at(x: f32, z: f32, yaw: f32) -> TreeGpu {
        let m = Mat4::from_translation(Vec3::new(x, 0.0, z)) * Mat4::from_rotation_y(yaw);
        TreeGpu {
            model: m.to_cols_array_2d(),
            tint: [0.9, 1.0, 0.8, 1.0],
        }
    }

    /// Prepares `trees`, all visible, seen from `eye` looking at the origin's tree centre.
    fn run(trees: &[TreeGpu], eye: Vec3, settings: &BtfSettings) -> (BtfFrame, Camera) {
        run_as(trees, eye, settings, false)
    }

    fn run_as(
        trees: &[TreeGpu],
        eye: Vec3,
        settings: &BtfSettings,
        hybrid: bool,
    ) -> (BtfFrame, Camera) {
        let camera = Camera::look_at(eye, Vec3::new(0.0, 5.0, 0.0), 60.0);
        let frustum = camera.frustum(16.0 / 9.0);
        let view = PrepareView {
            camera: &camera,
            focal_px: FOCAL,
            to_sun: Vec3::new(0.3, 0.8, 0.2).normalize(),
            frustum: &frustum,
        };
        let visible = vec![(0..trees.len() as u32).collect::<Vec<_>>()];
        let frame = scene().prepare(trees, &visible, &view, settings, usize::MAX, hybrid);
        (frame, camera)
    }

    #[test]
    fn trees_left_out_of_the_sun_billboards_are_skipped() {
        let trees = [
            tree_at(0.0, 0.0, 0.0),
            tree_at(20.0, 0.0, 0.0),
            tree_at(40.0, 0.0, 0.0),
        ];
        let sun = Vec3::new(0.3, 0.8, 0.2).normalize();
        let all = scene().sun_billboards(&trees, &[0, 0, 0], sun, usize::MAX, &[]);
        let some = scene().sun_billboards(&trees, &[0, 0, 0], sun, usize::MAX, &[1]);
        assert_eq!((all.len(), some.len()), (3, 2));
        assert_eq!(some[1].center, all[2].center);
    }

    #[test]
    fn hybrid_draws_a_tree_as_geometry_where_its_twig_texels_pass_the_bound() {
        let s = BtfSettings {
            lod_fade: 0.2,
            ..BtfSettings::default()
        };
        // The twig texel (4 mm) is 1 px at 2 m, 0.8 px (the band's start) at 2.5 m.
        assert_eq!(geometry_fade(&TEXELS, 1.0, FOCAL, 1.9, &s), 1.0);
        assert_eq!(geometry_fade(&TEXELS, 1.0, FOCAL, 2.6, &s), 0.0);
        let half = geometry_fade(&TEXELS, 1.0, FOCAL, 0.004 * FOCAL / 0.9, &s);
        assert!((half - 0.5).abs() < 1e-4, "{half}");
        // Abrupt without a band; a coarser LOD scale lets the twig images come closer.
        assert_eq!(geometry_fade(&TEXELS, 1.0, FOCAL, 2.2, &no_fade()), 0.0);
        let coarse = BtfSettings {
            lod_scale: 2.0,
            ..s
        };
        assert_eq!(geometry_fade(&TEXELS, 1.0, FOCAL, 1.5, &coarse), 0.0);

        let trees = [tree_at(0.0, 0.0, 0.3)];
        // Near: the whole tree as geometry, no billboards.
        let (near, _) = run_as(&trees, Vec3::new(0.0, 5.0, 1.5), &s, true);
        assert_eq!(near.stats.geometry_trees, 1);
        assert_eq!(near.twigs[0], vec![(0, 1.0)]);
        assert!(near.trunk_and_limbs[0].is_empty() && near.trunk_only[0].is_empty());
        assert!(near.records.is_empty() && near.stats.trees_per_level.iter().sum::<u32>() == 0);
        // The same view in `btf`: twig billboards, nothing as whole geometry.
        let (plain, _) = run_as(&trees, Vec3::new(0.0, 5.0, 1.5), &s, false);
        assert!(plain.twigs[0].is_empty() && plain.stats.billboards.twig > 0);
        // In the band: both, the billboards at the complement of the geometry's opacity.
        let z = 0.004 * FOCAL / 0.9;
        let (band, _) = run_as(&trees, Vec3::new(0.0, 5.0, z), &s, true);
        let (t, g) = band.twigs[0][0];
        assert!(t == 0 && (g - 0.5).abs() < 1e-3, "{g}");
        assert_eq!(band.stats.geometry_trees, 0);
        assert_eq!(band.stats.faded_trees, 1);
        assert!(band.trunk_and_limbs[0].is_empty());
        assert!(!band.records.is_empty());
        for r in &band.records {
            assert!((r.opacity - (1.0 - g)).abs() < 1e-4, "{}", r.opacity);
        }
        // Far: billboards only.
        let (far, _) = run_as(&trees, Vec3::new(0.0, 5.0, 8.0), &s, true);
        assert!(far.twigs[0].is_empty() && far.stats.geometry_trees == 0);
        assert_eq!(far.stats.trees_per_level.twig, 1);
    }

    fn no_fade() -> BtfSettings {
        BtfSettings {
            lod_fade: 0.0,
            ..BtfSettings::default()
        }
    }

    #[test]
    fn the_level_is_the_coarsest_whose_texels_project_below_the_scale() {
        let s = no_fade();
        // Tree level valid beyond 0.1 * 500 / 1 = 50 m, branch level beyond 10 m.
        assert_eq!(
            choose_level(&TEXELS, 1.0, FOCAL, 51.0, &s).level,
            Level::Tree
        );
        assert_eq!(
            choose_level(&TEXELS, 1.0, FOCAL, 49.0, &s).level,
            Level::Branch
        );
        assert_eq!(
            choose_level(&TEXELS, 1.0, FOCAL, 11.0, &s).level,
            Level::Branch
        );
        assert_eq!(
            choose_level(&TEXELS, 1.0, FOCAL, 9.0, &s).level,
            Level::Twig
        );
        // Up close nothing is valid: the twig level, blurred.
        assert_eq!(
            choose_level(&TEXELS, 1.0, FOCAL, 0.5, &s).level,
            Level::Twig
        );
        // A tree twice as large has texels twice as large: the bound moves out to 100 m.
        assert_eq!(
            choose_level(&TEXELS, 2.0, FOCAL, 90.0, &s).level,
            Level::Branch
        );
        // A LOD scale of 2 accepts texels of 2 px: the bound moves in to 25 m.
        let coarse = BtfSettings {
            lod_scale: 2.0,
            ..s
        };
        assert_eq!(
            choose_level(&TEXELS, 1.0, FOCAL, 30.0, &coarse).level,
            Level::Tree
        );
        assert!(
            choose_level(&TEXELS, 1.0, FOCAL, 30.0, &s)
                .fading_in
                .is_none()
        );
    }

    #[test]
    fn inside_the_fade_band_the_finer_level_fades_in_and_opacities_sum_to_one() {
        let s = BtfSettings {
            lod_fade: 0.2,
            ..BtfSettings::default()
        };
        // The tree level's texel is 0.8 px at 62.5 m, the band's start; 1 px at 50 m.
        let outside = choose_level(&TEXELS, 1.0, FOCAL, 70.0, &s);
        assert_eq!(outside.fading_in, None);
        let half = choose_level(&TEXELS, 1.0, FOCAL, 0.1 * FOCAL / 0.9, &s);
        assert_eq!(half.level, Level::Tree);
        let (finer, fade) = half.fading_in.expect("inside the band");
        assert_eq!(finer, Level::Branch);
        assert!((fade - 0.5).abs() < 1e-4, "fade {fade}");
        let total: f32 = half.draws().map(|(_, o)| o).sum();
        assert!((total - 1.0).abs() < 1e-6);
        // Just before the bound the finer level is almost opaque: the switch changes little.
        let edge = choose_level(&TEXELS, 1.0, FOCAL, 50.01, &s);
        assert!(edge.fading_in.unwrap().1 > 0.99);
        // The twig level has nothing finer to fade to.
        let twig = choose_level(&TEXELS, 1.0, FOCAL, 9.0, &s);
        assert_eq!((twig.level, twig.fading_in), (Level::Twig, None));
    }

    #[test]
    fn each_level_expands_into_its_billboards_and_geometry_lists() {
        let s = no_fade();
        let trees = [tree_at(0.0, 0.0, 0.3)];
        let cases = [
            (Vec3::new(0.0, 5.0, 80.0), Level::Tree, 1),
            (
                Vec3::new(0.0, 5.0, 30.0),
                Level::Branch,
                BRANCHES + TRUNK_TWIGS,
            ),
            (
                Vec3::new(0.0, 5.0, 8.0),
                Level::Twig,
                BRANCHES * BRANCH_TWIGS + TRUNK_TWIGS,
            ),
        ];
        for (eye, level, count) in cases {
            let (f, _) = run(&trees, eye, &s);
            assert_eq!(f.stats.trees_per_level[level], 1, "{level:?}");
            assert_eq!(f.records.len(), count, "{level:?}");
            assert_eq!(f.stats.total_billboards() as usize, count);
            let twigs = f.stats.billboards.twig as usize;
            match level {
                Level::Tree => {
                    assert_eq!(f.stats.billboards.tree, 1);
                    assert!(f.trunk_only[0].is_empty() && f.trunk_and_limbs[0].is_empty());
                }
                Level::Branch => {
                    assert_eq!(
                        (f.stats.billboards.branch as usize, twigs),
                        (BRANCHES, TRUNK_TWIGS)
                    );
                    assert_eq!((f.trunk_only[0].len(), f.trunk_and_limbs[0].len()), (1, 0));
                }
                Level::Twig => {
                    assert_eq!(twigs, count);
                    assert_eq!((f.trunk_only[0].len(), f.trunk_and_limbs[0].len()), (0, 1));
                }
            }
            // Every record points into its level's image set.
            let per_set = 18 * (18 + crate::format::AMBIENT_IMAGES_PER_VIEW);
            for r in &f.records {
                assert!(r.layer_base % per_set == 0 && r.layer_base / per_set <= 2);
            }
        }
    }

    #[test]
    fn a_fading_tree_draws_both_levels_with_complementary_opacity() {
        let s = BtfSettings {
            lod_fade: 0.2,
            ..BtfSettings::default()
        };
        // The tree's centre at 55.5 m: inside the tree level's band.
        let trees = [tree_at(0.0, 0.0, 0.0)];
        let (f, _) = run(&trees, Vec3::new(0.0, 5.0, 55.5), &s);
        assert_eq!(f.stats.faded_trees, 1);
        assert_eq!(f.records.len(), 1 + BRANCHES + TRUNK_TWIGS);
        let tree: Vec<f32> = f
            .records
            .iter()
            .filter(|r| r.layer_base == 2 * 18 * (18 + crate::format::AMBIENT_IMAGES_PER_VIEW))
            .map(|r| r.opacity)
            .collect();
        let finer: Vec<f32> = f
            .records
            .iter()
            .filter(|r| r.layer_base != 2 * 18 * (18 + crate::format::AMBIENT_IMAGES_PER_VIEW))
            .map(|r| r.opacity)
            .collect();
        assert_eq!(tree.len(), 1);
        assert!(finer.iter().all(|&o| (o + tree[0] - 1.0).abs() < 1e-6));
        assert!(tree[0] > 0.0 && tree[0] < 1.0);
        // The trunk is geometry while the branch level shows.
        assert_eq!(f.trunk_only[0], vec![0]);
    }

    #[test]
    fn weight_culling_drops_small_weights_and_renormalises() {
        // A crowd of trees at many angles, so that the blends vary.
        let trees: Vec<TreeGpu> = (0..40)
            .map(|i| tree_at((i % 8) as f32 * 9.0 - 30.0, -(i / 8) as f32 * 9.0, i as f32))
            .collect();
        let eye = Vec3::new(0.0, 30.0, 120.0);
        let (all, _) = run(&trees, eye, &no_fade());
        let threshold = 0.3;
        let culled_settings = BtfSettings {
            weight_threshold: threshold,
            ..no_fade()
        };
        let (culled, _) = run(&trees, eye, &culled_settings);
        assert_eq!(all.records.len(), culled.records.len());
        let mut dropped = 0;
        for r in &culled.records {
            // The light weights carry the light gain: they sum to it, at least 1.
            let gain: f32 = r.light_weight.iter().sum();
            assert!(
                (1.0 - 1e-5..=crate::sphere::MAX_LIGHT_GAIN + 1e-5).contains(&gain),
                "light weights {:?} sum to {gain}",
                r.light_weight
            );
            for w in [r.view_weight, r.light_weight.map(|x| x / gain)] {
                let sum: f32 = w.iter().sum();
                assert!((sum - 1.0).abs() < 1e-5, "weights {w:?} sum to {sum}");
                let largest = w.iter().copied().fold(0.0, f32::max);
                for x in w {
                    assert!(
                        x == 0.0 || x >= threshold || x == largest,
                        "kept {x} in {w:?}"
                    );
                    dropped += usize::from(x == 0.0);
                }
            }
        }
        assert!(dropped > 0, "a threshold of {threshold} dropped nothing");
        assert!(culled.stats.images_sampled < all.stats.images_sampled);
        assert!(culled.stats.fetches_saved > all.stats.fetches_saved);
        // Images sampled plus those saved is 15 per billboard.
        let n = culled.records.len() as u64;
        assert_eq!(
            culled.stats.images_sampled + culled.stats.fetches_saved,
            15 * n
        );
    }

    #[test]
    fn billboards_come_back_to_front_and_the_farthest_are_dropped_first() {
        let trees: Vec<TreeGpu> = (0..30)
            .map(|i| tree_at((i % 5) as f32 * 7.0 - 14.0, -(i / 5) as f32 * 7.0, i as f32))
            .collect();
        let eye = Vec3::new(0.0, 6.0, 25.0);
        let (f, camera) = run(&trees, eye, &no_fade());
        let depth = |r: &BillboardGpu| (Vec3::from(r.center) - eye).dot(camera.forward());
        assert!(f.records.len() > 30, "expected a mix of levels");
        assert!(f.records.windows(2).all(|w| depth(&w[0]) >= depth(&w[1])));
        // Capped: the nearest survive.
        let camera2 = Camera::look_at(eye, Vec3::new(0.0, 5.0, 0.0), 60.0);
        let frustum = camera2.frustum(16.0 / 9.0);
        let view = PrepareView {
            camera: &camera2,
            focal_px: FOCAL,
            to_sun: Vec3::Y,
            frustum: &frustum,
        };
        let visible = vec![(0..trees.len() as u32).collect::<Vec<_>>()];
        let cap = 10;
        let capped = scene().prepare(&trees, &visible, &view, &no_fade(), cap, false);
        assert_eq!(capped.records.len(), cap);
        assert_eq!(capped.stats.dropped as usize, f.records.len() - cap);
        let nearest: Vec<f32> = f.records[f.records.len() - cap..]
            .iter()
            .map(depth)
            .collect();
        let kept: Vec<f32> = capped.records.iter().map(depth).collect();
        assert_eq!(nearest, kept);
    }

    #[test]
    fn a_crowd_prepared_in_chunks_is_what_its_trees_give_one_by_one() {
        // More trees than one chunk takes, at every level, so that the threads split them.
        let n = 3 * PREPARE_CHUNK + 17;
        let trees: Vec<TreeGpu> = (0..n)
            .map(|i| {
                let (row, col) = ((i / 40) as f32, (i % 40) as f32);
                tree_at(col * 6.0 - 120.0, -row * 6.0 + 20.0, i as f32 * 0.7)
            })
            .collect();
        let eye = Vec3::new(0.0, 6.0, 24.0);
        let (all, camera) = run(&trees, eye, &BtfSettings::default());
        // Each tree alone, joined in order, then sorted back to front (stable: ties keep
        // the order made).
        let mut one_by_one: Vec<BillboardGpu> = Vec::new();
        let mut stats = BtfStats::default();
        let (mut trunk_only, mut trunk_and_limbs) = (Vec::new(), Vec::new());
        for (i, t) in trees.iter().enumerate() {
            let (f, _) = run(std::slice::from_ref(t), eye, &BtfSettings::default());
            one_by_one.extend(f.records);
            stats.add(&f.stats);
            trunk_only.extend(f.trunk_only[0].iter().map(|_| i as u32));
            trunk_and_limbs.extend(f.trunk_and_limbs[0].iter().map(|_| i as u32));
        }
        let depth = |r: &BillboardGpu| (Vec3::from(r.center) - eye).dot(camera.forward());
        one_by_one.sort_by(|a, b| depth(b).total_cmp(&depth(a)));
        assert!(stats.trees_per_level.iter().all(|&c| c > 0), "{stats:?}");
        assert_eq!(all.stats, stats);
        assert_eq!(all.trunk_only[0], trunk_only);
        assert_eq!(all.trunk_and_limbs[0], trunk_and_limbs);
        assert_eq!(all.records.len(), one_by_one.len());
        assert!(
            all.records
                .iter()
                .zip(&one_by_one)
                .all(|(a, b)| bytemuck::bytes_of(a) == bytemuck::bytes_of(b))
        );
    }

    #[test]
    fn trees_outside_the_view_make_no_billboards_and_overlays_tint_by_level() {
        let trees = [tree_at(0.0, 0.0, 0.0), tree_at(0.0, 400.0, 0.0)];
        // The second tree is behind the camera.
        let s = BtfSettings {
            show_lod: true,
            ..no_fade()
        };
        let (f, _) = run(&trees, Vec3::new(0.0, 5.0, 30.0), &s);
        assert_eq!(f.records.len(), BRANCHES + TRUNK_TWIGS);
        // The overlay colours a tree by the level it is drawn at: the twigs on the trunk of
        // a tree at the main-branch level show the main-branch colour.
        assert_eq!(f.stats.billboards.twig as usize, TRUNK_TWIGS);
        for r in &f.records {
            assert_eq!(r.mode, BillboardMode::Tint as u32);
            assert_eq!(r.tint, LOD_COLORS[Level::Branch]);
        }
    }

    /// The far trees' records as the GPU builds and sorts them, read back.
    fn gpu_far_records(
        scene: &BtfScene,
        trees: &[TreeGpu],
        view: &PrepareView,
        settings: &BtfSettings,
        budget: u64,
        near_room: Option<u64>,
    ) -> Vec<BillboardGpu> {
        use crate::render::{AdapterPreference, GpuContext};
        let ctx = GpuContext::headless(AdapterPreference::Cpu).expect("a Vulkan adapter");
        let layout = super::super::btf_layout(&ctx.device);
        let axes = ctx.device.create_buffer(&wgpu::BufferDescriptor {
            label: None,
            size: 16,
            usage: wgpu::BufferUsages::STORAGE,
            mapped_at_creation: false,
        });
        let texture = ctx.device.create_texture(&wgpu::TextureDescriptor {
            label: None,
            size: wgpu::Extent3d {
                width: 1,
                height: 1,
                depth_or_array_layers: 1,
            },
            mip_level_count: 1,
            sample_count: 1,
            dimension: wgpu::TextureDimension::D2,
            format: wgpu::TextureFormat::Rgba8UnormSrgb,
            usage: wgpu::TextureUsages::TEXTURE_BINDING,
            view_formats: &[],
        });
        let texture_view = texture.create_view(&wgpu::TextureViewDescriptor {
            dimension: Some(wgpu::TextureViewDimension::D2Array),
            ..Default::default()
        });
        let sampler = ctx
            .device
            .create_sampler(&wgpu::SamplerDescriptor::default());
        let species = vec![0u32; trees.len()];
        let bounds: Vec<Aabb> = trees
            .iter()
            .map(|t| {
                scene.species[0]
                    .bounds
                    .transformed(Mat4::from_cols_array_2d(&t.model))
            })
            .collect();
        let mut gpu = super::super::far::FarGpu::new(
            &ctx,
            scene,
            trees,
            &species,
            &bounds,
            &layout,
            (&axes, &texture_view, &sampler),
        )
        .unwrap()
        .expect("the far trees fit");
        if let Some(room) = near_room {
            gpu.set_near_room(room);
        }
        let (near, _) = gpu.prepare(&ctx, scene, trees, &bounds, view, settings, true);
        if settings.gpu_near {
            let (_, records, draws, slots) =
                scene.prepare_near(trees, &species, &near, view, settings, false, budget);
            assert!(slots <= budget);
            assert_eq!(records.is_empty(), budget == u64::MAX);
            assert!(gpu.upload_near(&ctx, &records, &draws, slots).unwrap());
        } else {
            let (_, records) = scene.prepare_sorted(trees, &near, view, settings, 0, false);
            assert!(gpu.upload_near(&ctx, &records, &[], 0).unwrap());
        }
        let mut encoder = ctx
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor { label: None });
        gpu.encode(&mut encoder, None);
        ctx.queue.submit([encoder.finish()]);
        gpu.read_sorted(&ctx).unwrap()
    }

    /// The weight of sample `i` in slots (`index`, `weight`).
    fn weight_of(index: [u32; 3], weight: [f32; 3], i: u32) -> f32 {
        (0..3).filter(|&k| index[k] == i).map(|k| weight[k]).sum()
    }

    #[test]
    fn the_gpu_builds_the_far_trees_records_the_cpu_would_back_to_front() {
        // A crowd 90 to 400 m away: every tree past the tree level's fade band.
        gpu_against_cpu(90.0, false, false, true, u64::MAX, false, None);
    }

    #[test]
    fn near_trees_made_on_the_cpu_are_sorted_with_the_far_ones() {
        // From 4 m: trees at every level, fading, the near ones' billboards made on the
        // CPU and sorted with the far ones' on the GPU.
        gpu_against_cpu(4.0, true, false, true, u64::MAX, false, None);
    }

    #[test]
    fn near_trees_expanded_on_the_gpu_are_what_the_cpu_would_make() {
        // The same, the near trees' billboards expanded and shaded on the GPU: their parts'
        // cube maps read towards the sun in each part's frame, and the parents' factors.
        gpu_against_cpu(4.0, true, true, true, u64::MAX, false, None);
        // And without cube maps (every factor 1), with the level overlay (a main-branch
        // draw's twigs in the main branch's colour).
        gpu_against_cpu(4.0, true, true, false, u64::MAX, true, None);
    }

    #[test]
    fn past_the_gpus_room_the_farther_near_trees_billboards_are_made_on_the_cpu() {
        // Room for some of the near trees' billboards only: the nearest trees' go to the
        // GPU, the others' are made on the CPU, and together they are the CPU's frame.
        gpu_against_cpu(4.0, true, true, true, 300, false, None);
    }

    #[test]
    fn near_slots_past_one_bindings_room_go_to_a_second_binding() {
        // A first binding of 100 slots (lavapipe's holds 524,288 records, which a frame of
        // 100,000 trees at 1280x720 passes): the next 100 go to the second, the farther
        // near trees' billboards to the CPU, and together they are the CPU's frame.
        gpu_against_cpu(4.0, true, true, true, 200, false, Some(100));
    }

    /// Trees from `z_min` to 400 m ahead; the GPU's billboards, back to front, are the
    /// CPU's (`near`: some trees are near; `gpu_near`: their billboards are expanded on the
    /// GPU, at most `budget` slots of them; `vcm`: with cube maps of random opacity;
    /// `overlay`: tinted by level).
    fn gpu_against_cpu(
        z_min: f32,
        near: bool,
        gpu_near: bool,
        vcm: bool,
        budget: u64,
        overlay: bool,
        near_room: Option<u64>,
    ) {
        // The tree level at 66 views and 6 lights, as the default bake; trees of mixed yaw
        // and scale.
        let mut scene = scene();
        scene.views.tree = DirectionSet::with_count(66).unwrap();
        scene.views.branch = DirectionSet::with_count(18).unwrap();
        scene.views.twig = DirectionSet::with_count(6).unwrap();
        scene.lights = DirectionSet::with_count(6).unwrap();
        if vcm {
            scene.vcm = Some(VcmShading::synthetic(
                4,
                &[(BRANCHES, BRANCH_TWIGS + TRUNK_TWIGS)],
                300,
            ));
        }
        let mut trees = Vec::new();
        let mut rng = 7u32;
        let mut next = || {
            rng = rng.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
            (rng >> 8) as f32 / (1u32 << 24) as f32
        };
        while trees.len() < 300 {
            // Denser near the camera.
            let z = next().powi(2) * (400.0 - z_min) + z_min;
            let x = (next() * 2.6 - 1.3) * (z + 10.0);
            let s = 0.8 + 0.4 * next();
            let m = Mat4::from_translation(Vec3::new(x, 3.0 * next(), z))
                * Mat4::from_rotation_y(next() * std::f32::consts::TAU)
                * Mat4::from_scale(Vec3::splat(s));
            trees.push(TreeGpu {
                model: m.to_cols_array_2d(),
                tint: [next(), next(), next(), 1.0],
            });
        }
        let camera = Camera::look_at(Vec3::new(0.0, 6.0, -2.0), Vec3::new(0.0, 0.0, 200.0), 60.0);
        let frustum = camera.frustum(16.0 / 9.0);
        let view = PrepareView {
            camera: &camera,
            focal_px: FOCAL,
            to_sun: Vec3::new(0.3, 0.5, -0.6).normalize(),
            frustum: &frustum,
        };
        let settings = BtfSettings {
            weight_threshold: 0.15,
            gpu_near,
            show_lod: overlay,
            ..BtfSettings::default()
        };
        scene.update_sun(view.to_sun);
        // The trees in view by their bounds, as the renderer culls (the billboard's own
        // test then drops a few more).
        let visible = vec![
            (0..trees.len() as u32)
                .filter(|&t| {
                    let m = Mat4::from_cols_array_2d(&trees[t as usize].model);
                    frustum.intersects(&scene.species[0].bounds.transformed(m))
                })
                .collect::<Vec<_>>(),
        ];
        assert!(visible[0].len() < trees.len(), "some trees are out of view");
        let bound = BtfScene::far_bound(&settings);
        let near_trees = trees
            .iter()
            .filter(|t| scene.is_near(0, t, &view, bound))
            .count();
        assert_eq!(near_trees > 0, near, "{near_trees} near trees");
        let cpu_frame = scene.prepare(&trees, &visible, &view, &settings, usize::MAX, false);
        if near {
            let levels = cpu_frame.stats.trees_per_level;
            assert!(
                levels[Level::Twig] > 0 && levels[Level::Branch] > 0,
                "{levels:?}"
            );
            assert!(cpu_frame.stats.faded_trees > 0);
        }
        let mut cpu = cpu_frame.records;
        assert!(cpu.len() > 100, "{} billboards in view", cpu.len());
        let gpu = gpu_far_records(&scene, &trees, &view, &settings, budget, near_room);
        assert_eq!(gpu.len(), cpu.len(), "as many billboards");
        let forward = camera.forward();
        let depth = |r: &BillboardGpu| (Vec3::from(r.center) - camera.position).dot(forward);
        for (k, pair) in gpu.windows(2).enumerate() {
            assert!(
                depth(&pair[0]) >= depth(&pair[1]) - 1e-3,
                "record {k} is nearer than the next"
            );
        }
        let close = |a: [f32; 3], b: [f32; 3], tol: f32| {
            (Vec3::from(a) - Vec3::from(b)).abs().max_element() <= tol
        };
        for (k, g) in gpu.iter().enumerate() {
            // Its match among the CPU's records (the same object seen the same way).
            let m = cpu
                .iter()
                .position(|c| {
                    (c.layer_base, c.opacity) == (g.layer_base, g.opacity)
                        && (c.radius - g.radius).abs() < 1e-4
                        && close(g.center, c.center, 1e-3)
                        && close(g.obj_right, c.obj_right, 1e-3)
                })
                .unwrap_or_else(|| panic!("record {k} is not the CPU's: {g:?}"));
            let c = cpu.swap_remove(m);
            assert!(
                close(g.center, c.center, 1e-3),
                "record {k}: centre {g:?} against {c:?}"
            );
            assert!((g.radius - c.radius).abs() < 1e-4);
            assert!(
                close(g.plane_right, c.plane_right, 1e-4),
                "record {k}: {g:?} against {c:?}"
            );
            assert!(close(g.plane_up, c.plane_up, 1e-4));
            assert!(close(g.obj_right, c.obj_right, 1e-4));
            assert!(close(g.obj_up, c.obj_up, 1e-4));
            for i in 0..66u32 {
                let (wg, wc) = (
                    weight_of(g.view_index, g.view_weight, i),
                    weight_of(c.view_index, c.view_weight, i),
                );
                assert!(
                    (wg - wc).abs() < 1e-3,
                    "record {k} view {i}: {wg} against {wc}"
                );
            }
            for i in 0..6 {
                let (wg, wc) = (
                    weight_of(g.light_index, g.light_weight, i),
                    weight_of(c.light_index, c.light_weight, i),
                );
                assert!(
                    (wg - wc).abs() < 1e-3,
                    "record {k} light {i}: {wg} against {wc}"
                );
            }
            assert_eq!(
                (g.layer_base, g.view_count, g.light_count, g.planes, g.mode),
                (c.layer_base, c.view_count, c.light_count, c.planes, c.mode)
            );
            assert_eq!((g.opacity, g.tint), (c.opacity, c.tint));
            assert!(close(g.vcm_box_origin, c.vcm_box_origin, 1e-5));
            assert!(close(g.vcm_box_scale, c.vcm_box_scale, 1e-5));
            let factors = |r: &BillboardGpu| {
                let mut v = r.vcm_direct.concat();
                v.extend(r.vcm_sky.concat());
                v.extend([r.parent_direct, r.parent_sky]);
                v
            };
            for (i, (fg, fc)) in factors(g).into_iter().zip(factors(&c)).enumerate() {
                assert!(
                    (fg - fc).abs() < 1e-3,
                    "record {k} factor {i}: {fg} against {fc}"
                );
            }
        }
    }
}
