"""Property tests of the validation layer (datagen/validate.py): generated capture arrays and detector histograms,
read by the commands that read files from outside.

Whatever the values (NaN, ±inf, negative, complex, huge, empty axes, uneven time columns), a command either exits
0 with output that is finite and consistent with its input, or exits 2 with one ``error:`` line and no traceback.
Hypothesis draws the cases from a fixed seed (``derandomize``), so a failure reproduces.
"""
from __future__ import annotations

import numpy as np
import pytest
import yaml
from click.testing import CliRunner
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from datagen.cli import main

pytestmark = pytest.mark.timeout(600)

SETTINGS = settings(max_examples=40, deadline=None, derandomize=True, database=None,
                    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])

# Values a hostile file holds: ordinary counts, and every edge a float can reach.
VALUE = st.one_of(st.integers(0, 50).map(float), st.floats(allow_nan=True, allow_infinity=True, width=64),
                  st.sampled_from([0.0, -1.0, 1e302, 2.0 ** 53, 5e-324]))


def _run(args) -> tuple[int, str]:
    """``datagen args`` in process: (exit code, output); no traceback, and exit 2 is one ``error:`` line."""
    res = CliRunner().invoke(main, [str(a) for a in args])
    assert res.exception is None or isinstance(res.exception, SystemExit), repr(res.exception)
    assert res.exit_code in (0, 2), res.output
    assert "Traceback" not in res.output
    if res.exit_code == 2:
        errors = [line for line in res.output.splitlines() if line.startswith("error:")]
        assert len(errors) == 1, res.output
    return res.exit_code, res.output


@st.composite
def captures(draw):
    """An LCT ``.mat`` content: rect_data (N, M, T) of any values and dtype, width and bin_resolution."""
    shape = (draw(st.integers(1, 4)), draw(st.integers(1, 4)), draw(st.integers(0, 24)))
    kind = draw(st.sampled_from(["counts", "counts", "counts", "any", "complex", "int"]))
    if kind == "counts":
        data = draw(hnp.arrays(np.float64, shape, elements=st.integers(0, 30).map(float)))
    elif kind == "int":
        data = draw(hnp.arrays(np.int32, shape, elements=st.integers(-3, 2 ** 31 - 1)))
    else:
        data = draw(hnp.arrays(np.float64, shape, elements=VALUE))
        if kind == "complex":
            data = data + 1j * draw(hnp.arrays(np.float64, shape, elements=st.sampled_from([0.0, 1.0])))
    good = draw(st.integers(0, 3)) > 0                            # most files hold a valid width and bin width
    width = 0.4 if good else draw(st.sampled_from([0.0, -0.4, np.nan, np.inf, 1e300]))
    bin_resolution = 4e-12 if good else draw(st.sampled_from([0.0, -4e-12, np.nan, 1e-300]))
    return data, width, bin_resolution


@SETTINGS
@given(case=captures())
def test_import_capture_of_any_array_exits_0_with_what_it_read_or_2_in_one_line(tmp_path_factory, case):
    from scipy.io import savemat

    from datagen.io import read_result

    data, width, bin_resolution = case
    tmp = tmp_path_factory.mktemp("cap")
    path = tmp / "capture.mat"
    savemat(path, {"rect_data": data, "width": np.array([[width]]), "bin_resolution": np.array([[bin_resolution]])})
    code, out = _run(["import-capture", path, "--out", tmp / "out"])
    if code == 2:
        assert not (tmp / "out").exists()                    # nothing left behind
        return
    result = read_result(tmp / "out" / "result.zarr")
    env = np.asarray(result.envelope)
    assert np.isfinite(env).all() and (env >= 0).all()
    assert env.size == data.size and env.shape[-1] == data.shape[-1]
    np.testing.assert_allclose(env.sum(), np.real(data).astype(np.float64).sum(), rtol=1e-12)
    edges = np.asarray(result.time_edges)
    assert np.isfinite(edges).all() and (np.diff(edges) > 0).all()
    np.testing.assert_allclose(np.diff(edges), bin_resolution, rtol=1e-9)


@st.composite
def histograms(draw):
    """A detector histogram file: (suffix, array), one column of counts (.npy / .txt) or (time, counts) columns
    (.csv) whose time column may be uneven, decreasing or not finite."""
    n = draw(st.integers(0, 48))
    counts = draw(st.one_of(hnp.arrays(np.float64, n, elements=st.integers(0, 400).map(float)),
                            hnp.arrays(np.float64, n, elements=VALUE)))
    if n > 0 and draw(st.booleans()):
        counts[draw(st.integers(0, n - 1))] += 5000.0                       # a peak to fit
    layout = draw(st.sampled_from(["npy", "txt", "csv"]))
    if layout != "csv":
        return layout, counts
    t = np.arange(n) * 50e-12
    edit = draw(st.sampled_from(["even", "uneven", "reversed", "nan"]))
    if n > 2 and edit == "uneven":
        t[n // 2:] += 17e-12
    elif n > 1 and edit == "reversed":
        t = t[::-1].copy()
    elif n > 0 and edit == "nan":
        t[0] = np.nan
    return layout, np.c_[t, counts]


@settings(SETTINGS, max_examples=20)        # each accepted histogram is a full fit (≈ 3 s)
@given(case=histograms())
def test_fit_detector_of_any_histogram_exits_0_with_finite_parameters_or_2_in_one_line(tmp_path_factory, case):
    layout, arr = case
    tmp = tmp_path_factory.mktemp("hist")
    path = tmp / f"h.{layout}"
    if layout == "npy":
        np.save(path, arr)
    else:
        np.savetxt(path, arr, delimiter="," if layout == "csv" else " ")
    args = ["fit-detector", path, "--repetition-rate", "20MHz", "--n-cycles", "100000", "--out", tmp / "det.yaml"]
    if layout != "csv":
        args += ["--bin-width", "50ps"]
    code, out = _run(args)
    if code == 2:
        assert not (tmp / "det.yaml").exists()
        return
    fitted = yaml.safe_load((tmp / "det.yaml").read_text())
    numbers = [v for v in _leaves(fitted) if isinstance(v, (int, float)) and not isinstance(v, bool)]
    assert numbers and all(np.isfinite(v) for v in numbers), fitted
    counts = arr[:, 1] if arr.ndim == 2 else arr
    assert np.isfinite(counts).all() and (counts >= 0).all() and counts.max() < 2.0 ** 53   # what was accepted


def _leaves(node):
    if isinstance(node, dict):
        for v in node.values():
            yield from _leaves(v)
    elif isinstance(node, list):
        for v in node:
            yield from _leaves(v)
    else:
        yield node
