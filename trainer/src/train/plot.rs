//! `loss.png`: the loss curves of a run (total and each term of Eq. 5, log scale), one colour
//! per term (each step faint, a running mean bold), stage boundaries marked; below, the learning
//! rate of every step and the validation scores while training.

use super::loss::{LossWeights, TERMS};
use super::records::{MetricsLine, Record, Scores, ValidationLine};
use anyhow::{Result, anyhow};
use plotters::prelude::*;
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

/// The drawing area of every panel.
type Area<'a> = DrawingArea<BitMapBackend<'a>, plotters::coord::Shift>;

/// Draws `loss.png` (PNG, 960×760) from the records of `metrics.jsonl`: the loss curves on top,
/// the learning rate of every step (the schedule as it ran) below left, the validation scores
/// while training below right.
pub fn loss_curves(records: &[Record], path: &Path, w: &LossWeights) -> Result<()> {
    let lines: Vec<&MetricsLine> = records
        .iter()
        .filter_map(|r| match r {
            Record::Step(s) => Some(s),
            Record::Validation(_) => None,
        })
        .collect();
    let validations: Vec<&ValidationLine> = records
        .iter()
        .filter_map(|r| match r {
            Record::Validation(v) => Some(v),
            Record::Step(_) => None,
        })
        .collect();
    if lines.is_empty() {
        return Ok(());
    }
    embedded_font()?;
    let tmp = path.with_extension("tmp.png");
    {
        let root = BitMapBackend::new(&tmp, (960, 760)).into_drawing_area();
        root.fill(&WHITE).map_err(|e| anyhow!("{e}"))?;
        let (top, bottom) = root.split_vertically(440);
        let (left, right) = bottom.split_horizontally(480);
        draw_losses(&top, &lines, w)?;
        draw_rates(&left, &lines)?;
        draw_validation(&right, &validations, lines.len())?;
        root.present().map_err(|e| anyhow!("{}: {e}", path.display()))?;
    }
    std::fs::rename(&tmp, path)?;
    Ok(())
}

/// The global steps where a stage ends.
fn stage_ends(lines: &[&MetricsLine]) -> Vec<f64> {
    lines
        .windows(2)
        .filter(|w| w[0].stage != w[1].stage)
        .map(|w| w[0].global_step as f64)
        .collect()
}

fn draw_losses(area: &Area, lines: &[&MetricsLine], w: &LossWeights) -> Result<()> {
    type Series<'a> = (&'static str, RGBColor, Box<dyn Fn(&MetricsLine) -> f64 + 'a>);
    let total: Series = ("total (Eq. 5)", BLACK, Box::new(|l| l.losses.total));
    let terms = TERMS.iter().map(|t| -> Series {
        let (r, g, b) = t.colour;
        (t.label, RGBColor(r, g, b), Box::new(move |l| w[t] * l.losses[t]))
    });
    let series: Vec<Series> = std::iter::once(total).chain(terms).collect();
    let positive = |v: f64| v.is_finite() && v > 0.0;
    let values: Vec<f64> = lines
        .iter()
        .flat_map(|l| series.iter().map(move |s| (s.2)(l)))
        .filter(|v| positive(*v))
        .collect();
    let lo = values.iter().cloned().fold(f64::INFINITY, f64::min).max(1e-12);
    let hi = values.iter().cloned().fold(0.0, f64::max).max(lo * 10.0);
    let n = lines.len() as f64;
    let mut chart = ChartBuilder::on(area)
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
                    .map(|l| f(l))
                    .filter(|v| positive(*v))
                    .fold((0.0, 0usize), |(s, n), v| (s + v, n + 1));
                positive(f(lines[i])).then(|| (lines[i].global_step as f64, sum / count as f64))
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
    for x in stage_ends(lines) {
        chart
            .draw_series(LineSeries::new(
                vec![(x, lo * 0.8), (x, hi * 1.25)],
                RGBColor(150, 150, 150),
            ))
            .map_err(|e| anyhow!("{e}"))?;
    }
    chart
        .configure_series_labels()
        .position(SeriesLabelPosition::LowerLeft)
        .background_style(WHITE.mix(0.8))
        .border_style(BLACK)
        .draw()
        .map_err(|e| anyhow!("{e}"))?;
    Ok(())
}

