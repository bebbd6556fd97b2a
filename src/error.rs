//! The library's error type: one enum, each variant saying what went wrong and, where it
//! can, what to do about it.

use std::path::PathBuf;

/// Every error the canopy library reports. Binaries turn it into a message and an exit code
/// with [`Error::is_bad_input`].
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum Error {
    #[error(transparent)]
    Scene(#[from] crate::scene::SceneError),

    #[error(transparent)]
    Model(#[from] crate::model::ModelError),

    #[error(transparent)]
    Format(#[from] crate::format::FormatError),

    #[error(
        "no GPU adapter found{0}; on a machine without a GPU install a software Vulkan driver \
         (Debian: apt-get install mesa-vulkan-drivers)"
    )]
    NoAdapter(String),

    #[error("could not create the GPU device on {adapter}: {source}")]
    RequestDevice {
        adapter: String,
        #[source]
        source: wgpu::RequestDeviceError,
    },

    #[error("GPU error: {0}")]
    Gpu(String),

    #[error("could not create a window surface: {0}")]
    CreateSurface(#[from] wgpu::CreateSurfaceError),

    #[error("image size {width}x{height} is not allowed: {reason}")]
    BadSize {
        width: u32,
        height: u32,
        reason: &'static str,
    },

    #[error("could not read image {path}: {source}")]
    ReadImage {
        path: PathBuf,
        #[source]
        source: image::ImageError,
    },

    #[error("could not write image {path}: {reason}")]
    WriteImage { path: PathBuf, reason: String },

    #[error(
        "images differ in size: {a} is {aw}x{ah}, {b} is {bw}x{bh}; compare images of the same size"
    )]
    ImageSizeMismatch {
        a: String,
        aw: u32,
        ah: u32,
        b: String,
        bw: u32,
        bh: u32,
    },

    #[error("{0}")]
    BadInput(String),

    #[error("window system: {0}")]
    Window(String),

    #[error("I/O error on {path}: {source}")]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
}

impl Error {
    /// True when the error comes from what the user gave (a file, an argument) rather than
    /// from the machine; the CLI exits with 2 for these and 1 for the rest.
    pub fn is_bad_input(&self) -> bool {
        if let Error::Format(f) = self {
            return f.needs_rebake();
        }
        matches!(
            self,
            Error::Scene(_)
                | Error::Model(_)
                | Error::BadSize { .. }
                | Error::ReadImage { .. }
                | Error::ImageSizeMismatch { .. }
                | Error::BadInput(_)
        )
    }
}

pub type Result<T, E = Error> = std::result::Result<T, E>;
