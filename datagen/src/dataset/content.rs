//! Content fingerprints and content groups: split integrity by what a shape, material or
//! environment *is*, not by what it is called.
//!
//! A `folder` source holding one OBJ under two names, a `dsbrdf` folder holding one material
//! twice, or ShapeNet's many re-uploaded models would otherwise put the same content on both
//! sides of a train/test boundary. Every catalogue item gets a fingerprint, items with equal
//! fingerprints (and, for shapes, near-duplicates by a coarse surface descriptor) are joined
//! into one group, and the plan deals whole groups, exactly as it deals the library's
//! near-duplicate material groups.
//!
//! * **Shapes** (scheme `shape-v1`): the mesh as the project's loader gives it in the file's own
//!   frame (bounding-box centre at the origin, farthest used vertex at distance 1: a rotation-free
//!   normalisation, so translation and uniform scale drop out), vertices rounded to a grid of
//!   [`SHAPE_QUANTUM`], each triangle written from its smallest vertex onwards (the cyclic order,
//!   hence the winding, is kept), triangles sorted, then hashed with blake3. File names,
//!   comments, groups, materials, normals, texture coordinates, vertex order and face order do not
//!   enter. Byte-identical and reordered files give identical bits after normalisation, so they
//!   always match; a translated or rescaled copy written with finite decimal precision differs by
//!   f32 rounding (about 1e-7 of the radius), and a vertex that lands within that of a rounding
//!   boundary changes the hash. No grid avoids that for every mesh, so such copies, and copies with
//!   small vertex jitter, are caught by the near-duplicate descriptor instead (reported as
//!   near-duplicates).
//! * **Near-duplicate shapes**: the surface area distribution on a 17³ lattice over the unit
//!   ball (each triangle sampled on a sub-triangle grid finer than half a cell, each sample spread
//!   trilinearly to the 8 surrounding nodes, so moving a vertex moves mass continuously), as
//!   fractions of the total area. Two shapes of one category whose descriptors differ by less
//!   than [`NEAR_DUPLICATE_L1`] in L1 (total variation, 0 to 2) are near-duplicates. Random
//!   vertex jitter of 0.1 % of the radius moves the descriptor by at most 0.006 (0.3 %: 0.03) on
//!   the procedural shapes; the closest two of 100 procedural shapes of one category are 0.067
//!   apart (monitors; cars 0.12, sofas 0.14, chairs 0.21; `tests/split_content/`). Merging two
//!   genuinely different but very similar shapes costs the deal one choice, never a leak.
//! * **Materials**: library materials from their analytic parameters (model and f64 bits),
//!   DSBRDF files from their 108 parameters (f64 bits, so formatting and key order do not matter),
//!   MERL files from their bytes (dimensions and table values: the format holds nothing else).
//! * **Environments**, only when splits deal them: the decoded texels (size and f32 bits).

use super::catalogue::{Catalogue, MaterialSource};
use super::manifest::ManifestFile;
use crate::shapes::{Mesh, Shape, UpAxis};
use matedit_contract::manifest::ManifestError;
use matedit_contract::records::Merge;
use matedit_physics::BrdfSpec;
use matedit_physics::brdf::Dsbrdf;
use matedit_physics::envmap::EnvMap;
use rayon::prelude::*;
use std::collections::BTreeMap;

/// Names the fingerprint definitions recorded in `dataset.json`; a change of any definition
/// gets a new name, so recorded fingerprints are only ever compared with their own kind.
pub const SCHEME: &str = "shape-v1 material-v1 environment-v1";

/// Rounding grid of the shape fingerprint, in units of the normalised radius. Coarse enough that
/// f32 rounding (1e-7) rarely crosses a boundary (per coordinate about 2e-4 of the time), fine
/// enough (1 mm on a 2 m car) that only geometry the renderer cannot tell apart collides.
pub const SHAPE_QUANTUM: f64 = 1.0 / 1024.0;

/// Lattice intervals per axis of the near-duplicate descriptor over [−1, 1] (cell 0.125).
pub const DESCRIPTOR_CELLS: usize = 16;

/// L1 distance below which two shapes of a category are near-duplicates.
pub const NEAR_DUPLICATE_L1: f64 = 0.03;

