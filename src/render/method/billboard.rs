//! The `billboard` method: what a user would pick without canopy, and the floor every other
//! method is charted against. Each tree is one quad facing the camera showing one image of
//! its species: the bake's tree-level image from a single side view, lit by a single light
//! from the front and 45 degrees up (the usual studio shot). The image never changes with
//! the view or the sun (no relighting; the sun's and sky's colours still scale it), there
//! is no hierarchy (the trunk is in the image) and there are no shadows. It draws through
//! the `btf` method's image array and pipeline, with one record per tree.

use glam::{Mat4, Vec3};

use super::btf::{
    BillboardGpu, BillboardMode, BtfAssets, BtfFrame, BtfScene, BtfStats, PrepareView,
};
use super::info::{MethodInfo, no_rows};
use super::interface::{Bake, DrawCx, Plan, PrepareCx, RenderMethod, SunWork};
use super::kind::Method;
use crate::Result;
use crate::model::mesh::Aabb;
use crate::render::GpuContext;
use crate::render::frame::FrameStats;
use crate::render::pipelines::Layouts;
use crate::render::world_gpu::{TreeGpu, TreeRun, WorldGpu};
use crate::sphere::billboard_axes;

/// The side the single image is taken from, in the tree's frame (horizontal).
pub const SIDE: Vec3 = Vec3::Z;

/// The one image each species shows.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct FixedImage {
    /// View sample nearest to [`SIDE`].
    pub view: u32,
    /// Light sample nearest to the front, 45 degrees up.
    pub light: u32,
}

impl FixedImage {
    /// The samples of `scene`'s bake nearest to the side view and its studio light.
    pub fn of(scene: &BtfScene) -> Self {
        let (views, lights) = scene.tree_directions();
        Self {
            view: views.nearest(SIDE) as u32,
            light: lights.nearest((SIDE + Vec3::Y).normalize()) as u32,
        }
    }
}

/// [`prepare`] for the frame, the records uploaded through the `btf` method's buffer.
pub fn prepare_frame(
    assets: &mut BtfAssets,
    ctx: &GpuContext,
    world: &WorldGpu,
    visible: &[Vec<u32>],
    view: &PrepareView,
) -> BtfFrame {
    let mut f = prepare(
        assets.scene(),
        &world.tree_data,
        visible,
        view,
        assets.max_billboards(),
    );
    assets.upload(ctx, &std::mem::take(&mut f.records));
    f
}

/// One camera-facing record per visible tree, back to front (at most `max` of them, the
/// nearest kept). The frame lists no tree parts as geometry.
pub fn prepare(
    scene: &BtfScene,
    trees: &[TreeGpu],
    visible: &[Vec<u32>],
    view: &PrepareView,
    max: usize,
) -> BtfFrame {
    let image = FixedImage::of(scene);
    let (views, lights) = scene.tree_directions();
    let obj = views
        .directions()
        .get(image.view as usize)
        .copied()
        .unwrap_or(SIDE);
    let (obj_right, obj_up) = billboard_axes(obj);
    let cam = view.camera.position;
    let forward = view.camera.forward();
    let mut stats = BtfStats::default();
    let mut sorted: Vec<(f32, BillboardGpu)> = Vec::new();
    for (sp, list) in visible.iter().enumerate() {
        let Some((layer_base, set_center, set_radius)) = scene.tree_set(sp) else {
            continue;
        };
        for &t in list {
            let Some(data) = trees.get(t as usize) else {
                continue;
            };
            let m = Mat4::from_cols_array_2d(&data.model);
            let scale = m.x_axis.truncate().length();
            if !(scale > 0.0 && scale.is_finite()) {
                continue;
            }
            let center = m.transform_point3(set_center);
            let radius = set_radius * scale;
            let bounds = Aabb {
                min: center - Vec3::splat(radius),
                max: center + Vec3::splat(radius),
            };
            if !view.frustum.intersects(&bounds) {
                continue;
            }
            let (right, up) = billboard_axes((cam - center).normalize_or(Vec3::Y));
            stats.trees_per_level.tree += 1;
            stats.billboards.tree += 1;
            // One view, one light, and the sky-lit and ground-lit images.
            let fetches = 1 + u64::from(crate::format::AMBIENT_IMAGES_PER_VIEW);
            stats.images_sampled += fetches;
            stats.fetches_saved += super::btf::FETCHES_AT_MOST - fetches;
            let record = BillboardGpu {
                center: center.to_array(),
                radius,
                plane_right: right.to_array(),
                plane_up: up.to_array(),
                obj_right: obj_right.to_array(),
                obj_up: obj_up.to_array(),
                view_index: [image.view; 3],
                layer_base,
                light_index: [image.light; 3],
                light_count: lights.len() as u32,
                view_weight: [1.0, 0.0, 0.0],
                view_count: views.len() as u32,
                light_weight: [1.0, 0.0, 0.0],
                tint: [data.tint[0], data.tint[1], data.tint[2]],
                mode: BillboardMode::Images as u32,
                ..BillboardGpu::UNSHADED
            };
            sorted.push(((center - cam).dot(forward), record));
        }
    }
    sorted.sort_by(|a, b| b.0.total_cmp(&a.0));
    if sorted.len() > max {
        stats.dropped = (sorted.len() - max) as u32;
        sorted.drain(..sorted.len() - max);
    }
    let records: Vec<BillboardGpu> = sorted.into_iter().map(|(_, b)| b).collect();
    BtfFrame {
        trunk_only: vec![Vec::new(); scene.species_count()],
        trunk_and_limbs: vec![Vec::new(); scene.species_count()],
        twigs: vec![Vec::new(); scene.species_count()],
        impostors: vec![Vec::new(); scene.species_count()],
        billboards: records.len() as u32,
        far: false,
        layer_batches: 0,
        compositor: None,
        records,
        stats,
    }
}

