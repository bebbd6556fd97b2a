//! Flicker along a flight. Between consecutive frames the picture changes because the
//! camera or the sun moved; the truth changes by exactly that much. What a stand-in changes
//! beyond it (a LOD switch, an image swap, a shadow that jumps) is flicker. Both changes are
//! measured as FLIP between frame i-1 and frame i: `method[k]` and `truth[k]` hold that for
//! frame i = k + 1.

use crate::{Error, Result};

/// Added to both means of the flicker ratio, so that a still truth (mean 0) gives a finite
/// ratio: 1 when the method is still too, large when it is not. Far below the FLIP of any
/// visible change, so it does not move ratios of moving flights.
pub const RATIO_FLOOR: f64 = 1e-4;

/// The largest flicker excess of a flight and where it happened.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Pop {
    /// The frame (index into the flight, >= 1) that differs too much from the one before.
    pub frame: usize,
    /// Its excess: method change minus the truth's change scaled to the method's usual
    /// level (FLIP; see [`flicker`]).
    pub excess: f64,
}

/// The temporal summary of one configuration along one flight.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct Flicker {
    /// Per frame i >= 1 (element k is frame k + 1): method change minus truth change.
    /// Negative where the method changes less than the truth (it smooths).
    pub excess: Vec<f64>,
    /// Mean frame-to-frame FLIP of the method.
    pub mean_method: f64,
    /// Mean frame-to-frame FLIP of the truth.
    pub mean_truth: f64,
    /// (mean_method + RATIO_FLOOR) / (mean_truth + RATIO_FLOOR): 1 means the method changes
    /// as much as the truth does, 2 twice as much.
    pub ratio: f64,
    /// The largest excess (the first of equals); none for a flight of fewer than 2 frames.
    pub worst_pop: Option<Pop>,
}

/// Per-frame flicker excess `method[k] - truth[k]`.
pub fn flicker_excess(method: &[f64], truth: &[f64]) -> Result<Vec<f64>> {
    if method.len() != truth.len() {
        return Err(Error::BadInput(format!(
            "flicker: {} frame-to-frame FLIP values for the method but {} for the truth; \
             both must come from the same flight",
            method.len(),
            truth.len()
        )));
    }
    if let Some((k, v)) = method
        .iter()
        .chain(truth)
        .enumerate()
        .find(|(_, v)| !v.is_finite() || **v < 0.0)
    {
        let which = if k < method.len() { "method" } else { "truth" };
        let frame = k % method.len().max(1) + 1;
        return Err(Error::BadInput(format!(
            "flicker: the {which}'s FLIP at frame {frame} is {v}; FLIP values are finite and >= 0"
        )));
    }
    Ok(method.iter().zip(truth).map(|(m, t)| m - t).collect())
}

