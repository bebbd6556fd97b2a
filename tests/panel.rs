//! The viewer's control panel, headless through egui_kittest: widgets are found by label,
//! clicked, and the frame description and requested actions change accordingly. The bench
//! results window the same way, on folders written by the test.

use canopy::app::bench_view::BenchWindow;
use canopy::app::panel::{PanelActions, PanelStats, controls};
use canopy::model::PerLevel;
use canopy::render::FrameDesc;
use canopy::scene::Scene;
use egui_kittest::Harness;
use egui_kittest::kittest::Queryable;

/// A harness as tall as a full-height viewer panel: the default 600 px would leave the
/// buttons at the bottom off screen, where a click does not reach them.
fn tall<S>() -> egui_kittest::HarnessBuilder<S> {
    Harness::builder().with_size(egui::vec2(800.0, 1200.0))
}

struct State {
    frame: FrameDesc,
    actions: PanelActions,
}

#[test]
fn screenshot_button_and_shadow_toggle_work() {
    let scene = Scene::default_scene();
    let state = State {
        frame: FrameDesc::from_scene(&scene),
        actions: PanelActions::default(),
    };
    let stats = PanelStats {
        trees_drawn: 12,
        trees_total: 1000,
        triangles: 1_500_000,
        ..Default::default()
    };
    let mut harness = tall().build_ui_state(
        move |ui, s: &mut State| {
            let a = controls(ui, &mut s.frame, &stats, None);
            if a.screenshot || a.screenshot_as {
                s.actions = a;
            }
        },
        state,
    );
    harness.run();
    harness.get_by_label("12 / 1000");
    harness.get_by_label("1.50 M");
    assert!(harness.state().frame.shadows.enabled);
    harness.get_by_label("sun shadows").click();
    harness.run();
    assert!(!harness.state().frame.shadows.enabled);
    harness.get_by_label("Screenshot (F12)").click();
    harness.run();
    assert!(harness.state().actions.screenshot);
}

#[test]
fn the_btf_controls_appear_with_the_btf_method_and_show_its_stats() {
    let scene = Scene::default_scene();
    let state = State {
        frame: FrameDesc::from_scene(&scene),
        actions: PanelActions::default(),
    };
    let frame_stats = canopy::render::FrameStats {
        btf: Some(canopy::render::method::btf::BtfStats {
            billboards: PerLevel {
                twig: 10,
                branch: 20,
                tree: 30,
            },
            trees_per_level: PerLevel {
                twig: 1,
                branch: 2,
                tree: 3,
            },
            faded_trees: 4,
            geometry_trees: 0,
            images_sampled: 540,
            fetches_saved: 180,
            light_blended: 0,
            canopy_tiles: 3,
            canopy_trees: 1200,
            dropped: 0,
            gpu_billboards: 0,
            vcm: true,
            impostors: 0,
        }),
        ..Default::default()
    };
    let stats = PanelStats {
        frame: frame_stats,
        btf_bytes: 16_500_000,
        vcm_bytes: 53_182_464,
        vcm_resolution: Some(32),
        sun_update_ms: Some(12.34),
        sun_update_gpu_ms: Some(45.67),
        bake_progress: Some((40, 100, "fir tree".into(), Some(61.7))),
        paused_for_bake: true,
        ..Default::default()
    };
    let mut harness = tall().build_ui_state(
        move |ui, s: &mut State| {
            controls(ui, &mut s.frame, &stats, None);
        },
        state,
    );
    harness.run();
    assert!(
        harness.query_by_label("show LOD level").is_none(),
        "geometry shows no btf controls"
    );
    harness.get_by_label("baking BTF images: fir tree, about 62 s left");
    harness.get_by_label(
        "until it is done, the view is drawn less often, to leave the bake the cores",
    );
    harness.get_by_label("btf").click();
    harness.run();
    assert_eq!(harness.state().frame.method, canopy::render::Method::Btf);
    harness.get_by_label("10 / 20 / 30");
    harness.get_by_label("9.00");
    harness.get_by_label("16.5 MB");
    harness.get_by_label("32² x 6 faces x 8 corners, 53.2 MB");
    harness.get_by_label("12.3 ms CPU + 45.7 ms GPU");
    harness.get_by_label("show LOD level").click();
    harness.run();
    assert!(harness.state().frame.btf.show_lod);
    assert!(harness.state().frame.btf.vcm);
    harness.get_by_label("show VCM shadow factor").click();
    harness.run();
    assert!(harness.state().frame.btf.show_shadow);
    assert!(harness.state().frame.btf.vcm_sky);
    harness.get_by_label("VCM sky occlusion").click();
    harness.run();
    assert!(!harness.state().frame.btf.vcm_sky);
    harness
        .get_by_label("VCM shading (trees shade each other)")
        .click();
    harness.run();
    assert!(!harness.state().frame.btf.vcm);
    harness.get_by_label("crossed").click();
    harness.run();
    assert_eq!(
        harness.state().frame.btf.planes,
        canopy::render::method::btf::PlaneMode::Crossed
    );
    // The texel method's controls come from its own knob table.
    assert!(harness.query_by_label("stacks").is_none());
    harness.get_by_label("texel").click();
    harness.run();
    assert!(harness.query_by_label("show LOD level").is_none());
    harness.get_by_label("stacks").click();
    harness.run();
    assert_eq!(
        harness.state().frame.texel.mode,
        canopy::render::method::texel::TexelMode::Stacks
    );
    harness.get_by_label("show slice count").click();
    harness.run();
    assert!(harness.state().frame.texel.show_slices);
    // The overdraw view is every method's.
    assert_eq!(harness.state().frame.overdraw, None);
    harness.get_by_label("reads").click();
    harness.run();
    assert_eq!(
        harness.state().frame.overdraw,
        Some(canopy::render::overdraw::OverdrawView::Reads)
    );
}

