//! The light's level from the photo's background. The network sees only the object, so L' comes
//! at whatever level makes I' = R(n', m', L') match the photo: a wrong m' (a dark material under
//! a bright light, or the reverse) puts L' at a wrong level, and every edit to another material
//! inherits the error (a chrome target twice too bright). Where the photo shows its
//! surroundings, they *are* the illumination seen from the object: each background pixel
//! looks along one direction of a perspective camera, so the background's radiance fixes L''s
//! level without going through m'.

use crate::photo::{Encoding, Photo, luminance, srgb_decode};
use matedit_trainer::model::LUMINANCE_WEIGHTS;

/// The horizontal field of view assumed when a photo does not say (degrees): a normal lens
/// (about 50 mm on 35 mm film).
pub const DEFAULT_FOV_DEG: f64 = 40.0;

/// At most this many background pixels are compared (a regular subsample beyond).
const MAX_SAMPLES: usize = 65_536;

/// Fewer usable background pixels than this (or than 2 % of the photo) leave the level to the
/// network: a cut-out photo or an object filling the frame says little about the light.
const MIN_SAMPLES: usize = 500;

/// How L's level was set.
#[derive(Clone, Debug, serde::Serialize, PartialEq)]
pub struct LightLevel {
    /// What set it.
    pub source: super::LevelSource,
    /// The factor L' was multiplied by (1 for "network").
    pub scale: f64,
    /// Background pixels compared.
    pub pixels: usize,
    /// The horizontal field of view the background's directions were computed with (degrees).
    pub fov_deg: f64,
    /// Where it came from: "given" (`--fov`), "exif" (the photo's 35 mm equivalent focal
    /// length, [`crate::photo::camera`]) or "default" ([`DEFAULT_FOV_DEG`]).
    pub fov_from: String,
    /// Why the background was not used, when it was not.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub note: Option<String>,
}

/// The direction a photo pixel looks along, in camera space (x right, y up, z towards the
/// viewer): a pinhole at the photo's centre with horizontal field of view `fov_deg`.
pub fn pixel_direction(x: f64, y: f64, width: usize, height: usize, fov_deg: f64) -> [f64; 3] {
    let t = (fov_deg.to_radians() / 2.0).tan();
    let (w, h) = (width as f64, height as f64);
    let dx = (2.0 * x / w - 1.0) * t;
    let dy = -(2.0 * y / h - 1.0) * t * h / w;
    let len = (dx * dx + dy * dy + 1.0).sqrt();
    [dx / len, dy / len, -1.0 / len]
}

/// L (`[3, He, 2He]`, docs/CONVENTIONS.md) along direction `d`, bilinear between texel centres
/// (wrapping in φ, clamped at the poles).
pub fn env_lookup(env: &[f32], env_height: usize, d: [f64; 3]) -> [f64; 3] {
    let (h, w) = (env_height, 2 * env_height);
    let theta = d[1].clamp(-1.0, 1.0).acos();
    let phi = d[0].atan2(-d[2]).rem_euclid(std::f64::consts::TAU);
    let u = phi / std::f64::consts::TAU * w as f64 - 0.5;
    let v = (theta / std::f64::consts::PI * h as f64 - 0.5).clamp(0.0, (h - 1) as f64);
    let (u0, v0) = (u.floor(), v.floor());
    let (fu, fv) = (u - u0, v - v0);
    let mut out = [0.0; 3];
    for (dv, wv) in [(0, 1.0 - fv), (1, fv)] {
        let row = (v0 as usize + dv).min(h - 1);
        for (du, wu) in [(0, 1.0 - fu), (1, fu)] {
            let col = (u0 as i64 + du).rem_euclid(w as i64) as usize;
            for (c, o) in out.iter_mut().enumerate() {
                *o += wu * wv * env[c * h * w + row * w + col] as f64;
            }
        }
    }
    out
}

/// L' (or L*) as the network's resolution and exposure have it, for [`light_level`].
#[derive(Clone, Copy)]
pub struct NetworkLight<'a> {
    /// Planar `[3, height, 2·height]`.
    pub env: &'a [f32],
    /// Its height.
    pub height: usize,
    /// The exposure the network saw the photo at.
    pub exposure: f64,
}

/// The horizontal field of view a photo's background is looked at with, and where it came
/// from: "given", "exif" or "default" (as [`LightLevel::fov_from`]).
#[derive(Clone, Copy)]
pub struct FieldOfView {
    /// Degrees.
    pub deg: f64,
    /// "given", "exif" or "default".
    pub from: &'static str,
}

