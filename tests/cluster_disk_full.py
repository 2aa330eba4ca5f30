"""Test hook: a Dask worker preload (``dask worker ADDR --preload tests/cluster_disk_full.py``) that gives this
worker a full disk while the file named by :data:`FLAG_ENV` exists (tests/test_cluster_tcp.py).

It wraps zarr's local-store write (the call that puts a shard file's bytes on disk) so that it raises
``OSError(ENOSPC, "No space left on device", path)``, the error a full disk raises there; everything above it
(zarr, ``write_shard``, Dask, the build) runs unchanged. Used because a really full file system (a tiny tmpfs
or loop mount) needs root, which CI does not have. Never imported by datagen itself.
"""
from __future__ import annotations

import errno
import os

import zarr.storage._local as local_store

FLAG_ENV = "DATAGEN_TEST_DISK_FULL"
"""Environment variable of the worker: a path; while a file exists there, shard writes fail with ENOSPC."""

def _hooked(real_put):
    def put(path, value, *args, **kwargs):
        flag = os.environ.get(FLAG_ENV)
        if flag and os.path.exists(flag):
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(path))
        return real_put(path, value, *args, **kwargs)
    put.real_put = real_put
    return put


# Dask may execute a preload file more than once in a worker: wrap zarr's own function, never our wrapper
local_store._put = _hooked(getattr(local_store._put, "real_put", local_store._put))
