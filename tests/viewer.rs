//! The viewer in a real window: started on the lone fir (its bake the run's shared one), it
//! renders frames and writes a screenshot of its 3D view, which must match `canopy render` of
//! the same frame by FLIP.
//! Needs an X display; CI runs it under Xvfb (.ci/run sets DISPLAY). Without a display the test says so and passes, so it
//! is listed as run: set CANOPY_REQUIRE_DISPLAY=1 to make a missing display a failure.

use crate::common;

use std::process::Command;

/// Whether there is a display to open a window on; without one the test says it is
/// skipped (and fails where CANOPY_REQUIRE_DISPLAY is set).
fn display_or_skip() -> bool {
    if std::env::var_os("DISPLAY").is_some() || std::env::var_os("WAYLAND_DISPLAY").is_some() {
        return true;
    }
    assert!(
        std::env::var_os("CANOPY_REQUIRE_DISPLAY").is_none(),
        "CANOPY_REQUIRE_DISPLAY is set but there is no DISPLAY"
    );
    eprintln!("skipped: no display (run under Xvfb with DISPLAY set)");
    false
}

/// The viewer tests' scene: one fir on flat ground, whose geometry frame lavapipe draws in
/// well under a second (the small scene's 30 trees take 6.5 s a frame at 1280x720).
const SCENE: &str = "lone_tree.toml";

/// `canopy view` of the lone fir on the geometry method, with a cache that holds its bake
/// (no bake beside the frames), writing a screenshot to `canopy-{name}-{process id}.png` in
/// the temporary directory (which it returns) after `frames` frames, with `env` set.
fn view_screenshot(
    name: &str,
    frames: &str,
    env: &[(&str, &str)],
) -> (std::path::PathBuf, std::process::Output) {
    let out = std::env::temp_dir().join(format!("canopy-{name}-{}.png", std::process::id()));
    let _ = std::fs::remove_file(&out);
    let cache = common::cache_holding(
        &common::load_scene(SCENE),
        &common::scratch_dir(&format!("{name}-cache")),
    );
    let o = Command::new(env!("CARGO_BIN_EXE_canopy"))
        .env("CANOPY_CACHE_DIR", cache)
        .envs(env.iter().copied())
        .arg("view")
        .arg(common::data(SCENE))
        .arg("--screenshot")
        .arg(&out)
        .args(["--after-frames", frames, "--method", "geometry"])
        .output()
        .unwrap();
    (out, o)
}

/// `canopy render` of the scene's start frame (the viewer's first frame: the scene's camera,
/// geometry) at `w` x `h` on the CPU adapter, with `extra` arguments.
fn render_start_frame(name: &str, w: u32, h: u32, extra: &[&str]) -> image::RgbImage {
    let out = std::env::temp_dir().join(format!("canopy-viewer-{name}-{}.png", std::process::id()));
    let o = Command::new(env!("CARGO_BIN_EXE_canopy"))
        .env("RUST_LOG", "error")
        .arg("render")
        .arg(common::data(SCENE))
        .arg("--out")
        .arg(&out)
        .args(["--size", &format!("{w}x{h}"), "--frames", "1", "--cpu"])
        .args(["--method", "geometry"])
        .args(extra)
        .output()
        .unwrap();
    assert!(
        o.status.success(),
        "render failed: {}",
        String::from_utf8_lossy(&o.stderr)
    );
    let img = image::open(&out).expect("render wrote a PNG").to_rgb8();
    let _ = std::fs::remove_file(&out);
    img
}

/// The screenshot's mean FLIP against `canopy render` of the same frame (the scene's start
/// camera and sun, geometry, the window's size) may not exceed this, the images-unchanged
/// tolerance. Measured on lavapipe (Mesa llvmpipe 15, Xvfb, 1280x720): 0.0000, both
/// draw the same frame with the same renderer.
const SCREENSHOT_FLIP: f32 = 0.002;

/// The failing counterpart: against a render with another sun (300°, 15°) the screenshot
/// is far outside that bound. Measured on lavapipe (the lone fir from above, its shadow
/// elsewhere): 0.4856.
const OTHER_SUN_FLIP: f32 = 0.1;

#[test]
fn viewer_screenshot_matches_a_render_of_the_same_frame() {
    if !display_or_skip() {
        return;
    }
    let (out, o) = view_screenshot("viewer", "3", &[]);
    assert!(
        o.status.success(),
        "viewer failed: {}",
        String::from_utf8_lossy(&o.stderr)
    );
    let shot = image::open(&out).expect("screenshot is a PNG").to_rgb8();
    let (w, h) = shot.dimensions();
    assert!(w > 100 && h > 100, "{w}x{h}");
    let flip = |img: &image::RgbImage| canopy::metrics::flip(img, &shot).unwrap().stats.mean;
    let same = flip(&render_start_frame("same", w, h, &[]));
    let other_sun = flip(&render_start_frame("other-sun", w, h, &["--sun", "300,15"]));
    eprintln!(
        "screenshot {w}x{h} against render: same frame {same:.4}, another sun {other_sun:.4}"
    );
    assert!(
        same <= SCREENSHOT_FLIP,
        "the screenshot is {same:.4} mean FLIP from a render of its frame (> {SCREENSHOT_FLIP}); \
         it is in {}",
        out.display()
    );
    assert!(
        other_sun > OTHER_SUN_FLIP,
        "another sun is only {other_sun:.4} from the screenshot (<= {OTHER_SUN_FLIP})"
    );
    let _ = std::fs::remove_file(&out);
}

