"""The TensorBoard converter, read back with TensorBoard's own reader."""

import json
import os

import numpy as np
import pytest

# scripts/test_python.sh installs both (python/[test]) and sets MATEDIT_REQUIRE_TENSORBOARD, so
# that these tests cannot skip there; elsewhere they skip, saying so.
if os.environ.get("MATEDIT_REQUIRE_TENSORBOARD"):
    import tensorboardX  # noqa: F401
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator
else:
    pytest.importorskip("tensorboardX", reason="tensorboardX is not installed")
    ea = pytest.importorskip("tensorboard.backend.event_processing.event_accumulator",
                             reason="tensorboard is not installed")
    EventAccumulator = ea.EventAccumulator

from matedit_data.tensorboard import convert, main  # noqa: E402


def read(logdir):
    acc = EventAccumulator(str(logdir), size_guidance={"scalars": 0, "images": 0})
    acc.Reload()
    return acc


def test_every_logged_scalar_and_sheet_is_an_event(trained_run, tmp_path):
    logdir = tmp_path / "tb"
    counts = convert(trained_run, logdir)
    acc = read(logdir)
    tags = acc.Tags()
    records = [json.loads(l) for l in (trained_run / "metrics.jsonl").read_text().splitlines()]
    steps = [r for r in records if "validation" not in r]
    vals = [r for r in records if "validation" in r]
    assert len(steps) == 2 and len(vals) == 2, "two steps, each validated"
    # Each step's losses and rate, value for value (TensorBoard keeps float32).
    for k in ["total", "normal", "material"]:
        events = acc.Scalars(f"train/{k}")
        assert [e.step for e in events] == [r["global_step"] for r in steps]
        assert np.allclose([e.value for e in events], [r["losses"][k] for r in steps], rtol=1e-6)
    assert [e.value for e in acc.Scalars("train/lr")] == pytest.approx([r["lr"] for r in steps])
    for k in ["o_l2", "o_ssim", "i_l2", "normal_cosine", "material_l2"]:
        events = acc.Scalars(f"val/{k}")
        assert np.allclose([e.value for e in events], [v["validation"][k] for v in vals], rtol=1e-6), k
    # The final evaluation's scores and the sheets.
    report = json.loads((trained_run / "eval.json").read_text())
    o = report["checkpoints"][0]["network"]["images"]["O'"]["l2"]
    assert acc.Scalars("eval/pretrain/o_l2")[0].value == pytest.approx(o["sum"] / o["count"], rel=1e-6)
    assert set(tags["images"]) >= {"validation/sheet", "eval/sheet", "plots/loss"}
    sheet = acc.Images("validation/sheet")
    assert [i.step for i in sheet] == [1, 2]
    assert sheet[0].encoded_image_string == (trained_run / "validation" / "0000001.png").read_bytes()
    assert counts["images"] == sum(len(acc.Images(t)) for t in tags["images"])
    assert counts["scalars"] == sum(len(acc.Scalars(t)) for t in tags["scalars"])


def test_converting_again_replaces_the_event_file(trained_run, tmp_path):
    logdir = tmp_path / "tb"
    convert(trained_run, logdir)
    first = sorted(p.name for p in logdir.iterdir())
    assert main([str(trained_run), "--logdir", str(logdir)]) == 0
    assert sorted(p.name for p in logdir.iterdir()) == first, "one event file, replaced"
    assert len(read(logdir).Scalars("train/total")) == 2, "not doubled"


def test_a_folder_that_is_not_a_run_is_refused(tmp_path, capsys):
    assert main([str(tmp_path)]) == 1
    assert "no metrics.jsonl" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main([str(tmp_path), "--follow", "0"])
