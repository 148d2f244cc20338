"""Real media: colour-dependent extinction (spectral tracking, RGB transmittance) and
emission (radiance x field, blackbody temperature), on both backends, against exact answers.

Per-pixel checks are z-tests with the render's own variance of the mean and a Sidak bound
over every pixel and channel (family false-failure rate ALPHA = 1 %); exact cases compare to
float64 or float32 rounding."""

import math

import numpy as np
import pytest

from stats import ALPHA, z_bound
from volmc.constants import SPECTRAL_TRACKING
from volmc.emission import blackbody_rgb, blackbody_table, luminance, planck
from volmc.render import render
from volmc.resources import scenes_dir
from volmc.scene import load_scene, scene_from_dict
from volmc.scene.errors import SceneError

ABSORBER = scenes_dir() / "tests" / "absorber.toml"
FURNACE = scenes_dir() / "tests" / "white_furnace.toml"


def _z(res, expected):
    m = res.film.mean()
    se = np.sqrt(res.film.variance_of_mean())
    return (m - expected) / np.where(se > 0, se, np.inf)


def _slab(medium, spp=256, res=6, lights=None, render_keys=None):
    """Orthographic view down -z through the cube [-1, 1]^3 (every ray crosses 2 units)."""
    return {"camera": {"type": "orthographic", "eye": [0.0, 0.0, 3.0], "target": [0, 0, 0],
                       "size": 1.6, "resolution": [res, res]},
            "medium": {"bounds": [[-1, -1, -1], [1, 1, 1]], **medium},
            "lights": lights if lights is not None else [],
            "render": {"spp": spp, **(render_keys or {})}}


# --- Colour-dependent extinction ------------------------------------------------------------

def test_chromatic_absorber_exact(backend):
    """Homogeneous chromatic absorber: each channel is L exp(-sigma_c d), exactly."""
    scale = (0.5, 1.0, 2.0)
    scene = load_scene(ABSORBER, [f"medium.scale={list(scale)}"])
    res = render(scene, progress=False, backend=backend)
    expected = np.array([0.8 * math.exp(-0.75 * 2.0 * s) for s in scale])
    exact = 1e-12 if backend == "numba" else 2e-6
    assert np.allclose(res.film.mean(), expected, rtol=exact, atol=0)


@pytest.mark.parametrize("estimator", ["ratio", "residual_ratio", "next_flight",
                                       "track_length"])
def test_chromatic_absorber_grid(tmp_path, backend, estimator):
    """Absorbing chromatic grid: every channel is L times its own exact transmittance
    exp(-scale_c tau) (z-test), for every estimator that supports colour."""
    from volmc.reference.optical_depth import optical_depth_exact
    rng = np.random.default_rng(11)
    grid = rng.random((4, 5, 6)) + 0.2
    np.save(tmp_path / "g.npy", grid)
    scale = [1.6, 0.7, 0.2]
    raw = _slab({"scale": scale, "albedo": 0.0, "density": {"file": str(tmp_path / "g.npy")}},
                spp=2048, res=4, lights=[{"type": "environment", "radiance": 1.0}],
                render_keys={"transmittance": estimator, "majorant_resolution": [2, 2, 2]})
    res = render(scene_from_dict(raw), progress=False, backend=backend)
    # Expected: the pixel average of exp(-s_c tau(x, y)) by a fine midpoint rule.
    n, h = 12, 1.6 / 4
    exp_img = np.zeros((4, 4, 3))
    for j in range(4):
        for i in range(4):
            acc = np.zeros(3)
            for a in range(n):
                for b in range(n):
                    x = -0.8 + (i + (a + 0.5) / n) * h
                    y = 0.8 - (j + (b + 0.5) / n) * h
                    tau = optical_depth_exact(grid, (-1.0, -1.0, -1.0), (1.0, 1.0, 1.0), 1.0,
                                              (x, y, 3.0), (0.0, 0.0, -1.0), 2.0, 4.0)
                    acc += np.exp(-np.array(scale) * tau)
            exp_img[j, i] = acc / n**2
    # The midpoint rule's own error (tau is piecewise smooth) is far below the noise.
    z = _z(res, exp_img)
    assert np.abs(z).max() < z_bound(ALPHA, z.size)


