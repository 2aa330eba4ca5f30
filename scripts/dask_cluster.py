#!/usr/bin/env python
"""Start a Dask cluster on this machine: one scheduler and N workers, separate processes on TCP (127.0.0.1).

    python scripts/dask_cluster.py --workers 2                 # prints the address, runs until Ctrl-C
    python scripts/dask_cluster.py --workers 2 -- datagen build configs/datasets/smoke.yaml \\
        --out out/smoke --scheduler {address}                  # runs the command, then stops the cluster

The first line printed on stdout is the scheduler's address (``tcp://127.0.0.1:PORT``). Each process (the
scheduler, each ``dask worker`` with its nanny) runs in its own process group; stopping the cluster (Ctrl-C,
SIGTERM, or the end of the command) sends SIGTERM to every group, then SIGKILL to what is left after
:data:`STOP_GRACE_S` seconds, so no process is left behind. Workers run one single-threaded process each, as
datagen's shard tasks expect (docs/datasets.md, "Running on a cluster").

Also importable (tests/test_cluster_tcp.py uses :class:`LocalTcpCluster` to kill single workers or the
scheduler).
"""
from __future__ import annotations

import argparse
import json
import os
import signal
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

START_TIMEOUT_S = 60
"""Seconds for the scheduler to write its address and for the workers to connect."""
STOP_GRACE_S = 10
"""Seconds between SIGTERM and SIGKILL when stopping."""


def free_port(host: str = "127.0.0.1") -> int:
    """A TCP port free on ``host`` now (the OS picks it)."""
    with socket.socket() as s:
        s.bind((host, 0))
        return s.getsockname()[1]


def _kill_group(proc: subprocess.Popen, sig: int) -> None:
    try:
        os.killpg(proc.pid, sig)
    except (ProcessLookupError, PermissionError):
        pass


