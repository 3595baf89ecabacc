"""One training tuple of the paper's Fig. 2, decoded from its two EXR files as the Rust trainer
decodes it (``trainer/src/data/sample.rs``), so that both give the same numbers.

* The image EXR holds ``R, G, B`` (I), ``O.R, O.G, O.B`` (O), ``normal.X/Y/Z``, ``mask`` and
  ``region``; the ``.env.exr`` holds the camera-space environment as ``R, G, B``.
* Strict about layout (a missing channel, a non-square image, a region value that is not one
  of the record's regions are errors naming the file), lenient about values: a non-finite value
  becomes 0 and is counted in ``Sample.sanitized``.
* Normals go through the renderer's ``shading_normal``: unit length, and tilted to
  ``n_z = 1e-4`` where they face away from the camera; a covered pixel whose normal cannot be
  shaded (zero, non-finite) is taken out of the mask and region map and counted in
  ``Sample.dropped``.
"""

from __future__ import annotations

import io
from dataclasses import dataclass
from typing import Dict, List, Optional, Tuple

import numpy as np

#: Normals facing away from the camera are tilted to this n_z (``physics::shading::MIN_FACING``).
MIN_FACING = 1e-4

#: Channels of every sample's image EXR.
IMAGE_CHANNELS = ("B", "G", "O.B", "O.G", "O.R", "R", "mask", "normal.X", "normal.Y", "normal.Z", "region")


class DatasetError(Exception):
    """A dataset file that cannot be used: ``file`` names it, ``reason`` says which check failed."""

    def __init__(self, file, reason: str):
        self.file = str(file)
        self.reason = reason
        super().__init__(f"{self.file}: {reason}")


@dataclass(frozen=True)
class Material:
    """One material of the dataset's table (``dataset.json`` → ``materials[id]``)."""

    id: str
    #: Near-duplicate group (whole groups are dealt to splits).
    group: str
    #: The 108 DSBRDF parameters (order of ``docs/CONVENTIONS.md``), float64 as recorded.
    raw: np.ndarray
    #: The same, normalised to the network's [-0.95, 0.95], float32 as the trainer holds them.
    normalised: np.ndarray
    #: ``dsbrdf:PATH`` of its file, the spec ``matedit edit --material`` takes (None for a
    #: WebDataset export, which carries the parameters but not the files).
    spec: Optional[str] = None


@dataclass
class Sample:
    """A decoded sample. Images are height × width × channels (numpy's image layout); the PyTorch
    tensors of :mod:`matedit_data.torch` are channel-first, as the trainer's batch."""

    id: str
    split: str
    index: int
    category: str
    shape_id: str
    #: Region names; ``region_map`` value r + 1 is region r.
    regions: List[str]
    #: Input image I (material m), linear HDR radiance, H×W×3 float32.
    I: np.ndarray
    #: Target image O (material m_t), H×W×3 float32.
    O: np.ndarray
    #: Camera-space unit normals (x right, y up, z towards the camera), H×W×3 float32, zero off
    #: the mask.
    normals: np.ndarray
    #: Object mask, H×W float32, exactly 0 or 1.
    mask: np.ndarray
    #: H×W uint8: 0 background, r = material region r − 1.
    region_map: np.ndarray
    #: The environment as the camera sees it, He×2He×3 float32 (equirectangular).
    env: np.ndarray
    #: Material m and target m_t per region.
    materials: List[Material]
    target_materials: List[Material]
    env_id: str
    #: The index record as written.
    record: dict
    #: Non-finite values in the files, replaced by 0.
    sanitized: int = 0
    #: Covered pixels taken out of the mask (normals the renderer cannot shade).
    dropped: int = 0

    @property
    def m(self) -> np.ndarray:
        """Normalised m per region, R×108 float32."""
        return np.stack([x.normalised for x in self.materials])

    @property
    def m_t(self) -> np.ndarray:
        """Normalised m_t per region, R×108 float32."""
        return np.stack([x.normalised for x in self.target_materials])

    @property
    def m_raw(self) -> np.ndarray:
        """Raw m per region, R×108 float64."""
        return np.stack([x.raw for x in self.materials])

    @property
    def m_t_raw(self) -> np.ndarray:
        """Raw m_t per region, R×108 float64."""
        return np.stack([x.raw for x in self.target_materials])

    @property
    def size(self) -> int:
        return self.I.shape[0]


