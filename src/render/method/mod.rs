//! The methods of the render core, one module each, behind one interface
//! ([`RenderMethod`], in [`interface`]): a CPU prepare step (culling, level of detail,
//! expansion, sorting, shading factors; testable without a GPU), the casters it gives the
//! ground shadow maps, its compute passes, its draws in the main pass and what it reports.
//! Everything methods share (targets, timestamps, terrain, sky, the sun cascades, ground
//! maps) stays in the core (`render/mod.rs`); constants more than one method reads are in
//! `render/consts.rs`.
//!
//! Adding a method: its module here, holding its [`RenderMethod`], its [`MethodInfo`]
//! (name, help, whether it needs a bake and follows the sun, its statistics as rows), its
//! settings, stats and knobs; its arm in [`Method`] (`kind.rs`); its lines in [`info`] and
//! [`registry`]; its settings' field in [`crate::render::FrameDesc`] and, when it draws
//! from the bake, its slot in [`Bake`]. The command line (`--method`, its help and a flag
//! per knob), the viewer's method buttons, knob controls and statistics grid, the bench's
//! chart and sweeps, `tune`'s grid (the knobs that offer it values) and the sun moves
//! `render --json` times follow [`Method::ALL`], [`info`] and [`RenderMethod::knobs`].

pub mod billboard;
pub mod btf;
pub mod geometry;
pub mod hybrid;
pub mod impostor;
pub mod info;
pub mod interface;
pub mod kind;
pub mod surfel;
pub mod texel;
pub mod view;

pub use info::{MethodInfo, StatRow};
pub use interface::{AfterCx, Bake, DrawCx, GroundCasters, Plan, PrepareCx, RenderMethod, SunWork};
pub use kind::Method;
pub use view::PrepareView;

use std::sync::OnceLock;

use crate::render::knob::{GROUND_KNOBS, Knob};

/// The knobs `method` reads: its own ([`RenderMethod::knobs`]) and, where its trees shade
/// the ground, the ground's.
pub fn knobs_of(method: Method) -> &'static [&'static Knob] {
    static TABLE: OnceLock<Vec<(Method, Vec<&'static Knob>)>> = OnceLock::new();
    let table = TABLE.get_or_init(|| {
        registry()
            .iter()
            .map(|m| {
                let mut knobs: Vec<&'static Knob> = m.knobs().iter().collect();
                if m.shades_ground() {
                    knobs.extend(GROUND_KNOBS.iter());
                }
                (m.method(), knobs)
            })
            .collect()
    });
    table
        .iter()
        .find(|(m, _)| *m == method)
        .map_or(&[], |(_, k)| k.as_slice())
}

/// Every knob name once (the first method's knob of each name), in the order of
/// [`Method::ALL`]: the command line's flags and the sweeps' keys.
pub fn all_knobs() -> Vec<&'static Knob> {
    let mut out: Vec<&'static Knob> = Vec::new();
    for m in Method::ALL {
        for k in knobs_of(*m) {
            if !out.iter().any(|o| o.name == k.name) {
                out.push(k);
            }
        }
    }
    out
}

/// Every method's knob named `name` (one setting to the user, held by each method that
/// reads it).
pub fn knobs_named(name: &str) -> Vec<&'static Knob> {
    let mut out: Vec<&'static Knob> = Vec::new();
    for m in Method::ALL {
        for k in knobs_of(*m) {
            if k.name == name && !out.iter().any(|o| std::ptr::eq(*o, *k)) {
                out.push(k);
            }
        }
    }
    out
}

/// What the rest of the program asks of `method` ([`MethodInfo`], declared in its module).
pub fn info(method: Method) -> &'static MethodInfo {
    match method {
        Method::Geometry => &geometry::INFO,
        Method::Btf => &btf::method::INFO,
        Method::Billboard => &billboard::INFO,
        Method::Texel => &texel::method::INFO,
        Method::Hybrid => &hybrid::INFO,
        Method::Impostor => &impostor::method::INFO,
        Method::Surfel => &surfel::method::INFO,
    }
}

/// One of each method, as the renderer holds them.
pub fn registry() -> Vec<Box<dyn RenderMethod>> {
    vec![
        Box::new(geometry::Geometry::default()),
        Box::new(btf::method::BtfMethod::new(false)),
        Box::new(billboard::Billboard::default()),
        Box::new(texel::method::TexelMethod::default()),
        Box::new(hybrid::HybridMethod::default()),
        Box::new(impostor::method::ImpostorMethod::default()),
        Box::new(surfel::method::SurfelMethod::default()),
    ]
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::render::knob::KnobKind;

    #[test]
    fn the_registry_holds_every_method_once() {
        let methods: Vec<Method> = registry().iter().map(|m| m.method()).collect();
        for m in Method::ALL {
            assert_eq!(
                methods.iter().filter(|&&x| x == *m).count(),
                1,
                "{} is not registered exactly once",
                m.name()
            );
        }
        assert_eq!(methods.len(), Method::ALL.len());
        for m in Method::ALL {
            assert_eq!(Method::parse(m.name()), Some(*m));
            assert!(!info(*m).summary.is_empty(), "{}", m.name());
        }
    }

    #[test]
    fn knobs_of_one_name_are_one_setting() {
        for k in all_knobs() {
            for other in knobs_named(k.name) {
                assert_eq!(
                    std::mem::discriminant(&k.kind),
                    std::mem::discriminant(&other.kind),
                    "two knobs named {} take different values",
                    k.name
                );
                if let (KnobKind::Choice { names: a, .. }, KnobKind::Choice { names: b, .. }) =
                    (k.kind, other.kind)
                {
                    assert_eq!(a, b, "{}", k.name);
                }
            }
        }
        let names: Vec<&str> = all_knobs().iter().map(|k| k.name).collect();
        for want in ["lod_scale", "vcm", "texel_mode", "ground_sky"] {
            assert!(names.contains(&want), "{want} missing from {names:?}");
        }
        assert_eq!(
            knobs_named("vcm").len(),
            5,
            "btf's, hybrid's copy of it, texel's, impostor's and surfel's"
        );
        assert!(
            knobs_of(Method::Hybrid)
                .iter()
                .any(|k| k.name == "impostor_px")
        );
        assert!(
            !knobs_of(Method::Btf)
                .iter()
                .any(|k| k.name == "impostor_px")
        );
        assert!(knobs_of(Method::Geometry).is_empty());
        assert!(
            knobs_of(Method::Hybrid)
                .iter()
                .any(|k| k.name == "lod_fade")
        );
    }

    #[test]
    fn every_knob_reads_back_what_it_writes() {
        use crate::render::knob::KnobValue;
        let scene = crate::scene::Scene::default_scene();
        for k in all_knobs() {
            for knob in knobs_named(k.name) {
                let mut d = crate::render::FrameDesc::from_scene(&scene);
                let v = match (knob.kind, knob.get(&d)) {
                    (
                        KnobKind::Number {
                            min, max, integer, ..
                        },
                        _,
                    ) => {
                        let x = 0.7 * min + 0.3 * max;
                        KnobValue::Number(if integer { x.round() } else { x })
                    }
                    (_, KnobValue::Toggle(on)) => KnobValue::Toggle(!on),
                    (KnobKind::Choice { names, .. }, _) => {
                        KnobValue::Choice(names[names.len() - 1])
                    }
                    _ => unreachable!("a toggle reads as on/off"),
                };
                knob.set(&mut d, v);
                assert_eq!(knob.get(&d), v, "{}", knob.name);
                assert_eq!(knob.parse(&knob.text(&d)), Ok(v), "{}", knob.name);
            }
        }
    }
}
