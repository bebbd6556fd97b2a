//! Camera and frustum: a perspective camera with reversed-Z infinite projection (depth 1 at
//! the near plane, 0 at infinity, so a kilometre of forest keeps depth precision), and the
//! frustum planes used to cull trees before they reach the GPU.

use glam::{Mat4, Vec3, Vec4};

use crate::model::mesh::Aabb;

/// A perspective camera. Yaw is measured from +Z towards +X, pitch up from the horizon,
/// both in radians.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Camera {
    pub position: Vec3,
    pub yaw: f32,
    pub pitch: f32,
    pub fov_y_deg: f32,
    pub near: f32,
    /// Orthographic instead of perspective, with an explicit orientation. Used by the bake,
    /// which photographs one object along each sampled direction, straight up and down too.
    pub ortho: Option<OrthoView>,
}

/// An orthographic view: where it looks, which way is up in the image, and half the image's
/// height in metres.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct OrthoView {
    pub forward: Vec3,
    pub up: Vec3,
    pub half_height: f32,
    /// Distance from the camera to the far plane (the near plane is `Camera::near`).
    pub far: f32,
}

impl Camera {
    pub const MAX_PITCH: f32 = 1.55;
    /// Depth range of an orthographic camera (m).
    pub const ORTHO_DEPTH: f32 = 10_000.0;

    /// A camera at `position` looking at `target`.
    pub fn look_at(position: Vec3, target: Vec3, fov_y_deg: f32) -> Self {
        let d = (target - position).normalize_or(Vec3::Z);
        let yaw = d.x.atan2(d.z);
        let pitch =
            d.y.clamp(-1.0, 1.0)
                .asin()
                .clamp(-Self::MAX_PITCH, Self::MAX_PITCH);
        Self {
            position,
            yaw,
            pitch,
            fov_y_deg: fov_y_deg.clamp(1.0, 170.0),
            near: 0.1,
            ortho: None,
        }
    }

    /// An orthographic camera at `position` looking along `forward`, with `up` (orthogonal
    /// to it) as the image's up, seeing `half_height` metres above and below its axis.
    pub fn orthographic(position: Vec3, forward: Vec3, up: Vec3, half_height: f32) -> Self {
        let mut c = Self::look_at(position, position + forward, 60.0);
        c.ortho = Some(OrthoView {
            forward: forward.normalize_or(Vec3::NEG_Z),
            up: up.normalize_or(Vec3::Y),
            half_height: half_height.max(1e-4),
            far: Self::ORTHO_DEPTH,
        });
        c.near = 0.0;
        c
    }

    /// An orthographic camera that sees only what lies between `near` and `far` metres in
    /// front of it: one slab of an object (the texel bake).
    pub fn slab(
        position: Vec3,
        forward: Vec3,
        up: Vec3,
        half_height: f32,
        near: f32,
        far: f32,
    ) -> Self {
        let mut c = Self::orthographic(position, forward, up, half_height);
        c.near = near.max(0.0);
        if let Some(o) = &mut c.ortho {
            o.far = far.max(c.near + 1e-4);
        }
        c
    }

    pub fn forward(&self) -> Vec3 {
        if let Some(o) = self.ortho {
            return o.forward;
        }
        Vec3::new(
            self.yaw.sin() * self.pitch.cos(),
            self.pitch.sin(),
            self.yaw.cos() * self.pitch.cos(),
        )
    }

    /// Right vector (horizontal for the perspective camera).
    pub fn right(&self) -> Vec3 {
        if let Some(o) = self.ortho {
            return o.forward.cross(o.up).normalize_or(Vec3::X);
        }
        Vec3::new(-self.yaw.cos(), 0.0, self.yaw.sin())
    }

    pub fn up(&self) -> Vec3 {
        if let Some(o) = self.ortho {
            return o.up;
        }
        self.right().cross(self.forward()).normalize_or(Vec3::Y)
    }

    pub fn view(&self) -> Mat4 {
        if let Some(o) = self.ortho {
            return glam::camera::rh::view::look_to_mat4(self.position, o.forward, o.up);
        }
        glam::camera::rh::view::look_to_mat4(self.position, self.forward(), Vec3::Y)
    }

    pub fn projection(&self, aspect: f32) -> Mat4 {
        if let Some(OrthoView {
            half_height: h,
            far,
            ..
        }) = self.ortho
        {
            // Reversed Z as for perspective: depth 1 at the camera, 0 far away.
            let w = h * aspect.max(1e-4);
            return glam::camera::rh::proj::directx::orthographic(-w, w, -h, h, far, self.near);
        }
        glam::camera::rh::proj::directx::perspective_infinite_reverse(
            self.fov_y_deg.to_radians(),
            aspect.max(1e-4),
            self.near,
        )
    }

    pub fn view_projection(&self, aspect: f32) -> Mat4 {
        self.projection(aspect) * self.view()
    }

    /// Focal length in pixels for an image `height` pixels tall: a length `l` at distance
    /// `z` covers `l * f_px / z` pixels (the LOD criterion of the thesis).
    pub fn focal_px(&self, height: u32) -> f32 {
        0.5 * height as f32 / (0.5 * self.fov_y_deg.to_radians()).tan()
    }

