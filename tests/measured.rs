//! Measured (MERL-format) BRDFs: a table written from an analytic BRDF renders like the analytic
//! BRDF itself, through the whole `datagen render` path.

mod common;
use common::*;
use matedit_datagen::preview::EnvRes;
use matedit_physics::brdf::{Brdf, MerlBrdf};
use matedit_physics::shading::Quality;

#[test]
fn merl_files_written_from_analytic_brdfs_render_within_2_percent() {
    let dir = scratch("merl");
    for spec in [
        "lambert:0.6,0.4,0.2",
        "plastic:0.3:0.5,0.2,0.1",
        "ggx:0.35:0.95,0.64,0.54",
    ] {
        let model = spec.parse::<matedit_physics::BrdfSpec>().unwrap().build().unwrap();
        let path = dir.join(format!("{}.binary", spec.split(':').next().unwrap()));
        std::fs::write(&path, MerlBrdf::tabulate_bytes(&model as &dyn Brdf)).unwrap();
        assert_eq!(std::fs::metadata(&path).unwrap().len(), 34_992_012);
        let merl = format!("merl:{}", path.display());
        let a = render_scene("sphere", spec, "builtin:sky", EnvRes::Rows(32), 48, Quality::Fast);
        let m = render_scene("sphere", &merl, "builtin:sky", EnvRes::Rows(32), 48, Quality::Fast);
        let px = fully_covered(48);
        let e = rel_rmse(&m.radiance, &a.radiance, &px);
        assert!(e < 0.02, "{spec}: tabulated vs analytic relative RMSE {e}");
        eprintln!("{spec}: tabulated vs analytic relative RMSE {:.3}%", 100.0 * e);
    }
}
