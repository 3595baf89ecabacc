//! MERL tables: lookups, interpolation and the file format, against closed forms and bad files.

use super::*;
use crate::brdf::{Fresnel, Ggx, Lambert, Plastic, testing};

#[test]
fn half_diff_round_trips() {
    for (th, td, pd) in [(0.1, 0.3, 0.5), (1.2, 0.7, 2.9), (0.01, 1.5, 0.01)] {
        let (wi, wo) = half_diff_to_directions(th, td, pd);
        let (a, _, b, c) = directions_to_half_diff(wi, wo);
        assert!((a - th).abs() < 1e-9 && (b - td).abs() < 1e-9 && (c - pd).abs() < 1e-9);
    }
}

#[test]
fn a_tabulated_lambert_is_exact_and_a_tabulated_ggx_is_close() {
    let l = Lambert {
        albedo: [0.5, 0.3, 0.1],
    };
    let m = MerlBrdf::from_bytes(&MerlBrdf::tabulate_bytes(&l), "mem").unwrap();
    assert!(m.invalid_entries() > 0, "below-horizon bins are marked like real files");
    let wi = DVec3::new(0.3, 0.2, 0.9).normalize();
    let wo = DVec3::new(-0.5, 0.1, 0.8).normalize();
    for (a, b) in m.eval(wi, wo).iter().zip(l.eval(wi, wo)) {
        assert!((a - b).abs() < 1e-6, "{a} vs {b}");
    }
    testing::check_basic(&m);
    let g = Plastic::new(0.4, [0.2, 0.2, 0.2]);
    let mg = MerlBrdf::from_bytes(&MerlBrdf::tabulate_bytes(&g), "mem").unwrap();
    let (a, b) = (mg.eval(wi, wo), g.eval(wi, wo));
    assert!((a[0] - b[0]).abs() / b[0] < 0.05, "{a:?} vs {b:?}");
    let _ = Ggx::new(0.3, Fresnel::None);
}

#[test]
fn wrong_files_are_refused_with_the_reason() {
    assert!(matches!(
        MerlBrdf::from_bytes(&[0; 100], "x.binary"),
        Err(MerlError::Size { got: 100, .. })
    ));
    let mut b = MerlBrdf::tabulate_bytes(&Lambert { albedo: [0.5; 3] });
    b[0] = 91;
    let e = MerlBrdf::from_bytes(&b, "x.binary").unwrap_err().to_string();
    assert!(e.contains("x.binary") && e.contains("[91, 90, 180]"), "{e}");
    b[0] = 90;
    b[12..20].copy_from_slice(&f64::NAN.to_le_bytes());
    assert!(matches!(
        MerlBrdf::from_bytes(&b, "x"),
        Err(MerlError::NotFinite { index: 0, .. })
    ));
    assert!(
        MerlBrdf::read(Path::new("/nonexistent.binary"))
            .unwrap_err()
            .to_string()
            .contains("/nonexistent.binary")
    );
}

/// Deterministic points in [0, 1)³ (additive recurrence on the plastic constant's powers).
fn points(n: usize) -> impl Iterator<Item = [f64; 3]> {
    let a = [
        0.819_172_513_396_164_4,
        0.671_043_606_703_789_2,
        0.549_700_477_901_970_5,
    ];
    (0..n).map(move |k| a.map(|x| (0.5 + x * k as f64).fract()))
}

fn ggx_table(alpha: f64) -> MerlBrdf {
    MerlBrdf::tabulate(&Ggx::new(alpha, Fresnel::Schlick([0.9, 0.5, 0.04])))
}

/// The index MERL's reference code gives θ_h, θ_d, φ_d (truncation).
fn reference_index(th: f64, td: f64, pd: f64) -> [usize; 3] {
    [
        ((th / FRAC_PI_2 * 8100.0).sqrt() as usize).min(89),
        ((td / FRAC_PI_2 * 90.0) as usize).min(89),
        ((pd / PI * 180.0) as usize).min(179),
    ]
}

