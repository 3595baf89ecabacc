//! The loss of Eq. 5 and each of its terms.
//!
//! ```text
//! l = w_n·l_normal + w_m·l_material + w_p·l_perceptual            (Eq. 5; Eq. 3, Eq. 4)
//!   + w_L·l_illumination + w_s·l_ssim + w_E·l_light_energy + w_D·l_light_direction
//! ```
//!
//! The first line is the paper's; the four terms of the second are not in it, and their weights
//! are 0 unless a manifest's `[loss]` sets them.
//!
//! Each term is defined once, in its own module, as a [`Term`]: its name (its weight's field in
//! `[loss]` and its field in `metrics.jsonl`), its weight's symbol, default and range, how it is
//! computed, its plot label, and the stage kinds that use it. [`TERMS`] lists them in the order
//! the logs write them. The step ([`super::step`]), the plot ([`super::plot`]), the bench and the
//! manifest's `[loss]` read that list and nothing else, so adding a term is one module here, its
//! line in [`TERMS`], and its test.
//!
//! Every term is on the scale of the paper's image metric (L2 on [0, 255] images) or a plain
//! mean, so the paper's weights keep their meaning. The image terms compare through
//! [`display`], a smooth version of the evaluation's tone map (`metrics`): the ground truth's
//! exposure (its 99th-percentile channel value on the object becomes white), a soft clamp to
//! [0, 1] instead of the hard one (so an over-bright prediction still has a gradient back), and a
//! display gamma whose slope at black is bounded like sRGB's. They therefore weigh each pixel as
//! the L2 and SSIM scores will see it, whatever the light probe's absolute scale.

pub mod illumination;
pub mod light_direction;
pub mod light_energy;
pub mod material;
pub mod normal;
pub mod perceptual;
mod reduce;
pub mod ssim;
#[cfg(test)]
mod tests;
mod tone;

pub use illumination::TERM as ILLUMINATION;
pub use light_direction::TERM as LIGHT_DIRECTION;
pub use light_energy::TERM as LIGHT_ENERGY;
pub use material::TERM as MATERIAL;
pub use normal::TERM as NORMAL;
pub use perceptual::{Perceptual, TERM as PERCEPTUAL};
pub use reduce::{mean, row_sums, sum_all};
pub use ssim::TERM as SSIM;
pub use tone::{display, exposure};

use super::stage_kind::StageKind;
use crate::data::TensorBatch;
use burn::tensor::Tensor;
use serde::de::{MapAccess, Visitor};
use serde::ser::SerializeMap;
use serde::{Deserialize, Deserializer, Serialize, Serializer};

/// Every term, in the order `metrics.jsonl` writes them (after the total).
pub const TERMS: [&Term; 7] = [
    &NORMAL,
    &MATERIAL,
    &PERCEPTUAL,
    &ILLUMINATION,
    &SSIM,
    &LIGHT_ENERGY,
    &LIGHT_DIRECTION,
];

/// The largest weight a manifest may give any term.
pub const MAX_WEIGHT: f64 = 1e6;

/// One term of the loss.
#[derive(Debug)]
pub struct Term {
    /// Its name: its weight's field in `[loss]`, its field in `metrics.jsonl`.
    pub name: &'static str,
    /// Its weight's symbol (w_n, …).
    pub symbol: &'static str,
    /// What the weight multiplies, for the plot's legend and the docs.
    pub label: &'static str,
    /// Its curve's colour on the plot (RGB).
    pub colour: (u8, u8, u8),
    /// Its weight where `[loss]` gives none: the paper's for its terms, 0 (left out) for the others.
    pub default_weight: f64,
    /// Whether it is computed and logged at weight 0 (the paper's terms, so that a run that
    /// weighs one at 0 still logs how it goes); the others are computed only when weighted.
    pub logged_at_zero: bool,
    /// Whether `metrics.jsonl` writes it when it is 0 (the later options are left out then, so
    /// that runs without them log what they always logged).
    pub written_when_zero: bool,
    /// The stage kinds whose steps use it.
    pub stages: &'static [StageKind],
    /// How it is computed.
    pub compute: Compute,
}

/// How a term is computed.
#[derive(Debug)]
pub enum Compute {
    /// From a prediction and its truth: `None` where the step did not predict what it compares.
    Prediction(fn(&Predicted, &TensorBatch) -> Option<Tensor<1>>),
    /// From the predicted L' and the true L (`[B, 3, He, 2He]` each): a step that computes it
    /// predicts L'.
    Light(fn(Tensor<4>, Tensor<4>) -> Tensor<1>),
    /// From a rendered image and its truth on the object's pixels; a step with I' and O' adds
    /// the two.
    Image(fn(&ImagePair) -> Tensor<1>),
}

impl Term {
    /// Whether it compares L' with L: a step that computes it predicts L'.
    pub fn reads_light(&self) -> bool {
        matches!(self.compute, Compute::Light(_))
    }

    /// Whether a step of `kind` under the weights `w` computes this term.
    pub fn computed(&self, kind: StageKind, w: &LossWeights) -> bool {
        self.stages.contains(&kind) && (self.logged_at_zero || w[self] > 0.0)
    }