/// `blake3:HEX` of the shape fingerprint of a loaded (normalised) mesh.
pub fn mesh_fingerprint(mesh: &Mesh) -> String {
    let q = |i: u32| {
        let p = mesh.positions[i as usize].as_dvec3() / SHAPE_QUANTUM;
        [p.x.round() as i32, p.y.round() as i32, p.z.round() as i32]
    };
    let mut tris: Vec<[[i32; 3]; 3]> = mesh
        .triangles
        .iter()
        .map(|t| {
            let v = t.map(q);
            // The smallest of the three rotations: a canonical start that keeps the winding.
            [v, [v[1], v[2], v[0]], [v[2], v[0], v[1]]]
                .into_iter()
                .min()
                .unwrap_or(v)
        })
        .collect();
    tris.sort_unstable();
    let mut h = blake3::Hasher::new();
    h.update(b"shape-v1");
    h.update(&(tris.len() as u64).to_le_bytes());
    for t in &tris {
        for v in t {
            for c in v {
                h.update(&c.to_le_bytes());
            }
        }
    }
    format!("blake3:{}", h.finalize().to_hex())
}

/// The near-duplicate descriptor of a loaded (normalised) mesh: area fractions on the
/// (`DESCRIPTOR_CELLS` + 1)³ lattice nodes.
pub fn mesh_descriptor(mesh: &Mesh) -> Vec<f32> {
    let g = DESCRIPTOR_CELLS;
    let n1 = g + 1;
    let cell = 2.0 / g as f64;
    let mut acc = vec![0.0f64; n1 * n1 * n1];
    let mut splat = |p: glam::DVec3, w: f64| {
        let mut idx = [0usize; 3];
        let mut frac = [0.0f64; 3];
        for (k, c) in p.to_array().into_iter().enumerate() {
            let x = ((c + 1.0) / cell).clamp(0.0, g as f64);
            let i = (x.floor() as usize).min(g - 1);
            idx[k] = i;
            frac[k] = x - i as f64;
        }
        for corner in 0..8 {
            let mut wt = w;
            let mut at = 0;
            for k in 0..3 {
                let up = (corner >> k) & 1;
                wt *= if up == 1 { frac[k] } else { 1.0 - frac[k] };
                at = at * n1 + idx[k] + up;
            }
            acc[at] += wt;
        }
    };
    for t in &mesh.triangles {
        let [a, b, c] = t.map(|i| mesh.positions[i as usize].as_dvec3());
        let (e1, e2) = (b - a, c - a);
        let area = 0.5 * e1.cross(e2).length();
        if area <= 0.0 || !area.is_finite() {
            continue;
        }
        let longest = e1.length().max(e2.length()).max((c - b).length());
        // Sub-triangles no longer than half a cell, so a sample stands for a patch that the
        // trilinear spread treats as a point.
        let n = ((longest / (0.5 * cell)).ceil() as usize).clamp(1, 64);
        let w = area / (n * n) as f64;
        let nf = n as f64;
        for i in 0..n {
            for j in 0..n - i {
                let (u, v) = ((i as f64 + 1.0 / 3.0) / nf, (j as f64 + 1.0 / 3.0) / nf);
                splat(a + e1 * u + e2 * v, w);
                if i + j + 1 < n {
                    let (u, v) = ((i as f64 + 2.0 / 3.0) / nf, (j as f64 + 2.0 / 3.0) / nf);
                    splat(a + e1 * u + e2 * v, w);
                }
            }
        }
    }
    let total: f64 = acc.iter().sum();
    let scale = if total > 0.0 { 1.0 / total } else { 0.0 };
    acc.into_iter().map(|x| (x * scale) as f32).collect()
}

/// L1 distance of two descriptors (0: same area distribution, 2: disjoint).
pub fn descriptor_distance(a: &[f32], b: &[f32]) -> f64 {
    a.iter().zip(b).map(|(x, y)| (*x as f64 - *y as f64).abs()).sum()
}

/// Sums of the descriptor over blocks of 5×5×5 nodes: a lower bound of the L1 distance (merging
/// bins never increases it) that rules most pairs out at 1/64 of the cost.
fn coarse(d: &[f32]) -> [f64; 64] {
    let n1 = DESCRIPTOR_CELLS + 1;
    let mut out = [0.0; 64];
    for x in 0..n1 {
        for y in 0..n1 {
            for z in 0..n1 {
                let b = ((x / 5).min(3) * 4 + (y / 5).min(3)) * 4 + (z / 5).min(3);
                out[b] += d[(x * n1 + y) * n1 + z] as f64;
            }
        }
    }
    out
}

