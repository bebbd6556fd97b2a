//! The `impostor` method's knobs, as the command line, the panel, the bench's sweeps and
//! `tune` see them. Its frames per side and frame size are bake settings
//! (`[bake] impostor_frames`, `impostor_resolution`, `impostor_layout`).

use crate::render::knob::Knob;

pub static KNOBS: &[Knob] = &[
    Knob::number(
        "alpha_cutoff",
        "alpha cut-off",
        "coverage below which an impostor's pixel is dropped, dithered around it (0.5: each pixel drawn with the chance of its coverage)",
        (0.05, 0.95),
        |d| d.impostor.alpha_cutoff,
        |d, v| d.impostor.alpha_cutoff = v,
    )
    .slider(0.05, 0.95, false)
    .tuned(&["0.3", "0.5", "0.7"]),
    Knob::toggle(
        "parallax",
        "depth parallax",
        "move each frame's point along the eye's ray to the depth the frame stored",
        |d| d.impostor.parallax,
        |d, v| d.impostor.parallax = v,
    )
    .tuned(&["off", "on"]),
    Knob::toggle(
        "parallax_depth",
        "depth of the parallax point",
        "write the depth of the point the parallax found (exact where impostors cross) instead of the quad's (the depth test then runs after shading: slower)",
        |d| d.impostor.parallax_depth,
        |d, v| d.impostor.parallax_depth = v,
    ),
    Knob::number(
        "self_shadow",
        "self-shadowing",
        "light's extinction per radius of crown between a point and what the frame nearest the sun (or the zenith) sees first: the impostor's frames as its own shadow maps (0: none)",
        (0.0, 256.0),
        |d| d.impostor.self_shadow,
        |d, v| d.impostor.self_shadow = v,
    )
    .slider(0.0, 64.0, false)
    .tuned(&["0", "16", "64"]),
    Knob::number(
        "geometry_px",
        "geometry above (px)",
        "a tree whose impostor texels project above this many pixels is drawn as geometry, faded in over the last fifth before it (0: never)",
        (0.0, 64.0),
        |d| d.impostor.geometry_px,
        |d, v| d.impostor.geometry_px = v,
    )
    .slider(0.0, 16.0, false)
    .tuned(&["0", "1", "2", "4"]),
    Knob::toggle(
        "vcm",
        "VCM shading (trees shade each other)",
        "shade the trees by the visibility cube maps (when the bake has them)",
        |d| d.impostor.vcm,
        |d, v| d.impostor.vcm = v,
    ),
    Knob::toggle(
        "show_lod",
        "show LOD level",
        "colour each impostor white",
        |d| d.impostor.show_lod,
        |d, v| d.impostor.show_lod = v,
    ),
];
