//! One optimisation step of each training stage (Sec. 3.3), written like the paper reads:
//! predict n', m', L'; re-render I' = R(n', m', L') and O' = R(n', m_t, L'); minimise
//! l = w_n·l_normal + w_m·l_material + w_p·l_perceptual (Eq. 5).

use super::loss::{Compute, ImagePair, LossWeights, Losses, Perceptual, Predicted, TERMS};
use super::stage_kind::StageKind;
use crate::data;
use crate::data::TensorBatch;
use crate::model::network::Net;
use crate::rendering_layer::RenderingLayer;
use crate::rendering_layer::op::{Rendered, host};
use anyhow::{Context, Result};
use burn::optim::{GradientsParams, ModuleOptimizer};
use burn::tensor::{Device, Tensor};
use matedit_physics::brdf::dsbrdf::PARAMS;
use serde::{Deserialize, Serialize};

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
    let direct_light = TERMS.iter().any(|t| t.reads_light() && t.computed(step.kind, w));
    let light = (step.joint() && rw.illumination.reads_prediction()) || direct_light;
    let p = net.predict(&b.input, &b.mask, &b.region_masks, light);
    let predicted = Predicted {
        normals: Some(&p.normals),
        materials: Some(&p.materials),
        env: p.env.as_ref(),
    };
    let mut losses = Losses::default();
    let mut total = prediction_terms(step.kind, &predicted, &b, w, &mut losses);
    if step.joint() {
        let inputs = LayerInputs {
            normals: rw.normals.input(Some(&p.normals), &b.normals),
            materials: rw.material.input(Some(&p.materials), &b.materials),
            env: rw.illumination.input(p.env.as_ref(), &b.env),
            region_map: &host_batch.region_map,
        };
        let on_device = crate::rendering_layer::on_device(ctx.device, ctx.layer.texels().height());
        let terms = match on_device {
            Some(layer) => joint_on_device(&layer, inputs, rw, &b, ctx, &mut losses)?,
            None => joint_on_host(inputs, rw, &b, ctx, &mut losses)?,
        };
        for term in terms {
            total = add(total, term);
        }
    }
    losses.total = losses.weighted_total(w);
    let total = total.unwrap_or_else(|| Tensor::zeros([1], device));
    let grads = GradientsParams::from_grads(total.backward(), net);
    Ok((losses, grads))
}

fn add(sum: Option<Tensor<1>>, t: Tensor<1>) -> Option<Tensor<1>> {
    Some(match sum {
        Some(s) => s + t,
        None => t,
    })
}

/// Σ w·l over the prediction terms a step of `kind` computes, each term's value written to
/// `losses` (`None`: no term computed).
fn prediction_terms(
    kind: StageKind,
    p: &Predicted,
    b: &TensorBatch,
    w: &LossWeights,
    losses: &mut Losses,
) -> Option<Tensor<1>> {
    let mut total = None;
    for t in TERMS.iter().filter(|t| t.computed(kind, w)) {
        let l = match t.compute {
            Compute::Prediction(f) => f(p, b),
            Compute::Light(f) => p.env.map(|env| f(env.clone(), b.env.clone())),
            Compute::Image(_) => None,
        };
        if let Some(l) = l {
            losses.set(t, scalar(&l));
            total = add(total, l.mul_scalar(w[t]));
        }
    }
    total
}

/// Σ w·l over the image terms a step of `kind` computes, each on every image against its
/// truth (I' against I, and O' against O where rendered), the sum of the images' values
/// written to `losses`.
fn image_terms(
    kind: StageKind,
    pairs: &[(&Tensor<4>, &Tensor<4>)],
    b: &TensorBatch,
    ctx: &StepContext,
    losses: &mut Losses,
) -> Tensor<1> {
    let w = ctx.weights;
    let mut total = None;
    for t in TERMS.iter().filter(|t| t.computed(kind, w)) {
        let Compute::Image(f) = t.compute else { continue };
        let mut sum = None;
        for (rendered, truth) in pairs {
            let pair = ImagePair {
                rendered,
                truth,
                mask: &b.mask,
                perceptual: ctx.perceptual,
            };
            sum = add(sum, f(&pair));
        }
        if let Some(l) = sum {
            losses.set(t, scalar(&l));
            total = add(total, l.mul_scalar(w[t]));
        }
    }
    total.unwrap_or_else(|| Tensor::zeros([1], ctx.device))
}

/// The rendering layer's inputs in a joint step (each the prediction or the truth).
struct LayerInputs<'a> {
    normals: Tensor<4>,
    materials: Tensor<3>,
    env: Tensor<4>,
    region_map: &'a [u8],
}

/// I' against I and, when rendered, O' against O.
fn image_pairs<'a>(
    ip: &'a Tensor<4>,
    op: Option<&'a Tensor<4>>,
    b: &'a TensorBatch,
) -> Vec<(&'a Tensor<4>, &'a Tensor<4>)> {
    let mut pairs = vec![(ip, &b.input)];
    pairs.extend(op.map(|o| (o, &b.target)));
    pairs
}

/// Whether O' = R(n, m_t, L) trains anything: only through n or L, when they learn through the
/// layer (m_t is the target, not a prediction).
fn renders_target(rw: RenderWith) -> bool {
    rw.normals.learns_through_layer() || rw.illumination.learns_through_layer()
}

/// The joint step's image terms through the fused CPU layer: I' and O' are rendered on the host,
/// the image losses back-propagate to ∂l/∂I' and ∂l/∂O', and the layer's VJP joins the graph as
/// the surrogate scalars of [`crate::rendering_layer::op`] (the terms to add to the step's loss).
fn joint_on_host(
    x: LayerInputs,
    rw: RenderWith,
    b: &TensorBatch,
    ctx: &StepContext,
    losses: &mut Losses,
) -> Result<Vec<Tensor<1>>> {
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
    let loss = image_terms(StageKind::Joint, &image_pairs(&ip, op.as_ref(), b), b, ctx, losses);
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
    Ok(terms)
}

/// The joint step's image terms through the rendering layer on the GPU: I' and O' stay on the
/// device and the image losses join the step's graph directly; an input that does not learn
/// through the layer is detached.
fn joint_on_device(
    layer: &crate::rendering_layer::DeviceRendering,
    x: LayerInputs,
    rw: RenderWith,
    b: &TensorBatch,
    ctx: &StepContext,
    losses: &mut Losses,
) -> Result<Vec<Tensor<1>>> {
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
    let loss = image_terms(StageKind::Joint, &image_pairs(&ip, op.as_ref(), b), b, ctx, losses);
    Ok(vec![loss])
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
    let m_p = m_p.reshape([n, 1, PARAMS]);
    let predicted = Predicted {
        normals: None,
        materials: Some(&m_p),
        env: None,
    };
    let mut losses = Losses::default();
    let kind = StageKind::EncoderDecoder;
    let direct = prediction_terms(kind, &predicted, &b, w, &mut losses);
    let image = image_terms(kind, &[(&o_p, &b.target)], &b, ctx, &mut losses);
    let total = match direct {
        Some(d) => d + image,
        None => image,
    };
    losses.total = losses.weighted_total(w);
    let grads = GradientsParams::from_grads(total.backward(), net);
    Ok((losses, grads))
}
