"""The Dask engine of dataset builds (:mod:`datagen.dataset.build`): connect to a scheduler, or start a
``LocalCluster``, before anything is written; then run the shard tasks on it.

A scheduler that does not answer within :data:`SCHEDULER_TIMEOUT_S` seconds, or has no worker within the
build's worker timeout (:data:`WORKER_TIMEOUT_S` by default, ``--worker-timeout``), is a one-line
:class:`SchedulerError` before anything is written; so are a scheduler lost mid-build and a build left without
any worker for that long (finished shards are kept for ``--resume``). Write errors no retry can fix (disk full,
quota, read-only) stop the build at once. A shard that fails for any other reason is reported with its
exception's type and message (``KilledWorker: …``, ``DatasetError: …``). docs/datasets.md, "Running on a
cluster", describes the fault behaviours.
"""
from __future__ import annotations

import errno
import os
import queue
import sys
import time
import traceback
from collections import Counter
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any, Callable, Iterator

from ..errors import ConfigError
from .store import ShardTask

SCHEDULER_TIMEOUT_S = 10
"""Seconds to reach a Dask scheduler before the build gives up (nothing is written before it answers)."""

WORKER_TIMEOUT_S = 60.0
"""Default seconds a build waits for at least one Dask worker on its scheduler (``--worker-timeout``): when
it connects, and whenever every worker is gone during the build."""

MAX_WORKER_TIMEOUT_S = 86400.0
"""Longest ``--worker-timeout``: a day."""

WATCH_S = 2.0
"""Seconds between checks of the worker count while no shard finishes."""

FATAL_ERRNOS = frozenset({errno.ENOSPC, errno.EDQUOT, errno.EROFS})
"""Write errors no retry can fix (disk full, quota exceeded, read-only file system): the build stops at once,
keeping its finished shards for ``--resume``."""


class SchedulerError(ConfigError):
    """The Dask scheduler cannot be reached (or its address is not one), has no worker, or was lost."""


def fatal_error(exc: BaseException | None) -> bool:
    """True for a write error no retry can fix (:data:`FATAL_ERRNOS`)."""
    return isinstance(exc, OSError) and exc.errno in FATAL_ERRNOS


class StoreWriteError(OSError):
    """The store cannot be written (:data:`FATAL_ERRNOS`); finished shards are kept, the build resumes later."""


@contextmanager
def named_write_errors(doing: str, then: str):
    """Turn a :func:`fatal_error` raised inside into a :class:`StoreWriteError` of one line naming what was being
    written and the file, when known: "No space left on device while ``doing`` (FILE); ``then``"."""
    try:
        yield
    except OSError as exc:
        if not fatal_error(exc):
            raise
        where = f" ({exc.filename})" if getattr(exc, "filename", None) else ""
        raise StoreWriteError(exc.errno, f"{os.strerror(exc.errno)} while {doing}{where}; {then}") from None


def one_line(exc: BaseException) -> str:
    """``exc`` as ``Type: message`` on one line (whitespace collapsed; the type alone if it has no message)."""
    text = " ".join(str(exc).split())
    return f"{type(exc).__name__}: {text}" if text else type(exc).__name__


@dataclass
class DaskConnection:
    """A connected Dask ``client``, the ``cluster`` this build started (a LocalCluster) or None, the
    ``scheduler`` as given and the ``worker_timeout`` in seconds."""

    client: Any
    cluster: Any
    scheduler: str
    worker_timeout: float

    def n_workers(self) -> int:
        """Workers connected to the scheduler now (0 when it cannot be asked)."""
        try:
            return len(self.client.nthreads())
        except Exception:  # noqa: BLE001 - a scheduler that does not answer has no usable worker
            return 0

    def close(self) -> None:
        """Close the client and, if this build started it, the LocalCluster. The client's log is muted
        meanwhile: closing a client that is still trying to reach a lost scheduler logs a traceback."""
        import logging

        log = logging.getLogger("distributed.client")
        level = log.level
        log.setLevel(logging.CRITICAL)
        try:
            self.client.close()
            if self.cluster is not None:
                self.cluster.close()
        finally:
            log.setLevel(level)


def check_worker_timeout(worker_timeout) -> None:
    """Refuse a worker timeout that is not a number of seconds > 0 and at most :data:`MAX_WORKER_TIMEOUT_S`
    (ValueError naming ``--worker-timeout``)."""
    ok = isinstance(worker_timeout, (int, float)) and not isinstance(worker_timeout, bool)
    if not (ok and 0 < worker_timeout < float("inf")):
        raise ValueError(f"--worker-timeout must be a number of seconds > 0, got {worker_timeout!r}")
    if worker_timeout > MAX_WORKER_TIMEOUT_S:
        raise ValueError(f"--worker-timeout {worker_timeout:g} is above its bound of {MAX_WORKER_TIMEOUT_S:g} s (a "
                         "day): a build waits that long at most for a worker")


