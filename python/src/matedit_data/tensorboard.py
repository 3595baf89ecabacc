"""A training run's logs as TensorBoard event files, through tensorboardX.

    python -m matedit_data.tensorboard OUT/train/RUN                 # writes RUN/tensorboard/
    python -m matedit_data.tensorboard RUN --follow 30               # again whenever it grows
    tensorboard --logdir OUT/train                                    # compare runs

Every scalar the trainer logs becomes a TensorBoard scalar at the run's global step:
``train/total`` and ``train/<term>`` (each loss term of Eq. 5, unweighted, as ``metrics.jsonl``
has it), ``train/lr``, ``val/<score>`` (``o_l2``, ``o_ssim``, ``i_l2``, ``i_ssim``,
``normal_cosine``, ``material_l2``: the validation lines), ``eval/<stage>/<score>`` (``eval.json``
after the run) and ``time/images_per_second`` (``log.jsonl``). The contact sheets are images:
``validation/sheet`` (``validation/NNNNNNN.png``), ``eval/sheet`` (``eval.png``) and
``eval/methods`` (``eval-methods.png``); ``loss.png`` is ``plots/loss``.

The event file is rewritten whole (into a temporary file, then renamed), so a converter killed
halfway leaves the previous one; converting twice gives the same events (their wall time is 0:
TensorBoard's step axis is the run's own).
"""

from __future__ import annotations

import argparse
import json
import os
import struct
import sys
import tempfile
import time
from pathlib import Path
from typing import Dict, Iterable, List, Optional

#: The scores of a validation line and of eval.json's network row.
SCORES = ("o_l2", "o_ssim", "i_l2", "i_ssim", "normal_cosine", "material_l2")

#: The suffix of the event files this module writes (others in the folder are left alone).
SUFFIX = ".matedit"


def _lines(path: Path) -> List[dict]:
    if not path.exists():
        return []
    out = []
    for n, line in enumerate(path.read_text().splitlines(), 1):
        if not line.strip():
            continue
        try:
            out.append(json.loads(line))
        except json.JSONDecodeError as e:
            # A line the trainer is writing right now: the rest comes with the next conversion.
            if n == len(path.read_text().splitlines()):
                break
            raise ValueError(f"{path}:{n}: not a metrics line: {e}") from e
    return out


def _png_size(data: bytes) -> Optional[tuple]:
    """(width, height) of a PNG, from its IHDR chunk."""
    if len(data) < 24 or data[:8] != b"\x89PNG\r\n\x1a\n" or data[12:16] != b"IHDR":
        return None
    return struct.unpack(">II", data[16:24])


def _eval_scores(row: dict) -> Dict[str, float]:
    """The scores of eval.json's ``network`` metrics, named as a validation's."""
    images = row.get("images", {})

    def mean(m: Optional[dict]) -> Optional[float]:
        if not m or not m.get("count"):
            return None
        return m["sum"] / m["count"]

    values = {
        "o_l2": mean(images.get("O'", {}).get("l2")),
        "o_ssim": mean(images.get("O'", {}).get("ssim")),
        "i_l2": mean(images.get("I'", {}).get("l2")),
        "i_ssim": mean(images.get("I'", {}).get("ssim")),
        "normal_cosine": mean(row.get("normal_cosine")),
        "material_l2": mean(row.get("material_l2_normalised")),
    }
    return {k: v for k, v in values.items() if v is not None}


