//! Eq. 6 against finite differences, closed forms and its own guarantees.

use super::*;
use crate::train::synthetic::sphere_batch;

/// Directional derivative of E along `d` by central differences against the analytic one.
fn check_gradient(par: &Parametrised, q: &[f64], seed: u64, what: &str) {
    let (_, g) = par.evaluate(q).unwrap();
    let mut s = seed;
    let mut rnd = || {
        s = s.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        ((s >> 11) as f64 / (1u64 << 53) as f64) - 0.5
    };
    // A direction along the gradient's largest entries and a random one.
    let mut idx: Vec<usize> = (0..g.len()).collect();
    idx.sort_by(|&a, &b| g[b].abs().total_cmp(&g[a].abs()));
    let mut along = vec![0.0; g.len()];
    for &i in idx.iter().take(12) {
        along[i] = g[i].signum();
    }
    let random: Vec<f64> = (0..g.len()).map(|_| rnd()).collect();
    for (name, d) in [("gradient's largest", along), ("random", random)] {
        let norm = d.iter().map(|v| v * v).sum::<f64>().sqrt().max(1e-300);
        let d: Vec<f64> = d.iter().map(|v| v / norm).collect();
        let analytic: f64 = g.iter().zip(&d).map(|(a, b)| a * b).sum();
        let e = |h: f64| {
            let qh: Vec<f64> = q.iter().zip(&d).map(|(a, b)| a + h * b).collect();
            par.problem.energy(&par.point(&qh), false).unwrap().0.total
        };
        let h = 1e-3;
        let fd = (e(h) - e(-h)) / (2.0 * h);
        let scale = analytic.abs().max(fd.abs()).max(1e-3 * e(0.0).abs());
        assert!(
            (fd - analytic).abs() <= 0.03 * scale,
            "{what}, {name}: finite differences {fd} against the analytic {analytic}"
        );
    }
}

struct Scene {
    layer: RenderingLayer,
    image: Vec<f32>,
    region_map: Vec<u8>,
    truth: Prediction,
    size: usize,
}

fn scene(seed: u64) -> Scene {
    sphere_scene(12, seed)
}

/// The layer's own rendering of a sphere of `size`² under a small sky.
fn sphere_scene(size: usize, seed: u64) -> Scene {
    let layer = RenderingLayer::new(4);
    let hb = sphere_batch(1, size, 4, seed, &layer);
    Scene {
        image: hb.input.clone(),
        region_map: hb.region_map.clone(),
        truth: Prediction {
            normals: hb.normals.clone(),
            materials: hb.materials.clone(),
            env: hb.env.clone(),
        },
        size,
        layer,
    }
}

fn problem<'a>(s: &'a Scene, image: &'a [f32], prior: &'a Prediction) -> Problem<'a> {
    Problem {
        layer: &s.layer,
        size: s.size,
        regions: 1,
        image,
        region_map: &s.region_map,
        normals: &prior.normals,
        env: &prior.env,
        a: 1.0,
        b: 10.0,
        priors: Priors::NONE,
    }
}

#[test]
fn the_stride_is_the_smallest_that_fits_the_pixel_budget() {
    for budget in [1usize, 2, 7, 100, 2048] {
        let cfg = Eq6Config {
            coarse_pixels: budget,
            ..Eq6Config::default()
        };
        let counts = (0..3000)
            .chain((3000..300_000).step_by(997))
            .chain([1 << 20, 40_000_000]);
        for object in counts {
            let k = cfg.stride(object);
            if object <= budget {
                assert_eq!(k, 1, "{object} pixels fit {budget}");
                continue;
            }
            assert!(k >= 2 && object.div_ceil(k * k) <= budget, "{object} / {k}² > {budget}");
            assert!(
                k == 2 || object.div_ceil((k - 1) * (k - 1)) > budget,
                "{object} pixels: {} would do for {budget}",
                k - 1
            );
        }
    }
    let never = Eq6Config {
        coarse_pixels: 0,
        ..Eq6Config::default()
    };
    assert_eq!(never.stride(10_000_000), 1);
}

