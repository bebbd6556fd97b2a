//! Memory a frame leaves behind: `btf` drawn frame after frame, its far trees built on the
//! GPU, keeps the C heap flat. The heap is the process's, so the test runs itself again in
//! a process of its own (the suite's executable, this test alone), where no other test
//! allocates beside it while the heap is measured.
//!
//! Lavapipe (Mesa 22) compiles a shader again, with the values inlined, each time a
//! pipeline whose branches and loop bounds read a uniform buffer is bound, and keeps every
//! compilation until the device goes. The far trees' build pass therefore reads its
//! parameters from a read-only storage buffer: from a uniform buffer, each frame of the
//! default forest would leave about 1.4 MB of compiled shader behind, and an hour in the
//! viewer several gigabytes.

use crate::common;

use canopy::render::{Camera, FrameDesc, Method, Renderer};
use glam::Vec3;

/// Frames drawn before the heap is first measured: pipelines, buffers and the frame's
/// targets are made by then.
const WARM_FRAMES: usize = 6;

/// Frames drawn between the two measurements.
const FRAMES: usize = 40;

/// Most heap growth allowed per frame over [`FRAMES`]. Measured on lavapipe (llvmpipe 15,
/// 2026-11-29, release build): 5.1 KB a frame with the build pass's parameters in a storage
/// buffer. With them in a uniform buffer the test fails, and takes 230 s instead of 36 s:
/// every frame compiles the build pass again.
const MAX_BYTES_PER_FRAME: f64 = 64.0 * 1024.0;

/// Set in the process the test starts for itself.
const ALONE: &str = "CANOPY_HEAP_TEST_ALONE";

#[test]
fn btf_frames_with_far_trees_on_the_gpu_leave_the_heap_flat() {
    if std::env::var_os(ALONE).is_none() {
        let exe = std::env::current_exe().expect("the test executable");
        let out = std::process::Command::new(exe)
            .args([
                "frame_memory::btf_frames_with_far_trees_on_the_gpu_leave_the_heap_flat",
                "--exact",
                "--test-threads",
                "1",
                "--nocapture",
            ])
            .env(ALONE, "1")
            .output()
            .expect("running the test in a process of its own");
        let text = format!(
            "{}{}",
            String::from_utf8_lossy(&out.stdout),
            String::from_utf8_lossy(&out.stderr)
        );
        eprintln!("{text}");
        assert!(out.status.success(), "the test alone failed");
        assert!(text.contains("1 passed"), "the test alone did not run");
        return;
    }
    let ctx = common::gpu();
    // 144 firs on a 12 x 12 grid, 9 m apart, seen from 150-160 m: all at the tree level,
    // every one built by the GPU's far pass.
    let trees: Vec<(Vec3, f32)> = (0..144)
        .map(|i| {
            let (x, z) = ((i % 12) as f32 - 5.5, (i / 12) as f32 - 5.5);
            (Vec3::new(x * 9.0, 0.0, z * 9.0), 1.0)
        })
        .collect();
    let scene = common::lone_fir();
    let world = common::firs_at(&trees);
    let baked = common::fir_bake_for(&world);
    let mut renderer = Renderer::new(&ctx, &world).unwrap();
    renderer.attach_btf(&ctx, &baked, &world).unwrap();

    let target = Vec3::new(0.0, 6.0, 0.0);
    // The camera turns a little each frame, as it does in a flight.
    let frame_at = |k: usize| {
        let a = 0.3 + 0.01 * k as f32;
        let eye = target + Vec3::new(a.sin() * 150.0, 60.0, a.cos() * 150.0);
        let mut f = FrameDesc::from_scene(&scene);
        f.camera = Camera::look_at(eye, target, 30.0);
        f.method = Method::Btf;
        f.btf.gpu_far = true;
        f
    };
    let mut draw = |k: usize| {
        let (_, stats) = renderer
            .render_image(&ctx, &frame_at(k), 96, 64, 1)
            .expect("btf frame");
        stats.btf.map_or(0, |b| b.gpu_billboards)
    };
    for k in 0..WARM_FRAMES {
        draw(k);
    }
    let (before, _) = canopy::render::memory::heap_bytes();
    let mut gpu_billboards = 0;
    for k in WARM_FRAMES..WARM_FRAMES + FRAMES {
        gpu_billboards = gpu_billboards.max(draw(k));
    }
    let (after, _) = canopy::render::memory::heap_bytes();
    assert!(
        gpu_billboards >= 100,
        "the far trees should be built on the GPU (at most {gpu_billboards} billboards were)"
    );
    if before == 0 && after == 0 {
        eprintln!("no heap counters on this platform: nothing measured");
        return;
    }
    let per_frame = (after as f64 - before as f64) / FRAMES as f64;
    eprintln!(
        "C heap in use {:.1} MB -> {:.1} MB over {FRAMES} frames: {:.1} KB a frame",
        before as f64 / 1e6,
        after as f64 / 1e6,
        per_frame / 1024.0
    );
    assert!(
        per_frame <= MAX_BYTES_PER_FRAME,
        "each btf frame left {:.1} KB on the heap (at most {:.1} KB allowed)",
        per_frame / 1024.0,
        MAX_BYTES_PER_FRAME / 1024.0
    );
}
