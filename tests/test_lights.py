"""Sun discs, spot lights and sphere lights (volmc/reference/lights.py): the direction
samplers against their densities (chi-square over (cos, phi) cells, Sidak over the cases at
family level ALPHA, fixed seeds), the pdfs at the samples, the inverse, the kernels against
the reference, and renders against closed forms and quadratures: a small sun converges to the
parallel one, a spot in fog matches a single-scattering quadrature of its cone and falloff, a
small far sphere is a point lamp of equal power, a sphere is opaque and visible, and every
way of combining light and phase sampling renders the same image."""

import math

import numpy as np
import pytest
from numba import njit

from stats import ALPHA, chi2_pvalue, cos_phi_bins, direction_cos_phi, sidak
from volmc.check import compare_images
from volmc.pack import pack_scene
from volmc.reference.lights import (sample_area_light, sphere_hit, sphere_light_pdf,
                                    spot_falloff)
from volmc.reference.rng import uniforms
from volmc.reference.sampling import cone_pdf, invert_cone, sample_cone
from volmc.render import render
from volmc.scene import scene_from_dict, validate
from volmc.scene.errors import SceneError
from volmc.scene.serialize import to_dict

N = 400_000
BOX = [[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]]


def _lights(lights):
    """The packed light records (float64, float32) of a fog box lit by ``lights``."""
    sc = scene_from_dict({"camera": {"eye": [0, 0, 3], "target": [0, 0, 0],
                                     "resolution": [4, 4]},
                          "medium": {"bounds": BOX, "density": 1.0}, "lights": lights})
    return pack_scene(sc).lights, pack_scene(sc, np.float32).lights


@njit(cache=True)
def _sample(lights, i, p, u):
    """Directions sample_area_light draws from p with the uniforms u, their pdfs, distances,
    and the density functions' values at them (cone_pdf for a sun, sphere_light_pdf along
    sphere_hit for a sphere)."""
    n = u.shape[0] // 2
    dirs = np.empty((n, 3))
    out = np.empty((n, 4))
    lt = lights[i]
    pt = (p[0], p[1], p[2])
    for k in range(n):
        w, dist, pdf, _ = sample_area_light(lt, pt, u[2 * k], u[2 * k + 1])
        dirs[k, 0], dirs[k, 1], dirs[k, 2] = w
        if lt.type == 0:
            f = cone_pdf(w, (-lt.vec[0], -lt.vec[1], -lt.vec[2]), lt.size)
            t = math.inf
        else:
            t = sphere_hit(lt, pt, w)
            f = sphere_light_pdf(lt, pt, w, t)
        out[k, 0], out[k, 1], out[k, 2], out[k, 3] = pdf, f, dist, t
    return dirs, out


@njit(cache=True)
def _density_along(lights, i, p, axis, mu):
    """sphere_light_pdf from p at the directions of cosine mu about axis (phi = 0)."""
    lt = lights[i]
    pt = (p[0], p[1], p[2])
    out = np.empty(mu.shape[0])
    ax = (axis[0], axis[1], axis[2])
    for k in range(mu.shape[0]):
        s = math.sqrt(max(0.0, 1.0 - mu[k] * mu[k]))
        # any unit vector at angle acos(mu) from the axis: the density is symmetric about it
        h = (1.0, 0.0, 0.0) if abs(ax[0]) < 0.9 else (0.0, 1.0, 0.0)
        c = (ax[1] * h[2] - ax[2] * h[1], ax[2] * h[0] - ax[0] * h[2],
             ax[0] * h[1] - ax[1] * h[0])
        cn = math.sqrt(c[0] ** 2 + c[1] ** 2 + c[2] ** 2)
        w = (mu[k] * ax[0] + s * c[0] / cn, mu[k] * ax[1] + s * c[1] / cn,
             mu[k] * ax[2] + s * c[2] / cn)
        t = sphere_hit(lt, pt, w)
        out[k] = sphere_light_pdf(lt, pt, w, t) if t < math.inf else 0.0
    return out


SUN = {"type": "directional", "direction": [0.36, -0.8, -0.48], "irradiance": 2.0,
       "angle": 24.0}