#[test]
fn an_l_bfgs_run_stops_at_its_evaluation_budget_and_keeps_its_lowest_point() {
    let s = scene(3);
    let pr = problem(&s, &s.image, &s.truth);
    let mut start = s.truth.clone();
    start.env.iter_mut().for_each(|v| *v *= 2.0);
    let par = Parametrised::new(&pr, Property::Light, start).with_budget(3);
    let q0 = par.start();
    // Scaling the light by e^t: t = −ln 2 is the truth.
    let at = |t: f64| q0.iter().map(|w| w + t).collect::<Vec<f64>>();
    let e: Vec<f64> = [0.0, -0.69, -0.3]
        .iter()
        .map(|&t| par.evaluate(&at(t)).unwrap().0.total)
        .collect();
    assert_eq!(par.evaluations(), 3);
    // The cached last point costs nothing; a new one is refused.
    assert!(par.evaluate(&at(-0.3)).is_ok());
    assert!(par.evaluate(&at(-0.5)).is_err());
    let (q, best) = par.best().unwrap();
    assert_eq!(best.total, e[1]);
    assert_eq!(q, at(-0.69));
    assert!(e[1] < e[0] && e[1] < e[2]);
}

/// A sphere of `size`² under a small sky, its material, light and normals perturbed.
fn perturbed(size: usize, seed: u64) -> (Scene, Prediction) {
    let s = sphere_scene(size, seed);
    let mut start = s.truth.clone();
    for (k, v) in start.materials.iter_mut().enumerate() {
        *v = (*v + if k % 3 == 0 { 0.25 } else { -0.15 }).clamp(-0.95, 0.95);
    }
    start
        .env
        .iter_mut()
        .enumerate()
        .for_each(|(k, v)| *v *= if k % 2 == 0 { 0.6 } else { 1.5 });
    let p = size * size;
    for k in 0..p {
        let v = [
            start.normals[k] + 0.15,
            start.normals[p + k] - 0.1,
            start.normals[2 * p + k],
        ];
        let len = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
        if s.region_map[k] > 0 && len > 0.0 {
            for (c, vc) in v.iter().enumerate() {
                start.normals[c * p + k] = vc / len;
            }
        }
    }
    (s, start)
}

#[test]
fn coarse_to_fine_lowers_e_about_as_far_as_every_pixel_does_and_never_raises_it() {
    let (s, start) = perturbed(40, 11);
    let object = s.region_map.iter().filter(|&&r| r > 0).count();
    let pr = problem(&s, &s.image, &start);
    let full = post_optimise(
        &pr,
        start.clone(),
        &Eq6Config {
            coarse_pixels: 0,
            ..Eq6Config::default()
        },
    )
    .unwrap();
    assert_eq!(full.stride, 1);
    for budget in [object / 4, object / 9, 40] {
        let cfg = Eq6Config {
            coarse_pixels: budget,
            ..Eq6Config::default()
        };
        let r = post_optimise(&pr, start.clone(), &cfg).unwrap();
        assert!(r.stride >= 2, "{budget}: stride {}", r.stride);
        assert_eq!(r.start, full.start);
        // The whole image's E at the start and the end, the coarse alternation's between.
        let (first, last) = (r.steps[0], r.steps[r.steps.len() - 1]);
        assert_eq!((first.stride, first.energy), (1, r.start.total));
        assert_eq!((last.stride, last.energy), (1, r.end.total));
        let coarse: Vec<&Step> = r.steps.iter().filter(|s| s.stride > 1).collect();
        assert!(!coarse.is_empty() && coarse.iter().all(|s| s.stride == r.stride));
        for w in coarse.windows(2) {
            assert!(w[1].energy <= w[0].energy * (1.0 + 1e-12), "{:?} → {:?}", w[0], w[1]);
        }
        assert!(r.end.total <= r.start.total);
        assert!(
            r.end.total < 0.5 * r.start.total && r.end.total < 2.0 * full.end.total,
            "budget {budget} (stride {}): E {:.4e} → {:.4e}; every pixel: {:.4e}",
            r.stride,
            r.start.total,
            r.end.total,
            full.end.total
        );
        // The constraints hold at every pixel.
        let p = s.size * s.size;
        for k in (0..p).filter(|&k| s.region_map[k] > 0) {
            let n = (0..3).map(|c| (r.point.normals[c * p + k] as f64).powi(2)).sum::<f64>();
            assert!((n - 1.0).abs() < 1e-4);
        }
        assert!(r.point.env.iter().all(|v| *v >= 0.0 && v.is_finite()));
    }
}

