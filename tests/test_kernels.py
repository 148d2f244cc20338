"""Kernel-vs-reference, function level: the OpenCL twins fed the same inputs as the Numba
functions agree within float32 tolerance, including the docs/robustness.md inputs."""

import math

import numpy as np
import pytest

import cl_harness
from cl_harness import f3, i3, out_buf, run, to_dev
from stats import ALPHA, z_bound
from volmc.reference.grid import grid_lookup
from volmc.reference.phase import hg_eval, hg_sample, hg_sample_cos
from volmc.reference.rng import philox4x32_10, rng_new, rng_next, uniforms
from volmc.reference.sampling import (coordinate_system, sample_exponential,
                                      sample_uniform_sphere)
from tracking_runs import grid_media, walks
from volmc.constants import TRACK_FREE_FLIGHT, TRACK_LENGTH, TRACK_RATIO

#: Every test here runs at every lane width (tests/conftest.py, ``lanes``).
pytestmark = pytest.mark.usefixtures("lanes")

EDGE_U = np.array([0.0, 2.0**-24, 0.25, 0.5, 0.75, 1 - 2.0**-24], np.float64)


def test_philox_identical():
    rng = np.random.default_rng(0)
    ctr = rng.integers(0, 2**32, size=(4096, 4), dtype=np.uint32)
    key = rng.integers(0, 2**32, size=(4096, 2), dtype=np.uint32)
    ctr[0] = 0
    key[0] = 0
    ctr[1] = 0xFFFFFFFF
    key[1] = 0xFFFFFFFF
    out, ob = out_buf((4096, 4), np.uint32)
    run("t_philox", 4096, to_dev(ctr), to_dev(key), ob, outs=[(out, ob)])
    ref = np.array([philox4x32_10(*c, *k) for c, k in zip(ctr, key)], np.uint64)
    assert np.array_equal(out.astype(np.uint64), ref)


@pytest.mark.parametrize("seed,pixel,sample,stream", [(0, 0, 0, 0), (2**40 + 3, 77, 5, 1),
                                                      (2**64 - 1, 2**32 - 1, 2**32 - 1, 2)])
def test_uniform_streams_identical(seed, pixel, sample, stream):
    """Each lane draws its own stream (pixel + lane), bit for bit the reference's."""
    n, lanes = 1001, cl_harness.LANES
    out, ob = out_buf((lanes, n))
    run("t_uniforms", lanes, np.uint64(seed), np.uint32(pixel), np.uint32(sample),
        np.uint32(stream), np.uint32(n), ob, outs=[(out, ob)])
    for lane in range(lanes):
        ref = uniforms(np.uint64(seed), (pixel + lane) % 2**32, sample, stream, n)
        assert np.array_equal(out[lane].astype(np.float64), ref)   # bit-identical
    assert out.max() < 1.0


def test_ragged_draws_identical():
    """Lanes that draw at different times, from two streams they exchange and restart, each
    draw their own streams bit for bit (the prefetch of kernels/rng.h at W > 1)."""
    seed, pixel, sample, count = 2**33 + 9, 40, 3, 300
    n = 3 * cl_harness.LANES
    plan = np.random.default_rng(5).choice(5, size=(n, count), p=[0.4, 0.3, 0.2, 0.05, 0.05])
    plan = plan.astype(np.uint32)
    out, ob = out_buf((n, count))
    run("t_uniforms_ragged", n, np.uint64(seed), np.uint32(pixel), np.uint32(sample),
        np.uint32(count), to_dev(plan), ob, outs=[(out, ob)])
    for e in range(n):
        a, b = (rng_new(seed, pixel + e, sample, s) for s in (0, 1))
        ref = np.full(count, -1.0)
        for k, op in enumerate(plan[e]):
            if op == 3:
                a, b = b, a
            if op == 4:
                a = rng_new(seed, pixel + e, sample + 1, 0)
            if op in (1, 3, 4):
                ref[k] = rng_next(a)
            elif op == 2:
                ref[k] = rng_next(b)
        assert np.array_equal(out[e].astype(np.float64), ref), e


def test_exponential():
    u = np.concatenate([EDGE_U, uniforms(1, 0, 0, 2, 2000)]).astype(np.float32)
    for a in (1e-3, 0.7, 50.0):
        out, ob = out_buf((u.size, 2))
        run("t_exponential", u.size, to_dev(u), np.float32(a), ob, outs=[(out, ob)])
        ref = np.array([sample_exponential(float(x), a) for x in u])
        assert np.all(np.isfinite(out))
        assert np.allclose(out, ref, rtol=2e-6, atol=1e-30)


