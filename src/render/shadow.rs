//! Cascaded sun shadow maps: the camera's view up to the shadow distance is cut into three
//! slices, and each gets an orthographic light matrix fitted to the slice's bounding sphere
//! (so it does not change size as the camera turns) and snapped to whole texels (so shadows
//! do not shimmer as it moves). Depth covers the whole scene, so casters outside the view
//! still cast into it.

use glam::{Mat4, Vec3};

use super::camera::Camera;
use super::frame::ShadowSettings;
use super::{GpuContext, SHADOW_FORMAT};
use crate::model::mesh::Aabb;

pub use super::consts::CASCADES;

/// Light matrices and view-depth ranges of the cascades.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Cascades {
    pub matrices: [Mat4; CASCADES],
    /// Far view depth (m) of each cascade.
    pub splits: [f32; CASCADES],
    /// World size (m) of one shadow-map texel in each cascade.
    pub texel_world: [f32; CASCADES],
}

impl Cascades {
    /// Cascades that cast nothing (shadows off, or the sun below the horizon).
    pub fn none() -> Self {
        Self {
            matrices: [Mat4::IDENTITY; CASCADES],
            splits: [0.0; CASCADES],
            texel_world: [0.0; CASCADES],
        }
    }

    pub fn fit(
        camera: &Camera,
        aspect: f32,
        to_sun: Vec3,
        settings: &ShadowSettings,
        scene: &Aabb,
    ) -> Self {
        let near = camera.near.max(0.5);
        let far = settings.distance.max(near * 2.0);
        let splits = split_depths(near, far);
        let size = settings.map_size.max(16) as f32;
        let up = if to_sun.y.abs() > 0.99 {
            Vec3::Z
        } else {
            Vec3::Y
        };
        let light_view = glam::camera::rh::view::look_to_mat4(Vec3::ZERO, -to_sun, up);
        // Depth range of the whole scene seen from the sun.
        let (mut zmin, mut zmax) = (f32::MAX, f32::MIN);
        for c in scene.corners() {
            let z = light_view.transform_point3(c).z;
            zmin = zmin.min(z);
            zmax = zmax.max(z);
        }
        let margin = 1.0;
        let (z_near, z_far) = (-zmax - margin, -zmin + margin);

        let tan_v = (0.5 * camera.fov_y_deg.to_radians()).tan();
        let tan_h = tan_v * aspect;
        let mut out = Self::none();
        let mut z0 = near;
        for (i, &z1) in splits.iter().enumerate() {
            let f = camera.forward();
            let center = camera.position + f * (0.5 * (z0 + z1));
            // Radius to the far corners (they are the furthest from the midpoint).
            let far_corner = f * z1 + camera.right() * tan_h * z1 + camera.up() * tan_v * z1;
            let near_corner = f * z0 + camera.right() * tan_h * z0 + camera.up() * tan_v * z0;
            let mid = f * (0.5 * (z0 + z1));
            let radius = (far_corner - mid)
                .length()
                .max((near_corner - mid).length());
            let texel = 2.0 * radius / size;
            let c = light_view.transform_point3(center);
            let cx = (c.x / texel).floor() * texel;
            let cy = (c.y / texel).floor() * texel;
            let proj = glam::camera::rh::proj::directx::orthographic(
                cx - radius,
                cx + radius,
                cy - radius,
                cy + radius,
                z_near,
                z_far,
            );
            out.matrices[i] = proj * light_view;
            out.splits[i] = z1;
            out.texel_world[i] = texel;
            z0 = z1;
        }
        out
    }
}

impl Cascades {
    /// One map covering a sphere (the bake's studio: every pixel uses cascade 0).
    pub fn fit_sphere(to_sun: Vec3, center: Vec3, radius: f32, map_size: u32) -> Self {
        Self::fit_sphere_reaching(to_sun, center, radius, radius, map_size)
    }

    /// [`Self::fit_sphere`], with the map's depth reaching `below` metres past the sphere's
    /// centre away from the sun (where its shadows may fall), at least the radius.
    pub fn fit_sphere_reaching(
        to_sun: Vec3,
        center: Vec3,
        radius: f32,
        below: f32,
        map_size: u32,
    ) -> Self {
        let up = if to_sun.y.abs() > 0.99 {
            Vec3::Z
        } else {
            Vec3::Y
        };
        let r = radius.max(1e-3);
        let depth = 2.0 * r + below.max(r);
        let view = glam::camera::rh::view::look_to_mat4(center + to_sun * 2.0 * r, -to_sun, up);
        let proj = glam::camera::rh::proj::directx::orthographic(-r, r, -r, r, 0.0, depth);
        let m = proj * view;
        Self {
            matrices: [m; CASCADES],
            splits: [f32::MAX; CASCADES],
            texel_world: [2.0 * r / map_size.max(16) as f32; CASCADES],
        }
    }
}

/// Split depths between `near` and `far`: a blend of logarithmic and uniform splits
/// (the "practical split scheme", weight 0.75 on the logarithmic one).
pub fn split_depths(near: f32, far: f32) -> [f32; CASCADES] {
    let lambda = 0.75;
    let mut out = [far; CASCADES];
    for (i, o) in out.iter_mut().enumerate().take(CASCADES - 1) {
        let t = (i + 1) as f32 / CASCADES as f32;
        let log = near * (far / near).powf(t);
        let uni = near + (far - near) * t;
        *o = lambda * log + (1.0 - lambda) * uni;
    }
    out
}

