//! The species gallery: a window showing one prototype of the scene (each species'
//! variants included) alone on flat ground, drawn as full geometry or as its surfel tree
//! from a chosen distance under the viewer's sun and sky, with its triangles per level and
//! what its bake holds. The picture is drawn once per choice, not every frame.

use glam::Vec3;
use image::RgbaImage;
use rayon::prelude::*;

use crate::Result;
use crate::model::{TreeModel, World};
use crate::render::{Camera, FrameDesc, GpuContext, Method, Renderer};

/// Size of the gallery's picture (pixels).
pub const PICTURE: (u32, u32) = (240, 300);
/// The distances the slider offers (m).
pub const DISTANCES: (f32, f32) = (5.0, 500.0);
/// The methods a prototype can be drawn with (neither needs a bake).
pub const METHODS: [Method; 2] = [Method::Geometry, Method::Surfel];

/// What the gallery draws: a prototype, from a distance, with a method.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Choice {
    pub prototype: usize,
    pub distance: f32,
    pub method: Method,
}

/// What the gallery lists of one prototype.
#[derive(Clone, Debug, PartialEq)]
pub struct PrototypeInfo {
    /// The prototype's name (`fir`, or `fir 2` for a species' second variant).
    pub name: String,
    /// Triangles of its twig, main branch and whole tree.
    pub triangles: [u64; 3],
    /// Trees of the scene drawn with it.
    pub trees: usize,
    /// Bytes its bake holds: BTF images of its three levels and the cube maps of its
    /// main branches and twigs.
    pub baked_bytes: u64,
    /// Bytes of its surfel tree in the bake, about (0: the bake makes none).
    pub surfel_bytes: u64,
    /// Side-view crown coverage (share of the crown's silhouette hull covered, mean of four
    /// azimuths; [`crate::model::silhouette`]).
    pub crown_coverage: f32,
    /// An imported tree's levels: where its file gives them, or why it has the tree level
    /// only.
    pub levels_note: Option<String>,
}

impl PrototypeInfo {
    /// The list for `world`, with the bake's sampling from `settings`.
    pub fn of_world(world: &World, settings: &crate::format::BakeSettings) -> Vec<PrototypeInfo> {
        let counts = world.forest.species_histogram(world.species.len());
        let vcm = crate::format::vcm_record_bytes(settings.vcm_resolution, settings.compress);
        world
            .species
            .par_iter()
            .zip(counts)
            .map(|(t, trees)| {
                let c = t.triangle_counts();
                let btf: u64 = crate::bake::baked_levels(t)
                    .iter()
                    .map(|&l| {
                        crate::format::btf_record_bytes(
                            settings.views_of(l),
                            settings.lights,
                            settings.resolution,
                            settings.compress,
                        )
                    })
                    .sum();
                let objects =
                    (t.tree_branches.len() + t.branch_twigs.len() + t.tree_twigs.len()) as u64;
                PrototypeInfo {
                    name: t.name.clone(),
                    triangles: [c.twig, c.branch, c.tree],
                    trees,
                    baked_bytes: btf + objects * vcm,
                    surfel_bytes: if settings.surfel_budget == 0 {
                        0
                    } else {
                        crate::bake::surfel::record_bytes(settings.surfel_budget)
                    },
                    crown_coverage: crate::model::silhouette::crown_coverage(t).mean,
                    levels_note: t.levels_note.clone(),
                }
            })
            .collect()
    }
}

/// The gallery window's state.
#[derive(Default)]
pub struct Gallery {
    /// Whether the window is open.
    pub open: bool,
    selected: usize,
    distance: Option<f32>,
    method: Option<Method>,
    /// The picture on show.
    shown: Option<egui::TextureHandle>,
    /// Why the last picture could not be drawn.
    error: Option<String>,
    /// The choice of the last picture drawn or tried.
    drawn_for: Option<Choice>,
}

impl Gallery {
    /// The prototype, distance and method chosen.
    pub fn choice(&self) -> Choice {
        Choice {
            prototype: self.selected,
            distance: self.distance.unwrap_or(50.0),
            method: self.method.unwrap_or(Method::Geometry),
        }
    }

    /// Forgets the picture (another scene is on show).
    pub fn reset(&mut self) {
        self.selected = 0;
        self.shown = None;
        self.error = None;
        self.drawn_for = None;
    }

    /// Shows `img`, drawn for `choice`.
    pub fn set_picture(&mut self, ctx: &egui::Context, choice: Choice, img: &RgbaImage) {
        let size = [img.width() as usize, img.height() as usize];
        self.shown = Some(ctx.load_texture(
            "species gallery",
            egui::ColorImage::from_rgba_unmultiplied(size, img.as_raw()),
            egui::TextureOptions::LINEAR,
        ));
        self.error = None;
        self.drawn_for = Some(choice);
    }