#[test]
fn coarse_to_fine_survives_an_object_the_subset_misses_and_nan_pixels() {
    let (mut s, start) = perturbed(24, 4);
    let p = s.size * s.size;
    // Only odd columns: every second pixel's subset holds none of the object.
    for k in 0..p {
        if (k % s.size) % 2 == 0 {
            s.region_map[k] = 0;
        }
    }
    let mut image = s.image.clone();
    for k in (0..p).step_by(5) {
        image[k] = f32::NAN;
    }
    let object = s.region_map.iter().filter(|&&r| r > 0).count();
    let pr = problem(&s, &image, &start);
    let cfg = Eq6Config {
        coarse_pixels: object / 3,
        ..Eq6Config::default()
    };
    let r = post_optimise(&pr, start.clone(), &cfg).unwrap();
    assert_eq!(r.stride, 2);
    assert!(r.end.total.is_finite() && r.end.total <= r.start.total);
    assert!(
        r.point
            .normals
            .iter()
            .chain(&r.point.env)
            .chain(&r.point.materials)
            .all(|v| v.is_finite())
    );
}

#[test]
fn eq6_gradients_match_finite_differences_on_hard_cases() {
    let s = scene(5);
    let p = s.size * s.size;
    // Off the truth, so that every term has a gradient.
    let mut start = s.truth.clone();
    for (k, v) in start.materials.iter_mut().enumerate() {
        *v = (*v + 0.2 * ((k % 5) as f32 - 2.0) / 2.0).clamp(-0.95, 0.95);
    }
    for v in start.env.iter_mut() {
        *v *= 1.3;
    }
    let prior = s.truth.clone();
    let pr = problem(&s, &s.image, &prior);
    for property in [Property::Normals, Property::Material, Property::Light] {
        let par = Parametrised::new(&pr, property, start.clone());
        check_gradient(&par, &par.start(), 1, &format!("{property:?}"));
    }
    // Grazing normals: tilt every normal to n_z ≈ 0.05.
    let mut grazing = start.clone();
    for k in 0..p {
        if s.region_map[k] == 0 {
            continue;
        }
        let (x, y) = (grazing.normals[k], grazing.normals[p + k]);
        let r = (x * x + y * y).sqrt().max(1e-6);
        let (sx, sy) = (x / r, y / r);
        let z: f32 = 0.05;
        let t = (1.0 - z * z).sqrt();
        grazing.normals[k] = sx * t;
        grazing.normals[p + k] = sy * t;
        grazing.normals[2 * p + k] = z;
    }
    let par = Parametrised::new(&pr, Property::Normals, grazing.clone());
    check_gradient(&par, &par.start(), 2, "grazing normals");
    // Sharp lobes: every parameter near the normalised range's edge.
    let mut sharp = start.clone();
    for (k, v) in sharp.materials.iter_mut().enumerate() {
        *v = if k % 2 == 0 { 0.97 } else { -0.9 };
    }
    let par = Parametrised::new(&pr, Property::Material, sharp);
    check_gradient(&par, &par.start(), 3, "sharp lobes");
    // A black environment (the light starts at exp(ln 1e-6)).
    let mut black = start.clone();
    black.env.iter_mut().for_each(|v| *v = 0.0);
    for property in [Property::Light, Property::Material] {
        let par = Parametrised::new(&pr, property, black.clone());
        let (e, g) = par.evaluate(&par.start()).unwrap();
        assert!(e.total.is_finite() && g.iter().all(|v| v.is_finite()));
        if property == Property::Light {
            check_gradient(&par, &par.start(), 4, "black environment");
        }
    }
    // NaN pixels in the photo take no part: E and its gradient stay finite and equal those
    // of the image without those pixels.
    let mut holed = s.image.clone();
    let on: Vec<usize> = (0..p).filter(|&k| s.region_map[k] > 0).collect();
    for &k in on.iter().step_by(7) {
        holed[k] = f32::NAN;
    }
    let hp = problem(&s, &holed, &prior);
    for property in [Property::Normals, Property::Material, Property::Light] {
        let par = Parametrised::new(&hp, property, start.clone());
        let (e, g) = par.evaluate(&par.start()).unwrap();
        assert!(e.total.is_finite() && g.iter().all(|v| v.is_finite()), "{property:?}");
        check_gradient(&par, &par.start(), 5, &format!("NaN pixels, {property:?}"));
    }
}

