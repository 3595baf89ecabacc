//! Learning-rate schedules of a stage (`[[stages]]`: `learning_rate`, `warmup`, `decay`), built
//! from burn-optim's schedulers and read as a pure function of the stage's step, so that a
//! resumed run gets the rate the uninterrupted one had (no scheduler state is checkpointed,
//! none can be lost).
//!
//! * `learning_rate = [[from_step, lr], …]`, piecewise constant: the paper's form (1e-4, later
//!   1e-6 and 1e-8), and the default `decay = "piecewise"`;
//! * `warmup = W`: the first W steps rise linearly from `warmup_start` × the first rate to it
//!   (burn's linear scheduler), then the schedule proper starts;
//! * `decay = "cosine"` or `"linear"`: from the (single) rate to `final_lr` at the stage's last
//!   step (burn's cosine-annealing and linear schedulers); `decay = "step"`: × `gamma` every
//!   `decay_every` steps (burn's step scheduler).

use burn::lr_scheduler::LrSchedulerConfig;
use burn::lr_scheduler::cosine::CosineAnnealingLrSchedulerConfig;
use burn::lr_scheduler::linear::LinearLrSchedulerConfig;
use burn::lr_scheduler::sequential::SequentialLrSchedulerConfig;
use burn::lr_scheduler::step::StepLrSchedulerConfig;
use matedit_contract::manifest::Named;

/// What follows the warm-up.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Decay {
    /// `learning_rate` as written: constant between its steps (the paper's).
    #[default]
    Piecewise,
    /// Half a cosine from the rate down to `final_lr` at the stage's last step.
    Cosine,
    /// A straight line from the rate down (or up) to `final_lr` at the stage's last step.
    Linear,
    /// The rate × `gamma` every `decay_every` steps.
    Step,
}

impl Named for Decay {
    const NAMES: &'static [(&'static str, Self)] = &[
        ("piecewise", Decay::Piecewise),
        ("cosine", Decay::Cosine),
        ("linear", Decay::Linear),
        ("step", Decay::Step),
    ];
}

/// A stage's schedule, as the manifest gives it.
#[derive(Clone, Debug, PartialEq)]
pub struct ScheduleSpec {
    /// `[[from_step, lr], …]`.
    pub rates: Vec<(usize, f64)>,
    /// Steps of linear warm-up (0: none).
    pub warmup: usize,
    /// The fraction of the first rate the warm-up starts from.
    pub warmup_start: f64,
    /// What follows the warm-up.
    pub decay: Decay,
    /// The rate at the stage's last step (`cosine`, `linear`).
    pub final_lr: Option<f64>,
    /// Steps between two decays (`step`).
    pub decay_every: Option<usize>,
    /// The factor of each decay (`step`).
    pub gamma: Option<f64>,
}

