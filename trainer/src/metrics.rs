//! The per-sample metrics of Sec. 4 on plain f32 slices (no Burn), shared by the evaluation
//! (`eval`) and the training losses (`train::loss` follows its tone map and SSIM window).
//!
//! Layouts: images and normals are channel-first `[3, H, W]`, the mask is `[H, W]` with a pixel on
//! the object when its value is > 0.5 (the loader's rule; a non-finite mask value is "off").
//! Non-finite image, normal or material values are read as 0, so no metric is ever NaN;
//! [`count_non_finite`] lets callers report how many there were.
//!
//! **Tone map** (L2 and SSIM): [`matedit_physics::tonemap::tonemap_u8`] — multiply by an
//! exposure, clamp to [0, 1], sRGB transfer function, ×255 and round to an integer in [0, 255]:
//! the 8-bit display images the paper's "tone mapped images in the range [0, 255]" refer to, and
//! the operator of the PNG previews (docs/CONVENTIONS.md). The exposure belongs to the ground
//! truth ([`metric_exposure`]: its 99th-percentile channel value on the object becomes white) and
//! is applied unchanged to the prediction. A fixed exposure would make the score depend on the
//! arbitrary scale of HDR light probes: at exposure 1 the quickstart test split had 56 % of its
//! object pixels clipped to white, where every method looks alike.
//!
//! An empty mask gives the "nothing wrong" values: L2 0, SSIM 1, cosine 1. The
//! [`Metrics`](crate::eval::Metrics) accumulator skips such samples instead of averaging them in.

use matedit_physics::brdf::Dsbrdf;
use matedit_physics::brdf::dsbrdf::PARAMS;
use matedit_physics::tonemap::tonemap_u8;

/// The ground truth's channel-value percentile (over object pixels) that the tone map makes white.
pub const WHITE_PERCENTILE: f64 = 0.99;
/// Half width of the SSIM window: 11 × 11 taps.
pub const SSIM_RADIUS: usize = 5;
/// σ of the SSIM Gaussian window, in pixels (Wang et al. 2004).
pub const SSIM_SIGMA: f64 = 1.5;
/// SSIM's luminance constant (0.01 · 255)².
pub const SSIM_C1: f64 = (0.01 * 255.0) * (0.01 * 255.0);
/// SSIM's contrast constant (0.03 · 255)².
pub const SSIM_C2: f64 = (0.03 * 255.0) * (0.03 * 255.0);

/// How many values of `xs` are NaN or ±∞.
pub fn count_non_finite(xs: &[f32]) -> u64 {
    xs.iter().filter(|v| !v.is_finite()).count() as u64
}

/// Whether the mask holds at least one object pixel.
pub fn mask_is_empty(mask: &[f32]) -> bool {
    !mask.iter().any(|&m| m > 0.5)
}

fn finite(v: f32) -> f32 {
    if v.is_finite() { v } else { 0.0 }
}

/// The tone map's exposure for ground truth `truth` (`[3, H, W]`) on `mask`: 1 / its
/// [`WHITE_PERCENTILE`] channel value over the object pixels (non-finite values read as 0), or 1
/// when that is not positive (a black or empty ground truth).
pub fn metric_exposure(truth: &[f32], mask: &[f32]) -> f32 {
    let hw = mask.len();
    let mut v: Vec<f32> = (0..3)
        .flat_map(|c| (0..hw).filter(|&p| mask[p] > 0.5).map(move |p| c * hw + p))
        .filter_map(|i| truth.get(i).map(|&x| finite(x)))
        .collect();
    if v.is_empty() {
        return 1.0;
    }
    v.sort_by(f32::total_cmp);
    let white = v[((v.len() - 1) as f64 * WHITE_PERCENTILE).round() as usize];
    if white > 0.0 && (1.0 / white).is_finite() {
        1.0 / white
    } else {
        1.0
    }
}

