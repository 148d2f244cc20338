"""Placement of a medium: the affine map from its local space (the box ``bounds``, the grid's
voxels) to the world.

Convention, written once here and in docs/scene_format.md: a transform is a 4x4 affine
matrix M, row-major, acting on column vectors, ``world = M @ [x, y, z, 1]``. The TOML form
``{ scale = S, rotate = R, translate = T }`` composes M = translate(T) @ rotate(R) @ scale(S):
scale first, then rotate, then translate. ``rotate = [ax, ay, az, degrees]`` turns
right-handed about the axis (counter-clockwise seen from its tip); a list of such rotations
applies them in order, the first first. A ray enters local space through the inverse map
without renormalising its direction, so a distance along it stays a world distance and
extinction stays per world unit (pbrt-v4's rule): scaling a medium by 2 doubles the optical
depth across it.
"""

import math

import numpy as np

TRANSFORM_KEYS = ("scale", "rotate", "translate", "matrix")

#: Smallest |det M| / (product of the column lengths) a transform may have: below it the map
#: is singular as far as float32 kernels are concerned (its inverse would lose every digit).
MIN_CONDITION = 1e-6


def rotation(axis, degrees):
    """3x3 right-handed rotation by ``degrees`` about ``axis`` (any non-zero length)."""
    a = np.asarray(axis, float)
    a = a / np.max(np.abs(a))   # first: the norm of a 1e-170 axis underflows to 0
    a = a / np.linalg.norm(a)
    th = math.radians(degrees)
    c, s = math.cos(th), math.sin(th)
    x, y, z = a
    k = np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])
    return c * np.eye(3) + s * k + (1.0 - c) * np.outer(a, a)


def axis_angle(r):
    """[ax, ay, az, degrees] of the 3x3 rotation r (a scene's ``rotate`` value that gives it
    back to rounding)."""
    r = np.asarray(r, float)
    c = min(max((np.trace(r) - 1.0) * 0.5, -1.0), 1.0)
    v = np.array([r[2, 1] - r[1, 2], r[0, 2] - r[2, 0], r[1, 0] - r[0, 1]])
    if np.linalg.norm(v) > 1e-6:
        axis = v / np.linalg.norm(v)
    elif c > 0.0:
        return [0.0, 1.0, 0.0, 0.0]
    else:   # a half turn: r = 2 a a^T - I
        k = int(np.argmax(np.diag(r)))
        axis = (r[:, k] + np.eye(3)[k]) / np.linalg.norm(r[:, k] + np.eye(3)[k])
    return [float(x) for x in axis] + [math.degrees(math.acos(c))]


def compose(scale=(1.0, 1.0, 1.0), rotations=(), translate=(0.0, 0.0, 0.0)):
    """The 4x4 matrix translate @ rotate_n @ ... @ rotate_1 @ scale."""
    lin = np.diag(np.asarray(scale, float))
    for axis, deg in rotations:
        lin = rotation(axis, deg) @ lin
    m = np.eye(4)
    m[:3, :3] = lin
    m[:3, 3] = translate
    return m


def as_tuple(m):
    """A matrix as the scene keeps it: a 4x4 tuple of float rows."""
    return tuple(tuple(float(x) for x in row) for row in np.asarray(m, float))


def singularity(m):
    """None when the 4x4 affine m is invertible in float32 terms, else why not."""
    lin = np.asarray(m, float)[:3, :3]
    cols = np.linalg.norm(lin, axis=0)
    if not np.all(cols > 0.0):
        return "it maps an axis to zero"
    det = float(np.linalg.det(lin))
    cond = abs(det) / float(np.prod(cols))
    if not cond >= MIN_CONDITION:
        return f"its 3x3 part is singular (det {det:.3g}, {cond:.2g} of the volume its " \
               f"columns span; at least {MIN_CONDITION:g})"
    return None


def is_axis_scale(m):
    """True when m only scales each axis by a positive factor and translates: such a map is
    the same as moving the box's corners, so the kernels need no transform for it."""
    lin = np.asarray(m, float)[:3, :3]
    return bool(np.all(lin == np.diag(np.diag(lin))) and np.all(np.diag(lin) > 0.0))


