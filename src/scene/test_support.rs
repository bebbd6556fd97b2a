//! What the scene tests share: a complete, compact scene and helpers that edit one line of
//! it and check the error's file, line, key and words.

use super::*;

/// A complete, compact scene used by the error tests (line numbers matter).
pub(crate) const BASE: &str = r#"# test scene
[terrain]
size = 200.0
resolution = 33
seed = 1
relief = 20.0
feature_size = 80.0

[[species]]
name = "fir"
preset = "fir"
seed = 1

[[species]]
name = "oak"
preset = "broadleaf"
seed = 2

[forest]
count = 30
seed = 3
min_spacing = 6.0
mix = [0.6, 0.4]
scale_min = 0.8
scale_max = 1.2
random_yaw = true

[sun]
azimuth = 135.0
elevation = 35.0
color = [1.0, 0.95, 0.85]
intensity = 3.0

[sky]
color = [0.35, 0.5, 0.8]
ground_color = [0.12, 0.1, 0.06]
intensity = 1.0

[camera]
position = [0.0, 40.0, -90.0]
look_at = [0.0, 10.0, 0.0]
fov_deg = 55.0
"#;

/// Replaces the unique line `from` (exact, trimmed) of BASE with `to`; returns the text
/// and the 1-based line number of the last line of `to`.
pub(crate) fn edit(from: &str, to: &str) -> (String, usize) {
    let lines: Vec<&str> = BASE.lines().collect();
    let hits: Vec<usize> = lines
        .iter()
        .enumerate()
        .filter(|(_, l)| l.trim() == from)
        .map(|(i, _)| i)
        .collect();
    assert_eq!(hits.len(), 1, "line `{from}` must be unique in BASE");
    let i = hits[0];
    let mut out: Vec<String> = lines.iter().map(|s| s.to_string()).collect();
    out[i] = to.to_owned();
    // The reported line is the last line of `to` (to insert a key after `from`, pass
    // "from\nnew_key = ...").
    let extra = to.lines().count().saturating_sub(1);
    (out.join("\n") + "\n", i + 1 + extra)
}

pub(crate) fn error_of(text: &str) -> String {
    match Scene::parse(text, "scene.toml") {
        Ok(_) => panic!("accepted:\n{text}"),
        Err(e) => e.to_string(),
    }
}

/// The 1-based number of the `nth` (from 0) line of `text` that `is` picks; 0 when none.
pub(crate) fn nth_line(text: &str, nth: usize, is: impl Fn(&str) -> bool) -> usize {
    text.lines()
        .enumerate()
        .filter(|(_, l)| is(l))
        .nth(nth)
        .map_or(0, |(i, _)| i + 1)
}

/// Parses `text`, which must fail with a message that starts `scene.toml:{line}: {start}`;
/// returns the message.
pub(crate) fn error_at(text: &str, line: usize, start: &str) -> String {
    let msg = error_of(text);
    assert!(
        msg.starts_with(&format!("scene.toml:{line}: {start}")),
        "{msg}"
    );
    msg
}

/// `edit` + parse; asserts the message has the file, the line and the key.
pub(crate) fn expect_error(from: &str, to: &str, key: &str, words: &[&str]) -> String {
    let (text, line) = edit(from, to);
    let msg = error_of(&text);
    assert!(
        msg.starts_with(&format!("scene.toml:{line}: ")),
        "line {line} missing: {msg}"
    );
    assert!(msg.contains(key), "key {key} missing: {msg}");
    for w in words {
        assert!(msg.contains(w), "`{w}` missing: {msg}");
    }
    msg
}

pub(crate) fn small_world_scene() -> Scene {
    match Scene::parse(SMALL_TEST_SCENE_TOML, "small.toml") {
        Ok(s) => s,
        Err(e) => panic!("{e}"),
    }
}
