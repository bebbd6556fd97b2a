//! The integration tests, in one binary: one link of wgpu, egui and naga, and fixtures baked once
//! per run (`common`) for every module that draws them.

mod common;

mod btf;
mod cli;
mod cli_bake;
mod compositor;
mod compress;
mod far_canopy;
mod frame_memory;
mod front_to_back;
mod fuzz;
mod gltf;
mod gltf_levels;
mod gpu;
mod gpu_layout;
mod ground_shadows;
mod hybrid;
mod images_unchanged;
mod impostor;
mod impostor_draw;
mod layers;
mod light_blend;
mod overlays;
mod panel;
mod passes;
mod progressive;
mod reference;
mod shaders;
mod species;
mod stability;
mod surfel;
mod texel;
mod tune;
mod vcm;
mod viewer;
mod world_edge;