def world_box(m, lo, hi):
    """(lo, hi) of the world's axis-aligned box around the local box [lo, hi] placed by m."""
    corners = np.array([[(lo, hi)[i][0], (lo, hi)[j][1], (lo, hi)[k][2]]
                        for i in (0, 1) for j in (0, 1) for k in (0, 1)])
    w = corners @ np.asarray(m, float)[:3, :3].T + np.asarray(m, float)[:3, 3]
    return tuple(float(x) for x in w.min(axis=0)), tuple(float(x) for x in w.max(axis=0))


def box_frame(lo, hi):
    """(centre, unit) of the box [lo, hi]: its centre and a power of two close to its largest
    half-extent (``scene_frame``; a placed medium's local space gets one too)."""
    centre = tuple(0.5 * (lo[i] + hi[i]) for i in range(3))
    half = max(0.5 * (hi[i] - lo[i]) for i in range(3))
    return centre, 2.0 ** round(math.log2(half))


def placement(medium):
    """(lo, hi, M): the world's axis-aligned box around the placed medium, and the transform
    the kernels must apply (4x4 float64 array), or None when the box alone places the medium:
    no transform, or one that only scales axes by positive factors and translates (then
    [lo, hi] is the placed box itself and the grid keeps its orientation)."""
    lo, hi = medium.bounds
    m = medium.transform
    if m is None:
        return tuple(lo), tuple(hi), None
    wlo, whi = world_box(m, lo, hi)
    return wlo, whi, (None if is_axis_scale(m) else np.array(m, float))


def parse(c, raw, key):
    """A validated transform table (scene keys, see the module docstring) as a 4x4 tuple, or
    None for the identity. ``c`` is the schema's checker: errors name ``key``'s sub-keys."""
    c.table(raw, key)
    c.known(raw, TRANSFORM_KEYS, key + ".")
    if "matrix" in raw:
        others = [k for k in raw if k != "matrix"]
        if others:
            c.fail(f"{key}.{others[0]}", "a transform is either a 'matrix' or scale/rotate/"
                                         "translate, not both")
        m = _matrix(c, raw["matrix"], key + ".matrix")
    else:
        s = raw.get("scale", 1.0)
        if isinstance(s, list):
            s = c.vec3(s, key + ".scale")
        else:
            s = (c.number(s, key + ".scale"),) * 3
        rots = _rotations(c, raw.get("rotate", []), key + ".rotate")
        t = c.vec3(raw.get("translate", [0.0, 0.0, 0.0]), key + ".translate")
        m = compose(s, rots, t)
        if not np.all(np.isfinite(m)):
            c.fail(key, "the composed matrix is not finite")
    why = singularity(m)
    if why:
        c.fail(key, f"transform is singular: {why}")
    if np.array_equal(m, np.eye(4)):
        return None
    return as_tuple(m)


def _matrix(c, v, key):
    if not (isinstance(v, list) and len(v) == 4 and all(isinstance(r, list) and len(r) == 4
                                                         for r in v)):
        c.fail(key, "expected 4 rows of 4 numbers (row-major; world = M x local)")
    m = np.array([[c.number(x, key) for x in row] for row in v])
    if not np.array_equal(m[3], [0.0, 0.0, 0.0, 1.0]):
        c.fail(key, f"not affine: the last row must be [0, 0, 0, 1], got "
                    f"{[float(x) for x in m[3]]}")
    return m


def _rotations(c, v, key):
    """[ax, ay, az, degrees] or a list of those, as [(axis, degrees), ...]."""
    if not isinstance(v, list):
        c.fail(key, f"expected [ax, ay, az, degrees] or a list of them, got {type(v).__name__}")
    if v and not isinstance(v[0], list):
        v = [v]
    out = []
    for i, r in enumerate(v):
        k = key if len(v) == 1 else f"{key}[{i}]"
        if not isinstance(r, list) or len(r) != 4:
            c.fail(k, "expected [ax, ay, az, degrees]")
        axis = c.vec3(r[:3], k, nonzero=True)
        out.append((axis, c.number(r[3], k)))
    return out
