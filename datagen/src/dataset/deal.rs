//! The deal: which shapes, materials and environments each split gets. Shapes are dealt per
//! category from a seeded shuffle, materials by near-duplicate group, environments from one
//! shuffled pool; content groups (`content.rs`) are dealt whole, and explicit id lists are
//! checked against the same rules. Each shuffle has its own stream ([`stream_of`]), so adding a
//! split or a source does not reshuffle the others.

use super::catalogue::Catalogue;
use super::manifest::ManifestFile;
use matedit_assets::random::Draw;
use matedit_contract::manifest::ManifestError;
use std::collections::{BTreeMap, BTreeSet};

/// A 64-bit stream id from strings (stable across platforms and versions of this program).
pub fn stream_of(parts: &[&str]) -> u64 {
    let mut h = blake3::Hasher::new();
    for p in parts {
        h.update(p.as_bytes());
        h.update(&[0]);
    }
    let bytes = h.finalize();
    u64::from_le_bytes(bytes.as_bytes()[..8].try_into().unwrap_or([0; 8]))
}

fn shuffle<T>(items: &mut [T], draw: &mut Draw) {
    for i in (1..items.len()).rev() {
        let j = draw.int(0, i);
        items.swap(i, j);
    }
}

pub(super) fn deal_shapes(mf: &ManifestFile, cat: &Catalogue, seed: u64) -> Result<Vec<Vec<usize>>, ManifestError> {
    let splits = &mf.manifest.splits;
    let index: BTreeMap<&str, usize> = cat.shapes.iter().enumerate().map(|(i, s)| (s.id.as_str(), i)).collect();
    let mut taken: BTreeMap<usize, usize> = BTreeMap::new();
    // Content group → (split, the member it took), so a second split reaching the same group
    // through another id is named with both ids.
    let mut owner: BTreeMap<&str, (usize, usize)> = BTreeMap::new();
    let mut out = vec![Vec::new(); splits.len()];
    for (i, s) in splits.iter().enumerate() {
        for id in &s.get_ref().shape_ids {
            let &k = index.get(id.as_str()).ok_or_else(|| {
                mf.invalid(
                    s.span(),
                    &format!("splits[{i}].shape_ids"),
                    format!("{id} is not provided by any [[shapes]] source"),
                )
            })?;
            if let Some(&j) = taken.get(&k) {
                return Err(mf.invalid(
                    s.span(),
                    &format!("splits[{i}].shape_ids"),
                    format!(
                        "{id} is already in split {:?}: splits may not share a shape",
                        splits[j].get_ref().name
                    ),
                ));
            }
            let g = cat.shapes[k].group.as_str();
            if let Some(&(j, other)) = owner.get(g)
                && j != i
            {
                return Err(mf.invalid(
                    s.span(),
                    &format!("splits[{i}].shape_ids"),
                    format!(
                        "{id} and {} in split {:?} are one shape by content ({}): splits may not share a shape",
                        cat.shapes[other].id,
                        splits[j].get_ref().name,
                        why_joined(cat, "shape", &cat.shapes[other].id, id)
                    ),
                ));
            }
            owner.entry(g).or_insert((i, k));
            taken.insert(k, i);
            out[i].push(k);
        }
    }
    let categories: BTreeSet<&str> = cat.shapes.iter().map(|s| s.category.as_str()).collect();
    for c in &categories {
        // Whole groups not reached by explicit ids, in the order of their first member: a
        // catalogue without duplicates gives the same pool, shuffle and deal as single shapes.
        let mut groups: Vec<Vec<usize>> = Vec::new();
        let mut slot: BTreeMap<&str, usize> = BTreeMap::new();
        for (k, s) in cat.shapes.iter().enumerate() {
            if s.category != *c || owner.contains_key(s.group.as_str()) {
                continue;
            }
            let at = *slot.entry(s.group.as_str()).or_insert_with(|| {
                groups.push(Vec::new());
                groups.len() - 1
            });
            groups[at].push(k);
        }
        let total = cat.shapes.iter().filter(|s| s.category == *c).count();
        let pooled: usize = groups.iter().map(Vec::len).sum();
        shuffle(&mut groups, &mut Draw::new(seed, stream_of(&["shapes", c])));
        let mut next = 0;
        let mut dealt = 0;
        for (i, s) in splits.iter().enumerate() {
            if let Some(n) = s.get_ref().shapes.get(*c) {
                let want = *n.get_ref();
                let left: usize = groups[next..].iter().map(Vec::len).sum();
                if want > left {
                    return Err(mf.invalid(
                        n.span(),
                        &format!("splits[{i}].shapes.{c}"),
                        format!(
                            "asks for {want} {c} shapes but only {left} are left ({total} provided, {} taken by explicit ids or their content groups, {dealt} by earlier splits, whole groups)",
                            total - pooled
                        ),
                    ));
                }
                let mut got = 0;
                while got < want {
                    // A group dealt in part leaves its other members unused: they never go
                    // to another split.
                    for &k in &groups[next] {
                        if got < want {
                            out[i].push(k);
                            got += 1;
                        }
                    }
                    dealt += groups[next].len();
                    next += 1;
                }
            }
        }
    }
    for (i, s) in splits.iter().enumerate() {
        for (c, n) in &s.get_ref().shapes {
            if !categories.contains(c.as_str()) {
                return Err(mf.invalid(
                    n.span(),
                    &format!("splits[{i}].shapes.{c}"),
                    format!(
                        "no source provides {c:?} shapes (categories provided: {})",
                        categories.iter().copied().collect::<Vec<_>>().join(", ")
                    ),
                ));
            }
        }
        out[i].sort();
    }
    Ok(out)
}

