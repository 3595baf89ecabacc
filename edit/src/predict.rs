//! The network's prediction for a framed photo (n', m', L') and the renders made from it with
//! the rendering layer: I', O' with the target materials, and the relit image.

use super::Prepared;
use anyhow::Result;
use burn::tensor::Device;
use matedit_trainer::model::network::Net;
use matedit_trainer::model::prediction::Prediction;
use matedit_trainer::rendering_layer::{LayerInput, RenderingLayer};

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
pub fn network_prediction(net: &Net, prep: &Prepared) -> Result<Prediction> {
    net.predict_photo(&prep.input, &prep.mask, &prep.region_map, prep.regions, &Device::flex())
}

/// Renders I' from `x`, O' with `targets` (normalised, `[R, 108]`) and the relit image with
/// `relight` (`[3, He, 2He]` camera-space radiance in the network's units, at the level
/// [`crate::light::relight::at_level`] set).
pub fn render_all(
    layer: &RenderingLayer,
    prep: &Prepared,
    x: Prediction,
    targets: Option<&[f32]>,
    relight: Option<&[f32]>,
) -> Result<Predicted> {
    let (s, r) = (prep.size, prep.regions);
    let render = |m: &[f32], l: &[f32]| -> Result<Vec<f32>> {
        Ok(layer.forward(&LayerInput {
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
    let relit = relight.map(|l| render(&x.materials, l)).transpose()?;
    Ok(Predicted {
        normals: x.normals,
        materials: x.materials,
        env: x.env,
        env_height: layer.texels().height(),
        i_prime,
        o_prime,
        relit,
    })
}
