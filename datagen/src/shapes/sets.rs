//! The procedural shapes as files, with a contact sheet.

use crate::preview::{EnvRes, RenderOptions, Shadows, render};
use crate::shapes::procedural::Category;
use anyhow::Result;
use matedit_physics::shading::Quality;
use std::path::{Path, PathBuf};

/// Colours of a category's regions, by id, in the OBJ materials and the contact sheet: a car's
/// body, rims, tyres, glass and lights; the others' frame (housing) and seat (cushions, screen).
pub fn region_colours(c: Category) -> &'static [[f32; 3]] {
    match c {
        Category::Car => &[
            [0.45, 0.6, 0.9],
            [0.8, 0.8, 0.82],
            [0.06, 0.06, 0.06],
            [0.12, 0.2, 0.24],
            [1.0, 0.85, 0.45],
        ],
        _ => &[[0.45, 0.6, 0.9], [0.95, 0.5, 0.15]],
    }
}

/// The contact sheet's light and material: a procedural sun and sky, a glossy white paint
/// tinted per region.
const SHEET_ENV: &str = "builtin:sunsky:3";
const SHEET_BRDF: &str = "library:carpaint-white-gloss";

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
    const RES: usize = 192;
    for c in Category::ALL {
        for s in seed..seed + count as u64 {
            let path = dir.join(format!("{}_{s}.obj", c.name()));
            let colours = region_colours(c);
            c.generate(s).write_obj(&path, colours)?;
            paths.push(path);
            let (yaw, pitch) = sheet_pose(c);
            let r = render(&RenderOptions {
                shape: format!("procedural:{}:{s}", c.name()),
                up: Default::default(),
                yaw_deg: yaw,
                pitch_deg: pitch,
                brdf: SHEET_BRDF.parse()?,
                env: SHEET_ENV.into(),
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
                    let tint = colours[(g.region[p] as usize).min(colours.len() - 1)];
                    let c = [0, 1, 2].map(|k| matedit_physics::tonemap::tonemap_u8(r.radiance[p][k] * tint[k], 0.6));
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
