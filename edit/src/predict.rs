//! The network's prediction for a framed photo (n', m', L') and the renders made from it with
//! the rendering layer: I', O' with the target materials, and the relit image.

use super::Prepared;
use anyhow::{Context, Result};
use burn::tensor::Device;
use matedit_physics::brdf::dsbrdf::PARAMS;
use matedit_trainer::model::network::Net;
use matedit_trainer::post_optimisation;
use matedit_trainer::render::op::host;
use matedit_trainer::render::{Batch, RenderingLayer};
use matedit_trainer::train::batch::HostBatch;

/// The network's predictions and the renders made from them, at the network's resolution.
#[derive(Clone, Debug)]
pub struct Predicted {
    /// n' `[3, S, S]`.
    pub normals: Vec<f32>,
    /// m' `[R, 108]`, normalised.
    pub materials: Vec<f32>,
    /// L' `[3, He, 2He]`.
    pub env: Vec<f32>,
    /// Environment rows.
    pub env_height: usize,
    /// I' = R(n', m', L').
    pub i_prime: Vec<f32>,
    /// O' = R(n', m_t, L'), when target materials were given.
    pub o_prime: Option<Vec<f32>>,
    /// R(n', m', L_new), when another illumination was given.
    pub relit: Option<Vec<f32>>,
}

/// n', m', L': the network's prediction for `prep` (normals zero off the object).
pub fn network_prediction(net: &Net, env_height: usize, prep: &Prepared) -> Result<post_optimisation::Point> {
    let device = Device::flex();
    let (s, r) = (prep.size, prep.regions);
    let hb = HostBatch {
        batch: 1,
        size: s,
        regions: r,
        env_height,
        ids: vec!["photo".into()],
        input: prep.input.clone(),
        target: vec![0.0; 3 * s * s],
        normals: vec![0.0; 3 * s * s],
        mask: prep.mask.clone(),
        region_map: prep.region_map.clone(),
        env: vec![0.0; 6 * env_height * env_height],
        materials: vec![0.0; r * PARAMS],
        target_materials: vec![0.0; r * PARAMS],
    };
    let tb = hb.to_device(&device);
    let p = net.predict(&tb.input, &tb.mask, &tb.region_masks, true);
    let mut normals = host(&p.normals);
    for k in 0..s * s {
        if prep.mask[k] <= 0.0 {
            for c in 0..3 {
                normals[c * s * s + k] = 0.0;
            }
        }
    }
    Ok(post_optimisation::Point {
        normals,
        materials: host(&p.materials),
        env: p
            .env
            .as_ref()
            .map(host)
            .context("the network predicted no illumination")?,
    })
}

/// Renders I' from `x`, O' with `targets` (normalised, `[R, 108]`) and the relit image with
/// `relight` (`[3, He, 2He]` camera-space radiance, scaled to L's mean radiance: a photo's
/// exposure is arbitrary, so the other light takes the predicted light's level).
pub fn render_all(
    layer: &RenderingLayer,
    prep: &Prepared,
    x: post_optimisation::Point,
    env_height: usize,
    targets: Option<&[f32]>,
    relight: Option<&[f32]>,
) -> Result<Predicted> {
    let (s, r) = (prep.size, prep.regions);
    let render = |m: &[f32], l: &[f32]| -> Result<Vec<f32>> {
        Ok(layer.forward(&Batch {
            batch: 1,
            size: (s, s),
            regions: r,
            normals: &x.normals,
            region_map: &prep.region_map,
            materials: m,
            env: l,
        })?)
    };
    let i_prime = render(&x.materials, &x.env)?;
    let o_prime = targets.map(|t| render(t, &x.env)).transpose()?;
    let mean = |v: &[f32]| v.iter().map(|&x| x as f64).sum::<f64>() / v.len().max(1) as f64;
    let relit = relight
        .map(|l| {
            let k = (mean(&x.env) / mean(l).max(1e-30)) as f32;
            let l: Vec<f32> = l.iter().map(|v| v * k).collect();
            render(&x.materials, &l)
        })
        .transpose()?;
    Ok(Predicted {
        normals: x.normals,
        materials: x.materials,
        env: x.env,
        env_height,
        i_prime,
        o_prime,
        relit,
    })
}
