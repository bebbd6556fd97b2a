//! The `canopy` binary's baked files end to end: a file named with `--baked` is used or
//! refused with its reason (one case per baked section and version), concurrent bakes and
//! an unwritable or full cache, and bakes estimated and refused before they start.

use crate::cli::{canopy, tmp};
use crate::common;

use std::process::Command;

/// Where each kind of section (1 to 5: BTF, VCM, texel, impostor, surfel) lies in the
/// baked file `bytes` (its last section of the kind: start, length), checking that every
/// section is stored deflated.
fn deflated_sections(bytes: &[u8]) -> [Option<(usize, usize)>; 5] {
    let u32_at = |at: usize| u32::from_le_bytes(bytes[at..at + 4].try_into().unwrap());
    let sections = u32_at(12) as usize;
    // The format's header: 80 fixed bytes, the section table of 28-byte entries, the header
    // checksum.
    let mut at = 84 + 28 * sections;
    let mut found = [None; 5];
    for i in 0..sections {
        let entry = 80 + 28 * i;
        let len = u64::from_le_bytes(bytes[entry + 8..entry + 16].try_into().unwrap()) as usize;
        // Packing 1: the sections are stored deflated.
        assert_eq!(u32_at(entry + 16), 1, "section {i} stored deflated");
        if let Some(slot) = (u32_at(entry) as usize)
            .checked_sub(1)
            .and_then(|k| found.get_mut(k))
        {
            *slot = Some((at, len));
        }
        at += len;
    }
    found
}

/// `--baked FILE`: a file from `bake --out` is used as it is (no bake, no cache); one of
/// another scene, a truncated one, a missing one, or `--baked` with a method that draws no
/// baked images exits with 2 and the specific reason, and nothing is baked in its place.
#[test]
fn a_named_baked_file_is_used_or_refused_with_its_reason() {
    let cache = tmp("baked-cache");
    let lone = common::data("lone_tree.toml");
    let file = tmp("lone.canopy");
    let o = canopy()
        .env("CANOPY_CACHE_DIR", &cache)
        .arg("bake")
        .arg(&lone)
        .arg("--out")
        .arg(&file)
        .arg("--cpu")
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let render = |scene: &std::path::Path, baked: &std::path::Path, method: &str| {
        canopy()
            .env("CANOPY_CACHE_DIR", &cache)
            .arg("render")
            .arg(scene)
            .args([
                "--method", method, "--size", "64x48", "--frames", "1", "--cpu",
            ])
            .arg("--baked")
            .arg(baked)
            .arg("--out")
            .arg(tmp("baked.png"))
            .output()
            .unwrap()
    };
    let o = render(&lone, &file, "btf");
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let cached = std::fs::read_dir(&cache).map_or(0, |d| d.count());
    assert_eq!(cached, 0, "nothing baked into the cache");

    let refused = |o: std::process::Output, want: &str| {
        let err = String::from_utf8_lossy(&o.stderr).to_string();
        assert_eq!(o.status.code(), Some(2), "{err}");
        assert!(err.contains(want), "expected {want:?} in: {err}");
    };
    // Another scene.
    refused(
        render(&common::data("small.toml"), &file, "btf"),
        "baked for another scene",
    );
    // Truncated.
    let bytes = std::fs::read(&file).unwrap();
    let cut = tmp("cut.canopy");
    std::fs::write(&cut, &bytes[..bytes.len() / 2]).unwrap();
    refused(render(&lone, &cut, "btf"), "cannot use the baked file");
    assert_eq!(
        std::fs::read(&cut).unwrap().len(),
        bytes.len() / 2,
        "left as it was"
    );
    // The texel method draws from the file too.
    let o = render(&lone, &file, "texel");
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let u32_at = |at: usize| u32::from_le_bytes(bytes[at..at + 4].try_into().unwrap());
    let [
        btf_section,
        vcm_section,
        texel_section,
        impostor_section,
        surfel_section,
    ] = deflated_sections(&bytes);
    // The bake written again as `file_name` with one byte of `(start, len)` changed at
    // `start + len / part`.
    let flipped = |(start, len): (usize, usize), part: usize, bit: u8, file_name: &str| {
        let mut b = bytes.clone();
        b[start + len / part] ^= bit;
        let path = tmp(file_name);
        std::fs::write(&path, &b).unwrap();
        path
    };
    // The bake is block-compressed by default: BC7 images (encoding byte 1 after the
    // first record's level), BC4 cube maps. A byte changed in their blocks: refused with
    // the section's checksum.
    let compressed = u32_at(72);
    assert_eq!(compressed, 1, "[bake] compress is on by default");
    for (section, name) in [(btf_section, "btf image sets"), (vcm_section, "vcm sets")] {
        let (start, len) = section.expect("the bake has BTF and VCM sections");
        let mut payload = Vec::new();
        std::io::Read::read_to_end(
            &mut flate2::read::DeflateDecoder::new(&bytes[start..start + len]),
            &mut payload,
        )
        .unwrap();
        let encoding = if name == "vcm sets" { 4 + 9 } else { 4 + 5 };
        assert_eq!(payload[encoding], 1, "{name}: stored compressed");
        let bad = flipped((start, len), 2, 0x10, "bad-blocks.canopy");
        refused(
            render(&lone, &bad, "btf"),
            &format!("({name}) does not match its bytes"),
        );
    }
    // A file of format version 6 (before block compression): refused with the re-bake
    // hint.
    let mut old = bytes.clone();
    old[8..12].copy_from_slice(&6u32.to_le_bytes());
    let bad = tmp("v6.canopy");
    std::fs::write(&bad, &old).unwrap();
    refused(
        render(&lone, &bad, "btf"),
        "format version 6, but this canopy reads versions 7 to 9; re-bake with `canopy bake`",
    );
    // One byte changed inside the texel volumes' section (kind 3): refused, naming it.
    let texels = texel_section.expect("the bake has a texel section");
    let bad = flipped(texels, 2, 0x40, "bad-texels.canopy");
    refused(render(&lone, &bad, "texel"), "texel");
    refused(render(&lone, &bad, "btf"), "checksum");
    // One byte changed inside the impostors' section (kind 4): refused, naming it.
    let impostors = impostor_section.expect("the bake has an impostor section");
    let bad = flipped(impostors, 3, 0x04, "bad-impostors.canopy");
    refused(render(&lone, &bad, "btf"), "(impostors)");
    // One byte changed inside the surfel trees' section (kind 5): refused, naming it.
    let surfels = surfel_section.expect("the bake has a surfel section");
    let bad = flipped(surfels, 2, 0x08, "bad-surfels.canopy");
    refused(render(&lone, &bad, "surfel"), "(surfel trees)");
    // Missing.
    refused(render(&lone, &tmp("none.canopy"), "btf"), "could not open");
    // A method without baked images.
    refused(render(&lone, &file, "geometry"), "--baked is for");
    // The viewer checks the file before it opens a window.
    refused(
        canopy()
            .env("CANOPY_CACHE_DIR", &cache)
            .arg("view")
            .arg(common::data("small.toml"))
            .arg("--baked")
            .arg(&file)
            .output()
            .unwrap(),
        "baked for another scene",
    );
    let cached = std::fs::read_dir(&cache).map_or(0, |d| d.count());
    assert_eq!(cached, 0, "nothing baked into the cache");
}

