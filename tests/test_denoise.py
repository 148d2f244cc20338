"""The albedo AOV (film.py) and the denoised preview (volmc/denoise.py, --denoise).

The AOV of a sample is the albedo of the medium its camera ray first scatters in, else 0.
On a slab seen face-on by an orthographic camera every ray crosses the same thickness, so
a sample's AOV is the albedo with probability P = 1 - exp(-sigma x thickness) (the camera
ray collides in the slab) and 0 otherwise: per pixel the fraction of samples that carry it
is Binomial(n, P), z-tested (Sidak over pixels and channels, family level 1e-3). The AOV
changes nothing else: the image is the same bit for bit with and without it. The kernels
and the reference trace the same paths, so their AOVs agree sample by sample.

Denoising: on the cloud at 16 spp, the preview is closer to a 512-spp render than the
noisy image is (it would not be if the filter were given the wrong channels, the AOV in
place of the colour, or rows scrambled); the unbiased files are unchanged and the
denoised file's metadata says what made it.
"""

import math
import os
import sys

import numpy as np
import pytest

from stats import z_bound
from volmc.film import read_exr
from volmc.render import render
from volmc.resources import scenes_dir
from volmc.scene import load_scene, scene_from_dict
from volmc.scene.errors import SceneError

THICK = 0.5
SCALE = 2.0
ALBEDO = [0.9, 0.5, 0.2]


def slab(spp=128, seed=5, max_depth=4):
    # The box is wider than the view's middle: the left quarter of the image misses it.
    return scene_from_dict({
        "camera": {"type": "orthographic", "eye": [0.0, 0.0, 3.0], "size": 2.0,
                   "resolution": [16, 8]},
        "medium": {"bounds": [[-1.0, -2.0, -THICK / 2], [3.0, 2.0, THICK / 2]],
                   "density": 1.0, "scale": SCALE, "albedo": ALBEDO,
                   "phase": {"type": "hg", "g": 0.3}},
        "lights": [{"type": "environment", "radiance": [0.3, 0.5, 0.7]}],
        "render": {"spp": spp, "seed": seed, "max_depth": max_depth}})


def test_slab_albedo_aov_is_albedo_times_collision_probability(backend):
    r = render(slab(), backend=backend, progress=False, albedo=True)
    aov = r.film.albedo()
    n = r.film.spp
    assert np.all(aov[:, :4] == 0.0)   # rays that miss the box never scatter
    p = 1.0 - math.exp(-SCALE * THICK)
    hit = aov[:, 4:]
    # Each sample carries the whole albedo or nothing: the same fraction in every channel.
    frac = hit / np.asarray(ALBEDO)
    assert np.allclose(frac, frac[..., :1], atol=1e-6)
    z = (frac[..., 0] - p) / math.sqrt(p * (1.0 - p) / n)
    assert np.abs(z).max() < z_bound(1e-3, z.size)


def test_no_scattering_no_albedo(backend):
    """max_depth = 0: no camera ray scatters, so the AOV is 0 everywhere."""
    r = render(slab(max_depth=0, spp=8), backend=backend, progress=False, albedo=True)
    assert np.all(r.film.albedo() == 0.0)
    assert r.film.alpha().max() > 0.5


def test_the_aov_changes_nothing_else(backend):
    scene = load_scene(scenes_dir() / "cloud.toml", overrides=["camera.resolution=[24,16]"])
    a = render(scene, backend=backend, spp=4, progress=False)
    b = render(scene, backend=backend, spp=4, progress=False, albedo=True)
    assert a.film.albedo() is None and b.film.albedo() is not None
    assert np.array_equal(a.film.sum, b.film.sum[..., :4])
    assert np.array_equal(a.film.sum_sq, b.film.sum_sq[..., :4])
    assert b.film.albedo().max() > 0.5   # the cloud's albedo is near 1 where it is dense


def test_kernel_and_reference_aovs_agree():
    scene = load_scene(scenes_dir() / "cloud.toml", overrides=["camera.resolution=[24,16]"])
    a = render(scene, backend="opencl", spp=8, progress=False, albedo=True).film.albedo()
    b = render(scene, backend="numba", spp=8, progress=False, albedo=True).film.albedo()
    # Same paths: equal up to float32 rounding of the albedo, except where a float32
    # decision flipped (none in this run; a few would be allowed).
    assert np.mean(np.abs(a - b) > 1e-6) < 0.01
    assert np.abs(a - b).mean() < 1e-4


def test_lane_widths_give_the_same_aov():
    scene = load_scene(scenes_dir() / "cloud.toml", overrides=["camera.resolution=[24,16]"])
    a = render(scene, spp=8, progress=False, albedo=True, lanes=1).film.albedo()
    b = render(scene, spp=8, progress=False, albedo=True, lanes=16).film.albedo()
    assert np.mean(a != b) < 0.01


