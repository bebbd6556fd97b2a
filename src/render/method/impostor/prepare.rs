//! The `impostor` method's CPU work: one record per tree in view (front to back, so that
//! the depth test drops what is hidden before it is shaded), with its tree-level VCM
//! factors. No GPU needed: the tests run it on made-up trees.

use glam::{Mat3, Mat4, Vec3};

use super::settings::{GEOMETRY_FADE, IMPOSTOR_COLOR, ImpostorSettings, ImpostorStats};
use crate::model::mesh::Aabb;
use crate::render::method::view::PrepareView;
use crate::render::vcm_shading::Shade;
use crate::render::world_gpu::TreeGpu;

/// One tree's record, as `shaders/impostor.wgsl` reads it (`struct Impostor`).
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
pub struct ImpostorGpu {
    pub center: [f32; 3],
    pub radius: f32,
    pub axis_x: [f32; 3],
    pub layer: u32,
    pub axis_y: [f32; 3],
    pub opacity: f32,
    pub axis_z: [f32; 3],
    pub mode: u32,
    pub tint: [f32; 3],
    pub parent_direct: f32,
    pub vcm_box_origin: [f32; 3],
    pub parent_sky: f32,
    pub vcm_box_scale: [f32; 3],
    pub _pad: f32,
    pub vcm_direct: [[f32; 4]; 2],
    pub vcm_sky: [[f32; 4]; 2],
}

/// `ImpostorGpu::mode`: the impostor itself, the LOD overlay's colour, the VCM sun factor.
pub const MODE_IMAGES: u32 = 0;
pub const MODE_TINT: u32 = 1;

/// The atlases' layout and the knobs the shader reads (`struct ImpostorParams`).
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
pub struct ImpostorParams {
    pub frames: u32,
    pub octa_layout: u32,
    pub resolution: u32,
    pub mips: u32,
    pub alpha_cutoff: f32,
    pub parallax: u32,
    pub self_shadow: f32,
    pub _pad: u32,
}

/// One species' impostor as the prepare step needs it: its atlas layer, the bounding
/// sphere its frames frame (object frame) and the side of a frame's texel there.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SpeciesImpostor {
    pub layer: u32,
    pub center: Vec3,
    pub radius: f32,
    pub texel: f32,
}

pub use crate::render::vcm_shading::TreeShade;

/// What the prepare step chose: the impostors' records and the trees drawn as geometry.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ImpostorFrame {
    /// The records, front to back.
    pub records: Vec<ImpostorGpu>,
    /// Per species: the trees drawn as geometry, each with its opacity (1: whole; below 1
    /// its impostor is drawn too, in the pixels the geometry leaves).
    pub geometry: Vec<Vec<(u32, f32)>>,
    pub stats: ImpostorStats,
}

/// How much of a tree of `species` is drawn as geometry (0 none, 1 all of it) at `z` from
/// the eye: its frames' texels of `scale`, projected, against `geometry_px`, faded in over
/// the last [`GEOMETRY_FADE`] before it.
pub fn geometry_opacity(
    species: &SpeciesImpostor,
    scale: f32,
    focal_px: f32,
    z: f32,
    geometry_px: f32,
) -> f32 {
    if geometry_px.is_nan() || geometry_px <= 0.0 {
        return 0.0;
    }
    let px = crate::lod::projected_px(species.texel * scale, focal_px, z);
    let start = geometry_px * (1.0 - GEOMETRY_FADE);
    ((px - start) / (geometry_px - start)).clamp(0.0, 1.0)
}

