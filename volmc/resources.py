"""Where the bundled kernels and scenes are, for source checkouts and installed wheels alike."""

import importlib.resources
from pathlib import Path

_REPO_ROOT = Path(__file__).resolve().parent.parent


def _package_dir(package, repo_dir):
    # In a checkout (or an editable install) the folders sit at the repository root; a
    # wheel installs them as the packages volmc.kernels / volmc.scenes.
    local = _REPO_ROOT / repo_dir
    if local.is_dir() and (_REPO_ROOT / "pyproject.toml").is_file():
        return local
    return Path(str(importlib.resources.files(package)))


def scenes_dir() -> Path:
    """Folder of the bundled scenes (``scenes/``)."""
    return _package_dir("volmc.scenes", "scenes")


def kernels_dir() -> Path:
    """Folder of the OpenCL sources (``kernels/``)."""
    return _package_dir("volmc.kernels", "kernels")


def default_scene() -> Path:
    """The scene ``volmc render`` renders when given none: the procedural cloud."""
    return scenes_dir() / "cloud.toml"
