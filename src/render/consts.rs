//! Constants more than one part of the render core reads: target formats, size limits and
//! the defaults of the reference. A leaf module: it imports nothing of the crate, so every
//! method and every pass can use it without importing each other.

/// Format of the main view's depth (reversed Z).
pub const DEPTH_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Depth32Float;

/// Format of the sun's shadow maps.
pub const SHADOW_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Depth32Float;

/// Sun shadow cascades that follow the camera.
pub const CASCADES: usize = 3;

/// Largest shadow-map side accepted.
pub const MAX_SHADOW_MAP: u32 = 8192;

/// Images per side of one BTF texture layer: the images are packed [`ATLAS_SIDE`]² to a
/// layer (image `i` in layer `i / ATLAS_SIDE²`, square `i % ATLAS_SIDE²` row by row), so
/// that a scene of many prototypes fits the 2048 layers most GPUs allow (three species of
/// three variants at 18 views x 7 lights are 3,402 images). `shaders/billboard.wgsl`'s
/// `btf_sample` reads them, keeping half a texel inside the square at the level sampled.
pub const ATLAS_SIDE: u32 = 4;

/// Directions of the reference's sky visibility (docs/results/geometry.md says how the count was
/// chosen).
pub const SKY_DIRECTIONS: u32 = 64;

/// Default side of a tree's own sun map in the reference, in texels: about 1 cm for a 20 m
/// fir (docs/results/geometry.md has the sizes measured against it).
pub const SELF_MAP_SIZE: u32 = 2048;

/// The show-level overlay's colour of the trees a method draws as geometry in place of its stand-ins (their foliage
/// tint; white on the leaves' own colour reads as pale, so a strong magenta).
pub const GEOMETRY_COLOR: [f32; 3] = [1.6, 0.3, 1.8];
