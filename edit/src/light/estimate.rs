//! What of L' an edit keeps: only what the checkpoint reads from a picture.
//!
//! The light's layout around the vertical axis and its colour are estimates only if the network
//! answers them from the picture; a network that gives every picture the same key light and the
//! same tint answers a prior (on the photo benchmark the quickstart's brightest texel is the same
//! one in every scene, its colour the same bluish one; docs/PERFORMANCE.md, "What the network's
//! L' carries of each photo"). [`LightSkill::measure`] asks the checkpoint once per loaded model
//! (`Model::light_skill`, when an edit first needs it): it renders a grey plastic sphere under one light turned to four azimuths and tinted warm and cool,
//! and measures how far L' follows. What it does not follow, an edit ([`LightEstimate::Auto`])
//! replaces by its expectation over what the picture did not say: L' averaged around the
//! vertical axis (lights are captured at any heading), and its colour neutral.

use crate::photo::{Encoding, Framing, Photo, luminance, prepare_framed};
use crate::predict::network_prediction;
use anyhow::{Context, Result};
use matedit_trainer::model::network::Net;
use matedit_trainer::rendering_layer::{LayerInput, RenderingLayer};

/// Which of L' an edit keeps.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, clap::ValueEnum, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum LightEstimate {
    /// What the checkpoint reads from a picture ([`LightSkill`]); the rest is averaged around the
    /// vertical axis or made neutral.
    #[default]
    Auto,
    /// L' as the network gives it (the paper's).
    Network,
}

/// The heading skill at and above which L''s layout around the vertical axis counts as read: the
/// skill is 0 for an L' that stays put, about 0.5 for one that changes but not with the light's
/// heading (chance), and 1 for one that turns with it.
pub const HEADING_READ: f64 = 0.75;
/// The colour skill at and above which L''s colour counts as read: the share of a tint L' shows
/// (0 for none; an L' showing half of every tint is nearer the truth than grey).
pub const COLOUR_READ: f64 = 0.5;
/// The turns of the probe's light: quarter turns, a whole number of columns for every map of an
/// even number of rows.
const TURNS: usize = 4;

/// Columns of the `k`-th of [`TURNS`] turns of a map of `h` rows.
fn turn_columns(k: usize, h: usize) -> usize {
    k * 2 * h / TURNS
}

/// How far a checkpoint's L' follows the light of its input, each in [0, 1].
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct LightSkill {
    /// Turning the light about the vertical axis: 0 when L' stays put, 1 when it turns along.
    pub azimuth: f64,
    /// Tinting the light: the share of the tint's change in log(red/blue) that L' shows.
    pub colour: f64,
}

/// What an edit did with L', for `report.json`.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct LightEstimateReport {
    /// What was asked.
    pub estimate: LightEstimate,
    /// The checkpoint's skills (measured for `auto` only).
    pub skill: Option<LightSkill>,
    /// L' was averaged around the vertical axis.
    pub averaged_around_vertical: bool,
    /// L''s colour was made neutral.
    pub made_neutral: bool,
}

/// The key light's lobe, exp(κ(cos − 1)): 21° across at half its peak, two texels of the probe's
/// 16 rows.
const KEY_SHARPNESS: f64 = 40.0;
/// Rows of the probe's light (at most the network's).
const PROBE_ROWS: usize = 16;
/// The warm and cool tints of [`LightSkill::measure`] (log(red/blue) ±0.6).
const TINTS: [[f64; 3]; 2] = [[1.35, 1.0, 0.74], [0.74, 1.0, 1.35]];

