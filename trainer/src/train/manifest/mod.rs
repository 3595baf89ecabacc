//! Training manifests (`manifests/train/*.toml`): what to train, on which data, in which stages.
//! Field reference: `manifests/README.md` (section "Training manifests"). Errors name the file,
//! the line and the field, before any work starts.

use super::loss::perceptual::{DEFAULT_LAYERS, Perceptual};
use super::loss::{LossWeights, MAX_WEIGHT, TERMS};
use super::schedule::Decay;
use super::stage_kind::StageKind;
use super::step::RenderWith;
use super::validation::{BestMetric, Validation};
use crate::data::OnCorrupt;
use crate::device::DeviceName;
use crate::model::network::{Exposure, NetConfig};
use crate::model::vgg16::Layer;
use crate::model::{Init, Widths};
use matedit_contract::manifest::{Choice, ManifestError, Named, Resolved, expand_vars, key_span, table_key_span};
use serde::Deserialize;
use std::path::{Path, PathBuf};
use toml::Spanned;

/// A training manifest as written.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TrainManifest {
    /// Run identity and output.
    pub run: RunSection,
    /// Network shape.
    pub model: ModelSection,
    /// Eq. 5 weights and the perceptual loss.
    #[serde(default)]
    pub loss: LossSection,
    /// Data pipeline.
    pub data: DataSection,
    /// Stages, in order.
    pub stages: Vec<Spanned<StageSection>>,
    /// Evaluation after the last stage.
    #[serde(default)]
    pub eval: EvalSection,
}

/// `[run]`.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RunSection {
    /// Run name.
    pub name: String,
    /// Seed of initialisation, data order and dropout.
    pub seed: u64,
    /// Output folder (relative to the working directory); `trainer run --out` overrides.
    pub output: String,
    /// `cpu` (Burn's flex backend), `wgpu` (the rendering layer as a GPU kernel; needs the `wgpu`
    /// feature) or `cuda` (needs the `cuda` feature).
    #[serde(default = "default_device")]
    pub device: Spanned<Choice<DeviceName>>,
    /// Start from the weights of this checkpoint folder (another run's stage) instead of a fresh
    /// initialisation: finetuning, e.g. the paper's multi-material model from the single-material
    /// one. The optimiser starts fresh.
    #[serde(default)]
    pub init_from: Option<Spanned<String>>,
}

fn default_device() -> Spanned<Choice<DeviceName>> {
    Choice::default_to(DeviceName::Cpu)
}

/// `[model]`.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ModelSection {
    /// Input side; must equal the dataset's image resolution.
    pub input_size: Spanned<usize>,
    /// Environment height (64 in the paper; the datasets' maps are 64×128).
    #[serde(default = "default_env_height")]
    pub env_height: Spanned<usize>,
    /// `cpu-small`, `paper`, or a table of widths.
    pub widths: Spanned<WidthsSpec>,
    /// `uniform-0.08` (the paper) or `default` (Burn's Kaiming uniform).
    #[serde(default = "default_init")]
    pub init: Spanned<Choice<Init>>,
    /// `absolute` (the paper: each image as rendered) or `normalised` (each image at one mean
    /// object luminance, as `matedit edit` shows a photo; [`Exposure`]).
    #[serde(default = "default_exposure")]
    pub exposure: Spanned<Choice<Exposure>>,
}

fn default_env_height() -> Spanned<usize> {
    Spanned::new(0..0, 64)
}

fn default_init() -> Spanned<Choice<Init>> {
    Choice::default_to(Init::Uniform008)
}

fn default_exposure() -> Spanned<Choice<Exposure>> {
    Choice::default_to(Exposure::Absolute)
}

/// `[loss]`: the weight of each loss term (by the term's name: `loss::TERMS`) and the
/// perceptual loss's network.
#[derive(Clone, Debug)]
pub struct LossSection {
    /// Each term's weight, in the order of `loss::TERMS`; the term's default, with an empty
    /// span, where the manifest gives none.
    pub weights: [Spanned<f64>; TERMS.len()],
    /// Pretrained VGG16 weights (torchvision `.pth`/`.pt`, or safetensors) for the perceptual
    /// loss; without, the documented fallback is used and the log says so.
    pub vgg16: Option<Spanned<String>>,
    /// VGG16 layers compared (default: relu1_2, relu2_2, relu3_3, relu4_3).
    pub vgg16_layers: Spanned<Vec<Layer>>,
}