/// Two processes baking the same scene into one cache at once leave one valid file (each
/// writes its own temporary file and renames it over the cache file); a cache folder that
/// cannot be created costs only the caching: the frame is drawn from memory and the reason
/// is printed.
#[test]
fn concurrent_bakes_leave_one_valid_file_and_an_unwritable_cache_is_only_a_warning() {
    let cache = tmp("concurrent-cache");
    let lone = btf_only_fir("concurrent");
    let bake = || {
        canopy()
            .env("CANOPY_CACHE_DIR", &cache)
            .arg("bake")
            .arg(&lone)
            .arg("--cpu")
            .stdout(std::process::Stdio::null())
            .stderr(std::process::Stdio::piped())
            .spawn()
            .unwrap()
    };
    let (a, b) = (bake(), bake());
    for child in [a, b] {
        let o = child.wait_with_output().unwrap();
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    }
    let files: Vec<std::path::PathBuf> = std::fs::read_dir(&cache)
        .unwrap()
        .map(|e| e.unwrap().path())
        .collect();
    assert_eq!(files.len(), 1, "one file, no temporary left: {files:?}");
    assert!(files[0].extension().is_some_and(|e| e == "canopy"));
    canopy::format::from_bytes(&std::fs::read(&files[0]).unwrap()).expect("a valid bake");
    // A render takes it from the cache as it is.
    let before = std::fs::metadata(&files[0]).unwrap().modified().unwrap();
    let o = canopy()
        .env("CANOPY_CACHE_DIR", &cache)
        .arg("render")
        .arg(&lone)
        .args([
            "--method", "btf", "--size", "32x24", "--frames", "1", "--cpu",
        ])
        .arg("--out")
        .arg(tmp("concurrent.png"))
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let after = std::fs::metadata(&files[0]).unwrap().modified().unwrap();
    assert_eq!(before, after, "not baked again");

    // The cache folder cannot be made (its parent is a file): drawn anyway, and said why.
    let blocker = tmp("not-a-folder");
    std::fs::write(&blocker, b"a file").unwrap();
    let o = canopy()
        .env("CANOPY_CACHE_DIR", blocker.join("cache"))
        .env("RUST_LOG", "warn")
        .arg("render")
        .arg(&lone)
        .args([
            "--method", "btf", "--size", "32x24", "--frames", "1", "--cpu",
        ])
        .arg("--out")
        .arg(tmp("uncached.png"))
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{err}");
    assert!(err.contains("could not cache the bake"), "{err}");
    assert!(tmp("uncached.png").exists());
}

