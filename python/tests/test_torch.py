"""The PyTorch side: batches equal to the trainer's, and DataLoader workers that together read
every sample exactly once."""

import json
import os

import numpy as np
import pytest

# CI installs PyTorch and sets MATEDIT_REQUIRE_TORCH, so that these tests cannot skip there.
if os.environ.get("MATEDIT_REQUIRE_TORCH"):
    import torch
else:
    torch = pytest.importorskip("torch", reason="PyTorch is not installed")
from torch.utils.data import DataLoader  # noqa: E402

import matedit_data as md  # noqa: E402
from matedit_data.torch import SampleDataset, ShardDataset, collate  # noqa: E402
from conftest import dump  # noqa: E402


def test_a_collated_batch_is_the_trainers_batch_bit_for_bit(dataset, tmp_path):
    ds = SampleDataset(dataset, "train")
    batch = collate([ds[k] for k in range(3, 9)])
    trainer = dump(dataset, "train", 3, 6, tmp_path / "b.safetensors")
    assert batch["ids"] == json.loads(trainer["__metadata__"]["ids"])
    assert batch["region_counts"].tolist() == json.loads(trainer["__metadata__"]["region_counts"])
    assert len(set(batch["region_counts"].tolist())) > 1, "the batch must pad its materials"
    for k in ("input", "target", "normals", "mask", "region_map", "env", "materials", "target_materials"):
        ours = batch[k].numpy()
        assert ours.dtype == trainer[k].dtype and ours.shape == trainer[k].shape, k
        assert np.array_equal(ours.view(np.uint8), trainer[k].view(np.uint8)), k


@pytest.mark.parametrize("kind", ["folder", "webdataset"])
def test_two_workers_over_a_split_see_every_sample_once(dataset, export, kind):
    path = dataset if kind == "folder" else export
    want = [s.id for s in md.open_dataset(dataset).split("train")]
    loader = DataLoader(ShardDataset(path, "train"), batch_size=4, num_workers=2, collate_fn=collate)
    seen = [i for b in loader for i in b["ids"]]
    assert sorted(seen) == sorted(want) and len(seen) == len(want)
    shuffled = DataLoader(ShardDataset(path, "train", shuffle_seed=3), batch_size=4, num_workers=2, collate_fn=collate)
    again = [i for b in shuffled for i in b["ids"]]
    assert sorted(again) == sorted(want) and again != seen


def test_a_map_style_dataset_with_two_workers_and_shuffling_sees_every_sample_once(dataset):
    want = [s.id for s in md.open_dataset(dataset).split("test")]
    loader = DataLoader(
        SampleDataset(dataset, "test"),
        batch_size=5,
        shuffle=True,
        num_workers=2,
        collate_fn=collate,
        generator=torch.Generator().manual_seed(0),
    )
    seen = [i for b in loader for i in b["ids"]]
    assert sorted(seen) == sorted(want)


def test_a_webdataset_export_is_refused_for_random_access(export):
    with pytest.raises(TypeError, match="ShardDataset"):
        SampleDataset(export, "train")
