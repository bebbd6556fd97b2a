//! Validation of the data types: the settings against their allowed values, each record's
//! fields against its data lengths, no duplicate records, and that a bake fits the format's
//! limits. The writer checks before writing, the reader while decoding.

use std::collections::HashSet;

use super::plan::plan_sections;
use super::*;

impl BakeSettings {
    /// Checks every field against its allowed values.
    pub fn validate(&self) -> Result<(), FormatError> {
        let bad = |field, value, allowed| {
            Err(FormatError::InvalidSettings {
                field,
                value,
                allowed,
            })
        };
        if !DIRECTION_COUNTS.contains(&self.views) {
            return bad("views", self.views, SETTINGS_DIRECTIONS);
        }
        if !DIRECTION_COUNTS.contains(&self.tree_views) {
            return bad("tree_views", self.tree_views, SETTINGS_DIRECTIONS);
        }
        if !DIRECTION_COUNTS.contains(&self.lights) {
            return bad("lights", self.lights, SETTINGS_DIRECTIONS);
        }
        if !BTF_RESOLUTIONS.contains(&self.resolution) {
            return bad("resolution", self.resolution, SETTINGS_RESOLUTIONS);
        }
        if !SUPERSAMPLE_RANGE.contains(&self.supersample) {
            return bad("supersample", self.supersample, SETTINGS_SUPERSAMPLE);
        }
        if !VCM_RESOLUTION_RANGE.contains(&self.vcm_resolution) {
            return bad(
                "vcm_resolution",
                self.vcm_resolution,
                SETTINGS_VCM_RESOLUTION,
            );
        }
        if self.texel_resolution != 0 && !TEXEL_RESOLUTION_RANGE.contains(&self.texel_resolution) {
            return bad(
                "texel_resolution",
                self.texel_resolution,
                SETTINGS_TEXEL_RESOLUTION,
            );
        }
        if self.impostor_frames != 0 && !IMPOSTOR_FRAMES_RANGE.contains(&self.impostor_frames) {
            return bad(
                "impostor_frames",
                self.impostor_frames,
                SETTINGS_IMPOSTOR_FRAMES,
            );
        }
        if self.surfel_budget != 0 && !SURFEL_BUDGET_RANGE.contains(&self.surfel_budget) {
            return bad("surfel_budget", self.surfel_budget, SETTINGS_SURFEL_BUDGET);
        }
        if !IMPOSTOR_RESOLUTIONS.contains(&self.impostor_resolution) {
            return bad(
                "impostor_resolution",
                self.impostor_resolution,
                SETTINGS_IMPOSTOR_RESOLUTION,
            );
        }
        Ok(())
    }
}

impl BtfImageSet {
    /// What is wrong with this set's fields given its image lengths, if anything.
    pub(super) fn problem(&self, direct_len: u64, ambient_len: u64) -> Option<String> {
        if !DIRECTION_COUNTS.contains(&self.views) {
            return Some(format!(
                "views is {}, not {SETTINGS_DIRECTIONS}",
                self.views
            ));
        }
        if !DIRECTION_COUNTS.contains(&self.lights) {
            return Some(format!(
                "lights is {}, not {SETTINGS_DIRECTIONS}",
                self.lights
            ));
        }
        if !BTF_RESOLUTIONS.contains(&self.resolution) {
            return Some(format!(
                "resolution is {}, not {SETTINGS_RESOLUTIONS}",
                self.resolution
            ));
        }
        if let Some(i) = self.center.iter().position(|c| !c.is_finite()) {
            return Some(format!("center[{i}] is {}, not finite", self.center[i]));
        }
        if !(self.radius.is_finite() && self.radius > 0.0) {
            return Some(format!("radius is {}, not finite and > 0", self.radius));
        }
        if !(self.texel_size.is_finite() && self.texel_size > 0.0) {
            return Some(format!(
                "texel_size is {}, not finite and > 0",
                self.texel_size
            ));
        }
        let expected = self.expected_direct_len();
        if expected != Some(direct_len) {
            return Some(format!(
                "direct holds {direct_len} bytes, expected {} ({} views x {} lights x {} bytes \
                 an image of {}² in {:?})",
                show_len(expected),
                self.views,
                self.lights,
                show_len(self.image_bytes()),
                self.resolution,
                self.encoding
            ));
        }
        let expected = self.expected_ambient_len();
        if expected != Some(ambient_len) {
            return Some(format!(
                "ambient holds {ambient_len} bytes, expected {} ({AMBIENT_IMAGES_PER_VIEW} x {} views \
                 x {} bytes an image)",
                show_len(expected),
                self.views,
                show_len(self.image_bytes()),
            ));
        }
        None
    }
}

