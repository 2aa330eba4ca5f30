"""datagen.processes.ForkedCall: a function in a forked child, its value or its exception back, no process left."""
import os
import signal
import sys
import time

import numpy as np
import pytest

from datagen.processes import ForkedCall

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="fork and /proc")


def _reaped_within(pid: int, seconds: float) -> bool:
    """True once ``pid`` has left /proc: exited *and* reaped (a zombie still has its /proc entry)."""
    deadline = time.monotonic() + seconds
    while os.path.exists(f"/proc/{pid}") and time.monotonic() < deadline:
        time.sleep(0.01)
    return not os.path.exists(f"/proc/{pid}")


def test_forked_call_returns_the_childs_value_computed_from_inherited_arguments():
    data = np.arange(300_000, dtype=np.float64)      # inherited, not pickled; the 2.4 MB result exceeds a pipe buffer
    call = ForkedCall(lambda a, k: (os.getpid(), a * k), data, 3.0)
    pid, value = call.result()
    assert pid == call.pid and pid != os.getpid()
    np.testing.assert_array_equal(value, data * 3.0)
    assert _reaped_within(call.pid, 5.0)           # reaped by its daemon thread: no zombie


def test_forked_call_reraises_the_childs_exception_in_the_parent():
    def fail():
        raise ValueError("replica 3: bad sink")

    call = ForkedCall(fail)
    with pytest.raises(ValueError, match="replica 3: bad sink"):
        call.result()


def test_forked_call_names_a_child_that_died_without_a_result():
    call = ForkedCall(lambda: os.kill(os.getpid(), signal.SIGKILL))
    with pytest.raises(ChildProcessError, match=f"forked worker {call.pid} died without a result"):
        call.result()
    assert _reaped_within(call.pid, 0.0)


def test_cancel_kills_and_reaps_a_running_child():
    call = ForkedCall(time.sleep, 60)
    t0 = time.monotonic()
    call.cancel()
    assert time.monotonic() - t0 < 5.0 and _reaped_within(call.pid, 0.0)
    call.cancel()                                   # a second cancel is a no-op


def _call_in_daemon(queue):
    queue.put(ForkedCall(lambda: 41 + 1).result())


def test_forked_call_works_inside_a_daemonic_process():
    """multiprocessing forbids daemonic processes children of its own (a ProcessPoolExecutor there fails); a forked
    call is a plain fork and works (e.g. a simulate inside a daemonic worker of another pool)."""
    import multiprocessing as mp

    ctx = mp.get_context("fork")
    queue = ctx.Queue()
    proc = ctx.Process(target=_call_in_daemon, args=(queue,), daemon=True)
    proc.start()
    try:
        assert queue.get(timeout=30) == 42
    finally:
        proc.join(timeout=30)
    assert proc.exitcode == 0
