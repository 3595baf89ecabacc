//! One optimisation step of each training stage (Sec. 3.3), written like the paper reads:
//! predict n', m', L'; re-render I' = R(n', m', L') and O' = R(n', m_t, L'); minimise
//! l = w_n·l_normal + w_m·l_material + w_p·l_perceptual (Eq. 5).

use super::batch::{HostBatch, TensorBatch};
use super::loss::{material_loss, normal_loss, perceptual_fallback};
use super::network::Net;
use crate::render::RenderingLayer;
use crate::render::op::{Rendered, host};
use anyhow::{Context, Result};
use burn::optim::{GradientsParams, ModuleOptimizer};
use burn::tensor::{Device, Tensor};
use serde::{Deserialize, Serialize};

/// What a stage trains.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum StageKind {
    /// Normal and material modules alone, L2 losses only (Sec. 4: "pre-trained using L2 loss").
    /// A model stopped after this stage is the paper's *standalone* baseline of Tables 1 and 2.
    Pretrain,
    /// All three modules through the rendering layer with the joint loss of Eq. 5.
    Joint,
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

impl Default for LossWeights {
    fn default() -> Self {
        Self {
            normal: default_wn(),
            material: default_wm(),
            perceptual: default_wp(),
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
}

fn scalar(t: &Tensor<1>) -> f64 {
    host(t).first().copied().unwrap_or(f32::NAN) as f64
}

/// The two renderings of a joint step and the predictions they came from.
pub struct Predictions {
    /// n'.
    pub normals: Tensor<4>,
    /// m'.
    pub materials: Tensor<3>,
    /// L'.
    pub env: Tensor<4>,
}

/// Predicts n', m' and L' for a batch.
pub fn predict(net: &Net, b: &TensorBatch, with_light: bool) -> Predictions {
    let normals = net.normal.forward(b.input.clone(), b.mask.clone());
    let materials = net.material.forward(b.input.clone(), b.region_masks.clone());
    let env = if with_light {
        net.illumination.forward(b.input.clone(), b.mask.clone())
    } else {
        b.env.clone()
    };
    Predictions {
        normals,
        materials,
        env,
    }
}

/// One step: forward, losses, backward (through the fused rendering layer's VJP), Adam update.
pub fn train_step(
    net: Net,
    optim: &mut ModuleOptimizer,
    lr: f64,
    host_batch: &HostBatch,
    kind: StageKind,
    w: &LossWeights,
    layer: &RenderingLayer,
    device: &Device,
) -> Result<(Net, Losses)> {
    let b = host_batch.to_device(device);
    let joint = kind == StageKind::Joint;
    let p = predict(&net, &b, joint);
    let ln = normal_loss(p.normals.clone(), b.normals.clone(), b.mask.clone());
    let lm = material_loss(p.materials.clone(), b.materials.clone());
    let mut losses = Losses {
        normal: scalar(&ln),
        material: scalar(&lm),
        ..Losses::default()
    };
    let mut total = ln.mul_scalar(w.normal) + lm.mul_scalar(w.material);
    if joint {
        let regions = &host_batch.region_map;
        let i_r = Rendered::new(layer, &p.normals, &p.materials, &p.env, regions).context("rendering I'")?;
        let o_r = Rendered::new(layer, &p.normals, &b.target_materials, &p.env, regions).context("rendering O'")?;
        // The perceptual loss on leaves: its backward gives ∂l/∂I' and ∂l/∂O'.
        let (ip, op) = (i_r.image(device), o_r.image(device));
        let lp = perceptual_fallback(ip.clone(), b.input.clone(), b.mask.clone())
            + perceptual_fallback(op.clone(), b.target.clone(), b.mask.clone());
        losses.perceptual = scalar(&lp);
        let grads = lp.mul_scalar(w.perceptual).backward();
        let g_i = ip
            .grad(&grads)
            .map(|g| host(&g))
            .unwrap_or_else(|| vec![0.0; i_r.values().len()]);
        let g_o = op
            .grad(&grads)
            .map(|g| host(&g))
            .unwrap_or_else(|| vec![0.0; o_r.values().len()]);
        let si = i_r.pullback(
            layer,
            &g_i,
            Some(p.normals.clone()),
            Some(p.materials.clone()),
            Some(p.env.clone()),
        )?;
        let so = o_r.pullback(layer, &g_o, Some(p.normals.clone()), None, Some(p.env.clone()))?;
        for s in [si, so].into_iter().flatten() {
            total = total + s;
        }
    }
    losses.total = w.normal * losses.normal + w.material * losses.material + w.perceptual * losses.perceptual;
    if !losses.total.is_finite() {
        anyhow::bail!("the loss is not finite ({losses:?}) on batch {:?}", host_batch.ids);
    }
    let grads = GradientsParams::from_grads(total.backward(), &net);
    let net = optim.step(lr, net, grads);
    Ok((net, losses))
}
