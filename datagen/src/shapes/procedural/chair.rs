//! Chairs: a dished seat and a back curved around the sitter (region 1, "seat") on four
//! splayed, tapered legs or a swivel base with castors, optional arms (region 0, "frame").

use super::builder::{Builder, rot_x, rot_y};
use super::surface::{self, Topology};
use glam::{Mat3, Vec3};
use matedit_assets::random::Draw;

const FRAME: u32 = 0;
const SEAT: u32 = 1;
/// The regions of a chair.
pub(super) const REGIONS: [&str; 2] = ["frame", "seat"];

pub(super) fn build(b: &mut Builder, r: &mut Draw) {
    let w = r.uniform(0.42, 0.6) as f32;
    let d = r.uniform(0.4, 0.54) as f32;
    let h = r.uniform(0.4, 0.5) as f32;
    let t = r.uniform(0.03, 0.09) as f32;
    let e_v = r.uniform(0.2, 0.45) as f32;
    let e_a = r.uniform(0.2, 0.6) as f32;
    let dish = r.uniform(0.0, 0.025) as f32;
    // The seat: a rounded slab sunk in the middle.
    let seat = surface::superellipsoid(Vec3::new(w / 2.0, t / 2.0, d / 2.0), e_v, e_a);
    let seat_dished = |u: f32, v: f32| {
        let p = seat(u, v);
        let (a, c) = (2.0 * p.x / w, 2.0 * p.z / d);
        p - Vec3::Y * dish * (1.0 - a * a).max(0.0) * (1.0 - c * c).max(0.0)
    };
    b.patch(
        surface::sample(Topology::Sphere, 48, 24, &seat_dished)
            .placed(Vec3::new(0.0, h + t / 2.0, 0.0), Mat3::IDENTITY),
        &|_, _, _| SEAT,
    );

    // The back: a slab bent forward at its sides, reclined about the seat's rear edge.
    let (bh, bt, tilt) = (
        r.uniform(0.32, 0.6) as f32,
        r.uniform(0.025, 0.07) as f32,
        r.uniform(2.0, 18.0) as f32,
    );
    let back_w = w * r.uniform(0.75, 1.0) as f32;
    let wrap = r.uniform(0.0, 0.09) as f32;
    // Its poles on the broad faces (the superellipsoid's polar axis along the thickness), so the
    // bend moves their caps gently instead of folding a thin edge.
    let back = surface::superellipsoid(Vec3::new(back_w / 2.0, bt / 2.0, bh / 2.0), e_v.max(0.3), e_a);
    let back_bent = |u: f32, v: f32| {
        let q = back(u, v);
        let p = Vec3::new(q.x, q.z, q.y);
        let a = 2.0 * p.x / back_w;
        p + Vec3::Z * wrap * a * a
    };
    let gap = r.uniform(0.0, 0.06) as f32;
    let rot = rot_x(-tilt);
    let pivot = Vec3::new(0.0, h + t + gap, -d / 2.0 + bt / 2.0);
    b.patch(
        surface::sample(Topology::Sphere, 48, 24, &back_bent).placed(pivot + rot * Vec3::new(0.0, bh / 2.0, 0.0), rot),
        &|_, _, _| SEAT,
    );
    if gap > 0.02 {
        // Two uprights carry a floating back.
        for sx in [-1.0, 1.0] {
            let x = sx * back_w * 0.3;
            b.rod(
                Vec3::new(x, h + t * 0.5, -d / 2.0 + bt / 2.0),
                pivot + rot * Vec3::new(x, bh * 0.3, 0.0),
                0.012,
                FRAME,
            );
        }
    }

    if r.chance(0.65) {
        let lr = r.uniform(0.013, 0.028) as f32;
        let taper = r.uniform(0.5, 1.0) as f32;
        let splay = r.uniform(0.0, 0.06) as f32;
        let inset = lr + r.uniform(0.01, 0.05) as f32;
        for (sx, sz) in [(-1.0, -1.0), (1.0, -1.0), (1.0, 1.0), (-1.0, 1.0)] {
            let top = Vec3::new(sx * (w / 2.0 - inset), h + t * 0.3, sz * (d / 2.0 - inset));
            let foot = Vec3::new(top.x + sx * splay, 0.0, top.z + sz * splay);
            // Tapered towards the floor, flat-ended.
            b.tapered_rod(foot, top, lr, taper, 0.04, (16, 24), FRAME);
        }
        if r.chance(0.4) {
            let y = h * r.uniform(0.2, 0.4) as f32;
            for sx in [-1.0, 1.0] {
                let x = sx * (w / 2.0 - inset + splay * (1.0 - y / h));
                b.rod(
                    Vec3::new(x, y, -(d / 2.0 - inset)),
                    Vec3::new(x, y, d / 2.0 - inset),
                    lr * 0.6,
                    FRAME,
                );
            }
        }
    } else {
        // Swivel: a column, a five- or four-spoke star sloping down, castors.
        let cr = r.uniform(0.022, 0.035) as f32;
        let foot_y = 0.07;
        b.rod(Vec3::new(0.0, foot_y, 0.0), Vec3::new(0.0, h, 0.0), cr, FRAME);
        b.superquadric(
            Vec3::new(0.0, h - 0.01, 0.0),
            Vec3::new(w * 0.22, 0.02, d * 0.22),
            0.3,
            0.6,
            Mat3::IDENTITY,
            (24, 12),
            FRAME,
        );
        let spokes = r.int(4, 5);
        let reach = r.uniform(0.26, 0.34) as f32;
        for k in 0..spokes {
            let rot = rot_y(360.0 * k as f32 / spokes as f32 + 18.0);
            let end = rot * Vec3::new(reach, 0.045, 0.0);
            b.rod(Vec3::new(0.0, foot_y, 0.0), end, 0.018, FRAME);
            b.superquadric(
                end - Vec3::Y * 0.02,
                Vec3::splat(0.024),
                1.0,
                1.0,
                Mat3::IDENTITY,
                (16, 10),
                FRAME,
            );
        }
    }

    if r.chance(0.4) {
        let ay = h + t + r.uniform(0.16, 0.24) as f32;
        let (aw, al) = (r.uniform(0.04, 0.07) as f32, d * r.uniform(0.6, 0.85) as f32);
        for sx in [-1.0, 1.0] {
            let x = sx * (w / 2.0 + aw / 2.0);
            b.superquadric(
                Vec3::new(x, ay, 0.0),
                Vec3::new(aw / 2.0, 0.018, al / 2.0),
                0.4,
                0.4,
                Mat3::IDENTITY,
                (24, 12),
                FRAME,
            );
            b.rod(
                Vec3::new(x, h + t * 0.5, al * 0.25),
                Vec3::new(x, ay, al * 0.25),
                0.014,
                FRAME,
            );
        }
    }
}
