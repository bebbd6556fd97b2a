//! Scene files: the TOML description of a forest scene (terrain, species, placement, sun,
//! sky, start camera), its loading and validation. Every problem is reported with the file
//! name, the line and the dotted key, e.g.
//! `scene.toml:14: forest.count: expected a non-negative integer, found -5`.

use std::ops::Range;
use std::path::{Path, PathBuf};

use glam::Vec3;
use serde::{Deserialize, Serialize};
use toml::de::{DeTable, DeValue};

pub use crate::model::params::{
    BAKE_DIRECTIONS, BAKE_RESOLUTIONS, BakeParams, ForestParams, MAX_SPECIES, MAX_TREES,
    SpeciesEntry, TERRAIN_RESOLUTION, TerrainParams, TexelParams, TexelSource,
};

fn is_default_texel(t: &TexelParams) -> bool {
    *t == TexelParams::default()
}
use crate::model::species::{PRESET_NAMES, preset};
use crate::model::{FieldError, ModelError, World, check};

/// The embedded default scene (1,000 trees on 1 km² of hills): the scene of every command
/// but the viewer, of the bench and of the tests; it documents the format.
pub const DEFAULT_SCENE_TOML: &str = include_str!("../assets/default.toml");

/// The embedded example forest at real density (`assets/scenes/forest.toml`): what the
/// viewer opens when given no scene.
pub const FOREST_SCENE_TOML: &str = include_str!("../assets/scenes/forest.toml");

/// One stand of the example forest, 250 m a side (`assets/scenes/stand.toml`).
pub const STAND_SCENE_TOML: &str = include_str!("../assets/scenes/stand.toml");

/// The example scenes embedded in the binary (the viewer's scene menu): name, a line on
/// what it is, and the scene file's text.
pub const EXAMPLE_SCENES: &[(&str, &str, &str)] = &[
    (
        "forest",
        "a forest at 600 trees per hectare: stands, clearings, meadows, about 36,000 trees (the viewer's default; a bake of about 5 minutes)",
        FOREST_SCENE_TOML,
    ),
    (
        "default",
        "1,000 trees spread over 1 km² of hills (the bench's and the tests' scene; a bake of about a minute)",
        DEFAULT_SCENE_TOML,
    ),
    (
        "stand",
        "one stand of that forest, 250 m a side at the same density: about 1,800 trees (a bake of minutes)",
        STAND_SCENE_TOML,
    ),
];

/// The small test scene (used by tests; about 30 trees on 100 m).
#[cfg(test)]
pub const SMALL_TEST_SCENE_TOML: &str = include_str!("../tests/data/small.toml");

/// Largest scene file accepted (bytes).
pub const MAX_SCENE_BYTES: u64 = 16 * 1024 * 1024;

/// A whole scene.
#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Scene {
    /// `[terrain]`
    pub terrain: TerrainParams,
    /// `[[species]]`, one entry per species.
    pub species: Vec<SpeciesEntry>,
    /// `[forest]`
    pub forest: ForestParams,
    /// `[sun]`
    pub sun: SunParams,
    /// `[sky]`
    pub sky: SkyParams,
    /// `[camera]`
    pub camera: CameraParams,
    /// `[bake]`: how BTF images are sampled. Optional, every key too.
    #[serde(default)]
    pub bake: BakeParams,
    /// `[texel]`: how the texel volumes are made. Optional, every key too.
    #[serde(default, skip_serializing_if = "is_default_texel")]
    pub texel: TexelParams,
    /// `[render]`: the `btf` knobs the viewer and `render` start from (what `canopy tune`
    /// writes). Optional, every key too.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub render: Option<RenderParams>,
}

/// `[render]`: starting values of the `btf` method's knobs.
#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct RenderParams {
    /// A level is used while its largest texel projects below this many pixels (0.05..=64).
    pub lod_scale: Option<f32>,
    /// Images whose blending weight is below this are skipped (0..=1).
    pub weight_threshold: Option<f32>,
    /// Width of the LOD cross-fade band, as a fraction of the bound (0..=1).
    pub lod_fade: Option<f32>,
    /// `single` or `crossed`.
    pub planes: Option<String>,
}

impl RenderParams {
    fn check(&self) -> Result<(), FieldError> {
        let range = |key: &str, v: Option<f32>, lo: f32, hi: f32| match v {
            Some(x) if !(lo..=hi).contains(&x) => {
                Err(FieldError::new(key, format!("must be a number in {lo}..={hi}")).with_found(x))
            }
            _ => Ok(()),
        };
        range("lod_scale", self.lod_scale, 0.05, 64.0)?;
        range("weight_threshold", self.weight_threshold, 0.0, 1.0)?;
        range("lod_fade", self.lod_fade, 0.0, 1.0)?;
        if let Some(p) = &self.planes
            && p != "single"
            && p != "crossed"
        {
            return Err(FieldError::new("planes", "must be `single` or `crossed`").with_found(p));
        }
        Ok(())
    }
}

/// `[sun]`: the directional light.
#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct SunParams {
    /// Degrees; 0 = towards +Z (north), 90 = towards +X (east), clockwise seen from above.
    pub azimuth: f32,
    /// Degrees above the horizon (-90..=90).
    pub elevation: f32,
    /// Linear RGB colour.
    #[serde(deserialize_with = "crate::model::serde_util::vec3")]
    pub color: [f32; 3],
    /// Multiplier on `color`.
    pub intensity: f32,
}

impl SunParams {
    /// Unit vector from the ground towards the sun.
    pub fn direction(&self) -> Vec3 {
        sun_direction(self.azimuth, self.elevation)
    }

    /// Colour times intensity.
    pub fn radiance(&self) -> Vec3 {
        Vec3::from(self.color) * self.intensity
    }
}

/// `[sky]`: hemispherical ambient light.
#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct SkyParams {
    /// Linear RGB of the sky at the zenith (ambient from above).
    #[serde(deserialize_with = "crate::model::serde_util::vec3")]
    pub color: [f32; 3],
    /// Linear RGB of the light bounced from the ground (ambient from below).
    #[serde(deserialize_with = "crate::model::serde_util::vec3")]
    pub ground_color: [f32; 3],
    /// Multiplier on both colours.
    pub intensity: f32,
}

/// `[camera]`: the start view.
#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct CameraParams {
    /// Eye position (m, world).
    #[serde(deserialize_with = "crate::model::serde_util::vec3")]
    pub position: [f32; 3],
    /// Point looked at (m, world).
    #[serde(deserialize_with = "crate::model::serde_util::vec3")]
    pub look_at: [f32; 3],
    /// Vertical field of view (degrees).
    pub fov_deg: f32,
}

/// Unit vector pointing from the ground towards the sun. Azimuth in degrees: 0 = +Z
/// (north), clockwise seen from above towards +X (east) at 90; elevation in degrees above
/// the horizon.
pub fn sun_direction(azimuth_deg: f32, elevation_deg: f32) -> Vec3 {
    let (az, el) = (azimuth_deg.to_radians(), elevation_deg.to_radians());
    Vec3::new(az.sin() * el.cos(), el.sin(), az.cos() * el.cos())
        .try_normalize()
        .unwrap_or(Vec3::Y)
}

