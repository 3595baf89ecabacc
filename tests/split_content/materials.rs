//! The quickstart's deal is unchanged by content groups; neural BRDF folders as material sources
//! whose variants stay together.

use super::*;

/// The quickstart's deal as it was before fingerprints existed (plan.json of commit c9635a4):
/// without duplicates the content groups must not change a single choice.
#[test]
fn the_quickstart_deal_is_unchanged_by_content_groups() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let l = load(&root.join("manifests/datasets/quickstart.toml")).unwrap();
    assert!(l.plan.catalogue.merges.is_empty(), "{:?}", l.plan.catalogue.merges);
    let cat = &l.plan.catalogue;
    let got: BTreeMap<&str, (Vec<&str>, Vec<&str>)> = l
        .plan
        .splits
        .iter()
        .map(|s| {
            (
                s.name.as_str(),
                (
                    s.shapes.iter().map(|&k| cat.shapes[k].id.as_str()).collect(),
                    s.materials.iter().map(|&k| cat.materials[k].id.as_str()).collect(),
                ),
            )
        })
        .collect();
    let expected: BTreeMap<&str, (Vec<&str>, Vec<&str>)> = QUICKSTART_DEAL
        .iter()
        .map(|(n, s, m)| (*n, (s.to_vec(), m.to_vec())))
        .collect();
    assert_eq!(got, expected);
}

type Deal = (&'static str, &'static [&'static str], &'static [&'static str]);
const QUICKSTART_DEAL: [Deal; 2] = [
    (
        "train",
        &[
            "procedural:car:0",
            "procedural:car:1",
            "procedural:car:3",
            "procedural:car:4",
            "procedural:chair:1",
            "procedural:chair:2",
            "procedural:chair:3",
            "procedural:monitor:0",
            "procedural:monitor:2",
            "procedural:sofa:0",
            "procedural:sofa:1",
        ],
        &[
            "library:carpaint-blue-gloss",
            "library:carpaint-blue-satin",
            "library:carpaint-green-gloss",
            "library:carpaint-green-satin",
            "library:carpaint-yellow-gloss",
            "library:carpaint-yellow-satin",
            "library:fabric-canvas",
            "library:fabric-felt-green",
            "library:fabric-velvet-red",
            "library:plastic-purple-matte",
            "library:plastic-purple-smooth",
            "library:plastic-teal-matte",
            "library:plastic-teal-smooth",
            "library:plastic-yellow-matte",
            "library:plastic-yellow-smooth",
            "library:rubber-black",
        ],
    ),
    (
        "test",
        &[
            "procedural:car:2",
            "procedural:chair:0",
            "procedural:monitor:1",
            "procedural:sofa:2",
        ],
        &[
            "library:carpaint-red-gloss",
            "library:carpaint-red-satin",
            "library:fabric-mustard",
            "library:wood-oak-raw",
            "library:wood-oak-varnished",
            "library:wood-pine-raw",
        ],
    ),
];

/// A valid `*.nbrdf.json` whose output layer's biases give the material its colour (the
/// network's other weights are small and shared).
fn nbrdf_text(rgb_bias: [f64; 3]) -> String {
    matedit_physics::brdf::NeuralBrdf::json_of(
        "t",
        |l, r, c| 0.05 * (((l * 31 + r * 7 + c) % 11) as f64 - 5.0) / 5.0,
        |l, c| if l == 2 { rgb_bias[c] } else { 0.1 },
    )
}

/// `source = "nbrdf"`: a folder of MERL neural BRDFs becomes materials `nbrdf:NAME`, MERL's
/// numbered variants (red, red2) one group that no split divides, and a dataset with measured
/// ground truth renders them and verifies.
#[test]
fn a_folder_of_neural_brdfs_is_a_material_source_whose_variants_stay_together() {
    let d = scratch("nbrdf");
    shape_folder(&d, false);
    let m = d.join("merl");
    std::fs::create_dir_all(&m).unwrap();
    for (name, rgb) in [
        ("red", [-0.5, -2.0, -2.0]),
        ("red2", [-0.4, -2.0, -2.0]),
        ("blue", [-2.0, -2.0, -0.5]),
        ("green", [-2.0, -0.5, -2.0]),
        ("grey", [-1.0, -1.0, -1.0]),
    ] {
        std::fs::write(m.join(format!("{name}.nbrdf.json")), nbrdf_text(rgb)).unwrap();
    }
    std::fs::write(m.join("notes.txt"), "not a material").unwrap();
    let text = manifest(7, "\n[[splits]]\nname = \"train\"\nshapes = { car = 3 }\nmaterials = 2\n\n[[splits]]\nname = \"test\"\nshapes = { car = 2 }\nmaterials = 2\n")
        .replace("source = \"dsbrdf\"\npath = \"materials\"", "source = \"nbrdf\"\npath = \"merl\"")
        .replace("quality = \"fast\"", "quality = \"exact\"\nground_truth = \"measured\"");
    for seed in 0..6 {
        let p = write(&d, "m.toml", &text.replace("seed = 7", &format!("seed = {seed}")));
        let l = load(&p).unwrap();
        let cat = &l.plan.catalogue;
        let ids: BTreeSet<&str> = cat.materials.iter().map(|m| m.id.as_str()).collect();
        assert_eq!(
            ids,
            ["nbrdf:blue", "nbrdf:green", "nbrdf:grey", "nbrdf:red", "nbrdf:red2"]
                .into_iter()
                .collect()
        );
        let group = |id: &str| cat.materials.iter().find(|m| m.id == id).unwrap().group.clone();
        assert_eq!(group("nbrdf:red"), "merl:red");
        assert_eq!(group("nbrdf:red2"), "merl:red");
        let holding = splits_holding(&l, &["nbrdf:red", "nbrdf:red2"], false);
        assert!(holding.len() <= 1, "seed {seed}: red and red2 in {holding:?}");
    }
    let out = d.join("out");
    run_to(&write(&d, "m.toml", &text), &out);
    let rep = verify(&out).unwrap();
    assert!(rep.problems.is_empty(), "{:?}", rep.problems);
    let o = Command::new(datagen()).arg("verify").arg(&out).output().unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stdout));
}