    fn index(&self) -> usize {
        TERMS.iter().position(|t| t.name == self.name).unwrap_or(0)
    }
}

/// What a step predicted, for the prediction terms (`None`: not predicted by this step).
pub struct Predicted<'a> {
    /// n', `[B, 3, H, W]`.
    pub normals: Option<&'a Tensor<4>>,
    /// m', `[B, R, 108]`, normalised.
    pub materials: Option<&'a Tensor<3>>,
    /// L', `[B, 3, He, 2He]`.
    pub env: Option<&'a Tensor<4>>,
}

/// A rendered image and what it should be, for the image terms.
pub struct ImagePair<'a> {
    /// I' or O', `[B, 3, H, W]`, linear.
    pub rendered: &'a Tensor<4>,
    /// I or O.
    pub truth: &'a Tensor<4>,
    /// The object's pixels, `[B, 1, H, W]`.
    pub mask: &'a Tensor<4>,
    /// The run's perceptual loss.
    pub perceptual: &'a Perceptual,
}

/// The weights of the loss, one per term of [`TERMS`]; `w[&SSIM]` reads one.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LossWeights([f64; TERMS.len()]);

impl LossWeights {
    /// Every weight 0: a base for runs and tests that train one term alone.
    pub const NONE: LossWeights = LossWeights([0.0; TERMS.len()]);

    /// These weights with `term`'s set to `w`.
    pub fn with(mut self, term: &Term, w: f64) -> Self {
        self.0[term.index()] = w;
        self
    }

    /// The terms of non-zero weight, by name.
    pub fn weighted(&self) -> Vec<&'static str> {
        TERMS.iter().filter(|t| self[t] != 0.0).map(|t| t.name).collect()
    }
}

impl Default for LossWeights {
    /// Each term's default weight (the paper's Eq. 5).
    fn default() -> Self {
        Self(TERMS.map(|t| t.default_weight))
    }
}

impl std::ops::Index<&Term> for LossWeights {
    type Output = f64;
    fn index(&self, t: &Term) -> &f64 {
        &self.0[t.index()]
    }
}

/// The terms of one step (unweighted) and their weighted total. `metrics.jsonl` writes it as
/// `{"total": …, "normal": …, …}` in the order of [`TERMS`].
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Losses {
    /// The loss (Eq. 5 and the terms weighted in).
    pub total: f64,
    terms: [f64; TERMS.len()],
}

impl Losses {
    /// The terms' total under the weights `w` (a term a step did not compute is 0, and adds
    /// nothing).
    pub fn weighted_total(&self, w: &LossWeights) -> f64 {
        TERMS.iter().map(|t| w[t] * self[t]).reduce(|a, b| a + b).unwrap_or(0.0)
    }

    /// Sets `term`'s value.
    pub fn set(&mut self, term: &Term, v: f64) {
        self.terms[term.index()] = v;
    }

    /// The total, then every term in the order of [`TERMS`] (a rank's block of a data-parallel step).
    pub fn to_values(&self) -> [f64; TERMS.len() + 1] {
        let mut v = [self.total; TERMS.len() + 1];
        v[1..].copy_from_slice(&self.terms);
        v
    }

    /// The terms from [`Losses::to_values`]'s order, the total formed under `w` as one process forms it.
    pub fn from_values(v: &[f64], w: &LossWeights) -> Self {
        let mut l = Losses::default();
        for (t, x) in l.terms.iter_mut().zip(v.iter().skip(1)) {
            *t = *x;
        }
        l.total = l.weighted_total(w);
        l
    }
}

impl std::ops::Index<&Term> for Losses {
    type Output = f64;
    fn index(&self, t: &Term) -> &f64 {
        &self.terms[t.index()]
    }
}

impl Serialize for Losses {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        let written: Vec<&&Term> = TERMS.iter().filter(|t| t.written_when_zero || self[t] != 0.0).collect();
        let mut m = s.serialize_map(Some(written.len() + 1))?;
        m.serialize_entry("total", &self.total)?;
        for t in written {
            m.serialize_entry(t.name, &self[t])?;
        }
        m.end()
    }
}

impl<'de> Deserialize<'de> for Losses {
    /// Each term by its name, 0 where the line has none; other fields are ignored.
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        struct LossesVisitor;
        impl<'de> Visitor<'de> for LossesVisitor {
            type Value = Losses;
            fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
                f.write_str("a map of loss terms")
            }
            fn visit_map<A: MapAccess<'de>>(self, mut map: A) -> Result<Losses, A::Error> {
                let mut l = Losses::default();
                let mut total = None;
                while let Some(key) = map.next_key::<String>()? {
                    if key == "total" {
                        total = Some(map.next_value::<f64>()?);
                    } else if let Some(t) = TERMS.iter().find(|t| t.name == key) {
                        l.set(t, map.next_value::<f64>()?);
                    } else {
                        map.next_value::<serde::de::IgnoredAny>()?;
                    }
                }
                l.total = total.ok_or_else(|| serde::de::Error::missing_field("total"))?;
                Ok(l)
            }
        }
        d.deserialize_map(LossesVisitor)
    }
}