/// The `billboard` method: its frame, the geometry runs (the terrain's) and its pipeline
/// (the `btf` method's).
#[derive(Default)]
pub struct Billboard {
    frame: Option<BtfFrame>,
    runs: Vec<Vec<TreeRun>>,
    pipeline: Option<wgpu::RenderPipeline>,
}

impl RenderMethod for Billboard {
    fn method(&self) -> Method {
        Method::Billboard
    }

    fn check(&self, bake: &Bake) -> Result<()> {
        bake.need_btf(Method::Billboard).map(|_| ())
    }

    fn prepare(&mut self, bake: &mut Bake, cx: PrepareCx<'_>) -> Result<Plan> {
        bake.need_btf(Method::Billboard)?;
        let Some(b) = bake.btf.as_mut() else {
            return Err(crate::Error::Gpu("the BTF images are not loaded".into()));
        };
        let bf = prepare_frame(b, cx.ctx, cx.world, &cx.visible, &cx.view);
        let (runs, plan) =
            super::btf::method::plan_geometry(cx.ctx, cx.world, cx.frame, &bf, SunWork::default());
        self.runs = runs;
        self.frame = Some(bf);
        Ok(plan)
    }

    fn ensure_pipelines(
        &mut self,
        bake: &mut Bake,
        ctx: &GpuContext,
        layouts: &Layouts,
        format: wgpu::TextureFormat,
    ) -> Result<()> {
        self.pipeline = super::btf::method::billboard_pipeline(bake, ctx, layouts, format);
        Ok(())
    }

    fn draw(
        &self,
        bake: &Bake,
        pass: &mut wgpu::RenderPass<'_>,
        cx: &DrawCx<'_>,
        stats: &mut FrameStats,
    ) {
        let frame = (&self.frame, &self.runs[..]);
        super::btf::method::draw_frame(
            bake,
            pass,
            cx,
            frame,
            self.pipeline.as_ref(),
            stats,
            &mut |_, _| {},
        );
        // The btf knobs do not apply.
        stats.btf = None;
    }
}

/// What the rest of the program asks of `billboard`.
pub const INFO: MethodInfo = MethodInfo {
    name: "billboard",
    summary: "one camera-facing image per tree from a single baked view and light: the floor (needs a bake)",
    needs_bake: true,
    follows_sun: false,
    stat_rows: no_rows,
};

#[cfg(test)]
mod tests {
    use super::*;
    use crate::render::Camera;
    use crate::render::method::btf::prepare::tests::scene;

    fn tree(x: f32, z: f32, yaw: f32) -> TreeGpu {
        let m = Mat4::from_translation(Vec3::new(x, 0.0, z)) * Mat4::from_rotation_y(yaw);
        TreeGpu {
            model: m.to_cols_array_2d(),
            tint: [1.0; 4],
        }
    }

