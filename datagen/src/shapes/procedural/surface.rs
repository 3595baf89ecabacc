//! Smooth closed surfaces for the procedural shapes: a parametric patch P(u, v) sampled on a
//! grid whose vertices are shared, so each part is watertight and its normals are continuous;
//! superquadrics, lathes and lofts are such patches.

use glam::{Mat3, Vec2, Vec3};

/// How the parameter square closes into a surface.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Topology {
    /// u periodic, v from a pole (v = 0) to a pole (v = 1): spheres, superquadrics, lathes.
    Sphere,
    /// u and v periodic: tyres.
    Torus,
}

/// A sampled patch: shared vertices, their normals, and triangles wound outwards.
pub struct Patch {
    /// Vertex positions.
    pub positions: Vec<Vec3>,
    /// Unit normal per vertex.
    pub normals: Vec<Vec3>,
    /// Triangles (indices into `positions`) with their centroid's (u, v).
    pub triangles: Vec<([u32; 3], Vec2)>,
}

/// Samples `f` on `segments` steps of u (around) and `rings` steps of v. Normals are those of
/// the surface (central differences of `f`), not of the triangles, so curved parts shade smoothly;
/// the orientation is chosen so that the enclosed volume is positive (outwards).
pub fn sample(topology: Topology, segments: usize, rings: usize, f: &dyn Fn(f32, f32) -> Vec3) -> Patch {
    let (su, sv) = (segments.max(3), rings.max(2));
    let normal_at = |u: f32, v: f32| normal(f, u, v);
    let mut positions = Vec::new();
    let mut normals = Vec::new();
    let mut triangles = Vec::new();
    let uv = |i: usize, j: usize| (i as f32 / su as f32, j as f32 / sv as f32);
    match topology {
        Topology::Sphere => {
            // Rings 1..sv-1 of su vertices, then the two poles.
            let ring = |i: usize, j: usize| ((j - 1) * su + i % su) as u32;
            for j in 1..sv {
                for i in 0..su {
                    let (u, v) = uv(i, j);
                    positions.push(f(u, v));
                    normals.push(normal_at(u, v));
                }
            }
            let (south, north) = (positions.len() as u32, positions.len() as u32 + 1);
            for (pole, next) in [(0.0_f32, 1usize), (1.0, sv - 1)] {
                // The pole's normal (the patch's own is 0/0 there): the mean of its ring's,
                // unless they cancel (a flat cap whose ring is already the rim), then from the
                // ring's centre to the pole, signed like the ring's normals.
                let p = f(0.0, pole);
                let mean = (0..su).map(|i| normals[ring(i, next) as usize]).sum::<Vec3>() / su as f32;
                let n = if mean.length() > 0.5 {
                    mean.normalize()
                } else {
                    let centre = (0..su).map(|i| positions[ring(i, next) as usize]).sum::<Vec3>() / su as f32;
                    let facing: f32 = (0..su)
                        .map(|i| {
                            let k = ring(i, next) as usize;
                            normals[k].dot(positions[k] - centre)
                        })
                        .sum();
                    (p - centre).normalize_or_zero() * if facing < 0.0 { -1.0 } else { 1.0 }
                };
                positions.push(p);
                normals.push(n);
            }
            for i in 0..su {
                let c = (i as f32 + 0.5) / su as f32;
                triangles.push(([south, ring(i + 1, 1), ring(i, 1)], Vec2::new(c, 0.5 / sv as f32)));
                triangles.push((
                    [north, ring(i, sv - 1), ring(i + 1, sv - 1)],
                    Vec2::new(c, 1.0 - 0.5 / sv as f32),
                ));
                for j in 1..sv - 1 {
                    let centre = Vec2::new(c, (j as f32 + 0.5) / sv as f32);
                    let (a, b, cc, d) = (ring(i, j), ring(i + 1, j), ring(i + 1, j + 1), ring(i, j + 1));
                    triangles.push(([a, b, cc], centre));
                    triangles.push(([a, cc, d], centre));
                }
            }
        }
        Topology::Torus => {
            let at = |i: usize, j: usize| ((j % sv) * su + i % su) as u32;
            for j in 0..sv {
                for i in 0..su {
                    let (u, v) = uv(i, j);
                    positions.push(f(u, v));
                    normals.push(normal_at(u, v));
                }
            }
            for j in 0..sv {
                for i in 0..su {
                    let centre = Vec2::new((i as f32 + 0.5) / su as f32, (j as f32 + 0.5) / sv as f32);
                    let (a, b, c, d) = (at(i, j), at(i + 1, j), at(i + 1, j + 1), at(i, j + 1));
                    triangles.push(([a, b, c], centre));
                    triangles.push(([a, c, d], centre));
                }
            }
        }
    }
    let mut patch = Patch {
        positions,
        normals,
        triangles,
    };
    patch.orient();
    patch
}