#[test]
fn eq6_stays_at_the_truth_and_moves_back_towards_it_from_a_perturbed_material() {
    let s = scene(9);
    let cfg = Eq6Config {
        rounds: 2,
        iterations: 10,
        ..Eq6Config::default()
    };
    // From the truth (the priors too), E is ~0 and stays there.
    let pr = problem(&s, &s.image, &s.truth);
    let r = post_optimise(&pr, s.truth.clone(), &cfg).unwrap();
    assert!(r.start.total < 1e-6 * s.image.iter().map(|v| (*v as f64).powi(2)).sum::<f64>());
    assert!(r.end.total <= r.start.total);
    let moved = r
        .point
        .materials
        .iter()
        .zip(&s.truth.materials)
        .map(|(a, b)| (a - b).abs())
        .fold(0.0_f32, f32::max);
    assert!(moved < 0.05, "moved {moved} from the truth");
    // From a perturbed material (normals and light true): the energy falls at every logged
    // step, and the material error falls.
    let mut start = s.truth.clone();
    for (k, v) in start.materials.iter_mut().enumerate() {
        *v = (*v + if k % 3 == 0 { 0.3 } else { -0.2 }).clamp(-0.95, 0.95);
    }
    let r = post_optimise(&pr, start.clone(), &cfg).unwrap();
    for w in r.steps.windows(2) {
        assert!(
            w[1].energy <= w[0].energy * (1.0 + 1e-12),
            "energy rose: {:?} → {:?}",
            w[0],
            w[1]
        );
    }
    assert!(r.end.total < 0.5 * r.start.total, "{:?} → {:?}", r.start, r.end);
    let err = |m: &[f32]| -> f64 {
        m.iter()
            .zip(&s.truth.materials)
            .map(|(a, b)| ((a - b) as f64).powi(2))
            .sum::<f64>()
            .sqrt()
    };
    // The rendered image, not the 108 parameters, is what Eq. 6 sees; its error falls.
    let img = |x: &Prediction| pr.energy(x, false).unwrap().0.image;
    assert!(img(&r.point) < 0.5 * img(&start));
    assert!(
        err(&r.point.materials) <= err(&start.materials),
        "{} → {}",
        err(&start.materials),
        err(&r.point.materials)
    );
    // Every point keeps the constraints: unit normals, materials inside the range, light ≥ 0.
    let p = s.size * s.size;
    for k in (0..p).filter(|&k| s.region_map[k] > 0) {
        let n = (0..3).map(|c| (r.point.normals[c * p + k] as f64).powi(2)).sum::<f64>();
        assert!((n - 1.0).abs() < 1e-4);
    }
    assert!(r.point.materials.iter().all(|v| v.abs() < 1.0));
    assert!(r.point.env.iter().all(|v| *v >= 0.0 && v.is_finite()));
}
