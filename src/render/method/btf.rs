//! The `btf` method: every tree as BTF billboards of its chosen level (Meyer, Neyret, Poulin
//! 2001). Per frame, on the CPU: choose each visible tree's level by the texel criterion,
//! expand it into billboards (the tree; its main branches; or its twigs, at their instance
//! transforms), find each billboard's view and light directions in its object frame and the
//! 3 nearest samples of each with their weights, cull small weights, sort back to front.
//! On the GPU: one instanced draw samples a single texture array holding every image set.

use std::collections::HashMap;

use glam::{Mat3, Mat4, Vec3};

use crate::format::Baked;
use crate::lod::{self, LevelTexels};
use crate::model::mesh::Aabb;
use crate::model::{Level, PerLevel, World};
use crate::render::GpuContext;
use crate::render::camera::Frustum;
use crate::render::frame::FrameStats;
use crate::render::pipelines::ColorPipelines;
use crate::render::shading::{ObjectFrame, Shade, VcmShading};
use crate::render::world_gpu::{PartKind, TreeRun, WorldGpu};
use crate::sphere::{DirectionSet, billboard_axes};
use crate::{Error, Result};

/// How each billboard is drawn.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum PlaneMode {
    /// One plane facing the eye; each view's image is reprojected onto it along its view.
    #[default]
    Single,
    /// Three planes, each view's image on the plane facing its own sampled view, summed
    /// with the views' weights where the eye's ray meets each (annex A's weighted sum).
    Crossed,
}

impl PlaneMode {
    pub fn parse(s: &str) -> Option<Self> {
        match s {
            "single" => Some(Self::Single),
            "crossed" => Some(Self::Crossed),
            _ => None,
        }
    }

    pub fn name(self) -> &'static str {
        match self {
            Self::Single => "single",
            Self::Crossed => "crossed",
        }
    }
}

/// The knobs of the `btf` method.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BtfSettings {
    /// A level is valid while its largest texel projects below this many pixels.
    pub lod_scale: f32,
    /// Images whose weight is below this are skipped and the others renormalised.
    pub weight_threshold: f32,
    pub planes: PlaneMode,
    /// Colour each billboard by its level instead of its images.
    pub show_lod: bool,
    /// Width of the cross-fade band before a level's bound, as a fraction of the bound
    /// (0 = switch abruptly).
    pub lod_fade: f32,
    /// Shade the billboards with the visibility cube maps (when the bake has them).
    pub vcm: bool,
    /// Draw each billboard's VCM sun factor (b·c·d) in grey instead of its images.
    pub show_shadow: bool,
    /// Weight the sky term by the cube maps' mean visibility (off: the cube maps shade the
    /// sun term only, as if the sky were never hidden).
    pub vcm_sky: bool,
}

impl Default for BtfSettings {
    fn default() -> Self {
        Self {
            lod_scale: 1.0,
            weight_threshold: 0.0,
            planes: PlaneMode::Single,
            show_lod: false,
            lod_fade: 0.2,
            vcm: true,
            show_shadow: false,
            vcm_sky: true,
        }
    }
}

/// What the `btf` method did in one frame.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize)]
pub struct BtfStats {
    /// Billboards drawn per level.
    pub billboards: PerLevel<u32>,
    /// Trees drawn at each level (by the coarser level while fading).
    pub trees_per_level: PerLevel<u32>,
    /// Trees drawn at two levels at once, cross-fading.
    pub faded_trees: u32,
    /// Image fetches per fragment summed over billboards (views x (lights + ambient)).
    pub images_sampled: u64,
    /// Fetches skipped by image-weight culling, against 3 x (3 + 1) = 12 per billboard.
    pub fetches_saved: u64,
    /// Billboards left out because the instance buffer would pass the GPU's limit.
    pub dropped: u32,
    /// The billboards were shaded by visibility cube maps.
    pub vcm: bool,
}

impl BtfStats {
    pub fn total_billboards(&self) -> u32 {
        self.billboards.iter().sum()
    }

    /// Images sampled per billboard, on average.
    pub fn images_per_billboard(&self) -> f64 {
        let n = self.total_billboards();
        if n == 0 {
            0.0
        } else {
            self.images_sampled as f64 / f64::from(n)
        }
    }
}

/// What a billboard's fragments show (`Billboard::mode` in `billboard.wgsl`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[repr(u32)]
pub enum BillboardMode {
    /// The weighted images: the method itself.
    Images = 0,
    /// The tint alone, times coverage (the LOD-level overlay).
    Tint = 1,
    /// The VCM sun factor in grey, times coverage.
    SunFactor = 2,
}

