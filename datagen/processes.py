"""Process lifetime: child processes that die with their parent (Linux's parent-death signal) and a watch thread
for the processes whose parent is not the one to outlive.

Used by the dataset build's fork server and workers (:mod:`datagen.dataset.workers`) and by the lookin
estimator's fork workers (``--workers N``, :mod:`datagen.transport.lookin`): a ``kill -9`` of ``datagen`` then
leaves no process computing behind it.
"""
from __future__ import annotations

import ctypes
import os
import signal
import sys
import threading
import time

PR_SET_PDEATHSIG = 1
"""prctl option: signal sent to this process when its parent dies (linux/prctl.h)."""

WATCH_INTERVAL_S = 0.5
"""Seconds between a watch thread's checks that the watched process is still alive."""


def set_parent_death_signal(sig: int = signal.SIGKILL) -> bool:
    """Ask the kernel to send ``sig`` to this process when its parent dies (Linux); False elsewhere."""
    if not sys.platform.startswith("linux"):
        return False
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        return libc.prctl(PR_SET_PDEATHSIG, int(sig), 0, 0, 0) == 0
    except (OSError, AttributeError):
        return False


def process_alive(pid: int) -> bool:
    """True while process ``pid`` exists and is not a zombie (a killed process its parent has not reaped)."""
    try:
        with open(f"/proc/{pid}/stat", "rb") as fh:
            return fh.read().rsplit(b")", 1)[1].split()[0] not in (b"Z", b"X")
    except FileNotFoundError:
        return False
    except OSError:
        pass
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def watch_process(pid: int, interval: float = WATCH_INTERVAL_S) -> threading.Thread:
    """Start a daemon thread that kills this process (SIGKILL, as the parent-death signal would) once process
    ``pid`` is gone."""
    def watch():
        while process_alive(pid):
            time.sleep(interval)
        os.kill(os.getpid(), signal.SIGKILL)

    thread = threading.Thread(target=watch, name="datagen-parent-watch", daemon=True)
    thread.start()
    return thread
