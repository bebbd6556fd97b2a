//! Pure-CPU scene model: deterministic generation of tree species (a hierarchy of instanced
//! parts: twig → main branch → tree), the terrain heightfield and the placement of the forest.
//!
//! Nothing here touches the GPU. Every generator is deterministic for its parameters and seed,
//! validates its input first (counts and resolutions are checked against sane maxima before
//! anything is allocated) and reports problems as [`ModelError`].

pub mod far_cover;
pub mod forest;
pub mod gltf;
pub mod level;
pub mod mesh;
pub mod params;
pub mod rng;
pub mod silhouette;
pub mod species;
pub mod stands;
pub mod summary;
pub mod terrain;
pub mod terrain_lod;
pub mod tree;
pub mod world;

pub use forest::{Forest, TreeInstance};
pub use level::{Level, PerLevel};
pub use mesh::{Aabb, Mesh, Vertex};
pub use params::{BakeParams, ForestParams, SpeciesEntry, StandParams, TerrainParams, TreeVcm};
pub use species::{CrownShape, FoliageKind, PRESET_NAMES, SpeciesParams, TwigArrangement, preset};
pub use terrain::Terrain;
pub use tree::{LevelCounts, PartCounts, TreeModel};
pub use world::World;

/// A problem with one parameter, named relative to its parameter block (for example `count`,
/// `mix[2]` or `trunk_radius`). The scene loader prefixes the block's own path, adds the line
/// number and shows the value as written in the file.
#[derive(Clone, Debug, PartialEq)]
pub struct FieldError {
    /// Field name relative to the parameter block, dotted for nested values.
    pub field: String,
    /// What is wrong, e.g. `must be > 0`.
    pub message: String,
    /// The offending value, if one is to be shown (`found ...`).
    pub found: Option<String>,
}

impl FieldError {
    /// A new field error without a shown value.
    pub fn new(field: impl Into<String>, message: impl Into<String>) -> Self {
        Self {
            field: field.into(),
            message: message.into(),
            found: None,
        }
    }

    /// The same error showing `value` as what was found.
    pub fn with_found(mut self, value: impl std::fmt::Display) -> Self {
        self.found = Some(value.to_string());
        self
    }

    /// The same error with `prefix.` put in front of the field name.
    pub fn prefixed(mut self, prefix: &str) -> Self {
        self.field = if self.field.is_empty() {
            prefix.to_owned()
        } else if self.field.starts_with('[') {
            format!("{prefix}{}", self.field)
        } else {
            format!("{prefix}.{}", self.field)
        };
        self
    }

    /// The message with the found value, e.g. `must be > 0, found -3`.
    pub fn describe(&self) -> String {
        match &self.found {
            Some(f) => format!("{}, found {f}", self.message),
            None => self.message.clone(),
        }
    }
}

impl std::fmt::Display for FieldError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}: {}", self.field, self.describe())
    }
}

/// Errors from the model generators.
#[derive(Debug, thiserror::Error)]
pub enum ModelError {
    /// A parameter is out of range; `context` names the parameter block (`terrain`,
    /// `forest`, `species \`fir\``).
    #[error("{context}: {error}")]
    InvalidParameter {
        /// Which parameter block.
        context: String,
        /// Which field and why.
        error: FieldError,
    },
    /// The forest could not be placed with the requested count and spacing.
    #[error(
        "forest: only {placed} of the requested {requested} trees fit with forest.min_spacing = {min_spacing} m \
         on a {size} m terrain (after {attempts} attempts); lower {asked_by} or forest.min_spacing, \
         or enlarge terrain.size"
    )]
    ForestDoesNotFit {
        /// Trees that were placed before giving up.
        placed: u32,
        /// Trees that were asked for.
        requested: u32,
        /// The minimum spacing in metres.
        min_spacing: f32,
        /// The terrain's side length in metres.
        size: f32,
        /// Dart-throwing attempts made.
        attempts: u64,
        /// The key that asked for the trees: `forest.count` or `forest.density`.
        asked_by: &'static str,
    },
    /// A scene entry names a species preset that does not exist.
    #[error("species `{name}`: unknown preset `{preset}`; expected one of {}", PRESET_NAMES.join(", "))]
    UnknownPreset {
        /// The species entry's name.
        name: String,
        /// The preset that was asked for.
        preset: String,
    },
    /// A scene entry gives neither or both of `preset` and `params`.
    #[error("species `{name}`: give exactly one of `preset`, `params` and `gltf`")]
    AmbiguousSpecies {
        /// The species entry's name.
        name: String,
    },
    /// A `gltf` species' file cannot be used.
    #[error("species `{name}`: {error}")]
    Import {
        /// The species entry's name.
        name: String,
        /// The file and what is wrong with it.
        error: gltf::GltfError,
    },
}

