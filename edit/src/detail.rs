//! The object at the photo's own resolution.
//!
//! The network sees the photo at its input side S (64 or 256); a photo shows the object at
//! hundreds of pixels. Rendering the edit at S and upsampling it loses the wheels, windows and
//! edges a person looks at. Instead the same framing square is sampled again at about one
//! network pixel per photo pixel ([`detail_size`], at most [`MAX_DETAIL_SIZE`]), and the
//! network's normals are brought to it by **joint bilateral upsampling** (Kopf et al. 2007)
//! guided by the photo ([`upsample_normals`]): each fine pixel averages the coarse normals
//! around it, weighted by distance and by how much the coarse pixel's colour resembles its
//! own, so normals change where the photo has an edge and not across it. The rendering layer
//! then renders I* and O' at that resolution.

use super::Prepared;
use super::photo::{Framing, Photo};
use anyhow::Result;
use matedit_physics::tonemap::srgb_encode;

/// The most object pixels the detail square holds: the rendering layer's time grows with them,
/// and this many keep a plain edit within two seconds on two cores (docs/PERFORMANCE.md,
/// "Editing photos at their own resolution"). An object that spans more photo pixels is
/// rendered at a coarser detail square and composited from it bilinearly; the shading, delta
/// and ratio composites keep the photo's own detail at every pixel.
pub const MAX_DETAIL_OBJECT_PIXELS: usize = 32_768;

/// The largest side of the detail square, whatever the object.
pub const MAX_DETAIL_SIZE: usize = 1024;

/// Spatial σ of the upsampling, in network pixels.
const SIGMA_SPACE: f64 = 0.75;
/// Range σ of the upsampling, on sRGB-encoded [0, 1] colour at the training exposure.
const SIGMA_RANGE: f64 = 0.08;
/// Coarse pixels either side of the one under a fine pixel that the upsampling reads.
const RADIUS: i64 = 2;

/// The side of the detail square for a framing of an object of `object_pixels` photo pixels:
/// one pixel per photo pixel, or fewer where the object would exceed `max_object_pixels`;
/// never below the network's side nor above [`MAX_DETAIL_SIZE`].
pub fn detail_size(framing: &Framing, object_pixels: usize, max_object_pixels: usize) -> usize {
    if !framing.side.is_finite() || framing.side <= 0.0 {
        return framing.size;
    }
    let shrink = (max_object_pixels as f64 / object_pixels.max(1) as f64).sqrt().min(1.0);
    let side = (framing.side * shrink).ceil();
    (side.min(1e9) as usize).clamp(framing.size, MAX_DETAIL_SIZE.max(framing.size))
}

/// The object at the photo's resolution: the photo framed at [`detail_size`] with the coarse
/// input's framing and exposure, and the normals there.
#[derive(Clone, Debug)]
pub struct Detail {
    /// The fine framing, input, mask and region map (the coarse exposure).
    pub prep: Prepared,
    /// Normals `[3, F, F]`, zero off the object.
    pub normals: Vec<f32>,
}

/// Frames `p` again at [`detail_size`] (at most [`MAX_DETAIL_OBJECT_PIXELS`] object pixels)
/// around the coarse input's square and upsamples the coarse `normals` (`[3, S, S]`) to it.
pub fn detail(
    p: &Photo,
    coverage: &[f32],
    labels: Option<(&[u8], usize)>,
    coarse: &Prepared,
    normals: &[f32],
) -> Result<Detail> {
    let object = coverage.iter().filter(|&&c| c > 0.0).count();
    let framing = Framing {
        size: detail_size(&coarse.framing, object, MAX_DETAIL_OBJECT_PIXELS),
        ..coarse.framing
    };
    let prep = super::prepare_framed(p, coverage, labels, framing, Some(coarse.exposure))?;
    let normals = upsample_normals(coarse, normals, &prep);
    Ok(Detail { prep, normals })
}

