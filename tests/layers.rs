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

/// The methods' modules under `src/render/method/`, each a file `NAME.rs` or a folder.
const METHODS: &[&str] = &[
    "geometry",
    "btf",
    "billboard",
    "texel",
    "hybrid",
    "impostor",
    "surfel",
];

/// The imports of one method by another that are allowed, with why: `hybrid` composes
/// `btf` and `impostor` through their public face; `billboard` is drawn through `btf`'s
/// images and pipeline (a debt: ARCHITECTURE.md, "Known debts").
const METHOD_IMPORTS: &[(&str, &str)] = &[
    ("hybrid", "btf"),
    ("hybrid", "impostor"),
    ("billboard", "btf"),
];

/// The methods a method's file names, by any of the paths that reach another method's
/// module: `method::x`, `render::x` (the core's re-export), or the `super::` chain that
/// climbs from the file's module to `method` (`super::x` from `method/billboard.rs`,
/// `super::super::super::x` from `method/btf/far/new.rs`). Comment lines are skipped.
fn methods_named(rel: &str, text: &str, own: &str) -> Vec<(String, usize)> {
    let below: Vec<&str> = rel
        .trim_start_matches("src/render/method/")
        .trim_end_matches(".rs")
        .split('/')
        .filter(|s| *s != "mod")
        .collect();
    let climb = "super::".repeat(below.len());
    let mut out = Vec::new();
    for (n, line) in text.lines().enumerate() {
        let code = line.trim_start();
        if code.starts_with("//") {
            continue;
        }
        for other in METHODS.iter().filter(|m| **m != own) {
            // (path, whether a `::` may come before it: not for the `super::` chain, where
            // that would be a longer chain, reaching elsewhere)
            let prefixes = [
                (format!("method::{other}"), true),
                (format!("render::{other}"), true),
                (format!("{climb}{other}"), false),
            ];
            let named = prefixes.iter().any(|(p, after_colons)| {
                code.match_indices(p.as_str()).any(|(i, _)| {
                    let before = code[..i].chars().next_back();
                    let after = code[i + p.len()..].chars().next();
                    !before.is_some_and(|c| is_ident(c) || (c == ':' && !after_colons))
                        && !after.is_some_and(is_ident)
                })
            });
            if named {
                out.push((other.to_string(), n + 1));
            }
        }
    }
    out
}

#[test]
fn every_method_is_in_the_import_check() {
    for m in canopy::render::Method::ALL {
        assert!(
            METHODS.contains(&m.name()),
            "{} is a method: add it to METHODS",
            m.name()
        );
    }
}

#[test]
fn no_method_imports_another_but_those_allowed() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let mut files = Vec::new();
    rust_files(root, &root.join("src/render/method"), &mut files);
    let mut bad = Vec::new();
    let mut used: Vec<(&str, String)> = Vec::new();
    for (rel, path) in &files {
        let Some(own) = METHODS.iter().copied().find(|m| {
            rel == &format!("src/render/method/{m}.rs")
                || rel.starts_with(&format!("src/render/method/{m}/"))
        }) else {
            continue;
        };
        let text = fs::read_to_string(path).expect("a source file");
        for (other, line) in methods_named(rel, &text, own) {
            if METHOD_IMPORTS.contains(&(own, other.as_str())) {
                used.push((own, other));
            } else {
                bad.push(format!("{rel}:{line}: {own} names the {other} method"));
            }
        }
    }
    assert!(
        bad.is_empty(),
        "a method reaches into another (share it through the render core instead):\n{}",
        bad.join("\n")
    );
    for (own, other) in METHOD_IMPORTS {
        assert!(
            used.iter().any(|(o, t)| o == own && t == other),
            "{own} no longer names {other}: take the pair out of METHOD_IMPORTS"
        );
    }
}

#[test]
fn the_method_import_check_catches_each_path() {
    let hits = |rel: &str, text: &str, own: &str| -> Vec<String> {
        methods_named(rel, text, own)
            .into_iter()
            .map(|(m, _)| m)
            .collect()
    };
    let nested = "src/render/method/btf/far/new.rs";
    assert!(hits(nested, "use super::super::billboard::BillboardGpu;", "btf").is_empty());
    assert_eq!(
        hits(nested, "use super::super::super::texel::X;", "btf"),
        ["texel"]
    );
    let shallow = "src/render/method/btf/method.rs";
    assert!(hits(shallow, "use super::super::super::texel::X;", "btf").is_empty());
    let folder = "src/render/method/texel/prepare.rs";
    assert_eq!(
        hits(folder, "use crate::render::method::btf::BtfScene;", "texel"),
        ["btf"]
    );
    assert_eq!(
        hits(folder, "use crate::render::btf::BtfStats;", "texel"),
        ["btf"]
    );
    assert_eq!(
        hits(folder, "use super::super::impostor::X;", "texel"),
        ["impostor"]
    );
    assert!(
        hits(
            folder,
            "// crate::render::method::btf::X in a comment",
            "texel"
        )
        .is_empty()
    );
    assert!(hits(folder, "use super::scene::TexelScene;", "texel").is_empty());
    assert!(hits(folder, "use crate::render::btf_like::X;", "texel").is_empty());
    let file = "src/render/method/billboard.rs";
    assert_eq!(
        hits(file, "use super::btf::{BtfAssets};", "billboard"),
        ["btf"]
    );
    assert!(hits(file, "use super::interface::Bake;", "billboard").is_empty());
}
