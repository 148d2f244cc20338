"""`volmc bench render --baseline DIR`: an earlier checkout renders in a worker process."""

from pathlib import Path

import numpy as np
import pytest

from volmc.bench.baseline import BaselineRunner
from volmc.film import Film
from volmc.render import batch_schedule, make_backend
from volmc.scene import load_scene
from volmc.scene.errors import SceneError
from volmc.scene.serialize import dict_to_toml

ROOT = Path(__file__).resolve().parents[1]

SCENE = {
    "camera": {"eye": [0.0, 0.0, 4.0], "target": [0.0, 0.0, 0.0], "fov": 40.0,
               "resolution": [12, 10]},
    "medium": {"bounds": [[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]], "density": 1.0,
               "scale": 2.0, "albedo": 0.8},
    "lights": [{"type": "environment", "radiance": 0.5},
               {"type": "directional", "direction": [0.3, -1.0, 0.2], "irradiance": 2.0}],
    "render": {"spp": 4, "seed": 3},
}


def test_baseline_renders_the_samples_this_code_renders(tmp_path, monkeypatch):
    """This checkout as its own baseline, given the scene by a path relative to the working
    directory (the worker runs in a directory of its own: it failed to find the scene)."""
    (tmp_path / "scene.toml").write_text(dict_to_toml(SCENE))
    monkeypatch.chdir(tmp_path)
    runner = BaselineRunner(ROOT, "scene.toml", ["render.seed=5"])
    try:
        image, seconds, _ = runner.render(3)
    finally:
        runner.close()
    assert seconds > 0.0
    scene = load_scene("scene.toml", ["render.seed=5"])
    backend = make_backend("opencl", scene, None)
    w, h = scene.camera.resolution
    film = Film(w, h)
    # The worker's warm-up rendered sample 0, so its first timed render is samples 1 to 3.
    for n in batch_schedule(w * h, 3):
        backend.render(1 + film.spp, n, film)
        film.spp += n
    assert image.shape == film.mean().shape
    np.testing.assert_array_equal(image, film.mean())
    other = make_backend("opencl", load_scene("scene.toml", []), None)
    film0 = Film(w, h)
    other.render(1, 3, film0)
    film0.spp = 3
    assert not np.array_equal(image, film0.mean())   # the -D override reached the worker


def test_baseline_that_cannot_start_says_why(tmp_path):
    """A checkout whose volmc fails to import: the one-line error carries the worker's last
    line of stderr, not the worker's traceback."""
    (tmp_path / "scene.toml").write_text(dict_to_toml(SCENE))
    bad = tmp_path / "old"
    (bad / "volmc").mkdir(parents=True)
    (bad / "volmc" / "__init__.py").write_text("raise ImportError('this volmc is broken')\n")
    (bad / "kernels").mkdir()   # a checkout's layout (check_checkout)
    (bad / "pyproject.toml").write_text("")
    with pytest.raises(SceneError, match="could not render the scene.*this volmc is broken"):
        BaselineRunner(bad, tmp_path / "scene.toml")
