//! The methods of the render core, one module each, behind one interface
//! ([`RenderMethod`], in [`interface`]): a CPU prepare step (culling, level of detail,
//! expansion, sorting, shading factors; testable without a GPU), the casters it gives the
//! ground shadow maps, its compute passes, its draws in the main pass and what it reports.
//! Everything methods share (targets, timestamps, terrain, sky, the sun cascades, ground
//! maps) stays in the core (`render/mod.rs`); constants more than one method reads are in
//! `render/consts.rs`.
//!
//! Adding a method: its module here (its settings and stats in its own folder), its arm in
//! [`Method`] (`kind.rs`), its entry in [`registry`], and, when it draws from the bake, its
//! slot in [`Bake`]. The command line (`--method`), the viewer's method buttons and the
//! bench's chart follow [`Method::ALL`]; a method's own knobs are still wired by hand into
//! [`crate::render::FrameDesc`], the command line, the panel and the bench's sweeps.

pub mod billboard;
pub mod btf;
pub mod geometry;
pub mod interface;
pub mod kind;
pub mod texel;
pub mod view;

pub use interface::{Bake, DrawCx, GroundCasters, Plan, PrepareCx, RenderMethod, SunWork};
pub use kind::Method;
pub use view::PrepareView;

/// One of each method, as the renderer holds them.
pub fn registry() -> Vec<Box<dyn RenderMethod>> {
    vec![
        Box::new(geometry::Geometry::default()),
        Box::new(btf::method::BtfMethod::new(false)),
        Box::new(billboard::Billboard::default()),
        Box::new(texel::method::TexelMethod::default()),
        Box::new(btf::method::BtfMethod::new(true)),
    ]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_registry_holds_every_method_once() {
        let methods: Vec<Method> = registry().iter().map(|m| m.method()).collect();
        for m in Method::ALL {
            assert_eq!(
                methods.iter().filter(|&&x| x == *m).count(),
                1,
                "{} is not registered exactly once",
                m.name()
            );
        }
        assert_eq!(methods.len(), Method::ALL.len());
    }
}