SPHERE = {"type": "sphere", "position": [0.2, 0.1, -0.3], "radius": 0.5, "radiance": 1.0}
SPOT = {"type": "spot", "position": [0.0, 1.6, 0.0], "direction": [0.0, -1.0, 0.0],
        "intensity": 2.0, "angle": 35.0, "blend": 0.4}

#: (name, light, point): a sun's cone; a sphere from outside (its cone) and from inside
#: (by area, a density that varies with direction).
CASES = [("sun", SUN, (0.0, 0.0, 0.0)),
         ("sphere outside", SPHERE, (1.1, 0.6, 0.4)),
         ("sphere inside", SPHERE, (0.45, 0.1, -0.3))]


def _axis(light, p):
    if light["type"] == "directional":
        a = -np.asarray(light["direction"], float)
    else:
        a = np.asarray(light["position"], float) - np.asarray(p)
    return a / np.linalg.norm(a)


def test_area_light_sampling_matches_its_density_chi_square():
    """Each case's directions against its density over (cos, phi) cells about the axis
    through the light (for the sphere from inside, the axis through the centre: its density
    is symmetric about it), Sidak over the cases."""
    a = sidak(ALPHA, len(CASES))
    for k, (name, light, p) in enumerate(CASES):
        recs, _ = _lights([light])
        axis = _axis(light, p)
        dirs, _ = _sample(recs, 0, np.asarray(p, float), uniforms(21, k, 0, 2, 2 * N))
        mu, phi = direction_cos_phi(dirs, axis)
        pj = np.minimum((phi / (2 * math.pi) * 12).astype(int), 11)
        if name != "sphere inside":
            # Uniform in a cone: equal cells of x = 1 - cos theta = |w - axis|^2 / 2 in
            # [0, omc] and of phi hold equal probability (the cone's edge is a cell edge).
            omc = recs[0]["size"] if light["type"] == "directional" else \
                1.0 - math.sqrt(1.0 - light["radius"] ** 2 / np.sum((axis * 0 + np.asarray(
                    light["position"]) - p) ** 2))
            x = 0.5 * np.sum((dirs - axis) ** 2, axis=1) / omc
            assert x.max() <= 1.0 + 1e-9, name   # nothing outside the cone
            ci = np.minimum((x * 30).astype(int), 29)
            expected = np.full((30, 12), len(dirs) / 360.0)
        else:
            pdf_cos = lambda mu: _density_along(recs, 0, np.asarray(p, float), axis,  # noqa
                                                np.asarray(mu, float))
            edges, expected = cos_phi_bins(pdf_cos, 30, 12, len(dirs), quad_nodes=48)
            assert abs(expected.sum() / len(dirs) - 1.0) < 1e-3   # the density integrates
            ci = np.clip(np.searchsorted(edges, mu, side="right") - 1, 0, len(edges) - 2)
        observed = np.bincount(ci * 12 + pj, minlength=expected.size).reshape(expected.shape)
        pv = chi2_pvalue(observed, expected)[0]
        assert pv > a, f"{name}: p = {pv:.3g}"


def test_sampled_pdfs_distances_and_inverse():
    """The pdf a sample reports is the density function's value there; a sphere sample's
    distance is where its ray meets the sphere; invert_cone undoes sample_cone."""
    for k, (name, light, p) in enumerate(CASES):
        recs, _ = _lights([light])
        _, out = _sample(recs, 0, np.asarray(p, float), uniforms(22, k, 0, 2, 20000))
        ok = out[:, 0] > 0
        assert ok.mean() > 0.999, name
        assert np.allclose(out[ok, 0], out[ok, 1], rtol=1e-6), name
        if light["type"] == "sphere":
            assert np.allclose(out[ok, 2], out[ok, 3], rtol=1e-6, atol=1e-9), name
    axis = (0.36, -0.48, 0.8)
    u = uniforms(23, 0, 0, 2, 2000).reshape(-1, 2)
    for omc in (4.3e-5, 0.1, 1.0, 2.0):
        for u1, u2 in u:
            w, pdf = sample_cone(u1, u2, axis, omc)
            assert math.isclose(pdf, 1.0 / (2 * math.pi * omc))
            assert cone_pdf(w, axis, omc) == pdf or 0.5 * np.sum((np.array(w) - axis) ** 2) \
                > omc * (1 - 1e-9)
            v1, v2 = invert_cone(w, axis, omc)
            assert abs(v1 - u1) < 1e-6 and min(abs(v2 - u2), 1 - abs(v2 - u2)) < 1e-6


