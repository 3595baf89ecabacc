//! Synthetic batches for benchmarks and tests: spheres of random materials under random skies,
//! rendered by the rendering layer itself (so I and O are consistent with n, m, L).

use crate::data;
use crate::rendering_layer::{LayerInput, RenderingLayer};
use matedit_physics::brdf::dsbrdf::PARAMS;
use matedit_physics::camera::unit_sphere_normals;
use rand_core::Rng;
use rand_pcg::Pcg64Mcg;

/// A batch of `batch` unit spheres at `size`² with `env_height` environments, seeded.
pub fn sphere_batch(batch: usize, size: usize, env_height: usize, seed: u64, layer: &RenderingLayer) -> data::Batch {
    let mut rng = Pcg64Mcg::new(0x5eed_0000_0000_0000_u128 | seed as u128);
    let mut u = || (rng.next_u32() >> 8) as f32 / (1u32 << 24) as f32;
    let (n, mask) = unit_sphere_normals(size);
    let p = size * size;
    let t = 2 * env_height * env_height;
    let mut hb = data::Batch {
        batch,
        size,
        regions: 1,
        env_height,
        ids: (0..batch).map(|i| format!("synthetic-{seed}-{i}")).collect(),
        ..data::Batch::default()
    };
    let axes: [Vec<_>; 3] = std::array::from_fn(|a| n.iter().take(p).map(|v| v[a]).collect());
    for _ in 0..batch {
        for axis in &axes {
            hb.normals.extend_from_slice(axis);
        }
        hb.mask.extend_from_slice(&mask);
        hb.region_map.extend(mask.iter().map(|&m| u8::from(m > 0.0)));
        let sun = (u() * t as f32) as usize % t;
        for _channel in 0..3 {
            let tint = 0.6 + 0.4 * u();
            hb.env.extend((0..t).map(|k| {
                if k == sun {
                    30.0
                } else {
                    tint * (0.3 + 0.7 * (1.0 - (k / (2 * env_height)) as f32 / env_height as f32))
                }
            }));
        }
        for target in [false, true] {
            let x: Vec<f32> = (0..PARAMS).map(|_| -0.8 + 1.4 * u()).collect();
            if target {
                hb.target_materials.extend(x);
            } else {
                hb.materials.extend(x);
            }
        }
    }
    let render = |materials: &[f32]| {
        layer
            .forward(&LayerInput {
                batch,
                size: (size, size),
                regions: 1,
                normals: &hb.normals,
                region_map: &hb.region_map,
                materials,
                env: &hb.env,
            })
            .unwrap_or_default()
    };
    hb.input = render(&hb.materials);
    hb.target = render(&hb.target_materials);
    hb
}