impl VcmSet {
    /// What is wrong with this set's fields given its opacity length, if anything.
    pub(super) fn problem(&self, opacity_len: u64) -> Option<String> {
        if !VCM_RESOLUTION_RANGE.contains(&self.resolution) {
            return Some(format!(
                "resolution is {}, not {SETTINGS_VCM_RESOLUTION}",
                self.resolution
            ));
        }
        if let Some(i) = self
            .mean_opacity
            .iter()
            .position(|m| !(m.is_finite() && (0.0..=1.0).contains(m)))
        {
            return Some(format!(
                "mean_opacity[{i}] is {}, not in [0, 1]",
                self.mean_opacity[i]
            ));
        }
        let expected = self.expected_opacity_len();
        if expected != Some(opacity_len) {
            return Some(format!(
                "opacity holds {opacity_len} bytes, expected {} (8 corners x 6 faces x {} bytes \
                 a face of {}² in {:?})",
                show_len(expected),
                show_len(self.face_bytes()),
                self.resolution,
                self.encoding
            ));
        }
        None
    }
}

impl TexelVolume {
    /// What is wrong with this volume's fields given its data length, if anything.
    pub(super) fn problem(&self, voxels_len: u64) -> Option<String> {
        if !DIRECTION_COUNTS.contains(&self.lights) {
            return Some(format!(
                "lights is {}, not {SETTINGS_DIRECTIONS}",
                self.lights
            ));
        }
        if let Some(i) = self.dims.iter().position(|d| !TEXEL_DIM_RANGE.contains(d)) {
            return Some(format!("dims[{i}] is {}, not 1 to 256", self.dims[i]));
        }
        if let Some(i) = self.box_min.iter().position(|c| !c.is_finite()) {
            return Some(format!("box_min[{i}] is {}, not finite", self.box_min[i]));
        }
        if !(self.voxel.is_finite() && self.voxel > 0.0) {
            return Some(format!("voxel is {}, not finite and > 0", self.voxel));
        }
        let expected = self.expected_voxels_len();
        if expected != Some(voxels_len) {
            return Some(format!(
                "voxels holds {voxels_len} bytes, expected {} ({} lights + sky x {}x{}x{} x 4)",
                show_len(expected),
                self.lights,
                self.dims[0],
                self.dims[1],
                self.dims[2]
            ));
        }
        None
    }
}

impl Impostor {
    /// What is wrong with this impostor's fields given its atlas lengths, if anything.
    pub(super) fn problem(&self, albedo_len: u64, normal_depth_len: u64) -> Option<String> {
        if !IMPOSTOR_FRAMES_RANGE.contains(&self.frames) {
            return Some(format!("frames is {}, not 4 to 32", self.frames));
        }
        if !IMPOSTOR_RESOLUTIONS.contains(&self.resolution) {
            return Some(format!(
                "resolution is {}, not {SETTINGS_IMPOSTOR_RESOLUTION}",
                self.resolution
            ));
        }
        let most = impostor_mip_levels(self.resolution);
        if !(1..=most).contains(&self.mip_levels) {
            return Some(format!(
                "mip_levels is {}, not 1 to {most} (frames of {} pixels, down to {})",
                self.mip_levels, self.resolution, IMPOSTOR_MIN_MIP_SIDE
            ));
        }
        if let Some(i) = self.center.iter().position(|c| !c.is_finite()) {
            return Some(format!("center[{i}] is {}, not finite", self.center[i]));
        }
        if !(self.radius.is_finite() && self.radius > 0.0) {
            return Some(format!("radius is {}, not finite and > 0", self.radius));
        }
        let expected = self.expected_atlas_len();
        for (name, len) in [("albedo", albedo_len), ("normal_depth", normal_depth_len)] {
            if expected != Some(len) {
                return Some(format!(
                    "{name} holds {len} bytes, expected {} ({} x {} frames of {}² pixels x 4, {} levels)",
                    show_len(expected),
                    self.frames,
                    self.frames,
                    self.resolution,
                    self.mip_levels
                ));
            }
        }
        None
    }
}

impl Baked {
    /// Checks everything [`write_atomic`] checks before writing: the settings, every set
    /// (sizes, finite floats, ...), no BTF `(species, level)` twice, and that the data fits
    /// the format's limits.
    pub fn validate(&self) -> Result<(), FormatError> {
        self.validate_for(MAX_SECTION_BYTES)
    }

