//! Cars: lower body and cabin (region 0, "body") on 4 or 6 wheels (region 1, "wheels"). Length
//! runs along x, so the default view is a side view.

use super::builder::Builder;
use glam::{Mat3, Vec3};
use matedit_assets::random::Draw;

pub(super) fn build(b: &mut Builder, r: &mut Draw) {
    let length = r.uniform(3.6, 5.2) as f32;
    let width = r.uniform(1.6, 2.0) as f32;
    let wheel_r = r.uniform(0.28, 0.4) as f32;
    let clearance = r.uniform(0.12, 0.25) as f32;
    let body_top = 2.0 * wheel_r + r.uniform(0.1, 0.35) as f32;
    let body_round = r.uniform(0.08, 0.22) as f32;
    let id = Mat3::IDENTITY;
    let body_h = body_top - clearance;
    b.rounded_box(
        Vec3::new(0.0, clearance + body_h / 2.0, 0.0),
        Vec3::new(length / 2.0, body_h / 2.0, width / 2.0),
        body_round,
        id,
        0,
    );
    // Cabin: sedan (centred), hatchback/van (long, to the rear), pickup (short, forward).
    let (frac, offset) = match r.int(0, 3) {
        0 => (r.uniform(0.45, 0.55), r.uniform(-0.05, 0.05)),
        1 => (r.uniform(0.55, 0.7), r.uniform(-0.18, -0.1)),
        2 => (r.uniform(0.75, 0.85), r.uniform(-0.08, -0.03)),
        _ => (r.uniform(0.28, 0.36), r.uniform(0.08, 0.16)),
    };
    let cabin_l = length * frac as f32;
    let cabin_h = r.uniform(0.38, 0.65) as f32;
    b.rounded_box(
        Vec3::new(length * offset as f32, body_top + cabin_h / 2.0 - 0.05, 0.0),
        Vec3::new(cabin_l / 2.0, cabin_h / 2.0, width / 2.0 * r.uniform(0.8, 0.92) as f32),
        r.uniform(0.12, 0.3) as f32,
        id,
        0,
    );
    let overhang = r.uniform(0.55, 0.95) as f32;
    let tyre = r.uniform(0.18, 0.28) as f32;
    let mut axles = vec![length / 2.0 - overhang, -(length / 2.0 - overhang)];
    if length > 4.6 && r.chance(0.3) {
        axles.push(-(length / 2.0 - overhang) + 2.2 * wheel_r);
    }
    for x in axles {
        for sz in [-1.0, 1.0] {
            let z_out = sz * (width / 2.0 + 0.01);
            let z_in = sz * (width / 2.0 - tyre);
            b.cylinder(
                Vec3::new(x, wheel_r, z_in),
                Vec3::new(x, wheel_r, z_out),
                wheel_r,
                20,
                1,
            );
        }
    }
}