/// One billboard as `billboard.wgsl` reads it (`struct Billboard`), byte for byte: each
/// `[_; 3]` is a WGSL `vec3` and the scalar after it fills its 16-byte slot (checked against
/// the WGSL by tests/gpu_layout.rs).
#[repr(C)]
#[derive(Clone, Copy, Debug, bytemuck::Pod, bytemuck::Zeroable)]
pub struct BillboardGpu {
    /// World centre of the quad.
    pub center: [f32; 3],
    /// World radius (half the quad's side).
    pub radius: f32,
    /// The quad's right axis in the world (unit).
    pub plane_right: [f32; 3],
    /// 1: one plane facing the eye; 3: crossed planes, one facing each sampled view (the
    /// quad then bounds them and the fragment shader finds each plane's point).
    pub planes: u32,
    /// The quad's up axis in the world (unit).
    pub plane_up: [f32; 3],
    /// Opacity of the whole billboard (the LOD cross-fade).
    pub opacity: f32,
    /// The quad's axes in the object frame, where the images were taken.
    pub obj_right: [f32; 3],
    pub _pad0: f32,
    pub obj_up: [f32; 3],
    pub _pad1: f32,
    /// Sample indices of the 3 nearest views.
    pub view_index: [u32; 3],
    /// First layer of this object's image set in the texture array.
    pub layer_base: u32,
    /// Sample indices of the 3 nearest lights.
    pub light_index: [u32; 3],
    /// Number of light samples of the bake.
    pub light_count: u32,
    /// View weights (0 = culled).
    pub view_weight: [f32; 3],
    /// Number of view samples of the bake.
    pub view_count: u32,
    /// Light weights (0 = culled).
    pub light_weight: [f32; 3],
    pub _pad2: f32,
    /// Colour tint of the tree, or the overlay colour.
    pub tint: [f32; 3],
    /// A [`BillboardMode`].
    pub mode: u32,
    /// Box coordinates of the billboard centre in its object's VCM box.
    pub vcm_box_origin: [f32; 3],
    /// The coarser levels' sun factor at the billboard's centre.
    pub parent_direct: f32,
    /// Box coordinates per unit of `p` (radii).
    pub vcm_box_scale: [f32; 3],
    /// The coarser levels' sky factor at the billboard's centre.
    pub parent_sky: f32,
    /// Sun visibility at the object's 8 box corners.
    pub vcm_direct: [[f32; 4]; 2],
    /// Sky visibility at the 8 corners.
    pub vcm_sky: [[f32; 4]; 2],
}

/// A billboard with every field zero and no VCM shading (all factors 1).
const NO_SHADE: BillboardGpu = BillboardGpu {
    center: [0.0; 3],
    radius: 0.0,
    plane_right: [0.0; 3],
    planes: 1,
    plane_up: [0.0; 3],
    opacity: 1.0,
    obj_right: [0.0; 3],
    _pad0: 0.0,
    obj_up: [0.0; 3],
    _pad1: 0.0,
    view_index: [0; 3],
    layer_base: 0,
    light_index: [0; 3],
    light_count: 0,
    view_weight: [0.0; 3],
    view_count: 0,
    light_weight: [0.0; 3],
    _pad2: 0.0,
    tint: [0.0; 3],
    mode: BillboardMode::Images as u32,
    vcm_box_origin: [0.5, 0.5, 0.5],
    parent_direct: 1.0,
    vcm_box_scale: [0.0; 3],
    parent_sky: 1.0,
    vcm_direct: [[1.0; 4]; 2],
    vcm_sky: [[1.0; 4]; 2],
};

impl BillboardGpu {
    /// Fills the VCM fields from `shade`, for an object of `bounds` whose billboard frame is
    /// `set`.
    fn shade(mut self, shade: &Shade, set: &SetInfo) -> Self {
        let points = set.bounds;
        let ext = (points.max - points.min).max(Vec3::splat(1e-6));
        self.vcm_box_origin = ((set.center - points.min) / ext).to_array();
        self.vcm_box_scale = (Vec3::splat(set.radius) / ext).to_array();
        self.parent_direct = shade.parent_direct;
        self.parent_sky = shade.parent_sky;
        let d = shade.direct;
        let k = shade.sky;
        self.vcm_direct = [[d[0], d[1], d[2], d[3]], [d[4], d[5], d[6], d[7]]];
        self.vcm_sky = [[k[0], k[1], k[2], k[3]], [k[4], k[5], k[6], k[7]]];
        self
    }
}

/// Where one image set sits in the texture array, and its billboard frame.
#[derive(Clone, Copy, Debug)]
struct SetInfo {
    layer_base: u32,
    center: Vec3,
    radius: f32,
    /// The object's bounds in its own frame (its VCM box).
    bounds: Aabb,
}

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