/// The factor that puts `light` (at the network's exposure) at the level of the
/// photo's background: Σ lum(background) / Σ lum(L(direction of each background pixel)), over
/// the pixels off the object that are not clipped (8- and 16-bit photos saturate: a clipped sky
/// would read too dark). Falls back to the network's level, saying why, where the background
/// is too small, clipped, black or the light black along it.
pub fn light_level(p: &Photo, coverage: &[f32], light: NetworkLight, fov: FieldOfView) -> LightLevel {
    let NetworkLight {
        env,
        height: env_height,
        exposure,
    } = light;
    let FieldOfView {
        deg: fov_deg,
        from: fov_from,
    } = fov;
    let network = |pixels: usize, why: &str| LightLevel {
        source: super::LevelSource::Network,
        scale: 1.0,
        pixels,
        fov_deg,
        fov_from: fov_from.into(),
        note: Some(why.into()),
    };
    let clip = match p.encoding {
        Encoding::Srgb8 => srgb_decode(254.0 / 255.0),
        Encoding::Srgb16 => srgb_decode(65_000.0 / 65_535.0),
        Encoding::Linear => f32::INFINITY,
    };
    let total = p.width * p.height;
    let step = ((total as f64 / MAX_SAMPLES as f64).sqrt().ceil() as usize).max(1);
    let (mut photo_sum, mut light_sum, mut pixels, mut background) = (0.0_f64, 0.0_f64, 0_usize, 0_usize);
    for y in (0..p.height).step_by(step) {
        for x in (0..p.width).step_by(step) {
            let k = y * p.width + x;
            if coverage[k] > 0.0 {
                continue;
            }
            background += 1;
            let rgb = p.rgb[k];
            if !rgb.iter().all(|v| v.is_finite() && *v >= 0.0 && *v < clip) {
                continue;
            }
            let d = pixel_direction(x as f64 + 0.5, y as f64 + 0.5, p.width, p.height, fov_deg);
            let l = env_lookup(env, env_height, d);
            photo_sum += luminance(rgb) * exposure;
            light_sum += (0..3).map(|c| LUMINANCE_WEIGHTS[c] * l[c]).sum::<f64>();
            pixels += 1;
        }
    }
    let sampled = total.div_ceil(step * step).max(1);
    if pixels < MIN_SAMPLES || pixels * 50 < sampled {
        let why = if background * 50 < sampled || background < MIN_SAMPLES {
            "the photo shows too little background (under 2 % of its pixels, or 500)"
        } else {
            "the background is clipped (over-exposed) almost everywhere"
        };
        return network(pixels, why);
    }
    if photo_sum <= 0.0 {
        return network(pixels, "the background is black (a cut-out?)");
    }
    let scale = photo_sum / light_sum;
    if !(scale.is_finite() && scale > 0.0) {
        return network(pixels, "the predicted light is black where the background is seen");
    }
    LightLevel {
        source: super::LevelSource::Background,
        scale,
        pixels,
        fov_deg,
        fov_from: fov_from.into(),
        note: None,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn net(env: &[f32], height: usize, exposure: f64) -> NetworkLight<'_> {
        NetworkLight { env, height, exposure }
    }

    const DEFAULT: FieldOfView = FieldOfView {
        deg: DEFAULT_FOV_DEG,
        from: "default",
    };

    /// A `[3, H, 2H]` map from a function of the direction.
    fn map(h: usize, f: impl Fn([f64; 3]) -> [f32; 3]) -> Vec<f32> {
        let w = 2 * h;
        let mut env = vec![0.0; 3 * h * w];
        for j in 0..h {
            for i in 0..w {
                let d = matedit_physics::envmap::texel_direction(i, j, w, h).to_array();
                for (c, v) in f(d).into_iter().enumerate() {
                    env[c * h * w + j * w + i] = v;
                }
            }
        }
        env
    }

    #[test]
    fn directions_follow_the_pinhole_and_the_map_convention() {
        // The centre looks along −z, the right edge at half the field of view to the right,
        // the top edge up; every direction is unit.
        let c = pixel_direction(320.0, 240.0, 640, 480, 60.0);
        assert!((c[2] + 1.0).abs() < 1e-12 && c[0].abs() < 1e-12 && c[1].abs() < 1e-12);
        let r = pixel_direction(640.0, 240.0, 640, 480, 60.0);
        assert!((r[0].atan2(-r[2]).to_degrees() - 30.0).abs() < 1e-9, "{r:?}");
        let t = pixel_direction(320.0, 0.0, 640, 480, 60.0);
        assert!(t[1] > 0.0 && t[0].abs() < 1e-12);
        for d in [c, r, t, pixel_direction(0.0, 480.0, 640, 480, 170.0)] {
            assert!(((d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt() - 1.0).abs() < 1e-12);
        }
        // A map that is its direction's components plus 2 is read back as such (bilinear
        // reproduces it to the texel's size), at the poles and across the seam at −z too.
        let env = map(64, |d| [(d[0] + 2.0) as f32, (d[1] + 2.0) as f32, (d[2] + 2.0) as f32]);
        for d in [
            [0.0, 0.0, -1.0],
            [0.0, 0.0, 1.0],
            [1.0, 0.0, 0.0],
            [0.0, 1.0, 0.0],
            [0.0, -1.0, 0.0],
            [0.6, 0.0, -0.8],
            [-0.6, 0.48, -0.64],
        ] {
            let l = env_lookup(&env, 64, d);
            for c in 0..3 {
                assert!((l[c] - (d[c] + 2.0)).abs() < 0.05, "{d:?}: {l:?}");
            }
        }
    }

    /// A 640×480 photo whose object is the centre square; its background is `bg(direction)`.
    fn photo(encoding: Encoding, fov: f64, bg: impl Fn([f64; 3]) -> [f32; 3]) -> (Photo, Vec<f32>) {
        let (w, h) = (640, 480);
        let mut rgb = Vec::with_capacity(w * h);
        let mut coverage = Vec::with_capacity(w * h);
        for y in 0..h {
            for x in 0..w {
                let inside = (200..440).contains(&x) && (120..360).contains(&y);
                coverage.push(if inside { 1.0 } else { 0.0 });
                let d = pixel_direction(x as f64 + 0.5, y as f64 + 0.5, w, h, fov);
                rgb.push(if inside { [0.3; 3] } else { bg(d) });
            }
        }
        (
            Photo {
                width: w,
                height: h,
                rgb,
                alpha: None,
                encoding,
            },
            coverage,
        )
    }

    #[test]
    fn the_level_is_what_makes_the_light_reproduce_the_background() {
        // The background is the light itself at a 0.25 × level, seen at exposure 3: scale
        // 0.75 at every field of view, whatever the map's structure.
        let sky = |d: [f64; 3]| {
            let up = d[1].max(0.0) as f32;
            [0.2 + up, 0.3 + 0.5 * up, 0.6 + 0.1 * (d[0] as f32).abs()]
        };
        let env = map(64, sky);
        for fov in [10.0, 40.0, 90.0, 150.0] {
            let (p, cov) = photo(Encoding::Linear, fov, |d| sky(d).map(|v| v * 0.25));
            let level = light_level(
                &p,
                &cov,
                net(&env, 64, 3.0),
                FieldOfView {
                    deg: fov,
                    from: "given",
                },
            );
            assert_eq!(level.source.as_str(), "background", "{fov}: {level:?}");
            assert!((level.scale - 0.75).abs() < 0.75 * 0.01, "{fov}: {level:?}");
        }
    }

    #[test]
    fn clipped_small_black_or_broken_backgrounds_leave_the_level_to_the_network() {
        let env = map(16, |_| [1.0; 3]);
        // Clipped everywhere (8-bit white).
        let (p, cov) = photo(Encoding::Srgb8, 40.0, |_| [1.0; 3]);
        let l = light_level(&p, &cov, net(&env, 16, 1.0), DEFAULT);
        assert_eq!((l.source.as_str(), l.scale), ("network", 1.0));
        assert!(l.note.as_deref().is_some_and(|n| n.contains("clipped")), "{l:?}");
        // The same white in a linear photo is not clipped.
        let (p, cov) = photo(Encoding::Linear, 40.0, |_| [1.0; 3]);
        assert_eq!(
            light_level(&p, &cov, net(&env, 16, 1.0), DEFAULT).source,
            super::super::LevelSource::Background
        );
        // Black background (a cut-out), NaN/negative background, the object filling the frame.
        let (p, cov) = photo(Encoding::Srgb8, 40.0, |_| [0.0; 3]);
        assert!(
            light_level(&p, &cov, net(&env, 16, 1.0), DEFAULT)
                .note
                .unwrap()
                .contains("black")
        );
        let (p, cov) = photo(Encoding::Linear, 40.0, |d| {
            [if d[0] > 0.0 { f32::NAN } else { -1.0 }; 3]
        });
        assert_eq!(
            light_level(&p, &cov, net(&env, 16, 1.0), DEFAULT).source,
            super::super::LevelSource::Network
        );
        let (p, _) = photo(Encoding::Linear, 40.0, |_| [0.5; 3]);
        let full = vec![1.0; p.width * p.height];
        let l = light_level(&p, &full, net(&env, 16, 1.0), DEFAULT);
        assert!(l.note.unwrap().contains("too little background"));
        // A black light along the background: no level, no division by zero.
        let dark_back = map(16, |d| [if d[2] < 0.0 { 0.0 } else { 1.0 }; 3]);
        let (p, cov) = photo(Encoding::Linear, 40.0, |_| [0.5; 3]);
        let l = light_level(&p, &cov, net(&dark_back, 16, 1.0), DEFAULT);
        assert_eq!((l.source.as_str(), l.scale), ("network", 1.0), "{l:?}");
    }
}
