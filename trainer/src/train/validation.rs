//! Validation while training (`[eval] every = N`): every N steps of the run and at the end of each
//! stage, the checkpoint just written is scored on `[eval].val_split` (a dataset's `val` split, or
//! `test`) with the paper's metrics, the scores are a line of `metrics.jsonl`, a contact sheet goes
//! to `validation/STEP.png`, and the checkpoint with the best score by `[eval].best` is kept as
//! `checkpoints/best` (its `best.json` says which step and score).
//!
//! Order, so that a kill at any moment resumes to what an uninterrupted run writes: the step's
//! line, the checkpoint, the best checkpoint (replaced atomically, and only when strictly better),
//! then the validation line. A resumed run keeps the lines up to its checkpoint's step and, where
//! that step's validation has no line yet, scores the checkpoint again: the same scores, so the
//! same line, and a best that a tie leaves as it is.

use super::records::{Scores, ValidationLine};
use crate::eval::run::{EvalOptions, evaluate};
use anyhow::{Context, Result, bail};
use matedit_contract::manifest::Named;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

/// The score the best checkpoint is kept by.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum BestMetric {
    /// The tone-mapped L2 of O' against O (the paper's edit error; lower is better).
    OL2,
    /// SSIM of O' against O (higher is better).
    OSsim,
    /// The tone-mapped L2 of I' against I (lower is better).
    IL2,
    /// SSIM of I' against I (higher is better).
    ISsim,
    /// Mean cosine of n' and n (higher is better).
    NormalCosine,
    /// L2 of the normalised m' and m (lower is better).
    MaterialL2,
}

impl Named for BestMetric {
    const NAMES: &'static [(&'static str, Self)] = &[
        ("o_l2", BestMetric::OL2),
        ("o_ssim", BestMetric::OSsim),
        ("i_l2", BestMetric::IL2),
        ("i_ssim", BestMetric::ISsim),
        ("normal_cosine", BestMetric::NormalCosine),
        ("material_l2", BestMetric::MaterialL2),
    ];
}

impl BestMetric {
    /// Whether a larger value is better.
    pub fn higher_is_better(self) -> bool {
        matches!(self, BestMetric::OSsim | BestMetric::ISsim | BestMetric::NormalCosine)
    }

    /// Its value in `scores`.
    pub fn of(self, s: &Scores) -> Option<f64> {
        match self {
            BestMetric::OL2 => s.o_l2,
            BestMetric::OSsim => s.o_ssim,
            BestMetric::IL2 => s.i_l2,
            BestMetric::ISsim => s.i_ssim,
            BestMetric::NormalCosine => s.normal_cosine,
            BestMetric::MaterialL2 => s.material_l2,
        }
    }

    /// Whether `new` beats `old` (strictly: a tie keeps the earlier checkpoint).
    pub fn beats(self, new: f64, old: f64) -> bool {
        if self.higher_is_better() { new > old } else { new < old }
    }
}

/// `checkpoints/best/best.json`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Best {
    /// The metric's name.
    pub metric: String,
    /// Its value.
    pub value: f64,
    /// The validation it came from.
    pub line: ValidationLine,
    /// The checkpoint copied (its name under `checkpoints/`).
    pub checkpoint: String,
}

/// What a run validates, and when.
#[derive(Clone, Debug)]
pub struct Validation {
    /// Validate every this many steps of the run (and at each stage's end).
    pub every: usize,
    /// The dataset folder.
    pub data: PathBuf,
    /// The split.
    pub split: String,
    /// At most this many samples (0: all).
    pub samples: usize,
    /// Only these shape categories (all when empty).
    pub categories: Vec<String>,
    /// What the best checkpoint is kept by.
    pub best: BestMetric,
}

impl Validation {
    /// Whether the step that brought the run to `global` steps (ending its stage when
    /// `stage_done`) is validated.
    pub fn due(&self, global: usize, stage_done: bool) -> bool {
        self.every > 0 && (stage_done || global.is_multiple_of(self.every))
    }

    /// Refuses a dataset without the split, before the first step.
    pub fn check(&self) -> Result<()> {
        let ds = crate::data::Dataset::open(&self.data)?;
        if ds.split(&self.split).is_none() {
            bail!(
                "[eval].val_split = {:?}: the dataset {} has no such split (splits: {}); give the dataset a split \
                 with role = \"val\" (manifests/README.md), or validate on \"test\"",
                self.split,
                self.data.display(),
                ds.split_names().join(", ")
            );
        }
        Ok(())
    }

