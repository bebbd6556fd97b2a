//! How much of a tree's crown its foliage covers seen from the side: the share of the crown's
//! silhouette hull (the convex hull of everything drawn at or above the lowest leaf or
//! needle) that the tree's triangles cover, seen orthographically from a few azimuths. A
//! real conifer's crown reads as a solid cone from the side, a sapling's as a stick with
//! sprays; this is the number that tells them apart, computed on the CPU from the
//! model alone.

use glam::{Mat3, Vec2, Vec3};

use super::mesh::Mesh;
use super::tree::TreeModel;

/// Samples along the tree's tallest side of the side view: the tree seen about as a 1280x720
/// frame shows it when it fills the frame's height.
pub const SAMPLES_TALL: u32 = 720;

/// Azimuths of the side views (degrees about the vertical). Orthographic views from
/// opposite sides have mirrored silhouettes, so half a turn covers every side.
pub const AZIMUTHS_DEG: [f32; 4] = [0.0, 45.0, 90.0, 135.0];

/// A tree's side-view crown coverage.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CrownCoverage {
    /// The mean over [`AZIMUTHS_DEG`].
    pub mean: f32,
    /// The least covered side.
    pub min: f32,
    /// One per azimuth of [`AZIMUTHS_DEG`].
    pub per_view: [f32; 4],
}

/// The crown coverage of `tree`'s full geometry.
pub fn crown_coverage(tree: &TreeModel) -> CrownCoverage {
    mesh_crown_coverage(&tree.flatten())
}

/// The crown coverage of a tree mesh in its tree frame (+Y up); see [`crown_coverage`].
/// A mesh without foliage, or an empty one, covers nothing (0).
pub fn mesh_crown_coverage(mesh: &Mesh) -> CrownCoverage {
    let mut per_view = [0.0f32; 4];
    for (c, az) in per_view.iter_mut().zip(AZIMUTHS_DEG) {
        *c = view_coverage(mesh, az.to_radians());
    }
    let mean = per_view.iter().sum::<f32>() / per_view.len() as f32;
    let min = per_view.iter().copied().fold(f32::INFINITY, f32::min);
    CrownCoverage {
        mean,
        min,
        per_view,
    }
}