class LocalTcpCluster:
    """A ``dask scheduler`` and ``n_workers`` ``dask worker`` processes on ``host``, each in its own process
    group (``start_new_session``). ``address`` is set once :meth:`start` returns; logs go to ``workdir``.

    Args:
        n_workers: worker processes (each ``--nthreads 1``).
        host: interface to bind (TCP).
        port: scheduler port (0: a free one).
        workdir: directory for the scheduler file and the logs (default: a new temporary one).
        worker_args: extra arguments for every ``dask worker`` (e.g. ``["--preload", "mod.py"]``).
        env: extra environment variables of the workers.
    """

    def __init__(self, n_workers: int = 2, host: str = "127.0.0.1", port: int = 0, workdir: str | Path | None = None,
                 worker_args: list[str] | None = None, env: dict[str, str] | None = None):
        self.n_workers, self.host, self.port = n_workers, host, port or free_port(host)
        self.workdir = Path(workdir or tempfile.mkdtemp(prefix="dask-cluster-"))
        self.worker_args, self.env = list(worker_args or []), dict(env or {})
        self.address = f"tcp://{host}:{self.port}"
        self.scheduler: subprocess.Popen | None = None
        self.workers: list[subprocess.Popen] = []

    def _spawn(self, args: list[str], log: str, env: dict[str, str] | None = None) -> subprocess.Popen:
        out = open(self.workdir / log, "ab")
        try:
            return subprocess.Popen(args, stdout=out, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
                                    start_new_session=True, env={**os.environ, **(env or {})})
        finally:
            out.close()

    def start_scheduler(self) -> str:
        """Start the scheduler; return its address once it answers (RuntimeError after
        :data:`START_TIMEOUT_S` s, with its log)."""
        self.workdir.mkdir(parents=True, exist_ok=True)
        info = self.workdir / f"scheduler-{self.port}.json"
        info.unlink(missing_ok=True)
        self.scheduler = self._spawn([sys.executable, "-m", "dask", "scheduler", "--host", self.host,
                                      "--port", str(self.port), "--no-dashboard", "--scheduler-file", str(info)],
                                     "scheduler.log")
        deadline = time.monotonic() + START_TIMEOUT_S
        while time.monotonic() < deadline:
            if self.scheduler.poll() is not None:
                break
            if info.exists():
                try:
                    self.address = json.loads(info.read_text())["address"]
                    return self.address
                except (ValueError, KeyError):
                    pass   # half written
            time.sleep(0.1)
        log = (self.workdir / "scheduler.log").read_text(errors="replace")[-2000:]
        self.stop()
        raise RuntimeError(f"the Dask scheduler did not start within {START_TIMEOUT_S} s:\n{log}")

    def add_worker(self, worker_args: list[str] | None = None, env: dict[str, str] | None = None) -> subprocess.Popen:
        """Start one more ``dask worker`` (with its nanny) on the scheduler; returns its process (the group
        leader)."""
        i = len(self.workers)
        proc = self._spawn([sys.executable, "-m", "dask", "worker", self.address, "--nthreads", "1",
                            "--no-dashboard", "--name", f"worker-{i}", "--host", self.host,
                            *self.worker_args, *(worker_args or [])], f"worker-{i}.log", {**self.env, **(env or {})})
        self.workers.append(proc)
        return proc

    def wait_for_workers(self, n: int, timeout: float = START_TIMEOUT_S) -> None:
        """Block until ``n`` workers are connected (TimeoutError after ``timeout`` s)."""
        from distributed import Client
        with Client(self.address, timeout=f"{START_TIMEOUT_S}s") as client:
            client.wait_for_workers(n, timeout=timeout)

    def start(self) -> "LocalTcpCluster":
        """Start the scheduler and the workers; return once every worker is connected."""
        self.start_scheduler()
        for _ in range(self.n_workers):
            self.add_worker()
        if self.n_workers:
            self.wait_for_workers(self.n_workers)
        return self

    def kill_worker(self, i: int, sig: int = signal.SIGKILL) -> None:
        """Send ``sig`` to worker ``i``'s whole process group (nanny and worker: a lost machine)."""
        _kill_group(self.workers[i], sig)
        self.workers[i].wait(timeout=STOP_GRACE_S)

    def kill_scheduler(self, sig: int = signal.SIGKILL) -> None:
        """Send ``sig`` to the scheduler's process group and wait for it to end."""
        if self.scheduler is not None:
            _kill_group(self.scheduler, sig)
            self.scheduler.wait(timeout=STOP_GRACE_S)

    def stop(self) -> None:
        """SIGTERM every process group (workers first), SIGKILL what is left after :data:`STOP_GRACE_S` s."""
        procs = [*self.workers, *([self.scheduler] if self.scheduler else [])]
        for proc in procs:
            if proc.poll() is None:
                _kill_group(proc, signal.SIGTERM)
        deadline = time.monotonic() + STOP_GRACE_S
        for proc in procs:
            try:
                proc.wait(timeout=max(0.1, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                pass
        for proc in procs:   # the group too: a worker's child (nanny → worker) may outlive its leader
            _kill_group(proc, signal.SIGKILL)
            if proc.poll() is None:
                proc.wait()
        deadline = time.monotonic() + STOP_GRACE_S
        while self.leftover() and time.monotonic() < deadline:   # SIGKILLed children take a moment to end
            time.sleep(0.05)

    def leftover(self) -> list[int]:
        """Pids of the processes still running (zombies aside) in this cluster's process groups (read from
        /proc: Linux; empty elsewhere)."""
        groups = {proc.pid for proc in [*self.workers, self.scheduler] if proc is not None}
        pids = []
        for stat in Path("/proc").glob("[0-9]*/stat"):
            try:
                state, _, pgrp = stat.read_text().rsplit(")", 1)[1].split()[:3]
            except (OSError, ValueError):
                continue   # ended meanwhile
            if int(pgrp) in groups and state != "Z":
                pids.append(int(stat.parent.name))
        return pids

    def __enter__(self) -> "LocalTcpCluster":
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                     usage="%(prog)s [--workers N] [--port P] [-- COMMAND ... {address} ...]")
    parser.add_argument("--workers", type=int, default=2, help="dask worker processes (default 2)")
    parser.add_argument("--host", default="127.0.0.1", help="interface to bind (default 127.0.0.1)")
    parser.add_argument("--port", type=int, default=0, help="scheduler port (default: a free one)")
    parser.add_argument("--logs", default=None, help="directory for the logs (default: a temporary one)")
    parser.add_argument("command", nargs=argparse.REMAINDER,
                        help="after --: a command to run against the cluster ({address} is replaced), then stop")
    args = parser.parse_args(argv)
    command = args.command[1:] if args.command[:1] == ["--"] else args.command
    cluster = LocalTcpCluster(args.workers, args.host, args.port, args.logs)

    def stop_on(signum, frame):
        raise KeyboardInterrupt
    signal.signal(signal.SIGTERM, stop_on)
    try:
        cluster.start()
        print(cluster.address, flush=True)
        print(f"{args.workers} worker(s) connected; logs in {cluster.workdir}", file=sys.stderr, flush=True)
        if command:
            return subprocess.call([part.replace("{address}", cluster.address) for part in command])
        while True:
            time.sleep(3600)
    except KeyboardInterrupt:
        return 0
    finally:
        cluster.stop()


if __name__ == "__main__":
    sys.exit(main())
