//! Species parameters: everything the tree generator needs to grow one species prototype
//! (trunk, crown envelope, main branches, twigs, leaves or needles, colours), the built-in
//! presets (`fir`, `broadleaf`, embedded from `assets/species/*.toml`) and their validation.

use serde::{Deserialize, Serialize};

use super::FieldError;
use super::check;

/// The names accepted by [`preset`].
pub const PRESET_NAMES: &[&str] = &["fir", "broadleaf", "pine"];

/// The fir preset as TOML (the file documents every field).
pub const FIR_TOML: &str = include_str!("../../assets/species/fir.toml");
/// The broadleaf preset as TOML.
pub const BROADLEAF_TOML: &str = include_str!("../../assets/species/broadleaf.toml");
/// The pine preset as TOML (the second conifer: long bare trunk, needles in clumps).
pub const PINE_TOML: &str = include_str!("../../assets/species/pine.toml");

/// Largest number of leaves or needles one tree may have (all levels multiplied out).
pub const MAX_FOLIAGE_PER_TREE: u64 = 2_000_000;

/// What grows on the twigs.
#[derive(Clone, Copy, Debug, Deserialize, Serialize, PartialEq, Eq, Hash)]
#[serde(rename_all = "lowercase")]
pub enum FoliageKind {
    /// Thin folded slivers (2 triangles each), mostly on the sides and top of the twig.
    Needles,
    /// Small flat leaves (4 triangles each) all around the twig.
    Leaves,
}

/// The shape of the crown envelope that main-branch lengths are fitted to.
#[derive(Clone, Copy, Debug, Deserialize, Serialize, PartialEq, Eq, Hash)]
#[serde(rename_all = "lowercase")]
pub enum CrownShape {
    /// A cone: widest (`crown_radius`) at the lowest branch, a point at the top.
    Conical,
    /// An ellipsoid from a little below the lowest branch to the top of the tree.
    Rounded,
}

/// How twigs sit along a main branch.
#[derive(Clone, Copy, Debug, Deserialize, Serialize, PartialEq, Eq, Hash)]
#[serde(rename_all = "lowercase")]
pub enum TwigArrangement {
    /// Alternating left and right in the branch's plane: the flat sprays of a fir.
    Planar,
    /// A golden-angle spiral around the branch.
    Spiral,
}

/// All parameters of one species. Lengths are metres, angles degrees, colours linear RGB.
/// Tree frame: origin at the ground, +Y up. See `assets/species/fir.toml` for a commented
/// example of every field.
#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct SpeciesParams {
    /// `needles` or `leaves`.
    pub foliage: FoliageKind,
    /// `conical` or `rounded`.
    pub crown: CrownShape,
    /// Tree height at scale 1 (m): the top of the crown envelope.
    pub height: f32,
    /// Where the trunk ends, as a fraction of `height` (the leader twigs sit there).
    pub trunk_height: f32,
    /// Trunk radius at the ground, above the root flare (m).
    pub trunk_radius: f32,
    /// Trunk radius where it ends (m).
    pub trunk_top_radius: f32,
    /// Sides of the trunk's cross-section (3..=32).
    pub trunk_sides: u32,
    /// Bark colour (linear RGB).
    #[serde(deserialize_with = "super::serde_util::vec3")]
    pub bark_color: [f32; 3],
    /// Height of the lowest main branch, as a fraction of `height`.
    pub crown_base: f32,
    /// Height of the highest main branch, as a fraction of `height`.
    pub crown_top: f32,
    /// Widest horizontal radius of the crown envelope (m).
    pub crown_radius: f32,
    /// Number of main branches (instances of the one branch prototype).
    pub branch_count: u32,
    /// Main branches per whorl (same height, evenly around the trunk); 1 gives a spiral.
    pub branches_per_whorl: u32,
    /// Angle between a branch and the vertical at the lowest branch (degrees; 90 = horizontal).
    pub branch_angle_low: f32,
    /// Same at the highest branch.
    pub branch_angle_high: f32,
    /// How far the limb bends down by its tip (degrees).
    pub branch_droop: f32,
    /// Length of the prototype limb (m); instances are scaled to fit the crown envelope.
    pub branch_length: f32,
    /// Limb radius at its base (m).
    pub branch_radius: f32,
    /// Sides of the limb's cross-section (3..=16).
    pub branch_sides: u32,
    /// Smallest scale of a main-branch instance (near the top of the crown).
    pub branch_min_scale: f32,
    /// Twigs per main branch, including the terminal twig at the limb's tip.
    pub twigs_per_branch: u32,
    /// `planar` (fir sprays) or `spiral`.
    pub twig_arrangement: TwigArrangement,
    /// Angle between a twig and its limb (degrees).
    pub twig_angle: f32,
    /// Length of the twig prototype (m).
    pub twig_length: f32,
    /// Radius of the twig's stem at its base (m).
    pub twig_radius: f32,
    /// Where along the limb the first twig sits (fraction of the limb's length).
    pub twig_start: f32,
    /// Scale of the twigs near the limb's tip relative to those near its base.
    pub twig_tip_scale: f32,
    /// Twigs at the end of the trunk: the first points straight up (the leader), the others
    /// around it.
    pub leader_twigs: u32,
    /// Leaves or needles per twig.
    pub foliage_per_twig: u32,
    /// Length of a leaf or needle (m).
    pub foliage_length: f32,
    /// Width of a leaf or needle (m).
    pub foliage_width: f32,
    /// Angle between a leaf or needle and the twig's axis (degrees).
    pub foliage_angle: f32,
    /// Main foliage colour (linear RGB).
    #[serde(deserialize_with = "super::serde_util::vec3")]
    pub foliage_color: [f32; 3],
    /// Second foliage colour mixed in per leaf (yellow-green leaves, light new needles near
    /// twig tips).
    #[serde(deserialize_with = "super::serde_util::vec3")]
    pub foliage_color_alt: [f32; 3],
    /// Amount of per-leaf/needle colour variation, 0..=1.
    pub foliage_variation: f32,
}

