"""Sample reads of a datagen dataset's arrays for the loader (:class:`datagen.dataset.NLOSDataset`).

Zarr's per-chunk read path costs ~1 ms per sample and field; a sample has a dozen fields. Each
field's shard file holds an index (offset, nbytes per inner chunk) at its end and one compressed chunk per
sample (``store.compression``: Blosc-LZ4 with byte shuffle by default, zstd or none), so the loader reads that
index once per shard and worker (cached), then ``pread``s and decodes just the sample's chunk (a few µs to
~20 µs), which keeps shuffled access as fast as sequential access. Arrays whose codecs are not the ones
:mod:`datagen.dataset.build` writes (or stores that are not local directories) fall back to zarr's own reader.

Checks on each read: the shard index's length, crc32c and bounds, and that the chunk decodes
(:func:`datagen.dataset.integrity.read_shard_index`, :func:`~datagen.dataset.integrity.corrupt_chunk`). A byte
changed inside a chunk's compressed data can still decode, to other values; with ``hashes`` (the loader's
``verify=True``) each shard file is first hashed whole against its recorded sha256, once per process.
"""
from __future__ import annotations

import json
import os
from collections import OrderedDict
from pathlib import Path
from typing import Callable

import numpy as np

from .integrity import EMPTY_CHUNK, REMEDY, DatasetCorruptError, corrupt_chunk, read_shard_index
from .store import file_sha256, read_marker

__all__ = ["OPEN_SHARDS", "FieldReader"]

OPEN_SHARDS = 8
"""Shard files kept open (with their decoded index) per field and worker."""


