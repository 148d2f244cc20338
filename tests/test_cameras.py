"""Cameras (issue 22, part 3): the thin lens and the panoramic camera.

The lens sample's warp is uniform on the disc (chi-square) and inverts; the panoramic
mapping inverts for every pixel; the kernels' twins (sample_uniform_disc,
invert_uniform_disc, panoramic_direction, invert_panoramic_direction, camera_ray) equal the
reference at every lane width; a pinhole is unchanged bit for bit by the lens keys at
aperture 0; and rendered images match closed forms: the blur of an edge out of focus, and
a panorama's environment and box. Statistical tests have fixed seeds and a family
false-failure rate of ALPHA (1 %) each."""

import math

import numpy as np
import pytest
from numba import njit

from cl_harness import out_buf, run, to_dev
from stats import ALPHA, chi2_pvalue
from volmc.cl.structs import kernel_params_dtype
from volmc.pack import pack_scene
from volmc.reference.camera import camera_ray, invert_panoramic_direction, panoramic_direction
from volmc.reference.rng import uniforms
from volmc.reference.sampling import invert_uniform_disc, sample_uniform_disc, uniform_disc_pdf
from volmc.render import render
from volmc.scene import SceneError, load_scene, scene_from_dict

EDGE_U = np.array([0.0, 2.0**-24, 0.25, 0.5, 0.75, 1 - 2.0**-24])


@njit(cache=True)
def _disc_points(u):
    n = u.shape[0]
    out = np.empty((n, 3))
    for i in range(n):
        (x, y), pdf = sample_uniform_disc(u[i, 0], u[i, 1])
        out[i, 0], out[i, 1], out[i, 2] = x, y, pdf
    return out


@njit(cache=True)
def _disc_inverses(p):
    out = np.empty((p.shape[0], 2))
    for i in range(p.shape[0]):
        out[i, 0], out[i, 1] = invert_uniform_disc((p[i, 0], p[i, 1]))
    return out


def _disc_chi2(x, y, n_r=20, n_phi=20):
    """p-value of points on the unit disc against the uniform density, over n_r x n_phi
    cells of equal area (equal steps of r^2 and of the angle)."""
    ri = np.minimum(((x * x + y * y) * n_r).astype(int), n_r - 1)
    phi = np.arctan2(y, x) % (2 * math.pi)
    pj = np.minimum((phi / (2 * math.pi) * n_phi).astype(int), n_phi - 1)
    observed = np.bincount(ri * n_phi + pj, minlength=n_r * n_phi)
    return chi2_pvalue(observed, np.full(n_r * n_phi, len(x) / (n_r * n_phi)))[0]


def test_uniform_disc_chi_square():
    """Concentric mapping: uniform on the disc (equal-area cells, 10^6 points, level ALPHA),
    inside it, with pdf 1 / pi. The test has power: the naive polar warp r = u1 fails it."""
    u = uniforms(21, 0, 0, 2, 2_000_000).reshape(-1, 2)
    p = _disc_points(u)
    assert np.all(p[:, 0] ** 2 + p[:, 1] ** 2 <= 1.0 + 1e-15)
    assert np.all(p[:, 2] == 1.0 / math.pi) and uniform_disc_pdf() == 1.0 / math.pi
    assert _disc_chi2(p[:, 0], p[:, 1]) > ALPHA
    r, phi = u[:, 0], 2 * math.pi * u[:, 1]
    assert _disc_chi2(r * np.cos(phi), r * np.sin(phi)) < 1e-12


def test_uniform_disc_round_trip():
    """invert_uniform_disc(sample_uniform_disc(u)) = u, on both wedges, their borders and the
    square's edges and centre."""
    u = np.concatenate([np.array([[a, b] for a in EDGE_U for b in EDGE_U]),
                        uniforms(22, 0, 0, 2, 200_000).reshape(-1, 2)])
    back = _disc_inverses(_disc_points(u)[:, :2])
    assert np.allclose(back, u, rtol=0, atol=1e-12), np.abs(back - u).max()


