//! Eight `f32` lanes behind one trait, [`F8`], with two implementations: plain arrays
//! ([`Portable`], any CPU) and AVX2 registers with fused multiply–add ([`Avx2`], chosen at run
//! time). The kernel is written once against the trait.
//!
//! Why not arrays and the auto-vectoriser alone: LLVM vectorised the kernel's `[f32; 8]` loops
//! only in part (a mix of 4-wide and scalar chains for the polynomials, scalar shuffles for every
//! horizontal test), which cost more than half the time. With explicit registers every lane
//! operation is one instruction.
//!
//! The transcendental functions follow `matedit_physics::fastmath` (same reductions, same
//! polynomials, read from its constants; `ln(0)` is −103.3), with the polynomial steps as multiply–adds, and `exp` is
//! restricted to the kernel's arguments (finite, at most 88). On [`Avx2`] these are fused (one
//! rounding), so the two implementations agree to rounding, not bit for bit; each is
//! deterministic on its own, and the layer picks one per CPU, so results depend neither on the
//! thread count nor on timing.

use matedit_physics::fastmath::{EXP_POLY, LN_POLY, LN2_HI, LN2_LO};

/// Eight `f32` lanes.
pub(crate) trait F8: Copy {
    /// A lane mask.
    type M: Copy;
    /// Every lane `v`.
    fn splat(v: f32) -> Self;
    /// The first eight values of `s`.
    fn load(s: &[f32]) -> Self;
    /// Writes the lanes to the first eight slots of `s`.
    fn store(self, s: &mut [f32]);
    /// Lane-wise `+`.
    fn add(self, b: Self) -> Self;
    /// Lane-wise `−`.
    fn sub(self, b: Self) -> Self;
    /// Lane-wise `×`.
    fn mul(self, b: Self) -> Self;
    /// Lane-wise `÷`.
    fn div(self, b: Self) -> Self;
    /// `self · b + c` (fused where the CPU has it).
    fn mul_add(self, b: Self, c: Self) -> Self;
    /// Lane-wise minimum (`b` where either is NaN, like `minps`).
    fn min(self, b: Self) -> Self;
    /// Lane-wise maximum (`b` where either is NaN, like `maxps`).
    fn max(self, b: Self) -> Self;
    /// Lane-wise `floor`.
    fn floor(self) -> Self;
    /// `self < b` (false for NaN).
    fn lt(self, b: Self) -> Self::M;
    /// `self ≥ b` (false for NaN).
    fn ge(self, b: Self) -> Self::M;
    /// `self == b` (false for NaN).
    fn eq(self, b: Self) -> Self::M;
    /// Mask AND.
    fn and(a: Self::M, b: Self::M) -> Self::M;
    /// Mask OR.
    fn or(a: Self::M, b: Self::M) -> Self::M;
    /// Whether any lane of the mask is set.
    fn any(m: Self::M) -> bool;
    /// `a` where the mask is set, `b` elsewhere.
    fn select(m: Self::M, a: Self, b: Self) -> Self;
    /// 2^k for lanes holding integers k ∈ [−126, 127].
    fn pow2i(k: Self) -> Self;
    /// For positive normal lanes: (m, e) with x = m · 2^e, m ∈ [0.5, 1).
    fn frexp(self) -> (Self, Self);
    /// The lanes' sum in a fixed order: ((l0+l4)+(l2+l6)) + ((l1+l5)+(l3+l7)).
    fn sum(self) -> f32;
}

/// Lanes as a plain array: any CPU.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct Portable(pub [f32; 8]);

#[inline(always)]
fn zip(a: [f32; 8], b: [f32; 8], f: impl Fn(f32, f32) -> f32) -> [f32; 8] {
    std::array::from_fn(|l| f(a[l], b[l]))
}