#[test]
fn dragging_a_sun_slider_holds_the_sun_until_it_is_let_go() {
    let scene = Scene::default_scene();
    let state = State {
        frame: FrameDesc::from_scene(&scene),
        actions: PanelActions::default(),
    };
    let stats = PanelStats::default();
    let mut harness = tall().build_ui_state(
        move |ui, s: &mut State| {
            s.actions = controls(ui, &mut s.frame, &stats, None);
        },
        state,
    );
    harness.run();
    let start = harness.state().frame.sun;
    let slider = harness
        .get_by_role_and_label(egui::accesskit::Role::Slider, "time of day h")
        .rect();
    let at = slider.center();
    harness.drag_at(at);
    harness.run();
    harness.hover_at(at + egui::vec2(30.0, 0.0));
    harness.run();
    assert!(
        harness.state().actions.sun_held,
        "a drag in progress holds the sun"
    );
    assert_ne!(harness.state().frame.sun, start, "the drag moved the sun");
    harness.drop_at(at + egui::vec2(30.0, 0.0));
    harness.run();
    harness.run();
    assert!(!harness.state().actions.sun_held, "let go");
}

#[test]
fn the_frame_time_plot_shows_cpu_and_gpu_lines_and_the_bench_button_opens_the_window() {
    let scene = Scene::default_scene();
    let state = State {
        frame: FrameDesc::from_scene(&scene),
        actions: PanelActions::default(),
    };
    let mut with_gpu = PanelStats::default();
    for i in 0..400 {
        let mut passes = canopy::render::timing::PassTimes::default();
        passes.add("terrain", 1.0);
        passes.add("billboards", 4.0);
        with_gpu
            .history
            .push_with_passes(16.0 + f64::from(i % 7), Some(5.0), passes);
    }
    let mut harness = tall().build_ui_state(
        move |ui, s: &mut State| {
            let a = controls(ui, &mut s.frame, &with_gpu, None);
            if a.open_bench || a.open_file || a.open_example.is_some() {
                s.actions = a;
            }
        },
        state,
    );
    harness.run();
    // The legend's entries name the plot's lines.
    harness.get_by_label("CPU frame");
    harness.get_by_label("GPU frame");
    harness.get_by_label("most of the GPU frame: billboards (80 %)");
    assert!(!harness.state().actions.open_bench);
    harness.get_by_label("Bench results…").click();
    harness.run();
    assert!(harness.state().actions.open_bench);
    assert!(!harness.state().actions.open_file);
    harness.get_by_label("Open…").click();
    harness.run();
    assert!(harness.state().actions.open_file);
    // The scene menu lists the embedded examples; picking one asks to open it.
    assert_eq!(harness.state().actions.open_example, None);
    harness.get_by_label("Example scenes").click();
    harness.run();
    harness.get_by_label("default");
    harness.get_by_label("pines");
    harness.get_by_label("forest").click();
    harness.run();
    assert_eq!(harness.state().actions.open_example, Some("forest"));

    let mut cpu_only = PanelStats::default();
    cpu_only.history.push(16.0, None);
    let mut frame = FrameDesc::from_scene(&scene);
    let mut harness = tall().build_ui(move |ui| {
        controls(ui, &mut frame, &cpu_only, None);
    });
    harness.run();
    harness.get_by_label("CPU frame");
    assert!(
        harness
            .query_by_label_contains("most of the GPU frame")
            .is_none()
    );
    assert!(
        harness.query_by_label("GPU frame").is_none(),
        "no GPU times, no GPU line"
    );
}

