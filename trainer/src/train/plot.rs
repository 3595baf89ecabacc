//! `loss.png`: the loss curves of a run (total and each term of Eq. 5, log scale), one colour
//! per term (each step faint, a running mean bold), stage boundaries marked.

use super::step::{LossWeights, Losses};
use anyhow::{Result, anyhow};
use plotters::prelude::*;
use serde::{Deserialize, Serialize};
use std::path::Path;

/// DejaVu Sans (Bitstream Vera licence: `assets/fonts/LICENSE-DejaVu.txt`), the font of every
/// plot, embedded: drawing text links no font library and looks up nothing on the machine.
const FONT: &[u8] = include_bytes!("../../../assets/fonts/DejaVuSans.ttf");

/// Makes the embedded font plotters' `sans-serif`, once per process; every plot calls it first.
pub fn embedded_font() -> Result<()> {
    static REGISTERED: std::sync::OnceLock<bool> = std::sync::OnceLock::new();
    let ok = *REGISTERED.get_or_init(|| plotters::style::register_font("sans-serif", FontStyle::Normal, FONT).is_ok());
    if ok {
        Ok(())
    } else {
        Err(anyhow!("the embedded plot font could not be read"))
    }
}

/// Draws the curves of `lines` into `path` (PNG, 960×540).
pub fn loss_curves(lines: &[MetricsLine], path: &Path, w: &LossWeights) -> Result<()> {
    if lines.is_empty() {
        return Ok(());
    }
    embedded_font()?;
    let tmp = path.with_extension("tmp.png");
    {
        let root = BitMapBackend::new(&tmp, (960, 540)).into_drawing_area();
        root.fill(&WHITE).map_err(|e| anyhow!("{e}"))?;
        type Series<'a> = (&'static str, RGBColor, Box<dyn Fn(&MetricsLine) -> f64 + 'a>);
        let series: [Series; 8] = [
            ("total (Eq. 5)", BLACK, Box::new(|l| l.losses.total)),
            (
                "w_n · normal",
                RGBColor(31, 119, 180),
                Box::new(|l| w.normal * l.losses.normal),
            ),
            (
                "w_m · material",
                RGBColor(255, 127, 14),
                Box::new(|l| w.material * l.losses.material),
            ),
            (
                "w_p · perceptual",
                RGBColor(44, 160, 44),
                Box::new(|l| w.perceptual * l.losses.perceptual),
            ),
            (
                "w_L · illumination",
                RGBColor(148, 103, 189),
                Box::new(|l| w.illumination * l.losses.illumination),
            ),
            (
                "w_s · (1 − SSIM)",
                RGBColor(214, 39, 40),
                Box::new(|l| w.ssim * l.losses.ssim),
            ),
            (
                "w_E · light energy",
                RGBColor(140, 86, 75),
                Box::new(|l| w.light_energy * l.losses.light_energy),
            ),
            (
                "w_D · light direction",
                RGBColor(227, 119, 194),
                Box::new(|l| w.light_direction * l.losses.light_direction),
            ),
        ];
        let positive = |v: f64| v.is_finite() && v > 0.0;
        let values: Vec<f64> = lines
            .iter()
            .flat_map(|l| series.iter().map(move |s| (s.2)(l)))
            .filter(|v| positive(*v))
            .collect();
        let lo = values.iter().cloned().fold(f64::INFINITY, f64::min).max(1e-12);
        let hi = values.iter().cloned().fold(0.0, f64::max).max(lo * 10.0);
        let n = lines.len() as f64;
        let mut chart = ChartBuilder::on(&root)
            .caption("training loss", ("sans-serif", 22))
            .margin(12)
            .x_label_area_size(36)
            .y_label_area_size(64)
            .build_cartesian_2d(0f64..n.max(1.0), (lo * 0.8..hi * 1.25).log_scale())
            .map_err(|e| anyhow!("{e}"))?;
        chart
            .configure_mesh()
            .x_desc("step (whole run)")
            .y_desc("loss")
            .draw()
            .map_err(|e| anyhow!("{e}"))?;
        for (name, colour, f) in series {
            let pts: Vec<(f64, f64)> = lines
                .iter()
                .map(|l| (l.global_step as f64, f(l)))
                .filter(|p| positive(p.1))
                .collect();
            if pts.is_empty() {
                continue;
            }
            // Single steps are noisy (one batch each): the raw curve faint, a running mean of
            // 1 % of the run (at least 5 steps, never across a stage boundary) on top.
            let window = (lines.len() / 100).max(5);
            let mut stage_start = 0;
            let smooth: Vec<(f64, f64)> = (0..lines.len())
                .filter_map(|i| {
                    if i > 0 && lines[i].stage != lines[i - 1].stage {
                        stage_start = i;
                    }
                    let from = i.saturating_sub(window - 1).max(stage_start);
                    let (sum, count) = lines[from..=i]
                        .iter()
                        .map(&f)
                        .filter(|v| positive(*v))
                        .fold((0.0, 0usize), |(s, n), v| (s + v, n + 1));
                    positive(f(&lines[i])).then(|| (lines[i].global_step as f64, sum / count as f64))
                })
                .collect();
            chart
                .draw_series(LineSeries::new(pts, colour.mix(0.25).stroke_width(1)))
                .map_err(|e| anyhow!("{e}"))?;
            chart
                .draw_series(LineSeries::new(smooth, colour.stroke_width(2)))
                .map_err(|e| anyhow!("{e}"))?
                .label(name)
                .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 18, y)], colour.stroke_width(2)));
        }
        // Stage boundaries.
        for w in lines.windows(2) {
            if w[0].stage != w[1].stage {
                let x = w[0].global_step as f64;
                chart
                    .draw_series(LineSeries::new(
                        vec![(x, lo * 0.8), (x, hi * 1.25)],
                        RGBColor(150, 150, 150),
                    ))
                    .map_err(|e| anyhow!("{e}"))?;
            }
        }
        chart
            .configure_series_labels()
            .position(SeriesLabelPosition::LowerLeft)
            .background_style(WHITE.mix(0.8))
            .border_style(BLACK)
            .draw()
            .map_err(|e| anyhow!("{e}"))?;
        root.present().map_err(|e| anyhow!("{}: {e}", path.display()))?;
    }
    std::fs::rename(&tmp, path)?;
    Ok(())
}

