//! The sRGB transfer function both ways, per 8-bit channel: what the renderer's read-back,
//! the bakes' CPU filtering and the image metrics share.

/// [`srgb_to_linear`] of every byte, for decoding many pixels.
pub fn srgb_lut() -> Vec<f32> {
    (0..=255u8).map(srgb_to_linear).collect()
}

/// An sRGB-encoded channel as a linear value in 0..=1.
pub fn srgb_to_linear(c: u8) -> f32 {
    let c = f32::from(c) / 255.0;
    if c <= 0.04045 {
        c / 12.92
    } else {
        ((c + 0.055) / 1.055).powf(2.4)
    }
}

/// A linear value (clamped to 0..=1) as an sRGB-encoded channel, rounded to nearest.
pub fn linear_to_srgb(c: f32) -> u8 {
    let c = c.clamp(0.0, 1.0);
    let s = if c <= 0.003_130_8 {
        c * 12.92
    } else {
        1.055 * c.powf(1.0 / 2.4) - 0.055
    };
    (s * 255.0 + 0.5) as u8
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_transfer_functions_invert_each_other_on_every_byte() {
        for b in 0..=255u8 {
            assert_eq!(linear_to_srgb(srgb_to_linear(b)), b);
        }
        assert_eq!(srgb_to_linear(0), 0.0);
        assert_eq!(srgb_to_linear(255), 1.0);
        // Mid grey: sRGB 188 is about half the light of white.
        assert!((srgb_to_linear(188) - 0.5029).abs() < 1e-3);
        assert_eq!(srgb_lut()[188], srgb_to_linear(188));
    }
}