@pytest.mark.parametrize("spectral", ["tracking", "hero", "channel"])
def test_chromatic_white_furnace(backend, spectral):
    """Albedo 1, chromatic extinction, unbounded depth: every channel equals the environment
    (spectral tracking, hero MIS, and one random channel per path)."""
    scene = load_scene(FURNACE, ["medium.scale=[12.0, 5.0, 1.5]", "render.spp=256",
                                 "camera.resolution=[8, 8]", "render.rr_depth=1000000",
                                 f"render.spectral={spectral}"])
    res = render(scene, progress=False, backend=backend)
    z = _z(res, 0.5)
    assert np.abs(z).max() < z_bound(ALPHA, z.size)
    assert res.counters["dropped"] == 0 and res.counters["capped"] == 0


def test_channel_mode_background_is_the_sky_exactly(backend):
    """Found by an outside test: with render.spectral = "channel" a camera ray that missed
    the box still carried 3x one random channel, so the background was noise around the
    sky's colour (0.71 to 1.30 for a sky of 1). It carries all three now: exactly the sky,
    variance 0; the box's pixels stay unbiased (a two-sample z-test against "tracking")."""
    raw = _slab({"scale": [3.0, 1.0, 0.3], "albedo": 0.8, "density": 1.0},
                spp=128, res=8, lights=[{"type": "environment", "radiance": [0.2, 0.5, 0.9]}],
                render_keys={"spectral": "channel"})
    raw["camera"]["size"] = 3.0   # the box covers the middle of the view
    res = render(scene_from_dict(raw), progress=False, backend=backend)
    miss = res.film.alpha() == 0.0
    assert 8 <= miss.sum() < 64
    sky = np.broadcast_to(np.float32([0.2, 0.5, 0.9]), res.film.mean()[miss].shape)
    assert np.array_equal(res.film.mean()[miss].astype(np.float32), sky)
    assert np.all(res.film.variance_of_mean()[miss] < 1e-15)   # 0 but for the sums' rounding
    raw["render"] = dict(raw["render"], spectral="tracking", seed=9)
    ref = render(scene_from_dict(raw), progress=False, backend=backend)
    d = (res.film.mean() - ref.film.mean())[~miss]
    z = d / np.sqrt(res.film.variance_of_mean()[~miss] + ref.film.variance_of_mean()[~miss])
    assert np.abs(z).max() < z_bound(ALPHA, z.size)


def test_grey_rgb_scale_renders_the_same_image(backend):
    """scale = [s, s, s] is grey: the same image as scale = s, bit for bit."""
    a = render(load_scene(FURNACE, ["render.spp=8", "medium.scale=4.0"]), progress=False,
               backend=backend)
    b = render(load_scene(FURNACE, ["render.spp=8", "medium.scale=[4.0, 4.0, 4.0]"]),
               progress=False, backend=backend)
    assert np.array_equal(a.film.mean(), b.film.mean())
    assert a.counters == b.counters


def test_spectral_tracking_of_a_grey_medium_is_unbiased(backend):
    """Spectral tracking forced onto a grey medium (its weights then vary only through the
    coloured albedo) agrees with delta tracking: a two-sample z-test per pixel."""
    from volmc.backends.base import make_backend
    keys = ["render.spp=512", "camera.resolution=[6, 6]", "medium.albedo=[0.95, 0.6, 0.3]",
            "render.transmittance=ratio", "render.free_flight=delta"]
    grey = render(load_scene(FURNACE, keys), progress=False, backend=backend)
    scene = load_scene(FURNACE, keys + ["render.seed=77"])
    if backend == "opencl":
        from volmc.backends.opencl import OpenCLBackend
        from volmc.scene.features import features
        be = OpenCLBackend(scene, feature_set=features(scene) | {"CHROMATIC"})
        be.medium[0]["spectral"] = SPECTRAL_TRACKING
    else:
        be = make_backend("numba", scene)
        be.packed.medium[0]["spectral"] = SPECTRAL_TRACKING
    spec = render(scene, backend=be, progress=False)
    d = grey.film.mean() - spec.film.mean()
    se = np.sqrt(grey.film.variance_of_mean() + spec.film.variance_of_mean())
    assert np.abs(d / se).max() < z_bound(ALPHA, d.size)


def test_chromatic_scene_rejects_grey_estimators():
    with pytest.raises(SceneError, match="render.transmittance"):
        load_scene(FURNACE, ["medium.scale=[1, 2, 3]", "render.transmittance=power_series"])


# --- Emission -----------------------------------------------------------------------------

