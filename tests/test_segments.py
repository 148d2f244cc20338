"""Recording the transmittance segments of a render (med.rec, record_segment, FEATURE_RECORD;
volmc/bench/segments.py) on both backends, and replaying them on the scene's own majorant
structure (transmittance_runner with maj/mnr)."""

import functools
import math

import numpy as np
import pytest

from stats import ALPHA, z_bound
from volmc.backends import make_backend
from volmc.bench.segments import record_segments
from volmc.constants import MAJORANT_GRID, RECORD_CAMERA, RECORD_SHADOW
from volmc.params import C_CAPPED, C_OVER_MAJORANT
from volmc.render import render
from volmc.scene import scene_from_dict

K = 16


def _cloud(res=16, spp=2, max_depth=4, lights=None, camera=None):
    """The procedural cloud at 24^3 voxels under the sky and a sun. max_depth 4 gives at most
    4 x 2 shadow segments and one camera segment per sample: a record of K = 16 never fills
    with 1 sample per pixel."""
    return scene_from_dict({
        "camera": camera or {"eye": [0.0, -0.25, 4.0], "target": [0, 0, 0], "fov": 36.0,
                             "resolution": [res, res]},
        "medium": {"bounds": [[-1, -1, -1], [1, 1, 1]],
                   "density": {"generator": "cloud", "resolution": 24, "seed": 7},
                   "scale": 40.0, "albedo": 0.99, "phase": {"type": "hg", "g": 0.75}},
        "lights": lights if lights is not None else [
            {"type": "environment", "radiance": [0.08, 0.12, 0.22]},
            {"type": "directional", "direction": [0.8, -0.5, -0.3],
             "irradiance": [3.6, 3.45, 3.2]}],
        "render": {"spp": spp, "max_depth": max_depth, "rr_depth": 5,
                   "transmittance": "ratio"}})


@functools.lru_cache(maxsize=None)
def _recording(backend, res=24, spp=1):
    return record_segments(_cloud(res, spp), backend, spp=spp, per_pixel=K, seed=3)


def test_segments_lie_in_the_box(backend):
    """Every recorded segment has a unit direction, t1 > t0 >= 0, both ends inside the
    medium box (packed frame), and the kind it was filed under."""
    rec = _recording(backend)
    m = rec.medium[0]
    lo, hi = np.array(m["bmin"]), np.array(m["bmax"])
    tol = 1e-5 * float(np.max(hi - lo))
    assert len(rec.camera) > 0 and len(rec.shadow) > 0
    for seg, kind in ((rec.camera, RECORD_CAMERA), (rec.shadow, RECORD_SHADOW)):
        o, d, t0, t1 = seg[:, :3], seg[:, 3:6], seg[:, 6], seg[:, 7]
        assert np.all(seg[:, 8] == kind)
        assert np.allclose(np.linalg.norm(d, axis=1), 1.0, atol=1e-5)
        assert np.all(t1 > t0) and np.all(t0 >= 0.0)
        for t in (t0, t1):
            p = o + t[:, None] * d
            assert np.all(p >= lo - tol) and np.all(p <= hi + tol)
    assert rec.full == 0 and rec.counts.sum() == len(rec.camera) + len(rec.shadow)


def test_recording_leaves_the_image_unchanged(backend):
    """Recording draws no random number and changes no arithmetic: the same seed and spp give
    the same image, bit for bit, with and without it (OpenCL: two builds)."""
    scene = _cloud(12, 2)
    a = render(scene, backend=make_backend(backend, scene), progress=False)
    be = make_backend(backend, scene, record=K)
    b = render(scene, backend=be, progress=False)
    assert np.array_equal(a.film.sum, b.film.sum)
    assert np.array_equal(a.film.sum_sq, b.film.sum_sq)
    assert be.segment_record()[:, 0, 0].sum() > 0
    assert make_backend(backend, scene).segment_record() is None


def test_shadow_segments_point_at_the_only_light(backend):
    """One directional light, one scattering event: every shadow segment runs towards the
    light, d = -direction."""
    direction = np.array([0.8, -0.5, -0.3]) / math.sqrt(0.98)
    scene = _cloud(12, 2, max_depth=1, lights=[
        {"type": "directional", "direction": direction.tolist(), "irradiance": 3.0}])
    rec = record_segments(scene, backend, spp=2, per_pixel=K)
    assert len(rec.shadow) > 20
    assert np.allclose(rec.shadow[:, 3:6], -direction, atol=1e-6)
    assert rec.counts[:, 1].max() <= 2   # one shadow ray per sample at most