/// One line of `metrics.jsonl`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct MetricsLine {
    /// Stage name.
    pub stage: String,
    /// Step within the stage (1-based: steps completed).
    pub step: usize,
    /// Steps completed in the run.
    pub global_step: usize,
    /// Learning rate of the step.
    pub lr: f64,
    /// Loss terms.
    pub losses: Losses,
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::train::step::Losses;

    #[test]
    fn curves_are_drawn_for_every_term_and_stage() {
        let lines: Vec<MetricsLine> = (1..=300)
            .map(|i| {
                let joint = i > 200;
                let wobble = 1.0 + 0.3 * ((i * 7919) % 13) as f64 / 13.0;
                let normal = 0.5 / (i as f64).sqrt() * wobble;
                let material = 0.2 / (i as f64).powf(0.3);
                let perceptual = if joint { 5000.0 * wobble } else { 0.0 };
                let illumination = 300.0 / (i as f64).powf(0.2);
                let ssim = if joint { 0.3 * wobble } else { 0.0 };
                let light_energy = 0.4 / (i as f64).powf(0.5);
                let light_direction = 0.2 / (i as f64).powf(0.4);
                MetricsLine {
                    stage: if joint { "joint" } else { "pretrain" }.into(),
                    step: if joint { i - 200 } else { i },
                    global_step: i,
                    lr: 1e-4,
                    losses: Losses {
                        total: 1e4 * normal
                            + 1e3 * material
                            + perceptual
                            + illumination
                            + 1e4 * ssim
                            + 1e3 * light_energy
                            + 1e3 * light_direction,
                        normal,
                        material,
                        perceptual,
                        illumination,
                        ssim,
                        light_energy,
                        light_direction,
                    },
                }
            })
            .collect();
        let path = std::env::temp_dir().join(format!("matedit-loss-{}.png", std::process::id()));
        let weights = LossWeights {
            illumination: 1.0,
            ssim: 1e4,
            light_energy: 1e3,
            light_direction: 1e3,
            ..LossWeights::default()
        };
        loss_curves(&lines, &path, &weights).unwrap();
        let img = image::open(&path).unwrap().to_rgb8();
        assert_eq!(img.dimensions(), (960, 540));
        // Each term's colour is on the canvas (the legend alone would be a few pixels).
        for colour in [
            [31u8, 119, 180],
            [255, 127, 14],
            [44, 160, 44],
            [148, 103, 189],
            [214, 39, 40],
            [140, 86, 75],
            [227, 119, 194],
        ] {
            let n = img.pixels().filter(|p| p.0 == colour).count();
            assert!(n > 300, "colour {colour:?}: {n} pixels");
        }
        // The caption is drawn in the embedded font: dark pixels along the top.
        let dark = (0..960)
            .flat_map(|x| (0..36).map(move |y| (x, y)))
            .filter(|&(x, y)| img.get_pixel(x, y).0.iter().all(|&c| c < 96))
            .count();
        assert!(dark > 100, "no caption text ({dark} dark pixels)");
        if let Ok(keep) = std::env::var("MATEDIT_KEEP_PLOT") {
            let _ = std::fs::copy(&path, keep);
        }
        let _ = std::fs::remove_file(&path);
    }
}
