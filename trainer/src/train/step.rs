//! One optimisation step of each training stage (Sec. 3.3), written like the paper reads:
//! predict n', m', L'; re-render I' = R(n', m', L') and O' = R(n', m_t, L'); minimise
//! l = w_n·l_normal + w_m·l_material + w_p·l_perceptual (Eq. 5).

use super::loss::{illumination_loss, light_direction_loss, light_energy_loss, material_loss, normal_loss, ssim_loss};
use super::perceptual::Perceptual;
use crate::data;
use crate::data::TensorBatch;
use crate::model::network::Net;
use crate::render::RenderingLayer;
use crate::render::op::{Rendered, host};
use anyhow::{Context, Result};
use burn::optim::{GradientsParams, ModuleOptimizer};
use burn::tensor::{Device, Tensor};
use matedit_physics::brdf::dsbrdf::PARAMS;
use serde::{Deserialize, Serialize};

/// What a stage trains.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum StageKind {
    /// Normal and material modules alone, L2 losses only (Sec. 4: "pre-trained using L2 loss").
    /// A model stopped after this stage is the paper's *standalone* baseline of Tables 1 and 2.
    Pretrain,
    /// The modules through the rendering layer with the joint loss of Eq. 5.
    Joint,
    /// Baseline 1 of Sec. 4.5 (after Kulkarni et al.): the encoder–decoder alone, with the L2
    /// loss on f_m (w_m) and the perceptual loss on its O' (w_p, and w_s when set); no rendering.
    EncoderDecoder,
}

/// Where the rendering layer takes one of its inputs from in a joint stage.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Source {
    /// The network's prediction (n', m' or L').
    #[default]
    Predicted,
    /// The sample's ground truth (n, m or L): the protocol of Tables 1 and 2, where the
    /// material module is trained given ground-truth normals and illumination, or the normal
    /// module given ground-truth material and illumination.
    Truth,
    /// The network's prediction, but the rendering layer's gradient stops there: that module
    /// learns from its own L2 loss only, while the other modules learn to re-render I and O
    /// from the prediction it really makes (a stop-gradient). For normals this keeps the
    /// perceptual loss from pushing lighting into n' (docs/PERFORMANCE.md, "Trainer").
    Detached,
}

impl Source {
    /// Whether the rendering layer reads the prediction (rather than the ground truth).
    pub fn reads_prediction(self) -> bool {
        self != Source::Truth
    }

    /// Whether the rendering layer's gradient reaches the module.
    pub fn learns_through_layer(self) -> bool {
        self == Source::Predicted
    }

    /// The rendering layer's input: the prediction (when there is one) or the truth. A
    /// detached prediction needs nothing more here: the layer's pullback only reaches the
    /// inputs it is handed as tracked (see `train_step`).
    fn input<const D: usize>(self, predicted: Option<&Tensor<D>>, truth: &Tensor<D>) -> Tensor<D> {
        match predicted {
            Some(p) if self.reads_prediction() => p.clone(),
            _ => truth.clone(),
        }
    }
}

/// The rendering layer's inputs in a joint stage (all predicted by default: Fig. 2).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RenderWith {
    /// n.
    #[serde(default)]
    pub normals: Source,
    /// m (of I'; O' always uses the target material m_t).
    #[serde(default)]
    pub material: Source,
    /// L.
    #[serde(default)]
    pub illumination: Source,
}

