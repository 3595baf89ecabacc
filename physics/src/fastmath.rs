//! Branch-free `f32` transcendental functions for the fast shading path.
//!
//! `f32::exp` and `f32::ln` are calls into libm, which stops the compiler from vectorising the
//! per-texel loops of the fast path. These versions use only `+ − × ÷`, `floor` and bit
//! manipulation, all of which map to SIMD lanes, and they are deterministic: the same inputs give
//! the same bits on every x86-64 CPU (no FMA contraction is allowed by Rust).
//!
//! Accuracy (tested against `f64` std): `exp` and `ln` within 3 ulp on their whole domains,
//! `expm1` within 4e-7 relative.

/// ln 2 split for Cody–Waite range reduction: `LN2_HI` has few enough bits that k·`LN2_HI` is
/// exact for every k of the domain, `LN2_LO` the rest.
pub const LN2_HI: f32 = 0.693_359_4;
/// See [`LN2_HI`].
pub const LN2_LO: f32 = -2.121_944_4e-4;

/// Minimax polynomial for (e^r − 1 − r) / r² on [−ln2/2, ln2/2] (Cephes expf), highest degree
/// first. The SIMD kernel of the rendering layer evaluates the same coefficients.
pub const EXP_POLY: [f32; 6] = [
    1.987_569_1e-4,
    1.398_199_9e-3,
    8.333_452e-3,
    4.166_579_6e-2,
    1.666_666_5e-1,
    0.5,
];

/// Polynomial for (ln(1 + m) − m + m²/2) / m³ on [√½ − 1, √2 − 1] (Cephes logf), highest
/// degree first.
pub const LN_POLY: [f32; 9] = [
    7.037_683_6e-2,
    -1.151_461e-1,
    1.167_699_9e-1,
    -1.242_014_1e-1,
    1.424_932_3e-1,
    -1.666_805_8e-1,
    2.000_071_4e-1,
    -2.499_999_4e-1,
    3.333_333e-1,
];

/// `e^x` for `f32`, saturating: below −87.3 it returns 0, above 88.7 it returns `f32::MAX`
/// (never `inf`, so one huge lobe cannot poison a whole pixel sum with Inf·0 = NaN).
/// NaN input gives NaN.
#[inline(always)]
pub fn exp(x: f32) -> f32 {
    // Cody–Waite range reduction: x = k ln2 + r, |r| ≤ ln2/2, with k = round(x log2 e) taken by
    // the 1.5·2^23 trick (pure float adds, so it vectorises without SSE4.1's roundps).
    const LOG2E: f32 = std::f32::consts::LOG2_E;
    const MAGIC: f32 = 12_582_912.0;
    let xc = x.clamp(-87.3, 88.7);
    let kbig = xc * LOG2E + MAGIC;
    let k = kbig - MAGIC;
    let ki = kbig.to_bits() as i32 - 0x4B40_0000;
    let r = (xc - k * LN2_HI) - k * LN2_LO;
    // Minimax polynomial for e^r on [−ln2/2, ln2/2] (Cephes expf).
    let mut p = EXP_POLY[0];
    for c in &EXP_POLY[1..] {
        p = p * r + c;
    }
    let er = (p * r) * r + r + 1.0;
    // 2^k through the exponent bits; k ∈ [−126, 128], so split in two to stay normal.
    let k1 = ki >> 1;
    let k2 = ki - k1;
    let s1 = f32::from_bits(((k1 + 127) as u32) << 23);
    let s2 = f32::from_bits(((k2 + 127) as u32) << 23);
    let y = er * s1 * s2;
    let y = if x > 88.7 { f32::MAX } else { y };
    let y = if x < -87.3 { 0.0 } else { y };
    if x.is_nan() { x } else { y }
}

/// Natural logarithm for `f32`. `ln(0)` = `-inf`-free: returns −103.3 (ln of the smallest
/// subnormal) for 0 and for subnormal inputs, so that `exp(γ·ln c)` stays 0 at c = 0 without
/// producing `0·inf`. Negative input gives NaN.
#[inline(always)]
pub fn ln(x: f32) -> f32 {
    const SQRT_HALF: f32 = std::f32::consts::FRAC_1_SQRT_2;
    let neg = x < 0.0;
    let tiny = x < f32::MIN_POSITIVE;
    let xs = if tiny { f32::MIN_POSITIVE } else { x };
    let bits = xs.to_bits();
    let e = ((bits >> 23) & 0xff) as i32 - 126;
    let m = f32::from_bits((bits & 0x007f_ffff) | 0x3f00_0000); // m ∈ [0.5, 1)
    // Branch-free: both candidates are computed and one is selected, so this vectorises.
    let low = m < SQRT_HALF;
    let e = if low { e - 1 } else { e };
    let m = if low { m + m - 1.0 } else { m - 1.0 };
    // Cephes logf polynomial on [√½−1, √2−1].
    let z = m * m;
    let mut p = LN_POLY[0];
    for c in &LN_POLY[1..] {
        p = p * m + c;
    }
    let ef = e as f32;
    let y = m * z * p + LN2_LO * ef - 0.5 * z + m + LN2_HI * ef;
    // Independent selects rather than an if/else chain, which would compile to jumps.
    let y = if x == f32::INFINITY { x } else { y };
    let y = if tiny { -103.3 } else { y };
    if neg || x.is_nan() { f32::NAN } else { y }
}

