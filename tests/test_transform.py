"""medium.transform: a medium placed by an affine map (volmc/scene/transform.py).

Quarter turns and mirrors of a grid must render as the rearranged array in a moved box (the
same density at every world point, so the same image from the same random numbers); a
30-degree turn renders alike in the kernels and the float64 reference; the transmittance
through a turned homogeneous box is the closed form exp(-sigma x chord); a transform that
only scales axes and translates is folded into the box (no kernel feature, the same image
bit for bit as the moved box). Image comparisons are volmc.check.compare_images (per-pixel
z-tests at family level ALPHA, Sidak over pixels and channels).
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