impl Default for SpeciesParams {
    /// The fir (a test checks that this equals `preset("fir")`).
    fn default() -> Self {
        SpeciesParams {
            foliage: FoliageKind::Needles,
            crown: CrownShape::Conical,
            height: 18.0,
            trunk_height: 0.95,
            trunk_radius: 0.22,
            trunk_top_radius: 0.03,
            trunk_sides: 8,
            bark_color: [0.09, 0.065, 0.045],
            crown_base: 0.12,
            crown_top: 0.92,
            crown_radius: 4.0,
            branch_count: 64,
            branches_per_whorl: 1,
            branch_angle_low: 100.0,
            branch_angle_high: 65.0,
            branch_droop: 25.0,
            branch_length: 3.0,
            branch_radius: 0.07,
            branch_sides: 5,
            branch_min_scale: 0.4,
            twigs_per_branch: 10,
            twig_arrangement: TwigArrangement::Spiral,
            twig_angle: 60.0,
            twig_length: 1.3,
            twig_radius: 0.012,
            twig_start: 0.03,
            twig_tip_scale: 1.2,
            leader_twigs: 4,
            foliage_per_twig: 90,
            foliage_length: 0.42,
            foliage_width: 0.09,
            foliage_angle: 80.0,
            foliage_color: [0.035, 0.085, 0.03],
            foliage_color_alt: [0.09, 0.16, 0.04],
            foliage_variation: 0.35,
        }
    }
}

/// The built-in preset `name` (one of [`PRESET_NAMES`]), or `None`.
pub fn preset(name: &str) -> Option<SpeciesParams> {
    let text = match name {
        "fir" => FIR_TOML,
        "broadleaf" => BROADLEAF_TOML,
        "pine" => PINE_TOML,
        _ => return None,
    };
    // The embedded presets are checked by tests; a failure here cannot come from user input.
    toml::from_str(text).ok()
}