def test_camera_segments_are_the_camera_rays(backend):
    """The camera segment of each sample lies on its camera ray: the eye (perspective) is on
    the segment's line, behind its start; a pixel records one per sample whose ray meets the
    box, none for the others."""
    scene = _cloud(16, 3)
    rec = record_segments(scene, backend, spp=3, per_pixel=3 * 9 + 1)   # never full
    assert rec.full == 0
    from volmc.pack import pack_scene
    prm = pack_scene(scene).params[0]   # the camera: the packed eye less near forward
    eye = np.array(prm["eye"]) - prm["near"] * np.array(prm["forward"])
    v = rec.camera[:, :3] - eye
    along = np.einsum("ij,ij->i", v, rec.camera[:, 3:6])
    off = np.linalg.norm(v - along[:, None] * rec.camera[:, 3:6], axis=1)
    assert np.all(along > 0) and np.all(off < 1e-5 * np.maximum(along, 1.0))
    assert set(np.unique(rec.counts[:, 0])) <= {0, 1, 2, 3}
    # The central pixels see the box on every sample.
    assert np.all(rec.counts.reshape(16, 16, 2)[6:10, 6:10, 0] == 3)


def test_backends_record_the_same_segments():
    """Camera segments are the same rays on both backends (the same random numbers place
    them), so each pixel records the same number and the same segments up to float32
    rounding. Shadow segments follow paths that part after a few bounces: the mean count per
    pixel and the mean length t1 - t0 agree by two-sample z-tests (2 hypotheses, Sidak at
    ALPHA)."""
    a, b = _recording("opencl"), _recording("numba")
    same = a.counts[:, 0] == b.counts[:, 0]
    assert same.mean() > 0.99
    ca = a.camera[np.repeat(same, a.counts[:, 0])]
    cb = b.camera[np.repeat(same, b.counts[:, 0])]
    assert np.allclose(ca[:, :8], cb[:, :8], atol=2e-4)
    bound = z_bound(ALPHA, 2)
    for xa, xb in ((a.counts[:, 1].astype(float), b.counts[:, 1].astype(float)),
                   (a.shadow[:, 7] - a.shadow[:, 6], b.shadow[:, 7] - b.shadow[:, 6])):
        z = (xa.mean() - xb.mean()) / math.sqrt(xa.var(ddof=1) / xa.size
                                                + xb.var(ddof=1) / xb.size)
        assert abs(z) < bound, z


@pytest.mark.parametrize("name", ["ratio", "track_length", "residual_ratio", "power_series",
                                  "telescoping"])
def test_replay_on_the_grid_majorant_kernel_equals_reference(name):
    """Recorded segments replayed on the scene's majorant grid (maj, mnr kept, not the global
    bounds): kernel and reference agree per estimate for almost every estimate (float32
    against float64 can flip a decision near a threshold), and both stay within the Sidak
    bound of the exact transmittance."""
    from volmc.bench.transmittance_runner import OpenCLEstimator, run_numba
    from volmc.reference.optical_depth import optical_depth_exact
    rec = _recording("opencl")
    m = rec.medium[0]
    assert int(m["majorant_kind"]) == MAJORANT_GRID and rec.maj.size > 1
    rays = np.concatenate([rec.camera[:40], rec.shadow[:40]])
    rays = rays.astype(np.float32).astype(np.float64)
    n = 64
    kw = dict(maj=rec.maj, mnr=rec.mnr, nodes=rec.nodes)
    a, ca = OpenCLEstimator(name).run(rec.medium, rec.grid, rays, None, n, 9, **kw)
    b, cb = run_numba(name, rec.medium, rec.grid, rays, None, n, 9, **kw)
    assert np.mean(np.abs(a - b) < 1e-3) > 0.98
    for c in (ca, cb):   # no lookup above the majorant, no walk capped
        assert c[:, C_OVER_MAJORANT].sum() == 0 and c[:, C_CAPPED].sum() == 0
    lo, hi = tuple(m["bmin"]), tuple(m["bmax"])
    exact = np.array([math.exp(-optical_depth_exact(rec.grid, lo, hi, float(m["scale"]),
                                                    tuple(r[:3]), tuple(r[3:6]), r[6], r[7]))
                      for r in rays])
    bound = z_bound(ALPHA, 2)
    for est in (a, b):
        err = est.reshape(len(rays), n) - exact[:, None]
        se = err.std(ddof=1) / math.sqrt(err.size)
        assert abs(err.mean()) < bound * se + 1e-6, (err.mean(), se)
