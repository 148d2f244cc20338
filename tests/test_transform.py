"""medium.transform: a medium placed by an affine map (volmc/scene/transform.py).

Quarter turns and mirrors of a grid must render as the rearranged array in a moved box (the
same density at every world point, so the same image from the same random numbers); a
30-degree turn renders alike in the kernels and the float64 reference, and as the same
smooth field sampled on a world-aligned lattice (within a stated interpolation error); the
transmittance through a turned homogeneous box is the closed form exp(-sigma x chord); a
transform that only scales axes and translates is folded into the box (no kernel feature,
the same image bit for bit as the moved box). Image comparisons are
volmc.check.compare_images (per-pixel z-tests at family level ALPHA, Sidak over pixels and
channels), except the lattice test's, which allows for the interpolation error.
"""

import numpy as np
import pytest

from volmc.check import compare_images
from volmc.render import render
from volmc.scene import scene_from_dict
from volmc.scene.errors import SceneError
from volmc.scene.features import features
from volmc.scene.serialize import to_dict
from volmc.scene.schema import validate
from volmc.scene.transform import compose, rotation

from stats import ALPHA

GRID = np.random.default_rng(3).random((6, 8, 10)).astype(np.float32)   # [z, y, x]
BOX = [[-1.0, -0.8, -0.6], [1.0, 0.8, 0.6]]   # 10 x 8 x 6 voxels of 0.2


def _blob():
    """A dense blob off the box's centre, on 20 x 16 x 12 voxels over BOX: where a wrong map
    puts it shows in every pixel that sees it."""
    z, y, x = np.meshgrid(*[np.linspace(BOX[0][a] + 0.05, BOX[1][a] - 0.05, n)
                            for a, n in ((2, 12), (1, 16), (0, 20))], indexing="ij")
    r2 = (x - 0.5) ** 2 + (y + 0.3) ** 2 + (z - 0.2) ** 2
    return (4.0 * np.exp(-r2 / 0.3) + 0.05).astype(np.float32)


BLOB = _blob()


def grid_scene(grid, bounds, transform=None, res=16, spp=32, seed=1, majorant="grid"):
    med = {"bounds": bounds, "density": grid, "scale": 3.0, "albedo": 0.8,
           "phase": {"type": "hg", "g": 0.3}}
    if transform is not None:
        med["transform"] = transform
    return scene_from_dict({
        "camera": {"eye": [2.5, 1.5, 3.0], "fov": 40, "resolution": [res, res]},
        "medium": med,
        "lights": [{"type": "environment", "radiance": 0.05},
                   {"type": "directional", "direction": [-1, -1, -0.3], "irradiance": 3.0},
                   {"type": "point", "position": [0.3, 1.4, 0.9], "intensity": 1.0}],
        "render": {"spp": spp, "max_depth": 6, "seed": seed, "majorant": majorant}})


# --- the scene key ---------------------------------------------------------------------

def _medium_transform(transform):
    return grid_scene(GRID, BOX, transform).spec.medium.transform


def test_scale_rotate_translate_compose_in_that_order():
    m = np.array(_medium_transform({"scale": [2.0, 1.0, 0.5], "rotate": [0, 0, 1, 90],
                                    "translate": [1.0, 2.0, 3.0]}))
    # local +x: scaled to 2, turned to +y, moved
    assert np.allclose(m @ [1, 0, 0, 1], [1.0, 4.0, 3.0, 1.0])
    assert np.allclose(m @ [0, 0, 1, 1], [1.0, 2.0, 3.5, 1.0])
    # rotations apply in order, the first first: x -> y (about z), then y -> z (about x)
    m = np.array(_medium_transform({"rotate": [[0, 0, 1, 90], [1, 0, 0, 90]]}))
    assert np.allclose(m @ [1, 0, 0, 0], [0, 0, 1, 0])
    # the matrix form is the same map
    mat = compose((2.0, 1.0, 0.5), [((0, 0, 1), 90.0)], (1.0, 2.0, 3.0))
    m2 = _medium_transform({"matrix": mat.tolist()})
    assert np.allclose(np.array(m2), mat)
    assert _medium_transform({"scale": 1.0, "rotate": []}) is None   # the identity