def test_uniform_disc_kernel_matches_reference(lanes):
    """The kernel's warp and inverse, fed the reference's inputs: equal to float32 precision."""
    u = np.concatenate([np.array([[a, b] for a in EDGE_U for b in EDGE_U]),
                        uniforms(23, 0, 0, 2, 8000).reshape(-1, 2)]).astype(np.float32)
    ref = _disc_points(u.astype(np.float64))
    pts = ref[:, :2].astype(np.float32)
    out, ob = out_buf((len(u), 6))
    run("t_uniform_disc", len(u), to_dev(u.ravel()), to_dev(pts.ravel()), ob, outs=[(out, ob)])
    assert np.allclose(out[:, :2], ref[:, :2], rtol=0, atol=1e-6)
    assert np.all(out[:, 2] == np.float32(1.0 / math.pi))
    assert np.all(out[:, 5] == np.float32(1.0 / math.pi))
    back = _disc_inverses(pts.astype(np.float64))
    assert np.allclose(out[:, 3:5], back, rtol=0, atol=2e-6), np.abs(out[:, 3:5] - back).max()


@njit(cache=True)
def _panoramic_round_trips(f):
    out = np.empty((f.shape[0], 5))
    for i in range(f.shape[0]):
        w = panoramic_direction(f[i, 0], f[i, 1])
        out[i, 0], out[i, 1], out[i, 2] = w
        out[i, 3], out[i, 4] = invert_panoramic_direction(w)
    return out


def _film_fractions(w, h, seed):
    """Each pixel's centre, its top-left corner and a random point in it, as film fractions."""
    px, py = np.meshgrid(np.arange(w), np.arange(h))
    px, py = px.ravel().astype(float), py.ravel().astype(float)
    j = uniforms(seed, 0, 0, 2, 2 * px.size).reshape(-1, 2)
    pts = [np.stack([(px + a) / w, (py + b) / h], 1) for a, b in ((0.5, 0.5), (0.0, 0.0))]
    return np.concatenate(pts + [np.stack([(px + j[:, 0]) / w, (py + j[:, 1]) / h], 1)])


def _seam(a, b):
    """Distance of two longitude fractions on the circle (fx = 0 and 1 are the same seam)."""
    d = np.abs(a - b) % 1.0
    return np.minimum(d, 1.0 - d)


def test_panoramic_round_trip_every_pixel():
    """Every pixel's centre, corner and a jittered point map to a unit direction and back
    to the same film position (longitude on the circle; at the poles, fy = 0 or 1, only the
    latitude is defined). And the convention of docs/scene_format.md: the middle column
    looks forward (+z), three quarters across looks right (+x), the top row looks up."""
    f = _film_fractions(64, 32, 24)
    out = _panoramic_round_trips(f)
    assert np.allclose(np.linalg.norm(out[:, :3], axis=1), 1.0, atol=1e-15)
    assert np.allclose(out[:, 4], f[:, 1], rtol=0, atol=1e-14)
    pole = (f[:, 1] == 0.0)
    assert np.all(_seam(out[~pole, 3], f[~pole, 0]) < 1e-14)
    conv = _panoramic_round_trips(np.array([[0.5, 0.5], [0.75, 0.5], [0.25, 0.5], [0.0, 0.5],
                                            [0.5, 0.0], [0.5, 1.0]]))[:, :3]
    want = [(0, 0, 1), (1, 0, 0), (-1, 0, 0), (0, 0, -1), (0, 1, 0), (0, -1, 0)]
    assert np.allclose(conv, want, atol=1e-15)


def test_panoramic_kernel_matches_reference(lanes):
    f = _film_fractions(32, 16, 25).astype(np.float32)
    ref = _panoramic_round_trips(f.astype(np.float64))
    w = ref[:, :3].astype(np.float32)
    back = np.array([invert_panoramic_direction(tuple(float(x) for x in v)) for v in w])
    out, ob = out_buf((len(f), 5))
    run("t_panoramic", len(f), to_dev(f.ravel()), to_dev(w.ravel()), ob, outs=[(out, ob)])
    assert np.allclose(out[:, :3], ref[:, :3], rtol=0, atol=2e-6)
    assert np.allclose(out[:, 4], back[:, 1], rtol=0, atol=1e-6)
    assert np.all(_seam(out[:, 3], back[:, 0]) < 1e-6)


