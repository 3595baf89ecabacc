#!/usr/bin/env python3
"""Photo material-editing benchmark against Mitsuba 3 path-traced ground truth.

`render` path-traces "photos" with Mitsuba 3 (an independent renderer): one real mesh of
`../shared/eval-assets/meshes` per scene (RECIPES below: 3 cars first, then teapot, bunny, two
sofas, office chair, monitor, spot; meshes no training set may contain), in an input material
outside the project's material families (Mitsuba `roughplastic`, `principled`, measured
`roughconductor` Cu/Al/Cr), under a real HDR environment map (the eval-assets' Poly Haven maps and
Debian blender-data's studio lights, night maps excluded; rotated at random about +y) that is
also the visible background. No ground plane. A perspective camera (fov 30-40 deg) frames the
object so that its larger projected side spans 50-60 % of the frame; `path` (max_depth 4),
multijitter sampler, box filter, Mitsuba's scalar_rgb variant. The same scene, camera, light and
random seed are rendered again with each target material, which gives the true edited photo.
Every random choice is seeded, so renders are deterministic, and files already present are
kept (an interrupted render resumes). `--shapes DIR` adds one scene per OBJ of DIR (the
project's procedural shapes). At the default 64 spp a scene (mask + 4 renders, 640x480) took
40-60 s on 2 cores shared with another job. `score` runs `matedit edit` on each photo with each
method and compares its `edited.png` with that truth.

Targets (project spec / Mitsuba definition; every BSDF is wrapped in `twosided`):
    green   lambert:0.1,0.5,0.1     diffuse, reflectance (0.1, 0.5, 0.1)                   exact
    chrome  ggx:0.15:1,1,1          roughconductor, ggx, alpha 0.15, material "none" (F=1)  exact
    gold    library:gold-polished   roughconductor, ggx, alpha 0.12, material "Au"          near
"Exact" means the same BRDF (Mitsuba's GGX uses the separable Smith G1 as the project's does); the
library's gold is GGX alpha 0.12 with a Schlick F0 derived from measured n, k, where Mitsuba uses
the spectral conductor Fresnel of Au, hence "near". The truths include what a path tracer sees
(inter-reflections, self-shadowing), whatever the editing method models.

Images: 640x480 by default. Each scene has one exposure s shared by the photo and its truths:
s = min(0.2 / median background luminance, 1 / 90th percentile of the object's max(R, G, B)) of
the input render (Rec. 709 luminance, linear): the background's median maps to 0.2 unless that
would clip more than 10 % of the photo's object pixels (bright objects, dark studio backgrounds).
Truths may clip more (chrome mirrors the sky), as a photo at that exposure would.
PNG = sRGB(clamp(s * radiance, 0, 1)), 8 bit. The `*.exr` files hold the unscaled radiance.
`mask.png` is the object's coverage of each pixel (Mitsuba `aov` albedo of a white twosided
diffuse object, box filter, same sample count): exactly 0 off the object, 255 inside it.

Scores, per scene x target x method, on the object's pixels (mask > 127), on the 8-bit sRGB
values, against truth_TARGET.png:
  L2         mean over object pixels of the mean over R, G, B of the squared difference (0..255
             scale), the paper's L2;
  SSIM       Wang et al. 2004 per channel on the whole image (Gaussian window sigma 1.5, 11x11,
             K1 0.01, K2 0.03, L 255: skimage structural_similarity with gaussian_weights,
             use_sample_covariance=False, data_range=255, full=True), its map averaged over the
             object's pixels and the channels;
  grad corr  Pearson correlation, over the object's pixels, of the Sobel gradient magnitudes of
             the luminance (0.299 R + 0.587 G + 0.114 B of the 8-bit values) of edit and truth;
  beats      the edit has a lower L2 and a higher SSIM than the unchanged photo for that case
             (a failed edit does not beat it);
  seconds    report.json's seconds.total, median per method.
`unchanged` scores the photo itself. Means are over the cases a method completed; failures
are counted and reported with their stderr tail.

Usage:
    pip install mitsuba numpy scikit-image pillow; apt-get install -y blender-data  # optional maps
    python3 scripts/photo_bench.py render --out out/photobench [--scenes 10] [--spp 64]
    python3 scripts/photo_bench.py score --out out/photobench --matedit target/release/matedit \\
        --model out/train/quickstart [--methods "render=--composite render" ...] [--targets green,gold]
    python3 scripts/photo_bench.py all --out out/photobench --matedit BIN --model MODEL
    python3 scripts/photo_bench.py levels --out out/photobench --methods detail   # after `score`
    python3 scripts/photo_bench.py ceiling --out out/photobench   # a perfect edit's scores
    python3 scripts/photo_bench.py reach --out out/photobench     # the photo-keeping composites' bound
    python3 scripts/photo_bench.py relights --out out/photobench  # relighting truths, then:
    python3 scripts/photo_bench.py score --out out/photobench --matedit BIN --model MODEL --targets relit
    python3 scripts/photo_bench.py normals --out out/photobench --methods detail  # n*'s angle to the truth
    python3 scripts/photo_bench.py lprime --out out/photobench --method detail    # L' variants for --light
    python3 scripts/photo_bench.py combine --out out/photobench --methods A B --how mean|fit|truth
Oracles for methods (`{scene}/...` in --methods): sceneNN/light.exr (the true light in the
camera's frame, for `--light`), sceneNN/normals.exr (the true shading normals in the camera's
frame, for `--normals`), `{input}` (the project spec nearest the input material); `lprime` writes
sceneNN/lprime_METHOD_VARIANT.exr, not oracles: a method's own L' changed (`--light-level given`).
Outputs: DIR/sceneNN/{photo,mask,truth_green,truth_chrome,truth_gold}.png (+ .exr), DIR/scenes.json,
DIR/contact.png; DIR/edits/METHOD/sceneNN-TARGET/, DIR/edits/sheet.png, DIR/results.json.
"""
import argparse
import json
import os
import re
import shlex
import statistics
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from PIL import Image, ImageDraw
from skimage.filters import sobel
from skimage.metrics import structural_similarity

SEED = 20240611
MAX_DEPTH = 4
BG_TARGET = 0.2  # median background luminance after exposure
CLIP_PERCENTILE = 90  # at most 10 % of the photo's object pixels clip
BLENDER_MAPS = Path("/usr/share/blender/datafiles/studiolights/world")
EXCLUDED_MAPS = {"dikhololo_night_1k.hdr": "near black", "night.exr": "near black"}
TILE = (160, 120)


# ---------------------------------------------------------------------------------------------
# Scenes


@dataclass(frozen=True)
class MeshEntry:
    path: str  # relative to the assets' meshes/ folder, or absolute
    axes: tuple  # the file's axes that become x, y (up), z, e.g. ("x", "z", "-y")
    azimuth: tuple  # camera azimuth ranges (from +z towards +x, degrees), one picked at random
    elevation: tuple = (8.0, 22.0)  # camera elevation range, degrees
    face_normals: bool = False  # flat shading for low-poly meshes without usable normals


CAR_VIEWS = ((30, 60), (120, 150))  # three-quarter views of a car lengthwise along x
MESHES = {
    "minicooper": MeshEntry("nikhil366-PyTorch3D/car.obj", ("y", "z", "x"), CAR_VIEWS),
    "cybercar": MeshEntry("LENKFF-P2M/cybercar.obj", ("z", "y", "-x"), CAR_VIEWS),
    "beetle": MeshEntry("common-3d-test-models/beetle.obj", ("z", "y", "-x"), CAR_VIEWS),
    "teapot": MeshEntry("common-3d-test-models/teapot.obj", ("x", "y", "z"), ((10, 50), (-50, -10)), (15, 30)),
    "bunny": MeshEntry("common-3d-test-models/stanford-bunny.obj", ("x", "y", "z"), ((-40, 40),)),
    "sofa": MeshEntry("LENKFF-P2M/sofa.obj", ("-z", "y", "x"), ((15, 45), (-45, -15)), (12, 25)),
    "oldsofa": MeshEntry("LENKFF-P2M/oldsofa.obj", ("x", "y", "z"), ((15, 45), (-45, -15)), (12, 25)),
    "officechair": MeshEntry("codeyeJR-Models/chair.obj", ("x", "y", "z"), ((40, 75), (105, 140)), (15, 28)),
    "monitor": MeshEntry("codeyeJR-Models/monitor.obj", ("z", "y", "-x"), ((140, 165), (195, 220)), (5, 15), True),
    "spot": MeshEntry("common-3d-test-models/spot.obj", ("x", "y", "z"), ((40, 80), (-80, -40))),
}
# The procedural shapes (docs/CONVENTIONS.md): +y up, front towards +z, cars lengthwise along x.
PROCEDURAL_VIEWS = {"car": CAR_VIEWS, "chair": ((20, 50), (-50, -20)), "sofa": ((15, 45), (-45, -15)),
                    "monitor": ((15, 40), (-40, -15))}


def rgb(v):
    return {"type": "rgb", "value": list(v)}


def roughplastic(colour, alpha):
    return (f"roughplastic ggx alpha={alpha} diffuse={colour}",
            {"type": "roughplastic", "distribution": "ggx", "alpha": alpha, "diffuse_reflectance": rgb(colour)})


def principled(colour, metallic, roughness, specular):
    return (f"principled base={colour} metallic={metallic} roughness={roughness} specular={specular}",
            {"type": "principled", "base_color": rgb(colour), "metallic": metallic,
             "roughness": roughness, "specular": specular})


def conductor(material, alpha):
    return (f"roughconductor ggx alpha={alpha} material={material}",
            {"type": "roughconductor", "distribution": "ggx", "alpha": alpha, "material": material})


# The scene recipes: mesh, input material, environment map. Cars first.
RECIPES = [
    ("minicooper", roughplastic((0.55, 0.04, 0.03), 0.08), "kiara_1_dawn_1k.hdr"),
    ("cybercar", principled((0.05, 0.16, 0.45), 0.7, 0.3, 0.5), "potsdamer_platz_1k.hdr"),
    ("beetle", roughplastic((0.75, 0.55, 0.06), 0.15), "courtyard.exr"),
    ("teapot", conductor("Cu", 0.2), "lebombo_1k.hdr"),
    ("bunny", principled((0.8, 0.74, 0.64), 0.0, 0.45, 0.5), "forest_slope_1k.hdr"),
    ("sofa", roughplastic((0.12, 0.3, 0.28), 0.3), "st_fagans_interior_1k.hdr"),
    ("oldsofa", principled((0.32, 0.1, 0.05), 0.0, 0.55, 0.4), "interior.exr"),
    ("officechair", conductor("Al", 0.25), "empty_warehouse_01_1k.hdr"),
    ("monitor", roughplastic((0.04, 0.04, 0.045), 0.05), "city.exr"),
    ("spot", conductor("Cr", 0.1), "sunset.exr"),
]
SHAPE_MATERIALS = [roughplastic((0.1, 0.2, 0.6), 0.1), principled((0.7, 0.7, 0.72), 1.0, 0.25, 0.5),
                   conductor("Cu", 0.15)]