/// `[loss]`'s fields: the terms' names, then the perceptual loss's.
const LOSS_FIELDS: [&str; TERMS.len() + 2] = {
    let mut names = [""; TERMS.len() + 2];
    let mut i = 0;
    while i < TERMS.len() {
        names[i] = TERMS[i].name;
        i += 1;
    }
    names[TERMS.len()] = "vgg16";
    names[TERMS.len() + 1] = "vgg16_layers";
    names
};

impl<'de> Deserialize<'de> for LossSection {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        struct Fields;
        impl<'de> serde::de::Visitor<'de> for Fields {
            type Value = LossSection;
            fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
                f.write_str("the [loss] table")
            }
            fn visit_map<A: serde::de::MapAccess<'de>>(self, mut map: A) -> Result<LossSection, A::Error> {
                use serde::de::Error;
                let mut section = LossSection::default();
                let mut seen = [false; LOSS_FIELDS.len()];
                while let Some(key) = map.next_key::<String>()? {
                    let Some(k) = LOSS_FIELDS.iter().position(|f| *f == key) else {
                        return Err(A::Error::unknown_field(&key, &LOSS_FIELDS));
                    };
                    if std::mem::replace(&mut seen[k], true) {
                        return Err(A::Error::duplicate_field(LOSS_FIELDS[k]));
                    }
                    match LOSS_FIELDS[k] {
                        "vgg16" => section.vgg16 = Some(map.next_value()?),
                        "vgg16_layers" => section.vgg16_layers = map.next_value()?,
                        _ => section.weights[k] = map.next_value()?,
                    }
                }
                Ok(section)
            }
        }
        d.deserialize_map(Fields)
    }
}

fn default_layers() -> Spanned<Vec<Layer>> {
    Spanned::new(0..0, DEFAULT_LAYERS.to_vec())
}

impl Default for LossSection {
    fn default() -> Self {
        Self {
            weights: TERMS.map(|t| Spanned::new(0..0, t.default_weight)),
            vgg16: None,
            vgg16_layers: default_layers(),
        }
    }
}

/// Widths by preset name or explicitly.
#[derive(Clone, Debug, Deserialize)]
#[serde(untagged)]
pub enum WidthsSpec {
    /// `cpu-small` or `paper`.
    Preset(String),
    /// Every width.
    Explicit {
        /// First strided convolution's channels.
        base_channels: usize,
        /// Channel cap.
        max_channels: usize,
        /// Fully connected width.
        hidden: usize,
        /// Normal module's fine-scale channels.
        normal_channels: usize,
        /// Dropout probability.
        #[serde(default = "default_dropout")]
        dropout: f64,
    },
}

fn default_dropout() -> f64 {
    0.5
}

/// `[data]`.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DataSection {
    /// Dataset folder (a `datagen` output: `index.jsonl`, `dataset.json`, `shards/`).
    pub dataset: String,
    /// Shuffle buffer, in samples.
    #[serde(default = "default_shuffle")]
    pub shuffle_buffer: usize,
    /// Background decoding threads.
    #[serde(default = "default_workers")]
    pub workers: usize,
    /// `stop` (default): a corrupt or truncated file ends the run naming it; `skip`: it is
    /// skipped and reported.
    #[serde(default = "default_on_corrupt")]
    pub on_corrupt: Spanned<Choice<OnCorrupt>>,
    /// Recompute every file's checksum when reading it.
    #[serde(default = "default_true")]
    pub verify_checksums: bool,
}

fn default_shuffle() -> usize {
    64
}
fn default_workers() -> usize {
    2
}
fn default_on_corrupt() -> Spanned<Choice<OnCorrupt>> {
    Choice::default_to(OnCorrupt::Stop)
}
fn default_true() -> bool {
    true
}

/// `[eval]`.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct EvalSection {
    /// Held-out split.
    #[serde(default = "default_test")]
    pub split: String,
    /// At most this many samples (0: all).
    #[serde(default)]
    pub max_samples: usize,
    /// Score only these shape categories (default: all; the paper's Table 2 is on cars).
    #[serde(default)]
    pub categories: Vec<String>,
    /// Validate while training every this many steps of the run, and at each stage's end
    /// (default 0: only the evaluation after the last stage).
    #[serde(default = "default_every")]
    pub every: Spanned<usize>,
    /// The split validated on (default `val`: a dataset split of role `val`).
    #[serde(default = "default_val")]
    pub val_split: String,
    /// At most this many samples per validation (0: all).
    #[serde(default = "default_val_samples")]
    pub val_samples: usize,
    /// The score `checkpoints/best` is kept by (default `o_l2`).
    #[serde(default = "default_best")]
    pub best: Spanned<Choice<BestMetric>>,
}