/// A refusal: the manifest field at fault and why.
pub type Refusal = (&'static str, String);

impl ScheduleSpec {
    /// Checks the schedule of a stage of `steps` steps: `Err` names the field at fault.
    pub fn check(&self, steps: usize) -> Result<(), Refusal> {
        let r = &self.rates;
        if r.is_empty() || r[0].0 != 0 || r.windows(2).any(|w| w[1].0 <= w[0].0) {
            return Err((
                "learning_rate",
                "a list of [from_step, lr] starting at step 0, in increasing steps".into(),
            ));
        }
        if let Some((_, lr)) = r.iter().find(|(_, lr)| !(*lr > 0.0 && *lr <= 1.0)) {
            return Err((
                "learning_rate",
                format!("learning rates must lie in (0, 1], got {lr:e}"),
            ));
        }
        if self.warmup >= steps && self.warmup > 0 {
            return Err((
                "warmup",
                format!("{} warm-up steps leave none of the stage's {steps}", self.warmup),
            ));
        }
        if !(self.warmup_start > 0.0 && self.warmup_start <= 1.0) {
            return Err((
                "warmup_start",
                format!("a fraction of the first rate in (0, 1], got {}", self.warmup_start),
            ));
        }
        if self.warmup > 0
            && let Some((from, _)) = r.iter().skip(1).find(|(from, _)| *from <= self.warmup)
        {
            return Err((
                "learning_rate",
                format!(
                    "the rate changes at step {from}, inside the {} warm-up steps",
                    self.warmup
                ),
            ));
        }
        let unused = |field: &'static str, set: bool| -> Result<(), Refusal> {
            if set {
                Err((field, format!("not used by decay = \"{}\"", self.decay.name())))
            } else {
                Ok(())
            }
        };
        match self.decay {
            Decay::Piecewise => {
                unused("final_lr", self.final_lr.is_some())?;
                unused("decay_every", self.decay_every.is_some())?;
                unused("gamma", self.gamma.is_some())?;
            }
            Decay::Cosine | Decay::Linear => {
                unused("decay_every", self.decay_every.is_some())?;
                unused("gamma", self.gamma.is_some())?;
                self.single_rate()?;
                let lr = r[0].1;
                let f = self.final_lr.unwrap_or(0.0);
                if !(0.0..=1.0).contains(&f) || (self.decay == Decay::Cosine && f > lr) {
                    return Err((
                        "final_lr",
                        format!(
                            "must lie in [0, {}], got {f:e}",
                            if self.decay == Decay::Cosine { lr } else { 1.0 }
                        ),
                    ));
                }
                if steps < self.warmup + 2 {
                    return Err((
                        "decay",
                        format!(
                            "a {} decay needs 2 steps after the warm-up; the stage has {steps}",
                            self.decay.name()
                        ),
                    ));
                }
            }
            Decay::Step => {
                unused("final_lr", self.final_lr.is_some())?;
                self.single_rate()?;
                match self.decay_every {
                    Some(n) if n >= 1 => {}
                    _ => return Err(("decay_every", "decay = \"step\" needs decay_every ≥ 1 (steps)".into())),
                }
                let g = self.gamma.unwrap_or(0.1);
                if !(g > 0.0 && g <= 1.0) {
                    return Err(("gamma", format!("must lie in (0, 1], got {g}")));
                }
            }
        }
        Ok(())
    }

    fn single_rate(&self) -> Result<(), Refusal> {
        if self.rates.len() == 1 {
            Ok(())
        } else {
            Err((
                "learning_rate",
                format!(
                    "decay = \"{}\" starts from one rate ([[0, lr]]); piecewise rates are decay = \"piecewise\"",
                    self.decay.name()
                ),
            ))
        }
    }

    /// The burn scheduler configuration of a (checked) stage of `steps` steps.
    fn config(&self, steps: usize) -> LrSchedulerConfig {
        let lr = self.rates[0].1;
        let w = self.warmup;
        // Burn's cosine and linear schedulers reach their end after `num_iters` steps: the last
        // step of the stage.
        let span = steps.saturating_sub(w + 1).max(1);
        let main: LrSchedulerConfig = match self.decay {
            Decay::Piecewise if self.rates.len() == 1 => LrSchedulerConfig::Constant(lr),
            Decay::Piecewise => SequentialLrSchedulerConfig::new(
                self.rates
                    .iter()
                    .map(|&(_, lr)| LrSchedulerConfig::Constant(lr))
                    .collect(),
                // Counted from the end of the warm-up, where the sequence starts.
                self.rates[1..].iter().map(|&(from, _)| from - w).collect(),
            )
            .into(),
            Decay::Cosine => CosineAnnealingLrSchedulerConfig::new(lr, span)
                .with_min_lr(self.final_lr.unwrap_or(0.0))
                .into(),
            Decay::Linear => LinearLrSchedulerConfig::new(lr, self.final_lr.unwrap_or(0.0), span).into(),
            Decay::Step => StepLrSchedulerConfig::new(lr, self.decay_every.unwrap_or(1))
                .with_gamma(self.gamma.unwrap_or(0.1))
                .into(),
        };
        if w == 0 {
            return main;
        }
        let warm = LinearLrSchedulerConfig::new(lr * self.warmup_start, lr, w);
        SequentialLrSchedulerConfig::new(vec![warm.into(), main], vec![w]).into()
    }

    /// The rate of every step of a (checked) stage of `steps` steps: entry k is step k's.
    pub fn rates(&self, steps: usize) -> Vec<f64> {
        // Burn builds a scheduler from its configuration through a sequence's `init` (a sequence
        // of one: the configuration's own `build` is private to burn-optim).
        match SequentialLrSchedulerConfig::new(vec![self.config(steps)], Vec::new()).init() {
            Ok(mut s) => (0..steps).map(|_| s.step().base()).collect(),
            // A checked spec builds: this is burn refusing what `check` accepted.
            Err(e) => panic!("burn refused a checked learning-rate schedule: {e}"),
        }
    }

    /// The rate at step `step` of a (checked) stage of `steps` steps.
    pub fn lr_at(&self, step: usize, steps: usize) -> f64 {
        self.rates(steps.max(step + 1))[step]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn spec(rates: &[(usize, f64)]) -> ScheduleSpec {
        ScheduleSpec {
            rates: rates.to_vec(),
            warmup: 0,
            warmup_start: 0.01,
            decay: Decay::Piecewise,
            final_lr: None,
            decay_every: None,
            gamma: None,
        }
    }

    #[test]
    fn the_papers_piecewise_schedule_steps_at_its_first_steps() {
        let s = spec(&[(0, 1e-4), (20000, 1e-6), (27000, 1e-8)]);
        s.check(30000).unwrap();
        let r = s.rates(30000);
        assert_eq!(
            [0, 19999, 20000, 26999, 27000, 29999].map(|k| r[k]),
            [1e-4, 1e-4, 1e-6, 1e-6, 1e-8, 1e-8]
        );
        assert_eq!(spec(&[(0, 3e-4)]).rates(3), vec![3e-4; 3]);
    }

    #[test]
    fn warm_up_then_cosine_reaches_its_ends_exactly() {
        let s = ScheduleSpec {
            warmup: 10,
            decay: Decay::Cosine,
            final_lr: Some(1e-5),
            ..spec(&[(0, 1e-3)])
        };
        s.check(110).unwrap();
        let r = s.rates(110);
        assert!(
            (r[0] - 1e-5).abs() < 1e-18,
            "warm-up starts at 1 % of the rate: {}",
            r[0]
        );
        for k in 1..10 {
            assert!(r[k] > r[k - 1], "warm-up rises");
            let want = 1e-5 + (1e-3 - 1e-5) * k as f64 / 10.0;
            assert!((r[k] - want).abs() < 1e-15, "linear: step {k}: {} vs {want}", r[k]);
        }
        assert_eq!(r[10], 1e-3, "the peak, where the cosine starts");
        for k in 11..110 {
            assert!(r[k] < r[k - 1], "cosine falls: step {k}");
            // The closed form, half a cosine over the 99 steps left.
            let t = (k - 10) as f64 / 99.0;
            let want = 1e-5 + 0.5 * (1e-3 - 1e-5) * (1.0 + (std::f64::consts::PI * t).cos());
            assert!((r[k] - want).abs() < 1e-15, "step {k}: {} vs {want}", r[k]);
        }
        assert!((r[109] - 1e-5).abs() < 1e-18, "the last step has final_lr: {}", r[109]);
    }

    #[test]
    fn linear_and_step_decays_follow_their_closed_forms() {
        let lin = ScheduleSpec {
            decay: Decay::Linear,
            final_lr: Some(0.0),
            ..spec(&[(0, 1e-2)])
        };
        lin.check(11).unwrap();
        let r = lin.rates(11);
        for (k, v) in r.iter().enumerate() {
            assert!((v - 1e-2 * (1.0 - k as f64 / 10.0)).abs() < 1e-17, "step {k}: {v}");
        }
        let st = ScheduleSpec {
            decay: Decay::Step,
            decay_every: Some(3),
            gamma: Some(0.5),
            ..spec(&[(0, 0.8)])
        };
        st.check(9).unwrap();
        assert_eq!(st.rates(9), vec![0.8, 0.8, 0.8, 0.4, 0.4, 0.4, 0.2, 0.2, 0.2]);
    }

    #[test]
    fn warm_up_before_piecewise_rates_keeps_their_steps() {
        let s = ScheduleSpec {
            warmup: 4,
            warmup_start: 0.5,
            ..spec(&[(0, 1e-3), (6, 1e-4)])
        };
        s.check(8).unwrap();
        let r = s.rates(8);
        assert_eq!(r[0], 5e-4);
        assert_eq!(&r[4..], &[1e-3, 1e-3, 1e-4, 1e-4], "the change stays at step 6: {r:?}");
    }

    #[test]
    fn a_rate_is_a_pure_function_of_the_step() {
        // A resumed run asks for step k cold: it must get the uninterrupted run's rate.
        let s = ScheduleSpec {
            warmup: 7,
            decay: Decay::Cosine,
            ..spec(&[(0, 2e-3)])
        };
        let all = s.rates(50);
        for k in [0, 6, 7, 8, 30, 49] {
            assert_eq!(s.lr_at(k, 50), all[k], "step {k}");
        }
        assert!(all.iter().all(|v| v.is_finite() && *v >= 0.0));
    }

    #[test]
    fn schedules_that_cannot_run_are_refused_naming_the_field() {
        let cases: Vec<(ScheduleSpec, usize, &str, &str)> = vec![
            (spec(&[]), 10, "learning_rate", "starting at step 0"),
            (spec(&[(1, 1e-3)]), 10, "learning_rate", "starting at step 0"),
            (spec(&[(0, 1e-3), (0, 1e-4)]), 10, "learning_rate", "increasing"),
            (spec(&[(0, 0.0)]), 10, "learning_rate", "(0, 1]"),
            (spec(&[(0, f64::NAN)]), 10, "learning_rate", "(0, 1]"),
            (
                ScheduleSpec {
                    warmup: 10,
                    ..spec(&[(0, 1e-3)])
                },
                10,
                "warmup",
                "leave none",
            ),
            (
                ScheduleSpec {
                    warmup_start: 0.0,
                    ..spec(&[(0, 1e-3)])
                },
                10,
                "warmup_start",
                "(0, 1]",
            ),
            (
                ScheduleSpec {
                    warmup_start: f64::INFINITY,
                    ..spec(&[(0, 1e-3)])
                },
                10,
                "warmup_start",
                "(0, 1]",
            ),
            (
                ScheduleSpec {
                    warmup: 5,
                    ..spec(&[(0, 1e-3), (5, 1e-4)])
                },
                10,
                "learning_rate",
                "inside the 5 warm-up",
            ),
            (
                ScheduleSpec {
                    final_lr: Some(0.0),
                    ..spec(&[(0, 1e-3)])
                },
                10,
                "final_lr",
                "not used",
            ),
            (
                ScheduleSpec {
                    gamma: Some(0.5),
                    ..spec(&[(0, 1e-3)])
                },
                10,
                "gamma",
                "not used",
            ),
            (
                ScheduleSpec {
                    decay: Decay::Cosine,
                    ..spec(&[(0, 1e-3), (5, 1e-4)])
                },
                10,
                "learning_rate",
                "one rate",
            ),
            (
                ScheduleSpec {
                    decay: Decay::Cosine,
                    final_lr: Some(1e-2),
                    ..spec(&[(0, 1e-3)])
                },
                10,
                "final_lr",
                "[0, 0.001]",
            ),
            (
                ScheduleSpec {
                    decay: Decay::Linear,
                    final_lr: Some(-1.0),
                    ..spec(&[(0, 1e-3)])
                },
                10,
                "final_lr",
                "[0, 1]",
            ),
            (
                ScheduleSpec {
                    decay: Decay::Linear,
                    decay_every: Some(2),
                    ..spec(&[(0, 1e-3)])
                },
                10,
                "decay_every",
                "not used",
            ),
            (
                ScheduleSpec {
                    decay: Decay::Cosine,
                    warmup: 9,
                    ..spec(&[(0, 1e-3)])
                },
                10,
                "decay",
                "needs 2 steps",
            ),
            (
                ScheduleSpec {
                    decay: Decay::Step,
                    ..spec(&[(0, 1e-3)])
                },
                10,
                "decay_every",
                "needs decay_every",
            ),
            (
                ScheduleSpec {
                    decay: Decay::Step,
                    decay_every: Some(0),
                    ..spec(&[(0, 1e-3)])
                },
                10,
                "decay_every",
                "needs decay_every",
            ),
            (
                ScheduleSpec {
                    decay: Decay::Step,
                    decay_every: Some(2),
                    gamma: Some(1.5),
                    ..spec(&[(0, 1e-3)])
                },
                10,
                "gamma",
                "(0, 1]",
            ),
            (
                ScheduleSpec {
                    decay: Decay::Step,
                    decay_every: Some(2),
                    final_lr: Some(0.0),
                    ..spec(&[(0, 1e-3)])
                },
                10,
                "final_lr",
                "not used",
            ),
        ];
        for (s, steps, field, want) in cases {
            let (f, msg) = s.check(steps).unwrap_err();
            assert_eq!(f, field, "{s:?}: {msg}");
            assert!(msg.contains(want), "{s:?}: {msg}");
        }
    }

    #[test]
    fn every_accepted_schedule_gives_finite_rates_in_range() {
        // A sweep over the documented ranges: whatever `check` accepts, burn builds, and every
        // rate is finite and in [0, 1].
        for decay in [Decay::Piecewise, Decay::Cosine, Decay::Linear, Decay::Step] {
            for steps in [1, 2, 3, 10, 1000] {
                for warmup in [0, 1, 5, 999] {
                    for lr in [1e-12, 1e-4, 1.0] {
                        for final_lr in [None, Some(0.0), Some(lr / 10.0), Some(lr)] {
                            let s = ScheduleSpec {
                                warmup,
                                warmup_start: 1e-3,
                                decay,
                                final_lr: final_lr.filter(|_| matches!(decay, Decay::Cosine | Decay::Linear)),
                                decay_every: (decay == Decay::Step).then_some(7),
                                gamma: (decay == Decay::Step).then_some(0.3),
                                ..spec(&[(0, lr)])
                            };
                            if s.check(steps).is_err() {
                                continue;
                            }
                            let r = s.rates(steps);
                            assert_eq!(r.len(), steps);
                            assert!(
                                r.iter().all(|v| v.is_finite() && (0.0..=1.0).contains(v)),
                                "{s:?}: {r:?}"
                            );
                        }
                    }
                }
            }
        }
    }
}