def connect_dask(scheduler: str, workers: int | None, worker_timeout: float = WORKER_TIMEOUT_S,
                 say: Callable[[str], None] | None = None) -> DaskConnection:
    """Connect for a build: "local" starts a Dask LocalCluster of ``workers`` processes; an address
    ("tcp://host:8786") connects within :data:`SCHEDULER_TIMEOUT_S` seconds, says (``say``, default: a line on
    stderr) how many workers are connected, and waits up to ``worker_timeout`` seconds for the first one.

    Raises:
        SchedulerError: the address is malformed, the scheduler does not answer in time, or no worker
            connected within ``worker_timeout`` s (one line naming the address; nothing was written).
    """
    import logging

    from distributed import Client, LocalCluster

    if scheduler == "local":
        cluster = LocalCluster(n_workers=workers or os.cpu_count() or 1, threads_per_worker=1, processes=True,
                               dashboard_address=None, silence_logs=logging.ERROR)
        return DaskConnection(Client(cluster), cluster, scheduler, worker_timeout)
    say = say or (lambda line: print(line, file=sys.stderr, flush=True))
    try:
        conn = DaskConnection(Client(scheduler, timeout=f"{SCHEDULER_TIMEOUT_S}s"), None, scheduler, worker_timeout)
    except (OSError, TimeoutError, ValueError, TypeError) as exc:
        raise SchedulerError(f"--scheduler {scheduler}: cannot reach the Dask scheduler within "
                             f"{SCHEDULER_TIMEOUT_S} s ({one_line(exc)[:200]}); start it, or drop --scheduler to "
                             "build with local processes (nothing was written)") from None
    n = conn.n_workers()
    say(f"dask scheduler {scheduler}: {n} worker(s) connected" +
        ("" if n else f"; waiting up to {worker_timeout:g} s for one (--worker-timeout)"))
    if n == 0:
        try:
            conn.client.wait_for_workers(1, timeout=worker_timeout)
        except (OSError, TimeoutError):
            conn.close()
            raise SchedulerError(f"--scheduler {scheduler}: no Dask worker connected within {worker_timeout:g} s "
                                 f"(--worker-timeout); start workers with `dask worker {scheduler}` "
                                 "(nothing was written)") from None
        say(f"dask scheduler {scheduler}: {conn.n_workers()} worker(s) connected")
    return conn


def _lost_scheduler(exc: BaseException) -> bool:
    return getattr(exc, "reason", None) == "scheduler-connection-lost"


def run_dask(write_shard: Callable, root: str, cfg: dict, tasks: list[ShardTask], conn: DaskConnection,
             retries: int) -> Iterator[tuple[ShardTask, "dict | None", "str | None"]]:
    """Run ``write_shard(root, cfg, task)`` for every task on the Dask connection ``conn``, retrying a failed
    one up to ``retries`` times (from here, not by Dask, so that a full disk is not retried); yield
    (task, marker, None) or (task, None, reason) as they finish, the reason's first line being the exception's
    ``Type: message`` (:func:`one_line`; ``KilledWorker: …`` for a shard whose workers kept dying), the
    traceback after it. Waiting never blocks unwatched: every :data:`WATCH_S` seconds without news (no shard
    finished, or a finished shard's marker not fetched yet because its worker died and Dask recomputes it) the
    worker count is checked against ``conn.worker_timeout``.

    Raises:
        OSError: a write error no retry fixes (:func:`fatal_error`), at once.
        SchedulerError: the connection to the scheduler was lost, or no worker was connected for
            ``conn.worker_timeout`` seconds while shards were left (one line; finished shards are kept).
    """
    import uuid

    run = uuid.uuid4().hex[:8]
    finished: queue.Queue = queue.Queue()
    futures, attempts = {}, Counter()

    def submit(task: ShardTask) -> None:
        key = f"datagen-shard-{task.split}-{task.shard}-{run}-{attempts[task]}"
        fut = conn.client.submit(write_shard, root, cfg, task, key=key, pure=False)
        futures[fut] = task
        fut.add_done_callback(finished.put)

    for task in tasks:
        submit(task)
    alone_since = None   # when the build was first seen without any worker

    def watch(left: int) -> None:   # nothing came for WATCH_S seconds: give up if no worker for too long
        nonlocal alone_since
        alone_since = None if conn.n_workers() else (alone_since or time.monotonic())
        if alone_since is not None and time.monotonic() - alone_since > conn.worker_timeout:
            raise SchedulerError(f"--scheduler {conn.scheduler}: no Dask worker connected for "
                                 f"{conn.worker_timeout:g} s (--worker-timeout) with {left} shard(s) left; the "
                                 "finished shards are kept: start workers, then run again with --resume")

    def result(fut):   # the marker; a worker that died before it was fetched has it recomputed: keep watching
        while True:
            try:
                return fut.result(timeout=WATCH_S)
            except TimeoutError:
                if fut.status == "error":   # the task's own TimeoutError
                    raise
                watch(len(futures) + 1)

    while futures:
        try:
            fut = finished.get(timeout=WATCH_S)
        except queue.Empty:
            watch(len(futures))
            continue
        task = futures.pop(fut)
        try:
            marker = result(fut)
        except SchedulerError:
            raise
        except Exception as exc:  # noqa: BLE001 - any failure of a shard is reported, not fatal
            if fatal_error(exc):
                raise exc from None
            if _lost_scheduler(exc):
                raise SchedulerError(f"--scheduler {conn.scheduler}: lost the connection to the Dask scheduler "
                                     "mid-build; the shards finished so far are kept: restart it and its workers, "
                                     "then run again with --resume") from None
            attempts[task] += 1
            if attempts[task] <= retries:
                submit(task)
            else:
                tb = "".join(traceback.format_tb(exc.__traceback__))[-2000:]
                yield task, None, f"{one_line(exc)}\n{tb}"
        else:
            yield task, marker, None
        fut.release()
