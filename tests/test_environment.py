"""Environment maps (lights.environment.file): the sampler against its density (chi-square,
Mitsuba's ChiSquareTest style: cells with expected counts under 5 pooled, Sidak-corrected
over the maps at family level ALPHA = 1 %, fixed seeds), the density's integral and its
agreement with sampling, the inverse, the kernels against the reference, the orientation
convention end to end through a panoramic camera, renders (a constant map is the constant
sky; importance, uniform and compensated sampling agree), and bad input."""

import math
import subprocess
import sys

import numpy as np
import pytest
from numba import njit

from stats import ALPHA, chi2_pvalue, sidak
from volmc.check import compare_images
from volmc.film import write_exr
from volmc.pack import env_buffer, pack_scene
from volmc.reference.environment import (env_uv, env_to_map, environment_distribution,
                                         environment_pdf, invert_environment,
                                         sample_environment)
from volmc.render import render
from volmc.scene import scene_from_dict
from volmc.scene.errors import SceneError


def _maps():
    """One bright texel, a sky with a sun (a gradient and a hot 2 x 1 spot), a constant 3 x 2
    map: [H, W, 3] float32."""
    one = np.full((8, 16, 3), 0.02, np.float32)
    one[2, 11] = 50.0
    v = (np.arange(32) + 0.5) / 32
    sky = np.repeat((0.2 + np.cos(np.pi * v) ** 2)[:, None], 64, axis=1)
    sky = np.stack([0.5 * sky, 0.7 * sky, sky], axis=-1).astype(np.float32)
    sky[9, 40:42] = (400.0, 380.0, 300.0)
    return {"one texel": one, "sky with sun": sky, "constant 3x2": np.full((2, 3, 3), 0.7,
                                                                           np.float32)}


def _write(tmp_path, name, texels):
    path = tmp_path / f"{name.replace(' ', '_')}.exr"
    write_exr(path, texels)
    return path


def _scene(map_path, rotation=0.0, render_keys=None, medium=None, camera=None, lights=None):
    env = {"type": "environment", "file": str(map_path), "strength": 1.0, "rotation": rotation}
    cam = {"eye": [0.0, 0.0, 3.0], "target": [0.0, 0.0, 0.0], "fov": 40.0,
           "resolution": [8, 8]}
    return scene_from_dict({
        "camera": dict(cam, **(camera or {})),
        "medium": medium or {"bounds": [[-1, -1, -1], [1, 1, 1]], "density": 1.5,
                             "albedo": 0.9, "phase": {"type": "hg", "g": 0.5}},
        "lights": [env] + (lights or []),
        "render": dict({"spp": 64}, **(render_keys or {}))})


@njit(cache=True)
def _draw(prm, env, us):
    out = np.empty((len(us), 4))
    for i in range(len(us)):
        w, pdf = sample_environment(prm, env, us[i, 0], us[i, 1])
        out[i, 0], out[i, 1], out[i, 2], out[i, 3] = w[0], w[1], w[2], pdf
    return out


@njit(cache=True)
def _uv_of(prm, ws):
    out = np.empty((len(ws), 2))
    for i in range(len(ws)):
        u, v = env_uv(env_to_map(prm, (ws[i, 0], ws[i, 1], ws[i, 2])))
        out[i, 0], out[i, 1] = u, v
    return out


def _cell_probabilities(pdf_uv, nu, nv):
    """Probability of each of nu x nv equal cells of the (u, v) square under the piecewise
    constant texel density pdf_uv [H, W] (exact: the overlap areas of cells and texels)."""
    h, w = pdf_uv.shape

    def overlap(n_cells, n_tex):
        a = np.linspace(0, 1, n_cells + 1)
        b = np.linspace(0, 1, n_tex + 1)
        return np.clip(np.minimum(a[1:, None], b[None, 1:]) - np.maximum(a[:-1, None],
                                                                           b[None, :-1]),
                       0, None)
    return overlap(nv, h) @ pdf_uv @ overlap(nu, w).T


