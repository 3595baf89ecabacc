"""Read matedit's synthetic material-editing datasets into numpy and PyTorch.

>>> from matedit_data import open_dataset
>>> ds = open_dataset("out/quickstart")
>>> s = next(iter(ds.split("test")))
>>> s.I.shape, s.normals.shape, s.m.shape            # (64, 64, 3) (64, 64, 3) (1, 108)

The values are those the Rust trainer reads (tested bit for bit against ``trainer dump-batch``).
``matedit_data.torch`` has the PyTorch datasets and the batch collation; :func:`load_network`
reads a network ``trainer export`` wrote. The format:
``docs/FORMAT.md`` in the matedit repository.
"""

from .dataset import FORMAT, WEBDATASET_FORMAT, Dataset, Shard, Split, checksum, open_dataset
from .network import NETWORK_FORMAT, Network, load_network
from .sample import IMAGE_CHANNELS, DatasetError, Material, Sample, decode_env, decode_image, shading_normals

__version__ = "0.1.0"

__all__ = [
    "FORMAT",
    "WEBDATASET_FORMAT",
    "IMAGE_CHANNELS",
    "NETWORK_FORMAT",
    "Network",
    "Dataset",
    "DatasetError",
    "Material",
    "Sample",
    "Shard",
    "Split",
    "checksum",
    "decode_env",
    "decode_image",
    "load_network",
    "open_dataset",
    "shading_normals",
]
