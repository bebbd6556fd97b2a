//! The image axes of a billboard seen from a direction, shared by the bake's camera and the
//! billboards at render time.

use glam::Vec3;

/// Image axes of the billboard seen from `view` (a unit vector from the object towards the
/// viewer): (right, up). The bake's camera and the billboards at render time use the same
/// rule, so an image lands on its plane the way it was taken.
pub fn billboard_axes(view: Vec3) -> (Vec3, Vec3) {
    let v = view.normalize_or(Vec3::Z);
    let hint = if v.y.abs() > 0.999 { Vec3::Z } else { Vec3::Y };
    let right = hint.cross(v).normalize_or(Vec3::X);
    let up = v.cross(right).normalize_or(Vec3::Y);
    (right, up)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn billboard_axes_are_orthonormal_everywhere() {
        for v in [
            Vec3::X,
            Vec3::Y,
            -Vec3::Y,
            Vec3::Z,
            Vec3::new(1.0, 2.0, 3.0).normalize_or_zero(),
        ] {
            let (r, u) = billboard_axes(v);
            assert!((r.length() - 1.0).abs() < 1e-5 && (u.length() - 1.0).abs() < 1e-5);
            assert!(r.dot(u).abs() < 1e-5 && r.dot(v).abs() < 1e-5 && u.dot(v).abs() < 1e-5);
            // right, up, view form a right-handed frame: the viewer sees right to the right.
            assert!((r.cross(u) - v).length() < 1e-4, "{v}");
        }
    }
}
