//! Procedural environment maps embedded in the binary.
//!
//! Two fixed maps (`sky`, `studio`) for previews, and four seeded families with physically
//! plausible dynamic range for datasets ([`Family`]): a clear sky with a sun (sun:sky irradiance
//! 3–8, peak radiance ~10⁴–10⁵ like real HDR captures), an overcast sky (CIE overcast
//! luminance, range < 10), a studio of 2–4 softboxes over a dark surround, and a room lit by a
//! window.

use super::random::Draw;
use anyhow::{Result, bail};
use glam::DVec3;
use matedit_physics::EnvMap;
use std::f64::consts::PI;

/// Names accepted by [`builtin`].
pub const BUILTIN_NAMES: &str =
    "sky, studio, constant:V, constant:R,G,B, sunsky:SEED, overcast:SEED, softbox:SEED, window:SEED";

/// A seeded family of procedural environments.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Family {
    /// Clear sky: blue gradient, circumsolar glow, a sun disc of 0.5°–1° radius, ground.
    SunSky,
    /// CIE standard overcast sky, L(θ) ∝ (1 + 2 cos θ)/3, over a dim ground.
    Overcast,
    /// Dark studio with 2–4 round softboxes.
    Softbox,
    /// Interior: dim walls, floor and ceiling, one bright window of sky, sometimes a lamp.
    Window,
}

impl Family {
    /// All families, in a fixed order.
    pub const ALL: [Family; 4] = [Family::SunSky, Family::Overcast, Family::Softbox, Family::Window];

    /// The family's name in `builtin:NAME:SEED`.
    pub fn name(self) -> &'static str {
        match self {
            Family::SunSky => "sunsky",
            Family::Overcast => "overcast",
            Family::Softbox => "softbox",
            Family::Window => "window",
        }
    }

    /// Generates the map of `seed` at `height` rows.
    pub fn generate(self, seed: u64, height: usize) -> EnvMap {
        let mut r = Draw::new(seed, self as u64 + 1);
        match self {
            Family::SunSky => sun_sky(&mut r, height),
            Family::Overcast => overcast(&mut r, height),
            Family::Softbox => softboxes(&mut r, height),
            Family::Window => window(&mut r, height),
        }
    }
}

fn dir(elevation_deg: f64, azimuth_deg: f64) -> DVec3 {
    matedit_physics::envmap::spherical_direction((90.0 - elevation_deg).to_radians(), azimuth_deg.to_radians())
}

fn cap_solid_angle(radius_deg: f64) -> f64 {
    2.0 * PI * (1.0 - radius_deg.to_radians().cos())
}

fn sun_sky(r: &mut Draw, height: usize) -> EnvMap {
    let sun = dir(r.uniform(8.0, 70.0), r.uniform(0.0, 360.0));
    let radius = r.uniform(0.5, 1.0);
    let turbidity = r.uniform(0.0, 1.0);
    let zenith = [0.18 + 0.2 * turbidity, 0.35 + 0.2 * turbidity, 0.85];
    let horizon = [0.9, 0.95, 1.05];
    let ground_albedo = r.uniform(0.1, 0.3);
    let ratio = r.uniform(3.0, 8.0);
    // Sky irradiance on a horizontal plane ≈ π × mean sky radiance (~0.7 here); the sun delivers
    // `ratio` times that at normal incidence.
    let sun_radiance = ratio * PI * 0.7 / cap_solid_angle(radius);
    let cos_r = radius.to_radians().cos();
    let ground = ground_albedo * (0.7 + ratio * 0.7 * sun.y.max(0.0));
    EnvMap::from_fn(height, |d| {
        if d.dot(sun) > cos_r {
            return [
                sun_radiance as f32,
                (sun_radiance * 0.96) as f32,
                (sun_radiance * 0.9) as f32,
            ];
        }
        if d.y < 0.0 {
            return [ground as f32, (ground * 0.9) as f32, (ground * 0.75) as f32];
        }
        let t = d.y.sqrt();
        let glow = 2.0 * (-(d.dot(sun).clamp(-1.0, 1.0).acos().to_degrees()) / 12.0).exp();
        std::array::from_fn(|c| ((horizon[c] * (1.0 - t) + zenith[c] * t) * (1.0 + glow)) as f32)
    })
}

