"""robustness case 6, 8 and 9: degenerate rays through majorant grids, empty and single-voxel
grids, and grid files holding NaN, infinities or negative values.

Function-level checks run the OpenCL twins through kernels/testing.cl (t_dda, t_track;
float32) and the Numba reference functions (float64) on the same rays
and Philox streams. Image-level checks render tiny scenes on both backends.
"""

import math
import os
import subprocess
import sys

import numpy as np
import pytest

from cl_harness import f3, i3, out_buf, run, to_dev
from stats import ALPHA, chi2_pvalue, sidak, z_bound
from test_dda import clip as dda_clip
from tracking_runs import grid_media, walks
from volmc.bench.transmittance_runner import OpenCLEstimator, run_numba
from volmc.constants import TRACK_FREE_FLIGHT, TRACK_RATIO
from volmc.params import C_LOOKUPS
from volmc.reference.dda import dda_segments
from volmc.reference.majorant import build_majorant_grid, cell_of
from volmc.reference.optical_depth import optical_depth_exact
from volmc.techniques import ESTIMATORS
from volmc.render import render
from volmc.scene import SceneError, load_scene, scene_from_dict
from volmc.scene.grids import write_vol
from volmc.scene.serialize import dict_to_toml
from volmc.backends import BACKENDS

BMIN = np.array([-1.0, -1.0, -1.0])
BMAX = np.array([1.0, 1.0, 1.0])
INV_EXT = 1.0 / (BMAX - BMIN)
MAX_STEPS = 1_000_000


def clip(o, d):
    """[t0, t1] of the ray inside this file's box (t >= 0), or None (test_dda's clip)."""
    return dda_clip(o, d, BMIN, BMAX)


def ray_rows(rays):
    """[n, 9] float64 rows o, d, t0, t1, 0 (the layout of the test kernels), clipped; o and
    d are rounded to float32 first, so both backends trace the same ray."""
    rows = []
    for o, d in rays:
        o = np.asarray(o, np.float32).astype(np.float64)
        d = np.asarray(d, np.float32).astype(np.float64)
        t0, t1 = clip(o, d)
        rows.append([*o, *d, t0, t1, 0.0])
    return np.array(rows)


def free_flights(backend, grid, scale, res, rays, n_per_ray, seed):
    """(distances or -1 / -2, lookups) of n_per_ray delta-tracking walks per ray over the
    majorant grid of resolution res (cz, cy, cx)."""
    maj, mnr = build_majorant_grid(grid, res)
    media = grid_media(BMIN, BMAX, scale, grid, len(rays), maj_res=res)
    t, _, lk = walks(backend, TRACK_FREE_FLIGHT, False, media, grid, rays, n_per_ray, seed,
                     MAX_STEPS, maj, mnr)
    return t, lk


def dda_walks(backend, rays, res, max_segments=64):
    """Per ray, the DDA segments [k, 5] = (t_enter, t_exit, iz, iy, ix)."""
    if backend == "numba":
        walks = []
        for r in rays:
            out = np.zeros((max_segments, 5))
            n = dda_segments(tuple(r[:3]), tuple(r[3:6]), r[6], r[7], tuple(BMIN), tuple(BMAX),
                             res, out)
            walks.append(out[:n])
        return walks
    out, ob = out_buf((len(rays), max_segments, 5))
    cnt, cb = out_buf(len(rays), np.int32)
    run("t_dda", len(rays), to_dev(rays.astype(np.float32).ravel()), f3(BMIN), f3(BMAX),
        i3(res), np.int32(max_segments), ob, cb, outs=[(out, ob), (cnt, cb)])
    return [out[r, :cnt[r]].astype(np.float64) for r in range(len(rays))]


def distance_chi2(t, grid, scale, row, n):
    """p-value of collision distances (escapes as one more cell) against the exact
    CDF 1 - exp(-tau(t0, t)) along the ray."""
    o, d, t0, t1 = tuple(row[:3]), tuple(row[3:6]), row[6], row[7]
    edges = np.linspace(t0, t1, 21)
    cdf = np.array([1 - math.exp(-optical_depth_exact(grid, tuple(BMIN), tuple(BMAX), scale, o,
                                                      d, t0, e)) for e in edges])
    expected = np.append(np.diff(cdf), 1 - cdf[-1]) * n
    hit = t >= 0
    observed = np.append(np.histogram(np.clip(t[hit], t0, t1), bins=edges)[0], np.sum(~hit))
    return chi2_pvalue(observed, expected)[0]


