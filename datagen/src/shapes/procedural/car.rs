//! Cars: a body lofted along its length from rounded cross-sections that follow a side profile
//! (nose, hood, windscreen, roof, rear window, boot), narrowing above the beltline, with wheel
//! arches; windows, lights, tyres and rims are regions of their own. Length runs along x (front
//! at +x), so the default view is a side view.

use super::builder::{Builder, Grid};
use super::surface::{self, Profile, Topology, smoothstep, spow};
use glam::{Mat3, Vec2, Vec3};
use matedit_assets::random::Draw;

/// Region ids, in [`REGIONS`] order.
const BODY: u32 = 0;
const WHEELS: u32 = 1;
const TYRES: u32 = 2;
const GLASS: u32 = 3;
const LIGHTS: u32 = 4;
/// The regions of a car.
pub(super) const REGIONS: [&str; 5] = ["body", "wheels", "tyres", "glass", "lights"];

/// Body styles: where the windscreen, roof and rear window sit along the length (fractions of
/// it from the front), and how high the roof is above the beltline (metres).
struct Style {
    hood: (f64, f64),
    screen: (f64, f64),
    roof: (f64, f64),
    rear: (f64, f64),
    roof_h: (f64, f64),
    boot_drop: (f64, f64),
}

const STYLES: [Style; 5] = [
    // Sedan: long hood, three boxes.
    Style {
        hood: (0.26, 0.32),
        screen: (0.13, 0.17),
        roof: (0.22, 0.3),
        rear: (0.11, 0.15),
        roof_h: (0.42, 0.52),
        boot_drop: (-0.02, 0.03),
    },
    // Hatchback: the roof runs to a steep tailgate.
    Style {
        hood: (0.2, 0.26),
        screen: (0.13, 0.17),
        roof: (0.36, 0.42),
        rear: (0.08, 0.12),
        roof_h: (0.45, 0.55),
        boot_drop: (0.02, 0.08),
    },
    // SUV: tall, short hood, square back.
    Style {
        hood: (0.2, 0.24),
        screen: (0.09, 0.12),
        roof: (0.5, 0.56),
        rear: (0.04, 0.07),
        roof_h: (0.55, 0.68),
        boot_drop: (0.02, 0.06),
    },
    // Coupé: long hood, low roof, fastback.
    Style {
        hood: (0.3, 0.36),
        screen: (0.17, 0.21),
        roof: (0.12, 0.18),
        rear: (0.24, 0.3),
        roof_h: (0.34, 0.42),
        boot_drop: (0.0, 0.04),
    },
    // Van: stubby nose, one long roof.
    Style {
        hood: (0.08, 0.12),
        screen: (0.12, 0.16),
        roof: (0.64, 0.7),
        rear: (0.02, 0.04),
        roof_h: (0.75, 0.95),
        boot_drop: (0.02, 0.05),
    },
];

