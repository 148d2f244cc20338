"""The Python API (volmc/api.py, exported from volmc): loading with overrides, scenes built
in Python with numpy grids, rendering, saving, transmittance on the caller's rays, errors."""

import io
import math
import os
import subprocess
import sys

import numpy as np
import pytest

from stats import ALPHA, z_bound

import volmc
from volmc.film import read_exr
from volmc.resources import scenes_dir

#: The default scene, shrunk: 8x8 pixels, 4 spp, a 16^3 cloud.
SMALL = {"camera.resolution": [8, 8], "render.spp": 4, "medium.density.resolution": 16}

BOX = [[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]]


def _base(density, spp=256):
    """A small scene with all three light types around a box of medium ``density``."""
    return {"camera": {"eye": [0.3, 0.2, 3.0], "target": [0, 0, 0], "fov": 50,
                       "resolution": [8, 8]},
            "medium": {"bounds": BOX, "density": density, "scale": 3.0,
                       "albedo": [0.9, 0.6, 0.3], "phase": {"type": "hg", "g": 0.4}},
            "lights": [{"type": "environment", "radiance": 0.4},
                       {"type": "directional", "direction": [-1, -1, -0.5], "irradiance": 2.0},
                       {"type": "point", "position": [0.5, 1.5, 0.5], "intensity": 1.5}],
            "render": {"spp": spp}}


