//! The `btf` method's knobs (`hybrid` takes them too), as the command line, the panel, the
//! bench's sweeps and `tune` see them.

use super::settings::PlaneMode;
use crate::render::knob::Knob;

pub static KNOBS: &[Knob] = &[
    Knob::number(
        "lod_scale",
        "LOD scale px",
        "a level is drawn while its largest texel projects below this many pixels",
        (0.05, 64.0),
        |d| d.btf.lod_scale,
        |d, v| d.btf.lod_scale = v,
    )
    .slider(0.25, 16.0, true)
    .tuned(&["0.5", "1", "2", "4", "8"]),
    Knob::number(
        "weight_threshold",
        "weight threshold",
        "images whose blending weight is below this are skipped (the others renormalised)",
        (0.0, 1.0),
        |d| d.btf.weight_threshold,
        |d, v| d.btf.weight_threshold = v,
    )
    .slider(0.0, 0.5, false)
    .tuned(&["0", "0.1", "0.2", "0.3"]),
    Knob::number(
        "lod_fade",
        "LOD cross-fade band",
        "width of the cross-fade before each level's bound, as a fraction of it (0 = pop)",
        (0.0, 1.0),
        |d| d.btf.lod_fade,
        |d, v| d.btf.lod_fade = v,
    )
    .tuned(&["0", "0.2"]),
    Knob::choice(
        "planes",
        "billboard planes",
        "single: one camera-facing plane per billboard; crossed: three planes, one per sampled view",
        &["single", "crossed"],
        |d| d.btf.planes.name(),
        |d, v| d.btf.planes = PlaneMode::parse(v).unwrap_or(d.btf.planes),
    )
    .tuned(&["single", "crossed"]),
    Knob::toggle(
        "show_lod",
        "show LOD level",
        "colour each billboard by its level (twig red, main branch yellow, tree blue)",
        |d| d.btf.show_lod,
        |d, v| d.btf.show_lod = v,
    ),
    Knob::number(
        "light_gain",
        "light gain between light samples",
        "how far the blend of the 3 nearest light samples is brightened towards the sun's strength: 0 = the plain blend, 1 = the whole gain",
        (0.0, 1.0),
        |d| d.btf.light_gain,
        |d, v| d.btf.light_gain = v,
    ),
    Knob::toggle(
        "vcm",
        "VCM shading (trees shade each other)",
        "shade the trees by the visibility cube maps (when the bake has them)",
        |d| d.btf.vcm,
        |d, v| d.btf.vcm = v,
    ),
    Knob::toggle(
        "vcm_sky",
        "VCM sky occlusion",
        "weight the sky light by the cube maps' mean visibility too (off: they shade the sun light only)",
        |d| d.btf.vcm_sky,
        |d, v| d.btf.vcm_sky = v,
    )
    .when(|d| d.btf.vcm),
    Knob::toggle(
        "show_shadow",
        "show VCM shadow factor",
        "draw each billboard's VCM sun factor alone, in grey (white = fully lit)",
        |d| d.btf.show_shadow,
        |d, v| d.btf.show_shadow = v,
    )
    .when(|d| d.btf.vcm),
    Knob::toggle(
        "gpu_far",
        "far trees' billboards on the GPU",
        "build the billboards of the trees drawn at the tree level alone in compute passes, the CPU preparing the near trees only",
        |d| d.btf.gpu_far,
        |d, v| d.btf.gpu_far = v,
    ),
    Knob::toggle(
        "gpu_near",
        "near trees' billboards on the GPU",
        "with gpu_far: expand the near trees' billboards on the GPU too, the CPU choosing their levels and cross-fades only",
        |d| d.btf.gpu_near,
        |d, v| d.btf.gpu_near = v,
    )
    .when(|d| d.btf.gpu_far),
    Knob::toggle(
        "light_blend",
        "tree level's light blend once per sun",
        "tree-level billboards read their 3 lights' images blended once per sun and yaw bin: 9 image reads a pixel instead of 15",
        |d| d.btf.light_blend,
        |d, v| d.btf.light_blend = v,
    ),
    Knob::toggle(
        "front_to_back",
        "billboards front to back",
        "draw the billboards nearest first into a layer of their own and skip those behind where it is already opaque; off: back to front over the frame",
        |d| d.btf.front_to_back,
        |d, v| d.btf.front_to_back = v,
    ),
    Knob::toggle(
        "compositor",
        "billboards composited by tiles",
        "composite the billboards front to back in compute, one workgroup per 16x16-pixel tile, stopping where a pixel is opaque; off: the rasteriser draws them",
        |d| d.btf.compositor,
        |d, v| d.btf.compositor = v,
    ),
    Knob::number(
        "stop_below",
        "compositor stops below",
        "with the compositor: a pixel stops where what is behind it would add less than this share of its colour (0: never)",
        (0.0, 0.5),
        |d| d.btf.stop_below,
        |d, v| d.btf.stop_below = v,
    )
    .slider(0.0, 0.05, false)
    .when(|d| d.btf.compositor),
    Knob::number(
        "full_above",
        "compositor: full shade above",
        "with the compositor: billboards are shaded in full (3 views) while the pixel lets through more than this, behind by their heaviest view alone (0: all in full)",
        (0.0, 1.0),
        |d| d.btf.full_above,
        |d, v| d.btf.full_above = v,
    )
    .slider(0.0, 1.0, false)
    .when(|d| d.btf.compositor),
    Knob::toggle(
        "far_canopy",
        "far canopy",
        "past the distance where a typical crown is narrower than canopy_px pixels, draw the forest as one layer over the ground (its trees' colours, seen from above) instead of a billboard per tree",
        |d| d.btf.far_canopy,
        |d, v| d.btf.far_canopy = v,
    )
    .when(|d| d.btf.gpu_far)
    .tuned(&["off", "on"]),
    Knob::number(
        "canopy_px",
        "far canopy below (px)",
        "a tree whose crown is narrower than this on screen is drawn by the far canopy (the band where its billboard fades out starts there)",
        (0.5, 64.0),
        |d| d.btf.canopy_px,
        |d, v| d.btf.canopy_px = v,
    )
    .slider(1.0, 16.0, true)
    .when(|d| d.btf.gpu_far && d.btf.far_canopy),
];
