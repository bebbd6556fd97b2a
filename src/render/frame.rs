//! The plain description of one frame (camera, sun, sky, method, settings) that callers hand
//! to the render core, and the statistics it hands back.

use glam::Vec3;

use super::camera::Camera;
use crate::scene::{Scene, sun_direction};

use super::method::btf::settings::{BtfSettings, BtfStats};
pub use super::method::kind::Method;
use super::method::texel::settings::{TexelSettings, TexelStats};

/// The sun: a directional light.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Sun {
    /// Degrees from +Z (north) towards +X (east).
    pub azimuth_deg: f32,
    /// Degrees above the horizon; at or below 0 the sun gives no direct light.
    pub elevation_deg: f32,
    pub color: Vec3,
    pub intensity: f32,
}

impl Sun {
    /// Unit vector from the ground towards the sun.
    pub fn direction(&self) -> Vec3 {
        sun_direction(self.azimuth_deg, self.elevation_deg)
    }

    /// A sun shining from `to_sun` (a unit vector towards it).
    pub fn from_direction(to_sun: Vec3, color: Vec3, intensity: f32) -> Self {
        let d = to_sun.normalize_or(Vec3::Y);
        Self {
            azimuth_deg: d.x.atan2(d.z).to_degrees().rem_euclid(360.0),
            elevation_deg: d.y.clamp(-1.0, 1.0).asin().to_degrees(),
            color,
            intensity,
        }
    }

    /// Radiance scale of the direct term (zero once the sun has set).
    pub fn radiance(&self) -> Vec3 {
        if self.elevation_deg <= 0.0 {
            Vec3::ZERO
        } else {
            self.color * self.intensity
        }
    }
}

/// Hemispherical sky light.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Sky {
    pub color: Vec3,
    pub ground_color: Vec3,
    pub intensity: f32,
}

/// What surrounds what is drawn.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Stage {
    /// The scene: sky behind, terrain drawn, no sun below the horizon.
    #[default]
    World,
    /// One object alone, as the bake photographs it: transparent background, no terrain,
    /// light from any direction (object frames are turned every way), one shadow map
    /// fitted around the object.
    Studio,
}

/// What a [`Stage::Studio`] frame draws of the `geometry` method: its lit picture, or one
/// of the maps the impostor bake stores. (A world frame is always lit.)
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub enum StudioOutput {
    /// The lit picture.
    #[default]
    Lit,
    /// Each surface's unlit colour (its albedo), alpha 1 where something is drawn.
    Albedo,
    /// Each surface's normal (the world frame, which is the object's in the studio),
    /// facing the camera for two-sided leaves, as `n * 0.5 + 0.5` in the target's bytes as
    /// they are (the shader undoes the sRGB target's encoding); in alpha its view depth,
    /// `near` (m) -> 0 to `far` -> 1, clamped.
    NormalDepth { near: f32, far: f32 },
}

/// Sun shadows by cascaded shadow maps.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ShadowSettings {
    pub enabled: bool,
    /// Side of each cascade's depth map, in texels.
    pub map_size: u32,
    /// View distance (m) beyond which nothing receives sun shadows.
    pub distance: f32,
}

impl Default for ShadowSettings {
    fn default() -> Self {
        Self {
            enabled: true,
            map_size: 2048,
            distance: 600.0,
        }
    }
}

/// The `geometry` method as the reference every accuracy figure is measured against: the
/// sky light hidden where trees and hills hide the sky (a sky visibility volume), sun
/// shadows from larger cascade maps reaching the whole scene, and each tree's shadows on
/// itself from a map of its own (src/render/self_shadow.rs).
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct Reference {
    /// Directions over the sky hemisphere whose depth maps give the sky visibility.
    pub sky_directions: u32,
    /// Side (texels) of each sun cascade's map (at least the frame's own).
    pub sun_map_size: u32,
    /// Side (texels) of each tree's own sun map; 0: none, the cascades shade the trees
    /// themselves too (the reference before them).
    pub self_map_size: u32,
}

impl Default for Reference {
    fn default() -> Self {
        Self {
            sky_directions: super::consts::SKY_DIRECTIONS,
            sun_map_size: 4096,
            self_map_size: super::consts::SELF_MAP_SIZE,
        }
    }
}