/// A channel-first linear image as display values in [0, 255] at `exposure` (see the module
/// docs).
pub fn tonemap_display(img: &[f32], exposure: f32) -> Vec<f64> {
    img.iter()
        .map(|&v| f64::from(tonemap_u8(finite(v), exposure)))
        .collect()
}

fn check_shapes(pred: &[f32], truth: &[f32], mask: &[f32], h: usize, w: usize) {
    assert_eq!(mask.len(), h * w, "mask: expected H·W = {} values", h * w);
    assert_eq!(
        pred.len(),
        3 * h * w,
        "prediction: expected 3·H·W = {} values",
        3 * h * w
    );
    assert_eq!(
        truth.len(),
        3 * h * w,
        "ground truth: expected 3·H·W = {} values",
        3 * h * w
    );
}

/// Mean of `per_pixel` over the object pixels (`default` when there are none).
fn masked_mean(mask: &[f32], default: f64, per_pixel: impl Fn(usize) -> f64) -> f64 {
    let (mut sum, mut n) = (0.0, 0u64);
    for (p, _) in mask.iter().enumerate().filter(|&(_, &m)| m > 0.5) {
        sum += per_pixel(p);
        n += 1;
    }
    if n == 0 { default } else { sum / n as f64 }
}

/// The paper's image L2: both images tone-mapped to [0, 255] (at the ground truth's exposure),
/// per pixel the mean over R, G, B of the squared difference, averaged over the object pixels.
///
/// # Panics
/// When a slice's length does not match `h`, `w`.
pub fn l2_tonemapped(pred: &[f32], truth: &[f32], mask: &[f32], h: usize, w: usize) -> f64 {
    check_shapes(pred, truth, mask, h, w);
    l2_tonemapped_at(pred, truth, mask, h, w, metric_exposure(truth, mask))
}

/// [`l2_tonemapped`] at a given exposure.
///
/// # Panics
/// When a slice's length does not match `h`, `w`.
pub fn l2_tonemapped_at(pred: &[f32], truth: &[f32], mask: &[f32], h: usize, w: usize, exposure: f32) -> f64 {
    check_shapes(pred, truth, mask, h, w);
    let (a, b) = (tonemap_display(pred, exposure), tonemap_display(truth, exposure));
    let hw = h * w;
    masked_mean(mask, 0.0, |p| {
        (0..3).map(|c| (a[c * hw + p] - b[c * hw + p]).powi(2)).sum::<f64>() / 3.0
    })
}

/// The 11 Gaussian taps, unnormalised: each window is renormalised where it is truncated.
fn gaussian_taps() -> [f64; 2 * SSIM_RADIUS + 1] {
    std::array::from_fn(|i| {
        let d = i as f64 - SSIM_RADIUS as f64;
        (-d * d / (2.0 * SSIM_SIGMA * SSIM_SIGMA)).exp()
    })
}

/// Gaussian-weighted local mean of one `[h, w]` plane. The window is cut at the image border and
/// renormalised over the pixels it keeps. The cut 2-D window is the product of the cut 1-D ones,
/// so two renormalised 1-D passes give exactly the renormalised 2-D window.
fn local_mean(src: &[f64], h: usize, w: usize) -> Vec<f64> {
    let taps = gaussian_taps();
    let pass = |src: &[f64], n: usize, at: &dyn Fn(usize, usize) -> usize, lines: usize| {
        let mut out = vec![0.0; src.len()];
        for line in 0..lines {
            for i in 0..n {
                let (lo, hi) = (i.saturating_sub(SSIM_RADIUS), (i + SSIM_RADIUS).min(n - 1));
                let (mut acc, mut norm) = (0.0, 0.0);
                for j in lo..=hi {
                    let t = taps[j + SSIM_RADIUS - i];
                    acc += t * src[at(line, j)];
                    norm += t;
                }
                out[at(line, i)] = acc / norm;
            }
        }
        out
    };
    let rows = pass(src, w, &|y, x| y * w + x, h);
    pass(&rows, h, &|x, y| y * w + x, w)
}