/// Colours of the 'show LOD level' overlay.
pub const LOD_COLOURS: PerLevel<[f32; 3]> = PerLevel {
    twig: [0.9, 0.2, 0.15],
    branch: [0.95, 0.8, 0.1],
    tree: [0.2, 0.45, 0.95],
};

/// The BTF image sets on the GPU and the per-frame billboard buffer.
pub struct BtfAssets {
    species: Vec<SpeciesParts>,
    views: DirectionSet,
    lights: DirectionSet,
    _texture: wgpu::Texture,
    texture_view: wgpu::TextureView,
    sampler: wgpu::Sampler,
    view_axes: wgpu::Buffer,
    layout: wgpu::BindGroupLayout,
    billboards: wgpu::Buffer,
    capacity: usize,
    max_capacity: usize,
    bind_group: wgpu::BindGroup,
    pipelines: HashMap<wgpu::TextureFormat, wgpu::RenderPipeline>,
    opacity_pipeline: Option<wgpu::RenderPipeline>,
    sun_billboards: wgpu::Buffer,
    sun_capacity: usize,
    sun_bind_group: wgpu::BindGroup,
    scratch: Vec<(f32, BillboardGpu)>,
    /// Bytes of the texture array, mipmaps included.
    pub bytes: u64,
    /// The visibility cube maps, when the bake has them.
    vcm: Option<VcmShading>,
}

/// Trees the `btf` method draws partly as geometry this frame.
pub struct BtfFrame {
    /// Per species: trees at the main-branch level (their trunk is geometry).
    pub trunk_only: Vec<Vec<u32>>,
    /// Per species: trees at the twig level (trunk and limbs are geometry).
    pub trunk_and_limbs: Vec<Vec<u32>>,
    pub billboards: u32,
    pub stats: BtfStats,
}