CAMERAS = {
    "pinhole": {},
    "orthographic": {"type": "orthographic", "size": 1.5},
    "thin lens": {"aperture": 0.3, "focus_distance": 2.5},
    "orthographic lens": {"type": "orthographic", "aperture": 0.2, "focus_distance": 6.0},
    "panoramic": {"type": "panoramic"},
    # The focus plane almost at infinity (the pinhole's rays from every lens point) and
    # almost at the lens (rays straight away from the lens centre).
    "far focus": {"aperture": 0.3, "focus_distance": 3e38},
    "near focus": {"aperture": 0.3, "focus_distance": 1e-30},
}


def _camera_scene(keys, resolution=(9, 5)):
    cam = {"eye": [0.3, -0.4, 3.6], "target": [0.1, 0.2, -0.3], "up": [0.2, 1.0, 0.1],
           "fov": 50.0, "resolution": list(resolution), **keys}
    return scene_from_dict({"camera": cam, "medium": {"bounds": [[-1, -1, -1], [1, 1, 1]],
                                                      "density": 1.0}})


@pytest.mark.parametrize("name", list(CAMERAS))
def test_camera_ray_kernel_matches_reference(name, lanes):
    """camera_ray per pixel, film jitter and lens sample, float32 kernel against the
    float64 reference on the same packed parameters."""
    scene = _camera_scene(CAMERAS[name])
    w, h = scene.camera.resolution
    prm64 = pack_scene(scene).params[0]
    prm32 = pack_scene(scene, np.float32).params
    assert prm32.dtype == kernel_params_dtype()
    px, py = np.meshgrid(np.arange(w), np.arange(h))
    n = px.size
    u = uniforms(26, 0, 0, 2, 4 * n).reshape(n, 4)
    u[:4] = [[0, 0, 0, 0], [0.5, 0.5, 0.5, 0.5], [1 - 2**-24] * 4, [0, 1 - 2**-24] * 2]
    inp = np.column_stack([px.ravel(), py.ravel(), u]).astype(np.float32)
    out, ob = out_buf((n, 6))
    run("t_camera_ray", n, prm32[0], to_dev(inp.ravel()), ob, outs=[(out, ob)])
    ref = np.array([np.concatenate(camera_ray(prm64, int(a[0]), int(a[1]),
                                              *(float(x) for x in a[2:])))
                    for a in inp.astype(np.float64)])
    assert np.allclose(np.linalg.norm(out[:, 3:], axis=1), 1.0, atol=1e-6)
    assert np.allclose(out, ref, rtol=0, atol=3e-6), np.abs(out - ref).max()
    # Rays start on the plane at near along forward, short of the box (pack.camera_near;
    # a panoramic camera's at the eye), on the lines they have from the camera: a pinhole's
    # all pass through it.
    f, eye, near = (np.asarray(prm64[k], np.float64) for k in ("forward", "eye", "near"))
    if scene.camera.type == "panoramic":
        assert near == 0.0 and np.all(ref[:, :3] == eye)
        return
    focus = scene.camera.focus_distance if scene.camera.aperture > 0 else np.inf
    assert near == focus or 0.5 < near < 3.6 - 3**0.5     # the box is the frame: unit 1
    assert np.allclose((ref[:, :3] - eye) @ f, 0.0, rtol=0, atol=1e-12)
    if scene.camera.aperture == 0 and scene.camera.type != "orthographic":
        to_camera = eye - near * f - ref[:, :3]
        assert np.allclose(np.cross(to_camera, ref[:, 3:]), 0.0, rtol=0, atol=1e-12)


@pytest.mark.parametrize("keys", [{}, {"type": "orthographic", "size": 1.6},
                                  {"aperture": 1e-5, "focus_distance": 1e12}])
def test_a_camera_far_away_sees_the_box(keys, backend):
    """A camera 1e12 box sizes away (a telephoto at 1e8 was enough): the kernels' float32
    rounded its rays' distances to 8 units and more and rendered a box of 2 as empty sky.
    Each pixel of an absorbing box seen along its axis is exactly exp(-2)."""
    d = 1e12
    scene = scene_from_dict({
        "camera": {"eye": [0.0, 0.0, d], "target": [0.0, 0.0, 0.0],
                   "fov": float(np.degrees(2 * np.arctan(0.8 / d))), "resolution": [4, 4],
                   **keys},
        "medium": {"bounds": [[-1, -1, -1], [1, 1, 1]], "density": 1.0, "albedo": 0.0},
        # Behind the camera: no camera ray meets it, and it must not hold the plane back.
        "lights": [{"type": "environment", "radiance": 1.0},
                   {"type": "sphere", "position": [0.0, 0.0, d + 10.0], "radius": 1.0,
                    "radiance": 1.0}],
        "render": {"spp": 2}})
    img = np.asarray(render(scene, backend=backend, progress=False).image)
    assert np.allclose(img, np.exp(-2.0), rtol=2e-6, atol=0)