/// Errors from loading a scene file.
#[derive(Debug, thiserror::Error)]
pub enum SceneError {
    /// The file could not be read.
    #[error("cannot read scene file `{}`: {source}", path.display())]
    Io {
        /// The path as given.
        path: PathBuf,
        /// Why.
        source: std::io::Error,
    },
    /// The file is larger than [`MAX_SCENE_BYTES`].
    #[error("scene file `{}` is {size} bytes; scene files are limited to {MAX_SCENE_BYTES} bytes", path.display())]
    TooLarge {
        /// The path as given.
        path: PathBuf,
        /// Its size in bytes.
        size: u64,
    },
    /// The text is not valid TOML.
    #[error("{origin}:{line}: TOML syntax error: {message}")]
    Syntax {
        /// File name used in messages.
        origin: String,
        /// 1-based line.
        line: usize,
        /// What the TOML parser said.
        message: String,
    },
    /// A key is unknown, missing, of the wrong type or out of range.
    #[error("{origin}:{line}: {key}: {message}")]
    Invalid {
        /// File name used in messages.
        origin: String,
        /// 1-based line.
        line: usize,
        /// Dotted key, e.g. `forest.count` or `species[1].params.height`.
        key: String,
        /// What is wrong.
        message: String,
    },
}

impl SceneError {
    /// The 1-based line the error points at, if any.
    pub fn line(&self) -> Option<usize> {
        match self {
            SceneError::Syntax { line, .. } | SceneError::Invalid { line, .. } => Some(*line),
            _ => None,
        }
    }

    /// The dotted key the error is about, if any.
    pub fn key(&self) -> Option<&str> {
        match self {
            SceneError::Invalid { key, .. } => Some(key),
            _ => None,
        }
    }
}

impl Default for Scene {
    /// The embedded default scene.
    fn default() -> Self {
        Scene::default_scene()
    }
}

impl Scene {
    /// Parses and validates scene text; `origin` is the file name used in messages.
    pub fn parse(text: &str, origin: &str) -> Result<Scene, SceneError> {
        let doc = DeTable::parse(text).map_err(|e| {
            let span = e.span().unwrap_or(0..0);
            let mut message = e.message().trim().to_owned();
            if message == "duplicate key"
                && let Some(k) = text.get(span.clone())
            {
                message = format!("duplicate key `{}`", k.trim());
            }
            SceneError::Syntax {
                origin: origin.to_owned(),
                line: line_of(text, span.start),
                message,
            }
        })?;
        let locator = Locator {
            text,
            origin,
            root: doc.get_ref(),
        };
        let scene: Scene = toml::from_str(text).map_err(|e| locator.serde_error(&e))?;
        scene.check().map_err(|e| locator.field_error(e))?;
        Ok(scene)
    }

    /// Reads, parses and validates the scene file at `path`.
    pub fn load(path: &Path) -> Result<Scene, SceneError> {
        let io = |source| SceneError::Io {
            path: path.to_path_buf(),
            source,
        };
        let size = std::fs::metadata(path).map_err(io)?.len();
        if size > MAX_SCENE_BYTES {
            return Err(SceneError::TooLarge {
                path: path.to_path_buf(),
                size,
            });
        }
        let text = std::fs::read_to_string(path).map_err(io)?;
        Scene::parse(&text, &path.display().to_string())
    }

    /// The embedded example scene `name` (see [`EXAMPLE_SCENES`]), or `None` for a name
    /// that is not one.
    pub fn example(name: &str) -> Option<Result<Scene, SceneError>> {
        EXAMPLE_SCENES
            .iter()
            .find(|(n, _, _)| *n == name)
            .map(|(n, _, text)| Scene::parse(text, &format!("{n}.toml")))
    }

    /// The embedded default scene (`assets/default.toml`): 1,000 trees, the scene of every
    /// command but the viewer when none is named.
    pub fn default_scene() -> Scene {
        // Embedded text, not user input; a test checks that it parses.
        Scene::parse(DEFAULT_SCENE_TOML, "default.toml")
            .unwrap_or_else(|e| panic!("the embedded default scene is invalid: {e}"))
    }

    /// What the viewer opens when given no scene: the example forest at real density
    /// (`assets/scenes/forest.toml`, about 36,000 trees).
    pub fn viewer_scene() -> Scene {
        // Embedded text, not user input; a test checks that it parses.
        Scene::parse(FOREST_SCENE_TOML, "forest.toml")
            .unwrap_or_else(|e| panic!("the embedded example forest is invalid: {e}"))
    }

    /// Builds the world of this scene: its terrain, species prototypes and forest
    /// (see [`World::build`]). Deterministic for the scene.
    pub fn build_world(&self) -> Result<World, ModelError> {
        let mut world = World::build(&self.terrain, &self.species, &self.forest)?;
        world.tree_vcm = self.bake.tree_vcm;
        Ok(world)
    }

    /// Checks every value (after deserialisation); the error names the full dotted key.
    pub fn check(&self) -> Result<(), FieldError> {
        self.terrain.check().map_err(|e| e.prefixed("terrain"))?;
        if self.species.is_empty() {
            return Err(FieldError::new(
                "species",
                "at least one [[species]] entry is needed",
            ));
        }
        for (i, s) in self.species.iter().enumerate() {
            check::range_u32(
                &format!("species[{i}].variants"),
                s.variants,
                1,
                crate::model::params::MAX_VARIANTS,
            )?;
        }
        let prototypes: usize = self.species.iter().map(|s| s.variants as usize).sum();
        if prototypes > MAX_SPECIES {
            return Err(FieldError::new(
                "species",
                format!("at most {MAX_SPECIES} species prototypes (variants included) are allowed"),
            )
            .with_found(prototypes));
        }
        if self.species.len() > MAX_SPECIES {
            return Err(FieldError::new(
                "species",
                format!("at most {MAX_SPECIES} species are allowed"),
            )
            .with_found(self.species.len()));
        }
        for (i, s) in self.species.iter().enumerate() {
            let at = format!("species[{i}]");
            if s.name.trim().is_empty() {
                return Err(FieldError::new(format!("{at}.name"), "must not be empty"));
            }
            if self.species[..i].iter().any(|o| o.name == s.name) {
                return Err(FieldError::new(
                    format!("{at}.name"),
                    format!("duplicate species name `{}`", s.name),
                ));
            }
            match (&s.preset, &s.params) {
                (Some(_), Some(_)) => {
                    return Err(FieldError::new(
                        format!("{at}.preset"),
                        "give either `preset` or a [species.params] table, not both",
                    ));
                }
                (None, None) => {
                    return Err(FieldError::new(
                        at,
                        format!(
                            "give `preset` (one of {}) or a [species.params] table",
                            PRESET_NAMES.join(", ")
                        ),
                    ));
                }
                (Some(name), None) => {
                    if preset(name).is_none() {
                        return Err(FieldError::new(
                            format!("{at}.preset"),
                            format!(
                                "unknown preset `{name}`; expected one of {}",
                                PRESET_NAMES.join(", ")
                            ),
                        ));
                    }
                }
                (None, Some(p)) => p.check().map_err(|e| e.prefixed(&format!("{at}.params")))?,
            }
        }
        self.forest
            .check(self.species.len())
            .map_err(|e| e.prefixed("forest"))?;
        let sun = &self.sun;
        check::range("sun.azimuth", sun.azimuth, -360.0, 360.0)?;
        check::range("sun.elevation", sun.elevation, -90.0, 90.0)?;
        check::color("sun.color", sun.color, 100.0)?;
        check::range("sun.intensity", sun.intensity, 0.0, 1000.0)?;
        check::color("sky.color", self.sky.color, 100.0)?;
        check::color("sky.ground_color", self.sky.ground_color, 100.0)?;
        check::range("sky.intensity", self.sky.intensity, 0.0, 1000.0)?;
        let cam = &self.camera;
        check::vec3("camera.position", cam.position, 1e6)?;
        check::vec3("camera.look_at", cam.look_at, 1e6)?;
        if Vec3::from(cam.position).distance(Vec3::from(cam.look_at)) < 1e-3 {
            return Err(FieldError::new(
                "camera.look_at",
                "must differ from camera.position",
            ));
        }
        check::range("camera.fov_deg", cam.fov_deg, 1.0, 170.0)?;
        self.bake.check().map_err(|e| e.prefixed("bake"))?;
        self.texel.check().map_err(|e| e.prefixed("texel"))?;
        if let Some(r) = &self.render {
            r.check().map_err(|e| e.prefixed("render"))?;
        }
        Ok(())
    }
}

