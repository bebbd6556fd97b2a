//! What the commands share: the value enums clap parses choices into, the parsers of the
//! values clap has none for (sizes, points, ranges), the scene to load and the adapter.

use std::path::Path;

use clap::ValueEnum;
use glam::Vec3;

use crate::render::btf::PlaneMode;
use crate::render::method::texel::TexelMode;
use crate::render::scale::{MIN_SCALE, RenderScale};
use crate::render::{AdapterPreference, Method};
use crate::scene::Scene;

/// `--method` takes the renderer's own list: every method of [`Method::ALL`], named as
/// [`Method::name`] names it (a new method needs nothing here).
impl ValueEnum for Method {
    fn value_variants<'a>() -> &'a [Self] {
        Method::ALL
    }

    fn to_possible_value(&self) -> Option<clap::builder::PossibleValue> {
        Some(clap::builder::PossibleValue::new(self.name()))
    }
}

/// `--texel-mode`: how texel volumes are sliced.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum TexelModeArg {
    Slices3d,
    Stacks,
    Polygons,
}

impl From<TexelModeArg> for TexelMode {
    fn from(m: TexelModeArg) -> TexelMode {
        match m {
            TexelModeArg::Slices3d => TexelMode::Slices3d,
            TexelModeArg::Stacks => TexelMode::Stacks,
            TexelModeArg::Polygons => TexelMode::Polygons,
        }
    }
}

/// `--planes`: one camera-facing plane per billboard, or three crossed planes.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum PlanesArg {
    Single,
    Crossed,
}

impl From<PlanesArg> for PlaneMode {
    fn from(p: PlanesArg) -> PlaneMode {
        match p {
            PlanesArg::Single => PlaneMode::Single,
            PlanesArg::Crossed => PlaneMode::Crossed,
        }
    }
}

/// The parser of an `on`/`off` switch, as a bool.
pub fn on_off() -> impl clap::builder::TypedValueParser<Value = bool> {
    use clap::builder::TypedValueParser as _;
    clap::builder::PossibleValuesParser::new(["on", "off"]).map(|s| s == "on")
}

/// `--render-scale`: a fraction of the window in `MIN_SCALE..=1`, or `auto`.
pub fn parse_render_scale(s: &str) -> Result<RenderScale, String> {
    if s == "auto" {
        return Ok(RenderScale {
            auto: true,
            ..RenderScale::default()
        });
    }
    match s.parse::<f32>() {
        Ok(v) if (MIN_SCALE..=1.0).contains(&v) => Ok(RenderScale {
            scale: v,
            auto: false,
            ..RenderScale::default()
        }),
        _ => Err(format!(
            "{s:?} is not a render scale: give a fraction in {MIN_SCALE}..=1, or auto"
        )),
    }
}

/// A number above 0 and at most 1000.
pub fn parse_positive(s: &str) -> Result<f32, String> {
    let v: f32 = s.parse().map_err(|_| format!("{s:?} is not a number"))?;
    if v.is_finite() && v > 0.0 && v <= 1000.0 {
        Ok(v)
    } else {
        Err(format!("{v} must be above 0 and at most 1000"))
    }
}

/// A number in 0..=1.
pub fn parse_unit(s: &str) -> Result<f32, String> {
    let v: f32 = s.parse().map_err(|_| format!("{s:?} is not a number"))?;
    if (0.0..=1.0).contains(&v) {
        Ok(v)
    } else {
        Err(format!("{v} must be between 0 and 1"))
    }
}

/// `N` finite comma-separated numbers; `what` names them in the error.
fn parse_floats<const N: usize>(s: &str, what: &str) -> Result<[f32; N], String> {
    let parts: Vec<&str> = s.split(',').map(str::trim).collect();
    if parts.len() != N {
        return Err(format!(
            "expected {what} ({N} comma-separated numbers), got {s:?}"
        ));
    }
    let mut out = [0.0; N];
    for (o, p) in out.iter_mut().zip(&parts) {
        let v: f32 = p
            .parse()
            .map_err(|_| format!("{p:?} is not a number (in {s:?})"))?;
        if !v.is_finite() {
            return Err(format!("{p:?} is not a finite number (in {s:?})"));
        }
        *o = v;
    }
    Ok(out)
}

/// A point, `X,Y,Z`.
pub fn parse_vec3(s: &str) -> Result<Vec3, String> {
    parse_floats::<3>(s, "X,Y,Z").map(Vec3::from)
}

