#!/usr/bin/env python3
"""Real furniture and vehicle meshes for training, from Debian's Sweet Home 3D furniture libraries.

The procedural shapes are built from boxes, tubes and lathed profiles; real objects have bevels,
cushions, wheel arches and screens' bezels. Debian's `sweethome3d-furniture` package (five
libraries, 820 models, Blend Swap CC-0 and CC-BY, KatorLegaz, Reallusion and Scopia; their
licences are inside each `.sh3f`) ships real meshes in OBJ. This script picks the cars, chairs,
sofas and monitors among them by the catalogue's own names and writes one folder per category,
which a dataset manifest reads as `[[shapes]] source = "folder"` with that `category`
(`manifests/datasets/experiments/quickstart-real-shapes.toml`):

    apt-get install -y sweethome3d-furniture
    python3 scripts/sweethome3d_shapes.py --out out/shapes/sweethome3d
    MATEDIT_SH3D_SHAPES=$PWD/out/shapes/sweethome3d datagen run manifests/datasets/experiments/quickstart-real-shapes.toml

Each model is written as OUT/CATEGORY/LIBRARY/SLUG.obj, geometry only (`v`, `vn`, `f`, groups;
materials and textures are dropped: the factory draws its own), with the catalogue's
`modelRotation` applied so that every model stands with +y up, as the folder source's default
`up = "y"` expects. Output is deterministic (sorted, no timestamps) and written atomically per
file; a model already present is kept. Nothing of the photo benchmark's meshes is among them (its
beetle is Sutherland's 1972 mesh; the catalogue's "VW new beetle" is left out all the same, so that
no car of the benchmark has a namesake in training).
"""

import argparse
import os
import re
import sys
import zipfile
from pathlib import Path

DEFAULT_LIBRARIES = "/usr/share/sweethome3d/furniture"

# (category, catalogue name pattern, excluded pattern), matched case-insensitively on the
# catalogue's English name (the exclusion also on the model's path; cars must also be in the
# catalogue's category "Vehicles", but for the toy "Car model").
RULES = [
    ("car", r"sedan|chevrolet|ford|seat leon|peugeot|renault|suv|\bvan\b|smart car|truck|bus|car model|fork lift",
     r"beetle|bike|scooter|stroller|skateboard|tricycle|cycle|yamaha"),
    ("chair", r"\bchair\b|armchair", r"wheelchair|high chair|child|swing"),
    ("sofa", r"sofa|couch", r"opened"),
    ("monitor", r"\btv\b(?! (stand|remote))|television(?! cabinet)|\bscreen$|laptop|monitor|computer",
     r"intercom|door|cctv|japanese"),
]


def catalogue(sh3f: zipfile.ZipFile):
    """The catalogue's entries: dicts of name, category, model, modelRotation (latin-1 text;
    Java's properties escape other characters as \\uXXXX, which only names use)."""
    text = sh3f.read("PluginFurnitureCatalog.properties").decode("latin-1")
    entries = {}
    for line in text.splitlines():
        m = re.match(r"^(name|category|model|modelRotation)#(\d+)=(.*)$", line)
        if m:
            entries.setdefault(int(m.group(2)), {})[m.group(1)] = m.group(3).strip()
    return [entries[k] for k in sorted(entries)]


def category_of(entry):
    name = entry.get("name", "")
    # The model's file name says more than some names do ("Screen" is a Japanese folding screen).
    described = f"{name} {entry.get('model', '')}"
    for category, include, exclude in RULES:
        if category == "car" and entry.get("category") != "Vehicles" and "car model" not in name.lower():
            continue
        if re.search(include, name, re.I) and not re.search(exclude, described, re.I):
            return category
    return None


def rotate(line: str, rot):
    parts = line.split()
    x, y, z = (float(p) for p in parts[1:4])
    v = [rot[0] * x + rot[1] * y + rot[2] * z, rot[3] * x + rot[4] * y + rot[5] * z,
         rot[6] * x + rot[7] * y + rot[8] * z]
    return f"{parts[0]} {v[0]:.6g} {v[1]:.6g} {v[2]:.6g}"


def geometry_only(obj_text: str, rot):
    """The OBJ's vertices, normals, groups and faces (texture coordinates and materials dropped;
    faces keep their position and normal indices, so `f a/b/c` becomes `f a//c`)."""
    out = []
    for line in obj_text.splitlines():
        line = line.strip()
        if line.startswith(("v ", "vn ")):
            out.append(rotate(line, rot) if rot else line)
        elif line.startswith("f "):
            verts = []
            for tok in line.split()[1:]:
                idx = tok.split("/")
                verts.append(idx[0] + (f"//{idx[2]}" if len(idx) > 2 and idx[2] else ""))
            out.append("f " + " ".join(verts))
        elif line.startswith(("g ", "o ")):
            out.append(line)
    return "\n".join(out) + "\n"


def slug(text: str):
    return re.sub(r"[^a-z0-9]+", "-", text.lower()).strip("-")


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--libraries", default=DEFAULT_LIBRARIES,
                    help=f"folder of Sweet Home 3D .sh3f libraries (default {DEFAULT_LIBRARIES})")
    ap.add_argument("--out", help="output folder (one subfolder per category)")
    ap.add_argument("--list", action="store_true", help="print the selection and write nothing")
    args = ap.parse_args()
    libs = sorted(Path(args.libraries).glob("*.sh3f"))
    if not libs:
        sys.exit(f"{args.libraries}: no .sh3f library (apt-get install -y sweethome3d-furniture)")
    if not args.list and not args.out:
        sys.exit("--out is required (or --list)")
    counts = {}
    for lib in libs:
        with zipfile.ZipFile(lib) as z:
            names = set(z.namelist())
            for entry in catalogue(z):
                category = category_of(entry)
                model = entry.get("model", "").lstrip("/")
                if category is None or model not in names or not model.lower().endswith(".obj"):
                    continue
                stem = slug(Path(model).stem)
                dest = Path(args.out or ".") / category / slug(lib.stem) / f"{stem}.obj"
                counts[category] = counts.get(category, 0) + 1
                if args.list:
                    print(f"{category}\t{lib.stem}\t{entry.get('name')}\t{model}")
                    continue
                if dest.exists():
                    continue
                rot = None
                if "modelRotation" in entry:
                    rot = [float(t) for t in entry["modelRotation"].split()]
                    if len(rot) != 9:
                        sys.exit(f"{lib}: {entry.get('name')}: modelRotation is not a 3x3 matrix")
                text = z.read(model).decode("utf-8", errors="replace")
                dest.parent.mkdir(parents=True, exist_ok=True)
                tmp = dest.with_suffix(".obj.tmp")
                tmp.write_text(geometry_only(text, rot))
                os.replace(tmp, dest)
    print(" ".join(f"{k} {counts[k]}" for k in sorted(counts)), file=sys.stderr)


if __name__ == "__main__":
    main()
