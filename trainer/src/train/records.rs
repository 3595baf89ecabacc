//! The lines of `metrics.jsonl`: one per step (its losses and learning rate) and one per
//! validation (its scores), read, and cut back to a checkpoint on resume.

use super::loss::Losses;
use crate::eval::{I_PRIME, Metrics, O_PRIME};
use anyhow::{Context, Result};
use serde::{Deserialize, Serialize};
use std::path::Path;

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

/// One validation's scores (the metrics of `trainer eval`'s "network" row).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Scores {
    /// The split scored.
    pub split: String,
    /// Samples scored.
    pub samples: u64,
    /// Tone-mapped L2 of O' = R(n', m_t, L') against O.
    pub o_l2: Option<f64>,
    /// SSIM of O' against O.
    pub o_ssim: Option<f64>,
    /// Tone-mapped L2 of I' = R(n', m', L') against I.
    pub i_l2: Option<f64>,
    /// SSIM of I' against I.
    pub i_ssim: Option<f64>,
    /// Mean cosine of n' and n.
    pub normal_cosine: Option<f64>,
    /// L2 of the normalised m' and m.
    pub material_l2: Option<f64>,
}

impl Scores {
    /// The scores of an evaluation's network row.
    pub fn of(split: &str, m: &Metrics) -> Self {
        Self {
            split: split.to_string(),
            samples: m.samples,
            o_l2: m.image_l2(O_PRIME),
            o_ssim: m.image_ssim(O_PRIME),
            i_l2: m.image_l2(I_PRIME),
            i_ssim: m.image_ssim(I_PRIME),
            normal_cosine: m.normal_cosine.value(),
            material_l2: m.material_l2_normalised.value(),
        }
    }

    /// Every score there is, by its name (the names `[eval] best` takes).
    pub fn named(&self) -> Vec<(&'static str, f64)> {
        [
            ("o_l2", self.o_l2),
            ("o_ssim", self.o_ssim),
            ("i_l2", self.i_l2),
            ("i_ssim", self.i_ssim),
            ("normal_cosine", self.normal_cosine),
            ("material_l2", self.material_l2),
        ]
        .into_iter()
        .filter_map(|(n, v)| v.map(|v| (n, v)))
        .collect()
    }
}

/// A validation's line in `metrics.jsonl` (a step's line has `losses` instead).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ValidationLine {
    /// The stage.
    pub stage: String,
    /// Steps completed in the stage.
    pub step: usize,
    /// Steps completed in the run.
    pub global_step: usize,
    /// The scores.
    pub validation: Scores,
}

/// One line of `metrics.jsonl`: a step's losses, or a validation's scores.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(untagged)]
pub enum Record {
    /// A validation (it has a `validation` field).
    Validation(ValidationLine),
    /// A step.
    Step(MetricsLine),
}

impl Record {
    /// Steps completed in the run at this line.
    pub fn global_step(&self) -> usize {
        match self {
            Record::Validation(v) => v.global_step,
            Record::Step(s) => s.global_step,
        }
    }
}

/// Reads `metrics.jsonl`: every line, a step's or a validation's.
pub fn read_records(path: &Path) -> Result<Vec<Record>> {
    let text = std::fs::read_to_string(path).with_context(|| format!("cannot read {}", path.display()))?;
    text.lines()
        .enumerate()
        .map(|(i, l)| {
            serde_json::from_str(l).with_context(|| format!("{}:{}: not a metrics line", path.display(), i + 1))
        })
        .collect()
}

/// Keeps the lines of `metrics.jsonl` up to a checkpoint `global` steps into the run (the
/// validation of that step included, where it was written).
pub fn truncate_records(path: &Path, global: usize) -> Result<()> {
    if !path.exists() {
        return Ok(());
    }
    let text = std::fs::read_to_string(path)?;
    let mut kept = String::new();
    for (i, l) in text.lines().enumerate() {
        let r: Record =
            serde_json::from_str(l).with_context(|| format!("{}:{}: not a metrics line", path.display(), i + 1))?;
        if r.global_step() > global {
            break;
        }
        kept.push_str(l);
        kept.push('\n');
    }
    matedit_contract::io::write_atomically(path, |p| Ok(std::fs::write(p, kept)?))
}

/// Whether `metrics.jsonl` holds the validation of the run's `global`-th step.
pub fn recorded(path: &Path, global: usize) -> Result<bool> {
    if !path.exists() {
        return Ok(false);
    }
    Ok(read_records(path)?
        .iter()
        .any(|r| matches!(r, Record::Validation(v) if v.global_step == global)))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn records_read_both_kinds_and_truncate_at_a_checkpoint() {
        let d = tempfile::tempdir().unwrap();
        let p = d.path().join("metrics.jsonl");
        let step = |g: usize| {
            format!(
                r#"{{"stage":"a","step":{g},"global_step":{g},"lr":0.001,"losses":{{"total":1.0,"normal":0.0,"material":0.0,"perceptual":0.0,"illumination":0.0,"ssim":0.0}}}}"#
            )
        };
        let val = |g: usize| {
            format!(
                r#"{{"stage":"a","step":{g},"global_step":{g},"validation":{{"split":"val","samples":4,"o_l2":2.5}}}}"#
            )
        };
        let text = [step(1), step(2), val(2), step(3), step(4), val(4)].join("\n") + "\n";
        std::fs::write(&p, &text).unwrap();
        let r = read_records(&p).unwrap();
        assert!(matches!(&r[2], Record::Validation(v) if v.validation.o_l2 == Some(2.5)));
        assert!(matches!(&r[3], Record::Step(s) if s.global_step == 3));
        assert!(recorded(&p, 2).unwrap() && !recorded(&p, 3).unwrap());
        truncate_records(&p, 3).unwrap();
        let kept = read_records(&p).unwrap();
        assert_eq!(kept.len(), 4, "steps 1–3 and step 2's validation");
        assert!(!recorded(&p, 4).unwrap());
        std::fs::write(&p, "{\"x\": 1}\n").unwrap();
        let e = read_records(&p).unwrap_err().to_string();
        assert!(e.contains("metrics.jsonl:1: not a metrics line"), "{e}");
    }
}
