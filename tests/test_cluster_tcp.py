"""The cluster path against real processes: a ``dask scheduler`` and ``dask worker`` processes on TCP
(127.0.0.1, free ports; scripts/dask_cluster.py starts them, each in its own process group), and ``datagen build``
run in this process. A worker SIGKILLed mid-build; the scheduler killed mid-build, then ``--resume`` against a new one
(first without workers: a bounded wait and one line); a worker whose disk fills (tests/cluster_disk_full.py), then
``--resume`` once space is back. Every finished dataset equals a local build bit for bit, and no process of a
cluster is left behind.
"""
from __future__ import annotations

import importlib.util
import json
import re
import subprocess
import sys
import threading
import time
import traceback
from pathlib import Path

import pytest
import yaml
import zarr
from click.testing import CliRunner

from test_hostile_build import arrays   # every array's bytes (strings: their texts)

from datagen.cli.main import main
from datagen.dataset import build_dataset, load_dataset_config, read_card, verify_dataset
from datagen.dataset.config import SplitSpec
from datagen.dataset.store import DONE_DIR, shard_file

ROOT = Path(__file__).resolve().parents[1]
SMOKE = ROOT / "configs" / "datasets" / "smoke.yaml"
DISK_FULL_HOOK = Path(__file__).with_name("cluster_disk_full.py")
N_SHARDS = 5          # 10 samples in shards of 2: train 3, val 1, test_phong 1
STEP_TIMEOUT_S = 60   # any single wait of a test (a build, a marker, a process exit)

pytestmark = pytest.mark.timeout(150)

_spec = importlib.util.spec_from_file_location("dask_cluster", ROOT / "scripts" / "dask_cluster.py")
dask_cluster = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(dask_cluster)


def config():
    """The smoke config cut to 10 samples in 5 shards of 2 (a fraction of a second of work per shard)."""
    smoke = load_dataset_config(SMOKE)
    splits = {"train": SplitSpec(count=6), "val": SplitSpec(count=2),
              "test_phong": smoke.splits["test_phong"].model_copy(update={"count": 2})}
    return smoke.model_copy(update={"splits": splits, "shard_size": 2})


@pytest.fixture(scope="module")
def config_path(tmp_path_factory):
    path = tmp_path_factory.mktemp("config") / "cluster.yaml"
    path.write_text(yaml.safe_dump(config().to_json()))
    return path


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    """The same config built in this process: what every cluster build must equal."""
    out = tmp_path_factory.mktemp("reference") / "ds"
    assert build_dataset(config(), out, workers=0, progress=False).shards_built == N_SHARDS
    return out


@pytest.fixture
def clusters(tmp_path):
    """Start clusters with ``clusters(n_workers, **kwargs)``; every one is stopped at teardown and must leave no
    process behind."""
    started = []

    def start(n_workers: int, **kwargs):
        cluster = dask_cluster.LocalTcpCluster(n_workers, workdir=tmp_path / f"cluster{len(started)}", **kwargs)
        started.append(cluster)
        return cluster.start()

    yield start
    for cluster in started:
        cluster.stop()
    for cluster in started:
        assert cluster.leftover() == [], f"processes left behind by the cluster in {cluster.workdir}"


class Build:
    """``datagen build ... --scheduler ADDRESS`` run in this process (click's runner) on a thread, so that the
    test can kill cluster processes meanwhile; :meth:`finish` waits for it (the exit code, the output)."""

    def __init__(self, config_path: Path, out: Path, address: str, *extra: str):
        args = ["build", str(config_path), "--out", str(out), "--scheduler", address, "--quiet", *extra]
        self.result = None
        self.thread = threading.Thread(target=self._run, args=(args,), daemon=True)
        self.thread.start()

    def _run(self, args: list[str]) -> None:
        self.result = CliRunner().invoke(main, args)

    def running(self) -> bool:
        return self.thread.is_alive()

    def finish(self) -> tuple[int, str]:
        self.thread.join(timeout=STEP_TIMEOUT_S)
        assert self.result is not None, f"the build did not end within {STEP_TIMEOUT_S} s"
        assert self.result.exception is None or isinstance(self.result.exception, SystemExit), \
            "".join(traceback.format_exception(*self.result.exc_info))
        return self.result.exit_code, self.result.output


