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
