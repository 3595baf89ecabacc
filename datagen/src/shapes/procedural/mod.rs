//! Procedural shapes of the paper's four categories (car, chair, sofa, monitor), built from
//! smooth closed parts (lofts, superquadrics, lathes), each with parametric variation and a
//! semantic segmentation, deterministic from a seed.
//!
//! Conventions: +y up, the object's front towards +z (cars: length along x, so the default
//! view is a side view), units roughly metres (the renderer normalises to the unit ball).

mod builder;
mod car;
mod chair;
mod monitor;
mod sofa;
mod surface;

pub use builder::Builder;

use super::Mesh;
use matedit_assets::random::Draw;

/// A shape category of the paper's dataset.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Category {
    /// Cars: sedans, hatchbacks, SUVs, coupés, vans; regions body, wheels, tyres, glass, lights.
    Car,
    /// Chairs: four splayed legs or a swivel base, with or without arms; regions frame and seat.
    Chair,
    /// Sofas: 1–3 seats, rolled or square arms, legs or a plinth; regions frame and cushions.
    Sofa,
    /// Monitors: four aspect ratios, bevels, neck and foot styles; regions housing and screen.
    Monitor,
}

impl Category {
    /// All categories, in a fixed order.
    pub const ALL: [Category; 4] = [Category::Car, Category::Chair, Category::Sofa, Category::Monitor];

    /// Lower-case name.
    pub fn name(self) -> &'static str {
        match self {
            Category::Car => "car",
            Category::Chair => "chair",
            Category::Sofa => "sofa",
            Category::Monitor => "monitor",
        }
    }

    /// The region names, by id.
    pub fn regions(self) -> &'static [&'static str] {
        match self {
            Category::Car => &car::REGIONS,
            Category::Chair => &chair::REGIONS,
            Category::Sofa => &sofa::REGIONS,
            Category::Monitor => &monitor::REGIONS,
        }
    }

    /// Generates the shape of `seed`.
    pub fn generate(self, seed: u64) -> Mesh {
        self.builder(seed).finish()
    }

    /// The parts of the shape of `seed`, before normalisation.
    fn builder(self, seed: u64) -> Builder {
        let mut r = Draw::new(seed, 100 + self as u64);
        let mut b = Builder::new(self.regions(), format!("procedural:{}:{seed}", self.name()));
        match self {
            Category::Car => car::build(&mut b, &mut r),
            Category::Chair => chair::build(&mut b, &mut r),
            Category::Sofa => sofa::build(&mut b, &mut r),
            Category::Monitor => monitor::build(&mut b, &mut r),
        }
        b
    }
}

impl std::str::FromStr for Category {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        Category::ALL
            .into_iter()
            .find(|c| c.name() == s)
            .ok_or_else(|| format!("unknown category {s:?} (car, chair, sofa, monitor)"))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::Vec3;
    use std::collections::HashMap;

    const SEEDS: u64 = 50;

    #[test]
    fn every_category_is_deterministic_and_labels_every_region() {
        for c in Category::ALL {
            for seed in 0..SEEDS {
                let m = c.generate(seed);
                let again = c.generate(seed);
                assert_eq!(m.positions, again.positions, "{c:?} {seed}");
                assert_eq!(m.corner_normals, again.corner_normals, "{c:?} {seed}");
                assert_eq!(m.regions, c.regions().iter().map(|r| r.to_string()).collect::<Vec<_>>());
                for region in 0..c.regions().len() as u32 {
                    let n = m.triangle_region.iter().filter(|&&r| r == region).count();
                    assert!(n > 10, "{c:?} {seed}: region {region} has {n} triangles");
                }
                assert!(m.positions.iter().all(|p| p.is_finite() && p.length() <= 1.0 + 1e-5));
                let unit = |n: &Vec3| (n.length() - 1.0).abs() < 1e-4;
                assert!(m.corner_normals.iter().flatten().all(unit), "{c:?} {seed}");
                assert_eq!(m.degenerate_dropped, 0, "{c:?} {seed}");
            }
        }
    }