/// The learning rate of every step, log scale.
fn draw_rates(area: &Area, lines: &[&MetricsLine]) -> Result<()> {
    let rates: Vec<(f64, f64)> = lines
        .iter()
        .map(|l| (l.global_step as f64, l.lr))
        .filter(|p| p.1.is_finite() && p.1 > 0.0)
        .collect();
    // The smallest rate, halved (a constant schedule is then a line inside the panel).
    let lo = rates.iter().map(|p| p.1).fold(1.0, f64::min).clamp(1e-12, 1.0) / 2.0;
    let hi = rates.iter().map(|p| p.1).fold(0.0, f64::max).max(lo * 10.0);
    let n = lines.len() as f64;
    let mut chart = ChartBuilder::on(area)
        .caption("learning rate", ("sans-serif", 18))
        .margin(12)
        .x_label_area_size(32)
        .y_label_area_size(64)
        .build_cartesian_2d(0f64..n.max(1.0), (lo * 0.8..hi * 1.25).log_scale())
        .map_err(|e| anyhow!("{e}"))?;
    chart
        .configure_mesh()
        .x_desc("step (whole run)")
        .y_labels(6)
        .light_line_style(WHITE.mix(0.0))
        .y_label_formatter(&|v| format!("{v:.0e}"))
        .draw()
        .map_err(|e| anyhow!("{e}"))?;
    chart
        .draw_series(LineSeries::new(rates, RGBColor(31, 119, 180).stroke_width(2)))
        .map_err(|e| anyhow!("{e}"))?;
    for x in stage_ends(lines) {
        chart
            .draw_series(LineSeries::new(
                vec![(x, lo * 0.8), (x, hi * 1.25)],
                RGBColor(150, 150, 150),
            ))
            .map_err(|e| anyhow!("{e}"))?;
    }
    Ok(())
}