@pytest.mark.parametrize("density", ["homogeneous", "grid"])
def test_emitting_absorber(tmp_path, backend, density):
    """Albedo 0, no light: L = Le (1 - exp(-sigma_a d)) per channel."""
    Le = [1.0, 0.5, 0.25]
    dens = 0.6
    if density == "grid":
        np.save(tmp_path / "c.npy", np.full((3, 4, 5), dens))
        src = {"file": str(tmp_path / "c.npy")}
    else:
        src = dens
    raw = _slab({"density": src, "scale": [1.0, 0.5, 2.0], "albedo": 0.0,
                 "emission": {"radiance": Le}}, spp=1024, res=4)
    res = render(scene_from_dict(raw), progress=False, backend=backend)
    expected = np.array([Le[c] * (1 - math.exp(-dens * s * 2.0))
                         for c, s in enumerate([1.0, 0.5, 2.0])])
    z = _z(res, expected)
    assert np.abs(z).max() < z_bound(ALPHA, z.size)


def test_emitting_absorber_temperature(backend):
    """Blackbody emission of a constant temperature: L = scale rgb(T) (1 - exp(-sigma d))."""
    T, k = 1500.0, 1e-4
    raw = _slab({"density": 0.4, "albedo": 0.0,
                 "emission": {"temperature": T, "scale": k}}, spp=1024, res=4)
    res = render(scene_from_dict(raw), progress=False, backend=backend)
    expected = k * blackbody_rgb(T) * (1 - math.exp(-0.4 * 2.0))
    z = _z(res, expected)
    assert np.abs(z).max() < z_bound(ALPHA, z.size)


@pytest.mark.parametrize("albedo, g, scale, spectral", [
    (0.5, 0.4, 3.0, "tracking"), (0.8, -0.3, [6.0, 2.0, 0.5], "tracking"),
    (0.7, 0.5, [1.0, 4.0, 9.0], "hero"), (0.6, 0.0, [5.0, 2.5, 1.0], "channel"),
    (0.0, 0.0, 4.0, "tracking")])
def test_equilibrium_furnace(tmp_path, backend, albedo, g, scale, spectral):
    """Emission Le inside, environment Le outside: radiance is Le everywhere, whatever the
    albedo, phase, density or colour of the extinction."""
    Le = [0.7, 0.4, 0.2]
    rng = np.random.default_rng(5)
    np.save(tmp_path / "g.npy", rng.random((6, 6, 6)))
    raw = {"camera": {"eye": [0.0, 0.3, 3.5], "target": [0, 0, 0], "fov": 40.0,
                      "resolution": [6, 6]},
           "medium": {"bounds": [[-1, -1, -1], [1, 1, 1]], "scale": scale, "albedo": albedo,
                      "density": {"file": str(tmp_path / "g.npy")},
                      "phase": {"type": "hg", "g": g} if g else {"type": "isotropic"},
                      "emission": {"radiance": Le}},
           "lights": [{"type": "environment", "radiance": Le}],
           "render": {"spp": 512, "max_depth": -1, "rr_depth": 1000000,
                      "transmittance": "ratio", "spectral": spectral}}
    res = render(scene_from_dict(raw), progress=False, backend=backend)
    z = _z(res, np.array(Le))
    assert np.abs(z).max() < z_bound(ALPHA, z.size)


def test_emission_field_and_temperature_grid_kernel_matches_reference(tmp_path):
    """Kernel against reference on one scene with every new feature: a chromatic grid, a
    temperature grid, HG scattering. The same random numbers: the images agree to float32
    rounding except where a rounding flips a decision."""
    rng = np.random.default_rng(2)
    np.save(tmp_path / "d.npy", rng.random((8, 8, 8)))
    np.save(tmp_path / "t.npy", 800.0 + 1200.0 * rng.random((5, 6, 7)))
    raw = {"camera": {"eye": [0.0, 0.0, 3.5], "target": [0, 0, 0], "resolution": [8, 8]},
           "medium": {"bounds": [[-1, -1, -1], [1, 1, 1]], "scale": [4.0, 2.0, 1.0],
                      "albedo": 0.6, "density": {"file": str(tmp_path / "d.npy")},
                      "phase": {"type": "hg", "g": 0.5},
                      "emission": {"temperature": {"file": str(tmp_path / "t.npy")},
                                   "scale": 1e-5}},
           "lights": [{"type": "environment", "radiance": [0.1, 0.2, 0.3]},
                      {"type": "directional", "direction": [0, -1, 0], "irradiance": 1.0}],
           "render": {"spp": 32, "transmittance": "ratio"}}
    scene = scene_from_dict(raw)
    a = render(scene, progress=False, backend="opencl").film.mean()
    b = render(scene, progress=False, backend="numba").film.mean()
    rel = np.abs(a - b) / (np.abs(b) + 1e-3)
    assert np.median(rel) < 1e-5
    assert np.mean(rel > 1e-3) < 0.05


