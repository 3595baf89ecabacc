"""Opening a dataset: a folder written by ``datagen run`` or a WebDataset export written by
``datagen export --webdataset``, checked on opening as the Rust trainer checks it
(``trainer/src/data/mod.rs``): the format version, the index's checksum against
``dataset.json``, every record's split, materials and files, the counts per split. Every
sample file is checked against its blake3 checksum as it is read, unless ``verify=False``.
Errors are :class:`DatasetError`, naming the file and the check that failed.
"""

from __future__ import annotations

import json
import os
import tarfile
from pathlib import Path, PurePosixPath
from typing import Dict, Iterator, List, Optional, Sequence

import blake3
import numpy as np

from .sample import DatasetError, Material, Sample, decode_env, decode_image

#: The dataset format this reader reads (``dataset.json`` → ``format``).
FORMAT = "matedit-dataset-1"
#: The WebDataset export's format (``shards.json`` → ``format``).
WEBDATASET_FORMAT = "matedit-webdataset-1"


def checksum(data: bytes) -> str:
    """``blake3:HEX`` of some bytes, as the index records them."""
    return "blake3:" + blake3.blake3(data).hexdigest()


def _read_json(path: Path) -> dict:
    try:
        text = path.read_bytes()
    except OSError as e:
        raise DatasetError(path, f"cannot read: {e.strerror or e}") from None
    try:
        return json.loads(text)
    except ValueError as e:
        raise DatasetError(path, f"not JSON: {e}") from None


def _file_stem(material_id: str) -> str:
    """The file name of a material id (``datagen``'s ``materials::file_stem``)."""
    return "".join(c if (c.isascii() and c.isalnum()) or c in "-." else "_" for c in material_id)


def _plain(rel: str) -> bool:
    """Whether a recorded path stays inside the dataset (a record comes from a file anyone can edit)."""
    p = PurePosixPath(rel)
    return bool(rel) and not p.is_absolute() and all(part not in ("", ".", "..") for part in rel.split("/"))


class Shard:
    """A unit of reading: a shard folder of a dataset, or one tar of an export. Iterating it
    yields its samples in index order; :class:`matedit_data.torch.ShardDataset` deals shards to
    DataLoader workers."""

    def __init__(self, dataset: "Dataset", name: str, records: List[dict], tar: Optional[Path] = None):
        self.dataset = dataset
        self.name = name
        self.records = records
        self.tar = tar

    def __len__(self) -> int:
        return len(self.records)

    def __iter__(self) -> Iterator[Sample]:
        if self.tar is None:
            for r in self.records:
                yield self.dataset.load(r)
        else:
            yield from self.dataset._read_tar(self)

    def __repr__(self) -> str:
        return f"Shard({self.name!r}, {len(self)} samples)"


class Split:
    """A split's samples in index order."""

    def __init__(self, dataset: "Dataset", name: str, role: str, records: List[dict], shards: List[Shard]):
        self.dataset = dataset
        self.name = name
        self.role = role
        self.records = records
        self.shards = shards

    def __len__(self) -> int:
        return len(self.records)

    def __iter__(self) -> Iterator[Sample]:
        for shard in self.shards:
            yield from shard

    def __getitem__(self, i: int) -> Sample:
        """Sample ``i`` of the split (random access: dataset folders only; a tar is read in order)."""
        if self.dataset.kind != "folder":
            raise TypeError("a WebDataset export is read in order: iterate the split or its shards")
        return self.dataset.load(self.records[i])

    def __repr__(self) -> str:
        return f"Split({self.name!r}, role={self.role!r}, {len(self)} samples, {len(self.shards)} shards)"