fn default_every() -> Spanned<usize> {
    Spanned::new(0..0, 0)
}
fn default_val() -> String {
    "val".into()
}
fn default_val_samples() -> usize {
    64
}
fn default_best() -> Spanned<Choice<BestMetric>> {
    Choice::default_to(BestMetric::OL2)
}

fn default_test() -> String {
    "test".into()
}

impl Default for EvalSection {
    fn default() -> Self {
        Self {
            split: default_test(),
            max_samples: 0,
            categories: Vec::new(),
            every: default_every(),
            val_split: default_val(),
            val_samples: default_val_samples(),
            best: default_best(),
        }
    }
}

/// A validated manifest with its resolved values.
#[derive(Clone, Debug)]
pub struct TrainPlan {
    /// The manifest, resolved (`extends` followed, `--set` applied): its path, and the text that
    /// is hashed into checkpoints (so a resume refuses a changed manifest) and saved with the run.
    pub source: Resolved,
    /// As written.
    pub manifest: TrainManifest,
    /// Network configuration.
    pub net: NetConfig,
    /// Default dataset folder.
    pub dataset: PathBuf,
    /// Eq. 5 weights.
    pub weights: LossWeights,
    /// VGG16 weights for the perceptual loss, if configured.
    pub vgg16: Option<PathBuf>,
    /// Checkpoint to start from, if configured.
    pub init_from: Option<PathBuf>,
    /// Skip corrupt samples instead of stopping.
    pub skip_corrupt: bool,
    /// The device the run trains on.
    pub device: DeviceName,
    /// Validation while training (`[eval] every`), if asked for.
    pub validation: Option<Validation>,
}

/// Reads and validates a training manifest, its `extends` followed and `sets` (`--set
/// PATH=VALUE`) applied.
pub fn load(path: &Path, sets: &[String]) -> Result<TrainPlan, ManifestError> {
    validate(Resolved::read(path, sets)?)
}

/// Validates manifest text that came from `path` (its `extends` followed from there).
pub fn parse(path: &Path, text: String) -> Result<TrainPlan, ManifestError> {
    validate(Resolved::resolve(path, text, &[])?)
}