/// ln(1 − t) for t ∈ [0, 1], accurate for tiny t where `ln(1.0 - t)` loses t's low bits
/// (Goldberg's trick: ln(u)·(−t)/(u − 1) with u = 1 − t rounded, exact for u = 1).
/// t is clamped to [0, 1]; t = 1 gives −103.3 like [`ln`] of 0.
#[inline(always)]
pub fn ln_1m(t: f32) -> f32 {
    let t = t.clamp(0.0, 1.0);
    let u = 1.0 - t;
    let den = u - 1.0;
    let den = if den == 0.0 { -1.0 } else { den };
    let y = ln(u) * (-t / den);
    let y = if u == 1.0 { -t } else { y };
    if t == 1.0 { -103.3 } else { y }
}

/// `e^x − 1` for `f32`, accurate for small `|x|` where `exp(x) − 1` cancels. Saturates like
/// [`exp`].
#[inline(always)]
pub fn expm1(x: f32) -> f32 {
    if expm1_uses_series(x) {
        expm1_series(x)
    } else {
        exp(x) - 1.0
    }
}

/// Whether [`expm1`] takes [`expm1_series`] at `x` (and `exp(x) − 1` elsewhere, NaN included).
/// Vectorised callers test it over a block of lanes and evaluate only the branch every lane takes
/// when they agree: the same operations per lane, so the same bits, at half the cost.
#[inline(always)]
pub fn expm1_uses_series(x: f32) -> bool {
    x.abs() < 0.35
}

/// [`expm1`] for `|x| < 0.35`: the Taylor series to x^8/8! (truncation < 3e-10 relative).
#[inline(always)]
pub fn expm1_series(x: f32) -> f32 {
    let mut t = 1.0 / 40320.0_f32;
    t = t * x + 1.0 / 5040.0;
    t = t * x + 1.0 / 720.0;
    t = t * x + 1.0 / 120.0;
    t = t * x + 1.0 / 24.0;
    t = t * x + 1.0 / 6.0;
    t = t * x + 0.5;
    (t * x) * x + x
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ulps(a: f32, b: f64) -> f64 {
        let b32 = b as f32;
        ((a - b32).abs() as f64) / (b32.abs() as f64 * f32::EPSILON as f64).max(f32::MIN_POSITIVE as f64)
    }

    #[test]
    fn exp_matches_std_over_its_domain() {
        let mut worst: f64 = 0.0;
        let mut x = -87.0_f32;
        while x < 88.5 {
            let u = ulps(exp(x), (x as f64).exp());
            worst = worst.max(u);
            x += 0.0137;
        }
        assert!(worst <= 3.0, "worst exp error {worst} ulp");
    }

    #[test]
    fn exp_saturates_and_propagates_nan() {
        assert_eq!(exp(-1000.0), 0.0);
        assert_eq!(exp(1000.0), f32::MAX);
        assert_eq!(exp(f32::INFINITY), f32::MAX);
        assert_eq!(exp(f32::NEG_INFINITY), 0.0);
        assert!(exp(f32::NAN).is_nan());
        assert_eq!(exp(0.0), 1.0);
    }

    #[test]
    fn ln_matches_std_and_handles_edges() {
        let mut worst: f64 = 0.0;
        let mut x = 1e-37_f32;
        while x < 1e37 {
            let want = (x as f64).ln();
            let err = ((ln(x) as f64) - want).abs() / (want.abs().max(1e-30) * f32::EPSILON as f64);
            // Near x = 1, ln → 0 and relative ulps are meaningless: use absolute error there.
            let abs_ok = ((ln(x) as f64) - want).abs() < 2.0 * f32::EPSILON as f64;
            if !abs_ok {
                worst = worst.max(err);
            }
            x *= 1.013;
        }
        assert!(worst <= 3.0, "worst ln error {worst} ulp");
        for x in [0.999_f32, 1.0, 1.001, 0.5, 2.0] {
            assert!(((ln(x) as f64) - (x as f64).ln()).abs() < 2e-7, "ln({x})");
        }
        assert_eq!(ln(0.0), -103.3);
        assert_eq!(ln(1e-45), -103.3);
        assert!(ln(-1.0).is_nan());
        assert!(ln(f32::NAN).is_nan());
        assert_eq!(ln(f32::INFINITY), f32::INFINITY);
    }

    #[test]
    fn ln_1m_is_accurate_near_zero_and_at_the_ends() {
        let mut worst: f64 = 0.0;
        let mut t = 1e-12_f32;
        while t < 0.999 {
            let want = (-(t as f64)).ln_1p();
            worst = worst.max(((ln_1m(t) as f64) - want).abs() / want.abs());
            t *= 1.01;
        }
        assert!(worst < 4e-7, "worst ln_1m relative error {worst}");
        assert_eq!(ln_1m(0.0), 0.0);
        assert_eq!(ln_1m(-1.0), 0.0);
        assert_eq!(ln_1m(1.0), -103.3);
        assert_eq!(ln_1m(2.0), -103.3);
    }

    #[test]
    fn expm1_is_accurate_for_tiny_and_large_arguments() {
        let mut worst: f64 = 0.0;
        for i in -4000..4000 {
            let x = i as f32 * 1e-3;
            let want = (x as f64).exp_m1();
            if want != 0.0 {
                worst = worst.max(((expm1(x) as f64) - want).abs() / want.abs());
            }
        }
        for x in [1e-30_f32, 1e-10, 1e-6, -1e-6, 0.3499, 0.35, 0.3501, 20.0, 80.0] {
            let want = (x as f64).exp_m1();
            worst = worst.max(((expm1(x) as f64) - want).abs() / want.abs());
        }
        assert!(worst < 4e-7, "worst expm1 relative error {worst}");
        assert_eq!(expm1(0.0), 0.0);
        assert_eq!(expm1(1e4), f32::MAX);
    }
}