impl F8 for Portable {
    type M = [bool; 8];
    #[inline(always)]
    fn splat(v: f32) -> Self {
        Self([v; 8])
    }
    #[inline(always)]
    fn load(s: &[f32]) -> Self {
        Self(std::array::from_fn(|l| s[l]))
    }
    #[inline(always)]
    fn store(self, s: &mut [f32]) {
        s[..8].copy_from_slice(&self.0);
    }
    #[inline(always)]
    fn add(self, b: Self) -> Self {
        Self(zip(self.0, b.0, |x, y| x + y))
    }
    #[inline(always)]
    fn sub(self, b: Self) -> Self {
        Self(zip(self.0, b.0, |x, y| x - y))
    }
    #[inline(always)]
    fn mul(self, b: Self) -> Self {
        Self(zip(self.0, b.0, |x, y| x * y))
    }
    #[inline(always)]
    fn div(self, b: Self) -> Self {
        Self(zip(self.0, b.0, |x, y| x / y))
    }
    #[inline(always)]
    fn mul_add(self, b: Self, c: Self) -> Self {
        Self(std::array::from_fn(|l| self.0[l] * b.0[l] + c.0[l]))
    }
    #[inline(always)]
    fn min(self, b: Self) -> Self {
        Self(zip(self.0, b.0, |x, y| if x < y { x } else { y }))
    }
    #[inline(always)]
    fn max(self, b: Self) -> Self {
        Self(zip(self.0, b.0, |x, y| if x > y { x } else { y }))
    }
    #[inline(always)]
    fn floor(self) -> Self {
        Self(self.0.map(f32::floor))
    }
    #[inline(always)]
    fn lt(self, b: Self) -> [bool; 8] {
        std::array::from_fn(|l| self.0[l] < b.0[l])
    }
    #[inline(always)]
    fn ge(self, b: Self) -> [bool; 8] {
        std::array::from_fn(|l| self.0[l] >= b.0[l])
    }
    #[inline(always)]
    fn eq(self, b: Self) -> [bool; 8] {
        std::array::from_fn(|l| self.0[l] == b.0[l])
    }
    #[inline(always)]
    fn and(a: [bool; 8], b: [bool; 8]) -> [bool; 8] {
        std::array::from_fn(|l| a[l] & b[l])
    }
    #[inline(always)]
    fn or(a: [bool; 8], b: [bool; 8]) -> [bool; 8] {
        std::array::from_fn(|l| a[l] | b[l])
    }
    #[inline(always)]
    fn any(m: [bool; 8]) -> bool {
        m.iter().fold(false, |a, &b| a | b)
    }
    #[inline(always)]
    fn select(m: [bool; 8], a: Self, b: Self) -> Self {
        Self(std::array::from_fn(|l| if m[l] { a.0[l] } else { b.0[l] }))
    }
    #[inline(always)]
    fn pow2i(k: Self) -> Self {
        Self(k.0.map(|k| f32::from_bits(((k as i32 + 127) as u32) << 23)))
    }
    #[inline(always)]
    fn frexp(self) -> (Self, Self) {
        let m = self
            .0
            .map(|x| f32::from_bits((x.to_bits() & 0x007f_ffff) | 0x3f00_0000));
        let e = self.0.map(|x| (((x.to_bits() >> 23) & 0xff) as i32 - 126) as f32);
        (Self(m), Self(e))
    }
    #[inline(always)]
    fn sum(self) -> f32 {
        let v = self.0;
        let s: [f32; 4] = std::array::from_fn(|l| v[l] + v[l + 4]);
        (s[0] + s[2]) + (s[1] + s[3])
    }
}

#[cfg(target_arch = "x86_64")]
pub(crate) use avx2::Avx2;

#[cfg(target_arch = "x86_64")]
mod avx2 {
    use super::F8;
    use std::arch::x86_64::*;

    /// Lanes in an AVX2 register. Only created inside functions compiled with
    /// `#[target_feature(enable = "avx2,fma")]` that run after `is_x86_feature_detected!`
    /// confirmed both features (see `kernel.rs`); every method is inlined into those.
    #[derive(Clone, Copy, Debug)]
    pub(crate) struct Avx2(__m256);