/// A lost GPU device (destroyed at frame 2 through the test hook) is replaced: the viewer
/// goes on and writes its screenshot with the new device.
#[test]
fn the_viewer_recovers_from_a_lost_device() {
    if !display_or_skip() {
        return;
    }
    let (out, o) = view_screenshot(
        "viewer-lost",
        "6",
        &[
            ("CANOPY_TEST_LOSE_DEVICE_AT_FRAME", "2"),
            ("RUST_LOG", "warn"),
        ],
    );
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "viewer failed: {err}");
    assert!(err.contains("device was lost"), "{err}");
    let img = image::open(&out).expect("screenshot is a PNG").to_rgb8();
    assert!(img.width() > 100 && img.height() > 100);
}

/// How a soak runs: the scene (in `tests/data/`), whether its bake is the run's shared one
/// (else the viewer bakes it into the cache first), its length and sampling (s), and an
/// action every `every_frames` frames.
struct Soak<'a> {
    name: &'a str,
    scene: &'a str,
    shared_bake: bool,
    seconds: u32,
    sample_seconds: u32,
    every_frames: u32,
    actions: &'a [&'a str],
}

/// Runs the viewer on `soak.scene` under a soak script and checks that it passed (its own
/// judgement: resident and GPU memory grew by at most 5 % from the first interval wholly
/// after the warm-up to the last) and reported every sample.
fn soak(soak: Soak) {
    let Soak {
        name,
        scene,
        shared_bake,
        seconds,
        sample_seconds,
        every_frames,
        actions,
    } = soak;
    let dir = common::scratch_dir(name);
    let report = dir.join("soak.csv");
    let script = dir.join("soak.toml");
    std::fs::write(
        &script,
        format!(
            "seconds = {seconds}\nsample_seconds = {sample_seconds}\nevery_frames = {every_frames}\nreport = {:?}\nactions = {actions:?}\n",
            report.display().to_string()
        ),
    )
    .unwrap();
    let mut viewer = Command::new(env!("CARGO_BIN_EXE_canopy"));
    if shared_bake {
        viewer.env(
            "CANOPY_CACHE_DIR",
            common::cache_holding(&common::load_scene(scene), &dir.join("cache")),
        );
    }
    let o = viewer
        .arg("view")
        .arg(common::data(scene))
        .arg("--script")
        .arg(&script)
        .output()
        .unwrap();
    let out = String::from_utf8_lossy(&o.stdout);
    let err = String::from_utf8_lossy(&o.stderr);
    eprintln!("{out}");
    assert!(o.status.success(), "soak failed: {err}\n{out}");
    let csv = std::fs::read_to_string(&report).unwrap();
    // A sample at the start, one each interval, and on while a slow machine warms up.
    let intervals = (seconds / sample_seconds) as usize;
    assert!(
        csv.lines().count() > intervals + 1,
        "samples every {sample_seconds} s for {seconds} s: {csv}"
    );
    assert!(out.contains("soak:"), "{out}");
}

/// The short soak of every run: for 24 s the viewer flies over the BTF test stand (its bake
/// the run's shared one, on show from the first frame), sweeps the sun, switches methods
/// and texel modes, changes a knob, resizes and takes screenshots; memory sampled every 8 s
/// must not grow (the warm-up: every action run twice).
#[test]
fn a_short_soak_does_not_grow() {
    if !display_or_skip() {
        return;
    }
    soak(Soak {
        name: "soak-short",
        scene: "btf.toml",
        shared_bake: true,
        seconds: 24,
        sample_seconds: 8,
        every_frames: 1,
        actions: &[
            "fly",
            "sun",
            "method texel",
            "texel_mode stacks",
            "resize 700x500",
            "screenshot",
            "method btf",
            "lod_scale 2",
            "method billboard",
        ],
    });
}

/// The two-minute soak: every action of the viewer's scripts over the small scene (baked
/// by the viewer into the cache first), for 120 s after the bake is on show, sampled every
/// 40 s (the warm-up: the first 40 s, every action run twice, and
/// lavapipe's pools settled: a resident peak up by at most 1 % on the interval before). A
/// slow machine runs on until it has those intervals. Not in the default run (it takes
/// 2-4 minutes); run it with
/// `cargo test --test suite viewer::a_two_minute_soak_does_not_grow -- --ignored`.
#[test]
#[ignore = "two minutes or more; run with --ignored"]
fn a_two_minute_soak_does_not_grow() {
    if !display_or_skip() {
        return;
    }
    soak(Soak {
        name: "soak",
        scene: "small.toml",
        shared_bake: false,
        seconds: 120,
        sample_seconds: 40,
        every_frames: 2,
        actions: &[
            "fly",
            "sun",
            "method texel",
            "texel_mode stacks",
            "resize 700x500",
            "method geometry",
            "screenshot",
            "method btf",
            "lod_scale 2",
            "resize 900x600",
            "texel_mode slices3d",
            "lod_scale 1",
            "method billboard",
        ],
    });
}

