//! The `canopy` binary end to end: `render` writes a PNG and prints its stats as JSON,
//! `compare` reports FLIP, `bench` writes its outputs, and bad input exits with 2 and a
//! message saying what is wrong. The baked files and the cache (`bake`, `--baked`, `info`)
//! are `cli_bake.rs`'s, with these helpers.

use crate::common;

use std::path::Path;
use std::process::Command;

pub(crate) fn canopy() -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_canopy"));
    c.env("RUST_LOG", "error");
    c
}

pub(crate) fn tmp(name: &str) -> std::path::PathBuf {
    let dir = std::env::temp_dir().join(format!("canopy-cli-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    dir.join(name)
}

#[test]
fn render_then_compare_end_to_end() {
    let out = tmp("lone.png");
    let scene = common::data("lone_tree.toml");
    render_reports_its_frames_and_memory(&scene, &out);
    the_reference_reports_its_sky_volume(&scene);
    an_image_against_itself_has_zero_error(&out);
    let out2 = another_sun_has_a_positive_error(&scene, &out);
    pixel_classes_split_the_comparison(&scene, &out, &out2);
}

/// `render --json` of the lone fir: its frames, their time and where the memory is.
fn render_reports_its_frames_and_memory(scene: &Path, out: &Path) {
    let started = std::time::Instant::now();
    let o = canopy()
        .args(["render"])
        .arg(scene)
        .args(["--out"])
        .arg(out)
        .args(["--size", "96x64", "--frames", "2", "--cpu", "--json"])
        .output()
        .unwrap();
    let wall_ms = started.elapsed().as_secs_f64() * 1000.0;
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "render failed: {err}");
    assert!(!err.contains("below the terrain"), "{err}");
    let json: serde_json::Value =
        serde_json::from_slice(&o.stdout).expect("stdout is one JSON object");
    assert_eq!(json["method"], "geometry");
    assert_eq!(json["width"], 96);
    assert_eq!(json["height"], 64);
    // The frames' time in milliseconds. The timed frames fit in the command's own time (a
    // time in microseconds would not), and lavapipe draws no frame of this scene (89,000
    // triangles, 267,000 in the shadow maps) in under 20 ms (a time in seconds, or one that
    // timed only the submission, would be).
    let frame_ms = json["frame_ms"].as_f64().unwrap();
    assert_eq!(json["frames_timed"], 2, "{json}");
    assert!(
        frame_ms > 20.0 && 2.0 * frame_ms < wall_ms,
        "frame_ms {frame_ms} for 2 frames of a {wall_ms:.0} ms command"
    );
    assert!(json["trees_drawn"].as_u64().unwrap() > 0);
    assert!(json["triangles"].as_u64().unwrap() > 0);
    assert_eq!(json["reference"], false);
    assert!(json.get("sky_volume_bytes").is_none());
    let img = image::open(out).unwrap();
    assert_eq!((img.width(), img.height()), (96, 64));
    memory_adds_up(&json);
}

/// Where the memory is: the GPU's allocations by part add up to their total, and the
/// sun's cascades (3 layers of 2048² 4-byte depth at the default --shadow-map) are one of
/// them, at their size.
fn memory_adds_up(json: &serde_json::Value) {
    let memory = &json["memory"];
    let allocated = memory["gpu_allocated_bytes"]
        .as_u64()
        .expect("lavapipe reports");
    let parts = memory["gpu_parts"].as_array().unwrap();
    let sum: u64 = parts.iter().map(|p| p["bytes"].as_u64().unwrap()).sum();
    assert_eq!(sum, allocated, "{memory}");
    let cascades = parts
        .iter()
        .find(|p| p["name"] == "shadow cascades")
        .and_then(|p| p["bytes"].as_u64())
        .expect("the cascades are a part");
    let expected = 3 * 2048 * 2048 * 4;
    assert!(
        cascades >= expected && cascades < expected + expected / 10,
        "{cascades} bytes of cascades"
    );
    assert!(memory["resident_peak_bytes"].as_u64().unwrap() >= allocated / 2);
}

fn the_reference_reports_its_sky_volume(scene: &Path) {
    // The reference says so, with its sky visibility's directions, cell and bytes.
    let o = canopy()
        .args(["render"])
        .arg(scene)
        .args(["--out"])
        .arg(tmp("lone-reference.png"))
        .args(["--size", "32x24", "--frames", "1", "--cpu", "--json"])
        .args(["--reference", "--sky-directions", "8"])
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let json: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(json["reference"], true);
    assert_eq!(json["sky_directions"], 8);
    assert!(json["sky_cell_m"].as_f64().unwrap() >= 0.5, "{json}");
    let bytes = json["sky_volume_bytes"].as_u64().unwrap();
    // About 2 M cells at most, one byte each (1.05 MB measured on this scene).
    assert!(bytes > 1 && bytes <= 3_000_000, "{json}");
}

fn an_image_against_itself_has_zero_error(out: &Path) {
    // The same image against itself: zero error.
    let o = canopy()
        .arg("compare")
        .arg(out)
        .arg(out)
        .arg("--json")
        .output()
        .unwrap();
    assert!(o.status.success());
    let s: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    for key in ["mean", "p50", "p90", "p99"] {
        assert_eq!(s[key].as_f64(), Some(0.0), "{key}");
    }
}

fn another_sun_has_a_positive_error(scene: &Path, out: &Path) -> std::path::PathBuf {
    // Another sun: a positive error, and a diff image on request.
    let out2 = tmp("lone-sun.png");
    let o = canopy()
        .arg("render")
        .arg(scene)
        .arg("--out")
        .arg(&out2)
        .args([
            "--size", "96x64", "--frames", "1", "--cpu", "--sun", "300,15",
        ])
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let diff = tmp("diff.png");
    let o = canopy()
        .arg("compare")
        .arg(out)
        .arg(&out2)
        .arg("--json")
        .arg("--diff")
        .arg(&diff)
        .output()
        .unwrap();
    assert!(o.status.success());
    let s: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert!(s["mean"].as_f64().unwrap() > 0.01, "{s}");
    assert!(diff.exists());
    out2
}

fn pixel_classes_split_the_comparison(scene: &Path, out: &Path, out2: &Path) {
    // Split by the first frame's pixel classes: each class says how bright both images are
    // there (the same image: equal; the other sun: the ground differs).
    let classes = tmp("lone-classes.png");
    let o = canopy()
        .arg("render")
        .arg(scene)
        .arg("--out")
        .arg(&classes)
        .args([
            "--size",
            "96x64",
            "--frames",
            "1",
            "--cpu",
            "--pixel-classes",
        ])
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    for (b, same) in [(out, true), (out2, false)] {
        let o = canopy()
            .arg("compare")
            .arg(out)
            .arg(b)
            .arg("--classes")
            .arg(&classes)
            .arg("--json")
            .output()
            .unwrap();
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        let s: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
        let ground = s["classes"]
            .as_array()
            .unwrap()
            .iter()
            .find(|c| c["class"] == "ground")
            .unwrap_or_else(|| panic!("no ground class: {s}"));
        let (a_lum, b_lum) = (
            ground["reference_luminance"].as_f64().unwrap(),
            ground["luminance"].as_f64().unwrap(),
        );
        assert!(a_lum > 0.0 && b_lum > 0.0, "{ground}");
        assert_eq!(a_lum == b_lum, same, "{ground}");
    }
    let o = canopy()
        .arg("compare")
        .arg(out)
        .arg(out2)
        .arg("--classes")
        .arg(&classes)
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&o.stdout);
    assert!(
        text.contains("luminance") && text.contains("of A's"),
        "{text}"
    );
}

