//! The display transform for previews (PNG) and for the paper's image metrics.
//!
//! Operator: multiply by `exposure`, clamp to [0, 1], apply the sRGB transfer function
//! (IEC 61966-2-1), quantise to 8 bits with rounding. NaN maps to 0. It clips highlights, as the
//! paper's "tone mapped images ... in the range [0, 255]" do; the EXR keeps the linear values.

/// sRGB encoding of a linear value in [0, 1].
pub fn srgb_encode(v: f32) -> f32 {
    if v <= 0.003_130_8 {
        12.92 * v
    } else {
        1.055 * v.powf(1.0 / 2.4) - 0.055
    }
}

/// Linear radiance to an 8-bit display value.
pub fn tonemap_u8(v: f32, exposure: f32) -> u8 {
    let x = v * exposure;
    let x = if x.is_nan() { 0.0 } else { x.clamp(0.0, 1.0) };
    (srgb_encode(x) * 255.0).round() as u8
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tonemap_is_monotone_clamped_and_safe() {
        assert_eq!(tonemap_u8(0.0, 1.0), 0);
        assert_eq!(tonemap_u8(1.0, 1.0), 255);
        assert_eq!(tonemap_u8(1e30, 1.0), 255);
        assert_eq!(tonemap_u8(f32::INFINITY, 1.0), 255);
        assert_eq!(tonemap_u8(-3.0, 1.0), 0);
        assert_eq!(tonemap_u8(f32::NAN, 1.0), 0);
        assert_eq!(tonemap_u8(0.215_861, 1.0), 128); // sRGB 128/255
        let mut last = 0;
        for i in 0..=1000 {
            let t = tonemap_u8(i as f32 / 1000.0, 1.0);
            assert!(t >= last);
            last = t;
        }
    }
}
