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
"""
from __future__ import annotations

import os
import signal

from ..processes import process_alive, set_parent_death_signal, watch_process

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