    /// Scores checkpoint `name` of run `out` (after `stage`'s `step`-th step, `global` in the
    /// run), writes its sheet and, where it is the best so far, copies it to `checkpoints/best`.
    /// Returns the line for `metrics.jsonl`.
    pub fn run(&self, out: &Path, name: &str, stage: &str, step: usize, global: usize) -> Result<ValidationLine> {
        let ckpt = out.join("checkpoints").join(name);
        let sheets = out.join("validation");
        std::fs::create_dir_all(&sheets).with_context(|| format!("cannot create {}", sheets.display()))?;
        let opts = EvalOptions {
            data: self.data.clone(),
            split: self.split.clone(),
            train_data: None,
            batch: 8,
            max_samples: self.samples,
            categories: self.categories.clone(),
            progress: false,
            sheet: Some((sheets.join(format!("{global:07}.png")), 4)),
            eq6: None,
            lombardi: None,
            names: Vec::new(),
        };
        let report = evaluate(std::slice::from_ref(&ckpt), &opts)
            .with_context(|| format!("validating {} on split {}", ckpt.display(), self.split))?;
        let line = ValidationLine {
            stage: stage.to_string(),
            step,
            global_step: global,
            validation: Scores::of(&self.split, &report.checkpoints[0].network),
        };
        self.keep_if_best(out, name, &line)?;
        Ok(line)
    }

    /// Copies checkpoint `name` to `checkpoints/best` when `line` beats the best so far.
    fn keep_if_best(&self, out: &Path, name: &str, line: &ValidationLine) -> Result<()> {
        let Some(value) = self.best.of(&line.validation).filter(|v| v.is_finite()) else {
            return Ok(());
        };
        if let Some(b) = read_best(out)?
            && b.metric == self.best.name()
            && !self.best.beats(value, b.value)
        {
            return Ok(());
        }
        let dir = out.join("checkpoints");
        let src = dir.join(name);
        let best = Best {
            metric: self.best.name().to_string(),
            value,
            line: line.clone(),
            checkpoint: name.to_string(),
        };
        super::checkpoint::replace_folder(&dir, "best", |tmp| {
            for f in ["model.bpk", "optimizer.bpk", "state.json"] {
                std::fs::copy(src.join(f), tmp.join(f))
                    .with_context(|| format!("cannot copy {}", src.join(f).display()))?;
            }
            std::fs::write(tmp.join("best.json"), serde_json::to_string_pretty(&best)?)?;
            Ok(())
        })?;
        Ok(())
    }
}

/// The best checkpoint's record, where there is one.
pub fn read_best(out: &Path) -> Result<Option<Best>> {
    let p = out.join("checkpoints").join("best").join("best.json");
    if !p.exists() {
        return Ok(None);
    }
    let text = std::fs::read_to_string(&p).with_context(|| format!("cannot read {}", p.display()))?;
    Ok(Some(serde_json::from_str(&text).with_context(|| {
        format!("{}: not a best-checkpoint record", p.display())
    })?))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_best_is_strictly_better_in_the_metrics_direction() {
        assert!(BestMetric::OL2.beats(1.0, 2.0) && !BestMetric::OL2.beats(2.0, 2.0));
        assert!(BestMetric::OSsim.beats(0.9, 0.8) && !BestMetric::OSsim.beats(0.8, 0.8));
        assert!(BestMetric::NormalCosine.higher_is_better() && !BestMetric::MaterialL2.higher_is_better());
        let s = Scores {
            o_l2: Some(3.0),
            normal_cosine: Some(0.5),
            ..Default::default()
        };
        assert_eq!(s.named(), vec![("o_l2", 3.0), ("normal_cosine", 0.5)]);
    }

    #[test]
    fn validation_is_due_every_n_steps_and_at_each_stages_end() {
        let v = Validation {
            every: 5,
            data: PathBuf::new(),
            split: "val".into(),
            samples: 0,
            categories: Vec::new(),
            best: BestMetric::OL2,
        };
        assert_eq!((1..=12).filter(|&g| v.due(g, false)).collect::<Vec<_>>(), vec![5, 10]);
        assert!(v.due(7, true));
        assert!(!Validation { every: 0, ..v }.due(10, true), "every = 0: never");
    }
}