/// A camera under the hills is drawn (the terrain's underside) but `render` says so on
/// stderr with the ground's height there; one above them draws without a word.
#[test]
fn render_warns_when_the_camera_is_below_the_terrain() {
    let scene = common::data("small.toml");
    let world = common::small_scene().build_world().unwrap();
    let (x, z) = (0.0f32, -58.0f32);
    let ground = world.terrain.height_at(x, z);
    let render_from = |y: f32| {
        let o = canopy()
            .arg("render")
            .arg(&scene)
            .arg("--out")
            .arg(tmp(&format!("below-{y}.png")))
            .args(["--size", "32x24", "--frames", "1", "--cpu"])
            .arg("--camera")
            .arg(format!("{x},{y},{z}"))
            .args(["--look-at", "0,6,8"])
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&o.stderr).into_owned();
        assert!(o.status.success(), "{err}");
        err
    };
    let y = ground - 20.0;
    let err = render_from(y);
    let want = format!(
        "warning: the camera is 20.0 m below the terrain (ground at y = {ground:.1} m there)"
    );
    assert!(err.contains(&want), "stderr {err:?} lacks {want:?}");
    let err = render_from(ground + 2.0);
    assert!(!err.contains("below the terrain"), "{err}");
}

#[test]
fn bad_input_exits_with_2_and_says_what_is_wrong() {
    // A missing scene file.
    let o = canopy()
        .args(["render", "/nonexistent/scene.toml", "--out", "/tmp/x.png"])
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&o.stderr).contains("/nonexistent/scene.toml"));

    // A scene with a typo.
    let bad = tmp("typo.toml");
    let text = std::fs::read_to_string(common::data("small.toml"))
        .unwrap()
        .replacen("[forest]\n", "[forest]\ncuont = 3\n", 1);
    std::fs::write(&bad, text).unwrap();
    let o = canopy()
        .arg("render")
        .arg(&bad)
        .args(["--out", "/tmp/x.png"])
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(2));
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("cuont"), "{err}");

    // Bad arguments.
    for args in [
        vec!["render", "--out", "/tmp/x.png", "--size", "0x10"],
        vec!["render", "--out", "/tmp/x.png", "--sun", "10"],
        vec!["render", "--out", "/tmp/x.png", "--method", "nope"],
        vec![
            "render",
            "--out",
            "/tmp/x.png",
            "--camera",
            "1,2,nan",
            "--look-at",
            "0,0,0",
        ],
    ] {
        let o = canopy().args(&args).output().unwrap();
        assert_eq!(o.status.code(), Some(2), "{args:?}");
    }

    // Comparing images of different sizes, and a missing image.
    let a = tmp("a.png");
    let b = tmp("b.png");
    image::RgbaImage::new(4, 4).save(&a).unwrap();
    image::RgbaImage::new(5, 4).save(&b).unwrap();
    let o = canopy().arg("compare").arg(&a).arg(&b).output().unwrap();
    assert_eq!(o.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&o.stderr).contains("differ in size"));
    let o = canopy()
        .arg("compare")
        .arg(&a)
        .arg("/nonexistent.png")
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(2));
}