/// SSIM (Wang et al. 2004) on the tone-mapped [0, 255] images: 11 × 11 Gaussian window with
/// σ = 1.5 (normalised), C1 = (0.01·255)², C2 = (0.03·255)², population (co)variances, computed
/// per channel over the whole image; the SSIM map is averaged over the object pixels and the
/// three channels.
///
/// **Border rule:** near the image border the window is truncated to the pixels inside the image
/// and renormalised to sum 1 (scikit-image reflects the image instead and then drops a
/// 5-pixel border; both agree on pixels at least 5 pixels from the border). Background pixels
/// inside an object pixel's window take part in its statistics, as in a full-image SSIM.
///
/// # Panics
/// When a slice's length does not match `h`, `w`.
pub fn ssim(pred: &[f32], truth: &[f32], mask: &[f32], h: usize, w: usize) -> f64 {
    check_shapes(pred, truth, mask, h, w);
    ssim_at(pred, truth, mask, h, w, metric_exposure(truth, mask))
}

/// [`ssim`] at a given exposure.
///
/// # Panics
/// When a slice's length does not match `h`, `w`.
pub fn ssim_at(pred: &[f32], truth: &[f32], mask: &[f32], h: usize, w: usize, exposure: f32) -> f64 {
    check_shapes(pred, truth, mask, h, w);
    ssim_of_display(
        &tonemap_display(pred, exposure),
        &tonemap_display(truth, exposure),
        mask,
        h,
        w,
    )
}

/// The SSIM of [`ssim`] between two images already in display values (`[3, H, W]`, [0, 255]):
/// the window, constants, border rule and object-pixel average of [`ssim`], without its tone map.
/// The training's structural loss (`train::loss::ssim_loss`) is checked against this.
///
/// # Panics
/// When a slice's length does not match `h`, `w`.
pub fn ssim_of_display(a: &[f64], b: &[f64], mask: &[f32], h: usize, w: usize) -> f64 {
    let hw = h * w;
    assert!(
        a.len() == 3 * hw && b.len() == 3 * hw && mask.len() == hw,
        "ssim_of_display: images of {} and {} values, mask of {}, for 3 × {h} × {w}",
        a.len(),
        b.len(),
        mask.len()
    );
    if mask_is_empty(mask) {
        return 1.0;
    }
    let mut total = 0.0;
    for c in 0..3 {
        let (x, y) = (&a[c * hw..(c + 1) * hw], &b[c * hw..(c + 1) * hw]);
        let prod = |u: &[f64], v: &[f64]| u.iter().zip(v).map(|(p, q)| p * q).collect::<Vec<_>>();
        let (mx, my) = (local_mean(x, h, w), local_mean(y, h, w));
        let (mxx, myy, mxy) = (
            local_mean(&prod(x, x), h, w),
            local_mean(&prod(y, y), h, w),
            local_mean(&prod(x, y), h, w),
        );
        total += masked_mean(mask, 1.0, |p| {
            // Same operation order for x and y, so identical images give exactly 1.
            let (vx, vy, vxy) = (mxx[p] - mx[p] * mx[p], myy[p] - my[p] * my[p], mxy[p] - mx[p] * my[p]);
            let num = (2.0 * mx[p] * my[p] + SSIM_C1) * (2.0 * vxy + SSIM_C2);
            let den = (mx[p] * mx[p] + my[p] * my[p] + SSIM_C1) * (vx + vy + SSIM_C2);
            num / den
        });
    }
    total / 3.0
}