pub(super) fn build(b: &mut Builder, r: &mut Draw) {
    let style = &STYLES[r.int(0, STYLES.len() - 1)];
    let u = |r: &mut Draw, (lo, hi): (f64, f64)| r.uniform(lo, hi) as f32;
    let length = r.uniform(3.8, 5.0) as f32;
    let half_w = r.uniform(0.8, 0.95) as f32;
    let wheel_r = r.uniform(0.3, 0.38) as f32;
    let clearance = r.uniform(0.13, 0.22) as f32 + if style.roof_h.0 > 0.5 { 0.06 } else { 0.0 };
    let belt = 2.0 * wheel_r + r.uniform(0.28, 0.38) as f32 + clearance - 0.15;
    let nose_drop = r.uniform(0.0, 0.04) as f32;
    let roof = belt + u(r, style.roof_h);
    let boot = belt + u(r, style.boot_drop);
    let tumble = r.uniform(0.12, 0.24) as f32;
    let corner = r.uniform(0.35, 0.5) as f32;
    let nose_p = r.uniform(3.0, 6.0) as f32;

    // The side profile, from the front (+x) to the back.
    let half_l = length / 2.0;
    let (hood, screen, roof_run, rear) = (u(r, style.hood), u(r, style.screen), u(r, style.roof), u(r, style.rear));
    // Windscreen and rear window no steeper than 2 : 1 (a near-vertical pane
    // would fall between two of the loft's sections).
    let x_screen = half_l - length * hood;
    let x_roof_front = x_screen - (length * screen).max(0.5 * (roof - belt));
    let rear_run = (length * rear).max(0.5 * (roof - boot));
    let x_rear_base = (x_roof_front - length * roof_run - rear_run).max(-half_l + 0.08);
    let x_roof_back = (x_rear_base + rear_run).min(x_roof_front - 0.1);
    let top = Profile::new(&[
        (-half_l, boot - 0.03),
        (x_rear_base, boot),
        (x_roof_back, roof),
        (x_roof_front, roof),
        (x_screen, belt),
        (half_l, belt - nose_drop),
    ]);

    let overhang_f = r.uniform(0.16, 0.22) as f32 * length;
    let overhang_r = r.uniform(0.17, 0.24) as f32 * length;
    let axles = [half_l - overhang_f, -half_l + overhang_r];
    let tyre_w = r.uniform(0.09, 0.13) as f32;
    let well_z = half_w - 2.0 * tyre_w - 0.06;
    let arch_r = wheel_r + 0.07;
    let arch_w = 1.6 * arch_r;
    // The bottom: the clearance, raised into arches over the wheels, (1 − t²)² so that they
    // leave the sill without a crease and the loft samples their slopes; near the sides only,
    // so the wheel wells do not run across the car.
    let bottom = |x: f32, z: f32| {
        let arch = axles
            .iter()
            .map(|&a| (1.0 - ((x - a) / arch_w).powi(2)).max(0.0).powi(2))
            .fold(0.0_f32, f32::max);
        let raised = clearance + (wheel_r + arch_r - clearance) * arch;
        clearance + (raised - clearance) * smoothstep(well_z - 0.3, well_z + 0.03, z.abs())
    };
    // The waist splits the section: above it the hood and cabin, below it the sides down to the
    // bottom; every arch top (2r + 0.07) stays under it, every top over it.
    let waist = belt - 0.06;
    let end = |xi: f32| (1.0 - xi.abs().min(1.0).powf(nose_p)).max(0.0).powf(1.0 / nose_p);
    let body = |uu: f32, v: f32| {
        // Cosine spacing along the length: dense at the nose and tail, where the section shrinks.
        let xi = -(std::f32::consts::PI * v).cos();
        let x = half_l * xi;
        let omega = std::f32::consts::TAU * uu;
        let (cz, cy) = (spow(omega.cos(), corner), spow(omega.sin(), corner));
        let s = end(xi);
        let z0 = half_w * (1.0 - 0.05 * xi * xi) * cz;
        let y0 = if cy >= 0.0 {
            waist + (top.at(x) - waist) * cy
        } else {
            waist + (waist - bottom(x, z0)) * cy
        };
        let z = z0 * (1.0 - tumble * smoothstep(belt, roof, y0));
        Vec3::new(x, waist + (y0 - waist) * s, z * s)
    };
    let (glass_back, glass_front) = (x_roof_back - 0.5 * length * rear, x_roof_front + 0.5 * length * screen);
    let pillar = 0.5 * (x_roof_back + x_roof_front);
    // Windows are whole quads of the loft's grid, judged at the quad's centre, so their edges
    // follow the sections instead of zig-zagging across triangles.
    let region = |_: Vec3, _: Vec3, uv: Vec2| {
        let (c, n) = (body(uv.x, uv.y), surface::normal(&body, uv.x, uv.y));
        // The loft's parametrisation faces its normals inwards or outwards; the side windows
        // only need |n.z| and the screens |n.x|, so the sign does not matter.
        let in_cabin = c.y > belt + 0.04 && c.y < top.at(c.x) - 0.035 && c.x > glass_back && c.x < glass_front;
        if !in_cabin {
            BODY
        } else if n.z.abs() > 0.55 {
            // Side windows, a B-pillar between them.
            if (c.x - pillar).abs() > 0.05 && c.x > x_rear_base + 0.06 && c.x < x_screen - 0.06 {
                GLASS
            } else {
                BODY
            }
        } else if n.x.abs() > 0.3 && c.z.abs() < 0.78 * half_w * (1.0 - tumble * smoothstep(belt, roof, c.y)) {
            GLASS
        } else {
            BODY
        }
    };
    let grid: Grid = (96, 160);
    b.patch(surface::sample(Topology::Sphere, grid.0, grid.1, &body), &region);

    // Wheels: a tyre (a superelliptic tube around the axle) and a dished rim inside it.
    let tube = r.uniform(0.25, 0.34) as f32 * wheel_r;
    let rim_e = r.uniform(0.2, 0.4) as f32;
    let turn = Mat3::from_rotation_x(std::f32::consts::FRAC_PI_2);
    for &x in &axles {
        for side in [-1.0_f32, 1.0] {
            let centre = Vec3::new(x, wheel_r, side * (half_w - tyre_w - 0.02));
            let tyre = move |uu: f32, v: f32| {
                let (a, t) = (std::f32::consts::TAU * uu, std::f32::consts::TAU * v);
                let radial = wheel_r - tube + tube * spow(t.cos(), 0.45);
                let axial = tyre_w * spow(t.sin(), 0.45);
                Vec3::new(radial * a.cos(), radial * a.sin(), axial)
            };
            b.patch(
                surface::sample(Topology::Torus, 40, 20, &tyre).placed(centre, Mat3::IDENTITY),
                &|_, _, _| TYRES,
            );
            b.superquadric(
                centre,
                Vec3::new(wheel_r - 1.6 * tube, tyre_w * 0.7, wheel_r - 1.6 * tube),
                rim_e,
                1.0,
                turn,
                (32, 16),
                WHEELS,
            );
        }
    }

    // Head and tail lights, set into the nose and the tail.
    let light_w = r.uniform(0.12, 0.2) as f32;
    let light_h = r.uniform(0.04, 0.07) as f32;
    for (sign, y) in [(1.0_f32, waist - 0.06), (-1.0, waist - 0.03)] {
        for side in [-1.0_f32, 1.0] {
            let z = side * half_w * 0.68;
            // Where the body's end reaches this width: end(ξ) = 0.68 (a little inside).
            let xi = (1.0 - 0.68_f32.powf(nose_p)).powf(1.0 / nose_p);
            b.superquadric(
                Vec3::new(sign * (half_l * xi - 0.015), y, z),
                Vec3::new(0.04, light_h, light_w),
                0.4,
                0.4,
                Mat3::IDENTITY,
                (24, 12),
                LIGHTS,
            );
        }
    }
}
