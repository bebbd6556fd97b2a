//! A method's knobs as data: each [`Knob`] names a setting of the frame, its kind (a number
//! in a range, on/off, one of a few choices), its help, and how to read and write it on a
//! [`FrameDesc`]. The command line (one flag per knob), the viewer's panel (one control per
//! knob), the bench's sweeps, `tune`'s grid and the JSON reports all read the same tables,
//! so a method's knobs are declared once, in its own folder
//! ([`super::method::RenderMethod::knobs`]).

use super::frame::FrameDesc;

/// What values a knob takes, and where it keeps them on a frame.
#[derive(Clone, Copy, Debug)]
pub enum KnobKind {
    /// A number in `min..=max` (a whole number when `integer`); the panel's slider spans
    /// `slider`, on a logarithmic scale when `log`.
    Number {
        min: f32,
        max: f32,
        slider: (f32, f32),
        log: bool,
        integer: bool,
        get: fn(&FrameDesc) -> f32,
        set: fn(&mut FrameDesc, f32),
    },
    /// `on` or `off`.
    Toggle {
        get: fn(&FrameDesc) -> bool,
        set: fn(&mut FrameDesc, bool),
    },
    /// One of `names`.
    Choice {
        names: &'static [&'static str],
        get: fn(&FrameDesc) -> &'static str,
        /// Given one of `names`.
        set: fn(&mut FrameDesc, &str),
    },
}

/// One value of a knob.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum KnobValue {
    Number(f32),
    Toggle(bool),
    Choice(&'static str),
}

impl std::fmt::Display for KnobValue {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            KnobValue::Number(v) => write!(f, "{v}"),
            KnobValue::Toggle(true) => f.write_str("on"),
            KnobValue::Toggle(false) => f.write_str("off"),
            KnobValue::Choice(c) => f.write_str(c),
        }
    }
}

impl serde::Serialize for KnobValue {
    fn serialize<S: serde::Serializer>(&self, s: S) -> std::result::Result<S::Ok, S::Error> {
        match self {
            KnobValue::Number(v) => s.serialize_f32(*v),
            KnobValue::Toggle(b) => s.serialize_bool(*b),
            KnobValue::Choice(c) => s.serialize_str(c),
        }
    }
}

/// A setting of the frame that a method reads.
#[derive(Clone, Copy)]
pub struct Knob {
    /// Its name: `--NAME` on the command line (`_` written `-`), `NAME=` in `--sweep`, the
    /// key in JSON reports. Knobs of different methods that share a name are one setting
    /// to the user (e.g. `vcm`): one flag sets each of them.
    pub name: &'static str,
    /// The panel's label (with the unit).
    pub label: &'static str,
    /// What it does, for `--help` and the panel's hover text.
    pub help: &'static str,
    pub kind: KnobKind,
    /// The panel offers it only while this holds (e.g. a sub-option of an option that is on).
    pub enabled: fn(&FrameDesc) -> bool,
    /// The values `canopy tune` tries (empty: tune leaves it as the scene sets it).
    pub tune: &'static [&'static str],
}

impl std::fmt::Debug for Knob {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Knob").field("name", &self.name).finish()
    }
}

/// Knobs are equal when they are the same entry of a table.
impl PartialEq for Knob {
    fn eq(&self, other: &Self) -> bool {
        std::ptr::eq(self, other)
    }
}

fn always(_: &FrameDesc) -> bool {
    true
}

impl Knob {
    const fn of(
        name: &'static str,
        label: &'static str,
        help: &'static str,
        kind: KnobKind,
    ) -> Knob {
        Knob {
            name,
            label,
            help,
            kind,
            enabled: always,
            tune: &[],
        }
    }

    /// An on/off knob.
    pub const fn toggle(
        name: &'static str,
        label: &'static str,
        help: &'static str,
        get: fn(&FrameDesc) -> bool,
        set: fn(&mut FrameDesc, bool),
    ) -> Knob {
        Self::of(name, label, help, KnobKind::Toggle { get, set })
    }

    /// A number in `range`, its slider over the same range (see [`Self::slider`]).
    pub const fn number(
        name: &'static str,
        label: &'static str,
        help: &'static str,
        range: (f32, f32),
        get: fn(&FrameDesc) -> f32,
        set: fn(&mut FrameDesc, f32),
    ) -> Knob {
        let kind = KnobKind::Number {
            min: range.0,
            max: range.1,
            slider: range,
            log: false,
            integer: false,
            get,
            set,
        };
        Self::of(name, label, help, kind)
    }

