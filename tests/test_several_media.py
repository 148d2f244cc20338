"""Several media ([[media]]): overlapping coefficients add, a real collision picks the medium
by its share of the extinction, one merged majorant-segment iterator walks them all.

Exact cases compare to float32 rounding; statistical ones are z-tests with the render's own
variance of the mean, Sidak-corrected over every pixel and channel (family false-failure
rate ALPHA = 1 %, fixed seeds)."""

import math

import numpy as np
import pytest

from stats import ALPHA, z_bound
from volmc.render import render
from volmc.scene import scene_from_dict
from volmc.scene.errors import SceneError
from volmc.scene.schema import MAX_MEDIA

#: Two slabs overlapping in depth, wider than the view: every orthographic ray down -z
#: crosses 1.5 units of each, 1 unit of them together.
SLAB_A = {"bounds": [[-2, -2, -1.0], [2, 2, 0.5]], "density": 1.0}
SLAB_B = {"bounds": [[-2, -2, -0.5], [2, 2, 1.0]], "density": 1.0}


def _scene(media, lights, spp=64, res=6, render_keys=None, camera=None):
    cam = {"type": "orthographic", "eye": [0.0, 0.0, 3.0], "target": [0, 0, 0], "size": 1.6,
           "resolution": [res, res]}
    return {"camera": dict(cam, **(camera or {})), "media": media, "lights": lights,
            "render": {"spp": spp, **(render_keys or {})}}


def _z(res, expected):
    m = res.film.mean()
    se = np.sqrt(res.film.variance_of_mean())
    return (m - expected) / np.where(se > 0, se, np.inf)


def test_one_medium_in_media_renders_as_medium(backend):
    """[[media]] with one entry is [medium]: the same image bit for bit."""
    med = {"bounds": [[-1, -1, -1], [1, 1, 1]], "density": {"generator": "cloud",
                                                            "resolution": 16}, "scale": 4.0,
           "albedo": 0.8}
    base = _scene([med], [{"type": "directional", "direction": [0, -1, 0], "irradiance": 2.0}],
                  spp=8)
    a = render(scene_from_dict(base), progress=False, backend=backend)
    one = {k: v for k, v in base.items() if k != "media"}
    b = render(scene_from_dict(dict(one, medium=med)), progress=False, backend=backend)
    assert np.array_equal(a.film.sum, b.film.sum)


@pytest.mark.parametrize("grid", [False, True], ids=["constant", "grid"])
def test_overlapping_absorbers_add_their_extinction(backend, grid):
    """Two absorbers overlapping in depth: T = exp(-(s_a 1.5 + s_b 1.5)) on every ray, and
    the alpha channel 1 - T; a constant grid (per-cell majorants merged with the other
    medium's global one) gives the same."""
    sa, sb = 0.7, 1.9
    a = dict(SLAB_A, scale=sa, albedo=0.0)
    b = dict(SLAB_B, scale=sb, albedo=0.0)
    if grid:
        a["density"] = np.ones((5, 7, 6))
    res = render(scene_from_dict(_scene([a, b], [{"type": "environment", "radiance": 1.0}],
                                        spp=4)), progress=False, backend=backend)
    T = math.exp(-(sa + sb) * 1.5)
    np.testing.assert_allclose(res.film.mean(), T, rtol=2e-5)
    np.testing.assert_allclose(res.film.alpha(), 1.0 - T, rtol=2e-5)


def test_white_furnace_with_two_phase_functions(backend):
    """Albedo 1 in two overlapping media of different densities and phase functions,
    unbounded depth: every pixel equals the environment."""
    a = dict(SLAB_A, density={"generator": "cloud", "resolution": 12}, scale=6.0,
             phase={"type": "hg", "g": 0.8})
    b = dict(SLAB_B, scale=2.0, phase={"type": "hg", "g": -0.5},
             transform={"rotate": [1, 1, 0, 25]})
    res = render(scene_from_dict(_scene([a, b], [{"type": "environment", "radiance": 0.5}],
                                        spp=128, render_keys={"max_depth": -1,
                                                              "rr_depth": 1000000})),
                 progress=False, backend=backend)
    z = _z(res, 0.5)
    assert np.abs(z).max() < z_bound(ALPHA, z.size)
    assert res.counters["dropped"] == res.counters["capped"] == 0


def _hg(g, c):
    return (1 - g * g) / (4 * math.pi * (1 + g * g - 2 * g * c) ** 1.5)


def _single_scatter(boxes, light_dir, E, shape, n=4000, equal=False):
    """Single scattering by closed-form transmittances and a midpoint quadrature in depth,
    on every orthographic ray down -z from z = 3 (an image of ``shape``): boxes are (z0, z1,
    sigma, albedo, g) slabs spanning the view, lit by a directional light propagating along
    light_dir (irradiance E). The phase functions mix by each medium's sigma_s; ``equal``:
    by equal shares of the media present instead (what a wrong pick would give)."""
    wl = -np.asarray(light_dir, float) / np.linalg.norm(light_dir)
    d = np.array([0.0, 0.0, -1.0])
    cos = float(d @ wl)
    zlo, zhi = min(b[0] for b in boxes), max(b[1] for b in boxes)
    z = zhi - (np.arange(n) + 0.5) * (zhi - zlo) / n
    dz = (zhi - zlo) / n
    sig = sum(np.where((z >= b[0]) & (z <= b[1]), b[2], 0.0) for b in boxes)
    inside = [((z >= b[0]) & (z <= b[1])).astype(float) for b in boxes]
    sig_s_f = sum(w * b[2] * b[3] * _hg(b[4], cos) for w, b in zip(inside, boxes))
    if equal:
        sig_s_f = sig * sum(w * b[3] * _hg(b[4], cos) for w, b in zip(inside, boxes)) / \
            np.maximum(sum(inside), 1.0)
    tau_cam = np.cumsum(sig * dz) - 0.5 * sig * dz
    # towards the light: the slabs span the view, so only their z faces bound the path
    tau_sun = sum(b[2] * np.clip(b[1] - np.clip(z, b[0], b[1]), 0, None) / wl[2]
                  for b in boxes) if wl[2] > 0 else None
    L = np.sum(np.exp(-tau_cam) * sig_s_f * E * np.exp(-tau_sun)) * dz
    return np.full(shape, L)


