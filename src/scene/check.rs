//! The checks a scene's values must pass after deserialisation (ranges, finite numbers,
//! one of `preset` or `params`, ...); each error names the full dotted key.

use glam::Vec3;

use super::{RenderParams, Scene};
use crate::model::params::MAX_SPECIES;
use crate::model::species::{PRESET_NAMES, preset};
use crate::model::{FieldError, check};

impl RenderParams {
    pub(super) fn check(&self) -> Result<(), FieldError> {
        let range = |key: &str, v: Option<f32>, lo: f32, hi: f32| match v {
            Some(x) if !(lo..=hi).contains(&x) => {
                Err(FieldError::new(key, format!("must be a number in {lo}..={hi}")).with_found(x))
            }
            _ => Ok(()),
        };
        range("lod_scale", self.lod_scale, 0.05, 64.0)?;
        range("weight_threshold", self.weight_threshold, 0.0, 1.0)?;
        range("lod_fade", self.lod_fade, 0.0, 1.0)?;
        range("canopy_px", self.canopy_px, 0.5, 64.0)?;
        if let Some(p) = &self.planes
            && p != "single"
            && p != "crossed"
        {
            return Err(FieldError::new("planes", "must be `single` or `crossed`").with_found(p));
        }
        Ok(())
    }
}

impl Scene {
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
        let prototypes: usize = self.species.iter().map(|s| s.prototypes() as usize).sum();
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
            if let Some(g) = &s.gltf {
                if s.preset.is_some() || s.params.is_some() {
                    return Err(FieldError::new(
                        format!("{at}.gltf"),
                        "give one of `preset`, a [species.params] table and `gltf`, not several",
                    ));
                }
                if g.trim().is_empty() {
                    return Err(FieldError::new(format!("{at}.gltf"), "must not be empty"));
                }
                if s.gltf_variants.iter().any(|v| v.trim().is_empty()) {
                    return Err(FieldError::new(
                        format!("{at}.gltf_variants"),
                        "must not hold an empty path",
                    ));
                }
                check::range_u32(
                    &format!("{at}.gltf_variants"),
                    s.prototypes(),
                    1,
                    crate::model::params::MAX_VARIANTS,
                )?;
                if let Some(scale) = s.scale {
                    check::range(&format!("{at}.scale"), scale, 1e-4, 1e4)?;
                }
                if s.variants != 1 {
                    return Err(FieldError::new(
                        format!("{at}.variants"),
                        "a `gltf` species takes its variants as files: `gltf_variants = [\"b.glb\", ...]`",
                    )
                    .with_found(s.variants));
                }
                continue;
            }
            for (key, given) in [
                ("scale", s.scale.is_some()),
                ("up", s.up.is_some()),
                ("gltf_variants", !s.gltf_variants.is_empty()),
            ] {
                if given {
                    return Err(FieldError::new(
                        format!("{at}.{key}"),
                        "only a `gltf` species takes it",
                    ));
                }
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
                            "give `preset` (one of {}), a [species.params] table or `gltf`",
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::test_support::*;
    use crate::scene::{ForestParams, TexelParams, TexelSource};

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
            msg.contains("forest.stands.covr") && msg.contains("expected one of `cover`"),
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
        let header = nth_line(BASE, 1, |l| l == "[[species]]");
        error_at(&text, header, "species[1]: give `preset`");
        // Both.
        let text = BASE.replace(
            "preset = \"broadleaf\"\nseed = 2\n",
            &format!(
                "preset = \"broadleaf\"\nseed = 2\n[species.params]\n{}\n",
                crate::model::species::BROADLEAF_TOML
            ),
        );
        let line = nth_line(&text, 0, |l| l == "preset = \"broadleaf\"");
        error_at(&text, line, "species[1].preset: give either");
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
        let line = nth_line(BASE, 0, |l| l == "[[species]]");
        error_at(&text, line, "species: at most 64 species");
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
}