    /// One of `names`.
    pub const fn choice(
        name: &'static str,
        label: &'static str,
        help: &'static str,
        names: &'static [&'static str],
        get: fn(&FrameDesc) -> &'static str,
        set: fn(&mut FrameDesc, &str),
    ) -> Knob {
        Self::of(name, label, help, KnobKind::Choice { names, get, set })
    }

    /// A number knob whose panel slider spans `lo..=hi` (`log`: on a logarithmic scale).
    pub const fn slider(mut self, lo: f32, hi: f32, log: bool) -> Knob {
        if let KnobKind::Number { slider, log: l, .. } = &mut self.kind {
            *slider = (lo, hi);
            *l = log;
        }
        self
    }

    /// A number knob that takes whole numbers only.
    pub const fn integer(mut self) -> Knob {
        if let KnobKind::Number { integer, .. } = &mut self.kind {
            *integer = true;
        }
        self
    }

    /// Offered in the panel only while `enabled` holds.
    pub const fn when(mut self, enabled: fn(&FrameDesc) -> bool) -> Knob {
        self.enabled = enabled;
        self
    }

    /// Tried by `canopy tune` at these values.
    pub const fn tuned(mut self, values: &'static [&'static str]) -> Knob {
        self.tune = values;
        self
    }

    /// The knob's value on `frame`.
    pub fn get(&self, frame: &FrameDesc) -> KnobValue {
        match self.kind {
            KnobKind::Number { get, .. } => KnobValue::Number(get(frame)),
            KnobKind::Toggle { get, .. } => KnobValue::Toggle(get(frame)),
            KnobKind::Choice { get, .. } => KnobValue::Choice(get(frame)),
        }
    }

    /// Writes `value` on `frame` (a value of another kind is ignored; [`Self::parse`]
    /// gives values of the right kind).
    pub fn set(&self, frame: &mut FrameDesc, value: KnobValue) {
        match (self.kind, value) {
            (KnobKind::Number { set, .. }, KnobValue::Number(v)) => set(frame, v),
            (KnobKind::Toggle { set, .. }, KnobValue::Toggle(v)) => set(frame, v),
            (KnobKind::Choice { set, .. }, KnobValue::Choice(v)) => set(frame, v),
            _ => {}
        }
    }
    /// Parses `text` as a value of this knob, or says what values it takes.
    pub fn parse(&self, text: &str) -> std::result::Result<KnobValue, String> {
        let text = text.trim();
        match self.kind {
            KnobKind::Number {
                min, max, integer, ..
            } => {
                let what = if integer {
                    "a whole number"
                } else {
                    "a number"
                };
                let v: f32 = text
                    .parse()
                    .ok()
                    .filter(|v: &f32| v.is_finite())
                    .ok_or_else(|| {
                        format!("`{text}` is not {what}; give {what} in {min}..={max}")
                    })?;
                if integer && v.fract() != 0.0 {
                    return Err(format!(
                        "`{text}` is not a whole number; give one in {min}..={max}"
                    ));
                }
                if !(min..=max).contains(&v) {
                    return Err(format!("{v} is out of range; give {what} in {min}..={max}"));
                }
                Ok(KnobValue::Number(v))
            }
            KnobKind::Toggle { .. } => match text {
                "on" => Ok(KnobValue::Toggle(true)),
                "off" => Ok(KnobValue::Toggle(false)),
                _ => Err(format!("`{text}`: give on or off")),
            },
            KnobKind::Choice { names, .. } => names
                .iter()
                .find(|n| **n == text)
                .map(|n| KnobValue::Choice(n))
                .ok_or_else(|| format!("`{text}`: give one of {}", names.join(", "))),
        }
    }

    /// The knob's value on `frame`, as text that [`Self::parse`] reads back.
    pub fn text(&self, frame: &FrameDesc) -> String {
        self.get(frame).to_string()
    }

    /// The command line's flag, `--` and the name with `-` for `_`.
    pub fn flag(&self) -> String {
        format!("--{}", self.name.replace('_', "-"))
    }

    /// The values the knob takes, in words (for help texts).
    pub fn values(&self) -> String {
        match self.kind {
            KnobKind::Number { min, max, .. } => format!("{min}..={max}"),
            KnobKind::Toggle { .. } => "on or off".into(),
            KnobKind::Choice { names, .. } => names.join(", "),
        }
    }
}