/// The records of the trees in view, front to back, at most `max` (the nearest kept), and
/// the trees near enough to be drawn as geometry.
/// `shade(t, species, model)` gives tree `t`'s tree-level VCM factors and the box they are
/// taken over, in the object frame (None: unshaded).
pub fn prepare(
    species: &[SpeciesImpostor],
    trees: &[TreeGpu],
    visible: &[Vec<u32>],
    view: &PrepareView,
    settings: &ImpostorSettings,
    max: usize,
    shade: &mut TreeShade<'_>,
) -> ImpostorFrame {
    let cam = view.camera.position;
    let mut geometry: Vec<Vec<(u32, f32)>> = vec![Vec::new(); visible.len()];
    let mut whole = 0u32;
    let mut drawn: Vec<Vec<(u32, f32)>> = vec![Vec::new(); visible.len()];
    for (sp, list) in visible.iter().enumerate() {
        let Some(info) = species.get(sp) else {
            continue;
        };
        for &t in list {
            let Some((center, scale)) = trees.get(t as usize).and_then(|d| placed(info, d)) else {
                continue;
            };
            if !in_view(view, center, info.radius * scale) {
                continue;
            }
            let z = (center - cam).length();
            let fade = geometry_opacity(info, scale, view.focal_px, z, settings.geometry_px);
            if fade > 0.0 {
                geometry[sp].push((t, fade));
                if fade >= 1.0 {
                    whole += 1;
                    continue;
                }
            }
            drawn[sp].push((t, 1.0 - fade));
        }
    }
    let tint = settings.show_lod.then_some(IMPOSTOR_COLOR);
    let records = records(species, trees, &drawn, view, settings, tint, max, shade);
    let stats = ImpostorStats {
        impostors: records.len() as u32,
        geometry_trees: geometry.iter().map(|l| l.len() as u32).sum(),
        ..Default::default()
    };
    debug_assert!(stats.geometry_trees >= whole);
    ImpostorFrame {
        records,
        geometry,
        stats,
    }
}

/// Tree `data`'s impostor sphere centre in the world and its scale; None for a tree of no
/// valid scale.
fn placed(info: &SpeciesImpostor, data: &TreeGpu) -> Option<(Vec3, f32)> {
    let m = Mat4::from_cols_array_2d(&data.model);
    let scale = m.x_axis.truncate().length();
    (scale > 0.0 && scale.is_finite()).then(|| (m.transform_point3(info.center), scale))
}

/// The sphere of `radius` around `center` meets the view.
fn in_view(view: &PrepareView, center: Vec3, radius: f32) -> bool {
    view.frustum.intersects(&Aabb {
        min: center - Vec3::splat(radius),
        max: center + Vec3::splat(radius),
    })
}

