"""What the tests of every peer renderer share: the skip marker from the peer's probe, the
scene the agreement cases vary, and the `volmc peer NAME` command-line checks (a small scene
file, the run with its JSON report, the one-line error when the peer's package is hidden)."""
import json
import os
import subprocess
import sys
import textwrap

import numpy as np
import pytest

from volmc.peers.errors import PeerUnavailable
from volmc.scene import scene_from_dict

LIGHTS = [{"type": "environment", "radiance": [0.2, 0.3, 0.5]},
          {"type": "directional", "direction": [-0.6, -0.55, -0.6],
           "irradiance": [3.0, 2.8, 2.5]},
          {"type": "point", "position": [0.5, 2.0, 1.0], "intensity": [4.0, 3.0, 2.0]}]


def needs_peer(probe):
    """(marker, version): a skip marker naming why the peer is absent, and its version (None
    when absent)."""
    try:
        version, reason = probe(), ""
    except PeerUnavailable as e:
        version, reason = None, str(e)
    return pytest.mark.skipif(version is None, reason=f"peer absent: {reason}"), version


def peer_scene(camera=None, medium=None, render=None, lights=None):
    """A cloud grid in non-cubic bounds under all three light types, multiple scattering; each
    argument updates its table."""
    raw = {
        "camera": {"eye": [0.3, 0.4, 4.0], "target": [0.0, 0.0, 0.0], "fov": 40.0,
                   "resolution": [24, 16]},
        "medium": {"bounds": [[-1.0, -0.5, -0.8], [1.2, 1.0, 0.6]],
                   "density": {"generator": "cloud", "resolution": 20, "seed": 3},
                   "scale": 12.0, "albedo": [0.9, 0.7, 0.5],
                   "phase": {"type": "hg", "g": 0.6}},
        "lights": lights or LIGHTS,
        "render": {"spp": 256, "max_depth": -1},
    }
    for key, part in (("camera", camera), ("medium", medium), ("render", render)):
        raw[key].update(part or {})
    return scene_from_dict(raw)


#: Two media side by side ([[media]]) whose placed boxes do not overlap: on the left the
#: cloud of peer_scene, turned 35 degrees about y; on the right a homogeneous box with backward
#: HG, turned 30 degrees about (1, 0, 1). The sun shines from the right, almost level, so the
#: box shadows part of the cloud (shadow rays cross both boxes).
TWO_MEDIA = [
    {"bounds": [[-1.0, -0.6, -0.7], [1.0, 0.9, 0.7]],
     "density": {"generator": "cloud", "resolution": 20, "seed": 3},
     "scale": 12.0, "albedo": [0.9, 0.7, 0.5], "phase": {"type": "hg", "g": 0.6},
     "transform": {"rotate": [0, 1, 0, 35.0], "translate": [-1.35, 0.0, 0.0]}},
    {"bounds": [[-0.5, -0.5, -0.5], [0.5, 0.5, 0.5]], "density": 1.0, "scale": 1.5,
     "albedo": [0.6, 0.8, 0.95], "phase": {"type": "hg", "g": -0.3},
     "transform": {"rotate": [1, 0, 1, 30.0], "translate": [1.3, 0.0, 0.2]}},
]
TWO_MEDIA_LIGHTS = [LIGHTS[0], {"type": "directional", "direction": [-1.0, -0.1, -0.15],
                                "irradiance": [3.0, 2.8, 2.5]}]


def peer_media_scene(media=None, camera=None, render=None, lights=None):
    """A scene of several media (``[[media]]``, default TWO_MEDIA), framed to show both
    boxes of TWO_MEDIA, multiple scattering; camera and render update their tables."""
    raw = {
        "camera": {"eye": [0.0, 0.6, 5.0], "target": [-0.25, 0.15, 0.0], "fov": 30.0,
                   "resolution": [32, 16]},
        "media": media or TWO_MEDIA,
        "lights": lights or TWO_MEDIA_LIGHTS,
        "render": {"spp": 256, "max_depth": -1},
    }
    for key, part in (("camera", camera), ("render", render)):
        raw[key].update(part or {})
    return scene_from_dict(raw)