/// The flicker summary of a configuration from its frame-to-frame FLIP and the truth's.
///
/// The worst pop is judged on the truth's change scaled to the method's usual level:
/// `method[k] - truth[k] * median(method) / median(truth)`. The raw excess would hide every
/// pop of a method smoother than the truth: geometry's needles sparkle from frame to frame
/// (on the BTF stand at 128x128, in 0.5 % dolly steps, the truth changes by 0.020 a frame,
/// btf by 0.009 and by 0.018 at an abrupt level switch, a raw excess of -0.002).
pub fn flicker(method: &[f64], truth: &[f64]) -> Result<Flicker> {
    let excess = flicker_excess(method, truth)?;
    let median = |v: &[f64]| {
        let mut v = v.to_vec();
        v.sort_by(f64::total_cmp);
        v.get(v.len() / 2).copied().unwrap_or(0.0)
    };
    let scale = (median(method) + RATIO_FLOOR) / (median(truth) + RATIO_FLOOR);
    let scaled: Vec<f64> = method
        .iter()
        .zip(truth)
        .map(|(m, t)| m - t * scale)
        .collect();
    let mean = |v: &[f64]| {
        if v.is_empty() {
            0.0
        } else {
            v.iter().sum::<f64>() / v.len() as f64
        }
    };
    let (mean_method, mean_truth) = (mean(method), mean(truth));
    let worst_pop = scaled
        .iter()
        .enumerate()
        .fold(None::<Pop>, |best, (k, &e)| match best {
            Some(b) if b.excess >= e => Some(b),
            _ => Some(Pop {
                frame: k + 1,
                excess: e,
            }),
        });
    Ok(Flicker {
        excess,
        mean_method,
        mean_truth,
        ratio: (mean_method + RATIO_FLOOR) / (mean_truth + RATIO_FLOOR),
        worst_pop,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn smooth(n: usize) -> Vec<f64> {
        (0..n)
            .map(|k| 0.05 + 0.01 * (k as f64 * 0.7).sin())
            .collect()
    }

    #[test]
    fn identical_sequences_have_no_excess_and_ratio_one() {
        let t = smooth(20);
        let f = flicker(&t, &t).unwrap();
        assert!(f.excess.iter().all(|&e| e == 0.0));
        assert_eq!(f.excess.len(), 20);
        assert!((f.ratio - 1.0).abs() < 1e-12, "{}", f.ratio);
        assert_eq!(f.mean_method, f.mean_truth);
    }

    #[test]
    fn one_injected_pop_is_the_worst_pop_at_its_frame() {
        let t = smooth(30);
        let mut m: Vec<f64> = t.iter().map(|v| v + 0.002).collect();
        m[11] += 0.25;
        let f = flicker(&m, &t).unwrap();
        let pop = f.worst_pop.unwrap();
        assert_eq!(pop.frame, 12, "element 11 is the change into frame 12");
        assert!((pop.excess - 0.25).abs() < 0.005, "{pop:?}");
        assert!(f.ratio > 1.1, "{}", f.ratio);
    }

    #[test]
    fn a_pop_of_a_method_smoother_than_the_truth_is_found() {
        // The truth sparkles at 0.02 a frame, the method changes 0.009 and pops to 0.018:
        // a raw excess of -0.002, the pop still stands out against the scaled truth.
        let t: Vec<f64> = (0..16)
            .map(|k| 0.02 + 0.001 * ((k * 7) % 3) as f64)
            .collect();
        let mut m: Vec<f64> = t.iter().map(|v| v * 0.45).collect();
        m[8] = 0.018;
        let f = flicker(&m, &t).unwrap();
        assert!(f.excess[8] < 0.0, "the raw excess misses it");
        let pop = f.worst_pop.unwrap();
        assert_eq!(pop.frame, 9);
        assert!(pop.excess > 0.008, "{pop:?}");
    }

    #[test]
    fn a_still_truth_gives_a_finite_ratio() {
        let still = vec![0.0; 5];
        assert_eq!(flicker(&still, &still).unwrap().ratio, 1.0);
        let r = flicker(&[0.0, 0.01, 0.0, 0.0, 0.0], &still).unwrap().ratio;
        assert!(r.is_finite() && r > 10.0, "{r}");
    }

    #[test]
    fn a_method_smoother_than_the_truth_has_negative_excess() {
        let t = smooth(8);
        let m: Vec<f64> = t.iter().map(|v| v * 0.5).collect();
        let f = flicker(&m, &t).unwrap();
        assert!(f.excess.iter().all(|&e| e < 0.0));
        assert!(f.ratio < 0.6 && f.ratio > 0.4, "{}", f.ratio);
    }

    #[test]
    fn mismatched_or_bad_input_is_an_error_not_a_number() {
        let e = flicker(&[0.1, 0.2], &[0.1]).unwrap_err().to_string();
        assert!(
            e.contains("2") && e.contains("1") && e.contains("same flight"),
            "{e}"
        );
        let e = flicker(&[0.1, f64::NAN], &[0.1, 0.1])
            .unwrap_err()
            .to_string();
        assert!(e.contains("method") && e.contains("frame 2"), "{e}");
        let e = flicker(&[0.1, 0.1], &[0.1, -1.0]).unwrap_err().to_string();
        assert!(e.contains("truth") && e.contains("frame 2"), "{e}");
        assert!(flicker(&[], &[]).unwrap().worst_pop.is_none());
    }
}