/// Validates a resolved manifest.
pub fn validate(source: Resolved) -> Result<TrainPlan, ManifestError> {
    let m: TrainManifest = source.parse()?;
    let text = &source.text;
    let bad = |span: std::ops::Range<usize>, field: &str, msg: String| source.invalid(span, field, msg);
    let widths = match m.model.widths.get_ref() {
        WidthsSpec::Preset(p) => Widths::preset(p).ok_or_else(|| {
            bad(
                m.model.widths.span(),
                "model.widths",
                format!("unknown preset {p:?} ({}, or a table)", Widths::preset_names()),
            )
        })?,
        WidthsSpec::Explicit {
            base_channels,
            max_channels,
            hidden,
            normal_channels,
            dropout,
        } => {
            if [*base_channels, *max_channels, *hidden, *normal_channels].contains(&0) || !(0.0..1.0).contains(dropout)
            {
                return Err(bad(
                    m.model.widths.span(),
                    "model.widths",
                    "widths must be positive and dropout in [0, 1)".into(),
                ));
            }
            Widths::new(*base_channels, *max_channels, *hidden, *normal_channels).with_dropout(*dropout)
        }
    };
    let init = source.choice(&m.model.init, "model.init")?;
    let exposure = source.choice(&m.model.exposure, "model.exposure")?;
    let kinds = |k: StageKind| m.stages.iter().filter(|s| s.get_ref().kind == k).count();
    if kinds(StageKind::EncoderDecoder) > 0
        && let Some(other) = m.stages.iter().find(|s| s.get_ref().kind != StageKind::EncoderDecoder)
    {
        return Err(bad(
            other.span(),
            "stages.kind",
            "Baseline 1 (kind = \"encoder-decoder\") is a network of its own: give it a manifest without pretrain or joint stages".into(),
        ));
    }
    let net = NetConfig::new(*m.model.input_size.get_ref(), widths)
        .with_env_height(*m.model.env_height.get_ref())
        .with_init(init)
        .with_exposure((exposure == Exposure::Normalised).then_some(exposure))
        .with_encoder_decoder(m.stages.iter().any(|s| s.get_ref().kind == StageKind::EncoderDecoder));
    if let Err(e) = net.validate() {
        let span = if e.starts_with("input_size") {
            m.model.input_size.span()
        } else {
            m.model.env_height.span()
        };
        return Err(bad(
            span,
            if e.starts_with("input_size") {
                "model.input_size"
            } else {
                "model.env_height"
            },
            e,
        ));
    }
    let device = source.choice(&m.run.device, "run.device")?;
    if let Err(e) = device.check_built() {
        return Err(bad(m.run.device.span(), "run.device", e));
    }
    let skip_corrupt = source.choice(&m.data.on_corrupt, "data.on_corrupt")? == OnCorrupt::Skip;
    if m.stages.is_empty() {
        return Err(bad(0..0, "stages", "at least one [[stages]] entry is needed".into()));
    }
    for (i, st) in m.stages.iter().enumerate() {
        let s = st.get_ref();
        let field = |f: &str| format!("stages[{i}].{f}");
        // An error names the line of the key that is wrong, not the stage's first line.
        let at = |key: &str| key_span(text, st.span(), key);
        for (key, v) in [("steps", s.steps), ("batch_size", s.batch_size)] {
            if v == 0 {
                return Err(bad(at(key), &field(key), format!("{key} must be positive")));
            }
        }
        if let Choice::Unknown(name) = &s.decay {
            return Err(bad(at("decay"), &field("decay"), Decay::refusal(name)));
        }
        if let Err((key, msg)) = s.schedule().check(s.steps) {
            return Err(bad(at(key), &field(key), msg));
        }
        for (name, b) in [("beta1", s.beta1), ("beta2", s.beta2)] {
            if !(0.0..1.0).contains(&b) {
                return Err(bad(at(name), &field(name), format!("must lie in [0, 1), got {b}")));
            }
        }
        let rw = s.render_with;
        if s.kind != StageKind::Joint && rw != RenderWith::default() {
            return Err(bad(
                at("render_with"),
                &field("render_with"),
                format!(
                    "a {} stage does not render; render_with applies to joint stages",
                    if s.kind == StageKind::Pretrain {
                        "pretrain"
                    } else {
                        "encoder-decoder"
                    }
                ),
            ));
        }
        if ![rw.normals, rw.material, rw.illumination]
            .iter()
            .any(|s| s.learns_through_layer())
        {
            return Err(bad(
                at("render_with"),
                &field("render_with"),
                "with none of n, m and L \"predicted\" (all \"truth\" or \"detached\") the rendering layer trains nothing".into(),
            ));
        }
        if let Some(src) = &s.from
            && !m.stages[..i].iter().any(|o| &o.get_ref().name == src)
        {
            return Err(bad(
                at("from"),
                &field("from"),
                format!("{src:?} is not an earlier stage"),
            ));
        }
        if s.name == "best" || s.name.is_empty() || s.name.starts_with('.') || s.name.contains(['/', '\\']) {
            return Err(bad(
                at("name"),
                &field("name"),
                format!(
                    "{:?} cannot name a checkpoint folder (\"best\" is the best checkpoint's; no slashes or leading dot)",
                    s.name
                ),
            ));
        }
        if m.stages[..i].iter().any(|o| o.get_ref().name == s.name) {
            return Err(bad(
                at("name"),
                &field("name"),
                format!("stage name {:?} is used twice", s.name),
            ));
        }
    }
    let resolve = |w: &str, field: &str| -> Result<PathBuf, ManifestError> {
        expand_vars(w)
            .map(PathBuf::from)
            .map_err(|e| bad(table_key_span(text, "data", "dataset"), field, e))
    };
    let dataset = resolve(&m.data.dataset, "data.dataset")?;
    if m.data.workers > 256 {
        return Err(bad(
            table_key_span(text, "data", "workers"),
            "data.workers",
            format!("at most 256 decoding threads, got {}", m.data.workers),
        ));
    }
    if m.data.shuffle_buffer > 1_000_000 {
        return Err(bad(
            table_key_span(text, "data", "shuffle_buffer"),
            "data.shuffle_buffer",
            format!("at most 1000000 samples, got {}", m.data.shuffle_buffer),
        ));
    }
    let l = &m.loss;
    for (t, v) in TERMS.iter().zip(&l.weights) {
        if !(0.0..=MAX_WEIGHT).contains(v.get_ref()) {
            return Err(bad(
                v.span(),
                &format!("loss.{}", t.name),
                format!("a weight must lie in [0, {MAX_WEIGHT:e}], got {:e}", v.get_ref()),
            ));
        }
    }
    if l.vgg16_layers.get_ref().is_empty() {
        return Err(bad(
            l.vgg16_layers.span(),
            "loss.vgg16_layers",
            "at least one layer (relu1_2, relu2_2, relu3_3, relu4_3)".into(),
        ));
    }
    let vgg16 = match &l.vgg16 {
        None => None,
        Some(v) => {
            let p = expand_vars(v.get_ref())
                .map(PathBuf::from)
                .map_err(|e| bad(v.span(), "loss.vgg16", e))?;
            if p.as_os_str().is_empty() {
                // `"${VGG16_WEIGHTS:-}"` with the variable unset: the fallback, said in the log.
                None
            } else if !p.is_file() {
                return Err(bad(v.span(), "loss.vgg16", format!("{}: no such file", p.display())));
            } else {
                Some(p)
            }
        }
    };
    let init_from = match &m.run.init_from {
        None => None,
        Some(v) => {
            let p = expand_vars(v.get_ref())
                .map(PathBuf::from)
                .map_err(|e| bad(v.span(), "run.init_from", e))?;
            if !p.join("state.json").is_file() {
                return Err(bad(
                    v.span(),
                    "run.init_from",
                    format!("{}: not a checkpoint folder (no state.json)", p.display()),
                ));
            }
            Some(p)
        }
    };
    let e = &m.eval;
    let best = source.choice(&e.best, "eval.best")?;
    if *e.every.get_ref() > 1_000_000_000 {
        return Err(bad(
            e.every.span(),
            "eval.every",
            format!("at most 1e9 steps, got {}", e.every.get_ref()),
        ));
    }
    let validation = (*e.every.get_ref() > 0).then(|| Validation {
        every: *e.every.get_ref(),
        data: dataset.clone(),
        split: e.val_split.clone(),
        samples: e.val_samples,
        categories: e.categories.clone(),
        best,
    });
    let weights = TERMS
        .iter()
        .zip(&l.weights)
        .fold(LossWeights::NONE, |w, (t, v)| w.with(t, *v.get_ref()));
    Ok(TrainPlan {
        validation,
        source,
        manifest: m,
        net,
        dataset,
        weights,
        vgg16,
        init_from,
        skip_corrupt,
        device,
    })
}