class Dataset:
    """An opened dataset. ``kind`` is ``"folder"`` or ``"webdataset"``; ``info`` is
    ``dataset.json`` as read (manifest, split membership, content, material table)."""

    def __init__(self, path, verify: bool = True):
        self.dir = Path(path)
        self.verify = verify
        if (self.dir / "shards.json").is_file():
            self.kind = "webdataset"
        elif (self.dir / "dataset.json").is_file():
            self.kind = "folder"
        else:
            raise DatasetError(
                self.dir / "dataset.json",
                "missing: not a dataset (an unfinished run? `datagen join` writes it)",
            )
        ds_path = self.dir / "dataset.json"
        self.info = _read_json(ds_path)
        if self.info.get("format") != FORMAT:
            raise DatasetError(
                ds_path,
                f"format {self.info.get('format')!r}: this reader reads {FORMAT!r} (a dataset of another version)",
            )
        self.name: str = self.info.get("name", "")
        self.manifest: dict = self.info.get("manifest", {})
        self.materials: Dict[str, Material] = {}
        for mid, m in self.info.get("materials", {}).items():
            self.materials[mid] = self._material(ds_path, mid, m)
        self._splits: Dict[str, Split] = {}
        if self.kind == "folder":
            self._open_folder(ds_path)
        else:
            self._open_export()

    # -- opening ---------------------------------------------------------------------------------

    def _material(self, where: Path, mid: str, m: dict) -> Material:
        spec = None
        if self.kind == "folder":
            spec = "dsbrdf:" + str(self.dir / "materials" / f"{_file_stem(mid)}.dsbrdf.json")
        return _material(where, f"material {mid}", mid, m, spec)

    def _check_record(self, at: str, rec: dict) -> None:
        regions = rec.get("regions", [])
        r = len(regions)
        if not 1 <= r <= 255:
            raise DatasetError(at, f"sample {rec.get('id')}: {r} regions: expected 1 to 255")
        if len(rec.get("material_ids", [])) != r or len(rec.get("target_material_ids", [])) != r:
            raise DatasetError(at, f"sample {rec.get('id')}: one material and one target per region expected ({r} regions)")
        for mid in rec["material_ids"] + rec["target_material_ids"]:
            if mid not in self.materials:
                raise DatasetError(at, f"sample {rec.get('id')}: material {mid} is not in dataset.json's material table")
        for key in ("image", "env"):
            rel = rec.get("files", {}).get(key)
            if rel is None or key not in rec.get("checksums", {}):
                raise DatasetError(at, f"sample {rec.get('id')}: no {key} file or checksum recorded")
            if not _plain(rel):
                raise DatasetError(at, f"sample {rec.get('id')}: {key} file {rel!r} is not a plain path inside the dataset")

    def _open_folder(self, ds_path: Path) -> None:
        index_path = self.dir / "index.jsonl"
        try:
            index = index_path.read_bytes()
        except OSError as e:
            raise DatasetError(index_path, f"cannot read: {e.strerror or e}") from None
        splits = {s["name"]: [] for s in self.info.get("splits", [])}
        ids = set()
        for n, line in enumerate(index.split(b"\n"), start=1):
            if not line.strip():
                continue
            at = f"{index_path}:{n}"
            try:
                rec = json.loads(line)
            except ValueError as e:
                raise DatasetError(at, f"bad record: {e}") from None
            self._check_record(at, rec)
            if rec["id"] in ids:
                raise DatasetError(at, f"sample id {rec['id']} appears twice")
            ids.add(rec["id"])
            if rec.get("split") not in splits:
                raise DatasetError(at, f"split {rec.get('split')!r} is not in {ds_path}")
            splits[rec["split"]].append(rec)
        if checksum(index) != self.info.get("index_checksum"):
            raise DatasetError(index_path, f"checksum differs from {ds_path}'s index_checksum (modified or from another run)")
        for s in self.info.get("splits", []):
            records = splits[s["name"]]
            want = self.info.get("counts", {}).get(s["name"], 0)
            if len(records) != want:
                raise DatasetError(index_path, f"{len(records)} samples of split {s['name']}, {ds_path} says {want}")
            by_shard: Dict[str, List[dict]] = {}
            for r in records:
                by_shard.setdefault(r["shard"], []).append(r)
            shards = [Shard(self, name, recs) for name, recs in by_shard.items()]
            self._splits[s["name"]] = Split(self, s["name"], s.get("role", ""), records, shards)

    def _open_export(self) -> None:
        rec_path = self.dir / "shards.json"
        rec = _read_json(rec_path)
        if rec.get("format") != WEBDATASET_FORMAT:
            raise DatasetError(
                rec_path,
                f"format {rec.get('format')!r}: this reader reads {WEBDATASET_FORMAT!r} (an export of another version)",
            )
        if rec.get("source_index_checksum") != self.info.get("index_checksum"):
            raise DatasetError(rec_path, "exported from another dataset than its dataset.json describes")
        self.export = rec
        for s in rec.get("splits", []):
            shards = []
            for t in s.get("shards", []):
                name = t["name"]
                if not _plain(name) or "/" in name:
                    raise DatasetError(rec_path, f"shard {name!r} is not a file name")
                shards.append(Shard(self, name, [None] * int(t["samples"]), tar=self.dir / name))
            records = [None] * int(s.get("samples", 0))
            if sum(len(x) for x in shards) != len(records):
                raise DatasetError(rec_path, f"split {s['name']}: its shards' samples do not add up to {len(records)}")
            self._splits[s["name"]] = Split(self, s["name"], s.get("role", ""), records, shards)

    # -- what a user asks for -------------------------------------------------------------------

    @property
    def splits(self) -> List[str]:
        """Split names in manifest order."""
        return list(self._splits)

    @property
    def counts(self) -> Dict[str, int]:
        return {name: len(s) for name, s in self._splits.items()}

    def split(self, name: str) -> Split:
        try:
            return self._splits[name]
        except KeyError:
            raise KeyError(f"{self.dir}: no split {name!r} (it has {', '.join(self._splits)})") from None

    def __repr__(self) -> str:
        counts = ", ".join(f"{k}: {v}" for k, v in self.counts.items())
        return f"Dataset({str(self.dir)!r}, {self.kind}, {counts})"

    # -- reading samples ------------------------------------------------------------------------

    def _read(self, rec: dict, key: str) -> bytes:
        path = self.dir / rec["files"][key]
        try:
            data = path.read_bytes()
        except OSError as e:
            raise DatasetError(path, f"cannot read: {e.strerror or e}") from None
        if self.verify:
            got, want = checksum(data), rec["checksums"][key]
            if got != want:
                raise DatasetError(path, f"checksum mismatch (corrupt or modified): {got}, the index says {want}")
        return data

    def load(self, rec: dict) -> Sample:
        """Reads and decodes the sample of an index record (folder datasets)."""
        image = self._read(rec, "image")
        env = self._read(rec, "env")
        return self._decode(rec, image, env, self.dir / rec["files"]["image"], self.dir / rec["files"]["env"])

    def _decode(self, rec: dict, image: bytes, env: bytes, image_name, env_name, materials=None) -> Sample:
        try:
            px = decode_image(image, len(rec["regions"]))
        except ValueError as e:
            raise DatasetError(image_name, str(e)) from None
        try:
            env_px, env_sanitized = decode_env(env)
        except ValueError as e:
            raise DatasetError(env_name, str(e)) from None
        table = materials or self.materials
        return Sample(
            id=rec["id"],
            split=rec["split"],
            index=rec["index"],
            category=rec["category"],
            shape_id=rec["shape_id"],
            regions=list(rec["regions"]),
            I=px.I,
            O=px.O,
            normals=px.normals,
            mask=px.mask,
            region_map=px.region_map,
            env=env_px,
            materials=[table[m] for m in rec["material_ids"]],
            target_materials=[table[m] for m in rec["target_material_ids"]],
            env_id=rec["env_id"],
            record=rec,
            sanitized=px.sanitized + env_sanitized,
            dropped=px.dropped,
        )

    def _read_tar(self, shard: Shard) -> Iterator[Sample]:
        path = shard.tar
        want = len(shard)
        seen = 0
        try:
            with tarfile.open(path, mode="r:") as tar:
                for rec, members in _group(tar, path):
                    yield self.sample_from_members(rec, members, path)
                    seen += 1
        except FileNotFoundError:
            raise DatasetError(path, "missing (the export is incomplete: rerun `datagen export`)") from None
        except (tarfile.TarError, EOFError, OSError) as e:
            raise DatasetError(path, f"cannot read the tar (truncated or corrupt?): {e}") from None
        if seen != want:
            raise DatasetError(path, f"{seen} samples, shards.json says {want} (truncated?)")

    def sample_from_members(self, rec: dict, members: Dict[str, bytes], where) -> Sample:
        """The sample of one WebDataset key: its record (the ``json`` member) and its ``exr`` and
        ``env.exr`` members, checked against the record's checksums."""
        for key, ext in (("image", "exr"), ("env", "env.exr")):
            if ext not in members:
                raise DatasetError(where, f"sample {rec.get('id')}: no {ext} member")
            if self.verify:
                got, want = checksum(members[ext]), rec.get("checksums", {}).get(key)
                if got != want:
                    raise DatasetError(
                        where, f"sample {rec.get('id')}: member {ext}: checksum mismatch (corrupt or modified): {got}, its record says {want}"
                    )
        table = sample_materials(rec, where)
        name = lambda ext: f"{where}:{rec['id']}.{ext}"  # noqa: E731
        return self._decode(rec, members["exr"], members["env.exr"], name("exr"), name("env.exr"), table)


