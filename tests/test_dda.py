"""3-D DDA over majorant cells against a brute-force walk, including degenerate rays
(robustness case 6): axis-parallel, -0.0 components, starting on box and cell faces, inside."""

import math

import numpy as np
import pytest

from tracking_runs import grid_media, walks
from volmc.constants import TRACK_FREE_FLIGHT
from volmc.reference.dda import dda_segments
from volmc.reference.majorant import cell_of


BMIN = np.array([-1.0, -0.5, 0.0])
BMAX = np.array([1.0, 1.5, 3.0])
RES = (6, 4, 5)   # (cz, cy, cx)


def clip(o, d, bmin=BMIN, bmax=BMAX):
    """[t0, t1] of the ray inside the box (t >= 0), or None. Zero components (+-0.0) never
    cross their slabs; a ray lying in a face plane counts as inside."""
    t0, t1 = -math.inf, math.inf
    for a in range(3):
        if d[a] == 0.0:
            if not bmin[a] <= o[a] <= bmax[a]:
                return None
            continue
        ta, tb = (bmin[a] - o[a]) / d[a], (bmax[a] - o[a]) / d[a]
        t0, t1 = max(t0, min(ta, tb)), min(t1, max(ta, tb))
    t0 = max(t0, 0.0)
    return (t0, t1) if t1 > t0 else None



def _flights(grid, maj, mnr, scale, o, d, t0, t1, n, decomposition, key, pixel=0):
    """n free flights (reference, over majorant cells maj/mnr) along one ray in the BMIN-BMAX
    box with random numbers (key, ray 0, i): (collision distances, inf on escape; lookups)."""
    media = grid_media(BMIN, BMAX, scale, grid, 1, maj_res=maj.shape)
    t, _, lk = walks("numba", TRACK_FREE_FLIGHT, decomposition, media, grid,
                     [[*o, *d, t0, t1, 0.0]], n, key, maj=maj, mnr=mnr)
    return np.where(t >= 0.0, t, np.inf), int(lk.sum())


def _distance_fit_pvalue(grid, scale, o, d, t0, t1, t):
    """Chi-square p-value of collision distances t (inf = escape) against the exact
    distribution 1 - T(t) along the ray, in 24 equal bins plus escape."""
    from stats import chi2_pvalue
    from volmc.reference.optical_depth import optical_depth_exact
    edges = np.linspace(t0, t1, 25)
    cdf = np.array([1 - math.exp(-optical_depth_exact(grid, tuple(BMIN), tuple(BMAX), scale,
                                                      tuple(o), tuple(d), t0, e))
                    for e in edges])
    expected = np.append(np.diff(cdf), 1 - cdf[-1]) * len(t)
    observed = np.append(np.histogram(t[np.isfinite(t)], bins=edges)[0],
                         np.sum(~np.isfinite(t)))
    return chi2_pvalue(observed, expected)[0]

def check_ray(o, d):
    seg = clip(o, d)
    if seg is None:
        return 0
    t0, t1 = seg
    out = np.zeros((64, 5))
    n = dda_segments(tuple(o), tuple(d), t0, t1, tuple(BMIN), tuple(BMAX), RES, out)
    s = out[:n]
    assert n >= 1 and n <= sum(RES) + 1
    # Tiling: contiguous, from t0 to t1, non-decreasing.
    assert s[0, 0] == t0 and s[-1, 1] == t1
    assert np.all(s[1:, 0] == s[:-1, 1]) and np.all(s[:, 1] >= s[:, 0])
    # Brute force: fine samples along the ray must fall in the cell of their segment.
    ts = np.linspace(t0, t1, 4001)[1:-1]
    pts = np.asarray(o) + ts[:, None] * np.asarray(d)
    iz, iy, ix = cell_of(pts, BMIN, BMAX, RES)
    k = np.clip(np.searchsorted(s[:, 1], ts, side="left"), 0, n - 1)
    size = (BMAX - BMIN) / np.array([RES[2], RES[1], RES[0]])
    rel = (pts - BMIN) / size
    near_face = np.any(np.abs(rel - np.round(rel)) < 1e-7, axis=1)
    ok = (s[k, 2] == iz) & (s[k, 3] == iy) & (s[k, 4] == ix)
    assert np.all(ok | near_face), np.flatnonzero(~(ok | near_face))[:5]
    # Every cell the brute force sees is visited, and no cell twice.
    cells = {tuple(c) for c in np.stack([iz, iy, ix], 1)[~near_face]}
    walked = [tuple(int(v) for v in c) for c in s[s[:, 1] > s[:, 0]][:, 2:5]]
    assert cells <= set(walked)
    assert len(walked) == len(set(walked))
    return n