    // SAFETY (every `unsafe` block below): an `Avx2` value exists only on a CPU with AVX2 and
    // FMA (see the type's documentation), and loads and stores go through slices whose length is
    // checked first.
    impl F8 for Avx2 {
        type M = __m256;
        #[inline(always)]
        fn splat(v: f32) -> Self {
            unsafe { Self(_mm256_set1_ps(v)) }
        }
        #[inline(always)]
        fn load(s: &[f32]) -> Self {
            let s = &s[..8];
            unsafe { Self(_mm256_loadu_ps(s.as_ptr())) }
        }
        #[inline(always)]
        fn store(self, s: &mut [f32]) {
            let s = &mut s[..8];
            unsafe { _mm256_storeu_ps(s.as_mut_ptr(), self.0) }
        }
        #[inline(always)]
        fn add(self, b: Self) -> Self {
            unsafe { Self(_mm256_add_ps(self.0, b.0)) }
        }
        #[inline(always)]
        fn sub(self, b: Self) -> Self {
            unsafe { Self(_mm256_sub_ps(self.0, b.0)) }
        }
        #[inline(always)]
        fn mul(self, b: Self) -> Self {
            unsafe { Self(_mm256_mul_ps(self.0, b.0)) }
        }
        #[inline(always)]
        fn div(self, b: Self) -> Self {
            unsafe { Self(_mm256_div_ps(self.0, b.0)) }
        }
        #[inline(always)]
        fn mul_add(self, b: Self, c: Self) -> Self {
            unsafe { Self(_mm256_fmadd_ps(self.0, b.0, c.0)) }
        }
        #[inline(always)]
        fn min(self, b: Self) -> Self {
            unsafe { Self(_mm256_min_ps(self.0, b.0)) }
        }
        #[inline(always)]
        fn max(self, b: Self) -> Self {
            unsafe { Self(_mm256_max_ps(self.0, b.0)) }
        }
        #[inline(always)]
        fn floor(self) -> Self {
            unsafe { Self(_mm256_floor_ps(self.0)) }
        }
        #[inline(always)]
        fn lt(self, b: Self) -> __m256 {
            unsafe { _mm256_cmp_ps::<_CMP_LT_OQ>(self.0, b.0) }
        }
        #[inline(always)]
        fn ge(self, b: Self) -> __m256 {
            unsafe { _mm256_cmp_ps::<_CMP_GE_OQ>(self.0, b.0) }
        }
        #[inline(always)]
        fn eq(self, b: Self) -> __m256 {
            unsafe { _mm256_cmp_ps::<_CMP_EQ_OQ>(self.0, b.0) }
        }
        #[inline(always)]
        fn and(a: __m256, b: __m256) -> __m256 {
            unsafe { _mm256_and_ps(a, b) }
        }
        #[inline(always)]
        fn or(a: __m256, b: __m256) -> __m256 {
            unsafe { _mm256_or_ps(a, b) }
        }
        #[inline(always)]
        fn any(m: __m256) -> bool {
            unsafe { _mm256_movemask_ps(m) != 0 }
        }
        #[inline(always)]
        fn select(m: __m256, a: Self, b: Self) -> Self {
            unsafe { Self(_mm256_blendv_ps(b.0, a.0, m)) }
        }
        #[inline(always)]
        fn pow2i(k: Self) -> Self {
            unsafe {
                let ki = _mm256_cvtps_epi32(k.0);
                let bits = _mm256_slli_epi32::<23>(_mm256_add_epi32(ki, _mm256_set1_epi32(127)));
                Self(_mm256_castsi256_ps(bits))
            }
        }
        #[inline(always)]
        fn frexp(self) -> (Self, Self) {
            unsafe {
                let bits = _mm256_castps_si256(self.0);
                let m = _mm256_or_si256(
                    _mm256_and_si256(bits, _mm256_set1_epi32(0x007f_ffff)),
                    _mm256_set1_epi32(0x3f00_0000),
                );
                let e = _mm256_sub_epi32(
                    _mm256_and_si256(_mm256_srli_epi32::<23>(bits), _mm256_set1_epi32(0xff)),
                    _mm256_set1_epi32(126),
                );
                (Self(_mm256_castsi256_ps(m)), Self(_mm256_cvtepi32_ps(e)))
            }
        }
        #[inline(always)]
        fn sum(self) -> f32 {
            unsafe {
                // s[l] = v[l] + v[l+4], then (s0+s2) + (s1+s3): the portable order.
                let s = _mm_add_ps(_mm256_castps256_ps128(self.0), _mm256_extractf128_ps::<1>(self.0));
                let t = _mm_add_ps(s, _mm_movehl_ps(s, s));
                _mm_cvtss_f32(_mm_add_ss(t, _mm_movehdup_ps(t)))
            }
        }
    }
}

