"""The afterpulsing regime of fit-detector's coverage test (tests/test_fit_detector.py, check_coverage), in a file
of its own: CI gives each file one worker (scripts/test.sh: --dist loadfile), so its three minutes run beside the
other regimes instead of after them."""
from __future__ import annotations

import pytest

from test_fit_detector import SEPARATE, check_coverage


@pytest.mark.slow
@pytest.mark.parametrize("regime", SEPARATE)
def test_fit_recovers_every_parameter_within_its_95_percent_interval(regime):
    check_coverage(regime)