/// Everything that may change from one frame to the next.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FrameDesc {
    pub camera: Camera,
    pub sun: Sun,
    pub sky: Sky,
    pub method: Method,
    pub shadows: ShadowSettings,
    /// Fog density per metre (0 = none): far trees fade towards the horizon colour.
    pub fog_density: f32,
    pub exposure: f32,
    pub stage: Stage,
    /// Knobs of the `btf` method.
    pub btf: BtfSettings,
    /// Knobs of the `texel` method.
    pub texel: TexelSettings,
    /// The `impostor` method's knobs.
    pub impostor: super::method::impostor::ImpostorSettings,
    /// The `surfel` method's knobs.
    pub surfel: super::method::surfel::SurfelSettings,
    /// Draw the trees (off: terrain and sky only, e.g. while a bake is running).
    pub trees: bool,
    /// Image-based methods: soft tree shadows on the ground from an alpha shadow map, and
    /// the terrain's own shadows from a depth map of the terrain, both seen from the sun
    /// and rebuilt only when it moves. (The geometry method always has both.)
    pub ground_shadows: bool,
    /// Image-based methods: the terrain (and `hybrid`'s geometry trees) see the sky only
    /// where the trees leave it open, from the sky visibility volume the reference uses,
    /// when the renderer has one ([`super::Renderer::prepare_sky`]).
    pub ground_sky: bool,
    /// Image-based methods: the terrain's chunks are drawn as coarse as keeps their height
    /// error below this many pixels on screen, and only those in view; a coarse chunk's
    /// fragments take the full grid's colour, normal and height from the terrain's maps
    /// ([`super::terrain_maps`]). 0: every chunk at full detail, as `geometry` draws it.
    pub terrain_px: f32,
    /// The user is moving the sun right now (a drag in progress): the ground shadow maps
    /// are rebuilt at a reduced resolution while it lasts, and at full resolution on the
    /// first frame after it ends.
    pub sun_held: bool,
    /// Draw `geometry` as the reference (other methods ignore it).
    pub reference: Option<Reference>,
    /// The fraction of the window the viewer draws the 3D view at (the render core draws
    /// at whatever size it is given; the viewer applies this).
    pub render_scale: super::scale::RenderScale,
    /// `geometry` only: draw each pixel's class instead of its colour (sky black, ground
    /// red, trees nearer than [`NEAR_TREE_M`] green, farther ones blue), so that an error
    /// map can be split by what each pixel shows.
    pub pixel_classes: bool,
    /// Draw the overdraw view over the frame instead of its picture: fragments shaded, or
    /// images read, per pixel ([`super::overdraw`]); `None`: the picture.
    pub overdraw: Option<super::overdraw::OverdrawView>,
    /// What a studio frame draws (the world's frames ignore it).
    pub studio_output: StudioOutput,
}

/// Where the pixel classes' near trees end (m).
pub const NEAR_TREE_M: f32 = 100.0;

impl FrameDesc {
    /// The reference this frame is drawn as: its [`Self::reference`] when the method is
    /// `geometry` (other methods ignore it).
    pub fn reference_drawn(&self) -> Option<Reference> {
        self.reference.filter(|_| self.method == Method::Geometry)
    }

    /// The frame a scene file describes: its start camera, sun and sky.
    pub fn from_scene(scene: &Scene) -> Self {
        let c = &scene.camera;
        Self {
            camera: Camera::look_at(Vec3::from(c.position), Vec3::from(c.look_at), c.fov_deg),
            sun: Sun {
                azimuth_deg: scene.sun.azimuth,
                elevation_deg: scene.sun.elevation,
                color: Vec3::from(scene.sun.color),
                intensity: scene.sun.intensity,
            },
            sky: Sky {
                color: Vec3::from(scene.sky.color),
                ground_color: Vec3::from(scene.sky.ground_color),
                intensity: scene.sky.intensity,
            },
            method: Method::Geometry,
            shadows: ShadowSettings::default(),
            fog_density: 0.0006,
            exposure: 1.0,
            stage: Stage::World,
            btf: BtfSettings::from_scene(scene),
            texel: Default::default(),
            impostor: Default::default(),
            surfel: Default::default(),
            trees: true,
            ground_shadows: true,
            ground_sky: true,
            terrain_px: 0.5,
            sun_held: false,
            reference: None,
            render_scale: Default::default(),
            pixel_classes: false,
            overdraw: None,
            studio_output: StudioOutput::Lit,
        }
    }
}

/// What the render core did for one frame.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize)]
pub struct FrameStats {
    pub width: u32,
    pub height: u32,
    /// Trees that passed frustum culling and were drawn in the main view.
    pub trees_drawn: u32,
    /// Trees drawn into the shadow maps (summed over cascades).
    pub shadow_casters: u32,
    /// Triangles drawn in the main view (terrain included).
    pub triangles: u64,
    /// Triangles drawn into the shadow maps.
    pub shadow_triangles: u64,
    pub draw_calls: u32,
    /// GPU time of the frame from timestamp queries, when the adapter has them and the
    /// caller asked for a blocking measurement.
    pub gpu_ms: Option<f64>,
    /// The same frame's GPU time per pass, in the order they ran (empty where `gpu_ms` is
    /// None); they add up to `gpu_ms` but for the gaps between passes.
    pub passes: crate::render::timing::PassTimes,
    /// With the overdraw view on, in a measured frame: fragments shaded and images read
    /// per pixel, averaged over the image.
    pub overdraw: Option<super::overdraw::OverdrawMeans>,
    /// CPU time of culling and the method's prepare step (levels, expansion, sorting,
    /// shading factors, instance lists), in ms; sun-dependent work is not included.
    pub prepare_ms: f64,
    /// What the `btf` method did (absent for other methods).
    pub btf: Option<BtfStats>,
    /// What the `texel` method did (absent for other methods).
    pub texel: Option<TexelStats>,
    /// What the `impostor` method did (absent for other methods).
    pub impostor: Option<super::method::impostor::ImpostorStats>,
    /// What the `surfel` method did (absent for other methods).
    pub surfel: Option<super::method::surfel::SurfelStats>,
    /// Sun-dependent state was rebuilt this frame (the sun moved): the trees' VCM reads
    /// and the ground alpha shadow map.
    pub sun_update: bool,
    /// What that cost (ms): the VCM reads on the CPU plus the ground map pass, waited for
    /// on the GPU when the frame is measured.
    pub sun_update_ms: Option<f64>,
    /// Side (texels) of the ground shadow maps the frame was shaded with, when it had them.
    pub ground_map_size: Option<u32>,
}