def test_temperature_remap_is_the_grid_in_kelvin(tmp_path):
    """emission.remap = [v_min, v_max, T_min, T_max] on a flame-style grid packs exactly the
    kelvin grid it maps to (clamped outside [v_min, v_max]), so it renders the same image,
    sample for sample, as that kelvin grid given directly."""
    from volmc.pack import pack_scene
    rng = np.random.default_rng(4)
    flame = rng.uniform(0.0, 1.3, (5, 6, 7))          # outside [0.1, 1] on both sides
    np.save(tmp_path / "flame.npy", flame)
    v = flame.astype(np.float32).astype(np.float64)
    kelvin = 300.0 + np.clip((v - 0.1) / 0.9, 0.0, 1.0) * 1500.0
    np.save(tmp_path / "kelvin.npy", kelvin.astype(np.float32))
    def raw(temperature, **extra):
        return _slab({"density": 0.8, "albedo": 0.3,
                      "emission": {"temperature": {"file": str(tmp_path / temperature)},
                                   "scale": 1e-4, **extra}},
                     spp=16, lights=[{"type": "environment", "radiance": 0.1}])
    a = scene_from_dict(raw("flame.npy", remap=[0.1, 1.0, 300.0, 1800.0]))
    b = scene_from_dict(raw("kelvin.npy"))
    pa, pb = pack_scene(a, np.float32), pack_scene(b, np.float32)
    assert np.array_equal(pa.emis, pb.emis) and np.array_equal(pa.table, pb.table)
    assert pa.emis.min() == 300.0 and pa.emis.max() == 1800.0
    ra = render(a, progress=False, backend="opencl").film.sum
    rb = render(b, progress=False, backend="opencl").film.sum
    assert np.array_equal(ra, rb) and ra[..., :3].max() > 0
    # A falling ramp, and the key written back by serialisation.
    from volmc.scene import validate
    from volmc.scene.serialize import to_dict
    c = scene_from_dict(raw("flame.npy", remap=[0.0, 1.0, 1800.0, 300.0]))
    assert np.allclose(pack_scene(c, np.float32).emis, 1800.0 - np.clip(v, 0.0, 1.0) * 1500.0,
                       rtol=1e-7)
    assert validate(to_dict(c.spec), c.spec.file) == c.spec


@pytest.mark.parametrize("emission, words", [
    ({"temperature": 1.0, "remap": [0.0, 1.0, 500.0]}, "expected [v_min"),
    ({"temperature": 1.0, "remap": [1.0, 1.0, 500.0, 900.0]}, "v_min < v_max"),
    ({"temperature": 1.0, "remap": [0.0, 1.0, -5.0, 900.0]}, "[0, inf]"),
    ({"radiance": 1.0, "remap": [0.0, 1.0, 500.0, 900.0]}, "only 'temperature'"),
])
def test_bad_temperature_remap(emission, words):
    with pytest.raises(SceneError) as e:
        scene_from_dict(_slab({"density": 1.0, "emission": emission}))
    assert e.value.key == "medium.emission.remap" and words in str(e.value)


@pytest.mark.parametrize("emission", [{"temperature": 1e34, "scale": 1e-10},
                                      {"temperature": 1.0, "remap": [0.0, 1.0, 500.0, 1e34],
                                       "scale": 1e-10}])
def test_blackbody_past_float32_is_refused(emission):
    """Found by an outside test: the kernels keep the blackbody table unscaled in float32,
    so at 1e34 K every sample was infinite and dropped (a black image) while the float64
    reference rendered scale x B(T) = 1e31. Refused at loading now, naming the key."""
    with pytest.raises(SceneError) as e:
        scene_from_dict(_slab({"density": 1.0, "emission": emission}))
    assert e.value.key == "medium.emission.temperature" and "past float32" in str(e.value)
    scene_from_dict(_slab({"density": 1.0, "emission": dict(emission, temperature=2e31)
                           if "remap" not in emission else dict(emission, remap=[
                               0.0, 1.0, 500.0, 2e31])}))   # 3e38 nits: still in range