def run_build(*args) -> tuple[int, str]:
    return Build(*args).finish()


def markers(out: Path) -> dict[str, bytes]:
    return {str(p.relative_to(out)): p.read_bytes() for p in sorted((out / DONE_DIR).glob("*/*.json"))}


def shard_files(out: Path, done: dict[str, bytes]) -> list[Path]:
    """Every array's shard file of the shards whose markers are ``done``."""
    group = zarr.open_group(str(out), mode="r")
    return [shard_file(out, m["split"], name, m["shard"], group[m["split"]][name].ndim)
            for m in map(json.loads, done.values()) for name in m["sha256"]]


def running(pid: int) -> bool:
    """``pid`` is a process that has not ended (a zombie has)."""
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] != "Z"
    except OSError:
        return False


def wait_for_first_marker(out: Path, build: Build) -> int:
    """Block until a shard of ``out`` is done (its marker written); return how many are done."""
    deadline = time.monotonic() + STEP_TIMEOUT_S
    while not markers(out):
        assert build.running(), build.finish()[1]
        assert time.monotonic() < deadline, "no shard finished in time"
        time.sleep(0.05)
    return len(markers(out))


def error_lines(output: str) -> list[str]:
    return [line for line in output.splitlines() if "error" in line.lower()]


def assert_same_as(out: Path, reference: Path) -> None:
    """Bit for bit: every array's bytes and every shard file's sha256 equal the local build's."""
    assert read_card(out)["status"] == "complete"
    assert arrays(out) == arrays(reference)
    assert read_card(out)["shards"] == read_card(reference)["shards"]
    assert verify_dataset(out) == []


def test_worker_sigkilled_mid_build_still_completes_bit_identically(clusters, config_path, reference, tmp_path):
    cluster, out = clusters(2), tmp_path / "ds"
    build = Build(config_path, out, cluster.address)
    assert wait_for_first_marker(out, build) < N_SHARDS          # mid-build: shards are left
    cluster.kill_worker(0)                                     # SIGKILL to its nanny and worker process
    code, output = build.finish()
    assert code == 0, output
    assert f"dask scheduler {cluster.address}: 2 worker(s) connected" in output
    assert f"{N_SHARDS} shards built (10 samples" in output and "0 already done" in output
    assert_same_as(out, reference)


@pytest.mark.parametrize("value", ["0", "-1", "nan", "inf"])
def test_worker_timeout_not_a_positive_number_is_refused_before_anything(config_path, tmp_path, value):
    out = tmp_path / "ds"
    res = CliRunner().invoke(main, ["build", str(config_path), "--out", str(out), "--scheduler",
                                    "tcp://127.0.0.1:1", "--worker-timeout", value, "--quiet"])
    assert res.exit_code == 2 and res.output.strip() == (f"error: --worker-timeout must be a number of seconds > 0, "
                                                         f"got {float(value)!r}")
    assert not out.exists()


def test_every_worker_gone_mid_build_is_one_line_after_the_worker_timeout(clusters, config_path, tmp_path):
    cluster, out = clusters(1), tmp_path / "ds"
    build = Build(config_path, out, cluster.address, "--worker-timeout", "2")
    assert wait_for_first_marker(out, build) < N_SHARDS
    cluster.kill_worker(0)
    code, output = build.finish()
    assert code == 2, output
    [line] = error_lines(output)
    left = re.fullmatch(f"error: --scheduler {re.escape(cluster.address)}: no Dask worker connected for 2 s "
                        r"\(--worker-timeout\) with (\d) shard\(s\) left; the finished shards are kept: start "
                        r"workers, then run again with --resume", line)
    assert left and N_SHARDS - len(markers(out)) <= int(left[1]) <= N_SHARDS, line
    assert read_card(out)["status"] == "incomplete" and 0 < len(markers(out)) < N_SHARDS


