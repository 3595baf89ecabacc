//! The re-rendered object back in the photo, at the photo's resolution: inside the mask (blended
//! by its soft coverage) the render (or the photo changed by it), bilinearly resampled from the
//! detail square's pixels ([`crate::detail`]) and scaled back from the training exposure;
//! outside it the photo, untouched.

use super::photo::{Photo, luminance};
use super::{Composite, Prepared};

/// Largest factor [`Composite::Ratio`] and [`Composite::Shading`] apply (where I* is nearly
/// black the ratio is noise).
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
        // I*, for the composites that compare the photo with it.
        let i = match how {
            Composite::Render => [0.0; 3],
            _ => match sample(i_prime, &prep.mask, n, u, v) {
                Some(i) => i,
                None => continue,
            },
        };
        let new = match how {
            Composite::Render => r.map(|v| v * back),
            Composite::Shading => {
                let (lp, li) = (luminance(p.rgb[k]), luminance(i) * back as f64);
                // I* black (a back-facing normal renders nothing): O' is black there too, and
                // the photo's light cannot be carried; otherwise the ratio, capped.
                let gain = if li > 0.0 {
                    (lp / li).min(MAX_RATIO as f64) as f32
                } else {
                    1.0
                };
                r.map(|v| v * back * gain)
            }
            Composite::Delta => std::array::from_fn(|ch| p.rgb[k][ch] + (r[ch] - i[ch]) * back),
            Composite::Ratio => std::array::from_fn(|ch| {
                let ratio = if i[ch] > 1e-6 {
                    (r[ch] / i[ch]).min(MAX_RATIO)
                } else {
                    1.0
                };
                p.rgb[k][ch] * ratio
            }),
        };
        for ch in 0..3 {
            let v = c * new[ch] + (1.0 - c) * o[ch];
            o[ch] = if v.is_finite() { v.max(0.0) } else { o[ch] };
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::photo::{Encoding, Framing};

    const N: usize = 8;

    /// An N×N photo whose object is the inner 4×4 (soft coverage ½ on its left column), framed
    /// one network pixel per photo pixel at exposure 2.
    fn scene() -> (Photo, Vec<f32>, Prepared) {
        let rgb: Vec<[f32; 3]> = (0..N * N)
            .map(|k| [0.1 + 0.01 * k as f32, 0.3, 0.05 + 0.002 * k as f32])
            .collect();
        let inside = |k: usize| (2..6).contains(&(k % N)) && (2..6).contains(&(k / N));
        let coverage: Vec<f32> = (0..N * N)
            .map(|k| match (inside(k), k % N) {
                (false, _) => 0.0,
                (true, 2) => 0.5,
                _ => 1.0,
            })
            .collect();
        let mask: Vec<f32> = (0..N * N).map(|k| f32::from(u8::from(inside(k)))).collect();
        let prep = Prepared {
            size: N,
            regions: 1,
            framing: Framing {
                x0: 0.0,
                y0: 0.0,
                side: N as f64,
                size: N,
            },
            exposure: 2.0,
            input: vec![0.0; 3 * N * N],
            region_map: mask.iter().map(|&m| m as u8).collect(),
            mask,
        };
        let photo = Photo {
            width: N,
            height: N,
            rgb,
            alpha: None,
            encoding: Encoding::Srgb8,
        };
        (photo, coverage, prep)
    }

    /// A `[3, N, N]` image at the training exposure from a per-pixel colour in photo units.
    fn planar(f: impl Fn(usize) -> [f32; 3]) -> Vec<f32> {
        let mut out = vec![0.0; 3 * N * N];
        for k in 0..N * N {
            for (c, v) in f(k).into_iter().enumerate() {
                out[c * N * N + k] = v * 2.0;
            }
        }
        out
    }

    const ALL: [Composite; 4] = [
        Composite::Render,
        Composite::Shading,
        Composite::Delta,
        Composite::Ratio,
    ];

    #[test]
    fn a_render_that_explains_the_photo_gives_the_photo_back_and_the_background_is_untouched() {
        let (p, cov, prep) = scene();
        let same = planar(|k| p.rgb[k]);
        for how in ALL {
            let out = composite(&p, &cov, &prep, &same, &same, how);
            for k in 0..N * N {
                if cov[k] == 0.0 {
                    assert_eq!(out[k], p.rgb[k], "{how:?}: background pixel {k} changed");
                } else {
                    for c in 0..3 {
                        assert!(
                            (out[k][c] - p.rgb[k][c]).abs() < 1e-5,
                            "{how:?} pixel {k}: {:?}",
                            out[k]
                        );
                    }
                }
            }
        }
    }

    #[test]
    fn shading_takes_the_colour_of_the_edit_and_the_light_and_shade_of_the_photo() {
        let (p, cov, prep) = scene();
        // I* explains half of the photo's luminance and none of its colour: grey.
        let i_star = planar(|k| [0.5 * luminance(p.rgb[k]) as f32; 3]);
        let target = planar(|_| [0.02, 0.2, 0.03]);
        let out = composite(&p, &cov, &prep, &target, &i_star, Composite::Shading);
        for k in (0..N * N).filter(|&k| cov[k] == 1.0) {
            // Gain 2 on the target's colour, whatever the photo's hue.
            for (c, t) in [0.02, 0.2, 0.03].into_iter().enumerate() {
                assert!((out[k][c] - 2.0 * t).abs() < 1e-5, "pixel {k}: {:?}", out[k]);
            }
        }
        // Soft coverage blends with the photo.
        let k = 3 * N + 2;
        assert!((out[k][1] - (0.5 * 0.4 + 0.5 * p.rgb[k][1])).abs() < 1e-5);
    }

    #[test]
    fn dark_or_broken_renders_never_reach_the_output() {
        let (p, cov, prep) = scene();
        let black = planar(|_| [0.0; 3]);
        let bright = planar(|_| [1.0; 3]);
        let nan = planar(|_| [f32::NAN; 3]);
        let inf = planar(|_| [f32::INFINITY, 0.0, 1.0]);
        let tiny = planar(|_| [1e-30; 3]);
        for how in ALL {
            for (render, i_star) in [
                (&bright, &black),
                (&bright, &tiny),
                (&black, &bright),
                (&nan, &bright),
                (&bright, &nan),
                (&inf, &bright),
                (&bright, &inf),
            ] {
                let out = composite(&p, &cov, &prep, render, i_star, how);
                for (k, o) in out.iter().enumerate() {
                    assert!(o.iter().all(|v| v.is_finite() && *v >= 0.0), "{how:?} pixel {k}: {o:?}");
                    if cov[k] == 0.0 {
                        assert_eq!(*o, p.rgb[k]);
                    }
                }
            }
        }
        // A near-black I* under a bright photo: the gain is capped, not 10³⁰.
        let out = composite(&p, &cov, &prep, &bright, &tiny, Composite::Shading);
        let k = 4 * N + 4;
        assert!(out[k][0] <= MAX_RATIO + 1e-4, "{:?}", out[k]);
    }
}