fn overcast(r: &mut Draw, height: usize) -> EnvMap {
    let lz = r.log_uniform(0.5, 3.0);
    let tint = [r.uniform(0.95, 1.0), 1.0, r.uniform(1.0, 1.08)];
    let ground = lz * r.uniform(0.1, 0.25);
    EnvMap::from_fn(height, |d| {
        if d.y < 0.0 {
            return [ground as f32; 3];
        }
        let l = lz * (1.0 + 2.0 * d.y) / 3.0;
        tint.map(|t| (l * t) as f32)
    })
}

fn softboxes(r: &mut Draw, height: usize) -> EnvMap {
    let surround = r.uniform(0.02, 0.12);
    let boxes: Vec<(DVec3, f64, f64)> = (0..r.int(2, 4))
        .map(|_| {
            (
                dir(r.uniform(5.0, 80.0), r.uniform(0.0, 360.0)),
                r.uniform(6.0, 30.0).to_radians().cos(),
                r.log_uniform(5.0, 60.0),
            )
        })
        .collect();
    EnvMap::from_fn(height, |d| {
        let mut l = if d.y < 0.0 { surround * 0.5 } else { surround };
        for (c, cos_r, lb) in &boxes {
            if d.dot(*c) > *cos_r {
                l += lb;
            }
        }
        [l as f32; 3]
    })
}

fn window(r: &mut Draw, height: usize) -> EnvMap {
    let wall = r.uniform(0.05, 0.3);
    let floor = wall * r.uniform(0.5, 1.0);
    let sky = r.log_uniform(15.0, 150.0);
    let az = r.uniform(0.0, 360.0);
    let (half_w, el_lo, el_hi) = (r.uniform(15.0, 40.0), r.uniform(-5.0, 10.0), r.uniform(30.0, 60.0));
    let lamp = r.chance(0.5).then(|| {
        (
            dir(r.uniform(60.0, 90.0), r.uniform(0.0, 360.0)),
            r.log_uniform(50.0, 400.0),
        )
    });
    EnvMap::from_fn(height, |d| {
        let el = d.y.clamp(-1.0, 1.0).asin().to_degrees();
        let phi = d.x.atan2(-d.z).to_degrees();
        let dphi = ((phi - az).rem_euclid(360.0) + 180.0).rem_euclid(360.0) - 180.0;
        if dphi.abs() < half_w && el > el_lo && el < el_hi {
            // Sky through the window, slightly bluer and brighter towards the top.
            let t = (el - el_lo) / (el_hi - el_lo);
            return [
                (sky * (0.8 + 0.2 * t)) as f32,
                (sky * (0.85 + 0.2 * t)) as f32,
                (sky * (0.95 + 0.25 * t)) as f32,
            ];
        }
        if let Some((c, lr)) = lamp
            && d.dot(c) > 4f64.to_radians().cos()
        {
            return [lr as f32, (lr * 0.85) as f32, (lr * 0.6) as f32];
        }
        let l = if el < 0.0 {
            floor
        } else {
            wall * (1.0 + 0.5 * (el / 90.0))
        };
        [(l * 1.05) as f32, l as f32, (l * 0.9) as f32]
    })
}

/// Resolution of the procedural maps (rows).
const HEIGHT: usize = 256;