/// e^x for finite x ≤ 88, the kernel's arguments (γ·ln cos θ_h ≤ 0 and κ·cos^γ ≤ 29.3):
/// `fastmath::exp`'s reduction and polynomial, the polynomial by Estrin's scheme (three levels of
/// dependent multiply–adds instead of Horner's six: the kernel waits on this chain) and one power
/// of two. Below −87.3 it gives 0, as `fastmath::exp` does (no subnormal results, which some CPUs
/// compute slowly); larger or NaN arguments are outside its domain.
#[inline(always)]
pub(crate) fn exp<V: F8>(x: V) -> V {
    const LOG2E: f32 = std::f32::consts::LOG2_E;
    let xc = x.max(V::splat(-87.3));
    let k = xc.mul(V::splat(LOG2E)).add(V::splat(0.5)).floor();
    let r = k.mul_add(V::splat(-LN2_HI), xc);
    let r = k.mul_add(V::splat(-LN2_LO), r);
    let r2 = r.mul(r);
    let r4 = r2.mul(r2);
    let c = EXP_POLY;
    let p = pair(c[0], c[1], r).mul_add(r4, pair(c[2], c[3], r).mul_add(r2, pair(c[4], c[5], r)));
    // k ∈ [−126, 127]: 2^k is one normal number.
    let y = p.mul_add(r2, r.add(V::splat(1.0))).mul(V::pow2i(k));
    V::select(x.lt(V::splat(-87.3)), V::splat(0.0), y)
}

/// hi·m + lo: one pair of Estrin's scheme (`exp`, `ln`, the e^x − 1 polynomials).
#[inline(always)]
fn pair<V: F8>(hi: f32, lo: f32, m: V) -> V {
    V::splat(hi).mul_add(m, V::splat(lo))
}

/// Natural logarithm of lanes in [0, ∞), like `fastmath::ln`: 0 and subnormals give −103.3.
/// (Negative input does not occur in the kernel; it gives an unspecified finite value.)
#[inline(always)]
pub(crate) fn ln<V: F8>(x: V) -> V {
    const SQRT_HALF: f32 = std::f32::consts::FRAC_1_SQRT_2;
    let tiny = x.lt(V::splat(f32::MIN_POSITIVE));
    let xs = V::select(tiny, V::splat(f32::MIN_POSITIVE), x);
    let (m, e) = xs.frexp();
    let low = m.lt(V::splat(SQRT_HALF));
    let e = V::select(low, e.sub(V::splat(1.0)), e);
    let m = V::select(low, m.add(m), m).sub(V::splat(1.0));
    let z = m.mul(m);
    // Estrin's scheme, as in `exp`.
    let z4 = z.mul(z);
    let c = LN_POLY;
    let f0 = pair(c[5], c[6], m).mul_add(z, pair(c[7], c[8], m));
    let f1 = pair(c[1], c[2], m).mul_add(z, pair(c[3], c[4], m));
    let p = V::splat(c[0]).mul(z4).mul_add(z4, f1.mul_add(z4, f0));
    let y = m.mul(z).mul(p);
    let y = e.mul_add(V::splat(LN2_LO), y);
    let y = z.mul_add(V::splat(-0.5), y);
    let y = y.add(m);
    let y = e.mul_add(V::splat(LN2_HI), y);
    V::select(tiny, V::splat(-103.3), y)
}

/// ln(1 − t) for t ∈ [0, 1], accurate for tiny t (Goldberg's trick, as `fastmath::ln_1m`);
/// t = 1 gives −103.3.
#[inline(always)]
pub(crate) fn ln_1m<V: F8>(t: V) -> V {
    let t = t.max(V::splat(0.0)).min(V::splat(1.0));
    let u = V::splat(1.0).sub(t);
    let den = u.sub(V::splat(1.0));
    let exact = den.eq(V::splat(0.0));
    let den = V::select(exact, V::splat(-1.0), den);
    let y = ln(u).mul(V::splat(0.0).sub(t).div(den));
    let y = V::select(exact, V::splat(0.0).sub(t), y);
    V::select(t.ge(V::splat(1.0)), V::splat(-103.3), y)
}

/// Whether every lane has |x| < 0.35, where [`expm1_taylor`] is exact to 3e-10.
#[inline(always)]
pub(crate) fn all_small<V: F8>(x: V) -> bool {
    !V::any(V::or(x.ge(V::splat(0.35)), x.lt(V::splat(-0.35))))
}

/// e^x − 1 by its Taylor polynomial to x⁸/8!: for |x| < 0.35 only.
#[inline(always)]
pub(crate) fn expm1_taylor<V: F8>(x: V) -> V {
    // Estrin's scheme, as in `exp`: the kernel's hottest chain, four levels deep instead of eight.
    let x2 = x.mul(x);
    let x4 = x2.mul(x2);
    let high = V::splat(1.0 / 40320.0).mul_add(x2, pair(1.0 / 5040.0, 1.0 / 720.0, x));
    let p = high.mul_add(
        x4,
        pair(1.0 / 120.0, 1.0 / 24.0, x).mul_add(x2, pair(1.0 / 6.0, 0.5, x)),
    );
    p.mul_add(x2, x)
}

