"""A network ``trainer export CKPT --safetensors OUT`` wrote: its tensors and configuration.

>>> from matedit_data import load_network
>>> net = load_network("out/net.safetensors")
>>> net.config["input_size"], net.stage, len(net.tensors)        # 64 'joint' 74
>>> state = net.torch_layout()          # linear weights transposed to PyTorch's [out, in]

Tensors are named by their path in the network (``normal.global.convs.0.weight``; the table is in
``docs/FORMAT.md``, "A trained network") and kept in Burn's layout: convolutions ``[out, in, kh,
kw]``, transposed convolutions ``[in, out, kh, kw]`` (both as PyTorch's), linear layers ``[in,
out]`` (PyTorch's ``nn.Linear`` holds ``[out, in]``: :meth:`Network.torch_layout` transposes them).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Dict

import numpy as np
from safetensors.numpy import load_file
from safetensors import safe_open

from .sample import DatasetError

#: The format ``trainer export`` writes (the ``matedit.format`` metadata value).
NETWORK_FORMAT = "matedit-net/1"


@dataclass
class Network:
    """An exported network."""

    #: The network's configuration (input_size, env_height, widths, exposure, ...), as the trainer
    #: records it.
    config: dict
    #: Every tensor, float32, in Burn's layout.
    tensors: Dict[str, np.ndarray]
    #: The stage and step of the checkpoint it came from.
    stage: str
    step: int
    #: ``blake3:HEX`` of the checkpoint's ``model.bpk``.
    source: str
    #: Every metadata entry, as written.
    metadata: Dict[str, str]

    def torch_layout(self) -> Dict[str, np.ndarray]:
        """The tensors with every linear weight (the 2-D ``weight`` tensors) transposed to
        PyTorch's ``[out, in]``; the rest as they are."""
        out = {}
        for name, t in self.tensors.items():
            if name.endswith(".weight") and t.ndim == 2:
                out[name] = np.ascontiguousarray(t.T)
            else:
                out[name] = t
        return out


def load_network(path) -> Network:
    """Reads an exported network, refusing a file of another format or with a tensor that is not
    finite float32."""
    path = Path(path)
    try:
        with safe_open(str(path), framework="numpy") as f:
            meta = dict(f.metadata() or {})
    except Exception as e:  # the safetensors package raises its own error types
        raise DatasetError(path, f"not a safetensors file: {e}") from e
    fmt = meta.get("matedit.format")
    if fmt is None:
        raise DatasetError(path, "not a matedit network (no matedit.format metadata)")
    if fmt != NETWORK_FORMAT:
        raise DatasetError(path, f"format {fmt!r} (this reader reads {NETWORK_FORMAT!r})")
    try:
        config = json.loads(meta["matedit.net"])
    except (KeyError, json.JSONDecodeError) as e:
        raise DatasetError(path, f"matedit.net is not a network configuration: {e}") from e
    tensors = load_file(str(path))
    for name, t in tensors.items():
        if t.dtype != np.float32:
            raise DatasetError(path, f"{name} is {t.dtype}, not float32")
        if not np.isfinite(t).all():
            raise DatasetError(path, f"{name} holds a value that is not finite")
    return Network(
        config=config,
        tensors=tensors,
        stage=meta.get("matedit.stage", ""),
        step=int(meta.get("matedit.step", "0")),
        source=meta.get("matedit.source", ""),
        metadata=meta,
    )