impl ModelError {
    /// Wraps a [`FieldError`] of the named parameter block.
    pub fn invalid(context: impl Into<String>, error: FieldError) -> Self {
        ModelError::InvalidParameter {
            context: context.into(),
            error,
        }
    }
}

/// Serde helpers shared by the parameter types.
pub mod serde_util {
    use serde::Deserializer;
    use serde::de::{Error, IgnoredAny, SeqAccess, Visitor};

    /// Deserialises exactly three numbers (`[r, g, b]` or `[x, y, z]`). Unlike the default
    /// for `[f32; 3]`, extra elements are an error rather than silently ignored. Nothing is
    /// allocated, whatever the input.
    pub fn vec3<'de, D: Deserializer<'de>>(d: D) -> Result<[f32; 3], D::Error> {
        struct V;
        impl<'de> Visitor<'de> for V {
            type Value = [f32; 3];
            fn expecting(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
                f.write_str("an array of 3 numbers")
            }
            fn visit_seq<A: SeqAccess<'de>>(self, mut seq: A) -> Result<[f32; 3], A::Error> {
                let mut out = [0.0f32; 3];
                let mut n = 0usize;
                while n < 3 {
                    match seq.next_element::<f32>()? {
                        Some(v) => out[n] = v,
                        None => return Err(A::Error::invalid_length(n, &self)),
                    }
                    n += 1;
                }
                while seq.next_element::<IgnoredAny>()?.is_some() {
                    n += 1;
                }
                if n == 3 {
                    Ok(out)
                } else {
                    Err(A::Error::invalid_length(n, &self))
                }
            }
        }
        d.deserialize_seq(V)
    }
}

/// Small shared checks used by the parameter validators. Each returns a [`FieldError`] that
/// names the field and the offending value.
pub mod check {
    use super::FieldError;

    /// `value` must be finite.
    pub fn finite(field: &str, value: f32) -> Result<(), FieldError> {
        if value.is_finite() {
            Ok(())
        } else {
            Err(FieldError::new(field, "must be a finite number").with_found(value))
        }
    }

    /// `value` must be finite and strictly positive.
    pub fn positive(field: &str, value: f32) -> Result<(), FieldError> {
        finite(field, value)?;
        if value > 0.0 {
            Ok(())
        } else {
            Err(FieldError::new(field, "must be > 0").with_found(value))
        }
    }

    /// `value` must be finite and within `lo..=hi`.
    pub fn range(field: &str, value: f32, lo: f32, hi: f32) -> Result<(), FieldError> {
        finite(field, value)?;
        if (lo..=hi).contains(&value) {
            Ok(())
        } else {
            Err(FieldError::new(field, format!("must be between {lo} and {hi}")).with_found(value))
        }
    }

    /// Integer `value` must be within `lo..=hi`.
    pub fn range_u32(field: &str, value: u32, lo: u32, hi: u32) -> Result<(), FieldError> {
        if (lo..=hi).contains(&value) {
            Ok(())
        } else {
            Err(FieldError::new(field, format!("must be between {lo} and {hi}")).with_found(value))
        }
    }

    /// An RGB colour: three finite components, each within `0..=max`.
    pub fn color(field: &str, value: [f32; 3], max: f32) -> Result<(), FieldError> {
        for (i, c) in value.iter().enumerate() {
            let f = format!("{field}[{i}]");
            finite(&f, *c)?;
            if !(0.0..=max).contains(c) {
                return Err(FieldError::new(
                    f,
                    format!("colour components must be between 0 and {max}"),
                )
                .with_found(c));
            }
        }
        Ok(())
    }

    /// A point or direction: three finite components within `-max..=max`.
    pub fn vec3(field: &str, value: [f32; 3], max: f32) -> Result<(), FieldError> {
        for (i, c) in value.iter().enumerate() {
            range(&format!("{field}[{i}]"), *c, -max, max)?;
        }
        Ok(())
    }
}
