"""Bit-for-bit samples on any CPU: the pipeline's products and norms avoid BLAS (datagen/vectors.py), whose kernels
OpenBLAS picks by CPU model. OPENBLAS_CORETYPE makes this machine's OpenBLAS run another model's kernels; a sample
made under each must be the same to the last bit."""
from __future__ import annotations

import os
import subprocess
import sys

import numpy as np
import pytest

from conftest import ROOT
from datagen.vectors import matmul, norm

DUMP = """
import sys, numpy as np
from datagen.dataset import load_dataset_config, make_sample
out = {}
for name in ("wall_smoke", "confocal_smoke"):
    sample = make_sample(load_dataset_config(sys.argv[1] + f"/configs/datasets/{name}.yaml"), "train", 0)
    out.update({f"{name}/{k}": np.asarray(v) for k, v in sample.arrays.items()})
np.savez(sys.argv[2], **out)
"""


def test_matmul_and_norm_are_numpys_products():
    rng = np.random.default_rng(3)
    for sa, sb in [((3,), (3,)), ((5, 3), (3,)), ((3,), (3, 4)), ((5, 3), (3, 4)), ((7, 5, 3), (3,)),
                   ((7, 5, 3), (3, 2)), ((3,), (7, 3, 2)), ((7, 5, 3), (7, 3, 2))]:
        a, b = rng.random(sa), rng.random(sb)
        assert np.shape(matmul(a, b)) == np.shape(a @ b)
        np.testing.assert_allclose(matmul(a, b), a @ b, rtol=1e-14, atol=0)
    v = rng.random((4, 5))
    assert norm(v) == pytest.approx(float(np.linalg.norm(v)), rel=1e-15)
    assert norm(np.zeros(3)) == 0.0


@pytest.mark.parametrize("coretype", ["Nehalem", "Sandybridge"])
def test_samples_do_not_depend_on_openblas_kernels(tmp_path, coretype):
    """wall_smoke and confocal_smoke train 0 (envelope, counts, labels, params with its error estimate) made with
    OpenBLAS's kernels for this CPU and with those of ``coretype``: every array equal. Without datagen.vectors the
    envelopes and params differed (≈ 1e-11 relative; the rooms' mesh transforms in their last bits)."""
    arrays = []
    for name, env in (("native", {}), (coretype, {"OPENBLAS_CORETYPE": coretype})):
        out = tmp_path / f"{name}.npz"
        subprocess.run([sys.executable, "-c", DUMP, str(ROOT), str(out)], check=True, cwd=ROOT,
                       env={**os.environ, **env}, capture_output=True, timeout=300)
        arrays.append(np.load(out, allow_pickle=True))
    native, other = arrays
    assert sorted(native.files) == sorted(other.files) and len(native.files) > 20
    for key in native.files:
        a, b = native[key], other[key]
        same = repr(a) == repr(b) if a.dtype == object else a.dtype == b.dtype and a.tobytes() == b.tobytes()
        assert same, f"{key} differs with OPENBLAS_CORETYPE={coretype}"
