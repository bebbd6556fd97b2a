//! The `surfel` method's knobs, as the command line, the panel, the bench's sweeps and
//! `tune` see them.

use crate::render::knob::Knob;

pub static KNOBS: &[Knob] = &[
    Knob::number(
        "surfel_px",
        "surfel spacing (px)",
        "each block of a tree is drawn at the coarsest level whose surfel spacing projects to at most this many pixels (below 1 more surfels than pixels; above 1 pull-push fills the holes)",
        (0.25, 8.0),
        |d| d.surfel.surfel_px,
        |d, v| d.surfel.surfel_px = v,
    )
    .slider(0.25, 4.0, false)
    .tuned(&["1", "1.5", "2"]),
    Knob::number(
        "surfel_tolerance",
        "depth tolerance (spacings)",
        "surfels up to this many of their level's spacings behind their pixel's nearest one are averaged into the pixel",
        (0.0, 16.0),
        |d| d.surfel.tolerance,
        |d, v| d.surfel.tolerance = v,
    )
    .slider(0.0, 8.0, false)
    .tuned(&["1", "2", "4"]),
    Knob::number(
        "surfel_geometry_px",
        "geometry above (px)",
        "a tree whose finest surfels project above this many pixels at its nearest point is drawn as geometry, faded in over the last fifth before it (0: never)",
        (0.0, 64.0),
        |d| d.surfel.geometry_px,
        |d, v| d.surfel.geometry_px = v,
    )
    .slider(0.0, 16.0, false),
    Knob::toggle(
        "surfel_fill",
        "fill holes (pull-push)",
        "fill an empty pixel from the half- or quarter-resolution level where that level is covered at least half and in front of the frame",
        |d| d.surfel.fill,
        |d, v| d.surfel.fill = v,
    ),
    Knob::number(
        "surfel_shadow",
        "self-shadowing",
        "multiplies each tree's own extinction (its surfels' area as a volume) between a surfel and the sun, and between it and the sky (the share of the sky its tree leaves it, baked); 0: none",
        (0.0, 8.0),
        |d| d.surfel.self_shadow,
        |d, v| d.surfel.self_shadow = v,
    )
    .slider(0.0, 4.0, false)
    .tuned(&["0.5", "1", "2"]),
    Knob::toggle(
        "vcm",
        "VCM shading (trees shade each other)",
        "shade the trees by the visibility cube maps (when the bake has them)",
        |d| d.surfel.vcm,
        |d, v| d.surfel.vcm = v,
    ),
    Knob::toggle(
        "show_lod",
        "show LOD level",
        "colour each surfel by its level of the LDC tree (red the finest, then orange, yellow, green, blue, violet)",
        |d| d.surfel.show_lod,
        |d, v| d.surfel.show_lod = v,
    ),
];
