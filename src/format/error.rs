//! The error of reading or writing a `.canopy` file.

use std::io;
use std::path::PathBuf;

/// Everything that can go wrong reading or writing a `.canopy` file. Every variant but
/// [`FormatError::Io`] means the file (or the data given to write) is unusable and the
/// scene must be baked again; see [`FormatError::needs_rebake`].
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum FormatError {
    /// The operating system refused a read, write, sync or rename.
    #[error("{action} {}: {source}", path.display())]
    Io {
        path: PathBuf,
        /// What was being done, e.g. "could not open".
        action: &'static str,
        #[source]
        source: io::Error,
    },

    /// The file does not start with [`MAGIC`](super::MAGIC).
    #[error(
        "not a canopy file: it starts with \"{}\" where a .canopy file starts with \"CANOPY\\r\\n\" \
         (a file whose line endings were converted in transfer looks like this too); \
         give a file written by `canopy bake`, or re-bake with `canopy bake`",
        found.escape_ascii()
    )]
    NotCanopy {
        /// The first bytes of the file (up to 8).
        found: Vec<u8>,
    },

    /// The file has another format version.
    #[error(
        "the .canopy file has format version {found}, but this canopy reads versions \
         {oldest} to {supported}; re-bake with `canopy bake`"
    )]
    UnsupportedVersion {
        found: u32,
        oldest: u32,
        supported: u32,
    },

    /// The file ends before something it declares.
    #[error(
        "the .canopy file is truncated: {what} needs {needed} bytes but only {available} are \
         there (an interrupted copy or download?); copy it again or re-bake with `canopy bake`"
    )]
    Truncated {
        what: String,
        needed: u64,
        available: u64,
    },

    /// A checksum does not match its bytes.
    #[error(
        "the .canopy file is corrupt: the checksum of the {section} does not match its bytes \
         (stored {stored:08x}, computed {computed:08x}); re-bake with `canopy bake`"
    )]
    ChecksumMismatch {
        /// "header", or "section 3 (btf image sets)".
        section: String,
        stored: u32,
        computed: u32,
    },

    /// A size or count is beyond what the format allows.
    #[error(
        "size out of range: {field} is {value}, over the limit of {limit} (a corrupt file, or a \
         bake too large for the format); re-bake with `canopy bake`, with fewer views or lights \
         or a lower resolution if the bake itself is too large"
    )]
    AbsurdSize {
        field: String,
        value: u64,
        limit: u64,
    },

    /// A section (or the data given to write) does not decode to what its header promises.
    #[error(
        "malformed canopy data in {section}: {reason}; re-bake with `canopy bake` \
         (a bake that produces this is a bug)"
    )]
    MalformedContent { section: String, reason: String },

    /// A bake setting is outside the allowed values.
    #[error(
        "invalid bake setting {field} = {value} (allowed: {allowed}); fix the bake settings \
         and re-bake with `canopy bake`"
    )]
    InvalidSettings {
        field: &'static str,
        value: u32,
        allowed: &'static str,
    },

    /// The file was baked from another scene or with other settings.
    #[error(
        "the .canopy file was baked for another scene or other bake settings (scene hash \
         {found:016x}, expected {expected:016x}); re-bake with `canopy bake`"
    )]
    SceneMismatch { found: u64, expected: u64 },
}

impl FormatError {
    /// True when the file exists but cannot be used as it is (corrupt, truncated, stale,
    /// another version): a cache should bake again and overwrite it. False for I/O errors.
    pub fn needs_rebake(&self) -> bool {
        !matches!(self, FormatError::Io { .. })
    }

    /// True for an I/O error saying the file does not exist.
    pub fn is_not_found(&self) -> bool {
        matches!(self, FormatError::Io { source, .. } if source.kind() == io::ErrorKind::NotFound)
    }
}