    /// The view frustum (near plane and four sides; the far plane is at infinity).
    pub fn frustum(&self, aspect: f32) -> Frustum {
        if self.ortho.is_some() {
            return Frustum::from_ortho(self.view_projection(aspect));
        }
        let f = self.forward();
        let r = self.right();
        let u = self.up();
        let half_v = 0.5 * self.fov_y_deg.to_radians();
        let half_h = (half_v.tan() * aspect).atan();
        let p = self.position;
        // Inward-facing side normals: rotate the forward vector towards each side.
        let side = |axis: Vec3, angle: f32, sign: f32| {
            let n = (f * angle.sin() - axis * sign * angle.cos()).normalize_or_zero();
            n.extend(-n.dot(p))
        };
        let planes = [
            f.extend(-f.dot(p + f * self.near)),
            side(r, half_h, 1.0),
            side(r, half_h, -1.0),
            side(u, half_v, 1.0),
            side(u, half_v, -1.0),
        ];
        Frustum {
            planes: planes.to_vec(),
        }
    }
}

/// Planes (xyz = inward normal, w = offset) bounding a convex region.
#[derive(Clone, Debug)]
pub struct Frustum {
    pub planes: Vec<Vec4>,
}

impl Frustum {
    /// Conservative box test: false only when the box lies wholly outside one plane.
    pub fn intersects(&self, b: &Aabb) -> bool {
        self.planes.iter().all(|pl| {
            let n = pl.truncate();
            let positive = Vec3::select(n.cmpge(Vec3::ZERO), b.max, b.min);
            n.dot(positive) + pl.w >= 0.0
        })
    }

    /// The box seen by an orthographic `view_proj` (clip x, y in -1..1, z in 0..1).
    pub fn from_ortho(view_proj: Mat4) -> Self {
        // Gribb-Hartmann extraction, valid for any projection with depth in 0..1.
        let m = view_proj.transpose();
        let (r0, r1, r2, r3) = (m.x_axis, m.y_axis, m.z_axis, m.w_axis);
        let planes = [r3 + r0, r3 - r0, r3 + r1, r3 - r1, r2, r3 - r2]
            .into_iter()
            .map(|p| {
                let len = p.truncate().length();
                if len > 0.0 { p / len } else { p }
            })
            .collect();
        Frustum { planes }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn unit_box_at(c: Vec3) -> Aabb {
        Aabb {
            min: c - Vec3::splat(0.5),
            max: c + Vec3::splat(0.5),
        }
    }

    #[test]
    fn look_at_points_the_camera_at_the_target() {
        let cam = Camera::look_at(Vec3::new(0.0, 10.0, 0.0), Vec3::new(10.0, 0.0, 10.0), 60.0);
        let want = (Vec3::new(10.0, -10.0, 10.0)).normalize_or_zero();
        assert!(cam.forward().dot(want) > 0.9999);
    }

    #[test]
    fn frustum_keeps_what_is_in_front_and_drops_what_is_behind_or_aside() {
        let cam = Camera::look_at(Vec3::ZERO, Vec3::Z, 60.0);
        let fr = cam.frustum(1.0);
        assert!(fr.intersects(&unit_box_at(Vec3::new(0.0, 0.0, 10.0))));
        assert!(!fr.intersects(&unit_box_at(Vec3::new(0.0, 0.0, -10.0))));
        assert!(!fr.intersects(&unit_box_at(Vec3::new(30.0, 0.0, 10.0))));
        assert!(!fr.intersects(&unit_box_at(Vec3::new(0.0, 30.0, 10.0))));
        // A box straddling the side plane is kept.
        assert!(fr.intersects(&unit_box_at(Vec3::new(5.9, 0.0, 10.0))));
    }

    #[test]
    fn frustum_agrees_with_projection() {
        let cam = Camera::look_at(Vec3::new(3.0, 2.0, 1.0), Vec3::new(-20.0, 0.0, 40.0), 50.0);
        let aspect = 1.6;
        let vp = cam.view_projection(aspect);
        let fr = cam.frustum(aspect);
        // Points just inside and just outside the image borders.
        for &(x, y, inside) in &[
            (0.95, 0.0, true),
            (1.05, 0.0, false),
            (0.0, -0.95, true),
            (0.0, -1.05, false),
        ] {
            let clip = vp.inverse() * Vec4::new(x, y, 0.01, 1.0);
            let p = clip.truncate() / clip.w;
            let tiny = Aabb { min: p, max: p };
            assert_eq!(fr.intersects(&tiny), inside, "ndc ({x}, {y})");
        }
    }

    #[test]
    fn orthographic_camera_uses_reversed_depth() {
        let cam = Camera::orthographic(Vec3::new(0.0, 0.0, 10.0), -Vec3::Z, Vec3::Y, 2.0);
        let vp = cam.view_projection(1.0);
        let near = vp.project_point3(Vec3::new(1.0, 1.0, 9.0));
        let far = vp.project_point3(Vec3::new(1.0, 1.0, -9.0));
        assert!(
            near.z > far.z && near.z <= 1.0 && far.z >= 0.0,
            "{near} {far}"
        );
        assert!((near.x - 0.5).abs() < 1e-4 && (near.y - 0.5).abs() < 1e-4);
        let fr = cam.frustum(1.0);
        assert!(fr.intersects(&unit_box_at(Vec3::ZERO)));
        assert!(!fr.intersects(&unit_box_at(Vec3::new(5.0, 0.0, 0.0))));
    }

    #[test]
    fn ortho_frustum_contains_its_box() {
        let vp = glam::camera::rh::proj::directx::orthographic(-1.0, 1.0, -1.0, 1.0, 0.0, 10.0);
        let fr = Frustum::from_ortho(vp);
        assert!(fr.intersects(&unit_box_at(Vec3::new(0.0, 0.0, -5.0))));
        assert!(!fr.intersects(&unit_box_at(Vec3::new(0.0, 0.0, 5.0))));
        assert!(!fr.intersects(&unit_box_at(Vec3::new(3.0, 0.0, -5.0))));
    }
}