impl BtfAssets {
    pub fn new(ctx: &GpuContext, baked: &Baked, world: &World) -> Result<Self> {
        let bad = |m: String| {
            Error::BadInput(format!(
                "baked BTF data does not fit the scene: {m}; re-bake with `canopy bake`"
            ))
        };
        let s = &baked.settings;
        let views = DirectionSet::with_count(s.views as usize).map_err(|e| bad(e.to_string()))?;
        let lights = DirectionSet::with_count(s.lights as usize).map_err(|e| bad(e.to_string()))?;
        let res = s.resolution;
        let per_set = s.views * s.lights + s.views;
        // Every species needs its three levels.
        let mut index: HashMap<(u32, Level), usize> = HashMap::new();
        for (i, set) in baked.btf.iter().enumerate() {
            if set.views != s.views || set.lights != s.lights || set.resolution != res {
                return Err(bad(format!(
                    "image set {i} has other sizes than the file's settings"
                )));
            }
            index.insert((set.species, set.level), i);
        }
        let mut order = Vec::new();
        for sp in 0..world.species.len() {
            for level in Level::ALL {
                let l = level.index();
                let i = index
                    .get(&(sp as u32, level))
                    .copied()
                    .ok_or_else(|| bad(format!("species {sp} level {l} is missing")))?;
                order.push(i);
            }
        }
        let layers = per_set as u64 * order.len() as u64;
        let max_layers = u64::from(ctx.device.limits().max_texture_array_layers);
        if layers > max_layers {
            return Err(Error::BadInput(format!(
                "the BTF needs {layers} texture layers but this GPU allows {max_layers}; bake with fewer views or lights"
            )));
        }
        let mips = res.max(1).ilog2() + 1;
        let texture = ctx.checked("allocating the BTF texture array", || {
            ctx.device.create_texture(&wgpu::TextureDescriptor {
                label: Some("btf images"),
                size: wgpu::Extent3d {
                    width: res,
                    height: res,
                    depth_or_array_layers: layers.max(1) as u32,
                },
                mip_level_count: mips,
                sample_count: 1,
                dimension: wgpu::TextureDimension::D2,
                format: wgpu::TextureFormat::Rgba8UnormSrgb,
                usage: wgpu::TextureUsages::TEXTURE_BINDING | wgpu::TextureUsages::COPY_DST,
                view_formats: &[],
            })
        })?;
        let image_bytes = (res * res * 4) as usize;
        let mut bytes = 0u64;
        let mut species: Vec<SpeciesParts> = Vec::new();
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
                let k = sp * 3 + level.index();
                let set = &baked.btf[order[k]];
                let base = k as u32 * per_set;
                sets[level] = SetInfo {
                    layer_base: base,
                    center: Vec3::from(set.center),
                    radius: set.radius,
                    bounds: level_bounds[level],
                };
                texels[level] = set.texel_size;
                let images = set
                    .direct
                    .chunks_exact(image_bytes)
                    .chain(set.ambient.chunks_exact(image_bytes));
                for (i, img) in images.enumerate() {
                    bytes += upload_layer(ctx, &texture, base + i as u32, res, img, mips);
                }
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
        let texture_view = texture.create_view(&wgpu::TextureViewDescriptor {
            dimension: Some(wgpu::TextureViewDimension::D2Array),
            ..Default::default()
        });
        let sampler = ctx.device.create_sampler(&wgpu::SamplerDescriptor {
            label: Some("btf"),
            address_mode_u: wgpu::AddressMode::ClampToEdge,
            address_mode_v: wgpu::AddressMode::ClampToEdge,
            mag_filter: wgpu::FilterMode::Linear,
            min_filter: wgpu::FilterMode::Linear,
            mipmap_filter: wgpu::MipmapFilterMode::Linear,
            ..Default::default()
        });
        let axes: Vec<[f32; 4]> = views
            .directions()
            .iter()
            .flat_map(|&v| {
                let (r, u) = billboard_axes(v);
                [r.extend(0.0).to_array(), u.extend(0.0).to_array()]
            })
            .collect();
        let view_axes = wgpu::util::DeviceExt::create_buffer_init(
            &ctx.device,
            &wgpu::util::BufferInitDescriptor {
                label: Some("btf view axes"),
                contents: bytemuck::cast_slice(&axes),
                usage: wgpu::BufferUsages::STORAGE,
            },
        );
        let layout = ctx
            .device
            .create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
                label: Some("btf"),
                entries: &[
                    storage_entry(0, wgpu::ShaderStages::VERTEX_FRAGMENT),
                    storage_entry(1, wgpu::ShaderStages::FRAGMENT),
                    wgpu::BindGroupLayoutEntry {
                        binding: 2,
                        visibility: wgpu::ShaderStages::FRAGMENT,
                        ty: wgpu::BindingType::Texture {
                            sample_type: wgpu::TextureSampleType::Float { filterable: true },
                            view_dimension: wgpu::TextureViewDimension::D2Array,
                            multisampled: false,
                        },
                        count: None,
                    },
                    wgpu::BindGroupLayoutEntry {
                        binding: 3,
                        visibility: wgpu::ShaderStages::FRAGMENT,
                        ty: wgpu::BindingType::Sampler(wgpu::SamplerBindingType::Filtering),
                        count: None,
                    },
                ],
            });
        let stride = std::mem::size_of::<BillboardGpu>();
        let limits = ctx.device.limits();
        let max_capacity = (limits
            .max_storage_buffer_binding_size
            .min(limits.max_buffer_size)
            / stride as u64) as usize;
        let capacity = 1024.min(max_capacity);
        let billboards = billboard_buffer(ctx, capacity);
        let bind_group = make_bind_group(
            ctx,
            &layout,
            &billboards,
            &view_axes,
            &texture_view,
            &sampler,
        );
        let sun_capacity = world.forest.instances.len().clamp(1, max_capacity);
        let sun_billboards = billboard_buffer(ctx, sun_capacity);
        let sun_bind_group = make_bind_group(
            ctx,
            &layout,
            &sun_billboards,
            &view_axes,
            &texture_view,
            &sampler,
        );
        Ok(Self {
            species,
            views,
            lights,
            _texture: texture,
            texture_view,
            sampler,
            view_axes,
            layout,
            billboards,
            capacity,
            max_capacity,
            bind_group,
            pipelines: HashMap::new(),
            opacity_pipeline: None,
            sun_billboards,
            sun_capacity,
            sun_bind_group,
            scratch: Vec::new(),
            bytes,
            vcm: VcmShading::new(baked, world)?,
        })
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

    /// Chooses levels, builds and sorts the billboards and uploads them.
    #[allow(clippy::too_many_arguments)]
    pub fn prepare(
        &mut self,
        ctx: &GpuContext,
        world: &WorldGpu,
        visible: &[Vec<u32>],
        camera: &crate::render::Camera,
        focal_px: f32,
        to_sun: Vec3,
        frustum: &Frustum,
        settings: &BtfSettings,
    ) -> BtfFrame {
        let mut out = BtfFrame {
            trunk_only: vec![Vec::new(); self.species.len()],
            trunk_and_limbs: vec![Vec::new(); self.species.len()],
            billboards: 0,
            stats: BtfStats::default(),
        };
        let mut scratch = std::mem::take(&mut self.scratch);
        scratch.clear();
        let vcm = self.vcm.as_ref().filter(|_| settings.vcm);
        out.stats.vcm = vcm.is_some();
        let cam = camera.position;
        let forward = camera.forward();
        for (sp, trees) in visible.iter().enumerate() {
            let Some(parts) = self.species.get(sp) else {
                continue;
            };
            for &t in trees {
                let data = &world.tree_data[t as usize];
                let m = Mat4::from_cols_array_2d(&data.model);
                let scale = m.x_axis.truncate().length();
                let center = m.transform_point3(parts.bounds.center());
                let z = (center - cam).length();
                let level = lod::choose(&parts.texels, scale, focal_px, z, settings.lod_scale);
                // Cross-fade: while the chosen level's texel is within the last `lod_fade`
                // fraction of the bound, the next finer level fades in over it, so that the
                // switch at the bound itself changes nothing.
                let px = lod::projected_px(parts.texels[level] * scale, focal_px, z);
                let start = settings.lod_scale * (1.0 - settings.lod_fade.clamp(0.0, 1.0));
                let finer = level.finer();
                let fade = match finer {
                    Some(_) if settings.lod_fade > 0.0 && px > start => {
                        ((px - start) / (settings.lod_scale - start).max(1e-6)).clamp(0.0, 1.0)
                    }
                    _ => 0.0,
                };
                let mut draws = vec![(level, 1.0 - fade)];
                if let (Some(f), true) = (finer, fade > 0.0) {
                    draws.push((f, fade));
                    out.stats.faded_trees += 1;
                }
                out.stats.trees_per_level[level] += 1;
                let mut geometry = None;
                for (level, opacity) in draws {
                    let tint = if settings.show_lod {
                        (LOD_COLOURS[level], BillboardMode::Tint)
                    } else if settings.show_shadow {
                        ([1.0; 3], BillboardMode::SunFactor)
                    } else {
                        (
                            [data.tint[0], data.tint[1], data.tint[2]],
                            BillboardMode::Images,
                        )
                    };
                    let mut emit = |part: Mat4, lvl: Level, shade: Shade, stats: &mut BtfStats| {
                        let shade = if settings.vcm_sky {
                            shade
                        } else {
                            shade.without_sky()
                        };
                        self.push(
                            &mut scratch,
                            m * part,
                            &parts.sets[lvl],
                            cam,
                            forward,
                            to_sun,
                            frustum,
                            settings,
                            tint,
                            opacity,
                            lvl,
                            &shade,
                            stats,
                        );
                    };
                    let shading = vcm.map(|v| v.for_tree(t as usize, sp, &m, &parts.frames));
                    let trunk_twig = |k: usize, tw: &Mat4| {
                        shading.as_ref().map_or(Shade::NONE, |s| {
                            s.trunk_twig(parts.branch_twigs.len() + k, tw)
                        })
                    };
                    match level {
                        Level::Tree => {
                            let shade = shading.as_ref().map_or(Shade::NONE, |s| s.tree());
                            emit(Mat4::IDENTITY, Level::Tree, shade, &mut out.stats)
                        }
                        Level::Branch => {
                            geometry = geometry.max(Some(1));
                            for (i, b) in parts.branches.iter().enumerate() {
                                let shade =
                                    shading.as_ref().map_or(Shade::NONE, |s| s.branch(i, b));
                                emit(*b, Level::Branch, shade, &mut out.stats);
                            }
                            for (k, tw) in parts.trunk_twigs.iter().enumerate() {
                                emit(*tw, Level::Twig, trunk_twig(k, tw), &mut out.stats);
                            }
                        }
                        Level::Twig => {
                            geometry = Some(2);
                            for (i, b) in parts.branches.iter().enumerate() {
                                match &shading {
                                    Some(s) => {
                                        s.branch_twigs(i, b, &parts.branch_twigs, |j, shade| {
                                            emit(
                                                *b * parts.branch_twigs[j],
                                                Level::Twig,
                                                shade,
                                                &mut out.stats,
                                            )
                                        })
                                    }
                                    None => {
                                        for tw in &parts.branch_twigs {
                                            emit(
                                                *b * *tw,
                                                Level::Twig,
                                                Shade::NONE,
                                                &mut out.stats,
                                            );
                                        }
                                    }
                                }
                            }
                            for (k, tw) in parts.trunk_twigs.iter().enumerate() {
                                emit(*tw, Level::Twig, trunk_twig(k, tw), &mut out.stats);
                            }
                        }
                    }
                }
                // The finest level drawn decides which parts are geometry.
                match geometry {
                    Some(1) => out.trunk_only[sp].push(t),
                    Some(2) => out.trunk_and_limbs[sp].push(t),
                    _ => {}
                }
            }
        }
        // Back to front.
        scratch.sort_by(|a, b| b.0.total_cmp(&a.0));
        if scratch.len() > self.max_capacity {
            out.stats.dropped = (scratch.len() - self.max_capacity) as u32;
            // Keep the nearest ones: they matter most.
            scratch.drain(..scratch.len() - self.max_capacity);
        }
        if scratch.len() > self.capacity {
            self.capacity = (scratch.len() * 3 / 2).min(self.max_capacity);
            self.billboards = billboard_buffer(ctx, self.capacity);
            self.bind_group = make_bind_group(
                ctx,
                &self.layout,
                &self.billboards,
                &self.view_axes,
                &self.texture_view,
                &self.sampler,
            );
        }
        let data: Vec<BillboardGpu> = scratch.iter().map(|(_, b)| *b).collect();
        if !data.is_empty() {
            ctx.queue
                .write_buffer(&self.billboards, 0, bytemuck::cast_slice(&data));
        }
        out.billboards = data.len() as u32;
        self.scratch = scratch;
        out
    }

    #[allow(clippy::too_many_arguments)]
    fn push(
        &self,
        out: &mut Vec<(f32, BillboardGpu)>,
        m: Mat4,
        set: &SetInfo,
        cam: Vec3,
        forward: Vec3,
        to_sun: Vec3,
        frustum: &Frustum,
        settings: &BtfSettings,
        tint: ([f32; 3], BillboardMode),
        opacity: f32,
        level: Level,
        shade: &Shade,
        stats: &mut BtfStats,
    ) {
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
        if !frustum.intersects(&sphere_box) {
            return;
        }
        let rot = Mat3::from_mat4(m) * (1.0 / scale);
        let to_object = rot.transpose();
        let v_obj = to_object * (cam - center).normalize_or(Vec3::Y);
        let l_obj = to_object * to_sun;
        let mut vb = self.views.blend(v_obj);
        vb.cull(settings.weight_threshold);
        let mut lb = self.lights.blend(l_obj);
        lb.cull(settings.weight_threshold);
        let lights_used = lb.weight.iter().filter(|&&w| w > 0.0).count() as u64;
        let views_used = vb.weight.iter().filter(|&&w| w > 0.0).count() as u64;
        let fetches = views_used * (lights_used + 1);
        stats.images_sampled += fetches;
        stats.fetches_saved += 12 - fetches.min(12);
        stats.billboards[level] += 1;
        let depth = (center - cam).dot(forward);
        let base = BillboardGpu {
            center: center.to_array(),
            radius,
            opacity,
            view_index: vb.index,
            layer_base: set.layer_base,
            light_index: lb.index,
            light_count: self.lights.len() as u32,
            view_weight: vb.weight,
            view_count: self.views.len() as u32,
            light_weight: lb.weight,
            tint: tint.0,
            mode: tint.1 as u32,
            ..NO_SHADE
        }
        .shade(shade, set);
        // The quad faces the eye in both modes; with crossed planes it only bounds the
        // three planes, one facing each sampled view, which the fragment shader intersects.
        let (r, u) = billboard_axes(v_obj);
        let bb = BillboardGpu {
            plane_right: (rot * r).normalize_or(Vec3::X).to_array(),
            plane_up: (rot * u).normalize_or(Vec3::Y).to_array(),
            obj_right: r.to_array(),
            obj_up: u.to_array(),
            planes: match settings.planes {
                PlaneMode::Single => 1,
                PlaneMode::Crossed => 3,
            },
            ..base
        };
        out.push((depth, bb));
    }

    /// The frame's draws in the main pass: the trunks (and limbs) of the trees drawn at the
    /// finer levels as geometry (`runs`: trunk only, then trunk and limbs; the terrain with
    /// the first when asked), then every billboard in one instanced draw, back to front.
    #[allow(clippy::too_many_arguments)]
    pub(crate) fn draw_main(
        &self,
        pass: &mut wgpu::RenderPass<'_>,
        world: &WorldGpu,
        runs: &[Vec<TreeRun>],
        pipes: &ColorPipelines,
        pipeline: Option<&wgpu::RenderPipeline>,
        bf: &BtfFrame,
        terrain: bool,
        stats: &mut FrameStats,
    ) {
        let (t0, _, c0) = world.draw(pass, &runs[0], Some(pipes), terrain, &[PartKind::Trunk]);
        let (t1, _, c1) = world.draw(
            pass,
            &runs[1],
            Some(pipes),
            false,
            &[PartKind::Trunk, PartKind::Limbs],
        );
        stats.triangles = t0 + t1 + 2 * u64::from(bf.billboards);
        stats.trees_drawn = bf.stats.trees_per_level.iter().sum();
        stats.draw_calls += c0 + c1;
        if let Some(pipeline) = pipeline
            && bf.billboards > 0
        {
            pass.set_pipeline(pipeline);
            pass.set_bind_group(1, &self.bind_group, &[]);
            pass.draw(0..6, 0..bf.billboards);
            stats.draw_calls += 1;
        }
        stats.btf = Some(bf.stats);
    }

    /// Every tree's tree-level billboard as the sun sees it (for the ground alpha shadow
    /// map). Returns how many were uploaded.
    pub fn prepare_sun(&mut self, ctx: &GpuContext, world: &WorldGpu, to_sun: Vec3) -> u32 {
        let mut out = Vec::with_capacity(world.tree_data.len());
        for (i, data) in world.tree_data.iter().enumerate() {
            let Some(parts) = self.species.get(world.tree_species[i] as usize) else {
                continue;
            };
            let m = Mat4::from_cols_array_2d(&data.model);
            let scale = m.x_axis.truncate().length();
            if !(scale > 0.0 && scale.is_finite()) {
                continue;
            }
            let set = &parts.sets.tree;
            let rot = Mat3::from_mat4(m) * (1.0 / scale);
            let to_object = rot.transpose();
            let v_obj = to_object * to_sun;
            let vb = self.views.blend(v_obj);
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
                view_count: self.views.len() as u32,
                tint: [1.0; 3],
                ..NO_SHADE
            });
        }
        out.truncate(self.sun_capacity);
        if !out.is_empty() {
            ctx.queue
                .write_buffer(&self.sun_billboards, 0, bytemuck::cast_slice(&out));
        }
        out.len() as u32
    }

    /// The opacity pipeline of the ground alpha shadow map.
    pub fn opacity_pipeline(
        &mut self,
        device: &wgpu::Device,
        light_frame_layout: &wgpu::BindGroupLayout,
    ) -> &wgpu::RenderPipeline {
        let layout = &self.layout;
        self.opacity_pipeline
            .get_or_insert_with(|| build_opacity_pipeline(device, light_frame_layout, layout))
    }

    pub fn sun_bind_group(&self) -> &wgpu::BindGroup {
        &self.sun_bind_group
    }

    pub fn pipeline(
        &mut self,
        device: &wgpu::Device,
        frame_layout: &wgpu::BindGroupLayout,
        format: wgpu::TextureFormat,
    ) -> &wgpu::RenderPipeline {
        let layout = &self.layout;
        self.pipelines
            .entry(format)
            .or_insert_with(|| build_pipeline(device, frame_layout, layout, format))
    }

    pub fn bind_group(&self) -> &wgpu::BindGroup {
        &self.bind_group
    }

    /// Billboard-frame facts per species and level (centre, radius), for tests and tools.
    pub fn texel_sizes(&self, species: usize) -> Option<LevelTexels> {
        self.species.get(species).map(|s| s.texels)
    }
}

