//! The module layers point one way: `model` (with the small pure modules `sphere`, `lod`,
//! `vcm`) → `scene` / `format` → `render` → `bake` → `bench` → `app` / `main` / `cli`. This test
//! reads every source file under `src/` and fails, naming each offending file and line, when
//! a file mentions a module above its own layer (in code, a path in a doc link or a comment
//! alike).

use std::fs;
use std::path::{Path, PathBuf};

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

/// The modules a file at `rel` (relative to the crate root, e.g. `src/render/btf.rs`) must
/// not mention.
fn forbidden(rel: &str) -> Vec<&'static str> {
    const LOW: [&str; 4] = [
        "crate::scene",
        "crate::format",
        "crate::render",
        "crate::bake",
    ];
    let mut out = Vec::new();
    let model = rel.starts_with("src/model/")
        || ["src/lod.rs", "src/sphere.rs", "src/vcm.rs"].contains(&rel);
    if model {
        out.extend(LOW);
    }
    let scene_or_format = rel.starts_with("src/scene/") || rel.starts_with("src/format/");
    if scene_or_format {
        out.extend(["crate::render", "crate::bake"]);
    }
    if rel.starts_with("src/render/") {
        out.push("crate::bake");
    }
    // The bench drives the render core and the bake; nothing it builds on may know it.
    if model || scene_or_format || rel.starts_with("src/render/") || rel.starts_with("src/bake/") {
        out.push("crate::bench");
    }
    // The command line (`src/cli/`, `src/main.rs`) sits at the top beside the viewer.
    if !(rel.starts_with("src/app/") || rel.starts_with("src/cli/") || rel == "src/main.rs") {
        out.push("crate::app");
    }
    out
}

/// `path` followed by a character that cannot continue an identifier (so `crate::bake`
/// does not match `crate::baker`).
fn mentions(line: &str, path: &str) -> bool {
    line.match_indices(path).any(|(i, _)| {
        !line[i + path.len()..]
            .chars()
            .next()
            .is_some_and(|c| c.is_alphanumeric() || c == '_')
    })
}

/// The modules named at the top of each grouped import `crate::{a, b::c, ...}` in `text`,
/// as (`crate::a`, 1-based line of the brace).
fn grouped(text: &str) -> Vec<(String, usize)> {
    let mut out = Vec::new();
    for (start, _) in text.match_indices("crate::{") {
        let line = text[..start].matches('\n').count() + 1;
        let body = &text[start + "crate::{".len()..];
        let (mut depth, mut item) = (0usize, String::new());
        let mut items = Vec::new();
        for c in body.chars() {
            match c {
                '{' => depth += 1,
                '}' if depth == 0 => break,
                '}' => depth -= 1,
                ',' if depth == 0 => {
                    items.push(std::mem::take(&mut item));
                    continue;
                }
                _ => {}
            }
            if depth == 0 {
                item.push(c);
            }
        }
        items.push(item);
        for it in items {
            let name: String = it
                .trim()
                .chars()
                .take_while(|c| c.is_alphanumeric() || *c == '_')
                .collect();
            if !name.is_empty() {
                out.push((format!("crate::{name}"), line));
            }
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
            && files.iter().any(|(rel, _)| rel == "src/model/world.rs"),
        "the walk finds the sources: {files:?}"
    );
    let mut offences = Vec::new();
    for (rel, path) in &files {
        let banned = forbidden(rel);
        if banned.is_empty() {
            continue;
        }
        let text = fs::read_to_string(path)
            .unwrap_or_else(|e| panic!("cannot read {}: {e}", path.display()));
        for (n, line) in text.lines().enumerate() {
            for b in &banned {
                if mentions(line, b) {
                    offences.push(format!("{rel}:{}: mentions {b}: {}", n + 1, line.trim()));
                }
            }
        }
        for (module, line) in grouped(&text) {
            if banned.contains(&module.as_str()) {
                offences.push(format!("{rel}:{line}: imports {module} in a group"));
            }
        }
    }
    for o in &offences {
        eprintln!("{o}");
    }
    assert!(
        offences.is_empty(),
        "{} import(s) point up the layers \
         (model → scene/format → render → bake → bench → app/main):\n{}",
        offences.len(),
        offences.join("\n")
    );
}

#[test]
fn the_rules_catch_what_they_should() {
    assert!(forbidden("src/render/btf.rs").contains(&"crate::bake"));
    assert!(!forbidden("src/render/frame.rs").contains(&"crate::scene"));
    assert!(forbidden("src/model/world.rs").contains(&"crate::scene"));
    assert!(forbidden("src/lod.rs").contains(&"crate::format"));
    assert!(forbidden("src/format/mod.rs").contains(&"crate::render"));
    assert!(forbidden("src/format/read.rs").contains(&"crate::bake"));
    assert!(forbidden("src/scene/locate.rs").contains(&"crate::render"));
    assert!(!forbidden("src/cli/view.rs").contains(&"crate::app"));
    assert!(forbidden("src/bake/mod.rs").contains(&"crate::app"));
    assert!(!forbidden("src/app/mod.rs").contains(&"crate::app"));
    assert!(!forbidden("src/main.rs").contains(&"crate::app"));
    assert!(forbidden("src/bench/flight.rs").contains(&"crate::app"));
    assert!(!forbidden("src/bench/flight.rs").contains(&"crate::render"));
    for low in [
        "src/render/frame.rs",
        "src/render/method/btf.rs",
        "src/model/world.rs",
        "src/lod.rs",
        "src/scene/mod.rs",
        "src/format/mod.rs",
        "src/bake/cache.rs",
    ] {
        assert!(forbidden(low).contains(&"crate::bench"), "{low}");
    }
    assert!(!forbidden("src/app/mod.rs").contains(&"crate::bench"));
    assert!(!forbidden("src/main.rs").contains(&"crate::bench"));
    assert!(mentions("use crate::bake::billboard_axes;", "crate::bake"));
    assert!(mentions("crate::bake", "crate::bake"));
    assert!(!mentions("use crate::baker;", "crate::bake"));
    assert_eq!(
        grouped("use crate::{Error, bake::{self, x},\n render};"),
        [
            ("crate::Error".to_owned(), 1),
            ("crate::bake".to_owned(), 1),
            ("crate::render".to_owned(), 1)
        ]
    );
}
