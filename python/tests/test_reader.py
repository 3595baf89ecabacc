"""The Python reader against the Rust trainer, bit for bit, and against damaged datasets."""

import json
import subprocess

import numpy as np
import pytest

import matedit_data as md
from conftest import binary, copy_dataset, dump, run

FIELDS = ("I", "O", "normals", "mask", "region_map", "env", "m", "m_t")


def bits(a: np.ndarray) -> np.ndarray:
    """The bytes of an array: equal bits, not equal values (0.0 ≠ -0.0, NaN = the same NaN)."""
    return np.ascontiguousarray(a).view(np.uint8)


def same(a, b) -> bool:
    return a.shape == b.shape and a.dtype == b.dtype and np.array_equal(bits(a), bits(b))


def numpy_batch(samples):
    """The trainer's batch layout from numpy samples (channel-first, materials padded)."""
    regions = max(len(s.regions) for s in samples)
    pad = lambda m: np.concatenate([m, np.repeat(m[-1:], regions - len(m), axis=0)])  # noqa: E731
    chw = lambda a: a.transpose(2, 0, 1)  # noqa: E731
    return {
        "input": np.stack([chw(s.I) for s in samples]),
        "target": np.stack([chw(s.O) for s in samples]),
        "normals": np.stack([chw(s.normals) for s in samples]),
        "mask": np.stack([s.mask for s in samples]),
        "region_map": np.stack([s.region_map for s in samples]),
        "env": np.stack([chw(s.env) for s in samples]),
        "materials": np.stack([pad(s.m) for s in samples]),
        "target_materials": np.stack([pad(s.m_t) for s in samples]),
    }


def assert_like_trainer(samples, trainer):
    ids = json.loads(trainer["__metadata__"]["ids"])
    assert ids == [s.id for s in samples]
    assert json.loads(trainer["__metadata__"]["region_counts"]) == [len(s.regions) for s in samples]
    ours = numpy_batch(samples)
    for k, v in ours.items():
        assert same(v, trainer[k]), f"{k}: the Python reader differs from the trainer"


@pytest.mark.parametrize("split", ["train", "test"])
def test_every_sample_is_what_the_trainer_reads_bit_for_bit(dataset, tmp_path, split):
    ds = md.open_dataset(dataset)
    samples = list(ds.split(split))
    assert len(samples) == ds.info["counts"][split] > 0
    assert len({len(s.regions) for s in samples}) > 1, "the test needs samples of several region counts"
    assert_like_trainer(samples, dump(dataset, split, 0, len(samples), tmp_path / "b.safetensors"))
    s = samples[0]
    assert s.I.shape == (32, 32, 3) and s.I.dtype == np.float32
    assert s.env.shape == (16, 32, 3) and s.region_map.dtype == np.uint8
    assert s.m.shape == (len(s.regions), 108) and s.m_raw.dtype == np.float64
    assert s.materials[0].spec.startswith("dsbrdf:") and s.materials[0].spec.endswith(".dsbrdf.json")
    n = np.linalg.norm(s.normals.astype(np.float64), axis=-1)
    assert np.allclose(n[s.mask == 1], 1.0, atol=1e-6) and (n[s.mask == 0] == 0).all()


def write_exr(path, channels):
    import OpenEXR

    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    OpenEXR.File(header, {k: np.ascontiguousarray(v, dtype=np.float32) for k, v in channels.items()}).write(str(path))


def replace_sample_files(data, rec, image=None, env=None):
    """Rewrites a sample's files and the checksums that bind them (index, dataset.json)."""
    index = (data / "index.jsonl").read_text()
    for key, channels in (("image", image), ("env", env)):
        if channels is None:
            continue
        p = data / rec["files"][key]
        write_exr(p, channels)
        index = index.replace(rec["checksums"][key], md.checksum(p.read_bytes()))
    (data / "index.jsonl").write_text(index)
    ds_json = (data / "dataset.json").read_text()
    info = json.loads(ds_json)
    ds_json = ds_json.replace(info["index_checksum"], md.checksum(index.encode()))
    (data / "dataset.json").write_text(ds_json)


