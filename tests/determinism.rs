//! The same inputs give byte-identical outputs whatever the thread count.

mod common;
use common::*;
use matedit_datagen::preview::{EnvRes, RenderOptions, Shadows, render};
use matedit_physics::shading::Quality;

fn render_with_threads(threads: usize, shape: &str, out: &std::path::Path) -> Vec<u32> {
    let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
    pool.install(|| {
        let r = render(&RenderOptions {
            shape: shape.into(),
            up: Default::default(),
            yaw_deg: 0.0,
            pitch_deg: 0.0,
            brdf: format!(
                "dsbrdf:{}/assets/materials/red_plastic.dsbrdf.json",
                env!("CARGO_MANIFEST_DIR")
            )
            .parse()
            .unwrap(),
            env: "builtin:sky".into(),
            env_rotation_deg: 33.0,
            env_res: EnvRes::Rows(16),
            res: 40,
            shadows: Shadows::On,
            quality: Quality::Fast,
            progress: false,
            accel: Default::default(),
        })
        .unwrap();
        r.write_exr(out).unwrap();
        r.radiance.iter().flatten().map(|v| v.to_bits()).collect()
    })
}

#[test]
fn images_and_files_are_identical_on_1_2_and_3_threads() {
    let dir = scratch("determinism");
    let obj = dir.join("sphere.obj");
    write_uv_sphere(&obj, 24, 48);
    // A non-convex scene too: the sphere plus a floor, so shadow rays hit things.
    let scene = dir.join("scene.obj");
    let mut text = std::fs::read_to_string(&obj).unwrap();
    let n = text.lines().filter(|l| l.starts_with("v ")).count();
    text += &format!(
        "v -2 -1 -2\nv 2 -1 -2\nv 2 -1 2\nv -2 -1 2\nf {} {} {} {}\n",
        n + 1,
        n + 4,
        n + 3,
        n + 2
    );
    std::fs::write(&scene, text).unwrap();
    // And the procedural shapes: lofted, self-shadowing, tens of thousands of triangles.
    let shapes = [
        obj.to_str().unwrap(),
        scene.to_str().unwrap(),
        "procedural:car:7",
        "procedural:chair:3",
        "procedural:sofa:5",
        "procedural:monitor:2",
    ];
    for shape in shapes {
        let a = render_with_threads(1, shape, &dir.join("a.exr"));
        let b = render_with_threads(2, shape, &dir.join("b.exr"));
        let c = render_with_threads(3, shape, &dir.join("c.exr"));
        assert_eq!(a, b);
        assert_eq!(a, c);
        let fa = std::fs::read(dir.join("a.exr")).unwrap();
        assert_eq!(fa, std::fs::read(dir.join("b.exr")).unwrap());
        assert_eq!(fa, std::fs::read(dir.join("c.exr")).unwrap());
    }
}