/// The weights of Eq. 5.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LossWeights {
    /// w_n (the paper: 1e4).
    #[serde(default = "default_wn")]
    pub normal: f64,
    /// w_m (the paper: 1e3).
    #[serde(default = "default_wm")]
    pub material: f64,
    /// w_p (the paper: 1).
    #[serde(default = "default_wp")]
    pub perceptual: f64,
    /// w_L, a direct loss on L' (not in the paper, which trains L' only through the rendering
    /// layer; 0, the default, leaves it out). See [`super::loss::illumination_loss`].
    #[serde(default)]
    pub illumination: f64,
    /// w_s, a structural loss 1 − SSIM on I' and O' added to the perceptual loss (not in the
    /// paper; 0, the default, leaves it out). See [`super::loss::ssim_loss`].
    #[serde(default)]
    pub ssim: f64,
    /// w_E, a loss on the energy of L' (not in the paper; 0, the default, leaves it out): what
    /// the direct loss clips away. See [`super::loss::light_energy_loss`].
    #[serde(default, skip_serializing_if = "is_zero")]
    pub light_energy: f64,
    /// w_D, a loss on where L' comes from (not in the paper; 0, the default, leaves it out): the
    /// key light's side, which the direct loss lets a module average away. See
    /// [`super::loss::light_direction_loss`].
    #[serde(default, skip_serializing_if = "is_zero")]
    pub light_direction: f64,
}

fn is_zero(v: &f64) -> bool {
    *v == 0.0
}

fn default_wn() -> f64 {
    1e4
}
fn default_wm() -> f64 {
    1e3
}
fn default_wp() -> f64 {
    1.0
}

impl LossWeights {
    /// Every weight 0: a base for runs and tests that train one term alone.
    pub const NONE: LossWeights = LossWeights {
        normal: 0.0,
        material: 0.0,
        perceptual: 0.0,
        illumination: 0.0,
        ssim: 0.0,
        light_energy: 0.0,
        light_direction: 0.0,
    };
}

impl Default for LossWeights {
    fn default() -> Self {
        Self {
            normal: default_wn(),
            material: default_wm(),
            perceptual: default_wp(),
            illumination: 0.0,
            ssim: 0.0,
            light_energy: 0.0,
            light_direction: 0.0,
        }
    }
}

/// The loss terms of one step (unweighted) and the weighted total.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Losses {
    /// Eq. 5.
    pub total: f64,
    /// Eq. 3 (masked mean).
    pub normal: f64,
    /// Eq. 4 (mean).
    pub material: f64,
    /// Perceptual loss on I' plus on O' (0 in pretraining).
    pub perceptual: f64,
    /// The direct loss on L' (0 unless its weight is set).
    #[serde(default)]
    pub illumination: f64,
    /// 1 − SSIM on I' plus on O' (0 unless its weight is set, and in pretraining).
    #[serde(default)]
    pub ssim: f64,
    /// The loss on L''s energy (0 unless its weight is set; not written then, so that runs
    /// without it log what they always logged).
    #[serde(default, skip_serializing_if = "is_zero")]
    pub light_energy: f64,
    /// The loss on where L' comes from (0 unless its weight is set; not written then).
    #[serde(default, skip_serializing_if = "is_zero")]
    pub light_direction: f64,
}

impl Losses {
    /// Eq. 5's total of these terms under the weights `w` (every stage kind's terms not in use
    /// are 0, and add nothing).
    pub fn weighted_total(&self, w: &LossWeights) -> f64 {
        w.normal * self.normal
            + w.material * self.material
            + w.perceptual * self.perceptual
            + w.illumination * self.illumination
            + w.ssim * self.ssim
            + w.light_energy * self.light_energy
            + w.light_direction * self.light_direction
    }
}

/// What every step of a run shares.
pub struct StepContext<'a> {
    /// The fused rendering layer.
    pub layer: &'a RenderingLayer,
    /// Eq. 5 weights.
    pub weights: &'a LossWeights,
    /// The perceptual loss (VGG16 features or the documented fallback).
    pub perceptual: &'a Perceptual,
    /// The Burn device (with autodiff).
    pub device: &'a Device,
}

/// What one step does: the stage's kind and the rendering layer's inputs.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct StepKind {
    /// Pretrain (L2 only) or joint (Eq. 5).
    pub kind: StageKind,
    /// Joint stages: where n, m and L come from.
    pub render_with: RenderWith,
}

