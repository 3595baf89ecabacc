//! Relighting (Fig. 4 of the paper): the level of the map the predicted material is rendered
//! under (`--relight`, `--relight-level`).

use crate::light::{renderable, scaled_by};
use anyhow::{Context, Result, bail};
use matedit_physics::envmap::texel_solid_angle;
use matedit_trainer::rendering_layer::MAX_RADIANCE;

/// What sets a relighting map's level.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, clap::ValueEnum, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum RelightLevel {
    /// The photo's light's: the map scaled to the mean radiance over the sphere of the light the
    /// edit found (L* at its level), so that the new light moves the object's light and shade
    /// and changes its colour but not its exposure (HDR maps are seldom calibrated to a photo).
    /// Each texel weighs its solid angle: an equirectangular map's polar rows are small.
    #[default]
    Light,
    /// The map's own values, radiance in the photo's linear units (as `--light-level given`).
    Given,
}

/// How a relighting map's level was set (`report.json`'s `relight_level`).
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct RelightLevelReport {
    /// What set it.
    pub source: RelightLevel,
    /// What the map's values were multiplied by, into the network's units.
    pub scale: f64,
}

/// The mean luminance of `l` (`[3, He, 2He]`) over the sphere, each texel weighted by its solid
/// angle; non-finite texels count as black.
pub fn mean_radiance(l: &[f32], env_height: usize) -> f64 {
    let (h, w) = (env_height, 2 * env_height);
    let n = h * w;
    if h == 0 || l.len() != 3 * n {
        return 0.0;
    }
    let mut sum = 0.0;
    for row in 0..h {
        let sa = texel_solid_angle(row, w, h);
        for k in row * w..(row + 1) * w {
            let y = 0.2126 * l[k] as f64 + 0.7152 * l[n + k] as f64 + 0.0722 * l[2 * n + k] as f64;
            if y.is_finite() {
                sum += y * sa;
            }
        }
    }
    sum / (4.0 * std::f64::consts::PI)
}

/// Refuses a relighting map that lights nothing (black, or no finite texel), before the edit
/// runs: [`at_level`] would refuse it only after the network.
pub fn check(l: &[f32], env_height: usize) -> Result<()> {
    lit_mean(l, env_height).map(|_| ())
}

/// [`mean_radiance`] of a map that lights something; a black one refused.
fn lit_mean(l: &[f32], env_height: usize) -> Result<f64> {
    let mean = mean_radiance(l, env_height);
    if !(mean.is_finite() && mean > 0.0) {
        bail!("the relighting map is black (mean radiance {mean:.3e}): it lights nothing");
    }
    Ok(mean)
}

/// The relighting map `l` at `level`, in the network's units: scaled to the mean radiance of
/// `light` (L*, the network's units) or by the photo's `exposure` (its own values). Refused
/// where that cannot be rendered: a black map asked to match a light, a scale that is not
/// finite, or a texel above what the layer renders.
pub fn at_level(
    l: &[f32],
    light: &[f32],
    env_height: usize,
    level: RelightLevel,
    exposure: f64,
) -> Result<(Vec<f32>, RelightLevelReport)> {
    let scale = match level {
        RelightLevel::Given => exposure,
        RelightLevel::Light => mean_radiance(light, env_height) / lit_mean(l, env_height)?,
    };
    if !(scale.is_finite() && scale >= 0.0) {
        bail!("the relighting map's level cannot be set: its scale would be {scale:.3e}");
    }
    let scaled = scaled_by(l, scale);
    if let Err(brightest) = renderable(&scaled) {
        bail!(
            "the relighting map is too bright at its level (--relight-level {}): its brightest texel \
             becomes {brightest:.3e}, above the {MAX_RADIANCE:.0e} the rendering layer renders",
            match level {
                RelightLevel::Light => "light",
                RelightLevel::Given => "given",
            }
        );
    }
    Ok((scaled, RelightLevelReport { source: level, scale }))
}

/// Another illumination to render the object's own material under (Fig. 4), read and checked.
pub struct Relight {
    /// Its spec, as given.
    pub spec: String,
    /// The map (`[3, He, 2He]`, camera space).
    pub env: Vec<f32>,
    /// What sets its level.
    pub level: RelightLevel,
}

