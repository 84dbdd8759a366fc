//! The sRGB transfer function, both ways: colour bytes in PLY, PNG and
//! glTF are sRGB-encoded; averaging, lighting and glTF's `COLOR_0` are
//! linear. One copy for the viewer, the glTF reader and writer, and the
//! texture painter.

/// Linear (0 to 1, clamped) to sRGB-encoded.
pub fn linear_to_srgb(c: f64) -> f64 {
    let c = c.clamp(0.0, 1.0);
    if c <= 0.003_130_8 {
        12.92 * c
    } else {
        1.055 * c.powf(1.0 / 2.4) - 0.055
    }
}

/// sRGB-encoded (0 to 1, clamped) to linear.
pub fn srgb_to_linear(c: f64) -> f64 {
    let c = c.clamp(0.0, 1.0);
    if c <= 0.04045 {
        c / 12.92
    } else {
        ((c + 0.055) / 1.055).powf(2.4)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_byte_round_trips() {
        for b in 0..=255u32 {
            let c = b as f64 / 255.0;
            assert_eq!((linear_to_srgb(srgb_to_linear(c)) * 255.0).round() as u32, b);
        }
        assert_eq!(srgb_to_linear(2.0), 1.0);
        assert_eq!(linear_to_srgb(-1.0), 0.0);
    }
}