/// Mean over the object pixels of the cosine between predicted and true normals (`[3, H, W]`,
/// any length). A zero-length vector (either one) counts as cosine 0; non-finite components
/// count as 0. Both normals unit length makes this the paper's Table 2 "cosine".
///
/// # Panics
/// When a slice's length does not match `h`, `w`.
pub fn normal_cosine(pred: &[f32], truth: &[f32], mask: &[f32], h: usize, w: usize) -> f64 {
    check_shapes(pred, truth, mask, h, w);
    let hw = h * w;
    masked_mean(mask, 1.0, |p| {
        let v = |img: &[f32], c: usize| f64::from(finite(img[c * hw + p]));
        let (mut dot, mut aa, mut bb) = (0.0, 0.0, 0.0);
        for c in 0..3 {
            dot += v(pred, c) * v(truth, c);
            aa += v(pred, c) * v(pred, c);
            bb += v(truth, c) * v(truth, c);
        }
        // sqrt(aa·bb) rather than |a|·|b|: for b = ±a it is exactly aa, so the cosine is exactly ±1.
        let norm = (aa * bb).sqrt();
        if norm > 0.0 { (dot / norm).clamp(-1.0, 1.0) } else { 0.0 }
    })
}

/// Raw DSBRDF parameters of a normalised 108-vector (non-finite entries read as 0).
fn raw_params(normalised: &[f32]) -> [f64; PARAMS] {
    assert_eq!(
        normalised.len(),
        PARAMS,
        "material: expected {PARAMS} normalised parameters"
    );
    let x: Vec<f64> = normalised.iter().map(|&v| f64::from(finite(v))).collect();
    // The length is checked and NaN replaced above: the only two errors of from_normalised.
    *Dsbrdf::from_normalised(&x)
        .expect("checked length, finite values")
        .params()
}

fn squared_distance(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(p, q)| (p - q).powi(2)).sum()
}

/// Material L2 of Table 1 in the raw DSBRDF scale: both normalised vectors mapped back with
/// [`Dsbrdf::from_normalised`] (clamped to [−1, 1]), then the **sum** over the 108 parameters of
/// the squared difference — Eq. 4, l = (m − m')², has no averaging over parameters (the mean
/// squared error is this / 108). Raw γ spans [1e-3, 1e4], so γ differences dominate.
///
/// # Panics
/// When a slice does not hold 108 values.
pub fn material_l2(pred_normalised: &[f32], truth_normalised: &[f32]) -> f64 {
    squared_distance(&raw_params(pred_normalised), &raw_params(truth_normalised))
}