# ------------------------------------------------------------------------------- case 6

#: Degenerate rays in the box [-1, 1]^3 with an 8^3 grid, whose voxel faces (and majorant
#: cell faces at resolution 8^3) are the planes k / 4 - 1.
DEGENERATE_RAYS = {
    "axis +x from outside": ((-3.0, 0.1, 0.3), (1.0, 0.0, 0.0)),
    "axis -y, -0.0 components, from the face y = 1": ((0.3, 1.0, -0.6), (-0.0, -1.0, -0.0)),
    "axis +z along voxel edge x = 0.25, y = -0.5, from the face z = -1":
        ((0.25, -0.5, -1.0), (0.0, 0.0, 1.0)),
    "oblique from an interior voxel face, -0.0 y": ((0.5, 0.1, 0.2), (0.6, -0.0, 0.8)),
    "diagonal from a box corner through voxel corners":
        ((-1.0, -1.0, -1.0), tuple(np.full(3, 1 / math.sqrt(3)))),
    "diagonal back from the opposite corner":
        ((1.0, 1.0, 1.0), tuple(np.full(3, -1 / math.sqrt(3)))),
    "lying in the box face x = -1": ((-1.0, 0.3, -2.0), (0.0, 0.0, 1.0)),
    "along the box edge x = -1, y = 1, from a voxel face": ((-1.0, 1.0, 0.75), (0.0, 0.0, -1.0)),
    "axis -x from an interior voxel face, -0.0 z": ((0.75, 0.25, 0.5), (-1.0, 0.0, -0.0)),
    "axis +z with -0.0 x lying in the voxel face x = 0.25": ((0.25, 0.3, -1.0), (-0.0, 0.0, 1.0)),
}


def perturbed(o, d):
    """The ray moved 1e-5 towards the box centre and tilted by 1e-5 (inwards for the rays
    lying in faces, so the perturbed ray stays in the medium)."""
    o = np.asarray(o, float)
    o2 = o - 1e-5 * o / np.linalg.norm(o)
    d2 = np.asarray(d, float) + 1e-5 * np.array([0.3, -0.2, 0.1])
    return tuple(o2), tuple(d2 / np.linalg.norm(d2))


def _case6_grid():
    return 0.2 + np.random.default_rng(61).random((8, 8, 8)) ** 2


def test_case06_dda_degenerate_rays_never_stall_or_skip(backend, lanes):
    """robustness case 6: for axis-parallel rays, rays with -0.0 components, rays starting on box
    faces, corners and voxel faces, and rays lying in faces or edges, over majorant grids of
    8^3, 4^3 and 3 x 5 x 2 cells: the DDA segments tile [t0, t1] exactly (first enters at
    t0, last exits at t1, each starts where the previous ended, none backwards), the walk
    takes at most cx + cy + cz segments (no stall), every point sampled along the ray lies in
    the cell of its segment (or, on a cell face, in one of the cells sharing that face), no
    cell is visited twice, and every cell the ray passes through is visited (no skip)."""
    rays = ray_rows(DEGENERATE_RAYS.values())
    for res in ((8, 8, 8), (4, 4, 4), (3, 5, 2)):
        size = (BMAX - BMIN) / np.array(res[::-1])
        for (name, row), s in zip(zip(DEGENERATE_RAYS, rays), dda_walks(backend, rays, res)):
            where = f"{name}, cells {res}"
            t0, t1 = row[6], row[7]
            if backend == "opencl":
                t0, t1 = float(np.float32(t0)), float(np.float32(t1))
            assert 1 <= len(s) <= sum(res), f"{where}: {len(s)} segments"
            assert s[0, 0] == t0 and s[-1, 1] == t1, where
            assert np.all(s[1:, 0] == s[:-1, 1]) and np.all(s[:, 1] >= s[:, 0]), where
            ts = np.linspace(t0, t1, 2001)[1:-1]
            pts = row[:3] + ts[:, None] * row[3:6]
            iz, iy, ix = cell_of(pts, BMIN, BMAX, res)
            rel = (pts - BMIN) / size
            near_face = np.any(np.abs(rel - np.round(rel)) < 1e-4, axis=1)
            # A point on (or within rounding of) a cell face belongs to the cells on both
            # sides: its segment's cell must be one of them, per axis.
            n_xyz = np.array(res[::-1])
            lo = np.clip(np.floor(rel - 1e-4), 0, n_xyz - 1)
            hi = np.clip(np.floor(rel + 1e-4), 0, n_xyz - 1)
            k = np.clip(np.searchsorted(s[:, 1], ts, side="left"), 0, len(s) - 1)
            cell_xyz = s[k][:, [4, 3, 2]]
            ok = np.all((cell_xyz >= lo) & (cell_xyz <= hi), axis=1)
            assert np.all(ok), f"{where}: points outside their segment's cell"
            walked = [tuple(c) for c in s[s[:, 1] > s[:, 0]][:, 2:5].astype(int)]
            assert len(walked) == len(set(walked)), f"{where}: a cell visited twice"
            seen = {tuple(c) for c in np.stack([iz, iy, ix], 1)[~near_face]}
            assert seen <= set(walked), f"{where}: cells skipped: {seen - set(walked)}"