def test_hard_cases_decode_as_the_trainer_decodes_them(dataset, tmp_path):
    """Non-finite values, normals that are zero, huge, tiny, facing away or straight away, masks
    near the threshold: every one as the trainer reads it."""
    data = copy_dataset(dataset, tmp_path / "hard")
    ds = md.open_dataset(data)
    rec = ds.split("test").records[0]
    ch = md.sample.read_exr((data / rec["files"]["image"]).read_bytes())[2]
    ys, xs = np.nonzero(ch["mask"] > 0.5)
    cases = [
        (0.0, 0.0, 0.0),  # zero: dropped
        (0.0, 0.0, -1.0),  # straight away: dropped
        (1.0, 0.0, -0.5),  # away: tilted to n_z = 1e-4
        (0.3, -0.2, 1e-5),  # grazing: tilted
        (1e-30, 1e-30, 1e-30),  # too short: dropped
        (3e38, 3e38, 0.0),  # overflows f32 but not f64
        (np.nan, 0.0, 1.0),  # sanitized to 0 first
        (np.inf, 0.0, 1.0),
        (2.0, 2.0, 2.0),  # unnormalised
        (-7e-13, 7e-13, -1.0),  # tilt with almost no azimuth
    ]
    for k, n in enumerate(cases):
        y, x = ys[k], xs[k]
        ch["normal.X"][y, x], ch["normal.Y"][y, x], ch["normal.Z"][y, x] = n
    ch["R"][0, 0], ch["G"][0, 1], ch["O.B"][1, 1] = np.nan, np.inf, -np.inf
    ch["mask"][ys[20], xs[20]] = 0.5000001  # covered
    ch["mask"][ys[21], xs[21]] = 0.5  # not covered
    ch["mask"][ys[22], xs[22]] = np.nan  # sanitized: not covered
    env = md.sample.read_exr((data / rec["files"]["env"]).read_bytes())[2]
    env["R"][0, 0] = np.nan
    replace_sample_files(data, rec, image=ch, env=env)
    s = md.open_dataset(data).split("test")[0]
    assert s.sanitized == 7 and s.dropped == 4, (s.sanitized, s.dropped)
    assert_like_trainer([s], dump(data, "test", 0, 1, tmp_path / "hard.safetensors"))


def test_a_region_outside_the_record_is_refused_naming_the_file_and_pixel(dataset, tmp_path):
    data = copy_dataset(dataset, tmp_path / "regions")
    ds = md.open_dataset(data)
    rec = ds.split("train").records[0]
    ch = md.sample.read_exr((data / rec["files"]["image"]).read_bytes())[2]
    ys, xs = np.nonzero(ch["mask"] > 0.5)
    ch["region"][ys[0], xs[0]] = len(rec["regions"])
    replace_sample_files(data, rec, image=ch)
    with pytest.raises(md.DatasetError) as e:
        md.open_dataset(data).split("train")[0]
    assert e.value.file.endswith(rec["files"]["image"]) and "is not one of the record's" in e.value.reason


def test_the_webdataset_export_gives_the_same_samples(dataset, export):
    folder, tars = md.open_dataset(dataset), md.open_dataset(export)
    assert tars.kind == "webdataset" and tars.counts == folder.counts
    record = json.loads((export / "shards.json").read_text())
    for split in folder.splits:
        shards = record["splits"][[s["name"] for s in record["splits"]].index(split)]["shards"]
        assert len(shards) == 3 and all(t["samples"] <= 5 for t in shards)
        for t in shards:
            assert md.checksum((export / t["name"]).read_bytes()) == t["checksum"]
        for a, b in zip(folder.split(split), tars.split(split), strict=True):
            assert a.id == b.id and a.regions == b.regions
            for f in FIELDS:
                assert same(getattr(a, f), getattr(b, f)), f"{a.id}: {f}"
            assert [m.id for m in a.materials] == [m.id for m in b.materials]
            assert same(a.m_raw, b.m_raw)


def test_the_webdataset_package_reads_the_export(dataset, export):
    import webdataset as wds

    folder = md.open_dataset(dataset)
    tars = md.open_dataset(export)
    urls = [str(export / s.name) for s in tars.split("test").shards]
    seen = []
    for d in wds.WebDataset(urls, shardshuffle=False, empty_check=False):
        assert set(d) >= {"__key__", "exr", "env.exr", "json"}, sorted(d)
        rec = json.loads(d["json"])
        s = tars.sample_from_members(rec, {"exr": d["exr"], "env.exr": d["env.exr"]}, d["__url__"])
        ref = folder.split("test")[rec["index"]]
        assert d["__key__"] == ref.id == s.id
        for f in FIELDS:
            assert same(getattr(s, f), getattr(ref, f)), f
        seen.append(s.id)
    assert seen == [s.id for s in folder.split("test")]


