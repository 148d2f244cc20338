"""The octree of majorants (issue 13): per-leaf bounds that hold under trilinear
interpolation, the split criterion, the walk of a ray through the leaves against a
brute-force walk (including the degenerate rays of robustness case 6), the kernel twin
segment by segment, and renders that agree with the majorant grid's."""

import numpy as np
import pytest

from test_dda import clip
from test_majorant import _lookups
from volmc.reference.majorant import build_majorant_grid, cell_of
from volmc.reference.octree import (OCTREE_SPLIT_THRESHOLD, build_octree, octree_depth,
                                    octree_leaf_of, octree_segments)


BMIN = np.array([-1.0, -0.5, 0.0])
BMAX = np.array([1.0, 1.5, 3.0])
SCALE = 6.0


def _grid():
    """40 x 50 x 60 voxels (z, y, x): smooth blobs, a noisy block, a constant slab and empty
    space, so the octree has deep, shallow, homogeneous and empty leaves."""
    rng = np.random.default_rng(3)
    z, y, x = np.meshgrid(*[np.linspace(0, 1, n) for n in (40, 50, 60)], indexing="ij")
    g = np.exp(-((x - 0.3) ** 2 + (y - 0.6) ** 2 + (z - 0.4) ** 2) / 0.01)
    g[5:15, 30:45, 35:55] += rng.random((10, 15, 20))
    g[25:40, 0:20, 0:30] = 0.7
    g[g < 1e-3] = 0.0
    return g


def _octree(grid=None):
    grid = _grid() if grid is None else grid
    depth = octree_depth(grid.shape)
    fmx, fmn = build_majorant_grid(grid, (2 ** depth,) * 3)
    mx, mn, ch = build_octree(fmx, fmn, BMAX - BMIN, SCALE)
    return grid, depth, mx, mn, ch


def _leaf_of_points(pts, depth, ch):
    cz, cy, cx = cell_of(pts, BMIN, BMAX, (2 ** depth,) * 3)
    return octree_leaf_of(ch, depth, np.stack([cx, cy, cz], 1))


def test_leaf_bounds_hold_at_a_million_points_and_the_criterion_splits():
    grid, depth, mx, mn, ch = _octree()
    leaves = ch == 0
    assert depth == 3 and leaves.sum() > 50 and (~leaves).sum() > 5
    assert np.all(mn <= mx) and np.any((mx > 0) & (mx == mn) & leaves)
    assert np.any((mx == 0) & leaves)
    rng = np.random.default_rng(1)
    pts = BMIN + rng.random((1_000_000, 3)) * (BMAX - BMIN)
    # Points on the finest cell faces (and so on every node face) too.
    n = 2 ** depth
    faces = BMIN + np.stack(np.meshgrid(*[np.linspace(0, 1, n + 1)] * 3, indexing="ij"),
                            -1).reshape(-1, 3) * (BMAX - BMIN)
    pts = np.concatenate([pts, faces])
    vals = _lookups(grid, tuple(BMIN), tuple(1.0 / (BMAX - BMIN)), pts)
    for shift in (0.0, 1e-9, -1e-9):   # a face point belongs to the leaves on both sides
        leaf, _ = _leaf_of_points(pts + shift, depth, ch)
        assert np.all(ch[leaf] == 0)
        assert np.all(vals <= mx[leaf] * (1 + 1e-7) + 1e-30)
        assert np.all(vals >= mn[leaf] * (1 - 1e-7) - 1e-30)
    # The criterion: an inner node's spread exceeds the threshold, a leaf's above the
    # finest level does not; and every node's bounds are the pooled finest-level bounds.
    leaf, level = octree_leaf_of(ch, depth, np.stack(np.meshgrid(*[np.arange(n)] * 3,
                                                                 indexing="ij"), -1).reshape(-1, 3))
    diag = np.linalg.norm(BMAX - BMIN) / 2.0 ** level
    spread = (mx[leaf].astype(np.float64) - mn[leaf]) * SCALE * diag
    assert np.all((spread <= OCTREE_SPLIT_THRESHOLD) | (level == depth))
    inner = np.flatnonzero(~leaves)
    assert np.all(mx[ch[inner][:, None] + np.arange(8)].max(1) == mx[inner])
    assert np.all(mn[ch[inner][:, None] + np.arange(8)].min(1) == mn[inner])


def _walk(o, d, depth, ch):
    seg = clip(o, d, BMIN, BMAX)
    if seg is None:
        return None
    t0, t1 = seg
    out = np.zeros((3 * 2 ** depth + 3, 3))
    k = octree_segments(tuple(o), tuple(d), t0, t1, tuple(BMIN), tuple(BMAX), ch, depth, out)
    return t0, t1, out[:k]


