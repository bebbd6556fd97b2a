//! The `surfel` method: Guennebaud and Paulin's surfel texels (2002) drawn as today's
//! point renderers draw what is smaller than a pixel. Each species is sampled into an LDC
//! tree (`sample/`: three orthogonal layered depth images per block of an octree, a
//! parent level made from its children at twice the spacing); each frame walks every tree
//! in view from its root, drawing each block at the coarsest level whose surfel spacing
//! projects to about one pixel (`prepare.rs`); the blocks are splatted in compute, one
//! surfel to one pixel (a depth pass, then the colours near each pixel's front surface
//! averaged), and the holes filled by pull-push (`gpu.rs`, `shaders/surfel.wgsl`). Lit per
//! surfel by the sun and the sky with the tree-level VCM factors and ground shadows the
//! other image-based methods get.

pub mod gpu;
pub mod knobs;
pub mod method;
pub mod prepare;
pub mod sample;
pub mod settings;

pub use gpu::SurfelAssets;
pub use settings::{SurfelSettings, SurfelStats};
