import os
import shutil
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


def _gpu_tests_selected(items):
    return shutil.which("clang-19") is not None and any(
        item.path.name == "test_gpu_portability.py" and item.originalname in (
            "test_kernels_compile_cleanly_for_gpu",
            "test_no_recursion_and_no_undefined_functions") for item in items)


def _broad_run(items):
    return len({item.path for item in items}) >= 5


#: Background jobs (tests/background.py): {job: (script, arguments, nice, when to start it)}.
#: The Numba compiles of the render path start when the run is broad (tests from five modules
#: or more, where some test renders one and several media with the Numba backend; a narrow
#: run that needs them compiles them itself), the GPU builds when their tests are selected
#: (and clang-19 exists). Jobs needed earlier in the run are served first (lower nice): the
#: one-medium compile (tests/hard), the several-media one (test_check.py), the GPU builds.
BACKGROUND_JOBS = {
    "numba_one": ("warm_numba.py", ("one",), 10, _broad_run),
    "numba_several": ("warm_numba.py", ("several",), 15, _broad_run),
    "gpu_portability": ("test_gpu_portability.py", (), 19, _gpu_tests_selected),
}


@pytest.hookimpl(trylast=True)   # after -k and -m have deselected
def pytest_collection_modifyitems(session, config, items):
    """Start the background jobs the selected tests need."""
    import background
    for job, (script, args, nice, wanted) in BACKGROUND_JOBS.items():
        if wanted(items):
            background.start(job, script, nice, args)


@pytest.fixture(scope="session", autouse=True)
def render_path_compiled():
    """The first Numba render of one medium, and of several, waits for the background job
    that compiles its render path (warm_numba.py) rather than compiling it a second time
    beside it."""
    import background
    import volmc.backends.numba as numba_backend
    media_data = numba_backend.media_data

    def waiting(pk):
        out = media_data(pk)
        background.result("numba_one" if len(out) == 1 else "numba_several")
        return out
    numba_backend.media_data = waiting
    yield
    numba_backend.media_data = media_data


def pytest_sessionfinish(session, exitstatus):
    import background
    background.stop_all()