/// The validations' scores: the L2 errors on a log scale (left axis), SSIM and the normals'
/// cosine on [0, 1] (right axis).
fn draw_validation(area: &Area, vals: &[&ValidationLine], steps: usize) -> Result<()> {
    if vals.is_empty() {
        area.draw(&Text::new(
            "no validation while training ([eval] every = 0)",
            (24, 140),
            ("sans-serif", 16).into_font().color(&RGBColor(110, 110, 110)),
        ))
        .map_err(|e| anyhow!("{e}"))?;
        return Ok(());
    }
    type Pick = fn(&Scores) -> Option<f64>;
    let errors: [(&str, RGBColor, Pick); 3] = [
        ("O' L2", RGBColor(214, 39, 40), |s| s.o_l2),
        ("I' L2", RGBColor(255, 127, 14), |s| s.i_l2),
        ("m' L2", RGBColor(140, 86, 75), |s| s.material_l2),
    ];
    let unit: [(&str, RGBColor, Pick); 3] = [
        ("O' SSIM", RGBColor(44, 160, 44), |s| s.o_ssim),
        ("I' SSIM", RGBColor(23, 190, 207), |s| s.i_ssim),
        ("n' cosine", RGBColor(31, 119, 180), |s| s.normal_cosine),
    ];
    let positive = |v: &f64| v.is_finite() && *v > 0.0;
    let all: Vec<f64> = vals
        .iter()
        .flat_map(|v| errors.iter().filter_map(|(_, _, f)| f(&v.validation)))
        .filter(positive)
        .collect();
    let lo = all.iter().cloned().fold(f64::INFINITY, f64::min);
    let lo = if lo.is_finite() { lo.clamp(1e-12, 1e12) } else { 1.0 };
    let hi = all.iter().cloned().fold(0.0, f64::max).max(lo * 10.0);
    let mut chart = ChartBuilder::on(area)
        .caption(format!("validation ({})", vals[0].validation.split), ("sans-serif", 18))
        .margin(12)
        .x_label_area_size(32)
        .y_label_area_size(56)
        .right_y_label_area_size(40)
        .build_cartesian_2d(0f64..(steps as f64).max(1.0), (lo * 0.8..hi * 1.25).log_scale())
        .map_err(|e| anyhow!("{e}"))?
        .set_secondary_coord(0f64..(steps as f64).max(1.0), 0f64..1f64);
    chart
        .configure_mesh()
        .x_desc("step (whole run)")
        .y_desc("L2")
        .draw()
        .map_err(|e| anyhow!("{e}"))?;
    chart
        .configure_secondary_axes()
        .y_desc("SSIM, cosine")
        .draw()
        .map_err(|e| anyhow!("{e}"))?;
    for (name, colour, f) in errors {
        let pts: Vec<(f64, f64)> = vals
            .iter()
            .filter_map(|v| f(&v.validation).filter(positive).map(|y| (v.global_step as f64, y)))
            .collect();
        if pts.is_empty() {
            continue;
        }
        chart
            .draw_series(LineSeries::new(pts.clone(), colour.stroke_width(2)))
            .map_err(|e| anyhow!("{e}"))?
            .label(name)
            .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 18, y)], colour.stroke_width(2)));
        chart
            .draw_series(pts.into_iter().map(|p| Circle::new(p, 3, colour.filled())))
            .map_err(|e| anyhow!("{e}"))?;
    }
    for (name, colour, f) in unit {
        let pts: Vec<(f64, f64)> = vals
            .iter()
            .filter_map(|v| {
                f(&v.validation)
                    .filter(|y| y.is_finite())
                    .map(|y| (v.global_step as f64, y.clamp(0.0, 1.0)))
            })
            .collect();
        if pts.is_empty() {
            continue;
        }
        chart
            .draw_secondary_series(LineSeries::new(pts.clone(), colour.stroke_width(2)))
            .map_err(|e| anyhow!("{e}"))?
            .label(name)
            .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 18, y)], colour.stroke_width(2)));
        chart
            .draw_secondary_series(pts.into_iter().map(|p| Circle::new(p, 3, colour.filled())))
            .map_err(|e| anyhow!("{e}"))?;
    }
    chart
        .configure_series_labels()
        .position(SeriesLabelPosition::LowerLeft)
        .background_style(WHITE.mix(0.8))
        .border_style(BLACK)
        .label_font(("sans-serif", 12))
        .draw()
        .map_err(|e| anyhow!("{e}"))?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::train::loss::Losses;
    use crate::train::records::{Record, Scores, ValidationLine};

    fn weights() -> LossWeights {
        use crate::train::loss::{ILLUMINATION, LIGHT_DIRECTION, LIGHT_ENERGY, SSIM};
        LossWeights::default()
            .with(&ILLUMINATION, 1.0)
            .with(&SSIM, 1e4)
            .with(&LIGHT_ENERGY, 1e3)
            .with(&LIGHT_DIRECTION, 1e3)
    }

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
                let mut losses = Losses::default();
                for (t, v) in TERMS.iter().zip([
                    normal,
                    material,
                    perceptual,
                    illumination,
                    ssim,
                    light_energy,
                    light_direction,
                ]) {
                    losses.set(t, v);
                }
                losses.total = losses.weighted_total(&weights());
                MetricsLine {
                    stage: if joint { "joint" } else { "pretrain" }.into(),
                    step: if joint { i - 200 } else { i },
                    global_step: i,
                    lr: 1e-4,
                    losses,
                }
            })
            .collect();
        let path = std::env::temp_dir().join(format!("matedit-loss-{}.png", std::process::id()));
        let weights = weights();
        let mut records: Vec<Record> = lines.into_iter().map(Record::Step).collect();
        for g in [100, 200, 250, 300] {
            records.push(Record::Validation(ValidationLine {
                stage: if g > 200 { "joint" } else { "pretrain" }.into(),
                step: g,
                global_step: g,
                validation: Scores {
                    split: "val".into(),
                    samples: 8,
                    o_l2: Some(2000.0 / g as f64),
                    o_ssim: Some(0.5 + g as f64 / 1000.0),
                    i_l2: Some(1500.0 / g as f64),
                    i_ssim: Some(0.6),
                    normal_cosine: Some(0.8),
                    material_l2: Some(0.3),
                },
            }));
        }
        loss_curves(&records, &path, &weights).unwrap();
        let img = image::open(&path).unwrap().to_rgb8();
        assert_eq!(img.dimensions(), (960, 760));
        // Each term's colour is on the canvas (the legend alone would be a few pixels).
        for t in TERMS {
            let colour = [t.colour.0, t.colour.1, t.colour.2];
            let n = img.pixels().filter(|p| p.0 == colour).count();
            assert!(n > 300, "{}: colour {colour:?}: {n} pixels", t.name);
        }
        // The learning rate's panel (lower left) and the validation's (lower right) are drawn.
        let coloured = |x0: u32, x1: u32, c: [u8; 3]| {
            (x0..x1)
                .flat_map(|x| (460..760).map(move |y| (x, y)))
                .filter(|&(x, y)| img.get_pixel(x, y).0 == c)
                .count()
        };
        assert!(coloured(0, 480, [31, 119, 180]) > 100, "the learning rate");
        assert!(coloured(480, 960, [214, 39, 40]) > 50, "validation O' L2");
        assert!(coloured(480, 960, [44, 160, 44]) > 50, "validation O' SSIM");
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
