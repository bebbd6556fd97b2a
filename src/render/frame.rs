//! The plain description of one frame (camera, sun, sky, method, settings) that callers hand
//! to the render core, the statistics it hands back, and the uniform block the shaders see.

use glam::{Mat4, Vec3};

use super::camera::Camera;
use crate::scene::{Scene, sun_direction};

/// How the forest is drawn. Each method can draw the whole scene alone.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Method {
    /// Every leaf, needle and branch as triangles: the ground truth.
    #[default]
    Geometry,
    /// BTF billboards of the twig / main branch / tree hierarchy (needs a bake).
    Btf,
    /// One camera-facing image per tree from a single baked view and light: the floor.
    Billboard,
    /// Each tree as a volumetric texel: its baked volumes sliced parallel to the screen
    /// (needs a bake with texel volumes).
    Texel,
    /// `btf`, with a tree drawn as geometry wherever even its twig level's texels project
    /// above the LOD bound (cross-faded): no more detail than the view needs, and no less.
    Hybrid,
}

impl Method {
    pub const ALL: &'static [Method] = &[
        Method::Geometry,
        Method::Btf,
        Method::Billboard,
        Method::Texel,
        Method::Hybrid,
    ];

    pub fn name(self) -> &'static str {
        match self {
            Method::Geometry => "geometry",
            Method::Btf => "btf",
            Method::Billboard => "billboard",
            Method::Texel => "texel",
            Method::Hybrid => "hybrid",
        }
    }

    /// The method draws baked images (and needs a bake).
    pub fn needs_bake(self) -> bool {
        matches!(
            self,
            Method::Btf | Method::Billboard | Method::Texel | Method::Hybrid
        )
    }

    /// The method draws the BTF hierarchy and takes the `btf` knobs.
    pub fn is_btf(self) -> bool {
        matches!(self, Method::Btf | Method::Hybrid)
    }

    pub fn parse(s: &str) -> Option<Method> {
        Self::ALL.iter().copied().find(|m| m.name() == s)
    }
}

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
            sky_directions: super::sky_visibility::SKY_DIRECTIONS,
            sun_map_size: 4096,
            self_map_size: super::self_shadow::SELF_MAP_SIZE,
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
    pub btf: super::btf::BtfSettings,
    /// Knobs of the `texel` method.
    pub texel: super::method::texel::TexelSettings,
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
}

/// Where the pixel classes' near trees end (m).
pub const NEAR_TREE_M: f32 = 100.0;

impl FrameDesc {
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
            btf: btf_settings_of(scene),
            texel: Default::default(),
            trees: true,
            ground_shadows: true,
            ground_sky: true,
            sun_held: false,
            reference: None,
            render_scale: Default::default(),
            pixel_classes: false,
        }
    }
}

/// The `btf` knobs a scene starts from: its `[render]` table over the defaults.
pub fn btf_settings_of(scene: &Scene) -> super::btf::BtfSettings {
    let mut s = super::btf::BtfSettings::default();
    if let Some(r) = &scene.render {
        s.lod_scale = r.lod_scale.unwrap_or(s.lod_scale);
        s.weight_threshold = r.weight_threshold.unwrap_or(s.weight_threshold);
        s.lod_fade = r.lod_fade.unwrap_or(s.lod_fade);
        if let Some(p) = r.planes.as_deref().and_then(super::btf::PlaneMode::parse) {
            s.planes = p;
        }
    }
    s
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
    /// CPU time of culling and the method's prepare step (levels, expansion, sorting,
    /// shading factors, instance lists), in ms; sun-dependent work is not included.
    pub prepare_ms: f64,
    /// What the `btf` method did (absent for other methods).
    pub btf: Option<super::btf::BtfStats>,
    /// What the `texel` method did (absent for other methods).
    pub texel: Option<super::method::texel::TexelStats>,
    /// Sun-dependent state was rebuilt this frame (the sun moved): the trees' VCM reads
    /// and the ground alpha shadow map.
    pub sun_update: bool,
    /// What that cost (ms): the VCM reads on the CPU plus the ground map pass, waited for
    /// on the GPU when the frame is measured.
    pub sun_update_ms: Option<f64>,
    /// Side (texels) of the ground shadow maps the frame was shaded with, when it had them.
    pub ground_map_size: Option<u32>,
}