def test_case06_degenerate_rays_same_optical_depth_as_perturbed(backend):
    """robustness case 6: along each degenerate ray and along the same ray perturbed by 1e-5, delta
    tracking over the 8^3 majorant grid (cell faces = voxel faces) gives collision distances
    that pass a chi-square test against the exact CDF 1 - exp(-tau(t)), and ratio tracking
    with the global majorant gives a mean transmittance within the bound of exp(-tau): the
    degenerate ray sees the optical depth of its perturbed neighbours (whose exact tau
    differs by < 1e-3). No walk is capped and every estimate is finite and in [0, 1].
    Sidak over 2 tests x 2 rays x the degenerate rays."""
    grid = _case6_grid()
    scale = 1.3
    res = (8, 8, 8)
    rays_deg = ray_rows(DEGENERATE_RAYS.values())
    rays_pert = ray_rows([perturbed(o, d) for o, d in DEGENERATE_RAYS.values()])
    rays = np.concatenate([rays_deg, rays_pert])
    names = [f"{n}" for n in DEGENERATE_RAYS] + [f"{n} (perturbed)" for n in DEGENERATE_RAYS]
    taus = [optical_depth_exact(grid, tuple(BMIN), tuple(BMAX), scale, tuple(r[:3]),
                                tuple(r[3:6]), r[6], r[7]) for r in rays]
    m = len(rays_deg)
    for k in range(m):
        assert abs(taus[k] - taus[m + k]) < 1e-3, names[k]
    n = 40_000
    a = sidak(ALPHA, 2 * len(rays))
    zb = z_bound(ALPHA, 2 * len(rays))
    t, lk = free_flights(backend, grid, scale, res, rays, n, seed=62)
    mbar = float(np.float32(scale * grid.max()))
    media = grid_media(BMIN, BMAX, scale, grid, len(rays), sigma_maj=mbar)
    _, T, _ = walks(backend, TRACK_RATIO, False, media, grid, rays, 4000, 63, MAX_STEPS)
    assert np.all(t != -2.0), "a free flight was capped"
    assert np.all(np.isfinite(T)) and T.min() >= 0.0 and T.max() <= 1.0
    fails = []
    for k, row in enumerate(rays):
        tk = t[k * n:(k + 1) * n]
        assert np.all(np.isfinite(tk)), names[k]
        p = distance_chi2(tk, grid, scale, row, n)
        Tk = T[k * 4000:(k + 1) * 4000]
        z = (Tk.mean() - math.exp(-taus[k])) / (Tk.std(ddof=1) / math.sqrt(Tk.size))
        if not p > a or not abs(z) < zb:
            fails.append(f"{names[k]}: distance chi-square p={p:.3g}, ratio tracking z={z:.2f}")
    assert not fails, "; ".join(fails)


# ------------------------------------------------------------------------------- case 8

def _estimate(backend, name, med, grid, rays, bounds, n):
    if backend == "numba":
        return run_numba(name, med, grid, rays, bounds, n, 81)
    return OpenCLEstimator(name).run(med, grid, rays, bounds, n, 81)