/// The lone fir's scene baking what `btf` draws only (no texel volumes, impostor or surfel
/// trees: less than half its bake), written as `{name}-fir.toml` in the tests' directory:
/// for the tests of how bakes reach the cache, which draw it with `btf`.
fn btf_only_fir(name: &str) -> std::path::PathBuf {
    let path = tmp(&format!("{name}-fir.toml"));
    std::fs::write(&path, common::lone_fir_for_btf_only()).unwrap();
    path
}

/// A full disk (a 64 KiB tmpfs, where the machine lets the tests mount one): a screenshot
/// that does not fit is an error naming the path and the reason, and leaves no file, not
/// even a temporary; a bake the cache cannot hold is drawn from memory with a warning.
#[test]
fn a_full_disk_is_reported_and_leaves_nothing_half_written() {
    let dir = tmp("full-disk");
    std::fs::create_dir_all(&dir).unwrap();
    let mounted = Command::new("mount")
        .args(["-t", "tmpfs", "-o", "size=64k", "tmpfs"])
        .arg(&dir)
        .output()
        .is_ok_and(|o| o.status.success());
    if !mounted {
        eprintln!("skipped: cannot mount a small tmpfs here (needs root)");
        return;
    }
    let result = std::panic::catch_unwind(|| {
        // A 512 x 512 image of noise does not compress into 64 KiB.
        let mut seed = 1u32;
        let img = image::RgbaImage::from_fn(512, 512, |_, _| {
            seed = seed.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
            image::Rgba([
                (seed >> 24) as u8,
                (seed >> 16) as u8,
                (seed >> 8) as u8,
                255,
            ])
        });
        let shot = dir.join("shot.png");
        let e = canopy::imageio::save_png(&shot, &img)
            .expect_err("no room")
            .to_string();
        assert!(e.contains("shot.png"), "{e}");
        assert!(e.to_lowercase().contains("space"), "{e}");
        let left: Vec<_> = std::fs::read_dir(&dir).unwrap().collect();
        assert!(left.is_empty(), "left behind: {left:?}");
        // The cache on the full disk: drawn anyway, the reason printed.
        let o = canopy()
            .env("CANOPY_CACHE_DIR", dir.join("cache"))
            .env("RUST_LOG", "warn")
            .arg("render")
            .arg(btf_only_fir("full-disk"))
            .args([
                "--method", "btf", "--size", "32x24", "--frames", "1", "--cpu",
            ])
            .arg("--out")
            .arg(tmp("full-disk.png"))
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&o.stderr).to_string();
        assert!(o.status.success(), "{err}");
        assert!(err.contains("could not cache the bake"), "{err}");
        let cached: Vec<_> = std::fs::read_dir(dir.join("cache"))
            .map(|d| d.flatten().map(|e| e.path()).collect())
            .unwrap_or_default();
        assert!(cached.is_empty(), "nothing half-written: {cached:?}");
    });
    let _ = Command::new("umount").arg(&dir).output();
    if let Err(p) = result {
        std::panic::resume_unwind(p);
    }
}

