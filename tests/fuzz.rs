//! Mutation fuzzing of the parsers that read what users hand canopy: the baked-file
//! decoder (`format::from_bytes`), the scene parser (`Scene::parse`) and the glTF reader
//! (`model::gltf::import_slice`), seeded with real inputs (baked files built here through
//! the public types, the embedded default scene, the species presets and the test scenes,
//! Pine_5 as `.gltf` and as `.glb`).
//!
//! Each input must end in `Ok` or a clean `Err`: no panic, no single allocation larger than
//! the input allows (a length read from the file never sizes a buffer unchecked), no input
//! taking a second. Half of the baked inputs have their checksums recomputed after the
//! mutation, so the records behind the checksums are reached too.
//!
//! `cargo test --release --test suite fuzz:: -- --ignored` runs 1,000,000 inputs per target
//! (`CANOPY_FUZZ_INPUTS` to change, `CANOPY_FUZZ_SEED` for another sequence) and prints
//! inputs, time and outcomes; the plain `cargo test` runs a short smoke of each.

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;
use std::time::{Duration, Instant};

use canopy::format::{self, BakeSettings, Baked, BtfImageSet, Impostor, TexelVolume, VcmSet};
use canopy::model::Level;
use canopy::scene::Scene;
use canopy::sphere::OctaLayout;

/// The system allocator, remembering the largest single allocation of the current thread
/// while it tracks.
struct Watch;

thread_local! {
    static TRACKING: Cell<bool> = const { Cell::new(false) };
    static LARGEST: Cell<usize> = const { Cell::new(0) };
}