    /// Says why the picture for `choice` could not be drawn.
    pub fn set_error(&mut self, choice: Choice, error: String) {
        self.error = Some(error);
        self.drawn_for = Some(choice);
    }

    /// Draws the window when open. Returns the choice to draw when the picture on show is
    /// not of the current choice (and the slider is not being dragged).
    pub fn show(&mut self, ctx: &egui::Context, protos: &[PrototypeInfo]) -> Option<Choice> {
        if !self.open {
            return None;
        }
        let mut open = self.open;
        let mut settled = true;
        let mut distance = self.distance.unwrap_or(50.0);
        let mut method = self.method.unwrap_or(Method::Geometry);
        if self.selected >= protos.len() {
            self.selected = 0;
        }
        egui::Window::new("Species gallery")
            .open(&mut open)
            .resizable(false)
            .show(ctx, |ui| {
                if protos.is_empty() {
                    ui.label("this scene has no species");
                    return;
                }
                egui::ComboBox::from_label("prototype")
                    .selected_text(protos[self.selected].name.clone())
                    .show_ui(ui, |ui| {
                        for (i, p) in protos.iter().enumerate() {
                            ui.selectable_value(&mut self.selected, i, p.name.clone());
                        }
                    });
                let slider = ui.add(
                    egui::Slider::new(&mut distance, DISTANCES.0..=DISTANCES.1)
                        .logarithmic(true)
                        .suffix(" m")
                        .text("distance"),
                );
                settled = !slider.dragged();
                ui.horizontal(|ui| {
                    ui.label("drawn as");
                    for m in METHODS {
                        ui.selectable_value(&mut method, m, m.name());
                    }
                });
                match (&self.shown, &self.error) {
                    (_, Some(e)) => {
                        ui.colored_label(egui::Color32::from_rgb(230, 80, 70), e);
                    }
                    (Some(texture), None) => {
                        ui.add(
                            egui::Image::new(texture)
                                .fit_to_exact_size(egui::vec2(PICTURE.0 as f32, PICTURE.1 as f32)),
                        );
                    }
                    (None, None) => {
                        ui.label("drawing…");
                    }
                }
                let p = &protos[self.selected];
                egui::Grid::new("gallery stats")
                    .num_columns(2)
                    .show(ui, |ui| {
                        ui.label("triangles twig / branch / tree");
                        ui.label(format!(
                            "{} / {} / {}",
                            p.triangles[0], p.triangles[1], p.triangles[2]
                        ));
                        ui.end_row();
                        ui.label("trees in the scene");
                        ui.label(p.trees.to_string());
                        ui.end_row();
                        ui.label("baked (BTF + VCMs)");
                        ui.label(format!("{:.1} MB", p.baked_bytes as f64 / 1e6));
                        ui.end_row();
                        ui.label("surfel tree (about)");
                        ui.label(if p.surfel_bytes == 0 {
                            "none baked".to_string()
                        } else {
                            format!("{:.1} MB", p.surfel_bytes as f64 / 1e6)
                        });
                        ui.end_row();
                        ui.label("crown covered from the side");
                        ui.label(format!("{:.0} %", 100.0 * p.crown_coverage));
                        ui.end_row();
                    });
                if let Some(note) = &p.levels_note {
                    ui.label(format!("levels (imported): {note}"));
                }
            });
        self.open = open;
        self.distance = Some(distance);
        self.method = Some(method);
        let want = self.choice();
        (self.open && settled && !protos.is_empty() && self.drawn_for != Some(want)).then_some(want)
    }
}

/// Draws `tree` alone on flat ground from `distance` metres (a little above its middle,
/// looking at it) with `method` (one of [`METHODS`]: full geometry, or its surfel tree
/// sampled now), under the sun, sky and fog of `base`.
pub fn render_prototype(
    gpu: &GpuContext,
    tree: &TreeModel,
    base: &FrameDesc,
    distance: f32,
    method: Method,
) -> Result<RgbaImage> {
    let world = World::lone(tree.clone(), (4.0 * distance).clamp(60.0, 4000.0));
    let mut renderer = Renderer::new(gpu, &world)?;
    let b = &tree.tree_bounds;
    let target = Vec3::new(
        0.5 * (b.min.x + b.max.x),
        0.5 * (b.min.y + b.max.y),
        0.5 * (b.min.z + b.max.z),
    );
    let eye = target + Vec3::new(0.0, 0.15 * distance, -distance);
    let mut frame = *base;
    frame.method = method;
    frame.trees = true;
    frame.camera = Camera::look_at(eye, target, 40.0);
    frame.sun_held = false;
    renderer
        .render_image(gpu, &frame, PICTURE.0, PICTURE.1, 1)
        .map(|(img, _)| img)
}