def test_rotation_is_right_handed():
    assert np.allclose(rotation((0, 0, 1), 90) @ [1, 0, 0], [0, 1, 0])
    # any non-zero length: the norm of this one underflowed to 0 (a NaN matrix)
    assert np.array_equal(rotation((1e-170, 0, 0), 30), rotation((1, 0, 0), 30))
    assert np.allclose(rotation((0, 2, 0), 90) @ [0, 0, 1], [1, 0, 0])
    assert np.allclose(rotation((1, 1, 1), 120) @ [1, 0, 0], [0, 1, 0])


def test_transform_round_trips_through_the_scene_dict():
    s = grid_scene(GRID, BOX, {"rotate": [1, 2, 3, 31.0], "scale": [1, -2, 1]}).spec
    d = to_dict(s)
    assert "matrix" in d["medium"]["transform"]
    back = validate(d, s.file)
    assert back.medium.transform == s.medium.transform
    assert to_dict(back) == d


@pytest.mark.parametrize("transform, key, words", [
    ({"scale": 0.0}, "medium.transform", "singular"),
    ({"matrix": [[1, 1, 0, 0], [0, 1e-9, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]},
     "medium.transform", "singular"),   # x and y map to nearly the same direction
    ({"matrix": [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 1, 1]]},
     "medium.transform.matrix", "affine"),
    ({"matrix": [[1, 0, 0], [0, 1, 0], [0, 0, 1]]}, "medium.transform.matrix", "4 rows"),
    ({"matrix": [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]], "scale": 2},
     "medium.transform.scale", "either"),
    ({"rotate": [0, 0, 0, 30]}, "medium.transform.rotate", "zero vector"),
    ({"rotate": [0, 0, 1]}, "medium.transform.rotate", "[ax, ay, az, degrees]"),
    ({"translate": [0, float("nan"), 0]}, "medium.transform.translate", "finite"),
    ({"shear": 1}, "medium.transform.shear", "unknown key"),
    # found by an outside test: a float64 zero-width placed box, then a ZeroDivisionError
    ({"translate": [1e17, 0, 0]}, "medium.transform", "placed box has zero size along x"),
    ({"rotate": [0, 0, 1, 30], "translate": [1e17, 0, 0]}, "medium.transform",
     "placed box has zero size along x"),
])
def test_bad_transforms_name_the_key(transform, key, words):
    with pytest.raises(SceneError) as e:
        _medium_transform(transform)
    assert e.value.key == key and words in str(e.value)


# --- renders ---------------------------------------------------------------------------

def _compare(a, b, backend):
    ra = render(a, backend=backend, progress=False)
    rb = render(b, backend=backend, progress=False)
    c = compare_images(ra.image, ra.film.variance_of_mean(), rb.image, rb.film.variance_of_mean())
    assert c.passed, c.summary()
    assert ra.counters["capped"] == 0
    return ra, rb


#: (transform, the array as the world sees it [z, y, x], its world box): the same density at
#: every world point. A quarter turn about +z takes local +x to world +y and local +y to -x.
REARRANGED = {
    "quarter turn about z": ({"rotate": [0, 0, 1, 90]},
                             np.transpose(GRID, (0, 2, 1))[:, :, ::-1],
                             [[-0.8, -1.0, -0.6], [0.8, 1.0, 0.6]]),
    "mirror in x": ({"scale": [-1, 1, 1]}, GRID[:, :, ::-1], BOX),
    "half turn about y, moved": ({"rotate": [0, 1, 0, 180], "translate": [0.2, 0.0, -0.1]},
                                 GRID[::-1, :, ::-1],
                                 [[-0.8, -0.8, -0.7], [1.2, 0.8, 0.5]]),
}


