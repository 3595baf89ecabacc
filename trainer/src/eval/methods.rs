//! Table 3's other methods on one batch: Eq. 6 from the network's prediction, Baseline 1 (the
//! encoder–decoder), and the Lombardi-style optimiser given the true normals.

use super::report::{CheckpointEval, LombardiEval};
use super::score::score_batch;
use super::{I_PRIME, O_PRIME};
use crate::baseline::lombardi::{self, LombardiConfig, ReflectancePrior};
use crate::data;
use crate::rendering_layer::op::host;
use crate::rendering_layer::{LayerInput, RenderingLayer};
use anyhow::{Result, bail};
use matedit_physics::brdf::dsbrdf::PARAMS;

/// Eq. 6 on every sample of a batch from the predictions `n_p`, `m_p`, `l_p` (also its priors):
/// the optimised n*, m*, L* in the batch layouts, and [E at the prediction, E at the end,
/// seconds] summed over the samples.
pub(super) fn eq6_batch(
    layer: &RenderingLayer,
    hb: &data::Batch,
    n_p: &[f32],
    m_p: &[f32],
    l_p: &[f32],
    cfg: &crate::post_optimisation::Eq6Config,
) -> Result<(crate::model::prediction::Prediction, [f64; 3])> {
    use crate::model::prediction::Prediction;
    use crate::post_optimisation::{Problem, post_optimise};
    let (p, t, r) = (hb.size * hb.size, 6 * hb.env_height * hb.env_height, hb.regions);
    let mut out = Prediction {
        normals: Vec::with_capacity(n_p.len()),
        materials: Vec::with_capacity(m_p.len()),
        env: Vec::with_capacity(l_p.len()),
    };
    let mut energy = [0.0; 3];
    for k in 0..hb.batch {
        let t0 = std::time::Instant::now();
        let start = Prediction {
            normals: n_p[k * 3 * p..(k + 1) * 3 * p].to_vec(),
            materials: m_p[k * r * PARAMS..(k + 1) * r * PARAMS].to_vec(),
            env: l_p[k * t..(k + 1) * t].to_vec(),
        };
        let problem = Problem::eq6(
            layer,
            hb.size,
            r,
            &hb.input[k * 3 * p..(k + 1) * 3 * p],
            &hb.region_map[k * p..(k + 1) * p],
            &start,
            cfg.a,
            cfg.b,
        );
        let res = post_optimise(&problem, start.clone(), cfg)?;
        energy[0] += res.start.total;
        energy[1] += res.end.total;
        energy[2] += t0.elapsed().as_secs_f64();
        out.normals.extend(res.point.normals);
        out.materials.extend(res.point.materials);
        out.env.extend(res.point.env);
    }
    Ok((out, energy))
}

/// Baseline 1 on a batch: its O' = D(f_o, E(m_t)) against O and f_m against m (the full
/// pipeline's row), and R(n, f_m, L) against I (Table 1's protocol). It predicts no normals
/// and no light, so Table 2 and the mean-material baseline have no entry for it.
pub(super) fn encoder_decoder_batch(
    ed: &crate::model::encoder_decoder::EncoderDecoder,
    layer: &RenderingLayer,
    hb: &data::Batch,
    tb: crate::data::TensorBatch,
    row: &mut CheckpointEval,
) -> Result<Vec<f32>> {
    if hb.regions != 1 {
        bail!(
            "Baseline 1 edits single-material objects; samples {:?} have {} regions",
            hb.ids,
            hb.regions
        );
    }
    let m_t = tb.target_materials.reshape([hb.batch, PARAMS]);
    let (m_p, o_p) = ed.edit(tb.input, tb.mask, m_t);
    let (m_p, o_p) = (host(&m_p), host(&o_p));
    let i_given_n_l = layer.forward(&LayerInput {
        batch: hb.batch,
        size: (hb.size, hb.size),
        regions: 1,
        normals: &hb.normals,
        region_map: &hb.region_map,
        materials: &m_p,
        env: &hb.env,
    })?;
    row.network
        .merge(&score_batch(hb, &[(O_PRIME, &o_p, &hb.target)], None, Some(&m_p)));
    row.material_protocol.merge(&score_batch(
        hb,
        &[(I_PRIME, &i_given_n_l, &hb.input)],
        None,
        Some(&m_p),
    ));
    Ok(o_p)
}

/// The Lombardi-style optimiser on every sample of a batch, scored into `row`; its O'.
pub(super) fn lombardi_batch(
    layer: &RenderingLayer,
    hb: &data::Batch,
    prior: &ReflectancePrior,
    cfg: &LombardiConfig,
    row: &mut LombardiEval,
) -> Result<Vec<f32>> {
    let (p, r) = (hb.size * hb.size, hb.regions);
    let (mut i_s, mut o_s, mut m_s) = (Vec::new(), Vec::new(), Vec::new());
    for k in 0..hb.batch {
        let t0 = std::time::Instant::now();
        let px = k * 3 * p..(k + 1) * 3 * p;
        let normals = &hb.normals[px.clone()];
        let region_map = &hb.region_map[k * p..(k + 1) * p];
        let o = lombardi::Observed {
            size: hb.size,
            regions: r,
            image: &hb.input[px.clone()],
            region_map,
            normals,
        };
        let res = lombardi::recover(layer, &o, prior, cfg)?;
        let target = &hb.target_materials[k * r * PARAMS..(k + 1) * r * PARAMS];
        let one = |m: &[f32], env: &[f32]| {
            layer.forward(&LayerInput {
                batch: 1,
                size: (hb.size, hb.size),
                regions: r,
                normals,
                region_map,
                materials: m,
                env,
            })
        };
        i_s.extend(one(&res.point.materials, &res.point.env)?);
        o_s.extend(one(target, &res.point.env)?);
        m_s.extend_from_slice(&res.point.materials);
        row.energy[0] += res.start.total;
        row.energy[1] += res.end.total;
        row.seconds += t0.elapsed().as_secs_f64();
    }
    row.metrics.merge(&score_batch(
        hb,
        &[(I_PRIME, &i_s, &hb.input), (O_PRIME, &o_s, &hb.target)],
        None,
        Some(&m_s),
    ));
    Ok(o_s)
}
