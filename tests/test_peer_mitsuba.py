"""volmc against Mitsuba 3 (the peer renderer), when Mitsuba is installed and can run.

Each agreement test renders a small scene with both renderers and applies the per-pixel Welch
test of volmc.peers.compare (Sidak over all pixel channels at 1 %, plus the image-mean test):
one false failure in a hundred per scene when the two renderers compute the same image. A
deliberately wrong translation must be detected, so the test has power against the
conventions it is meant to pin down (HG sign, path-depth offset, fov axis, grid placement).
"""

import json
import subprocess
import sys
import textwrap

import numpy as np
import pytest

from volmc.peers import compare
from volmc.peers.mitsuba import PeerUnavailable, find_libllvm, probe
from volmc.scene import scene_from_dict

try:
    MITSUBA = probe()
    REASON = ""
except PeerUnavailable as e:
    MITSUBA, REASON = None, str(e)

needs_mitsuba = pytest.mark.skipif(MITSUBA is None, reason=f"peer absent: {REASON}")


def _scene(camera=None, medium=None, render=None, lights=None):
    raw = {
        "camera": {"eye": [0.3, 0.4, 4.0], "target": [0.0, 0.0, 0.0], "fov": 40.0,
                   "resolution": [24, 16]},
        "medium": {"bounds": [[-1.0, -0.5, -0.8], [1.2, 1.0, 0.6]],
                   "density": {"generator": "cloud", "resolution": 20, "seed": 3},
                   "scale": 12.0, "albedo": [0.9, 0.7, 0.5],
                   "phase": {"type": "hg", "g": 0.6}},
        "lights": lights or [
            {"type": "environment", "radiance": [0.2, 0.3, 0.5]},
            {"type": "directional", "direction": [-0.6, -0.55, -0.6],
             "irradiance": [3.0, 2.8, 2.5]},
            {"type": "point", "position": [0.5, 2.0, 1.0], "intensity": [4.0, 3.0, 2.0]}],
        "render": {"spp": 256, "max_depth": -1},
    }
    for key, part in (("camera", camera), ("medium", medium), ("render", render)):
        raw[key].update(part or {})
    return scene_from_dict(raw)


CASES = {
    # Multiple scattering in a grid of non-cubic bounds, all three light types.
    "grid": _scene(),
    # Single scattering with backward HG: pins the depth offset and the HG sign.
    "single_scatter": _scene(medium={"phase": {"type": "hg", "g": -0.5}},
                             render={"max_depth": 1}),
    # Orthographic camera at a wide aspect ratio: pins the size convention.
    "orthographic": _scene(camera={"type": "orthographic", "size": 2.5,
                                   "resolution": [28, 14]}, render={"max_depth": 6}),
    # Camera inside a homogeneous medium (Mitsuba must be told its medium).
    "camera_inside": _scene(camera={"eye": [0.1, 0.2, 0.3], "target": [1.0, 0.0, -1.0],
                                    "fov": 70.0, "resolution": [16, 16]},
                            medium={"density": 1.0, "scale": 1.5, "phase": {"type": "isotropic"}}),
}


def _compare(scene, mi_scene=None, spp=256, passes=16):
    from volmc.peers.mitsuba import MitsubaRenderer
    from volmc.render import render
    rv = render(scene, backend="opencl", spp=spp, progress=False)
    peer = MitsubaRenderer(mi_scene or scene)
    mean_p, var_p, _, pass_means = peer.render(spp, seed=11, passes=passes)
    return compare.agreement(rv.film.mean(), rv.film.variance_of_mean(), mean_p, var_p,
                             pass_means, spp)


@needs_mitsuba
@pytest.mark.parametrize("name", sorted(CASES))
def test_volmc_agrees_with_mitsuba(name):
    agr = _compare(CASES[name])
    assert agr.passed, agr.summary("Mitsuba")