/// Below this |x|, [`expm1_tiny`]'s fourth-degree polynomial is within 2.2e-8 of e^x − 1,
/// relatively (the first omitted term, x⁵/5!, over x).
pub(crate) const EXPM1_TINY: f32 = 0.04;

/// e^x − 1 by its Taylor polynomial to x⁴/4!: for |x| < [`EXPM1_TINY`] only.
#[inline(always)]
pub(crate) fn expm1_tiny<V: F8>(x: V) -> V {
    let x2 = x.mul(x);
    let p = V::splat(1.0 / 24.0).mul_add(x2, pair(1.0 / 6.0, 0.5, x));
    p.mul_add(x2, x)
}

/// e^x − 1 for finite x ≤ 88, accurate for small |x| (the Taylor polynomial
/// below 0.35, e^x − 1 beyond). A group whose lanes are all small skips the general path.
#[inline(always)]
pub(crate) fn expm1<V: F8>(x: V) -> V {
    let small = expm1_taylor(x);
    if all_small(x) {
        return small;
    }
    let big = exp(x).sub(V::splat(1.0));
    let is_small = V::and(x.lt(V::splat(0.35)), V::splat(-0.35).lt(x));
    V::select(is_small, small, big)
}

/// e^x for finite x ≤ 88, with the same shortcut for groups of small arguments
/// (broad lobes, γ ≪ 1).
#[inline(always)]
pub(crate) fn exp_fast<V: F8>(x: V) -> V {
    if all_small(x) {
        return expm1_taylor(x).add(V::splat(1.0));
    }
    exp(x)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn lanes(f: impl Fn(usize) -> f32) -> [f32; 8] {
        std::array::from_fn(f)
    }

    /// Runs `check` on the portable lanes and, where the CPU allows, on AVX2 lanes.
    fn both(xs: [f32; 8], check: impl Fn(&str, [f32; 8])) {
        check("portable", xs);
        #[cfg(target_arch = "x86_64")]
        if std::is_x86_feature_detected!("avx2") && std::is_x86_feature_detected!("fma") {
            check("avx2", xs);
        }
    }

    fn apply(which: &str, xs: [f32; 8], f: fn(Portable) -> Portable, g: AvxFn) -> [f32; 8] {
        if which == "portable" {
            return f(Portable(xs)).0;
        }
        g(xs)
    }

    type AvxFn = fn([f32; 8]) -> [f32; 8];

    #[cfg(target_arch = "x86_64")]
    macro_rules! avx {
        ($f:expr) => {{
            #[target_feature(enable = "avx2,fma")]
            fn inner(xs: [f32; 8]) -> [f32; 8] {
                let mut out = [0.0; 8];
                $f(Avx2::load(&xs)).store(&mut out);
                out
            }
            fn outer(xs: [f32; 8]) -> [f32; 8] {
                // SAFETY: `both` calls this only after detecting AVX2 and FMA.
                unsafe { inner(xs) }
            }
            outer as AvxFn
        }};
    }
    #[cfg(not(target_arch = "x86_64"))]
    macro_rules! avx {
        ($f:expr) => {{ (|x| x) as AvxFn }};
    }

    #[test]
    fn exp_ln_ln1m_expm1_match_std_in_both_implementations() {
        let grid: Vec<f32> = (-8700..8796).map(|i| i as f32 * 0.01 + 0.003).collect();
        for chunk in grid.chunks_exact(8) {
            let xs = lanes(|l| chunk[l]);
            both(xs, |which, xs| {
                let e = apply(which, xs, exp, avx!(exp));
                for l in 0..8 {
                    let want = (xs[l] as f64).exp();
                    assert!(((e[l] as f64) / want - 1.0).abs() < 4e-7, "{which} exp({})", xs[l]);
                }
                let m = apply(which, xs, expm1, avx!(expm1));
                for l in 0..8 {
                    let want = (xs[l] as f64).exp_m1();
                    let err = (m[l] as f64 - want).abs() / want.abs().max(1e-30);
                    assert!(err < 5e-7, "{which} expm1({}) = {} want {want}", xs[l], m[l]);
                }
            });
        }
        let mut t = 1e-12f32;
        while t < 0.92 {
            let xs = lanes(|l| t * (1.0 + l as f32 * 0.01));
            both(xs, |which, xs| {
                let y = apply(which, xs, ln_1m, avx!(ln_1m));
                let x = apply(which, xs, ln, avx!(ln));
                for l in 0..8 {
                    let want = (-(xs[l] as f64)).ln_1p();
                    assert!(((y[l] as f64) / want - 1.0).abs() < 5e-7, "{which} ln_1m({})", xs[l]);
                    let want = (xs[l] as f64).ln();
                    assert!(
                        (x[l] as f64 - want).abs() < 4e-7 * want.abs().max(1.0),
                        "{which} ln({})",
                        xs[l]
                    );
                }
            });
            t *= 1.07;
        }
    }

    #[test]
    fn the_short_expm1_polynomials_hold_over_their_whole_ranges() {
        // |x| from 1e-30 to each polynomial's bound, both signs, and the bounds themselves.
        let mut xs: Vec<f32> = Vec::new();
        let mut t = 1e-30f32;
        while t < 0.35 {
            xs.extend([t, -t]);
            t *= 1.013;
        }
        xs.extend([
            0.0,
            -0.0,
            EXPM1_TINY,
            -EXPM1_TINY,
            f32::from_bits(0.35f32.to_bits() - 1),
            -f32::from_bits(0.35f32.to_bits() - 1),
        ]);
        while !xs.len().is_multiple_of(8) {
            xs.push(0.0);
        }
        for chunk in xs.chunks_exact(8) {
            let xs = lanes(|l| chunk[l]);
            both(xs, |which, xs| {
                let taylor = apply(which, xs, expm1_taylor, avx!(expm1_taylor));
                let tiny = apply(which, xs, expm1_tiny, avx!(expm1_tiny));
                for l in 0..8 {
                    let x = xs[l] as f64;
                    let want = x.exp_m1();
                    let rel = |got: f32| {
                        if want == 0.0 {
                            (got as f64).abs()
                        } else {
                            (got as f64 - want).abs() / want.abs()
                        }
                    };
                    assert!(rel(taylor[l]) < 2e-7, "{which} expm1_taylor({x}) = {}", taylor[l]);
                    // Rounding (about 1e-7 at most here) plus the truncation's 2.2e-8 at the bound.
                    if x.abs() <= EXPM1_TINY as f64 {
                        assert!(rel(tiny[l]) < 1.2e-7, "{which} expm1_tiny({x}) = {}", tiny[l]);
                    }
                }
            });
        }
    }

    #[test]
    fn edges_stay_finite() {
        let xs = [-1e4, -87.4, 88.0, -1e-30, 0.0, f32::MIN_POSITIVE / 4.0, 1.0, 2.0];
        both(xs, |which, xs| {
            let e = apply(which, xs, exp, avx!(exp));
            // Below −87.3: 0, never a subnormal.
            assert_eq!((e[0], e[1]), (0.0, 0.0), "{which} {e:?}");
            assert!(((e[2] as f64) / (88.0f64).exp() - 1.0).abs() < 4e-7, "{which} {}", e[2]);
            assert_eq!((e[3], e[4]), (1.0, 1.0), "{which}");
            let m = apply(which, xs, expm1, avx!(expm1));
            assert!(
                m.iter().all(|v| v.is_finite()) && m[0] == -1.0 && m[4] == 0.0,
                "{which} {m:?}"
            );
            let l = apply(which, xs, ln, avx!(ln));
            assert_eq!((l[4], l[5], l[6]), (-103.3, -103.3, 0.0), "{which}");
            let m = apply(which, xs, ln_1m, avx!(ln_1m));
            assert_eq!((m[4], m[6], m[7]), (0.0, -103.3, -103.3), "{which}");
            assert!(m.iter().all(|v| v.is_finite()), "{which} {m:?}");
        });
    }

    #[test]
    fn sums_add_in_the_documented_order() {
        let xs = [1e8, 1.0, -1e8, 1.0, 3.0, 5.0, 7.0, 11.0];
        let want = ((xs[0] + xs[4]) + (xs[2] + xs[6])) + ((xs[1] + xs[5]) + (xs[3] + xs[7]));
        assert_eq!(Portable(xs).sum(), want);
        #[cfg(target_arch = "x86_64")]
        if std::is_x86_feature_detected!("avx2") && std::is_x86_feature_detected!("fma") {
            #[target_feature(enable = "avx2,fma")]
            fn inner(xs: [f32; 8]) -> f32 {
                Avx2::load(&xs).sum()
            }
            // SAFETY: AVX2 and FMA detected just above.
            assert_eq!(unsafe { inner(xs) }, want);
        }
    }
}
