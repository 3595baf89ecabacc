//! The re-rendered object back in the photo, at the photo's resolution: inside the mask (blended
//! by its soft coverage) the render (or the photo changed by it), bilinearly resampled from the
//! detail square's pixels ([`crate::detail`]) and scaled back from the training exposure;
//! outside it the photo, untouched.

use super::Prepared;
use super::blur::masked_blur;
use super::photo::{Photo, luminance};

/// How the re-rendered object goes back into the photo.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, clap::ValueEnum, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Composite {
    /// The paper's: the object's pixels are O', rendered at the photo's resolution.
    Render,
    /// The photo's own luminance at every scale, times the change the render makes to it,
    /// O''s luminance over I*'s blurred (σ = 15 % of the framing square), in O''s colour: the
    /// layer says how much brighter or darker the object becomes and what colour, the photo
    /// where its light and shade lie (not in the paper; the best measured on the photo
    /// benchmark).
    #[default]
    Structure,
    /// O' times the photo's fine detail: the photo's luminance over I*'s, divided by the same
    /// ratio blurred; the large scale comes from the render, edges, texture and small shadows
    /// from the photo (not in the paper).
    Detail,
    /// O' times the photo's luminance over I*'s: O''s colour with the photo's light and shade
    /// (its edges, texture and what the layer does not model), achromatic, so the input's hue
    /// does not survive (not in the paper).
    Shading,
    /// The photo plus the edit's change, I + O' − I*: what the rendering layer cannot explain
    /// stays as the photo has it, its colour too (not in the paper).
    Delta,
    /// The photo times O'/I': the edit's change of shading and colour, with the photo's own
    /// detail kept at full resolution (not in the paper).
    Ratio,
}

impl Composite {
    /// The composite measured best for relighting on the photo benchmark (its objects under
    /// their own maps turned, docs/PERFORMANCE.md, "Relighting"): `ratio`, I × R(m*, L_new) /
    /// R(m*, L*). The material is the same in both renders, so what m* gets wrong of it cancels
    /// in the ratio, and the photo's own detail stays.
    pub fn best_for_relighting() -> Self {
        Self::Ratio
    }

    /// The composite measured best on the photo benchmark for what is known of the photo:
    /// `ratio` when the object's material is known (I × R(m_t)/R(m*) is exact when m* is right);
    /// `detail` when its light is given at a known level (O' is then at the right level and
    /// shaded by the right light, which `structure`'s shrunk, blurred change would discard);
    /// `structure` when both are the network's guesses (docs/PERFORMANCE.md, "The object's own
    /// material, given", "The photo's structure" and "What a photo-keeping composite can reach").
    pub fn best_for(known_material: bool, known_light: bool) -> Self {
        match (known_material, known_light) {
            (true, _) => Self::Ratio,
            (false, true) => Self::Detail,
            (false, false) => Self::Structure,
        }
    }
}

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

/// The blur that separates the photo's detail from its large-scale shading in
/// [`Composite::Detail`], as a fraction of the framing square's side (photo pixels).
pub const DETAIL_SIGMA_FRACTION: f64 = 0.04;

/// The photo with the edited object's `values` ([`object_values`], turned into the result in
/// place: a photo-sized buffer at a time, as a 25-megapixel edit's memory budget counts) blended
/// in by the soft coverage, each through `hold` (the photo's range, [`crate::range`]); the photo
/// where a value is not finite.
pub fn blend(
    p: &Photo,
    coverage: &[f32],
    mut values: Vec<[f32; 3]>,
    hold: impl Fn([f32; 3]) -> [f32; 3],
) -> Vec<[f32; 3]> {
    for ((o, &c), q) in values.iter_mut().zip(coverage).zip(&p.rgb) {
        if c <= 0.0 {
            *o = *q;
            continue;
        }
        let new = hold(*o);
        for ch in 0..3 {
            let v = c * new[ch] + (1.0 - c) * q[ch];
            o[ch] = if v.is_finite() { v.max(0.0) } else { q[ch] };
        }
    }
    values
}