def test_an_orthographic_image_does_not_depend_on_the_distance(backend):
    """The same orthographic rays from 3 and from 1e10 units: the same image of a cloud to
    float rounding (the rays start on a plane short of the box either way)."""
    from volmc.resources import default_scene

    def image(z):
        scene = load_scene(default_scene(), SMALL_CLOUD + [
            f"camera.eye=[0.0, 0.0, {z}]", "camera.target=[0.0, 0.0, 0.0]",
            'camera.type="orthographic"', "camera.size=2.2", "medium.albedo=0.0"])
        return np.asarray(render(scene, backend=backend, progress=False).image)
    near, far = image(3.0), image(1e10)
    assert near.std() > 0.05
    assert np.allclose(near, far, rtol=2e-5, atol=1e-6)


SMALL_CLOUD = ["medium.density.resolution=16", "camera.resolution=[8, 6]", "render.spp=8",
               "render.max_depth=4"]


@pytest.mark.parametrize("sampler", ["independent", "sobol"])
def test_aperture_zero_is_the_pinhole_bit_for_bit(backend, sampler):
    """aperture = 0 is the pinhole: with the lens keys given (and any focus distance) every
    pixel is the render without them, bit for bit, so no lens sample was drawn and no
    sampler dimension moved."""
    from volmc.resources import default_scene
    keys = SMALL_CLOUD + [f"render.sampler={sampler}"]
    a = render(load_scene(default_scene(), keys), progress=False, backend=backend)
    b = render(load_scene(default_scene(), keys + ["camera.aperture=0",
                                                    "camera.focus_distance=1.7"]),
               progress=False, backend=backend)
    assert np.array_equal(a.film.sum, b.film.sum) and np.array_equal(a.film.sum_sq, b.film.sum_sq)
    c = render(load_scene(default_scene(), keys + ["camera.aperture=0.05"]),
               progress=False, backend=backend)
    assert not np.array_equal(a.film.sum, c.film.sum)   # the same test sees a real lens


def _edge_scene(focus, aperture, spp, sampler="independent"):
    """A black half-plane x < 0 (an absorbing slab 1e-4 thick, optical depth 100) at z = 0
    before an environment of radiance 1, seen from z = 4 by a 25 x 2 pixel camera whose
    middle column straddles the edge."""
    return scene_from_dict({
        "camera": {"eye": [0, 0, 4], "target": [0, 0, 0], "fov": 2.0 * math.degrees(
            math.atan(0.2 / 12.5)), "resolution": [25, 2], "aperture": aperture,
            "focus_distance": focus},
        "medium": {"bounds": [[-3, -3, -5e-5], [0, 3, 5e-5]], "density": 1.0, "scale": 1e6,
                   "albedo": 0.0},
        "lights": [{"type": "environment", "radiance": 1.0}],
        "render": {"spp": spp, "seed": 5, "sampler": sampler}})


def _disc_marginal_cdf(t):
    """P(X < t) of the x coordinate of a uniform point of the unit disc."""
    t = np.clip(t, -1.0, 1.0)
    return 0.5 + (t * np.sqrt(1.0 - t * t) + np.arcsin(t)) / math.pi


def _edge_expected(focus, aperture, w=25):
    """Pixel values of _edge_scene. The image plane's sx spans [-0.2, 0.2] (sx = 0 at the
    edge); the ray from lens point (lx, ly) through the focus point of sx meets z = 0 at
    x = 4 sx + lx (1 - 4 / focus), and is bright when x > 0: the pixel is the mean over its
    sx of P(lx (1 - 4 / focus) > -4 sx), by quadrature."""
    from scipy import integrate
    c = aperture * (1.0 - 4.0 / focus)
    vals = []
    for px in range(w):
        lo, hi = -0.2 + 0.4 * px / w, -0.2 + 0.4 * (px + 1) / w
        if c == 0.0:
            vals.append(max(0.0, hi - max(lo, 0.0)) / (hi - lo))
            continue
        f = (lambda s: _disc_marginal_cdf(4.0 * s / -c)) if c < 0 else \
            (lambda s: 1.0 - _disc_marginal_cdf(-4.0 * s / c))
        vals.append(integrate.quad(f, lo, hi, points=[0.0] if lo < 0 < hi else None,
                                   epsabs=1e-10)[0] / (hi - lo))
    return np.array(vals)


