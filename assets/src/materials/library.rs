//! The material library: 120 named analytic materials in seven families, from near-mirror metals
//! to matte fabrics, each with a near-duplicate group that decides its train/test split.
//!
//! | family | materials | model |
//! |---|---|---|
//! | metal | 16 metals × polished (α 0.12), brushed (0.3), rough (0.55) | GGX, Schlick F0 from measured n, k (`assets/materials/metals_f0.json`) |
//! | carpaint | 10 colours × gloss (α 0.08), satin (0.25) | plastic (coloured base + F0 0.04 coat) |
//! | plastic | 10 colours × smooth (α 0.1), matte (0.4) | plastic |
//! | rubber | 6 colours, α 0.7 | plastic |
//! | ceramic | 6 glazes, α 0.06 | plastic |
//! | fabric | 8 cloths | Lambert |
//! | wood | 6 species × raw (Lambert), varnished (plastic α 0.2) | Lambert / plastic |
//!
//! **Split**: all variants of one metal, one colour or one species share a group (they are
//! near-duplicates), and a group is in the test split when the FNV-1a hash of its name is
//! divisible by 4, so about a quarter of the groups, never part of one, are held out.

use matedit_physics::BrdfSpec;
use serde::Deserialize;

/// Train or test.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Split {
    /// Used for training.
    Train,
    /// Held out.
    Test,
}

/// One library material.
#[derive(Clone, Debug, PartialEq)]
pub struct LibraryMaterial {
    /// Unique name, e.g. `gold-brushed`.
    pub name: String,
    /// Family (metal, carpaint, ...).
    pub family: &'static str,
    /// Near-duplicate group, e.g. `metal-gold`.
    pub group: String,
    /// The source BRDF.
    pub spec: BrdfSpec,
}

impl LibraryMaterial {
    /// The split of this material's group.
    pub fn split(&self) -> Split {
        split_of(&self.group)
    }
}

/// The split of a group (FNV-1a of the name, divisible by 4 → test).
pub fn split_of(group: &str) -> Split {
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    for b in group.bytes() {
        h ^= b as u64;
        h = h.wrapping_mul(0x0000_0100_0000_01b3);
    }
    if h.is_multiple_of(4) { Split::Test } else { Split::Train }
}

#[derive(Deserialize)]
struct MetalTable {
    metals: std::collections::BTreeMap<String, Metal>,
}

#[derive(Deserialize)]
struct Metal {
    f0_rgb: [f64; 3],
}

const METALS_JSON: &str = include_str!("../../materials/metals_f0.json");

fn colours(list: &[(&str, [f64; 3])]) -> Vec<(String, [f64; 3])> {
    list.iter().map(|(n, c)| (n.to_string(), *c)).collect()
}

