//! How many slices a volumetric texel needs (Meyer-Neyret 1998 as Babahenini et al. state
//! it; ../shared/seeds/DIGEST.md section 7). With `a` the angle between the view ray and
//! the slices' normal, `H` the texel's height along that normal, `Z` its depth and `F` the
//! focal length in pixels:
//!
//! - C1: the visible depth between slices, d = H·tan(a)/n metres, seen at depth Z, stays
//!   under `d0` pixels on screen: n > F·H·tan(a)/(Z·d0). The seeds bound d in metres; a
//!   bound in metres never falls with distance, so a texel far away, a few pixels tall, got
//!   as many slices as one nearby. Measured on the screen, C1 follows the texel's size
//!   there, as C2 does.
//! - C2: the projected spacing between slices, l = F·(H/n)·sin(a)/Z, stays under `d1`
//!   pixels: n > F·H·sin(a)/(Z·d1).
//!
//! n = max(C1, C2), capped, rounded up to a power of two for the pre-composited levels.
//! C1 (tan) exceeds C2 (sin) as the view grazes the stack.
//!
//! Slices parallel to the screen (Decaudin-Neyret 2009) have no angle: every gap between
//! two slices is seen end-on, as depth. A box `D` metres deep along the view at distance Z
//! gets n > F·D/(Z·d0) slices (C1) and n > F·D/(Z·d1) (C2, a gap seen as if it were across
//! the screen, the worst case of sin(a) = 1): the tighter of the two bounds rules.

/// The knobs of both criteria.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct SliceBounds {
    /// Largest visible depth between slices, in pixels on screen.
    pub d0: f32,
    /// Largest projected spacing between slices (pixels).
    pub d1: f32,
    /// Most slices a texel may use.
    pub max_slices: u32,
}

impl Default for SliceBounds {
    fn default() -> Self {
        Self {
            d0: 2.0,
            d1: 2.0,
            max_slices: 128,
        }
    }
}

impl SliceBounds {
    /// Knobs brought into their valid ranges (d0 and d1 above zero, at least one slice).
    pub fn sanitized(self) -> Self {
        let pos = |v: f32, default: f32| if v.is_finite() && v > 0.0 { v } else { default };
        let d = Self::default();
        Self {
            d0: pos(self.d0, d.d0),
            d1: pos(self.d1, d.d1),
            max_slices: self.max_slices.clamp(1, 1024),
        }
    }
}

/// C1: slices a stack of height `h` at depth `z`, seen at `angle` (radians, from its
/// normal) through a focal length of `focal_px` pixels, needs so that the visible depth
/// between slices stays under `d0` pixels.
pub fn c1(focal_px: f32, h: f32, angle: f32, z: f32, d0: f32) -> f32 {
    focal_px * h * angle.tan().abs() / (z.max(1e-3) * d0)
}

/// C2: slices so that the projected spacing stays under `d1` pixels, for a stack of
/// height `h` at depth `z`, seen at `angle`, through a focal length of `focal_px` pixels.
pub fn c2(focal_px: f32, h: f32, angle: f32, z: f32, d1: f32) -> f32 {
    focal_px * h * angle.sin().abs() / (z.max(1e-3) * d1)
}

/// The seeds' slice count for a stack: max(C1, C2), at least 1, rounded up to a power of
/// two and capped at `bounds.max_slices` (itself taken down to a power of two).
pub fn stack_slices(focal_px: f32, h: f32, angle: f32, z: f32, bounds: &SliceBounds) -> u32 {
    let b = bounds.sanitized();
    let n = c1(focal_px, h, angle, z, b.d0).max(c2(focal_px, h, angle, z, b.d1));
    let cap = 1u32 << b.max_slices.ilog2();
    ceil_pow2(n).min(cap)
}

/// Slices parallel to the screen through a box `depth` metres deep along the view, at
/// distance `z`: F·D/(Z·min(d0, d1)), at least 1, capped (not rounded: no pre-composited
/// levels are needed).
pub fn screen_slices(focal_px: f32, depth: f32, z: f32, bounds: &SliceBounds) -> u32 {
    let b = bounds.sanitized();
    let n = focal_px * depth / (z.max(1e-3) * b.d0.min(b.d1));
    if !n.is_finite() {
        return b.max_slices;
    }
    (n.ceil() as u32).clamp(1, b.max_slices)
}

