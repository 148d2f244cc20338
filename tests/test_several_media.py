"""Several media ([[media]]): overlapping coefficients add, a real collision picks the medium
by its share of the extinction, one merged majorant-segment iterator walks them all.

Exact cases compare to float32 rounding; statistical ones are z-tests with the render's own
variance of the mean, Sidak-corrected over every pixel and channel (family false-failure
rate ALPHA = 1 %, fixed seeds)."""

import math

import numpy as np
import pytest

from stats import ALPHA, z_bound
from volmc.render import render
from volmc.scene import scene_from_dict
from volmc.scene.errors import SceneError
from volmc.scene.schema import MAX_MEDIA

#: Two slabs overlapping in depth, wider than the view: every orthographic ray down -z
#: crosses 1.5 units of each, 1 unit of them together.
SLAB_A = {"bounds": [[-2, -2, -1.0], [2, 2, 0.5]], "density": 1.0}
SLAB_B = {"bounds": [[-2, -2, -0.5], [2, 2, 1.0]], "density": 1.0}


def _scene(media, lights, spp=64, res=6, render_keys=None, camera=None):
    cam = {"type": "orthographic", "eye": [0.0, 0.0, 3.0], "target": [0, 0, 0], "size": 1.6,
           "resolution": [res, res]}
    return {"camera": dict(cam, **(camera or {})), "media": media, "lights": lights,
            "render": {"spp": spp, **(render_keys or {})}}


def _z(res, expected):
    m = res.film.mean()
    se = np.sqrt(res.film.variance_of_mean())
    return (m - expected) / np.where(se > 0, se, np.inf)


def test_one_medium_in_media_renders_as_medium(backend):
    """[[media]] with one entry is [medium]: the same image bit for bit."""
    med = {"bounds": [[-1, -1, -1], [1, 1, 1]], "density": {"generator": "cloud",
                                                            "resolution": 16}, "scale": 4.0,
           "albedo": 0.8}
    base = _scene([med], [{"type": "directional", "direction": [0, -1, 0], "irradiance": 2.0}],
                  spp=8)
    a = render(scene_from_dict(base), progress=False, backend=backend)
    one = {k: v for k, v in base.items() if k != "media"}
    b = render(scene_from_dict(dict(one, medium=med)), progress=False, backend=backend)
    assert np.array_equal(a.film.sum, b.film.sum)


@pytest.mark.parametrize("grid", [False, True], ids=["constant", "grid"])
def test_overlapping_absorbers_add_their_extinction(backend, grid):
    """Two absorbers overlapping in depth: T = exp(-(s_a 1.5 + s_b 1.5)) on every ray, and
    the alpha channel 1 - T; a constant grid (per-cell majorants merged with the other
    medium's global one) gives the same."""
    sa, sb = 0.7, 1.9
    a = dict(SLAB_A, scale=sa, albedo=0.0)
    b = dict(SLAB_B, scale=sb, albedo=0.0)
    if grid:
        a["density"] = np.ones((5, 7, 6))
    res = render(scene_from_dict(_scene([a, b], [{"type": "environment", "radiance": 1.0}],
                                        spp=4)), progress=False, backend=backend)
    T = math.exp(-(sa + sb) * 1.5)
    np.testing.assert_allclose(res.film.mean(), T, rtol=2e-5)
    np.testing.assert_allclose(res.film.alpha(), 1.0 - T, rtol=2e-5)


@pytest.mark.parametrize("lanes", [1, 16])
def test_media_at_their_majorants_are_not_over_them(lanes):
    """Two overlapping constant media, one stored as a brick grid, under global majorants:
    their extinctions equal their majorants, and float32 rounds the grid's interpolation and
    the media's sum an ulp or so above them. That is no majorant error and is not counted
    (constants.OVER_MAJORANT_SLACK): found by a differential fuzz, where the kernels counted
    2 of 146,858 lookups and the render warned of a biased image (the reference, in float64,
    counted none)."""
    scene = {"camera": {"eye": [0.43, 2.89, -3.28], "fov": 36, "resolution": [9, 14]},
             "media": [{"bounds": [[-0.88, -1.33, -0.37], [0.42, 0.42, 1.21]],
                        "density": 1.9027803802046195, "scale": 3.969962459465923,
                        "albedo": 0.67},
                       {"bounds": [[-1.06, -0.30, -0.61], [0.56, 0.76, 0.71]],
                        "density": np.full((3, 2, 10), 0.52249676, np.float32),
                        "scale": 3.0, "albedo": 0.5}],
             "lights": [{"type": "environment", "radiance": 0.5}],
             "render": {"grid_storage": "bricks", "majorant": "global",
                        "transmittance": "ratio", "spp": 256, "seed": 0}}
    res = render(scene_from_dict(scene), progress=False, backend="opencl", lanes=lanes)
    assert res.counters["lookups"] > 100000 and res.counters["over_majorant"] == 0


