"""Every test under tests/hard is one of docs/robustness.md's cases and carries the ``hard`` marker.

``pytest -m hard`` runs exactly this suite; plain ``pytest`` (the CI command) runs it too.
"""

import pathlib

import pytest

_HERE = pathlib.Path(__file__).parent


def pytest_collection_modifyitems(config, items):
    for item in items:
        if _HERE in pathlib.Path(str(item.fspath)).parents:
            item.add_marker(pytest.mark.hard)
