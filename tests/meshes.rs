//! The mesh pipeline (OBJ → normalisation → BVH → interpolated normals → shading) against the
//! analytic sphere, and shadow rays against geometry with known occlusion.

mod common;
use common::*;
use matedit_datagen::preview::{EnvRes, RenderOptions, Shadows, render};
use matedit_physics::shading::Quality;

#[test]
fn a_fine_uv_sphere_mesh_renders_like_the_analytic_sphere() {
    let dir = scratch("uvsphere");
    let obj = dir.join("sphere.obj");
    write_uv_sphere(&obj, 96, 192);
    let res = 48;
    let a = render_scene(
        "sphere",
        "plastic:0.3:0.6,0.5,0.4",
        "builtin:sky",
        EnvRes::Rows(32),
        res,
        Quality::Fast,
    );
    let m = render_scene(
        obj.to_str().unwrap(),
        "plastic:0.3:0.6,0.5,0.4",
        "builtin:sky",
        EnvRes::Rows(32),
        res,
        Quality::Fast,
    );
    let px = fully_covered(res);
    for &p in &px {
        assert_eq!(m.gbuffer.mask[p], 1.0);
        let (na, nm) = (
            glam::Vec3::from(a.gbuffer.normal[p]),
            glam::Vec3::from(m.gbuffer.normal[p]),
        );
        assert!(na.dot(nm) > 0.999, "pixel {p}: {na} vs {nm}");
    }
    let e = rel_rmse(&m.radiance, &a.radiance, &px);
    assert!(e < 0.01, "relative RMSE {e}");
}

#[test]
fn shadows_on_a_convex_mesh_change_little_and_a_wall_casts_a_shadow() {
    let dir = scratch("shadows");
    let obj = dir.join("sphere.obj");
    write_uv_sphere(&obj, 48, 96);
    let opts = |shape: &str, shadows| RenderOptions {
        shape: shape.into(),
        up: Default::default(),
        yaw_deg: 0.0,
        pitch_deg: 0.0,
        brdf: "lambert:0.8,0.8,0.8".parse().unwrap(),
        env: "builtin:constant:1".into(),
        env_rotation_deg: 0.0,
        env_res: EnvRes::Rows(16),
        res: 24,
        shadows,
        quality: Quality::Fast,
        progress: false,
        accel: Default::default(),
    };
    let off = render(&opts(obj.to_str().unwrap(), Shadows::Off)).unwrap();
    let on = render(&opts(obj.to_str().unwrap(), Shadows::On)).unwrap();
    assert!(on.stats.shadows_traced);
    let px = fully_covered(24);
    assert!(rel_rmse(&on.radiance, &off.radiance, &px) < 0.02);

    // A floor facing the camera with a wall standing on its left half, leaning towards the
    // camera: floor pixels right next to the wall see less of the sky.
    let scene = dir.join("wall.obj");
    std::fs::write(
        &scene,
        "v -1 -1 0\nv 1 -1 0\nv 1 1 0\nv -1 1 0\n\
         v 0 -1 0\nv 0 1 0\nv 0 1 1\nv 0 -1 1\n\
         f 1 2 3 4\nf 5 6 7 8\n",
    )
    .unwrap();
    let off = render(&opts(scene.to_str().unwrap(), Shadows::Off)).unwrap();
    let on = render(&opts(scene.to_str().unwrap(), Shadows::On)).unwrap();
    // Floor pixel just right of the wall (x ≈ 0.1 after normalisation scales by 1/√(1.25)).
    let res = 24;
    let p = (res / 2) * res + res / 2 + 1;
    assert_eq!(on.gbuffer.mask[p], 1.0);
    assert!(
        on.radiance[p][0] < 0.8 * off.radiance[p][0],
        "{:?} vs {:?}",
        on.radiance[p],
        off.radiance[p]
    );
    assert!(on.radiance.iter().flatten().all(|v| v.is_finite()));
}

#[test]
fn regions_reach_the_image() {
    let dir = scratch("regions");
    std::fs::write(dir.join("r.mtl"), "newmtl frame\nKd 1 0 0\nnewmtl seat\nKd 0 1 0\n").unwrap();
    let obj = dir.join("r.obj");
    std::fs::write(
        &obj,
        "mtllib r.mtl\nv -1 -1 0\nv 0 -1 0\nv 0 1 0\nv -1 1 0\nv 1 -1 0\nv 1 1 0\n\
         usemtl frame\nf 1 2 3 4\nusemtl seat\nf 2 5 6 3\n",
    )
    .unwrap();
    let r = render_scene(
        obj.to_str().unwrap(),
        "lambert:0.5,0.5,0.5",
        "builtin:studio",
        EnvRes::Rows(8),
        16,
        Quality::Fast,
    );
    assert_eq!(r.stats.regions, ["frame", "seat"]);
    let (left, right) = (8 * 16 + 3, 8 * 16 + 12);
    assert_eq!((r.gbuffer.mask[left], r.gbuffer.mask[right]), (1.0, 1.0));
    assert_eq!((r.gbuffer.region[left], r.gbuffer.region[right]), (0, 1));
}