#[test]
fn samples_sit_on_the_lower_edges_of_merls_bins_and_interpolate_linearly_in_index_space() {
    // The reference lookup switches from bin i − 1 to bin i exactly at the sample angle.
    for i in 1..89 {
        let (th, td, pd) = sample_angles(i, i, 2 * i);
        assert_eq!(
            reference_index(th * (1.0 + 1e-9), td * (1.0 + 1e-9), pd * (1.0 + 1e-9)),
            [i, i, 2 * i]
        );
        assert_eq!(
            reference_index(th * (1.0 - 1e-9), td * (1.0 - 1e-9), pd * (1.0 - 1e-9)),
            [i - 1, i - 1, 2 * i - 1]
        );
    }
    // A table holding its own index-space coordinates (θ_h through the square-root mapping)
    // reads back the coordinates of any direction: a half-bin offset between where the
    // table is written and where lookups put the samples would show as an error of 0.5.
    let m = MerlBrdf::from_half_diff_fn(|th, td, pd| {
        let [uh, ud, _] = angles_to_index(th, td, pd);
        Some([uh, ud, 2.0 + (2.0 * pd).cos()])
    });
    let mut checked = 0;
    for [a, b, c] in points(4000).chain([[0.0, 0.0, 0.0], [1e-12, 0.3, 0.999_999]]) {
        let (th, td, pd) = (a * a * 1.2, b * 0.6, c * 2.0 * PI);
        let (wi, wo) = half_diff_to_directions(th, td, pd);
        if wi.z <= 1e-3 || wo.z <= 1e-3 {
            continue;
        }
        let [uh, ud, _] = angles_to_index(th, td, pd);
        let f = m.eval(wi, wo);
        assert!((f[0] - uh).abs() < 2e-5 * uh.max(1.0), "θ_h {th}: {} vs {uh}", f[0]);
        assert!((f[1] - ud).abs() < 2e-5 * ud.max(1.0), "θ_d {td}: {} vs {ud}", f[1]);
        // cos 2φ_d is periodic in π: no seam at φ_d = 0 ≡ π, curvature error only.
        assert!((f[2] - 2.0 - (2.0 * pd).cos()).abs() < 2e-4, "φ_d {pd}: {}", f[2]);
        checked += 1;
    }
    assert!(checked > 2000, "{checked}");
}

#[test]
fn the_fast_half_diff_coordinates_match_merls_rotations() {
    for [a, b, c] in points(2000) {
        let wi = DVec3::new(2.0 * a - 1.0, 2.0 * b - 1.0, c + 1e-3).normalize();
        let wo = DVec3::new(2.0 * c - 1.0, 1.0 - 2.0 * a, b + 1e-3).normalize();
        let (th, _, td, pd) = directions_to_half_diff(wi, wo);
        let want = angles_to_index(th, td, pd);
        let Some(got) = index_coords(wi, wo) else {
            panic!("{wi} {wo}");
        };
        for k in 0..3 {
            let mut d = (got[k] - want[k]).abs();
            if k == 2 {
                d = d.min(RES_PHI_D as f64 - d);
            }
            assert!(d < 1e-7, "{wi} {wo}: {got:?} vs {want:?}");
        }
    }
}

#[test]
fn extreme_and_invalid_directions_give_finite_non_negative_values() {
    let m = ggx_table(0.1);
    let g = Ggx::new(0.1, Fresnel::Schlick([0.9, 0.5, 0.04]));
    let eps = 1e-9;
    let mut pairs = Vec::new();
    for th in [
        0.0,
        1e-12,
        1e-6,
        0.3,
        FRAC_PI_2 - 0.2,
        FRAC_PI_2 - 1e-3,
        FRAC_PI_2 - eps,
    ] {
        for td in [0.0, 1e-12, 0.4, 1.0, FRAC_PI_2 - 1e-3, FRAC_PI_2 - eps] {
            for pd in [0.0, eps, PI - eps, PI, PI + eps, 2.0 * PI - eps, -eps, -PI] {
                pairs.push(half_diff_to_directions(th, td, pd));
            }
        }
    }
    let nan = DVec3::new(f64::NAN, 0.0, 1.0);
    let inf = DVec3::new(f64::INFINITY, 0.0, 1.0);
    pairs.extend([
        (DVec3::Z, DVec3::Z),
        (nan, DVec3::Z),
        (DVec3::Z, nan),
        (DVec3::splat(f64::NAN), DVec3::splat(f64::NAN)),
        (inf, DVec3::Z),
        (DVec3::new(0.0, 0.0, f64::INFINITY), DVec3::Z),
        (DVec3::ZERO, DVec3::Z),
        (DVec3::new(1.0, 0.0, 1e-300), DVec3::new(-1.0, 0.0, 1e-300)),
        (DVec3::new(1.0, 0.0, 1e-300), DVec3::new(1.0, 0.0, 1e-300)),
    ]);
    for lookup in [MerlLookup::Trilinear, MerlLookup::Nearest] {
        let m = m.clone().with_lookup(lookup);
        for &(wi, wo) in &pairs {
            let f = m.eval(wi, wo);
            assert!(
                f.iter().all(|v| v.is_finite() && *v >= 0.0),
                "{lookup:?} f({wi}, {wo}) = {f:?}"
            );
            let usable = wi.z > 0.0 && wo.z > 0.0 && wi.is_finite() && wo.is_finite();
            if !usable {
                assert_eq!(f, [0.0; 3], "{lookup:?} below the horizon or not finite: {wi}, {wo}");
            }
        }
    }
    // θ_h = 0 is sample 0: on the θ_d samples the table returns the analytic peak itself.
    for id in [0, 10, 45, 80] {
        let (_, td, _) = sample_angles(0, id, 0);
        for pd in [0.0, 1.0, PI - eps, 2.0 * PI - eps] {
            let (wi, wo) = half_diff_to_directions(0.0, td, pd);
            let (a, b) = (m.eval(wi, wo), g.eval(wi, wo));
            for c in 0..3 {
                assert!((a[c] - b[c]).abs() <= 1e-6 * b[c], "θ_d {td} φ_d {pd}: {a:?} vs {b:?}");
            }
        }
    }
    // φ_d wraps: both sides of 0 ≡ π agree, and φ_d + π (reciprocity) is the same entry.
    for (th, td) in [(0.2, 0.3), (0.6, 1.0), (0.05, 0.8)] {
        let at = |pd| {
            let (wi, wo) = half_diff_to_directions(th, td, pd);
            m.eval(wi, wo)
        };
        let (a, b, c, d) = (at(1e-9), at(2.0 * PI - 1e-9), at(PI - 1e-9), at(PI + 1e-9));
        for k in 0..3 {
            let tol = 1e-6 * a[k].max(1e-3);
            assert!((a[k] - b[k]).abs() < tol && (a[k] - c[k]).abs() < tol && (a[k] - d[k]).abs() < tol);
        }
    }
}

