//! Opening what File → Open, the scene menu or a dropped file brings: a scene (put on show,
//! its bake started) or a bake of the scene on show.

use std::path::Path;

use super::{App, reload};
use crate::model::World;
use crate::render::{FrameDesc, Renderer};
use crate::scene::Scene;
use crate::{Error, Result};

/// What File → Open or a file dropped on the window brings.
pub enum Opened {
    /// A scene file, parsed and its world built.
    Scene(Box<Scene>, Box<World>),
    /// A baked file of the scene on show.
    Baked(Box<crate::format::Baked>),
}

/// Opens `path` for the viewer showing `current`: a `.toml` scene, or a `.canopy` bake of
/// `current` (one of another scene, a corrupt or truncated one is refused with its reason;
/// it is never re-baked, since the user chose that file).
pub fn open_file(path: &Path, current: &Scene) -> Result<Opened> {
    let ext = path
        .extension()
        .map(|e| e.to_string_lossy().to_ascii_lowercase())
        .unwrap_or_default();
    match ext.as_str() {
        "toml" => {
            let scene = Scene::load(path)?;
            let world = scene.build_world()?;
            Ok(Opened::Scene(Box::new(scene), Box::new(world)))
        }
        "canopy" => Ok(Opened::Baked(Box::new(crate::bake::open_baked(
            path, current,
        )?))),
        _ => Err(Error::BadInput(format!(
            "cannot open {}: the viewer opens scene files (.toml) and baked files (.canopy)",
            path.display()
        ))),
    }
}

impl App {
    /// Opens a scene or a bake chosen with File → Open or dropped on the window; what
    /// cannot be opened is reported in the panel and the scene on show stays.
    pub(super) fn open(&mut self, path: &Path) {
        if self.running.is_none() {
            return;
        }
        match open_file(path, &self.scene) {
            Ok(Opened::Scene(scene, world)) => self.show_scene(
                *scene,
                *world,
                &path.display().to_string(),
                Some(reload::Watch::new(path)),
            ),
            Ok(Opened::Baked(baked)) => {
                // Attached on the next frame, as a bake named with --baked is.
                self.bake_job = None;
                self.preloaded = Some((*baked, path.to_path_buf()));
            }
            Err(e) => self.message = Some((e.to_string(), true)),
        }
    }

    /// Opens the embedded example scene `name` (the scene menu); its bake comes from the
    /// cache or is made in the background, as for any scene.
    pub(super) fn open_example(&mut self, name: &str) {
        let opened = match Scene::example(name) {
            None => Err(Error::BadInput(format!("no example scene named `{name}`"))),
            Some(scene) => scene.map_err(Error::from).and_then(|scene| {
                let world = scene.build_world()?;
                Ok((scene, world))
            }),
        };
        match opened {
            Ok((scene, world)) => {
                self.show_scene(scene, world, &format!("example scene `{name}`"), None)
            }
            Err(e) => self.message = Some((e.to_string(), true)),
        }
    }

    /// Puts `scene` on show in place of the current one (the method kept, its bake started
    /// from the cache or in the background), watching its file where it has one.
    fn show_scene(
        &mut self,
        scene: Scene,
        world: World,
        label: &str,
        watch: Option<reload::Watch>,
    ) {
        let Some(r) = &mut self.running else { return };
        match Renderer::new(&r.ctx, &world) {
            Ok(renderer) => {
                let (method, render_scale) = (self.frame.method, self.frame.render_scale);
                r.renderer = renderer;
                self.scene = scene;
                self.world = world;
                self.frame = FrameDesc::from_scene(&self.scene);
                // The method and the render scale are the viewer's, not the scene's.
                self.frame.method = method;
                self.frame.render_scale = render_scale;
                // A bake still running for the old scene is left to finish unseen.
                self.bake_job = None;
                self.bake_failed = false;
                self.preloaded = None;
                self.title = format!("canopy: {label}");
                r.window.set_title(&self.title);
                self.watch = watch;
                self.rebake = None;
                self.stats.trees_total = self.world.forest.instances.len();
                self.gallery.reset();
                self.message = Some((format!("opened {label}"), false));
            }
            Err(e) => self.message = Some((format!("cannot open {label}: {e}"), true)),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::path::PathBuf;

    fn data(name: &str) -> PathBuf {
        Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("tests/data")
            .join(name)
    }

    fn tmp(name: &str) -> PathBuf {
        let dir = std::env::temp_dir().join(format!("canopy-open-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        dir.join(name)
    }

    #[test]
    fn open_takes_scenes_and_bakes_of_the_scene_and_refuses_the_rest_with_the_reason() {
        let current = Scene::default_scene();
        match open_file(&data("lone_tree.toml"), &current) {
            Ok(Opened::Scene(scene, world)) => {
                assert_eq!(scene.forest.count, Some(1));
                assert_eq!(world.forest.instances.len(), 1);
            }
            Ok(Opened::Baked(_)) => panic!("a scene opened as a bake"),
            Err(e) => panic!("{e}"),
        }
        let err = |p: &Path| match open_file(p, &current) {
            Ok(_) => panic!("{} opened", p.display()),
            Err(e) => e.to_string(),
        };
        let e = err(&tmp("missing.toml"));
        assert!(e.contains("missing.toml"), "{e}");
        let e = err(Path::new("notes.txt"));
        assert!(e.contains(".toml") && e.contains(".canopy"), "{e}");
        // A scene with a typo: the file, line and key.
        let typo = tmp("typo.toml");
        let text = std::fs::read_to_string(data("lone_tree.toml"))
            .unwrap()
            .replace("count = 1", "cout = 1");
        std::fs::write(&typo, text).unwrap();
        let e = err(&typo);
        assert!(e.contains("typo.toml") && e.contains("cout"), "{e}");
        // A bake of another scene, and a truncated bake: refused, never re-baked.
        let baked = crate::format::Baked {
            scene_hash: 42,
            settings: crate::format::BakeSettings {
                texel_resolution: 0,
                impostor_frames: 0,
                impostor_resolution: 64,
                impostor_layout: Default::default(),
                ..crate::format::test_support::settings()
            },
            btf: Vec::new(),
            vcm: Vec::new(),
            texels: Vec::new(),
            impostors: Vec::new(),
            surfels: Vec::new(),
        };
        let other = tmp("other.canopy");
        crate::format::write_atomic(&other, &baked).unwrap();
        let e = err(&other);
        assert!(e.contains("another scene"), "{e}");
        let cut = tmp("cut.canopy");
        let bytes = std::fs::read(&other).unwrap();
        std::fs::write(&cut, &bytes[..bytes.len() / 2]).unwrap();
        let e = err(&cut);
        assert!(e.contains("cut.canopy"), "{e}");
        assert_eq!(std::fs::read(&cut).unwrap().len(), bytes.len() / 2);
        // The bake of the scene on show opens.
        let mine = crate::format::Baked {
            scene_hash: crate::bake::cache::scene_hash(&current),
            ..baked
        };
        let own = tmp("own.canopy");
        crate::format::write_atomic(&own, &mine).unwrap();
        assert!(matches!(open_file(&own, &current), Ok(Opened::Baked(_))));
    }
}
