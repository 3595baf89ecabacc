"""PyTorch datasets over a matedit dataset, giving the tensors of the Rust trainer's batch
(``trainer/src/data/batch.rs``): channel-first, float32 except the uint8 region map, materials
padded to the batch's largest region count by repeating each sample's last material.

* :class:`SampleDataset`: map-style, any sample by position (dataset folders), for
  ``DataLoader(..., shuffle=True)``;
* :class:`ShardDataset`: iterable over shards, each DataLoader worker (and each
  ``torch.distributed`` rank) reading its own shards whole, for folders and WebDataset exports;
* :func:`collate`: a list of samples as one batch, value for value as the trainer stacks it.
"""

from __future__ import annotations

from typing import Dict, List, Optional

import numpy as np
import torch
from torch.utils.data import Dataset as _TorchDataset
from torch.utils.data import IterableDataset, get_worker_info

from .dataset import Dataset, open_dataset
from .sample import Sample


def to_tensors(s: Sample) -> Dict[str, object]:
    """One sample as the trainer holds it: ``input``, ``target``, ``normals`` [3, S, S],
    ``mask``, ``region_map`` [S, S], ``env`` [3, He, 2He], ``materials``, ``target_materials``
    [R, 108], ``id``."""
    chw = lambda a: torch.from_numpy(np.ascontiguousarray(a.transpose(2, 0, 1)))  # noqa: E731
    return {
        "id": s.id,
        "input": chw(s.I),
        "target": chw(s.O),
        "normals": chw(s.normals),
        "mask": torch.from_numpy(s.mask),
        "region_map": torch.from_numpy(s.region_map),
        "env": chw(s.env),
        "materials": torch.from_numpy(s.m),
        "target_materials": torch.from_numpy(s.m_t),
    }


def _pad(m: torch.Tensor, regions: int) -> torch.Tensor:
    if m.shape[0] == regions:
        return m
    return torch.cat([m, m[-1:].expand(regions - m.shape[0], -1)])


def collate(items: List[Dict[str, object]]) -> Dict[str, object]:
    """Stacks samples (of one image and environment size) into the trainer's batch: ``input``,
    ``target``, ``normals`` [B, 3, S, S], ``mask``, ``region_map`` [B, S, S], ``env`` [B, 3, He,
    2He], ``materials``, ``target_materials`` [B, R, 108] (R the batch's largest region count; a
    sample with fewer repeats its last material, which no pixel refers to), ``region_counts``
    [B], ``ids``."""
    if not items:
        raise ValueError("cannot collate an empty batch")
    items = [to_tensors(i) if isinstance(i, Sample) else i for i in items]
    sizes = {(tuple(i["input"].shape), tuple(i["env"].shape)) for i in items}
    if len(sizes) != 1:
        raise ValueError(f"one batch needs one image and environment size, got {sorted(sizes)}")
    regions = max(i["materials"].shape[0] for i in items)
    out: Dict[str, object] = {
        k: torch.stack([i[k] for i in items]) for k in ("input", "target", "normals", "mask", "region_map", "env")
    }
    out["materials"] = torch.stack([_pad(i["materials"], regions) for i in items])
    out["target_materials"] = torch.stack([_pad(i["target_materials"], regions) for i in items])
    out["region_counts"] = torch.tensor([i["materials"].shape[0] for i in items])
    out["ids"] = [i["id"] for i in items]
    return out


class SampleDataset(_TorchDataset):
    """The samples of one split of a dataset folder, by position in index order."""

    def __init__(self, path, split: str = "train", verify: bool = True):
        self.path, self.split_name, self.verify = str(path), split, verify
        self._ds: Optional[Dataset] = None
        self._len = len(self._dataset().split(split))

    def _dataset(self) -> Dataset:
        # Opened again in each worker process rather than pickled whole.
        if self._ds is None:
            self._ds = open_dataset(self.path, verify=self.verify)
            if self._ds.kind != "folder":
                raise TypeError(f"{self.path}: a WebDataset export is read in order: use ShardDataset")
        return self._ds

    def __getstate__(self):
        return {**self.__dict__, "_ds": None}

    def __len__(self) -> int:
        return self._len

    def __getitem__(self, i: int) -> Dict[str, object]:
        return to_tensors(self._dataset().split(self.split_name)[i])


class ShardDataset(IterableDataset):
    """The samples of one split, shard by shard: worker w of W (of each rank r of R) reads shards
    ``r·W + w, r·W + w + R·W, …``, so that every sample is read once per pass. ``shuffle_seed``
    shuffles the order of the shards (the same order in every worker; pass a new seed per epoch)."""

    def __init__(self, path, split: str = "train", verify: bool = True, shuffle_seed: Optional[int] = None):
        self.path, self.split_name, self.verify, self.shuffle_seed = str(path), split, verify, shuffle_seed
        self.shards = len(open_dataset(self.path, verify=verify).split(split).shards)

    def __iter__(self):
        ds = open_dataset(self.path, verify=self.verify)
        shards = list(ds.split(self.split_name).shards)
        if self.shuffle_seed is not None:
            order = np.random.default_rng(self.shuffle_seed).permutation(len(shards))
            shards = [shards[k] for k in order]
        info = get_worker_info()
        worker, workers = (info.id, info.num_workers) if info else (0, 1)
        rank, world = 0, 1
        if torch.distributed.is_available() and torch.distributed.is_initialized():
            rank, world = torch.distributed.get_rank(), torch.distributed.get_world_size()
        for shard in shards[rank * workers + worker :: world * workers]:
            for s in shard:
                yield to_tensors(s)


__all__ = ["SampleDataset", "ShardDataset", "collate", "to_tensors"]