fn storage_entry(binding: u32, visibility: wgpu::ShaderStages) -> wgpu::BindGroupLayoutEntry {
    wgpu::BindGroupLayoutEntry {
        binding,
        visibility,
        ty: wgpu::BindingType::Buffer {
            ty: wgpu::BufferBindingType::Storage { read_only: true },
            has_dynamic_offset: false,
            min_binding_size: None,
        },
        count: None,
    }
}

fn billboard_buffer(ctx: &GpuContext, capacity: usize) -> wgpu::Buffer {
    ctx.device.create_buffer(&wgpu::BufferDescriptor {
        label: Some("btf billboards"),
        size: (capacity.max(1) * std::mem::size_of::<BillboardGpu>()) as u64,
        usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST,
        mapped_at_creation: false,
    })
}

fn make_bind_group(
    ctx: &GpuContext,
    layout: &wgpu::BindGroupLayout,
    billboards: &wgpu::Buffer,
    view_axes: &wgpu::Buffer,
    view: &wgpu::TextureView,
    sampler: &wgpu::Sampler,
) -> wgpu::BindGroup {
    ctx.device.create_bind_group(&wgpu::BindGroupDescriptor {
        label: Some("btf"),
        layout,
        entries: &[
            wgpu::BindGroupEntry {
                binding: 0,
                resource: billboards.as_entire_binding(),
            },
            wgpu::BindGroupEntry {
                binding: 1,
                resource: view_axes.as_entire_binding(),
            },
            wgpu::BindGroupEntry {
                binding: 2,
                resource: wgpu::BindingResource::TextureView(view),
            },
            wgpu::BindGroupEntry {
                binding: 3,
                resource: wgpu::BindingResource::Sampler(sampler),
            },
        ],
    })
}