def test_white_furnace_with_two_phase_functions(backend):
    """Albedo 1 in two overlapping media of different densities and phase functions,
    unbounded depth: every pixel equals the environment."""
    a = dict(SLAB_A, density={"generator": "cloud", "resolution": 12}, scale=6.0,
             phase={"type": "hg", "g": 0.8})
    b = dict(SLAB_B, scale=2.0, phase={"type": "hg", "g": -0.5},
             transform={"rotate": [1, 1, 0, 25]})
    res = render(scene_from_dict(_scene([a, b], [{"type": "environment", "radiance": 0.5}],
                                        spp=128, render_keys={"max_depth": -1,
                                                              "rr_depth": 1000000})),
                 progress=False, backend=backend)
    z = _z(res, 0.5)
    assert np.abs(z).max() < z_bound(ALPHA, z.size)
    assert res.counters["dropped"] == res.counters["capped"] == 0


def _hg(g, c):
    return (1 - g * g) / (4 * math.pi * (1 + g * g - 2 * g * c) ** 1.5)


def _single_scatter(boxes, light_dir, E, shape, n=4000, equal=False):
    """Single scattering by closed-form transmittances and a midpoint quadrature in depth,
    on every orthographic ray down -z from z = 3 (an image of ``shape``): boxes are (z0, z1,
    sigma, albedo, g) slabs spanning the view, lit by a directional light propagating along
    light_dir (irradiance E). The phase functions mix by each medium's sigma_s; ``equal``:
    by equal shares of the media present instead (what a wrong pick would give)."""
    wl = -np.asarray(light_dir, float) / np.linalg.norm(light_dir)
    d = np.array([0.0, 0.0, -1.0])
    cos = float(d @ wl)
    zlo, zhi = min(b[0] for b in boxes), max(b[1] for b in boxes)
    z = zhi - (np.arange(n) + 0.5) * (zhi - zlo) / n
    dz = (zhi - zlo) / n
    sig = sum(np.where((z >= b[0]) & (z <= b[1]), b[2], 0.0) for b in boxes)
    inside = [((z >= b[0]) & (z <= b[1])).astype(float) for b in boxes]
    sig_s_f = sum(w * b[2] * b[3] * _hg(b[4], cos) for w, b in zip(inside, boxes))
    if equal:
        sig_s_f = sig * sum(w * b[3] * _hg(b[4], cos) for w, b in zip(inside, boxes)) / \
            np.maximum(sum(inside), 1.0)
    tau_cam = np.cumsum(sig * dz) - 0.5 * sig * dz
    # towards the light: the slabs span the view, so only their z faces bound the path
    tau_sun = sum(b[2] * np.clip(b[1] - np.clip(z, b[0], b[1]), 0, None) / wl[2]
                  for b in boxes) if wl[2] > 0 else None
    L = np.sum(np.exp(-tau_cam) * sig_s_f * E * np.exp(-tau_sun)) * dz
    return np.full(shape, L)


def test_a_collision_scatters_with_its_medium_by_share(backend):
    """Single scattering in two overlapping media with different densities, albedos and
    phase functions against the quadrature of the analytically mixed phase function
    sum_i sigma_s,i f_i / sum_i sigma_s,i. The same render must reject the mixture a pick by
    equal shares would give (the test has power)."""
    a = dict(SLAB_A, scale=0.4, albedo=0.9, phase={"type": "hg", "g": 0.7})
    b = dict(SLAB_B, scale=1.3, albedo=0.5, phase={"type": "hg", "g": -0.6})
    light = [0.5, 0.0, -1.0]
    res = render(scene_from_dict(_scene([a, b], [{"type": "directional", "direction": light,
                                                  "irradiance": 3.0}], spp=512,
                                        render_keys={"max_depth": 1})),
                 progress=False, backend=backend)
    boxes = [(-1.0, 0.5, 0.4, 0.9, 0.7), (-0.5, 1.0, 1.3, 0.5, -0.6)]
    expect = _single_scatter(boxes, light, 3.0, (6, 6))
    z = _z(res, expect[..., None])
    bound = z_bound(ALPHA, z.size)
    assert np.abs(z).max() < bound
    # Power, on the image mean (every pixel has the same expectation here): the mixture of
    # a pick by equal shares is rejected, the right one is not.
    wrong = _single_scatter(boxes, light, 3.0, (6, 6), equal=True)
    se = math.sqrt(res.film.variance_of_mean().sum()) / res.film.mean().size
    z_right = (res.film.mean().mean() - expect.mean()) / se
    z_wrong = (res.film.mean().mean() - wrong.mean()) / se
    assert abs(z_right) < z_bound(ALPHA) < abs(z_wrong)


