"""Fixtures: the test dataset rendered by the datagen under test, its WebDataset export, and the
trainer's own reading of it (``trainer dump-batch``). The binaries come from ``MATEDIT_DATAGEN``
and ``MATEDIT_TRAINER`` (default: the workspace's ``target/release``)."""

import os
import shutil
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


def binary(name: str) -> Path:
    var = f"MATEDIT_{name.upper()}"
    p = Path(os.environ.get(var, ROOT / "target" / "release" / name))
    if not p.is_file():
        pytest.fail(f"{p} does not exist: build it (cargo build --release) or set {var}")
    return p


def run(*args, **kw):
    r = subprocess.run([str(a) for a in args], capture_output=True, text=True, **kw)
    if r.returncode != 0:
        raise AssertionError(f"{' '.join(map(str, args))} failed ({r.returncode}):\n{r.stdout}\n{r.stderr}")
    return r


@pytest.fixture(scope="session")
def dataset(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("data") / "tiny"
    run(binary("datagen"), "run", Path(__file__).with_name("tiny.toml"), "--out", out)
    return out


@pytest.fixture(scope="session")
def export(dataset, tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("wds") / "tiny-wds"
    # Small limits, so that a split spans several tars.
    run(binary("datagen"), "export", dataset, "--webdataset", out, "--shard-samples", "5")
    return out


@pytest.fixture(scope="session")
def trained_run(dataset, tmp_path_factory) -> Path:
    """A run of the trainer under test: two steps, each validated."""
    out = tmp_path_factory.mktemp("train") / "run"
    run(
        binary("trainer"), "run", Path(__file__).with_name("tiny-train.toml"), "--out", out,
        "--quiet", "--set", f"data.dataset={json_string(dataset)}",
    )
    return out


@pytest.fixture(scope="session")
def network(trained_run, tmp_path_factory) -> Path:
    """The trained run's network, exported."""
    out = tmp_path_factory.mktemp("net") / "net.safetensors"
    run(binary("trainer"), "export", trained_run / "checkpoints" / "pretrain", "--safetensors", out)
    return out


def json_string(p: Path) -> str:
    """A path as a TOML basic string (JSON's escapes are TOML's)."""
    import json

    return json.dumps(str(p))


def dump(data: Path, split: str, first: int, count: int, out: Path) -> dict:
    """The trainer's batch of those samples, as numpy arrays (and its metadata)."""
    from safetensors import safe_open

    run(binary("trainer"), "dump-batch", data, "--split", split, "--first", first, "--count", count, "--out", out)
    with safe_open(str(out), framework="numpy") as f:
        tensors = {k: f.get_tensor(k) for k in f.keys()}
        tensors["__metadata__"] = f.metadata()
    return tensors


def copy_dataset(src: Path, dst: Path) -> Path:
    shutil.copytree(src, dst)
    return dst