unsafe impl GlobalAlloc for Watch {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        note(layout.size());
        unsafe { System.alloc(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        unsafe { System.dealloc(ptr, layout) }
    }
    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        note(layout.size());
        unsafe { System.alloc_zeroed(layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        note(new_size);
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

fn note(size: usize) {
    let _ = TRACKING.try_with(|t| {
        if t.get() {
            let _ = LARGEST.try_with(|l| l.set(l.get().max(size)));
        }
    });
}

#[global_allocator]
static ALLOCATOR: Watch = Watch;

/// Runs `f`, returning its result, the largest single allocation it made and its time.
fn watched<T>(f: impl FnOnce() -> T) -> (T, usize, Duration) {
    LARGEST.with(|l| l.set(0));
    TRACKING.with(|t| t.set(true));
    let t0 = Instant::now();
    let out = f();
    let took = t0.elapsed();
    TRACKING.with(|t| t.set(false));
    (out, LARGEST.with(|l| l.get()), took)
}

/// xorshift64*: a small, seeded, reproducible generator.
struct Rng(u64);

impl Rng {
    fn next(&mut self) -> u64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        self.0.wrapping_mul(0x2545_f491_4f6c_dd1d)
    }
    fn below(&mut self, n: usize) -> usize {
        (self.next() % n.max(1) as u64) as usize
    }
}

/// Values that sit on the edges of what fields hold.
const EDGE_U32: [u32; 12] = [
    0,
    1,
    2,
    6,
    7,
    8,
    255,
    256,
    4096,
    0x7fff_ffff,
    0x8000_0000,
    u32::MAX,
];

/// One to four mutations of `seed`: bit flips, edge values written over 4 bytes, random
/// bytes, truncation, a copied or deleted run, or a splice of `other`.
fn mutate(seed: &[u8], other: &[u8], rng: &mut Rng) -> Vec<u8> {
    let mut b = seed.to_vec();
    for _ in 0..1 + rng.below(4) {
        if b.is_empty() {
            b.push(rng.next() as u8);
            continue;
        }
        match rng.below(8) {
            0 => {
                let i = rng.below(b.len());
                b[i] ^= 1 << rng.below(8);
            }
            1 | 2 => {
                // Edge values land on the 4-byte fields of the header and records.
                let i = rng.below(b.len()) & !3;
                let v = EDGE_U32[rng.below(EDGE_U32.len())].to_le_bytes();
                for (k, byte) in v.iter().enumerate() {
                    if let Some(x) = b.get_mut(i + k) {
                        *x = *byte;
                    }
                }
            }
            3 => {
                let i = rng.below(b.len());
                b[i] = rng.next() as u8;
            }
            4 => {
                let n = rng.below(b.len());
                b.truncate(n);
            }
            5 => {
                let i = rng.below(b.len());
                let n = rng.below(64).min(b.len() - i);
                let run: Vec<u8> = b[i..i + n].to_vec();
                let at = rng.below(b.len());
                b.splice(at..at, run);
            }
            6 => {
                let i = rng.below(b.len());
                let n = rng.below(64).min(b.len() - i);
                b.drain(i..i + n);
            }
            _ => {
                if !other.is_empty() {
                    let from = rng.below(other.len());
                    let n = rng.below(256).min(other.len() - from);
                    let at = rng.below(b.len());
                    let end = (at + n).min(b.len());
                    b.splice(at..end, other[from..from + n].iter().copied());
                }
            }
        }
    }
    b
}

fn u32_at(b: &[u8], at: usize) -> Option<u32> {
    Some(u32::from_le_bytes(b.get(at..at + 4)?.try_into().ok()?))
}

/// Recomputes the checksums of a (mutated) baked file where its section table can be
/// followed, so that the decoder reads past them.
fn fix_checksums(b: &mut [u8]) {
    let Some(n) = u32_at(b, 12).map(|n| n as usize).filter(|&n| n <= 64) else {
        return;
    };
    // The format's header: 80 fixed bytes (76 before version 9), then the section table
    // of 28-byte entries (16 in version 7).
    let version = u32_at(b, 8);
    let entry_bytes = if version == Some(7) { 16 } else { 28 };
    let fixed = if version.is_some_and(|v| v >= 9) {
        80
    } else {
        76
    };
    let table_end = fixed + entry_bytes * n;
    let mut at = table_end + 4;
    for i in 0..n {
        let entry = fixed + entry_bytes * i;
        let Some(len) = b
            .get(entry + 8..entry + 16)
            .map(|s| u64::from_le_bytes(s.try_into().unwrap_or([0; 8])) as usize)
        else {
            return;
        };
        let Some(end) = at.checked_add(len).filter(|&e| e <= b.len()) else {
            break;
        };
        let crc = crc32fast::hash(&b[at..end]).to_le_bytes();
        b[entry + 4..entry + 8].copy_from_slice(&crc);
        at = end;
    }
    if table_end + 4 <= b.len() {
        let crc = crc32fast::hash(&b[..table_end]).to_le_bytes();
        b[table_end..table_end + 4].copy_from_slice(&crc);
    }
}

fn noise(seed: u32, len: usize) -> Vec<u8> {
    let mut r = Rng(u64::from(seed) * 0x9e37_79b9 + 1);
    (0..len).map(|_| r.next() as u8).collect()
}

/// A real species' surfel tree, sampled small (about 2,000 level-0 surfels).
fn surfel_tree() -> format::SurfelSet {
    let params = canopy::model::preset("broadleaf").expect("a preset");
    let tree = canopy::model::TreeModel::generate(&params, 3).expect("a tree");
    canopy::render::method::surfel::sample::sample_species(&[tree], 2_000, 0.0)
        .pop()
        .expect("one species")
}

/// Small valid baked files: VCM sets, texel volumes, an impostor and a surfel tree; the
/// same with a BTF set; and that block-compressed.
fn baked_seeds() -> Vec<Vec<u8>> {
    let settings = BakeSettings {
        views: 6,
        tree_views: 6,
        lights: 6,
        resolution: 32,
        supersample: 2,
        vcm_resolution: 8,
        texel_resolution: 16,
        impostor_frames: 4,
        impostor_resolution: 16,
        impostor_layout: OctaLayout::Hemi,
        compress: false,
        surfel_budget: 2_000,
    };
    // 4 x 4 frames of 16², 2 levels: (64² + 32²) x 4 bytes an atlas.
    let atlas = (64 * 64 + 32 * 32) * 4;
    let impostor = Impostor {
        species: 0,
        layout: OctaLayout::Hemi,
        frames: 4,
        resolution: 16,
        mip_levels: 2,
        center: [0.0, 4.0, 0.0],
        radius: 5.0,
        albedo: noise(5, atlas),
        normal_depth: noise(6, atlas),
    };
    let vcm = |owner: u32, level: Level| VcmSet {
        species: 0,
        owner,
        level,
        encoding: format::MapEncoding::R8,
        resolution: 8,
        opacity: noise(owner + 3, 48 * 64),
        mean_opacity: [0.5; 8],
    };
    let texel = |species: u32, dims: [u32; 3]| TexelVolume {
        species,
        lights: 6,
        dims,
        box_min: [-1.0, 0.0, -1.0],
        voxel: 0.5,
        voxels: noise(species + 9, 7 * dims.iter().product::<u32>() as usize * 4),
    };
    let small = Baked {
        scene_hash: 0x5eed,
        settings,
        btf: Vec::new(),
        vcm: vec![vcm(0, Level::Twig), vcm(3, Level::Tree)],
        texels: vec![texel(0, [2, 3, 2]), texel(1, [3, 2, 1])],
        impostors: vec![impostor],
        surfels: vec![surfel_tree()],
    };
    let image = 32 * 32 * 4;
    let with_btf = Baked {
        btf: vec![BtfImageSet {
            species: 0,
            level: Level::Branch,
            encoding: format::ImageEncoding::Rgba8,
            views: 6,
            lights: 6,
            resolution: 32,
            center: [0.0, 1.0, 0.0],
            radius: 2.0,
            texel_size: 0.05,
            direct: noise(1, image * 36),
            ambient: noise(2, image * 12),
        }],
        ..small.clone()
    };
    // The same block-compressed: BC7 images, BC4 cube maps.
    let mut compressed = with_btf.clone();
    canopy::bake::compress::compress(&mut compressed);
    // Mostly zeros, stored deflated.
    let mut zeros = small.clone();
    for v in &mut zeros.vcm {
        v.opacity.fill(0);
    }
    for t in &mut zeros.texels {
        t.voxels.fill(0);
    }
    let deflated = format::to_bytes_packed(&zeros, format::Packing::Deflate);
    assert!(deflated.len() < format::to_bytes(&zeros).len());
    let mut seeds: Vec<Vec<u8>> = [small, with_btf, compressed]
        .iter()
        .map(format::to_bytes)
        .collect();
    seeds.push(deflated);
    for s in &seeds {
        format::from_bytes(s).expect("the seeds are valid baked files");
    }
    seeds
}

/// The scene texts canopy ships and tests with.
fn scene_seeds() -> Vec<Vec<u8>> {
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
    let mut out = Vec::new();
    for dir in ["assets", "assets/species", "tests/data"] {
        let Ok(entries) = std::fs::read_dir(root.join(dir)) else {
            continue;
        };
        let mut paths: Vec<_> = entries.flatten().map(|e| e.path()).collect();
        paths.sort();
        for p in paths {
            if p.extension().is_some_and(|e| e == "toml")
                && let Ok(b) = std::fs::read(&p)
            {
                out.push(b);
            }
        }
    }
    assert!(out.len() >= 3, "scene seeds found: {}", out.len());
    out
}

/// What a fuzz run saw.
#[derive(Debug, Default)]
struct Outcome {
    inputs: u64,
    accepted: u64,
    refused: u64,
    largest_alloc: usize,
    slowest: Duration,
    seconds: f64,
}

fn inputs(default: u64) -> u64 {
    std::env::var("CANOPY_FUZZ_INPUTS")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(default)
}

fn rng() -> Rng {
    let seed = std::env::var("CANOPY_FUZZ_SEED")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(0x00c0_ffee_u64);
    Rng(seed | 1)
}

/// Feeds `count` mutated baked files to the decoder.
fn fuzz_baked(count: u64) -> Outcome {
    let seeds = baked_seeds();
    let mut rng = rng();
    let mut o = Outcome::default();
    let t0 = Instant::now();
    for i in 0..count {
        // Mostly the small seed; one input in 16 from the one with images (150 KB), one
        // in 16 from the one with BC7 images and BC4 cube maps.
        let k = match i % 16 {
            15 => 1,
            7 => 2,
            _ => 0,
        };
        let other = if k == 0 { 1 } else { 0 };
        let mut input = mutate(&seeds[k], &seeds[other], &mut rng);
        if rng.below(2) == 0 {
            fix_checksums(&mut input);
        }
        let (result, largest, took) = watched(|| format::from_bytes(&input));
        // A file's records never need more than the file's own size in one buffer (and
        // a little to start with).
        assert!(
            largest <= input.len() * 2 + (1 << 16),
            "input {i}: an allocation of {largest} bytes for a {}-byte file",
            input.len()
        );
        assert!(took < Duration::from_secs(1), "input {i} took {took:?}");
        match result {
            Ok(_) => o.accepted += 1,
            Err(e) => {
                assert!(!e.to_string().is_empty());
                o.refused += 1;
            }
        }
        o.largest_alloc = o.largest_alloc.max(largest);
        o.slowest = o.slowest.max(took);
        o.inputs += 1;
    }
    o.seconds = t0.elapsed().as_secs_f64();
    o
}

/// Feeds `count` mutated scene texts to the parser.
fn fuzz_scenes(count: u64) -> Outcome {
    let seeds = scene_seeds();
    let mut rng = rng();
    let mut o = Outcome::default();
    let t0 = Instant::now();
    for i in 0..count {
        let a = rng.below(seeds.len());
        let b = rng.below(seeds.len());
        let input = mutate(&seeds[a], &seeds[b], &mut rng);
        let text = String::from_utf8_lossy(&input).into_owned();
        let (result, largest, took) = watched(|| Scene::parse(&text, "fuzz.toml"));
        assert!(
            largest <= text.len() * 64 + (1 << 20),
            "input {i}: an allocation of {largest} bytes for a {}-byte scene",
            text.len()
        );
        assert!(took < Duration::from_secs(1), "input {i} took {took:?}");
        match result {
            Ok(_) => o.accepted += 1,
            Err(e) => {
                assert!(!e.to_string().is_empty());
                o.refused += 1;
            }
        }
        o.largest_alloc = o.largest_alloc.max(largest);
        o.slowest = o.slowest.max(took);
        o.inputs += 1;
    }
    o.seconds = t0.elapsed().as_secs_f64();
    o
}

/// The glTF seeds: Pine_5's JSON (its buffer and two small stand-in textures beside it in
/// the returned folder) and Pine_5 as one GLB with those textures in buffer views, so that
/// mutations reach the binary chunk, the accessors' bytes and the images too.
fn gltf_seeds() -> (Vec<Vec<u8>>, std::path::PathBuf) {
    let pine = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("assets/trees/pine5");
    let dir = std::env::temp_dir().join(format!("canopy-fuzz-gltf-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    std::fs::copy(pine.join("Pine_5.bin"), dir.join("Pine_5.bin")).unwrap();
    // 8x8, alternately opaque and cut away, so that both alpha paths run.
    let tiny = image::RgbaImage::from_fn(8, 8, |x, y| {
        image::Rgba([40, 90, 20, if (x + y) % 2 == 0 { 255 } else { 0 }])
    });
    let mut png = Vec::new();
    image::DynamicImage::ImageRgba8(tiny)
        .write_to(&mut std::io::Cursor::new(&mut png), image::ImageFormat::Png)
        .unwrap();
    for name in ["Bark_NormalTree.png", "Leaf_Pine_C.png"] {
        std::fs::write(dir.join(name), &png).unwrap();
    }
    let text = std::fs::read(pine.join("Pine_5.gltf")).unwrap();
    let mut j: serde_json::Value = serde_json::from_slice(&text).unwrap();
    let mut bin = std::fs::read(pine.join("Pine_5.bin")).unwrap();
    let view = serde_json::json!({"buffer": 0, "byteOffset": bin.len(), "byteLength": png.len()});
    bin.extend_from_slice(&png);
    while !bin.len().is_multiple_of(4) {
        bin.push(0);
    }
    let views = j["bufferViews"].as_array_mut().unwrap();
    views.push(view);
    let v = views.len() - 1;
    for img in j["images"].as_array_mut().unwrap() {
        *img = serde_json::json!({"bufferView": v, "mimeType": "image/png"});
    }
    j["buffers"] = serde_json::json!([{"byteLength": bin.len()}]);
    let mut json = serde_json::to_vec(&j).unwrap();
    while !json.len().is_multiple_of(4) {
        json.push(b' ');
    }
    let mut glb = Vec::new();
    glb.extend_from_slice(b"glTF");
    glb.extend_from_slice(&2u32.to_le_bytes());
    glb.extend_from_slice(&((12 + 8 + json.len() + 8 + bin.len()) as u32).to_le_bytes());
    glb.extend_from_slice(&(json.len() as u32).to_le_bytes());
    glb.extend_from_slice(&0x4E4F_534Au32.to_le_bytes());
    glb.extend_from_slice(&json);
    glb.extend_from_slice(&(bin.len() as u32).to_le_bytes());
    glb.extend_from_slice(&0x004E_4942u32.to_le_bytes());
    glb.extend_from_slice(&bin);
    (vec![text, glb], dir)
}

/// Feeds `count` mutated glTF files (JSON and GLB) to the glTF reader.
fn fuzz_gltf(count: u64) -> Outcome {
    use canopy::model::gltf;
    let (seeds, dir) = gltf_seeds();
    // Both seeds must be accepted as they are.
    for seed in &seeds {
        let tree = gltf::import_slice(seed, &dir, gltf::ImportOptions::default()).unwrap();
        assert_eq!(tree.mesh.triangle_count(), 1646);
    }
    let mut rng = rng();
    let mut o = Outcome::default();
    let t0 = Instant::now();
    for i in 0..count {
        let a = rng.below(seeds.len());
        let input = mutate(&seeds[a], &seeds[1 - a], &mut rng);
        let (result, largest, took) =
            watched(|| gltf::import_slice(&input, &dir, gltf::ImportOptions::default()));
        // What an import holds is bounded by its budgets (2,000,000 vertices and
        // triangles, images of 8192² at most and no more than 1032 pixel bytes per byte
        // of image data), whatever the input claims.
        assert!(
            largest <= 256 << 20,
            "input {i}: an allocation of {largest} bytes for a {}-byte file",
            input.len()
        );
        assert!(took < Duration::from_secs(2), "input {i} took {took:?}");
        match result {
            Ok(_) => o.accepted += 1,
            Err(e) => {
                assert!(!e.is_empty());
                o.refused += 1;
            }
        }
        o.largest_alloc = o.largest_alloc.max(largest);
        o.slowest = o.slowest.max(took);
        o.inputs += 1;
    }
    o.seconds = t0.elapsed().as_secs_f64();
    let _ = std::fs::remove_dir_all(&dir);
    o
}

#[test]
fn fuzz_smoke_gltf_reader() {
    let o = fuzz_gltf(3_000);
    eprintln!("glTF reader smoke: {o:?}");
    assert!(o.refused > 0 && o.accepted > 0);
}

#[test]
#[ignore = "a million inputs: cargo test --release --test suite fuzz:: -- --ignored"]
fn fuzz_gltf_reader() {
    let o = fuzz_gltf(inputs(1_000_000));
    eprintln!(
        "glTF reader: {} inputs in {:.1} s ({} accepted, {} refused), largest allocation {} bytes, slowest input {:?}",
        o.inputs, o.seconds, o.accepted, o.refused, o.largest_alloc, o.slowest
    );
}

#[test]
fn fuzz_smoke_baked_decoder() {
    let o = fuzz_baked(3_000);
    eprintln!("baked decoder smoke: {o:?}");
    assert!(o.refused > 0 && o.accepted + o.refused == o.inputs);
}

#[test]
fn fuzz_smoke_scene_parser() {
    let o = fuzz_scenes(3_000);
    eprintln!("scene parser smoke: {o:?}");
    assert!(o.refused > 0 && o.accepted > 0);
}

#[test]
#[ignore = "a million inputs: cargo test --release --test suite fuzz:: -- --ignored"]
fn fuzz_baked_decoder() {
    let o = fuzz_baked(inputs(1_000_000));
    eprintln!(
        "baked decoder: {} inputs in {:.1} s ({} accepted, {} refused), largest allocation {} bytes, slowest input {:?}",
        o.inputs, o.seconds, o.accepted, o.refused, o.largest_alloc, o.slowest
    );
}

#[test]
#[ignore = "a million inputs: cargo test --release --test suite fuzz:: -- --ignored"]
fn fuzz_scene_parser() {
    let o = fuzz_scenes(inputs(1_000_000));
    eprintln!(
        "scene parser: {} inputs in {:.1} s ({} accepted, {} refused), largest allocation {} bytes, slowest input {:?}",
        o.inputs, o.seconds, o.accepted, o.refused, o.largest_alloc, o.slowest
    );
}