def _check_walk(o, d, depth, ch):
    r = _walk(o, d, depth, ch)
    if r is None:
        return 0
    t0, t1, s = r
    n = len(s)
    assert 1 <= n <= 3 * 2 ** depth + 1
    assert s[0, 0] == t0 and s[-1, 1] == t1
    assert np.all(s[1:, 0] == s[:-1, 1]) and np.all(s[:, 1] >= s[:, 0])
    assert np.all(ch[s[:, 2].astype(int)] == 0)          # leaves only
    ts = np.linspace(t0, t1, 4001)[1:-1]
    pts = np.asarray(o) + ts[:, None] * np.asarray(d)
    leaf, _ = _leaf_of_points(pts, depth, ch)
    k = np.clip(np.searchsorted(s[:, 1], ts, side="left"), 0, n - 1)
    size = (BMAX - BMIN) / 2 ** depth
    rel = (pts - BMIN) / size
    near_face = np.any(np.abs(rel - np.round(rel)) < 1e-7, axis=1)
    ok = s[k, 2] == leaf
    assert np.all(ok | near_face), np.flatnonzero(~(ok | near_face))[:5]
    walked = [int(v) for v in s[s[:, 1] > s[:, 0]][:, 2]]
    assert set(leaf[~near_face].tolist()) <= set(walked)
    assert len(walked) == len(set(walked))               # no leaf twice (leaves are convex)
    return n


DEGENERATE = [
    ((-3.0, 0.3, 1.2), (1.0, 0.0, 0.0)),              # axis-parallel
    ((0.1, 0.2, -2.0), (-0.0, 0.0, 1.0)),             # -0.0 components
    ((0.1, 3.0, 0.7), (0.0, -1.0, -0.0)),
    ((-1.0, 0.2, 1.1), (0.6, 0.0, 0.8)),               # starts on a box face
    ((0.0, 0.5, 1.5), (0.0, 0.0, 1.0)),                # starts on node faces (x = 0, y = 0.5)
    ((-3.0, 0.5, 1.5), (1.0, 0.0, 0.0)),               # runs exactly along node faces (y, z)
    ((1.0, 1.5, 3.0), (-0.5, -0.5, -0.70710678)),     # starts on a box corner
    ((0.2, 0.3, 2.999999999), (0.0, 0.0, 1.0)),        # tiny segment before the face
    ((-1.0, -0.5, 0.0), (0.5773502691896258,) * 3),    # along the main diagonal's corners
]


def _rays(n, seed):
    rng = np.random.default_rng(seed)
    out = []
    for o, d in DEGENERATE:
        d = np.array(d, float)
        out.append((np.array(o, float), d / np.linalg.norm(d)))
    for _ in range(n):
        d = rng.normal(size=3)
        d /= np.linalg.norm(d)
        inside = rng.random() < 0.5
        o = BMIN + rng.random(3) * (BMAX - BMIN) if inside else \
            (BMIN + BMAX) / 2 - 4 * d + rng.normal(size=3) * 0.5
        out.append((o, d))
    return out


def test_walk_tiles_the_ray_and_matches_a_brute_force_walk():
    _, depth, _, _, ch = _octree()
    hits = sum(_check_walk(o, d, depth, ch) > 0 for o, d in _rays(300, 0))
    assert hits > 200
    for o, d in _rays(0, 0):
        assert _check_walk(o, d, depth, ch) >= 1


def test_walk_of_a_single_leaf_and_of_the_full_depth():
    """A homogeneous grid is one leaf (depth 0 walk: one segment); a grid that splits
    everywhere walks the finest cells exactly as the DDA does."""
    g = np.full((16, 16, 16), 0.5)
    _, depth, mx, mn, ch = _octree(g)
    assert len(ch) == 1 and mx[0] == mn[0] == np.float32(0.5)
    t0, t1, s = _walk(np.array([-3.0, 0.1, 1.0]), np.array([1.0, 0.0, 0.0]), depth, ch)
    assert len(s) == 1 and s[0, 0] == t0 and s[0, 1] == t1
    from volmc.reference.dda import dda_segments
    g = np.random.default_rng(2).random((16, 16, 16)) * 50
    _, depth, _, _, ch = _octree(g)
    assert np.sum(ch == 0) == 8 ** depth
    for o, d in _rays(50, 5):
        r = _walk(o, d, depth, ch)
        if r is None:
            continue
        t0, t1, s = r
        ref = np.zeros((64, 5))
        k = dda_segments(tuple(o), tuple(d), t0, t1, tuple(BMIN), tuple(BMAX),
                         (2 ** depth,) * 3, ref)
        assert np.allclose(s[:, :2], ref[:k, :2], rtol=0, atol=1e-12)