/// A procedural map by name:
/// * `sky`: clear sky (zenith blue to pale horizon), a sun of 2.5° radius with radiance 800 at
///   40° elevation, and a dark ground;
/// * `studio`: dim grey surround with a large overhead softbox and a smaller side softbox;
/// * `constant:V` or `constant:R,G,B`: uniform radiance (the furnace test's environment).
pub fn builtin(name: &str) -> Result<EnvMap> {
    if let Some(v) = name.strip_prefix("constant:") {
        let parts: Vec<f32> = v
            .split(',')
            .map(|s| s.trim().parse::<f32>())
            .collect::<Result<_, _>>()
            .map_err(|_| anyhow::anyhow!("builtin:constant:{v}: expected a radiance V or R,G,B"))?;
        let rgb = match parts[..] {
            [x] => [x; 3],
            [r, g, b] => [r, g, b],
            _ => bail!("builtin:constant:{v}: expected one or three values"),
        };
        if rgb.iter().any(|x| !x.is_finite() || *x < 0.0) {
            bail!("builtin:constant:{v}: radiance must be finite and non-negative");
        }
        return Ok(EnvMap::constant(HEIGHT, rgb));
    }
    if let Some((family, seed)) = name.split_once(':') {
        let Some(f) = Family::ALL.into_iter().find(|f| f.name() == family) else {
            bail!("builtin:{name}: unknown builtin environment (known: {BUILTIN_NAMES})");
        };
        let seed: u64 = seed
            .parse()
            .map_err(|_| anyhow::anyhow!("builtin:{name}: the seed must be an unsigned integer"))?;
        return Ok(f.generate(seed, HEIGHT));
    }
    match name {
        "sky" => Ok(EnvMap::from_fn(HEIGHT, sky)),
        "studio" => Ok(EnvMap::from_fn(HEIGHT, studio)),
        _ => bail!("builtin:{name}: unknown builtin environment (known: {BUILTIN_NAMES})"),
    }
}

fn sky(d: DVec3) -> [f32; 3] {
    let sun_dir = DVec3::new(0.5, 40f64.to_radians().sin(), 0.7).normalize();
    if d.dot(sun_dir) > 2.5f64.to_radians().cos() {
        return [800.0, 760.0, 700.0];
    }
    if d.y < 0.0 {
        return [0.12, 0.1, 0.08];
    }
    let t = d.y.powf(0.5);
    let horizon = [1.1, 1.15, 1.2];
    let zenith = [0.25, 0.45, 0.95];
    std::array::from_fn(|c| (horizon[c] * (1.0 - t) + zenith[c] * t) as f32)
}

fn studio(d: DVec3) -> [f32; 3] {
    let top = DVec3::new(0.0, 1.0, 0.3).normalize();
    let side = DVec3::new(-0.8, 0.2, 0.5).normalize();
    if d.dot(top) > 30f64.to_radians().cos() {
        [2.0; 3]
    } else if d.dot(side) > 12f64.to_radians().cos() {
        [6.0, 5.7, 5.4]
    } else {
        [0.15; 3]
    }
}

/// A tone-mapped thumbnail of a map (for contact sheets): resampled to `rows × 2·rows`, exposed
/// so that the median texel is mid-grey (0.18), then the preview tone map.
pub fn thumbnail(map: &EnvMap, rows: usize) -> Vec<[u8; 4]> {
    let small = map.resampled(rows, 0.0);
    let mut lum: Vec<f32> = small.texels().iter().map(|t| (t[0] + t[1] + t[2]) / 3.0).collect();
    lum.sort_by(|a, b| a.total_cmp(b));
    let median = lum[lum.len() / 2].max(1e-6);
    let exposure = 0.18 / median;
    small
        .texels()
        .iter()
        .map(|t| {
            let c = t.map(|v| matedit_physics::tonemap::tonemap_u8(v, exposure));
            [c[0], c[1], c[2], 255]
        })
        .collect()
}