def test_a_collision_scatters_with_its_medium_by_share(backend):
    """Single scattering in two overlapping media with different densities, albedos and
    phase functions against the quadrature of the analytically mixed phase function
    sum_i sigma_s,i f_i / sum_i sigma_s,i. The same render must reject the mixture a pick by
    equal shares would give (the test has power)."""
    a = dict(SLAB_A, scale=0.4, albedo=0.9, phase={"type": "hg", "g": 0.7})
    b = dict(SLAB_B, scale=1.3, albedo=0.5, phase={"type": "hg", "g": -0.6})
    light = [0.5, 0.0, -1.0]
    res = render(scene_from_dict(_scene([a, b], [{"type": "directional", "direction": light,
                                                  "irradiance": 3.0}], spp=512,
                                        render_keys={"max_depth": 1})),
                 progress=False, backend=backend)
    boxes = [(-1.0, 0.5, 0.4, 0.9, 0.7), (-0.5, 1.0, 1.3, 0.5, -0.6)]
    expect = _single_scatter(boxes, light, 3.0, (6, 6))
    z = _z(res, expect[..., None])
    bound = z_bound(ALPHA, z.size)
    assert np.abs(z).max() < bound
    # Power, on the image mean (every pixel has the same expectation here): the mixture of
    # a pick by equal shares is rejected, the right one is not.
    wrong = _single_scatter(boxes, light, 3.0, (6, 6), equal=True)
    se = math.sqrt(res.film.variance_of_mean().sum()) / res.film.mean().size
    z_right = (res.film.mean().mean() - expect.mean()) / se
    z_wrong = (res.film.mean().mean() - wrong.mean()) / se
    assert abs(z_right) < z_bound(ALPHA) < abs(z_wrong)


def test_scene_keys_and_errors():
    lights = [{"type": "environment", "radiance": 1.0}]
    s = scene_from_dict(_scene([SLAB_A, dict(SLAB_B, transform={"translate": [0, 0, 3]})],
                               lights))
    assert len(s.media) == 2 and len(s.media_scenes) == 2
    assert s.media[1].transform is not None
    with pytest.raises(SceneError, match="not both"):
        scene_from_dict(dict(_scene([SLAB_A], lights), medium=SLAB_B))
    with pytest.raises(SceneError, match=f"at most {MAX_MEDIA}"):
        scene_from_dict(_scene([SLAB_A] * (MAX_MEDIA + 1), lights))
    with pytest.raises(SceneError, match=r"media\[1\]\.scale"):
        scene_from_dict(_scene([dict(SLAB_A, scale=[1, 2, 3]), dict(SLAB_B, scale=[3, 2, 1])],
                               lights))
    with pytest.raises(SceneError, match=r"media\[1\]\.density"):
        scene_from_dict(_scene([SLAB_A, dict(SLAB_B, density=-1.0)], lights))
    with pytest.raises(SceneError, match="non-empty"):
        scene_from_dict(_scene([], lights))


def test_cli_names_the_medium_of_bad_input(tmp_path):
    """A singular transform in the second medium: one line naming media[1].transform, exit
    status 2, no traceback."""
    import subprocess
    import sys
    (tmp_path / "two.toml").write_text('''
[camera]
resolution = [4, 4]
[[media]]
bounds = [[-1, -1, -1], [1, 1, 1]]
density = 1.0
[[media]]
bounds = [[-1, -1, -1], [1, 1, 1]]
density = 1.0
transform = { scale = [1, 0, 1] }
''')
    p = subprocess.run([sys.executable, "-m", "volmc.cli", "render", "two.toml", "-o", "x.exr"],
                       cwd=tmp_path, capture_output=True, text=True)
    assert p.returncode == 2
    lines = p.stderr.strip().splitlines()
    assert len(lines) == 1 and "media[1].transform" in lines[0], p.stderr
    assert "Traceback" not in p.stderr and not (tmp_path / "x.exr").exists()


def test_several_media_checkpoint_and_resume(tmp_path):
    """A scene of several media serialises back to itself (what checkpoints and EXR metadata
    store), resumes a checkpoint to the uninterrupted render's sums bit for bit, and refuses
    a checkpoint whose second medium differs."""
    from volmc.resources import scenes_dir
    from volmc.scene import load_scene
    from volmc.scene.schema import validate
    from volmc.scene.serialize import to_dict
    path = scenes_dir() / "tests" / "media.toml"
    scene = load_scene(path, ["camera.resolution=[6, 6]"])
    spec = scene.spec
    assert validate(to_dict(spec), spec.file) == spec
    full = render(scene, backend="opencl", spp=8, progress=False, chunk_samples=1)
    ck = tmp_path / "ck.npz"
    render(scene, backend="opencl", spp=3, progress=False, checkpoint=str(ck), chunk_samples=1)
    res = render(scene, backend="opencl", spp=8, progress=False, resume=str(ck),
                 chunk_samples=1)
    np.testing.assert_array_equal(res.film.sum, full.film.sum)
    other = load_scene(path, ["camera.resolution=[6, 6]", "media.1.albedo=0.6"])
    with pytest.raises(SceneError):
        render(other, backend="opencl", spp=8, progress=False, resume=str(ck),
               chunk_samples=1)
