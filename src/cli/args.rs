//! What the commands share: `--method`'s values, the parsers of the values clap has none
//! for (sizes, points, ranges), the scene to load and the adapter.

use std::path::Path;

use clap::ValueEnum;
use glam::Vec3;

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
        Some(
            clap::builder::PossibleValue::new(self.name())
                .help(crate::render::method::info(*self).summary),
        )
    }
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

/// `--bc7-textures`, shared by `render`, `view` and `bench`.
#[derive(clap::Args)]
pub struct Bc7Textures {
    /// Keep the BTF images block-compressed (BC7) on a software adapter too, as a GPU with
    /// BC textures holds them, instead of decoding them for speed: to see the memory such a
    /// GPU needs (lavapipe samples BC7 about 15 times slower).
    #[arg(long)]
    bc7_textures: bool,
}

impl Bc7Textures {
    /// Sets it for the bakes attached from now on.
    pub fn apply(&self) {
        if self.bc7_textures {
            crate::render::method::btf::BC7_ON_CPU_ADAPTERS
                .store(true, std::sync::atomic::Ordering::Relaxed);
        }
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
        assert!(parse_render_scale("auto").unwrap().auto);
        assert_eq!(parse_render_scale("0.5").unwrap().scale, 0.5);
        assert!(parse_render_scale("2").is_err());
    }
}
