//! The procedural shapes as files, with a contact sheet.

use crate::render::{EnvRes, RenderOptions, Shadows, render};
use crate::shapes::procedural::Category;
use anyhow::Result;
use matedit_physics::shading::Quality;
use std::path::{Path, PathBuf};

/// Colours of region 0 and region 1 in the OBJ materials and the contact sheet.
pub const REGION_COLOURS: [[f32; 3]; 2] = [[0.45, 0.6, 0.9], [0.95, 0.5, 0.15]];

/// A view that shows each category's parts: (yaw, pitch) in degrees.
pub fn sheet_pose(c: Category) -> (f32, f32) {
    match c {
        Category::Car => (25.0, 15.0),
        Category::Chair => (35.0, 20.0),
        Category::Sofa => (25.0, 15.0),
        Category::Monitor => (30.0, 10.0),
    }
}

/// Writes `count` shapes of every category (`<category>_<seed>.obj/.mtl`) and `shapes.png`.
pub fn write_category_set(dir: &Path, count: usize, seed: u64) -> Result<Vec<PathBuf>> {
    let mut paths = Vec::new();
    let mut tiles = Vec::new();
    const RES: usize = 128;
    for c in Category::ALL {
        for s in seed..seed + count as u64 {
            let path = dir.join(format!("{}_{s}.obj", c.name()));
            c.generate(s).write_obj(&path, &REGION_COLOURS)?;
            paths.push(path);
            let (yaw, pitch) = sheet_pose(c);
            let r = render(&RenderOptions {
                shape: format!("procedural:{}:{s}", c.name()),
                up: Default::default(),
                yaw_deg: yaw,
                pitch_deg: pitch,
                brdf: "lambert:1,1,1".parse()?,
                env: "builtin:studio".into(),
                env_rotation_deg: 0.0,
                env_res: EnvRes::Rows(32),
                res: RES,
                shadows: Shadows::Off,
                quality: Quality::Fast,
                progress: false,
                accel: Default::default(),
            })?;
            let g = &r.gbuffer;
            let tile = (0..RES * RES)
                .map(|p| {
                    let tint = REGION_COLOURS[(g.region[p] as usize).min(1)];
                    let c = [0, 1, 2].map(|k| matedit_physics::tonemap::tonemap_u8(r.radiance[p][k] * tint[k], 1.2));
                    [c[0], c[1], c[2], (g.mask[p] * 255.0) as u8]
                })
                .collect();
            tiles.push(tile);
        }
    }
    let sheet = dir.join("shapes.png");
    matedit_contract::io::write_contact_sheet(&sheet, &tiles, RES, RES, count.max(1))?;
    paths.push(sheet);
    Ok(paths)
}