/// Uploads one image and its mip chain (box-filtered in linear light) to `layer`.
/// Returns the bytes uploaded.
fn upload_layer(
    ctx: &GpuContext,
    texture: &wgpu::Texture,
    layer: u32,
    res: u32,
    rgba: &[u8],
    mips: u32,
) -> u64 {
    let Some(mut img) = image::RgbaImage::from_raw(res, res, rgba.to_vec()) else {
        return 0;
    };
    let mut bytes = 0u64;
    for level in 0..mips {
        let (w, h) = img.dimensions();
        ctx.queue.write_texture(
            wgpu::TexelCopyTextureInfo {
                texture,
                mip_level: level,
                origin: wgpu::Origin3d {
                    x: 0,
                    y: 0,
                    z: layer,
                },
                aspect: wgpu::TextureAspect::All,
            },
            img.as_raw(),
            wgpu::TexelCopyBufferLayout {
                offset: 0,
                bytes_per_row: Some(4 * w),
                rows_per_image: Some(h),
            },
            wgpu::Extent3d {
                width: w,
                height: h,
                depth_or_array_layers: 1,
            },
        );
        bytes += u64::from(4 * w * h);
        if w > 1 {
            img = crate::render::target::downsample(&img, 2);
        }
    }
    bytes
}

fn build_opacity_pipeline(
    device: &wgpu::Device,
    frame_layout: &wgpu::BindGroupLayout,
    btf_layout: &wgpu::BindGroupLayout,
) -> wgpu::RenderPipeline {
    // dst = dst * (1 - alpha): transmittance multiplies.
    let transmit = wgpu::BlendComponent {
        src_factor: wgpu::BlendFactor::Zero,
        dst_factor: wgpu::BlendFactor::OneMinusSrcAlpha,
        operation: wgpu::BlendOperation::Add,
    };
    billboard_pipeline(
        device,
        [frame_layout, btf_layout],
        ("ground_map.wgsl", crate::render::shaders::ground_map()),
        "fs_opacity",
        crate::render::GROUND_FORMAT,
        transmit,
        (crate::render::SHADOW_FORMAT, wgpu::CompareFunction::Less),
    )
}