def test_random_rays_from_outside_and_inside():
    rng = np.random.default_rng(0)
    hits = 0
    for _ in range(300):
        d = rng.normal(size=3)
        d /= np.linalg.norm(d)
        inside = rng.random() < 0.5
        o = BMIN + rng.random(3) * (BMAX - BMIN) if inside else \
            (BMIN + BMAX) / 2 - 4 * d + rng.normal(size=3) * 0.5
        hits += check_ray(o, d) > 0
    assert hits > 200


@pytest.mark.parametrize("o,d", [
    ((-3.0, 0.3, 1.2), (1.0, 0.0, 0.0)),             # axis-parallel
    ((0.1, 0.2, -2.0), (-0.0, 0.0, 1.0)),            # -0.0 components
    ((0.1, 3.0, 0.7), (0.0, -1.0, -0.0)),
    ((-1.0, 0.2, 1.1), (0.6, 0.0, 0.8)),              # starts on a box face
    ((-0.2, 0.5, 1.5), (0.0, 0.0, 1.0)),              # starts on internal cell faces, x = -0.2
    ((-3.0, 0.5, 1.5), (1.0, 0.0, 0.0)),              # runs exactly along cell faces (y, z)
    ((1.0, 1.5, 3.0), (-0.5, -0.5, -0.70710678)),    # starts on a box corner
    ((0.2, 0.3, 2.999999999), (0.0, 0.0, 1.0)),       # tiny segment before the face
])
def test_degenerate_rays(o, d):
    d = np.array(d, float)
    d /= np.linalg.norm(d) if np.linalg.norm(d) > 0 else 1.0
    assert check_ray(np.array(o, float), d) >= 1


def test_free_flight_over_majorant_grid_distribution():
    """Delta tracking over a majorant grid: collision distances pass a chi-square test against
    the exact CDF 1 - T(t) along fixed rays, for several majorant resolutions (including a
    grid with empty cells), and it needs fewer lookups than the global majorant."""
    from stats import ALPHA, sidak
    from volmc.reference.majorant import build_majorant_grid

    rng = np.random.default_rng(4)
    grid = rng.random((12, 10, 8)) ** 4
    grid[:, :, :3] = 0.0          # an empty slab: cells with zero majorant
    scale = 1.5
    cases = [(res, ray) for res in ((1, 1, 1), (3, 5, 2), (12, 10, 8)) for ray in range(2)]
    a = sidak(ALPHA, len(cases))
    lookups = {}
    for res, k in cases:
        maj, mnr = build_majorant_grid(grid, res)
        d = np.array([0.8, 0.3, 0.5]) if k == 0 else np.array([-0.0, 0.6, 0.8])
        d /= np.linalg.norm(d)
        o = np.array([-0.95, -0.4, 0.1]) if k == 0 else np.array([0.3, -0.45, 0.05])
        t0, t1 = clip(o, d)
        n = 60000
        t, lk = _flights(grid, maj, mnr, scale, o, d, t0, t1, n, False, 7, 3)
        p = _distance_fit_pvalue(grid, scale, o, d, t0, t1, t)
        assert p > a, (res, k, p)
        lookups[(res, k)] = lk
    for k in range(2):
        assert lookups[((12, 10, 8), k)] < lookups[((1, 1, 1), k)]


def test_kernel_dda_matches_reference(lanes):
    """The OpenCL twin visits the same cells with the same segment ends (float32) for random
    and degenerate rays."""
    from cl_harness import f3, i3, out_buf, run, to_dev
    rng = np.random.default_rng(8)
    rays = []
    dirs = [np.array([1.0, 0.0, 0.0]), np.array([-0.0, 0.6, 0.8]), np.array([0.0, -1.0, -0.0])]
    for k in range(200):
        d = dirs[k] if k < len(dirs) else rng.normal(size=3)
        d = d / np.linalg.norm(d)
        o = BMIN + rng.random(3) * (BMAX - BMIN)
        if k == 0:
            o = np.array([-1.0, 0.5, 1.5])   # on a box face and on cell faces
        seg = clip(o, d)
        rays.append([*o, *d, seg[0], seg[1], 0.0])
    rays = np.array(rays).astype(np.float32)
    m = 32
    out, ob = out_buf((len(rays), m, 5))
    cnt, cb = out_buf(len(rays), np.int32)
    run("t_dda", len(rays), to_dev(rays.ravel()), f3(BMIN), f3(BMAX), i3(RES), np.int32(m), ob,
        cb, outs=[(out, ob), (cnt, cb)])
    agree = 0
    for r, ray in enumerate(rays.astype(np.float64)):
        ref = np.zeros((m, 5))
        n = dda_segments(tuple(ray[:3]), tuple(ray[3:6]), ray[6], ray[7], tuple(BMIN),
                         tuple(BMAX), RES, ref)
        a = out[r, :cnt[r]]
        a, b = a[a[:, 1] - a[:, 0] > 1e-5], ref[:n][ref[:n, 1] - ref[:n, 0] > 1e-5]
        if len(a) == len(b) and np.array_equal(a[:, 2:], b[:, 2:]) and \
                np.allclose(a[:, :2], b[:, :2], atol=1e-5):
            agree += 1
    assert agree >= len(rays) - 2, agree   # float32 may split a corner crossing differently