impl StepKind {
    /// Pretraining: L2 losses only.
    pub const PRETRAIN: StepKind = StepKind {
        kind: StageKind::Pretrain,
        render_with: RenderWith {
            normals: Source::Predicted,
            material: Source::Predicted,
            illumination: Source::Predicted,
        },
    };

    /// Joint training of Fig. 2: every input of the rendering layer predicted.
    pub const JOINT: StepKind = StepKind {
        kind: StageKind::Joint,
        render_with: RenderWith {
            normals: Source::Predicted,
            material: Source::Predicted,
            illumination: Source::Predicted,
        },
    };

    fn joint(&self) -> bool {
        self.kind == StageKind::Joint
    }
}

fn scalar(t: &Tensor<1>) -> f64 {
    host(t).first().copied().unwrap_or(f32::NAN) as f64
}

/// One step: forward, losses, backward (through the fused rendering layer's VJP), Adam update.
pub fn train_step(
    net: Net,
    optim: &mut ModuleOptimizer,
    lr: f64,
    host_batch: &data::Batch,
    step: StepKind,
    ctx: &StepContext,
) -> Result<(Net, Losses)> {
    let (losses, grads) = losses_and_gradients(&net, host_batch, step, ctx)?;
    check_finite(&losses, host_batch)?;
    let net = optim.step(lr, net, grads);
    Ok((net, losses))
}

/// Refuses a step whose loss is not finite (nothing is updated then).
pub fn check_finite(losses: &Losses, host_batch: &data::Batch) -> Result<()> {
    if !losses.total.is_finite() {
        anyhow::bail!("the loss is not finite ({losses:?}) on batch {:?}", host_batch.ids);
    }
    Ok(())
}

/// A step's loss terms and the gradients of its total, without the update (a data-parallel
/// step sums the gradients of the ranks before it updates). The loss need not be finite.
pub fn losses_and_gradients(
    net: &Net,
    host_batch: &data::Batch,
    step: StepKind,
    ctx: &StepContext,
) -> Result<(Losses, GradientsParams)> {
    if step.kind == StageKind::EncoderDecoder {
        return encoder_decoder_gradients(net, host_batch, ctx);
    }
    let (w, device) = (ctx.weights, ctx.device);
    let b = host_batch.to_device(device);
    let rw = step.render_with;
    let direct_light = w.illumination > 0.0 || w.light_energy > 0.0 || w.light_direction > 0.0;
    let light = (step.joint() && rw.illumination.reads_prediction()) || direct_light;
    let p = net.predict(&b.input, &b.mask, &b.region_masks, light);
    let ln = normal_loss(p.normals.clone(), b.normals.clone(), b.mask.clone());
    let lm = material_loss(p.materials.clone(), b.materials.clone());
    let mut losses = Losses {
        normal: scalar(&ln),
        material: scalar(&lm),
        ..Losses::default()
    };
    let mut total = ln.mul_scalar(w.normal) + lm.mul_scalar(w.material);
    if let (true, Some(env)) = (w.illumination > 0.0, &p.env) {
        let ll = illumination_loss(env.clone(), b.env.clone());
        losses.illumination = scalar(&ll);
        total = total + ll.mul_scalar(w.illumination);
    }
    if let (true, Some(env)) = (w.light_energy > 0.0, &p.env) {
        let le = light_energy_loss(env.clone(), b.env.clone());
        losses.light_energy = scalar(&le);
        total = total + le.mul_scalar(w.light_energy);
    }
    if let (true, Some(env)) = (w.light_direction > 0.0, &p.env) {
        let ld = light_direction_loss(env.clone(), b.env.clone());
        losses.light_direction = scalar(&ld);
        total = total + ld.mul_scalar(w.light_direction);
    }
    if step.joint() {
        let inputs = LayerInputs {
            normals: rw.normals.input(Some(&p.normals), &b.normals),
            materials: rw.material.input(Some(&p.materials), &b.materials),
            env: rw.illumination.input(p.env.as_ref(), &b.env),
            region_map: &host_batch.region_map,
        };
        let on_device = crate::render::on_device(ctx.device, ctx.layer.texels().height());
        let (terms, image) = match on_device {
            Some(layer) => joint_on_device(&layer, inputs, rw, &b, ctx)?,
            None => joint_on_host(inputs, rw, &b, ctx)?,
        };
        losses.perceptual = image.perceptual;
        losses.ssim = image.ssim;
        for term in terms {
            total = total + term;
        }
    }
    losses.total = losses.weighted_total(w);
    let grads = GradientsParams::from_grads(total.backward(), net);
    Ok((losses, grads))
}

