//! A map of a scene seen from straight above (`canopy info --map`): the terrain shaded by
//! height and slope, the stands, clearings and meadows of `[forest.stands]`, and every tree
//! as a disc of its crown's size in its species' colour. Drawn on the CPU from the model
//! alone, so it needs no GPU and no bake: the quickest way to see where a forest stands.

use glam::Vec3;
use image::{Rgba, RgbaImage};

use crate::model::stands::{Cover, StandMap, height_range, normalise};
use crate::model::{ForestParams, SpeciesEntry, World};

/// Largest map side in pixels.
pub const MAX_MAP_SIZE: u32 = 8192;

/// Crown colours, by species index (cycled).
const SPECIES_COLOURS: [[u8; 3]; 6] = [
    [24, 70, 40],   // dark blue-green: the first species (a conifer in the examples)
    [120, 170, 50], // light yellow-green: the second (a broadleaf)
    [60, 120, 120], // teal: the third (a pine)
    [200, 120, 40],
    [40, 120, 180],
    [200, 200, 60],
];

/// Draws the map of `world`, built from the scene's `species` entries and placed by
/// `forest`, `size` pixels a side (north up, east right). The variants of a species share
/// its colour.
pub fn draw(
    world: &World,
    species: &[SpeciesEntry],
    forest: &ForestParams,
    size: u32,
) -> RgbaImage {
    let size = size.clamp(16, MAX_MAP_SIZE);
    // The species entry of each prototype (the variants of an entry follow each other).
    let entry_of: Vec<usize> = species
        .iter()
        .enumerate()
        .flat_map(|(i, e)| std::iter::repeat_n(i, e.prototypes() as usize))
        .collect();
    let t = &world.terrain;
    let half = 0.5 * t.size;
    let px = t.size / size as f32;
    let stands = forest
        .stands
        .as_ref()
        .filter(|_| forest.density.is_some())
        .map(|st| StandMap::build(st, forest.seed, t));
    let (lo, hi) = height_range(t);
    let light = Vec3::new(-1.0, 1.5, 1.0).normalize(); // from the north-west
    let world_of = |i: u32, j: u32| {
        // Row 0 is the north edge (+Z).
        (-half + (i as f32 + 0.5) * px, half - (j as f32 + 0.5) * px)
    };
    let mut img = RgbaImage::from_fn(size, size, |i, j| {
        let (x, z) = world_of(i, j);
        let h = normalise(t.height_at(x, z), lo, hi);
        let shade = 0.55 + 0.45 * t.normal_at(x, z).dot(light).max(0.0);
        let low = Vec3::new(0.36, 0.45, 0.25);
        let high = Vec3::new(0.62, 0.62, 0.45);
        let mut c = low.lerp(high, h);
        if let Some(m) = &stands {
            c = match m.cover_at(x, z) {
                Cover::Meadow => Vec3::new(0.72, 0.78, 0.38),
                Cover::Clearing => c,
                // The stand's floor, darker where the density is full.
                Cover::Stand => c.lerp(Vec3::new(0.25, 0.32, 0.2), 0.5 * m.factor_at(x, z)),
            };
        }
        let c = (c * shade * 255.0).clamp(Vec3::ZERO, Vec3::splat(255.0));
        Rgba([c.x as u8, c.y as u8, c.z as u8, 255])
    });
    // Crowns: discs of the prototype's half width, scaled.
    for tree in &world.forest.instances {
        let Some(proto) = world.species.get(tree.species as usize) else {
            continue;
        };
        let b = &proto.tree_bounds;
        let r_m = 0.25 * ((b.max.x - b.min.x) + (b.max.z - b.min.z)) * tree.scale;
        let r = (r_m / px).max(0.7);
        let cx = (tree.position.x + half) / px;
        let cy = (half - tree.position.z) / px;
        let entry = entry_of.get(tree.species as usize).copied().unwrap_or(0);
        let col = SPECIES_COLOURS[entry % SPECIES_COLOURS.len()];
        let (x0, x1) = (
            (cx - r).floor().max(0.0),
            (cx + r).ceil().min(size as f32 - 1.0),
        );
        let (y0, y1) = (
            (cy - r).floor().max(0.0),
            (cy + r).ceil().min(size as f32 - 1.0),
        );
        if x1 < x0 || y1 < y0 {
            continue;
        }
        for y in y0 as u32..=y1 as u32 {
            for x in x0 as u32..=x1 as u32 {
                let d = ((x as f32 + 0.5 - cx).powi(2) + (y as f32 + 0.5 - cy).powi(2)).sqrt();
                if d > r {
                    continue;
                }
                // Lit from the north-west, darker at the rim.
                let lit = 0.75
                    + 0.35 * (1.0 - d / r)
                    + 0.15 * ((cx - x as f32) - (cy - y as f32)) / r.max(1.0);
                let p = img.get_pixel_mut(x, y);
                for k in 0..3 {
                    p[k] = (f32::from(col[k]) * lit).clamp(0.0, 255.0) as u8;
                }
            }
        }
    }
    img
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::{SpeciesEntry, StandParams, TerrainParams};

    #[test]
    fn trees_show_where_they_stand() {
        let terrain = TerrainParams {
            size: 200.0,
            resolution: 33,
            relief: 10.0,
            ..TerrainParams::default()
        };
        let species = [SpeciesEntry::from_preset("fir", "fir", 1)];
        let forest = ForestParams {
            count: None,
            density: Some(100.0),
            min_spacing: 4.0,
            mix: vec![1.0],
            stands: Some(StandParams {
                cover: 0.5,
                size: 80.0,
                ..StandParams::default()
            }),
            ..ForestParams::default()
        };
        let world = match World::build(&terrain, &species, &forest) {
            Ok(w) => w,
            Err(e) => panic!("{e}"),
        };
        let img = draw(&world, &species, &forest, 200);
        assert_eq!(img.dimensions(), (200, 200));
        // Every trunk's pixel is crown-coloured (dark green, blue above red).
        let mut crowns = 0;
        for t in &world.forest.instances {
            let x = (t.position.x + 100.0) as u32;
            let y = (100.0 - t.position.z) as u32;
            let p = img.get_pixel(x.min(199), y.min(199));
            if p[1] < 120 && p[2] > p[0] {
                crowns += 1;
            }
        }
        let n = world.forest.instances.len();
        assert!(n > 50 && crowns == n, "{crowns} of {n}");
    }
}