    fn run(trees: &[TreeGpu], eye: Vec3, to_sun: Vec3) -> (BtfFrame, Camera) {
        let camera = Camera::look_at(eye, Vec3::new(0.0, 5.0, 0.0), 60.0);
        let frustum = camera.frustum(1.5);
        let view = PrepareView {
            camera: &camera,
            focal_px: 500.0,
            to_sun,
            frustum: &frustum,
        };
        let visible = vec![(0..trees.len() as u32).collect()];
        (
            prepare(&scene(), trees, &visible, &view, usize::MAX),
            camera,
        )
    }

    #[test]
    fn one_record_per_tree_with_the_same_image_whatever_the_view_and_sun() {
        let trees: Vec<TreeGpu> = (0..12)
            .map(|i| tree((i % 4) as f32 * 8.0 - 12.0, -(i / 4) as f32 * 8.0, i as f32))
            .collect();
        let image = FixedImage::of(&scene());
        let mut first = None;
        for (eye, sun) in [
            (Vec3::new(0.0, 5.0, 12.0), Vec3::Y),
            (
                Vec3::new(30.0, 60.0, 40.0),
                Vec3::new(-0.6, 0.3, 0.2).normalize(),
            ),
        ] {
            let (f, camera) = run(&trees, eye, sun);
            assert_eq!(f.records.len(), 12, "every tree is in view");
            assert_eq!(f.stats.trees_per_level.tree, 12);
            assert!(f.trunk_only[0].is_empty() && f.trunk_and_limbs[0].is_empty());
            for r in &f.records {
                assert_eq!(
                    (r.view_index[0], r.light_index[0]),
                    (image.view, image.light)
                );
                assert_eq!(
                    (r.view_weight, r.light_weight),
                    ([1.0, 0.0, 0.0], [1.0, 0.0, 0.0])
                );
                // The quad faces the camera.
                let n = Vec3::from(r.plane_right).cross(Vec3::from(r.plane_up));
                let to_eye = (camera.position - Vec3::from(r.center)).normalize();
                assert!(n.dot(to_eye) > 0.999, "{n} vs {to_eye}");
            }
            let depth = |r: &BillboardGpu| (Vec3::from(r.center) - eye).dot(camera.forward());
            assert!(f.records.windows(2).all(|w| depth(&w[0]) >= depth(&w[1])));
            // The image axes are the fixed view's, whatever the tree's turn.
            let axes: Vec<_> = f.records.iter().map(|r| (r.obj_right, r.obj_up)).collect();
            assert!(axes.windows(2).all(|w| w[0] == w[1]));
            first.get_or_insert(axes[0]);
            assert_eq!(first, Some(axes[0]));
        }
        // The side view is horizontal and the light 45 degrees up in front of it.
        let sc = scene();
        let (views, lights) = sc.tree_directions();
        assert!(views.directions()[image.view as usize].dot(SIDE) > 0.99);
        let l = lights.directions()[image.light as usize];
        assert!(l.dot((SIDE + Vec3::Y).normalize()) > 0.9, "{l}");
    }

    #[test]
    fn trees_outside_the_view_are_left_out_and_the_cap_keeps_the_nearest() {
        let trees = [
            tree(0.0, 0.0, 0.0),
            tree(0.0, 300.0, 0.0),
            tree(0.0, -40.0, 0.0),
        ];
        let (f, _) = run(&trees, Vec3::new(0.0, 5.0, 20.0), Vec3::Y);
        assert_eq!(f.records.len(), 2, "the tree behind the camera is culled");
        let camera = Camera::look_at(Vec3::new(0.0, 5.0, 20.0), Vec3::new(0.0, 5.0, 0.0), 60.0);
        let frustum = camera.frustum(1.5);
        let view = PrepareView {
            camera: &camera,
            focal_px: 500.0,
            to_sun: Vec3::Y,
            frustum: &frustum,
        };
        let capped = prepare(&scene(), &trees, &[vec![0, 1, 2]], &view, 1);
        assert_eq!((capped.records.len(), capped.stats.dropped), (1, 1));
        assert_eq!(capped.records[0].center[2], 0.0, "the nearest tree stays");
    }
}
