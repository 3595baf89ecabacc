//! The re-rendered object back in the photo, at the photo's resolution: inside the mask (blended
//! by its soft coverage) the render (or the photo changed by it), bilinearly resampled from the
//! detail square's pixels ([`crate::detail`]) and scaled back from the training exposure;
//! outside it the photo, untouched.

use super::photo::Photo;
use super::{Composite, Prepared};

/// Largest factor [`Composite::Ratio`] applies (where I' is nearly black the ratio is noise).
const MAX_RATIO: f32 = 16.0;

/// Bilinear sample of a `[3, S, S]` image at continuous pixel coordinates (centres at k + 0.5),
/// from the object's pixels only (weights renormalised over them); `None` where no object pixel
/// is among the four neighbours.
fn sample(img: &[f32], mask: &[f32], n: usize, u: f64, v: f64) -> Option<[f32; 3]> {
    let (x, y) = (u - 0.5, v - 0.5);
    let (x0, y0) = (x.floor(), y.floor());
    let (fx, fy) = (x - x0, y - y0);
    let mut acc = [0.0_f64; 3];
    let mut wsum = 0.0;
    for (dy, wy) in [(0, 1.0 - fy), (1, fy)] {
        for (dx, wx) in [(0, 1.0 - fx), (1, fx)] {
            let (xi, yi) = (x0 as i64 + dx, y0 as i64 + dy);
            if xi < 0 || yi < 0 || xi >= n as i64 || yi >= n as i64 {
                continue;
            }
            let k = yi as usize * n + xi as usize;
            let w = wx * wy;
            if mask[k] <= 0.0 || w <= 0.0 {
                continue;
            }
            for (c, a) in acc.iter_mut().enumerate() {
                *a += w * img[c * n * n + k] as f64;
            }
            wsum += w;
        }
    }
    (wsum > 0.0).then(|| acc.map(|a| (a / wsum) as f32))
}

/// The photo with `render` (`[3, S, S]`, at the training exposure) composited into the object.
/// `i_prime` is the re-rendered input, used by [`Composite::Ratio`].
pub fn composite(
    p: &Photo,
    coverage: &[f32],
    prep: &Prepared,
    render: &[f32],
    i_prime: &[f32],
    how: Composite,
) -> Vec<[f32; 3]> {
    let n = prep.size;
    let back = (1.0 / prep.exposure) as f32;
    let mut out = p.rgb.clone();
    for (k, o) in out.iter_mut().enumerate() {
        let c = coverage[k];
        if c <= 0.0 {
            continue;
        }
        let (x, y) = ((k % p.width) as f64 + 0.5, (k / p.width) as f64 + 0.5);
        let (u, v) = prep.framing.to_net(x, y);
        let Some(r) = sample(render, &prep.mask, n, u, v) else {
            continue;
        };
        let new = match how {
            Composite::Render => r.map(|v| v * back),
            Composite::Delta => {
                let Some(i) = sample(i_prime, &prep.mask, n, u, v) else {
                    continue;
                };
                std::array::from_fn(|ch| p.rgb[k][ch] + (r[ch] - i[ch]) * back)
            }
            Composite::Ratio => {
                let Some(i) = sample(i_prime, &prep.mask, n, u, v) else {
                    continue;
                };
                std::array::from_fn(|ch| {
                    let ratio = if i[ch] > 1e-6 {
                        (r[ch] / i[ch]).min(MAX_RATIO)
                    } else {
                        1.0
                    };
                    p.rgb[k][ch] * ratio
                })
            }
        };
        for ch in 0..3 {
            let v = c * new[ch] + (1.0 - c) * o[ch];
            o[ch] = if v.is_finite() { v.max(0.0) } else { o[ch] };
        }
    }
    out
}
