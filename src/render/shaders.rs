//! WGSL sources. Each pass has its own file in `shaders/`; `common.wgsl` (frame uniforms,
//! the instanced hierarchy, the vertex format) is prepended to each, since WGSL has no
//! include. Everything is embedded at build time, so the binary runs from any directory.

const COMMON: &str = include_str!("../../shaders/common.wgsl");
const GEOMETRY: &str = include_str!("../../shaders/geometry.wgsl");
const SHADOW: &str = include_str!("../../shaders/shadow.wgsl");
const SKY: &str = include_str!("../../shaders/sky.wgsl");

/// A pass's full WGSL module: the shared prelude and the pass's own file.
fn with_common(pass: &str) -> String {
    format!("{COMMON}\n{pass}")
}

/// Every shader module the render core builds, by name, for validation and for pipelines.
pub fn all() -> Vec<(&'static str, String)> {
    vec![
        ("geometry", geometry()),
        ("shadow", shadow()),
        ("sky", sky()),
    ]
}

pub fn geometry() -> String {
    with_common(GEOMETRY)
}

pub fn shadow() -> String {
    with_common(SHADOW)
}

pub fn sky() -> String {
    with_common(SKY)
}