/// Why two ids of one kind share a content group, from the recorded merges: the reason of the
/// merge that names both, else of the merges naming either (a chain), else a near-duplicate
/// name group.
fn why_joined(cat: &Catalogue, kind: &str, a: &str, b: &str) -> String {
    let of = |x: &str| {
        cat.merges
            .iter()
            .filter(|m| m.kind == kind && m.ids.iter().any(|i| i == x))
            .map(|m| m.reason.clone())
            .collect::<Vec<_>>()
    };
    if let Some(m) = cat
        .merges
        .iter()
        .find(|m| m.kind == kind && m.ids.iter().any(|i| i == a) && m.ids.iter().any(|i| i == b))
    {
        return m.reason.clone();
    }
    let mut reasons: Vec<String> = of(a).into_iter().chain(of(b)).collect();
    reasons.sort();
    reasons.dedup();
    if reasons.is_empty() {
        "near-duplicate group".into()
    } else {
        format!("joined by {}", reasons.join(", "))
    }
}

pub(super) fn deal_materials(
    mf: &ManifestFile,
    cat: &Catalogue,
    seed: u64,
    roles: &[String],
) -> Result<Vec<Vec<usize>>, ManifestError> {
    let splits = &mf.manifest.splits;
    let index: BTreeMap<&str, usize> = cat
        .materials
        .iter()
        .enumerate()
        .map(|(i, m)| (m.id.as_str(), i))
        .collect();
    // Group → (split that owns it, the member it listed first).
    let mut owner: BTreeMap<&str, (usize, usize)> = BTreeMap::new();
    let mut out = vec![Vec::new(); splits.len()];
    for (i, s) in splits.iter().enumerate() {
        for id in &s.get_ref().material_ids {
            let &k = index.get(id.as_str()).ok_or_else(|| {
                mf.invalid(
                    s.span(),
                    &format!("splits[{i}].material_ids"),
                    format!("{id} is not provided by any [[materials]] source"),
                )
            })?;
            let g = cat.materials[k].group.as_str();
            match owner.get(g) {
                Some(&(j, other)) if j != i => {
                    let other = &cat.materials[other].id;
                    return Err(mf.invalid(
                        s.span(),
                        &format!("splits[{i}].material_ids"),
                        format!(
                            "{id} (group {g}) would share its near-duplicate group with {other} in split {:?} ({}): splits may not share a material",
                            splits[j].get_ref().name,
                            why_joined(cat, "material", other, id)
                        ),
                    ));
                }
                _ => {}
            }
            if out[i].contains(&k) {
                return Err(mf.invalid(
                    s.span(),
                    &format!("splits[{i}].material_ids"),
                    format!("{id} is listed twice"),
                ));
            }
            owner.entry(g).or_insert((i, k));
            out[i].push(k);
        }
    }
    let mut groups: Vec<&str> = cat
        .materials
        .iter()
        .map(|m| m.group.as_str())
        .filter(|g| !owner.contains_key(g))
        .collect::<BTreeSet<_>>()
        .into_iter()
        .collect();
    shuffle(&mut groups, &mut Draw::new(seed, stream_of(&["materials"])));
    let mut next = 0;
    for (i, s) in splits.iter().enumerate() {
        let Some(n) = &s.get_ref().materials else { continue };
        let want = *n.get_ref();
        let mut got = 0;
        while got < want {
            let Some(g) = groups.get(next) else {
                return Err(mf.invalid(
                    n.span(),
                    &format!("splits[{i}].materials"),
                    format!(
                        "asks for {want} materials but only {got} could be drawn: the sources provide {} materials in {} near-duplicate groups, and whole groups go to one split",
                        cat.materials.len(),
                        cat.materials.iter().map(|m| &m.group).collect::<BTreeSet<_>>().len()
                    ),
                ));
            };
            next += 1;
            for (k, m) in cat.materials.iter().enumerate() {
                if m.group == *g && got < want {
                    out[i].push(k);
                    got += 1;
                }
            }
        }
    }
    for (i, s) in splits.iter().enumerate() {
        let Some(from) = &s.get_ref().materials_from else {
            continue;
        };
        let field = format!("splits[{i}].materials_from");
        let Some(j) = splits[..i].iter().position(|t| &t.get_ref().name == from) else {
            return Err(mf.invalid(s.span(), &field, format!("{from:?} is not an earlier split")));
        };
        if roles[j] != roles[i] {
            return Err(mf.invalid(
                s.span(),
                &field,
                format!(
                    "split {from:?} has role {} and this one {}: splits of different roles (train, val, test) may not share materials",
                    roles[j], roles[i]
                ),
            ));
        }
        if s.get_ref().materials.is_some() || !s.get_ref().material_ids.is_empty() {
            return Err(mf.invalid(
                s.span(),
                &field,
                "give materials_from or materials/material_ids, not both",
            ));
        }
        out[i] = out[j].clone();
    }
    // Groups may be shared only between splits of one role.
    for i in 0..splits.len() {
        for j in 0..i {
            if roles[i] == roles[j] {
                continue;
            }
            for &a in &out[i] {
                if let Some(&b) = out[j]
                    .iter()
                    .find(|&&b| cat.materials[b].group == cat.materials[a].group)
                {
                    let group = &cat.materials[a].group;
                    let (a, b) = (&cat.materials[a].id, &cat.materials[b].id);
                    return Err(mf.invalid(
                        splits[i].span(),
                        &format!("splits[{i}].material_ids"),
                        format!(
                            "{a} shares its near-duplicate group {group} with {b} in split {:?} ({}): splits may not share a material",
                            splits[j].get_ref().name,
                            why_joined(cat, "material", b, a)
                        ),
                    ));
                }
            }
        }
    }
    for o in &mut out {
        o.sort();
    }
    Ok(out)
}

