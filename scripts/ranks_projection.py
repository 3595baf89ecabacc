#!/usr/bin/env python3
"""A projection, not a measurement: images/s of data-parallel training on N = 1…64 GPUs, from
a GPU step time measured on one device and the gradient all-reduce measured on this machine
(`mpirun -np 2 trainer bench-ranks`), scaled by bandwidth.

A ring all-reduce moves 2(N−1)/N of the buffer through every rank. Measured here, 2 ranks moved
it at an effective rate (buffer / time) well below this machine's memcpy: MPI's shared-memory
transport copies in and out and sums. That rate is scaled by the ratio of a node's memcpy
bandwidth per rank to this machine's; across nodes the rate is also capped by the network
link. Every step also copies the gradients off the GPU and back (PCIe): Burn 0.22's buffers
cannot be handed to NCCL or a CUDA-aware MPI.

Weak scaling: every GPU keeps its batch (the global batch grows with N), so the compute per
step is the one-device step. Strong scaling (the global batch fixed) is printed too.

    python3 scripts/ranks_projection.py --step 0.93 --batch 16 --buffer-mib 256.6 --here-ms 267.0 --memcpy-here 13.4
"""
import argparse


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--step", type=float, required=True, help="one device's step, seconds (H100 joint step: 0.93)")
    ap.add_argument("--batch", type=int, required=True, help="images per device and step")
    ap.add_argument("--buffer-mib", type=float, required=True, help="the gradient buffer (bench-ranks)")
    ap.add_argument("--here-ms", type=float, required=True, help="the 2-rank all-reduce measured here, ms")
    ap.add_argument("--memcpy-here", type=float, required=True, help="this machine's memcpy, GB/s")
    ap.add_argument("--node-memcpy", type=float, nargs="+", default=[13.4, 75.0, 150.0],
                    help="a node's memcpy bandwidth per rank, GB/s (one projection each)")
    ap.add_argument("--link", type=float, default=12.5, help="the network link, GB/s (100 Gb/s: 12.5)")
    ap.add_argument("--pcie", type=float, default=25.0, help="GPU↔host copies, GB/s (PCIe 4.0 x16: about 25)")
    ap.add_argument("--gpus-per-node", type=int, default=8)
    a = ap.parse_args()
    size = a.buffer_mib * 2**20
    pcie = 2 * size / (a.pcie * 1e9)
    for node in a.node_memcpy:
        rate = size / (a.here_ms / 1e3) * node / a.memcpy_here / 1e9
        print(f"\nnode memcpy {node:g} GB/s per rank (all-reduce rate {rate:.2f} GB/s), link {a.link:g} GB/s, PCIe {a.pcie:g} GB/s "
              f"({a.buffer_mib:g} MiB of gradients; step {a.step:g} s for {a.batch} images)")
        print("| GPUs | all-reduce + copies (ms) | weak scaling: images/s | its share of the step | "
              f"strong scaling (global batch {a.batch}): images/s | its share |")
        print("|---|---|---|---|---|---|")
        for n in (1, 2, 4, 8, 16, 32, 64):
            # The effective rate measured here (at 2 ranks a ring moves the buffer once).
            rate = size / (a.here_ms / 1e3) * node / a.memcpy_here
            if n > a.gpus_per_node:
                rate = min(rate, a.link * 1e9)
            t = 0.0 if n == 1 else 2 * (n - 1) / n * size / rate + pcie
            weak = n * a.batch / (a.step + t)
            if a.batch % n == 0:
                strong_step = a.step / n + t
                strong = f"{a.batch / strong_step:.0f} | {t / strong_step:.0%}"
            else:
                strong = "– | –"
            print(f"| {n} | {t * 1e3:.0f} | {weak:.0f} | {t / (a.step + t):.1%} | {strong} |")


if __name__ == "__main__":
    main()
