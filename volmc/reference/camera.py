"""Cameras: the primary ray of a film position. Twin of ``kernels/camera.h``.

The camera frame is ``pack.camera_basis``: forward, right (the image's +x) and up (the
image's top). Film position (px + u1, py + u2) is in pixels, py = 0 at the top row.

* **Perspective** (a pinhole): from the eye through the point (sx, sy) of the image plane at
  distance 1 along forward, sy = +tan(fov / 2) at the top.
* **Orthographic**: from the point eye + sx right + sy up along forward, sy = +size / 2 at
  the top.
* **Thin lens** (either of them with params.aperture > 0; pbrt's and Mitsuba's model): the
  pinhole ray's point at distance focus_distance along forward (the plane in focus) is kept,
  and the ray starts instead from a point of the lens, a disc of radius aperture about the
  pinhole ray's origin in the right/up plane, sampled uniformly (``sample_uniform_disc``)
  from the two lens uniforms (v1, v2). Points on the plane in focus stay sharp; the others
  blur into discs. A pinhole (aperture 0) ignores v1, v2, and the integrator draws none.
* **Panoramic**: equirectangular, 360 x 180 degrees about the eye (``panoramic_direction``).

Rays start on the plane at distance prm.near along forward (``pack.camera_near``: just short
of everything a camera ray can meet and of a thin lens's plane in focus; 0 for a panoramic
camera), where the ray described above crosses it, and prm.eye is moved there too (the host
does it in float64): the same lines, with origins near what they see, so a camera 1e8 box
sizes away loses no digits in float32. A perspective ray's origin is eye + near (sx right +
sy up), a thin lens's moves by (aperture - near lens_slope) q instead of aperture q, an
orthographic ray's is as above.

Every image is of radiance: a pixel is the mean radiance over its film area, with no weight
for the solid angle a pixel spans (a panoramic pixel near a pole spans less than one at the
horizon, and its value is still the mean radiance arriving through it).
"""

import math

from numba import njit

from ..constants import CAMERA_ORTHOGRAPHIC, CAMERA_PANORAMIC, PI, TWO_PI
from .sampling import normalize, sample_uniform_disc


@njit(cache=True, inline="always")
def panoramic_direction(fx, fy):
    """Unit direction (x right, y up, z forward, in the camera frame) of film fraction
    (fx, fy) in [0, 1)^2 of an equirectangular image, fy = 0 at the top.

    Longitude phi = 2 pi (fx - 1/2): the middle column looks forward, phi grows to the right
    (fx = 3/4 looks along right) and both side edges look backward. Latitude
    lat = pi (1/2 - fy): the top row looks up, the bottom row down. Seen from the eye the
    image is not mirrored: its middle is the perspective camera's image, stretched."""
    phi = TWO_PI * (fx - 0.5)
    lat = PI * (0.5 - fy)
    c = math.cos(lat)
    return c * math.sin(phi), math.sin(lat), c * math.cos(phi)


@njit(cache=True, inline="always")
def invert_panoramic_direction(w):
    """Film fraction (fx, fy) that ``panoramic_direction`` maps to unit direction w: fx in
    [0, 1] (the seam behind the camera is fx = 0 and fx = 1 alike), fy in [0, 1]. The
    latitude is atan2 of the up component against the horizontal length, accurate at the
    poles too (an asin would lose half its digits there); at a pole fx is arbitrary."""
    phi = math.atan2(w[0], w[2])
    lat = math.atan2(w[1], math.sqrt(w[0] * w[0] + w[2] * w[2]))
    return phi / TWO_PI + 0.5, 0.5 - lat / PI


@njit(cache=True, inline="always")
def camera_ray(prm, px, py, u1, u2, v1, v2):
    """Primary ray through film position (px + u1, py + u2) (pixels; py = 0 at the top), with
    lens uniforms (v1, v2) when prm.aperture > 0. Returns (origin, unit direction)."""
    f, r, u, e = prm.forward, prm.right, prm.up, prm.eye
    if prm.cam_type == CAMERA_PANORAMIC:
        w = panoramic_direction((px + u1) / prm.width, (py + u2) / prm.height)
        return (e[0], e[1], e[2]), (w[0] * r[0] + w[1] * u[0] + w[2] * f[0],
                                    w[0] * r[1] + w[1] * u[1] + w[2] * f[1],
                                    w[0] * r[2] + w[1] * u[2] + w[2] * f[2])
    sx = (2.0 * (px + u1) / prm.width - 1.0) * prm.half_height * prm.aspect
    sy = (1.0 - 2.0 * (py + u2) / prm.height) * prm.half_height
    if prm.cam_type == CAMERA_ORTHOGRAPHIC:
        o = (e[0] + sx * r[0] + sy * u[0], e[1] + sx * r[1] + sy * u[1],
             e[2] + sx * r[2] + sy * u[2])
        if not prm.aperture > 0.0:
            return o, (f[0], f[1], f[2])
        v = (f[0], f[1], f[2])
    else:
        # From the plane at prm.near along forward (module docstring).
        n = prm.near
        o = (e[0] + sx * n * r[0] + sy * n * u[0], e[1] + sx * n * r[1] + sy * n * u[1],
             e[2] + sx * n * r[2] + sy * n * u[2])
        v = (f[0] + sx * r[0] + sy * u[0], f[1] + sx * r[1] + sy * u[1],
             f[2] + sx * r[2] + sy * u[2])
        if not prm.aperture > 0.0:
            return o, normalize(v)
    # v has length 1 along forward, so the pinhole ray meets the plane in focus at o + F v.
    # From the lens point o + a q (q on the unit disc in the right/up plane) the direction
    # is F v - a q, or v - (a / F) q: no absolute position enters it (a camera far from
    # the origin loses no digits), and the ratio a / F (prm.lens_slope) is finite for
    # every focus distance (F v alone would overflow float32 for a far focus plane).
    # Scaled by its largest component before normalising: with a large slope its squared
    # length would overflow float32 in the kernel.
    (lx, ly), _ = sample_uniform_disc(v1, v2)
    q = (lx * r[0] + ly * u[0], lx * r[1] + ly * u[1], lx * r[2] + ly * u[2])
    k, a = prm.lens_slope, prm.aperture
    w = (v[0] - k * q[0], v[1] - k * q[1], v[2] - k * q[2])
    s = 1.0 / max(abs(w[0]), abs(w[1]), abs(w[2]))
    d = normalize((w[0] * s, w[1] * s, w[2] * s))
    # From the lens point, w has length 1 along forward: it meets the plane at near after
    # near w, at o + a q + near (v - k q) = (the pinhole ray's point there) + (a - near k) q.
    a = a - prm.near * k
    return (o[0] + a * q[0], o[1] + a * q[1], o[2] + a * q[2]), d