/// 1-based line of byte offset `pos`.
fn line_of(text: &str, pos: usize) -> usize {
    let pos = pos.min(text.len());
    text.as_bytes()[..pos]
        .iter()
        .filter(|&&b| b == b'\n')
        .count()
        + 1
}

/// One step of a dotted key path.
#[derive(Clone, Debug, PartialEq)]
enum Seg {
    Key(String),
    Index(usize),
}

fn path_string(path: &[Seg]) -> String {
    let mut s = String::new();
    for seg in path {
        match seg {
            Seg::Key(k) => {
                if !s.is_empty() {
                    s.push('.');
                }
                s.push_str(k);
            }
            Seg::Index(i) => s.push_str(&format!("[{i}]")),
        }
    }
    s
}

/// Splits `species[1].params.height` into segments.
fn parse_path(path: &str) -> Vec<Seg> {
    let mut out = Vec::new();
    for part in path.split('.') {
        let mut rest = part;
        if let Some(b) = rest.find('[') {
            if b > 0 {
                out.push(Seg::Key(rest[..b].to_owned()));
            }
            rest = &rest[b..];
            while let Some(stripped) = rest.strip_prefix('[') {
                let Some(end) = stripped.find(']') else { break };
                if let Ok(i) = stripped[..end].parse() {
                    out.push(Seg::Index(i));
                }
                rest = &stripped[end + 1..];
            }
        } else if !rest.is_empty() {
            out.push(Seg::Key(rest.to_owned()));
        }
    }
    out
}

/// Where a span points in the document tree.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Hit {
    Key,
    Value,
}

/// Finds keys and lines in the parsed document for error messages.
struct Locator<'a> {
    text: &'a str,
    origin: &'a str,
    root: &'a DeTable<'a>,
}

impl Locator<'_> {
    fn invalid(&self, line: usize, key: String, message: String) -> SceneError {
        SceneError::Invalid {
            origin: self.origin.to_owned(),
            line,
            key,
            message,
        }
    }

    /// Span of the value at `path`, or of the deepest existing ancestor.
    fn span_of(&self, path: &[Seg]) -> Option<Range<usize>> {
        let mut table = self.root;
        let mut value: Option<&toml::Spanned<DeValue<'_>>> = None;
        let mut best = None;
        for seg in path {
            let next = match (seg, value.map(|v| v.get_ref())) {
                (Seg::Key(k), None) => table.get(k.as_str()),
                (Seg::Key(k), Some(DeValue::Table(t))) => {
                    table = t;
                    table.get(k.as_str())
                }
                (Seg::Index(i), Some(DeValue::Array(a))) => a.get(*i),
                _ => None,
            };
            match next {
                Some(v) => {
                    best = Some(v.span());
                    value = Some(v);
                }
                None => break,
            }
        }
        best
    }

    /// The raw text of the value at `path` if it exists exactly there.
    fn raw_value(&self, path: &[Seg]) -> Option<String> {
        let mut table = self.root;
        let mut value: Option<&toml::Spanned<DeValue<'_>>> = None;
        for seg in path {
            let next = match (seg, value.map(|v| v.get_ref())) {
                (Seg::Key(k), None) => table.get(k.as_str()),
                (Seg::Key(k), Some(DeValue::Table(t))) => {
                    table = t;
                    table.get(k.as_str())
                }
                (Seg::Index(i), Some(DeValue::Array(a))) => a.get(*i),
                _ => None,
            };
            value = Some(next?);
        }
        let v = value?;
        match v.get_ref() {
            DeValue::Table(_) | DeValue::Array(_) => None,
            _ => self.text.get(v.span()).map(|s| s.trim().to_owned()),
        }
    }

    /// A semantic error: locate its key's line and show the value as written.
    fn field_error(&self, mut e: FieldError) -> SceneError {
        let path = parse_path(&e.field);
        let line = self
            .span_of(&path)
            .map(|s| line_of(self.text, s.start))
            .unwrap_or(1);
        if e.found.is_some()
            && let Some(raw) = self.raw_value(&path)
        {
            e.found = Some(raw);
        }
        self.invalid(line, e.field.clone(), e.describe())
    }

    /// The deepest key or value whose span is (or contains) `span`.
    fn find(&self, span: &Range<usize>) -> Option<(Vec<Seg>, Hit)> {
        fn walk(
            table: &DeTable<'_>,
            path: &mut Vec<Seg>,
            span: &Range<usize>,
            best: &mut Option<(Vec<Seg>, Hit, bool)>,
        ) {
            for (k, v) in table.iter() {
                path.push(Seg::Key(k.get_ref().to_string()));
                consider(k.span(), Hit::Key, path, span, best);
                visit(v, path, span, best);
                path.pop();
            }
        }
        fn visit(
            v: &toml::Spanned<DeValue<'_>>,
            path: &mut Vec<Seg>,
            span: &Range<usize>,
            best: &mut Option<(Vec<Seg>, Hit, bool)>,
        ) {
            consider(v.span(), Hit::Value, path, span, best);
            match v.get_ref() {
                DeValue::Table(t) => walk(t, path, span, best),
                DeValue::Array(a) => {
                    for (i, e) in a.iter().enumerate() {
                        path.push(Seg::Index(i));
                        visit(e, path, span, best);
                        path.pop();
                    }
                }
                _ => {}
            }
        }
        fn consider(
            s: Range<usize>,
            hit: Hit,
            path: &[Seg],
            span: &Range<usize>,
            best: &mut Option<(Vec<Seg>, Hit, bool)>,
        ) {
            let exact = s == *span;
            let contains = s.start <= span.start && span.end <= s.end && s.start < s.end;
            if !(exact || contains) {
                return;
            }
            let better = match best {
                None => true,
                Some((p, _, was_exact)) => {
                    (exact && !*was_exact) || (exact == *was_exact && path.len() > p.len())
                }
            };
            if better {
                *best = Some((path.to_vec(), hit, exact));
            }
        }
        let mut best = None;
        walk(self.root, &mut Vec::new(), span, &mut best);
        best.map(|(p, h, _)| (p, h))
    }

    /// Turns a deserialisation error (unknown key, missing key, wrong type, bad value)
    /// into a message naming the key and line.
    fn serde_error(&self, e: &toml::de::Error) -> SceneError {
        let span = e.span().unwrap_or(0..0);
        let line = line_of(self.text, span.start);
        let msg = e.message().trim();
        let found = self
            .text
            .get(span.clone())
            .map(|s| {
                let s = s.trim();
                if s.chars().count() > 40 {
                    format!("{}...", s.chars().take(40).collect::<String>())
                } else {
                    s.to_owned()
                }
            })
            .unwrap_or_default();
        let located = self.find(&span);

        if let Some(rest) = msg.strip_prefix("unknown field `") {
            let (name, expected) = rest.split_once('`').unwrap_or((rest, ""));
            let mut path = located.map(|(p, _)| p).unwrap_or_default();
            if path.last() != Some(&Seg::Key(name.to_owned())) {
                path.push(Seg::Key(name.to_owned()));
            }
            let parent = path_string(&path[..path.len() - 1]);
            let table = if parent.is_empty() {
                "at the top level".to_owned()
            } else {
                format!("in [{parent}]")
            };
            let expected = list_of_names(expected);
            let message = if expected.is_empty() {
                format!("unknown key `{name}` {table}")
            } else {
                format!("unknown key `{name}` {table}; expected one of {expected}")
            };
            return self.invalid(line, path_string(&path), message);
        }
        if let Some(rest) = msg.strip_prefix("missing field `") {
            let name = rest.split('`').next().unwrap_or(rest);
            let mut path = match located {
                Some((p, Hit::Value)) if span.start < span.end => p,
                _ => Vec::new(),
            };
            let parent = path_string(&path);
            path.push(Seg::Key(name.to_owned()));
            let message = if parent.is_empty() {
                format!("missing required key `{name}` (a [{name}] table or `{name} = ...`)")
            } else {
                format!("missing required key `{name}` in [{parent}]")
            };
            return self.invalid(line, path_string(&path), message);
        }
        // `[[name]]` where a single `[name]` table belongs.
        if found.starts_with("[[")
            && let Some((mut p, _)) = located.clone()
        {
            if matches!(p.last(), Some(Seg::Index(_))) {
                p.pop();
            }
            let key = path_string(&p);
            return self.invalid(
                line,
                key.clone(),
                format!("expected a single [{key}] table, found an array of tables [[{key}]]"),
            );
        }
        let key = located
            .map(|(p, _)| path_string(&p))
            .unwrap_or_else(|| "(document)".to_owned());
        if let Some(rest) = msg.strip_prefix("unknown variant `") {
            let (name, expected) = rest.split_once('`').unwrap_or((rest, ""));
            let message = format!(
                "unknown value `{name}`; expected one of {}",
                list_of_names(expected)
            );
            return self.invalid(line, key, message);
        }
        let detail = msg
            .strip_prefix("invalid type: ")
            .or_else(|| msg.strip_prefix("invalid value: "))
            .or_else(|| msg.strip_prefix("invalid length "));
        if let Some(rest) = detail
            && let Some((what, expected)) = rest.rsplit_once(", expected ")
        {
            let negative = found.starts_with('-');
            let expected = match expected.trim() {
                "u8" | "u16" | "u32" | "u64" | "usize" => {
                    if msg.starts_with("invalid value: ") && !negative {
                        let max = match expected.trim() {
                            "u8" => u64::from(u8::MAX),
                            "u16" => u64::from(u16::MAX),
                            "u32" => u64::from(u32::MAX),
                            _ => u64::MAX,
                        };
                        format!("a non-negative integer no larger than {max}")
                    } else {
                        "a non-negative integer".to_owned()
                    }
                }
                "i8" | "i16" | "i32" | "i64" => "an integer".to_owned(),
                "f32" | "f64" => "a number".to_owned(),
                "a boolean" => "true or false".to_owned(),
                "a string" => "a string in quotes".to_owned(),
                "a sequence" => "an array".to_owned(),
                e if e.starts_with("an array of length ") => {
                    format!("an array of {} numbers", &e["an array of length ".len()..])
                }
                e if e.starts_with("struct ") || e == "a map" => "a table".to_owned(),
                e => e.to_owned(),
            };
            let found = if msg.starts_with("invalid length ") {
                format!("{found} ({} elements)", what.trim())
            } else if found.is_empty() {
                what.to_owned()
            } else {
                found
            };
            return self.invalid(line, key, format!("expected {expected}, found {found}"));
        }
        self.invalid(line, key, msg.to_owned())
    }
}

