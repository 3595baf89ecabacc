//! The evaluation's report: each checkpoint's scores per table and method, the baselines', and
//! their Markdown tables; written as `METRICS.json`.

use super::{Metrics, O_PRIME, TableRow};
use crate::baseline::lombardi::LombardiConfig;
use anyhow::Result;
use serde::{Deserialize, Serialize};
use std::path::Path;

/// One checkpoint's scores.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct CheckpointEval {
    /// Row label (the checkpoint's stage name).
    pub name: String,
    /// The checkpoint folder.
    pub checkpoint: String,
    /// n', m', L' all predicted: I', O', normal cosine, material L2.
    pub network: Metrics,
    /// R(n, m', L) against I, and the material L2 (Table 1).
    pub material_protocol: Metrics,
    /// R(n', m, L) against I, and the normal cosine (Table 2).
    pub normal_protocol: Metrics,
    /// O' = R(n', m̄, L') against O (trivial baseline).
    pub mean_material: Metrics,
    /// n*, m*, L* after the post-optimisation (Eq. 6) from n', m', L': I*, O*, normal cosine,
    /// material L2 (`--eq6`).
    #[serde(default)]
    pub eq6: Option<Metrics>,
    /// Eq. 6's energy at the prediction and at the end, summed over the samples, and its seconds.
    #[serde(default)]
    pub eq6_energy: Option<[f64; 3]>,
}

/// `METRICS.json`.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct EvalReport {
    /// Dataset folder.
    pub dataset: String,
    /// Scored split.
    pub split: String,
    /// Shape categories scored (empty: all).
    #[serde(default)]
    pub categories: Vec<String>,
    /// Samples scored.
    pub samples: u64,
    /// Material ids averaged into m̄.
    pub mean_material_of: Vec<String>,
    /// O' = I against O (trivial baseline, no network).
    pub copy_input: Metrics,
    /// Per checkpoint, in the order given.
    pub checkpoints: Vec<CheckpointEval>,
    /// The Lombardi-style optimiser given the true normals: I* = R(n, m*, L*) against I,
    /// O' = R(n, m_t, L*) against O, m* against m (`--lombardi`).
    #[serde(default)]
    pub lombardi: Option<LombardiEval>,
}

/// The Lombardi-style baseline's scores and what produced them.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct LombardiEval {
    /// Its settings.
    pub config: Option<LombardiConfig>,
    /// Training materials its reflectance prior was fitted to.
    pub prior_materials: usize,
    /// The scores.
    pub metrics: Metrics,
    /// Its energy at the uninformed start and at the end, summed over the samples.
    pub energy: [f64; 2],
    /// Seconds, summed over the samples.
    pub seconds: f64,
}

impl EvalReport {
    /// The Markdown report: Tables 1–3 and the full pipeline.
    pub fn markdown(&self) -> String {
        let rows = |f: &dyn Fn(&CheckpointEval) -> Metrics| -> Vec<TableRow> {
            self.checkpoints
                .iter()
                .map(|c| TableRow {
                    name: c.name.clone(),
                    metrics: f(c),
                })
                .collect()
        };
        let mut t3 = vec![TableRow {
            name: "O' = I".into(),
            metrics: self.copy_input.clone(),
        }];
        // The last checkpoint that predicts n' and L' (Baseline 1 predicts neither).
        if let Some(last) = self.checkpoints.iter().rev().find(|c| c.mean_material.samples > 0) {
            t3.push(TableRow {
                name: format!("mean material (n', L' of {})", last.name),
                metrics: last.mean_material.clone(),
            });
        }
        if let Some(l) = &self.lombardi {
            t3.push(TableRow {
                name: "Lombardi (true n)".into(),
                metrics: l.metrics.clone(),
            });
        }
        for c in &self.checkpoints {
            t3.push(TableRow {
                name: c.name.clone(),
                metrics: c.network.clone(),
            });
            if let Some(m) = &c.eq6 {
                t3.push(TableRow {
                    name: format!("{} + Eq. 6", c.name),
                    metrics: m.clone(),
                });
            }
        }
        let of = if self.categories.is_empty() {
            String::new()
        } else {
            format!(", categories {}", self.categories.join(", "))
        };
        let mut out = format!(
            "Evaluation of {} on split {}{of} ({} samples; L2 on tone-mapped [0, 255] images, SSIM 11×11 σ 1.5, \
             object pixels only).\n\n",
            self.dataset, self.split, self.samples
        );
        out += "Table 1 (material module, given ground-truth normals and illumination):\n\n";
        out += &super::table1_markdown(&rows(&|c| c.material_protocol.clone()));
        out += "\nTable 2 (normal module, given ground-truth material and illumination):\n\n";
        out += &super::table2_markdown(&rows(&|c| c.normal_protocol.clone()));
        out += "\nTable 3 (material transfer, O' against O: R(n', m_t, L') for the networks of Fig. 2, R(n, m_t, L*) for \
                Lombardi, the decoder's image for Baseline 1; trivial baselines first):\n\n";
        out += &super::table3_markdown(&t3);
        out += "\nFull pipeline (n', m', L' all predicted):\n\n";
        out += &super::tables::pipeline_markdown(&rows(&|c| c.network.clone()));
        out
    }

    /// Whether `name`'s O' beats the trivial baselines on L2 (lower) and SSIM (higher): both, or
    /// O' = I alone for a method that predicts no n' and L' to edit with the mean material
    /// (Baseline 1).
    pub fn beats_baselines(&self, name: &str) -> Option<bool> {
        let c = self.checkpoints.iter().find(|c| c.name == name)?;
        let (l2, ssim) = (c.network.image_l2(O_PRIME)?, c.network.image_ssim(O_PRIME)?);
        let mut baselines = vec![&self.copy_input];
        if c.mean_material.samples > 0 {
            baselines.push(&c.mean_material);
        }
        Some(
            baselines.iter().all(|b| {
                b.image_l2(O_PRIME).is_some_and(|v| l2 < v) && b.image_ssim(O_PRIME).is_some_and(|v| ssim > v)
            }),
        )
    }
}

/// Writes `report` as JSON to `path`, atomically.
pub fn write_report(report: &EvalReport, path: &Path) -> Result<()> {
    matedit_contract::io::write_atomically(path, |p| Ok(std::fs::write(p, serde_json::to_string_pretty(report)?)?))
}