def test_no_emission_compiles_none_of_it():
    from volmc.scene.features import features
    assert "EMISSION" not in features(load_scene(FURNACE))
    assert "CHROMATIC" not in features(load_scene(FURNACE, ["medium.scale=[2, 2, 2]"]))
    s = load_scene(FURNACE, ["medium.scale=[2, 1, 2]", "medium.emission={radiance=1}"])
    assert {"EMISSION", "CHROMATIC"} <= features(s)


# --- Blackbody colour ------------------------------------------------------------------------

def test_planck_integrates_to_stefan_boltzmann():
    """Integral of B over wavelength = sigma T^4 / pi (radiance)."""
    lam = np.linspace(50.0, 200000.0, 400001)
    for T in (800.0, 1500.0, 6000.0):
        b = planck(lam, T)
        total = np.sum((b[1:] + b[:-1]) * np.diff(lam)) / 2   # numpy 1.26: no np.trapezoid
        assert total == pytest.approx(5.670374419e-8 * T**4 / math.pi, rel=2e-3)


@pytest.mark.parametrize("T, x, y", [(2000.0, 0.5266, 0.4133), (3000.0, 0.4369, 0.4041),
                                     (6500.0, 0.3135, 0.3237)])
def test_blackbody_chromaticity_on_planckian_locus(T, x, y):
    """xy chromaticity of the blackbody colour against the Planckian locus (CIE 1931)."""
    from volmc.emission import blackbody_xyz
    X, Y, Z = blackbody_xyz(T)
    assert X / (X + Y + Z) == pytest.approx(x, abs=3e-3)
    assert Y / (X + Y + Z) == pytest.approx(y, abs=3e-3)


@pytest.mark.parametrize("t_max, bound", [(2000.0, 1e-4), (20000.0, 2e-3)])
def test_blackbody_table_interpolation_error(t_max, bound):
    """Linear interpolation in the table, as the renderer does, against the conversion."""
    table, per_k = blackbody_table(t_max)
    temps = np.linspace(1000.0, t_max, 997)
    x = temps * per_k
    i = np.minimum(x.astype(int), len(table) - 2)
    w = (x - i)[:, None]
    interp = table[i] * (1 - w) + table[i + 1] * w
    exact = blackbody_rgb(temps)
    rel = np.abs(interp - exact) / np.maximum(exact.max(axis=1, keepdims=True), 1e-300)
    assert rel.max() < bound


def test_cold_table_is_zero_and_finite():
    table, per_k = blackbody_table(1e-36)
    assert per_k == 0.0 and not table.any()


def test_blackbody_table_interpolates_the_conversion():
    table, per_k = blackbody_table(2000.0)
    assert per_k == pytest.approx((len(table) - 1) / 2000.0)
    i = 700
    assert np.allclose(table[i], blackbody_rgb(i / per_k), rtol=1e-12)
    assert np.all(table[0] == 0.0) and luminance(1000.0) < luminance(1500.0)


# --- Scene keys ------------------------------------------------------------------------------

@pytest.mark.parametrize("define, key", [
    ("medium.scale=[1, 2]", "medium.scale"),
    ("medium.scale=[1, -2, 3]", "medium.scale"),
    ("medium.emission={radiance=1, temperature=1000}", "medium.emission"),
    ("medium.emission={}", "medium.emission"),
    ("medium.emission={temperature=1000, field=2}", "medium.emission.field"),
    ("medium.emission={radiance=1, scale=2}", "medium.emission.scale"),
    ("medium.emission={radiance=1, colour=2}", "medium.emission.colour"),
    ("medium.emission={radiance=-1}", "medium.emission.radiance"),
    ("medium.emission={temperature=-5}", "medium.emission.temperature"),
    ("medium.emission={temperature={generator='cloud', resolution=8, channel='temperature'}}",
     "medium.emission.temperature.channel"),
    ("medium.density={file='x.npy', grid='a'}", "medium.density.grid"),
    ("render.spectral=wavelength", "render.spectral"),
])
def test_bad_new_keys(define, key):
    with pytest.raises(SceneError) as e:
        load_scene(FURNACE, [define])
    assert key in str(e.value)


def test_new_keys_round_trip():
    from volmc.scene.schema import validate
    from volmc.scene.serialize import to_dict
    scene = load_scene(FURNACE, ["medium.scale=[3, 2, 1]", "render.spectral=channel",
                                 "medium.emission={temperature={generator='plume', "
                                 "resolution=8, seed=2}, scale=0.5}"])
    d = to_dict(scene.spec)   # paths are written resolved
    assert to_dict(validate(d, scene.file)) == d
    assert validate(d, scene.file).medium.emission == scene.medium.emission