/// The knobs of every method whose trees shade the ground
/// ([`super::method::RenderMethod::shades_ground`]).
pub static GROUND_KNOBS: &[Knob] = &[
    Knob::toggle(
        "ground_shadows",
        "ground shadows (alpha map + terrain)",
        "tree shadows on the ground from an alpha shadow map, and the terrain's own shadows, both rebuilt when the sun moves",
        |d| d.ground_shadows,
        |d, v| d.ground_shadows = v,
    ),
    Knob::toggle(
        "ground_sky",
        "ground sky visibility (through the trees)",
        "the ground sees the sky only where the trees leave it open (the reference's sky visibility, computed once before the first frame)",
        |d| d.ground_sky,
        |d, v| d.ground_sky = v,
    ),
    Knob::number(
        "terrain_px",
        "terrain detail (px of height error)",
        "terrain chunks out of view are skipped and the others drawn as coarse as keeps their height error below this many pixels (0: every chunk at full detail)",
        (0.0, 16.0),
        |d| d.terrain_px,
        |d, v| d.terrain_px = v,
    )
    .slider(0.0, 4.0, false),
];

/// A set of knob values, applied in order; setting a knob again replaces its value.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct KnobValues(pub Vec<(&'static Knob, KnobValue)>);

impl KnobValues {
    /// Sets `knob` to `value` (replacing a value of the same knob).
    pub fn set(&mut self, knob: &'static Knob, value: KnobValue) {
        match self.0.iter_mut().find(|(k, _)| std::ptr::eq(*k, knob)) {
            Some(slot) => slot.1 = value,
            None => self.0.push((knob, value)),
        }
    }

    /// Every knob in `knobs` as `frame` has it.
    pub fn read(knobs: &[&'static Knob], frame: &FrameDesc) -> Self {
        Self(knobs.iter().map(|k| (*k, k.get(frame))).collect())
    }

    /// Writes each value on `frame`.
    pub fn apply_to(&self, frame: &mut FrameDesc) {
        for (k, v) in &self.0 {
            k.set(frame, *v);
        }
    }

    /// The value of the knob named `name`, if set.
    pub fn get(&self, name: &str) -> Option<KnobValue> {
        self.0.iter().find(|(k, _)| k.name == name).map(|(_, v)| *v)
    }

    /// Name and value of each, for JSON reports.
    pub fn to_map(&self) -> std::collections::BTreeMap<&'static str, KnobValue> {
        self.0.iter().map(|(k, v)| (k.name, *v)).collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    static COUNT: Knob = Knob::number(
        "count_thing",
        "count",
        "",
        (1.0, 10.0),
        |d| d.fog_density,
        |d, v| d.fog_density = v,
    )
    .integer();

    #[test]
    fn numbers_are_checked_against_their_range_and_kind() {
        assert_eq!(COUNT.parse("3"), Ok(KnobValue::Number(3.0)));
        assert_eq!(COUNT.parse("1"), Ok(KnobValue::Number(1.0)));
        assert_eq!(COUNT.parse("10"), Ok(KnobValue::Number(10.0)));
        assert!(COUNT.parse("0").unwrap_err().contains("1..=10"));
        assert!(COUNT.parse("3.5").unwrap_err().contains("whole number"));
        assert!(COUNT.parse("11").unwrap_err().contains("1..=10"));
        assert!(COUNT.parse("NaN").is_err());
        assert!(COUNT.parse("x").unwrap_err().contains("not a whole number"));
        assert_eq!(COUNT.flag(), "--count-thing");
    }

    #[test]
    fn every_number_knob_takes_both_ends_of_its_range() {
        for k in crate::render::method::all_knobs() {
            if let KnobKind::Number { min, max, .. } = k.kind {
                for v in [min, max] {
                    assert_eq!(
                        k.parse(&v.to_string()),
                        Ok(KnobValue::Number(v)),
                        "{}",
                        k.flag()
                    );
                }
            }
        }
    }

    #[test]
    fn toggles_and_choices_read_their_words() {
        let t = Knob::toggle("t", "t", "", |d| d.trees, |d, v| d.trees = v);
        assert_eq!(t.parse("on"), Ok(KnobValue::Toggle(true)));
        assert_eq!(t.parse("off"), Ok(KnobValue::Toggle(false)));
        assert!(t.parse("yes").unwrap_err().contains("on or off"));
        let c = Knob::choice("c", "c", "", &["a", "b"], |_| "a", |_, _| {});
        assert_eq!(c.parse("b"), Ok(KnobValue::Choice("b")));
        assert!(c.parse("c").unwrap_err().contains("a, b"));
        assert_eq!(KnobValue::Toggle(false).to_string(), "off");
    }

    #[test]
    fn a_value_of_another_kind_is_not_written() {
        let mut d = FrameDesc::from_scene(&crate::scene::Scene::default_scene());
        let before = d.fog_density;
        COUNT.set(&mut d, KnobValue::Toggle(true));
        assert_eq!(d.fog_density, before);
        COUNT.set(&mut d, KnobValue::Number(4.0));
        assert_eq!(COUNT.get(&d), KnobValue::Number(4.0));
    }
}