def _material(where, what: str, mid: str, m: dict, spec: Optional[str]) -> Material:
    """A material record (`raw`, `normalised`, `group`) as a :class:`Material`, checked."""
    raw = np.asarray(m.get("raw", []), dtype=np.float64)
    norm = np.asarray(m.get("normalised", []), dtype=np.float64)
    if norm.shape != (108,) or raw.shape != (108,) or not np.isfinite(norm).all():
        raise DatasetError(where, f"{what}: expected 108 finite raw and normalised parameters")
    return Material(mid, m.get("group", mid), raw, norm.astype(np.float32), spec)


def sample_materials(rec: dict, where) -> Dict[str, Material]:
    """The materials a WebDataset sample's JSON member carries, by id."""
    out = {}
    for m in rec.get("materials", []) + rec.get("target_materials", []):
        mid = m.get("id", "")
        out[mid] = _material(where, f"sample {rec.get('id')}: material {mid}", mid, m, None)
    for mid in rec.get("material_ids", []) + rec.get("target_material_ids", []):
        if mid not in out:
            raise DatasetError(where, f"sample {rec.get('id')}: material {mid} is not in its JSON member")
    return out


def _group(tar: tarfile.TarFile, path) -> Iterator[tuple]:
    """(record, {ext: bytes}) per key of a tar, in order (WebDataset's grouping: the key is the
    name up to its first dot, and a sample's members are consecutive)."""
    key, members = None, {}

    def done():
        if "json" not in members:
            raise DatasetError(path, f"sample {key}: no json member")
        try:
            rec = json.loads(members.pop("json"))
        except ValueError as e:
            raise DatasetError(path, f"sample {key}: json member: {e}") from None
        if rec.get("id") != key:
            raise DatasetError(path, f"member key {key} holds the record of {rec.get('id')!r}")
        return rec, members

    for info in tar:
        if not info.isfile():
            continue
        base = os.path.basename(info.name)
        k, _, ext = base.partition(".")
        if k != key and key is not None:
            yield done()
            members = {}
        key = k
        f = tar.extractfile(info)
        members[ext] = f.read() if f else b""
    if key is not None:
        yield done()


def open_dataset(path, verify: bool = True) -> Dataset:
    """Opens a dataset folder (``datagen run``) or a WebDataset export (``datagen export
    --webdataset``). With ``verify`` (the default), every sample file is checked against its
    blake3 checksum as it is read."""
    return Dataset(path, verify=verify)


__all__: Sequence[str] = ["Dataset", "Split", "Shard", "open_dataset", "checksum", "FORMAT", "WEBDATASET_FORMAT"]
