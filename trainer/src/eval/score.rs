//! Scoring a batch: each named image against its truth on the object's pixels, with the
//! predicted normals and materials where given.

use super::{Metrics, Pair, Sample};
use crate::data;
use matedit_physics::brdf::dsbrdf::PARAMS;

/// Scores the images of a batch (`(name, prediction, truth)`, all `[B, 3, S, S]`) and, when
/// given, predicted normals `[B, 3, S, S]` and materials `[B, R, 108]` (regions present only:
/// padded slots repeat the last material).
pub(super) fn score_batch(
    hb: &data::Batch,
    images: &[(&str, &[f32], &[f32])],
    normals: Option<&[f32]>,
    materials: Option<&[f32]>,
) -> Metrics {
    let (s, r) = (hb.size, hb.regions);
    let p = s * s;
    let mut m = Metrics::default();
    for i in 0..hb.batch {
        let px = i * 3 * p..(i + 1) * 3 * p;
        let images: Vec<(&str, Pair)> = images
            .iter()
            .map(|(name, a, b)| {
                let pair = Pair {
                    pred: &a[px.clone()],
                    truth: &b[px.clone()],
                };
                (*name, pair)
            })
            .collect();
        let normals = normals.map(|n| Pair {
            pred: &n[px.clone()],
            truth: &hb.normals[px.clone()],
        });
        let regions = &hb.region_map[i * p..(i + 1) * p];
        let mats: Vec<Pair> = materials.map_or_else(Vec::new, |q| {
            (0..r)
                .filter(|&k| regions.iter().any(|&v| v as usize == k + 1))
                .map(|k| {
                    let o = (i * r + k) * PARAMS;
                    Pair {
                        pred: &q[o..o + PARAMS],
                        truth: &hb.materials[o..o + PARAMS],
                    }
                })
                .collect()
        });
        m.add(&Sample {
            h: s,
            w: s,
            mask: &hb.mask[i * p..(i + 1) * p],
            images,
            normals,
            materials: mats,
        });
    }
    m
}