@needs_mitsuba
@pytest.mark.parametrize("wrong", ["hg_sign", "depth_offset", "fov_axis", "grid_flip"])
def test_wrong_translation_is_detected(wrong, monkeypatch):
    """Each convention the translation handles, broken on purpose, makes the images differ."""
    import volmc.peers.mitsuba as pm
    scene = CASES["single_scatter"]
    original = pm.scene_dict

    def broken(sc, mi=None):
        d = original(sc, mi)
        medium = d["volmc_medium"]
        if wrong == "hg_sign":
            medium["phase"]["g"] = -medium["phase"]["g"]
        elif wrong == "depth_offset":
            d["integrator"]["max_depth"] -= 1
        elif wrong == "fov_axis":
            d["sensor"]["fov_axis"] = "x"
        else:
            grid = np.asarray(sc.grid, np.float32)[:, ::-1, :]
            medium["sigma_t"]["grid"] = pm._mi().VolumeGrid(np.ascontiguousarray(grid[..., None]))
        return d

    monkeypatch.setattr(pm, "scene_dict", broken)
    agr = _compare(scene)
    assert not agr.passed, agr.summary("Mitsuba")


@needs_mitsuba
def test_peer_cli_reports_agreement_and_speed(tmp_path):
    scene = tmp_path / "s.toml"
    scene.write_text(textwrap.dedent("""
        [camera]
        eye = [0.3, 0.4, 4.0]
        fov = 40.0
        resolution = [16, 16]
        [medium]
        bounds = [[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]]
        density = 1.0
        scale = 2.0
        albedo = 0.8
        phase = { type = "hg", g = 0.3 }
        [[lights]]
        type = "environment"
        radiance = 0.5
        [render]
        spp = 64
    """))
    out = tmp_path / "r.json"
    p = subprocess.run([sys.executable, "-m", "volmc.cli", "peer", "mitsuba", str(scene),
                        "--reference-spp", "256", "--json", str(out), "--images", str(tmp_path)],
                       capture_output=True, text=True)
    assert p.returncode == 0, p.stdout + p.stderr
    rep = json.loads(out.read_text())
    assert rep["agreement"]["passed"] and rep["spp"] == 64 and rep["reference_spp"] == 256
    assert rep["volmc"]["rmse"] > 0 and rep["mitsuba"]["rmse"] > 0
    assert rep["equal_error_time_ratio"] > 0
    assert (tmp_path / "mitsuba.exr").is_file() and (tmp_path / "reference.exr").is_file()


def test_peer_cli_without_mitsuba_is_one_line_error(tmp_path):
    """With Mitsuba hidden, the CLI says why in one line and exits 2."""
    hide = tmp_path / "hide"
    hide.mkdir()
    (hide / "mitsuba.py").write_text("raise ImportError('hidden for the test')\n")
    import os
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(hide)] + sys.path))
    p = subprocess.run([sys.executable, "-m", "volmc.cli", "peer", "mitsuba", "--spp", "1"],
                       capture_output=True, text=True, env=env)
    assert p.returncode == 2
    lines = p.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("volmc: error: command line: peer:")
    assert "volmc[peers]" in lines[0] and "Traceback" not in p.stderr


def test_find_libllvm_honours_environment(monkeypatch):
    monkeypatch.setenv("DRJIT_LIBLLVM_PATH", "/some/libLLVM.so.19.1")
    assert find_libllvm() == "/some/libLLVM.so.19.1"


def test_welch_test_has_stated_size():
    """Same-mean images: the per-pixel test rejects in about 1 % of images (Sidak level)."""
    rng = np.random.default_rng(5)
    fails = 0
    trials = 400
    for _ in range(trials):
        a = rng.normal(1.0, 0.1, (8, 8, 3))
        passes = rng.normal(1.0, 0.2, (8, 8, 8, 3))
        mean_p = passes.mean(axis=0)
        var_p = passes.var(axis=0, ddof=1) / 8
        agr = compare.agreement(a, np.full_like(a, 0.01), mean_p, var_p,
                                passes.mean(axis=(1, 2)), 10**6)
        fails += not agr.passed
    # Family level 1 % for the pixels plus 1 % for the means: at most ~2 %; 400 trials give
    # a binomial upper 99.9 % bound of about 4.5 % at that rate.
    assert fails / trials < 0.045
    # ...and a 20 % shift of the peer is found.
    agr = compare.agreement(a, np.full_like(a, 1e-6), mean_p * 1.2, var_p,
                            passes.mean(axis=(1, 2)) * 1.2, 10**6)
    assert not agr.passed