#[test]
fn the_bench_window_shows_a_folders_table_or_what_is_missing() {
    let dir = std::env::temp_dir().join(format!("canopy-panel-bench-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let mut window = BenchWindow::default();
    window.open = true;
    window.folder = dir.display().to_string();
    let mut harness = tall().build_ui_state(
        |ui, w: &mut BenchWindow| {
            w.show(ui.ctx());
        },
        window,
    );
    harness.run();
    harness.get_by_label("Bench results");
    harness.get_by_label("Browse…");
    harness.get_by_label("Load").click();
    harness.run();
    harness.get_by_label_contains("does not exist");
    harness.get_by_label_contains("run `canopy bench --out");

    std::fs::create_dir_all(&dir).unwrap();
    image::RgbaImage::from_pixel(6, 4, image::Rgba([200, 40, 40, 255]))
        .save(dir.join("chart.png"))
        .unwrap();
    std::fs::write(
        dir.join("summary.json"),
        r#"{"scene": "s.toml", "flight": "walk", "frames": 2, "width": 96, "height": 64,
            "truth_supersample": 1, "repeats": 1, "device": "llvmpipe",
            "time_source": "cpu-wall-clock", "truth_rendered": 2, "truth_cached": 0,
            "seconds": 3.0, "configurations": [
            {"label": "billboard", "method": "billboard", "median_ms": 3.25,
             "median_prepare_ms": 0.5, "speedup_vs_geometry": 4.5,
             "mean_flip": 0.125, "p95_flip": 0.5, "flicker_ratio": 1.75,
             "worst_pop": null, "worst_frame": 1, "worst_frame_flip": 0.2}]}"#,
    )
    .unwrap();
    harness.get_by_label("Load").click();
    harness.run();
    assert!(
        harness.state().error().is_none(),
        "{:?}",
        harness.state().error()
    );
    assert!(harness.query_by_label_contains("does not exist").is_none());
    harness.get_by_label("billboard");
    harness.get_by_label("3.25");
    harness.get_by_label("4.50x");
    harness.get_by_label("0.1250");
    harness.get_by_label("1.75");
    harness.get_by_label("no flight.png in this folder");

    std::fs::write(dir.join("summary.json"), "not json").unwrap();
    harness.get_by_label("Load").click();
    harness.run();
    harness.get_by_label_contains("summary.json is not a bench summary");
    assert!(
        harness.query_by_label("billboard").is_none(),
        "a failed load clears the old table"
    );
    let _ = std::fs::remove_dir_all(&dir);
}

/// The species gallery asks for a picture of the chosen prototype once, shows its stats,
/// and asks again when another prototype is picked.
#[test]
fn the_species_gallery_asks_for_each_choice_once_and_shows_its_stats() {
    use canopy::app::gallery::{Choice, Gallery, PrototypeInfo};
    use canopy::render::Method;
    let scene = Scene::default_scene();
    let world = scene.build_world().expect("default world");
    let protos = PrototypeInfo::of_world(&world, &canopy::bake::cache::settings_of(&scene));
    assert_eq!(protos.len(), 2);
    assert_eq!(protos[0].trees + protos[1].trees, 1000);
    assert!(
        protos[0].baked_bytes > 1_000_000,
        "{}",
        protos[0].baked_bytes
    );
    struct G {
        gallery: Gallery,
        asked: Vec<Choice>,
    }
    let mut gallery = Gallery::default();
    gallery.open = true;
    let shown = protos.clone();
    let mut harness = tall().build_ui_state(
        move |ui, s: &mut G| {
            if let Some(want) = s.gallery.show(ui.ctx(), &shown) {
                s.asked.push(want);
                let img = image::RgbaImage::new(8, 8);
                s.gallery.set_picture(ui.ctx(), want, &img);
            }
        },
        G {
            gallery,
            asked: Vec::new(),
        },
    );
    harness.run();
    harness.get_by_label("Species gallery");
    let t = protos[0].triangles;
    harness.get_by_label(&format!("{} / {} / {}", t[0], t[1], t[2]));
    harness.get_by_label(&protos[0].trees.to_string());
    // The surfel tree's bytes, about (the default bake makes them).
    assert!(
        protos[0].surfel_bytes > 1_000_000,
        "{}",
        protos[0].surfel_bytes
    );
    harness.get_by_label(&format!("{:.1} MB", protos[0].surfel_bytes as f64 / 1e6));
    let asked = |prototype, method| Choice {
        prototype,
        distance: 50.0,
        method,
    };
    // One request for the first prototype at the default distance, however many frames.
    assert_eq!(harness.state().asked, vec![asked(0, Method::Geometry)]);
    // Picking the second prototype asks for it.
    harness.get_by_label("prototype").click();
    harness.run();
    harness.get_by_label(&protos[1].name).click();
    harness.run();
    assert_eq!(
        harness.state().asked,
        vec![asked(0, Method::Geometry), asked(1, Method::Geometry)]
    );
    let t = protos[1].triangles;
    harness.get_by_label(&format!("{} / {} / {}", t[0], t[1], t[2]));
    // Drawing it as surfels asks for that.
    harness.get_by_label("surfel").click();
    harness.run();
    assert_eq!(
        harness.state().asked.last(),
        Some(&asked(1, Method::Surfel))
    );
}
