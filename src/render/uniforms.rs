//! The uniform block every pass's shaders see (`struct Frame` in `shaders/frame.wgsl`),
//! filled from a frame's description.

use glam::{Mat4, Vec3};

use super::frame::{FrameDesc, Method, Stage, StudioOutput};
use super::shadow::Cascades;

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
    /// The overdraw view: on (1) or off (0), the target's width and height, what the heat
    /// map shows ([`super::overdraw::OverdrawView::index`]).
    pub overdraw: [u32; 4],
    /// What a studio frame draws: 0 its lit picture, 1 albedo, 2 normal and depth
    /// ([`StudioOutput`]; 0 in the world).
    pub studio_output: u32,
    /// The view depth (m) the studio's depth map reads 0 at, and 1 / the depth it reads 1
    /// further on.
    pub studio_depth_near: f32,
    pub studio_depth_scale: f32,
    /// Fills the block to a multiple of 16 bytes.
    pub studio_pad: u32,
}

/// The frame's sun, sky and ground light (colour x intensity; the sun 0 below the horizon
/// except in the studio).
pub fn frame_lights(frame: &FrameDesc) -> [Vec3; 3] {
    let sun = if frame.stage == Stage::Studio {
        frame.sun.color * frame.sun.intensity
    } else {
        frame.sun.radiance()
    };
    let sky = frame.sky.color * frame.sky.intensity;
    let ground = frame.sky.ground_color * frame.sky.intensity;
    [sun, sky, ground]
}

impl FrameUniforms {
    /// Uniforms for the main view.
    pub fn new(frame: &FrameDesc, aspect: f32, cascades: &Cascades) -> Self {
        let vp = frame.camera.view_projection(aspect);
        let studio = frame.stage == Stage::Studio;
        let [sun, sky, ground] = frame_lights(frame);
        let horizon = frame.sky.color.lerp(Vec3::new(0.85, 0.88, 0.92), 0.55);
        let shadows_on = frame.shadows.enabled && (studio || frame.sun.elevation_deg > 0.0);
        let (studio_output, depth_near, depth_far) = match frame.studio_output {
            _ if !studio => (0, 0.0, 1.0),
            StudioOutput::Lit => (0, 0.0, 1.0),
            StudioOutput::Albedo => (1, 0.0, 1.0),
            StudioOutput::NormalDepth { near, far } => (2, near, far),
        };
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
            overdraw: [0; 4],
            studio_output,
            studio_depth_near: depth_near,
            studio_depth_scale: 1.0 / (depth_far - depth_near).max(1e-6),
            studio_pad: 0,
        }
    }

    /// The same block for a shadow pass: only `view_proj` matters there.
    pub fn for_light(mut self, light_view_proj: Mat4) -> Self {
        self.view_proj = light_view_proj.to_cols_array_2d();
        self
    }
}