def test_kernel_lights_match_the_reference():
    """kernels/lights.h and the cone sampler of sampling.h (float32, the default lane width)
    against the reference on the same inputs: sampled directions, distances, pdfs and
    radiances, sphere_hit, sphere_light_pdf and spot_falloff."""
    import cl_harness
    rng = np.random.default_rng(5)
    n = 3000
    us = rng.random((n, 2)).astype(np.float32)
    out, ob = cl_harness.out_buf((n, 6))
    inv, ib = cl_harness.out_buf((n, 2))
    axis = np.array([0.36, -0.48, 0.8])
    omc = 0.05
    cl_harness.run("t_cone", n, cl_harness.to_dev(us.ravel()), cl_harness.f3(axis),
                   np.float32(omc), ob, ib, outs=[(out, ob), (inv, ib)])
    for i in range(n):
        w, pdf = sample_cone(float(us[i, 0]), float(us[i, 1]), tuple(axis), omc)
        assert np.allclose(out[i, :3], w, atol=3e-6) and math.isclose(out[i, 3], pdf,
                                                                       rel_tol=1e-5)
    assert np.allclose(inv, us, atol=2e-4)
    for light in (SUN, SPHERE, SPOT):
        r64, r32 = _lights([light])
        p = rng.uniform(-1.5, 1.5, (n, 3))
        w = rng.normal(size=(n, 3))
        w /= np.linalg.norm(w, axis=1, keepdims=True)
        if light["type"] == "sphere":   # half the rays aimed at the sphere
            aim = np.asarray(light["position"]) + rng.uniform(-0.4, 0.4, (n, 3)) - p
            w[::2] = (aim / np.linalg.norm(aim, axis=1, keepdims=True))[::2]
        inp = np.concatenate([p, us, w], axis=1).astype(np.float32)
        o, obuf = cl_harness.out_buf((n, 12))
        cl_harness.run("t_lights", n, cl_harness.to_dev(r32), np.int32(0),
                       cl_harness.to_dev(inp.ravel()), obuf, outs=[(o, obuf)])
        lt = r64[0]
        for i in range(n):
            pi, wi = tuple(float(x) for x in inp[i, :3]), tuple(float(x) for x in inp[i, 5:])
            if light["type"] == "spot":
                ref = spot_falloff(lt, wi)
                assert abs(o[i, 8] - ref) < 2e-4, (i, o[i, 8], ref)
                continue
            ws, dist, pdf, le = sample_area_light(lt, pi, float(us[i, 0]), float(us[i, 1]))
            assert math.isclose(o[i, 5], le, rel_tol=1e-5)
            if pdf > 0:
                assert np.allclose(o[i, :3], ws, atol=2e-5), (light["type"], i)
                assert math.isclose(o[i, 4], pdf, rel_tol=1e-3), (light["type"], i)
                if math.isfinite(dist):
                    assert abs(o[i, 3] - dist) < 2e-4 * max(1.0, dist), i
            if light["type"] == "sphere":
                t = sphere_hit(lt, pi, wi)
                if math.isinf(t):
                    assert o[i, 6] > 1e37, i
                else:
                    assert abs(o[i, 6] - t) < 2e-4 * max(1.0, t), (i, o[i, 6], t)
                    ref = sphere_light_pdf(lt, pi, wi, t)
                    assert math.isclose(o[i, 7], ref, rel_tol=2e-3) or abs(o[i, 7] - ref) \
                        < 1e-3 * max(o[i, 7], ref), (i, o[i, 7], ref)


def _ortho(lights, medium, spp, seed, **render_keys):
    return scene_from_dict({
        "camera": {"type": "orthographic", "eye": [0.0, 0.0, 3.0], "target": [0, 0, 0],
                   "size": 2.0, "resolution": [12, 12]},
        "medium": dict({"bounds": BOX}, **medium), "lights": lights,
        "render": dict({"spp": spp, "seed": seed}, **render_keys)})