impl Patch {
    /// Turns the whole patch (normals and winding) outwards if its signed volume is negative.
    fn orient(&mut self) {
        if self.signed_volume() < 0.0 {
            for n in &mut self.normals {
                *n = -*n;
            }
            for (t, _) in &mut self.triangles {
                t.swap(1, 2);
            }
        }
    }

    /// The volume enclosed, positive when the triangles wind outwards.
    pub fn signed_volume(&self) -> f32 {
        let p = &self.positions;
        self.triangles
            .iter()
            .map(|(t, _)| p[t[0] as usize].dot(p[t[1] as usize].cross(p[t[2] as usize])) / 6.0)
            .sum()
    }

    /// Moves the patch: `rot` then `centre`.
    pub fn placed(mut self, centre: Vec3, rot: Mat3) -> Patch {
        for p in &mut self.positions {
            *p = centre + rot * *p;
        }
        for n in &mut self.normals {
            *n = rot * *n;
        }
        self
    }
}

/// The unit normal of the patch `f` at (u, v), from central differences; its sign follows the
/// parametrisation (see [`sample`] for outwards).
pub fn normal(f: &dyn Fn(f32, f32) -> Vec3, u: f32, v: f32) -> Vec3 {
    let h = 1e-3_f32;
    let du = f(u + h, v) - f(u - h, v);
    let dv = f(u, v + h) - f(u, v - h);
    du.cross(dv).normalize_or_zero()
}

/// sgn(c)·|c|^e: the superquadric's signed power.
pub fn spow(c: f32, e: f32) -> f32 {
    c.signum() * c.abs().powf(e)
}

/// A superellipsoid of half-extents `half`, +y its polar axis: `e_vertical` shapes its profile
/// (1 round, → 0 square), `e_around` its horizontal section. Returns the patch function.
pub fn superellipsoid(half: Vec3, e_vertical: f32, e_around: f32) -> impl Fn(f32, f32) -> Vec3 {
    move |u, v| {
        let eta = std::f32::consts::PI * (v - 0.5);
        let omega = std::f32::consts::TAU * u;
        let (ce, se) = (spow(eta.cos(), e_vertical), spow(eta.sin(), e_vertical));
        Vec3::new(
            half.x * ce * spow(omega.cos(), e_around),
            half.y * se,
            half.z * ce * spow(omega.sin(), e_around),
        )
    }
}

/// A solid of revolution about +y: `profile(t)` gives (radius, height) for t from 0 (bottom
/// pole, radius 0) to 1 (top pole, radius 0). Rings are cosine-spaced in t, dense at the ends,
/// where a cap turns from the axis to the side.
pub fn lathe(profile: impl Fn(f32) -> (f32, f32)) -> impl Fn(f32, f32) -> Vec3 {
    move |u, v| {
        let t = 0.5 - 0.5 * (std::f32::consts::PI * v.clamp(0.0, 1.0)).cos();
        let (r, y) = profile(t);
        let omega = std::f32::consts::TAU * u;
        Vec3::new(r * omega.cos(), y, r * omega.sin())
    }
}

/// A monotone cubic through `points` (x increasing): Fritsch–Carlson slopes, so the curve never
/// overshoots its control points (a hood stays a hood); flat outside the range.
pub struct Profile {
    xs: Vec<f32>,
    ys: Vec<f32>,
    slopes: Vec<f32>,
}

impl Profile {
    /// The curve through `points`; x must increase strictly.
    pub fn new(points: &[(f32, f32)]) -> Profile {
        let xs: Vec<f32> = points.iter().map(|p| p.0).collect();
        let ys: Vec<f32> = points.iter().map(|p| p.1).collect();
        let n = xs.len();
        let d: Vec<f32> = (0..n - 1).map(|k| (ys[k + 1] - ys[k]) / (xs[k + 1] - xs[k])).collect();
        let mut slopes = vec![0.0; n];
        for k in 1..n - 1 {
            slopes[k] = if d[k - 1] * d[k] <= 0.0 {
                0.0
            } else {
                // Weighted harmonic mean (Fritsch–Butland): monotone and C¹.
                let (h0, h1) = (xs[k] - xs[k - 1], xs[k + 1] - xs[k]);
                let (w1, w2) = (2.0 * h1 + h0, h1 + 2.0 * h0);
                (w1 + w2) / (w1 / d[k - 1] + w2 / d[k])
            };
        }
        Profile { xs, ys, slopes }
    }

