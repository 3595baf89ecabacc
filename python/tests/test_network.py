"""A network ``trainer export`` wrote, read with the ``safetensors`` package."""

import os

import numpy as np
import pytest

import matedit_data as md


def test_an_exported_network_reads_with_its_configuration(network):
    net = md.load_network(network)
    assert net.config["input_size"] == 32 and net.config["env_height"] == 16
    assert net.config["widths"]["base_channels"] == 4
    assert net.stage == "pretrain" and net.step == 2
    assert net.source.startswith("blake3:")
    assert net.metadata["matedit.format"] == md.NETWORK_FORMAT
    # The three modules of Fig. 2, every tensor float32 and finite (checked by the reader).
    prefixes = {name.split(".")[0] for name in net.tensors}
    assert prefixes == {"normal", "material", "illumination"}
    # The material module ends in the 108 DSBRDF parameters; the illumination module in RGB.
    last_fc = max((n for n in net.tensors if n.startswith("material.fc.") and n.endswith(".weight")))
    assert net.tensors[last_fc].shape[1] == 108
    assert net.tensors["normal.full.1.bias"].shape == (3,)
    # Two training steps moved the weights away from any constant.
    assert all(float(np.std(t)) > 0 for n, t in net.tensors.items() if n.endswith(".weight"))


def test_pytorch_layout_transposes_linear_weights_only(network):
    net = md.load_network(network)
    torch_state = net.torch_layout()
    assert torch_state.keys() == net.tensors.keys()
    for name, t in net.tensors.items():
        if name.endswith(".weight") and t.ndim == 2:
            assert torch_state[name].shape == t.shape[::-1]
            assert np.array_equal(torch_state[name], t.T)
        else:
            assert torch_state[name] is t


def test_a_linear_layer_in_pytorch_gives_burns_product(network):
    if os.environ.get("MATEDIT_REQUIRE_TORCH"):
        import torch
    else:
        torch = pytest.importorskip("torch", reason="PyTorch is not installed")
    net = md.load_network(network)
    state = net.torch_layout()
    w, b = state["material.fc.0.weight"], state["material.fc.0.bias"]
    layer = torch.nn.Linear(w.shape[1], w.shape[0])
    layer.load_state_dict({"weight": torch.from_numpy(w), "bias": torch.from_numpy(b)})
    x = np.random.default_rng(3).standard_normal((4, w.shape[1])).astype(np.float32)
    # Burn's linear layer: x · W + b with W as stored, [in, out].
    want = x @ net.tensors["material.fc.0.weight"] + b
    got = layer(torch.from_numpy(x)).detach().numpy()
    assert np.allclose(got, want, rtol=1e-5, atol=1e-6)


def test_files_of_another_kind_are_refused(network, tmp_path):
    from safetensors.numpy import save_file

    plain = tmp_path / "plain.safetensors"
    save_file({"x": np.zeros(3, np.float32)}, str(plain))
    with pytest.raises(md.DatasetError, match="not a matedit network"):
        md.load_network(plain)
    future = tmp_path / "future.safetensors"
    save_file({"x": np.zeros(3, np.float32)}, str(future), metadata={"matedit.format": "matedit-net/9"})
    with pytest.raises(md.DatasetError, match="format 'matedit-net/9'"):
        md.load_network(future)
    nan = tmp_path / "nan.safetensors"
    meta = md.load_network(network).metadata
    save_file({"x": np.array([np.nan], np.float32)}, str(nan), metadata=meta)
    with pytest.raises(md.DatasetError, match="not finite"):
        md.load_network(nan)
    junk = tmp_path / "junk.safetensors"
    junk.write_bytes(b"not a file")
    with pytest.raises(md.DatasetError, match="not a safetensors file"):
        md.load_network(junk)
