//! Parametric material families: one analytic material per seed, its colour, albedo and
//! roughness drawn from continuous distributions. The library names a few dozen materials; a
//! module trained on those learns to name one of them, while a photo's object is none of them.
//! Drawn materials show it albedo, hue and gloss as quantities (the network's
//! albedo, and with it the edit's light level, was one value for every photo).
//!
//! A material is a function of its family and seed alone (as `builtin:sunsky:3` is of its
//! family and seed), so `parametric:plastic:17` is the same material in every dataset.

use crate::random::Draw;
use matedit_physics::{BrdfSpec, LUMINANCE_WEIGHTS as LUMINANCE};

/// A family of drawn materials.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ParametricFamily {
    /// A clear coat over a coloured diffuse base (`plastic:α:R,G,B`): plastics, paints,
    /// rubbers, glazes. Coat roughness α log-uniform in [0.05, 0.7]; the base's luminance
    /// log-uniform in [0.02, 0.85], its hue uniform, its HSV saturation uniform in [0, 1); no
    /// channel above 0.95 (a colour too saturated for its luminance is dimmed instead).
    Plastic,
    /// A metal (`ggx:α:F0`): GGX α log-uniform in [0.05, 0.6]; F0's luminance uniform in
    /// [0.45, 0.95], hue uniform, saturation uniform in [0, 0.6); no channel above 0.98.
    Metal,
}

/// The bounds a family's draws stay in (the documented ranges above).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Ranges {
    /// Roughness α: lowest and highest.
    pub alpha: [f64; 2],
    /// Luminance of the albedo (plastic) or F0 (metal): lowest and highest before dimming.
    pub luminance: [f64; 2],
    /// HSV saturation: lowest and highest.
    pub saturation: [f64; 2],
    /// No channel above this.
    pub max_channel: f64,
}

impl ParametricFamily {
    /// Every family.
    pub const ALL: [ParametricFamily; 2] = [ParametricFamily::Plastic, ParametricFamily::Metal];

    /// The name manifests and ids use.
    pub fn name(self) -> &'static str {
        match self {
            ParametricFamily::Plastic => "plastic",
            ParametricFamily::Metal => "metal",
        }
    }

    /// The family called `name`.
    pub fn parse(name: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|f| f.name() == name)
    }

    /// What the family draws from.
    pub fn ranges(self) -> Ranges {
        match self {
            ParametricFamily::Plastic => Ranges {
                alpha: [0.05, 0.7],
                luminance: [0.02, 0.85],
                saturation: [0.0, 1.0],
                max_channel: 0.95,
            },
            ParametricFamily::Metal => Ranges {
                alpha: [0.05, 0.6],
                luminance: [0.45, 0.95],
                saturation: [0.0, 0.6],
                max_channel: 0.98,
            },
        }
    }

    /// The material of `seed`.
    pub fn spec(self, seed: u64) -> BrdfSpec {
        let r = self.ranges();
        // One stream per family, so that a plastic and a metal of one seed are unrelated.
        let stream = match self {
            ParametricFamily::Plastic => 0x7061_7261_706c_6173, // "paraplas"
            ParametricFamily::Metal => 0x7061_7261_6d65_7461,   // "parameta"
        };
        let mut d = Draw::new(seed, stream);
        let alpha = round4(d.log_uniform(r.alpha[0], r.alpha[1]));
        let luminance = match self {
            ParametricFamily::Plastic => d.log_uniform(r.luminance[0], r.luminance[1]),
            ParametricFamily::Metal => d.uniform(r.luminance[0], r.luminance[1]),
        };
        let hue = d.uniform(0.0, 1.0);
        let saturation = d.uniform(r.saturation[0], r.saturation[1]);
        let colour = coloured(luminance, hue, saturation, r.max_channel);
        match self {
            ParametricFamily::Plastic => BrdfSpec::Plastic { alpha, albedo: colour },
            ParametricFamily::Metal => BrdfSpec::Ggx { alpha, f0: colour },
        }
    }
}

/// Four decimals: what a `--brdf` string would say, so an id's spec can be written out exactly.
fn round4(x: f64) -> f64 {
    (x * 1e4).round() / 1e4
}

/// An RGB colour of luminance `y` (or dimmer, where no channel may exceed `max_channel`), hue and
/// HSV saturation as given, rounded to four decimals and never below 1e-4.
fn coloured(y: f64, hue: f64, saturation: f64, max_channel: f64) -> [f64; 3] {
    let c = hsv(hue, saturation);
    let lum: f64 = (0..3).map(|i| c[i] * LUMINANCE[i]).sum();
    let peak = c.iter().copied().fold(0.0, f64::max);
    let scale = (y / lum).min(max_channel / peak);
    c.map(|v| round4(v * scale).clamp(1e-4, max_channel))
}