@pytest.mark.parametrize("backend", ["opencl", "numba"])
@pytest.mark.parametrize("case", sorted(REARRANGED))
def test_quarter_turns_and_mirrors_render_as_the_rearranged_grid(backend, case):
    transform, world_grid, world_box = REARRANGED[case]
    a = grid_scene(GRID, BOX, transform)
    b = grid_scene(np.ascontiguousarray(world_grid), world_box)
    assert "TRANSFORM" in features(a) and "TRANSFORM" not in features(b)
    ra, rb = _compare(a, b, backend)
    # Same random numbers, same densities at the same points: the images agree far beyond
    # the z-test, up to float rounding in where a ray meets a cell (a wrong turn or mirror
    # moves whole voxels and fails the z-test above).
    assert np.abs(ra.image - rb.image).mean() < 1e-3 * np.abs(rb.image).mean()


@pytest.mark.parametrize("majorant, lanes", [("grid", None), ("grid", 1), ("octree", None),
                                             ("global", None)])
def test_turned_grid_renders_alike_in_kernels_and_reference(majorant, lanes):
    """The kernels at the default lane width, and at W = 1 (scalar code, what GPUs run)."""
    t = {"rotate": [[1, 2, 0.5, 30.0], [0, 1, 0, -20.0]], "scale": [1.1, -0.9, 1.3],
         "translate": [0.1, -0.2, 0.05]}
    a = render(grid_scene(BLOB, BOX, t, majorant=majorant, spp=64), backend="opencl",
               progress=False, lanes=lanes)
    b = render(grid_scene(BLOB, BOX, t, majorant=majorant, spp=64, seed=7), backend="numba",
               progress=False)
    c = compare_images(a.image, a.film.variance_of_mean(), b.image, b.film.variance_of_mean())
    assert c.passed, c.summary()
    assert a.counters["over_majorant"] == 0 and b.counters["over_majorant"] == 0
    assert a.image.mean() > 0.05   # the medium is in view: rays cross it


def test_axis_scale_and_translate_is_folded_into_the_box():
    t = {"scale": [2.0, 0.5, 1.5], "translate": [0.3, -0.1, 0.2]}
    a = grid_scene(GRID, BOX, t)
    moved = [[2.0 * BOX[0][0] + 0.3, 0.5 * BOX[0][1] - 0.1, 1.5 * BOX[0][2] + 0.2],
             [2.0 * BOX[1][0] + 0.3, 0.5 * BOX[1][1] - 0.1, 1.5 * BOX[1][2] + 0.2]]
    b = grid_scene(GRID, moved)
    assert "TRANSFORM" not in features(a)
    ra = render(a, backend="opencl", progress=False)
    rb = render(b, backend="opencl", progress=False)
    assert np.array_equal(ra.image, rb.image)


# --- transmittance: the closed form ----------------------------------------------------

def _chord(m, lo, hi, o, d):
    """Length of ray o + t d (t >= 0, unit d) inside the box [lo, hi] placed by 4x4 m."""
    inv = np.linalg.inv(m)
    ol = inv[:3, :3] @ o + inv[:3, 3]
    dl = inv[:3, :3] @ d
    with np.errstate(divide="ignore"):
        ta, tb = (np.asarray(lo) - ol) / dl, (np.asarray(hi) - ol) / dl
    t0 = max(np.minimum(ta, tb).max(), 0.0)
    t1 = np.maximum(ta, tb).min()
    return max(t1 - t0, 0.0)


