//! Monitors: the display surface (region 1, "screen") in a housing with a stand and base
//! (region 0, "housing"); flat panels or deep CRT-style backs, 16:9, 16:10 or 4:3.

use super::builder::Builder;
use glam::{Mat3, Vec3};
use matedit_assets::random::Draw;

pub(super) fn build(b: &mut Builder, r: &mut Draw) {
    let sw = r.uniform(0.42, 0.75) as f32;
    let aspect = [16.0 / 9.0, 16.0 / 10.0, 4.0 / 3.0][r.int(0, 2)];
    let sh = sw / aspect;
    let bezel = r.uniform(0.008, 0.035) as f32;
    let crt = r.chance(0.15);
    let pt = if crt {
        r.uniform(0.25, 0.4) as f32
    } else {
        r.uniform(0.02, 0.05) as f32
    };
    let base_t = r.uniform(0.015, 0.03) as f32;
    let neck_h = r.uniform(0.06, 0.2) as f32;
    let y0 = base_t + neck_h;
    let id = Mat3::IDENTITY;
    let centre = Vec3::new(0.0, y0 + sh / 2.0 + bezel, 0.0);
    let (hw, hh) = (sw / 2.0 + bezel, sh / 2.0 + bezel);
    if crt {
        b.rounded_box(
            centre + Vec3::new(0.0, 0.0, -0.02),
            Vec3::new(hw, hh, 0.02),
            0.01,
            id,
            0,
        );
        b.rounded_box(
            centre + Vec3::new(0.0, -0.02, -0.04 - pt / 2.0),
            Vec3::new(hw * 0.75, hh * 0.75, pt / 2.0),
            0.06,
            id,
            0,
        );
    } else {
        b.rounded_box(
            centre + Vec3::new(0.0, 0.0, -pt / 2.0),
            Vec3::new(hw, hh, pt / 2.0),
            pt * 0.3,
            id,
            0,
        );
    }
    b.rounded_box(
        centre + Vec3::new(0.0, 0.0, 0.002),
        Vec3::new(sw / 2.0, sh / 2.0, 0.002),
        0.001,
        id,
        1,
    );
    let back = if crt { -0.1 } else { -pt - 0.03 };
    let neck_w = r.uniform(0.03, 0.08) as f32;
    let neck_top = centre.y;
    b.rounded_box(
        Vec3::new(0.0, (base_t + neck_top) / 2.0, back),
        Vec3::new(neck_w / 2.0, (neck_top - base_t) / 2.0, 0.015),
        0.008,
        id,
        0,
    );
    if r.chance(0.5) {
        let rad = r.uniform(0.1, 0.16) as f32;
        b.cylinder(Vec3::new(0.0, 0.0, back), Vec3::new(0.0, base_t, back), rad, 24, 0);
    } else {
        let (bw, bd) = (r.uniform(0.18, 0.3) as f32, r.uniform(0.14, 0.22) as f32);
        b.rounded_box(
            Vec3::new(0.0, base_t / 2.0, back),
            Vec3::new(bw / 2.0, base_t / 2.0, bd / 2.0),
            base_t * 0.4,
            id,
            0,
        );
    }
}