@pytest.mark.parametrize("sampler", ["independent", "sobol"])
def test_thin_lens_blurs_an_edge_as_the_closed_form(backend, sampler):
    """The edge image per pixel against its closed form: focused on the edge (focus 4) the
    lens gives the pinhole's image, the edge sharp within its middle pixel; focused nearer
    (2) or farther (12) the edge spreads over about 4 and 5 pixels on each side. Every
    sample is 1 (its ray passes the edge) or 0, so a pixel's count of bright samples is
    binomial: an exact two-sided binomial test per grey pixel, Sidak over the grey pixels of
    the three renders (family level ALPHA), and the pixels the closed form calls black or
    white are exactly that. With Sobol points (the lens from SAMPLER_PAIR_LENS) a pixel's
    count varies less than a binomial one, so the test only gets more conservative. The
    kernel and the reference each match it, so they match each other."""
    from scipy.stats import binomtest
    from stats import sidak
    spp, tests = 256, []
    for focus, aperture in [(4.0, 0.25), (2.0, 0.25), (12.0, 0.5)]:
        img = render(_edge_scene(focus, aperture, spp, sampler), progress=False,
                     backend=backend).film.mean()[..., 0]
        want = np.broadcast_to(_edge_expected(focus, aperture), img.shape)
        grey = (want > 1e-9) & (want < 1 - 1e-9)
        assert grey[0].sum() == 1 if focus == 4.0 else grey[0].sum() >= 7, (focus, want)
        assert np.allclose(img[~grey], np.round(want[~grey]), rtol=0, atol=1e-6), (focus, img)
        k = np.round(img[grey] * spp).astype(int)
        assert np.allclose(k, img[grey] * spp, rtol=0, atol=1e-3)   # whole counts
        tests += [binomtest(int(a), spp, float(p)).pvalue for a, p in zip(k, want[grey])]
    assert min(tests) > sidak(ALPHA, len(tests)), min(tests)


def test_panoramic_render_sees_the_environment_and_a_box(backend):
    """A panorama from the origin (forward -z, up +y) of an environment of radiance 0.7 and
    an opaque box to the right (+x): every pixel whose rays all miss the box is exactly the
    environment's radiance, every pixel whose rays all hit it is black, and the box is
    where the convention puts it, about three quarters across the image at mid-height.
    Radiance needs no weight for the pixels' solid angles."""
    from volmc.reference.integrator import ray_box
    w, h = 32, 16
    scene = scene_from_dict({
        "camera": {"type": "panoramic", "eye": [0, 0, 0], "target": [0, 0, -1],
                   "resolution": [w, h]},
        "medium": {"bounds": [[2, -1, -1], [4, 1, 1]], "density": 1.0, "scale": 1e4,
                   "albedo": 0.0},
        "lights": [{"type": "environment", "radiance": 0.7}], "render": {"spp": 16}})
    img = render(scene, progress=False, backend=backend).film.mean()
    hits = np.zeros((h, w, 2), int)   # (rays into the box, rays) over a 5 x 5 grid per pixel
    for py in range(h):
        for px in range(w):
            for a in np.linspace(0, 1, 5):
                for b in np.linspace(0, 1, 5):
                    x, y, z = panoramic_direction((px + a) / w, (py + b) / h)
                    # camera frame (right, up, forward) = world (+x, +y, -z)
                    t0, t1 = ray_box((0.0, 0.0, 0.0), (x, y, -z), (2.0, -1.0, -1.0),
                                     (4.0, 1.0, 1.0))
                    hits[py, px] += (t1 > max(t0, 0.0), 1)
    dark = hits[..., 0] == hits[..., 1]
    # Clear: no grid ray of the pixel or of its neighbours meets the box (the box's outline
    # could cut a pixel's corner between grid rays); columns wrap at the seam.
    near = np.pad(hits[..., 0] > 0, ((1, 1), (0, 0)))
    near = sum(np.roll(near, k, axis=1) for k in (-1, 0, 1))
    clear = (near[:-2] + near[1:-1] + near[2:]) == 0
    assert dark.sum() >= 8 and clear.sum() > 0.8 * w * h
    assert np.allclose(img[clear], 0.7, rtol=2e-6, atol=0)
    assert np.all(img[dark] < 1e-6)
    rows, cols = np.nonzero(dark)
    assert abs(cols.mean() + 0.5 - 0.75 * w) < 1 and abs(rows.mean() + 0.5 - 0.5 * h) < 1


