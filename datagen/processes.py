"""Process lifetime: child processes that die with their parent (Linux's parent-death signal) and a watch thread
for the processes whose parent is not the one to outlive.

Used by the dataset build's fork server and workers (:mod:`datagen.dataset.workers`), by the lookin
estimator's fork workers (``--workers N``, :mod:`datagen.transport.lookin`) and by the area sampler's forked
replicas (:class:`ForkedCall`): a ``kill -9`` of ``datagen`` then leaves no process computing behind it.
"""
from __future__ import annotations

import ctypes
import os
import pickle
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


class ForkedCall:
    """``fn(*args)`` in a forked child process; :meth:`result` returns its value or raises its exception.

    The child inherits ``fn`` and ``args`` (nothing is pickled on the way in), dies with this process (parent-death
    signal), sends its return value pickled through a pipe and leaves with ``os._exit`` (no atexit handlers, no
    flush of inherited stdio buffers). Cheaper than a one-task ``ProcessPoolExecutor`` (no management thread,
    queues or shutdown handshake: ≈ 25 ms less per 2-worker demo-room run, docs/accuracy.md), and usable inside
    daemonic processes: the area sampler forks one per worker beyond the first. Its child is reaped by a daemon
    thread once the result is read, so the parent does not wait for the child's exit. Call :meth:`cancel` if the
    result will not be read (an exception in the parent): the child is killed and reaped. Linux/POSIX only
    (``os.fork``).

    Raises (from :meth:`result`):
        ChildProcessError: the child died without a result (killed, out of memory), naming its pid and status.
        the child's own exception, re-raised in the parent (as ``RuntimeError`` with its text if it cannot be
        pickled).
    """

    def __init__(self, fn, *args) -> None:
        parent = os.getpid()
        read, write = os.pipe()
        pid = os.fork()
        if pid == 0:                                         # the child: run, send, leave
            status = 0
            try:
                os.close(read)
                set_parent_death_signal()
                if os.getppid() != parent:                   # the parent died before the signal was armed
                    os._exit(1)
                try:
                    payload = pickle.dumps((True, fn(*args)), protocol=pickle.HIGHEST_PROTOCOL)
                except BaseException as exc:                 # noqa: BLE001 — sent to the parent, re-raised there
                    try:
                        payload = pickle.dumps((False, exc))
                    except Exception:                        # noqa: BLE001 — an exception that cannot be pickled
                        payload = pickle.dumps((False, RuntimeError(f"{type(exc).__name__}: {exc}")))
                with os.fdopen(write, "wb") as fh:
                    fh.write(payload)
            except BaseException:                            # noqa: BLE001 — never return into the parent's code
                status = 1
            finally:
                os._exit(status)
        os.close(write)
        self.pid, self._read, self._done = pid, read, False

    def result(self):
        """The child's return value (blocks until the child has sent it)."""
        with os.fdopen(self._read, "rb") as fh:
            data = fh.read()
        self._done = True
        if not data:
            _, status = os.waitpid(self.pid, 0)
            raise ChildProcessError(f"forked worker {self.pid} died without a result (wait status {status})")
        threading.Thread(target=_reap, args=(self.pid,), name="datagen-reap", daemon=True).start()
        ok, value = pickle.loads(data)
        if not ok:
            raise value
        return value

    def cancel(self) -> None:
        """Kill and reap the child when its result will not be read (no-op after :meth:`result`)."""
        if self._done:
            return
        self._done = True
        try:
            os.kill(self.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
        os.close(self._read)
        os.waitpid(self.pid, 0)


def _reap(pid: int) -> None:
    try:
        os.waitpid(pid, 0)
    except ChildProcessError:
        pass
