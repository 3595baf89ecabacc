//! Chairs: seat and back (region 1, "seat") on four legs or a swivel base, optional arms and
//! stretchers (region 0, "frame").

use super::builder::{Builder, rot_x, rot_y};
use glam::{Mat3, Vec3};
use matedit_assets::random::Draw;

pub(super) fn build(b: &mut Builder, r: &mut Draw) {
    let w = r.uniform(0.42, 0.62) as f32;
    let d = r.uniform(0.40, 0.56) as f32;
    let h = r.uniform(0.40, 0.50) as f32;
    let t = r.uniform(0.04, 0.10) as f32;
    let round = r.uniform(0.005, 0.03) as f32;
    b.rounded_box(
        Vec3::new(0.0, h + t / 2.0, 0.0),
        Vec3::new(w / 2.0, t / 2.0, d / 2.0),
        round,
        Mat3::IDENTITY,
        1,
    );

    let (bh, bt, tilt) = (
        r.uniform(0.35, 0.62) as f32,
        r.uniform(0.03, 0.08) as f32,
        r.uniform(0.0, 16.0) as f32,
    );
    let back_w = w * r.uniform(0.8, 1.0) as f32;
    let rot = rot_x(-tilt);
    let pivot = Vec3::new(0.0, h + t, -d / 2.0 + bt / 2.0);
    b.rounded_box(
        pivot + rot * Vec3::new(0.0, bh / 2.0, 0.0),
        Vec3::new(back_w / 2.0, bh / 2.0, bt / 2.0),
        round,
        rot,
        1,
    );

    if r.chance(0.7) {
        let lr = r.uniform(0.015, 0.03) as f32;
        let inset = lr + r.uniform(0.0, 0.04) as f32;
        let square = r.chance(0.5);
        let corners = [(-1.0, -1.0), (1.0, -1.0), (1.0, 1.0), (-1.0, 1.0)];
        for (sx, sz) in corners {
            let (x, z) = (sx * (w / 2.0 - inset), sz * (d / 2.0 - inset));
            if square {
                b.rounded_box(
                    Vec3::new(x, h / 2.0, z),
                    Vec3::new(lr, h / 2.0, lr),
                    lr * 0.3,
                    Mat3::IDENTITY,
                    0,
                );
            } else {
                b.cylinder(Vec3::new(x, 0.0, z), Vec3::new(x, h, z), lr, 12, 0);
            }
        }
        if r.chance(0.5) {
            let y = h * r.uniform(0.2, 0.4) as f32;
            for sx in [-1.0, 1.0] {
                let x = sx * (w / 2.0 - inset);
                b.cylinder(
                    Vec3::new(x, y, -(d / 2.0 - inset)),
                    Vec3::new(x, y, d / 2.0 - inset),
                    lr * 0.6,
                    8,
                    0,
                );
            }
        }
    } else {
        let cr = r.uniform(0.022, 0.04) as f32;
        b.cylinder(Vec3::new(0.0, 0.06, 0.0), Vec3::new(0.0, h, 0.0), cr, 16, 0);
        let spokes = r.int(4, 5);
        let reach = r.uniform(0.25, 0.33) as f32;
        for k in 0..spokes {
            let rot = rot_y(360.0 * k as f32 / spokes as f32);
            b.rounded_box(
                rot * Vec3::new(reach / 2.0, 0.04, 0.0),
                Vec3::new(reach / 2.0, 0.02, 0.025),
                0.01,
                rot,
                0,
            );
        }
    }

    if r.chance(0.4) {
        let ay = h + t + r.uniform(0.16, 0.24) as f32;
        let (aw, al) = (r.uniform(0.04, 0.07) as f32, d * r.uniform(0.7, 0.9) as f32);
        for sx in [-1.0, 1.0] {
            let x = sx * (w / 2.0 + aw / 2.0);
            b.rounded_box(
                Vec3::new(x, ay, 0.0),
                Vec3::new(aw / 2.0, 0.02, al / 2.0),
                0.015,
                Mat3::IDENTITY,
                0,
            );
            let post = (ay - h - t) / 2.0;
            b.rounded_box(
                Vec3::new(x, h + t + post, al * 0.3),
                Vec3::new(0.015, post, 0.015),
                0.005,
                Mat3::IDENTITY,
                0,
            );
        }
    }
}
