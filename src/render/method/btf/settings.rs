//! The knobs of the `btf` method and what it reports per frame.

use crate::model::{Level, PerLevel};
use crate::scene::Scene;

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
    /// How far the blend of the 3 nearest light samples is brightened towards the sun's
    /// strength, 0..1: the weights are scaled by `DirectionSet::light_gain` to this power
    /// (blended images are lit as by a light shorter than the sun, by up to 1/sqrt(3)
    /// between 6 samples). 0 = the plain blend; 1 = the whole gain, right for a surface
    /// lit linearly in the light direction but too bright in dense stands; the default
    /// [`LIGHT_GAIN`] is the measured compromise.
    pub light_gain: f32,
    /// Build the billboards of the trees drawn at the tree level alone on the GPU (compute
    /// passes), leaving the CPU the near trees only; off: the CPU prepares every tree.
    pub gpu_far: bool,
    /// With `gpu_far`: the near trees' billboards are expanded on the GPU too (the CPU
    /// choosing their levels and cross-fades only); off: the CPU builds them.
    pub gpu_near: bool,
    /// Tree-level billboards read their 3 lights' images blended once per sun and yaw bin
    /// (`light_blend`): 9 image reads a fragment instead of 15.
    pub light_blend: bool,
    /// Past the distance where a typical crown is narrower than `canopy_px` pixels, the
    /// forest is drawn as the far canopy (needs `gpu_far`).
    pub far_canopy: bool,
    pub canopy_px: f32,
    /// `hybrid`: where a tree's tree-level texels project below this many pixels, its
    /// tree level is drawn as the bake's octahedral impostor (when it has them) instead of
    /// BTF billboards, cross-faded over the last `lod_fade` fraction below it; 0: never,
    /// `lod_scale` or more: wherever the tree level is drawn. Above 0 every tree is
    /// prepared on the CPU (`gpu_far` and the far canopy are not used).
    pub impostor_px: f32,
    /// The billboards are drawn front to back into the trees' layer, and where it is
    /// opaque the farther ones are skipped ([`crate::render::layer`]); off: back to front
    /// over the frame.
    pub front_to_back: bool,
    /// The billboards are composited front to back in compute, by screen tiles
    /// ([`crate::render::compositor`]), instead of rasterised.
    pub compositor: bool,
    /// With `compositor`: a pixel stops compositing where it lets through less than this
    /// (0: never).
    pub stop_below: f32,
    /// With `compositor`: layers are shaded in full while the pixel lets through more than
    /// this, behind by their heaviest view sample alone (0: all in full).
    pub full_above: f32,
}

/// The default [`BtfSettings::light_gain`]. Bench, 320x180, 3 frames, mean FLIP against
/// the reference at strengths 0 / 0.5 / 1: the default forest's overview 0.0303 / 0.0291 /
/// 0.0285, sunset 0.0899 / 0.0875 / 0.0869, walk 0.0497 / 0.0471 / 0.0458; the dense
/// stand.toml's overview 0.1295 / 0.1283 / 0.1329, sunset 0.2791 / 0.2817 / 0.2888.
pub const LIGHT_GAIN: f32 = 0.5;

/// Default [`BtfSettings::impostor_px`]: none. Measured (docs/results/hybrid.md, "hybrid with
/// impostors"), the whole tree level as impostors is faster and gains on the overview
/// flight, but costs 0.0035 mean FLIP on the walk, 0.0027 at sunset and 0.015 at the
/// default start camera, so `hybrid` keeps `btf`'s tree billboards unless asked.
pub const IMPOSTOR_PX: f32 = 0.0;

/// Default on-screen crown width (px) below which trees are drawn as the far canopy.
pub const CANOPY_PX: f32 = 4.0;

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
            light_gain: LIGHT_GAIN,
            gpu_far: true,
            gpu_near: true,
            light_blend: true,
            far_canopy: true,
            canopy_px: CANOPY_PX,
            impostor_px: IMPOSTOR_PX,
            front_to_back: false,
            compositor: false,
            stop_below: crate::render::compositor::STOP_BELOW,
            full_above: crate::render::compositor::FULL_ABOVE,
        }
    }
}

impl BtfSettings {
    /// The compositor's knobs.
    pub fn compositor_knobs(&self) -> crate::render::compositor::CompositorKnobs {
        crate::render::compositor::CompositorKnobs {
            stop_below: self.stop_below,
            full_above: self.full_above,
        }
    }