def test_exponential_without_collision():
    """a <= 0: no collision. The kernel returns NO_LIMIT (FLT_MAX; INFINITY is undefined
    under -cl-fast-relaxed-math), the reference math.inf, both with pdf 0: the pairing
    volmc/constants.py documents."""
    u = np.array([0.0, 0.3, 0.999], np.float32)
    for a in (0.0, -1.0):
        out, ob = out_buf((u.size, 2))
        run("t_exponential", u.size, to_dev(u), np.float32(a), ob, outs=[(out, ob)])
        assert np.all(out[:, 0] == np.finfo(np.float32).max) and np.all(out[:, 1] == 0.0)
        assert all(sample_exponential(float(x), a) == (math.inf, 0.0) for x in u)


def test_uniform_sphere():
    u = np.array([[a, b] for a in EDGE_U for b in EDGE_U] +
                 list(uniforms(2, 0, 0, 2, 4000).reshape(-1, 2)), np.float32)
    out, ob = out_buf((len(u), 4))
    run("t_uniform_sphere", len(u), to_dev(u.ravel()), ob, outs=[(out, ob)])
    ref = np.array([(*sample_uniform_sphere(float(a), float(b))[0],
                     sample_uniform_sphere(float(a), float(b))[1]) for a, b in u])
    assert np.allclose(out, ref, atol=2e-6)


HARD_G = [0.0, 1e-6, -1e-6, 1e-4, -1e-4, 1e-3, -1e-3, 0.3, -0.3, 0.6, -0.6, 0.9, -0.9, 0.99,
          -0.99, 0.999, -0.999, 0.9999, -0.9999, 1 - 2.0**-24, -(1 - 2.0**-24)]


def test_hg_sample_cos_hard_cases():
    """robustness case 1-2: cos in [-1, 1], finite pdf, agreement with the float64 twin."""
    gs, us = np.meshgrid(np.array(HARD_G, np.float32), EDGE_U.astype(np.float32))
    gs, us = gs.ravel(), us.ravel()
    out, ob = out_buf((gs.size, 3))
    run("t_hg_sample_cos", gs.size, to_dev(us), to_dev(gs), ob, outs=[(out, ob)])
    c, s, pdf = out.T
    assert np.all(np.abs(c) <= 1.0) and np.all((s >= 0) & (s <= 1))
    assert np.all(np.isfinite(pdf)) and np.all(pdf > 0)
    for i, (g, u) in enumerate(zip(gs, us)):
        rc, rs, rp = hg_sample_cos(float(u), float(g))
        # 1 - cos is what the float32 code resolves; compare cos absolutely and the pdf relatively.
        assert abs(c[i] - rc) <= 4e-7 + 1e-6 * abs(1 - abs(rc)), (g, u)
        assert abs(s[i] - rs) <= 2e-3 * max(rs, 1e-3) + 1e-6, (g, u)
        assert math.isclose(pdf[i], rp, rel_tol=1e-4), (g, u, pdf[i], rp)