impl SpeciesParams {
    /// Checks every field against its valid range; the first problem is returned, naming
    /// the field.
    pub fn check(&self) -> Result<(), FieldError> {
        use check::*;
        positive("height", self.height)?;
        range("height", self.height, 0.1, 200.0)?;
        range("trunk_height", self.trunk_height, 0.05, 1.0)?;
        positive("trunk_radius", self.trunk_radius)?;
        range("trunk_radius", self.trunk_radius, 0.0, 10.0)?;
        range("trunk_top_radius", self.trunk_top_radius, 0.0, 10.0)?;
        if self.trunk_top_radius > self.trunk_radius {
            return Err(FieldError::new(
                "trunk_top_radius",
                format!("must not exceed trunk_radius ({})", self.trunk_radius),
            )
            .with_found(self.trunk_top_radius));
        }
        range_u32("trunk_sides", self.trunk_sides, 3, 32)?;
        color("bark_color", self.bark_color, 1.0)?;
        range("crown_base", self.crown_base, 0.0, 1.0)?;
        range("crown_top", self.crown_top, 0.0, 1.0)?;
        if self.crown_top < self.crown_base {
            return Err(FieldError::new(
                "crown_top",
                format!("must be >= crown_base ({})", self.crown_base),
            )
            .with_found(self.crown_top));
        }
        positive("crown_radius", self.crown_radius)?;
        range("crown_radius", self.crown_radius, 0.0, 100.0)?;
        range_u32("branch_count", self.branch_count, 0, 1000)?;
        range_u32("branches_per_whorl", self.branches_per_whorl, 1, 32)?;
        range("branch_angle_low", self.branch_angle_low, 0.0, 150.0)?;
        range("branch_angle_high", self.branch_angle_high, 0.0, 150.0)?;
        range("branch_droop", self.branch_droop, -60.0, 60.0)?;
        positive("branch_length", self.branch_length)?;
        range("branch_length", self.branch_length, 0.0, 100.0)?;
        positive("branch_radius", self.branch_radius)?;
        range("branch_radius", self.branch_radius, 0.0, 5.0)?;
        range_u32("branch_sides", self.branch_sides, 3, 16)?;
        range("branch_min_scale", self.branch_min_scale, 0.01, 1.0)?;
        range_u32("twigs_per_branch", self.twigs_per_branch, 0, 500)?;
        range("twig_angle", self.twig_angle, 0.0, 120.0)?;
        positive("twig_length", self.twig_length)?;
        range("twig_length", self.twig_length, 0.0, 20.0)?;
        positive("twig_radius", self.twig_radius)?;
        range("twig_radius", self.twig_radius, 0.0, 1.0)?;
        range("twig_start", self.twig_start, 0.0, 1.0)?;
        range("twig_tip_scale", self.twig_tip_scale, 0.05, 2.0)?;
        range_u32("leader_twigs", self.leader_twigs, 0, 32)?;
        range_u32("foliage_per_twig", self.foliage_per_twig, 0, 10_000)?;
        positive("foliage_length", self.foliage_length)?;
        range("foliage_length", self.foliage_length, 0.0, 5.0)?;
        positive("foliage_width", self.foliage_width)?;
        range("foliage_width", self.foliage_width, 0.0, 5.0)?;
        range("foliage_angle", self.foliage_angle, 0.0, 120.0)?;
        color("foliage_color", self.foliage_color, 1.0)?;
        color("foliage_color_alt", self.foliage_color_alt, 1.0)?;
        range("foliage_variation", self.foliage_variation, 0.0, 1.0)?;
        let twigs = self.total_twigs();
        let foliage = twigs * u64::from(self.foliage_per_twig);
        if foliage > MAX_FOLIAGE_PER_TREE {
            return Err(FieldError::new(
                "foliage_per_twig",
                format!(
                    "{twigs} twigs x {} = {foliage} leaves/needles per tree exceeds the limit of \
                     {MAX_FOLIAGE_PER_TREE}; lower foliage_per_twig, twigs_per_branch or branch_count",
                    self.foliage_per_twig
                ),
            ));
        }
        Ok(())
    }

