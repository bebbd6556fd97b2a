//! The `impostor` method: what people who render forests today pick (Unreal's Impostor
//! Baker, Amplify Impostors, Godot-Octahedral-Impostors, three.js octahedral-impostor),
//! on canopy's chart beside `btf`. One quad per tree shows its species' octahedral
//! impostor (src/bake/impostor.rs): the 3 baked frames around the view direction in the
//! tree's own frame, blended by their barycentric weights, each shifted by its stored
//! depth (parallax); albedo and normal blended, then lit per pixel by the sun and sky with
//! the tree-level VCM factors and ground shadows `btf` gets, so that a comparison isolates
//! the representation. Alpha-tested with a dithered threshold and depth-written: opaque,
//! drawn front to back, never sorted for blending.

pub mod assets;
pub mod knobs;
pub mod method;
pub mod prepare;
pub mod settings;

pub use assets::ImpostorAssets;
pub use settings::{ImpostorSettings, ImpostorStats};