def test_case08_all_zero_grid_functions(backend, lanes):
    """robustness case 8, function level: in an all-zero grid every majorant cell is empty, so
    delta tracking over the majorant grid escapes every walk with zero lookups, and every
    transmittance estimator of the registry given the (zero) majorant returns exactly 1 with
    zero lookups, for axis-parallel, degenerate and oblique rays."""
    grid = np.zeros((8, 8, 8))
    rays = ray_rows(list(DEGENERATE_RAYS.values()) + [((-0.9, -0.8, -0.7), (0.48, 0.6, 0.64))])
    t, lk = free_flights(backend, grid, 2.0, (4, 4, 4), rays, 64, seed=80)
    assert np.all(t == -1.0) and np.all(lk == 0)
    med = grid_media(BMIN, BMAX, 2.0, grid, 1)
    for name in ESTIMATORS:
        est, cnt = _estimate(backend, name, med, grid, rays, np.zeros((len(rays), 2)), 16)
        assert np.all(est == 1.0), f"{name}: {est[est != 1.0][:4]}"
        assert cnt[:, C_LOOKUPS].sum() == 0, f"{name}: {cnt[:, C_LOOKUPS].sum()} lookups"


def _box_scene(density, albedo, resolution=(8, 8), camera=None, **render_keys):
    """The box [-1, 1]^3 seen by an orthographic camera that it fills (one pixel per
    voxel of a 16^3 grid at 16 x 16), under an environment of radiance 0.7 and a sun."""
    cam = camera or {"type": "orthographic", "eye": [0.0, 0.0, 3.0], "target": [0, 0, 0],
                     "size": 2.0, "resolution": list(resolution)}
    return scene_from_dict({
        "camera": cam,
        "medium": {"bounds": [[-1, -1, -1], [1, 1, 1]], "density": density, "scale": 3.0,
                   "albedo": albedo, "phase": {"type": "hg", "g": 0.3}},
        "lights": [{"type": "environment", "radiance": 0.7},
                   {"type": "directional", "direction": [0.0, -1.0, -0.0], "irradiance": 2.0}],
        "render": {"spp": 16, "max_depth": 8, "seed": 8, **render_keys}})


@pytest.mark.parametrize("majorant", ["grid", "global"])
def test_case08_all_zero_grid_render(tmp_path, backend, majorant):
    """robustness case 8, image level: an all-zero grid (16^3) renders exactly the environment L
    in every pixel, with zero density lookups and zero scattering events, both through the
    transmittance path (albedo 0, orthographic camera filled by the box) and the scattering
    path (albedo 0.9, with a sun that must cast nothing; a perspective camera sees the box
    from a corner), with per-cell (grid) and global majorants."""
    np.save(tmp_path / "zero.npy", np.zeros((16, 16, 16), np.float32))
    persp = {"eye": [2.5, 1.9, 3.1], "target": [0, 0, 0], "fov": 60, "resolution": [8, 8]}
    for albedo, cam in ((0.0, None), (0.9, persp)):
        scene = _box_scene({"file": str(tmp_path / "zero.npy")}, albedo, camera=cam,
                           majorant=majorant)
        res = render(scene, backend=backend, progress=False)
        img = res.film.mean()
        L = float(np.float32(0.7)) if backend == "opencl" else 0.7
        assert np.all(img == L), (albedo, cam, img.min(), img.max())
        c = res.counters
        assert c["lookups"] == 0 and c["scatter_events"] == 0, (albedo, cam, c)
        assert c["dropped"] == 0 and c["capped"] == 0


#: The single non-zero voxel (z, y, x) of a 16^3 grid and the majorant cells (4^3): its
#: trilinear support straddles cell faces on every axis, so it influences 8 cells.
VOXEL = (8, 7, 8)
VOXEL_RES = (4, 4, 4)


def _single_voxel_grid(value):
    g = np.zeros((16, 16, 16))
    g[VOXEL] = value
    return g


def _voxel_centre():
    return BMIN + (np.array(VOXEL[::-1]) + 0.5) / 16 * (BMAX - BMIN)


