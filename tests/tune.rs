//! `canopy tune` on the BTF test stand: the configuration it picks meets the target when
//! measured again, a looser target never picks a costlier one, and `--write` leaves a scene
//! file that parses and starts from the picked knobs.

use crate::common;

use canopy::bench::command::{TuneRequest, run_tune};
use canopy::bench::run::{self, BenchOptions};
use canopy::bench::tune::{TuneTarget, choose};
use canopy::bench::{Flight, FlightContext};
use canopy::render::{AdapterPreference, FrameDesc, GpuContext, Renderer};
use canopy::scene::Scene;

#[test]
fn tune_picks_what_meets_the_target_and_looser_targets_cost_no_more() {
    let dir = common::scratch_dir("tune-test");
    let scene_path = dir.join("stand.toml");
    std::fs::copy(common::data("btf.toml"), &scene_path).unwrap();
    // The stand's bake is in the cache (the run's shared one): tune measures, it does not bake.
    let cache_dir = common::cache_holding(&common::btf_stand(), &dir.join("cache"));
    let target = TuneTarget::new(0.3, 2.0).unwrap();
    let req = TuneRequest {
        scene: Some(scene_path.clone()),
        flight: "orbit".into(),
        target,
        width: 96,
        height: 64,
        frames: 3,
        truth_supersample: 1,
        repeats: 1,
        adapter: AdapterPreference::Cpu,
        progress: false,
        write: true,
        bake: false,
        method: canopy::render::Method::Btf,
        cache_dir: cache_dir.clone(),
    };
    let o = run_tune(&req).unwrap();
    let i = o.chosen.expect("a loose target is met");
    let picked = &o.results.summaries[i];
    eprintln!(
        "picked {} ({:.2} ms, FLIP {:.4}, flicker {:.2}) of {} in {:.0} s",
        picked.label,
        picked.median_ms,
        picked.mean_flip,
        picked.flicker_ratio,
        o.configs.len(),
        o.seconds
    );
    // A looser target never picks a costlier configuration (the same measurements).
    let mut last = 0.0;
    for e in [0.32, 0.25, 0.2, 0.18, 0.16, 0.15, 0.12] {
        let t = TuneTarget::new(e, 2.0).unwrap();
        if let Some(k) = choose(&o.results.summaries, &t) {
            let s = &o.results.summaries[k];
            assert!(s.mean_flip <= e);
            eprintln!("  target {e}: {} at {:.2} ms", s.label, s.median_ms);
            // Targets go from loose to tight: the cost may only grow.
            assert!(
                s.median_ms >= last,
                "target {e}: {} ms after {last} ms",
                s.median_ms
            );
            last = s.median_ms;
        }
    }
    // Measured again, the pick meets the target (lavapipe is deterministic: the same FLIP).
    let scene = Scene::load(&scene_path).unwrap();
    let world = scene.build_world().unwrap();
    let ctx = GpuContext::headless(AdapterPreference::Cpu).unwrap();
    let mut renderer = Renderer::new(&ctx, &world).unwrap();
    let cache = canopy::bake::cache::cache_path_in(&cache_dir, &scene);
    let (baked, _) =
        canopy::bake::load_or_bake_at(&cache, &ctx, &scene, &world, &mut |_| {}).unwrap();
    renderer.attach_btf(&ctx, &baked, &world).unwrap();
    renderer
        .prepare_reference(
            &ctx,
            &world,
            canopy::render::Reference::default().sky_directions,
            true,
        )
        .unwrap();
    let flight = Flight::resolve("orbit", &FlightContext::from_world(&world)).unwrap();
    let opts = BenchOptions {
        width: 96,
        height: 64,
        truth_supersample: 1,
        repeats: 1,
        cache_dir: cache_dir.clone(),
        scene_content: canopy::bench::scene_content(&scene),
        // The same truth as `tune`'s: the reference.
        reference: Some(canopy::render::Reference::default()),
    };
    let again = run::run(
        &ctx,
        &mut renderer,
        &FrameDesc::from_scene(&scene),
        &flight.frames(3),
        &o.configs[i..=i],
        &opts,
        &mut |_| {},
    )
    .unwrap();
    let s = &again.summaries[0];
    eprintln!(
        "measured again: FLIP {:.4}, flicker {:.2}",
        s.mean_flip, s.flicker_ratio
    );
    assert!(target.met_by(s), "{s:?}");
    assert!((s.mean_flip - picked.mean_flip).abs() < 1e-3);
    // --write: the scene now starts from the picked knobs.
    assert_eq!(o.written.as_deref(), Some(scene_path.as_path()));
    let start = FrameDesc::from_scene(&scene).btf;
    let mut chosen = FrameDesc::from_scene(&scene);
    o.configs[i].knobs.apply_to(&mut chosen);
    let want = chosen.btf;
    assert_eq!(
        (
            start.lod_scale,
            start.weight_threshold,
            start.lod_fade,
            start.planes
        ),
        (
            want.lod_scale,
            want.weight_threshold,
            want.lod_fade,
            want.planes
        )
    );
}

#[test]
fn tune_searches_btf_or_impostor_and_writes_btf_only() {
    let req = |method, write| TuneRequest {
        scene: Some(common::data("btf.toml")),
        flight: "orbit".into(),
        target: TuneTarget::new(0.3, 2.0).unwrap(),
        width: 96,
        height: 64,
        frames: 3,
        truth_supersample: 1,
        repeats: 1,
        adapter: AdapterPreference::Cpu,
        progress: false,
        write,
        bake: false,
        method,
        cache_dir: common::scratch_dir("tune-refused").join("cache"),
    };
    let e = run_tune(&req(canopy::render::Method::Texel, false))
        .err()
        .expect("texel is not tuned")
        .to_string();
    let tuned: Vec<&str> = canopy::bench::tune::tuned_methods()
        .iter()
        .map(|m| m.name())
        .collect();
    assert!(
        tuned.contains(&"btf") && tuned.contains(&"impostor"),
        "{tuned:?}"
    );
    for name in &tuned {
        assert!(e.contains(name), "{e} names {name}");
    }
    let e = run_tune(&req(canopy::render::Method::Impostor, true))
        .err()
        .expect("--write is btf's")
        .to_string();
    assert!(e.contains("--write"), "{e}");
}