def _agree(a, b, alpha=ALPHA):
    c = compare_images(a.film.mean()[..., :3], a.film.variance_of_mean()[..., :3],
                       b.film.mean()[..., :3], b.film.variance_of_mean()[..., :3], alpha=alpha)
    assert c.passed, c.summary()


def test_small_sun_converges_to_the_parallel_sun(backend):
    """Single scattering under a sun of apex 1 degree renders what the parallel sun of the
    same irradiance renders (per-pixel z-tests)."""
    medium = {"density": 1.0, "scale": 0.7, "albedo": 0.8, "phase": {"type": "hg", "g": 0.5}}
    sun = {"type": "directional", "direction": [0.2, -1.0, 0.1], "irradiance": 3.0}
    a = render(_ortho([sun], medium, 512, 1, max_depth=2), progress=False, backend=backend)
    b = render(_ortho([dict(sun, angle=1.0)], medium, 512, 2, max_depth=2), progress=False,
               backend=backend)
    _agree(a, b)


def _spot_quadrature(sigma, albedo, light, res=12, nodes=96, sub=6):
    """Single scattering of a spot above the box [-1, 1]^3 seen by the orthographic camera of
    _ortho (rays along -z from z = 1): per pixel the mean over sub x sub Gauss points of
    int_0^2 sigma_s f I falloff e^{-sigma t} e^{-sigma l} / r^2 dt, l the light path's length
    inside the box (it leaves through the top face y = 1), isotropic phase f = 1 / (4 pi)."""
    c = np.asarray(light["position"], float)
    ax = np.asarray(light["direction"], float)
    ax /= np.linalg.norm(ax)
    cos_o = math.cos(math.radians(light["angle"]))
    cos_i = cos_o + light["blend"] * (1 - cos_o)
    xg, wg = np.polynomial.legendre.leggauss(nodes)
    t = 1.0 + xg            # [0, 2]
    sx, sw = np.polynomial.legendre.leggauss(sub)
    img = np.zeros((res, res))
    h = 2.0 / res
    for j in range(res):
        for i in range(res):
            acc = 0.0
            for a, wa in zip(sx, sw):
                for b, wb in zip(sx, sw):
                    x = -1 + (i + 0.5 + 0.5 * a) * h
                    y = 1 - (j + 0.5 + 0.5 * b) * h
                    q = np.stack([np.full_like(t, x), np.full_like(t, y), 1.0 - t], axis=1)
                    v = c - q
                    r = np.linalg.norm(v, axis=1)
                    cos_t = -(v / r[:, None]) @ ax
                    s = np.clip((cos_t - cos_o) / max(cos_i - cos_o, 1e-300), 0, 1)
                    fall = np.where(cos_t >= cos_i, 1.0, np.where(cos_t <= cos_o, 0.0,
                                                                   s * s * (3 - 2 * s)))
                    ell = r * (1.0 - y) / (c[1] - y)
                    g = albedo * sigma / (4 * math.pi) * light["intensity"] * fall * \
                        np.exp(-sigma * (t + ell)) / r ** 2
                    acc += wa * wb * 0.25 * np.sum(wg * g)
            img[j, i] = acc
    return img


@pytest.mark.parametrize("equiangular", [False, True])
def test_spot_in_fog_matches_single_scattering_quadrature(backend, equiangular):
    """A spot with a blended edge above a homogeneous fog box: every pixel of a max_depth 1
    render agrees with the quadrature of the cone and its falloff (z-tests, Sidak over the
    pixels), by next-event estimation alone and with equiangular sampling."""
    sigma, albedo = 0.8, 0.9
    res = render(_ortho([SPOT], {"density": 1.0, "scale": sigma, "albedo": albedo}, 1024, 4,
                        max_depth=1, equiangular=equiangular),
                 progress=False, backend=backend)
    exp = _spot_quadrature(sigma, albedo, SPOT)
    assert exp.max() > 0.02 and (exp == 0).mean() > 0.05   # lit and unlit pixels
    # A pixel the cone's edge barely touches (expected under 1e-3 of the brightest) gets a
    # lit sample so rarely that its variance estimate is no guide: the normal approximation
    # of the z-test needs many contributing samples. The others are tested.
    keep = (exp == 0) | (exp > 1e-3 * exp.max())
    assert keep.mean() > 0.95
    e = np.repeat(exp[keep][:, None, None], 3, axis=2)
    c = compare_images(res.film.mean()[keep][:, None, :3],
                       res.film.variance_of_mean()[keep][:, None, :3], e, np.zeros_like(e),
                       alpha=ALPHA / 2)
    assert c.passed, c.summary()


