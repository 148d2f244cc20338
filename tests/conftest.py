import os
import sys

# The statistics helpers live beside the tests.
sys.path.insert(0, os.path.dirname(__file__))

import pytest  # noqa: E402

from volmc.backends import BACKENDS  # noqa: E402


@pytest.fixture(params=BACKENDS)
def backend(request):
    """Every render backend, by name (volmc.backends.BACKENDS: the list is defined once)."""
    return request.param


#: The lane widths every kernel builds for (volmc.cl.lanes.LANE_WIDTHS).
from volmc.cl.lanes import LANE_WIDTHS  # noqa: E402


@pytest.fixture(params=LANE_WIDTHS, ids=[f"W{w}" for w in LANE_WIDTHS])
def lanes(request, monkeypatch):
    """Every lane width: the width tests/cl_harness.py builds and launches with, and (through
    $VOLMC_LANES) that of every OpenCL backend, estimator and benchmark the test makes."""
    import cl_harness
    monkeypatch.setattr(cl_harness, "LANES", request.param)
    monkeypatch.setenv("VOLMC_LANES", str(request.param))
    return request.param
