//! The methods of the render core, one module each. A method turns the frame's visible
//! trees into what it draws: a CPU prepare step (culling, level of detail, expansion,
//! sorting, shading factors; testable without a GPU) and the draws it adds to the passes
//! the core runs. Everything methods share (targets, timestamps, terrain, sky, shadow
//! cascades' textures, ground maps) stays in the core (`render/mod.rs`).
//!
//! Adding a method means a module here, an arm in `frame::Method` and its `Prepared` arm
//! and draw call in `Renderer::render`.

pub mod billboard;
pub mod btf;
pub mod geometry;
pub mod texel;