TARGETS = {
    "green": {"spec": "lambert:0.1,0.5,0.1", "exact": True,
              "mitsuba": {"type": "diffuse", "reflectance": rgb((0.1, 0.5, 0.1))}},
    "chrome": {"spec": "ggx:0.15:1,1,1", "exact": True,
               "mitsuba": {"type": "roughconductor", "distribution": "ggx", "alpha": 0.15, "material": "none"}},
    "gold": {"spec": "library:gold-polished", "exact": False,
             "mitsuba": {"type": "roughconductor", "distribution": "ggx", "alpha": 0.12, "material": "Au"}},
}


def available_maps(assets):
    """Every usable map by file name: the eval-assets' maps, then blender-data's."""
    maps = {p.name: p for p in sorted((assets / "envmaps").glob("*.hdr"))}
    if BLENDER_MAPS.is_dir():
        maps.update({p.name: p for p in sorted(BLENDER_MAPS.glob("*.exr"))})
    else:
        print(f"note: {BLENDER_MAPS} not found (apt-get install -y blender-data): "
              "its maps are replaced by unused eval-assets maps", file=sys.stderr)
    for name in EXCLUDED_MAPS:
        maps.pop(name, None)
    return maps


def scene_plans(n, assets, shapes_dir):
    """The first n recipes (cycled, each cycle with new random views), then one scene per OBJ of
    shapes_dir. Every random choice comes from a generator seeded by (SEED, scene index)."""
    maps = available_maps(assets)
    spare = iter([m for m in maps if m not in {r[2] for r in RECIPES}] * (n // len(RECIPES) + 1))
    plans = []
    for i in range(n):
        mesh_key, material, map_name = RECIPES[i % len(RECIPES)]
        if map_name not in maps:
            map_name = next(spare)
        entry = MESHES[mesh_key]
        plans.append(dict(mesh=mesh_key, mesh_path=str(assets / "meshes" / entry.path), entry=entry,
                          material=material, map=map_name, map_path=str(maps[map_name])))
    shape_files = sorted(Path(shapes_dir).glob("*.obj")) if shapes_dir else []
    map_names = sorted(maps)
    for k, path in enumerate(shape_files):
        category = path.stem.split("_")[0]
        entry = MeshEntry(str(path), ("x", "y", "z"), PROCEDURAL_VIEWS.get(category, ((20, 50), (-50, -20))))
        map_name = map_names[k % len(map_names)]
        plans.append(dict(mesh=path.stem, mesh_path=str(path), entry=entry,
                          material=SHAPE_MATERIALS[k % len(SHAPE_MATERIALS)], map=map_name,
                          map_path=str(maps[map_name])))
    for i, plan in enumerate(plans):
        rng = np.random.default_rng([SEED, i])
        e = plan["entry"]
        lo, hi = e.azimuth[rng.integers(len(e.azimuth))]
        plan.update(name=f"scene{i:02d}", seed=int(rng.integers(1 << 30)),
                    env_rotation=float(rng.uniform(0, 360)), fov=float(rng.uniform(30, 40)),
                    azimuth=float(rng.uniform(lo, hi)), elevation=float(rng.uniform(*e.elevation)),
                    frame_fraction=float(rng.uniform(0.5, 0.6)))
    return plans


# ---------------------------------------------------------------------------------------------
# Meshes and cameras


def parse_obj(path):
    """Positions, triangles (fan-triangulated) and per-corner normal indices (-1: none)."""
    verts, normals, tris, tri_normals = [], [], [], []
    with open(path, errors="replace") as f:
        for line in f:
            if line.startswith("v "):
                verts.append([float(x) for x in line.split()[1:4]])
            elif line.startswith("vn "):  # a malformed normal becomes NaN, i.e. unusable
                normals.append([float(x) for x in (line.split()[1:4] + ["nan"] * 3)[:3]])
            elif line.startswith("f "):
                corners = []
                for tok in line.split()[1:]:
                    parts = tok.split("/")
                    vi = int(parts[0])
                    ni = int(parts[2]) if len(parts) > 2 and parts[2] else 0
                    corners.append((vi - 1 if vi > 0 else len(verts) + vi,
                                    ni - 1 if ni > 0 else (len(normals) + ni if ni < 0 else -1)))
                for k in range(1, len(corners) - 1):
                    tri = (corners[0], corners[k], corners[k + 1])
                    tris.append([c[0] for c in tri])
                    tri_normals.append([c[1] for c in tri])
    return (np.array(verts, np.float64), np.array(normals, np.float64).reshape(-1, 3),
            np.array(tris, np.int64), np.array(tri_normals, np.int64))


def axes_matrix(axes):
    """The rotation whose rows pick the file's axes named in axes (a proper rotation)."""
    m = np.zeros((3, 3))
    for row, name in enumerate(axes):
        m[row, "xyz".index(name[-1])] = -1.0 if name.startswith("-") else 1.0
    assert np.isclose(np.linalg.det(m), 1.0), f"axes {axes} are not a proper rotation"
    return m


def load_mesh(path, entry):
    """Render-ready geometry: positions turned by entry.axes to y-up, bounding box centred at the
    origin with its largest side 2; vertex normals from the file where they are valid, else
    area-weighted smooth normals (or flat normals when entry.face_normals)."""
    verts, normals, tris, tri_n = parse_obj(path)
    rot = axes_matrix(entry.axes)
    p = verts @ rot.T
    e1, e2 = p[tris[:, 1]] - p[tris[:, 0]], p[tris[:, 2]] - p[tris[:, 0]]
    face_n = np.cross(e1, e2)
    keep = np.linalg.norm(face_n, axis=1) > 1e-12 * max(1.0, np.abs(p).max()) ** 2
    tris, tri_n, face_n = tris[keep], tri_n[keep], face_n[keep]
    used = np.unique(tris)
    lo, hi = p[used].min(0), p[used].max(0)
    p = (p - (lo + hi) / 2) * (2.0 / (hi - lo).max())
    unit_face = face_n / np.linalg.norm(face_n, axis=1, keepdims=True)
    if entry.face_normals:
        corner_n = np.repeat(unit_face[:, None, :], 3, axis=1)
    else:
        smooth = np.zeros_like(p)
        for k in range(3):
            np.add.at(smooth, tris[:, k], face_n)
        smooth_len = np.linalg.norm(smooth, axis=1, keepdims=True)
        corner_n = smooth[tris] / np.maximum(smooth_len[tris], 1e-30)
        degenerate = (smooth_len[tris][..., 0] < 1e-30)
        corner_n[degenerate] = np.repeat(unit_face[:, None, :], 3, axis=1)[degenerate]
        if len(normals):
            file_n = normals @ rot.T
            has = tri_n >= 0
            fn = file_n[np.where(has, tri_n, 0)]
            length = np.linalg.norm(fn, axis=-1)
            good = has & np.isfinite(length) & (length > 0.5)
            corner_n[good] = fn[good] / length[good][:, None]
    keys = np.concatenate([tris.reshape(-1, 1).astype(np.float64), corner_n.reshape(-1, 3)], axis=1)
    uniq, inverse = np.unique(keys, axis=0, return_inverse=True)
    return {"positions": p[uniq[:, 0].astype(np.int64)], "normals": uniq[:, 1:],
            "faces": inverse.reshape(-1, 3), "points": p[used]}


def frame_camera(points, plan, width, height):
    """Origin and target of a camera at the plan's azimuth/elevation whose view centres the
    object with its larger projected side filling plan['frame_fraction'] of the frame."""
    az, el = np.radians(plan["azimuth"]), np.radians(plan["elevation"])
    back = np.array([np.sin(az) * np.cos(el), np.sin(el), np.cos(az) * np.cos(el)])
    fwd = -back
    right = np.cross(fwd, [0.0, 1.0, 0.0])
    right /= np.linalg.norm(right)
    up = np.cross(right, fwd)
    tan_x = np.tan(np.radians(plan["fov"]) / 2)
    tan_y = tan_x * height / width
    target, dist = np.zeros(3), 4.0
    for _ in range(30):
        rel = points - (target - fwd * dist)
        depth = rel @ fwd
        x, y = (rel @ right) / depth / tan_x, (rel @ up) / depth / tan_y
        size = max(x.max() - x.min(), y.max() - y.min()) / 2
        cx, cy = (x.max() + x.min()) / 2, (y.max() + y.min()) / 2
        target = target + right * cx * tan_x * dist + up * cy * tan_y * dist
        dist *= size / plan["frame_fraction"]
    return target - fwd * dist, target


# ---------------------------------------------------------------------------------------------
# Rendering


def mitsuba():
    import mitsuba as mi

    mi.set_variant("scalar_rgb")  # llvm_ad_rgb aborted in LLVM 15's instruction selection here
    return mi


def build_scene(mi, geom, bsdf, plan, camera, width, height, spp, env=True, integrator=None):
    props = mi.Properties()
    props["bsdf"] = mi.load_dict({"type": "twosided", "bsdf": bsdf})
    mesh = mi.Mesh(plan["mesh"], len(geom["positions"]), len(geom["faces"]), props, has_vertex_normals=True)
    params = mi.traverse(mesh)
    params["vertex_positions"] = geom["positions"].astype(np.float32).ravel()
    params["vertex_normals"] = geom["normals"].astype(np.float32).ravel()
    params["faces"] = geom["faces"].astype(np.uint32).ravel()
    params.update()
    origin, target = camera
    scene = {
        "type": "scene",
        "integrator": integrator or {"type": "path", "max_depth": MAX_DEPTH},
        "sensor": {"type": "perspective", "fov": plan["fov"], "fov_axis": "x",
                   "to_world": mi.ScalarTransform4f().look_at(origin=origin.tolist(), target=target.tolist(),
                                                               up=[0, 1, 0]),
                   "film": {"type": "hdrfilm", "width": width, "height": height, "rfilter": {"type": "box"}},
                   "sampler": {"type": "multijitter", "sample_count": spp}},
        "object": mesh,
    }
    if env:
        scene["env"] = {"type": "envmap", "filename": plan["map_path"],
                        "to_world": mi.ScalarTransform4f().rotate([0, 1, 0], plan["env_rotation"])}
    return mi.load_dict(scene)


def camera_frame_light(mi, record, height=64, supersample=8):
    """The scene's illumination as `matedit edit --light` reads it: the map (rotated as rendered)
    seen from the camera, +z towards the camera, x right, y up (docs/CONVENTIONS.md), `height`
    rows, each texel the mean of supersample² bilinear lookups of the full map over its area."""
    full = np.array(mi.Bitmap(record["map_file"]), dtype=np.float64)[..., :3]
    fh, fw = full.shape[:2]
    cam = record["camera"]
    fwd = np.array(cam["target"]) - np.array(cam["origin"])
    fwd /= np.linalg.norm(fwd)
    right = np.cross(fwd, [0.0, 1.0, 0.0])
    right /= np.linalg.norm(right)
    up = np.cross(right, fwd)
    w = 2 * height
    j = (np.arange(height * supersample) + 0.5) / (height * supersample)
    i = (np.arange(w * supersample) + 0.5) / (w * supersample)
    phi, theta = np.meshgrid(2 * np.pi * i, np.pi * j)
    d = np.stack([np.sin(theta) * np.sin(phi), np.cos(theta), -np.sin(theta) * np.cos(phi)], -1)
    world = d[..., :1] * right + d[..., 1:2] * up + d[..., 2:] * -fwd
    a = np.radians(record["env_rotation_deg"])  # the map's to_world is R_y(a): look up R_y(-a) d
    x = np.cos(a) * world[..., 0] - np.sin(a) * world[..., 2]
    z = np.sin(a) * world[..., 0] + np.cos(a) * world[..., 2]
    u = (np.arctan2(x, -z) / (2 * np.pi)) % 1.0 * fw - 0.5
    v = np.arccos(np.clip(world[..., 1], -1, 1)) / np.pi * fh - 0.5
    u0, v0 = np.floor(u).astype(int), np.floor(v).astype(int)
    fu, fv = (u - u0)[..., None], (v - v0)[..., None]
    def at(uu, vv):
        return full[np.clip(vv, 0, fh - 1), uu % fw]
    look = ((1 - fu) * (1 - fv) * at(u0, v0) + fu * (1 - fv) * at(u0 + 1, v0)
            + (1 - fu) * fv * at(u0, v0 + 1) + fu * fv * at(u0 + 1, v0 + 1))
    return look.reshape(height, supersample, w, supersample, 3).mean(axis=(1, 3)).astype(np.float32)


def camera_frame_geometry(mi, rec, plan, width, height):
    """Per pixel, in the camera's frame (+x right, +y up, +z towards the camera): the object's
    shading normal, the mean of 16 samples' normals renormalised (zero where no sample hits the
    object) and turned towards the camera where the two-sided surface faces away (as rendered),
    and the unit direction towards the camera. Both [height, width, 3]."""
    geom = load_mesh(rec["mesh_file"], plan["entry"])
    origin, target = np.array(rec["camera"]["origin"]), np.array(rec["camera"]["target"])
    scene = build_scene(mi, geom, {"type": "diffuse"}, plan, (origin, target), width, height, 16, env=False,
                        integrator={"type": "aov", "aovs": "n:sh_normal,p:position"})
    mi.render(scene, seed=1)
    layers = dict(scene.sensors()[0].film().bitmap().split())
    fwd = (target - origin) / np.linalg.norm(target - origin)
    right = np.cross(fwd, [0.0, 1.0, 0.0])
    right /= np.linalg.norm(right)
    to_camera = np.stack([right, np.cross(right, fwd), -fwd])
    n = np.array(layers["n"], dtype=np.float64)[..., :3] @ to_camera.T
    wo = (origin - np.array(layers["p"], dtype=np.float64)[..., :3]) @ to_camera.T
    wo /= np.maximum(np.linalg.norm(wo, axis=-1, keepdims=True), 1e-12)
    n = np.where((np.sum(n * wo, -1) < 0)[..., None], -n, n)
    length = np.linalg.norm(n, axis=-1, keepdims=True)
    return np.where(length > 1e-6, n / np.maximum(length, 1e-12), 0.0), wo


def camera_frame_normals(mi, rec, plan, width, height):
    """The object's shading normals as `matedit edit --normals` reads them (camera_frame_geometry)."""
    return camera_frame_geometry(mi, rec, plan, width, height)[0].astype(np.float32)


def render_radiance(mi, scene, seed):
    return np.array(mi.render(scene, seed=seed), dtype=np.float32)[..., :3]


def render_coverage(mi, geom, plan, camera, width, height, spp):
    """Fraction of each pixel's samples that hit the object: the `albedo` AOV of a white diffuse."""
    scene = build_scene(mi, geom, {"type": "diffuse", "reflectance": rgb((1, 1, 1))}, plan, camera, width, height,
                        spp, env=False, integrator={"type": "aov", "aovs": "a:albedo"})
    mi.render(scene, seed=plan["seed"])
    layers = dict(scene.sensors()[0].film().bitmap().split())
    return np.clip(np.array(layers["a"], dtype=np.float64)[..., 0], 0.0, 1.0)


def luminance709(img):
    return img[..., 0] * 0.2126 + img[..., 1] * 0.7152 + img[..., 2] * 0.0722


def exposure(photo, coverage):
    photo = photo.astype(np.float64)
    bg = luminance709(photo)[coverage == 0]
    obj = photo.max(axis=-1)[coverage == 1]
    cap = 1 / max(np.percentile(obj, CLIP_PERCENTILE), 1e-8) if obj.size else np.inf
    return float(min(BG_TARGET / max(np.median(bg), 1e-8), cap))


def srgb8(linear):
    x = np.clip(linear, 0.0, 1.0)
    x = np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055)
    return np.round(x * 255).astype(np.uint8)


def srgb_decode(c):
    """Linear values of sRGB-encoded ones in [0, 1] (the inverse of srgb8's curve)."""
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


def texel_grid(h=64, w=128):
    """The directions of a `[h, w]` map's texel centres (docs/CONVENTIONS.md: +z towards the camera,
    y up) and each texel's solid angle, both `[h, w, ...]`."""
    theta, phi = np.meshgrid(np.pi * (np.arange(h) + 0.5) / h, 2 * np.pi * (np.arange(w) + 0.5) / w, indexing="ij")
    dirs = np.stack([np.sin(theta) * np.sin(phi), np.cos(theta), -np.sin(theta) * np.cos(phi)], -1)
    band = np.pi * np.arange(h + 1) / h
    dw = np.repeat(((2 * np.pi / w) * (np.cos(band[:-1]) - np.cos(band[1:])))[:, None], w, 1)
    return dirs, dw


def write_atomic(path, writer):
    path = Path(path)
    tmp = path.with_name(f".{path.stem}.{os.getpid()}.tmp{path.suffix}")
    writer(tmp)
    os.replace(tmp, path)


def write_png(path, array):
    write_atomic(path, lambda p: Image.fromarray(array).save(p, format="PNG"))


def write_exr(mi, path, array):
    write_atomic(path, lambda p: mi.Bitmap(np.ascontiguousarray(array, dtype=np.float32)).write(str(p)))


def render_scene(mi, plan, out, width, height, spp):
    """Renders whatever of a scene's files is missing; returns its scenes.json record."""
    d = out / plan["name"]
    d.mkdir(parents=True, exist_ok=True)
    t_scene = time.time()
    geom = load_mesh(plan["mesh_path"], plan["entry"])
    camera = frame_camera(geom["points"], plan, width, height)
    timings = {}
    if not (d / "mask.png").exists():
        t = time.time()
        write_png(d / "mask.png", np.round(render_coverage(mi, geom, plan, camera, width, height, spp) * 255)
                  .astype(np.uint8))
        timings["mask"] = time.time() - t
    coverage = np.asarray(Image.open(d / "mask.png"), dtype=np.float64) / 255
    jobs = [("photo", plan["material"][1])] + [(f"truth_{k}", t["mitsuba"]) for k, t in TARGETS.items()]
    scale = None
    for name, bsdf in jobs:
        exr, png = d / f"{name}.exr", d / f"{name}.png"
        if exr.exists():
            radiance = np.array(mi.Bitmap(str(exr)), dtype=np.float32)[..., :3]
        else:
            t = time.time()
            radiance = render_radiance(mi, build_scene(mi, geom, bsdf, plan, camera, width, height, spp), plan["seed"])
            write_exr(mi, exr, radiance)
            timings[name] = time.time() - t
        if scale is None:
            scale = exposure(radiance, coverage)
        if not png.exists():
            write_png(png, srgb8(radiance * scale))
    done = ", ".join(f"{k} {v:.1f} s" for k, v in timings.items()) or "all renders present"
    print(f"{plan['name']} {plan['mesh']:<12} {plan['map']:<26} {plan['material'][0]}: {done}; "
          f"total {time.time() - t_scene:.1f} s", flush=True)
    origin, target = camera
    return {
        "name": plan["name"], "mesh": plan["mesh"], "mesh_file": plan["mesh_path"],
        "mesh_axes": list(plan["entry"].axes),
        "map": plan["map"], "map_file": plan["map_path"], "env_rotation_deg": plan["env_rotation"],
        "fov_deg_x": plan["fov"], "camera": {"origin": origin.tolist(), "target": target.tolist(),
                                              "azimuth_deg": plan["azimuth"], "elevation_deg": plan["elevation"],
                                              "frame_fraction": plan["frame_fraction"]},
        "input_material": plan["material"][0], "input_mitsuba": plan["material"][1],
        "exposure": scale, "seed": plan["seed"],
        "object_pixels": int((coverage > 0.5).sum()),
        "targets": [{"name": k, "spec": t["spec"], "mitsuba": t["mitsuba"], "exact": t["exact"]}
                    for k, t in TARGETS.items()],
    }


def tile(path, size=TILE):
    return Image.open(path).convert("RGB").resize(size, Image.LANCZOS)


def labelled(img, text):
    draw = ImageDraw.Draw(img)
    draw.rectangle(draw.textbbox((3, 2), text, spacing=0), fill=(0, 0, 0))
    draw.text((3, 2), text, fill=(255, 255, 0))
    return img


def grid(rows, header):
    """A sheet of equally sized tiles under a row of column names."""
    w, h = TILE
    sheet = Image.new("RGB", (w * max(len(r) for r in rows), h * len(rows) + 14), (32, 32, 32))
    draw = ImageDraw.Draw(sheet)
    for c, name in enumerate(header):
        draw.text((c * w + 3, 1), name, fill=(255, 255, 255))
    for r, row in enumerate(rows):
        for c, img in enumerate(row):
            sheet.paste(img, (c * w, r * h + 14))
    return sheet


def write_contact(out, records):
    rows = []
    for rec in records:
        d = out / rec["name"]
        first = labelled(tile(d / "photo.png"), f"{rec['name']} {rec['mesh']} / {rec['map']}")
        rows.append([first, tile(d / "mask.png")] + [tile(d / f"truth_{k}.png") for k in TARGETS])
    write_atomic(out / "contact.png",
                 lambda p: grid(rows, ["photo", "mask"] + [f"truth {k}" for k in TARGETS]).save(p, format="PNG"))


def cmd_render(args):
    mi = mitsuba()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    settings = {"width": args.width, "height": args.height, "spp": args.spp, "max_depth": MAX_DEPTH, "seed": SEED}
    stamp = out / "render.json"
    if stamp.exists() and json.loads(stamp.read_text()) != settings:
        raise SystemExit(f"{out} holds renders made with {stamp.read_text().strip()}, not {settings}: "
                         "use another --out")
    write_atomic(stamp, lambda p: p.write_text(json.dumps(settings)))
    plans = scene_plans(10 if args.scenes is None else args.scenes, Path(args.assets), args.shapes)
    print(f"rendering {len(plans)} scenes at {args.width}x{args.height}, {args.spp} spp, path max_depth "
          f"{MAX_DEPTH}, Mitsuba {mi.__version__} {mi.variant()}", flush=True)
    t0 = time.time()
    records = [render_scene(mi, p, out, args.width, args.height, args.spp) for p in plans]
    for plan, rec in zip(plans, records):  # the true light and normals, for oracle methods
        light = out / rec["name"] / "light.exr"
        if not light.exists():
            write_exr(mi, light, camera_frame_light(mi, rec))
        normals = out / rec["name"] / "normals.exr"
        if not normals.exists():
            write_exr(mi, normals, camera_frame_normals(mi, rec, plan, args.width, args.height))
    write_atomic(out / "scenes.json", lambda p: p.write_text(json.dumps({**settings, "scenes": records}, indent=1)))
    write_contact(out, records)
    print(f"{len(records)} scenes in {time.time() - t0:.0f} s: {out / 'scenes.json'}, {out / 'contact.png'}")


# ---------------------------------------------------------------------------------------------
# Scoring

DEFAULT_METHODS = ["render=--composite render", "ratio=--composite ratio", "detail=--composite detail",
                   "detail+eq6=--composite detail --eq6"]


def rgb8(path):
    return np.asarray(Image.open(path).convert("RGB"), dtype=np.float64)


def grad_magnitude(img):
    return sobel(img[..., 0] * 0.299 + img[..., 1] * 0.587 + img[..., 2] * 0.114)


def scores(edit, truth, obj, truth_grad):
    l2 = float(np.mean((edit - truth)[obj] ** 2))
    _, ssim_map = structural_similarity(edit, truth, channel_axis=2, gaussian_weights=True, sigma=1.5,
                                        use_sample_covariance=False, data_range=255, full=True)
    g = grad_magnitude(edit)[obj]
    t = truth_grad[obj]
    corr = float(np.corrcoef(g, t)[0, 1]) if g.std() > 0 and t.std() > 0 else None  # undefined when flat
    return {"l2": l2, "ssim": float(ssim_map[obj].mean()), "grad_corr": corr}


def parse_methods(items):
    methods = {}
    for item in items:
        name, sep, margs = item.partition("=")
        if not sep or not re.fullmatch(r"[A-Za-z0-9_.+-]+", name) or name == "unchanged":
            raise SystemExit(f"--methods: expected NAME=ARGS, NAME of [A-Za-z0-9_.+-] and not 'unchanged', "
                             f"got {item!r}")
        methods[name] = margs.split()
    return methods


METALS_F0 = Path(__file__).resolve().parents[1] / "assets" / "materials" / "metals_f0.json"


def project_spec(mitsuba):
    """The project's material spec nearest to a scene's Mitsuba input material, for methods that
    give the object's own material (`--input-material {input}`), an oracle like `{scene}/light.exr`.
    None is exact: `roughplastic` -> plastic:ALPHA:DIFFUSE (Mitsuba's coating refracts and
    reflects internally, the project's adds a GGX lobe of F0 0.04); `principled` -> plastic with
    alpha = roughness^2 when metallic < 0.5, else ggx with F0 = metallic * base + (1 - metallic) *
    0.08 * specular (its diffuse share dropped); `roughconductor` -> ggx with the metal's F0 of
    assets/materials/metals_f0.json (Schlick against Mitsuba's spectral Fresnel)."""
    kind = mitsuba["type"]
    fmt = lambda v: ",".join(f"{x:.4g}" for x in v)
    if kind == "roughplastic":
        return f"plastic:{mitsuba['alpha']:.4g}:{fmt(mitsuba['diffuse_reflectance']['value'])}"
    if kind == "principled":
        base, alpha = mitsuba["base_color"]["value"], mitsuba["roughness"] ** 2
        if mitsuba["metallic"] < 0.5:
            return f"plastic:{alpha:.4g}:{fmt(base)}"
        m = mitsuba["metallic"]
        return f"ggx:{alpha:.4g}:{fmt([m * b + (1 - m) * 0.08 * mitsuba['specular'] for b in base])}"
    if kind == "roughconductor":
        metals = json.loads(METALS_F0.read_text())["metals"].values()
        f0 = next(v["f0_rgb"] for v in metals if v["file"] == mitsuba["material"])
        return f"ggx:{mitsuba['alpha']:.4g}:{fmt(f0)}"
    raise ValueError(f"no project spec for Mitsuba material {kind}")


def run_edit(args, scene_dir, spec, out_dir, extra, input_spec=None):
    """Runs matedit edit; returns (edited image or None, seconds, error text). `{scene}` in
    `extra` is the scene's folder, `{input}` the project spec of its input material. A `spec` of
    None relights instead (`--relight` the scene's relight.exr) and returns relit.png."""
    out_dir.mkdir(parents=True, exist_ok=True)
    edited = out_dir / ("edited.png" if spec is not None else "relit.png")
    report = out_dir / "report.json"
    if not (args.reuse and edited.exists() and report.exists()):
        for f in (edited, report):
            f.unlink(missing_ok=True)
        cmd = [args.matedit, "edit", "--model", args.model, "--image", str(scene_dir / "photo.png"),
               "--mask", str(scene_dir / "mask.png"), "--out", str(out_dir)]
        cmd += ["--material", spec] if spec is not None else ["--relight", str(scene_dir / "relight.exr")]
        cmd += [a.replace("{scene}", str(scene_dir)).replace("{input}", input_spec or "") for a in extra]
        try:
            proc = subprocess.run(cmd, capture_output=True, text=True, timeout=args.timeout)
        except (OSError, subprocess.TimeoutExpired) as e:
            return None, None, f"{shlex.join(cmd)}: {e}"
        if proc.returncode != 0 or not edited.exists():
            tail = (proc.stderr or proc.stdout)[-1500:]
            return None, None, f"{shlex.join(cmd)}: exit {proc.returncode}\n{tail}"
    try:
        seconds = json.loads(report.read_text())["seconds"]["total"]
    except (OSError, ValueError, KeyError, TypeError):
        seconds = None
    return rgb8(edited), seconds, None


def mean_or_none(values):
    return float(np.mean(values)) if values else None


def summarise(cases, methods):
    """Means of the completed cases, beats k / n over all cases, median seconds, per method."""
    table = {}
    for m in ["unchanged"] + list(methods):
        mine = [c for c in cases if c["method"] == m]
        ok = [c for c in mine if c["error"] is None]
        secs = [c["seconds"] for c in ok if c["seconds"] is not None]
        table[m] = {
            "cases": len(mine), "failed": len(mine) - len(ok),
            "l2": mean_or_none([c["l2"] for c in ok]),
            "ssim": mean_or_none([c["ssim"] for c in ok]),
            "grad_corr": mean_or_none([c["grad_corr"] for c in ok if c["grad_corr"] is not None]),
            "beats_unchanged": None if m == "unchanged" else sum(bool(c.get("beats")) for c in mine),
            "median_seconds": statistics.median(secs) if secs else None,
        }
    return table


def fmt(v, spec):
    return "—" if v is None else format(v, spec)


def markdown(table, first_col=None):
    head = ([first_col] if first_col else []) + ["method", "L2", "SSIM", "gradient corr.",
                                                 "beats unchanged on L2 and SSIM (k / n)", "median s", "failed"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for key, row in table:
        beats = "—" if row["beats_unchanged"] is None else f"{row['beats_unchanged']} / {row['cases']}"
        cells = list(key) + [fmt(row["l2"], ".1f"), fmt(row["ssim"], ".4f"), fmt(row["grad_corr"], ".3f"), beats,
                             fmt(row["median_seconds"], ".2f"), str(row["failed"])]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def write_sheet(out, cases, scenes, targets, methods, rows_max=12):
    """Rows of photo | truth | each method's edit for a few scenes x targets, spread over the scenes."""
    n_scenes = max(1, rows_max // len(targets))
    picked = [scenes[i] for i in sorted({round(k * (len(scenes) - 1) / max(1, n_scenes - 1))
                                         for k in range(min(n_scenes, len(scenes)))})]
    blank = Image.new("RGB", TILE, (90, 90, 90))
    failed = {(c["scene"], c["target"], c["method"]) for c in cases if c["error"]}
    rows = []
    for rec in picked:
        d = out / rec["name"]
        for t in targets:
            row = [labelled(tile(d / "photo.png"), f"{rec['name']} {rec['mesh']}"),
                   labelled(tile(d / f"truth_{t}.png"), t)]
            for m in methods:
                edited = out / "edits" / m / f"{rec['name']}-{t}" / scored_target(t)["image"]
                ok = (rec["name"], t, m) not in failed and edited.exists()
                row.append(tile(edited) if ok else labelled(blank.copy(), "failed"))
            rows.append(row)
    write_atomic(out / "edits" / "sheet.png",
                 lambda p: grid(rows, ["photo", "truth"] + list(methods)).save(p, format="PNG"))


# ---------------------------------------------------------------------------------------------
# What a perspective view is worth


def ggx_f1(n, wo, light, dirs, dw, alpha):
    """Eq. 2 for a GGX conductor with F = 1 and separable Smith G1 (the `chrome` target, exactly
    as the project renders `ggx:ALPHA:1,1,1`), per pixel normal n and view direction wo, under a
    [T, 3] light sampled at texel centres dirs with solid angles dw. numpy, in chunks."""
    out = np.zeros((n.shape[0], 3))
    a2 = alpha * alpha

    def g1(c):
        c = np.clip(c, 1e-6, 1.0)
        return 2.0 / (1.0 + np.sqrt(1.0 + a2 * (1.0 - c * c) / (c * c)))

    for s in range(0, n.shape[0], 2000):
        nn, oo = n[s:s + 2000], wo[s:s + 2000]
        ci, co = nn @ dirs.T, np.sum(nn * oo, 1)[:, None]
        h = oo[:, None, :] + dirs[None]
        h /= np.linalg.norm(h, axis=2, keepdims=True)
        ch = np.einsum("pk,ptk->pt", nn, h)
        d = a2 / (np.pi * (ch * ch * (a2 - 1.0) + 1.0) ** 2)
        f = d * g1(ci) * g1(co) / (4.0 * np.clip(ci, 1e-6, None) * np.clip(co, 1e-6, None))
        out[s:s + 2000] = np.where((ci > 0) & (co > 0), f * ci * dw[None], 0.0) @ light
    return out


def cmd_perspective(args):
    """Renders each scene's chrome truth with the layer's Eq. 2 from Mitsuba's own normals and the
    true light (`light.exr`), once with the layer's single view direction +z and once with each
    pixel's own direction towards the camera, and prints both errors against Mitsuba's path
    traced truth: what a perspective layer could gain, with everything else exact."""
    mi = mitsuba()
    out = Path(args.out)
    records = json.loads((out / "scenes.json").read_text())["scenes"][: args.scenes]
    plans = {p["name"]: p for p in scene_plans(len(records), Path(args.assets), None)}
    dirs, dw = texel_grid()
    dirs, dw = dirs.reshape(-1, 3), dw.reshape(-1)
    rows = []
    for rec in records:
        plan = plans[rec["name"]]
        obj = np.asarray(Image.open(out / rec["name"] / "mask.png")) > 127
        n, wo = camera_frame_geometry(mi, rec, plan, 640, 480)
        n, wo = n[obj], wo[obj]
        light = np.array(mi.Bitmap(str(out / rec["name"] / "light.exr")))[..., :3].reshape(-1, 3)
        truth = np.array(mi.Bitmap(str(out / rec["name"] / "truth_chrome.exr")))[..., :3][obj]
        errors = []
        for view in (np.tile([0.0, 0.0, 1.0], (len(n), 1)), wo):
            r = ggx_f1(n, view, light, dirs, dw, 0.15)
            errors.append(float(np.mean(np.abs(r - truth)) / np.mean(truth)))
        rows.append((rec["name"], rec["mesh"], rec["fov_deg_x"], *errors))
        print(f"{rec['name']} {rec['mesh']:<12} fov {rec['fov_deg_x']:.1f}: relative error orthographic "
              f"{errors[0]:.3f}, perspective {errors[1]:.3f}", flush=True)
    orth, persp = np.median([r[3] for r in rows]), np.median([r[4] for r in rows])
    print(f"\nmedian over {len(rows)} scenes: orthographic {orth:.3f}, perspective {persp:.3f} "
          f"(mean |layer − truth| / mean truth on the object, chrome, true normals and light)")


CEILING = "truth-reseeded"


def cmd_ceiling(args):
    """What a perfect edit scores: each target's truth rendered again with another seed (the same
    scene, camera, spp and exposure; only the path tracer's noise differs), scored against the
    truth exactly as an edit is. No method can expect more on these truths: the rows are the
    benchmark's ceiling, set by the Monte Carlo noise of a 64-spp truth. Writes
    sceneNN/truth_TARGET_reseed.{exr,png} (kept, so a rerun only scores) and DIR/ceiling.json."""
    mi = mitsuba()
    out = Path(args.out)
    settings = json.loads((out / "scenes.json").read_text())
    records = settings["scenes"][: args.scenes]
    plans = {p["name"]: p for p in scene_plans(len(records), Path(args.assets), None)}
    targets = [t for t in args.targets.split(",") if t]
    cases = []
    for rec in records:
        d = out / rec["name"]
        plan = plans[rec["name"]]
        camera = (np.array(rec["camera"]["origin"]), np.array(rec["camera"]["target"]))
        geom = None
        photo, obj = rgb8(d / "photo.png"), rgb8(d / "mask.png")[..., 0] > 127
        for t in targets:
            exr, png = d / f"truth_{t}_reseed.exr", d / f"truth_{t}_reseed.png"
            if not png.exists():
                if geom is None:
                    geom = load_mesh(rec["mesh_file"], plan["entry"])
                scene = build_scene(mi, geom, TARGETS[t]["mitsuba"], plan, camera, settings["width"],
                                    settings["height"], settings["spp"])
                radiance = render_radiance(mi, scene, rec["seed"] + 1)
                write_exr(mi, exr, radiance)
                write_png(png, srgb8(radiance * rec["exposure"]))
            truth = rgb8(d / f"truth_{t}.png")
            tg = grad_magnitude(truth)
            base = scores(photo, truth, obj, tg)
            s = scores(rgb8(png), truth, obj, tg)
            for method, sc in (("unchanged", base), (CEILING, s)):
                cases.append({"scene": rec["name"], "target": t, "method": method, "error": None, "seconds": None,
                              **sc, "beats": method != "unchanged" and s["l2"] < base["l2"] and s["ssim"] > base["ssim"]})
            print(f"{rec['name']} {t:<6} another render of the truth: L2 {s['l2']:7.1f}  SSIM {s['ssim']:.4f}  "
                  f"grad {fmt(s['grad_corr'], '.3f')}", flush=True)
    overall = summarise(cases, [CEILING])
    per_target = {t: summarise([c for c in cases if c["target"] == t], [CEILING]) for t in targets}
    print()
    print(markdown([((m,), row) for m, row in overall.items()]))
    print()
    print(markdown([((t, m), row) for t, table in per_target.items() for m, row in table.items()], first_col="target"))
    command = shlex.join([Path(sys.executable).name] + sys.argv)
    print(f"\nCommand: `{command}`")
    report = {"command": command, "seed_offset": 1, "means": overall, "per_target": per_target, "cases": cases}
    write_atomic(out / "ceiling.json", lambda p: p.write_text(json.dumps(report, indent=1)))


RELIT = "relit"  # `score --targets relit`: `--relight {scene}/relight.exr`, scored on relit.png
RELIGHT_TURN_DEG = 180.0


def scored_target(t):
    """What `score` does for target t: the spec given to `--material` (None: `--relight` the
    scene's relight.exr instead), the image it scores, and how the target names its truth."""
    if t == RELIT:
        return {"spec": None, "image": "relit.png",
                "kind": "relight", "about": {"relight": f"input material, its map turned {RELIGHT_TURN_DEG:.0f} deg"}}
    return {"spec": TARGETS[t]["spec"], "image": "edited.png",
            "kind": "exact" if TARGETS[t]["exact"] else "near", "about": TARGETS[t]}


def record_geometry(rec):
    """A scene's mesh entry and render plan rebuilt from its scenes.json record (recipe meshes
    and `--shapes` ones alike)."""
    known = MESHES.get(rec["mesh"])
    entry = MeshEntry(rec["mesh_file"], tuple(rec["mesh_axes"]), ((0, 1),),
                      face_normals=bool(known and known.face_normals and known.path in rec["mesh_file"]))
    plan = {"mesh": rec["mesh"], "fov": rec["fov_deg_x"], "map_path": rec["map_file"],
            "env_rotation": rec["env_rotation_deg"]}
    camera = (np.array(rec["camera"]["origin"]), np.array(rec["camera"]["target"]))
    return entry, plan, camera


def cmd_relights(args):
    """Relighting truths: each scene's object in its own input material under its own map turned
    by RELIGHT_TURN_DEG about the vertical axis (the same light's level, colour and detail, its
    key light elsewhere), path-traced with the scene's camera, spp and exposure. Writes
    sceneNN/relight.exr (that light as `matedit edit --relight` reads it: camera frame, +z
    towards the camera; the map's own radiance, like light.exr, so right at `--relight-level
    light`, not `given`, which reads the photo's linear units) and sceneNN/truth_relit.{exr,png};
    kept, so a rerun only fills gaps.
    `score --targets relit` then scores `matedit edit --relight {scene}/relight.exr`."""
    mi = mitsuba()
    out = Path(args.out)
    settings = json.loads((out / "scenes.json").read_text())
    for rec in settings["scenes"][: args.scenes]:
        d = out / rec["name"]
        d.mkdir(parents=True, exist_ok=True)
        t0 = time.time()
        turned = dict(rec, env_rotation_deg=(rec["env_rotation_deg"] + RELIGHT_TURN_DEG) % 360.0)
        if not (d / "relight.exr").exists():
            write_exr(mi, d / "relight.exr", camera_frame_light(mi, turned))
        exr, png = d / f"truth_{RELIT}.exr", d / f"truth_{RELIT}.png"
        if not exr.exists():
            entry, plan, camera = record_geometry(turned)
            scene = build_scene(mi, load_mesh(rec["mesh_file"], entry), rec["input_mitsuba"], plan, camera,
                                settings["width"], settings["height"], settings["spp"])
            write_exr(mi, exr, render_radiance(mi, scene, rec["seed"]))
        if not png.exists():
            radiance = np.array(mi.Bitmap(str(exr)), dtype=np.float32)[..., :3]
            write_png(png, srgb8(radiance * rec["exposure"]))
        print(f"{rec['name']} {rec['mesh']:<12} relit under {rec['map']} turned {RELIGHT_TURN_DEG:.0f} deg: "
              f"{time.time() - t0:.1f} s", flush=True)


REACH_SIGMAS = (0.02, 0.05, 0.15)


def cmd_reach(args):
    """What a composite that keeps the photo's own light and shade can reach at best: the photo's
    luminance times the truth's own change (truth luminance over photo luminance), blurred over the
    object at sigma = a share of its bounding square's side, in the truth's colour; and the same
    with one gain and one colour per edit (the truth's mean change). These use the truth, so they
    are bounds, not methods: `structure` is of this family with the change estimated by the layer,
    so it cannot score above the blurred rows (docs/PERFORMANCE.md, "What a photo-keeping
    composite can reach"). Writes DIR/reach.json."""
    from scipy.ndimage import gaussian_filter  # scikit-image's own dependency

    out = Path(args.out)
    records = json.loads((out / "scenes.json").read_text())["scenes"][: args.scenes]
    targets = [t for t in args.targets.split(",") if t]
    methods = [f"change blurred {round(100 * s)} %" for s in REACH_SIGMAS] + ["one gain and colour per edit"]
    cases = []
    for rec in records:
        d = out / rec["name"]
        photo = rgb8(d / "photo.png")
        obj = rgb8(d / "mask.png")[..., 0] > 127
        ys, xs = np.nonzero(obj)
        side = max(np.ptp(ys), np.ptp(xs)) + 1
        lin = srgb_decode(photo / 255)
        lp = luminance709(lin)
        weight = {s: gaussian_filter(obj.astype(np.float64), s * side) for s in REACH_SIGMAS}
        for t in targets:
            truth = rgb8(d / f"truth_{t}.png")
            tg = grad_magnitude(truth)
            base = scores(photo, truth, obj, tg)
            cases.append({"scene": rec["name"], "target": t, "method": "unchanged", "error": None,
                          "seconds": None, **base})
            tl = srgb_decode(truth / 255)
            lt = luminance709(tl)
            change = np.where(obj, (lt + 1e-4) / (lp + 1e-4), 0.0)  # tiny floor: black pixels of either
            colour = tl / np.maximum(lt, 1e-6)[..., None]
            mean_colour = tl[obj].mean(0) / max(lt[obj].mean(), 1e-6)
            gains = [gaussian_filter(change, s * side) / np.maximum(weight[s], 1e-9) for s in REACH_SIGMAS]
            gains.append(np.full_like(lp, lt[obj].mean() / max(lp[obj].mean(), 1e-6)))
            for i, (m, g) in enumerate(zip(methods, gains)):
                c = colour if i < len(REACH_SIGMAS) else mean_colour
                edit = np.where(obj[..., None], c * (lp * g)[..., None], lin)
                s = scores(srgb8(edit).astype(np.float64), truth, obj, tg)
                cases.append({"scene": rec["name"], "target": t, "method": m, "error": None, "seconds": None,
                              **s, "beats": s["l2"] < base["l2"] and s["ssim"] > base["ssim"]})
    overall = summarise(cases, methods)
    per_target = {t: summarise([c for c in cases if c["target"] == t], methods) for t in targets}
    print(markdown([((m,), row) for m, row in overall.items()]))
    print()
    print(markdown([((t, m), row) for t, table in per_target.items() for m, row in table.items()], first_col="target"))
    command = shlex.join([Path(sys.executable).name] + sys.argv)
    print(f"\nCommand: `{command}`")
    report = {"command": command, "sigmas": REACH_SIGMAS, "means": overall, "per_target": per_target, "cases": cases}
    write_atomic(out / "reach.json", lambda p: p.write_text(json.dumps(report, indent=1)))


LIGHT_VARIANTS = {
    "light_blocks.exr": "the true light averaged over 8x8-texel blocks (8x16 values: the key light's direction, "
                        "no detail)",
    "light_rows.exr": "the true light averaged over each row (elevation kept, azimuth lost)",
    "light_sh2.exr": "the true light projected on real spherical harmonics of order <= 2 (9 per channel), "
                     "negatives clamped",
    "light_background.exr": "the photo's own background, averaged per row of the map along a 40 deg pinhole's "
                            "directions, the nearest seen row above and below (no oracle)",
}


def sh2_basis(d):
    x, y, z = d[..., 0], d[..., 1], d[..., 2]
    return np.stack([0.282095 * np.ones_like(x), 0.488603 * y, 0.488603 * z, 0.488603 * x,
                     1.092548 * x * y, 1.092548 * y * z, 0.315392 * (3 * z * z - 1), 1.092548 * x * z,
                     0.546274 * (x * x - y * y)], -1)


def cmd_lights(args):
    """Writes variants of each scene's light next to `light.exr` (LIGHT_VARIANTS), so that `score`
    can measure which of the light's features an edit needs: `--light {scene}/light_blocks.exr`."""
    mi = mitsuba()
    out = Path(args.out)
    records = json.loads((out / "scenes.json").read_text())["scenes"][: args.scenes]
    dirs, dw = texel_grid()
    h, w = dw.shape
    basis = sh2_basis(dirs)
    for rec in records:
        d = out / rec["name"]
        light = np.array(mi.Bitmap(str(d / "light.exr")), dtype=np.float64)[..., :3]
        blocks = light.reshape(h // 8, 8, w // 8, 8, 3).mean(axis=(1, 3)).repeat(8, 0).repeat(8, 1)
        rows = np.repeat(light.mean(axis=1, keepdims=True), w, 1)
        sh = np.maximum(np.einsum("hwk,kc->hwc", basis, np.einsum("hwk,hwc,hw->kc", basis, light, dw)), 0.0)
        photo = srgb_decode(rgb8(d / "photo.png") / 255.0)
        py, px = np.mgrid[0:photo.shape[0], 0:photo.shape[1]] + 0.5
        t = np.tan(np.radians(40.0) / 2)
        ray = np.stack([(2 * px / photo.shape[1] - 1) * t, -(2 * py / photo.shape[0] - 1) * t * photo.shape[0]
                        / photo.shape[1], -np.ones_like(px)], -1)
        ray /= np.linalg.norm(ray, axis=-1, keepdims=True)
        seen = (rgb8(d / "mask.png")[..., 0] == 0) & (photo.max(-1) < srgb_decode(254 / 255))
        row = np.clip((np.arccos(np.clip(ray[..., 1], -1, 1)) / np.pi * h).astype(int), 0, h - 1)[seen]
        sums = np.zeros((h, 3))
        np.add.at(sums, row, photo[seen])
        count = np.bincount(row, minlength=h)
        have = np.flatnonzero(count > 20)
        background = np.zeros((h, w, 3))
        if len(have):
            nearest = have[np.abs(have[None, :] - np.arange(h)[:, None]).argmin(1)]
            background[:] = (sums[nearest] / count[nearest][:, None])[:, None, :]
        for name, array in [("light_blocks.exr", blocks), ("light_rows.exr", rows), ("light_sh2.exr", sh),
                            ("light_background.exr", background)]:
            write_exr(mi, d / name, array)
        print(f"{rec['name']}: {', '.join(LIGHT_VARIANTS)}", flush=True)


LPRIME_VARIANTS = ("same", "grey", "rows", "rows_grey", "rot90", "rot180", "rot270", "background",
                   "background_colour")


def wrapped_background(photo, obj, shape, sigma=3.0):
    """The photo's background wrapped around the sphere as Khan et al. 2006 do, `[h, w, 4]` (linear
    RGB and luminance) on a map of `shape`: the far hemisphere (z < 0, seen behind the object) is
    the photo stretched over azimuth and elevation +-90 deg, the near one its mirror image; the
    object's hole filled by a normalised Gaussian blur of the background; the map blurred by
    `sigma` texels."""
    from scipy.ndimage import gaussian_filter
    h, w = shape
    bg = (~obj).astype(np.float64)
    src = np.concatenate([photo, luminance709(photo)[..., None]], -1)
    s = max(photo.shape[:2]) / 16
    num = np.stack([gaussian_filter(src[..., c] * bg, s) for c in range(4)], -1)
    den = gaussian_filter(bg, s)[..., None]
    filled = np.where(bg[..., None] > 0, src, num / np.maximum(den, 1e-6))
    dirs, _ = texel_grid(h, w)
    far_z = -np.abs(dirs[..., 2])
    az = np.arctan2(dirs[..., 0], -far_z)
    el = np.arcsin(np.clip(dirs[..., 1], -1, 1))
    ph, pw = photo.shape[:2]
    x = np.clip((az / np.pi + 0.5) * (pw - 1), 0, pw - 1).astype(int)
    y = np.clip((0.5 - el / np.pi) * (ph - 1), 0, ph - 1).astype(int)
    wrapped = filled[y, x]
    return np.stack([gaussian_filter(wrapped[..., c], sigma, mode="wrap") for c in range(4)], -1)


def light_direction(light):
    """A map's luminance-weighted mean direction d = int Y w dW / int Y dW (`[h, w, 3]` linear RGB;
    |d| <= 1, 0 for light alike from every side), as the trainer's `light_direction` loss takes it."""
    dirs, dw = texel_grid(*light.shape[:2])
    y = np.maximum(luminance709(light), 0) * dw
    return (y[..., None] * dirs).sum((0, 1)) / max(y.sum(), 1e-30)


def cmd_lprime(args):
    """Writes variants of a method's L' (its edits' `env.exr`, in the photo's linear units, so
    that `--light FILE --light-level given` renders under the same light) next to each scene's
    files, as `lprime_METHOD_VARIANT.exr` (LPRIME_VARIANTS): the light as written; its mean colour
    made neutral; averaged around the vertical axis (+y, the map's rows); both; rotated about +y
    by 90, 180, 270 degrees (whole columns); times the photo's background wrapped around the
    sphere (`wrapped_background`), its luminance or (with L''s luminance) its colour, L''s mean
    kept. L' does not depend on the target, so the first target's edit is read. Prints each
    scene's key light (`light_direction`) of L' and of the true light and the angle between them,
    and how far each scene's L' (scaled to mean 1) is from the mean of them all, beside the same
    for the scenes' true lights: whether the network answers one layout for every photo."""
    mi = mitsuba()
    out = Path(args.out)
    records = json.loads((out / "scenes.json").read_text())["scenes"][: args.scenes]
    target = args.targets.split(",")[0]
    ours, truths = [], []
    for rec in records:
        d = out / rec["name"]
        env = out / "edits" / args.method / f"{rec['name']}-{target}" / "env.exr"
        if not env.exists():
            raise SystemExit(f"{env}: missing; run `score` with the method {args.method} first")
        light = np.array(mi.Bitmap(str(env)), dtype=np.float64)[..., :3]
        w = light.shape[1]
        rows = np.repeat(light.mean(axis=1, keepdims=True), w, 1)
        neutral = lambda x: x * (x.mean() / np.maximum(x.reshape(-1, 3).mean(0), 1e-30))
        photo = srgb_decode(rgb8(d / "photo.png") / 255.0)
        wrapped = wrapped_background(photo, rgb8(d / "mask.png")[..., 0] > 127, light.shape[:2])
        keep_mean = lambda x: x * (light.mean() / max(x.mean(), 1e-30))
        variants = {"same": light, "grey": neutral(light), "rows": rows, "rows_grey": neutral(rows),
                    "rot90": np.roll(light, w // 4, 1), "rot180": np.roll(light, w // 2, 1),
                    "rot270": np.roll(light, 3 * w // 4, 1),
                    "background": keep_mean(light * wrapped[..., 3:]),
                    "background_colour": keep_mean(light.mean(-1, keepdims=True) * wrapped[..., :3])}
        for name in LPRIME_VARIANTS:
            write_exr(mi, d / f"lprime_{args.method}_{name}.exr", variants[name])
        ours.append(light / max(light.mean(), 1e-30))
        true = np.array(mi.Bitmap(str(d / "light.exr")), dtype=np.float64)[..., :3]
        truths.append(true / max(true.mean(), 1e-30))
    angles = []
    for rec, lp, true in zip(records, ours, truths):
        a, b = light_direction(lp), light_direction(true)
        cos = a @ b / max(np.linalg.norm(a) * np.linalg.norm(b), 1e-30)
        angles.append(np.degrees(np.arccos(np.clip(cos, -1, 1))))
        print(f"{rec['name']}: key light (luminance-weighted mean direction) of L' "
              f"({a[0]:+.2f}, {a[1]:+.2f}, {a[2]:+.2f}) |d| {np.linalg.norm(a):.2f}, of the true light "
              f"({b[0]:+.2f}, {b[1]:+.2f}, {b[2]:+.2f}) |d| {np.linalg.norm(b):.2f}: {angles[-1]:.0f} deg apart",
              flush=True)
    print(f"key light's direction, L' against the true light: median {np.median(angles):.0f} deg, "
          f"mean {np.mean(angles):.0f} deg", flush=True)
    for label, maps in [(f"L' of {args.method}", np.array(ours)), ("the true lights", np.array(truths))]:
        mean = maps.mean(0)
        dev = np.sqrt(((maps - mean) ** 2).mean(axis=(1, 2, 3))) / np.sqrt((mean ** 2).mean())
        print(f"{label}: RMS distance of each scene's map (mean 1) from their mean, relative: "
              f"{' '.join(f'{v:.3f}' for v in dev)}", flush=True)
    print(f"wrote {', '.join(f'lprime_{args.method}_{v}.exr' for v in LPRIME_VARIANTS)} in each scene")


def cmd_combine(args):
    """Scores combinations of methods' edits already written by `score`. `--how mean`: each
    case's edits averaged in linear light and encoded to 8 bits again (an ensemble); `fit`: per
    scene, the method whose I' = R(n', m', L') is closest to the framed photo I (`i_prime.exr`
    against `input.exr`, the first target's edit; what an edit could choose without the truth);
    `truth`: per scene, the method with the lowest mean L2 over the targets (an upper bound)."""
    out = Path(args.out)
    scenes = json.loads((out / "scenes.json").read_text())["scenes"][: args.scenes]
    targets = [t for t in args.targets.split(",") if t]
    mi = mitsuba() if args.how == "fit" else None
    cases = []
    for rec in scenes:
        d = out / rec["name"]
        obj = rgb8(d / "mask.png")[..., 0] > 127
        photo = rgb8(d / "photo.png")
        edits = {}
        for m in args.methods:
            for t in targets:
                path = out / "edits" / m / f"{rec['name']}-{t}" / "edited.png"
                if not path.exists():
                    raise SystemExit(f"{path}: missing; run `score` with the method {m} first")
                edits[m, t] = rgb8(path)
        truth = {t: rgb8(d / f"truth_{t}.png") for t in targets}
        tg = {t: grad_magnitude(truth[t]) for t in targets}
        if args.how == "fit":
            def misfit(m):
                e = out / "edits" / m / f"{rec['name']}-{targets[0]}"
                i = np.array(mi.Bitmap(str(e / "input.exr")), dtype=np.float64)[..., :3]
                ip = np.array(mi.Bitmap(str(e / "i_prime.exr")), dtype=np.float64)[..., :3]
                inside = i.sum(-1) > 0
                return float(((ip - i)[inside] ** 2).mean())
            chosen = min(args.methods, key=misfit)
        elif args.how == "truth":
            chosen = min(args.methods, key=lambda m: np.mean([scores(edits[m, t], truth[t], obj, tg[t])["l2"]
                                                            for t in targets]))
        for t in targets:
            if args.how == "mean":
                lin = np.mean([srgb_decode(edits[m, t] / 255.0) for m in args.methods], axis=0)
                edit = srgb8(lin).astype(np.float64)
            else:
                edit = edits[chosen, t]
            s, base = scores(edit, truth[t], obj, tg[t]), scores(photo, truth[t], obj, tg[t])
            cases.append({"scene": rec["name"], "target": t, "method": args.how,
                          "chosen": None if args.how == "mean" else chosen, "error": None, "seconds": None,
                          **s, "beats": s["l2"] < base["l2"] and s["ssim"] > base["ssim"]})
        if args.how != "mean":
            print(f"{rec['name']}: {chosen}", flush=True)
    row = summarise(cases, [args.how])[args.how]
    print(f"{args.how} of {' '.join(args.methods)}: L2 {row['l2']:.1f}  SSIM {row['ssim']:.4f}  "
          f"grad {row['grad_corr']:.3f}  beats unchanged {row['beats_unchanged']} / {row['cases']}")
    report = {"command": shlex.join([Path(sys.executable).name] + sys.argv), "how": args.how,
              "methods": args.methods, "means": row, "cases": cases}
    json_path = Path(args.json) if args.json else out / "combine.json"
    write_atomic(json_path, lambda p: p.write_text(json.dumps(report, indent=1)))
    print(f"Command: `{report['command']}`; per-case results: {json_path}")


def cmd_score(args):
    out = Path(args.out)
    scenes = json.loads((out / "scenes.json").read_text())["scenes"][: args.scenes]  # None: all
    targets = [t for t in args.targets.split(",") if t]
    unknown = set(targets) - set(TARGETS) - {RELIT}
    if unknown:
        raise SystemExit(f"--targets: unknown {sorted(unknown)} (known: {', '.join(TARGETS)}, {RELIT})")
    methods = parse_methods(args.methods)
    if RELIT in targets:
        missing = [r["name"] for r in scenes if not (out / r["name"] / f"truth_{RELIT}.png").exists()]
        if missing:
            raise SystemExit(f"--targets {RELIT}: no relighting truth in {', '.join(missing[:3])}"
                             f"{' …' if len(missing) > 3 else ''}: run `photo_bench.py relights --out {out}` first")
    cases = []
    for rec in scenes:
        d = out / rec["name"]
        photo = rgb8(d / "photo.png")
        obj = rgb8(d / "mask.png")[..., 0] > 127
        for t in targets:
            truth = rgb8(d / f"truth_{t}.png")
            truth_grad = grad_magnitude(truth)
            base = scores(photo, truth, obj, truth_grad)
            cases.append({"scene": rec["name"], "mesh": rec["mesh"], "target": t, "method": "unchanged",
                          "error": None, "seconds": None, **base})
            for m, extra in methods.items():
                edited, secs, err = run_edit(args, d, scored_target(t)["spec"], out / "edits" / m / f"{rec['name']}-{t}",
                                             extra, project_spec(rec["input_mitsuba"]))
                if err is None and edited.shape != photo.shape:
                    err = (f"{scored_target(t)['image']} is {edited.shape[1]}x{edited.shape[0]}, "
                           f"the photo {photo.shape[1]}x{photo.shape[0]}")
                case = {"scene": rec["name"], "mesh": rec["mesh"], "target": t, "method": m, "error": err,
                        "seconds": secs, "beats": False}
                label = f"{rec['name']} {t:<6} {m:<12}"
                if err is None:
                    s = scores(edited, truth, obj, truth_grad)
                    case.update(s, beats=s["l2"] < base["l2"] and s["ssim"] > base["ssim"])
                    print(f"{label} L2 {s['l2']:8.1f}  SSIM {s['ssim']:.4f}  grad {fmt(s['grad_corr'], '.3f')}  "
                          f"{fmt(secs, '.2f')} s", flush=True)
                else:
                    print(f"{label} FAILED: {err.strip().splitlines()[-1] if err.strip() else err}", file=sys.stderr,
                          flush=True)
                cases.append(case)
    overall = summarise(cases, methods)
    per_target = {t: summarise([c for c in cases if c["target"] == t], methods) for t in targets}
    command = shlex.join([Path(sys.executable).name] + sys.argv)
    print(f"\n{len(scenes)} scenes x {len(targets)} targets, scored on the object's pixels against Mitsuba truths\n")
    print(markdown([((m,), row) for m, row in overall.items()]))
    print()
    print(markdown([((f"{t} ({scored_target(t)['kind']})", m), row)
                    for t, table in per_target.items() for m, row in table.items()], first_col="target"))
    print(f"\nCommand: `{command}`")
    failures = [c for c in cases if c["error"]]
    if failures:
        print(f"\n{len(failures)} edits failed; first: {failures[0]['error'][-800:]}", file=sys.stderr)
    results = {"command": command, "scenes": len(scenes), "targets": {t: scored_target(t)["about"] for t in targets},
               "methods": {m: shlex.join(a) for m, a in methods.items()}, "means": overall,
               "per_target": per_target, "cases": cases}
    json_path = Path(args.json) if args.json else out / ("results_relit.json" if RELIT in targets else "results.json")
    write_atomic(json_path, lambda p: p.write_text(json.dumps(results, indent=1)))
    write_sheet(out, cases, scenes, targets, list(methods))
    print(f"per-case results: {json_path}; sheet: {out / 'edits' / 'sheet.png'}")


def cmd_levels(args):
    """How far each method's edits are from the truth's level, and what its scores would be at the
    truth's level. The level error of a case is mean(linear edit) / mean(linear truth) over the
    object's pixels; a scene's is the geometric mean over its targets (one light, one error). The
    scores "at the truth's level" scale each edit's linear object pixels by the inverse of its
    case's error and encode them to 8 bits again: an upper bound that uses the truth, not a
    method, measuring what the edit's level costs against everything else."""
    out = Path(args.out)
    scenes = json.loads((out / "scenes.json").read_text())["scenes"][: args.scenes]
    targets = [t for t in args.targets.split(",") if t]
    report = {"command": shlex.join([Path(sys.executable).name] + sys.argv), "methods": {}}
    # Each case's truth, its gradients and the unchanged photo's scores, once for every method.
    truths = []
    for rec in scenes:
        d = out / rec["name"]
        obj = rgb8(d / "mask.png")[..., 0] > 127
        photo = rgb8(d / "photo.png")
        for t in targets:
            truth = rgb8(d / f"truth_{t}.png")
            tg = grad_magnitude(truth)
            truths.append((rec["name"], t, obj, truth, tg, scores(photo, truth, obj, tg)))
    for m in args.methods:
        cases, errors = [], {}
        for name, t, obj, truth, tg, base in truths:
            path = out / "edits" / m / f"{name}-{t}" / "edited.png"
            if not path.exists():
                raise SystemExit(f"{path}: missing; run `score` with the method {m} first")
            edit = rgb8(path)
            lin, lin_truth = srgb_decode(edit / 255.0), srgb_decode(truth / 255.0)
            error = float(lin[obj].mean() / max(lin_truth[obj].mean(), 1e-12))
            errors.setdefault(name, []).append(error)
            levelled = edit.copy()
            levelled[obj] = srgb8(lin[obj] / max(error, 1e-12))
            s = scores(levelled, truth, obj, tg)
            cases.append({"scene": name, "target": t, "level_error": error, **s,
                          "beats": s["l2"] < base["l2"] and s["ssim"] > base["ssim"]})
        per_scene = [(name, float(np.exp(np.mean(np.log(e))))) for name, e in errors.items()]
        logs = np.log([e for _, e in per_scene])
        row = {"log_rms": float(np.sqrt(np.mean(logs ** 2))), "bias": float(np.exp(logs.mean())),
               "per_scene": dict(per_scene),
               "at_truth_level": {"l2": float(np.mean([c["l2"] for c in cases])),
                                  "ssim": float(np.mean([c["ssim"] for c in cases])),
                                  "grad_corr": float(np.mean([c["grad_corr"] for c in cases
                                                              if c["grad_corr"] is not None])),
                                  "beats_unchanged": int(sum(c["beats"] for c in cases)), "cases": len(cases)},
               "cases": cases}
        report["methods"][m] = row
        a = row["at_truth_level"]
        print(f"{m}: level error log-RMS {row['log_rms']:.3f} (x{np.exp(row['log_rms']):.2f}), bias x{row['bias']:.2f}; "
              f"per scene {' '.join(f'{e:.2f}' for _, e in per_scene)}", flush=True)
        print(f"  at the truth's level: L2 {a['l2']:.1f}  SSIM {a['ssim']:.4f}  grad {a['grad_corr']:.3f}  "
              f"beats unchanged {a['beats_unchanged']} / {a['cases']}", flush=True)
    json_path = Path(args.json) if args.json else out / "levels.json"
    write_atomic(json_path, lambda p: p.write_text(json.dumps(report, indent=1)))
    print(f"Command: `{report['command']}`; per-case results: {json_path}")

def sample_framed(grid, framing, xs, ys):
    """An edit's `[size, size, 3]` normals (written over its framing square) at photo pixels
    (xs, ys), bilinearly, renormalised: what the detail path starts from at each pixel."""
    size = grid.shape[0]
    u = np.clip((xs + 0.5 - framing["x0"]) / framing["side"] * size - 0.5, 0, size - 1)
    v = np.clip((ys + 0.5 - framing["y0"]) / framing["side"] * size - 0.5, 0, size - 1)
    u0, v0 = np.minimum(np.floor(u).astype(int), size - 2), np.minimum(np.floor(v).astype(int), size - 2)
    fu, fv = (u - u0)[:, None], (v - v0)[:, None]
    n = ((1 - fu) * (1 - fv) * grid[v0, u0] + fu * (1 - fv) * grid[v0, u0 + 1]
         + (1 - fu) * fv * grid[v0 + 1, u0] + fu * fv * grid[v0 + 1, u0 + 1])
    return n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)


def cmd_normals(args):
    """How far each method's n* (its `normals.exr`, at the network's resolution over the edit's
    framing) is from the scene's path-traced normals (`normals.exr` of `render`): the median
    angle over each object's pixels, and the mean of those medians. n* does not depend on the
    target, so the first target's edit is read."""
    mi = mitsuba()
    out = Path(args.out)
    scenes = json.loads((out / "scenes.json").read_text())["scenes"][: args.scenes]
    target = args.targets.split(",")[0]
    report = {"command": shlex.join([Path(sys.executable).name] + sys.argv), "target": target, "methods": {}}
    truths = []
    for rec in scenes:
        d = out / rec["name"]
        obj = rgb8(d / "mask.png")[..., 0] > 127
        ys, xs = np.nonzero(obj)
        truth = np.array(mi.Bitmap(str(d / "normals.exr")), dtype=np.float64)[..., :3][ys, xs]
        truth /= np.maximum(np.linalg.norm(truth, axis=1, keepdims=True), 1e-12)
        truths.append((rec["name"], xs, ys, truth))
    for m in args.methods:
        medians = {}
        for name, xs, ys, truth in truths:
            d = out / "edits" / m / f"{name}-{target}"
            if not (d / "normals.exr").exists():
                raise SystemExit(f"{d / 'normals.exr'}: missing; run `score` with the method {m} first")
            framing = json.loads((d / "report.json").read_text())["framing"]
            grid = np.array(mi.Bitmap(str(d / "normals.exr")), dtype=np.float64)[..., :3]
            n = sample_framed(grid, framing, xs, ys)
            angles = np.degrees(np.arccos(np.clip((n * truth).sum(axis=1), -1.0, 1.0)))
            medians[name] = float(np.median(angles))
        mean = float(np.mean(list(medians.values())))
        report["methods"][m] = {"median_deg": medians, "mean_of_medians_deg": mean}
        print(f"{m}: median angle per object {' '.join(f'{a:.1f}' for a in medians.values())}; "
              f"mean {mean:.1f}°", flush=True)
    json_path = Path(args.json) if args.json else out / "normals.json"
    write_atomic(json_path, lambda p: p.write_text(json.dumps(report, indent=1)))
    print(f"Command: `{report['command']}`; per-object results: {json_path}")

# ---------------------------------------------------------------------------------------------


def square(text):
    n = int(text)
    if n < 1 or round(n**0.5) ** 2 != n:
        raise argparse.ArgumentTypeError(f"{n} is not a square (16, 36, 64, ...)")
    return n


def main():
    common = argparse.ArgumentParser(add_help=False)
    common.add_argument("--out", required=True, help="benchmark folder (scenes, edits, results)")
    common.add_argument("--scenes", type=int, help="render: how many scenes to make (default 10, plus --shapes); "
                        "score: the first N scenes of scenes.json (default all)")
    render = argparse.ArgumentParser(add_help=False)
    render.add_argument("--assets", default=str(Path(__file__).resolve().parents[2] / "shared" / "eval-assets"),
                        help="the eval-assets folder (meshes/, envmaps/)")
    render.add_argument("--spp", type=square, default=64, help="samples per pixel, a square (multijitter sampler)")
    render.add_argument("--width", type=int, default=640)
    render.add_argument("--height", type=int, default=480)
    render.add_argument("--shapes", help="also one scene per OBJ of this folder (`datagen assets shapes --out DIR`)")
    score = argparse.ArgumentParser(add_help=False)
    score.add_argument("--matedit", required=True, help="the matedit binary")
    score.add_argument("--model", required=True, help="the model passed to matedit edit --model")
    score.add_argument("--methods", nargs="+", default=DEFAULT_METHODS, metavar="NAME=ARGS",
                       help="methods as NAME=extra arguments of matedit edit (split on spaces); default: "
                       + "; ".join(DEFAULT_METHODS))
    score.add_argument("--targets", default=",".join(TARGETS),
                       help=f"comma-separated targets of {', '.join(TARGETS)}, or {RELIT} (`relights` first)")
    score.add_argument("--json", help=f"per-case results (default DIR/results.json; DIR/results_{RELIT}.json "
                       f"with {RELIT})")
    score.add_argument("--timeout", type=float, default=3600, help="seconds allowed per edit")
    score.add_argument("--reuse", action="store_true", help="keep edits already present instead of rerunning them")
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest="command", required=True)
    sub.add_parser("render", parents=[common, render], help="path-trace the photos, masks and truths")
    sub.add_parser("score", parents=[common, score], help="run matedit edit on every photo and score it")
    sub.add_parser("all", parents=[common, render, score], help="render, then score")
    sub.add_parser("perspective", parents=[common, render],
                   help="the layer with true normals and light, orthographic against per-pixel views")
    sub.add_parser("lights", parents=[common], help="variants of each scene's true light (what an edit needs of it)")
    ceiling = sub.add_parser("ceiling", parents=[common, render],
                             help="each truth rendered again with another seed and scored: what a perfect edit gets")
    ceiling.add_argument("--targets", default=",".join(TARGETS), help="comma-separated targets of " + ", ".join(TARGETS))
    sub.add_parser("relights", parents=[common],
                   help="relighting truths: each object under its own map turned 180 deg (then score --targets relit)")
    reach = sub.add_parser("reach", parents=[common],
                           help="what a composite keeping the photo's light and shade reaches given the truth's change")
    reach.add_argument("--targets", default=",".join(TARGETS), help="comma-separated targets of " + ", ".join(TARGETS))
    levels = sub.add_parser("levels", parents=[common],
                            help="each method's level error against the truths, and its scores at the truth's level")
    levels.add_argument("--methods", nargs="+", required=True, metavar="NAME",
                        help="methods whose edits `score` wrote (DIR/edits/NAME/)")
    levels.add_argument("--targets", default=",".join(TARGETS), help="comma-separated targets of " + ", ".join(TARGETS))
    levels.add_argument("--json", help="per-case results (default DIR/levels.json)")
    normals = sub.add_parser("normals", parents=[common],
                             help="each method's n* against the scene's path-traced normals (median angle)")
    normals.add_argument("--methods", nargs="+", required=True, metavar="NAME",
                         help="methods whose edits `score` wrote (DIR/edits/NAME/)")
    normals.add_argument("--targets", default=",".join(TARGETS), help="the first of these is read")
    normals.add_argument("--json", help="per-object results (default DIR/normals.json)")
    lprime = sub.add_parser("lprime", parents=[common],
                            help="variants of a method's L' (neutral, without azimuth, rotated) for --light")
    lprime.add_argument("--method", required=True, help="a method whose edits `score` wrote (DIR/edits/NAME/)")
    lprime.add_argument("--targets", default=",".join(TARGETS), help="the first of these is read")
    combine = sub.add_parser("combine", parents=[common],
                             help="score methods' edits combined: averaged, or one chosen per scene")
    combine.add_argument("--methods", nargs="+", required=True, metavar="NAME",
                         help="methods whose edits `score` wrote (DIR/edits/NAME/)")
    combine.add_argument("--how", choices=("mean", "fit", "truth"), default="mean")
    combine.add_argument("--targets", default=",".join(TARGETS), help="comma-separated targets of " + ", ".join(TARGETS))
    combine.add_argument("--json", help="per-case results (default DIR/combine.json)")
    args = parser.parse_args()
    if args.command in ("render", "all"):
        cmd_render(args)
    if args.command in ("score", "all"):
        cmd_score(args)
    if args.command == "perspective":
        cmd_perspective(args)
    if args.command == "lights":
        cmd_lights(args)
    if args.command == "normals":
        cmd_normals(args)
    if args.command == "levels":
        cmd_levels(args)
    if args.command == "ceiling":
        cmd_ceiling(args)
    if args.command == "relights":
        cmd_relights(args)
    if args.command == "reach":
        cmd_reach(args)
    if args.command == "lprime":
        cmd_lprime(args)
    if args.command == "combine":
        cmd_combine(args)


if __name__ == "__main__":
    main()
