//! What the format's tests share: a global allocator that measures the peak a closure
//! holds, sample bakes, and helpers that edit and reseal encoded bytes.

use std::fs;
use std::path::PathBuf;
use std::sync::atomic::{AtomicU64, Ordering};

use super::read::{u32_at, u64_at};
use super::*;

/// Counts the bytes allocated by the current thread while a closure runs, so tests can
/// check that decoding never allocates from an unchecked size. Thread-local, so tests
/// running in parallel do not disturb each other.
mod alloc_track {
    use std::alloc::{GlobalAlloc, Layout, System};
    use std::cell::Cell;

    thread_local! {
        static ON: Cell<bool> = const { Cell::new(false) };
        static LIVE: Cell<isize> = const { Cell::new(0) };
        static PEAK: Cell<isize> = const { Cell::new(0) };
    }

    fn note(delta: isize) {
        let _ = ON.try_with(|on| {
            if on.get() {
                let live = LIVE.get() + delta;
                LIVE.set(live);
                PEAK.set(PEAK.get().max(live));
            }
        });
    }

    pub struct Tracker;

    // SAFETY: forwards every call to `System` unchanged; only counts sizes.
    unsafe impl GlobalAlloc for Tracker {
        unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
            let p = unsafe { System.alloc(layout) };
            if !p.is_null() {
                note(layout.size() as isize);
            }
            p
        }

        unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
            let p = unsafe { System.alloc_zeroed(layout) };
            if !p.is_null() {
                note(layout.size() as isize);
            }
            p
        }

        unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
            unsafe { System.dealloc(ptr, layout) };
            note(-(layout.size() as isize));
        }

        unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
            let p = unsafe { System.realloc(ptr, layout, new_size) };
            if !p.is_null() {
                note(new_size as isize - layout.size() as isize);
            }
            p
        }
    }

    /// Runs `f` and returns its result and the most bytes it held allocated at once.
    pub fn peak_during<T>(f: impl FnOnce() -> T) -> (T, usize) {
        LIVE.set(0);
        PEAK.set(0);
        ON.set(true);
        let out = f();
        ON.set(false);
        (out, PEAK.get().max(0) as usize)
    }
}

#[global_allocator]
static TRACKER: alloc_track::Tracker = alloc_track::Tracker;
pub(crate) use alloc_track::peak_during;

/// Allowance for error messages, the section table and the like.
pub(crate) const SMALL_OVERHEAD: usize = 64 * 1024;

pub(crate) fn noise(seed: u32, len: usize) -> Vec<u8> {
    let mut x = seed.wrapping_mul(2_654_435_761).wrapping_add(12_345);
    (0..len)
        .map(|_| {
            x ^= x << 13;
            x ^= x >> 17;
            x ^= x << 5;
            (x >> 24) as u8
        })
        .collect()
}

pub(crate) fn settings() -> BakeSettings {
    BakeSettings {
        views: 6,
        tree_views: 6,
        lights: 6,
        resolution: 32,
        supersample: 2,
        vcm_resolution: 8,
        texel_resolution: 16,
        impostor_frames: 4,
        impostor_resolution: 16,
        impostor_layout: OctaLayout::Full,
        compress: false,
        surfel_budget: 5_000,
    }
}