/// The whole library, in a fixed order.
pub fn library() -> Vec<LibraryMaterial> {
    let mut out = Vec::new();
    let mut add = |name: String, family: &'static str, group: String, spec: BrdfSpec| {
        out.push(LibraryMaterial {
            name,
            family,
            group,
            spec,
        });
    };
    // The table is compiled in and checked by a test; an unparsable table yields no metals.
    let metals: MetalTable = serde_json::from_str(METALS_JSON).unwrap_or(MetalTable {
        metals: Default::default(),
    });
    for (metal, m) in &metals.metals {
        for (finish, alpha) in [("polished", 0.12), ("brushed", 0.3), ("rough", 0.55)] {
            add(
                format!("{metal}-{finish}"),
                "metal",
                format!("metal-{metal}"),
                BrdfSpec::Ggx { alpha, f0: m.f0_rgb },
            );
        }
    }
    let paints = colours(&[
        ("red", [0.5, 0.03, 0.03]),
        ("blue", [0.03, 0.08, 0.4]),
        ("black", [0.01, 0.01, 0.012]),
        ("white", [0.8, 0.8, 0.78]),
        ("grey", [0.25, 0.26, 0.27]),
        ("green", [0.04, 0.25, 0.08]),
        ("yellow", [0.7, 0.5, 0.03]),
        ("orange", [0.7, 0.2, 0.02]),
        ("burgundy", [0.2, 0.02, 0.04]),
        ("navy", [0.015, 0.025, 0.12]),
    ]);
    for (c, albedo) in &paints {
        for (finish, alpha) in [("gloss", 0.08), ("satin", 0.25)] {
            add(
                format!("carpaint-{c}-{finish}"),
                "carpaint",
                format!("carpaint-{c}"),
                BrdfSpec::Plastic { alpha, albedo: *albedo },
            );
        }
    }
    let plastics = colours(&[
        ("white", [0.75, 0.75, 0.73]),
        ("black", [0.02, 0.02, 0.02]),
        ("red", [0.6, 0.05, 0.04]),
        ("green", [0.08, 0.45, 0.1]),
        ("blue", [0.05, 0.15, 0.6]),
        ("yellow", [0.75, 0.6, 0.05]),
        ("grey", [0.3, 0.3, 0.3]),
        ("teal", [0.03, 0.35, 0.35]),
        ("purple", [0.3, 0.06, 0.4]),
        ("pink", [0.8, 0.35, 0.45]),
    ]);
    for (c, albedo) in &plastics {
        for (finish, alpha) in [("smooth", 0.1), ("matte", 0.4)] {
            add(
                format!("plastic-{c}-{finish}"),
                "plastic",
                format!("plastic-{c}"),
                BrdfSpec::Plastic { alpha, albedo: *albedo },
            );
        }
    }
    for (c, albedo) in colours(&[
        ("black", [0.03, 0.03, 0.03]),
        ("grey", [0.15, 0.15, 0.15]),
        ("red", [0.3, 0.04, 0.03]),
        ("blue", [0.04, 0.08, 0.25]),
        ("green", [0.05, 0.2, 0.06]),
        ("white", [0.55, 0.55, 0.52]),
    ]) {
        add(
            format!("rubber-{c}"),
            "rubber",
            format!("rubber-{c}"),
            BrdfSpec::Plastic { alpha: 0.7, albedo },
        );
    }
    for (c, albedo) in colours(&[
        ("white", [0.8, 0.8, 0.78]),
        ("celadon", [0.35, 0.5, 0.4]),
        ("cobalt", [0.05, 0.12, 0.5]),
        ("terracotta", [0.55, 0.2, 0.08]),
        ("black", [0.02, 0.02, 0.02]),
        ("cream", [0.75, 0.65, 0.45]),
    ]) {
        add(
            format!("ceramic-{c}"),
            "ceramic",
            format!("ceramic-{c}"),
            BrdfSpec::Plastic { alpha: 0.06, albedo },
        );
    }
    for (c, albedo) in colours(&[
        ("linen", [0.6, 0.55, 0.45]),
        ("denim", [0.08, 0.12, 0.25]),
        ("velvet-red", [0.3, 0.02, 0.04]),
        ("felt-green", [0.08, 0.25, 0.1]),
        ("wool-grey", [0.3, 0.3, 0.28]),
        ("canvas", [0.5, 0.45, 0.33]),
        ("cotton-black", [0.025, 0.025, 0.03]),
        ("mustard", [0.55, 0.4, 0.05]),
    ]) {
        add(
            format!("fabric-{c}"),
            "fabric",
            format!("fabric-{c}"),
            BrdfSpec::Lambert(albedo),
        );
    }
    for (s, albedo) in colours(&[
        ("oak", [0.45, 0.3, 0.16]),
        ("walnut", [0.2, 0.11, 0.06]),
        ("pine", [0.6, 0.45, 0.25]),
        ("cherry", [0.4, 0.16, 0.08]),
        ("maple", [0.65, 0.5, 0.32]),
        ("ebony", [0.04, 0.03, 0.025]),
    ]) {
        add(
            format!("wood-{s}-raw"),
            "wood",
            format!("wood-{s}"),
            BrdfSpec::Lambert(albedo),
        );
        add(
            format!("wood-{s}-varnished"),
            "wood",
            format!("wood-{s}"),
            BrdfSpec::Plastic { alpha: 0.2, albedo },
        );
    }
    out
}

/// A library material by name, or an error listing how to see the names.
pub fn find(name: &str) -> anyhow::Result<LibraryMaterial> {
    library().into_iter().find(|m| m.name == name).ok_or_else(|| {
        anyhow::anyhow!("library:{name}: no such material (list them with `datagen assets materials --list`)")
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_library_is_large_unique_valid_and_split_by_group() {
        let lib = library();
        assert!(lib.len() >= 100, "{} materials", lib.len());
        let names: std::collections::BTreeSet<_> = lib.iter().map(|m| &m.name).collect();
        assert_eq!(names.len(), lib.len(), "names are unique");
        assert_eq!(
            lib.iter().filter(|m| m.family == "metal").count(),
            48,
            "16 metals from the measured table"
        );
        for m in &lib {
            m.spec.build().unwrap_or_else(|e| panic!("{}: {e}", m.name));
        }
        // Every group is entirely in one split, and both splits are used.
        let test = lib.iter().filter(|m| m.split() == Split::Test).count();
        assert!(test > 10 && test < lib.len() / 2, "{test} test materials");
        for a in &lib {
            for b in &lib {
                if a.group == b.group {
                    assert_eq!(a.split(), b.split());
                }
            }
        }
        assert_eq!(
            find("gold-brushed").unwrap().spec,
            BrdfSpec::Ggx {
                alpha: 0.3,
                f0: [0.9411, 0.7974, 0.4027]
            }
        );
        assert!(find("unobtainium").is_err());
    }
}