fn hash_f64s(kind: &str, values: &[f64]) -> String {
    let mut h = blake3::Hasher::new();
    h.update(kind.as_bytes());
    h.update(&[0]);
    for v in values {
        // −0 and +0 are the same parameter.
        let v = if *v == 0.0 { 0.0 } else { *v };
        h.update(&v.to_bits().to_le_bytes());
    }
    format!("blake3:{}", h.finalize().to_hex())
}

/// The parameter fingerprint of a material.
pub fn material_fingerprint(source: &MaterialSource) -> Result<String, String> {
    match source {
        MaterialSource::Analytic(spec) => Ok(match spec {
            BrdfSpec::Lambert(c) => hash_f64s("material-v1 lambert", c),
            BrdfSpec::Ggx { alpha, f0 } => hash_f64s("material-v1 ggx", &[*alpha, f0[0], f0[1], f0[2]]),
            BrdfSpec::Plastic { alpha, albedo } => {
                hash_f64s("material-v1 plastic", &[*alpha, albedo[0], albedo[1], albedo[2]])
            }
            // Not produced by the library or the parametric families today; the spec's text is still a parameter list.
            other => {
                let mut h = blake3::Hasher::new();
                h.update(b"material-v1 spec\0");
                h.update(format!("{other:?}").as_bytes());
                format!("blake3:{}", h.finalize().to_hex())
            }
        }),
        MaterialSource::Dsbrdf(path) => {
            let m = Dsbrdf::load(path).map_err(|e| format!("{}: {e}", path.display()))?;
            Ok(hash_f64s("material-v1 dsbrdf", m.params()))
        }
        MaterialSource::Merl(path) => file_fingerprint(b"material-v1 merl\0", path),
        MaterialSource::Nbrdf(path) => file_fingerprint(b"material-v1 nbrdf\0", path),
    }
}

/// A measured material's fingerprint: its file's bytes under a tag naming the format.
fn file_fingerprint(tag: &[u8], path: &std::path::Path) -> Result<String, String> {
    let bytes = std::fs::read(path).map_err(|e| format!("{}: {e}", path.display()))?;
    let mut h = blake3::Hasher::new();
    h.update(tag);
    h.update(&bytes);
    Ok(format!("blake3:{}", h.finalize().to_hex()))
}

/// The pixel fingerprint of a decoded environment map.
pub fn env_fingerprint(map: &EnvMap) -> String {
    let mut h = blake3::Hasher::new();
    h.update(b"environment-v1");
    h.update(&(map.width() as u64).to_le_bytes());
    h.update(&(map.height() as u64).to_le_bytes());
    for t in map.texels() {
        for c in t {
            h.update(&c.to_bits().to_le_bytes());
        }
    }
    format!("blake3:{}", h.finalize().to_hex())
}

/// Union–find whose representative is always the smallest index, so groups do not depend on
/// the order unions happen in.
struct Sets(Vec<usize>);

impl Sets {
    fn new(n: usize) -> Sets {
        Sets((0..n).collect())
    }
    fn find(&mut self, mut i: usize) -> usize {
        while self.0[i] != i {
            self.0[i] = self.0[self.0[i]];
            i = self.0[i];
        }
        i
    }
    /// Joins the sets of `a` and `b`; false when they were one already.
    fn union(&mut self, a: usize, b: usize) -> bool {
        let (ra, rb) = (self.find(a), self.find(b));
        if ra == rb {
            return false;
        }
        let (lo, hi) = (ra.min(rb), ra.max(rb));
        self.0[hi] = lo;
        true
    }
}

