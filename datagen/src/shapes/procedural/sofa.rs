//! Sofas: seat and back cushions (region 1, "cushions") on a base with arms, back frame and
//! optional legs (region 0, "frame").

use super::builder::{Builder, rot_x};
use glam::{Mat3, Vec3};
use matedit_assets::random::Draw;

pub(super) fn build(b: &mut Builder, r: &mut Draw) {
    let width = r.uniform(1.1, 2.4) as f32;
    let depth = r.uniform(0.78, 1.0) as f32;
    let seats = ((width / 0.75).round() as usize).clamp(1, 3);
    let leg_h = if r.chance(0.6) {
        r.uniform(0.05, 0.16) as f32
    } else {
        0.0
    };
    let base_h = r.uniform(0.15, 0.28) as f32;
    let arm_w = r.uniform(0.08, 0.25) as f32;
    let arm_h = r.uniform(0.5, 0.7) as f32;
    let back_t = r.uniform(0.12, 0.22) as f32;
    let back_top = arm_h + r.uniform(0.1, 0.3) as f32;
    let round = r.uniform(0.02, 0.06) as f32;
    let id = Mat3::IDENTITY;

    let base_y = leg_h + base_h / 2.0;
    b.rounded_box(
        Vec3::new(0.0, base_y, 0.0),
        Vec3::new(width / 2.0, base_h / 2.0, depth / 2.0),
        round,
        id,
        0,
    );
    for sx in [-1.0, 1.0] {
        let x = sx * (width / 2.0 - arm_w / 2.0);
        let arm_bottom = leg_h;
        let half_h = (arm_h - arm_bottom) / 2.0;
        b.rounded_box(
            Vec3::new(x, arm_bottom + half_h, 0.0),
            Vec3::new(arm_w / 2.0, half_h, depth / 2.0),
            round * 1.5,
            id,
            0,
        );
    }
    let back_half_h = (back_top - leg_h) / 2.0;
    b.rounded_box(
        Vec3::new(0.0, leg_h + back_half_h, -depth / 2.0 + back_t / 2.0),
        Vec3::new(width / 2.0, back_half_h, back_t / 2.0),
        round,
        id,
        0,
    );
    if leg_h > 0.0 {
        let lr = r.uniform(0.02, 0.035) as f32;
        for (sx, sz) in [(-1.0, -1.0), (1.0, -1.0), (1.0, 1.0), (-1.0, 1.0)] {
            let (x, z) = (sx * (width / 2.0 - 0.06), sz * (depth / 2.0 - 0.06));
            b.cylinder(Vec3::new(x, 0.0, z), Vec3::new(x, leg_h + 0.01, z), lr, 10, 0);
        }
    }

    let inner = width - 2.0 * arm_w;
    let cw = inner / seats as f32;
    let ch = r.uniform(0.1, 0.18) as f32;
    let cushion_d = depth - back_t;
    let top = leg_h + base_h;
    let recline = r.uniform(5.0, 18.0) as f32;
    let back_ch = (back_top - top - ch) * r.uniform(0.8, 1.0) as f32;
    let back_cd = r.uniform(0.12, 0.2) as f32;
    for k in 0..seats {
        let x = -inner / 2.0 + cw * (k as f32 + 0.5);
        b.rounded_box(
            Vec3::new(x, top + ch / 2.0, back_t / 2.0),
            Vec3::new(cw / 2.0 - 0.005, ch / 2.0, cushion_d / 2.0),
            round * 1.5,
            id,
            1,
        );
        let rot = rot_x(-recline);
        let pivot = Vec3::new(x, top + ch, -depth / 2.0 + back_t + back_cd / 2.0);
        b.rounded_box(
            pivot + rot * Vec3::new(0.0, back_ch / 2.0, 0.0),
            Vec3::new(cw / 2.0 - 0.005, back_ch / 2.0, back_cd / 2.0),
            round * 1.5,
            rot,
            1,
        );
    }
}
