//! Evaluation metrics of Sec. 4 and the Markdown tables of Tables 1–3.
//!
//! * [`crate::metrics`] (shared with training's losses): the per-sample metrics on f32 slices —
//!   L2 and SSIM on tone-mapped [0, 255] images, normal cosine, material L2 (raw and normalised
//!   scale), all on object pixels;
//! * [`Metrics`]: their averages over a split, per named output (`I'`, `O'`), serialisable;
//! * [`tables`]: Markdown tables shaped like the paper's Tables 1, 2 and 3.

mod methods;
pub mod report;
pub mod run;
mod score;
pub mod sheet;
pub mod tables;

use crate::metrics;
pub use metrics::{l2_tonemapped, material_l2, material_l2_normalised, normal_cosine, ssim};
pub use report::EvalReport;
pub use run::{EvalOptions, evaluate};
pub use tables::{TableRow, pipeline_markdown, table1_markdown, table2_markdown, table3_markdown};

use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;

/// Output name of the re-rendered input image I'.
pub const I_PRIME: &str = "I'";
/// Output name of the edited image O'.
pub const O_PRIME: &str = "O'";

/// A running mean: sum and count.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Mean {
    /// Sum of the values added.
    pub sum: f64,
    /// Number of values added.
    pub count: u64,
}

impl Mean {
    /// Adds one value.
    pub fn add(&mut self, v: f64) {
        self.sum += v;
        self.count += 1;
    }

    /// The mean, `None` before the first value.
    pub fn value(&self) -> Option<f64> {
        (self.count > 0).then(|| self.sum / self.count as f64)
    }

    fn merge(&mut self, other: &Mean) {
        self.sum += other.sum;
        self.count += other.count;
    }
}

/// Image metrics of one named output.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct ImageMetrics {
    /// [`l2_tonemapped`] per sample.
    pub l2: Mean,
    /// [`ssim`] per sample.
    pub ssim: Mean,
}

/// A predicted / ground-truth pair of one quantity of a sample.
#[derive(Clone, Copy, Debug)]
pub struct Pair<'a> {
    /// The network's value.
    pub pred: &'a [f32],
    /// The ground truth.
    pub truth: &'a [f32],
}

/// What one evaluated sample provides; absent parts are not scored.
#[derive(Clone, Debug, Default)]
pub struct Sample<'a> {
    /// Image height.
    pub h: usize,
    /// Image width.
    pub w: usize,
    /// Object mask `[H, W]` (> 0.5 is object).
    pub mask: &'a [f32],
    /// Images `[3, H, W]` (linear) by output name, e.g. ([`I_PRIME`], I' vs I).
    pub images: Vec<(&'a str, Pair<'a>)>,
    /// Normals `[3, H, W]`.
    pub normals: Option<Pair<'a>>,
    /// Normalised 108-vectors, one per material region.
    pub materials: Vec<Pair<'a>>,
}

/// Per-sample metrics averaged over a split. Every mean counts its own samples (a sample may
/// lack normals, say); `samples` counts [`Metrics::add`] calls.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Metrics {
    /// Samples added.
    pub samples: u64,
    /// Image metrics by output name ([`I_PRIME`], [`O_PRIME`], ...).
    pub images: BTreeMap<String, ImageMetrics>,
    /// [`normal_cosine`] per sample.
    pub normal_cosine: Mean,
    /// [`material_l2`] (raw scale, in the JSON only: γ up to 1e4 dominates it) per material.
    pub material_l2: Mean,
    /// [`material_l2_normalised`] per material.
    pub material_l2_normalised: Mean,
    /// Non-finite values met in the inputs (read as 0).
    pub non_finite: u64,
    /// Samples whose mask had no object pixel: their image and normal metrics are skipped.
    pub empty_masks: u64,
}

impl Metrics {
    /// Scores one sample and adds it to the averages.
    ///
    /// # Panics
    /// When a slice's length does not match `h`, `w` (or 108 for a material).
    pub fn add(&mut self, s: &Sample) {
        use metrics::count_non_finite as bad;
        self.samples += 1;
        let empty = metrics::mask_is_empty(s.mask);
        self.empty_masks += u64::from(empty);
        self.non_finite += bad(s.mask);
        for (name, p) in &s.images {
            self.non_finite += bad(p.pred) + bad(p.truth);
            let m = self.images.entry((*name).to_owned()).or_default();
            if !empty {
                m.l2.add(l2_tonemapped(p.pred, p.truth, s.mask, s.h, s.w));
                m.ssim.add(ssim(p.pred, p.truth, s.mask, s.h, s.w));
            }
        }
        if let Some(p) = s.normals {
            self.non_finite += bad(p.pred) + bad(p.truth);
            if !empty {
                self.normal_cosine.add(normal_cosine(p.pred, p.truth, s.mask, s.h, s.w));
            }
        }
        for p in &s.materials {
            self.non_finite += bad(p.pred) + bad(p.truth);
            self.material_l2.add(material_l2(p.pred, p.truth));
            self.material_l2_normalised.add(material_l2_normalised(p.pred, p.truth));
        }
    }