class FieldReader:
    """Sample reads of one array ``<root>/<split>/<name>``: fast path or zarr fallback (see the module doc).

    Per process it caches shard indexes and open file descriptors (``OPEN_SHARDS`` per field) and, given
    ``hashes`` (shard number → recorded sha256 hex or None), the shards whose hash matched (:meth:`verify`); none
    of it is pickled, so a DataLoader worker starts with empty caches and hashes again what it reads."""

    def __init__(self, root: Path, split: str, name: str, hashes: dict[int, str | None] | None = None):
        self.root, self.split, self.name, self.hashes = root, split, name, hashes
        self.prefix = str(root / split / name / "c") + "/"
        meta = json.loads((root / split / name / "zarr.json").read_text())
        self.shape = tuple(meta["shape"])
        self.sample_shape = self.shape[1:]
        self.suffix = "/0" * (len(self.shape) - 1)
        self.fill = meta.get("fill_value", 0)
        self.is_str = meta["data_type"] == "string"
        self.dtype = None if self.is_str else np.dtype(meta["data_type"]).newbyteorder("<")
        self._meta = meta
        self._reset()

    def _reset(self) -> None:
        self.shard_size, self.decode = _fast_path(self._meta, self.sample_shape, self.dtype, self.is_str)
        self._open: OrderedDict[int, tuple[int, np.ndarray]] = OrderedDict()
        self._zarr = None
        self._verified: set[int] = set()

    def verify(self, shard: int) -> None:
        """Hash shard file ``shard`` (:func:`datagen.dataset.store.file_sha256`) against its recorded sha256:
        ``hashes[shard]``, else the done marker's (:func:`datagen.dataset.store.read_marker`); once per process.

        Raises:
            DatasetCorruptError: the file is missing, no hash is recorded, or the hashes differ (names the file
                and :data:`datagen.dataset.integrity.REMEDY`).
        """
        if shard in self._verified:
            return
        path = f"{self.prefix}{shard}{self.suffix}"
        expected = (self.hashes or {}).get(shard) or (read_marker(self.root, self.split, shard) or {}).get(
            "sha256", {}).get(self.name)
        try:
            actual = file_sha256(Path(path))
        except FileNotFoundError:
            raise DatasetCorruptError(f"{path}: shard file missing; {REMEDY}") from None
        if expected is None:
            raise DatasetCorruptError(f"{path}: no sha256 recorded in the dataset card or the done marker, so "
                                      f"verify=True cannot check it; {REMEDY}")
        if actual != expected:
            raise DatasetCorruptError(f"{path}: sha256 {actual[:16]}… differs from the recorded {expected[:16]}…: "
                                      f"the shard changed after the build (damaged); {REMEDY}")
        self._verified.add(shard)

    def _shard(self, shard: int) -> tuple[int, np.ndarray]:
        """(open fd, (shard_size, 2) uint64 index of (offset, nbytes)) of shard ``shard``."""
        entry = self._open.get(shard)
        if entry is not None:
            self._open.move_to_end(shard)
            return entry
        path = f"{self.prefix}{shard}{self.suffix}"
        try:
            fd = os.open(path, os.O_RDONLY)
        except FileNotFoundError:
            raise DatasetCorruptError(f"{path}: shard file missing; {REMEDY}") from None
        try:
            entry = (fd, read_shard_index(fd, path, self.shard_size))   # length, crc32c and bounds checked
        except BaseException:
            os.close(fd)
            raise
        self._open[shard] = entry
        if len(self._open) > OPEN_SHARDS:
            os.close(self._open.popitem(last=False)[1][0])
        return entry

    def read(self, i: int) -> np.ndarray:
        """Sample ``i`` as an array of shape ``sample_shape`` (0-d object array holding a str for strings); with
        ``hashes``, its shard file is verified first (:meth:`verify`)."""
        if self.hashes is not None:
            self.verify(i // self._meta["chunk_grid"]["configuration"]["chunk_shape"][0])
        if self.decode is None:
            try:
                if self._zarr is None:
                    import zarr
                    self._zarr = zarr.open_array(str(self.root / self.split / self.name), mode="r")
                return np.asarray(self._zarr[i])
            except (OSError, ValueError, RuntimeError, MemoryError) as exc:
                raise corrupt_chunk(str(self.root / self.split / self.name), i, exc) from None
        shard, k = divmod(i, self.shard_size)
        fd, index = self._shard(shard)
        offset, nbytes = int(index[k, 0]), int(index[k, 1])
        if offset == EMPTY_CHUNK and nbytes == EMPTY_CHUNK:
            if self.is_str:
                return np.asarray(self.fill or "", dtype=object)
            return np.full(self.sample_shape, self.fill, dtype=self.dtype)
        try:
            return self.decode(os.pread(fd, nbytes, offset))
        except (OSError, ValueError, RuntimeError, MemoryError) as exc:   # damaged chunk bytes
            raise corrupt_chunk(f"{self.prefix}{shard}{self.suffix}", i, exc) from None

    def close(self) -> None:
        for fd, _ in self._open.values():
            os.close(fd)
        self._open.clear()

    def __del__(self):
        try:
            self.close()
        except Exception:  # noqa: BLE001 - interpreter shutdown
            pass

    def __getstate__(self):   # nothing opened or cached crosses a process boundary
        return {k: v for k, v in self.__dict__.items() if k not in ("_open", "_zarr", "decode", "shard_size",
                                                                  "_verified")}

    def __setstate__(self, state):
        self.__dict__.update(state)
        self._reset()


def _fast_path(meta: dict, sample_shape: tuple, dtype, is_str: bool) -> tuple[int | None, Callable | None]:
    """(samples per shard, decode(bytes) → sample array) when the array is laid out as :mod:`datagen.dataset.build`
    writes it (sharding codec, one sample per inner chunk, index at the end, bytes + blosc/zstd/no
    compression); (None, None) otherwise (the reader then uses zarr)."""
    codecs = meta.get("codecs", [])
    if len(codecs) != 1 or codecs[0]["name"] != "sharding_indexed":
        return None, None
    conf = codecs[0]["configuration"]
    shard_shape = meta["chunk_grid"]["configuration"]["chunk_shape"]
    if (conf.get("index_location", "end") != "end" or list(conf["chunk_shape"]) != [1, *sample_shape]
            or list(shard_shape[1:]) != list(sample_shape)
            or meta.get("chunk_key_encoding", {}).get("configuration", {}).get("separator", "/") != "/"
            or [c["name"] for c in conf["index_codecs"]] != ["bytes", "crc32c"]):
        return None, None
    inner = list(conf["codecs"])
    decompress: Callable = bytes
    if inner and inner[-1]["name"] == "zstd":
        from numcodecs.zstd import decompress
        inner = inner[:-1]
    elif inner and inner[-1]["name"] == "blosc":
        import numcodecs.blosc
        from numcodecs.blosc import decompress
        if numcodecs.blosc.use_threads is None:   # unset: blosc would look up the process on every call, and
            numcodecs.blosc.use_threads = False   # threads only cost time on one-sample chunks
        inner = inner[:-1]
    names = [c["name"] for c in inner]
    if is_str and names == ["vlen-utf8"]:
        from numcodecs import VLenUTF8
        vlen = VLenUTF8()
        return shard_shape[0], lambda raw: np.asarray(vlen.decode(decompress(raw))[0], dtype=object)
    if not is_str and names == ["bytes"] and inner[0].get("configuration", {}).get("endian", "little") == "little":
        def decode(raw: bytes) -> np.ndarray:
            return np.frombuffer(bytearray(decompress(raw)), dtype=dtype).reshape(sample_shape)
        return shard_shape[0], decode
    return None, None
