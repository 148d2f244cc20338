"""The wheel ships every subpackage, the kernels and the scenes (a non-editable install must
work exactly like the checkout)."""

import fnmatch
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def _config():
    return tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]


def test_every_subpackage_is_listed():
    listed = set(_config()["packages"])
    found = {".".join(p.parent.relative_to(ROOT).parts)
             for p in (ROOT / "volmc").rglob("__init__.py")}
    assert found <= listed, found - listed


def test_kernels_and_scenes_are_package_data():
    cfg = _config()
    assert cfg["package-dir"]["volmc.kernels"] == "kernels"
    assert cfg["package-dir"]["volmc.scenes"] == "scenes"
    data = cfg["package-data"]
    assert {"*.h", "*.cl"} <= set(data["volmc.kernels"])
    assert {"*.toml", "tests/*.toml"} <= set(data["volmc.scenes"])
    kernel_files = {p.name for p in (ROOT / "kernels").iterdir()}
    assert all(n.endswith((".h", ".cl")) for n in kernel_files), kernel_files
    shipped = {p.relative_to(ROOT / "scenes").as_posix() for p in (ROOT / "scenes").rglob("*")
               if p.is_file()}
    patterns = data["volmc.scenes"]

    for f in shipped:
        assert any(_glob_match(f, pat) for pat in patterns), f


def _glob_match(path, pattern):
    """Whether setuptools' package-data glob ``pattern`` takes ``path``: as in glob, a ``*``
    stays within one folder (fnmatch alone would let "*.toml" take "bench/thin.toml", which
    the wheel does not ship)."""
    parts, pats = path.split("/"), pattern.split("/")
    return len(parts) == len(pats) and all(fnmatch.fnmatch(a, b) for a, b in zip(parts, pats))