impl Relight {
    /// The map a spec names, checked at the network's environment height.
    pub fn read(spec: &str, level: RelightLevel, env_height: usize) -> Result<Self> {
        let env = crate::target::relight_env(spec, env_height)?;
        check(&env, env_height).with_context(|| format!("--relight {spec}"))?;
        Ok(Self {
            spec: spec.to_string(),
            env,
            level,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn uniform(h: usize, rgb: [f32; 3]) -> Vec<f32> {
        rgb.iter().flat_map(|&v| std::iter::repeat_n(v, 2 * h * h)).collect()
    }

    #[test]
    fn a_uniform_maps_mean_is_its_luminance_at_every_resolution() {
        for h in [1, 2, 3, 8, 16, 64] {
            let m = mean_radiance(&uniform(h, [2.0, 1.0, 0.5]), h);
            let want = 0.2126 * 2.0 + 0.7152 + 0.0722 * 0.5;
            assert!((m - want).abs() < 1e-9 * want, "{h}: {m} vs {want}");
        }
        // Wrong sizes and broken texels read as no light, never NaN.
        assert_eq!(mean_radiance(&[1.0; 5], 2), 0.0);
        assert_eq!(mean_radiance(&[], 0), 0.0);
        let mut broken = uniform(4, [1.0; 3]);
        broken[3] = f32::NAN;
        broken[40] = f32::INFINITY;
        assert!(mean_radiance(&broken, 4).is_finite());
    }

    #[test]
    fn a_texel_near_a_pole_weighs_less_than_one_at_the_horizon() {
        // One bright texel, at the top row or at the equator: the sphere's mean sees its solid
        // angle, sin θ-weighted as an integral over the sphere would.
        let h = 16;
        let n = 2 * h * h;
        let at = |row: usize| {
            let mut l = vec![0.0_f32; 3 * n];
            for c in 0..3 {
                l[c * n + row * 2 * h] = 1.0;
            }
            mean_radiance(&l, h)
        };
        let (pole, equator) = (at(0), at(h / 2));
        let want = texel_solid_angle(h / 2, 2 * h, h) / texel_solid_angle(0, 2 * h, h);
        assert!(
            (equator / pole - want).abs() < 1e-9 * want && want > 10.0,
            "{pole} {equator}"
        );
    }

    #[test]
    fn the_light_level_matches_the_means_and_the_given_level_is_the_exposure() {
        let h = 8;
        let light = uniform(h, [3.0, 3.0, 3.0]);
        let mut map = uniform(h, [0.1, 0.2, 0.4]);
        map[5] = 50.0; // a sun
        let (scaled, r) = at_level(&map, &light, h, RelightLevel::Light, 7.0).unwrap();
        assert!((mean_radiance(&scaled, h) - 3.0).abs() < 1e-5, "{r:?}");
        // The layout and colour are the map's: every texel scaled alike.
        for (s, m) in scaled.iter().zip(&map) {
            assert!((s - m * r.scale as f32).abs() <= 1e-6 * s.abs().max(1.0));
        }
        let (given, g) = at_level(&map, &light, h, RelightLevel::Given, 7.0).unwrap();
        assert_eq!(
            g,
            RelightLevelReport {
                source: RelightLevel::Given,
                scale: 7.0
            }
        );
        assert_eq!(given[5], 350.0);
    }

    #[test]
    fn black_broken_and_too_bright_maps_are_refused_by_name() {
        let h = 4;
        let light = uniform(h, [1.0; 3]);
        let e = at_level(&uniform(h, [0.0; 3]), &light, h, RelightLevel::Light, 1.0).unwrap_err();
        assert!(e.to_string().contains("black"), "{e}");
        let e = at_level(&uniform(h, [1.0; 3]), &light, h, RelightLevel::Given, f64::NAN).unwrap_err();
        assert!(e.to_string().contains("scale"), "{e}");
        let e = at_level(&uniform(h, [1.0; 3]), &light, h, RelightLevel::Given, 1e7).unwrap_err();
        assert!(e.to_string().contains("--relight-level given"), "{e}");
        // All of a map's light in one texel, matched to a bright L*: past what the layer renders.
        let mut spike = uniform(h, [0.0; 3]);
        spike[0] = 1.0;
        let e = at_level(&spike, &uniform(h, [1e4; 3]), h, RelightLevel::Light, 1.0).unwrap_err();
        assert!(e.to_string().contains("--relight-level light"), "{e}");
    }

    #[test]
    fn negative_texels_and_odd_exposures_never_give_a_non_finite_or_negative_scale() {
        let h = 4;
        let light = uniform(h, [1.0; 3]);
        // HDR files carry small negative texels from their filtering: a map that is negative on
        // the whole lights nothing; one that is positive on the whole is scaled as any other.
        let e = at_level(&uniform(h, [-0.5; 3]), &light, h, RelightLevel::Light, 1.0).unwrap_err();
        assert!(e.to_string().contains("black"), "{e}");
        let mut mixed = uniform(h, [1.0; 3]);
        mixed[1] = -0.01;
        let (scaled, r) = at_level(&mixed, &light, h, RelightLevel::Light, 1.0).unwrap();
        assert!(
            r.scale.is_finite() && r.scale > 0.0 && scaled.iter().all(|v| v.is_finite()),
            "{r:?}"
        );
        // An exposure below zero or beyond f64 is refused; a light that is black scales any map
        // to black, never to NaN.
        for bad in [-1.0, f64::INFINITY, f64::NEG_INFINITY] {
            assert!(at_level(&light, &light, h, RelightLevel::Given, bad).is_err(), "{bad}");
        }
        let (dark, r) = at_level(&light, &uniform(h, [0.0; 3]), h, RelightLevel::Light, 1.0).unwrap();
        assert!(r.scale == 0.0 && dark.iter().all(|&v| v == 0.0), "{r:?}");
    }
}