def test_scene_keys_and_errors():
    lights = [{"type": "environment", "radiance": 1.0}]
    s = scene_from_dict(_scene([SLAB_A, dict(SLAB_B, transform={"translate": [0, 0, 3]})],
                               lights))
    assert len(s.media) == 2 and len(s.media_scenes) == 2
    assert s.media[1].transform is not None
    with pytest.raises(SceneError, match="not both"):
        scene_from_dict(dict(_scene([SLAB_A], lights), medium=SLAB_B))
    with pytest.raises(SceneError, match=f"at most {MAX_MEDIA}"):
        scene_from_dict(_scene([SLAB_A] * (MAX_MEDIA + 1), lights))
    with pytest.raises(SceneError, match=r"media\[1\]\.scale"):
        scene_from_dict(_scene([dict(SLAB_A, scale=[1, 2, 3]), dict(SLAB_B, scale=[3, 2, 1])],
                               lights))
    # A black medium has no ratios to share, first or not (it set (1, 1, 1) when first)
    for order in ((0.0, [1, 2, 3], [2, 4, 6]), ([1, 2, 3], 0.0, [2, 4, 6])):
        scene_from_dict(_scene([dict(SLAB_A, scale=k) for k in order], lights))
    with pytest.raises(SceneError, match=r"media\[2\]\.scale: .* differ from media\[1\]'s"):
        scene_from_dict(_scene([dict(SLAB_A, scale=k) for k in (0.0, [1, 2, 3], [3, 2, 1])],
                               lights))
    with pytest.raises(SceneError, match=r"media\[1\]\.density"):
        scene_from_dict(_scene([SLAB_A, dict(SLAB_B, density=-1.0)], lights))
    with pytest.raises(SceneError, match="non-empty"):
        scene_from_dict(_scene([], lights))


def test_cli_names_the_medium_of_bad_input(tmp_path):
    """A singular transform in the second medium: one line naming media[1].transform, exit
    status 2, no traceback."""
    import subprocess
    import sys
    (tmp_path / "two.toml").write_text('''
[camera]
resolution = [4, 4]
[[media]]
bounds = [[-1, -1, -1], [1, 1, 1]]
density = 1.0
[[media]]
bounds = [[-1, -1, -1], [1, 1, 1]]
density = 1.0
transform = { scale = [1, 0, 1] }
''')
    p = subprocess.run([sys.executable, "-m", "volmc.cli", "render", "two.toml", "-o", "x.exr"],
                       cwd=tmp_path, capture_output=True, text=True)
    assert p.returncode == 2
    lines = p.stderr.strip().splitlines()
    assert len(lines) == 1 and "media[1].transform" in lines[0], p.stderr
    assert "Traceback" not in p.stderr and not (tmp_path / "x.exr").exists()


def test_several_media_checkpoint_and_resume(tmp_path):
    """A scene of several media serialises back to itself (what checkpoints and EXR metadata
    store), resumes a checkpoint to the uninterrupted render's sums bit for bit, and refuses
    a checkpoint whose second medium differs."""
    from volmc.resources import scenes_dir
    from volmc.scene import load_scene
    from volmc.scene.schema import validate
    from volmc.scene.serialize import to_dict
    path = scenes_dir() / "tests" / "media.toml"
    scene = load_scene(path, ["camera.resolution=[6, 6]"])
    spec = scene.spec
    assert validate(to_dict(spec), spec.file) == spec
    full = render(scene, backend="opencl", spp=8, progress=False, chunk_samples=1)
    ck = tmp_path / "ck.npz"
    render(scene, backend="opencl", spp=3, progress=False, checkpoint=str(ck), chunk_samples=1)
    res = render(scene, backend="opencl", spp=8, progress=False, resume=str(ck),
                 chunk_samples=1)
    np.testing.assert_array_equal(res.film.sum, full.film.sum)
    other = load_scene(path, ["camera.resolution=[6, 6]", "media.1.albedo=0.6"])
    with pytest.raises(SceneError):
        render(other, backend="opencl", spp=8, progress=False, resume=str(ck),
               chunk_samples=1)


