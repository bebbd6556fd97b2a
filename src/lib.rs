//! canopy: a real-time forest viewer. The library holds everything but the window: the
//! scene file, the procedural tree hierarchies and terrain (`model`), the window-free GPU
//! render core (`render`), image metrics (`metrics`) and the viewer shell (`app`), which
//! the `canopy` binary drives.

pub mod app;
pub mod bake;
pub mod bench;
pub mod color;
pub mod error;
pub mod forest_map;
pub mod format;
pub mod imageio;
pub mod lod;
pub mod metrics;
pub mod model;
pub mod progress;
pub mod render;
pub mod scene;
pub mod slices;
pub mod sphere;
pub mod vcm;

pub use error::{Error, Result};