#[test]
fn unmeasured_neighbours_are_left_out_not_read_as_zero() {
    // Measured (0.5, 0.25, 0.125) where θ_d < 30°, except for a hole of single bins;
    // unmeasured elsewhere.
    let m = MerlBrdf::from_half_diff_fn(|th, td, pd| {
        let [uh, ud, up] = angles_to_index(th, td, pd);
        let hole = uh as usize == 20 && ud as usize == 10 && up as usize == 40;
        (ud < 30.0 && !hole).then_some([0.5, 0.25, 0.125])
    });
    assert_eq!(m.invalid_entries(), 3 * (RES_THETA_H * 60 * RES_PHI_D + 1));
    let at = |m: &MerlBrdf, uh: f64, ud: f64, up: f64| {
        let th = (uh / RES_THETA_H as f64).powi(2) * FRAC_PI_2;
        let (wi, wo) = half_diff_to_directions(th, ud / 90.0 * FRAC_PI_2, up / 180.0 * PI);
        m.eval(wi, wo)
    };
    for (uh, ud, up) in [
        (20.0, 10.0, 40.0),
        (19.5, 9.7, 40.3),
        (20.3, 10.0, 39.5),
        (10.0, 29.5, 5.0),
        (10.0, 29.0, 5.0),
    ] {
        let f = at(&m, uh, ud, up);
        for (v, want) in f.iter().zip([0.5, 0.25, 0.125]) {
            assert!((v - want).abs() < 1e-6, "({uh}, {ud}, {up}): {f:?}");
        }
    }
    // No measured corner: 0.
    assert_eq!(at(&m, 10.0, 45.5, 5.0), [0.0; 3]);
    // The nearest lookup reads an unmeasured sample as 0, as before.
    assert_eq!(
        at(&m.clone().with_lookup(MerlLookup::Nearest), 20.0, 10.0, 40.0),
        [0.0; 3]
    );
}