@pytest.mark.parametrize("backend", ["opencl", "numba"])
@pytest.mark.parametrize("density", ["constant", "grid"])
def test_turned_box_transmittance_is_the_closed_form(backend, density):
    """Homogeneous (a number, or a constant grid, which trilinear interpolation keeps constant
    up to the faces): T = exp(-sigma x world chord), with sigma per world unit, so the
    scale of the transform stretches the chord and the optical depth with it."""
    from volmc import estimate_transmittance
    t = {"rotate": [1, 1, 0, 30.0], "scale": [1.5, 1.0, 0.7], "translate": [0.2, 0.1, 0.0]}
    dens = 1.2 if density == "constant" else np.full((4, 4, 4), 1.2, np.float32)
    med = {"bounds": BOX, "density": dens, "scale": 0.9, "transform": t}
    m = compose((1.5, 1.0, 0.7), [((1, 1, 0), 30.0)], (0.2, 0.1, 0.0))
    rng = np.random.default_rng(5)
    o = rng.normal(size=(64, 3)) * 3.0
    target = rng.uniform(-0.8, 0.8, size=(64, 3))
    d = target - o
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    res = estimate_transmittance(med, o, d, estimator="analytic" if density == "constant"
                                 else "ratio", n=4, backend=backend)
    chords = np.array([_chord(m, BOX[0], BOX[1], o[i], d[i]) for i in range(len(o))])
    assert (chords > 0).mean() > 0.6   # most rays cross the box
    rho = 1.2 if density == "constant" else float(np.float32(1.2))   # as the grid holds it
    expect = np.exp(-rho * 0.9 * chords)
    tol = 1e-5 if backend == "opencl" else 1e-12
    assert np.allclose(res.estimates, expect, rtol=tol * 10, atol=tol)
    assert np.allclose(np.nan_to_num(res.t_exit - res.t_enter), chords, atol=1e-5)


def test_benchmarks_see_a_turned_medium_as_its_rearranged_grid():
    """The lookup ceiling's camera segments and the majorant-segment count of `volmc bench
    render` walk a placed medium in its own space: a quarter turn gives what the rearranged
    array gives (the same rays, lengths and segments)."""
    from volmc.bench.convergence import segments_per_camera_ray
    from volmc.bench.lookups import camera_segments
    transform, world_grid, world_box = REARRANGED["quarter turn about z"]
    a = grid_scene(GRID, BOX, transform)
    b = grid_scene(np.ascontiguousarray(world_grid), world_box)
    sa, sb = camera_segments(a)[0], camera_segments(b)[0]
    assert len(sa) == len(sb) > 0
    assert np.allclose(sa[:, 7] - sa[:, 6], sb[:, 7] - sb[:, 6], rtol=1e-9, atol=1e-12)
    for majorant in ("grid", "octree"):
        assert segments_per_camera_ray(a, majorant) == \
            pytest.approx(segments_per_camera_ray(b, majorant), rel=1e-9)


# --- a 30-degree turn against the same field on a world lattice --------------------------

#: The turned grid's own box (centred: the turn keeps it there), the turn (a non-unit axis,
#: which the map must normalise) and the lattice spacing of both grids (about 1/48 world
#: units on every axis: 96 x 86 x 77 voxels turned, 140 x 125 x 113 world-aligned).
SMOOTH_BOX = np.array([[-1.0, -0.9, -0.8], [1.0, 0.9, 0.8]])
TURN = (1.0, 2.0, 3.0, 30.0)
SPACING = 1.0 / 48.0
#: The smooth field f, defined in world space: Gaussian blobs with sigmas along the world
#: axes, (peak density, (sx, sy, sz), centre given in the box's own space and placed by the
#: turn). Each centre is more than 5.5 of its largest sigma from every face of the box, so f
#: < 1e-7 at the outermost voxel centres (asserted): cutting f off at the box (grid B) or
#: clamping to the edge voxels (both grids) moves no optical depth by 1e-6.
SMOOTH_BLOBS = ((2.0, (0.13, 0.08, 0.10), (0.25, 0.1, 0.0)),
                (2.5, (0.09, 0.12, 0.10), (-0.3, -0.15, 0.05)),
                (1.5, (0.10, 0.10, 0.09), (0.05, 0.15, -0.05)))