def convert(run, logdir=None) -> Dict[str, int]:
    """Writes the event file of training run folder ``run`` into ``logdir`` (default
    ``run/tensorboard``); returns how many scalars and images it holds."""
    from tensorboardX import SummaryWriter
    from tensorboardX.proto.summary_pb2 import Summary

    run = Path(run)
    logdir = Path(logdir) if logdir is not None else run / "tensorboard"
    records = _lines(run / "metrics.jsonl")
    if not records and not (run / "eval.json").exists():
        raise FileNotFoundError(f"{run}: no metrics.jsonl (not a trainer run folder, or not started)")
    logdir.mkdir(parents=True, exist_ok=True)
    counts = {"scalars": 0, "images": 0}
    last = max((r.get("global_step", 0) for r in records), default=0)
    with tempfile.TemporaryDirectory(dir=logdir, prefix=".tmp-") as tmp:
        writer = SummaryWriter(logdir=tmp, filename_suffix=SUFFIX, flush_secs=3600)

        def scalar(tag: str, value, step: int) -> None:
            if value is None or not isinstance(value, (int, float)):
                return
            writer.add_scalar(tag, float(value), step, walltime=0.0)
            counts["scalars"] += 1

        def image(tag: str, path: Path, step: int) -> None:
            if not path.is_file():
                return
            data = path.read_bytes()
            size = _png_size(data)
            if size is None:
                return
            img = Summary.Image(height=size[1], width=size[0], colorspace=4, encoded_image_string=data)
            writer.file_writer.add_summary(Summary(value=[Summary.Value(tag=tag, image=img)]), step, walltime=0.0)
            counts["images"] += 1

        for r in records:
            g = r["global_step"]
            if "validation" in r:
                for k in SCORES:
                    scalar(f"val/{k}", r["validation"].get(k), g)
                image("validation/sheet", run / "validation" / f"{g:07d}.png", g)
            else:
                scalar("train/lr", r.get("lr"), g)
                for k, v in r.get("losses", {}).items():
                    scalar(f"train/{k}", v, g)
        for n, r in enumerate(_lines(run / "log.jsonl"), 1):
            scalar("time/images_per_second", r.get("images_per_second"), n)
        eval_json = run / "eval.json"
        if eval_json.exists():
            report = json.loads(eval_json.read_text())
            for row in report.get("checkpoints", []):
                for k, v in _eval_scores(row.get("network", {})).items():
                    scalar(f"eval/{row.get('name', '?')}/{k}", v, last)
        image("eval/sheet", run / "eval.png", last)
        image("eval/methods", run / "eval-methods.png", last)
        image("plots/loss", run / "loss.png", last)
        writer.close()
        written = [p for p in Path(tmp).iterdir() if p.name.startswith("events.out.tfevents.")]
        if len(written) != 1:
            raise RuntimeError(f"tensorboardX wrote {len(written)} event files into {tmp}")
        # One event file of ours in the folder: the old one goes once the new one is in place.
        target = logdir / f"events.out.tfevents.matedit{SUFFIX}"
        os.replace(written[0], target)
    for old in logdir.glob(f"events.out.tfevents.*{SUFFIX}"):
        if old.name != target.name:
            old.unlink()
    return counts


def _state(run: Path) -> tuple:
    """What changes when the run writes something the events show."""
    files = [run / "metrics.jsonl", run / "eval.json", run / "loss.png", run / "log.jsonl"]
    return tuple((p.stat().st_size, p.stat().st_mtime_ns) if p.exists() else None for p in files)


def main(argv: Optional[Iterable[str]] = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m matedit_data.tensorboard", description=__doc__.split("\n\n")[0])
    ap.add_argument("run", type=Path, help="a `trainer run` output folder")
    ap.add_argument("--logdir", type=Path, help="where the event file goes (default: RUN/tensorboard)")
    ap.add_argument("--follow", type=float, metavar="SECONDS",
                    help="convert again every SECONDS while the run grows, until eval.json appears")
    a = ap.parse_args(list(argv) if argv is not None else None)
    if a.follow is not None and not a.follow > 0:
        ap.error("--follow takes a positive number of seconds")
    seen = None
    while True:
        state = _state(a.run)
        if state != seen:
            try:
                c = convert(a.run, a.logdir)
            except (FileNotFoundError, ValueError) as e:
                print(f"error: {e}", file=sys.stderr)
                return 1
            print(f"{a.logdir or a.run / 'tensorboard'}: {c['scalars']} scalars, {c['images']} images", file=sys.stderr)
            seen = state
        if a.follow is None or (a.run / "eval.json").exists():
            return 0
        time.sleep(a.follow)


if __name__ == "__main__":
    sys.exit(main())