def test_small_far_sphere_is_a_point_lamp_of_equal_power(backend):
    """A sphere of radius 0.01 (power P) 2.5 units above a cloud renders as a point lamp of
    intensity P / (4 pi): the two differ by O((r / d)^2) = 2e-5, far below the noise."""
    medium = {"density": 1.2, "albedo": 0.9, "phase": {"type": "hg", "g": 0.3}}
    pos = [0.3, 2.5, 0.4]
    a = render(_ortho([{"type": "sphere", "position": pos, "radius": 0.01, "power": 40.0}],
                      medium, 256, 1, max_depth=4), progress=False, backend=backend)
    b = render(_ortho([{"type": "point", "position": pos, "intensity": 40.0 / (4 * math.pi)}],
                      medium, 256, 2, max_depth=4), progress=False, backend=backend)
    assert a.film.mean()[..., :3].mean() > 0.01
    _agree(a, b)


def test_sphere_is_opaque_and_seen(backend):
    """Camera rays through empty space see a sphere's radiance exactly, with coverage 1,
    and the environment around it; a point lamp inside a black sphere lights nothing."""
    sphere = {"type": "sphere", "position": [0.0, 0.0, 0.0], "radius": 0.5,
              "radiance": [1.0, 2.0, 3.0]}
    sc = _ortho([sphere, {"type": "environment", "radiance": 0.25}], {"density": 0.0}, 8, 1)
    r = render(sc, progress=False, backend=backend)
    x = -1 + (np.arange(12) + 0.5) * 2 / 12
    r2 = x[None, :] ** 2 + x[::-1, None] ** 2   # pixel centres; half a diagonal is 0.118
    inside, outside = r2 < 0.38 ** 2, r2 > 0.62 ** 2
    m = r.film.mean()
    assert np.allclose(m[inside, :3], [1.0, 2.0, 3.0], rtol=1e-6)
    assert np.allclose(r.alpha[inside], 1.0) and np.allclose(r.alpha[outside], 0.0)
    assert np.allclose(m[outside, :3], 0.25, rtol=1e-6)
    fog = {"density": 1.0, "albedo": 0.9}
    lamp = {"type": "point", "position": [0.0, 0.0, 0.0], "intensity": 5.0}
    black = dict(sphere, radius=0.2, radiance=0.0)
    for eq in (False, True):
        dark = render(_ortho([lamp, black], fog, 32, 3, equiangular=eq), progress=False,
                      backend=backend)
        assert np.all(dark.film.mean()[..., :3] == 0.0)
    lit = render(_ortho([lamp], fog, 32, 3), progress=False, backend=backend)
    assert lit.film.mean()[..., :3].min() > 0.0


def _lit(seed, **keys):
    """A cloud under a wide sun, a spot, a sphere inside the box and a dim sky."""
    return scene_from_dict({
        "camera": {"eye": [0.0, 0.4, 4.0], "target": [0, 0, 0], "fov": 45.0,
                   "resolution": [10, 10]},
        "medium": {"bounds": BOX, "density": 1.2, "albedo": 0.9,
                   "phase": {"type": "hg", "g": 0.4}},
        "lights": [{"type": "directional", "direction": [0.3, -1.0, 0.2], "irradiance": 2.0,
                    "angle": 30.0},
                   dict(SPOT, position=[0.0, 1.8, 0.5], intensity=[6.0, 5.0, 4.0]),
                   {"type": "sphere", "position": [0.6, -0.3, 0.2], "radius": 0.3,
                    "power": 20.0},
                   {"type": "environment", "radiance": 0.1}],
        "render": dict({"spp": 256, "seed": seed, "max_depth": 6}, **keys)})