def test_case08_single_voxel_free_flight(backend):
    """robustness case 8, function level: a 16^3 grid that is zero except one voxel. Rays through
    the voxel (axis-parallel through its centre, oblique, and grazing the edge of its
    trilinear support) give collision distances that pass the chi-square test against the
    exact CDF: the voxel is not missed. Rays that cross only empty majorant cells escape
    with zero lookups. Sidak over the rays."""
    grid = _single_voxel_grid(40.0)
    c = _voxel_centre()
    h = 2.0 / 16
    hits = [((c[0], c[1], -2.0), (0.0, 0.0, 1.0)),
            ((-2.0, c[1] + 0.3 * h, c[2] - 0.2 * h), (1.0, 0.0, -0.0)),
            (tuple(c - 3 * np.array([0.6, 0.0, 0.8])), (0.6, 0.0, 0.8)),
            ((c[0] + 0.9 * h, c[1] - 0.85 * h, 2.0), (-0.0, 0.0, -1.0))]   # near the support edge
    misses = [((-0.9, -0.9, -2.0), (0.0, 0.0, 1.0)), ((0.9, 0.8, 2.0), (-0.0, -0.0, -1.0)),
              ((-2.0, -0.9, 0.9), (1.0, 0.0, 0.0))]
    rays = ray_rows(hits + misses)
    scale = 1.0
    n = 40_000
    t, lk = free_flights(backend, grid, scale, VOXEL_RES, rays, n, seed=84)
    a = sidak(ALPHA, len(hits))
    for k in range(len(hits)):
        tk = t[k * n:(k + 1) * n]
        tau = optical_depth_exact(grid, tuple(BMIN), tuple(BMAX), scale, tuple(rays[k, :3]),
                                  tuple(rays[k, 3:6]), rays[k, 6], rays[k, 7])
        assert tau > 0.05, (k, tau)
        p = distance_chi2(tk, grid, scale, rays[k], n)
        assert p > a, f"ray {k} (tau {tau:.3f}): p={p:.3g}, P(hit)={np.mean(tk >= 0):.4f}"
    miss = slice(len(hits) * n, None)
    assert np.all(t[miss] == -1.0) and np.all(lk[miss] == 0)


def _single_voxel_expected(grid, scale, L, n_pix):
    """Pixel averages of L exp(-tau) for an orthographic camera looking down -z at the box
    (size 2, n_pix^2 pixels): Gauss-Legendre in each quarter of each pixel (the optical depth
    has kinks only at voxel-centre lines, which are pixel centres and edges here)."""
    x, w = np.polynomial.legendre.leggauss(6)
    h = 2.0 / n_pix
    img = np.zeros((n_pix, n_pix))
    for j in range(n_pix):
        for i in range(n_pix):
            x0, y1 = -1 + i * h, 1 - j * h
            if abs(x0 + h / 2 - _voxel_centre()[0]) > 3 * h or \
                    abs(y1 - h / 2 - _voxel_centre()[1]) > 3 * h:
                img[j, i] = L
                continue
            acc = 0.0
            for qx in (x0, x0 + h / 2):
                for qy in (y1 - h / 2, y1 - h):
                    for xi, wi in zip(x, w):
                        for yj, wj in zip(x, w):
                            px = qx + (xi + 1) * h / 4
                            py = qy + (yj + 1) * h / 4
                            tau = optical_depth_exact(grid, tuple(BMIN), tuple(BMAX), scale,
                                                      (px, py, 3.0), (0.0, 0.0, -1.0), 2.0, 4.0)
                            acc += wi * wj * math.exp(-tau) / 4
            img[j, i] = L * acc / 4
    return img


def test_case08_single_voxel_render(tmp_path, backend):
    """robustness case 8, image level: an absorbing (albedo 0) 16^3 grid, zero except one voxel
    (optical depth 3 through its centre) whose support straddles majorant cell faces on
    every axis, seen by an orthographic camera with one pixel per voxel: every pixel
    matches L times the exact transmittance averaged over the pixel (per-pixel z-test,
    Sidak over pixels), so the voxel is not missed; pixels whose rays meet no density are
    exactly L with zero variance, and lookups happen only in the 8 non-empty majorant
    cells (their count is at most what ratio tracking makes there)."""
    value, spp = 8.0, 512
    grid = _single_voxel_grid(value)
    np.save(tmp_path / "voxel.npy", grid.astype(np.float32))
    scene = _box_scene({"file": str(tmp_path / "voxel.npy")}, 0.0, resolution=(16, 16),
                       spp=spp, majorant_resolution=list(VOXEL_RES))
    res = render(scene, backend=backend, progress=False)
    L = 0.7
    expected = _single_voxel_expected(grid, 3.0, L, 16)
    m = res.film.mean()[..., 0]
    se = np.sqrt(res.film.variance_of_mean()[..., 0])
    assert np.all(np.isfinite(m)) and m.min() >= 0
    assert res.counters["dropped"] == 0 and res.counters["capped"] == 0
    exact = se == 0
    assert np.sum(exact) > 0.5 * m.size and np.allclose(expected[exact], L, rtol=1e-12)
    assert np.allclose(m[exact], expected[exact], rtol=2e-6, atol=0), "exact pixels differ"
    z = (m[~exact] - expected[~exact]) / se[~exact]
    assert np.abs(z).max() < z_bound(ALPHA, m.size), (np.abs(z).max(), expected.min())
    assert expected.min() < 0.5 * L                          # the voxel is clearly visible
    # Lookups only in the 2 x 2 x 2 non-empty majorant cells ([-0.5, 0.5]^3): a quarter of
    # the camera rays cross them over a length of 1, where ratio tracking makes
    # Poisson(scale * value * 1) lookups; every other ray makes none.
    mean_lookups = 0.25 * 16 * 16 * spp * 3.0 * value
    assert 0 < res.counters["lookups"] < mean_lookups + z_bound(ALPHA) * math.sqrt(mean_lookups)