#[test]
fn an_unwritable_output_path_is_an_error_and_leaves_nothing() {
    let blocker = tmp("file-not-dir");
    std::fs::write(&blocker, b"x").unwrap();
    let out = blocker.join("out.png");
    let o = canopy()
        .arg("render")
        .arg(common::data("lone_tree.toml"))
        .arg("--out")
        .arg(&out)
        .args(["--size", "32x32", "--frames", "1", "--cpu"])
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&o.stderr).contains("out.png"));
    assert!(!out.exists());
}

#[test]
fn bench_writes_its_outputs_and_a_second_run_reuses_the_truth() {
    let out = tmp("bench");
    // The cache holds the stand's bake (the run's shared one): the bench renders, it does
    // not bake.
    let cache = common::cache_holding(&common::load_scene("btf.toml"), &tmp("bench-cache"));
    let scene = common::data("btf.toml");
    let run = || {
        let o = canopy()
            .env("CANOPY_CACHE_DIR", &cache)
            .args(["bench"])
            .arg(&scene)
            .args(["--flight", "orbit", "--frames", "3", "--size", "64x48"])
            .args([
                "--methods",
                "geometry,btf,billboard,texel",
                "--sweep",
                "lod_scale=1,2",
                "--sweep",
                "slice_d1=2,4",
                "--sweep",
                "texel_mode=slices3d,stacks",
            ])
            .args([
                "--repeats",
                "1",
                "--truth-supersample",
                "1",
                "--cpu",
                "--json",
                "--out",
            ])
            .arg(&out)
            .output()
            .unwrap();
        assert!(
            o.status.success(),
            "bench failed: {}",
            String::from_utf8_lossy(&o.stderr)
        );
        let json: serde_json::Value =
            serde_json::from_slice(&o.stdout).expect("stdout is one JSON object");
        json
    };
    let first = run();
    let configs = first["configurations"].as_array().expect("configurations");
    let labels: Vec<&str> = configs
        .iter()
        .map(|c| c["label"].as_str().unwrap())
        .collect();
    assert_eq!(
        labels,
        [
            "geometry",
            "btf lod_scale=1",
            "btf lod_scale=2",
            "billboard",
            "texel slice_d1=2 texel_mode=slices3d",
            "texel slice_d1=2 texel_mode=stacks",
            "texel slice_d1=4 texel_mode=slices3d",
            "texel slice_d1=4 texel_mode=stacks",
        ]
    );
    for (i, c) in configs.iter().enumerate() {
        assert!(c["median_ms"].as_f64().unwrap() > 0.0, "{c}");
        let flip = c["mean_flip"].as_f64().unwrap();
        // The truth is the reference (sky visibility, whole-scene sun shadows): the
        // interactive geometry differs from it, a little.
        if i == 0 {
            assert!(flip > 0.0 && flip < 0.2, "{c}");
        } else {
            assert!(flip > 0.0 && flip < 1.0, "{c}");
        }
        assert!(c["flicker_ratio"].as_f64().unwrap().is_finite(), "{c}");
    }
    assert_eq!(configs[1]["knobs"]["lod_scale"], 1.0);
    assert_eq!(configs[6]["knobs"]["slice_d1"], 4.0);
    assert_eq!(configs[5]["knobs"]["texel_mode"], "stacks");
    assert_eq!(configs[6]["knobs"]["texel_mode"], "slices3d");
    assert_eq!(configs[0]["speedup_vs_geometry"], 1.0);
    assert_eq!(
        (
            first["truth_rendered"].as_u64(),
            first["truth_cached"].as_u64()
        ),
        (Some(3), Some(0))
    );
    let csv = std::fs::read_to_string(out.join("results.csv")).unwrap();
    assert_eq!(csv.lines().count(), 1 + 3 * 8, "{csv}");
    for f in [
        "summary.json",
        "chart.png",
        "flight.png",
        "worst-0.png",
        "worst-5.png",
    ] {
        assert!(out.join(f).is_file(), "{f} written");
    }
    let chart = image::open(out.join("chart.png")).unwrap();
    assert!(chart.width() >= 200 && chart.height() >= 200);
    let second = run();
    assert_eq!(
        (
            second["truth_rendered"].as_u64(),
            second["truth_cached"].as_u64()
        ),
        (Some(0), Some(3)),
        "the second bench renders no geometry truth"
    );
}

#[test]
fn bench_refuses_bad_sweeps_and_flights_with_2() {
    for args in [
        ["--sweep", "lod_scale=abc"],
        ["--sweep", "blur=1,2"],
        ["--flight", "no-such-flight"],
        ["--frames", "1"],
    ] {
        let o = canopy()
            .args(["bench", "--out"])
            .arg(tmp("never"))
            .args(args)
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(2), "{args:?}: {err}");
        assert!(err.contains("error"), "{args:?}: {err}");
    }
    assert!(!tmp("never").exists(), "nothing written on bad input");
}