/// The sun's `AZIMUTH,ELEVATION` in degrees, the elevation in -90..=90.
pub fn parse_sun(s: &str) -> Result<(f32, f32), String> {
    let [az, el] = parse_floats::<2>(s, "AZIMUTH,ELEVATION in degrees")?;
    if !(-90.0..=90.0).contains(&el) {
        return Err(format!("sun elevation {el} is outside -90..90 degrees"));
    }
    Ok((az, el))
}

/// An image size, `WIDTHxHEIGHT`, each side 1..=16384.
pub fn parse_size(s: &str) -> Result<(u32, u32), String> {
    let (w, h) = s
        .split_once(['x', 'X'])
        .ok_or_else(|| format!("expected WIDTHxHEIGHT, e.g. 1280x720, got {s:?}"))?;
    let w: u32 = w
        .trim()
        .parse()
        .map_err(|_| format!("bad width in {s:?}"))?;
    let h: u32 = h
        .trim()
        .parse()
        .map_err(|_| format!("bad height in {s:?}"))?;
    if w == 0 || h == 0 || w > 16384 || h > 16384 {
        return Err(format!("size {w}x{h} must be between 1x1 and 16384x16384"));
    }
    Ok((w, h))
}

/// `--sweep KEY=V1,V2,...`.
pub fn parse_sweep(s: &str) -> Result<crate::bench::run::Sweep, String> {
    crate::bench::run::Sweep::parse(s).map_err(|e| e.to_string())
}

/// The scene file at `path`, or the embedded default scene.
pub fn load_scene(path: Option<&Path>) -> crate::Result<Scene> {
    match path {
        Some(p) => Ok(Scene::load(p)?),
        None => Ok(Scene::default_scene()),
    }
}

/// The adapter `--cpu` asks for.
pub fn adapter(cpu: bool) -> AdapterPreference {
    if cpu {
        AdapterPreference::Cpu
    } else {
        AdapterPreference::Default
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_method_names_are_the_renderers() {
        let names: Vec<String> = <Method as ValueEnum>::value_variants()
            .iter()
            .map(|m| {
                let value = m.to_possible_value().map(|v| v.get_name().to_owned());
                assert_eq!(value.as_deref(), Some(m.name()));
                assert_eq!(Method::from_str(m.name(), false), Ok(*m));
                m.name().to_owned()
            })
            .collect();
        let all: Vec<String> = Method::ALL.iter().map(|m| m.name().to_owned()).collect();
        assert_eq!(names, all, "one value per method, in the renderer's order");
    }

    #[test]
    fn the_texel_modes_and_planes_parse_as_the_renderer_names_them() {
        for m in TexelModeArg::value_variants() {
            let name = m.to_possible_value().unwrap().get_name().to_owned();
            assert_eq!(TexelMode::parse(&name), Some(TexelMode::from(*m)), "{name}");
        }
        for p in PlanesArg::value_variants() {
            let name = p.to_possible_value().unwrap().get_name().to_owned();
            assert_eq!(PlaneMode::parse(&name), Some(PlaneMode::from(*p)), "{name}");
        }
    }

    #[test]
    fn values_parse_and_bad_ones_say_why() {
        assert_eq!(parse_size("640x360"), Ok((640, 360)));
        assert!(parse_size("0x10").unwrap_err().contains("between 1x1"));
        assert!(parse_size("640").unwrap_err().contains("WIDTHxHEIGHT"));
        assert_eq!(parse_vec3("1,-2,3"), Ok(Vec3::new(1.0, -2.0, 3.0)));
        assert!(parse_vec3("1,2,nan").unwrap_err().contains("finite"));
        assert!(parse_vec3("1,2").unwrap_err().contains("X,Y,Z"));
        assert_eq!(parse_sun("135,35"), Ok((135.0, 35.0)));
        assert!(parse_sun("10").is_err());
        assert!(parse_sun("0,95").unwrap_err().contains("-90..90"));
        assert_eq!(parse_unit("0.5"), Ok(0.5));
        assert!(parse_unit("1.5").is_err());
        assert_eq!(parse_positive("2"), Ok(2.0));
        assert!(parse_positive("0").is_err());
        assert!(parse_render_scale("auto").unwrap().auto);
        assert_eq!(parse_render_scale("0.5").unwrap().scale, 0.5);
        assert!(parse_render_scale("2").is_err());
    }
}