/// Worst ratio, over consecutive points of `path`, of the jump in value to what trilinear
/// interpolation of the table allows: |Δf| ≤ Σ_k |Δu_k| · (largest difference between
/// neighbouring entries along axis k in the box of samples around both points).
fn worst_jump(m: &MerlBrdf, path: &[(DVec3, DVec3)]) -> f64 {
    let mut worst: f64 = 0.0;
    for pair in path.windows(2) {
        let [(ai, ao), (bi, bo)] = [pair[0], pair[1]];
        let (Some(ua), Some(ub)) = (index_coords(ai, ao), index_coords(bi, bo)) else {
            continue;
        };
        let (fa, fb) = (m.eval(ai, ao), m.eval(bi, bo));
        // Samples along each axis, in order, covering the cells of both points.
        let mut axes: [Vec<usize>; 3] = Default::default();
        let mut du = [0.0; 3];
        for k in 0..3 {
            let (lo, hi) = (ua[k].min(ub[k]), ua[k].max(ub[k]));
            du[k] = hi - lo;
            axes[k] = if k == 2 && du[k] > RES_PHI_D as f64 / 2.0 {
                du[k] = RES_PHI_D as f64 - du[k];
                (hi as usize..RES_PHI_D).chain(0..=lo as usize + 1).collect()
            } else if k == 2 {
                (lo as usize..=hi as usize + 1).map(|p| p % RES_PHI_D).collect()
            } else {
                (lo as usize..=(hi as usize + 1).min(RES_THETA_H - 1)).collect()
            };
        }
        let at = |ih: usize, id: usize, ip: usize| {
            m.entry(ih, id, ip)
                .unwrap_or_else(|| panic!("paths stay where the table is measured: ({ih}, {id}, {ip})"))
        };
        let mut step = [[0.0_f64; 3]; 3];
        let mut top = [0.0_f64; 3];
        for (jh, &ih) in axes[0].iter().enumerate() {
            for (jd, &id) in axes[1].iter().enumerate() {
                for (jp, &ip) in axes[2].iter().enumerate() {
                    let v = at(ih, id, ip);
                    let next = [
                        axes[0].get(jh + 1).map(|&n| at(n, id, ip)),
                        axes[1].get(jd + 1).map(|&n| at(ih, n, ip)),
                        axes[2].get(jp + 1).map(|&n| at(ih, id, n)),
                    ];
                    for c in 0..3 {
                        top[c] = top[c].max(v[c]);
                        for k in 0..3 {
                            if let Some(w) = next[k] {
                                step[k][c] = step[k][c].max((w[c] - v[c]).abs());
                            }
                        }
                    }
                }
            }
        }
        for c in 0..3 {
            let bound = (0..3).map(|k| du[k] * step[k][c]).sum::<f64>() + 1e-6 * top[c] + 1e-12;
            worst = worst.max((fa[c] - fb[c]).abs() / bound);
        }
    }
    worst
}

#[test]
fn interpolated_values_have_no_jumps_beyond_the_tables_local_variation() {
    let m = ggx_table(0.15);
    let dir = |theta: f64, phi: f64| DVec3::new(theta.sin() * phi.cos(), theta.sin() * phi.sin(), theta.cos());
    let n = 20_000;
    let mut paths: Vec<Vec<(DVec3, DVec3)>> = Vec::new();
    // The light circling a fixed viewer: through the mirror direction (θ_h = 0) and across
    // the φ_d seam.
    let wo = dir(0.5, 0.0);
    paths.push((0..n).map(|k| (dir(0.5, 2.0 * PI * k as f64 / n as f64), wo)).collect());
    // The light sweeping the plane of incidence through the specular peak.
    paths.push(
        (0..n)
            .map(|k| (dir(-1.0 + 2.0 * k as f64 / n as f64, PI), wo))
            .collect(),
    );
    // Both directions moving: θ_d from 0 (ω_i = ω_o) outwards.
    paths.push(
        (0..n)
            .map(|k| {
                let t = 1.0 * k as f64 / n as f64;
                (dir(0.3 + t, 0.2), dir(0.3, 0.2 + 2.0 * t))
            })
            .collect(),
    );
    // Across the φ_d seam (0 ≡ π) away from the degenerate θ_h = 0 and θ_d = 0, where the
    // circling light crosses it.
    for centre in [0.0, PI] {
        paths.push(
            (0..n)
                .map(|k| half_diff_to_directions(0.5, 0.8, centre - 0.3 + 0.6 * k as f64 / n as f64))
                .collect(),
        );
    }
    for (i, path) in paths.iter().enumerate() {
        let w = worst_jump(&m, path);
        assert!(w <= 1.0, "path {i}: a jump {w:.3}× the table's local variation");
        // The check is sharp enough to see the nearest lookup's steps.
        let w = worst_jump(&m.clone().with_lookup(MerlLookup::Nearest), path);
        assert!(w > 5.0, "path {i}: nearest lookup's worst step only {w:.3}× the bound");
    }
}

#[test]
fn written_files_read_back_identical_and_a_failed_write_leaves_nothing() {
    let m = ggx_table(0.3);
    let dir = std::env::temp_dir().join(format!("matedit-merl-unit-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("ggx.binary");
    m.write(&path).unwrap();
    assert_eq!(std::fs::metadata(&path).unwrap().len() as usize, FILE_BYTES);
    let back = MerlBrdf::read(&path).unwrap();
    assert_eq!(back, m);
    assert_eq!(back.invalid_entries(), m.invalid_entries());
    let missing = dir.join("no/such/dir/x.binary");
    let e = m.write(&missing).unwrap_err().to_string();
    assert!(e.contains("no/such/dir/x.binary"), "{e}");
    let left: Vec<_> = std::fs::read_dir(&dir)
        .unwrap()
        .flatten()
        .map(|e| e.file_name())
        .collect();
    assert_eq!(left, [std::ffi::OsString::from("ggx.binary")]);
    std::fs::remove_dir_all(&dir).unwrap();
}