/// Coverage of the crown's hull seen along the horizontal direction at azimuth `az`.
fn view_coverage(mesh: &Mesh, az: f32) -> f32 {
    // The crown starts at the lowest leaf or needle; below it the trunk stands alone.
    let crown_bottom = mesh
        .vertices
        .iter()
        .filter(|v| v.foliage > 0.5)
        .map(|v| v.position[1])
        .fold(f32::INFINITY, f32::min);
    if !crown_bottom.is_finite() {
        return 0.0;
    }
    // Screen axes: u across (horizontal), v up.
    let rot = Mat3::from_rotation_y(-az);
    let project = |p: [f32; 3]| {
        let q = rot * Vec3::from(p);
        Vec2::new(q.x, q.y)
    };
    let (mut lo, mut hi) = (Vec2::splat(f32::INFINITY), Vec2::splat(f32::NEG_INFINITY));
    for v in &mesh.vertices {
        let p = project(v.position);
        lo = lo.min(p);
        hi = hi.max(p);
    }
    lo.y = lo.y.max(crown_bottom);
    let extent = (hi - lo).max(Vec2::splat(1e-6));
    let cell = extent.x.max(extent.y) / SAMPLES_TALL as f32;
    let w = ((extent.x / cell).ceil() as usize).clamp(1, SAMPLES_TALL as usize + 1);
    let h = ((extent.y / cell).ceil() as usize).clamp(1, SAMPLES_TALL as usize + 1);
    let mut covered = vec![false; w * h];

    // Point-sampled rasterisation at the sample centres (top-left rule not needed: a
    // sample on a shared edge counts once or twice, both mean covered).
    for tri in mesh.indices.chunks_exact(3) {
        let [a, b, c] = [tri[0], tri[1], tri[2]].map(|i| {
            mesh.vertices
                .get(i as usize)
                .map_or(Vec2::ZERO, |v| (project(v.position) - lo) / cell)
        });
        let area = (b - a).perp_dot(c - a);
        if area.abs() < 1e-12 {
            continue;
        }
        let min = a.min(b).min(c);
        let max = a.max(b).max(c);
        if max.y < 0.0 {
            continue; // wholly below the crown
        }
        let x0 = (min.x - 0.5).ceil().max(0.0) as usize;
        let x1 = ((max.x - 0.5).floor() as isize).min(w as isize - 1);
        let y0 = (min.y - 0.5).ceil().max(0.0) as usize;
        let y1 = ((max.y - 0.5).floor() as isize).min(h as isize - 1);
        if x1 < x0 as isize || y1 < y0 as isize {
            continue;
        }
        let s = area.signum();
        for y in y0..=y1 as usize {
            for x in x0..=x1 as usize {
                let p = Vec2::new(x as f32 + 0.5, y as f32 + 0.5);
                let e0 = (b - a).perp_dot(p - a) * s;
                let e1 = (c - b).perp_dot(p - b) * s;
                let e2 = (a - c).perp_dot(p - c) * s;
                if e0 >= 0.0 && e1 >= 0.0 && e2 >= 0.0 {
                    covered[y * w + x] = true;
                }
            }
        }
    }

    // The hull of the covered samples, from each row's leftmost and rightmost one.
    let mut points = Vec::with_capacity(2 * h);
    for y in 0..h {
        let row = &covered[y * w..(y + 1) * w];
        if let (Some(l), Some(r)) = (row.iter().position(|&c| c), row.iter().rposition(|&c| c)) {
            points.push(Vec2::new(l as f32 + 0.5, y as f32 + 0.5));
            points.push(Vec2::new(r as f32 + 0.5, y as f32 + 0.5));
        }
    }
    let hull = convex_hull(points);
    if hull.len() < 3 {
        return 0.0;
    }
    let (mut inside, mut hit) = (0u64, 0u64);
    for y in 0..h {
        let Some((l, r)) = hull_span(&hull, y as f32 + 0.5) else {
            continue;
        };
        let x0 = (l - 0.5).ceil().max(0.0) as usize;
        let x1 = ((r - 0.5).floor() as isize).min(w as isize - 1);
        if x1 < x0 as isize {
            continue;
        }
        let row = &covered[y * w + x0..=y * w + x1 as usize];
        inside += row.len() as u64;
        hit += row.iter().filter(|&&c| c).count() as u64;
    }
    if inside == 0 {
        0.0
    } else {
        hit as f32 / inside as f32
    }
}

/// Andrew's monotone chain: the convex hull, counter-clockwise, without collinear points.
fn convex_hull(mut p: Vec<Vec2>) -> Vec<Vec2> {
    p.sort_by(|a, b| a.x.total_cmp(&b.x).then(a.y.total_cmp(&b.y)));
    p.dedup();
    if p.len() < 3 {
        return p;
    }
    let cross = |o: Vec2, a: Vec2, b: Vec2| (a - o).perp_dot(b - o);
    let mut hull: Vec<Vec2> = Vec::with_capacity(2 * p.len());
    for pass in 0..2 {
        let start = hull.len();
        let iter: Box<dyn Iterator<Item = &Vec2>> = if pass == 0 {
            Box::new(p.iter())
        } else {
            Box::new(p.iter().rev())
        };
        for &q in iter {
            while hull.len() >= start + 2
                && cross(hull[hull.len() - 2], hull[hull.len() - 1], q) <= 0.0
            {
                hull.pop();
            }
            hull.push(q);
        }
        hull.pop(); // the last point of each chain starts the other
    }
    hull
}