/// A two-level surfel tree: a leaf block of three surfels under a root of one.
pub(crate) fn surfel_set(species: u32) -> SurfelSet {
    use crate::model::mesh::Aabb;
    use glam::Vec3;
    let bounds = Aabb::new(Vec3::new(-1.0, 0.0, -1.0), Vec3::new(1.0, 3.0, 1.0));
    let surfel = |k: u32| Surfel {
        position: Vec3::new(0.1 * k as f32, 1.0 + 0.2 * k as f32, -0.3),
        normal: Vec3::new(0.0, 1.0, 0.2 * k as f32).normalize(),
        albedo: Vec3::new(0.1, 0.3 + 0.1 * k as f32, 0.05),
        foliage: k.is_multiple_of(2),
        coverage: 0.25 * (k + 1) as f32,
        openness: 0.9 - 0.2 * k as f32,
    };
    let words = (0..4)
        .flat_map(|k| pack_surfel(&surfel(k), bounds.min, bounds.extent()))
        .collect();
    let nodes = vec![
        SurfelNode {
            level: 0,
            bounds,
            first: 0,
            count: 3,
            children: Vec::new(),
        },
        SurfelNode {
            level: 1,
            bounds,
            first: 3,
            count: 1,
            children: vec![0],
        },
    ];
    SurfelSet {
        species,
        bounds,
        spacing0: 0.05,
        gains: vec![1.0, 1.5],
        per_level: vec![3, 1],
        roots: SurfelSet::roots_of(&nodes, 2),
        nodes,
        words,
        density: SurfelDensity {
            origin: bounds.min,
            voxel: 1.5,
            dims: [2, 2, 2],
            sigma: (0..8).map(|k| 0.5 * k as f32).collect(),
        },
    }
}

/// A 4 x 4-frame impostor of 16² frames, 2 levels (40 KB).
pub(crate) fn impostor(species: u32) -> Impostor {
    let len = Impostor::atlas_bytes(4, 16, 2).unwrap() as usize;
    Impostor {
        species,
        layout: OctaLayout::Hemi,
        frames: 4,
        resolution: 16,
        mip_levels: 2,
        center: [0.0, 6.0, -0.5],
        radius: 7.5,
        albedo: noise(species + 300, len),
        normal_depth: noise(species + 400, len),
    }
}

pub(crate) fn texel_volume(species: u32, dims: [u32; 3]) -> TexelVolume {
    let len = 7 * dims.iter().product::<u32>() as usize * 4;
    TexelVolume {
        species,
        lights: 6,
        dims,
        box_min: [-1.5, 0.0, -1.5],
        voxel: 0.25,
        voxels: noise(species + 200, len),
    }
}

pub(crate) fn btf_set(species: u32, level: Level) -> BtfImageSet {
    let (views, lights, res) = (6u32, 6u32, 32u32);
    let image = (res * res * 4) as usize;
    BtfImageSet {
        species,
        level,
        encoding: ImageEncoding::Rgba8,
        views,
        lights,
        resolution: res,
        center: [0.5, -1.25, 3.0],
        radius: 2.5 + species as f32,
        texel_size: 0.01,
        direct: noise(species * 7 + 1, image * (views * lights) as usize),
        ambient: noise(
            species * 7 + 2,
            image * (views * AMBIENT_IMAGES_PER_VIEW) as usize,
        ),
    }
}

pub(crate) fn vcm_set(owner: u32, level: Level, resolution: u32) -> VcmSet {
    VcmSet {
        species: 0,
        owner,
        level,
        encoding: MapEncoding::R8,
        resolution,
        opacity: noise(owner + 100, 48 * (resolution * resolution) as usize),
        mean_opacity: [0.0, 0.125, 0.25, 0.375, 0.5, 0.625, 0.75, 1.0],
    }
}

/// Two BTF sets, two VCM sets, a texel volume, an impostor and a surfel tree (about 400 KB).
pub(crate) fn sample() -> Baked {
    Baked {
        scene_hash: 0x0123_4567_89ab_cdef,
        settings: settings(),
        btf: vec![btf_set(0, Level::Twig), btf_set(1, Level::Tree)],
        vcm: vec![vcm_set(0, Level::Twig, 8), vcm_set(7, Level::Branch, 16)],
        texels: vec![texel_volume(0, [8, 16, 8])],
        impostors: vec![impostor(0)],
        surfels: vec![surfel_set(0)],
    }
}

/// A few KB: two small VCM sets and a texel volume, no BTF, no impostor.
pub(crate) fn small() -> Baked {
    Baked {
        scene_hash: 42,
        settings: settings(),
        btf: Vec::new(),
        vcm: vec![vcm_set(3, Level::Twig, 8), vcm_set(4, Level::Tree, 8)],
        texels: vec![texel_volume(1, [2, 3, 2])],
        impostors: Vec::new(),
        surfels: Vec::new(),
    }
}

