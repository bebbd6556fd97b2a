//! Live reload of the scene file the viewer shows. The file is looked at twice a second
//! (its modification time and length; editors that save by renaming a new file over the
//! old are seen too) and an edit is sorted by what it changes:
//!
//! - only the frame (sun, sky, camera, the `[render]` knobs): applied at once, to the
//!   fields the edit touched, so the user's own changes to the others stay;
//! - what is baked (species, terrain, placement, `[bake]`, `[texel]`: the bake key
//!   differs): a background bake of the new scene, the old one shown until it is ready;
//! - a broken edit: its error (file, line, key) in the panel, the last good scene kept.

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant, SystemTime};

use crate::model::World;
use crate::render::FrameDesc;
use crate::scene::Scene;

/// What an edit of the scene file means.
pub enum Reload {
    /// The file parses to the scene on show.
    Unchanged,
    /// Only the frame changes.
    Frame(Box<Scene>),
    /// The bake changes: the new scene and its world.
    Rebake(Box<Scene>, Box<World>),
    /// The edit cannot be used; why, with the file, line and key where the parser says.
    Broken(String),
}

/// Sorts the new text of the scene file shown as `current`.
pub fn classify(current: &Scene, text: &str, origin: &str) -> Reload {
    let scene = match Scene::parse(text, origin) {
        Ok(s) => s,
        Err(e) => return Reload::Broken(e.to_string()),
    };
    if scene == *current {
        return Reload::Unchanged;
    }
    if crate::bake::cache::scene_hash(&scene) == crate::bake::cache::scene_hash(current) {
        return Reload::Frame(Box::new(scene));
    }
    match scene.build_world() {
        Ok(world) => Reload::Rebake(Box::new(scene), Box::new(world)),
        Err(e) => Reload::Broken(format!("{origin}: {e}")),
    }
}

/// Applies to `frame` the parts of the frame the edit from `old` to `new` touched (sun,
/// sky, start camera, `[render]` knobs); the others keep what the user set.
pub fn apply_frame_edit(old: &Scene, new: &Scene, frame: &mut FrameDesc) {
    let fresh = FrameDesc::from_scene(new);
    if old.sun != new.sun {
        frame.sun = fresh.sun;
    }
    if old.sky != new.sky {
        frame.sky = fresh.sky;
    }
    if old.camera != new.camera {
        frame.camera = fresh.camera;
    }
    if old.render != new.render {
        frame.btf.lod_scale = fresh.btf.lod_scale;
        frame.btf.weight_threshold = fresh.btf.weight_threshold;
        frame.btf.lod_fade = fresh.btf.lod_fade;
        frame.btf.planes = fresh.btf.planes;
        frame.btf.far_canopy = fresh.btf.far_canopy;
        frame.btf.canopy_px = fresh.btf.canopy_px;
    }
}

/// How often the file is looked at.
pub const POLL: Duration = Duration::from_millis(500);

/// The scene file being watched.
pub struct Watch {
    pub path: PathBuf,
    stamp: Option<(SystemTime, u64)>,
    checked: Instant,
}

impl Watch {
    pub fn new(path: &Path) -> Self {
        Self {
            path: path.to_path_buf(),
            stamp: stamp(path),
            checked: Instant::now(),
        }
    }

    /// The file's new text when it changed since the last look (at most every [`POLL`]),
    /// or why it cannot be read.
    pub fn poll(&mut self) -> Option<Result<String, String>> {
        if self.checked.elapsed() < POLL {
            return None;
        }
        self.checked = Instant::now();
        self.changed()
    }

    /// As [`Watch::poll`], without waiting for the poll interval.
    pub fn changed(&mut self) -> Option<Result<String, String>> {
        let now = stamp(&self.path);
        if now == self.stamp || now.is_none() {
            // A file being replaced can be missing for a moment: wait for it.
            return None;
        }
        self.stamp = now;
        Some(
            std::fs::read(&self.path)
                .map_err(|e| format!("cannot read {}: {e}", self.path.display()))
                .and_then(|b| {
                    if b.len() as u64 > crate::scene::MAX_SCENE_BYTES {
                        Err(format!(
                            "{} is too large for a scene file",
                            self.path.display()
                        ))
                    } else {
                        Ok(String::from_utf8_lossy(&b).into_owned())
                    }
                }),
        )
    }
}

fn stamp(path: &Path) -> Option<(SystemTime, u64)> {
    let m = std::fs::metadata(path).ok()?;
    Some((m.modified().ok()?, m.len()))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn lone() -> (String, Scene) {
        let text = std::fs::read_to_string(
            Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/lone_tree.toml"),
        )
        .unwrap();
        let scene = Scene::parse(&text, "lone.toml").unwrap();
        (text, scene)
    }

    #[test]
    fn a_sun_edit_changes_the_frame_a_count_edit_the_bake_a_typo_nothing() {
        let (text, scene) = lone();
        assert!(matches!(
            classify(&scene, &text, "lone.toml"),
            Reload::Unchanged
        ));
        // The sun: applied to the frame at once, the user's camera kept.
        let sun = text.replace("elevation = 45.0", "elevation = 20.0");
        let Reload::Frame(new) = classify(&scene, &sun, "lone.toml") else {
            panic!("a sun edit is a frame edit");
        };
        let mut frame = FrameDesc::from_scene(&scene);
        frame.camera.position += glam::Vec3::X;
        let moved = frame.camera;
        apply_frame_edit(&scene, &new, &mut frame);
        assert_eq!(frame.sun.elevation_deg, 20.0);
        assert_eq!(frame.camera, moved);
        // The tree count: a new bake.
        let count = text.replace("count = 1\n", "count = 2\n");
        assert_ne!(count, text);
        match classify(&scene, &count, "lone.toml") {
            Reload::Rebake(s, w) => {
                assert_eq!(s.forest.count, Some(2));
                assert_eq!(w.forest.instances.len(), 2);
            }
            _ => panic!("a count edit is a bake edit"),
        }
        // A typo: the error names the file, line and key.
        let typo = text.replace("elevation = 45.0", "elevaton = 45.0");
        let Reload::Broken(why) = classify(&scene, &typo, "lone.toml") else {
            panic!("a typo is refused");
        };
        assert!(
            why.contains("lone.toml:") && why.contains("elevaton"),
            "{why}"
        );
    }

    #[test]
    fn the_watch_sees_a_saved_edit_once() {
        let dir = std::env::temp_dir().join(format!("canopy-watch-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("scene.toml");
        std::fs::write(&path, "a = 1\n").unwrap();
        let mut w = Watch::new(&path);
        assert!(w.changed().is_none());
        std::fs::write(&path, "a = 22\n").unwrap();
        assert_eq!(w.changed(), Some(Ok("a = 22\n".to_string())));
        assert!(w.changed().is_none());
        // Gone for a moment (an editor replacing the file): nothing yet.
        std::fs::remove_file(&path).unwrap();
        assert!(w.changed().is_none());
    }
}