/// The records of the trees `drawn` (per species: tree and opacity) whose sphere is in
/// view, front to back, at most `max` (the nearest kept); `tint`: every record shows this
/// colour instead of its images (the LOD overlay). `hybrid` draws its tree level with
/// these.
#[allow(clippy::too_many_arguments)]
pub fn records(
    species: &[SpeciesImpostor],
    trees: &[TreeGpu],
    drawn: &[Vec<(u32, f32)>],
    view: &PrepareView,
    settings: &ImpostorSettings,
    tint: Option<[f32; 3]>,
    max: usize,
    shade: &mut TreeShade<'_>,
) -> Vec<ImpostorGpu> {
    let cam = view.camera.position;
    let forward = view.camera.forward();
    let mut sorted: Vec<(f32, ImpostorGpu)> = Vec::new();
    for (sp, list) in drawn.iter().enumerate() {
        let Some(info) = species.get(sp) else {
            continue;
        };
        for &(t, opacity) in list {
            let Some(data) = trees.get(t as usize) else {
                continue;
            };
            let Some((center, scale)) = placed(info, data) else {
                continue;
            };
            let m = Mat4::from_cols_array_2d(&data.model);
            let radius = info.radius * scale;
            if !in_view(view, center, radius) {
                continue;
            }
            let rot = Mat3::from_mat4(m) * (1.0 / scale);
            let unit = Aabb {
                min: info.center - Vec3::splat(info.radius),
                max: info.center + Vec3::splat(info.radius),
            };
            let (s, bounds) = settings
                .vcm
                .then(|| shade(t as usize, sp, &m))
                .flatten()
                .unwrap_or((Shade::NONE, unit));
            let ext = (bounds.max - bounds.min).max(Vec3::splat(1e-6));
            let (tint, mode) = match tint {
                Some(c) => (c, MODE_TINT),
                None => ([data.tint[0], data.tint[1], data.tint[2]], MODE_IMAGES),
            };
            let d = s.direct;
            let k = s.sky;
            let record = ImpostorGpu {
                center: center.to_array(),
                radius,
                axis_x: rot.x_axis.normalize_or(Vec3::X).to_array(),
                layer: info.layer,
                axis_y: rot.y_axis.normalize_or(Vec3::Y).to_array(),
                opacity,
                axis_z: rot.z_axis.normalize_or(Vec3::Z).to_array(),
                mode,
                tint,
                parent_direct: s.parent_direct,
                vcm_box_origin: ((info.center - bounds.min) / ext).to_array(),
                parent_sky: s.parent_sky,
                vcm_box_scale: (Vec3::splat(info.radius) / ext).to_array(),
                _pad: 0.0,
                vcm_direct: [[d[0], d[1], d[2], d[3]], [d[4], d[5], d[6], d[7]]],
                vcm_sky: [[k[0], k[1], k[2], k[3]], [k[4], k[5], k[6], k[7]]],
            };
            sorted.push(((center - cam).dot(forward), record));
        }
    }
    sorted.sort_by(|a, b| a.0.total_cmp(&b.0));
    sorted.truncate(max);
    sorted.into_iter().map(|(_, r)| r).collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::render::Camera;

    fn tree(x: f32, z: f32, yaw: f32, scale: f32) -> TreeGpu {
        let m = Mat4::from_translation(Vec3::new(x, 0.0, z))
            * Mat4::from_rotation_y(yaw)
            * Mat4::from_scale(Vec3::splat(scale));
        TreeGpu {
            model: m.to_cols_array_2d(),
            tint: [0.9, 1.0, 1.1, 1.0],
        }
    }

    fn species() -> Vec<SpeciesImpostor> {
        vec![SpeciesImpostor {
            layer: 3,
            center: Vec3::new(0.0, 5.0, 0.0),
            radius: 5.0,
            texel: 10.0 / 64.0,
        }]
    }

    fn run(
        trees: &[TreeGpu],
        settings: &ImpostorSettings,
        max: usize,
    ) -> (ImpostorFrame, Vec<usize>) {
        let camera = Camera::look_at(Vec3::new(0.0, 5.0, 30.0), Vec3::new(0.0, 5.0, 0.0), 60.0);
        let frustum = camera.frustum(1.5);
        let view = PrepareView {
            camera: &camera,
            focal_px: 500.0,
            to_sun: Vec3::Y,
            frustum: &frustum,
        };
        let visible = vec![(0..trees.len() as u32).collect()];
        let mut asked = Vec::new();
        let mut shade = |t: usize, _sp: usize, _m: &Mat4| {
            asked.push(t);
            let shade = Shade {
                direct: [0.5; 8],
                sky: [0.25; 8],
                parent_direct: 1.0,
                parent_sky: 1.0,
            };
            let bounds = Aabb {
                min: Vec3::new(-3.0, 0.0, -3.0),
                max: Vec3::new(3.0, 10.0, 3.0),
            };
            Some((shade, bounds))
        };
        let f = prepare(
            &species(),
            trees,
            &visible,
            &view,
            settings,
            max,
            &mut shade,
        );
        (f, asked)
    }

    #[test]
    fn one_record_per_tree_in_view_front_to_back_in_its_own_frame() {
        let trees = [
            tree(0.0, -40.0, 0.3, 1.0),
            tree(2.0, 0.0, 1.2, 2.0),
            tree(0.0, 60.0, 0.0, 1.0),
        ];
        let far = ImpostorSettings {
            geometry_px: 0.0,
            ..Default::default()
        };
        let (f, asked) = run(&trees, &far, usize::MAX);
        let (r, stats) = (f.records, f.stats);
        assert!(f.geometry[0].is_empty());
        assert_eq!(r.len(), 2, "the tree behind the camera is left out");
        assert_eq!(stats.impostors, 2);
        assert_eq!(asked, vec![0, 1]);
        // Nearest first.
        assert_eq!(r[0].center, [2.0, 10.0, 0.0]);
        assert_eq!(r[0].radius, 10.0);
        assert_eq!(r[1].center, [0.0, 5.0, -40.0]);
        // The axes are the tree's turn, unit length whatever its scale.
        let x = Vec3::from(r[0].axis_x);
        assert!(
            (x - Mat3::from_rotation_y(1.2) * Vec3::X).length() < 1e-5,
            "{x}"
        );
        assert!((Vec3::from(r[0].axis_y) - Vec3::Y).length() < 1e-5);
        assert_eq!(r[0].layer, 3);
        assert_eq!(r[0].tint, [0.9, 1.0, 1.1]);
        assert_eq!(r[0].vcm_direct, [[0.5; 4]; 2]);
        assert_eq!(r[0].vcm_sky, [[0.25; 4]; 2]);
        // The sphere's centre in box coordinates, and the box per radius.
        assert_eq!(r[0].vcm_box_origin, [0.5, 0.5, 0.5]);
        assert_eq!(r[0].vcm_box_scale, [5.0 / 6.0, 0.5, 5.0 / 6.0]);
    }

    #[test]
    fn knobs_reach_the_records_and_the_cap_keeps_the_nearest() {
        let trees = [tree(0.0, -40.0, 0.0, 1.0), tree(0.0, 0.0, 0.0, 1.0)];
        let off = ImpostorSettings {
            vcm: false,
            show_lod: true,
            geometry_px: 0.0,
            ..Default::default()
        };
        let (f, asked) = run(&trees, &off, 1);
        let r = f.records;
        assert!(asked.is_empty(), "no VCM read with vcm off");
        assert_eq!(r.len(), 1);
        assert_eq!(r[0].center[2], 0.0, "the nearest stays");
        assert_eq!((r[0].mode, r[0].tint), (MODE_TINT, IMPOSTOR_COLOR));
        assert_eq!(r[0].vcm_direct, [[1.0; 4]; 2]);
        let bad = [TreeGpu {
            model: Mat4::ZERO.to_cols_array_2d(),
            tint: [1.0; 4],
        }];
        assert!(
            run(&bad, &ImpostorSettings::default(), 8)
                .0
                .records
                .is_empty()
        );
    }

    #[test]
    fn near_trees_are_geometry_faded_in_below_the_bound_and_their_impostor_fades_out() {
        let sp = species()[0];
        // A frame texel of 10/64 m at 500 px focal length projects 2 px at 39 m.
        let at = |px: f32| sp.texel * 500.0 / px;
        assert_eq!(geometry_opacity(&sp, 1.0, 500.0, at(2.5), 2.0), 1.0);
        assert_eq!(geometry_opacity(&sp, 1.0, 500.0, at(1.5), 2.0), 0.0);
        let mid = geometry_opacity(&sp, 1.0, 500.0, at(1.8), 2.0);
        assert!((mid - 0.5).abs() < 1e-4, "{mid}");
        assert_eq!(
            geometry_opacity(&sp, 1.0, 500.0, 1.0, 0.0),
            0.0,
            "0 is never"
        );
        // The camera 30 m from the first tree (whole geometry) and 30 + 14 m from the
        // second (inside the band: both drawn, complementary).
        let trees = [
            tree(0.0, 0.0, 0.0, 1.0),
            tree(0.0, -14.0, 0.0, 1.0),
            tree(0.0, -200.0, 0.0, 1.0),
        ];
        let (f, _) = run(&trees, &ImpostorSettings::default(), usize::MAX);
        let g = &f.geometry[0];
        assert_eq!(g.len(), 2, "{g:?}");
        assert_eq!(g[0], (0, 1.0));
        let (t, o) = g[1];
        assert!(t == 1 && o > 0.0 && o < 1.0, "{g:?}");
        assert_eq!(f.records.len(), 2, "the fading tree and the far one");
        assert!((f.records[0].opacity - (1.0 - o)).abs() < 1e-6);
        assert_eq!(f.records[1].opacity, 1.0);
        assert_eq!((f.stats.impostors, f.stats.geometry_trees), (2, 2));
    }
}