/// `[3, S, S]` normals of a sphere filling the square (camera space: +z towards the camera, y
/// up), its mask and region map.
fn sphere(s: usize) -> (Vec<f32>, Vec<f32>, Vec<u8>) {
    let p = s * s;
    let (mut n, mut mask, mut regions) = (vec![0.0_f32; 3 * p], vec![0.0_f32; p], vec![0_u8; p]);
    for k in 0..p {
        let x = ((k % s) as f64 + 0.5) / s as f64 * 2.0 - 1.0;
        let y = 1.0 - ((k / s) as f64 + 0.5) / s as f64 * 2.0;
        let r2 = x * x + y * y;
        if r2 < 0.9 {
            for (c, v) in [x, y, (1.0 - r2).sqrt()].into_iter().enumerate() {
                n[c * p + k] = v as f32;
            }
            mask[k] = 1.0;
            regions[k] = 1;
        }
    }
    (n, mask, regions)
}

/// `[3, h, 2h]`: a sky brighter towards the zenith over a dim ground, and a key light 35° above
/// the horizon, tinted `tint`.
fn probe_light(h: usize, tint: [f64; 3]) -> Vec<f32> {
    let (w, p) = (2 * h, 2 * h * h);
    let key = matedit_physics::envmap::spherical_direction(55f64.to_radians(), 300f64.to_radians());
    let mut l = vec![0.0_f32; 3 * p];
    for row in 0..h {
        for col in 0..w {
            let d = matedit_physics::envmap::texel_direction(col, row, w, h);
            let base = if d.y > 0.0 { 0.3 + 0.4 * d.y } else { 0.08 };
            let v = base + 40.0 * (KEY_SHARPNESS * (d.dot(key) - 1.0)).exp();
            for (c, t) in tint.iter().enumerate() {
                l[c * p + row * w + col] = (v * t) as f32;
            }
        }
    }
    l
}

/// `l` (`[3, h, 2h]`) turned about the vertical axis by `cols` columns.
fn turned(l: &[f32], h: usize, cols: usize) -> Vec<f32> {
    let w = 2 * h;
    let mut out = vec![0.0_f32; l.len()];
    for (k, v) in l.iter().enumerate() {
        let (plane_row, col) = (k / w, k % w);
        out[plane_row * w + (col + cols) % w] = *v;
    }
    out
}

/// Per-texel luminance of `l` (`[3, h, 2h]`) over its mean, each row's mean taken away: what of
/// the map changes around the vertical axis.
fn azimuthal_part(l: &[f32], h: usize) -> Vec<f64> {
    let (w, p) = (2 * h, 2 * h * h);
    let y: Vec<f64> = (0..p).map(|k| luminance([l[k], l[p + k], l[2 * p + k]])).collect();
    let mean = y.iter().sum::<f64>() / p as f64;
    let mean = if mean > 0.0 { mean } else { 1.0 };
    let mut out = vec![0.0; p];
    for row in 0..h {
        let r = &y[row * w..(row + 1) * w];
        let rm = r.iter().sum::<f64>() / w as f64;
        for col in 0..w {
            out[row * w + col] = (r[col] - rm) / mean;
        }
    }
    out
}

/// The azimuth skill of the L's (`[3, h, 2h]`) given for the probe's light turned by
/// [`turn_columns`] (`maps[k]` for the `k`-th turn): how much nearer each L' is to another turned
/// along than to it unturned. Solid-angle weights (sin θ per row) count every direction alike. 0
/// where every map is uniform around the axis.
fn azimuth_skill(maps: &[Vec<f32>], h: usize) -> f64 {
    let (w, n) = (2 * h, maps.len());
    debug_assert_eq!(n, TURNS);
    let parts: Vec<Vec<f64>> = maps.iter().map(|m| azimuthal_part(m, h)).collect();
    let weight = |t: usize| (((t / w) as f64 + 0.5) * std::f64::consts::PI / h as f64).sin();
    let (mut stays, mut turns) = (0.0, 0.0);
    for (j, a) in parts.iter().enumerate() {
        for (k, b) in parts.iter().enumerate().filter(|(k, _)| *k != j) {
            let shift = turn_columns((k + n - j) % n, h);
            for t in 0..a.len() {
                let (row, col) = (t / w, t % w);
                let along = a[row * w + (col + w - shift) % w];
                stays += weight(t) * (b[t] - a[t]).powi(2);
                turns += weight(t) * (b[t] - along).powi(2);
            }
        }
    }
    if stays + turns > 0.0 {
        stays / (stays + turns)
    } else {
        0.0
    }
}

