//! The `texel` method's knobs, as the command line, the panel and the bench's sweeps see
//! them.

use super::settings::TexelMode;
use crate::render::knob::Knob;

pub static KNOBS: &[Knob] = &[
    Knob::choice(
        "texel_mode",
        "slicing",
        "slices3d: slices parallel to the screen through a 3D texture (Decaudin-Neyret 2009); stacks: the seeds' three axis stacks of 2D slices with pre-composited power-of-two levels (Meyer-Neyret 1998); polygons: slices3d's slices drawn as polygons",
        &["slices3d", "stacks", "polygons"],
        |d| d.texel.mode.name(),
        |d, v| d.texel.mode = TexelMode::parse(v).unwrap_or(d.texel.mode),
    ),
    Knob::number(
        "slice_d0",
        "slice depth d0 px",
        "largest visible depth between slices, in pixels on screen (criterion C1)",
        (0.05, 100.0),
        |d| d.texel.bounds.d0,
        |d, v| d.texel.bounds.d0 = v,
    )
    .slider(0.25, 16.0, true),
    Knob::number(
        "slice_d1",
        "slice spacing d1 px",
        "largest projected spacing between slices, pixels (criterion C2)",
        (0.05, 100.0),
        |d| d.texel.bounds.d1,
        |d, v| d.texel.bounds.d1 = v,
    )
    .slider(0.25, 16.0, true),
    Knob::number(
        "max_slices",
        "max slices",
        "most slices per texel",
        (1.0, 1024.0),
        |d| d.texel.bounds.max_slices as f32,
        |d, v| d.texel.bounds.max_slices = v.round().clamp(1.0, 1024.0) as u32,
    )
    .slider(1.0, 512.0, true)
    .integer(),
    Knob::toggle(
        "vcm",
        "VCM shading (trees shade each other)",
        "shade the trees by the visibility cube maps (when the bake has them)",
        |d| d.texel.vcm,
        |d, v| d.texel.vcm = v,
    ),
    Knob::toggle(
        "show_slices",
        "show slice count",
        "colour each texel by its slice count (blue 1, green about 11, red 128 or more)",
        |d| d.texel.show_slices,
        |d, v| d.texel.show_slices = v,
    ),
    Knob::toggle(
        "texel_tiles",
        "forest-cover tiles far away",
        "beyond tile_distance, draw the trees of a whole 64 m tile as one volume that follows the ground",
        |d| d.texel.tiles,
        |d, v| d.texel.tiles = v,
    ),
    Knob::number(
        "tile_distance",
        "tile distance m",
        "distance (m) beyond which a whole tile is drawn as one forest-cover volume",
        (1.0, 100_000.0),
        |d| d.texel.tile_distance,
        |d, v| d.texel.tile_distance = v,
    )
    .slider(50.0, 2000.0, true)
    .when(|d| d.texel.tiles),
];
