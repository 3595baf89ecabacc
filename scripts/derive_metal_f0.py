#!/usr/bin/env python3
"""Derive normal-incidence reflectance F0 (linear RGB) of real metals from measured complex
indices of refraction, for the material library (assets/materials/metals_f0.json).

Source data: the optical constants that ship with Mitsuba 3 (`mitsuba/data/ior/*.eta.spd` and
`*.k.spd`: luxpop.com and Palik's Handbook of Optical Constants of Solids), wavelength in nm.
Method: F0(λ) = ((n−1)² + k²) / ((n+1)² + k²) at every tabulated wavelength, linearly
interpolated to 1 nm, then averaged over the bands B = 400–500 nm, G = 500–600 nm,
R = 600–700 nm (a box approximation of the sRGB primaries, documented as such).

Usage: pip install mitsuba && python3 scripts/derive_metal_f0.py > assets/materials/metals_f0.json
"""
import json, os, sys

import mitsuba

METALS = {  # file stem -> display name
    "Ag": "silver", "Al": "aluminium", "Au": "gold", "Cu": "copper", "Cr": "chromium",
    "Ni_palik": "nickel", "W": "tungsten", "Ir": "iridium", "Rh": "rhodium", "Mo": "molybdenum",
    "Ta": "tantalum", "Be": "beryllium", "Nb": "niobium", "V_palik": "vanadium", "TiN": "titanium-nitride",
    "Hg": "mercury",
}
DIR = os.path.join(os.path.dirname(mitsuba.__file__), "data", "ior")


def read(path):
    pts = []
    for line in open(path):
        line = line.strip()
        if line and not line.startswith("#"):
            a, b = line.split()[:2]
            pts.append((float(a), float(b)))
    return pts


def at(pts, lam):
    for (x0, y0), (x1, y1) in zip(pts, pts[1:]):
        if x0 <= lam <= x1:
            return y0 + (y1 - y0) * (lam - x0) / (x1 - x0)
    raise ValueError(f"{lam} nm outside the table")


def band_f0(eta, k, lo, hi):
    vals = []
    for lam in range(lo, hi + 1):
        n, kk = at(eta, lam), at(k, lam)
        vals.append(((n - 1) ** 2 + kk ** 2) / ((n + 1) ** 2 + kk ** 2))
    return sum(vals) / len(vals)


out = {"source": f"mitsuba {mitsuba.__version__} data/ior (luxpop.com, Palik)", "method": __doc__.split("Method: ")[1].split("\n\n")[0].replace("\n", " "), "metals": {}}
for stem, name in METALS.items():
    eta, k = read(os.path.join(DIR, stem + ".eta.spd")), read(os.path.join(DIR, stem + ".k.spd"))
    out["metals"][name] = {"file": stem, "f0_rgb": [round(band_f0(eta, k, lo, hi), 4) for lo, hi in ((600, 700), (500, 600), (400, 500))]}
json.dump(out, sys.stdout, indent=1)
print()
