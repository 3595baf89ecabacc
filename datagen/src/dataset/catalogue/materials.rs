//! The catalogue's materials: the library's named materials, the parametric families' drawn
//! ones, and the files of DSBRDF, MERL and neural-BRDF folders.

use super::{Catalogue, Entry, MaterialItem, MaterialSource};
use crate::dataset::manifest::{IfMissing, ManifestFile, MaterialSource as MaterialSourceName, MaterialSourceToml};
use matedit_assets::materials::library::library;
use matedit_assets::materials::parametric::ParametricFamily;
use matedit_contract::manifest::{ManifestError, Named};
use std::collections::BTreeSet;
use std::path::Path;
use toml::Spanned;

/// `parametric:FAMILY:SEED` for seeds `first ..`, each its own group (two draws are never one
/// material's near-duplicates; identical parameters would still be joined by content).
fn parametric_items(family: ParametricFamily, first: u64, count: usize) -> impl Iterator<Item = MaterialItem> {
    (first..first + count as u64).map(move |seed| {
        let id = format!("parametric:{}:{seed}", family.name());
        MaterialItem {
            group: id.clone(),
            id,
            source: MaterialSource::Analytic(family.spec(seed)),
            fingerprint: String::new(),
            entry: 0,
        }
    })
}

/// MERL names differ by a trailing digit for near-duplicates (`blue-metallic-paint2`), so the
/// group drops trailing digits.
pub fn merl_group(name: &str) -> String {
    format!("merl:{}", name.trim_end_matches(|c: char| c.is_ascii_digit()))
}

fn library_items(names: Option<&Vec<String>>, families: Option<&Vec<String>>) -> Result<Vec<MaterialItem>, String> {
    let lib = library();
    let known_families: BTreeSet<&str> = lib.iter().map(|m| m.family).collect();
    if let Some(fs) = families {
        for f in fs {
            if !known_families.contains(f.as_str()) {
                return Err(format!(
                    "unknown family {f:?} (known: {})",
                    known_families.iter().copied().collect::<Vec<_>>().join(", ")
                ));
            }
        }
    }
    if let Some(ns) = names {
        for n in ns {
            if n != "*" && !lib.iter().any(|m| &m.name == n) {
                return Err(format!(
                    "no library material {n:?} (list them with `datagen assets materials --list`)"
                ));
            }
        }
    }
    let all = names.is_none() && families.is_none() || names.is_some_and(|n| n.iter().any(|x| x == "*"));
    Ok(lib
        .into_iter()
        .filter(|m| {
            all || names.is_some_and(|n| n.contains(&m.name))
                || families.is_some_and(|f| f.iter().any(|x| x == m.family))
        })
        .map(|m| MaterialItem {
            id: format!("library:{}", m.name),
            group: format!("library:{}", m.group),
            source: MaterialSource::Analytic(m.spec),
            fingerprint: String::new(),
            entry: 0,
        })
        .collect())
}

fn stem(p: &Path, suffix: &str) -> String {
    let n = p
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    n.strip_suffix(suffix).unwrap_or(&n).to_string()
}