pub(super) fn deal_envs(mf: &ManifestFile, cat: &Catalogue, seed: u64) -> Result<Vec<Vec<usize>>, ManifestError> {
    let splits = &mf.manifest.splits;
    let counted: Vec<_> = splits.iter().map(|s| s.get_ref().environments.as_ref()).collect();
    if counted.iter().all(Option::is_none) && splits.iter().all(|s| s.get_ref().environment_ids.is_empty()) {
        return Ok(vec![(0..cat.envs.len()).collect(); splits.len()]);
    }
    // Explicit ids first: each takes its whole group of identical maps away from the dealing
    // (the group's other members stay unused), and no group is named by two splits.
    let index: BTreeMap<&str, usize> = cat.envs.iter().enumerate().map(|(k, e)| (e.id.as_str(), k)).collect();
    let mut owner: BTreeMap<&str, (usize, usize)> = BTreeMap::new();
    let mut out: Vec<Vec<usize>> = vec![Vec::new(); splits.len()];
    for (i, s) in splits.iter().enumerate() {
        let field = format!("splits[{i}].environment_ids");
        for id in &s.get_ref().environment_ids {
            let &k = index.get(id.as_str()).ok_or_else(|| {
                mf.invalid(
                    s.span(),
                    &field,
                    format!("{id} is not provided by any [[environments]] source"),
                )
            })?;
            let g = cat.envs[k].group.as_str();
            if let Some(&(j, other)) = owner.get(g) {
                let why = if j == i && other == k {
                    format!("{id} is listed twice")
                } else {
                    format!(
                        "{id} and {} in split {:?} are one map by content (identical pixels): splits may not share an environment",
                        cat.envs[other].id,
                        splits[j].get_ref().name
                    )
                };
                return Err(mf.invalid(s.span(), &field, why));
            }
            owner.insert(g, (i, k));
            out[i].push(k);
        }
    }
    // Whole groups of identical pixels, in the order of their first member (single maps deal
    // as before).
    let mut pool: Vec<Vec<usize>> = Vec::new();
    let mut slot: BTreeMap<&str, usize> = BTreeMap::new();
    for (k, e) in cat.envs.iter().enumerate() {
        if owner.contains_key(e.group.as_str()) {
            continue;
        }
        let at = *slot.entry(e.group.as_str()).or_insert_with(|| {
            pool.push(Vec::new());
            pool.len() - 1
        });
        pool[at].push(k);
    }
    shuffle(&mut pool, &mut Draw::new(seed, stream_of(&["environments"])));
    let mut next = 0;
    for (i, (s, c)) in splits.iter().zip(&counted).enumerate() {
        let mut mine = std::mem::take(&mut out[i]);
        let Some(n) = c else {
            if !mine.is_empty() {
                mine.sort();
                out[i] = mine;
                continue;
            }
            return Err(mf.invalid(
                s.span(),
                &format!("splits[{i}].environments"),
                "when one split counts or lists its environments, every split must (environments are then split too)",
            ));
        };
        let want = *n.get_ref();
        let left: usize = pool[next..].iter().map(Vec::len).sum();
        if want > left {
            return Err(mf.invalid(
                n.span(),
                &format!("splits[{i}].environments"),
                format!(
                    "asks for {want} environments but only {left} are left of {} (identical maps go to one split)",
                    cat.envs.len()
                ),
            ));
        }
        let mut dealt = 0;
        while dealt < want {
            for &k in &pool[next] {
                if dealt < want {
                    mine.push(k);
                    dealt += 1;
                }
            }
            next += 1;
        }
        mine.sort();
        out[i] = mine;
    }
    Ok(out)
}