def test_light_and_phase_sampling_combine_without_bias():
    """The same lit cloud by the OpenCL kernel with the balance and power heuristics, three
    light samples, the Sobol sampler and equiangular sampling, and by the Numba reference:
    every image agrees with the first (z-tests, Sidak over the comparisons). An area light's
    radiance seen by a phase-sampled ray and its light-sampled estimate must agree for this."""
    variants = [{}, {"mis": "power"}, {"light_samples": 3}, {"sampler": "sobol"},
                {"equiangular": True}]
    res = [render(_lit(10 + i, **k), progress=False, backend="opencl")
           for i, k in enumerate(variants)]
    res.append(render(_lit(20), progress=False, backend="numba"))
    for r in res[1:]:
        _agree(r, res[0], ALPHA / (len(res) - 1))


@pytest.mark.parametrize("light, key, words", [
    (dict(SUN, angle=180.0), "angle", "below 180"),
    (dict(SUN, angle=1e-30), "angle", "overflows"),
    (dict(SPOT, angle=0.0), "angle", "(0, 180]"),
    (dict(SPOT, blend=1.5), "blend", "[0, 1]"),
    ({k: v for k, v in SPOT.items() if k != "angle"}, "angle", "missing"),
    (dict(SPHERE, radius=0.0), "radius", "> 0"),
    # squared in float32 by the kernels: 1e20 rendered black, 1e-20 NaN
    (dict(SPHERE, radius=1e20), "radius", "a normal float32"),
    (dict(SPHERE, radius=1e-20), "radius", "a normal float32"),
    (dict(SPHERE, power=3.0), "radiance", "exactly one"),
    ({k: v for k, v in SPHERE.items() if k != "radiance"}, "radiance", "exactly one"),
    (dict(SPOT, direction=[0, 0, 0]), "direction", ""),
])
def test_bad_light_keys(light, key, words):
    with pytest.raises(SceneError) as e:
        _lights([light])
    assert e.value.key == f"lights[0].{key}" and words in str(e.value)


def test_new_lights_serialise_back_to_themselves():
    sc = _lit(1)
    assert validate(to_dict(sc.spec), sc.spec.file) == sc.spec


@pytest.mark.parametrize("light, words", [(SUN, "a sun disc"), (SPOT, "a spot light"),
                                          (SPHERE, "a sphere light")])
def test_cycles_peer_refuses_the_new_lights(light, words):
    from volmc.peers.cycles import check_translatable
    from volmc.peers.errors import PeerUnavailable
    sc = scene_from_dict({"camera": {"eye": [0, 0, 3], "target": [0, 0, 0],
                                     "resolution": [4, 4]},
                          "medium": {"bounds": BOX, "density": 1.0}, "lights": [light]})
    with pytest.raises(PeerUnavailable, match=words):
        check_translatable(sc)


def test_cli_refuses_a_bad_light_with_exit_status_2(tmp_path):
    import subprocess
    import sys
    scene = tmp_path / "s.toml"
    scene.write_text('[camera]\n[medium]\ndensity = 1.0\nbounds = [[0, 0, 0], [1, 1, 1]]\n'
                     '[[lights]]\ntype = "sphere"\nposition = [0, 2, 0]\nradius = -1.0\n'
                     'radiance = 1.0\n')
    r = subprocess.run([sys.executable, "-m", "volmc.cli", "render", str(scene), "-o",
                        str(tmp_path / "out.exr")], capture_output=True, text=True)
    assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1
    assert "s.toml" in r.stderr and "lights[0].radius" in r.stderr
    assert not (tmp_path / "out.exr").exists()


