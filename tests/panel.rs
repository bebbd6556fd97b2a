//! The viewer's control panel, headless through egui_kittest: widgets are found by label,
//! clicked, and the frame description and requested actions change accordingly.

use canopy::app::panel::{PanelActions, PanelStats, controls};
use canopy::render::FrameDesc;
use canopy::scene::Scene;
use egui_kittest::Harness;
use egui_kittest::kittest::Queryable;

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
    let mut harness = Harness::new_ui_state(
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
