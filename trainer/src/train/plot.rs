//! `loss.png`: the loss curves of a run (total and each term of Eq. 5, log scale), one colour
//! per term, stage boundaries marked.

use super::run::MetricsLine;
use super::step::LossWeights;
use anyhow::{Result, anyhow};
use plotters::prelude::*;
use std::path::Path;

/// Draws the curves of `lines` into `path` (PNG, 960×540).
pub fn loss_curves(lines: &[MetricsLine], path: &Path, w: &LossWeights) -> Result<()> {
    if lines.is_empty() {
        return Ok(());
    }
    let tmp = path.with_extension("tmp.png");
    {
        let root = BitMapBackend::new(&tmp, (960, 540)).into_drawing_area();
        root.fill(&WHITE).map_err(|e| anyhow!("{e}"))?;
        type Series<'a> = (&'static str, RGBColor, Box<dyn Fn(&MetricsLine) -> f64 + 'a>);
        let series: [Series; 4] = [
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
            chart
                .draw_series(LineSeries::new(pts, colour.stroke_width(2)))
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
            .background_style(WHITE.mix(0.8))
            .border_style(BLACK)
            .draw()
            .map_err(|e| anyhow!("{e}"))?;
        root.present().map_err(|e| anyhow!("{}: {e}", path.display()))?;
    }
    std::fs::rename(&tmp, path)?;
    Ok(())
}