def test_scheduler_killed_then_resume_on_a_new_one_loses_and_repeats_nothing(clusters, config_path, reference,
                                                                            tmp_path):
    first, out = clusters(2), tmp_path / "ds"
    build = Build(config_path, out, first.address)
    wait_for_first_marker(out, build)
    first.kill_scheduler()
    code, output = build.finish()
    assert code == 2, output
    assert error_lines(output) == [f"error: --scheduler {first.address}: lost the connection to the Dask "
                                   "scheduler mid-build; the shards finished so far are kept: restart it and its "
                                   "workers, then run again with --resume"], output
    assert "NoneType" not in output and "Traceback" not in output
    # the workers of a dead scheduler stop by themselves (after their current shard): no stray writer remains
    deadline = time.monotonic() + STEP_TIMEOUT_S
    while any(w.poll() is None for w in first.workers):
        assert time.monotonic() < deadline, "a worker outlived its scheduler"
        time.sleep(0.1)
    done = markers(out)
    assert 0 < len(done) < N_SHARDS
    done_files = {path: path.stat().st_mtime_ns for path in shard_files(out, done)}
    assert len(done_files) == len(done) * len(json.loads(next(iter(done.values())))["sha256"])

    # a new scheduler without workers: one line naming it after the bounded wait, nothing touched
    second = clusters(0)
    code, output = run_build(config_path, out, second.address, "--resume", "--worker-timeout", "2")
    assert code == 2, output
    assert f"dask scheduler {second.address}: 0 worker(s) connected; waiting up to 2 s" in output
    assert error_lines(output) == [f"error: --scheduler {second.address}: no Dask worker connected within 2 s "
                                   f"(--worker-timeout); start workers with `dask worker {second.address}` "
                                   "(nothing was written)"]
    assert markers(out) == done

    second.add_worker(), second.add_worker()
    second.wait_for_workers(2)
    code, output = run_build(config_path, out, second.address, "--resume")
    assert code == 0, output
    assert f"{N_SHARDS - len(done)} shards built" in output and f"{len(done)} already done" in output
    after = markers(out)
    assert {k: after[k] for k in done} == done            # the shards done before were not written again
    assert {p: p.stat().st_mtime_ns for p in done_files} == done_files
    assert_same_as(out, reference)


def test_worker_with_a_full_disk_is_one_line_and_resume_completes_once_space_is_back(clusters, config_path,
                                                                                      reference, tmp_path):
    full = tmp_path / "disk_is_full"
    full.touch()
    cluster, out = clusters(1), tmp_path / "ds"
    cluster.add_worker(["--preload", str(DISK_FULL_HOOK)], {"DATAGEN_TEST_DISK_FULL": str(full)})
    cluster.wait_for_workers(2)
    code, output = run_build(config_path, out, cluster.address)
    assert code == 2, output
    lines = error_lines(output)
    assert len(lines) == 1 and "No space left on device while writing shard " in lines[0], output
    assert f" of {out}; the " in lines[0] and "free space, then run again with --resume" in lines[0]
    assert read_card(out)["status"] == "incomplete"
    full.unlink()                                              # space is back
    code, output = run_build(config_path, out, cluster.address, "--resume")
    assert code == 0, output
    assert_same_as(out, reference)


def test_cluster_script_prints_the_address_runs_a_command_and_leaves_nothing(tmp_path):
    """``scripts/dask_cluster.py --workers 1 -- COMMAND {address}`` runs COMMAND against the cluster, then
    stops it: the scheduler and the worker are gone when it returns."""
    probe = ("import sys; from distributed import Client; c = Client(sys.argv[1], timeout='30s'); "
             "print('workers', len(c.nthreads())); print('pids', *c.run(__import__('os').getpid).values(), "
             "c.run_on_scheduler(__import__('os').getpid))")
    res = subprocess.run([sys.executable, str(ROOT / "scripts" / "dask_cluster.py"), "--workers", "1",
                          "--logs", str(tmp_path), "--", sys.executable, "-c", probe, "{address}"],
                         capture_output=True, text=True, timeout=STEP_TIMEOUT_S)
    assert res.returncode == 0, res.stderr
    address, workers, pids = res.stdout.splitlines()
    assert address.startswith("tcp://127.0.0.1:") and workers == "workers 1"
    assert pids.startswith("pids ") and not [pid for pid in map(int, pids.split()[1:]) if running(pid)]