impl TrainPlan {
    /// The perceptual loss a training plan asks for: VGG16 where `[loss].vgg16` names weights,
    /// the fallback otherwise.
    pub fn perceptual(&self, device: &burn::tensor::Device) -> anyhow::Result<Perceptual> {
        match (&self.vgg16, &self.manifest.loss.vgg16) {
            (Some(w), _) => Perceptual::vgg16(w, self.manifest.loss.vgg16_layers.get_ref(), device),
            (None, None) => Ok(Perceptual::Fallback {
                why: "no VGG16 weights are configured ([loss].vgg16)",
            }),
            (None, Some(_)) => Ok(Perceptual::Fallback {
                why: "[loss].vgg16 expands to no path (its variable is unset or empty; scripts/fetch_vgg16.sh \
                      fetches ImageNet's weights)",
            }),
        }
    }

    /// The dataset folder of stage `i`.
    pub fn stage_dataset(&self, i: usize) -> Result<PathBuf, ManifestError> {
        match &self.manifest.stages[i].get_ref().dataset {
            Some(d) => expand_vars(d).map(PathBuf::from).map_err(|e| {
                self.source.invalid(
                    key_span(&self.source.text, self.manifest.stages[i].span(), "dataset"),
                    &format!("stages[{i}].dataset"),
                    e,
                )
            }),
            None => Ok(self.dataset.clone()),
        }
    }

    /// blake3 of the resolved manifest's text.
    pub fn hash(&self) -> String {
        blake3::hash(self.source.text.as_bytes()).to_hex().to_string()
    }

    /// The manifest named on the command line.
    pub fn path(&self) -> &Path {
        &self.source.path
    }
}

mod stage;
pub use stage::StageSection;

#[cfg(test)]
mod tests;
