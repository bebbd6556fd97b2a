//! The octahedral impostor of each species: the tree level (the geometry the BTF tree
//! level is photographed from) seen along every frame direction of an octahedral grid
//! ([`crate::sphere::OctaGrid`]), orthographic, framing its bounding sphere as the BTF
//! images do. Each frame is drawn twice by the render core's studio, supersampled: its
//! unlit colour, and its normal with its depth ([`StudioOutput`]); the CPU resolves,
//! dilates and mips each frame on its own ([`super::atlas`]).
//!
//! Cost: about 0.1 s a frame on lavapipe (2 cores) for a tree of 89k triangles, nearly
//! whatever the frame's size (docs/results/bake.md, "Impostors: frames, frame size, bytes and
//! bake time"; the estimate's fit is in [`super::estimate`]).

use glam::Vec3;

use super::atlas::{self, Atlas, FrameMaps};
use super::{bounding_sphere, level_object, studio_frame, studio_world};
use crate::format::{self, BakeSettings, Impostor};
use crate::model::{Level, World};
use crate::render::{Camera, FrameDesc, GpuContext, Renderer, StudioOutput, Sun};
use crate::sphere::{OctaGrid, billboard_axes};
use crate::{Error, Result};

/// The grid of frames the settings ask for (None: no impostors).
pub fn grid_of(settings: &BakeSettings) -> Option<OctaGrid> {
    (settings.impostor_frames > 0)
        .then(|| OctaGrid::new(settings.impostor_layout, settings.impostor_frames))
}

/// Bytes of one species' impostor record with these settings.
pub fn record_bytes(settings: &BakeSettings) -> u64 {
    format::impostor_record_bytes(
        settings.impostor_frames,
        settings.impostor_resolution,
        format::impostor_mip_levels(settings.impostor_resolution),
    )
}

/// Progress steps of the impostor bake of `world`: one per frame.
pub fn step_count(settings: &BakeSettings, world: &World) -> u64 {
    grid_of(settings).map_or(0, |g| g.len() as u64 * world.species.len() as u64)
}

/// The camera of the frame seen from `dir` (unit, from the object towards the camera):
/// orthographic, framing the bounding sphere, with the billboards' image axes.
pub fn frame_camera(center: Vec3, radius: f32, dir: Vec3) -> Camera {
    let (_, up) = billboard_axes(dir);
    Camera::orthographic(center + dir * (2.0 * radius), -dir, up, radius)
}

/// The studio frame that draws one of the impostor maps (`output`) with `camera`: the
/// object alone, no shadows, no sky visibility.
pub fn maps_frame(camera: Camera, output: StudioOutput) -> FrameDesc {
    let mut frame = studio_frame(
        camera,
        Sun::from_direction(Vec3::Y, Vec3::ZERO, 0.0),
        0.0,
        256,
    );
    frame.shadows.enabled = false;
    frame.reference = None;
    frame.studio_output = output;
    frame
}

/// One frame's maps, `res` pixels a side, drawn `ss` times larger by `renderer` (which holds
/// the object alone) from `dir`, resolved and dilated: what the bake lays into the atlas.
pub fn draw_frame(
    ctx: &GpuContext,
    renderer: &mut Renderer,
    (center, radius): (Vec3, f32),
    dir: Vec3,
    res: u32,
    ss: u32,
) -> Result<FrameMaps> {
    let camera = frame_camera(center, radius, dir);
    let mut pictures = Vec::with_capacity(2);
    for output in [
        StudioOutput::Albedo,
        StudioOutput::NormalDepth {
            near: radius,
            far: 3.0 * radius,
        },
    ] {
        let frame = maps_frame(camera, output);
        let (img, _) = renderer.render_image(ctx, &frame, res * ss, res * ss, 1)?;
        pictures.push(img.into_raw());
    }
    let mut maps = atlas::resolve(&pictures[0], &pictures[1], res, ss)?;
    atlas::dilate(&mut maps);
    Ok(maps)
}

/// Bakes the impostor of every species of `world` (none when the settings' frames are 0).
/// `progress` sees (frames done, what).
pub fn bake_impostors(
    ctx: &GpuContext,
    world: &World,
    settings: &BakeSettings,
    progress: &mut dyn FnMut(u64, &str),
) -> Result<Vec<Impostor>> {
    let Some(grid) = grid_of(settings) else {
        return Ok(Vec::new());
    };
    let res = settings.impostor_resolution;
    let ss = settings.supersample.max(1);
    let levels = format::impostor_mip_levels(res);
    let mut done = 0u64;
    let mut out = Vec::with_capacity(world.species.len());
    for (s, tree) in world.species.iter().enumerate() {
        let object = level_object(tree, Level::Tree);
        let (center, radius) = bounding_sphere(&object.tree_bounds);
        let studio = studio_world(object);
        let mut renderer = Renderer::new(ctx, &studio)?;
        let mut maps = Atlas::new(grid.frames, res, levels)?;
        let what = format!("{} impostor", tree.name);
        for k in 0..grid.len() {
            let f = grid.frame(k);
            let dir = grid.frame_dir(f);
            let frame_maps = draw_frame(ctx, &mut renderer, (center, radius), dir, res, ss)?;
            maps.put(f, frame_maps)?;
            done += 1;
            progress(done, &what);
        }
        out.push(Impostor {
            species: u32::try_from(s).map_err(|_| Error::BadInput("too many species".into()))?,
            layout: grid.layout,
            frames: grid.frames,
            resolution: res,
            mip_levels: levels,
            center: center.to_array(),
            radius,
            albedo: maps.albedo,
            normal_depth: maps.normal_depth,
        });
    }
    Ok(out)
}
