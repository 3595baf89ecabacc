//! Procedural shapes of the paper's four categories (car, chair, sofa, monitor), each with
//! real parametric variation and a two-region semantic segmentation, deterministic from a seed.
//!
//! Conventions: +y up, the object's front towards +z (cars: length along x, so the default
//! view is a side view), units roughly metres (the renderer normalises to the unit ball).

mod builder;
mod car;
mod chair;
mod monitor;
mod sofa;

pub use builder::Builder;

use super::Mesh;
use matedit_assets::random::Draw;

/// A shape category of the paper's dataset.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Category {
    /// Cars: sedans, hatchbacks, vans, pickups; regions body and wheels.
    Car,
    /// Chairs: four-legged or swivel, with or without arms; regions frame and seat.
    Chair,
    /// Sofas: 1–3 seats, arm styles, legs; regions frame and cushions.
    Sofa,
    /// Monitors: flat or deep, three aspect ratios, stand styles; regions housing and screen.
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

    /// The two region names (id 0, id 1).
    pub fn regions(self) -> [&'static str; 2] {
        match self {
            Category::Car => ["body", "wheels"],
            Category::Chair => ["frame", "seat"],
            Category::Sofa => ["frame", "cushions"],
            Category::Monitor => ["housing", "screen"],
        }
    }

    /// Generates the shape of `seed`.
    pub fn generate(self, seed: u64) -> Mesh {
        let mut r = Draw::new(seed, 100 + self as u64);
        let mut b = Builder::new(self.regions(), format!("procedural:{}:{seed}", self.name()));
        match self {
            Category::Car => car::build(&mut b, &mut r),
            Category::Chair => chair::build(&mut b, &mut r),
            Category::Sofa => sofa::build(&mut b, &mut r),
            Category::Monitor => monitor::build(&mut b, &mut r),
        }
        b.finish()
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

    #[test]
    fn every_category_is_deterministic_varied_and_uses_both_regions() {
        for c in Category::ALL {
            for seed in 0..12 {
                let m = c.generate(seed);
                let again = c.generate(seed);
                assert_eq!(m.positions, again.positions, "{c:?} {seed}");
                assert_eq!(m.regions, c.regions().map(String::from).to_vec());
                for region in 0..2 {
                    let n = m.triangle_region.iter().filter(|&&r| r == region).count();
                    assert!(n > 10, "{c:?} {seed}: region {region} has {n} triangles");
                }
                assert!(m.positions.iter().all(|p| p.is_finite() && p.length() <= 1.0 + 1e-5));
                assert!(
                    m.corner_normals
                        .iter()
                        .flatten()
                        .all(|n| (n.length() - 1.0).abs() < 1e-4)
                );
                assert_eq!(m.degenerate_dropped, 0);
            }
            // Different seeds give different proportions.
            let bbox = |m: &Mesh| m.positions.iter().fold(glam::Vec3::ZERO, |a, p| a.max(p.abs()));
            let shapes: Vec<glam::Vec3> = (0..6).map(|s| bbox(&c.generate(s))).collect();
            assert!(
                shapes.windows(2).any(|w| (w[0] - w[1]).length() > 0.02),
                "{c:?}: {shapes:?}"
            );
        }
    }
}