@pytest.mark.parametrize("compensate", [False, True])
def test_sampler_matches_its_density_chi_square(tmp_path, compensate):
    """Directions drawn from each map (turned by 70 degrees about a tilted axis for the sky),
    mapped back to (u, v) through the rotation, fall in 17 x 11 cells (not aligned with the
    texels, so the spread within a texel counts) as the density says."""
    maps = _maps()
    m = len(maps)
    for k, (name, texels) in enumerate(maps.items()):
        rot = [[1.0, 2.0, 0.5, 70.0]] if name == "sky with sun" else 0.0
        sc = _scene(_write(tmp_path, name, texels), rot,
                    {"env_compensation": compensate})
        pk = pack_scene(sc)
        us = np.random.default_rng(17 + k).random((200_000, 2))
        d = _draw(pk.params[0], pk.env, us)
        assert np.all(d[:, 3] > 0.0)
        uv = _uv_of(pk.params[0], np.ascontiguousarray(d[:, :3]))
        nu, nv = 17, 11
        obs, _, _ = np.histogram2d(uv[:, 1], uv[:, 0], bins=[nv, nu], range=[[0, 1], [0, 1]])
        expected = _cell_probabilities(pk.env.pdf, nu, nv) * len(us)
        assert abs(expected.sum() - len(us)) < 1e-6 * len(us)
        p, dof = chi2_pvalue(obs, expected)
        assert dof >= (1 if compensate else 5), (name, dof)   # compensated: the sun alone
        assert p > sidak(ALPHA, m), (name, p)


def test_density_integrates_to_one_and_is_what_sampling_reports(tmp_path):
    """The density per steradian integrates to 1 over the sphere (midpoint rule on a grid
    finer than the texels, d omega = 2 pi^2 sin theta du dv); at sampled directions
    environment_pdf equals the pdf sampling reported; invert_environment gives back the
    uniforms."""
    for k, (name, texels) in enumerate(_maps().items()):
        sc = _scene(_write(tmp_path, name, texels), 33.0)
        pk = pack_scene(sc)
        prm, env = pk.params[0], pk.env
        n_u, n_v = 640, 320
        u = (np.arange(n_u) + 0.5) / n_u
        v = (np.arange(n_v) + 0.5) / n_v
        h, w = texels.shape[:2]
        pdf_uv = env.pdf[np.minimum((v * h).astype(int), h - 1)][:, np.minimum(
            (u * w).astype(int), w - 1)]
        # per steradian x d omega = pdf_uv du dv
        assert abs(pdf_uv.sum() / (n_u * n_v) - 1.0) < 1e-9
        us = np.random.default_rng(5 + k).random((2000, 2))
        for u1, u2 in us:
            wd, pdf = sample_environment(prm, env, u1, u2)
            assert math.isclose(environment_pdf(prm, env, wd), pdf, rel_tol=1e-9), name
            b1, b2 = invert_environment(prm, env, wd)
            assert abs(b1 - u1) < 1e-9 and abs(b2 - u2) < 1e-9, (name, u1, u2, b1, b2)


def test_kernel_sampler_matches_the_reference(tmp_path):
    """The kernels' sample_environment, environment_pdf, env_radiance and invert_environment
    (float32, current lane width) against the reference's on the same uniforms."""
    import cl_harness
    from volmc.reference.environment import env_radiance
    texels = _maps()["sky with sun"]
    sc = _scene(_write(tmp_path, "sky", texels), [[0.3, 1.0, -0.2, 125.0]])
    pk64, pk32 = pack_scene(sc), pack_scene(sc, np.float32)
    n = 4000
    us = np.random.default_rng(3).random((n, 2)).astype(np.float32)
    out, ob = cl_harness.out_buf((n, 8))
    inv, ib = cl_harness.out_buf((n, 2))
    cl_harness.run("t_environment", n, pk32.params[0],
                   cl_harness.to_dev(env_buffer(pk32).astype(np.float32)),
                   cl_harness.to_dev(us.ravel()), ob, ib, outs=[(out, ob), (inv, ib)])
    prm, env = pk64.params[0], pk64.env
    for i in range(n):
        w, pdf = sample_environment(prm, env, float(us[i, 0]), float(us[i, 1]))
        assert np.allclose(out[i, :3], w, atol=2e-4), i
        assert math.isclose(out[i, 3], pdf, rel_tol=2e-3), i
        assert math.isclose(out[i, 4], environment_pdf(prm, env, w), rel_tol=2e-3) or \
            abs(out[i, 4] - pdf) < 2e-3 * pdf, i
        if np.allclose(out[i, 5:], env_radiance(prm, env, w), rtol=1e-5):
            continue
        # A direction on a texel border may round into the neighbour in float32.
        u, v = env_uv(env_to_map(prm, w))
        hh, ww = texels.shape[:2]
        assert min(abs(u * ww - round(u * ww)), abs(v * hh - round(v * hh))) < 1e-3, i
    assert np.allclose(inv, us, atol=2e-4)


