//! The module layers point one way. Every file under `src/` belongs to the layer of its
//! top-level module (`src/x.rs` and everything under `src/x/` are module `x`), and [`LAYERS`]
//! places every top-level module: a file whose module the table does not place fails the
//! test, so a new module must be given its layer. A file may name modules of its own layer
//! or below; this test reads every source file and fails, naming each offending file and
//! line, when one names a module above its layer, in code or in a doc link or comment alike.
//!
//! A module is named by a path from the crate root: `crate::x`, `$crate::x`, `canopy::x`
//! (the binary's and the doc examples' spelling), a group `crate::{x, y::z}`, the root's
//! re-exports (`crate::Error` is module `error`'s), and `super::` chains that climb to the
//! root. A `super::` chain is counted from the file's own module, so inside an inline module
//! (`mod tests`) it is read one level too high; only names the table places are taken from
//! such chains, which keeps that from raising false alarms.

use std::fs;
use std::path::{Path, PathBuf};

/// The layers, lowest first: a name for messages and the top-level modules in the layer.
/// `lib` and `main` are the crate roots.
const LAYERS: &[(&str, &[&str])] = &[
    (
        "model",
        &[
            // The procedural forest and the small pure modules built on it or on nothing.
            "model",
            "sphere",
            "lod",
            "vcm",
            "slices",
            "color",
            "progress",
            "forest_map",
            // The atomic-write helper: a leaf that imports nothing from the crate.
            "atomic_file",
        ],
    ),
    (
        "scene / format",
        // The scene file, the baked-data file, the crate's error type (which wraps theirs),
        // and the image utilities that report through it.
        &["scene", "format", "error", "imageio", "metrics"],
    ),
    ("render", &["render"]),
    ("bake", &["bake"]),
    ("bench", &["bench"]),
    ("app / cli / main", &["app", "cli", "main", "lib"]),
];

/// Items the crate root re-exports, with the module that defines them.
const ROOT_ITEMS: &[(&str, &str)] = &[("Error", "error"), ("Result", "error")];

/// Every `.rs` file under `dir`, as paths relative to `root` with `/` separators.
fn rust_files(root: &Path, dir: &Path, out: &mut Vec<(String, PathBuf)>) {
    let mut entries: Vec<_> = fs::read_dir(dir)
        .unwrap_or_else(|e| panic!("cannot read {}: {e}", dir.display()))
        .map(|e| e.expect("directory entry").path())
        .collect();
    entries.sort();
    for path in entries {
        if path.is_dir() {
            rust_files(root, &path, out);
        } else if path.extension().is_some_and(|e| e == "rs") {
            let rel = path
                .strip_prefix(root)
                .expect("under the root")
                .components()
                .map(|c| c.as_os_str().to_string_lossy().into_owned())
                .collect::<Vec<_>>()
                .join("/");
            out.push((rel, path));
        }
    }
}

/// The top-level module of a file `src/...`: `src/x.rs` and `src/x/...` are both `x`.
fn top_module(rel: &str) -> Option<&str> {
    let first = rel.strip_prefix("src/")?.split('/').next()?;
    Some(first.strip_suffix(".rs").unwrap_or(first))
}

/// The index in [`LAYERS`] of the layer holding top-level module `module`.
fn layer_of(module: &str) -> Option<usize> {
    LAYERS.iter().position(|(_, mods)| mods.contains(&module))
}

/// How many modules below the crate root the file's module is: `src/lib.rs` 0,
/// `src/x.rs` and `src/x/mod.rs` 1, `src/x/y.rs` 2.
fn depth(rel: &str) -> usize {
    let parts: Vec<&str> = rel.trim_start_matches("src/").split('/').collect();
    if parts == ["lib.rs"] || parts == ["main.rs"] {
        0
    } else if parts.last() == Some(&"mod.rs") {
        parts.len() - 1
    } else {
        parts.len()
    }
}

fn is_ident(c: char) -> bool {
    c.is_alphanumeric() || c == '_'
}

/// The leading identifier of `s`.
fn ident(s: &str) -> &str {
    let end = s.find(|c: char| !is_ident(c)).unwrap_or(s.len());
    &s[..end]
}