SMOOTH_SCALE = 1.5   # extinction per unit density: optical depths up to 0.95 through the blobs
#: The stated interpolation error: a bound on the difference in optical depth, along every
#: camera ray, between either grid and the continuous f, and so between the two grids' images
#: (T = exp(-tau) is 1-Lipschitz for tau >= 0, and a pixel is the mean of T over its area).
#: Trilinear interpolation errs by about (1/2) sum_i h^2 t_i (1 - t_i) f_ii at a point with
#: cell coordinates t: by 0.0067 at most here along a camera ray, for either grid (the
#: quadrature below measures it). Its mean over a cell, (h^2 / 12) Laplacian(f), is the same
#: however the lattice is turned, so the two grids differ from each other by far less (6e-4).
EPS_TAU = 0.01
SMOOTH_CAMERA = {"eye": [0.9, 1.1, 3.0], "target": [-0.05, 0.0, 0.0], "up": [0.0, 1.0, 0.0],
                 "fov": 20.0, "resolution": [24, 24]}
SMOOTH_SPP = 4096


def _turn(axis, degrees):
    """The right-handed turn as a 3x3 matrix, made without volmc (scipy's rotation vector)."""
    from scipy.spatial.transform import Rotation
    a = np.asarray(axis, float)
    return Rotation.from_rotvec(np.radians(degrees) * a / np.linalg.norm(a)).as_matrix()


def _smooth_field(p, turn):
    """f at world points p [..., 3], its blobs' centres placed by the 3x3 turn."""
    out = np.zeros(p.shape[:-1])
    for peak, sigma, centre in SMOOTH_BLOBS:
        q = (p - turn @ np.asarray(centre)) / np.asarray(sigma)
        out += peak * np.exp(-0.5 * np.sum(q * q, axis=-1))
    return out


def _voxel_centres(lo, hi, n):
    """Voxel centres [nz, ny, nx, 3] of an n = (nx, ny, nz) grid over the box [lo, hi]:
    lo + (i + 0.5) / n x extent (docs/scene_format.md, "Conventions")."""
    axes = [lo[a] + (np.arange(n[a]) + 0.5) * (hi[a] - lo[a]) / n[a] for a in range(3)]
    z, y, x = np.meshgrid(axes[2], axes[1], axes[0], indexing="ij")
    return np.stack([x, y, z], axis=-1)


def _inside(p, lo, hi):
    return np.all((p >= lo) & (p <= hi), axis=-1)


def _trilinear(grid, lo, hi, p):
    """The documented lookup of grid [nz, ny, nx] over [lo, hi] at points p [..., 3]:
    trilinear between voxel centres, clamped to the edge centres within half a voxel of a
    face (docs/scene_format.md, "Conventions")."""
    g = grid.astype(np.float64)
    i0, i1, w = [], [], []
    for a, n in enumerate(grid.shape[::-1]):
        x = np.clip((p[..., a] - lo[a]) / (hi[a] - lo[a]) * n - 0.5, 0.0, n - 1.0)
        k = np.minimum(x.astype(np.int64), n - 1)
        i0.append(k)
        i1.append(np.minimum(k + 1, n - 1))
        w.append(x - k)
    out = 0.0
    for cz in (0, 1):
        for cy in (0, 1):
            for cx in (0, 1):
                weight = ((w[0] if cx else 1 - w[0]) * (w[1] if cy else 1 - w[1])
                          * (w[2] if cz else 1 - w[2]))
                out = out + weight * g[(i1 if cz else i0)[2], (i1 if cy else i0)[1],
                                       (i1 if cx else i0)[0]]
    return out


def _camera_rays(sub):
    """(eye, unit directions [24 sub, 24 sub, 3]) of SMOOTH_CAMERA's rays through the centres
    of a sub x sub split of each pixel, row 0 at the top (docs/scene_format.md, "Camera
    basis")."""
    eye, target = np.array(SMOOTH_CAMERA["eye"]), np.array(SMOOTH_CAMERA["target"])
    forward = (target - eye) / np.linalg.norm(target - eye)
    right = np.cross(forward, SMOOTH_CAMERA["up"])
    right /= np.linalg.norm(right)
    up = np.cross(right, forward)
    w, h = SMOOTH_CAMERA["resolution"]
    half = np.tan(np.radians(SMOOTH_CAMERA["fov"]) / 2)
    sx = (2 * (np.arange(w * sub) + 0.5) / (w * sub) - 1) * half * (w / h)
    sy = (1 - 2 * (np.arange(h * sub) + 0.5) / (h * sub)) * half
    d = forward + sx[None, :, None] * right + sy[:, None, None] * up
    return eye, d / np.linalg.norm(d, axis=-1, keepdims=True)