    /// The curve at `x`.
    pub fn at(&self, x: f32) -> f32 {
        let n = self.xs.len();
        if x <= self.xs[0] {
            return self.ys[0];
        }
        if x >= self.xs[n - 1] {
            return self.ys[n - 1];
        }
        let k = self.xs.partition_point(|&a| a <= x).clamp(1, n - 1) - 1;
        let h = self.xs[k + 1] - self.xs[k];
        let t = (x - self.xs[k]) / h;
        let (t2, t3) = (t * t, t * t * t);
        (2.0 * t3 - 3.0 * t2 + 1.0) * self.ys[k]
            + (t3 - 2.0 * t2 + t) * h * self.slopes[k]
            + (-2.0 * t3 + 3.0 * t2) * self.ys[k + 1]
            + (t3 - t2) * h * self.slopes[k + 1]
    }
}

/// 0 below `a`, 1 above `b`, smooth between.
pub fn smoothstep(a: f32, b: f32, x: f32) -> f32 {
    let t = ((x - a) / (b - a)).clamp(0.0, 1.0);
    t * t * (3.0 - 2.0 * t)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every edge of a closed patch is shared by exactly two triangles, once in each direction.
    fn assert_watertight(p: &Patch) {
        let mut edges = std::collections::HashMap::new();
        for (t, _) in &p.triangles {
            for k in 0..3 {
                *edges.entry((t[k], t[(k + 1) % 3])).or_insert(0) += 1;
            }
        }
        for (&(a, b), &n) in &edges {
            assert_eq!(n, 1, "edge {a}-{b} used {n} times in one direction");
            assert_eq!(edges.get(&(b, a)), Some(&1), "edge {a}-{b} has no twin");
        }
    }

    #[test]
    fn a_sphere_patch_is_closed_outward_and_measures_a_sphere() {
        let f = superellipsoid(Vec3::ONE, 1.0, 1.0);
        let p = sample(Topology::Sphere, 64, 32, &f);
        assert_watertight(&p);
        let v = p.signed_volume();
        let exact = 4.0 / 3.0 * std::f32::consts::PI;
        assert!(v > 0.0 && (v - exact).abs() / exact < 0.01, "{v} vs {exact}");
        for (q, n) in p.positions.iter().zip(&p.normals) {
            assert!((q.length() - 1.0).abs() < 1e-5);
            assert!(n.dot(*q) > 0.999, "{q} {n}");
        }
    }

    #[test]
    fn a_torus_patch_is_closed_and_outward() {
        let (big, small) = (1.0_f32, 0.3_f32);
        let f = |u: f32, v: f32| {
            let (a, b) = (std::f32::consts::TAU * u, std::f32::consts::TAU * v);
            Vec3::new(
                (big + small * b.cos()) * a.cos(),
                small * b.sin(),
                (big + small * b.cos()) * a.sin(),
            )
        };
        let p = sample(Topology::Torus, 48, 24, &f);
        assert_watertight(&p);
        let exact = 2.0 * std::f32::consts::PI.powi(2) * big * small * small;
        assert!((p.signed_volume() - exact).abs() / exact < 0.02);
        for (q, n) in p.positions.iter().zip(&p.normals) {
            let core = Vec3::new(q.x, 0.0, q.z).normalize() * big;
            assert!(n.dot((*q - core).normalize()) > 0.999);
        }
    }

    #[test]
    fn boxy_superellipsoids_keep_unit_normals_and_no_degenerate_triangles() {
        for e in [0.1_f32, 0.2, 0.5, 1.0, 1.5] {
            let f = superellipsoid(Vec3::new(1.0, 0.2, 0.5), e, e);
            let p = sample(Topology::Sphere, 48, 32, &f);
            assert_watertight(&p);
            assert!(p.signed_volume() > 0.0);
            for n in &p.normals {
                assert!((n.length() - 1.0).abs() < 1e-4, "e {e}: {n}");
            }
            for (t, _) in &p.triangles {
                let [a, b, c] = t.map(|i| p.positions[i as usize]);
                assert!((b - a).cross(c - a).length() > 1e-9, "e {e}: a degenerate triangle");
            }
        }
    }

    #[test]
    fn the_profile_interpolates_without_overshoot() {
        let pr = Profile::new(&[(0.0, 0.0), (1.0, 1.0), (2.0, 1.0), (3.0, 0.2)]);
        for (x, y) in [(0.0, 0.0), (1.0, 1.0), (2.0, 1.0), (3.0, 0.2), (-1.0, 0.0), (4.0, 0.2)] {
            assert!((pr.at(x) - y).abs() < 1e-6);
        }
        for k in 0..=300 {
            let y = pr.at(k as f32 / 100.0);
            assert!((-1e-6..=1.0 + 1e-6).contains(&y), "{y}");
        }
        assert_eq!(
            (
                smoothstep(0.0, 1.0, -1.0),
                smoothstep(0.0, 1.0, 0.5),
                smoothstep(0.0, 1.0, 2.0)
            ),
            (0.0, 0.5, 1.0)
        );
    }
}
