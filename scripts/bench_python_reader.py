#!/usr/bin/env python3
"""Reading throughput of the Python package (python/, `matedit_data`) on a dataset, beside the
Rust trainer's loader on the same split: samples/s, median of --runs passes, checksums verified.

    python scripts/bench_python_reader.py DATASET [--split train] [--runs 3] [--trainer target/release/trainer]

Rows: numpy (iterating the split in one process), PyTorch DataLoader over SampleDataset and over
ShardDataset with 1 and 2 workers (batch 16, matedit_data.torch.collate), and `trainer
bench-loader` with 1 and 2 decoding threads. Figures: docs/PERFORMANCE.md, "Reading a dataset".
"""

import argparse
import re
import statistics
import subprocess
import time


def rate(fn, runs):
    out = []
    for _ in range(runs):
        t = time.perf_counter()
        n = fn()
        out.append(n / (time.perf_counter() - t))
    return statistics.median(out), n


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("dataset")
    ap.add_argument("--split", default="train")
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--trainer", default="target/release/trainer")
    a = ap.parse_args()

    from matedit_data import open_dataset

    ds = open_dataset(a.dataset)
    size = next(iter(ds.split(a.split))).size
    rows = []

    def numpy_pass():
        return sum(1 for _ in open_dataset(a.dataset).split(a.split))

    rows.append(("numpy, 1 process", *rate(numpy_pass, a.runs)))
    try:
        from torch.utils.data import DataLoader

        from matedit_data.torch import SampleDataset, ShardDataset, collate

        for name, make in (("SampleDataset", SampleDataset), ("ShardDataset", ShardDataset)):
            for workers in (1, 2):
                def loader_pass(make=make, workers=workers):
                    dl = DataLoader(make(a.dataset, a.split), batch_size=16, num_workers=workers, collate_fn=collate)
                    return sum(len(b["ids"]) for b in dl)

                rows.append((f"PyTorch DataLoader, {name}, {workers} worker{'s' if workers > 1 else ''}", *rate(loader_pass, a.runs)))
    except ImportError:
        print("(PyTorch is not installed: DataLoader rows skipped)")
    for workers in (1, 2):
        r = subprocess.run(
            [a.trainer, "bench-loader", a.dataset, "--split", a.split, "--workers", str(workers), "--runs", str(a.runs)],
            capture_output=True,
            text=True,
            check=True,
        )
        m = re.search(r"(\d+) samples, .* median ([0-9.]+) samples/s", r.stdout)
        rows.append((f"Rust `trainer bench-loader`, {workers} thread{'s' if workers > 1 else ''}", float(m.group(2)), int(m.group(1))))
    print(f"{a.dataset}, split {a.split}, {size}²: samples/s, median of {a.runs} passes, checksums verified")
    print("| reader | samples/s | samples |\n|---|--:|--:|")
    for name, r, n in rows:
        print(f"| {name} | {r:.1f} | {n} |")


if __name__ == "__main__":
    main()
