//! canopy: a real-time forest viewer. The library holds everything but the window: the
//! scene file, the procedural tree hierarchies and terrain (`model`), the window-free GPU
//! render core (`render`), image metrics (`metrics`), the viewer shell (`app`) and the
//! command line (`cli`), which the `canopy` binary parses and runs.

pub mod app;
pub mod atomic_file;
pub mod bake;
pub mod bench;
pub mod cli;
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