def test_an_export_is_byte_identical_and_resumes_after_a_lost_shard(dataset, export, tmp_path):
    again = tmp_path / "again"
    run(binary("datagen"), "export", dataset, "--webdataset", again, "--shard-samples", "5")
    names = sorted(p.name for p in export.glob("*.tar"))
    assert names == sorted(p.name for p in again.glob("*.tar"))
    for n in names + ["shards.json", "dataset.json"]:
        assert (export / n).read_bytes() == (again / n).read_bytes(), n
    # A killed run: one shard lost, one cut short, the record not yet written.
    (again / names[0]).unlink()
    with open(again / names[1], "r+b") as f:
        f.truncate(1000)
    (again / "shards.json").unlink()
    progress = {
        "source_index_checksum": json.loads((dataset / "dataset.json").read_text())["index_checksum"],
        "limits": json.loads((export / "shards.json").read_text())["limits"],
        "done": {
            t["name"]: t for s in json.loads((export / "shards.json").read_text())["splits"] for t in s["shards"]
        },
    }
    (again / ".export-progress.json").write_text(json.dumps(progress))
    r = run(binary("datagen"), "export", dataset, "--webdataset", again, "--shard-samples", "5")
    assert f"2 written now, {len(names) - 2} finished before" in r.stderr, r.stderr
    for n in names + ["shards.json"]:
        assert (export / n).read_bytes() == (again / n).read_bytes(), n
    other = subprocess.run(
        [str(binary("datagen")), "export", str(dataset), "--webdataset", str(again), "--shard-samples", "4"],
        capture_output=True,
        text=True,
    )
    assert other.returncode != 0 and "other shard limits" in other.stderr


def test_corrupt_truncated_and_missing_files_are_refused_by_name(dataset, export, tmp_path):
    data = copy_dataset(dataset, tmp_path / "bad")
    rec = md.open_dataset(data).split("train").records[1]
    image = data / rec["files"]["image"]
    raw = bytearray(image.read_bytes())
    raw[len(raw) // 2] ^= 0xFF
    image.write_bytes(bytes(raw))
    split = md.open_dataset(data).split("train")
    with pytest.raises(md.DatasetError) as e:
        split[1]
    assert e.value.file == str(image) and "checksum mismatch" in e.value.reason
    image.write_bytes(bytes(raw[: len(raw) // 3]))
    with pytest.raises(md.DatasetError) as e:
        md.open_dataset(data, verify=False).split("train")[1]
    assert e.value.file == str(image) and "cannot decode the EXR" in e.value.reason
    env = data / rec["files"]["env"]
    env.unlink()
    with pytest.raises(md.DatasetError) as e:
        md.open_dataset(data, verify=False).split("train")[1]
    assert e.value.file == str(env) and "cannot read" in e.value.reason
    with pytest.raises(KeyError, match="no split 'val' .*train, test"):
        md.open_dataset(data).split("val")

    index = data / "index.jsonl"
    index.write_text(index.read_text().replace('"category":"car"', '"category":"bus"', 1))
    with pytest.raises(md.DatasetError, match="index_checksum"):
        md.open_dataset(data)
    (data / "dataset.json").write_text((data / "dataset.json").read_text().replace("matedit-dataset-1", "matedit-dataset-2", 1))
    with pytest.raises(md.DatasetError, match="format 'matedit-dataset-2'.*another version"):
        md.open_dataset(data)
    with pytest.raises(md.DatasetError, match="not a dataset"):
        md.open_dataset(tmp_path)

    wds = copy_dataset(export, tmp_path / "bad-wds")
    tars = sorted(wds.glob("train-*.tar"))
    blob = bytearray(tars[0].read_bytes())
    at = blob.index(b"\x76\x2f\x31\x01")  # an EXR member's magic number: flip a byte inside it
    blob[at + 600] ^= 0xFF
    tars[0].write_bytes(bytes(blob))
    with pytest.raises(md.DatasetError) as e:
        list(md.open_dataset(wds).split("train"))
    assert e.value.file == str(tars[0]) and "checksum mismatch" in e.value.reason
    with open(tars[1], "r+b") as f:
        f.truncate(3000)
    shard = md.open_dataset(wds, verify=False).split("train").shards[1]
    with pytest.raises(md.DatasetError) as e:
        list(shard)
    assert e.value.file == str(tars[1]), e.value
    tars[2].unlink()
    with pytest.raises(md.DatasetError, match="missing"):
        list(md.open_dataset(wds).split("train").shards[2])
