//! Sofas: plump seat and back cushions (region 1, "cushions") on a rounded base with rolled or
//! square arms, a back frame and optional legs (region 0, "frame").

use super::builder::{Builder, rot_x};
use super::surface::{self, Topology};
use glam::{Mat3, Vec3};
use matedit_assets::random::Draw;

const FRAME: u32 = 0;
const CUSHIONS: u32 = 1;
/// The regions of a sofa.
pub(super) const REGIONS: [&str; 2] = ["frame", "cushions"];

/// A cushion: a soft superellipsoid whose faces bulge (`bulge` of its smallest half-extent).
fn cushion(b: &mut Builder, centre: Vec3, half: Vec3, e: f32, bulge: f32, rot: Mat3) {
    let f = surface::superellipsoid(half, e, e);
    let plump = move |u: f32, v: f32| {
        let p = f(u, v);
        let q = p / half;
        // The top and bottom faces swell in their middle, not at their edges (continuous: q.y
        // is 0 round the sides).
        p + Vec3::Y * bulge * half.min_element() * q.y * (1.0 - q.x * q.x).max(0.0) * (1.0 - q.z * q.z).max(0.0)
    };
    b.patch(
        surface::sample(Topology::Sphere, 40, 24, &plump).placed(centre, rot),
        &|_, _, _| CUSHIONS,
    );
}

pub(super) fn build(b: &mut Builder, r: &mut Draw) {
    let width = r.uniform(1.1, 2.4) as f32;
    let depth = r.uniform(0.78, 1.0) as f32;
    let seats = ((width / 0.7).round() as usize).clamp(1, 3);
    let leg_h = if r.chance(0.6) {
        r.uniform(0.06, 0.16) as f32
    } else {
        0.0
    };
    let base_h = r.uniform(0.15, 0.26) as f32;
    let arm_w = r.uniform(0.1, 0.25) as f32;
    let arm_h = r.uniform(0.5, 0.7) as f32;
    let rolled = r.chance(0.5);
    let back_t = r.uniform(0.14, 0.24) as f32;
    let back_top = arm_h + r.uniform(0.1, 0.3) as f32;
    let e_frame = r.uniform(0.2, 0.4) as f32;
    let id = Mat3::IDENTITY;

    let base_top = leg_h + base_h;
    b.superquadric(
        Vec3::new(0.0, leg_h + base_h / 2.0, 0.0),
        Vec3::new(width / 2.0, base_h / 2.0, depth / 2.0),
        e_frame,
        0.2,
        id,
        (48, 20),
        FRAME,
    );
    let back_h = back_top - leg_h;
    b.superquadric(
        Vec3::new(0.0, leg_h + back_h / 2.0, -depth / 2.0 + back_t / 2.0),
        Vec3::new(width / 2.0, back_h / 2.0, back_t / 2.0),
        e_frame.max(0.3),
        0.25,
        id,
        (48, 24),
        FRAME,
    );
    for sx in [-1.0, 1.0] {
        let h = arm_h - leg_h;
        b.superquadric(
            Vec3::new(sx * (width / 2.0 - arm_w / 2.0), leg_h + h / 2.0, 0.0),
            Vec3::new(arm_w / 2.0, h / 2.0, depth / 2.0),
            if rolled { 0.7 } else { e_frame },
            if rolled { 0.35 } else { 0.25 },
            id,
            (40, 24),
            FRAME,
        );
    }

    // Seat cushions between the arms, in front of the back.
    let inner = width - 2.0 * arm_w;
    let cush_h = r.uniform(0.12, 0.2) as f32;
    let e_c = r.uniform(0.25, 0.45) as f32;
    let bulge = r.uniform(0.05, 0.25) as f32;
    let seat_d = depth - back_t;
    let cw = inner / seats as f32;
    for k in 0..seats {
        let x = -inner / 2.0 + cw * (k as f32 + 0.5);
        cushion(
            b,
            Vec3::new(x, base_top + cush_h / 2.0, depth / 2.0 - seat_d / 2.0),
            Vec3::new(cw / 2.0 - 0.005, cush_h / 2.0, seat_d / 2.0 - 0.005),
            e_c,
            bulge,
            id,
        );
    }
    if r.chance(0.6) {
        // Back cushions, leaning on the back.
        let bc_t = r.uniform(0.1, 0.18) as f32;
        let bc_h = (back_top - base_top - cush_h) * r.uniform(0.75, 0.95) as f32;
        let lean = rot_x(-r.uniform(6.0, 14.0) as f32);
        for k in 0..seats {
            let x = -inner / 2.0 + cw * (k as f32 + 0.5);
            cushion(
                b,
                Vec3::new(x, base_top + cush_h + bc_h / 2.0, -depth / 2.0 + back_t + bc_t / 2.0),
                Vec3::new(cw / 2.0 - 0.005, bc_h / 2.0, bc_t / 2.0),
                e_c,
                bulge,
                lean,
            );
        }
    }
    if leg_h > 0.0 {
        let lr = r.uniform(0.02, 0.035) as f32;
        let taper = r.uniform(0.5, 1.0) as f32;
        for (sx, sz) in [(-1.0, -1.0), (1.0, -1.0), (1.0, 1.0), (-1.0, 1.0)] {
            let x = sx * (width / 2.0 - 0.08);
            let z = sz * (depth / 2.0 - 0.08);
            b.tapered_rod(
                Vec3::new(x, 0.0, z),
                Vec3::new(x, leg_h + 0.02, z),
                lr,
                taper,
                0.08,
                (16, 16),
                FRAME,
            );
        }
    }
}