/// Live reload in the running viewer: a sun edit is applied without a bake, a tree-count
/// edit is baked and shown, a typo is reported and the last good scene stays (the viewer's
/// log says each; the test waits for each line before the next edit).
#[test]
fn the_viewer_applies_scene_edits_live() {
    use std::io::BufRead;
    if !display_or_skip() {
        return;
    }
    let dir = common::scratch_dir("reload");
    let scene = dir.join("scene.toml");
    let text = std::fs::read_to_string(common::data(SCENE)).unwrap();
    std::fs::write(&scene, &text).unwrap();
    // The scene's bake is in the cache (the run's shared one): only the edit is baked.
    let cache = common::cache_holding(&common::load_scene(SCENE), &dir.join("cache"));
    let mut child = Command::new(env!("CARGO_BIN_EXE_canopy"))
        .env("CANOPY_CACHE_DIR", cache)
        .env("RUST_LOG", "canopy=info")
        .arg("view")
        .arg(&scene)
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let (tx, rx) = std::sync::mpsc::channel::<String>();
    let stderr = child.stderr.take().unwrap();
    std::thread::spawn(move || {
        for line in std::io::BufReader::new(stderr)
            .lines()
            .map_while(Result::ok)
        {
            if tx.send(line).is_err() {
                break;
            }
        }
    });
    let mut seen = Vec::new();
    let wait_for = |what: &str, seen: &mut Vec<String>| -> bool {
        let deadline = std::time::Instant::now() + std::time::Duration::from_secs(180);
        while std::time::Instant::now() < deadline {
            if let Ok(line) = rx.recv_timeout(std::time::Duration::from_millis(200)) {
                let hit = line.contains(what);
                seen.push(line);
                if hit {
                    return true;
                }
            }
        }
        false
    };
    // Running once the window's device exists.
    let started = wait_for("GPU:", &mut seen);
    let edit = |from: &str, to: &str| {
        let now = std::fs::read_to_string(&scene).unwrap();
        assert!(now.contains(from), "{from}");
        std::fs::write(&scene, now.replace(from, to)).unwrap();
    };
    let steps = started
        && {
            edit("elevation = 45.0", "elevation = 20.0");
            wait_for("applied the edit", &mut seen)
        }
        && {
            edit("count = 1\n", "count = 3\n");
            wait_for("the edited scene is baked and on show", &mut seen)
        }
        && {
            edit("elevation = 20.0", "elevaton = 20.0");
            wait_for("elevaton", &mut seen)
        };
    let _ = child.kill();
    let _ = child.wait();
    assert!(steps, "the viewer's log:\n{}", seen.join("\n"));
    assert!(
        !seen.iter().any(|l| l.contains("panicked")),
        "{}",
        seen.join("\n")
    );
}

/// A first bake (an empty cache) hands its tree levels to the viewer, which draws trees
/// before the bake has ended; the finished cache is left whole, nothing beside it but the
/// ground's sky visibility. Not in
/// the default run (a whole bake in the viewer); run it with
/// `cargo test --test suite viewer::a_first_bake_draws_trees_before_it_ends -- --ignored`.
#[test]
#[ignore = "a whole bake in the viewer; run with --ignored"]
fn a_first_bake_draws_trees_before_it_ends() {
    if !display_or_skip() {
        return;
    }
    let dir = common::scratch_dir("first-bake");
    let cache = dir.join("cache");
    let out = dir.join("shot.png");
    let o = Command::new(env!("CARGO_BIN_EXE_canopy"))
        .env("RUST_LOG", "canopy=info")
        .env("CANOPY_CACHE_DIR", &cache)
        .arg("view")
        .arg(common::data("lone_tree.toml"))
        .arg("--screenshot")
        .arg(&out)
        .args(["--after-frames", "2", "--wait-bake", "--method", "btf"])
        .output()
        .unwrap();
    let log = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{log}");
    // "timeline: ..., 9.1 s after the viewer started"
    let at = |what: &str| -> Option<f64> {
        let line = log.lines().find(|l| l.contains(what))?;
        let (_, rest) = line.split_once(", ")?;
        rest.split_whitespace().next()?.parse().ok()
    };
    let trees = at("timeline: the first frame with trees");
    let done = at("timeline: the bake is done");
    eprintln!("first trees at {trees:?} s, the bake done at {done:?} s");
    let (Some(trees), Some(done)) = (trees, done) else {
        panic!("the timeline lines are missing:\n{log}");
    };
    assert!(
        trees < done,
        "trees at {trees} s, the bake done at {done} s"
    );
    // The bake's one file, and the ground's sky visibility kept beside it.
    let files: Vec<_> = std::fs::read_dir(&cache)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .filter(|name| !name.ends_with(".sky64"))
        .collect();
    assert_eq!(files.len(), 1, "{files:?}");
    assert!(files[0].ends_with(".canopy") && !files[0].contains("partial"));
    assert!(out.exists());
}