def test_checkpoint_with_and_without_the_aov_refuses_to_mix(tmp_path):
    scene = slab(spp=4)
    ck = tmp_path / "c.npz"
    render(scene, backend="opencl", spp=2, progress=False, checkpoint=ck)
    with pytest.raises(SceneError, match="rendered without the albedo AOV.*without --denoise"):
        render(scene, backend="opencl", spp=4, progress=False, resume=ck, albedo=True)
    render(scene, backend="opencl", spp=2, progress=False, checkpoint=ck, albedo=True)
    with pytest.raises(SceneError, match="rendered with the albedo AOV.*resume it with --denoise"):
        render(scene, backend="opencl", spp=4, progress=False, resume=ck)
    r = render(scene, backend="opencl", spp=4, progress=False, resume=ck, albedo=True)
    full = render(scene, backend="opencl", spp=4, progress=False, albedo=True)
    assert np.array_equal(r.film.sum, full.film.sum)


# ------------------------------------------------------------------ the denoised preview

def test_missing_oidn_is_a_one_line_error(monkeypatch):
    from volmc.denoise import denoise
    monkeypatch.setitem(sys.modules, "pyoidn", None)   # import pyoidn raises ImportError
    with pytest.raises(SceneError, match=r"volmc\[denoise\]"):
        denoise(np.zeros((4, 4, 3)))


@pytest.fixture(scope="module")
def cloud_renders():
    import volmc
    scene = load_scene(scenes_dir() / "cloud.toml", overrides=["camera.resolution=[96,64]"])
    noisy = volmc.render(scene, spp=16, progress=False, albedo=True)
    ref = volmc.render(scene, spp=512, seed=99, progress=False)
    return noisy, ref


def _rmse(a, b):
    return float(np.sqrt(np.mean((np.asarray(a, np.float64) - b) ** 2)))


def test_denoised_preview_is_closer_to_the_reference(cloud_renders):
    pytest.importorskip("pyoidn")
    from volmc.denoise import denoise
    noisy, ref = cloud_renders
    e_noisy = _rmse(noisy.image, ref.image)
    e_albedo = _rmse(noisy.denoised(), ref.image)
    e_colour = _rmse(denoise(noisy.image), ref.image)
    assert e_albedo < 0.7 * e_noisy and e_colour < 0.7 * e_noisy
    # Given the AOV in place of the colour, the filter returns something far from the image.
    assert _rmse(denoise(noisy.albedo), ref.image) > e_noisy


def test_save_denoised_leaves_the_unbiased_image_alone(cloud_renders, tmp_path):
    pytest.importorskip("pyoidn")
    noisy, _ = cloud_renders
    noisy.save(tmp_path / "a.exr", denoised=True)
    noisy.save(tmp_path / "a.png", denoised=True)
    img, meta = read_exr(tmp_path / "a.exr", alpha=True)
    assert np.array_equal(img, noisy.result.film.rgba().astype(np.float32))
    assert "denoised" not in meta
    den, dmeta = read_exr(tmp_path / "a.denoised.exr", alpha=True)
    assert np.allclose(den[..., :3], noisy.denoised(), atol=1e-6)
    assert np.array_equal(den[..., 3], img[..., 3])   # the unbiased coverage
    assert dmeta["denoised"].startswith("Intel Open Image Denoise")
    assert int(dmeta["denoised.albedo_aov"]) == 1
    assert dmeta["denoised.from"] == os.fspath(tmp_path / "a.exr")
    assert (tmp_path / "a.denoised.png").stat().st_size > 0


# ------------------------------------------------------------------ the command line

def _run(args, tmp_path, env=None):
    import subprocess
    from cli_subprocess import volmc_cli, volmc_env
    return subprocess.run(volmc_cli(*args), capture_output=True, text=True, cwd=tmp_path,
                          env=env or volmc_env(), timeout=600)


def test_cli_denoise_writes_a_preview_beside_the_unchanged_render(tmp_path):
    pytest.importorskip("pyoidn")
    scene = str(scenes_dir() / "cloud.toml")
    common = [scene, "--spp", "4", "-D", "camera.resolution=[32,24]", "--quiet"]
    a = _run(["render", *common, "-o", "plain.exr"], tmp_path)
    b = _run(["render", *common, "-o", "d.exr", "--png", "--denoise"], tmp_path)
    assert a.returncode == 0 and b.returncode == 0, (a.stderr, b.stderr)
    plain, _ = read_exr(tmp_path / "plain.exr", alpha=True)
    img, meta = read_exr(tmp_path / "d.exr", alpha=True)
    assert np.array_equal(plain, img)   # the AOV changes nothing in the unbiased image
    den, dmeta = read_exr(tmp_path / "d.denoised.exr", alpha=True)
    assert dmeta["denoised.from"] == "d.exr" and int(dmeta["denoised.albedo_aov"]) == 1
    assert "denoised" not in meta
    assert np.array_equal(den[..., 3], img[..., 3])
    assert (tmp_path / "d.png").exists() and (tmp_path / "d.denoised.png").exists()


