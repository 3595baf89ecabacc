//! Where shapes come from, each with a stable id: a ShapeNet-layout tree, a plain folder of OBJ
//! files, or the procedural generators.
//!
//! | source | id | path |
//! |---|---|---|
//! | ShapeNet v2 | `shapenet:<synset>/<model_id>` | `<root>/<synset>/<model_id>/models/model_normalized.obj` |
//! | folder | `folder:<path relative to the folder, without .obj>` | any `*.obj` below the folder |
//! | procedural | `procedural:<category>:<seed>` | generated |
//!
//! Ids depend only on names inside the source, never on where it is mounted, so the same
//! dataset built on two machines names its shapes identically. Entries are sorted by id.

use super::procedural::Category;
use anyhow::{Context, Result, bail};
use std::path::Path;

/// ShapeNet synset ids of the paper's four categories.
pub const SHAPENET_SYNSETS: [(Category, &str); 4] = [
    (Category::Car, "02958343"),
    (Category::Chair, "03001627"),
    (Category::Sofa, "04256520"),
    (Category::Monitor, "03211117"),
];

/// One shape of a source.
#[derive(Clone, Debug, PartialEq, Eq, PartialOrd, Ord)]
pub struct ShapeEntry {
    /// Stable id.
    pub id: String,
    /// Category, where the source knows it.
    pub category: Option<Category>,
    /// What `Shape::load` accepts: a file path or `procedural:…`.
    pub spec: String,
}

/// The shapes of a ShapeNet v2 tree, for the given categories (all four when empty). A synset
/// folder that is absent is skipped; a model folder without `models/model_normalized.obj` is an
/// error naming it.
pub fn shapenet(root: &Path, categories: &[Category]) -> Result<Vec<ShapeEntry>> {
    if !root.is_dir() {
        bail!("ShapeNet root {} is not a directory", root.display());
    }
    let mut out = Vec::new();
    for (cat, synset) in SHAPENET_SYNSETS {
        if !categories.is_empty() && !categories.contains(&cat) {
            continue;
        }
        let dir = root.join(synset);
        if !dir.is_dir() {
            continue;
        }
        for e in std::fs::read_dir(&dir).with_context(|| format!("cannot list {}", dir.display()))? {
            let model = e?.path();
            if !model.is_dir() {
                continue;
            }
            let obj = model.join("models").join("model_normalized.obj");
            if !obj.is_file() {
                bail!(
                    "{}: no models/model_normalized.obj (not a ShapeNet v2 model folder)",
                    model.display()
                );
            }
            let id = model
                .file_name()
                .map(|n| n.to_string_lossy().into_owned())
                .unwrap_or_default();
            out.push(ShapeEntry {
                id: format!("shapenet:{synset}/{id}"),
                category: Some(cat),
                spec: path_spec(&obj)?,
            });
        }
    }
    out.sort();
    Ok(out)
}

/// Every `*.obj` below `dir` (recursively), with its category when `category` is given.
pub fn folder(dir: &Path, category: Option<Category>) -> Result<Vec<ShapeEntry>> {
    if !dir.is_dir() {
        bail!("shape folder {} is not a directory", dir.display());
    }
    let mut out = Vec::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        for e in std::fs::read_dir(&d).with_context(|| format!("cannot list {}", d.display()))? {
            let p = e?.path();
            if p.is_dir() {
                stack.push(p);
            } else if p.extension().is_some_and(|x| x.eq_ignore_ascii_case("obj")) {
                let rel = p.strip_prefix(dir).unwrap_or(&p).with_extension("");
                let rel = rel
                    .components()
                    .map(|c| c.as_os_str().to_string_lossy())
                    .collect::<Vec<_>>()
                    .join("/");
                out.push(ShapeEntry {
                    id: format!("folder:{rel}"),
                    category,
                    spec: path_spec(&p)?,
                });
            }
        }
    }
    out.sort();
    Ok(out)
}

/// `count` procedural shapes of `category` from seed `first`.
pub fn procedural(category: Category, first: u64, count: usize) -> Vec<ShapeEntry> {
    (first..first + count as u64)
        .map(|s| {
            let id = format!("procedural:{}:{s}", category.name());
            ShapeEntry {
                id: id.clone(),
                category: Some(category),
                spec: id,
            }
        })
        .collect()
}

fn path_spec(p: &Path) -> Result<String> {
    p.to_str()
        .map(str::to_string)
        .with_context(|| format!("{} is not valid UTF-8", p.display()))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shapenet_and_folder_sources_give_stable_sorted_ids() {
        let root = std::env::temp_dir().join(format!("matedit-sources-{}", std::process::id()));
        let obj = "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n";
        for (syn, id) in [
            ("03001627", "b"),
            ("03001627", "a"),
            ("02958343", "c"),
            ("99999999", "x"),
        ] {
            let d = root.join("sn").join(syn).join(id).join("models");
            std::fs::create_dir_all(&d).unwrap();
            std::fs::write(d.join("model_normalized.obj"), obj).unwrap();
        }
        let all = shapenet(&root.join("sn"), &[]).unwrap();
        let ids: Vec<&str> = all.iter().map(|e| e.id.as_str()).collect();
        assert_eq!(
            ids,
            ["shapenet:02958343/c", "shapenet:03001627/a", "shapenet:03001627/b"]
        );
        assert_eq!(all[0].category, Some(Category::Car));
        assert_eq!(shapenet(&root.join("sn"), &[Category::Chair]).unwrap().len(), 2);
        // A model folder without the mesh is named.
        std::fs::create_dir_all(root.join("sn/03001627/broken")).unwrap();
        assert!(
            shapenet(&root.join("sn"), &[])
                .unwrap_err()
                .to_string()
                .contains("broken")
        );

        let f = root.join("plain");
        std::fs::create_dir_all(f.join("sub")).unwrap();
        std::fs::write(f.join("sub/Chair1.OBJ"), obj).unwrap();
        std::fs::write(f.join("b.obj"), obj).unwrap();
        std::fs::write(f.join("notes.txt"), "x").unwrap();
        let ids: Vec<String> = folder(&f, None).unwrap().into_iter().map(|e| e.id).collect();
        assert_eq!(ids, ["folder:b", "folder:sub/Chair1"]);
        assert!(folder(&root.join("missing"), None).is_err());
        assert_eq!(procedural(Category::Sofa, 5, 2)[1].id, "procedural:sofa:6");
    }
}