fn build_pipeline(
    device: &wgpu::Device,
    frame_layout: &wgpu::BindGroupLayout,
    btf_layout: &wgpu::BindGroupLayout,
    format: wgpu::TextureFormat,
) -> wgpu::RenderPipeline {
    // Premultiplied "over": T = M + (1 - M_alpha) T0.
    let over = wgpu::BlendComponent {
        src_factor: wgpu::BlendFactor::One,
        dst_factor: wgpu::BlendFactor::OneMinusSrcAlpha,
        operation: wgpu::BlendOperation::Add,
    };
    // Reversed Z in the main view.
    billboard_pipeline(
        device,
        [frame_layout, btf_layout],
        ("btf.wgsl", crate::render::shaders::btf()),
        "fs_billboard",
        format,
        over,
        (crate::render::DEPTH_FORMAT, wgpu::CompareFunction::Greater),
    )
}

/// A pipeline drawing the billboards of `billboard.wgsl` with `fragment` of the module
/// `source` (named, source), blended by `blend`,
/// depth-tested (never written) against `depth`.
fn billboard_pipeline(
    device: &wgpu::Device,
    layouts: [&wgpu::BindGroupLayout; 2],
    source: (&str, String),
    fragment: &str,
    format: wgpu::TextureFormat,
    blend: wgpu::BlendComponent,
    depth: (wgpu::TextureFormat, wgpu::CompareFunction),
) -> wgpu::RenderPipeline {
    let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
        label: Some(source.0),
        source: wgpu::ShaderSource::Wgsl(source.1.into()),
    });
    let layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
        label: Some(fragment),
        bind_group_layouts: &[Some(layouts[0]), Some(layouts[1])],
        immediate_size: 0,
    });
    device.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
        label: Some(fragment),
        layout: Some(&layout),
        vertex: wgpu::VertexState {
            module: &module,
            entry_point: Some("vs_billboard"),
            compilation_options: Default::default(),
            buffers: &[],
        },
        primitive: wgpu::PrimitiveState {
            cull_mode: None,
            ..Default::default()
        },
        depth_stencil: Some(wgpu::DepthStencilState {
            format: depth.0,
            depth_write_enabled: Some(false),
            depth_compare: Some(depth.1),
            stencil: Default::default(),
            bias: Default::default(),
        }),
        multisample: Default::default(),
        fragment: Some(wgpu::FragmentState {
            module: &module,
            entry_point: Some(fragment),
            compilation_options: Default::default(),
            targets: &[Some(wgpu::ColorTargetState {
                format,
                blend: Some(wgpu::BlendState {
                    color: blend,
                    alpha: blend,
                }),
                write_mask: wgpu::ColorWrites::ALL,
            })],
        }),
        multiview_mask: None,
        cache: None,
    })
}
