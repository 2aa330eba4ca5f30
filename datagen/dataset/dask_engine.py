"""The Dask engine of dataset builds (:mod:`datagen.dataset.build`): connect to a scheduler, or start a
``LocalCluster``, before anything is written; then run the shard tasks on it.

A scheduler that does not answer within :data:`SCHEDULER_TIMEOUT_S` seconds is a one-line
:class:`SchedulerError`; write errors no retry can fix (disk full, quota, read-only) stop the build at once.
"""
from __future__ import annotations

import errno
import os
import traceback
from typing import Callable, Iterator

from ..errors import ConfigError
from .store import ShardTask

SCHEDULER_TIMEOUT_S = 10
"""Seconds to reach a Dask scheduler before the build gives up (nothing is written before it answers)."""

FATAL_ERRNOS = frozenset({errno.ENOSPC, errno.EDQUOT, errno.EROFS})
"""Write errors no retry can fix (disk full, quota exceeded, read-only file system): the build stops at once,
keeping its finished shards for ``--resume``."""


class SchedulerError(ConfigError):
    """The Dask scheduler cannot be reached (or its address is not one); nothing was written."""


def fatal_error(exc: BaseException | None) -> bool:
    """True for a write error no retry can fix (:data:`FATAL_ERRNOS`)."""
    return isinstance(exc, OSError) and exc.errno in FATAL_ERRNOS


def connect_dask(scheduler: str, workers: int | None):
    """(client, cluster or None) for ``scheduler``: "local" starts a Dask LocalCluster of ``workers`` processes;
    an address ("tcp://host:8786") connects within :data:`SCHEDULER_TIMEOUT_S` seconds.

    Raises:
        SchedulerError: the address is malformed or the scheduler does not answer in time (one line).
    """
    import logging

    from distributed import Client, LocalCluster

    if scheduler == "local":
        cluster = LocalCluster(n_workers=workers or os.cpu_count() or 1, threads_per_worker=1, processes=True,
                               dashboard_address=None, silence_logs=logging.ERROR)
        return Client(cluster), cluster
    try:
        return Client(scheduler, timeout=f"{SCHEDULER_TIMEOUT_S}s"), None
    except (OSError, TimeoutError, ValueError, TypeError) as exc:
        reason = " ".join(f"{type(exc).__name__}: {exc}".split())[:200]
        raise SchedulerError(f"--scheduler {scheduler}: cannot reach the Dask scheduler within "
                             f"{SCHEDULER_TIMEOUT_S} s ({reason}); start it, or drop --scheduler to build with "
                             "local processes (nothing was written)") from None


def run_dask(write_shard: Callable, root: str, cfg: dict, tasks: list[ShardTask], client,
             retries: int) -> Iterator[tuple[ShardTask, "dict | None", "str | None"]]:
    """Run ``write_shard(root, cfg, task)`` for every task on the Dask ``client``, Dask retrying each up to
    ``retries`` times; yield (task, marker, None) or (task, None, reason) as they finish.

    Raises:
        OSError: a write error no retry fixes (:func:`fatal_error`), at once.
    """
    import uuid

    from distributed import as_completed

    run = uuid.uuid4().hex[:8]
    futures = {client.submit(write_shard, root, cfg, task, key=f"datagen-shard-{task.split}-{task.shard}-{run}",
                             retries=retries, pure=False): task for task in tasks}
    for fut in as_completed(futures):
        task = futures[fut]
        if fut.status == "finished":
            yield task, fut.result(), None
        else:
            exc = fut.exception()
            if fatal_error(exc):
                raise exc
            tb = "".join(traceback.format_tb(fut.traceback()))[-2000:] if fut.traceback() else ""
            yield task, None, f"{type(exc).__name__}: {exc}\n{tb}"
        fut.release()