/// The uniform block of `frame.wgsl` (`struct Frame`), byte for byte: each `[f32; 3]` is a
/// WGSL `vec3<f32>` and the scalar after it fills its 16-byte slot (checked against the WGSL
/// by tests/gpu_layout.rs).
#[repr(C)]
#[derive(Clone, Copy, Debug, bytemuck::Pod, bytemuck::Zeroable)]
pub struct FrameUniforms {
    pub view_proj: [[f32; 4]; 4],
    pub inv_view_proj: [[f32; 4]; 4],
    /// The geometry method's shadow cascades.
    pub light_view_proj: [[[f32; 4]; 4]; 3],
    pub camera_pos: [f32; 3],
    /// Fog density per metre.
    pub fog_density: f32,
    pub camera_forward: [f32; 3],
    pub exposure: f32,
    /// Unit vector towards the sun.
    pub sun_dir: [f32; 3],
    /// 1 when sun shadows apply (cascades, or the ground depth map).
    pub shadows_on: u32,
    /// Sun colour x intensity (0 below the horizon, except in the studio).
    pub sun_color: [f32; 3],
    /// PCF radius of the cascades, in texels.
    pub pcf_radius: f32,
    pub sky_ambient: [f32; 3],
    /// Directions of the reference's sky visibility (0: the sky is never hidden).
    pub sky_vis_count: u32,
    pub ground_ambient: [f32; 3],
    /// Side of one cell of the sky visibility volume (m).
    pub sky_vis_texel_world: f32,
    pub sky_zenith: [f32; 3],
    /// 1: draw pixel classes instead of colours (see [`FrameDesc::pixel_classes`]).
    pub pixel_classes: u32,
    pub sky_horizon: [f32; 3],
    /// 1 when the cascades hold `hybrid`'s geometry trees alone, whose shadows then fall on
    /// the rest of the scene through them (they are left out of the ground alpha map).
    pub hybrid_cascades: u32,
    /// Far view depth of each cascade (m).
    pub cascade_splits: [f32; 3],
    /// One texel of a cascade's map in uv (1 / its side).
    pub cascade_texel_uv: f32,
    /// World size of one texel in each cascade.
    pub cascade_texel_world: [f32; 3],
    /// Half the side of the scene's square (m): past it (the horizon ring) the terrain
    /// depth map shades nothing; the trees' alpha map still does. 0 until they are built.
    pub ground_half: f32,
    /// The sun's view of the whole scene, for the ground shadow maps.
    pub ground_light_view_proj: [[f32; 4]; 4],
    /// 1 when the ground alpha shadow map applies.
    pub ground_alpha_on: u32,
    /// 1 when the terrain's depth from the ground pass replaces the cascades.
    pub terrain_depth_on: u32,
    /// World size of one texel of the ground maps.
    pub ground_texel_world: f32,
    /// Fraction of the ground textures' side in use.
    pub ground_uv_scale: f32,
}

impl FrameUniforms {
    /// Uniforms for the main view.
    pub fn new(frame: &FrameDesc, aspect: f32, cascades: &super::shadow::Cascades) -> Self {
        let vp = frame.camera.view_projection(aspect);
        let studio = frame.stage == Stage::Studio;
        let sun = if studio {
            frame.sun.color * frame.sun.intensity
        } else {
            frame.sun.radiance()
        };
        let sky = frame.sky.color * frame.sky.intensity;
        let ground = frame.sky.ground_color * frame.sky.intensity;
        let horizon = frame.sky.color.lerp(Vec3::new(0.85, 0.88, 0.92), 0.55);
        let shadows_on = frame.shadows.enabled && (studio || frame.sun.elevation_deg > 0.0);
        Self {
            view_proj: vp.to_cols_array_2d(),
            inv_view_proj: vp.inverse().to_cols_array_2d(),
            light_view_proj: cascades.matrices.map(|m| m.to_cols_array_2d()),
            camera_pos: frame.camera.position.to_array(),
            fog_density: frame.fog_density.max(0.0),
            camera_forward: frame.camera.forward().to_array(),
            exposure: frame.exposure,
            sun_dir: frame.sun.direction().to_array(),
            shadows_on: u32::from(shadows_on),
            sun_color: sun.to_array(),
            pcf_radius: 1.0,
            sky_ambient: sky.to_array(),
            sky_vis_count: 0,
            ground_ambient: ground.to_array(),
            sky_vis_texel_world: 0.0,
            sky_zenith: frame.sky.color.to_array(),
            pixel_classes: u32::from(frame.pixel_classes && frame.method == Method::Geometry),
            sky_horizon: horizon.to_array(),
            hybrid_cascades: 0,
            cascade_splits: cascades.splits,
            cascade_texel_uv: 1.0 / frame.shadows.map_size.max(1) as f32,
            cascade_texel_world: cascades.texel_world,
            ground_half: 0.0,
            ground_light_view_proj: Mat4::IDENTITY.to_cols_array_2d(),
            ground_alpha_on: 0,
            terrain_depth_on: 0,
            ground_texel_world: 0.0,
            ground_uv_scale: 0.0,
        }
    }

    /// The same block for a shadow pass: only `view_proj` matters there.
    pub fn for_light(mut self, light_view_proj: Mat4) -> Self {
        self.view_proj = light_view_proj.to_cols_array_2d();
        self
    }
}
