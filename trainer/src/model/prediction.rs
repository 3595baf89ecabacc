//! One image's (n, m, L) in host memory, in the rendering layer's layouts: the network's n', m',
//! L' for a photo, the refined n*, m*, L* of Eq. 6 (Sec. 3.5), or a baseline's estimate.

use super::network::Net;
use crate::rendering_layer::op::host;
use anyhow::{Context, Result, bail};
use burn::tensor::{Device, Tensor, TensorData};
use matedit_physics::brdf::dsbrdf::PARAMS;

/// n, m, L of one image.
#[derive(Clone, Debug, PartialEq)]
pub struct Prediction {
    /// Unit camera-space normals `[3, S, S]` (zero off the object).
    pub normals: Vec<f32>,
    /// Normalised DSBRDF parameters, one row per region, `[R, 108]`.
    pub materials: Vec<f32>,
    /// Camera-space environment `[3, He, 2He]`.
    pub env: Vec<f32>,
}

/// 1 inside each region: `[B, R, S, S]` from a region map `[B, S, S]` (0 = background, r =
/// region r − 1; values above `regions` belong to none).
pub fn region_masks(region_map: &[u8], batch: usize, regions: usize, pixels: usize) -> Vec<f32> {
    let mut masks = vec![0.0f32; batch * regions * pixels];
    for i in 0..batch {
        for k in 0..pixels {
            let reg = region_map[i * pixels + k] as usize;
            if reg > 0 && reg <= regions {
                masks[(i * regions + reg - 1) * pixels + k] = 1.0;
            }
        }
    }
    masks
}

impl Net {
    /// n', m', L' for one photo framed at the network's input: `input` `[3, S, S]` (linear, at
    /// the training exposure), `mask` `[S, S]`, `region_map` `[S, S]` with `regions` regions.
    /// Only what the network reads is asked for: no target, no true normals, no light.
    pub fn predict_photo(
        &self,
        input: &[f32],
        mask: &[f32],
        region_map: &[u8],
        regions: usize,
        device: &Device,
    ) -> Result<Prediction> {
        let p = mask.len();
        let s = p.isqrt();
        if s * s != p || input.len() != 3 * p || region_map.len() != p || regions == 0 {
            bail!(
                "a photo's input is [3, S, S] with an [S, S] mask and region map and at least one region \
                 (got {} input values, {p} mask values, {} region values, {regions} regions)",
                input.len(),
                region_map.len()
            );
        }
        let t4 = |v: Vec<f32>, c: usize| Tensor::<4>::from_data(TensorData::new(v, [1, c, s, s]), device);
        let prediction = self.predict(
            &t4(input.to_vec(), 3),
            &t4(mask.to_vec(), 1),
            &t4(region_masks(region_map, 1, regions, p), regions),
            true,
        );
        let mut normals = host(&prediction.normals);
        for (k, &m) in mask.iter().enumerate() {
            if m <= 0.0 {
                for c in 0..3 {
                    normals[c * p + k] = 0.0;
                }
            }
        }
        let materials = host(&prediction.materials);
        let env = host(
            prediction
                .env
                .as_ref()
                .context("the network predicted no illumination")?,
        );
        if normals.len() != 3 * p || materials.len() != regions * PARAMS {
            bail!(
                "the network's output does not match its input ({} normals, {} parameters)",
                normals.len(),
                materials.len()
            );
        }
        Ok(Prediction {
            normals,
            materials,
            env,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::Widths;
    use crate::model::network::NetConfig;

    #[test]
    fn region_masks_hold_one_per_region_and_ignore_the_background_and_strays() {
        // Two samples of 2×2: regions 1 and 2, background 0 and a stray 3 (beyond `regions`).
        let map = [0u8, 1, 2, 3, 2, 2, 1, 0];
        let m = region_masks(&map, 2, 2, 4);
        assert_eq!(
            m,
            vec![
                0., 1., 0., 0., /* sample 0, region 1 */ 0., 0., 1., 0., /* region 2 */
                0., 0., 1., 0., /* sample 1, region 1 */ 1., 1., 0., 0., /* region 2 */
            ]
        );
    }

    #[test]
    fn a_photo_gets_unit_normals_on_its_object_zero_off_it_and_one_material_per_region() {
        let device = Device::flex();
        let net = NetConfig::new(16, Widths::new(4, 16, 32, 8))
            .with_env_height(8)
            .init(&device);
        let (s, p) = (16, 256);
        let mask: Vec<f32> = (0..p).map(|k| f32::from(k % s >= 4 && k / s >= 4)).collect();
        let region_map: Vec<u8> = (0..p)
            .map(|k| if mask[k] > 0.0 { 1 + u8::from(k % s >= 10) } else { 0 })
            .collect();
        let input: Vec<f32> = (0..3 * p).map(|k| 0.1 + (k % 7) as f32 * 0.05).collect();
        let x = net.predict_photo(&input, &mask, &region_map, 2, &device).unwrap();
        assert_eq!(
            (x.normals.len(), x.materials.len(), x.env.len()),
            (3 * p, 2 * PARAMS, 3 * 8 * 16)
        );
        for (k, &on) in mask.iter().enumerate() {
            let n: f32 = (0..3).map(|c| x.normals[c * p + k].powi(2)).sum::<f32>().sqrt();
            if on > 0.0 {
                assert!((n - 1.0).abs() < 1e-4, "pixel {k}: |n| = {n}");
            } else {
                assert_eq!(n, 0.0, "pixel {k} is off the object");
            }
        }
        assert!(x.materials.iter().chain(&x.env).all(|v| v.is_finite()));
        assert!(x.env.iter().all(|&v| v >= 0.0), "L' is radiance");
        // Inputs that do not fit together are refused, not read out of bounds.
        for (i, m, r, regions) in [
            (&input[..3 * p - 1], &mask[..], &region_map[..], 2),
            (&input[..], &mask[..p - 1], &region_map[..], 2),
            (&input[..], &mask[..], &region_map[..p - 1], 2),
            (&input[..], &mask[..], &region_map[..], 0),
        ] {
            assert!(net.predict_photo(i, m, r, regions, &device).is_err());
        }
    }
}