/// Where the horizontal line at `y` enters and leaves the convex polygon `hull`.
fn hull_span(hull: &[Vec2], y: f32) -> Option<(f32, f32)> {
    let mut span: Option<(f32, f32)> = None;
    for (i, &a) in hull.iter().enumerate() {
        let b = hull[(i + 1) % hull.len()];
        let (lo, hi) = if a.y <= b.y { (a, b) } else { (b, a) };
        if y < lo.y || y > hi.y {
            continue;
        }
        let x = if hi.y - lo.y < 1e-9 {
            // A horizontal edge: both its ends are on the line.
            span = Some(span.map_or((lo.x.min(hi.x), lo.x.max(hi.x)), |(l, r)| {
                (l.min(lo.x.min(hi.x)), r.max(lo.x.max(hi.x)))
            }));
            continue;
        } else {
            lo.x + (hi.x - lo.x) * (y - lo.y) / (hi.y - lo.y)
        };
        span = Some(span.map_or((x, x), |(l, r)| (l.min(x), r.max(x))));
    }
    span
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::mesh::Vertex;

    fn quad(m: &mut Mesh, corners: [Vec3; 4], foliage: f32) {
        let base = m.vertices.len() as u32;
        for c in corners {
            m.vertices.push(Vertex::new(c, Vec3::Z, Vec3::ONE, foliage));
        }
        m.indices
            .extend_from_slice(&[base, base + 1, base + 2, base, base + 2, base + 3]);
    }

    #[test]
    fn a_solid_cone_is_covered_and_a_stick_with_sprays_is_not() {
        // A solid "crown": two crossed squares, 4 m a side, standing on a bare 2 m stick.
        let mut solid = Mesh::default();
        quad(
            &mut solid,
            [
                Vec3::new(-2.0, 2.0, 0.0),
                Vec3::new(2.0, 2.0, 0.0),
                Vec3::new(2.0, 6.0, 0.0),
                Vec3::new(-2.0, 6.0, 0.0),
            ],
            1.0,
        );
        quad(
            &mut solid,
            [
                Vec3::new(0.0, 2.0, -2.0),
                Vec3::new(0.0, 2.0, 2.0),
                Vec3::new(0.0, 6.0, 2.0),
                Vec3::new(0.0, 6.0, -2.0),
            ],
            1.0,
        );
        // The bare trunk below the crown does not count.
        quad(
            &mut solid,
            [
                Vec3::new(-0.1, 0.0, 0.0),
                Vec3::new(0.1, 0.0, 0.0),
                Vec3::new(0.1, 2.0, 0.0),
                Vec3::new(-0.1, 2.0, 0.0),
            ],
            0.0,
        );
        let c = mesh_crown_coverage(&solid);
        // From every azimuth the two squares project onto the same span: fully covered.
        assert!(c.min > 0.97, "{c:?}");

        // Four thin horizontal bars over the same height: a hull of 4x4 m, mostly empty.
        let mut sparse = Mesh::default();
        for k in 0..4 {
            let y = 2.0 + k as f32 * 4.0 / 3.0;
            quad(
                &mut sparse,
                [
                    Vec3::new(-2.0, y - 0.1, 0.0),
                    Vec3::new(2.0, y - 0.1, 0.0),
                    Vec3::new(2.0, y + 0.1, 0.0),
                    Vec3::new(-2.0, y + 0.1, 0.0),
                ],
                1.0,
            );
        }
        let c = mesh_crown_coverage(&sparse);
        // Seen edge-on (azimuth 90) the bars vanish; at 0 they cover 4 x 0.2 of 4 m.
        assert!(c.per_view[0] > 0.15 && c.per_view[0] < 0.3, "{c:?}");
        assert!(c.mean < 0.3, "{c:?}");
    }

    #[test]
    fn nothing_covers_nothing() {
        assert_eq!(mesh_crown_coverage(&Mesh::default()).mean, 0.0);
        let mut bark = Mesh::default();
        quad(
            &mut bark,
            [
                Vec3::new(-1.0, 0.0, 0.0),
                Vec3::new(1.0, 0.0, 0.0),
                Vec3::new(1.0, 1.0, 0.0),
                Vec3::new(-1.0, 1.0, 0.0),
            ],
            0.0,
        );
        assert_eq!(mesh_crown_coverage(&bark).mean, 0.0);
    }

    #[test]
    fn the_hull_spans_a_triangle() {
        let hull = convex_hull(vec![
            Vec2::new(0.0, 0.0),
            Vec2::new(4.0, 0.0),
            Vec2::new(2.0, 4.0),
            Vec2::new(2.0, 1.0), // inside
        ]);
        assert_eq!(hull.len(), 3);
        let (l, r) = hull_span(&hull, 2.0).unwrap();
        assert!((l - 1.0).abs() < 1e-5 && (r - 3.0).abs() < 1e-5, "{l} {r}");
        assert!(hull_span(&hull, 5.0).is_none());
    }
}