    /// Twig instances per tree: `branch_count * twigs_per_branch + leader_twigs`.
    pub fn total_twigs(&self) -> u64 {
        u64::from(self.branch_count) * u64::from(self.twigs_per_branch)
            + u64::from(self.leader_twigs)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn presets_parse_and_validate() {
        for name in PRESET_NAMES {
            let p = preset(name).unwrap_or_else(|| panic!("preset {name} must parse"));
            p.check().unwrap_or_else(|e| panic!("preset {name}: {e}"));
        }
        assert!(preset("oak").is_none());
        let fir = preset("fir").unwrap_or_default();
        assert_eq!(fir.foliage, FoliageKind::Needles);
        assert_eq!(
            preset("broadleaf").map(|p| p.foliage),
            Some(FoliageKind::Leaves)
        );
    }

    #[test]
    fn the_pine_is_a_second_conifer_with_a_bare_trunk_and_clumped_needles() {
        use crate::model::TreeModel;
        let model = |name: &str| {
            let p = preset(name).unwrap_or_else(|| panic!("preset {name}"));
            let h = p.height;
            match TreeModel::generate(&p, 1) {
                Ok(m) => (m, h),
                Err(e) => panic!("{e}"),
            }
        };
        let (pine, h) = model("pine");
        let (fir, fir_h) = model("fir");
        assert_eq!(pine.foliage, FoliageKind::Needles);
        // The lowest twig of the pine is above half its height; the fir's far below.
        let lowest = |m: &TreeModel| {
            m.twigs_in_tree_frame()
                .iter()
                .map(|t| t.w_axis.y)
                .fold(f32::INFINITY, f32::min)
        };
        assert!(lowest(&pine) > 0.5 * h, "pine {}", lowest(&pine));
        assert!(lowest(&fir) < 0.3 * fir_h, "fir {}", lowest(&fir));
        // Twigs only on the outer half of each limb: clumps at the limb ends.
        let p = preset("pine").unwrap_or_default();
        assert!(p.twig_start >= 0.4 && preset("fir").is_some_and(|f| f.twig_start < 0.2));
        // Near the thesis' fir in triangles (about 120,000).
        let tris = pine.triangle_counts().tree;
        assert!((60_000..=130_000).contains(&tris), "{tris}");
    }

    #[test]
    fn default_is_the_fir_preset() {
        assert_eq!(preset("fir"), Some(SpeciesParams::default()));
    }

    #[test]
    fn preset_round_trips_through_toml() {
        let p = SpeciesParams::default();
        let text = toml::to_string(&p).unwrap_or_default();
        let back: Result<SpeciesParams, _> = toml::from_str(&text);
        assert_eq!(back.ok(), Some(p));
    }

    #[test]
    fn unknown_field_is_rejected() {
        let text = format!("{FIR_TOML}\nbranch_cuont = 3\n");
        let r: Result<SpeciesParams, _> = toml::from_str(&text);
        let msg = r.err().map(|e| e.to_string()).unwrap_or_default();
        assert!(msg.contains("branch_cuont"), "{msg}");
    }

    /// Every check, one bad value each: the error names the field.
    #[test]
    fn every_check_names_its_field() {
        type Mutator = fn(&mut SpeciesParams);
        let cases: &[(&str, Mutator)] = &[
            ("height", |p| p.height = f32::NAN),
            ("height", |p| p.height = -1.0),
            ("height", |p| p.height = 500.0),
            ("trunk_height", |p| p.trunk_height = 1.5),
            ("trunk_radius", |p| p.trunk_radius = 0.0),
            ("trunk_radius", |p| p.trunk_radius = 11.0),
            ("trunk_top_radius", |p| p.trunk_top_radius = -0.1),
            ("trunk_top_radius", |p| p.trunk_top_radius = 1.0),
            ("trunk_sides", |p| p.trunk_sides = 2),
            ("bark_color[1]", |p| p.bark_color[1] = -0.5),
            ("bark_color[2]", |p| p.bark_color[2] = f32::INFINITY),
            ("crown_base", |p| p.crown_base = -0.1),
            ("crown_top", |p| p.crown_top = 1.1),
            ("crown_top", |p| p.crown_top = 0.05),
            ("crown_radius", |p| p.crown_radius = 0.0),
            ("crown_radius", |p| p.crown_radius = 1000.0),
            ("branch_count", |p| p.branch_count = 5000),
            ("branches_per_whorl", |p| p.branches_per_whorl = 0),
            ("branch_angle_low", |p| p.branch_angle_low = 200.0),
            ("branch_angle_high", |p| p.branch_angle_high = -1.0),
            ("branch_droop", |p| p.branch_droop = 90.0),
            ("branch_length", |p| p.branch_length = 0.0),
            ("branch_length", |p| p.branch_length = 101.0),
            ("branch_radius", |p| p.branch_radius = -1.0),
            ("branch_radius", |p| p.branch_radius = 6.0),
            ("branch_sides", |p| p.branch_sides = 17),
            ("branch_min_scale", |p| p.branch_min_scale = 0.0),
            ("twigs_per_branch", |p| p.twigs_per_branch = 501),
            ("twig_angle", |p| p.twig_angle = f32::NAN),
            ("twig_length", |p| p.twig_length = 0.0),
            ("twig_length", |p| p.twig_length = 21.0),
            ("twig_radius", |p| p.twig_radius = 0.0),
            ("twig_radius", |p| p.twig_radius = 2.0),
            ("twig_start", |p| p.twig_start = 2.0),
            ("twig_tip_scale", |p| p.twig_tip_scale = 0.0),
            ("leader_twigs", |p| p.leader_twigs = 33),
            ("foliage_per_twig", |p| p.foliage_per_twig = 10_001),
            ("foliage_per_twig", |p| {
                p.branch_count = 1000;
                p.twigs_per_branch = 500;
                p.foliage_per_twig = 100;
            }),
            ("foliage_length", |p| p.foliage_length = 0.0),
            ("foliage_length", |p| p.foliage_length = 6.0),
            ("foliage_width", |p| p.foliage_width = -0.01),
            ("foliage_width", |p| p.foliage_width = 6.0),
            ("foliage_angle", |p| p.foliage_angle = 130.0),
            ("foliage_color[0]", |p| p.foliage_color[0] = 2.0),
            ("foliage_color_alt[1]", |p| {
                p.foliage_color_alt[1] = f32::NAN
            }),
            ("foliage_variation", |p| p.foliage_variation = 1.5),
        ];
        for (field, mutate) in cases {
            let mut p = SpeciesParams::default();
            mutate(&mut p);
            match p.check() {
                Ok(()) => panic!("{field}: bad value accepted"),
                Err(e) => assert_eq!(&e.field, field, "{e}"),
            }
        }
        // Non-finite values are reported as such.
        let p = SpeciesParams {
            height: f32::NAN,
            ..SpeciesParams::default()
        };
        let msg = p.check().err().map(|e| e.describe()).unwrap_or_default();
        assert!(msg.contains("finite") && msg.contains("NaN"), "{msg}");
    }
}