/// The names a path reaches at the crate root, given the text just after its `crate::`:
/// one identifier, or each item of a group `{a, b::c, ...}`, with the byte offset (in
/// `rest`) where each starts. Line comments inside a group are skipped.
fn root_names(rest: &str) -> Vec<(&str, usize)> {
    let Some(body) = rest.strip_prefix('{') else {
        return vec![(ident(rest), 0)];
    };
    let mut out = Vec::new();
    let mut depth = 0usize;
    let mut in_comment = false;
    let mut at_item = true;
    for (i, c) in body.char_indices() {
        let pos = i + 1;
        if in_comment {
            in_comment = c != '\n';
            continue;
        }
        if body[i..].starts_with("//") {
            in_comment = true;
            continue;
        }
        if at_item && depth == 0 && is_ident(c) {
            at_item = false;
            out.push((ident(&rest[pos..]), pos));
        }
        match c {
            '{' => depth += 1,
            '}' if depth == 0 => break,
            '}' => depth -= 1,
            ',' if depth == 0 => at_item = true,
            _ => {}
        }
    }
    out
}

/// Every top-level name `text` reaches through the crate root, with its 1-based line and
/// whether it came from a `super::` chain: see the module docs for the spellings. `depth`
/// is the file's [`depth`].
fn references(text: &str, depth: usize) -> Vec<(String, usize, bool)> {
    let line_of = |at: usize| text[..at].matches('\n').count() + 1;
    let starts_path = |at: usize| {
        let before = text[..at].chars().next_back();
        !before.is_some_and(|c| is_ident(c) || c == ':')
    };
    let mut out = Vec::new();
    for prefix in ["crate::", "canopy::"] {
        for (at, _) in text.match_indices(prefix) {
            if !starts_path(at) {
                continue;
            }
            let after = at + prefix.len();
            for (name, off) in root_names(&text[after..]) {
                if !name.is_empty() && name != "self" {
                    out.push((name.to_owned(), line_of(after + off), false));
                }
            }
        }
    }
    if depth > 0 {
        for (at, _) in text.match_indices("super::") {
            if !starts_path(at) {
                continue;
            }
            let mut after = at;
            let mut climbs = 0;
            while text[after..].starts_with("super::") {
                after += "super::".len();
                climbs += 1;
            }
            if climbs < depth {
                continue;
            }
            for (name, off) in root_names(&text[after..]) {
                if !name.is_empty() && name != "self" {
                    out.push((name.to_owned(), line_of(after + off), true));
                }
            }
        }
    }
    out
}

/// What is wrong with the file at `rel` (e.g. `src/render/btf.rs`) whose text is `text`:
/// a module the table does not place, or a name above the file's layer.
fn check(rel: &str, text: &str) -> Vec<String> {
    let Some(own) = top_module(rel) else {
        return vec![format!("{rel}: not under src/")];
    };
    let Some(layer) = layer_of(own) else {
        return vec![format!(
            "{rel}: the top-level module `{own}` has no layer; place it in tests/layers.rs's LAYERS"
        )];
    };
    let mut out = Vec::new();
    for (name, line, by_super) in references(text, depth(rel)) {
        let module = ROOT_ITEMS
            .iter()
            .find(|(item, _)| *item == name)
            .map_or(name.as_str(), |(_, m)| m);
        match layer_of(module) {
            Some(l) if l > layer => out.push(format!(
                "{rel}:{line}: names `{module}` ({}) from the {} layer",
                LAYERS[l].0, LAYERS[layer].0
            )),
            Some(_) => {}
            None if by_super => {}
            None => out.push(format!(
                "{rel}:{line}: names crate::{name}, which LAYERS and ROOT_ITEMS do not place"
            )),
        }
    }
    out
}

#[test]
fn imports_point_one_way() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let mut files = Vec::new();
    rust_files(root, &root.join("src"), &mut files);
    assert!(
        files.iter().any(|(rel, _)| rel == "src/render/mod.rs")
            && files.iter().any(|(rel, _)| rel == "src/model/world.rs")
            && files.iter().any(|(rel, _)| rel == "src/vcm/billboard.rs"),
        "the walk finds the sources: {files:?}"
    );
    let mut offences = Vec::new();
    for (rel, path) in &files {
        let text = fs::read_to_string(path)
            .unwrap_or_else(|e| panic!("cannot read {}: {e}", path.display()));
        offences.extend(check(rel, &text));
    }
    let chain: Vec<&str> = LAYERS.iter().map(|(name, _)| *name).collect();
    assert!(
        offences.is_empty(),
        "{} file(s) or name(s) break the layers ({}):\n{}",
        offences.len(),
        chain.join(" → "),
        offences.join("\n")
    );
}