def _optical_depths(fields, lo, hi, sub=4, step=SPACING / 2):
    """{name: optical depth [24 sub, 24 sub]} along ``_camera_rays(sub)`` of each density
    function {name: world points [k, m, 3] -> densities [k, m]}: the midpoint rule in steps of
    at most ``step`` over each ray's chord through the box [lo, hi], which holds every
    field's support. (The step's error here is below 1e-4, and 8 x 8 rays a pixel find the
    same largest differences between the fields as 4 x 4 to within 10 %.)"""
    eye, d = _camera_rays(sub)
    shape, d = d.shape[:2], d.reshape(-1, 3)
    with np.errstate(divide="ignore"):
        ta, tb = (lo - eye) / d, (hi - eye) / d
    t0 = np.maximum(np.minimum(ta, tb).max(axis=1), 0.0)
    length = np.maximum(np.maximum(ta, tb).min(axis=1) - t0, 0.0)
    k = int(np.ceil(length.max() / step))
    t = t0[:, None] + (np.arange(k) + 0.5) / k * length[:, None]
    p = eye + t[..., None] * d[:, None, :]
    return {name: (SMOOTH_SCALE * length / k * fn(p).sum(axis=1)).reshape(shape)
            for name, fn in fields.items()}


def _transmittance_scene(grid, lo, hi, transform=None, seed=1):
    """Albedo 0 under a unit environment light: a pixel is the mean over its area of the
    transmittance T = exp(-tau) of its camera rays, each estimated by the camera-ray
    estimator of a scene that cannot scatter (unbiased, in [0, 1])."""
    med = {"bounds": [[float(x) for x in lo], [float(x) for x in hi]], "density": grid,
           "scale": SMOOTH_SCALE, "albedo": 0.0}
    if transform is not None:
        med["transform"] = transform
    return scene_from_dict({"camera": SMOOTH_CAMERA, "medium": med,
                            "lights": [{"type": "environment", "radiance": 1.0}],
                            "render": {"spp": SMOOTH_SPP, "seed": seed}})