/// The cascades' side for a frame at knob `map_size`, the side held now (`held`) and the
/// frames in a row that drew nothing into them (`idle`, this one included): the knob's
/// side while anything casts, a placeholder of [`IDLE_CASCADE_SIDE`] once nothing has for
/// [`IDLE_CASCADE_FRAMES`] frames. Clear maps shade everything lit at any size; the
/// image-based methods cast their trees' shadows through the ground maps, so their
/// cascades hold nothing and need not take 3 x 2048² x 4 bytes (50 MB).
pub fn cascade_side(map_size: u32, held: Option<u32>, idle: u32) -> u32 {
    if idle == 0 {
        map_size
    } else if idle >= IDLE_CASCADE_FRAMES {
        IDLE_CASCADE_SIDE
    } else {
        held.unwrap_or(IDLE_CASCADE_SIDE)
    }
}

/// Side of the cascades' maps while nothing is drawn into them.
pub const IDLE_CASCADE_SIDE: u32 = 16;

/// Frames in a row without casters before the cascades' maps shrink to the placeholder,
/// so that a method whose casters come and go (`hybrid`'s geometry trees) does not make
/// them again every other frame.
pub const IDLE_CASCADE_FRAMES: u32 = 30;

/// The cascades' depth maps: one texture array, a layer per cascade.
pub struct CascadeMaps {
    /// Side of each layer, in texels.
    pub size: u32,
    /// The whole array, as the colour passes sample it.
    pub array_view: wgpu::TextureView,
    /// One view per cascade, to render into.
    pub layer_views: Vec<wgpu::TextureView>,
}

impl CascadeMaps {
    pub fn new(ctx: &GpuContext, size: u32) -> crate::Result<Self> {
        let (array_view, layer_views) =
            layered_target(ctx, "shadow cascades", size, CASCADES as u32, SHADOW_FORMAT)?;
        Ok(Self {
            size,
            array_view,
            layer_views,
        })
    }
}

/// A square array texture of `layers` layers, `size` texels a side, drawn into a layer at a
/// time and sampled whole: its whole view and one view per layer.
pub(crate) fn layered_target(
    ctx: &GpuContext,
    label: &str,
    size: u32,
    layers: u32,
    format: wgpu::TextureFormat,
) -> crate::Result<(wgpu::TextureView, Vec<wgpu::TextureView>)> {
    let texture = ctx.checked(&format!("allocating the {label}"), || {
        super::pipelines::target_texture(
            &ctx.device,
            label,
            glam::UVec3::new(size, size, layers),
            format,
            wgpu::TextureUsages::RENDER_ATTACHMENT | wgpu::TextureUsages::TEXTURE_BINDING,
        )
    })?;
    let array = texture.create_view(&wgpu::TextureViewDescriptor {
        dimension: Some(wgpu::TextureViewDimension::D2Array),
        ..Default::default()
    });
    let views = (0..layers)
        .map(|i| {
            texture.create_view(&wgpu::TextureViewDescriptor {
                dimension: Some(wgpu::TextureViewDimension::D2),
                base_array_layer: i,
                array_layer_count: Some(1),
                ..Default::default()
            })
        })
        .collect();
    Ok((array, views))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cascades_shrink_only_after_a_while_without_casters_and_grow_at_once() {
        // The first frame without casters gets the placeholder; one with them the knob's.
        assert_eq!(cascade_side(2048, None, 1), IDLE_CASCADE_SIDE);
        assert_eq!(cascade_side(2048, Some(16), 0), 2048);
        // A gap of a few frames keeps what is held.
        assert_eq!(cascade_side(2048, Some(2048), 1), 2048);
        assert_eq!(
            cascade_side(2048, Some(2048), IDLE_CASCADE_FRAMES - 1),
            2048
        );
        assert_eq!(
            cascade_side(2048, Some(2048), IDLE_CASCADE_FRAMES),
            IDLE_CASCADE_SIDE
        );
        assert_eq!(cascade_side(1024, Some(2048), 0), 1024);
    }

    #[test]
    fn splits_increase_and_end_at_the_shadow_distance() {
        let s = split_depths(0.5, 600.0);
        assert!(s[0] > 0.5 && s[0] < s[1] && s[1] < s[2]);
        assert_eq!(s[2], 600.0);
    }

    #[test]
    fn cascades_contain_the_points_they_cover() {
        let cam = Camera::look_at(Vec3::new(0.0, 20.0, 0.0), Vec3::new(0.0, 0.0, 100.0), 60.0);
        let scene = Aabb {
            min: Vec3::new(-500.0, -10.0, -500.0),
            max: Vec3::new(500.0, 60.0, 500.0),
        };
        let settings = ShadowSettings::default();
        let sun = crate::scene::sun_direction(135.0, 35.0);
        let c = Cascades::fit(&cam, 1.5, sun, &settings, &scene);
        // A point in view at each cascade's middle depth projects inside that cascade.
        let mut z0 = cam.near.max(0.5);
        for i in 0..CASCADES {
            let z = 0.5 * (z0 + c.splits[i]);
            let p = cam.position + cam.forward() * z;
            let ndc = c.matrices[i].project_point3(p);
            assert!(ndc.x.abs() < 1.0 && ndc.y.abs() < 1.0, "cascade {i}: {ndc}");
            assert!((0.0..=1.0).contains(&ndc.z), "cascade {i}: {ndc}");
            z0 = c.splits[i];
        }
        assert!(c.texel_world[0] < c.texel_world[2]);
    }
}