def test_kernel_walk_matches_reference(lanes):
    """The OpenCL twin yields the same leaves with the same segment ends (float32) for random
    and degenerate rays."""
    from cl_harness import f3, out_buf, run, to_dev
    _, depth, _, _, ch = _octree()
    rays = []
    for o, d in _rays(300, 8):
        seg = clip(o, d, BMIN, BMAX)
        if seg is not None:
            rays.append([*o, *d, seg[0], seg[1], 0.0])
    rays = np.array(rays).astype(np.float32)
    m = 3 * 2 ** depth + 3
    out, ob = out_buf((len(rays), m, 3))
    cnt, cb = out_buf(len(rays), np.int32)
    run("t_octree", len(rays), to_dev(rays.ravel()), f3(BMIN), f3(BMAX), to_dev(ch),
        np.int32(depth), np.int32(m), ob, cb, outs=[(out, ob), (cnt, cb)])
    agree = 0
    for r, ray in enumerate(rays.astype(np.float64)):
        ref = np.zeros((m, 3))
        n = octree_segments(tuple(ray[:3]), tuple(ray[3:6]), ray[6], ray[7], tuple(BMIN),
                            tuple(BMAX), ch, depth, ref)
        a = out[r, :cnt[r]]
        assert a[0, 0] == np.float32(ray[6]) and a[-1, 1] == np.float32(ray[7])
        assert np.all(a[1:, 0] == a[:-1, 1])
        a, b = a[a[:, 1] - a[:, 0] > 1e-5], ref[:n][ref[:n, 1] - ref[:n, 0] > 1e-5]
        if len(a) == len(b) and np.array_equal(a[:, 2], b[:, 2]) and \
                np.allclose(a[:, :2], b[:, :2], atol=1e-5):
            agree += 1
    assert agree >= len(rays) - 2, agree   # float32 may split a corner crossing differently


def test_bricks_build_the_dense_octree():
    """A VDB scene (bricks) packs the octree of the same grid given densely."""
    from test_vdb_scenes import DATA, _scene, _truth
    from volmc.pack import pack_octree
    _, bounds = _truth()
    over = {"majorant": "octree"}
    a = pack_octree(_scene({"file": str(DATA / "blobs.vdb")}, render_keys=over))
    b = pack_octree(_scene({"file": str(DATA / "blobs_density.npy")}, bounds,
                           render_keys={**over, "grid_storage": "dense"}))
    assert a[3] == b[3] and len(a[2]) > 1
    for x, y in zip(a[:3], b[:3]):
        assert np.array_equal(x, y)


def _vdb(majorant, seed, spp):
    from test_vdb_scenes import DATA, _scene
    s = _scene({"file": str(DATA / "blobs.vdb")},
               render_keys={"majorant": majorant, "seed": seed, "spp": spp})
    return s


@pytest.mark.parametrize("which", ["cloud", "vdb"])
def test_octree_and_grid_majorants_agree(backend, which):
    """Renders with majorant = "octree" and "grid" agree by the per-pixel z-test (independent
    seeds; Sidak-corrected at ALPHA, volmc.check), with every lookup under its majorant."""
    from volmc.check import compare_images
    from volmc.render import render
    from volmc.resources import scenes_dir
    from volmc.scene import load_scene

    def scene(majorant, seed):
        if which == "vdb":
            return _vdb(majorant, seed, 64)
        over = ["camera.resolution=[16, 16]", "render.spp=128",
                "medium.density.resolution=48", f"render.majorant={majorant}",
                f"render.seed={seed}"]
        return load_scene(scenes_dir() / "cloud.toml", over)

    a = render(scene("grid", 0), backend=backend, progress=False)
    b = render(scene("octree", 1), backend=backend, progress=False)
    cmp = compare_images(a.image, a.film.variance_of_mean(), b.image, b.film.variance_of_mean())
    assert cmp.passed, cmp.summary("grid", "octree")
    assert b.counters["over_majorant"] == 0 and b.counters["capped"] == 0
    assert b.counters["lookups"] > 0


@pytest.mark.parametrize("estimator", ["ratio", "track_length"])
def test_tracking_estimators_under_the_octree_at_every_width(estimator):
    """volmc.estimate_transmittance with the octree: the same estimates at W = 16 as at
    W = 1, and the reference's within the standard error. The kernels returned T = 1
    without a lookup at W > 1 (an uninitialised walk record: kernels/lanes.h)."""
    import volmc
    scene = volmc.load_scene(overrides={"render.majorant": "octree",
                                        "camera.resolution": [8, 8]})
    o, d = [[0.0, 0.6, 4.0], [0.3, 0.0, 4.0]], [0.0, 0.0, -1.0]
    one, wide = (volmc.estimate_transmittance(scene, o, d, estimator=estimator, n=256,
                                              lanes=w) for w in (1, 16))
    np.testing.assert_array_equal(wide.estimates, one.estimates)
    assert (wide.lookups > 1.0).all() and (wide.estimates < 0.5).all()
    ref = volmc.estimate_transmittance(scene, o, d, estimator=estimator, n=256, seed=7,
                                       backend="numba")
    se = np.sqrt(one.stderr ** 2 + ref.stderr ** 2)
    assert (np.abs(one.estimates - ref.estimates) <= 4.5 * se).all(), (one.estimates,
                                                                       ref.estimates, se)
