//! Monitors: a thin bevelled panel with a bulge behind it (region 0, "housing") whose front
//! inside the bezel is the screen (region 1, "screen"), on a round or flat neck and a round or
//! square foot.

use super::builder::{Builder, rot_x};
use glam::{Mat3, Vec3};
use matedit_assets::random::Draw;

const HOUSING: u32 = 0;
const SCREEN: u32 = 1;
/// The regions of a monitor.
pub(super) const REGIONS: [&str; 2] = ["housing", "screen"];

pub(super) fn build(b: &mut Builder, r: &mut Draw) {
    let aspect = [16.0 / 9.0, 16.0 / 10.0, 21.0 / 9.0, 4.0 / 3.0][r.int(0, 3)];
    let pw = r.uniform(0.45, 0.75) as f32;
    let ph = pw / aspect as f32;
    let depth = r.uniform(0.012, 0.035) as f32;
    let bezel = r.uniform(0.006, 0.03) as f32;
    let e_edge = r.uniform(0.15, 0.3) as f32;
    let tilt = r.uniform(-4.0, 12.0) as f32;
    let stand_h = r.uniform(0.08, 0.2) as f32;
    let rot = rot_x(-tilt);
    let centre = Vec3::new(0.0, stand_h + ph / 2.0 + 0.02, 0.0);

    // Bevelled in depth (`bevel`), rounded at the corners of its outline (`e_edge`); the screen
    // is the front face inside the bezel, whole quads of the grid.
    let bevel = r.uniform(0.5, 0.8) as f32;
    let (sw, sh) = (pw / 2.0 - bezel, ph / 2.0 - bezel);
    b.superquadric_with(
        centre,
        Vec3::new(pw / 2.0, ph / 2.0, depth / 2.0),
        (bevel, e_edge),
        rot,
        (64, 32),
        &|p| {
            if p.z > 0.0 && p.x.abs() < sw && p.y.abs() < sh {
                SCREEN
            } else {
                HOUSING
            }
        },
    );
    // The electronics behind: a soft bulge, its front inside the panel.
    let bulge = r.uniform(0.03, 0.08) as f32;
    b.superquadric(
        centre + rot * Vec3::new(0.0, -ph * 0.05, depth / 2.0 - 0.004 - bulge),
        Vec3::new(
            pw * r.uniform(0.25, 0.4) as f32,
            ph * r.uniform(0.25, 0.4) as f32,
            bulge,
        ),
        0.6,
        0.6,
        rot,
        (32, 20),
        HOUSING,
    );

    let foot_y = 0.012;
    let back = depth / 2.0 - 0.004 - bulge * 1.6;
    let neck_top = centre + rot * Vec3::new(0.0, -ph * 0.1, back);
    let neck_foot = Vec3::new(0.0, foot_y, neck_top.z - r.uniform(0.0, 0.06) as f32);
    if r.chance(0.5) {
        b.rod(neck_foot, neck_top, r.uniform(0.015, 0.03) as f32, HOUSING);
    } else {
        // A flat column, leaning back.
        let mid = (neck_foot + neck_top) / 2.0;
        let along = neck_top - neck_foot;
        let lean = Mat3::from_quat(glam::Quat::from_rotation_arc(Vec3::Y, along.normalize()));
        b.superquadric(
            mid,
            Vec3::new(r.uniform(0.03, 0.06) as f32, along.length() / 2.0, 0.012),
            0.2,
            0.3,
            lean,
            (24, 16),
            HOUSING,
        );
    }
    let foot_w = r.uniform(0.16, 0.3) as f32;
    let round_foot = r.chance(0.5);
    b.superquadric(
        Vec3::new(0.0, foot_y, neck_foot.z + 0.02),
        Vec3::new(foot_w / 2.0, foot_y, foot_w * r.uniform(0.3, 0.45) as f32),
        0.25,
        if round_foot { 1.0 } else { 0.3 },
        Mat3::IDENTITY,
        (40, 12),
        HOUSING,
    );
}
