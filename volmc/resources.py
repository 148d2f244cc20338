"""Where the bundled kernels and scenes are, for source checkouts and installed wheels alike."""

from pathlib import Path

_PACKAGE = Path(__file__).resolve().parent
_REPO_ROOT = _PACKAGE.parent


def _package_dir(package, repo_dir):
    # A wheel installs the folders inside the package (volmc/kernels, volmc/scenes); in a
    # checkout (or an editable install) they sit at the repository root.
    installed = _PACKAGE / repo_dir
    if installed.is_dir():
        return installed
    local = _REPO_ROOT / repo_dir
    if local.is_dir() and (_REPO_ROOT / "pyproject.toml").is_file():
        return local
    raise FileNotFoundError(f"volmc's {repo_dir}/ folder is missing (looked in {installed} "
                            f"and {local}); reinstall volmc")


def scenes_dir() -> Path:
    """Folder of the bundled scenes (``scenes/``)."""
    return _package_dir("volmc.scenes", "scenes")


def kernels_dir() -> Path:
    """Folder of the OpenCL sources (``kernels/``)."""
    return _package_dir("volmc.kernels", "kernels")


def default_scene() -> Path:
    """The scene ``volmc render`` renders when given none: the procedural cloud."""
    return scenes_dir() / "cloud.toml"