fn guide(img: &[f32], k: usize, hw: usize) -> [f64; 3] {
    std::array::from_fn(|c| {
        let v = img[c * hw + k];
        let v = if v.is_finite() { v.clamp(0.0, 1.0) } else { 0.0 };
        srgb_encode(v) as f64
    })
}

/// Joint bilateral upsampling of the coarse normals (`[3, S, S]`, on `coarse`'s object) to
/// `fine`'s object pixels, guided by both inputs' colours; unit length, zero off the object.
/// A fine pixel whose neighbourhood holds no coarse object pixel takes the nearest one's normal;
/// one whose colour matches none of its neighbours' falls back to the spatial weights alone.
pub fn upsample_normals(coarse: &Prepared, normals: &[f32], fine: &Prepared) -> Vec<f32> {
    let (s, f) = (coarse.size, fine.size);
    let (hw, fw) = (s * s, f * f);
    let mut out = vec![0.0_f32; 3 * fw];
    let usable = |k: usize| {
        coarse.mask[k] > 0.0 && {
            let n = [normals[k], normals[hw + k], normals[2 * hw + k]];
            n.iter().all(|v| v.is_finite()) && n.iter().any(|&v| v != 0.0)
        }
    };
    // Without a single usable coarse normal every pixel faces the camera (and the nearest-pixel
    // search, which would scan the whole square for every fine pixel, is never run).
    if !(0..hw).any(usable) {
        for k in (0..fw).filter(|&k| fine.mask[k] > 0.0) {
            out[2 * fw + k] = 1.0;
        }
        return out;
    }
    let coarse_guide: Vec<[f64; 3]> = (0..hw).map(|k| guide(&coarse.input, k, hw)).collect();
    let scale = s as f64 / f as f64;
    let inv_space = 1.0 / (2.0 * SIGMA_SPACE * SIGMA_SPACE);
    let inv_range = 1.0 / (2.0 * SIGMA_RANGE * SIGMA_RANGE);
    for y in 0..f {
        for x in 0..f {
            let k = y * f + x;
            if fine.mask[k] <= 0.0 {
                continue;
            }
            let g = guide(&fine.input, k, fw);
            // The fine pixel's centre in coarse pixel units (coarse centres at i + 0.5).
            let (u, v) = ((x as f64 + 0.5) * scale, (y as f64 + 0.5) * scale);
            let (cx, cy) = (u.floor() as i64, v.floor() as i64);
            let mut joint = [0.0_f64; 4];
            let mut spatial = [0.0_f64; 4];
            for j in (cy - RADIUS).max(0)..=(cy + RADIUS).min(s as i64 - 1) {
                for i in (cx - RADIUS).max(0)..=(cx + RADIUS).min(s as i64 - 1) {
                    let c = j as usize * s + i as usize;
                    if !usable(c) {
                        continue;
                    }
                    let (du, dv) = (i as f64 + 0.5 - u, j as f64 + 0.5 - v);
                    let ws = (-(du * du + dv * dv) * inv_space).exp();
                    let gc = coarse_guide[c];
                    let d2: f64 = (0..3).map(|ch| (g[ch] - gc[ch]).powi(2)).sum::<f64>() / 3.0;
                    let wj = ws * (-d2 * inv_range).exp();
                    for ch in 0..3 {
                        joint[ch] += wj * normals[ch * hw + c] as f64;
                        spatial[ch] += ws * normals[ch * hw + c] as f64;
                    }
                    joint[3] += wj;
                    spatial[3] += ws;
                }
            }
            let sum = if joint[3] > 1e-6 * spatial[3] && joint[3] > 0.0 {
                joint
            } else if spatial[3] > 0.0 {
                spatial
            } else {
                match nearest(s, (u, v), &usable) {
                    Some(c) => [
                        normals[c] as f64,
                        normals[hw + c] as f64,
                        normals[2 * hw + c] as f64,
                        1.0,
                    ],
                    None => [0.0, 0.0, 1.0, 1.0],
                }
            };
            let n = unit_mean(sum);
            for ch in 0..3 {
                out[ch * fw + k] = n[ch] as f32;
            }
        }
    }
    out
}

