//! The glTF trees built into the binary, for the embedded example scenes: each file under
//! a path of the virtual folder [`ROOT`], as `assets/` holds it. A scene embedded in the
//! binary names its trees relative to `ROOT/assets/scenes`, as its file does in the
//! repository; the reader looks a path under `ROOT` up here instead of on disk.

use std::path::{Component, Path, PathBuf};

/// The virtual folder of the embedded files (no real path starts with it).
pub const ROOT: &str = "<embedded>";

/// The files, by their path under [`ROOT`].
const FILES: &[(&str, &[u8])] = &[
    (
        "assets/trees/pine5/Pine_5.gltf",
        include_bytes!("../../../assets/trees/pine5/Pine_5.gltf"),
    ),
    (
        "assets/trees/pine5/Pine_5.bin",
        include_bytes!("../../../assets/trees/pine5/Pine_5.bin"),
    ),
    (
        "assets/trees/pine5/Leaf_Pine_C.png",
        include_bytes!("../../../assets/trees/pine5/Leaf_Pine_C.png"),
    ),
    (
        "assets/trees/pine5/Bark_NormalTree.png",
        include_bytes!("../../../assets/trees/pine5/Bark_NormalTree.png"),
    ),
];

/// The folder an embedded scene's relative paths start from.
pub fn scenes_dir() -> PathBuf {
    Path::new(ROOT).join("assets").join("scenes")
}

/// The bytes of the embedded file at `path` (under [`ROOT`], `..` resolved); None for a
/// path outside it or a file that is not embedded.
pub fn lookup(path: &Path) -> Option<&'static [u8]> {
    let mut parts = path.components();
    if parts.next()? != Component::Normal(ROOT.as_ref()) {
        return None;
    }
    let mut names: Vec<&str> = Vec::new();
    for c in parts {
        match c {
            Component::Normal(n) => names.push(n.to_str()?),
            Component::ParentDir => {
                names.pop()?;
            }
            Component::CurDir => {}
            _ => return None,
        }
    }
    let key = names.join("/");
    FILES.iter().find(|(p, _)| *p == key).map(|(_, b)| *b)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_embedded_scene_finds_its_tree_beside_it() {
        let gltf = scenes_dir().join("../trees/pine5/Pine_5.gltf");
        let bytes = lookup(&gltf).expect("Pine_5 is embedded");
        assert!(bytes.starts_with(b"{"), "a glTF JSON file");
        assert!(lookup(&scenes_dir().join("../trees/pine5/Pine_5.bin")).is_some());
        assert!(lookup(&scenes_dir().join("../trees/pine5/nope.png")).is_none());
        assert!(lookup(Path::new("assets/trees/pine5/Pine_5.gltf")).is_none());
        assert!(lookup(&Path::new(ROOT).join("../../etc/passwd")).is_none());
    }
}