/// The smallest power of two at or above `n` (1 for n <= 1, saturating).
pub fn ceil_pow2(n: f32) -> u32 {
    if n.is_nan() || n <= 1.0 {
        return 1;
    }
    if n >= (1u32 << 31) as f32 {
        return 1 << 31;
    }
    (n.ceil() as u32).next_power_of_two()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn close(a: f32, b: f32) -> bool {
        (a - b).abs() <= 1e-4 * b.abs().max(1.0)
    }

    #[test]
    fn c1_and_c2_give_the_hand_computed_counts() {
        // A 10 m stack at 45 degrees (tan = 1), 100 m away through F = 500 px: its depth
        // spans 500 * 10 / 100 = 50 px, so 50 / 2.5 = 20 slices for d0 = 2.5 px.
        assert!(close(c1(500.0, 10.0, 45f32.to_radians(), 100.0, 2.5), 20.0));
        // At 60 degrees tan = sqrt(3): 50 * 1.732 / 2.5 = 34.64.
        assert!(close(
            c1(500.0, 10.0, 60f32.to_radians(), 100.0, 2.5),
            34.641
        ));
        // F = 500 px, H = 10 m, a = 30 degrees (sin 0.5), Z = 100 m, d1 = 2 px:
        // 500 * 10 * 0.5 / (100 * 2) = 12.5.
        assert!(close(c2(500.0, 10.0, 30f32.to_radians(), 100.0, 2.0), 12.5));
        // Seen straight along the normal, neither needs more than one slice.
        assert_eq!(c1(500.0, 10.0, 0.0, 100.0, 2.5), 0.0);
        assert_eq!(c2(500.0, 10.0, 0.0, 100.0, 2.0), 0.0);
        let b = SliceBounds {
            d0: 2.5,
            d1: 2.0,
            max_slices: 256,
        };
        // max(34.64, 500*10*0.866/(100*2) = 21.65) = 34.64 -> 64.
        assert_eq!(stack_slices(500.0, 10.0, 60f32.to_radians(), 100.0, &b), 64);
        assert_eq!(stack_slices(500.0, 10.0, 0.0, 100.0, &b), 1);
    }

    #[test]
    fn counts_grow_as_the_view_grazes_and_are_capped() {
        let b = SliceBounds {
            d0: 2.0,
            d1: 2.0,
            max_slices: 100,
        };
        let mut last = 0;
        for deg in [0.0f32, 20.0, 40.0, 50.0, 54.7] {
            let n = stack_slices(800.0, 12.0, deg.to_radians(), 60.0, &b);
            assert!(n >= last, "{deg} degrees: {n} after {last}");
            last = n;
        }
        // Near grazing, C1 explodes; the cap (taken down to a power of two) holds.
        assert_eq!(stack_slices(800.0, 12.0, 89f32.to_radians(), 60.0, &b), 64);
        // Nearer texels need more slices, farther ones fewer.
        let near = screen_slices(800.0, 8.0, 20.0, &SliceBounds::default());
        let far = screen_slices(800.0, 8.0, 400.0, &SliceBounds::default());
        assert!(near > far, "{near} vs {far}");
        // 8 m deep at 20 m: 800*8/(20*2) = 160, capped at 128.
        assert_eq!(near, 128);
        // At 400 m: 800*8/(400*2) = 8.
        assert_eq!(far, 8);
    }

    #[test]
    fn the_slice_count_falls_with_distance_at_fixed_knobs() {
        // An 18 m deep crown through F = 312 px (640x360, 60 degrees): as a tree recedes,
        // its count follows its size on screen down to one slice.
        let b = SliceBounds::default();
        let counts: Vec<u32> = [25.0, 50.0, 100.0, 200.0, 400.0, 700.0, 1400.0, 3000.0]
            .iter()
            .map(|z| screen_slices(312.0, 18.0, *z, &b))
            .collect();
        assert!(
            counts.windows(2).all(|w| w[1] < w[0] || w[1] == 1),
            "{counts:?}"
        );
        assert_eq!(counts[5], 5, "312*18/(700*2) = 4.01: 5 slices at 700 m");
        assert_eq!(*counts.last().unwrap(), 1);
        // The same holds for the axis stacks at any angle short of grazing.
        for deg in [10.0f32, 45.0, 70.0] {
            let a = deg.to_radians();
            let near = stack_slices(312.0, 18.0, a, 50.0, &b);
            let far = stack_slices(312.0, 18.0, a, 700.0, &b);
            assert!(far < near, "{deg}: {far} vs {near}");
        }
        // The tighter bound rules: halving d0 below d1 doubles the count.
        let tight = SliceBounds { d0: 1.0, ..b };
        assert_eq!(screen_slices(312.0, 18.0, 100.0, &tight), 57);
        assert_eq!(screen_slices(312.0, 18.0, 100.0, &b), 29);
    }

    #[test]
    fn powers_of_two_round_up() {
        assert_eq!(ceil_pow2(0.0), 1);
        assert_eq!(ceil_pow2(f32::NAN), 1);
        assert_eq!(ceil_pow2(1.0), 1);
        assert_eq!(ceil_pow2(1.01), 2);
        assert_eq!(ceil_pow2(16.0), 16);
        assert_eq!(ceil_pow2(17.0), 32);
        assert_eq!(ceil_pow2(f32::INFINITY), 1 << 31);
    }

    #[test]
    fn bad_knobs_fall_back_to_valid_ones() {
        let b = SliceBounds {
            d0: 0.0,
            d1: f32::NAN,
            max_slices: 0,
        }
        .sanitized();
        assert_eq!(b.d0, SliceBounds::default().d0);
        assert_eq!(b.d1, SliceBounds::default().d1);
        assert_eq!(b.max_slices, 1);
        assert_eq!(screen_slices(800.0, f32::INFINITY, 10.0, &b), 1);
    }
}