/// The share of a tint's change `asked` (in log(red/blue)) that L' `shown`, in [0, 1]; 0 where
/// it is not a number.
fn colour_skill(asked: f64, shown: f64) -> f64 {
    let share = shown / asked;
    if share.is_finite() { share.clamp(0.0, 1.0) } else { 0.0 }
}

/// The mean of each channel of `l` (`[3, …]`).
fn channel_means(l: &[f32]) -> [f64; 3] {
    let p = l.len() / 3;
    std::array::from_fn(|c| l[c * p..(c + 1) * p].iter().map(|&v| v as f64).sum::<f64>() / p.max(1) as f64)
}

/// log(red/blue) of `l`'s mean colour.
fn red_over_blue(l: &[f32]) -> f64 {
    let [r, _, b] = channel_means(l);
    (r.max(1e-30) / b.max(1e-30)).ln()
}

impl LightEstimate {
    /// Applies this choice to `env` (`[3, h, 2h]`, L'); `skill` gives the checkpoint's skill,
    /// asked for `auto` only.
    pub fn apply(
        self,
        skill: impl FnOnce() -> Result<LightSkill>,
        env: &mut [f32],
        h: usize,
    ) -> Result<LightEstimateReport> {
        Ok(match self {
            LightEstimate::Auto => skill()?.apply(env, h),
            LightEstimate::Network => LightEstimateReport {
                estimate: self,
                skill: None,
                averaged_around_vertical: false,
                made_neutral: false,
            },
        })
    }
}

impl LightEstimateReport {
    /// One line saying what of L' was replaced and why, when something was.
    pub fn describe(&self) -> Option<String> {
        let skill = self.skill?;
        let (what, unread, skills) = match (self.averaged_around_vertical, self.made_neutral) {
            (true, true) => (
                "averaged around the vertical axis and made neutral",
                "reads neither the light's heading nor its colour",
                format!("heading {:.2}, colour {:.2}", skill.azimuth, skill.colour),
            ),
            (true, false) => (
                "averaged around the vertical axis",
                "does not read the light's heading",
                format!("heading {:.2}", skill.azimuth),
            ),
            (false, true) => (
                "made neutral",
                "does not read the light's colour",
                format!("colour {:.2}", skill.colour),
            ),
            (false, false) => return None,
        };
        Some(format!(
            "light: L' {what}: this checkpoint {unread} from a picture ({skills}, of 1; \
             --light-estimate network keeps L' as it is)"
        ))
    }
}

impl LightSkill {
    /// Asks the checkpoint (its network `net`, of input side `size` and `env_height` rows of
    /// light) what it reads of the light: six renders of the probe and six passes of the network.
    pub fn measure(net: &Net, size: usize, env_height: usize) -> Result<Self> {
        // The probe's pictures need only a light as sharp as its key: rendered under fewer rows
        // than the network answers in, they cost a quarter (or less) of the layer's time.
        // Even, so that a quarter turn is a whole number of columns.
        let h = (PROBE_ROWS.min(env_height) / 2 * 2).max(2);
        let layer = RenderingLayer::new(h);
        let (normals, mask, region_map) = sphere(size);
        let (m, _) = crate::target::dsbrdf_of("plastic:0.1:0.5,0.5,0.5")?;
        let material: Vec<f32> = m.to_normalised().map(|v| v as f32).to_vec();
        // Each render is a linear photo of the sphere, framed one pixel per network pixel and
        // exposed as any photo is (`prepare_framed`), then shown to the network.
        let framing = Framing {
            x0: 0.0,
            y0: 0.0,
            side: size as f64,
            size,
        };
        let look = |l: &[f32]| -> Result<Vec<f32>> {
            let img = layer.forward(&LayerInput::one_region(size, &normals, &region_map, &material, l))?;
            let p = size * size;
            let photo = Photo {
                width: size,
                height: size,
                rgb: (0..p).map(|k| [img[k], img[p + k], img[2 * p + k]]).collect(),
                alpha: None,
                encoding: Encoding::Linear,
            };
            let prep = prepare_framed(&photo, &mask, None, framing, None).context("the light probe")?;
            Ok(network_prediction(net, &prep)?.env)
        };
        let white = probe_light(h, [1.0; 3]);
        let turns: Vec<Vec<f32>> = (0..TURNS)
            .map(|k| look(&turned(&white, h, turn_columns(k, h))))
            .collect::<Result<_>>()?;
        let [warm, cool] = TINTS.map(|t| probe_light(h, t));
        let asked = red_over_blue(&warm) - red_over_blue(&cool);
        let shown = red_over_blue(&look(&warm)?) - red_over_blue(&look(&cool)?);
        Ok(Self {
            azimuth: azimuth_skill(&turns, env_height),
            colour: colour_skill(asked, shown),
        })
    }