pub(super) fn materials_of(
    mf: &ManifestFile,
    cat: &mut Catalogue,
    i: usize,
    entry: &Spanned<MaterialSourceToml>,
) -> Result<(), ManifestError> {
    let s = entry.get_ref();
    let e = Entry {
        mf,
        span: entry.span(),
        field: format!("materials[{i}]"),
    };
    let kind = mf.choice(&s.source, &format!("{}.source", e.field))?;
    match kind {
        MaterialSourceName::Library => {
            e.not_for(
                "library",
                &[
                    ("origin", s.origin.is_some()),
                    ("licence", s.licence.is_some()),
                    ("path", s.path.is_some()),
                    ("if_missing", s.if_missing.is_some()),
                    ("count", s.count.is_some()),
                    ("first_seed", s.first_seed.is_some()),
                ],
            )?;
            let items = library_items(s.names.as_ref(), s.families.as_ref()).map_err(|err| e.invalid("names", err))?;
            cat.materials.extend(items);
        }
        MaterialSourceName::Parametric => {
            e.not_for(
                "parametric",
                &[
                    ("origin", s.origin.is_some()),
                    ("licence", s.licence.is_some()),
                    ("names", s.names.is_some()),
                    ("path", s.path.is_some()),
                    ("if_missing", s.if_missing.is_some()),
                ],
            )?;
            let families = e.required("families", s.families.as_ref(), "required: plastic, metal or both")?;
            if families.is_empty() {
                return Err(e.invalid("families", "empty: name plastic, metal or both"));
            }
            let first = s.first_seed.unwrap_or(0);
            let count = e.generated_count("count", s.count.as_ref(), first, "required: materials per family")?;
            for name in families {
                let family = ParametricFamily::parse(name).ok_or_else(|| {
                    e.invalid(
                        "families",
                        format!("unknown parametric family {name:?} (plastic or metal)"),
                    )
                })?;
                cat.materials.extend(parametric_items(family, first, count));
            }
        }
        MaterialSourceName::Dsbrdf | MaterialSourceName::Merl | MaterialSourceName::Nbrdf => {
            e.not_for(
                kind.name(),
                &[
                    ("names", s.names.is_some()),
                    ("families", s.families.is_some()),
                    ("count", s.count.is_some()),
                    ("first_seed", s.first_seed.is_some()),
                ],
            )?;
            let suffix = match kind {
                MaterialSourceName::Dsbrdf => ".dsbrdf.json",
                MaterialSourceName::Nbrdf => ".nbrdf.json",
                _ => ".binary",
            };
            match e.existing_path(s.path.as_ref(), s.if_missing.as_ref(), IfMissing::Library)? {
                Some(path) => {
                    let files = e.files_with(&path, suffix)?;
                    if files.is_empty() {
                        return Err(e.invalid("path", format!("{} holds no *{suffix} file", path.display())));
                    }
                    for f in files {
                        let name = stem(&f, suffix);
                        // A MERL material as a table and as a network shares one group, so that
                        // the two forms cannot land on both sides of a split.
                        let (id, group, source) = match kind {
                            MaterialSourceName::Dsbrdf => (
                                format!("dsbrdf:{name}"),
                                format!("dsbrdf:{name}"),
                                MaterialSource::Dsbrdf(f),
                            ),
                            MaterialSourceName::Nbrdf => {
                                (format!("nbrdf:{name}"), merl_group(&name), MaterialSource::Nbrdf(f))
                            }
                            _ => (format!("merl:{name}"), merl_group(&name), MaterialSource::Merl(f)),
                        };
                        cat.materials.push(MaterialItem {
                            id,
                            group,
                            source,
                            fingerprint: String::new(),
                            entry: i,
                        });
                    }
                }
                None => {
                    let items = library_items(None, None).map_err(|err| e.invalid_entry(err))?;
                    cat.substitutions.push(format!(
                        "{}: {} is missing; using the {} library materials",
                        e.field,
                        s.path.as_deref().unwrap_or(""),
                        items.len()
                    ));
                    cat.materials.extend(items);
                }
            }
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn merl_near_duplicates_share_a_group() {
        assert_eq!(merl_group("blue-metallic-paint2"), merl_group("blue-metallic-paint"));
        assert_ne!(merl_group("gold-paint"), merl_group("blue-metallic-paint"));
    }

    #[test]
    fn library_selection_by_name_and_family() {
        assert_eq!(library_items(None, None).unwrap().len(), library().len());
        let metals = library_items(None, Some(&vec!["metal".into()])).unwrap();
        assert_eq!(metals.len(), 48);
        assert!(
            library_items(Some(&vec!["nope".into()]), None)
                .unwrap_err()
                .contains("nope")
        );
        assert!(
            library_items(None, Some(&vec!["glass".into()]))
                .unwrap_err()
                .contains("glass")
        );
        let two = library_items(Some(&vec!["gold-brushed".into(), "rubber-red".into()]), None).unwrap();
        assert_eq!(two.len(), 2);
        assert_eq!(two[0].group, "library:metal-gold");
    }
}