def test_kernel_pdf_at_its_samples_near_the_poles(tmp_path):
    """In a 1024-row map, directions the kernel draws from the top and bottom rows have, by
    environment_pdf, the pdf sampling reported (MIS weighs escaping paths by the one and
    light samples by the other). With theta = acos(y) in float32 the pdf there was 0 for 8 %
    of them and more than 1 % off for 38 %."""
    import cl_harness
    h = 1024
    texels = np.full((h, 8, 3), 1.0, np.float32)
    texels[0] = texels[-1] = 1000.0
    pk32 = pack_scene(_scene(_write(tmp_path, "poles", texels)), np.float32)
    marginal = pack_scene(_scene(_write(tmp_path, "poles", texels))).env.marginal
    rng = np.random.default_rng(11)
    n = 20_000
    u1 = np.concatenate([rng.uniform(0.0, marginal[1], n // 2),
                         rng.uniform(marginal[-2], 1.0, n // 2)])
    us = np.stack([u1, rng.random(n)], axis=1).astype(np.float32)
    out, ob = cl_harness.out_buf((n, 8))
    inv, ib = cl_harness.out_buf((n, 2))
    cl_harness.run("t_environment", n, pk32.params[0],
                   cl_harness.to_dev(env_buffer(pk32).astype(np.float32)),
                   cl_harness.to_dev(us.ravel()), ob, ib, outs=[(out, ob), (inv, ib)])
    sampled, evaluated = out[:, 3].astype(np.float64), out[:, 4].astype(np.float64)
    # u1 within float32's spacing of 1 gives v = 1 (sin theta 0, pdf 0): a few in 10^5
    assert np.count_nonzero(sampled == 0.0) <= 1e-3 * n
    on = sampled > 0.0
    assert np.all(np.abs(evaluated[on] / sampled[on] - 1.0) < 1e-3)


def test_panoramic_camera_sees_the_map(tmp_path, backend):
    """A panoramic camera at the origin looking along -z (right = +x), through a medium of
    density 0, returns the map: with a 32 x 16 image of a 16 x 8 map every pixel lies in one
    texel, the one the convention names (u = fx - 1/2 for this camera, v = fy)."""
    texels = np.random.default_rng(8).random((8, 16, 3)).astype(np.float32) + 0.1
    sc = _scene(_write(tmp_path, "grid", texels), 0.0, {"spp": 4},
                medium={"bounds": [[-1, -1, -1], [1, 1, 1]], "density": 0.0},
                camera={"type": "panoramic", "eye": [0.0, 0.0, 0.0],
                        "target": [0.0, 0.0, -1.0], "resolution": [32, 16]})
    res = render(sc, progress=False, backend=backend)
    fx = (np.arange(32) + 0.5) / 32
    fy = (np.arange(16) + 0.5) / 16
    cols = (np.mod(fx - 0.5, 1.0) * 16).astype(int)
    rows = (fy * 8).astype(int)
    expected = texels[rows][:, cols]
    assert np.allclose(res.film.mean()[..., :3], expected, rtol=1e-5)
    assert np.all(res.film.variance_of_mean()[..., :3] < 1e-10)


def test_constant_map_renders_as_the_constant_sky(tmp_path, backend):
    """A map of one value c times radiance r renders as the constant environment c r (per
    pixel z-tests), with importance sampling and with MIS compensation."""
    c = np.full((4, 8, 3), 0.6, np.float32)
    path = _write(tmp_path, "const", c)
    base = render(scene_from_dict({
        "camera": {"eye": [0.0, 0.0, 3.0], "target": [0, 0, 0], "resolution": [8, 8]},
        "medium": {"bounds": [[-1, -1, -1], [1, 1, 1]], "density": 1.5, "albedo": 0.9},
        "lights": [{"type": "environment", "radiance": [0.3, 0.6, 0.9]}],
        "render": {"spp": 256, "seed": 1}}), progress=False, backend=backend)
    for comp in (False, True):
        sc = scene_from_dict({
            "camera": {"eye": [0.0, 0.0, 3.0], "target": [0, 0, 0], "resolution": [8, 8]},
            "medium": {"bounds": [[-1, -1, -1], [1, 1, 1]], "density": 1.5, "albedo": 0.9},
            "lights": [{"type": "environment", "file": str(path),
                        "radiance": [0.5, 1.0, 1.5]}],
            "render": {"spp": 256, "seed": 2, "env_compensation": comp}})
        res = render(sc, progress=False, backend=backend)
        c = compare_images(res.film.mean()[..., :3], res.film.variance_of_mean()[..., :3],
                           base.film.mean()[..., :3], base.film.variance_of_mean()[..., :3],
                           alpha=ALPHA / 2)
        assert c.passed, c.summary()


def test_importance_uniform_and_compensated_sampling_agree(tmp_path):
    """A sky with a wide sun lighting a cloud of HG droplets: importance sampling (balance and
    power heuristics, compensated or not) renders what uniform sampling renders (per-pixel
    z-tests, Sidak over the three comparisons), and at lower variance."""
    sky = _maps()["sky with sun"]
    sky[7:10, 38:44] = (30.0, 28.0, 24.0)   # a sun uniform sampling finds often enough for
    path = _write(tmp_path, "sky", sky)     # its variance estimate to be trusted
    keys = [{"env_sampling": "uniform"}, {}, {"mis": "power"}, {"env_compensation": True}]
    res = [render(_scene(path, 40.0, dict({"spp": 512, "seed": i}, **k)), progress=False,
                  backend="opencl") for i, k in enumerate(keys)]
    ref = res[0]
    for r in res[1:]:
        c = compare_images(r.film.mean()[..., :3], r.film.variance_of_mean()[..., :3],
                           ref.film.mean()[..., :3], ref.film.variance_of_mean()[..., :3],
                           alpha=ALPHA / (len(res) - 1))
        assert c.passed, c.summary()
    assert res[1].film.variance_of_mean()[..., :3].mean() < \
        0.5 * ref.film.variance_of_mean()[..., :3].mean()


def test_bad_maps_and_keys(tmp_path):
    """One-line errors naming the file and key."""
    good = _write(tmp_path, "good", _maps()["constant 3x2"])
    bad = _maps()["constant 3x2"].copy()
    bad[0, 1, 2] = -1.0
    bad[1, 2, 0] = np.nan
    badp = _write(tmp_path, "bad", bad)
    with pytest.raises(SceneError, match=r"lights\[0\]\.file: 2 of 6 texels"):
        _scene(badp)
    with pytest.raises(SceneError, match=r"lights\[0\]\.file: cannot read"):
        _scene(tmp_path / "missing.exr")
    (tmp_path / "junk.exr").write_bytes(b"not an exr at all" * 10)
    with pytest.raises(SceneError, match=r"lights\[0\]\.file: not a readable OpenEXR"):
        _scene(tmp_path / "junk.exr")
    (tmp_path / "sky.hdr").write_bytes(b"#?RADIANCE\n")
    with pytest.raises(SceneError, match=r"sky.hdr: lights\[0\]\.file: not an image"):
        _scene(tmp_path / "sky.hdr")
    with pytest.raises(SceneError, match=r"lights\[1\].*one environment"):
        _scene(good, lights=[{"type": "environment", "radiance": 1.0}])
    with pytest.raises(SceneError, match=r"lights\[0\]\.strength"):
        scene_from_dict({"camera": {}, "medium": {"density": 1.0, "bounds": [[0, 0, 0], [1, 1, 1]]},
                         "lights": [{"type": "environment", "file": str(good),
                                     "strength": -1.0}]})
    with pytest.raises(SceneError, match=r"lights\[0\]\.rotation"):
        scene_from_dict({"camera": {}, "medium": {"density": 1.0, "bounds": [[0, 0, 0], [1, 1, 1]]},
                         "lights": [{"type": "environment", "radiance": 1.0,
                                     "rotation": 30.0}]})
    with pytest.raises(SceneError, match=r"render\.env_sampling"):
        _scene(good, render_keys={"env_sampling": "cosine"})


def test_cli_refuses_a_bad_map_with_exit_status_2(tmp_path):
    bad = _maps()["constant 3x2"].copy()
    bad[0, 0, 0] = np.inf
    badp = _write(tmp_path, "bad", bad)
    scene = tmp_path / "s.toml"
    scene.write_text('[camera]\n[medium]\ndensity = 1.0\nbounds = [[0, 0, 0], [1, 1, 1]]\n'
                     f'[[lights]]\ntype = "environment"\nfile = "{badp.name}"\n')
    r = subprocess.run([sys.executable, "-m", "volmc.cli", "render", str(scene), "-o",
                        str(tmp_path / "out.exr")], capture_output=True, text=True)
    assert r.returncode == 2
    assert len(r.stderr.strip().splitlines()) == 1
    assert "bad.exr" in r.stderr and "lights[0].file" in r.stderr


def test_scene_with_a_map_serialises_back_to_itself(tmp_path):
    from volmc.scene.serialize import to_dict
    sc = _scene(_write(tmp_path, "c", _maps()["constant 3x2"]), [[0, 0, 1, 20.0]],
                {"env_sampling": "uniform", "env_compensation": True})
    again = scene_from_dict(to_dict(sc.spec))
    a, b = sc.spec.lights[0], again.spec.lights[0]
    assert a.resolved == b.resolved and a.strength == b.strength
    assert np.allclose(a.rotation, b.rotation, atol=1e-12)
    assert again.spec.render == sc.spec.render


def test_hdr_map_through_openimageio(tmp_path, monkeypatch):
    """A Radiance .hdr map reads through OpenImageIO (to its RGBE precision); without
    the extra the error names it."""
    import OpenImageIO as oiio
    texels = np.random.default_rng(4).random((6, 12, 3)).astype(np.float32) * 5 + 0.1
    path = tmp_path / "sky.hdr"
    out = oiio.ImageOutput.create(str(path))
    assert out.open(str(path), oiio.ImageSpec(12, 6, 3, "float"))
    assert out.write_image(texels)
    out.close()
    from volmc.scene.envmap import read_env_map
    got = read_env_map(str(path), "s.toml", "lights[0].file")
    # RGBE: one exponent per texel, 8 bits of mantissa for its largest channel
    assert got.shape == texels.shape and np.allclose(got, texels, rtol=0.01, atol=5.1 / 128)
    monkeypatch.setitem(sys.modules, "OpenImageIO", None)
    (tmp_path / "other.hdr").write_bytes(path.read_bytes())
    with pytest.raises(SceneError, match=r"volmc\[images\]"):
        read_env_map(str(tmp_path / "other.hdr"), "s.toml", "lights[0].file")


def test_memory_estimate_counts_the_map(tmp_path):
    """The memory check counts the map (its texels, sampling density and OpenCL buffer),
    named by its key, in proportion to its texels."""
    from volmc.memory import estimate
    sizes = {}
    for h, w in ((8, 16), (32, 64)):
        sc = _scene(_write(tmp_path, f"m{h}", np.ones((h, w, 3), np.float32)))
        for backend in ("opencl", "numba"):
            comps = [c for c in estimate(sc, backend, rows=1).components
                     if c.key == "lights[0].file"]
            assert len(comps) == 1
            sizes[h, backend] = comps[0].host + comps[0].device
            if backend == "opencl":
                assert comps[0].buffer == h * w * 20   # texels, pdf, conditional CDF
    assert sizes[32, "opencl"] == 16 * sizes[8, "opencl"]
    assert sizes[32, "numba"] == 16 * sizes[8, "numba"]


def test_cycles_peer_refuses_a_map(tmp_path):
    from volmc.peers.cycles import check_translatable
    from volmc.peers.errors import PeerUnavailable
    with pytest.raises(PeerUnavailable, match=r"lights\[0\] is an environment map"):
        check_translatable(_scene(_write(tmp_path, "c", _maps()["constant 3x2"])))


def test_damaged_maps_are_refused_not_crashed_on(tmp_path):
    """Mutation fuzzing of an EXR map (truncations, bit flips, overwritten words; fixed seed):
    each read gives a valid map (finite, >= 0) or one SceneError naming the key, never a
    crash, a hang or a silently half-read image (OpenEXR's reports of damage it read past,
    which it prints and carries on from, are turned into errors)."""
    from volmc.scene import envmap
    src = _write(tmp_path, "src", np.random.default_rng(0).random((16, 32, 3)) + 0.5)
    data = src.read_bytes()
    rng = np.random.default_rng(12)
    outcomes = {"ok": 0, "refused": 0}
    for k in range(400):
        b = bytearray(data)
        kind = k % 3
        if kind == 0:
            b = b[:rng.integers(0, len(b))]
        elif kind == 1:
            for _ in range(rng.integers(1, 8)):
                i = rng.integers(0, len(b))
                b[i] ^= 1 << int(rng.integers(0, 8))
        else:
            i = rng.integers(0, len(b) - 4)
            b[i:i + 4] = rng.integers(0, 256, 4, dtype=np.uint8).tobytes()
        path = tmp_path / f"f{k}.exr"
        path.write_bytes(bytes(b))
        envmap._cache.clear()
        try:
            px = envmap.read_env_map(str(path), "s.toml", "lights[0].file")
        except SceneError as e:
            assert "lights[0].file" in str(e) and "\n" not in str(e)
            outcomes["refused"] += 1
        else:
            assert px.dtype == np.float32 and px.ndim == 3 and px.shape[2] == 3
            assert np.all(np.isfinite(px)) and np.all(px >= 0)
            outcomes["ok"] += 1
        path.unlink()
    assert outcomes["refused"] > 100 and outcomes["ok"] > 10, outcomes


def test_a_loaded_scene_carries_its_map(tmp_path):
    """A loaded scene holds the map's texels (as it holds its grids), so a copy sent to a
    cluster worker that cannot see the file packs the same map."""
    import pickle
    from volmc.scene import envmap
    texels = _maps()["sky with sun"]
    path = _write(tmp_path, "sky", texels)
    sc = _scene(path, 25.0)
    path.unlink()
    envmap._cache.clear()
    again = pickle.loads(pickle.dumps(sc))
    assert np.array_equal(pack_scene(again).env.texels, texels)
    assert again.spec == sc.spec


def test_bench_refuses_a_bad_scene_with_one_line(tmp_path, capsys):
    """`python -m volmc.bench.envmap` on a scene whose map is missing: the one-line error
    and exit status 2, as `volmc render` gives (volmc.bench.report_main)."""
    from volmc.bench.envmap import main
    scene = tmp_path / "s.toml"
    scene.write_text('[camera]\n[medium]\ndensity = 1.0\nbounds = [[0, 0, 0], [1, 1, 1]]\n'
                     '[[lights]]\ntype = "environment"\nfile = "missing.exr"\n')
    with pytest.raises(SystemExit) as e:
        main([str(scene)])
    assert e.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "lights[0].file" in err[0] and "missing.exr" in err[0]