def test_inside_a_sphere_light_every_pixel_is_its_radiance(backend):
    """A furnace: the camera and a scattering box (albedo 1) inside a sphere light of
    radiance L. Every path ends on the sphere's inside, so every pixel is L in expectation
    (z-tests against L), whatever the medium does: next-event estimation samples the sphere
    by area from inside and phase-sampled rays find it, weighed by MIS."""
    L = [0.5, 1.0, 1.5]
    sc = scene_from_dict({
        "camera": {"eye": [0.0, 0.3, 2.4], "target": [0, 0, 0], "fov": 60.0,
                   "resolution": [10, 10]},
        "medium": {"bounds": BOX, "density": 1.5, "albedo": 1.0,
                   "phase": {"type": "hg", "g": 0.5}},
        "lights": [{"type": "sphere", "position": [0.0, 0.0, 0.0], "radius": 3.0,
                    "radiance": L}],
        "render": {"spp": 256, "seed": 5, "max_depth": -1}})
    r = render(sc, progress=False, backend=backend)
    e = np.broadcast_to(np.asarray(L, float), (10, 10, 3))
    assert r.film.variance_of_mean()[..., :3].max() > 0   # the box is seen and scatters
    c = compare_images(r.film.mean()[..., :3], r.film.variance_of_mean()[..., :3], e,
                       np.zeros_like(e))
    assert c.passed, c.summary()


def test_wide_sun_disc_has_the_radiance_of_its_irradiance(backend):
    """The absolute radiance of a wide sun disc (apex 120 degrees: theta = 60), against a
    closed form. A horizontal slab of thickness h (wide enough that every light path leaves
    through its top), the sun overhead, an orthographic camera looking straight down,
    single scattering (max_depth 1), isotropic phase, albedo 1. The disc's radiance is
    L = E / (pi sin^2 theta) (E measured at right angles to the sun), so at depth s

        L_pix = int_0^h sigma e^{-sigma s} / (4 pi) int_cone L e^{-sigma s / mu} dw ds
              = L / 2 int_cos(theta)^1 (1 - e^{-tau (1 + 1/mu)}) / (1 + 1/mu) dmu,

    tau = sigma h (Gauss-Legendre to machine precision). Without the attenuation the cone
    integral of L is E 2 / (1 + cos theta): a radiance of E / (2 pi (1 - cos theta))
    renders (1 + cos theta) / 2 = 0.75 of this. The image mean is z-tested against it with
    the render's variance (pixels are independent), Sidak over the three channels."""
    from volmc.check import ROUNDING_REL
    from stats import z_bound
    E, theta, sigma, h = 2.0, math.radians(60.0), 2.0, 0.5
    sc = scene_from_dict({
        "camera": {"type": "orthographic", "eye": [0.0, 2.0, 0.0], "target": [0, 0, 0],
                   "up": [0.0, 0.0, -1.0], "size": 2.0, "resolution": [8, 8]},
        "medium": {"bounds": [[-3.0, -h / 2, -3.0], [3.0, h / 2, 3.0]], "density": 1.0,
                   "scale": sigma, "albedo": 1.0},
        "lights": [{"type": "directional", "direction": [0.0, -1.0, 0.0], "irradiance": E,
                    "angle": 2 * math.degrees(theta)}],
        "render": {"spp": 1024, "seed": 3, "max_depth": 1}})
    # The light paths leave through the top: h tan(theta) from x, z in [-1, 1] stays in
    # the box's [-3, 3].
    assert h * math.tan(theta) < 2.0
    L = E / (math.pi * math.sin(theta) ** 2)
    mu, w = np.polynomial.legendre.leggauss(64)
    mu = math.cos(theta) + (1 - math.cos(theta)) * (mu + 1) / 2
    k = 1 + 1 / mu
    exp = L / 2 * (1 - math.cos(theta)) / 2 * np.sum(w * (1 - np.exp(-sigma * h * k)) / k)
    r = render(sc, progress=False, backend=backend)
    m, var = r.film.mean()[..., :3], r.film.variance_of_mean()[..., :3]
    n = m.shape[0] * m.shape[1]
    se = np.sqrt(var.sum(axis=(0, 1))) / n
    z = (m.mean(axis=(0, 1)) - exp) / np.hypot(se, ROUNDING_REL * exp)
    assert np.all(se < 0.01 * exp), (se, exp)           # the mutant radiance is 25 % off
    assert np.all(np.abs(z) < z_bound(ALPHA, 3)), (m.mean(axis=(0, 1)), exp, z)