/// Each top-level module is in exactly one layer, and every one the crate has is placed
/// (the walk above fails for a file of an unplaced module; this names the duplicates).
#[test]
fn the_table_places_each_module_once() {
    let mut all: Vec<&str> = LAYERS.iter().flat_map(|(_, m)| m.iter().copied()).collect();
    let n = all.len();
    all.sort_unstable();
    all.dedup();
    assert_eq!(all.len(), n, "a module is in two layers: {LAYERS:?}");
}

/// The checker reports what it should on synthetic files: each of these would pass
/// unnoticed if the rule or its path reading were broken.
#[test]
fn the_checker_catches_what_it_should() {
    // The edges issue 35 found, as they were.
    let billboard = check(
        "src/vcm/billboard.rs",
        "use crate::format::BtfImageSet;\nuse crate::sphere::Blend;\nuse crate::{Error, Result};\n",
    );
    assert_eq!(billboard.len(), 3, "{billboard:?}");
    assert!(billboard[0].starts_with("src/vcm/billboard.rs:1: names `format`"));
    assert!(billboard[1].starts_with("src/vcm/billboard.rs:3: names `error`"));
    assert_eq!(
        check("src/progress.rs", "fn f(p: &crate::bake::Progress) {}").len(),
        1
    );
    assert_eq!(
        check(
            "src/metrics.rs",
            "let l = crate::render::target::srgb_to_linear(v);"
        )
        .len(),
        1
    );
    // `src/x.rs` and `src/x/` alike, and both crate roots.
    assert_eq!(check("src/scene.rs", "use crate::render::X;").len(), 1);
    assert_eq!(
        check("src/scene/schema.rs", "use crate::render::X;").len(),
        1
    );
    assert!(check("src/cli/render.rs", "use crate::{app, bench, render};").is_empty());
    assert!(check("src/main.rs", "use canopy::{app, cli::Command};").is_empty());
    // Down and sideways are fine; up is not, wherever the name is written.
    assert!(check("src/render/camera.rs", "use crate::{model, scene, format};").is_empty());
    assert!(check("src/bench/run.rs", "use crate::bake::{self, x};").is_empty());
    assert_eq!(
        check("src/bake/mod.rs", "/// See [`crate::bench::run`].").len(),
        1
    );
    assert_eq!(
        check(
            "src/render/ground.rs",
            "use crate::{\n    model,\n    bake::x,\n};"
        )
        .len(),
        1
    );
    assert!(
        check(
            "src/render/ground.rs",
            "use crate::{\n    model,\n    bake::x,\n};"
        )[0]
        .starts_with("src/render/ground.rs:3:")
    );
    assert_eq!(
        check(
            "src/render/ground.rs",
            "use crate::{\n    model, // not bake\n    bench,\n};"
        )
        .len(),
        1
    );
    assert_eq!(check("src/model/tree.rs", "$crate::render::x!()").len(), 1);
    // A `super::` chain that climbs to the root, and one that does not.
    assert_eq!(
        check("src/vcm/billboard.rs", "use super::super::format::X;").len(),
        1
    );
    assert!(check("src/vcm/billboard.rs", "use super::Occluder;").is_empty());
    assert!(check("src/vcm.rs", "mod tests { use super::corner; }").is_empty());
    // An identifier that merely starts like a module, and paths that are not from the root.
    let baker = check("src/render/camera.rs", "use crate::baker;");
    assert!(
        baker.len() == 1 && baker[0].contains("crate::baker, which"),
        "{baker:?}"
    );
    assert!(check("src/model/tree.rs", "let x = my_crate::bake::y;").is_empty());
    assert!(check("src/model/tree.rs", "use wgpu::render::X;").is_empty());
    // A module the table does not place, and a root name it does not know.
    let new = check("src/newthing.rs", "");
    assert_eq!(new.len(), 1);
    assert!(new[0].contains("`newthing` has no layer"), "{new:?}");
    assert_eq!(check("src/newthing/part.rs", "").len(), 1);
    assert_eq!(check("src/bench/run.rs", "use crate::mystery;").len(), 1);
    assert_eq!(depth("src/lib.rs"), 0);
    assert_eq!(depth("src/vcm.rs"), 1);
    assert_eq!(depth("src/vcm/mod.rs"), 1);
    assert_eq!(depth("src/render/method/btf/far.rs"), 4);
}