/// HSV with V = 1.
fn hsv(h: f64, s: f64) -> [f64; 3] {
    let h6 = (h.rem_euclid(1.0)) * 6.0;
    let sector = h6.floor();
    let f = h6 - sector;
    let (p, q, t) = (1.0 - s, 1.0 - s * f, 1.0 - s * (1.0 - f));
    match sector as u32 {
        0 => [1.0, t, p],
        1 => [q, 1.0, p],
        2 => [p, 1.0, t],
        3 => [p, q, 1.0],
        4 => [t, p, 1.0],
        _ => [1.0, p, q],
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn parts(spec: &BrdfSpec) -> (f64, [f64; 3]) {
        match spec {
            BrdfSpec::Plastic { alpha, albedo } => (*alpha, *albedo),
            BrdfSpec::Ggx { alpha, f0 } => (*alpha, *f0),
            other => panic!("unexpected spec {other:?}"),
        }
    }

    fn lum(c: [f64; 3]) -> f64 {
        (0..3).map(|i| c[i] * LUMINANCE[i]).sum()
    }

    #[test]
    fn a_seed_is_one_material() {
        for f in ParametricFamily::ALL {
            for seed in [0, 1, 17, u64::MAX] {
                assert_eq!(f.spec(seed), f.spec(seed));
            }
            assert_ne!(f.spec(0), f.spec(1));
            assert_eq!(ParametricFamily::parse(f.name()), Some(f));
        }
        assert_eq!(ParametricFamily::parse("wood"), None);
        // The families' streams differ: the same seed is not the same colour.
        assert_ne!(
            parts(&ParametricFamily::Plastic.spec(3)).1,
            parts(&ParametricFamily::Metal.spec(3)).1
        );
    }

    #[test]
    fn draws_stay_in_their_documented_ranges_and_build() {
        for f in ParametricFamily::ALL {
            let r = f.ranges();
            for seed in 0..20_000u64 {
                let spec = f.spec(seed.wrapping_mul(0x9E37_79B9_7F4A_7C15));
                let (alpha, c) = parts(&spec);
                assert!(alpha >= r.alpha[0] - 5e-5 && alpha <= r.alpha[1] + 5e-5, "{spec:?}");
                for v in c {
                    assert!(v.is_finite() && (1e-4..=r.max_channel).contains(&v), "{spec:?}");
                }
                // Dimming only lowers the luminance (rounding aside).
                assert!(lum(c) <= r.luminance[1] + 1e-3, "{spec:?}");
                assert!(spec.build().is_ok(), "{spec:?}");
            }
        }
    }

    #[test]
    fn plastics_cover_dark_to_light_and_every_hue() {
        let n = 4000;
        let specs: Vec<[f64; 3]> = (0..n).map(|s| parts(&ParametricFamily::Plastic.spec(s)).1).collect();
        let mut l: Vec<f64> = specs.iter().map(|&c| lum(c)).collect();
        l.sort_by(f64::total_cmp);
        // Log-uniform luminance: a tenth below 0.03, a tenth above 0.4 (dimming lowers some).
        assert!(l[n as usize / 10] < 0.035, "10th percentile {}", l[n as usize / 10]);
        assert!(
            l[n as usize * 9 / 10] > 0.35,
            "90th percentile {}",
            l[n as usize * 9 / 10]
        );
        // Every dominant channel, and greys, each a sizeable share.
        let mut dominant = [0usize; 3];
        let mut greys = 0;
        for c in &specs {
            let max = c.iter().copied().fold(0.0, f64::max);
            let min = c.iter().copied().fold(1.0, f64::min);
            if max - min < 0.1 * max {
                greys += 1;
            } else {
                let k = (0..3).max_by(|&a, &b| c[a].total_cmp(&c[b])).unwrap_or(0);
                dominant[k] += 1;
            }
        }
        for (k, &d) in dominant.iter().enumerate() {
            assert!(d > n as usize / 6, "channel {k} dominant in {d} of {n}");
        }
        assert!(greys > n as usize / 20, "{greys} greys of {n}");
    }

    #[test]
    fn colours_hit_their_luminance_unless_dimmed() {
        for (y, h, s) in [(0.02, 0.0, 0.0), (0.5, 0.3, 0.5), (0.85, 0.6, 0.0), (0.2, 0.99, 0.99)] {
            let c = coloured(y, h, s, 0.95);
            assert!((lum(c) - y).abs() < 2e-4, "{y} {h} {s}: {c:?}");
        }
        // Saturated blue cannot be bright: dimmed to its peak, not clipped per channel.
        let c = coloured(0.8, 4.0 / 6.0, 1.0, 0.95);
        assert_eq!(c, [1e-4, 1e-4, 0.95]);
        // Hue wraps.
        assert_eq!(hsv(1.25, 0.5), hsv(0.25, 0.5));
    }
}