    /// [`Baked::validate`] with the section size limit as a parameter.
    pub(super) fn validate_for(&self, section_limit: u64) -> Result<(), FormatError> {
        self.settings.validate()?;
        for (i, set) in self.btf.iter().enumerate() {
            if let Some(reason) = set.problem(set.direct.len() as u64, set.ambient.len() as u64) {
                return Err(FormatError::MalformedContent {
                    section: format!("btf set {i} (species {}, {:?})", set.species, set.level),
                    reason,
                });
            }
        }
        for (i, set) in self.vcm.iter().enumerate() {
            if let Some(reason) = set.problem(set.opacity.len() as u64) {
                return Err(FormatError::MalformedContent {
                    section: format!("vcm set {i} (owner {}, {:?})", set.owner, set.level),
                    reason,
                });
            }
        }
        for (i, t) in self.texels.iter().enumerate() {
            if let Some(reason) = t.problem(t.voxels.len() as u64) {
                return Err(FormatError::MalformedContent {
                    section: format!("texel volume {i} (species {})", t.species),
                    reason,
                });
            }
        }
        for (i, imp) in self.impostors.iter().enumerate() {
            let lens = (imp.albedo.len() as u64, imp.normal_depth.len() as u64);
            if let Some(reason) = imp.problem(lens.0, lens.1) {
                return Err(FormatError::MalformedContent {
                    section: format!("impostor {i} (species {})", imp.species),
                    reason,
                });
            }
        }
        for (i, t) in self.surfels.iter().enumerate() {
            if let Some(reason) = t.problem() {
                return Err(FormatError::MalformedContent {
                    section: format!("surfel tree {i} (species {})", t.species),
                    reason,
                });
            }
        }
        check_unique_btf(&self.btf)?;
        check_unique_texels(&self.texels)?;
        check_unique_impostors(&self.impostors)?;
        check_unique_surfels(&self.surfels)?;
        let plans = plan_sections(self, section_limit);
        if let Some(p) = plans.iter().find(|p| p.len > section_limit) {
            return Err(FormatError::AbsurdSize {
                field: format!("the size of {} record {}", p.kind.name(), p.first),
                value: p.len - SECTION_PREFIX_BYTES,
                limit: section_limit.saturating_sub(SECTION_PREFIX_BYTES),
            });
        }
        if plans.len() > MAX_SECTIONS as usize {
            return Err(FormatError::AbsurdSize {
                field: "section count".into(),
                value: plans.len() as u64,
                limit: u64::from(MAX_SECTIONS),
            });
        }
        Ok(())
    }
}

pub(super) fn show_len(len: Option<u64>) -> String {
    len.map_or_else(|| "more than 2^64".to_owned(), |l| l.to_string())
}

/// The first record whose `key` was seen before, as malformed content (`what` names a
/// record; `of` what the repeated key means).
fn check_unique<T, K: std::hash::Hash + Eq>(
    records: &[T],
    key: impl Fn(&T) -> K,
    what: impl Fn(usize, &T) -> String,
    of: &str,
) -> Result<(), FormatError> {
    let mut seen = HashSet::with_capacity(records.len());
    for (i, r) in records.iter().enumerate() {
        if !seen.insert(key(r)) {
            return Err(FormatError::MalformedContent {
                section: what(i, r),
                reason: format!("{of} appears twice"),
            });
        }
    }
    Ok(())
}

pub(super) fn check_unique_texels(volumes: &[TexelVolume]) -> Result<(), FormatError> {
    check_unique(
        volumes,
        |t| t.species,
        |i, t| format!("texel volume {i} (species {})", t.species),
        "a texel volume of this species",
    )
}

pub(super) fn check_unique_impostors(impostors: &[Impostor]) -> Result<(), FormatError> {
    check_unique(
        impostors,
        |t| t.species,
        |i, t| format!("impostor {i} (species {})", t.species),
        "an impostor of this species",
    )
}

pub(super) fn check_unique_surfels(trees: &[SurfelSet]) -> Result<(), FormatError> {
    check_unique(
        trees,
        |t| t.species,
        |i, t| format!("surfel tree {i} (species {})", t.species),
        "a surfel tree of this species",
    )
}

pub(super) fn check_unique_btf(sets: &[BtfImageSet]) -> Result<(), FormatError> {
    check_unique(
        sets,
        |s| (s.species, s.level),
        |i, s| format!("btf set {i} (species {}, {:?})", s.species, s.level),
        "a btf set of this species and level",
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::format::test_support::*;
    use std::fs;

    #[test]
    fn invalid_settings_are_rejected_on_write_and_read() {
        let dir = scratch_dir("settings");
        let path = dir.join("bad.canopy");
        type Change = fn(&mut BakeSettings);
        let cases: [(Change, &str); 11] = [
            (|s| s.views = 7, "views"),
            (|s| s.lights = 0, "lights"),
            (|s| s.resolution = 256, "resolution"),
            (|s| s.supersample = 0, "supersample"),
            (|s| s.supersample = 9, "supersample"),
            (|s| s.vcm_resolution = 4, "vcm_resolution"),
            (|s| s.texel_resolution = 8, "texel_resolution"),
            (|s| s.texel_resolution = 512, "texel_resolution"),
            (|s| s.impostor_frames = 3, "impostor_frames"),
            (|s| s.impostor_frames = 33, "impostor_frames"),
            (|s| s.impostor_resolution = 48, "impostor_resolution"),
        ];
        for (change, name) in cases {
            let mut baked = small();
            change(&mut baked.settings);
            let err = write_atomic(&path, &baked).unwrap_err();
            assert!(
                matches!(err, FormatError::InvalidSettings { field, .. } if field == name),
                "{err:?}"
            );
            assert!(dir_entries(&dir).is_empty(), "nothing written");
            let err = from_bytes(&to_bytes(&baked)).unwrap_err();
            assert!(
                matches!(err, FormatError::InvalidSettings { field, .. } if field == name),
                "{err:?}"
            );
        }
        for good in DIRECTION_COUNTS {
            let mut s = settings();
            s.views = good;
            s.lights = good;
            s.validate().unwrap();
        }
        fs::remove_dir_all(&dir).unwrap();
    }
}
