//! WGSL sources. Each pass has its own file in `shaders/`; the shared parts (`frame.wgsl`:
//! the frame uniforms and the helpers every pass uses; `instancing.wgsl`: the instanced
//! hierarchy and vertex format; `billboard.wgsl`: the billboard record and its quad) are
//! prepended, since WGSL has no include. Everything is embedded at build time, so the binary
//! runs from any directory.

use std::cell::Cell;

thread_local! {
    static COUNTING: Cell<bool> = const { Cell::new(false) };
}

/// Builds the pipelines made in this thread with the overdraw view's counters in them
/// (`COUNT_OVERDRAW` in `frame.wgsl`) or without, until set again. The renderer sets it
/// for its frame and drops its pipelines when it changes.
pub fn set_counting(on: bool) {
    COUNTING.with(|c| c.set(on));
}

/// The pipeline constants of a module with `frame.wgsl` in it.
pub fn frame_options() -> wgpu::PipelineCompilationOptions<'static> {
    const ON: &[(&str, f64)] = &[("COUNT_OVERDRAW", 1.0)];
    wgpu::PipelineCompilationOptions {
        constants: if COUNTING.with(Cell::get) { ON } else { &[] },
        ..Default::default()
    }
}

const FRAME: &str = include_str!("../../shaders/frame.wgsl");
const INSTANCING: &str = include_str!("../../shaders/instancing.wgsl");
const BILLBOARD_RECORD: &str = include_str!("../../shaders/billboard_record.wgsl");
const BILLBOARD: &str = include_str!("../../shaders/billboard.wgsl");
const BTF_FAR: &str = include_str!("../../shaders/btf_far.wgsl");
const BTF_FAR_CANOPY: &str = include_str!("../../shaders/btf_far_canopy.wgsl");
const CANOPY: &str = include_str!("../../shaders/canopy.wgsl");
const GEOMETRY: &str = include_str!("../../shaders/geometry.wgsl");
const SHADOW: &str = include_str!("../../shaders/shadow.wgsl");
const SKY: &str = include_str!("../../shaders/sky.wgsl");
const BTF: &str = include_str!("../../shaders/btf.wgsl");
const GROUND_MAP: &str = include_str!("../../shaders/ground_map.wgsl");
const TEXEL: &str = include_str!("../../shaders/texel.wgsl");
const LIGHT_BLEND: &str = include_str!("../../shaders/light_blend.wgsl");
const BLIT: &str = include_str!("../../shaders/blit.wgsl");
const IMPOSTOR: &str = include_str!("../../shaders/impostor.wgsl");
const OVERDRAW: &str = include_str!("../../shaders/overdraw.wgsl");
const LAYER: &str = include_str!("../../shaders/layer.wgsl");
const COMPOSITOR: &str = include_str!("../../shaders/compositor.wgsl");
const SURFEL: &str = include_str!("../../shaders/surfel.wgsl");

/// A mesh pass's module: frame uniforms, instancing, then the pass's own file.
fn with_instancing(pass: &str) -> String {
    format!("{FRAME}\n{INSTANCING}\n{pass}")
}

/// A pass that draws no meshes: frame uniforms, then the pass's own file.
fn with_frame(pass: &str) -> String {
    format!("{FRAME}\n{pass}")
}

/// A pass that draws billboards: frame uniforms, the BTF atlas's layout, the billboard
/// record, the pass's file.
fn with_billboards(pass: &str) -> String {
    format!(
        "{FRAME}\n{}\n{BILLBOARD_RECORD}\n{BILLBOARD}\n{pass}",
        atlas_side()
    )
}

/// The BTF atlas's images per layer side, as a WGSL constant.
fn atlas_side() -> String {
    let atlas = super::consts::ATLAS_SIDE;
    format!("const BTF_ATLAS_SIDE: u32 = {atlas}u;")
}

/// The `btf` method's light-blend pass: the atlas side, then its file.
pub fn light_blend() -> String {
    format!("{}\n{LIGHT_BLEND}", atlas_side())
}

/// Every shader module the render core builds, by name, for validation and for pipelines.
pub fn all() -> Vec<(&'static str, String)> {
    vec![
        ("geometry", geometry()),
        ("shadow", shadow()),
        ("sky", sky()),
        ("btf", btf()),
        ("btf_far", btf_far()),
        ("canopy", canopy()),
        ("light_blend", light_blend()),
        ("ground_map", ground_map()),
        ("texel", texel()),
        ("impostor", impostor()),
        ("blit", blit()),
        ("overdraw", overdraw()),
        ("layer", layer()),
        ("compositor", compositor()),
        ("surfel", surfel()),
    ]
}

/// The `impostor` method's pass: frame uniforms, then its file.
pub fn impostor() -> String {
    with_frame(IMPOSTOR)
}

pub fn geometry() -> String {
    with_instancing(GEOMETRY)
}

pub fn shadow() -> String {
    with_instancing(SHADOW)
}

pub fn sky() -> String {
    with_frame(SKY)
}

pub fn btf() -> String {
    with_billboards(BTF)
}

/// The tile compositor (src/render/compositor.rs): the btf pass's billboards and their
/// shading, then its file.
/// The `surfel` method's splatting and pull-push passes: frame uniforms, then its file.
pub fn surfel() -> String {
    with_frame(SURFEL)
}

pub fn compositor() -> String {
    with_billboards(&format!("{BTF}\n{COMPOSITOR}"))
}

/// The `btf` method's far trees, built, sorted and gathered in compute passes: the
/// billboard record, its file, then the far canopy's colours.
pub fn btf_far() -> String {
    format!("{BILLBOARD_RECORD}\n{BTF_FAR}\n{BTF_FAR_CANOPY}")
}

/// The `btf` method's far canopy: frame uniforms, then its file.
pub fn canopy() -> String {
    with_frame(CANOPY)
}

/// The `texel` method's pass: frame uniforms, then its file.
pub fn texel() -> String {
    with_frame(TEXEL)
}

/// The overdraw view's heat map: frame uniforms, the sky's full-screen triangle, its file.
pub fn overdraw() -> String {
    with_frame(&format!("{SKY}\n{OVERDRAW}"))
}

/// The trees' layer's full-screen passes (no frame uniforms).
pub fn layer() -> String {
    LAYER.to_string()
}

/// The render scale's upscaling pass (no frame uniforms).
pub fn blit() -> String {
    BLIT.to_string()
}

/// The ground shadow maps' pass: its terrain is drawn with `shadow()`'s vertex stage.
pub fn ground_map() -> String {
    with_billboards(GROUND_MAP)
}