    /// Bounding boxes in the category's proportions, and 50 seeds that do not look alike.
    #[test]
    fn proportions_fit_the_category_and_vary() {
        for c in Category::ALL {
            let mut sizes: Vec<(Vec3, Vec<f32>)> = Vec::new();
            for seed in 0..SEEDS {
                let m = c.generate(seed);
                let (lo, hi) = m
                    .positions
                    .iter()
                    .fold((Vec3::INFINITY, Vec3::NEG_INFINITY), |(lo, hi), p| {
                        (lo.min(*p), hi.max(*p))
                    });
                let s = hi - lo;
                let ok = match c {
                    // Long, low, about twice as long as wide.
                    Category::Car => s.x > 1.8 * s.z && s.x > 1.7 * s.y && s.z > 0.7 * s.y,
                    Category::Chair => s.y > s.x && s.y > s.z,
                    Category::Sofa => s.x > s.y && s.x > s.z,
                    Category::Monitor => s.y > 1.2 * s.z && s.x > 1.5 * s.z,
                };
                assert!(ok, "{c:?} {seed}: extent {s}");
                // Proportions and how the surface divides into regions.
                let share: Vec<f32> = (0..c.regions().len() as u32)
                    .map(|r| m.triangle_region.iter().filter(|&&x| x == r).count() as f32 / m.triangles.len() as f32)
                    .collect();
                // Where the mass sits in the box: the side profile's and the plan's shape.
                let n = m.positions.len() as f32;
                let mean = m.positions.iter().map(|p| (*p - lo) / s).sum::<Vec3>() / n;
                let spread = m
                    .positions
                    .iter()
                    .map(|p| ((*p - lo) / s - mean).powf(2.0))
                    .sum::<Vec3>()
                    / n;
                let mut sig = share;
                sig.extend(mean.to_array());
                sig.extend(spread.to_array());
                sizes.push((s / s.max_element(), sig));
            }
            // No two of the 50 alike: proportions, region shares or the distribution of the surface in
            // its box 0.3 % apart.
            for i in 0..sizes.len() {
                for j in 0..i {
                    let (a, b) = (&sizes[i], &sizes[j]);
                    let shares = a.1.iter().zip(&b.1).map(|(x, y)| (x - y).abs()).fold(0.0, f32::max);
                    assert!(
                        (a.0 - b.0).abs().max_element().max(shares) > 0.003,
                        "{c:?}: seeds {i} and {j} alike: {a:?} {b:?}"
                    );
                }
            }
        }
    }

    /// Every part is closed: each edge is used once in each direction.
    #[test]
    fn every_part_is_watertight() {
        for c in Category::ALL {
            for seed in 0..SEEDS {
                let b = c.builder(seed);
                let m = b.mesh();
                for (k, part) in b.parts().iter().enumerate() {
                    let mut edges: HashMap<(u32, u32), u32> = HashMap::new();
                    for t in &m.triangles[part.clone()] {
                        for e in 0..3 {
                            *edges.entry((t[e], t[(e + 1) % 3])).or_default() += 1;
                        }
                    }
                    for (&(a, b2), &n) in &edges {
                        assert!(
                            n == 1 && edges.get(&(b2, a)) == Some(&1),
                            "{c:?} {seed} part {k}: edge {a}-{b2} is open"
                        );
                    }
                }
            }
        }
    }

    /// Shading normals agree with the surface: none more than 60° from its triangle's face, and
    /// across every edge of a car's body (one smooth loft) they turn by under 45°, so no facet
    /// or seam shows at 256² (a bumper's corner turns 90° over two or more edges).
    #[test]
    fn normals_are_smooth_and_follow_the_surface() {
        for c in Category::ALL {
            for seed in 0..SEEDS {
                let b = c.builder(seed);
                let m = b.mesh();
                for (k, (t, ns)) in m.triangles.iter().zip(&m.corner_normals).enumerate() {
                    let [p0, p1, p2] = t.map(|i| m.positions[i as usize]);
                    let face = (p1 - p0).cross(p2 - p0).normalize();
                    let part = b.parts().iter().position(|p| p.contains(&k));
                    for n in ns {
                        assert!(
                            n.dot(face) > 0.5,
                            "{c:?} {seed}: shading normal {n} against face {face} at {p0} (part {part:?})"
                        );
                    }
                }
                if c == Category::Car {
                    let body = b.parts()[0].clone();
                    let mut normal_of = HashMap::new();
                    for (t, ns) in m.triangles[body.clone()].iter().zip(&m.corner_normals[body]) {
                        for k in 0..3 {
                            normal_of.insert(t[k], ns[k]);
                        }
                    }
                    for t in &m.triangles[b.parts()[0].clone()] {
                        for k in 0..3 {
                            let (a, d) = (normal_of[&t[k]], normal_of[&t[(k + 1) % 3]]);
                            if a.y.min(d.y) < -0.2 {
                                // The underside and the wheel wells' lips face the ground, which
                                // no view of the dataset sees.
                                continue;
                            }
                            assert!(
                                a.dot(d) > 45f32.to_radians().cos(),
                                "{seed}: the body's normals turn {:.0}° across an edge at {}",
                                a.dot(d).acos().to_degrees(),
                                m.positions[t[k] as usize]
                            );
                        }
                    }
                }
            }
        }
    }
}