def test_thirty_degree_turn_renders_as_the_field_on_a_world_lattice():
    """A smooth field f sampled on a grid in the box's own space and placed by
    ``transform = { rotate = [1, 2, 3, 30] }`` (grid A) renders as f sampled on a
    world-aligned lattice over the turned box's bounding box, 0 outside the turned box (grid
    B), up to the stated interpolation error EPS_TAU; a deterministic quadrature of both
    grids' documented lookups along the camera rays shows each within EPS_TAU of f. The same
    grid turned by -30 degrees (the transposed, or inverse, map) fails the same comparison.

    Pixel test: |A - B| <= EPS_TAU + z sqrt(var_A + var_B), each variance of the mean from
    its own film (independent seeds), z the two-sided normal bound at family level ALPHA,
    Bonferroni over the 2 x 576 pixel tests that must pass (A against B; B against the
    quadrature's image of B, which shows the quadrature follows the rays the camera shoots;
    EPS_TAU there also covers the quadrature's 4 x 4 rays a pixel, within 5e-4). The
    allowance EPS_TAU also keeps pixels that only graze the blobs' far tails, where T = 1 to
    1e-9 and the film's variance is 0, from failing a z-test that cannot judge them."""
    from statistics import NormalDist

    turn, wrong = _turn(TURN[:3], TURN[3]), _turn(TURN[:3], -TURN[3])
    lo, hi = SMOOTH_BOX
    n = np.round((hi - lo) / SPACING).astype(int)
    a_grid = _smooth_field(_voxel_centres(lo, hi, n) @ turn.T, turn).astype(np.float32)
    corners = np.array([[(lo, hi)[i][0], (lo, hi)[j][1], (lo, hi)[k][2]]
                        for i in (0, 1) for j in (0, 1) for k in (0, 1)]) @ turn.T
    nw = np.ceil((corners.max(axis=0) - corners.min(axis=0)) / SPACING).astype(int)
    whi = 0.5 * nw * SPACING   # the turned box is centred: [-whi, whi] holds it, in voxels
    wlo = -whi
    centres = _voxel_centres(wlo, whi, nw)
    b_grid = (_smooth_field(centres, turn) * _inside(centres @ turn, lo, hi)).astype(np.float32)
    faces = np.concatenate([_voxel_centres(lo, hi, n)[s].reshape(-1, 3) for s in
                            (np.s_[[0, -1]], np.s_[:, [0, -1]], np.s_[:, :, [0, -1]])])
    assert _smooth_field(faces @ turn.T, turn).max() < 1e-7

    # The quadrature: either grid within EPS_TAU of f (with room for the rays between the
    # quadrature's), the grids within EPS_TAU of each other, the wrong turn far outside.
    def placed(grid, m):   # grid A's density at world points p, placed by the 3x3 turn m
        return lambda p: _trilinear(grid, lo, hi, p @ m) * _inside(p @ m, lo, hi)

    tau = _optical_depths({"f": lambda p: _smooth_field(p, turn) * _inside(p @ turn, lo, hi),
                           "A": placed(a_grid, turn), "wrong": placed(a_grid, wrong),
                           "B": lambda p: _trilinear(b_grid, wlo, whi, p)}, wlo, whi)
    err = {f"{x} - {y}": float(np.abs(tau[x] - tau[y]).max()) for x, y in
           (("A", "f"), ("B", "f"), ("A", "B"), ("wrong", "B"))}
    assert tau["f"].max() > 0.9 and (tau["f"] > 0.1).mean() > 0.2, err   # the blobs in view
    assert err["A - f"] < 0.8 * EPS_TAU and err["B - f"] < 0.8 * EPS_TAU, err
    assert err["A - B"] < 0.2 * EPS_TAU, err
    assert err["wrong - B"] > 50 * EPS_TAU, err

    # The renders (OpenCL): A, B and the wrong turn, independent seeds.
    sa = _transmittance_scene(a_grid, lo, hi, {"rotate": list(TURN)}, seed=1)
    sb = _transmittance_scene(b_grid, wlo, whi, seed=2)
    sw = _transmittance_scene(a_grid, lo, hi, {"rotate": [*TURN[:3], -TURN[3]]}, seed=3)
    assert "TRANSFORM" in features(sa) and "TRANSFORM" not in features(sb)
    ra, rb, rw = (render(s, backend="opencl", progress=False) for s in (sa, sb, sw))
    for r in (ra, rb, rw):
        assert r.counters["capped"] == 0 and r.counters["over_majorant"] == 0
    z = NormalDist().inv_cdf(1.0 - ALPHA / (2 * 2 * 576))
    t_b, var_b = rb.image[..., 0], rb.film.variance_of_mean()[..., 0]

    def outside(r, mean, var):   # pixels of r farther from `mean` than the bound
        diff = np.abs(r.image[..., 0] - mean)
        return diff > EPS_TAU + z * np.sqrt(r.film.variance_of_mean()[..., 0] + var)

    quad_b = np.exp(-tau["B"]).reshape(24, 4, 24, 4).mean(axis=(1, 3))
    assert not outside(rb, quad_b, 0.0).any()
    bad = outside(ra, t_b, var_b)
    assert not bad.any(), (f"{bad.sum()} pixels differ by more than EPS_TAU + {z:.2f} sigma; "
                           f"max |A - B| {np.abs(ra.image[..., 0] - t_b).max():.4f}")
    assert outside(rw, t_b, var_b).sum() > 100   # the negative control fails, and widely