# ------------------------------------------------------------------------------- case 9

BAD_VALUES = {
    # kind: (values written into voxels, words of the one-line message)
    "NaN": ([np.nan, np.nan], "grid contains 2 NaN values"),
    "+Inf": ([np.inf, np.inf, np.inf], "grid contains 3 infinite values"),
    "-Inf": ([-np.inf], "grid contains 1 infinite value"),
    "negative": ([-0.5, -2.0], "grid contains 2 negative values (minimum -2)"),
    # Every kind is counted at once, so one message names every repair the file needs.
    "mixed": ([np.nan, -np.inf, -0.25], "grid contains 1 NaN, 1 infinite and 1 negative "
                                        "values (minimum -0.25)"),
}


def _write_bad_grid(path, values):
    g = np.ones((3, 4, 5), np.float32)
    g.ravel()[[7, 19, 33][:len(values)]] = values
    if path.suffix == ".npy":
        np.save(path, g)
    elif path.suffix == ".npz":
        np.savez(path, density=g)
    else:
        write_vol(path, g)


@pytest.mark.parametrize("suffix", [".npy", ".npz", ".vol"])
def test_case09_bad_grid_files_rejected_at_load(tmp_path, suffix):
    """robustness case 9: grid files (.npy, .npz, Mitsuba .vol) holding NaN, +Inf, -Inf or
    negative voxels are rejected when the scene loads: SceneError whose one-line message is
    exactly ``<grid file>: medium.density: <what, with the count of bad voxels>``, and the
    CLI (`volmc render`, with each backend) prints exactly
    ``volmc: error: <grid file>: medium.density: ...`` on one line, exits with status 2
    without a traceback and writes no image."""
    env = dict(os.environ)
    root = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    env["PYTHONPATH"] = os.pathsep.join([root, env.get("PYTHONPATH", "")])
    raw = {"camera": {"eye": [0, 0, 4], "target": [0, 0, 0], "resolution": [4, 4]},
           "medium": {"bounds": [[-1, -1, -1], [1, 1, 1]], "density": None},
           "lights": [{"type": "environment", "radiance": 1.0}], "render": {"spp": 1}}
    for k, (kind, (values, words)) in enumerate(BAD_VALUES.items()):
        grid = tmp_path / f"bad_{kind.strip('+-')}{k}{suffix}"
        _write_bad_grid(grid, values)
        raw["medium"]["density"] = {"file": grid.name}
        scene = tmp_path / f"s{k}.toml"
        scene.write_text(dict_to_toml(raw))
        with pytest.raises(SceneError) as e:
            load_scene(str(scene))
        assert str(e.value) == f"{grid}: medium.density: {words}"
        backend = BACKENDS[k % 2]
        r = subprocess.run([sys.executable, "-m", "volmc.cli", "render", str(scene), "-o",
                            "out.exr", "--backend", backend], cwd=tmp_path, env=env,
                           capture_output=True, text=True, timeout=300)
        assert r.returncode == 2, (kind, backend, r.stderr)
        assert r.stderr == f"volmc: error: {grid}: medium.density: {words}\n", r.stderr
        assert "Traceback" not in r.stderr and not (tmp_path / "out.exr").exists()