pub(crate) fn section_count(bytes: &[u8]) -> usize {
    u32_at(bytes, 12) as usize
}

pub(crate) fn header_end(bytes: &[u8]) -> usize {
    FIXED_HEADER_BYTES + SECTION_ENTRY_BYTES * section_count(bytes)
}

/// Recomputes the header checksum only.
pub(crate) fn reseal_header(bytes: &mut [u8]) {
    let end = header_end(bytes);
    let crc = crc32fast::hash(&bytes[..end]);
    bytes[end..end + 4].copy_from_slice(&crc.to_le_bytes());
}

/// Recomputes every section checksum and the header checksum (sections must lie inside
/// the bytes).
pub(crate) fn reseal(bytes: &mut [u8]) {
    let mut pos = header_end(bytes) + 4;
    for i in 0..section_count(bytes) {
        let entry = FIXED_HEADER_BYTES + SECTION_ENTRY_BYTES * i;
        let len = u64_at(bytes, entry + 8) as usize;
        let crc = crc32fast::hash(&bytes[pos..pos + len]);
        bytes[entry + 4..entry + 8].copy_from_slice(&crc.to_le_bytes());
        pos += len;
    }
    reseal_header(bytes);
}

/// `baked`'s data with the second half of every image, map, volume and atlas zeroed, so
/// that its sections deflate to well under their size (noise does not).
pub(crate) fn compressible(mut baked: Baked) -> Baked {
    let zero_half = |v: &mut Vec<u8>| {
        let half = v.len() / 2;
        v[half..].fill(0);
    };
    for s in &mut baked.btf {
        zero_half(&mut s.direct);
        zero_half(&mut s.ambient);
    }
    for s in &mut baked.vcm {
        zero_half(&mut s.opacity);
    }
    for t in &mut baked.texels {
        zero_half(&mut t.voxels);
    }
    for i in &mut baked.impostors {
        zero_half(&mut i.albedo);
        zero_half(&mut i.normal_depth);
    }
    baked
}

/// `bytes` as one raw DEFLATE stream.
pub(crate) fn deflate(bytes: &[u8]) -> Vec<u8> {
    use std::io::Write;
    let mut e = flate2::write::DeflateEncoder::new(Vec::new(), flate2::Compression::fast());
    e.write_all(bytes).unwrap();
    e.finish().unwrap()
}

/// The payloads of a version-8 file's sections as stored.
pub(crate) fn payloads(bytes: &[u8]) -> Vec<Vec<u8>> {
    (0..section_count(bytes))
        .map(|i| {
            let start = payload_start(bytes, i);
            let len = u64_at(bytes, FIXED_HEADER_BYTES + SECTION_ENTRY_BYTES * i + 8) as usize;
            bytes[start..start + len].to_vec()
        })
        .collect()
}

/// The version-8 file `bytes` with section `i`'s payload replaced by `stored`, its entry
/// saying `packing` and `plain_len`, and every size and checksum made right.
pub(crate) fn with_section(
    bytes: &[u8],
    i: usize,
    stored: &[u8],
    packing: Packing,
    plain_len: u64,
) -> Vec<u8> {
    let mut parts = payloads(bytes);
    parts[i] = stored.to_vec();
    let end = header_end(bytes);
    let mut out = bytes[..end + 4].to_vec();
    let entry = FIXED_HEADER_BYTES + SECTION_ENTRY_BYTES * i;
    out[entry + 8..entry + 16].copy_from_slice(&(stored.len() as u64).to_le_bytes());
    out[entry + 16..entry + 20].copy_from_slice(&(packing as u32).to_le_bytes());
    out[entry + 20..entry + 28].copy_from_slice(&plain_len.to_le_bytes());
    for p in &parts {
        out.extend_from_slice(p);
    }
    let len = out.len() as u64;
    out[16..24].copy_from_slice(&len.to_le_bytes());
    reseal(&mut out);
    out
}

