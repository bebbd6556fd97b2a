//! Every method's knobs as flags of `canopy render`, one per knob name
//! ([`crate::render::method::all_knobs`]): `--lod-scale 2`, `--texel-mode stacks`, `--vcm off`
//! (an on/off knob given alone means on: `--show-lod`). A knob not given keeps the frame's
//! value (the scene's `[render]` table, else the method's default).

use clap::{Arg, ArgMatches, Command, FromArgMatches};

use crate::render::FrameDesc;
use crate::render::knob::{Knob, KnobKind, KnobValue};
use crate::render::method::{Method, all_knobs, knobs_named, knobs_of};

/// The knobs given on the command line, in the order of the flags' table.
#[derive(Clone, Debug, Default)]
pub struct KnobArgs {
    pub given: Vec<(&'static Knob, KnobValue)>,
}

impl KnobArgs {
    /// Writes each given knob on `frame` (on every method's knob of that name).
    pub fn apply_to(&self, frame: &mut FrameDesc) {
        for (k, v) in &self.given {
            for same in knobs_named(k.name) {
                same.set(frame, *v);
            }
        }
    }

    /// The given knobs `method` does not read (for a warning).
    pub fn ignored_by(&self, method: Method) -> Vec<&'static str> {
        self.given
            .iter()
            .filter(|(k, _)| !knobs_of(method).iter().any(|m| m.name == k.name))
            .map(|(k, _)| k.name)
            .collect()
    }
}

fn arg(k: &'static Knob) -> Arg {
    let methods: Vec<&str> = Method::ALL
        .iter()
        .filter(|m| knobs_of(**m).iter().any(|o| o.name == k.name))
        .map(|m| m.name())
        .collect();
    let a = Arg::new(k.name)
        .long(k.name.replace('_', "-"))
        .help(match k.kind {
            KnobKind::Number { .. } => {
                format!("{}: {} ({})", methods.join(", "), k.help, k.values())
            }
            _ => format!("{}: {}", methods.join(", "), k.help),
        })
        .help_heading("Method knobs")
        .value_parser(move |s: &str| k.parse(s))
        .required(false);
    match k.kind {
        KnobKind::Toggle { .. } => a
            .num_args(0..=1)
            .default_missing_value("on")
            .value_name("on|off"),
        KnobKind::Choice { names, .. } => a.value_name(names.join("|")),
        KnobKind::Number { .. } => a.value_name("N").allow_negative_numbers(true),
    }
}

impl FromArgMatches for KnobArgs {
    fn from_arg_matches(m: &ArgMatches) -> Result<Self, clap::Error> {
        let given = all_knobs()
            .into_iter()
            .filter_map(|k| m.get_one::<KnobValue>(k.name).map(|v| (k, *v)))
            .collect();
        Ok(Self { given })
    }

    fn update_from_arg_matches(&mut self, m: &ArgMatches) -> Result<(), clap::Error> {
        *self = Self::from_arg_matches(m)?;
        Ok(())
    }
}

impl clap::Args for KnobArgs {
    fn augment_args(cmd: Command) -> Command {
        all_knobs().into_iter().fold(cmd, |c, k| c.arg(arg(k)))
    }

    fn augment_args_for_update(cmd: Command) -> Command {
        Self::augment_args(cmd)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::Parser;

    #[derive(Parser)]
    struct Cli {
        #[command(flatten)]
        knobs: KnobArgs,
    }

    fn parse(args: &[&str]) -> Result<KnobArgs, clap::Error> {
        Cli::try_parse_from(std::iter::once("x").chain(args.iter().copied())).map(|c| c.knobs)
    }

    #[test]
    fn flags_set_the_frame_and_check_their_values() {
        let k = parse(&[
            "--lod-scale",
            "2",
            "--show-lod",
            "--vcm",
            "off",
            "--texel-mode",
            "stacks",
        ])
        .expect("valid flags");
        let mut d = FrameDesc::from_scene(&crate::scene::Scene::default_scene());
        k.apply_to(&mut d);
        assert_eq!(d.btf.lod_scale, 2.0);
        assert!(d.btf.show_lod);
        assert!(
            !d.btf.vcm && !d.texel.vcm,
            "one --vcm sets btf's and texel's"
        );
        assert_eq!(d.texel.mode.name(), "stacks");
        assert_eq!(k.ignored_by(Method::Texel), vec!["lod_scale", "show_lod"]);
        let e = parse(&["--lod-scale", "-1"]).expect_err("out of range");
        assert!(e.to_string().contains("0.05..=64"), "{e}");
        let e = parse(&["--planes", "triple"]).expect_err("no such choice");
        assert!(e.to_string().contains("single, crossed"), "{e}");
        assert!(parse(&[]).expect("none").given.is_empty());
    }
}