/// What [`object_values`] holds where the photo is kept.
pub const KEEP: [f32; 3] = [f32::NAN; 3];

/// What the layer rendered at the detail square, for [`object_values`]: both `[3, S, S]` at the
/// training exposure.
#[derive(Clone, Copy)]
pub struct Renders<'a> {
    /// The render put into the photo (O', or the relit image).
    pub render: &'a [f32],
    /// I', the re-rendered input, used by every composite but [`Composite::Render`].
    pub i_prime: &'a [f32],
}

/// The edited object's value at every photo pixel ([`KEEP`] outside the object, or where no
/// rendered pixel lies near), in the photo's linear units, before [`blend`] puts it into the
/// photo: the render composited `how` ([`Renders`]).
pub fn object_values(p: &Photo, coverage: &[f32], prep: &Prepared, renders: Renders, how: Composite) -> Vec<[f32; 3]> {
    let Renders { render, i_prime } = renders;
    let n = prep.size;
    let back = (1.0 / prep.exposure) as f32;
    let mut out = vec![KEEP; p.rgb.len()];
    let gain = match how {
        Composite::Detail => Some(detail_gain(p, coverage, prep, i_prime)),
        Composite::Structure => Some(structure_gain(p, coverage, prep, render, i_prime)),
        _ => None,
    };
    for (k, o) in out.iter_mut().enumerate() {
        if coverage[k] <= 0.0 {
            continue;
        }
        let (u, v) = net_point(prep, p.width, k);
        let Some(r) = sample(render, &prep.mask, n, u, v) else {
            continue;
        };
        // I*, for the composites that compare the photo with it per pixel (`detail` did, for
        // its gain, above).
        let i = match how {
            Composite::Render | Composite::Detail | Composite::Structure => [0.0; 3],
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
            Composite::Detail | Composite::Structure => {
                let gain = gain.as_ref().map_or(1.0, |g| g[k]);
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
        *o = new;
    }
    out
}

/// The blur of [`Composite::Structure`]'s change, as a fraction of the framing square's side
/// (the CLI's help names it: keep the two together). The layer's estimates (n' at the network's
/// resolution, a light it does not place) are right, if at all, at large scales only. 4 % to
/// the whole square measured within 0.001 SSIM on the photo benchmark; 15 % had the most edits
/// better than the photo.
pub const STRUCTURE_SIGMA_FRACTION: f64 = 0.15;

/// The power [`Composite::Structure`]'s change is raised to: its logarithm shrunk by a quarter
/// towards no change. The change is estimated through m', whose albedo errs about ×2 either way
/// (docs/PERFORMANCE.md, "The light's level"), and a noisy estimate shrunk towards its prior
/// errs less: measured 0.75 against 1 and 0.5, on the photo benchmark and on 48 edits of scenes
/// it was not chosen on ("The photo's structure").
pub const STRUCTURE_CHANGE_POWER: f64 = 0.75;

/// [`Composite::Structure`]'s gain per photo pixel on O' (at the training exposure, scaled
/// back): the photo's luminance times the change O'/I* in luminance blurred at σ =
/// [`STRUCTURE_SIGMA_FRACTION`] of the framing's side and raised to [`STRUCTURE_CHANGE_POWER`],
/// over O''s luminance. So the result's luminance is the photo's times that smooth change, its
/// colour O''s. Where either render is black or not finite the gain is 1 (O' as rendered); it
/// is capped at [`MAX_RATIO`].
fn structure_gain(p: &Photo, coverage: &[f32], prep: &Prepared, render: &[f32], i_prime: &[f32]) -> Vec<f32> {
    let (w, h, n) = (p.width, p.height, prep.size);
    let back = 1.0 / prep.exposure;
    let mut change = vec![0.0_f32; w * h];
    let mut rendered = vec![0.0_f64; w * h];
    let mut valid = vec![false; w * h];
    for k in 0..w * h {
        if coverage[k] <= 0.0 {
            continue;
        }
        let (u, v) = net_point(prep, w, k);
        if let (Some(r), Some(i)) = (
            sample(render, &prep.mask, n, u, v),
            sample(i_prime, &prep.mask, n, u, v),
        ) {
            let (lr, li) = (luminance(r), luminance(i));
            if lr > 0.0 && li > 0.0 && lr.is_finite() && li.is_finite() {
                change[k] = (lr / li).powf(STRUCTURE_CHANGE_POWER).min(MAX_RATIO as f64) as f32;
                rendered[k] = lr * back;
                valid[k] = true;
            }
        }
    }
    let sigma = (STRUCTURE_SIGMA_FRACTION * prep.framing.side).max(1.0);
    let smooth = masked_blur(&change, &valid, w, h, sigma);
    (0..w * h)
        .map(|k| {
            if !valid[k] {
                return 1.0;
            }
            let g = luminance(p.rgb[k]) * smooth[k] as f64 / rendered[k];
            if g.is_finite() {
                g.min(MAX_RATIO as f64) as f32
            } else {
                1.0
            }
        })
        .collect()
}

/// Where the centre of photo pixel `k` (of a photo `width` wide) falls on the framing square,
/// in the network's pixels: where the renders are sampled for it.
fn net_point(prep: &Prepared, width: usize, k: usize) -> (f64, f64) {
    prep.framing.to_net((k % width) as f64 + 0.5, (k / width) as f64 + 0.5)
}

/// [`Composite::Detail`]'s gain per photo pixel: the photo's luminance over I*'s (capped), over
/// its own blur at σ = [`DETAIL_SIGMA_FRACTION`] of the framing's side. What the layer explains
/// at large scale (the object's shading) divides out to 1; edges, texture, small shadows and
/// what the network's resolution missed stay.
fn detail_gain(p: &Photo, coverage: &[f32], prep: &Prepared, i_prime: &[f32]) -> Vec<f32> {
    let (w, h, n) = (p.width, p.height, prep.size);
    let back = 1.0 / prep.exposure;
    let mut gain = vec![0.0_f32; w * h];
    let mut valid = vec![false; w * h];
    for k in 0..w * h {
        if coverage[k] <= 0.0 {
            continue;
        }
        let (u, v) = net_point(prep, w, k);
        if let Some(i) = sample(i_prime, &prep.mask, n, u, v) {
            let (lp, li) = (luminance(p.rgb[k]), luminance(i) * back);
            if li > 0.0 && lp.is_finite() && li.is_finite() {
                gain[k] = (lp / li).min(MAX_RATIO as f64) as f32;
                valid[k] = true;
            }
        }
    }
    let sigma = (DETAIL_SIGMA_FRACTION * prep.framing.side).max(1.0);
    let base = masked_blur(&gain, &valid, w, h, sigma);
    (0..w * h)
        .map(|k| {
            if valid[k] && base[k] > 0.0 {
                (gain[k] / base[k]).min(MAX_RATIO)
            } else {
                1.0
            }
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::photo::Encoding;

    const N: usize = 8;

    /// The photo with `render` (`[3, S, S]`, at the training exposure) composited into the
    /// object as rendered (no range held): `i_prime` is the re-rendered input.
    fn composite(
        p: &Photo,
        coverage: &[f32],
        prep: &Prepared,
        (render, i_prime): (&[f32], &[f32]),
        how: Composite,
    ) -> Vec<[f32; 3]> {
        blend(
            p,
            coverage,
            object_values(p, coverage, prep, Renders { render, i_prime }, how),
            |v| v,
        )
    }

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
        let prep = Prepared::square(N, vec![0.0; 3 * N * N], mask, 2.0);
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

    const ALL: [Composite; 6] = [
        Composite::Render,
        Composite::Structure,
        Composite::Detail,
        Composite::Shading,
        Composite::Delta,
        Composite::Ratio,
    ];

    #[test]
    fn a_render_that_explains_the_photo_gives_the_photo_back_and_the_background_is_untouched() {
        let (p, cov, prep) = scene();
        let same = planar(|k| p.rgb[k]);
        for how in ALL {
            let out = composite(&p, &cov, &prep, (&same, &same), how);
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
        let out = composite(&p, &cov, &prep, (&target, &i_star), Composite::Shading);
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
    fn detail_keeps_the_renders_large_scale_and_the_photos_fine_detail() {
        // A 64×64 photo whose object (the centre 48×48) has a smooth shading times a fine
        // checker texture; I* explains the smooth shading at half its level. The target's
        // render is a flat colour: the result is that colour times the checker (around 1),
        // not times the smooth shading or the factor 2 between photo and I*.
        let (p, coverage, prep, inside) = square(|k| smooth(k) * checker(k));
        let plane = |f: &dyn Fn(usize) -> f32| -> Vec<f32> { (0..3).flat_map(|_| (0..M * M).map(f)).collect() };
        let i_star = plane(&|k| 0.5 * smooth(k));
        let target = [0.1_f32, 0.6, 0.2];
        let render: Vec<f32> = (0..3).flat_map(|c| (0..M * M).map(move |_| target[c])).collect();
        let out = composite(&p, &coverage, &prep, (&render, &i_star), Composite::Detail);
        let mut worst = 0.0_f32;
        for k in (0..M * M).filter(|&k| inside(k)) {
            // Away from the mask's edge (where the blur sees fewer pixels) the checker's ±20 %
            // comes back within a few per cent.
            let (x, y) = (k % M, k / M);
            if !(14..50).contains(&x) || !(14..50).contains(&y) {
                continue;
            }
            for c in 0..3 {
                worst = worst.max((out[k][c] / (target[c] * checker(k)) - 1.0).abs());
            }
        }
        assert!(worst < 0.05, "worst relative error {worst}");
        for k in (0..M * M).filter(|&k| !inside(k)) {
            assert_eq!(out[k], p.rgb[k]);
        }
    }

    /// The side of [`square`]'s photo.
    const M: usize = 64;

    /// A smooth shading across [`square`]'s photo.
    fn smooth(k: usize) -> f32 {
        0.2 + 0.6 * (k % M) as f32 / M as f32
    }

    /// A fine ±20 % checker texture.
    fn checker(k: usize) -> f32 {
        if (k % M + k / M).is_multiple_of(2) { 1.2 } else { 0.8 }
    }

    /// A 64×64 linear photo whose object (the centre 48×48) is `photo(k)` (grey), with its
    /// coverage and framing (the whole photo, exposure 1).
    fn square(photo: impl Fn(usize) -> f32) -> (Photo, Vec<f32>, Prepared, impl Fn(usize) -> bool) {
        let inside = |k: usize| (8..56).contains(&(k % M)) && (8..56).contains(&(k / M));
        let rgb = (0..M * M)
            .map(|k| if inside(k) { [photo(k); 3] } else { [0.4, 0.5, 0.6] })
            .collect();
        let coverage: Vec<f32> = (0..M * M).map(|k| f32::from(u8::from(inside(k)))).collect();
        let prep = Prepared::square(M, vec![0.0; 3 * M * M], coverage.clone(), 1.0);
        let p = Photo {
            width: M,
            height: M,
            rgb,
            alpha: None,
            encoding: Encoding::Linear,
        };
        (p, coverage, prep, inside)
    }

    #[test]
    fn structure_keeps_the_photos_light_and_shade_and_takes_the_renders_change_and_colour() {
        // The photo: a smooth shading times a fine checker, which I* explains but for the
        // checker. O' is a colour T under the same shading, and, on the right half, twice as
        // bright: a sharp change the photo does not show (as wrong normals make).
        let (p, cov, prep, inside) = square(|k| smooth(k) * checker(k));
        let t = [0.1_f32, 0.6, 0.2];
        let t_lum = luminance(t) as f32;
        let plane = |f: &dyn Fn(usize, usize) -> f32| -> Vec<f32> {
            (0..3)
                .flat_map(|c| (0..M * M).map(move |k| (c, k)))
                .map(|(c, k)| f(c, k))
                .collect()
        };
        let i_star = plane(&|_, k| smooth(k));
        // A uniform change: exact at every σ, the photo's checker and shading times the change
        // (shrunk by its power), in T's colour.
        let even = plane(&|c, k| t[c] * smooth(k));
        let out = composite(&p, &cov, &prep, (&even, &i_star), Composite::Structure);
        let shrunk = |c: f32| c.powf(STRUCTURE_CHANGE_POWER as f32);
        for k in (0..M * M).filter(|&k| inside(k)) {
            for c in 0..3 {
                let want = t[c] / t_lum * shrunk(t_lum) * smooth(k) * checker(k);
                assert!((out[k][c] / want - 1.0).abs() < 1e-4, "pixel {k}: {:?}", out[k]);
            }
        }
        // The sharp step: blurred into a ramp, its luminance the photo's times a change
        // between the two sides' (T's luminance and twice it), rising across the step; the
        // colour T's.
        let step = |k: usize| if k % M >= 32 { 2.0 } else { 1.0 };
        let stepped = plane(&|c, k| t[c] * smooth(k) * step(k));
        let out = composite(&p, &cov, &prep, (&stepped, &i_star), Composite::Structure);
        let row = 30 * M;
        let change: Vec<f32> = (8..56)
            .map(|x| luminance(out[row + x]) as f32 / luminance(p.rgb[row + x]) as f32 / shrunk(t_lum))
            .collect();
        // Between the two sides' changes (T's luminance and twice it, each shrunk).
        let top = shrunk(2.0);
        assert!(change.windows(2).all(|w| w[1] >= w[0] - 1e-4), "{change:?}");
        assert!(
            change.iter().all(|&g| (1.0 - 1e-4..=top + 1e-4).contains(&g)),
            "{change:?}"
        );
        assert!(change[0] < 1.01 && change[47] > top - 0.01, "{change:?}");
        // No sharp edge survives: the largest step between neighbours is a fraction of the 1.0
        // the render has, spread over σ = 15 % of the square (about 10 pixels).
        let jump = change.windows(2).map(|w| w[1] - w[0]).fold(0.0_f32, f32::max);
        assert!(jump < 0.1, "largest jump {jump}: {change:?}");
        for k in (0..M * M).filter(|&k| inside(k)) {
            let o = out[k];
            let colour = [o[0] / o[1], o[2] / o[1]];
            assert!((colour[0] - t[0] / t[1]).abs() < 1e-4 && (colour[1] - t[2] / t[1]).abs() < 1e-4);
        }
        for k in (0..M * M).filter(|&k| !inside(k)) {
            assert_eq!(out[k], p.rgb[k]);
        }
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
                let out = composite(&p, &cov, &prep, (render, i_star), how);
                for (k, o) in out.iter().enumerate() {
                    assert!(o.iter().all(|v| v.is_finite() && *v >= 0.0), "{how:?} pixel {k}: {o:?}");
                    if cov[k] == 0.0 {
                        assert_eq!(*o, p.rgb[k]);
                    }
                }
            }
        }
        // A near-black I* under a bright photo: the gain is capped, not 10³⁰.
        let out = composite(&p, &cov, &prep, (&bright, &tiny), Composite::Shading);
        let k = 4 * N + 4;
        assert!(out[k][0] <= MAX_RATIO + 1e-4, "{:?}", out[k]);
    }
}