@pytest.mark.parametrize("keys,key,msg", [
    ({"aperture": -0.1}, "camera.aperture", "must be in [0, inf]"),
    ({"aperture": math.nan}, "camera.aperture", "must be finite"),
    ({"aperture": "wide"}, "camera.aperture", "expected a number"),
    ({"focus_distance": 0.0}, "camera.focus_distance", "must be in (0, inf]"),
    ({"focus_distance": -2.0}, "camera.focus_distance", "must be in (0, inf]"),
    ({"focus_distance": math.inf}, "camera.focus_distance", "must be finite"),
    ({"type": "panoramic", "aperture": 0.1}, "camera.aperture", "a panoramic camera has no lens"),
    ({"type": "fisheye"}, "camera.type", "'panoramic'"),
])
def test_bad_camera_keys(keys, key, msg):
    with pytest.raises(SceneError) as e:
        _camera_scene(keys)
    assert f": {key}: " in str(e.value) and msg in str(e.value), str(e.value)
    assert "\n" not in str(e.value)


@pytest.mark.parametrize("keys", [
    {"eye": [3e38, 0.0, 0.0], "target": [-3e38, 0.0, 0.0]},   # eye to target overflows float32
    {"aperture": 3e38, "focus_distance": 1e-300},
    {"aperture": 1e-300, "focus_distance": 3e38},
])
def test_extreme_lenses_pack_finite(keys):
    """Every lens parameter reaches the kernels finite, and a lens however small stays a
    lens in float32 (both backends then draw its sample)."""
    scene = scene_from_dict({"camera": keys, "medium": {"bounds": [[-1, -1, -1], [1, 1, 1]],
                                                        "density": 1.0}})
    for real in (np.float64, np.float32):
        p = pack_scene(scene, real).params[0]
        assert np.isfinite(p["aperture"]) and np.isfinite(p["lens_slope"]), (real, p)
        assert (p["aperture"] > 0) == (scene.camera.aperture > 0)


def test_focus_distance_defaults_to_the_target_and_round_trips():
    """Without focus_distance the plane in focus passes through the target; the resolved
    scene writes it out, and the TOML reads back to the same camera."""
    from volmc.scene.schema import validate
    from volmc.scene.serialize import to_dict
    scene = _camera_scene({"aperture": 0.1})
    cam = scene.camera
    assert cam.focus_distance == pytest.approx(math.dist(cam.eye, cam.target), rel=1e-15)
    assert validate(to_dict(scene.spec), scene.spec.file).camera == cam
    assert _camera_scene({}).camera.aperture == 0.0


@pytest.mark.parametrize("command,camera,key", [
    ("render", 'aperture = -0.5', "camera.aperture"),
    ("render", 'type = "panoramic"\naperture = 0.2', "camera.aperture"),
    ("check", 'aperture = 0.1\nfocus_distance = 0', "camera.focus_distance"),
    ("render", 'focus_distance = nan', "camera.focus_distance"),
])
def test_bad_camera_file_one_line_exit_2(tmp_path, command, camera, key):
    """From a scene file: the one-line error names the file and the key, exit status 2."""
    import subprocess
    path = tmp_path / "lens.toml"
    path.write_text(f"[camera]\n{camera}\n[medium]\nbounds = [[-1, -1, -1], [1, 1, 1]]\n"
                    "density = 1.0\n")
    from cli_subprocess import volmc_cli, volmc_env
    r = subprocess.run(volmc_cli(command, str(path)), cwd=tmp_path, env=volmc_env(),
                       capture_output=True, text=True, timeout=600)
    assert r.returncode == 2, r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"volmc: error: {path}: {key}: "), r.stderr
