#!/usr/bin/env python3
"""An independent evaluation of the MERL neural BRDFs (`*.nbrdf.json`), for the tests.

Pure Python (no numpy): MERL's own `std_coords_to_half_diff_coords` and `rotate_vector`, written
after MERL's C reader, then the 6 -> 21 -> 21 -> 3 perceptron of the files' README in float64.

Reads JSON from stdin: {"files": [PATH, ...], "pairs": [[wi_x, wi_y, wi_z, wo_x, wo_y, wo_z], ...]}
and prints {"values": [[[r, g, b] per pair] per file]} (0 where either direction is at or below
the surface).
"""
import json
import math
import sys


def rotate_vector(v, axis, angle):
    c, s = math.cos(angle), math.sin(angle)
    d = v[0] * axis[0] + v[1] * axis[1] + v[2] * axis[2]
    cross = (axis[1] * v[2] - axis[2] * v[1], axis[2] * v[0] - axis[0] * v[2], axis[0] * v[1] - axis[1] * v[0])
    return tuple(v[k] * c + axis[k] * d * (1 - c) + cross[k] * s for k in range(3))


def half_diff(wi, wo):
    h = tuple(wi[k] + wo[k] for k in range(3))
    n = math.sqrt(sum(x * x for x in h))
    h = tuple(x / n for x in h)
    theta_h = math.acos(max(-1.0, min(1.0, h[2])))
    phi_h = math.atan2(h[1], h[0])
    temp = rotate_vector(wi, (0.0, 0.0, 1.0), -phi_h)
    diff = rotate_vector(temp, (0.0, 1.0, 0.0), -theta_h)
    theta_d = math.acos(max(-1.0, min(1.0, diff[2])))
    phi_d = math.atan2(diff[1], diff[0])
    return theta_h, theta_d, phi_d


def evaluate(net, wi, wo):
    if wi[2] <= 0 or wo[2] <= 0:
        return [0.0, 0.0, 0.0]
    th, td, pd = half_diff(wi, wo)
    x = [math.sin(th), 0.0, math.cos(th), math.sin(td) * math.cos(pd), math.sin(td) * math.sin(pd), math.cos(td)]
    for i, layer in enumerate(net["layers"]):
        w, b = layer["weight"], layer["bias"]
        y = [b[o] + sum(x[r] * w[r][o] for r in range(len(x))) for o in range(len(b))]
        x = [max(v, 0.0) for v in y] if i < 2 else y
    return [max(math.expm1(v), 0.0) for v in x]


def main():
    request = json.load(sys.stdin)
    values = []
    for path in request["files"]:
        with open(path) as f:
            net = json.load(f)
        values.append([evaluate(net, p[:3], p[3:]) for p in request["pairs"]])
    json.dump({"values": values}, sys.stdout)


if __name__ == "__main__":
    main()