    /// The knobs a scene starts from: its `[render]` table over the defaults.
    pub fn from_scene(scene: &Scene) -> Self {
        let mut s = Self::default();
        if let Some(r) = &scene.render {
            s.lod_scale = r.lod_scale.unwrap_or(s.lod_scale);
            s.weight_threshold = r.weight_threshold.unwrap_or(s.weight_threshold);
            s.lod_fade = r.lod_fade.unwrap_or(s.lod_fade);
            s.far_canopy = r.far_canopy.unwrap_or(s.far_canopy);
            s.canopy_px = r.canopy_px.unwrap_or(s.canopy_px);
            if let Some(p) = r.planes.as_deref().and_then(PlaneMode::parse) {
                s.planes = p;
            }
        }
        s
    }

    /// What a billboard of `level` shows instead of its images, with its colour, when an
    /// overlay is on (the LOD level before the VCM sun factor); None without one.
    pub(super) fn overlay(
        &self,
        level: Level,
    ) -> Option<([f32; 3], super::billboard::BillboardMode)> {
        if self.show_lod {
            Some((LOD_COLORS[level], super::billboard::BillboardMode::Tint))
        } else if self.show_shadow {
            Some(([1.0; 3], super::billboard::BillboardMode::SunFactor))
        } else {
            None
        }
    }
}

/// Image fetches per billboard pixel without image-weight culling: 3 views x (3 lights +
/// the sky-lit and the ground-lit image).
pub const FETCHES_AT_MOST: u64 = 3 * (3 + crate::format::AMBIENT_IMAGES_PER_VIEW as u64);

/// What the `btf` method did in one frame.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize)]
pub struct BtfStats {
    /// Billboards drawn per level.
    pub billboards: PerLevel<u32>,
    /// Trees drawn at each level (by the coarser level while fading).
    pub trees_per_level: PerLevel<u32>,
    /// Trees drawn at two levels at once, cross-fading (in `hybrid`, also a twig level
    /// fading into geometry).
    pub faded_trees: u32,
    /// `hybrid`: trees drawn wholly as geometry (not in `trees_per_level`).
    pub geometry_trees: u32,
    /// Image fetches per fragment summed over billboards (views x (lights + sky + ground)).
    pub images_sampled: u64,
    /// Fetches skipped by image-weight culling or read once from the light blends, against
    /// 3 x (3 + 2) = 15 per billboard.
    pub fetches_saved: u64,
    /// Billboards that read their lights' blend (`light_blend`: 3 images a view instead of
    /// 5, 9 a fragment instead of 15).
    pub light_blended: u32,
    /// Tiles of the far canopy drawn (0: none this frame).
    pub canopy_tiles: u32,
    /// Trees in view past the far canopy's band, drawn by the canopy alone.
    pub canopy_trees: u32,
    /// Billboards left out because the instance buffer would pass the GPU's limit.
    pub dropped: u32,
    /// Of `billboards`, those built on the GPU (far trees, and near ones with `gpu_near`);
    /// their image fetches are counted there and read back with them.
    pub gpu_billboards: u32,
    /// The billboards were shaded by visibility cube maps.
    pub vcm: bool,
    /// `hybrid` with `impostor_px`: trees whose tree level is drawn as an impostor (whole,
    /// or cross-fading with a finer level's billboards or its own tree billboard).
    pub impostors: u32,
}

impl BtfStats {
    /// Adds the counts of `o` (a part of the same frame) to these.
    pub fn add(&mut self, o: &BtfStats) {
        for level in crate::model::Level::ALL {
            self.billboards[level] += o.billboards[level];
            self.trees_per_level[level] += o.trees_per_level[level];
        }
        self.faded_trees += o.faded_trees;
        self.geometry_trees += o.geometry_trees;
        self.images_sampled += o.images_sampled;
        self.fetches_saved += o.fetches_saved;
        self.light_blended += o.light_blended;
        self.canopy_tiles += o.canopy_tiles;
        self.canopy_trees += o.canopy_trees;
        self.dropped += o.dropped;
        self.gpu_billboards += o.gpu_billboards;
        self.vcm |= o.vcm;
        self.impostors += o.impostors;
    }

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

/// Colours of the 'show LOD level' overlay.
pub const LOD_COLORS: PerLevel<[f32; 3]> = PerLevel {
    twig: [0.9, 0.2, 0.15],
    branch: [0.95, 0.8, 0.1],
    tree: [0.2, 0.45, 0.95],
};

pub use crate::render::consts::GEOMETRY_COLOR;

/// The far canopy's colour in the LOD view.
pub const CANOPY_COLOR: [f32; 3] = [0.1, 0.8, 0.75];