/// The rendering layer's inputs in a joint step (each the prediction or the truth).
struct LayerInputs<'a> {
    normals: Tensor<4>,
    materials: Tensor<3>,
    env: Tensor<4>,
    region_map: &'a [u8],
}

/// The unweighted image losses of a joint step, for the log.
struct ImageLosses {
    perceptual: f64,
    ssim: f64,
}

/// w_p·(perceptual loss) + w_s·(1 − SSIM) on I' against I and, when rendered, O' against O.
fn image_loss(ip: &Tensor<4>, op: Option<&Tensor<4>>, b: &TensorBatch, ctx: &StepContext) -> (Tensor<1>, ImageLosses) {
    let w = ctx.weights;
    let mut lp = ctx.perceptual.loss(ip.clone(), b.input.clone(), b.mask.clone());
    if let Some(op) = op {
        lp = lp + ctx.perceptual.loss(op.clone(), b.target.clone(), b.mask.clone());
    }
    let mut losses = ImageLosses {
        perceptual: scalar(&lp),
        ssim: 0.0,
    };
    let mut image_loss = lp.mul_scalar(w.perceptual);
    if w.ssim > 0.0 {
        let mut ls = ssim_loss(ip.clone(), b.input.clone(), b.mask.clone());
        if let Some(op) = op {
            ls = ls + ssim_loss(op.clone(), b.target.clone(), b.mask.clone());
        }
        losses.ssim = scalar(&ls);
        image_loss = image_loss + ls.mul_scalar(w.ssim);
    }
    (image_loss, losses)
}

/// Whether O' = R(n, m_t, L) trains anything: only through n or L, when they learn through the
/// layer (m_t is the target, not a prediction).
fn renders_target(rw: RenderWith) -> bool {
    rw.normals.learns_through_layer() || rw.illumination.learns_through_layer()
}

/// The joint step's image terms through the fused CPU layer: I' and O' are rendered on the host,
/// the image losses back-propagate to ∂l/∂I' and ∂l/∂O', and the layer's VJP joins the graph as
/// the surrogate scalars of [`crate::render::op`] (the terms to add to the step's loss).
fn joint_on_host(
    x: LayerInputs,
    rw: RenderWith,
    b: &TensorBatch,
    ctx: &StepContext,
) -> Result<(Vec<Tensor<1>>, ImageLosses)> {
    let pick = Source::learns_through_layer;
    let (normals, materials, env) = (&x.normals, &x.materials, &x.env);
    let i_r = Rendered::new(ctx.layer, normals, materials, env, x.region_map).context("rendering I'")?;
    let o_r = if renders_target(rw) {
        Some(Rendered::new(ctx.layer, normals, &b.target_materials, env, x.region_map).context("rendering O'")?)
    } else {
        None
    };
    // The image losses on leaves: their backward gives ∂l/∂I' and ∂l/∂O'.
    let ip = i_r.image(ctx.device);
    let op = o_r.as_ref().map(|o| o.image(ctx.device));
    let (loss, losses) = image_loss(&ip, op.as_ref(), b, ctx);
    let grads = loss.backward();
    let upstream = |t: &Tensor<4>, n: usize| t.grad(&grads).map(|g| host(&g)).unwrap_or_else(|| vec![0.0; n]);
    let tracked = |s: Source, t: &Tensor<4>| pick(s).then(|| t.clone());
    let g_i = upstream(&ip, i_r.values().len());
    let si = i_r.pullback(
        ctx.layer,
        &g_i,
        tracked(rw.normals, normals),
        pick(rw.material).then(|| materials.clone()),
        tracked(rw.illumination, env),
    )?;
    let mut terms: Vec<Tensor<1>> = si.into_iter().collect();
    if let (Some(o_r), Some(op)) = (&o_r, &op) {
        let g_o = upstream(op, o_r.values().len());
        let so = o_r.pullback(
            ctx.layer,
            &g_o,
            tracked(rw.normals, normals),
            None,
            tracked(rw.illumination, env),
        )?;
        terms.extend(so);
    }
    Ok((terms, losses))
}