    /// Adds another accumulator's samples (for evaluating shards in parallel).
    pub fn merge(&mut self, other: &Metrics) {
        self.samples += other.samples;
        for (name, m) in &other.images {
            let mine = self.images.entry(name.clone()).or_default();
            mine.l2.merge(&m.l2);
            mine.ssim.merge(&m.ssim);
        }
        self.normal_cosine.merge(&other.normal_cosine);
        self.material_l2.merge(&other.material_l2);
        self.material_l2_normalised.merge(&other.material_l2_normalised);
        self.non_finite += other.non_finite;
        self.empty_masks += other.empty_masks;
    }

    /// Mean L2 of output `name`, if scored.
    pub fn image_l2(&self, name: &str) -> Option<f64> {
        self.images.get(name).and_then(|m| m.l2.value())
    }

    /// Mean SSIM of output `name`, if scored.
    pub fn image_ssim(&self, name: &str) -> Option<f64> {
        self.images.get(name).and_then(|m| m.ssim.value())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use matedit_physics::brdf::dsbrdf::PARAMS;

    #[test]
    fn metrics_average_per_output_and_count_samples() {
        let mask = [1.0, 1.0];
        // Display values: 1.0 → 255, 0.0 → 0; per-pixel L2 255² in one of three channels.
        let (white, black) = ([1.0f32; 6], [0.0f32; 6]);
        let mut one_channel = black;
        one_channel[0] = 1.0;
        one_channel[1] = 1.0;
        let normals = [0.0, 0.0, 0.0, 0.0, 1.0, 1.0];
        let (m0, m1) = ([0.0f32; PARAMS], [0.1f32; PARAMS]);
        let mut acc = Metrics::default();
        acc.add(&Sample {
            h: 1,
            w: 2,
            mask: &mask,
            images: vec![
                (
                    I_PRIME,
                    Pair {
                        pred: &white,
                        truth: &white,
                    },
                ),
                (
                    O_PRIME,
                    Pair {
                        pred: &one_channel,
                        truth: &black,
                    },
                ),
            ],
            normals: Some(Pair {
                pred: &normals,
                truth: &normals,
            }),
            materials: vec![Pair { pred: &m1, truth: &m0 }],
        });
        let mut second = Metrics::default();
        second.add(&Sample {
            h: 1,
            w: 2,
            mask: &mask,
            images: vec![(
                O_PRIME,
                Pair {
                    pred: &black,
                    truth: &black,
                },
            )],
            ..Default::default()
        });
        acc.merge(&second);
        assert_eq!(acc.samples, 2);
        assert_eq!(acc.image_l2(I_PRIME), Some(0.0));
        assert_eq!(acc.image_ssim(I_PRIME), Some(1.0));
        assert_eq!(acc.images[I_PRIME].l2.count, 1);
        assert_eq!(acc.image_l2(O_PRIME), Some(255.0 * 255.0 / 3.0 / 2.0));
        assert_eq!(acc.normal_cosine.value(), Some(1.0));
        let n = acc.material_l2_normalised.value().unwrap_or(f64::NAN);
        assert!((n - PARAMS as f64 * 0.01).abs() < 1e-6, "{n}");
        assert_eq!(acc.material_l2.count, 1);
        assert_eq!(acc.image_l2("missing"), None);
    }

    #[test]
    fn non_finite_and_empty_masks_are_counted_and_results_stay_finite() {
        let img = [f32::NAN, 1.0, f32::INFINITY, 0.0, f32::NEG_INFINITY, 0.5];
        let ok = [0.5f32; 6];
        let mut acc = Metrics::default();
        for mask in [[1.0, f32::NAN], [0.0, 0.0]] {
            acc.add(&Sample {
                h: 1,
                w: 2,
                mask: &mask,
                images: vec![(I_PRIME, Pair { pred: &img, truth: &ok })],
                normals: Some(Pair { pred: &img, truth: &ok }),
                materials: vec![],
            });
        }
        assert_eq!(acc.samples, 2);
        assert_eq!(acc.empty_masks, 1);
        assert_eq!(acc.non_finite, 3 + 3 + 1 + 3 + 3);
        assert_eq!(acc.images[I_PRIME].l2.count, 1);
        for v in [
            acc.image_l2(I_PRIME),
            acc.image_ssim(I_PRIME),
            acc.normal_cosine.value(),
        ] {
            assert!(v.is_some_and(f64::is_finite), "{v:?}");
        }
        let json = serde_json::to_string(&acc).unwrap_or_default();
        let back: Metrics = serde_json::from_str(&json).unwrap_or_default();
        assert_eq!(back, acc);
    }
}