/// A file whose sections are all stored as they are, written as version 7: no surfel
/// budget in the header, the table's entries without their packing and inflated length.
pub(crate) fn as_version_7(bytes: &[u8]) -> Vec<u8> {
    let payloads = &bytes[header_end(bytes) + 4..];
    let mut out = bytes[..FIXED_HEADER_BYTES_V8].to_vec();
    out[8..12].copy_from_slice(&7u32.to_le_bytes());
    for i in 0..section_count(bytes) {
        let entry = FIXED_HEADER_BYTES + SECTION_ENTRY_BYTES * i;
        assert_eq!(u32_at(bytes, entry + 16), Packing::Plain as u32);
        out.extend_from_slice(&bytes[entry..entry + SECTION_ENTRY_BYTES_V7]);
    }
    let len = (out.len() + 4 + payloads.len()) as u64;
    out[16..24].copy_from_slice(&len.to_le_bytes());
    let crc = crc32fast::hash(&out);
    out.extend_from_slice(&crc.to_le_bytes());
    out.extend_from_slice(payloads);
    out
}

/// Offset of the first payload byte of section `i`.
pub(crate) fn payload_start(bytes: &[u8], i: usize) -> usize {
    let mut pos = header_end(bytes) + 4;
    for j in 0..i {
        pos += u64_at(bytes, FIXED_HEADER_BYTES + SECTION_ENTRY_BYTES * j + 8) as usize;
    }
    pos
}

pub(crate) fn scratch_dir(name: &str) -> PathBuf {
    static N: AtomicU64 = AtomicU64::new(0);
    let dir = std::env::temp_dir().join(format!(
        "canopy-format-test-{}-{name}-{}",
        std::process::id(),
        N.fetch_add(1, Ordering::Relaxed)
    ));
    let _ = fs::remove_dir_all(&dir);
    fs::create_dir_all(&dir).unwrap();
    dir
}

pub(crate) use crate::atomic_file::dir_entries;

#[test]
pub(crate) fn the_allocation_tracker_sees_allocations() {
    let (v, peak) = peak_during(|| vec![1u8; 10_000_000]);
    assert!(peak >= 10_000_000, "{peak}");
    drop(v);
    let ((), peak) = peak_during(|| ());
    assert_eq!(peak, 0);
}

/// `baked` with its RGBA8 BTF sets turned into BC7 mip chains and its R8 cube maps into
/// BC4 blocks, laid out as the bake's compression stores them (each level here a plain
/// 2x2 average of the one above: the format reads only the encodings and lengths).
pub fn compress_for_tests(baked: &mut Baked) {
    for set in &mut baked.btf {
        if set.encoding != ImageEncoding::Rgba8 {
            continue;
        }
        let res = set.resolution;
        let n = (res * res * 4) as usize;
        let chain = |img: &[u8]| -> Vec<u8> {
            let mut out = Vec::new();
            let mut level = img.to_vec();
            let mut side = res;
            for m in 0..bc::bc_mip_levels(res) {
                if m > 0 {
                    let half = side / 2;
                    let mut next = vec![0u8; (half * half * 4) as usize];
                    for y in 0..half as usize {
                        for x in 0..half as usize {
                            for c in 0..4 {
                                let at = |dx: usize, dy: usize| {
                                    u32::from(
                                        level[((2 * y + dy) * side as usize + 2 * x + dx) * 4 + c],
                                    )
                                };
                                let sum = at(0, 0) + at(1, 0) + at(0, 1) + at(1, 1);
                                next[(y * half as usize + x) * 4 + c] = (sum / 4) as u8;
                            }
                        }
                    }
                    level = next;
                    side = half;
                }
                out.extend_from_slice(&bc::encode_bc7(&level, side, side));
            }
            out
        };
        set.direct = set.direct.chunks_exact(n).flat_map(chain).collect();
        set.ambient = set.ambient.chunks_exact(n).flat_map(chain).collect();
        set.encoding = ImageEncoding::Bc7;
    }
    for set in &mut baked.vcm {
        bc::compress_vcm(set);
    }
}