#[cfg(test)]
mod registry {
    use super::*;

    /// Each term has its own name (its `[loss]` field and its `metrics.jsonl` field), symbol and
    /// colour, is found at its own place in [`TERMS`], and is used by some stage kind.
    #[test]
    fn every_term_is_one_entry_of_its_own() {
        for (i, t) in TERMS.iter().enumerate() {
            assert_eq!(t.index(), i, "{}", t.name);
            assert!(!t.stages.is_empty(), "{}", t.name);
            assert!((0.0..=MAX_WEIGHT).contains(&t.default_weight), "{}", t.name);
            for u in &TERMS[..i] {
                assert!(
                    t.name != u.name && t.symbol != u.symbol && t.colour != u.colour,
                    "{} and {}",
                    t.name,
                    u.name
                );
            }
            assert!(
                t.name != "total" && !t.name.starts_with("vgg16"),
                "{} is another field's name",
                t.name
            );
        }
        // Eq. 5's weights are the paper's; the other terms are off by default.
        let w = LossWeights::default();
        assert_eq!((w[&NORMAL], w[&MATERIAL], w[&PERCEPTUAL]), (1e4, 1e3, 1.0));
        assert_eq!(w.weighted(), ["normal", "material", "perceptual"]);
    }

    /// `metrics.jsonl`'s loss fields are written in [`TERMS`]' order after the total, the later
    /// options only when non-zero, and read back to the same values; a line of an older run
    /// (without the options) reads with them 0; a line without a total is refused.
    #[test]
    fn losses_are_written_and_read_by_the_terms_names() {
        let mut l = Losses::default();
        for (k, t) in TERMS.iter().enumerate() {
            l.set(t, 0.5 + k as f64);
        }
        l.total = 7.25;
        let text = serde_json::to_string(&l).unwrap();
        assert_eq!(
            text,
            r#"{"total":7.25,"normal":0.5,"material":1.5,"perceptual":2.5,"illumination":3.5,"ssim":4.5,"light_energy":5.5,"light_direction":6.5}"#
        );
        assert_eq!(serde_json::from_str::<Losses>(&text).unwrap(), l);
        let mut short = Losses::default();
        short.set(&NORMAL, 0.25);
        short.total = 2500.0;
        let text = serde_json::to_string(&short).unwrap();
        assert_eq!(
            text,
            r#"{"total":2500.0,"normal":0.25,"material":0.0,"perceptual":0.0,"illumination":0.0,"ssim":0.0}"#
        );
        let old = r#"{"total":1.0,"normal":0.1,"material":0.2,"perceptual":0.3,"unknown":[1]}"#;
        let read: Losses = serde_json::from_str(old).unwrap();
        assert_eq!((read.total, read[&PERCEPTUAL], read[&SSIM]), (1.0, 0.3, 0.0));
        assert!(serde_json::from_str::<Losses>(r#"{"normal":0.1}"#).is_err());
    }

    /// The total is Σ w·l in [`TERMS`]' order, and a data-parallel step's block carries every
    /// term through.
    #[test]
    fn the_total_is_the_weighted_sum_and_survives_the_ranks_block() {
        let mut l = Losses::default();
        for (k, t) in TERMS.iter().enumerate() {
            l.set(t, 1.0 + k as f64);
        }
        let w = LossWeights::NONE
            .with(&NORMAL, 2.0)
            .with(&SSIM, 0.5)
            .with(&LIGHT_DIRECTION, 3.0);
        assert_eq!(l.weighted_total(&w), 2.0 * 1.0 + 0.5 * 5.0 + 3.0 * 7.0);
        l.total = l.weighted_total(&w);
        let v = l.to_values();
        assert_eq!(v.len(), TERMS.len() + 1);
        assert_eq!(Losses::from_values(&v, &w), l);
        assert_eq!(w.weighted(), ["normal", "ssim", "light_direction"]);
    }

    /// A stage kind computes the terms its steps use: the paper's at any weight, the others
    /// only when weighted.
    #[test]
    fn stage_kinds_compute_the_terms_they_use() {
        let computed = |kind, w: &LossWeights| -> Vec<&str> {
            TERMS.iter().filter(|t| t.computed(kind, w)).map(|t| t.name).collect()
        };
        let w = LossWeights::default();
        assert_eq!(computed(StageKind::Pretrain, &w), ["normal", "material"]);
        assert_eq!(computed(StageKind::Joint, &w), ["normal", "material", "perceptual"]);
        assert_eq!(computed(StageKind::EncoderDecoder, &w), ["material", "perceptual"]);
        let all = TERMS.iter().fold(LossWeights::NONE, |w, t| w.with(t, 1.0));
        assert_eq!(
            computed(StageKind::Pretrain, &all),
            ["normal", "material", "illumination", "light_energy", "light_direction"]
        );
        assert_eq!(computed(StageKind::Joint, &all).len(), TERMS.len());
        assert_eq!(
            computed(StageKind::EncoderDecoder, &all),
            ["material", "perceptual", "ssim"]
        );
    }
}