/// The joint step's image terms through the rendering layer on the GPU: I' and O' stay on the
/// device and the image losses join the step's graph directly; an input that does not learn
/// through the layer is detached.
fn joint_on_device(
    layer: &crate::render::DeviceRendering,
    x: LayerInputs,
    rw: RenderWith,
    b: &TensorBatch,
    ctx: &StepContext,
) -> Result<(Vec<Tensor<1>>, ImageLosses)> {
    fn through<const D: usize>(s: Source, t: Tensor<D>) -> Tensor<D> {
        if s.learns_through_layer() { t } else { t.detach() }
    }
    let normals = through(rw.normals, x.normals);
    let env = through(rw.illumination, x.env);
    let materials = through(rw.material, x.materials);
    let ip = layer
        .render(normals.clone(), x.region_map, materials, env.clone())
        .context("rendering I'")?;
    let op = if renders_target(rw) {
        let o = layer.render(normals, x.region_map, b.target_materials.clone(), env);
        Some(o.context("rendering O'")?)
    } else {
        None
    };
    let (loss, losses) = image_loss(&ip, op.as_ref(), b, ctx);
    Ok((vec![loss], losses))
}

/// The losses and gradients of one step of Baseline 1: f_m against m (Eq. 4),
/// O' = D(f_o, E(m_t)) against O.
fn encoder_decoder_gradients(
    net: &Net,
    host_batch: &data::Batch,
    ctx: &StepContext,
) -> Result<(Losses, GradientsParams)> {
    let w = ctx.weights;
    let ed = net
        .encoder_decoder
        .as_ref()
        .context("an encoder-decoder stage needs a network built with its encoder-decoder")?;
    if host_batch.regions != 1 {
        anyhow::bail!(
            "Baseline 1 edits single-material objects; batch {:?} has {} regions",
            host_batch.ids,
            host_batch.regions
        );
    }
    let b = host_batch.to_device(ctx.device);
    let n = host_batch.batch;
    let m_t = b.target_materials.clone().reshape([n, PARAMS]);
    let (m_p, o_p) = ed.edit(b.input.clone(), b.mask.clone(), m_t);
    let lm = material_loss(m_p.reshape([n, 1, PARAMS]), b.materials.clone());
    let lp = ctx.perceptual.loss(o_p.clone(), b.target.clone(), b.mask.clone());
    let mut losses = Losses {
        material: scalar(&lm),
        perceptual: scalar(&lp),
        ..Losses::default()
    };
    let mut total = lm.mul_scalar(w.material) + lp.mul_scalar(w.perceptual);
    if w.ssim > 0.0 {
        let ls = ssim_loss(o_p, b.target.clone(), b.mask.clone());
        losses.ssim = scalar(&ls);
        total = total + ls.mul_scalar(w.ssim);
    }
    losses.total = w.material * losses.material + w.perceptual * losses.perceptual + w.ssim * losses.ssim;
    let grads = GradientsParams::from_grads(total.backward(), net);
    Ok((losses, grads))
}