    /// Replaces in `env` (`[3, h, 2h]`, L') what this skill does not read by its expectation.
    pub fn apply(&self, env: &mut [f32], h: usize) -> LightEstimateReport {
        let report = LightEstimateReport {
            estimate: LightEstimate::Auto,
            skill: Some(*self),
            averaged_around_vertical: self.azimuth < HEADING_READ,
            made_neutral: self.colour < COLOUR_READ,
        };
        if report.averaged_around_vertical {
            average_around_vertical(env, h);
        }
        if report.made_neutral {
            make_neutral(env);
        }
        report
    }
}

/// Every row of `env` (`[3, h, 2h]`, per channel) replaced by its mean: the map averaged over
/// every turn about the vertical axis.
pub fn average_around_vertical(env: &mut [f32], h: usize) {
    let w = 2 * h;
    for row in env.chunks_mut(w) {
        let mean = row.iter().map(|&v| v as f64).sum::<f64>() / w as f64;
        row.fill(mean as f32);
    }
}

/// `env` (`[3, …]`) with its mean colour made grey: each channel times the mean of the three
/// channel means over its own.
pub fn make_neutral(env: &mut [f32]) {
    let p = env.len() / 3;
    let means = channel_means(env);
    let grey = means.iter().sum::<f64>() / 3.0;
    for (c, m) in means.iter().enumerate() {
        let k = if *m > 0.0 && grey.is_finite() {
            (grey / m) as f32
        } else {
            1.0
        };
        env[c * p..(c + 1) * p].iter_mut().for_each(|v| *v *= k);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const H: usize = 8;

    /// A `[3, H, 2H]` map: `f(row, col)` in every channel times `tint`.
    fn map(f: impl Fn(usize, usize) -> f32, tint: [f32; 3]) -> Vec<f32> {
        let p = 2 * H * H;
        let mut l = vec![0.0; 3 * p];
        for k in 0..p {
            for c in 0..3 {
                l[c * p + k] = f(k / (2 * H), k % (2 * H)) * tint[c];
            }
        }
        l
    }

    fn key(row: usize, col: usize) -> f32 {
        0.2 + if row == 2 && col == 3 { 50.0 } else { 0.0 } + 0.1 * col as f32
    }

    #[test]
    fn the_azimuth_skill_is_one_for_a_light_that_turns_along_and_zero_for_one_that_stays() {
        let l = map(key, [1.0; 3]);
        let along: Vec<Vec<f32>> = (0..TURNS).map(|k| turned(&l, H, turn_columns(k, H))).collect();
        let stays = vec![l.clone(); 4];
        assert!((azimuth_skill(&along, H) - 1.0).abs() < 1e-12);
        assert!(azimuth_skill(&stays, H).abs() < 1e-12);
        // Half of each: in between.
        let half: Vec<Vec<f32>> = along
            .iter()
            .map(|a| a.iter().zip(&l).map(|(a, b)| 0.5 * (a + b)).collect())
            .collect();
        let s = azimuth_skill(&half, H);
        assert!(s > 0.2 && s < 0.8, "{s}");
        // Uniform around the axis, or black: nothing to follow.
        let rows = vec![map(|row, _| 1.0 + row as f32, [1.0; 3]); 4];
        assert_eq!(azimuth_skill(&rows, H), 0.0);
        assert_eq!(azimuth_skill(&vec![vec![0.0; 6 * H * H]; 4], H), 0.0);
        // A turn of a whole map is a roll of its columns.
        let t = turned(&l, H, 3);
        assert_eq!(t[2 * (2 * H) + 6], l[2 * (2 * H) + 3]);
        assert_eq!(turned(&l, H, 2 * H), l);
        // The colour skill: a share of the tint, whatever L' answered.
        assert_eq!(colour_skill(1.2, 0.6), 0.5);
        assert_eq!(colour_skill(1.2, 2.4), 1.0);
        assert_eq!(colour_skill(1.2, -0.3), 0.0);
        for shown in [f64::NAN, f64::INFINITY, f64::NEG_INFINITY] {
            assert_eq!(colour_skill(1.2, shown), 0.0, "{shown}");
        }
        assert_eq!(colour_skill(0.0, 0.0), 0.0);
    }

    #[test]
    fn averaging_around_the_vertical_keeps_each_rows_mean_and_making_neutral_the_level() {
        let mut l = map(key, [1.2, 1.0, 0.6]);
        let before = l.clone();
        average_around_vertical(&mut l, H);
        let w = 2 * H;
        for (r, (a, b)) in l.chunks(w).zip(before.chunks(w)).enumerate() {
            let (ma, mb) = (a.iter().sum::<f32>() / w as f32, b.iter().sum::<f32>() / w as f32);
            assert!((ma - mb).abs() <= 1e-5 * mb, "row {r}");
            assert!(a.iter().all(|&v| v == a[0]), "row {r} not uniform");
        }
        let mut n = before.clone();
        make_neutral(&mut n);
        let p = n.len() / 3;
        let mean = |v: &[f32], c: usize| v[c * p..(c + 1) * p].iter().map(|&x| x as f64).sum::<f64>() / p as f64;
        let grey = (0..3).map(|c| mean(&before, c)).sum::<f64>() / 3.0;
        for c in 0..3 {
            assert!((mean(&n, c) - grey).abs() < 1e-5 * grey, "channel {c}");
        }
        // Black, a black channel, and NaN: finite, and what cannot be made grey is left.
        let mut black = vec![0.0; 6 * H * H];
        make_neutral(&mut black);
        assert!(black.iter().all(|&v| v == 0.0));
        let mut no_blue = map(key, [1.0, 1.0, 0.0]);
        make_neutral(&mut no_blue);
        assert!(no_blue.iter().all(|v| v.is_finite()));
        let mut nan = map(key, [1.0; 3]);
        nan[0] = f32::NAN;
        make_neutral(&mut nan);
        assert!(nan[1..].iter().all(|v| v.is_finite()));
    }

    #[test]
    fn an_estimate_drops_only_what_the_checkpoint_does_not_read() {
        let l = map(key, [1.2, 1.0, 0.6]);
        for (azimuth, colour) in [(0.0, 0.0), (0.9, 0.0), (0.0, 0.9), (0.9, 0.9), (0.6, 0.6), (0.75, 0.5)] {
            let skill = LightSkill { azimuth, colour };
            let (avg, neutral) = (azimuth < HEADING_READ, colour < COLOUR_READ);
            let mut kept = l.clone();
            let never = || -> Result<LightSkill> { panic!("`network` asks for no skill") };
            let r = LightEstimate::Network.apply(never, &mut kept, H).unwrap();
            assert_eq!(kept, l);
            assert!(!r.averaged_around_vertical && !r.made_neutral && r.describe().is_none());
            let mut auto = l.clone();
            let r = LightEstimate::Auto.apply(|| Ok(skill), &mut auto, H).unwrap();
            assert_eq!(r.skill, Some(skill));
            assert_eq!(
                (r.averaged_around_vertical, r.made_neutral),
                (avg, neutral),
                "{skill:?}"
            );
            // The line names what was replaced, and only that skill's figure.
            match r.describe() {
                None => assert!(!avg && !neutral),
                Some(line) => {
                    assert_eq!(line.contains("averaged around"), avg, "{line}");
                    assert_eq!(line.contains("heading"), avg, "{line}");
                    assert_eq!(line.contains("neutral"), neutral, "{line}");
                    assert_eq!(line.contains(&format!("colour {colour:.2}")), neutral, "{line}");
                    assert_eq!(line.contains(&format!("heading {azimuth:.2}")), avg, "{line}");
                    assert!(line.contains("--light-estimate network"), "{line}");
                }
            }
            let mut expected = l.clone();
            if avg {
                average_around_vertical(&mut expected, H);
            }
            if neutral {
                make_neutral(&mut expected);
            }
            assert_eq!(auto, expected);
        }
    }

    #[test]
    fn an_l_prime_that_changes_but_not_with_the_heading_scores_chance_and_counts_as_not_read() {
        // Four unrelated layouts (a fixed pseudo-random texel pattern each).
        let noise = |seed: u32| {
            map(
                move |row, col| {
                    let x = (row as u32 * 2654435761) ^ (col as u32 * 40503) ^ (seed * 2246822519);
                    1.0 + (x.wrapping_mul(2654435761) >> 24) as f32 / 64.0
                },
                [1.0; 3],
            )
        };
        let maps: Vec<Vec<f32>> = (0..TURNS as u32).map(noise).collect();
        let s = azimuth_skill(&maps, H);
        assert!(s > 0.3 && s < 0.7, "{s}");
        assert!(s < HEADING_READ);
    }

    #[test]
    fn the_probe_measures_networks_of_every_light_size() {
        use matedit_trainer::model::Widths;
        use matedit_trainer::model::network::NetConfig;
        let device = burn::tensor::Device::flex();
        for (size, h) in [(16, 4), (16, 8), (32, 32), (16, 128)] {
            device.seed(7);
            let net = NetConfig::new(size, Widths::new(4, 16, 32, 8))
                .with_env_height(h)
                .init(&device);
            let s = LightSkill::measure(&net, size, h).unwrap();
            assert!(
                (0.0..=1.0).contains(&s.azimuth) && (0.0..=1.0).contains(&s.colour),
                "{size}² input, {h} rows: {s:?}"
            );
        }
    }

    #[test]
    fn a_checkpoints_skill_is_measured_in_range_and_the_same_every_time() {
        let m = crate::Model::load(crate::tests::model()).unwrap();
        let s = m.light_skill().unwrap();
        assert!(
            (0.0..=1.0).contains(&s.azimuth) && (0.0..=1.0).contains(&s.colour),
            "{s:?}"
        );
        let again = LightSkill::measure(&m.net, m.state.net.input_size, m.state.net.env_height).unwrap();
        assert_eq!(again, s);
        assert_eq!(m.light_skill().unwrap(), s);
        // The probe's light is what it says: tinted as asked, its key light off the vertical axis.
        let h = m.state.net.env_height;
        let [warm, cool] = TINTS.map(|t| probe_light(h, t));
        assert!(red_over_blue(&warm) > 0.5 && red_over_blue(&cool) < -0.5);
        let white = probe_light(16, [1.0; 3]);
        assert!(azimuthal_part(&white, 16).iter().any(|v| v.abs() > 1.0));
        let (n, mask, regions) = sphere(16);
        let on = mask.iter().filter(|&&v| v > 0.0).count();
        assert!(on > 150 && on == regions.iter().filter(|&&r| r == 1).count());
        for k in (0..256).filter(|&k| mask[k] > 0.0) {
            let len = (0..3).map(|c| n[c * 256 + k].powi(2)).sum::<f32>();
            assert!((len - 1.0).abs() < 1e-5 && n[2 * 256 + k] > 0.0);
        }
    }
}