_NEAR_SRC = """
#include "lane_io.h"
#include "medium.h"
/* Per ray (6 floats: o, d): the media whose near box the ray [0, inf) touches
 * (media_near), and those whose own box it crosses by the kernels' exact test (ray_box in
 * the medium's space, as enter_media uses it). */
kernel void t_media_near(global const Medium *media, global const float *rays,
                         global uint *out, int n) {
    lmask on;
    lint i = lane_element(n, &on);
    MediumData med;
    for (int k = 0; k < MEDIA_COUNT; ++k) med.m[k] = media[k];
    lvec3 o = load_float3(rays, i, 6, 0), d = load_float3(rays, i, 6, 3);
    lint near = media_near(&med, o, d, (lfloat)(0.0f), (lfloat)(FLT_MAX), on);
    lint hit = (lint)(0);
    for (int k = 0; k < MEDIA_COUNT; ++k) {
        const Medium *m = &med.m[k];
        lfloat tx;
        lfloat te = ray_box(to_medium(m, o), to_medium_dir(m, d), vec3(m->bmin), vec3(m->bmax),
                            &tx);
        hit = hit | select((lint)(0), (lint)(1 << k), (tx >= te) & (tx >= 0.0f));
    }
    store_uint(out, i, 2, 0, as_luint(near), on);
    store_uint(out, i, 2, 1, as_luint(hit), on);
}
"""

#: Media for the near-box tests: a turned and mirrored box, a tiny one far off the frame's
#: centre, a thin slab, and a plain box (scene units).
_NEAR_MEDIA = [
    {"bounds": [[-1, -1, -1], [1, 1, 1]], "density": 1.0,
     "transform": {"rotate": [[1, 2, 0.5, 37.0]], "scale": [1.2, -0.7, 0.9],
                   "translate": [0.3, 0.1, -0.2]}},
    {"bounds": [[40.0, 40.0, 40.0], [40.01, 40.02, 40.01]], "density": 1.0},
    {"bounds": [[-30, -0.5, -30], [30, -0.49, 30]], "density": 1.0},
    {"bounds": [[2, -3, 1], [4, -1, 2]], "density": 1.0},
]


def _near_rays(pk, n, rng):
    """Rays in the scene frame: aimed at random points of each medium's box (placed), and a
    quarter of them grazing a face, an edge or a corner of it; from near and from 1000 box
    sizes away; a tenth with one or two direction components exactly 0 (or -0)."""
    out = np.empty((n, 6))
    recs = pk.medium
    for r in range(n):
        m = recs[r % len(recs)]
        lo, hi = np.array(m["bmin"], float), np.array(m["bmax"], float)
        q = lo + rng.random(3) * (hi - lo)
        if r % 4 == 0:   # onto the surface: some coordinates at a face
            for a in rng.choice(3, rng.integers(1, 4), replace=False):
                q[a] = lo[a] if rng.random() < 0.5 else hi[a]
        if m["transformed"]:   # medium space to the scene frame
            x = np.array(m["xform"], float).reshape(3, 4)
            q = np.linalg.solve(x[:, :3], q - x[:, 3])
        d = rng.normal(size=3)
        if r % 10 == 3:
            d[rng.choice(3, rng.integers(1, 3), replace=False)] = 0.0 if r % 20 == 3 else -0.0
        d /= np.linalg.norm(d)
        far = 1000.0 if r % 3 == 0 else 3.0
        out[r, :3] = q - far * rng.random() * d
        out[r, 3:] = d
    return out


def test_near_boxes_never_miss_a_box_the_exact_test_hits(lanes):
    """media_near is a cull: every medium whose box the kernels' own slab test finds on a ray
    (float32, in the medium's space, grazing faces, edges and corners, axis-parallel rays,
    origins 1000 box sizes away) is in the ray's near set, in the kernels at every lane
    width and in the reference; and it culls: a ray aimed at one medium is near few others."""
    from cl_harness import build_source, out_buf, run_kernel, to_dev
    from volmc.pack import pack_scene
    from volmc.reference.medium import media_data, media_near, ray_box, to_medium, \
        to_medium_dir
    raw = _scene(_NEAR_MEDIA, [{"type": "environment", "radiance": 1.0}])
    sc = scene_from_dict(raw)
    n_media = len(_NEAR_MEDIA)
    pk32, pk64 = pack_scene(sc, np.float32), pack_scene(sc, np.float64)
    rays = _near_rays(pk64, 4000, np.random.default_rng(3))
    prg = build_source("t_media_near.cl", _NEAR_SRC, (f"-DMEDIA_COUNT={n_media}",))
    out, ob = out_buf((len(rays), 2), np.uint32)
    run_kernel(prg, "t_media_near", len(rays), to_dev(pk32.medium),
               to_dev(rays.astype(np.float32)), ob, outs=[(out, ob)])
    near, hit = out[:, 0], out[:, 1]
    assert np.all(hit & ~near == 0), np.flatnonzero(hit & ~near)[:10]
    assert (hit != 0).mean() > 0.9   # the rays do reach their media
    # It culls: of the (ray, medium) pairs that miss, few are near.
    bits = 1 << np.arange(n_media, dtype=np.uint32)
    missed = (hit[:, None] & bits) == 0
    kept = ((near[:, None] & bits) != 0) & missed
    assert kept.sum() < 0.1 * missed.sum()
    med = media_data(pk64)[:n_media]
    for r in range(0, len(rays), 7):   # the reference, float64, against its own exact test
        o, d = tuple(rays[r, :3]), tuple(rays[r, 3:])
        bits = media_near(med, o, d, 0.0, math.inf)
        for i in range(n_media):
            m = med[i].m
            te, tx = ray_box(to_medium(m, o), to_medium_dir(m, d), m["bmin"], m["bmax"])
            if tx >= te and tx >= 0.0:
                assert (bits >> i) & 1, (r, i)