/// Fingerprints every shape and material of `cat` (and its environments when `envs_dealt`),
/// joins identical content into groups (materials: together with their near-duplicate name
/// groups) and records the merges. Without duplicates every group is what it was, so the deal is
/// unchanged. A source that cannot be read is an error naming its manifest entry.
pub fn analyse(mf: &ManifestFile, cat: &mut Catalogue, envs_dealt: bool) -> Result<(), ManifestError> {
    let m = &mf.manifest;
    let entry_span = |list_span: Option<std::ops::Range<usize>>| list_span.unwrap_or(0..0);

    // Shapes: load in parallel (rayon keeps the order), fingerprint and describe.
    type Loaded = (String, Vec<f32>, Vec<String>);
    let loaded: Vec<Result<Loaded, String>> = cat
        .shapes
        .par_iter()
        .map(|s| match Shape::load(&s.spec, UpAxis::PosY) {
            Ok(Shape::Mesh(mesh)) => Ok((mesh_fingerprint(&mesh), mesh_descriptor(&mesh), mesh.regions.clone())),
            Ok(Shape::Sphere) => Ok((format!("sphere:{}", s.spec), Vec::new(), vec!["object".into()])),
            Err(e) => Err(e.to_string()),
        })
        .collect();
    let mut descriptors = Vec::with_capacity(loaded.len());
    for (s, r) in cat.shapes.iter_mut().zip(loaded) {
        match r {
            Ok((fp, d, regions)) => {
                s.fingerprint = fp;
                s.regions = regions;
                descriptors.push(d);
            }
            Err(e) => {
                let field = if s.spec.starts_with("procedural:") {
                    format!("shapes[{}]", s.entry)
                } else {
                    format!("shapes[{}].path", s.entry)
                };
                let span = entry_span(m.shapes.get(s.entry).map(|e| e.span()));
                return Err(mf.invalid(span, &field, format!("{}: cannot fingerprint: {e}", s.id)));
            }
        }
    }
    let n = cat.shapes.len();
    let mut sets = Sets::new(n);
    let mut merges = Vec::new();
    let mut by_fp: BTreeMap<&str, Vec<usize>> = BTreeMap::new();
    for (k, s) in cat.shapes.iter().enumerate() {
        by_fp.entry(s.fingerprint.as_str()).or_default().push(k);
    }
    let mut edges: Vec<(usize, usize, String)> = Vec::new();
    for members in by_fp.values() {
        for &k in &members[1..] {
            edges.push((members[0], k, "identical geometry".into()));
        }
    }
    for (a, b, why) in edges {
        if cat.shapes[a].category != cat.shapes[b].category {
            let s = &cat.shapes[b];
            let span = entry_span(m.shapes.get(s.entry).map(|e| e.span()));
            return Err(mf.invalid(
                span,
                &format!("shapes[{}].path", s.entry),
                format!(
                    "{} ({}) has identical geometry to {} ({}): one shape cannot be in two categories; remove one of the files",
                    s.id, s.category, cat.shapes[a].id, cat.shapes[a].category
                ),
            ));
        }
        if sets.union(a, b) {
            merges.push(Merge {
                kind: "shape".into(),
                ids: vec![cat.shapes[a].id.clone(), cat.shapes[b].id.clone()],
                reason: why,
            });
        }
    }
    let coarse_of: Vec<Option<[f64; 64]>> = descriptors.iter().map(|d| (!d.is_empty()).then(|| coarse(d))).collect();
    // Pairs within a category, in catalogue order; the distances are computed in parallel but
    // the unions happen in order, so the groups and the report are deterministic.
    let near: Vec<Vec<(usize, f64)>> = (0..n)
        .into_par_iter()
        .map(|i| {
            let Some(ci) = &coarse_of[i] else { return Vec::new() };
            (i + 1..n)
                .filter(|&j| cat.shapes[j].category == cat.shapes[i].category)
                .filter_map(|j| {
                    let cj = coarse_of[j].as_ref()?;
                    let lower: f64 = ci.iter().zip(cj).map(|(a, b)| (a - b).abs()).sum();
                    if lower >= NEAR_DUPLICATE_L1 {
                        return None;
                    }
                    let d = descriptor_distance(&descriptors[i], &descriptors[j]);
                    (d < NEAR_DUPLICATE_L1).then_some((j, d))
                })
                .collect()
        })
        .collect();
    for (i, list) in near.into_iter().enumerate() {
        for (j, d) in list {
            if sets.union(i, j) {
                merges.push(Merge {
                    kind: "shape".into(),
                    ids: vec![cat.shapes[i].id.clone(), cat.shapes[j].id.clone()],
                    reason: format!("near-duplicate geometry (L1 {d:.4})"),
                });
            }
        }
    }
    for k in 0..n {
        let r = sets.find(k);
        cat.shapes[k].group = cat.shapes[r].id.clone();
    }

    // Materials: parameter fingerprints, joined with the name groups.
    let fps: Vec<Result<String, String>> = cat
        .materials
        .par_iter()
        .map(|mat| material_fingerprint(&mat.source))
        .collect();
    for (mat, fp) in cat.materials.iter_mut().zip(fps) {
        match fp {
            Ok(fp) => mat.fingerprint = fp,
            Err(e) => {
                let span = entry_span(m.materials.get(mat.entry).map(|e| e.span()));
                return Err(mf.invalid(
                    span,
                    &format!("materials[{}].path", mat.entry),
                    format!("{}: cannot fingerprint: {e}", mat.id),
                ));
            }
        }
    }
    let n = cat.materials.len();
    let mut sets = Sets::new(n);
    let mut first_of_group: BTreeMap<&str, usize> = BTreeMap::new();
    let mut first_of_fp: BTreeMap<&str, usize> = BTreeMap::new();
    for (k, mat) in cat.materials.iter().enumerate() {
        let g = *first_of_group.entry(mat.group.as_str()).or_insert(k);
        sets.union(g, k);
    }
    for (k, mat) in cat.materials.iter().enumerate() {
        let f = *first_of_fp.entry(mat.fingerprint.as_str()).or_insert(k);
        if sets.union(f, k) {
            merges.push(Merge {
                kind: "material".into(),
                ids: vec![cat.materials[f].id.clone(), mat.id.clone()],
                reason: "identical parameters".into(),
            });
        }
    }
    // A joined group is named by its smallest name group, so groups without content merges
    // keep their names (and the deal its order).
    let mut name_of: BTreeMap<usize, String> = BTreeMap::new();
    for k in 0..n {
        let r = sets.find(k);
        let g = &cat.materials[k].group;
        let e = name_of.entry(r).or_insert_with(|| g.clone());
        if g < e {
            *e = g.clone();
        }
    }
    for k in 0..n {
        let r = sets.find(k);
        cat.materials[k].group = name_of[&r].clone();
    }

    // Environments: only when splits deal them (otherwise every split sees every map).
    if envs_dealt {
        let fps: Vec<Result<String, String>> = cat
            .envs
            .par_iter()
            .map(|e| {
                matedit_assets::envfile::load_env(&e.spec)
                    .map(|(map, _)| env_fingerprint(&map))
                    .map_err(|err| format!("{err:#}"))
            })
            .collect();
        for (env, fp) in cat.envs.iter_mut().zip(fps) {
            match fp {
                Ok(fp) => env.fingerprint = fp,
                Err(e) => {
                    let span = entry_span(m.environments.get(env.entry).map(|e| e.span()));
                    return Err(mf.invalid(
                        span,
                        &format!("environments[{}].path", env.entry),
                        format!("{}: cannot fingerprint: {e}", env.id),
                    ));
                }
            }
        }
        let mut first_of_fp: BTreeMap<String, usize> = BTreeMap::new();
        for k in 0..cat.envs.len() {
            let f = *first_of_fp.entry(cat.envs[k].fingerprint.clone()).or_insert(k);
            cat.envs[k].group = cat.envs[f].id.clone();
            if f != k {
                merges.push(Merge {
                    kind: "environment".into(),
                    ids: vec![cat.envs[f].id.clone(), cat.envs[k].id.clone()],
                    reason: "identical pixels".into(),
                });
            }
        }
    }
    cat.merges = merges;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::shapes::procedural::Category;

    #[test]
    fn rotating_a_triangle_keeps_the_fingerprint_but_flipping_it_does_not() {
        let mesh = |tris: Vec<[u32; 3]>| {
            let mut m = Category::Car.generate(0);
            m.triangles = tris;
            m
        };
        let base = Category::Car.generate(0);
        let rotated = mesh(base.triangles.iter().map(|t| [t[1], t[2], t[0]]).rev().collect());
        let flipped = mesh(base.triangles.iter().map(|t| [t[0], t[2], t[1]]).collect());
        assert_eq!(mesh_fingerprint(&base), mesh_fingerprint(&rotated));
        assert_ne!(mesh_fingerprint(&base), mesh_fingerprint(&flipped));
    }

    #[test]
    fn union_find_names_groups_by_their_smallest_member() {
        let mut s = Sets::new(5);
        assert!(s.union(4, 2));
        assert!(s.union(3, 4));
        assert!(!s.union(2, 3));
        assert_eq!((s.find(3), s.find(4), s.find(0)), (2, 2, 0));
    }
}