def test_import_is_light():
    """``import volmc`` imports neither Numba nor pyopencl nor the renderer."""
    code = ("import sys, volmc; heavy = [m for m in ('numba', 'pyopencl', 'volmc.render', "
            "'matplotlib') if m in sys.modules]; print(heavy)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True)
    assert out.stdout.strip() == "[]"


def test_render_stays_the_function():
    """volmc.render is the API function even after the driver module volmc.render loads."""
    from volmc.render import batch_schedule  # noqa: F401  (imports the module)
    assert callable(volmc.render) and volmc.render is volmc.api.render
    assert sys.modules["volmc.render"].batch_schedule is batch_schedule


def test_checkpoint_interval_default_is_the_drivers():
    """volmc.render's checkpoint_every default (a literal: ``import volmc`` stays light) is
    the driver's CHECKPOINT_EVERY, which --checkpoint-every also defaults to."""
    import inspect
    from volmc.render import CHECKPOINT_EVERY
    default = inspect.signature(volmc.api.render).parameters["checkpoint_every"].default
    assert default == CHECKPOINT_EVERY


def test_load_with_dict_and_list_overrides():
    a = volmc.load_scene(overrides=SMALL)
    b = volmc.load_scene(scenes_dir() / "cloud.toml",
                         ["camera.resolution=[8, 8]", "render.spp=4",
                          "medium.density.resolution=16"])
    for s in (a, b):
        assert s.camera.resolution == (8, 8) and s.render.spp == 4
        assert s.grid.shape == (16, 16, 16)
    assert np.array_equal(a.grid, b.grid) and a.spec == b.spec
    c = volmc.load_scene(overrides={"lights": [{"type": "environment", "radiance": 2}],
                                    "medium.albedo": (0.5, np.float32(0.25), 1),
                                    "camera.resolution": np.array([4, 2]), **{
                                        "medium.density.resolution": 8}})
    assert len(c.lights) == 1 and c.lights[0].radiance == (2.0, 2.0, 2.0)
    assert c.medium.albedo == (0.5, 0.25, 1.0) and c.camera.resolution == (4, 2)


def test_scene_from_dict_and_dataclasses(tmp_path):
    """A dict (tuples allowed), the same scene as dataclasses, and a numpy grid given as the
    density all validate to the same scene as the equivalent file."""
    from volmc.scene import (ArrayDensity, Camera, EnvironmentLight, FileDensity, Medium,
                             Render, SceneSpec)
    grid = np.random.default_rng(1).random((3, 4, 5)).astype(np.float32)
    np.save(tmp_path / "g.npy", grid)
    raw = {"camera": {"resolution": (6, 4)},
           "medium": {"bounds": BOX, "density": {"file": "g.npy"}},
           "lights": [{"type": "environment", "radiance": 1.0}], "render": {"spp": 2}}
    a = volmc.scene_from_dict(raw, base_dir=tmp_path)
    spec = SceneSpec("<python>", Camera(resolution=(6, 4)),
                     Medium(bounds=tuple(map(tuple, BOX)),
                            density=FileDensity("g.npy", str(tmp_path / "g.npy"))),
                     (EnvironmentLight((1.0, 1.0, 1.0)),), Render(spp=2))
    b = volmc.scene_from_dict(spec)
    c = volmc.scene_from_dict(dict(raw, medium={"bounds": BOX, "density": grid.astype(float)}))
    d = volmc.scene_from_dict(dict(raw, medium={"bounds": BOX,
                                                "density": grid}), overrides={"render.spp": 2})
    for s in (a, b, c, d):
        assert s.camera.resolution == (6, 4) and np.array_equal(s.grid, grid)
        assert s.grid.dtype == np.float32 and s.grid.flags.c_contiguous
    assert a.spec.camera == b.spec.camera and a.spec.render == b.spec.render
    assert isinstance(c.medium.density, ArrayDensity)
    grid[0, 0, 0] = 7.0   # the scene keeps its own copy
    assert d.grid[0, 0, 0] != 7.0


def test_render_image_variance_counters():
    scene = volmc.load_scene(overrides=SMALL)
    img = volmc.render(scene, progress=False)
    assert img.image.shape == (8, 8, 3) and img.image.dtype == np.float32
    assert img.variance.shape == (8, 8, 3) and img.variance.dtype == np.float32
    assert np.all(np.isfinite(img.image)) and np.all(img.variance >= 0)
    assert img.image.mean() > 0 and img.spp == 4 and img.seconds > 0 and not img.partial
    assert img.counters["lookups"] > 0 and img.counters["over_majorant"] == 0
    assert img.stats()["samples"] == 8 * 8 * 4
    assert "8x8, 4 spp" in repr(img)


def test_same_seed_same_image(backend):
    """Same scene, spp and seed: the same image bit for bit; another seed: another image."""
    scene = volmc.load_scene(overrides=SMALL)
    a = volmc.render(scene, spp=3, seed=5, backend=backend, progress=False)
    b = volmc.render(scene, spp=3, seed=5, backend=backend, progress=False)
    c = volmc.render(scene, spp=3, seed=6, backend=backend, progress=False)
    assert a.seed == 5 and a.spp == 3 and a.backend == backend
    assert np.array_equal(a.image, b.image) and np.array_equal(a.variance, b.variance)
    assert not np.array_equal(a.image, c.image)


def test_numpy_grid_renders_like_the_file_and_the_homogeneous_medium(tmp_path):
    """A numpy grid renders bit for bit like the same grid read from a .npy file (one code
    path once loaded), and a constant one like the homogeneous medium of the same density
    (robustness case 17: per-pixel two-sample z-test, Sidak over the pixels)."""
    const = np.full((3, 4, 5), 0.5, np.float32)
    np.save(tmp_path / "c.npy", const)
    a = volmc.render(volmc.scene_from_dict(_base(const)), progress=False)
    f = volmc.render(volmc.scene_from_dict(_base({"file": str(tmp_path / "c.npy")})),
                     progress=False)
    assert np.array_equal(a.image, f.image)
    h = volmc.render(volmc.scene_from_dict(_base(0.5)), progress=False)
    d = a.result.film.mean() - h.result.film.mean()
    se = np.sqrt(a.result.film.variance_of_mean() + h.result.film.variance_of_mean())
    assert np.abs(d / se).max() < z_bound(ALPHA, d.size)


def test_save_exr_png_and_repr_png(tmp_path):
    from matplotlib import image as mpimg
    img = volmc.render(volmc.load_scene(overrides=SMALL), progress=False)
    assert img.save(tmp_path / "a.exr") == str(tmp_path / "a.exr")
    back, meta = read_exr(tmp_path / "a.exr")
    assert np.array_equal(back, img.image)
    assert int(meta["spp"]) == 4 and meta["backend"] == "opencl" and "scene_toml" in meta
    img.save(tmp_path / "a.png")
    png = mpimg.imread(tmp_path / "a.png")
    assert png.shape[:2] == (8, 8)
    data = img._repr_png_()
    assert data.startswith(b"\x89PNG\r\n\x1a\n")
    assert np.array_equal(mpimg.imread(io.BytesIO(data)), png)
    with pytest.raises(volmc.VolmcError, match="expected a path ending in .exr or .png"):
        img.save(tmp_path / "a.jpg")
    with pytest.raises(volmc.VolmcError, match="directory does not exist"):
        img.save(tmp_path / "missing" / "a.exr")


def test_save_writes_the_variance_exr(tmp_path):
    """save(variance=True): <stem>.var.exr holds the variance of the mean, with the image's
    metadata, beside an EXR or a PNG; it is the file volmc render --variance writes."""
    img = volmc.render(volmc.load_scene(overrides=SMALL), progress=False)
    for name in ("b.exr", "c.png"):
        img.save(tmp_path / name, variance=True)
        var, meta = read_exr(tmp_path / (name[0] + ".var.exr"))
        assert np.array_equal(var, img.variance) and int(meta["spp"]) == 4
    assert np.any(img.variance > 0) and not np.array_equal(img.variance, img.image)
    cli = subprocess.run([sys.executable, "-m", "volmc.cli", "render", "--quiet", "--variance",
                          "-o", str(tmp_path / "d.exr"), "-D", "camera.resolution=[8, 8]",
                          "-D", "render.spp=4", "-D", "medium.density.resolution=16"],
                         capture_output=True, text=True)
    assert cli.returncode == 0, cli.stderr
    assert np.array_equal(read_exr(tmp_path / "d.var.exr")[0], img.variance)


def test_checkpoint_and_resume_through_the_api(tmp_path):
    """volmc.render(checkpoint=...) then volmc.render(resume=...) to more samples: the
    uninterrupted render's image (up to the order of the float64 sums: the checkpoint holds
    the first 3 spp summed apart) and counters; another seed's resume is refused; bad
    arguments are VolmcErrors."""
    scene = volmc.load_scene(overrides=SMALL)
    full = volmc.render(scene, spp=8, backend="numba", progress=False)
    ck = tmp_path / "ck.npz"
    volmc.render(scene, spp=3, backend="numba", progress=False, checkpoint=ck)
    res = volmc.render(scene, spp=8, backend="numba", progress=False, resume=ck)
    assert res.spp == 8 and res.counters == full.counters
    with np.load(ck) as z:   # the resumed render went on checkpointing to its file
        assert '"spp": 8' in str(z["header"])
    np.testing.assert_allclose(res.image, full.image, rtol=1e-6, atol=1e-12)
    with pytest.raises(volmc.VolmcError, match=r": resume: .*seed"):   # the API's name
        volmc.render(scene, spp=8, seed=9, backend="numba", progress=False, resume=ck)
    for kw, key in (({"checkpoint": 3}, "checkpoint"), ({"checkpoint_every": -1},
                                                        "checkpoint_every"),
                    ({"client": 5}, "client"), ({"client": " "}, "client"),
                    ({"checkpoint": tmp_path / "no" / "ck.npz"}, "checkpoint")):
        with pytest.raises(volmc.VolmcError, match=rf"^volmc\.render\(\): {key}: "):
            volmc.render(scene, backend="numba", progress=False, **kw)


def test_guards_that_fired_warn():
    """Walks cut by render.max_steps: volmc.render issues a VolmcWarning naming the count,
    the message volmc render prints; a clean render issues none."""
    import warnings
    scene = volmc.load_scene(overrides=dict(SMALL, **{"render.max_steps": 1}))
    with pytest.warns(volmc.VolmcWarning, match=r"^\d+ walks were cut by render\.max_steps$"):
        img = volmc.render(scene, progress=False)
    assert img.counters["capped"] > 0
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert volmc.render(volmc.load_scene(overrides=SMALL), progress=False).counters[
            "capped"] == 0


def test_a_medium_too_dense_for_float32_warns():
    """Found by an outside check: an emitting cube of extinction 1e7 per unit (the frame's
    half-size) rendered 2.6 % dark on the float32 kernels, its free paths a few float32
    steps of the positions, and nothing said so. Now the OpenCL render warns (the scale,
    not the box's size, decides: the same cube 1000 times larger warns as well); the Numba
    backend, in float64, and a medium of 1e5 do not."""
    import warnings

    def scene(scale, half=1.0):
        return volmc.scene_from_dict({
            "camera": {"type": "orthographic", "eye": [0.0, 0.0, 3.0 * half],
                       "size": 1e-5 * half, "resolution": [1, 1]},
            "medium": {"bounds": [[-half] * 3, [half] * 3], "density": 1.0, "scale": scale,
                       "albedo": 0.5},
            "lights": [{"type": "environment", "radiance": 1.0}], "render": {"spp": 4}})
    for s in (scene(1e7), scene(1e4, half=1000.0)):
        with pytest.warns(volmc.VolmcWarning, match="float32 steps of the positions"):
            volmc.render(s, progress=False)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        volmc.render(scene(1e7), backend="numba", progress=False)
        volmc.render(scene(1e5), progress=False)


def test_png_bytes_and_metadata_are_what_save_and_the_cli_write(tmp_path, monkeypatch):
    """png_bytes() (a notebook's preview) carries the alpha of a transparent background, as
    the saved PNG does (it was RGB); metadata()["scene"] is the scene file's absolute path,
    as volmc render writes it (it was the path as given)."""
    import io
    from matplotlib import image as mpimg
    from volmc.resources import default_scene
    monkeypatch.chdir(default_scene().parent)
    scene = volmc.load_scene(default_scene().name, overrides=dict(
        SMALL, **{"render.transparent_background": True}))
    img = volmc.render(scene, progress=False)
    assert img.metadata()["scene"] == str(default_scene().resolve())
    img.save(tmp_path / "a.png")
    shown = mpimg.imread(io.BytesIO(img.png_bytes()), format="png")
    saved = mpimg.imread(tmp_path / "a.png")
    assert shown.shape == saved.shape == (8, 8, 4) and np.array_equal(shown, saved)
    assert saved[..., 3].min() == 0.0 and saved[..., 3].max() > 0.5   # sky and cloud


def test_save_exr_of_a_numpy_grid_scene(tmp_path):
    """A scene with a numpy grid has no TOML form: the EXR is written without it."""
    scene = volmc.scene_from_dict(_base(np.full((2, 2, 2), 0.5), spp=2))
    img = volmc.render(scene, progress=False)
    img.save(tmp_path / "g.exr")
    back, meta = read_exr(tmp_path / "g.exr")
    assert np.array_equal(back, img.image) and "scene_toml" not in meta


@pytest.mark.parametrize("estimator", ["auto", "ratio", "track_length", "analytic"])
def test_transmittance_homogeneous_is_exact(backend, estimator):
    """Homogeneous segments are analytic: every estimate is exp(-sigma L), for rays from
    outside (clipped to the box), from inside, cut by t_max, and missing (T = 1). The box is
    translated and scaled (the scene frame is undone)."""
    lo, hi = [10.0, -2.0, 4.0], [14.0, 2.0, 8.0]
    medium = {"bounds": [lo, hi], "density": 0.5, "scale": 2.0}   # sigma = 1 per unit
    o = [[12.0, 0.0, -50.0], [12.0, 0.0, 6.0], [11.0, 1.0, 6.0], [0.0, 0.0, 0.0]]
    d = [[0.0, 0.0, 2.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]]
    t_max = [np.inf, np.inf, 1.5, np.inf]
    r = volmc.estimate_transmittance(medium, o, d, t_max, estimator=estimator, n=8,
                                     backend=backend, seed=3)
    length = np.array([4.0, 2.0, 1.5, 0.0])
    tol = 1e-12 if backend == "numba" else 1e-6
    assert np.allclose(r.estimates, np.exp(-length), rtol=tol, atol=0)
    assert np.all(r.stderr <= tol) and r.n == 8 and r.estimator == estimator
    assert np.allclose(r.t_enter[:3], [54.0, 0.0, 0.0])
    assert np.allclose(r.t_exit[:3], [58.0, 2.0, 1.5]) and np.isnan(r.t_enter[3])


@pytest.mark.parametrize("distance", [1e16, 1e30])
def test_transmittance_of_a_box_far_from_the_ray_origin(backend, distance):
    """A box far smaller than its distance from the origin (side 2 at 1e16, where float64
    spaces numbers 2 apart; side 1e-4 at 1e12): clipped from the ray's nearest approach to
    it, not from the origin, whose rounding made the box a miss (T = 1, t_enter NaN). A
    ray that ends before it still misses."""
    box = {"bounds": [[-1, -1, -1], [1, 1, 1]], "density": 2.0}
    r = volmc.estimate_transmittance(box, [[0, 0, -distance]] * 2, [[0, 0, 1]] * 2,
                                     [np.inf, 0.5 * distance], estimator="analytic", n=2,
                                     backend=backend)
    assert np.allclose(r.estimates, [np.exp(-4.0), 1.0], rtol=1e-6, atol=0)
    assert np.isclose(r.t_enter[0], distance, rtol=1e-15) and np.isnan(r.t_enter[1])
    tiny = {"bounds": [[-5e-5] * 3, [5e-5] * 3], "density": 1e4}
    r = volmc.estimate_transmittance(tiny, [[0, 0, -1e12]], [[0, 0, 1]], n=2,
                                     estimator="analytic", backend=backend)
    assert np.allclose(r.estimates, np.exp(-1.0), rtol=1e-6, atol=0)


def test_transmittance_on_a_grid_matches_the_optical_depth(backend):
    """On a random 6^3 grid with its grid majorant, the mean of n ratio-tracking and auto
    estimates per ray agrees with exp(-exact optical depth) (z-test per ray and estimator,
    Sidak over all of them; n large enough for the normal approximation of these skewed
    estimates); rays that miss give 1 exactly; lookups are counted."""
    from volmc.reference.optical_depth import optical_depth_exact
    rng = np.random.default_rng(4)
    grid = rng.random((6, 6, 6)) * 2.0
    scene = volmc.scene_from_dict({"camera": {}, "medium": {"bounds": BOX, "density": grid,
                                                            "scale": 1.5}})
    k = 12
    o = rng.normal(size=(k, 3)) * 3.0
    target = rng.uniform(-0.8, 0.8, size=(k, 3))
    d = target - o
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    g64 = scene.grid.astype(np.float64)
    names = ("ratio", "auto")
    bound = z_bound(ALPHA, k * len(names))
    for name in names:
        r = volmc.estimate_transmittance(scene, o, d, estimator=name, n=4096, backend=backend,
                                         seed=11)
        assert r.counters["capped"] == 0 and r.counters["over_majorant"] == 0
        assert np.all(r.lookups > 0) and np.all(r.stderr > 0)
        # The segment the result reports, inside the box: its exact optical depth.
        assert np.all(r.t_enter > 0) and np.all(r.t_exit > r.t_enter)
        exact = np.array([math.exp(-optical_depth_exact(
            g64, tuple(BOX[0]), tuple(BOX[1]), 1.5, tuple(o[i]), tuple(d[i]),
            r.t_enter[i], r.t_exit[i])) for i in range(k)])
        z = (r.estimates - exact) / r.stderr
        assert np.abs(z).max() < bound, (name, z)
    miss = volmc.estimate_transmittance(scene, [[5.0, 5.0, 5.0]], [[1.0, 0.0, 0.0]],
                                        backend=backend)
    assert miss.estimates[0] == 1.0 and miss.lookups[0] == 0
    # "analytic" would give the majorant's transmittance here (8.6e-6 where T = 1 on the
    # cloud): refused
    with pytest.raises(volmc.VolmcError, match="estimator: 'analytic' is exact in a "
                       "homogeneous medium only"):
        volmc.estimate_transmittance(scene, o, d, estimator="analytic", backend=backend)


def test_transmittance_same_seed_same_estimates():
    scene = volmc.load_scene(overrides=SMALL)
    args = ([[0.0, 0.0, 4.0]], [[0.0, 0.0, -1.0]])
    a = volmc.estimate_transmittance(scene, *args, estimator="ratio", n=16, seed=2)
    b = volmc.estimate_transmittance(scene, *args, estimator="ratio", n=16, seed=2)
    assert np.array_equal(a.estimates, b.estimates) and 0.0 <= a.estimates[0] < 1.0


def test_errors_are_volmc_errors_with_the_cli_message(tmp_path):
    from volmc.scene import SceneError
    assert issubclass(SceneError, volmc.VolmcError)
    cloud = str(scenes_dir() / "cloud.toml")
    with pytest.raises(volmc.VolmcError) as e:
        volmc.load_scene(cloud, {"render.spq": 4})
    assert str(e.value) == f"{cloud}: render.spq: unknown key (did you mean 'spp'?)"
    assert (e.value.file, e.value.key) == (cloud, "render.spq")
    with pytest.raises(volmc.VolmcError) as e:
        volmc.load_scene(cloud, ["render.spq=4"])
    assert str(e.value) == f"{cloud}: render.spq: unknown key (did you mean 'spp'?)"
    bad = np.ones((2, 2, 2))
    bad[0, 1, 0] = np.nan
    with pytest.raises(volmc.VolmcError) as e:
        volmc.scene_from_dict(_base(bad))
    assert str(e.value) == "<dict>: medium.density: grid contains 1 NaN value"
    for grid, msg in ((np.ones((2, 2)), "grid must be 3-D [z, y, x], got shape (2, 2)"),
                      (-np.ones((1, 1, 2)), "grid contains 2 negative values (minimum -1)")):
        with pytest.raises(volmc.VolmcError, match=r"^<dict>: medium.density: " +
                           msg.replace("(", r"\(").replace(")", r"\)").replace("[", r"\[")
                           .replace("]", r"\]")):
            volmc.scene_from_dict(_base(grid))
    scene = volmc.load_scene(overrides=SMALL)
    for kwargs, text in (({"spp": 0}, "volmc.render(): spp: must be in [1, 4294967295], got 0"),
                         ({"backend": "cuda"}, "volmc.render(): backend: must be one of"),
                         ({"seed": -1}, "volmc.render(): seed: must be in")):
        with pytest.raises(volmc.VolmcError, match=r"^" + text.replace("(", r"\(")
                           .replace(")", r"\)").replace("[", r"\[").replace("]", r"\]")):
            volmc.render(scene, progress=False, **kwargs)
    with pytest.raises(volmc.VolmcError, match="unknown estimator 'nope'"):
        volmc.estimate_transmittance(scene, [0, 0, 4], [0, 0, -1], estimator="nope")
    with pytest.raises(volmc.VolmcError, match="directions: must not be the zero vector"):
        volmc.estimate_transmittance(scene, [0, 0, 4], [0, 0, 0])
    with pytest.raises(volmc.VolmcError, match="t_max: must be >= 0"):
        volmc.estimate_transmittance(scene, [0, 0, 4], [0, 0, -1], -1.0)


def test_numpy_grids_in_every_media_entry():
    """A numpy array is a grid in a [[media]] entry as in [medium] (density, emission field
    and temperature), and through a media.N override; elsewhere arrays are lists."""
    g = np.ones((4, 5, 6), np.float32)
    box = [[-1, -1, -1], [1, 1, 1]]
    s = volmc.scene_from_dict({"camera": {}, "media": [
        {"bounds": box, "density": 1.0},
        {"bounds": box, "density": g, "emission": {"field": g, "radiance": 1.0}},
        {"bounds": box, "density": 0.5, "emission": {"temperature": g * 1500.0}}]})
    assert s.spec.media[1].density.array.shape == (4, 5, 6)
    assert s.spec.media[1].emission.field.array.shape == (4, 5, 6)
    assert s.spec.media[2].emission.temperature.array.shape == (4, 5, 6)
    s = volmc.scene_from_dict({"camera": {"eye": np.array([0.0, 0.0, 5.0])},
                               "media": [{"bounds": box, "density": 1.0}]},
                              overrides={"media.0.density": g})
    assert s.spec.media[0].density.array.shape == (4, 5, 6) and s.camera.eye == (0.0, 0.0, 5.0)


def test_api_arguments_found_by_a_hostile_pass(tmp_path):
    """Arguments a black-box pass over the API sent: each works, or is the one-line
    VolmcError (they were TypeError, AttributeError, MemoryError, a silent black PNG, or a
    list of a billion frames)."""
    import itertools
    import pyopencl as cl
    box = {"bounds": [[-1, -1, -1], [1, 1, 1]], "density": 2.0}
    o, d = [[0, 0, -5]], [0, 0, 1]
    from volmc.api import _device
    from volmc.cl.device import select_device
    device = select_device()
    assert isinstance(device, cl.Device)
    for spec in (device, 0, np.int64(0)):   # a Device was refused, an int crashed later
        r = volmc.estimate_transmittance(box, o, d, device=spec)
        assert r.estimates[0] == pytest.approx(math.exp(-4.0), rel=1e-6)
    assert _device(0, "opencl", "w") == "0"
    for scale in (1e200, 1e-170):   # overflowed to a miss, underflowed to "zero vector"
        r = volmc.estimate_transmittance(box, [[-5, 0, 0]], [scale, 0, 0])
        assert r.estimates[0] == pytest.approx(math.exp(-4.0), rel=1e-6)
    # a scene dict with [[media]] is a scene, not a [medium] table
    r = volmc.estimate_transmittance({"camera": {}, "media": [box]}, o, d)
    assert r.estimates[0] == pytest.approx(math.exp(-4.0), rel=1e-6)
    scene = volmc.load_scene(overrides={"camera.resolution": [6, 5], "render.spp": 2})
    img = volmc.render(scene, progress=False)
    huge = np.broadcast_to(np.zeros((1, 1, 1), np.float32), (3000, 3000, 3000))
    bad = [
        (lambda: volmc.estimate_transmittance(box, o, d, device=3.5), "device"),
        (lambda: volmc.estimate_transmittance({"camera": {}, "media": [box, box]}, o, d),
         "2 media"),
        (lambda: volmc.estimate_transmittance(box, o, d, t_max=np.full(10**6, np.inf),
                                              n=2**31 - 1), "n: "),
        (lambda: volmc.estimate_transmittance(box, o, d, estimator=["ratio"]), "estimator"),
        (lambda: volmc.render_frames({"camera": {}, "medium": box}, range(10**9)), "frames"),
        (lambda: volmc.render_frames({"camera": {}, "medium": box}, itertools.count()),
         "frames"),
        (lambda: volmc.render_frames({"camera": {}, "medium": box}, [1], output=str(
            tmp_path / ".exr")), "output"),
        (lambda: volmc.load_scene(overrides=5), "overrides"),
        (lambda: volmc.load_scene(overrides=[5]), "overrides"),
        (lambda: volmc.load_scene(3), "path"),
        (lambda: img.save(None), "path"),
        (lambda: img.save(str(tmp_path / "a\0.exr")), "path"),
        (lambda: img.save(str(tmp_path / ("x" * 300 + ".exr"))), "path"),
        (lambda: img.save(str(tmp_path / "a.png"), exposure="1"), "exposure"),
        (lambda: img.save(str(tmp_path / "a.png"), exposure=1e6), "exposure"),
        (lambda: img.save(str(tmp_path / "a.png"), exposure=float("nan")), "exposure"),
        (lambda: img.png_bytes(tonemap="bogus"), "tonemap"),
        # a broadcast view of 2.7e10 voxels: the check's temporaries ran out of memory
        (lambda: volmc.scene_from_dict({"camera": {}, "medium": {**box, "density": huge}}),
         "needs"),
        # a second pass: truthy strings taken as True, a str width, a TypeError in difflib,
        # and the device's error keyed for the command line
        (lambda: volmc.render(scene, albedo="no", progress=False), "albedo: expected True"),
        (lambda: volmc.render(scene, lanes="8", progress=False), "lanes: expected an integer"),
        (lambda: volmc.render_frames({"camera": {}, "medium": box}, [1], png="yes"),
         "png: expected True"),
        (lambda: img.save(str(tmp_path / "a.exr"), variance="no"), "variance: expected True"),
        (lambda: img.save(str(tmp_path / "a.exr"), denoised="no"), "denoised: expected True"),
        (lambda: volmc.scene_from_dict({"camera": {}, "medium": box, 1: 2}), "1: unknown key"),
        (lambda: volmc.render(scene, device="99", progress=False),
         "volmc.render(): device: 99: no such OpenCL platform"),
        (lambda: volmc.scene_from_dict({"camera": {}, "medium": {**box, "albedo": 1.0000001}}),
         "got 1.0000001"),
    ]
    for call, words in bad:
        with pytest.raises(volmc.VolmcError) as e:
            call()
        assert words in str(e.value) and "\n" not in str(e.value), (words, e.value)
    assert os.listdir(tmp_path) == []   # nothing written by a refused call
    assert img.save(os.fsencode(tmp_path / "b.exr")) == str(tmp_path / "b.exr")
