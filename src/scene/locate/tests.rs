//! The messages of scene files with errors: each names the file, the line and the key.

use super::*;
use crate::model::species::preset;
use crate::scene::Scene;
use crate::scene::test_support::*;

#[test]
fn load_reads_a_file() {
    let dir = std::env::temp_dir().join(format!("canopy-scene-test-{}", std::process::id()));
    let _ = std::fs::create_dir_all(&dir);
    let path = dir.join("s.toml");
    let _ = std::fs::write(&path, BASE);
    let ok = Scene::load(&path).unwrap_or_else(|e| panic!("{e}"));
    // What BASE says, read back.
    assert_eq!(ok.forest.count, Some(30));
    assert_eq!(ok.forest.mix, [0.6, 0.4]);
    assert_eq!(ok.terrain.resolution, 33);
    let names: Vec<_> = ok.species.iter().map(|s| s.name.as_str()).collect();
    assert_eq!(names, ["fir", "oak"]);
    assert_eq!(ok.species[1].preset.as_deref(), Some("broadleaf"));
    assert_eq!(ok.camera.position, [0.0, 40.0, -90.0]);
    assert_eq!(ok.sun.elevation, 35.0);
    let (bad, line) = edit("count = 30", "count = -5");
    let _ = std::fs::write(&path, bad);
    let msg = Scene::load(&path)
        .err()
        .map(|e| e.to_string())
        .unwrap_or_default();
    assert!(
        msg.starts_with(&format!("{}:{line}: forest.count", path.display())),
        "{msg}"
    );
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn unknown_key_names_key_table_and_expected_keys() {
    let msg = expect_error(
        "relief = 20.0",
        "reliefs = 20.0",
        "terrain.reliefs",
        &[
            "unknown field `reliefs`",
            "expected one of `size`, `resolution`",
        ],
    );
    assert!(msg.contains("`relief`,"), "{msg}");
    expect_error(
        "fov_deg = 55.0",
        "fov = 55.0",
        "camera.fov",
        &["unknown field `fov`", "fov_deg"],
    );
    // Unknown key inside an array-of-tables entry.
    expect_error(
        "name = \"oak\"",
        "nmae = \"oak\"",
        "species[1].nmae",
        &["unknown field `nmae`", "`name`"],
    );
}

#[test]
fn unknown_table_at_top_level() {
    expect_error(
        "[sky]",
        "[skies]",
        "skies",
        &["unknown field `skies`", "camera"],
    );
}

#[test]
fn missing_key_is_named() {
    let (text, _) = edit("count = 30", "");
    // Reported at the [forest] header.
    let header = nth_line(BASE, 0, |l| l == "[forest]");
    error_at(&text, header, "forest.count: missing required key");
    let (text, _) = edit("seed = 2", "");
    let header = nth_line(BASE, 1, |l| l == "[[species]]");
    error_at(&text, header, "species[1]: missing field `seed`");
}

#[test]
fn missing_table_is_named() {
    let text = BASE.replace(
        "[camera]\nposition = [0.0, 40.0, -90.0]\nlook_at = [0.0, 10.0, 0.0]\nfov_deg = 55.0\n",
        "",
    );
    let msg = error_of(&text);
    assert!(
        msg.starts_with("scene.toml:1: (top level): missing field `camera`"),
        "{msg}"
    );
}

#[test]
fn negative_count() {
    expect_error(
        "count = 30",
        "count = -5",
        "forest.count",
        &["integer `-5`, expected a non-negative integer"],
    );
}

#[test]
fn integer_too_large_for_type() {
    expect_error(
        "count = 30",
        "count = 99999999999",
        "forest.count",
        &["no larger than 4294967295", "99999999999"],
    );
}

#[test]
fn wrong_types() {
    expect_error(
        "size = 200.0",
        "size = \"big\"",
        "terrain.size",
        &["string \"big\", expected a number"],
    );
    expect_error(
        "count = 30",
        "count = 30.5",
        "forest.count",
        &["non-negative integer", "30.5"],
    );
    expect_error(
        "random_yaw = true",
        "random_yaw = 1",
        "forest.random_yaw",
        &["true or false"],
    );
    expect_error(
        "mix = [0.6, 0.4]",
        "mix = [0.6, \"x\"]",
        "forest.mix[1]",
        &["expected a number"],
    );
    expect_error(
        "mix = [0.6, 0.4]",
        "mix = 0.6",
        "forest.mix",
        &["expected an array"],
    );
    expect_error("name = \"fir\"", "name = 5", "species[0].name", &["string"]);
    expect_error(
        "color = [1.0, 0.95, 0.85]",
        "color = [1.0, 0.95]",
        "sun.color",
        &["array of 3 numbers"],
    );
}

#[test]
fn wrong_array_lengths() {
    expect_error(
        "color = [1.0, 0.95, 0.85]",
        "color = [1.0, 0.95, 0.85, 1.0]",
        "sun.color",
        &["invalid length 4, expected an array of 3 numbers"],
    );
    expect_error(
        "look_at = [0.0, 10.0, 0.0]",
        "look_at = []",
        "camera.look_at",
        &["invalid length 0, expected an array of 3 numbers"],
    );
}

#[test]
fn array_of_tables_where_a_table_belongs() {
    expect_error(
        "[terrain]",
        "[[terrain]]",
        "terrain",
        &["expected a single [terrain] table, found an array of tables [[terrain]]"],
    );
}

#[test]
fn wrong_type_for_table() {
    let text = BASE
        .replace(
            "[sky]\ncolor = [0.35, 0.5, 0.8]\nground_color = [0.12, 0.1, 0.06]\nintensity = 1.0\n",
            "",
        )
        .replace("# test scene\n", "# test scene\nsky = 5\n");
    let line = nth_line(&text, 0, |l| l == "sky = 5");
    error_at(
        &text,
        line,
        "sky: invalid type: integer `5`, expected a table",
    );
}

#[test]
fn syntax_error_has_line() {
    let (text, line) = edit("seed = 3", "seed = = 3");
    let msg = error_of(&text);
    assert!(
        msg.starts_with(&format!("scene.toml:{line}: TOML syntax error")),
        "{msg}"
    );
    let (text, line) = edit("scale_max = 1.2", "scale_min = 1.2");
    let msg = error_of(&text);
    assert!(msg.starts_with(&format!("scene.toml:{line}: ")), "{msg}");
    assert!(msg.contains("duplicate key `scale_min`"), "{msg}");
}

#[test]
fn unknown_enum_value_in_inline_params() {
    let mut text = BASE.replace("preset = \"broadleaf\"\n", "");
    let params: String = crate::model::species::BROADLEAF_TOML
        .lines()
        .filter(|l| !l.trim_start().starts_with('#'))
        .collect::<Vec<_>>()
        .join("\n");
    text = text.replace(
        "seed = 2\n",
        &format!(
            "seed = 2\n[species.params]\n{}\n",
            params.replace("\"leaves\"", "\"fronds\"")
        ),
    );
    let line = nth_line(&text, 0, |l| l.contains("\"fronds\""));
    let msg = error_at(&text, line, "species[1].params.foliage");
    assert!(
        msg.contains("unknown variant `fronds`, expected `needles` or `leaves`"),
        "{msg}"
    );
    // With a valid value the inline params are accepted.
    let ok = Scene::parse(&text.replace("\"fronds\"", "\"leaves\""), "scene.toml")
        .unwrap_or_else(|e| panic!("{e}"));
    // They are the broadleaf preset's, field for field, in place of the preset's name.
    assert_eq!(ok.species[1].preset, None);
    assert_eq!(ok.species[1].params, preset("broadleaf"));
    assert!(ok.species[1].params.is_some());
    // An out-of-range inline parameter is reported at its own line.
    let bad = text
        .replace("\"fronds\"", "\"leaves\"")
        .replace("crown_radius = 5.2", "crown_radius = -2");
    let line = nth_line(&bad, 0, |l| l.starts_with("crown_radius"));
    error_at(
        &bad,
        line,
        "species[1].params.crown_radius: must be > 0, found -2",
    );
}

#[test]
fn path_parsing() {
    assert_eq!(
        parse_path("species[1].params.height"),
        vec![
            Seg::Key("species".into()),
            Seg::Index(1),
            Seg::Key("params".into()),
            Seg::Key("height".into())
        ]
    );
    assert_eq!(
        parse_path("forest.mix[2]"),
        vec![
            Seg::Key("forest".into()),
            Seg::Key("mix".into()),
            Seg::Index(2)
        ]
    );
    assert_eq!(line_of("a\nb\nc", 2), 2);
    assert_eq!(line_of("a\nb\nc", 100), 3);
}

#[test]
fn rust_type_names_read_as_toml_words_and_other_messages_pass_unchanged() {
    assert_eq!(
        toml_words("invalid type: string \"x\", expected f32"),
        "invalid type: string \"x\", expected a number"
    );
    assert_eq!(
        toml_words("invalid type: integer `5`, expected struct SkyParams"),
        "invalid type: integer `5`, expected a table"
    );
    for plain in [
        "missing field `seed`",
        "unknown variant `x`, expected `a` or `b`",
        "invalid length 2, expected an array of 3 numbers",
    ] {
        assert_eq!(toml_words(plain), plain);
    }
}