/// The weighted mean of `sum` (`[Σ w·n, Σ w]`; the weights can be tiny) at unit length;
/// opposite normals that cancel face the camera.
fn unit_mean(sum: [f64; 4]) -> [f64; 3] {
    let mean = [sum[0] / sum[3], sum[1] / sum[3], sum[2] / sum[3]];
    let len = (mean[0] * mean[0] + mean[1] * mean[1] + mean[2] * mean[2]).sqrt();
    if len.is_finite() && len > 1e-6 {
        [mean[0] / len, mean[1] / len, mean[2] / len]
    } else {
        [0.0, 0.0, 1.0]
    }
}

/// The usable coarse pixel nearest to `(u, v)` (coarse pixel units), searched in growing
/// square rings (the caller checked that one exists).
fn nearest(s: usize, (u, v): (f64, f64), usable: &impl Fn(usize) -> bool) -> Option<usize> {
    let (cx, cy) = (u.floor() as i64, v.floor() as i64);
    let mut best: Option<(f64, usize)> = None;
    for r in 0..=s as i64 {
        for j in cy - r..=cy + r {
            for i in cx - r..=cx + r {
                if (j - cy).abs() != r && (i - cx).abs() != r {
                    continue;
                }
                if i < 0 || j < 0 || i >= s as i64 || j >= s as i64 {
                    continue;
                }
                let c = j as usize * s + i as usize;
                if !usable(c) {
                    continue;
                }
                let d = (i as f64 + 0.5 - u).powi(2) + (j as f64 + 0.5 - v).powi(2);
                if best.is_none_or(|(b, _)| d < b) {
                    best = Some((d, c));
                }
            }
        }
        // Every point of ring r + 1 lies at least r + ½ from (u, v): once the best is nearer, stop.
        if best.is_some_and(|(b, _)| b.sqrt() < r as f64 + 0.5) {
            break;
        }
    }
    best.map(|(_, c)| c)
}