def test_decomposition_tracking_distribution():
    """Decomposition tracking over a majorant grid: collision distances pass the chi-square
    test against 1 - T(t), and the per-cell minorants save lookups on a dense grid."""
    from stats import ALPHA, sidak
    from volmc.reference.majorant import build_majorant_grid

    grid = 0.5 + 0.5 * np.random.default_rng(5).random((12, 10, 8))   # dense: minorants > 0
    scale = 0.6
    a = sidak(ALPHA, 2)
    for res in ((3, 5, 2), (12, 10, 8)):
        maj, mnr = build_majorant_grid(grid, res)
        o, d = np.array([-0.9, -0.4, 0.1]), np.array([0.8, 0.3, 0.5])
        d /= np.linalg.norm(d)
        t0, t1 = clip(o, d)
        n = 60000
        t, lk = _flights(grid, maj, mnr, scale, o, d, t0, t1, n, True, 9, 1)
        t_delta, lk_delta = _flights(grid, maj, mnr, scale, o, d, t0, t1, n, False, 9, 1)
        assert np.array_equal(t, t_delta)          # same decisions for the same numbers
        assert lk < 0.7 * lk_delta                 # the control saves lookups
        assert _distance_fit_pvalue(grid, scale, o, d, t0, t1, t) > a


def test_kernel_tracking_over_a_non_cubic_majorant_grid_matches_reference():
    """Ratio tracking over a majorant grid with a different number of cells on each axis,
    (cz, cy, cx) = (4, 5, 6): the OpenCL walk (t_track, which looks each DDA cell's
    majorant up by dda_cell_index) and the Numba twin, on the same rays and random streams,
    count the same lookups and give the same estimate per walk (float32 may flip a rare
    accept test). A flat index with the wrong row stride reads other cells' majorants: a
    cubic grid cannot tell, as every stride is the same there. Deterministic."""
    from volmc.constants import TRACK_RATIO
    from volmc.reference.majorant import build_majorant_grid

    rng = np.random.default_rng(12)
    z, y, x = np.indices((8, 10, 12))        # (nz, ny, nx): a ramp, so that every cell
    grid = (1 + x + 12 * y + 120 * z) / 960.0 * (0.5 + 0.5 * rng.random(z.shape))
    grid[:, :, :2] = 0.0                     # has its own majorant, and some cells are empty
    res = (4, 5, 6)                          # (cz, cy, cx)
    maj, mnr = build_majorant_grid(grid, res)
    assert len(set(maj.shape)) == 3 and np.unique(maj).size > maj.size // 2
    rays = []
    for _ in range(24):
        d = rng.normal(size=3)
        d /= np.linalg.norm(d)
        o = BMIN + rng.random(3) * (BMAX - BMIN)
        t0, t1 = clip(o, d)
        rays.append([*o, *d, t0, t1, 0.0])
    rays = np.array(rays).astype(np.float32).astype(np.float64)
    n_per = 256
    media = grid_media(BMIN, BMAX, 6.0, grid, len(rays), maj_res=res)
    out = {b: walks(b, TRACK_RATIO, False, media, grid, rays, n_per, 13, maj=maj, mnr=mnr)
           for b in ("opencl", "numba")}
    (_, T_cl, lk_cl), (_, T_nb, lk_nb) = out["opencl"], out["numba"]
    assert lk_nb.mean() > 2.0                 # the walks do visit several cells
    same = (lk_cl == lk_nb) & np.isclose(T_cl, T_nb, rtol=1e-3, atol=1e-5)
    assert same.mean() > 0.995, same.mean()