def read_exr(data: bytes) -> Tuple[int, int, Dict[str, np.ndarray]]:
    """(width, height, channels as float32 arrays) of an EXR file's first part."""
    import OpenEXR

    try:
        f = OpenEXR.File(io.BytesIO(data), separate_channels=True)
        part = f.parts[0]
        channels = {name: np.asarray(ch.pixels, dtype=np.float32) for name, ch in part.channels.items()}
    except Exception as e:  # OpenEXR raises several kinds for a truncated or corrupt file
        raise ValueError(f"cannot decode the EXR (truncated or corrupt?): {e}") from None
    shapes = {c.shape for c in channels.values()}
    if len(shapes) != 1 or len(next(iter(shapes))) != 2:
        raise ValueError(f"channels of different shapes {sorted(shapes)}")
    h, w = next(iter(shapes))
    return w, h, channels


def _take(ch: Dict[str, np.ndarray], name: str, counter: List[int]) -> np.ndarray:
    if name not in ch:
        raise ValueError(f"no {name!r} channel (has {sorted(ch)})")
    v = ch[name].copy()
    bad = ~np.isfinite(v)
    n = int(bad.sum())
    if n:
        v[bad] = 0.0
        counter[0] += n
    return v


def shading_normals(nx: np.ndarray, ny: np.ndarray, nz: np.ndarray) -> Tuple[np.ndarray, np.ndarray]:
    """The renderer's ``shading_normal`` over arrays, in float64 as it computes: (normals as
    float64 ..×3, whether each can be shaded)."""
    x, y, z = (a.astype(np.float64) for a in (nx, ny, nz))
    with np.errstate(invalid="ignore", over="ignore", divide="ignore"):
        length = np.sqrt(x * x + y * y + z * z)
        ok = np.isfinite(length) & (length >= 1e-6)
        safe = np.where(ok, length, 1.0)
        vx, vy, vz = x / safe, y / safe, z / safe
        facing = vz >= MIN_FACING
        xy = np.sqrt(vx * vx + vy * vy)
        tilt_ok = xy >= 1e-12
        s = np.sqrt(1.0 - MIN_FACING * MIN_FACING) / np.where(tilt_ok, xy, 1.0)
        out = np.where(
            facing[..., None],
            np.stack([vx, vy, vz], axis=-1),
            np.stack([vx * s, vy * s, np.full_like(vz, MIN_FACING)], axis=-1),
        )
    ok = ok & (facing | tilt_ok)
    return out, ok


@dataclass
class ImagePixels:
    I: np.ndarray
    O: np.ndarray
    normals: np.ndarray
    mask: np.ndarray
    region_map: np.ndarray
    sanitized: int
    dropped: int


def decode_image(data: bytes, region_count: int) -> ImagePixels:
    """Decodes an image EXR of a sample with ``region_count`` regions (raises ValueError)."""
    w, h, ch = read_exr(data)
    if w != h or w == 0:
        raise ValueError(f"{w}×{h} is not a square image")
    if not 1 <= region_count <= 255:
        raise ValueError(f"{region_count} regions: expected 1 to 255")
    counter = [0]
    t = lambda name: _take(ch, name, counter)  # noqa: E731
    r, g, b = t("R"), t("G"), t("B")
    o_r, o_g, o_b = t("O.R"), t("O.G"), t("O.B")
    nx, ny, nz = t("normal.X"), t("normal.Y"), t("normal.Z")
    mask_in, region_in = t("mask"), t("region")
    covered = mask_in > 0.5
    reg = region_in[covered]
    bad = (reg < 0) | (np.mod(reg, 1.0) != 0) | (reg >= region_count)
    if bad.any():
        k = int(np.flatnonzero(covered.ravel())[np.flatnonzero(bad)[0]])
        raise ValueError(f"pixel {k}: region {region_in.ravel()[k]:g} is not one of the record's {region_count} regions")
    n, shadeable = shading_normals(nx, ny, nz)
    keep = covered & shadeable
    normals = np.where(keep[..., None], n, 0.0).astype(np.float32)
    mask = keep.astype(np.float32)
    region_map = np.where(keep, region_in + 1, 0).astype(np.uint8)
    return ImagePixels(
        I=np.stack([r, g, b], axis=-1),
        O=np.stack([o_r, o_g, o_b], axis=-1),
        normals=normals,
        mask=mask,
        region_map=region_map,
        sanitized=counter[0],
        dropped=int((covered & ~shadeable).sum()),
    )


def decode_env(data: bytes) -> Tuple[np.ndarray, int]:
    """Decodes an environment EXR: (He×2He×3 float32, values sanitized)."""
    w, h, ch = read_exr(data)
    if h == 0 or w != 2 * h:
        raise ValueError(f"{w}×{h}: an environment must be 2H wide")
    counter = [0]
    env = np.stack([_take(ch, c, counter) for c in ("R", "G", "B")], axis=-1)
    return env, counter[0]