/// The fine normals (`[3, F, F]` on `fine`'s object) averaged over each coarse pixel of
/// `coarse`'s object and made unit; a coarse pixel no fine object pixel falls in keeps its
/// normal from `fallback` (`[3, S, S]`).
pub fn downsample_normals(fine: &Prepared, normals: &[f32], coarse: &Prepared, fallback: &[f32]) -> Vec<f32> {
    let (s, f) = (coarse.size, fine.size);
    let (hw, fw) = (s * s, f * f);
    let mut sum = vec![[0.0_f64; 3]; hw];
    let scale = s as f64 / f as f64;
    for y in 0..f {
        for x in 0..f {
            let k = y * f + x;
            if fine.mask[k] <= 0.0 {
                continue;
            }
            let (cx, cy) = (
                (((x as f64 + 0.5) * scale) as usize).min(s - 1),
                (((y as f64 + 0.5) * scale) as usize).min(s - 1),
            );
            for (ch, a) in sum[cy * s + cx].iter_mut().enumerate() {
                *a += normals[ch * fw + k] as f64;
            }
        }
    }
    let mut out = fallback.to_vec();
    for (c, a) in sum.iter().enumerate() {
        if coarse.mask[c] <= 0.0 {
            continue;
        }
        let len = (a[0] * a[0] + a[1] * a[1] + a[2] * a[2]).sqrt();
        if len.is_finite() && len > 1e-9 {
            for ch in 0..3 {
                out[ch * hw + c] = (a[ch] / len) as f32;
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A square input of side `n`: colour `colour(x, y)` (linear, at the training exposure) on
    /// the pixels `on(x, y)`, one region.
    fn prepared(n: usize, on: impl Fn(usize, usize) -> bool, colour: impl Fn(usize, usize) -> [f32; 3]) -> Prepared {
        let p2 = n * n;
        let mut input = vec![0.0; 3 * p2];
        let mut mask = vec![0.0; p2];
        for y in 0..n {
            for x in 0..n {
                let k = y * n + x;
                if on(x, y) {
                    mask[k] = 1.0;
                    for (c, v) in colour(x, y).into_iter().enumerate() {
                        input[c * p2 + k] = v;
                    }
                }
            }
        }
        Prepared::square(n, input, mask, 1.0)
    }

    fn planar(n: usize, normal: impl Fn(usize, usize) -> [f32; 3]) -> Vec<f32> {
        let p2 = n * n;
        let mut out = vec![0.0; 3 * p2];
        for k in 0..p2 {
            for (c, v) in normal(k % n, k / n).into_iter().enumerate() {
                out[c * p2 + k] = v;
            }
        }
        out
    }

    fn at(v: &[f32], n: usize, x: usize, y: usize) -> [f32; 3] {
        [0, 1, 2].map(|c| v[c * n * n + y * n + x])
    }

    fn dist(a: [f32; 3], b: [f32; 3]) -> f32 {
        (0..3).map(|c| (a[c] - b[c]).powi(2)).sum::<f32>().sqrt()
    }

    #[test]
    fn the_detail_side_follows_the_photo_within_its_bounds() {
        let f = |side: f64, size: usize, object: usize| {
            detail_size(
                &Framing {
                    x0: -3.0,
                    y0: 2.0,
                    side,
                    size,
                },
                object,
                40_000,
            )
        };
        assert_eq!(f(300.2, 64, 30_000), 301, "one pixel per photo pixel");
        assert_eq!(f(400.0, 64, 160_000), 200, "half the side for four times the budget");
        assert_eq!(f(10.0, 64, 50), 64, "never below the network's side");
        assert_eq!(f(5000.0, 64, 1), MAX_DETAIL_SIZE);
        assert_eq!(f(5000.0, 2048, 1), 2048, "a network larger than the cap keeps its side");
        assert_eq!(f(300.0, 64, 0), 300);
        for bad in [f64::NAN, f64::INFINITY, -1.0, 0.0] {
            assert_eq!(f(bad, 64, 1000), 64, "{bad}");
        }
    }

    #[test]
    fn a_constant_normal_field_upsamples_and_downsamples_to_itself() {
        let n0 = [0.6, -0.0, 0.8];
        let disc = |r: f64, n: usize| {
            move |x: usize, y: usize| {
                let (u, v) = ((x as f64 + 0.5) / n as f64 - 0.5, (y as f64 + 0.5) / n as f64 - 0.5);
                u * u + v * v < r * r
            }
        };
        let coarse = prepared(16, disc(0.4, 16), |x, _| [0.1 * x as f32, 0.5, 0.2]);
        let fine = prepared(61, disc(0.4, 61), |x, _| [0.1 * x as f32 * 16.0 / 61.0, 0.5, 0.2]);
        let up = upsample_normals(&coarse, &planar(16, |_, _| n0), &fine);
        for k in 0..61 * 61 {
            let v = at(&up, 61, k % 61, k / 61);
            if fine.mask[k] > 0.0 {
                assert!(dist(v, n0) < 1e-6, "pixel {k}: {v:?}");
            } else {
                assert_eq!(v, [0.0; 3], "off the object");
            }
        }
        let down = downsample_normals(&fine, &up, &coarse, &vec![0.0; 3 * 256]);
        for k in (0..256).filter(|&k| coarse.mask[k] > 0.0) {
            assert!(dist(at(&down, 16, k % 16, k / 16), n0) < 1e-6);
        }
    }

    #[test]
    fn normals_change_where_the_photo_has_an_edge_not_across_it() {
        // Left of x = 0.43 (in units of the side) the object is red and tilted left, right of
        // it blue and tilted right. The edge falls inside a coarse pixel: bilinear upsampling
        // would blend the two normals over a whole coarse pixel on either side.
        let (s, f) = (16, 64);
        let edge = 0.43;
        let left = |x: usize, n: usize| (x as f64 + 0.5) / n as f64 <= edge;
        let colour = |l: bool| if l { [0.8, 0.05, 0.05] } else { [0.05, 0.05, 0.8] };
        let (nl, nr) = ([-0.6, 0.0, 0.8], [0.6, 0.0, 0.8]);
        let mix = |x: usize| {
            // The coarse pixel's share of the left side.
            let (a, b) = (x as f64 / s as f64, (x + 1) as f64 / s as f64);
            ((edge - a) / (b - a)).clamp(0.0, 1.0) as f32
        };
        let coarse = prepared(
            s,
            |_, _| true,
            |x, _| {
                let t = mix(x);
                let (l, r) = (colour(true), colour(false));
                [0, 1, 2].map(|c| t * l[c] + (1.0 - t) * r[c])
            },
        );
        let coarse_normals = planar(s, |x, _| {
            let t = mix(x);
            let v = [0, 1, 2].map(|c| t * nl[c] + (1.0 - t) * nr[c]);
            let len = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
            v.map(|c| c / len)
        });
        let fine = prepared(f, |_, _| true, |x, _| colour(left(x, f)));
        let up = upsample_normals(&coarse, &coarse_normals, &fine);
        // The two fine columns either side of the edge.
        let last_left = (0..f).filter(|&x| left(x, f)).max().unwrap();
        for y in [0, 17, 63] {
            let (a, b) = (at(&up, f, last_left, y), at(&up, f, last_left + 1, y));
            assert!(dist(a, nl) < 0.15, "left of the edge: {a:?}");
            assert!(dist(b, nr) < 0.15, "right of the edge: {b:?}");
            assert!(dist(a, b) > 1.0, "the edge is one fine pixel wide: {a:?} {b:?}");
        }
        // A uniform guide gives no edge: the same field blends across coarse pixels.
        let flat = prepared(f, |_, _| true, |_, _| [0.3; 3]);
        let flat_coarse = prepared(s, |_, _| true, |_, _| [0.3; 3]);
        let blurred = upsample_normals(&flat_coarse, &coarse_normals, &flat);
        assert!(dist(at(&blurred, f, last_left, 5), at(&blurred, f, last_left + 1, 5)) < 0.5);
    }

    #[test]
    fn unusable_coarse_normals_and_far_pixels_still_get_a_unit_normal() {
        // Coarse: one object pixel with a good normal, its neighbours NaN, zero or infinite.
        let s = 8;
        let coarse = prepared(s, |x, y| (2..5).contains(&x) && y == 1, |_, _| [0.5; 3]);
        let bad = planar(s, |x, _| match x {
            2 => [0.0, 0.6, 0.8],
            3 => [f32::NAN, 0.0, 1.0],
            _ => [0.0; 3],
        });
        let mut bad = bad;
        bad[2 * s * s + s + 4] = f32::INFINITY;
        // Fine: the whole square, much of it far from the coarse object.
        let fine = prepared(40, |_, _| true, |x, y| [0.01 * x as f32, 0.02 * y as f32, 0.9]);
        let up = upsample_normals(&coarse, &bad, &fine);
        for k in 0..1600 {
            let v = at(&up, 40, k % 40, k / 40);
            assert!(v.iter().all(|c| c.is_finite()), "pixel {k}: {v:?}");
            assert!((dist(v, [0.0; 3]) - 1.0).abs() < 1e-5, "pixel {k}: {v:?}");
            assert!(
                dist(v, [0.0, 0.6, 0.8]) < 1e-5,
                "pixel {k}: only one usable normal: {v:?}"
            );
        }
        // No usable coarse normal at all: facing the camera.
        let none = upsample_normals(&coarse, &vec![f32::NAN; 3 * s * s], &fine);
        assert_eq!(at(&none, 40, 7, 30), [0.0, 0.0, 1.0]);
    }
}