def slab_scene(tmp_path, density, scale=1.0):
    """An absorbing slab 0.5 thick along the view axis, seen by an orthographic camera against
    an environment of radiance 1: every pixel is exp(-tau). density: a number, or the density
    along z of a grid that is constant across x and y (clamped trilinear interpolation).
    Returns the scene and the optical depth per unit scale."""
    raw = {"camera": {"type": "orthographic", "eye": [0.0, 0.0, 3.0], "size": 1.2,
                      "resolution": [8, 8]},
           "medium": {"bounds": [[-1.0, -1.0, -0.25], [1.0, 1.0, 0.25]], "albedo": 0.0,
                      "density": density, "scale": scale},
           "lights": [{"type": "environment", "radiance": 1.0}],
           "render": {"spp": 256, "max_depth": -1}}
    if isinstance(density, list):
        grid = np.repeat(np.repeat(np.asarray(density, np.float32)[:, None, None], 2, 1), 2, 2)
        np.save(tmp_path / "slab.npy", grid)
        raw["medium"]["density"] = {"file": "slab.npy"}
        n = len(density)
        # Optical depth per unit scale: the piecewise-linear profile between voxel centres,
        # flat in the half voxels at either face (trapezoids are exact on it).
        u = [0.0] + [(k + 0.5) / n for k in range(n)] + [1.0]
        v = [density[0]] + list(density) + [density[-1]]
        depth = 0.5 * sum((u[k + 1] - u[k]) * (v[k] + v[k + 1]) / 2 for k in range(n + 1))
    else:
        depth = 0.5 * density
    return scene_from_dict(raw, base_dir=str(tmp_path)), depth



def assert_passes_match(pass_means, exact):
    """Independent passes' image means (passes x 3) agree with exact per-channel values:
    Student's t over the passes, Sidak over the three channels at 1 %, and within 10 % so that
    a wild spread cannot pass the t-test. The standard error's floor is 2e-6 of the exact
    value, a few float32 ulps, for a peer that computes the value deterministically (Cycles
    integrates a homogeneous absorber analytically)."""
    from scipy import stats
    mean = pass_means.mean(axis=0)
    se = pass_means.std(axis=0, ddof=1) / np.sqrt(len(pass_means))
    t = (mean - exact) / np.maximum(se, 2e-6 * exact)
    p = 2.0 * stats.t.sf(np.abs(t), len(pass_means) - 1)
    assert p.min() >= 1.0 - 0.99 ** (1 / 3), (mean, exact, t)
    assert np.all(np.abs(mean - exact) < 0.1 * exact)


PEER_SCENE = """
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
"""


def run_peer_cli(name, tmp_path, *extra):
    """`volmc peer NAME` on PEER_SCENE at 64 spp against a 256-spp reference; asserts the
    report's agreement and positive errors and returns the report."""
    scene = tmp_path / "s.toml"
    scene.write_text(textwrap.dedent(PEER_SCENE))
    out = tmp_path / "r.json"
    p = subprocess.run([sys.executable, "-m", "volmc.cli", "peer", name, str(scene),
                        "--reference-spp", "256", "--json", str(out), "--images",
                        str(tmp_path), *extra], capture_output=True, text=True)
    assert p.returncode == 0, p.stdout + p.stderr
    rep = json.loads(out.read_text())
    assert rep["agreement"]["passed"] and rep["spp"] == 64 and rep["reference_spp"] == 256
    assert rep["volmc"]["rmse"] > 0 and rep[name]["rmse"] > 0
    assert rep["equal_error_time_ratio"] > 0
    assert (tmp_path / f"{name}.exr").is_file() and (tmp_path / "reference.exr").is_file()
    # The variances the per-pixel test weighed: non-negative, and not all zero on either side.
    from volmc.film import read_exr
    for who in ("volmc", name):
        var, _ = read_exr(tmp_path / f"{who}.var.exr")
        assert np.all(var >= 0) and np.any(var > 0), who
    return rep


def assert_peer_cli_error_when_hidden(name, tmp_path, hidden, mention):
    """With the module `hidden` replaced by one whose import fails, `volmc peer NAME` says why
    in one line naming `mention` and exits 2."""
    hide = tmp_path / "hide"
    (hide / hidden).mkdir(parents=True)
    (hide / hidden / "__init__.py").write_text("raise ImportError('hidden for the test')\n")
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(hide)] + sys.path))
    p = subprocess.run([sys.executable, "-m", "volmc.cli", "peer", name, "--spp", "1"],
                       capture_output=True, text=True, env=env)
    assert p.returncode == 2
    lines = p.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("volmc: error: command line: peer:")
    assert mention in lines[0] and "Traceback" not in p.stderr
