"""Worker processes that die with their build: no orphan keeps computing (and writing shards) after a
``kill -9`` of ``datagen build``.

A local build (:mod:`datagen.dataset.build`) runs a ``ProcessPoolExecutor`` on the ``forkserver`` start
method: the build process starts a fork server (and multiprocessing's resource tracker), and the fork server
forks the workers. Linux's parent-death signal (``prctl(PR_SET_PDEATHSIG, SIGKILL)``) makes the kernel kill a
process when its parent dies, so:

- the fork server sets it on itself when it imports :mod:`datagen.dataset.forkserver_preload` (its preload
  module; :data:`BUILD_PID_ENV` names the build process it must outlive by nothing, and a fork server whose
  build already died ends at once);
- every worker sets it in the pool initializer (:func:`init_worker`; its parent is the fork server) and also
  starts a watch thread that exits the worker when the build process is gone (a second line of defence, and
  the only one where ``prctl`` does not exist; both from :mod:`datagen.processes`);
- the resource tracker exits by itself once every process holding its pipe (the build, the fork server, the
  workers) is gone.

Measured by tests/test_hostile_build.py: no process of a SIGKILLed build is left after 5 s.

:func:`check_build_options` checks the options that start and recycle the workers (with their upper bounds)
before a build runs anything.
"""
from __future__ import annotations

import os
import signal

import numpy as np

from ..processes import process_alive, set_parent_death_signal, watch_process

MAX_BUILD_WORKERS = 1024
"""Most worker processes (``--workers``; a Dask LocalCluster starts that many): each holds a sample's arrays."""

MAX_RETRIES = 100
"""Most extra attempts of a failed shard (``--retries``): a shard failing that often fails for good."""

MAX_TASKS_PER_WORKER = 10**6
"""Most shards a local worker computes before it is replaced (``--tasks-per-worker``)."""

BUILD_PID_ENV = "DATAGEN_BUILD_PID"
"""Environment variable holding the pid of the build process, read by the fork server's preload module."""


def guard_forkserver() -> None:
    """In the fork server (imported through :mod:`datagen.dataset.forkserver_preload`): die with the build
    process named by :data:`BUILD_PID_ENV`; exit at once if it is already gone. Does nothing in any other
    process (the variable is unset, or names another parent)."""
    pid = os.environ.get(BUILD_PID_ENV)
    if pid is None or not pid.isdigit():
        return
    if os.getppid() != int(pid):
        if not process_alive(int(pid)):
            os.kill(os.getpid(), signal.SIGKILL)
        return
    set_parent_death_signal()
    if not process_alive(int(pid)):   # died between the fork and the prctl
        os.kill(os.getpid(), signal.SIGKILL)


def init_worker(build_pid: int) -> None:
    """Pool-worker initializer: die with the fork server (parent-death signal) and with the build process
    ``build_pid`` (watch thread)."""
    set_parent_death_signal()
    watch_process(build_pid)


def check_build_options(workers: int | None, scheduler: str | None, retries: int, max_tasks_per_child: int) -> None:
    """Refuse invalid build options before anything runs or is written: ``--workers`` 0 ..
    :data:`MAX_BUILD_WORKERS`, ``--retries`` 0 .. :data:`MAX_RETRIES`, ``--tasks-per-worker`` 1 ..
    :data:`MAX_TASKS_PER_WORKER`, ``--scheduler`` "local" or an address.

    Raises:
        ValueError: naming the option (CLI spelling) and the value.
    """
    for option, value, low, high in (("--workers", workers, 0, MAX_BUILD_WORKERS),
                                     ("--retries", retries, 0, MAX_RETRIES),
                                     ("--tasks-per-worker", max_tasks_per_child, 1, MAX_TASKS_PER_WORKER)):
        if value is None and option == "--workers":
            continue
        if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < low:
            raise ValueError(f"{option} must be an integer >= {low}, got {value!r}")
        if value > high:
            raise ValueError(f"{option} {value} is above its bound of {high}: give at most {high}")
    if scheduler is not None and scheduler != "local" and (not isinstance(scheduler, str) or "://" not in scheduler):
        raise ValueError(f"--scheduler must be 'local' or an address such as tcp://HOST:8786, got {scheduler!r}")