@pytest.mark.parametrize("far", [1e6, 1e8])
def test_a_medium_far_away_leaves_the_near_one_rendered(far):
    """A grid cloud at the origin and a haze box `far` away behind the camera: the kernels
    agree with the reference, and with the cloud rendered alone. The frame was the box
    around both, whose centre sat far / 2 from the cloud, where float32 cannot place it:
    the kernels rendered the bare sky (pack.scene_frame)."""
    from volmc.check import check_scene
    rng = np.random.default_rng(3)
    cloud = {"bounds": [[-1, -1, -1], [1, 1, 1]], "density": rng.random((8, 8, 8)) * 2.0,
             "albedo": 0.0}
    haze = {"bounds": [[-1, -1, far - 1], [1, 1, far + 1]], "density": 1.0, "albedo": 0.0}
    raw = {"camera": {"eye": [0.3, 0.2, 4.0], "target": [0, 0, 0], "fov": 40,
                      "resolution": [16, 16]},
           "lights": [{"type": "environment", "radiance": 0.8}],
           "render": {"spp": 64, "max_depth": 4}}
    both = scene_from_dict({**raw, "media": [cloud, haze]})
    cmp, a, _ = check_scene(both)
    assert cmp.passed, cmp.summary()
    alone = render(scene_from_dict({**raw, "medium": cloud,
                                    "render": {**raw["render"], "seed": 9}}),
                   backend="opencl", progress=False)
    diff = a.film.mean() - alone.film.mean()
    se = np.sqrt(a.film.variance_of_mean() + alone.film.variance_of_mean())
    assert abs(diff.mean()) < 4.0 * np.sqrt((se ** 2).sum()) / diff.size, diff.mean()


def test_a_far_medium_in_view_renders_in_the_near_ones_frame():
    """The camera sees a cloud near it and, far behind it, a wide absorbing haze slab 1e6
    away: in the near box's frame the far slab still dims the sky by its exact exp(-tau)
    where no cloud is in front, and the kernels agree with the reference."""
    from volmc.check import check_scene
    rng = np.random.default_rng(4)
    cloud = {"bounds": [[-0.5, -0.5, -0.5], [0.5, 0.5, 0.5]],
             "density": rng.random((6, 6, 6)) * 3.0, "albedo": 0.0}
    haze = {"bounds": [[-1e6, -1e6, -1e6 - 1e4], [1e6, 1e6, -1e6 + 1e4]], "density": 1e-4,
            "albedo": 0.0}
    scene = scene_from_dict({"camera": {"eye": [0.0, 0.0, 4.0], "target": [0, 0, 0],
                                        "fov": 40, "resolution": [16, 16]},
                             "media": [cloud, haze],
                             "lights": [{"type": "environment", "radiance": 0.8}],
                             "render": {"spp": 32, "max_depth": 2}})
    cmp, a, _ = check_scene(scene)
    assert cmp.passed, cmp.summary()
    # A pixel the cloud does not cover: the slab's optical depth 2 along z, over the cosine
    # of the pixel centre's ray (fov is vertical, the image square; the pixel's own spread
    # of angles is within the tolerance).
    x = math.tan(math.radians(20.0)) * 15.0 / 16.0
    expected = 0.8 * math.exp(-2.0 * math.sqrt(1.0 + 2.0 * x * x))
    np.testing.assert_allclose(a.film.mean()[0, 0, :3], expected, rtol=0.02)
