//! A frame's billboards: each tree expanded into its records, gathered in chunks and
//! sorted back to front.

use super::*;
use crate::render::method::btf::billboard::NO_LIGHT_BLEND;
use crate::render::method::btf::light_blend::{bin_direction, light_weights, yaw_bin};

/// One frame's billboard records in the chunks that made them, and their order back to
/// front.
#[derive(Default)]
pub struct SortedBillboards {
    pub(super) records: Vec<Vec<BillboardGpu>>,
    /// Each chunk's first record, counting through the chunks in order.
    pub(super) starts: Vec<usize>,
    /// Depth and record index (as counted in `starts`), back to front.
    pub(super) keys: Vec<(f32, u32)>,
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

    /// Writes the records back to front into `out` as bytes (as many as it holds), or
    /// front to back (the nearest first) where `front_to_back`.
    /// (`wgpu::WriteOnly` of a slice is not `Send`, so this runs on one thread.)
    pub fn write(&self, mut out: wgpu::WriteOnly<'_, [u8]>, front_to_back: bool) {
        const SIZE: usize = std::mem::size_of::<BillboardGpu>();
        let n = self.len();
        let count = (out.len() / SIZE).min(n);
        for k in 0..count {
            let at = if front_to_back { n - 1 - k } else { k };
            out.slice(k * SIZE..(k + 1) * SIZE)
                .copy_from_slice(bytemuck::bytes_of(self.get(at)));
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
pub(super) const PREPARE_CHUNK: usize = 256;

/// What one chunk of trees made: their billboards in the order made, with their depths,
/// and the trees drawn partly or wholly as geometry, per species.
pub(super) struct Prepared {
    pub(super) records: Vec<BillboardGpu>,
    /// For the GPU to expand instead (`first` holding each one's billboard count).
    pub(super) draws: Vec<NearDrawGpu>,
    pub(super) depths: Vec<f32>,
    pub(super) stats: BtfStats,
    pub(super) trunk_only: Vec<Vec<u32>>,
    pub(super) trunk_and_limbs: Vec<Vec<u32>>,
    pub(super) twigs: Vec<Vec<(u32, f32)>>,
    pub(super) impostors: Vec<Vec<(u32, f32)>>,
}

impl Prepared {
    pub(super) fn new(species: usize) -> Self {
        Self {
            records: Vec::new(),
            draws: Vec::new(),
            depths: Vec::new(),
            stats: BtfStats::default(),
            trunk_only: vec![Vec::new(); species],
            trunk_and_limbs: vec![Vec::new(); species],
            twigs: vec![Vec::new(); species],
            impostors: vec![Vec::new(); species],
        }
    }
}

/// Expands one tree (model matrix `m`) at `level` into its billboards: the tree; its main
/// branches and the twigs on its trunk; or every twig, on the branches and on the trunk.
pub(super) fn expand(
    p: &mut Pusher,
    parts: &SpeciesParts,
    level: Level,
    m: Mat4,
    shading: Option<&crate::render::vcm_shading::TreeShading>,
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
pub(super) struct Pusher<'a, 'v> {
    pub(super) scene: &'a BtfScene,
    pub(super) view: &'a PrepareView<'v>,
    pub(super) settings: &'a BtfSettings,
    pub(super) records: &'a mut Vec<BillboardGpu>,
    /// Each record's depth along the view.
    pub(super) depths: &'a mut Vec<f32>,
    pub(super) stats: &'a mut BtfStats,
    pub(super) tint: ([f32; 3], BillboardMode),
    /// Opacity of the whole billboard (the cross-fade).
    pub(super) opacity: f32,
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
        let mut l_obj = to_object * self.view.to_sun;
        let scene = self.scene;
        // A tree-level billboard reads its lights' blend, made for its yaw bin.
        let bins = scene.light_bins;
        let light_blend = if level == Level::Tree && bins > 0 && self.settings.light_blend {
            let bin = yaw_bin(l_obj, self.view.to_sun, bins);
            l_obj = bin_direction(self.view.to_sun, bin, bins);
            scene.light_blend_first(set.prototype, bin)
        } else {
            NO_LIGHT_BLEND
        };
        let views = &scene.views[level];
        let mut vb = views.blend(v_obj);
        vb.cull(self.settings.weight_threshold);
        // The light weights carry the gain that brightens the blend towards the sun.
        let lb = light_weights(&scene.lights, l_obj, self.settings);
        let lights_used = if light_blend == NO_LIGHT_BLEND {
            lb.weight.iter().filter(|&&w| w > 0.0).count() as u64
        } else {
            1
        };
        let views_used = vb.weight.iter().filter(|&&w| w > 0.0).count() as u64;
        // Per view: its lights, its sky-lit and its ground-lit image.
        let fetches =
            views_used * (lights_used + u64::from(crate::format::AMBIENT_IMAGES_PER_VIEW));
        self.stats.images_sampled += fetches;
        self.stats.fetches_saved += FETCHES_AT_MOST - fetches.min(FETCHES_AT_MOST);
        self.stats.billboards[level] += 1;
        self.stats.light_blended += u32::from(light_blend != NO_LIGHT_BLEND);
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
            light_blend,
            tint: self.tint.0,
            mode: self.tint.1 as u32,
            ..BillboardGpu::UNSHADED
        }
        .shade(&shade, set);
        self.records.push(record);
        self.depths.push(depth);
    }
}

impl BtfScene {
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