def test_cli_denoise_without_oidn_fails_before_rendering(tmp_path):
    from cli_subprocess import volmc_env
    # A pyoidn that cannot be imported, first on the path.
    (tmp_path / "shadow").mkdir()
    (tmp_path / "shadow" / "pyoidn.py").write_text("raise ImportError('no OIDN here')\n")
    env = volmc_env()
    env["PYTHONPATH"] = os.pathsep.join([str(tmp_path / "shadow"), env["PYTHONPATH"]])
    r = _run(["render", str(scenes_dir() / "cloud.toml"), "--denoise", "-o", "x.exr"],
             tmp_path, env)
    assert r.returncode == 2
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and "volmc[denoise]" in lines[0] and "--denoise" in lines[0]
    assert not (tmp_path / "x.exr").exists()


def test_bench_denoise_reports_errors_that_fall(tmp_path):
    pytest.importorskip("pyoidn")
    import json
    from volmc.cli import main
    out = tmp_path / "d.json"
    assert main(["bench", "denoise", str(scenes_dir() / "cloud.toml"), "--width", "48",
                 "--spp-levels", "2,16", "--reference-spp", "256", "--json", str(out)]) == 0
    rows = json.loads(out.read_text())["scenes"][0]["rows"]
    assert [r["spp"] for r in rows] == [2, 16]
    assert rows[1]["mse_noisy"] < rows[0]["mse_noisy"]
    assert rows[0]["mse_denoised"] < rows[0]["mse_noisy"]
    assert rows[0]["worth_spp"] > 2


def test_normal_study_refuses_a_scene_without_a_grid(capsys):
    """Found by an outside test: `python -m volmc.bench.denoise_normal` on a homogeneous
    scene was a numpy broadcasting traceback after its reference render, and `--help` was
    read as a scene path. Now the one-line error, exit status 2, before rendering."""
    from volmc.bench.denoise_normal import main
    with pytest.raises(SystemExit) as e:
        main([str(scenes_dir() / "homogeneous.toml")])
    assert e.value.code == 2
    err = capsys.readouterr().err
    assert err.startswith("volmc: error: ") and "medium.density" in err and err.count("\n") == 1
    with pytest.raises(SystemExit) as e:
        main(["--help"])
    assert e.value.code == 0 and capsys.readouterr().out.startswith("usage:")


@pytest.mark.parametrize("transparent", [False, True])
def test_noise_free_pixels_keep_their_value(transparent):
    """The sky seen past the slab (its left quarter, but the column beside the slab) has no
    noise: the preview keeps it as rendered. The filter moved it by up to a third next to
    the noisy slab with the AOV (whose 0 there it reads as a dark surface), and gave an
    empty transparent background colour. Without the variance (1 spp) nothing is known to
    be exact."""
    pytest.importorskip("pyoidn")
    from volmc.denoise import denoise, denoise_film, noise_free
    sc = slab(spp=16)
    if transparent:
        sc = sc.with_render(transparent_background=True)
    r = render(sc, progress=False, albedo=True)
    m, var, cov = r.film.mean(), r.film.variance_of_mean(), r.film.alpha()
    sky = noise_free(m, var, cov)
    assert sky[:, :3].all() and not sky[:, 4:].any()
    assert np.all(m[:, :4] == (0.0 if transparent else np.array([0.3, 0.5, 0.7], np.float32)))
    out = denoise_film(r.film)[..., :3]
    assert np.array_equal(out[sky], m[sky].astype(np.float32))
    assert not np.array_equal(out[~sky], m[~sky].astype(np.float32))   # the rest is filtered
    assert not noise_free(m, np.full_like(var, np.inf), cov).any()
    plain = denoise(m, r.film.albedo())
    assert not np.array_equal(plain[sky], m[sky].astype(np.float32))   # what it guards


def test_a_pixel_of_zeros_inside_a_medium_is_denoised():
    """At 2 spp some of the cloud's pixels have only zeros (variance 0): not noise-free, so
    the preview fills them as the filter does. Keeping them left black holes (an outside
    check). Nor is an exact pixel whose neighbours are noisy (a few samples that all
    passed a thin medium)."""
    from volmc.denoise import noise_free
    sc = load_scene(scenes_dir() / "cloud.toml", ["camera.resolution=[32, 32]",
                                                  "lights.0.radiance=[0, 0, 0]"])
    r = render(sc, spp=2, progress=False)
    m, var, cov = r.film.mean(), r.film.variance_of_mean(), r.film.alpha()
    holes = np.all(m == 0, axis=-1) & np.all(var == 0, axis=-1) & (cov > 0)
    assert holes.sum() > 10                  # the case arises
    assert not noise_free(m, var, cov)[holes].any()
    lone = np.full((5, 5, 3), 2.0)
    var = np.full((5, 5, 3), 0.1)
    var[2, 2] = 0.0                          # exact alone among noisy neighbours
    assert not noise_free(lone, var).any()
    var[:] = 0.0
    assert noise_free(lone, var).all()