/// A bake's cost is known before it starts: `info` gives the file's size exactly (the bake
/// then writes that many bytes); a bake the format cannot hold, or one needing more memory
/// than there is (`CANOPY_MEMORY_LIMIT` stands for a small machine), is refused with exit
/// code 2 and the key to lower, before any work and with nothing written.
#[test]
fn bakes_are_estimated_and_refused_before_they_start() {
    let cache = tmp("estimate-cache");
    let lone = common::data("lone_tree.toml");
    let o = canopy()
        .arg("info")
        .arg(&lone)
        .arg("--json")
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let info: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    let estimate = &info["bake_estimate"];
    let file = tmp("estimated.canopy");
    let o = canopy()
        .env("CANOPY_CACHE_DIR", &cache)
        .args(["bake"])
        .arg(&lone)
        .arg("--out")
        .arg(&file)
        .args(["--cpu", "--json"])
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{err}");
    assert!(err.contains("bake estimate: about"), "{err}");
    let written = std::fs::metadata(&file).unwrap().len();
    let baked: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    // The estimate is the file with every section stored as it is, exactly but for the
    // surfel trees (sampled: their size is known once made); the file written holds the
    // same data, its sections deflated where that shrinks them.
    let sections = baked["sections"]
        .as_array()
        .expect("the bake lists its sections");
    let header = 84 + 28 * sections.len() as u64;
    let sum = |key: &str| -> u64 { sections.iter().map(|s| s[key].as_u64().unwrap()).sum() };
    let surfels = baked["surfel_bytes"].as_u64().unwrap();
    let estimated_surfels = estimate["surfel_bytes"].as_u64().unwrap();
    assert!(surfels > 0, "{baked}");
    assert_eq!(
        estimate["file_bytes"]
            .as_u64()
            .map(|b| b - estimated_surfels + surfels),
        Some(header + sum("data_bytes")),
        "{estimate} {baked}"
    );
    assert!(
        (0.5..2.0).contains(&(estimated_surfels as f64 / surfels as f64)),
        "surfel trees: {estimated_surfels} estimated, {surfels} made"
    );
    assert_eq!(header + sum("file_bytes"), written, "{baked}");
    assert!(written < header + sum("data_bytes"), "{baked}");
    assert!(estimate["memory_bytes"].as_u64().unwrap() > written);
    // The impostor section, in both: the lone fir's 4 x 4 frames of 32², mipped to 4 pixels
    // (4 levels), two RGBA8 atlases, and 52 bytes of record in the estimate.
    let atlas = (128 * 128 + 64 * 64 + 32 * 32 + 16 * 16) * 4;
    assert_eq!(baked["impostor_frames"], 4, "{baked}");
    assert_eq!(baked["impostor_resolution"], 32);
    assert_eq!(baked["impostor_layout"], "full");
    assert_eq!(baked["impostor_mip_levels"], 4);
    assert_eq!(baked["impostor_bytes"], 2 * atlas);
    assert_eq!(baked["impostors"][0]["species"], "fir");
    assert_eq!(estimate["impostor_bytes"], 2 * atlas + 52, "{estimate}");
    let imp = &info["impostors"];
    assert_eq!(
        (
            &imp["frames"],
            &imp["resolution"],
            &imp["layout"],
            &imp["mip_levels"]
        ),
        (
            &serde_json::json!(4),
            &serde_json::json!(32),
            &serde_json::json!("full"),
            &serde_json::json!(4)
        ),
        "{info}"
    );

    let refused = |o: std::process::Output, want: &str| {
        let err = String::from_utf8_lossy(&o.stderr).to_string();
        assert_eq!(o.status.code(), Some(2), "{err}");
        assert!(err.contains(want), "expected {want:?} in: {err}");
        assert!(!err.contains("baking"), "no work started: {err}");
    };
    // Too little memory: the bake and a render that would bake are refused.
    let small = common::data("small.toml");
    let bake_small = || {
        canopy()
            .env("CANOPY_CACHE_DIR", &cache)
            .env("CANOPY_MEMORY_LIMIT", "100000000")
            .arg("bake")
            .arg(&small)
            .arg("--cpu")
            .output()
            .unwrap()
    };
    refused(bake_small(), "only 0.1 GB is available; lower [");
    let o = canopy()
        .env("CANOPY_CACHE_DIR", &cache)
        .env("CANOPY_MEMORY_LIMIT", "100000000")
        .arg("render")
        .arg(&small)
        .args(["--method", "btf", "--size", "32x32", "--cpu", "--out"])
        .arg(tmp("refused.png"))
        .output()
        .unwrap();
    refused(o, "GB of memory to bake and view");
    assert!(!tmp("refused.png").exists());
    // A BTF set larger than a section of the file.
    let text = std::fs::read_to_string(&small).unwrap();
    let huge = tmp("huge.toml");
    assert!(
        !text.contains("[bake]"),
        "the small scene keeps the default bake"
    );
    let edited = format!("{text}\n[bake]\nviews = 258\nlights = 258\nresolution = 128\n");
    std::fs::write(&huge, edited).unwrap();
    let o = canopy()
        .env("CANOPY_CACHE_DIR", &cache)
        .arg("bake")
        .arg(&huge)
        .arg("--cpu")
        .output()
        .unwrap();
    refused(o, "lower [bake] resolution, views or lights");
    let o = canopy().arg("info").arg(&huge).output().unwrap();
    assert!(o.status.success());
    assert!(String::from_utf8_lossy(&o.stdout).contains("bake refused"));
    let cached = std::fs::read_dir(&cache).map_or(0, |d| d.count());
    assert_eq!(cached, 0, "nothing written to the cache");
}
