//! One `[[stages]]` entry of a training manifest: what it trains, on which split, for how many
//! steps, and its learning-rate schedule.

use super::super::schedule::{Decay, ScheduleSpec};
use super::super::stage_kind::StageKind;
use super::super::step::RenderWith;
use matedit_contract::manifest::{Choice, Named};
use serde::{Deserialize, Serialize};

/// One `[[stages]]` entry.
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct StageSection {
    /// Stage name (`pretrain`, `joint`, `finetune`, `multi-material`, …).
    pub name: String,
    /// What it trains: `pretrain` (normal + material modules, L2 only) or `joint` (Eq. 5
    /// through the rendering layer; also used for finetuning and multi-material stages).
    pub kind: StageKind,
    /// Joint stages: where the rendering layer takes n, m and L from (`predicted`, the default,
    /// or `truth`: the "combined" rows of Tables 1 and 2 train one module through the layer
    /// given the other two ground truths).
    #[serde(default)]
    pub render_with: RenderWith,
    /// Start from the final weights of this earlier stage instead of the previous one (stages
    /// then branch: e.g. the standalone and combined modules of Tables 1 and 2 from one
    /// pretrained network).
    #[serde(default)]
    pub from: Option<String>,
    /// Dataset of this stage, when not `[data].dataset`.
    #[serde(default)]
    pub dataset: Option<String>,
    /// Split to train on.
    #[serde(default = "default_split")]
    pub split: String,
    /// Optimisation steps.
    pub steps: usize,
    /// Samples per step.
    pub batch_size: usize,
    /// Learning rates: `[[from_step, lr], …]` (the paper: 1e-4, later 1e-6 and 1e-8); the
    /// starting rate of a `cosine`, `linear` or `step` decay (`[[0, lr]]`).
    pub learning_rate: Vec<(usize, f64)>,
    /// Steps of linear warm-up before the schedule (default 0: none).
    #[serde(default)]
    pub warmup: usize,
    /// The fraction of the first rate the warm-up starts from (default 0.01).
    #[serde(default = "default_warmup_start")]
    pub warmup_start: f64,
    /// After the warm-up: `piecewise` (default: `learning_rate` as written), `cosine` or
    /// `linear` (to `final_lr` at the stage's last step), `step` (× `gamma` every `decay_every`).
    #[serde(default = "default_decay")]
    pub decay: Choice<Decay>,
    /// The rate at the stage's last step, for `cosine` and `linear` (default 0).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub final_lr: Option<f64>,
    /// Steps between two decays, for `step`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub decay_every: Option<usize>,
    /// The factor of each decay, for `step` (default 0.1).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub gamma: Option<f64>,
    /// Adam β1 (the paper: 0.9, later 0.5).
    #[serde(default = "default_beta1")]
    pub beta1: f64,
    /// Adam β2.
    #[serde(default = "default_beta2")]
    pub beta2: f64,
    /// Steps between checkpoints (0: only at the end of the stage).
    #[serde(default)]
    pub checkpoint_every: usize,
}

fn default_warmup_start() -> f64 {
    0.01
}
fn default_decay() -> Choice<Decay> {
    Choice::Known(Decay::Piecewise, Decay::Piecewise.name().to_owned())
}
fn default_split() -> String {
    "train".into()
}
fn default_beta1() -> f64 {
    0.9
}
fn default_beta2() -> f64 {
    0.999
}

impl StageSection {
    /// The stage's learning-rate schedule (an unknown `decay` name reads as `piecewise`: the
    /// manifest's check has refused it before any schedule is asked for).
    pub fn schedule(&self) -> ScheduleSpec {
        ScheduleSpec {
            rates: self.learning_rate.clone(),
            warmup: self.warmup,
            warmup_start: self.warmup_start,
            decay: match self.decay {
                Choice::Known(d, _) => d,
                Choice::Unknown(_) => Decay::Piecewise,
            },
            final_lr: self.final_lr,
            decay_every: self.decay_every,
            gamma: self.gamma,
        }
    }

    /// The learning rate of every step of the stage (entry k: step k's).
    pub fn rates(&self) -> Vec<f64> {
        self.schedule().rates(self.steps)
    }

    /// The learning rate at `step`.
    pub fn lr_at(&self, step: usize) -> f64 {
        self.schedule().lr_at(step, self.steps)
    }
}