/// "`a`, `b` or `c`" / "one of `a`, `b`" → "a, b, c".
fn list_of_names(expected: &str) -> String {
    let names: Vec<&str> = expected
        .split('`')
        .enumerate()
        .filter(|(i, _)| i % 2 == 1)
        .map(|(_, s)| s)
        .collect();
    names.join(", ")
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A complete, compact scene used by the error tests (line numbers matter).
    const BASE: &str = r#"# test scene
[terrain]
size = 200.0
resolution = 33
seed = 1
relief = 20.0
feature_size = 80.0

[[species]]
name = "fir"
preset = "fir"
seed = 1

[[species]]
name = "oak"
preset = "broadleaf"
seed = 2

[forest]
count = 30
seed = 3
min_spacing = 6.0
mix = [0.6, 0.4]
scale_min = 0.8
scale_max = 1.2
random_yaw = true

[sun]
azimuth = 135.0
elevation = 35.0
color = [1.0, 0.95, 0.85]
intensity = 3.0

[sky]
color = [0.35, 0.5, 0.8]
ground_color = [0.12, 0.1, 0.06]
intensity = 1.0

[camera]
position = [0.0, 40.0, -90.0]
look_at = [0.0, 10.0, 0.0]
fov_deg = 55.0
"#;

    /// Replaces the unique line `from` (exact, trimmed) of BASE with `to`; returns the text
    /// and the 1-based line number of the last line of `to`.
    fn edit(from: &str, to: &str) -> (String, usize) {
        let lines: Vec<&str> = BASE.lines().collect();
        let hits: Vec<usize> = lines
            .iter()
            .enumerate()
            .filter(|(_, l)| l.trim() == from)
            .map(|(i, _)| i)
            .collect();
        assert_eq!(hits.len(), 1, "line `{from}` must be unique in BASE");
        let i = hits[0];
        let mut out: Vec<String> = lines.iter().map(|s| s.to_string()).collect();
        out[i] = to.to_owned();
        // The reported line is the last line of `to` (to insert a key after `from`, pass
        // "from\nnew_key = ...").
        let extra = to.lines().count().saturating_sub(1);
        (out.join("\n") + "\n", i + 1 + extra)
    }

    fn error_of(text: &str) -> String {
        match Scene::parse(text, "scene.toml") {
            Ok(_) => panic!("accepted:\n{text}"),
            Err(e) => e.to_string(),
        }
    }

    /// `edit` + parse; asserts the message has the file, the line and the key.
    fn expect_error(from: &str, to: &str, key: &str, words: &[&str]) -> String {
        let (text, line) = edit(from, to);
        let msg = error_of(&text);
        assert!(
            msg.starts_with(&format!("scene.toml:{line}: ")),
            "line {line} missing: {msg}"
        );
        assert!(msg.contains(key), "key {key} missing: {msg}");
        for w in words {
            assert!(msg.contains(w), "`{w}` missing: {msg}");
        }
        msg
    }

    #[test]
    fn density_stands_and_mix_high_parse_and_are_checked() {
        let (text, _) = edit(
            "count = 30",
            "density = 100.0\nmix_high = [0.9, 0.1]\n[forest.stands]\ncover = 0.5\nedge = 10.0",
        );
        // The [forest] keys after `count` now sit in [forest.stands]: move them back up.
        let text = text.replace(
            "edge = 10.0\nseed = 3\nmin_spacing = 6.0\nmix = [0.6, 0.4]\nscale_min = 0.8\nscale_max = 1.2\nrandom_yaw = true\n",
            "edge = 10.0\n",
        );
        let text = text.replace(
            "density = 100.0\n",
            "density = 100.0\nseed = 3\nmin_spacing = 6.0\nmix = [0.6, 0.4]\nscale_min = 0.8\nscale_max = 1.2\nrandom_yaw = true\n",
        );
        let s = match Scene::parse(&text, "scene.toml") {
            Ok(s) => s,
            Err(e) => panic!("{e}\n{text}"),
        };
        assert_eq!(s.forest.count, None);
        assert_eq!(s.forest.density, Some(100.0));
        assert_eq!(s.forest.mix_high, Some(vec![0.9, 0.1]));
        let st = s.forest.stands.unwrap_or_default();
        assert_eq!((st.cover, st.edge), (0.5, 10.0));
        assert_eq!(st.size, crate::model::StandParams::default().size);
        let w = match s.build_world() {
            Ok(w) => w,
            Err(e) => panic!("{e}"),
        };
        assert!(!w.forest.instances.is_empty());
        // A typo inside [forest.stands] is located.
        let bad = text.replace("cover = 0.5", "covr = 0.5");
        let msg = error_of(&bad);
        assert!(
            msg.contains("forest.stands.covr") && msg.contains("expected one of cover"),
            "{msg}"
        );
        let bad = text.replace("cover = 0.5", "cover = 1.5");
        let msg = error_of(&bad);
        assert!(
            msg.contains("forest.stands.cover") && msg.contains("between 0 and 1"),
            "{msg}"
        );
        // Both count and density, or neither.
        expect_error(
            "count = 30",
            "count = 30\ndensity = 100.0",
            "forest.density",
            &["either `count` or `density`"],
        );
        let msg = error_of(&BASE.replace("count = 30\n", ""));
        assert!(msg.contains("forest.count: missing required key"), "{msg}");
        // Stands need a density; mix_high one weight per species.
        let (text, cover_line) = edit(
            "random_yaw = true",
            "random_yaw = true\n[forest.stands]\ncover = 0.5",
        );
        let msg = error_of(&text);
        // Reported at the table's header, the line above `cover`.
        assert!(
            msg.starts_with(&format!("scene.toml:{}: forest.stands: ", cover_line - 1))
                && msg.contains("needs `density`"),
            "{msg}"
        );
        expect_error(
            "mix = [0.6, 0.4]",
            "mix = [0.6, 0.4]\nmix_high = [1.0]",
            "forest.mix_high",
            &["one weight per species"],
        );
        expect_error("count = 30", "density = nan", "forest.density", &["finite"]);
    }

    #[test]
    fn variants_parse_and_are_bounded() {
        let (text, _) = edit("seed = 2", "seed = 2\nvariants = 3");
        let s = match Scene::parse(&text, "scene.toml") {
            Ok(s) => s,
            Err(e) => panic!("{e}"),
        };
        assert_eq!((s.species[0].variants, s.species[1].variants), (1, 3));
        let w = match s.build_world() {
            Ok(w) => w,
            Err(e) => panic!("{e}"),
        };
        assert_eq!(w.species.len(), 4);
        expect_error(
            "seed = 2",
            "seed = 2\nvariants = 9",
            "species[1].variants",
            &["between 1 and 8"],
        );
        expect_error(
            "seed = 2",
            "seed = 2\nvariants = 0",
            "species[1].variants",
            &["between 1 and 8"],
        );
        // (That one variant keeps the bake key is tested in bake::cache.)
    }

    #[test]
    fn example_scenes_parse_and_the_forest_is_dense() {
        for (name, _, _) in EXAMPLE_SCENES {
            match Scene::example(name) {
                Some(Ok(_)) => {}
                Some(Err(e)) => panic!("example `{name}`: {e}"),
                None => panic!("example `{name}` not found"),
            }
        }
        assert!(Scene::example("nope").is_none());
        let forest = match Scene::example("forest") {
            Some(Ok(s)) => s,
            _ => panic!("forest"),
        };
        // Only the placement is needed here, not the species' meshes.
        let terrain = match crate::model::Terrain::generate(&forest.terrain) {
            Ok(t) => t,
            Err(e) => panic!("{e}"),
        };
        let placed =
            match crate::model::Forest::place(&forest.forest, &terrain, forest.species.len()) {
                Ok(f) => f,
                Err(e) => panic!("{e}"),
            };
        // The issue asks for at least 30,000 trees on 1 km².
        let n = placed.instances.len();
        assert!((30_000..=40_000).contains(&n), "{n} trees");
        let hist = placed.species_histogram(3);
        assert!(hist.iter().all(|h| *h > 3_000), "{hist:?}");
    }

    #[test]
    fn the_texel_table_picks_the_source_and_refuses_what_is_not_built() {
        let (text, _) = edit(
            "fov_deg = 55.0",
            "fov_deg = 55.0\n[texel]\nsource = \"voxel-colouring\"\nviews = 6",
        );
        let s = Scene::parse(&text, "scene.toml").unwrap();
        assert_eq!(s.texel.source, TexelSource::VoxelColouring);
        let base = Scene::parse(BASE, "scene.toml").unwrap();
        assert_eq!(base.texel, TexelParams::default());
        expect_error(
            "fov_deg = 55.0",
            "fov_deg = 55.0\n[texel]\nviews = 12",
            "texel.views",
            &["must be 6", "12"],
        );
        let msg = error_of(
            &edit(
                "fov_deg = 55.0",
                "fov_deg = 55.0\n[texel]\nsource = \"voxels\"",
            )
            .0,
        );
        assert!(
            msg.contains("source") && msg.contains("voxel-colouring"),
            "{msg}"
        );
    }

    #[test]
    fn base_scene_parses() {
        let s = Scene::parse(BASE, "scene.toml");
        let s = match s {
            Ok(s) => s,
            Err(e) => panic!("{e}"),
        };
        assert_eq!(s.species.len(), 2);
        assert_eq!(s.terrain.octaves, 5);
        assert_eq!(s.forest.tint_variation, 0.15);
        assert_eq!(
            s.species[1].try_params().unwrap().foliage,
            crate::model::FoliageKind::Leaves
        );
    }

    #[test]
    fn default_and_small_scenes_parse() {
        let d = Scene::default_scene();
        assert_eq!(d.forest.count, Some(1000));
        assert_eq!(d.terrain.resolution, 257);
        assert_eq!(d.species.len(), 2);
        assert_eq!(d.forest.mix.len(), 2);
        let small = Scene::parse(SMALL_TEST_SCENE_TOML, "small.toml");
        let small = match small {
            Ok(s) => s,
            Err(e) => panic!("{e}"),
        };
        assert!((20..=40).contains(&small.forest.count.unwrap_or(0)));
        assert!((80.0..=120.0).contains(&small.terrain.size));
    }

    #[test]
    fn scene_round_trips_through_toml() {
        let d = Scene::default_scene();
        let text = toml::to_string(&d).unwrap_or_default();
        let back = Scene::parse(&text, "round.toml").ok();
        assert_eq!(back, Some(d));
    }

    #[test]
    fn load_reports_missing_file_with_path() {
        let p = Path::new("/definitely/not/here/scene.toml");
        let msg = Scene::load(p)
            .err()
            .map(|e| e.to_string())
            .unwrap_or_default();
        assert!(msg.contains("/definitely/not/here/scene.toml"), "{msg}");
        assert!(msg.contains("cannot read"), "{msg}");
    }

    #[test]
    fn load_reads_a_file() {
        let dir = std::env::temp_dir().join(format!("canopy-scene-test-{}", std::process::id()));
        let _ = std::fs::create_dir_all(&dir);
        let path = dir.join("s.toml");
        let _ = std::fs::write(&path, BASE);
        let ok = Scene::load(&path).unwrap_or_else(|e| panic!("{e}"));
        // What BASE says, read back.
        assert_eq!(ok.forest.count, Some(30));
        assert_eq!(ok.forest.mix, [0.6, 0.4]);
        assert_eq!(ok.terrain.resolution, 33);
        let names: Vec<_> = ok.species.iter().map(|s| s.name.as_str()).collect();
        assert_eq!(names, ["fir", "oak"]);
        assert_eq!(ok.species[1].preset.as_deref(), Some("broadleaf"));
        assert_eq!(ok.camera.position, [0.0, 40.0, -90.0]);
        assert_eq!(ok.sun.elevation, 35.0);
        let (bad, line) = edit("count = 30", "count = -5");
        let _ = std::fs::write(&path, bad);
        let msg = Scene::load(&path)
            .err()
            .map(|e| e.to_string())
            .unwrap_or_default();
        assert!(
            msg.starts_with(&format!("{}:{line}: forest.count", path.display())),
            "{msg}"
        );
        let _ = std::fs::remove_dir_all(&dir);
    }

    // ---- deserialisation errors: unknown key, missing key, wrong type, negative count ----

    #[test]
    fn unknown_key_names_key_table_and_expected_keys() {
        let msg = expect_error(
            "relief = 20.0",
            "reliefs = 20.0",
            "terrain.reliefs",
            &[
                "unknown key `reliefs` in [terrain]",
                "expected one of size, resolution",
            ],
        );
        assert!(msg.contains("relief,"), "{msg}");
        expect_error(
            "fov_deg = 55.0",
            "fov = 55.0",
            "camera.fov",
            &["unknown key `fov` in [camera]", "fov_deg"],
        );
        // Unknown key inside an array-of-tables entry.
        expect_error(
            "name = \"oak\"",
            "nmae = \"oak\"",
            "species[1].nmae",
            &["in [species[1]]"],
        );
    }

    #[test]
    fn unknown_table_at_top_level() {
        expect_error(
            "[sky]",
            "[skies]",
            "skies",
            &["unknown key `skies` at the top level", "camera"],
        );
    }

    #[test]
    fn missing_key_is_named() {
        let (text, _) = edit("count = 30", "");
        let msg = error_of(&text);
        // Reported at the [forest] header.
        let header = BASE
            .lines()
            .position(|l| l == "[forest]")
            .map(|i| i + 1)
            .unwrap_or(0);
        assert!(
            msg.starts_with(&format!(
                "scene.toml:{header}: forest.count: missing required key"
            )),
            "{msg}"
        );
        let (text, _) = edit("seed = 2", "");
        let msg = error_of(&text);
        let header = BASE
            .lines()
            .enumerate()
            .filter(|(_, l)| *l == "[[species]]")
            .nth(1)
            .map(|(i, _)| i + 1)
            .unwrap_or(0);
        assert!(
            msg.starts_with(&format!("scene.toml:{header}: species[1].seed")),
            "{msg}"
        );
    }

    #[test]
    fn missing_table_is_named() {
        let text = BASE.replace(
            "[camera]\nposition = [0.0, 40.0, -90.0]\nlook_at = [0.0, 10.0, 0.0]\nfov_deg = 55.0\n",
            "",
        );
        let msg = error_of(&text);
        assert!(
            msg.starts_with("scene.toml:1: camera: missing required key `camera`"),
            "{msg}"
        );
    }

    #[test]
    fn negative_count() {
        expect_error(
            "count = 30",
            "count = -5",
            "forest.count",
            &["expected a non-negative integer, found -5"],
        );
    }

    #[test]
    fn integer_too_large_for_type() {
        expect_error(
            "count = 30",
            "count = 99999999999",
            "forest.count",
            &["no larger than 4294967295", "99999999999"],
        );
    }

    #[test]
    fn wrong_types() {
        expect_error(
            "size = 200.0",
            "size = \"big\"",
            "terrain.size",
            &["expected a number, found \"big\""],
        );
        expect_error(
            "count = 30",
            "count = 30.5",
            "forest.count",
            &["non-negative integer", "30.5"],
        );
        expect_error(
            "random_yaw = true",
            "random_yaw = 1",
            "forest.random_yaw",
            &["true or false"],
        );
        expect_error(
            "mix = [0.6, 0.4]",
            "mix = [0.6, \"x\"]",
            "forest.mix[1]",
            &["expected a number"],
        );
        expect_error(
            "mix = [0.6, 0.4]",
            "mix = 0.6",
            "forest.mix",
            &["expected an array"],
        );
        expect_error("name = \"fir\"", "name = 5", "species[0].name", &["string"]);
        expect_error(
            "color = [1.0, 0.95, 0.85]",
            "color = [1.0, 0.95]",
            "sun.color",
            &["array of 3 numbers"],
        );
    }

    #[test]
    fn wrong_array_lengths() {
        expect_error(
            "color = [1.0, 0.95, 0.85]",
            "color = [1.0, 0.95, 0.85, 1.0]",
            "sun.color",
            &["expected an array of 3 numbers", "(4 elements)"],
        );
        expect_error(
            "look_at = [0.0, 10.0, 0.0]",
            "look_at = []",
            "camera.look_at",
            &["expected an array of 3 numbers", "(0 elements)"],
        );
    }

    #[test]
    fn array_of_tables_where_a_table_belongs() {
        expect_error(
            "[terrain]",
            "[[terrain]]",
            "terrain",
            &["expected a single [terrain] table, found an array of tables [[terrain]]"],
        );
    }

    #[test]
    fn wrong_type_for_table() {
        let text = BASE
            .replace("[sky]\ncolor = [0.35, 0.5, 0.8]\nground_color = [0.12, 0.1, 0.06]\nintensity = 1.0\n", "")
            .replace("# test scene\n", "# test scene\nsky = 5\n");
        let line = text
            .lines()
            .position(|l| l == "sky = 5")
            .map(|i| i + 1)
            .unwrap_or(0);
        let msg = error_of(&text);
        assert!(
            msg.starts_with(&format!(
                "scene.toml:{line}: sky: expected a table, found 5"
            )),
            "{msg}"
        );
    }

    #[test]
    fn syntax_error_has_line() {
        let (text, line) = edit("seed = 3", "seed = = 3");
        let msg = error_of(&text);
        assert!(
            msg.starts_with(&format!("scene.toml:{line}: TOML syntax error")),
            "{msg}"
        );
        let (text, line) = edit("scale_max = 1.2", "scale_min = 1.2");
        let msg = error_of(&text);
        assert!(msg.starts_with(&format!("scene.toml:{line}: ")), "{msg}");
        assert!(msg.contains("duplicate key `scale_min`"), "{msg}");
    }

    #[test]
    fn unknown_enum_value_in_inline_params() {
        let mut text = BASE.replace("preset = \"broadleaf\"\n", "");
        let params: String = crate::model::species::BROADLEAF_TOML
            .lines()
            .filter(|l| !l.trim_start().starts_with('#'))
            .collect::<Vec<_>>()
            .join("\n");
        text = text.replace(
            "seed = 2\n",
            &format!(
                "seed = 2\n[species.params]\n{}\n",
                params.replace("\"leaves\"", "\"fronds\"")
            ),
        );
        let line = text
            .lines()
            .position(|l| l.contains("\"fronds\""))
            .map(|i| i + 1)
            .unwrap_or(0);
        let msg = error_of(&text);
        assert!(
            msg.starts_with(&format!("scene.toml:{line}: species[1].params.foliage")),
            "{msg}"
        );
        assert!(msg.contains("expected one of needles, leaves"), "{msg}");
        // With a valid value the inline params are accepted.
        let ok = Scene::parse(&text.replace("\"fronds\"", "\"leaves\""), "scene.toml")
            .unwrap_or_else(|e| panic!("{e}"));
        // They are the broadleaf preset's, field for field, in place of the preset's name.
        assert_eq!(ok.species[1].preset, None);
        assert_eq!(ok.species[1].params, preset("broadleaf"));
        assert!(ok.species[1].params.is_some());
        // An out-of-range inline parameter is reported at its own line.
        let bad = text
            .replace("\"fronds\"", "\"leaves\"")
            .replace("crown_radius = 5.2", "crown_radius = -2");
        let line = bad
            .lines()
            .position(|l| l.starts_with("crown_radius"))
            .map(|i| i + 1)
            .unwrap_or(0);
        let msg = error_of(&bad);
        assert!(
            msg.starts_with(&format!(
                "scene.toml:{line}: species[1].params.crown_radius: must be > 0, found -2"
            )),
            "{msg}"
        );
    }

    // ---- semantic checks: one test line each (key + line asserted) ----

    #[test]
    fn non_finite_numbers() {
        expect_error(
            "elevation = 35.0",
            "elevation = nan",
            "sun.elevation",
            &["must be a finite number, found nan"],
        );
        expect_error(
            "azimuth = 135.0",
            "azimuth = inf",
            "sun.azimuth",
            &["finite", "found inf"],
        );
        expect_error(
            "size = 200.0",
            "size = 1e60",
            "terrain.size",
            &["finite", "found 1e60"],
        );
        expect_error(
            "min_spacing = 6.0",
            "min_spacing = -inf",
            "forest.min_spacing",
            &["finite"],
        );
        expect_error(
            "fov_deg = 55.0",
            "fov_deg = nan",
            "camera.fov_deg",
            &["finite"],
        );
    }

    #[test]
    fn terrain_checks() {
        expect_error(
            "size = 200.0",
            "size = 0.0",
            "terrain.size",
            &["must be > 0, found 0.0"],
        );
        expect_error(
            "size = 200.0",
            "size = -10",
            "terrain.size",
            &["must be > 0"],
        );
        expect_error(
            "size = 200.0",
            "size = 200000.0",
            "terrain.size",
            &["between"],
        );
        expect_error(
            "resolution = 33",
            "resolution = 1",
            "terrain.resolution",
            &["between 2 and 4097, found 1"],
        );
        expect_error(
            "resolution = 33",
            "resolution = 5000",
            "terrain.resolution",
            &["between 2 and 4097"],
        );
        expect_error(
            "relief = 20.0",
            "relief = -1.0",
            "terrain.relief",
            &["between 0"],
        );
        expect_error(
            "feature_size = 80.0",
            "feature_size = 0.5",
            "terrain.feature_size",
            &["between 1"],
        );
        expect_error(
            "feature_size = 80.0",
            "feature_size = 80.0\noctaves = 20",
            "terrain.octaves",
            &["between 1 and 12"],
        );
        expect_error(
            "feature_size = 80.0",
            "feature_size = 80.0\nroughness = 1.5",
            "terrain.roughness",
            &["between 0 and 1"],
        );
    }

    #[test]
    fn species_checks() {
        expect_error(
            "name = \"oak\"",
            "name = \"fir\"",
            "species[1].name",
            &["duplicate species name `fir`"],
        );
        expect_error(
            "name = \"oak\"",
            "name = \"  \"",
            "species[1].name",
            &["must not be empty"],
        );
        expect_error(
            "preset = \"broadleaf\"",
            "preset = \"oak\"",
            "species[1].preset",
            &["unknown preset `oak`", "fir, broadleaf"],
        );
        // Neither preset nor params: reported at the entry's header.
        let (text, _) = edit("preset = \"broadleaf\"", "");
        let header = BASE
            .lines()
            .enumerate()
            .filter(|(_, l)| *l == "[[species]]")
            .nth(1)
            .map(|(i, _)| i + 1)
            .unwrap_or(0);
        let msg = error_of(&text);
        assert!(
            msg.starts_with(&format!("scene.toml:{header}: species[1]: give `preset`")),
            "{msg}"
        );
        // Both.
        let text = BASE.replace(
            "preset = \"broadleaf\"\nseed = 2\n",
            &format!(
                "preset = \"broadleaf\"\nseed = 2\n[species.params]\n{}\n",
                crate::model::species::BROADLEAF_TOML
            ),
        );
        let line = text
            .lines()
            .position(|l| l == "preset = \"broadleaf\"")
            .map(|i| i + 1)
            .unwrap_or(0);
        let msg = error_of(&text);
        assert!(
            msg.starts_with(&format!(
                "scene.toml:{line}: species[1].preset: give either"
            )),
            "{msg}"
        );
        // No species at all.
        let text = BASE
            .replace(
                "[[species]]\nname = \"fir\"\npreset = \"fir\"\nseed = 1\n",
                "",
            )
            .replace(
                "[[species]]\nname = \"oak\"\npreset = \"broadleaf\"\nseed = 2\n",
                "",
            );
        let msg = error_of(&text);
        assert!(msg.contains("species"), "{msg}");
    }

    #[test]
    fn too_many_species() {
        let mut text = BASE.to_owned();
        for i in 0..MAX_SPECIES {
            text.push_str(&format!(
                "[[species]]\nname = \"extra{i}\"\npreset = \"fir\"\nseed = 1\n"
            ));
        }
        let msg = error_of(&text);
        let line = BASE
            .lines()
            .position(|l| l == "[[species]]")
            .map_or(0, |i| i + 1);
        assert!(
            msg.starts_with(&format!("scene.toml:{line}: species: at most 64 species")),
            "{msg}"
        );
    }

    #[test]
    fn forest_without_species_is_rejected_by_its_check() {
        let p = ForestParams {
            mix: Vec::new(),
            ..ForestParams::default()
        };
        let e = p.check(0).err();
        assert_eq!(e.as_ref().map(|e| e.field.as_str()), Some("count"));
        // No trees and no species is fine.
        let p = ForestParams {
            count: Some(0),
            mix: Vec::new(),
            ..ForestParams::default()
        };
        assert_eq!(p.check(0), Ok(()));
    }

    #[test]
    fn load_rejects_huge_files_without_reading_them() {
        let dir = std::env::temp_dir().join(format!("canopy-scene-big-{}", std::process::id()));
        let _ = std::fs::create_dir_all(&dir);
        let path = dir.join("big.toml");
        std::fs::File::create(&path)
            .and_then(|f| f.set_len(MAX_SCENE_BYTES + 1))
            .unwrap_or_else(|e| panic!("making {}: {e}", path.display()));
        let msg = Scene::load(&path)
            .err()
            .map(|e| e.to_string())
            .unwrap_or_default();
        assert!(
            msg.contains("big.toml") && msg.contains("limited to"),
            "{msg}"
        );
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn forest_checks() {
        expect_error(
            "count = 30",
            "count = 100001",
            "forest.count",
            &["between 0 and 100000, found 100001"],
        );
        expect_error(
            "min_spacing = 6.0",
            "min_spacing = 0.0",
            "forest.min_spacing",
            &["must be > 0"],
        );
        expect_error(
            "min_spacing = 6.0",
            "min_spacing = 20000.0",
            "forest.min_spacing",
            &["between 0 and 10000"],
        );
        expect_error(
            "mix = [0.6, 0.4]",
            "mix = [0.6, 0.3, 0.1]",
            "forest.mix",
            &["one weight per species (2 species), found 3 weights"],
        );
        expect_error(
            "mix = [0.6, 0.4]",
            "mix = [0.6, -0.4]",
            "forest.mix[1]",
            &["between 0", "found -0.4"],
        );
        expect_error(
            "mix = [0.6, 0.4]",
            "mix = [0.0, 0.0]",
            "forest.mix",
            &["at least one weight"],
        );
        expect_error(
            "scale_min = 0.8",
            "scale_min = 1.5",
            "forest.scale_min",
            &["must be <= scale_max (1.2), found 1.5"],
        );
        expect_error(
            "scale_min = 0.8",
            "scale_min = 0.0",
            "forest.scale_min",
            &["must be > 0"],
        );
        expect_error(
            "scale_max = 1.2",
            "scale_max = 500.0",
            "forest.scale_max",
            &["between"],
        );
        expect_error(
            "random_yaw = true",
            "random_yaw = true\ntint_variation = 2.0",
            "forest.tint_variation",
            &["between 0 and 1"],
        );
    }

    #[test]
    fn sun_sky_camera_checks() {
        expect_error(
            "elevation = 35.0",
            "elevation = 95.0",
            "sun.elevation",
            &["between -90 and 90, found 95.0"],
        );
        expect_error(
            "azimuth = 135.0",
            "azimuth = 400.0",
            "sun.azimuth",
            &["between -360 and 360"],
        );
        expect_error(
            "color = [1.0, 0.95, 0.85]",
            "color = [1.0, -0.95, 0.85]",
            "sun.color[1]",
            &["between 0 and 100", "found -0.95"],
        );
        expect_error(
            "color = [1.0, 0.95, 0.85]",
            "color = [1.0, nan, 0.85]",
            "sun.color[1]",
            &["finite", "found nan"],
        );
        expect_error(
            "intensity = 3.0",
            "intensity = -3.0",
            "sun.intensity",
            &["between 0"],
        );
        expect_error(
            "color = [0.35, 0.5, 0.8]",
            "color = [0.35, 0.5, inf]",
            "sky.color[2]",
            &["finite"],
        );
        expect_error(
            "ground_color = [0.12, 0.1, 0.06]",
            "ground_color = [-0.12, 0.1, 0.06]",
            "sky.ground_color[0]",
            &["between 0"],
        );
        expect_error(
            "intensity = 1.0",
            "intensity = nan",
            "sky.intensity",
            &["finite"],
        );
        expect_error(
            "position = [0.0, 40.0, -90.0]",
            "position = [0.0, inf, -90.0]",
            "camera.position[1]",
            &["finite"],
        );
        expect_error(
            "look_at = [0.0, 10.0, 0.0]",
            "look_at = [0.0, 40.0, -90.0]",
            "camera.look_at",
            &["must differ"],
        );
        expect_error(
            "look_at = [0.0, 10.0, 0.0]",
            "look_at = [0.0, 1e9, 0.0]",
            "camera.look_at[1]",
            &["between"],
        );
        expect_error(
            "fov_deg = 55.0",
            "fov_deg = 179.0",
            "camera.fov_deg",
            &["between 1 and 170"],
        );
    }

    #[test]
    fn sun_direction_convention() {
        let close = |a: Vec3, b: Vec3| (a - b).length() < 1e-5;
        assert!(close(sun_direction(0.0, 0.0), Vec3::Z), "north is +Z");
        assert!(close(sun_direction(90.0, 0.0), Vec3::X), "east is +X");
        assert!(close(sun_direction(180.0, 0.0), -Vec3::Z));
        assert!(close(sun_direction(123.0, 90.0), Vec3::Y), "zenith");
        let d = sun_direction(135.0, 35.0);
        assert!((d.length() - 1.0).abs() < 1e-5);
        assert!((d.y - 35f32.to_radians().sin()).abs() < 1e-5);
        assert!(d.x > 0.0 && d.z < 0.0, "south-east");
    }

    #[test]
    fn path_parsing() {
        assert_eq!(
            parse_path("species[1].params.height"),
            vec![
                Seg::Key("species".into()),
                Seg::Index(1),
                Seg::Key("params".into()),
                Seg::Key("height".into())
            ]
        );
        assert_eq!(path_string(&parse_path("forest.mix[2]")), "forest.mix[2]");
        assert_eq!(line_of("a\nb\nc", 2), 2);
        assert_eq!(line_of("a\nb\nc", 100), 3);
    }

    fn small_world_scene() -> Scene {
        match Scene::parse(SMALL_TEST_SCENE_TOML, "small.toml") {
            Ok(s) => s,
            Err(e) => panic!("{e}"),
        }
    }

    #[test]
    fn small_scene_builds_its_world() {
        let scene = small_world_scene();
        let w = match scene.build_world() {
            Ok(w) => w,
            Err(e) => panic!("{e}"),
        };
        assert_eq!(w.species.len(), scene.species.len());
        assert_eq!(
            w.forest.instances.len(),
            scene.forest.count.unwrap_or(0) as usize
        );
        assert_eq!(w.species[0].name, scene.species[0].name);
        let hist = w.forest.species_histogram(w.species.len());
        assert!(
            hist.iter().all(|&c| c > 0),
            "both species present: {hist:?}"
        );
        assert!(w.total_triangles() > w.terrain_triangles());
        // The camera sees the trees: the look-at point is near the forest's centre and the
        // camera is above the ground.
        let cam = glam::Vec3::from(scene.camera.position);
        assert!(cam.y > w.terrain.height_at(cam.x, cam.z) + 2.0);
    }

    #[test]
    fn default_scene_builds_its_world_deterministically() {
        let scene = Scene::default_scene();
        let start = std::time::Instant::now();
        let a = match scene.build_world() {
            Ok(w) => w,
            Err(e) => panic!("{e}"),
        };
        eprintln!("default world built in {:.2?}", start.elapsed());
        assert_eq!(a.forest.instances.len(), 1000);
        let b = scene
            .build_world()
            .map(|w| w.forest.instances)
            .unwrap_or_default();
        assert_eq!(a.forest.instances, b);
        let hist = a.forest.species_histogram(a.species.len());
        eprintln!("species histogram {hist:?}");
        for s in &a.species {
            eprintln!(
                "{}: {:?} {:?} bounds {:?}",
                s.name,
                s.triangle_counts(),
                s.counts(),
                s.tree_bounds
            );
        }
        // Trees cover the whole terrain.
        let half = 0.5 * a.terrain.size;
        let xs: Vec<f32> = a.forest.instances.iter().map(|t| t.position.x).collect();
        let (lo, hi) = xs
            .iter()
            .fold((f32::MAX, f32::MIN), |(l, h), &x| (l.min(x), h.max(x)));
        assert!(lo < -0.8 * half && hi > 0.8 * half, "{lo}..{hi}");
        // The start camera stands above the terrain.
        let cam = glam::Vec3::from(scene.camera.position);
        let ground = a.terrain.height_at(cam.x, cam.z);
        eprintln!("camera {cam} ground {ground}");
        assert!(cam.y > ground + 10.0);
    }

    #[test]
    fn unknown_preset_is_reported_by_the_world_build() {
        let mut scene = small_world_scene();
        scene.species[0].preset = Some("oak".into());
        scene.species[0].params = None;
        let e = scene
            .build_world()
            .err()
            .map(|e| e.to_string())
            .unwrap_or_default();
        assert!(e.contains("oak"), "{e}");
    }
}