/// [`material_l2`] in the normalised scale ([−0.95, 0.95], the training target): sum over the
/// 108 parameters of the squared difference, values unclamped, non-finite entries read as 0.
///
/// # Panics
/// When a slice does not hold 108 values.
pub fn material_l2_normalised(pred_normalised: &[f32], truth_normalised: &[f32]) -> f64 {
    assert_eq!(
        pred_normalised.len(),
        PARAMS,
        "material: expected {PARAMS} normalised parameters"
    );
    assert_eq!(
        truth_normalised.len(),
        PARAMS,
        "material: expected {PARAMS} normalised parameters"
    );
    let f = |s: &[f32]| s.iter().map(|&v| f64::from(finite(v))).collect::<Vec<_>>();
    squared_distance(&f(pred_normalised), &f(truth_normalised))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The fixed exposure of the display tests.
    const METRIC_EXPOSURE: f32 = 1.0;

    fn l2_1(p: &[f32], t: &[f32], m: &[f32], h: usize, w: usize) -> f64 {
        l2_tonemapped_at(p, t, m, h, w, METRIC_EXPOSURE)
    }

    fn ssim_1(p: &[f32], t: &[f32], m: &[f32], h: usize, w: usize) -> f64 {
        ssim_at(p, t, m, h, w, METRIC_EXPOSURE)
    }
    use matedit_physics::brdf::dsbrdf::{GAMMA_RANGE, KAPPA_RANGE, LobeParam, param_index};

    /// The linear value that the metric tone map sends to display value `k`.
    fn lin(k: u8) -> f32 {
        let c = f32::from(k) / 255.0;
        let v = if c <= 0.040_45 {
            c / 12.92
        } else {
            ((c + 0.055) / 1.055).powf(2.4)
        };
        assert_eq!(
            tonemap_u8(v, METRIC_EXPOSURE),
            k,
            "sRGB decode of {k} does not round-trip"
        );
        v
    }

    /// A `[3, h, w]` linear image whose display values are `f(c, y, x)`.
    fn image(h: usize, w: usize, f: impl Fn(usize, usize, usize) -> u8) -> Vec<f32> {
        (0..3 * h * w)
            .map(|i| lin(f(i / (h * w), (i / w) % h, i % w)))
            .collect()
    }

    /// Knuth's MMIX LCG, upper 31 bits; the Python reference below uses the same recurrence.
    struct Lcg(u64);
    impl Lcg {
        fn next(&mut self) -> u64 {
            self.0 = self
                .0
                .wrapping_mul(6_364_136_223_846_793_005)
                .wrapping_add(1_442_695_040_888_963_407);
            self.0 >> 33
        }
    }

    fn random_linear(h: usize, w: usize, seed: u64) -> Vec<f32> {
        let mut r = Lcg(seed);
        // Up to 2.0, so clipped highlights are covered too.
        (0..3 * h * w).map(|_| (r.next() % 2000) as f32 / 1000.0).collect()
    }

    #[test]
    fn lcg_matches_the_python_reference_sequence() {
        let mut r = Lcg(12345);
        let first: Vec<u64> = (0..4).map(|_| r.next() % 256).collect();
        assert_eq!(first, [248, 55, 130, 133]);
    }

    #[test]
    fn ssim_of_identical_images_is_exactly_one() {
        let (h, w) = (17, 13);
        let a = random_linear(h, w, 7);
        let full = vec![1.0; h * w];
        let part: Vec<f32> = (0..h * w).map(|p| f32::from(u8::from(p % 3 == 0))).collect();
        assert_eq!(ssim_1(&a, &a, &full, h, w), 1.0);
        assert_eq!(ssim_1(&a, &a, &part, h, w), 1.0);
    }

    #[test]
    fn ssim_of_constant_images_is_the_luminance_term() {
        let (h, w) = (12, 9);
        let mask = vec![1.0; h * w];
        for (ka, kb) in [(100u8, 140u8), (0, 255), (30, 31), (200, 200)] {
            let (a, b) = (image(h, w, |_, _, _| ka), image(h, w, |_, _, _| kb));
            let (fa, fb) = (f64::from(ka), f64::from(kb));
            let expected = (2.0 * fa * fb + SSIM_C1) / (fa * fa + fb * fb + SSIM_C1);
            let got = ssim_1(&a, &b, &mask, h, w);
            assert!((got - expected).abs() < 1e-12, "{ka} vs {kb}: {got} != {expected}");
        }
    }

    #[test]
    fn ssim_is_symmetric() {
        let (h, w) = (20, 15);
        let (a, b) = (random_linear(h, w, 1), random_linear(h, w, 2));
        let mask: Vec<f32> = (0..h * w).map(|p| f32::from(u8::from(p % 5 != 0))).collect();
        let (ab, ba) = (ssim_1(&a, &b, &mask, h, w), ssim_1(&b, &a, &mask, h, w));
        assert_eq!(ab, ba);
        assert!(ab < 0.9);
    }

    #[test]
    fn ssim_matches_a_hand_computed_two_pixel_case() {
        // 1 × 2 image, display values x = [100, 120], y = [130, 110] in every channel. The window
        // of each pixel is cut to the two pixels: weight w0 = 1/(1+e) on itself and w1 = e/(1+e)
        // on the other, e = exp(−1/(2σ²)). Then σx² = σy² = 400·w0·w1 = −σxy at both pixels.
        let x = image(1, 2, |_, _, i| [100, 120][i]);
        let y = image(1, 2, |_, _, i| [130, 110][i]);
        let e = (-1.0f64 / 4.5).exp();
        let (w0, w1) = (1.0 / (1.0 + e), e / (1.0 + e));
        let v = 400.0 * w0 * w1;
        let pixel = |mx: f64, my: f64| {
            (2.0 * mx * my + SSIM_C1) * (-2.0 * v + SSIM_C2) / ((mx * mx + my * my + SSIM_C1) * (2.0 * v + SSIM_C2))
        };
        let expected = 0.5
            * (pixel(100.0 * w0 + 120.0 * w1, 130.0 * w0 + 110.0 * w1)
                + pixel(100.0 * w1 + 120.0 * w0, 130.0 * w1 + 110.0 * w0));
        let got = ssim_1(&x, &y, &[1.0, 1.0], 1, 2);
        assert!((got - expected).abs() < 1e-12, "{got} != {expected}");
        // The same closed form evaluated in Python (float64).
        assert!((got - -0.540_776_643_107_525_4).abs() < 1e-12);
    }

    #[test]
    fn ssim_matches_scikit_image_on_the_interior() {
        // Reference (scikit-image 0.26.0, numpy float64):
        //   structural_similarity(a, b, channel_axis=0, gaussian_weights=True, sigma=1.5,
        //                         use_sample_covariance=False, data_range=255)
        // on a, b = the display values below reshaped to (3, 32, 32), generated in Python with
        //   state = (state * 6364136223846793005 + 1442695040888963407) % 2**64; r = state >> 33
        // from state = 12345: a = [r % 256 for 3072 draws], then for each a-value in order
        // b = min(255, max(0, a + r % 201 - 100)). scikit-image reflects at the border and then
        // averages only pixels ≥ 5 from it, where every window is whole, so the interior mask
        // makes the border rules irrelevant.
        const SKIMAGE: f64 = 0.761_409_333_732_415_5;
        let n = 32;
        let mut r = Lcg(12345);
        let a: Vec<u8> = (0..3 * n * n).map(|_| (r.next() % 256) as u8).collect();
        let b: Vec<u8> = a
            .iter()
            .map(|&v| (i64::from(v) + (r.next() % 201) as i64 - 100).clamp(0, 255) as u8)
            .collect();
        let (fa, fb) = (
            image(n, n, |c, y, x| a[(c * n + y) * n + x]),
            image(n, n, |c, y, x| b[(c * n + y) * n + x]),
        );
        let interior: Vec<f32> = (0..n * n)
            .map(|p| f32::from(u8::from((5..n - 5).contains(&(p / n)) && (5..n - 5).contains(&(p % n)))))
            .collect();
        let got = ssim_1(&fa, &fb, &interior, n, n);
        assert!((got - SKIMAGE).abs() < 1e-12, "{got} != {SKIMAGE}");
    }

    #[test]
    fn ssim_ignores_unmasked_pixels_beyond_the_window() {
        let (h, w) = (24, 24);
        let (a, b) = (random_linear(h, w, 3), random_linear(h, w, 4));
        let mask: Vec<f32> = (0..h * w)
            .map(|p| f32::from(u8::from(p / w < 6 && p % w < 6)))
            .collect();
        let mut b2 = b.clone();
        for (i, v) in b2.iter_mut().enumerate() {
            let p = i % (h * w);
            if p / w > 11 || p % w > 11 {
                *v = 0.7 - *v;
            }
        }
        assert_eq!(ssim_1(&a, &b, &mask, h, w), ssim_1(&a, &b2, &mask, h, w));
    }

    #[test]
    fn l2_of_a_known_tone_mapped_difference() {
        // Per pixel: R 255 vs 128, G 0 vs 0, B 128 vs 0 → (127² + 0 + 128²) / 3.
        let pred = image(2, 3, |c, _, _| [255, 0, 128][c]);
        let truth = image(2, 3, |c, _, _| [128, 0, 0][c]);
        let got = l2_1(&pred, &truth, &[1.0; 6], 2, 3);
        assert_eq!(got, (127.0 * 127.0 + 128.0 * 128.0) / 3.0);
        // Highlights clip: linear 5.0 and 1.0 both display as 255.
        assert_eq!(l2_1(&[5.0; 18], &[1.0; 18], &[1.0; 6], 2, 3), 0.0);
    }

    #[test]
    fn l2_averages_over_masked_pixels_only() {
        // Two masked pixels differ by 10 and 0 in every channel; unmasked ones differ wildly.
        let pred = image(1, 4, |_, _, x| [110, 50, 255, 0][x]);
        let truth = image(1, 4, |_, _, x| [100, 50, 0, 255][x]);
        let mask = [1.0, 1.0, 0.0, 0.0];
        assert_eq!(l2_1(&pred, &truth, &mask, 1, 4), 50.0);
        let other = image(1, 4, |_, _, x| [110, 50, 17, 99][x]);
        assert_eq!(l2_1(&other, &truth, &mask, 1, 4), 50.0);
    }

    #[test]
    fn empty_mask_gives_the_documented_values() {
        let (a, b) = (random_linear(4, 4, 5), random_linear(4, 4, 6));
        let m = [0.0; 16];
        assert_eq!(l2_1(&a, &b, &m, 4, 4), 0.0);
        assert_eq!(ssim_1(&a, &b, &m, 4, 4), 1.0);
        assert_eq!(normal_cosine(&a, &b, &m, 4, 4), 1.0);
    }

    #[test]
    fn normal_cosine_closed_forms() {
        let (h, w) = (3, 5);
        let n = random_linear(h, w, 8).iter().map(|v| v - 1.0).collect::<Vec<_>>();
        let neg: Vec<f32> = n.iter().map(|v| -v).collect();
        let mask = vec![1.0; h * w];
        assert_eq!(normal_cosine(&n, &n, &mask, h, w), 1.0);
        assert_eq!(normal_cosine(&n, &neg, &mask, h, w), -1.0);
        // Pixel 0: parallel; 1: orthogonal; 2: predicted zero vector; 3: opposite but unmasked.
        let planar = |px: [[f32; 3]; 4]| -> Vec<f32> { (0..12).map(|i| px[i % 4][i / 4]).collect() };
        let pred = planar([[0.0, 0.0, 2.0], [3.0, 0.0, 0.0], [0.0; 3], [1.0, 0.0, 0.0]]);
        let truth = planar([[0.0, 0.0, 1.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [-1.0, 0.0, 0.0]]);
        let got = normal_cosine(&pred, &truth, &[1.0, 1.0, 1.0, 0.0], 1, 4);
        assert_eq!(got, 1.0 / 3.0);
        let zero = [0.0; 3];
        assert_eq!(normal_cosine(&zero, &zero, &[1.0], 1, 1), 0.0);
    }

    #[test]
    fn non_finite_inputs_give_finite_metrics() {
        let (h, w) = (8, 8);
        let mut a = random_linear(h, w, 9);
        let b = random_linear(h, w, 10);
        a[0] = f32::NAN;
        a[70] = f32::INFINITY;
        a[150] = f32::NEG_INFINITY;
        let mut mask = vec![1.0; h * w];
        mask[3] = f32::NAN;
        assert_eq!(count_non_finite(&a), 3);
        for v in [
            l2_1(&a, &b, &mask, h, w),
            ssim_1(&a, &b, &mask, h, w),
            normal_cosine(&a, &b, &mask, h, w),
        ] {
            assert!(v.is_finite());
        }
        // Read as 0: a NaN pixel scores like a black one.
        let mut black = a.clone();
        black[0] = 0.0;
        black[70] = 0.0;
        black[150] = 0.0;
        assert_eq!(l2_1(&a, &b, &mask, h, w), l2_1(&black, &b, &mask, h, w));
        let mut m = [0.5f32; PARAMS];
        m[0] = f32::NAN;
        m[1] = f32::INFINITY;
        assert!(material_l2(&m, &[0.0; PARAMS]).is_finite());
        assert!(material_l2_normalised(&m, &[0.0; PARAMS]).is_finite());
    }

    #[test]
    fn material_l2_closed_forms() {
        let truth = [-0.95f32; PARAMS];
        assert_eq!(material_l2(&truth, &truth), 0.0);
        assert_eq!(material_l2_normalised(&truth, &truth), 0.0);
        // Raw: every parameter at the bottom of its range, except one κ and one γ at the top.
        let mut pred = truth;
        pred[param_index(0, 0, LobeParam::Kappa, 0)] = 0.95;
        pred[param_index(2, 1, LobeParam::Gamma, 3)] = 0.95;
        let expected = (KAPPA_RANGE.1 - KAPPA_RANGE.0).powi(2) + (GAMMA_RANGE.1 - GAMMA_RANGE.0).powi(2);
        // ±0.95 is not exact in f32: its rounding (6e-9) moves the raw ends by ~1e-7 relative.
        let got = material_l2(&pred, &truth);
        assert!((got - expected).abs() <= 1e-6 * expected, "{got} != {expected}");
        let got_n = material_l2_normalised(&pred, &truth);
        assert!((got_n - 2.0 * 1.9f64.powi(2)).abs() < 1e-6, "{got_n}");
    }

    #[test]
    fn metrics_do_not_depend_on_the_scale_of_the_light() {
        let (h, w) = (16, 16);
        let (a, b) = (random_linear(h, w, 11), random_linear(h, w, 12));
        let mask: Vec<f32> = (0..h * w).map(|p| f32::from(u8::from(p % 5 != 0))).collect();
        for k in [1e-3f32, 0.25, 64.0, 1e4] {
            let (ka, kb): (Vec<f32>, Vec<f32>) = (a.iter().map(|v| v * k).collect(), b.iter().map(|v| v * k).collect());
            let (l1, lk) = (l2_tonemapped(&a, &b, &mask, h, w), l2_tonemapped(&ka, &kb, &mask, h, w));
            let (s1, sk) = (ssim(&a, &b, &mask, h, w), ssim(&ka, &kb, &mask, h, w));
            assert!((l1 - lk).abs() <= 1e-9 * l1.max(1.0), "L2 at scale {k}: {lk} vs {l1}");
            assert!((s1 - sk).abs() < 1e-12, "SSIM at scale {k}: {sk} vs {s1}");
        }
    }

    #[test]
    fn the_exposure_puts_the_99th_percentile_at_white() {
        // 100 object pixels with channel values 0.01 … 1.00 (R), ×2 (G), ×3 (B): 300 values, the
        // 99th percentile (index round(299·0.99) = 296, the fourth largest: 3.00, 2.97, 2.94,
        // 2.91) is 2.91.
        let mask = vec![1.0f32; 100];
        let img: Vec<f32> = (0..300)
            .map(|i| (i % 100 + 1) as f32 / 100.0 * (1 + i / 100) as f32)
            .collect();
        let e = metric_exposure(&img, &mask);
        assert!((e - 1.0 / 2.91).abs() < 1e-6, "{e}");
        // A black, non-finite or empty ground truth keeps exposure 1.
        assert_eq!(metric_exposure(&[0.0; 300], &mask), 1.0);
        assert_eq!(metric_exposure(&[f32::NAN; 300], &mask), 1.0);
        assert_eq!(metric_exposure(&img, &[0.0; 100]), 1.0);
        // Background pixels do not count.
        let mut bright = img.clone();
        bright[0] = 1e9;
        let mut m2 = mask.clone();
        m2[0] = 0.0;
        assert_eq!(metric_exposure(&bright, &m2), metric_exposure(&img, &m2));
    }
}