/// Writes `count` maps of every family (`<family>_<seed>.exr`, seeds `seed .. seed+count`) at
/// `height` rows, and `envmaps.png`, a contact sheet with one row per family. Returns the paths.
pub fn write_family_set(
    dir: &std::path::Path,
    count: usize,
    seed: u64,
    height: usize,
) -> Result<Vec<std::path::PathBuf>> {
    use rayon::prelude::*;
    let jobs: Vec<(Family, u64)> = Family::ALL
        .iter()
        .flat_map(|&f| (0..count as u64).map(move |k| (f, seed + k)))
        .collect();
    let results: Vec<Result<(std::path::PathBuf, Vec<[u8; 4]>)>> = jobs
        .par_iter()
        .map(|&(f, s)| {
            let map = f.generate(s, height);
            let path = dir.join(format!("{}_{s}.exr", f.name()));
            matedit_contract::io::write_env_exr(&path, &map)?;
            Ok((path, thumbnail(&map, 64)))
        })
        .collect();
    let mut paths = Vec::new();
    let mut tiles = Vec::new();
    for r in results {
        let (p, t) = r?;
        paths.push(p);
        tiles.push(t);
    }
    let sheet = dir.join("envmaps.png");
    matedit_contract::io::write_contact_sheet(&sheet, &tiles, 128, 64, count.max(1))?;
    paths.push(sheet);
    Ok(paths)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn peak_over_median(m: &EnvMap) -> f64 {
        let mut v: Vec<f64> = m.texels().iter().map(|t| (t[0] + t[1] + t[2]) as f64 / 3.0).collect();
        v.sort_by(|a, b| a.total_cmp(b));
        v[v.len() - 1] / v[v.len() / 2]
    }

    #[test]
    fn families_are_deterministic_varied_and_have_plausible_dynamic_range() {
        for f in Family::ALL {
            let a = f.generate(3, 128);
            assert_eq!(a, f.generate(3, 128), "{f:?} is not a function of its seed");
            assert_ne!(a, f.generate(4, 128), "{f:?} ignores its seed");
            assert!(a.texels().iter().flatten().all(|v| v.is_finite() && *v >= 0.0));
        }
        for seed in 0..8 {
            // Real clear-sky captures peak 1e4–1e5 above their median; overcast skies do not.
            let sun = peak_over_median(&Family::SunSky.generate(seed, 512));
            assert!((1e3..1e6).contains(&sun), "sunsky {seed}: {sun}");
            let oc = peak_over_median(&Family::Overcast.generate(seed, 128));
            assert!(oc < 10.0, "overcast {seed}: {oc}");
            assert!(peak_over_median(&Family::Softbox.generate(seed, 128)) > 20.0);
            assert!(peak_over_median(&Family::Window.generate(seed, 128)) > 20.0);
        }
    }

    #[test]
    fn the_sun_carries_the_intended_share_of_irradiance() {
        // Irradiance on a surface facing the sun: direct/total between about 0.6 and 0.95.
        for seed in 0..5 {
            let m = Family::SunSky.generate(seed, 512);
            let peak = m.texels().iter().map(|t| t[0]).fold(0.0, f32::max);
            let (mut direct, mut total) = (0.0, 0.0);
            let mut sun_dir = DVec3::ZERO;
            for j in 0..m.height() {
                let sa = matedit_physics::envmap::texel_solid_angle(j, m.width(), m.height());
                for i in 0..m.width() {
                    if m.texel(i, j)[0] == peak {
                        sun_dir += matedit_physics::envmap::texel_direction(i, j, m.width(), m.height()) * sa;
                    }
                }
            }
            let n = sun_dir.normalize();
            for j in 0..m.height() {
                let sa = matedit_physics::envmap::texel_solid_angle(j, m.width(), m.height());
                for i in 0..m.width() {
                    let d = matedit_physics::envmap::texel_direction(i, j, m.width(), m.height());
                    let e = m.texel(i, j)[0] as f64 * sa * d.dot(n).max(0.0);
                    total += e;
                    if m.texel(i, j)[0] == peak {
                        direct += e;
                    }
                }
            }
            let share = direct / total;
            assert!((0.6..0.95).contains(&share), "seed {seed}: direct share {share}");
        }
    }

    #[test]
    fn builtins_exist_and_bad_names_are_explained() {
        for n in [
            "sky",
            "studio",
            "constant:1",
            "constant:0.5,1,2",
            "sunsky:0",
            "overcast:1",
            "softbox:2",
            "window:3",
        ] {
            let m = builtin(n).unwrap();
            assert_eq!(m.height(), HEIGHT);
            assert!(m.texels().iter().flatten().all(|v| v.is_finite() && *v >= 0.0));
        }
        assert!(builtin("nope").unwrap_err().to_string().contains("sky"));
        assert!(builtin("constant:x").is_err());
        assert!(builtin("constant:-1").is_err());
        assert!(builtin("constant:1,2").is_err());
        assert!(builtin("sunsky:x").unwrap_err().to_string().contains("seed"));
        assert!(builtin("moon:1").unwrap_err().to_string().contains("unknown"));
    }
}