def test_hg_sample_directions():
    d_in = np.array([0.36, -0.48, 0.8])
    u = uniforms(3, 0, 0, 2, 4000).reshape(-1, 2).astype(np.float32)
    g = np.repeat(np.array([-0.9, -0.2, 0.0, 0.5, 0.95], np.float32), len(u) // 5 + 1)[:len(u)]
    out, ob = out_buf((len(u), 5))
    run("t_hg_sample", len(u), to_dev(u.ravel()), to_dev(g), f3(d_in), ob, outs=[(out, ob)])
    assert np.allclose(out[:, 4], out[:, 3], rtol=1e-4)   # phase_eval at the sample: its pdf
    for i in range(len(u)):
        w, pdf = hg_sample(float(u[i, 0]), float(u[i, 1]), tuple(d_in.astype(np.float32)
                                                                 .astype(float)), float(g[i]))
        assert np.allclose(out[i, :3], w, atol=3e-6)
        assert math.isclose(out[i, 3], pdf, rel_tol=1e-4)
    assert np.allclose(np.linalg.norm(out[:, :3], axis=1), 1.0, atol=1e-6)


@pytest.mark.parametrize("g", [0.999999, -0.999999, 1 - 2.0**-24])
def test_phase_eval_near_the_peak(g):
    """Found by an outside test: at g = 0.999999 the kernels evaluated HG from a float32
    cosine, whose 1 - cos moves in steps of 6e-8 while it is 5e-7 at 1e-3 rad, and
    next-event estimates towards a sun with 4 light samples came out 0.22 % bright (z = 10).
    From the chord of the two float32 directions (phase_eval), at angles from 1e-4 to 0.1
    rad around the peak (forward for g > 0, backward for g < 0), the kernel's value is HG
    at their exact angle to 1e-3, as is the float64 twin's to 1e-9. (Angles much below
    1e-5 rad are beyond what float32 directions hold.)"""
    from volmc.reference.phase import phase_eval
    from volmc.constants import PHASE_HG
    d = np.array([0.36, -0.48, 0.8])
    s = np.array([0.8, 0.6, 0.0])   # unit, orthogonal to d
    theta = np.geomspace(1e-4, 0.1, 200)
    axis = d if g > 0 else -d
    w = np.cos(theta)[:, None] * axis + np.sin(theta)[:, None] * s
    d32 = np.repeat(d[None].astype(np.float32), len(w), 0)
    w32 = w.astype(np.float32)
    out, ob = out_buf(len(w))
    run("t_phase_eval", len(w), to_dev(d32.ravel()), to_dev(w32.ravel()), np.float32(g), ob,
        outs=[(out, ob)])
    g32 = float(np.float32(g))
    # HG at the float32 vectors' exact angle (float64 chord of the normalised vectors)
    a, b = d32.astype(np.float64), w32.astype(np.float64)
    a /= np.linalg.norm(a, axis=1, keepdims=True)
    b /= np.linalg.norm(b, axis=1, keepdims=True)
    side = 0.5 * np.sum((b - a if g > 0 else b + a) ** 2, axis=1)
    denom = (1 - abs(g32)) ** 2 + 2 * abs(g32) * side
    exact = (1 - g32) * (1 + g32) / (4 * math.pi * denom ** 1.5)
    assert np.allclose(out, exact, rtol=1e-3)
    ref = np.array([phase_eval(PHASE_HG, g32, tuple(x), tuple(y)) for x, y in zip(a, b)])
    assert np.allclose(ref, exact, rtol=1e-9)


def test_hg_eval():
    mu = np.linspace(-1, 1, 401).astype(np.float32)
    for g in (-0.99, -0.5, 0.0, 1e-5, 0.5, 0.99):
        gg = np.full_like(mu, g)
        out, ob = out_buf(mu.size)
        run("t_hg_eval", mu.size, to_dev(mu), to_dev(gg), ob, outs=[(out, ob)])
        ref = np.array([hg_eval(float(m), float(np.float32(g))) for m in mu])
        assert np.allclose(out, ref, rtol=2e-5)


def test_coordinate_system():
    ns = np.array([[0, 0, 1], [0, 0, -1], [-0.0, 0, -1], [1, 0, 0], [0.36, -0.48, 0.8],
                   [0, 1, -0.0]], np.float32)
    out, ob = out_buf((len(ns), 2, 3))
    run("t_coordinate_system", len(ns), to_dev(ns.ravel()), ob, outs=[(out, ob)])
    for i, n in enumerate(ns):
        s, t = coordinate_system(tuple(float(x) for x in n))
        assert np.allclose(out[i, 0], s, atol=1e-6) and np.allclose(out[i, 1], t, atol=1e-6)


BMIN = (-1.0, -0.5, -2.0)
BMAX = (1.0, 1.5, 0.0)
INV_EXT = tuple(1.0 / (b - a) for a, b in zip(BMIN, BMAX))


def test_grid_lookup_including_faces():
    rng = np.random.default_rng(4)
    grid = rng.random((5, 6, 7)).astype(np.float32)
    pts = np.array(BMIN) + rng.random((5000, 3)) * (np.array(BMAX) - np.array(BMIN))
    # Faces, corners, voxel centres and half-voxel clamp zones.
    pts[:8] = [[BMIN[0], BMIN[1], BMIN[2]], [BMAX[0], BMAX[1], BMAX[2]],
               [BMIN[0], 0.5, -1.0], [BMAX[0], 0.5, -1.0], [0.0, BMIN[1], -1.0],
               [0.0, 0.5, BMAX[2]], [BMIN[0] + 1 / 7, 0.5, -1.0], [BMIN[0] + 0.5 / 7 * 2, 0, -1]]
    pts = pts.astype(np.float32)
    out, ob = out_buf(len(pts))
    run("t_grid_lookup", len(pts), to_dev(grid), i3((7, 6, 5)), f3(BMIN), f3(INV_EXT),
        to_dev(pts.ravel()), ob, outs=[(out, ob)])
    g64 = grid.astype(np.float64)
    inv32 = tuple(float(np.float32(x)) for x in INV_EXT)
    ref = np.array([grid_lookup(g64, BMIN, inv32, tuple(float(x) for x in p)) for p in pts])
    assert np.allclose(out, ref, rtol=1e-5, atol=1e-6)


def test_to_medium_maps_points_and_directions():
    """The scene frame to a placed medium's space (a turn, a mirror, a shear, a scale and a
    translation): the kernels, the reference and the packed 3x4 matrix agree, and the
    reference's map inverts the scene's transform (through the frames pack.medium_space
    composes)."""
    from volmc.pack import pack_scene, scene_frame
    from volmc.scene.transform import box_frame
    from volmc.reference.medium import to_medium, to_medium_dir
    from volmc.scene import scene_from_dict
    t = {"matrix": [[0.8, 0.3, 0.1, 2.0], [-0.2, 0.0, 1.1, -1.0], [0.4, -0.9, 0.2, 0.5],
                    [0, 0, 0, 1]]}
    box = [[-1.0, 0.0, 2.0], [3.0, 1.0, 2.5]]
    sc = scene_from_dict({"camera": {}, "medium": {"bounds": box, "density": 1.0,
                                                   "transform": t}})
    m64 = pack_scene(sc, np.float64).medium
    m32 = pack_scene(sc, np.float32).medium
    assert m64[0]["transformed"] == 1
    rng = np.random.default_rng(9)
    pd = rng.normal(size=(3000, 6)).astype(np.float32)
    out, ob = out_buf(pd.shape)
    run("t_to_medium", len(pd), to_dev(m32), to_dev(pd.ravel()), ob, outs=[(out, ob)])
    out = out.reshape(pd.shape)
    x = np.asarray(m64[0]["xform"]).reshape(3, 4)
    ref = np.array([to_medium(m64[0], tuple(map(float, r[:3]))) +
                    to_medium_dir(m64[0], tuple(map(float, r[3:]))) for r in pd])
    assert np.allclose(ref[:, :3], pd[:, :3] @ x[:, :3].T + x[:, 3], rtol=1e-12, atol=1e-12)
    assert np.allclose(ref[:, 3:], pd[:, 3:] @ x[:, :3].T, rtol=1e-12, atol=1e-12)
    assert np.allclose(out, ref, rtol=1e-5, atol=1e-5)
    # A world point: the scene frame's, then the medium's packed space, equals the inverse
    # of the transform followed by the box's own frame.
    centre, unit = scene_frame(sc)
    c_l, u_l = box_frame(*box)
    w = rng.normal(size=3) * 2.0
    local = np.linalg.solve(np.array(t["matrix"])[:3, :3], w - np.array(t["matrix"])[:3, 3])
    got = to_medium(m64[0], tuple((w - centre) / unit))
    assert np.allclose(got, (local - c_l) / u_l, rtol=1e-12, atol=1e-12)


def _rays(n, seed):
    rng = np.random.default_rng(seed)
    rays = np.zeros((n, 9))
    lo, hi = np.array(BMIN), np.array(BMAX)
    for r in range(n):
        o = lo + rng.random(3) * (hi - lo)
        d = rng.normal(size=3)
        d /= np.linalg.norm(d)
        with np.errstate(divide="ignore"):
            t1 = np.min(np.maximum((lo - o) / d, (hi - o) / d))
        rays[r, :3], rays[r, 3:6], rays[r, 6], rays[r, 7] = o, d, 0.0, t1
    return rays.astype(np.float32).astype(np.float64)


@pytest.mark.parametrize("kind", [TRACK_RATIO, TRACK_LENGTH, TRACK_FREE_FLIGHT],
                         ids=["ratio", "track_length", "free_flight"])
def test_tracking_per_ray_and_in_mean(kind):
    """Same rays, same streams: the estimates agree per estimate for the vast majority (float32
    rounding can flip a rare accept test), and the means agree statistically."""
    rng = np.random.default_rng(6)
    grid = (rng.random((5, 6, 7)) ** 2).astype(np.float32)
    scale = 3.0
    mbar = float(np.float32(scale * grid.max() * 1.3))
    rays = _rays(16, 7)
    n_per = 4000
    media = grid_media(BMIN, BMAX, scale, grid, len(rays), sigma_maj=mbar)
    runs = {b: walks(b, kind, False, media, grid, rays, n_per, 11) for b in ("opencl", "numba")}
    pick = 0 if kind == TRACK_FREE_FLIGHT else 1
    out, lk = runs["opencl"][pick], runs["opencl"][2]
    ref, ref_lk = runs["numba"][pick], runs["numba"][2]
    close = np.isclose(out, ref, rtol=1e-3, atol=1e-5) & (lk == ref_lk)
    assert close.mean() > 0.995, close.mean()
    bound = z_bound(ALPHA, len(rays))
    for r in range(len(rays)):
        a = out[r * n_per:(r + 1) * n_per].astype(np.float64)
        b = ref[r * n_per:(r + 1) * n_per]
        if kind == TRACK_FREE_FLIGHT:  # compare the probability of a collision
            a, b = (a >= 0).astype(float), (b >= 0).astype(float)
        se = math.sqrt(a.var(ddof=1) / n_per + b.var(ddof=1) / n_per)
        if se > 0:
            assert abs(a.mean() - b.mean()) < bound * se
