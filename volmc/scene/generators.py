"""Procedural density generators for participating media.

``cloud`` builds a cumulus cloud in the unit cube (+y up) in three stages:

1. Shape: a signed distance built from a low, wide dome (the body) plus a
   hierarchy of spheres ("puffs"): a tall central tower and a few lower
   towers (vertical stacks of puffs) whose heads form the big lumps of the
   top, bulges on the flanks, then two generations of smaller children on
   the upper side of every exposed puff for the cauliflower billows.  They
   are merged with a polynomial smooth-min and cut by the horizontal base
   plane with a smooth-max, so the base is flat.
2. Detail: the lookup point is domain-warped by fBm of gradient (Perlin)
   noise, and the distance is eroded by three octaves of Worley (cellular)
   noise, which add the small round bulges of a billowing surface.  Both
   fade out towards the base so it stays flat and fairly sharp.
3. Density: the eroded distance becomes a coverage that is 1 inside and
   falls to 0 over a thin shell; in that shell a high-frequency fBm erodes
   the low-coverage part away, leaving wispy edges around a solid core.

The density is a continuous function of the normalised point, evaluated at
voxel centres, so every resolution samples the same cloud.  All randomness
comes from ``numpy.random.default_rng(seed)`` (puff layout and the noise
permutation table), never from global RNG state.

``plume`` builds a rising smoke plume with its temperature: a column that
widens linearly with height from a small hot source near the floor, its axis
drifting and meandering, its cross-section domain-warped by fBm and its edge
eroded by fBm into wisps.  The noise is sampled in coordinates that scale with
the local plume width (eddies grow as the plume spreads), the density thins
with height, and the temperature falls from a glowing core at the base to the
ambient air.  Same conventions as ``cloud``: a continuous function of the
point, evaluated at voxel centres, seeded only through ``default_rng(seed)``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from numba import njit, prange

__all__ = ["cloud", "plume"]

# Voxel centres closer than this (fraction of the extent) to any face are
# forced to zero; the puff layout also keeps the cloud clear of this band so
# the cloud is never visibly cut by the box.
_FACE_MARGIN = 0.05

# Maximum displacement of the domain warp (unit-cube distance).  The warp
# fBm is clamped to [-1, 1] so this is a hard bound, which the kernel uses to
# skip noise evaluation far from the surface.
_WARP_AMP = 0.03
# Worley erosion amplitudes at the base and at the top of the cloud.
_EROSION_BASE = 0.006
_EROSION_TOP = 0.060
# Worley erosion lies in [_EROSION_LO, _EROSION_HI] * amplitude.
_EROSION_LO = -0.3
_EROSION_HI = 0.7
# Coverage goes from 0 to 1 over this distance inside the eroded surface.
_SHELL = 0.035
# Strongest erosion of low coverage by the wisp fBm (0 = none, 1 = all).
_WISP = 0.75
# Smooth-union radius between puffs: small so creases between billows stay.
_K_UNION = 0.03
# Smooth-max radius with the base plane: rounds the base rim slightly.
_K_BASE = 0.02
# Side-view squareness of the core dome (2 = ellipsoid).
_CORE_P = 2.5
# Resolution of the coarse distance grid used only to skip work.
_COARSE = 32
# How far above the base the detail noise fades in.
_BASE_FADE = 0.10


# --------------------------------------------------------------------------
# Noise primitives (numba).  ``perm`` is a 512-entry doubled permutation of
# 0..255, so nested lookups never need an extra mask.
# --------------------------------------------------------------------------


@njit(cache=True, inline="always")
def _fade(t):
    return t * t * t * (t * (t * 6.0 - 15.0) + 10.0)


@njit(cache=True, inline="always")
def _grad(h, x, y, z):
    # The 12 cube-edge gradients of improved Perlin noise (16 with repeats).
    h = h & 15
    u = x if h < 8 else y
    if h < 4:
        v = y
    elif h == 12 or h == 14:
        v = x
    else:
        v = z
    a = u if (h & 1) == 0 else -u
    b = v if (h & 2) == 0 else -v
    return a + b


@njit(cache=True)
def _perlin(perm, x, y, z):
    fx = math.floor(x)
    fy = math.floor(y)
    fz = math.floor(z)
    xi = int(fx) & 255
    yi = int(fy) & 255
    zi = int(fz) & 255
    x -= fx
    y -= fy
    z -= fz
    u = _fade(x)
    v = _fade(y)
    w = _fade(z)
    a = perm[xi] + yi
    aa = perm[a] + zi
    ab = perm[a + 1] + zi
    b = perm[xi + 1] + yi
    ba = perm[b] + zi
    bb = perm[b + 1] + zi
    x1 = x - 1.0
    y1 = y - 1.0
    z1 = z - 1.0
    g000 = _grad(perm[aa], x, y, z)
    g100 = _grad(perm[ba], x1, y, z)
    g010 = _grad(perm[ab], x, y1, z)
    g110 = _grad(perm[bb], x1, y1, z)
    g001 = _grad(perm[aa + 1], x, y, z1)
    g101 = _grad(perm[ba + 1], x1, y, z1)
    g011 = _grad(perm[ab + 1], x, y1, z1)
    g111 = _grad(perm[bb + 1], x1, y1, z1)
    x00 = g000 + u * (g100 - g000)
    x10 = g010 + u * (g110 - g010)
    x01 = g001 + u * (g101 - g001)
    x11 = g011 + u * (g111 - g011)
    y0 = x00 + v * (x10 - x00)
    y1_ = x01 + v * (x11 - x01)
    return y0 + w * (y1_ - y0)


@njit(cache=True)
def _fbm(perm, x, y, z, octaves):
    """Perlin fBm normalised by its amplitude sum and clamped to [-1, 1]."""
    s = 0.0
    amp = 1.0
    norm = 0.0
    for _ in range(octaves):
        s += amp * _perlin(perm, x, y, z)
        norm += amp
        amp *= 0.5
        # Irrational-ish lacunarity and a shift keep octaves from aligning
        # on the same lattice planes.
        x = x * 2.03 + 17.1
        y = y * 2.03 + 31.7
        z = z * 2.03 + 5.3
    s /= norm
    return min(1.0, max(-1.0, s))


@njit(cache=True)
def _worley(perm, x, y, z):
    """Distance to the nearest feature point (one per cell), in cell units,
    clamped to [0, 1]."""
    fx = math.floor(x)
    fy = math.floor(y)
    fz = math.floor(z)
    ix = int(fx)
    iy = int(fy)
    iz = int(fz)
    best = 1e30
    for dz in range(-1, 2):
        for dy in range(-1, 2):
            for dx in range(-1, 2):
                cx = ix + dx
                cy = iy + dy
                cz = iz + dz
                h = perm[perm[perm[cx & 255] + (cy & 255)] + (cz & 255)]
                px = cx + (perm[h] + 0.5) * (1.0 / 256.0) - x
                py = cy + (perm[h + 1] + 0.5) * (1.0 / 256.0) - y
                pz = cz + (perm[h + 2] + 0.5) * (1.0 / 256.0) - z
                d2 = px * px + py * py + pz * pz
                if d2 < best:
                    best = d2
    return min(1.0, math.sqrt(best))


# --------------------------------------------------------------------------
# Shape and density kernel
# --------------------------------------------------------------------------


@njit(cache=True)
def _shape_sdf(core, puffs, base_y, x, y, z):
    """Smooth union of the core dome and the puff spheres, cut by the base
    plane.

    Every operation is 1-Lipschitz, so the result moves by at most |dp| when
    the point moves by dp; the kernel relies on that for its early-outs.
    """
    # Core: a dome that is round seen from above but boxier than an
    # ellipsoid from the side (steep flanks, broad top): in scaled
    # coordinates it is the unit ball of the norm (h^p + |v|^p)^(1/p) with h
    # the horizontal radius.  For p >= 2 that norm has gradient length <= 1,
    # so (norm - 1) * min semi-axis is a 1-Lipschitz under-estimate of the
    # distance.
    dx = x - core[0]
    dy = y - core[1]
    dz = z - core[2]
    u = (core[6] * dx + core[7] * dz) / core[3]
    w = (-core[7] * dx + core[6] * dz) / core[5]
    v = abs(dy) / core[4]
    hr = math.sqrt(u * u + w * w)
    nrm = (hr ** _CORE_P + v ** _CORE_P) ** (1.0 / _CORE_P)
    d = (nrm - 1.0) * min(core[3], min(core[4], core[5]))
    for n in range(puffs.shape[0]):
        ex = x - puffs[n, 0]
        ey = y - puffs[n, 1]
        ez = z - puffs[n, 2]
        di = math.sqrt(ex * ex + ey * ey + ez * ez) - puffs[n, 3]
        # Polynomial smooth-min: equal to min() once |d - di| >= k.
        h = _K_UNION - abs(d - di)
        if h > 0.0:
            d = min(d, di) - h * h * (0.25 / _K_UNION)
        elif di < d:
            d = di
    # Smooth-max with the half-space y >= base_y.
    p = base_y - y
    h = _K_BASE - abs(d - p)
    if h > 0.0:
        return max(d, p) + h * h * (0.25 / _K_BASE)
    return max(d, p)


@njit(parallel=True, cache=True)
def _coarse_sdf(core, puffs, base_y, g):
    """Shape distance at the centres of a g^3 grid over the unit cube."""
    c = np.empty((g, g, g))
    for k in prange(g):
        for j in range(g):
            for i in range(g):
                c[k, j, i] = _shape_sdf(core, puffs, base_y, (i + 0.5) / g,
                                        (j + 0.5) / g, (k + 0.5) / g)
    return c


@njit(parallel=True, cache=True)
def _cloud_kernel(out, core, puffs, perm, base_y, top_y, coarse):
    nz, ny, nx = out.shape
    g = coarse.shape[0]
    # A voxel is at most half a coarse cell diagonal from its cell centre;
    # with the 1-Lipschitz shape distance that bounds its distance without
    # evaluating every puff (most voxels are far outside or deep inside).
    slack = 0.5 * math.sqrt(3.0) / g
    warp_freq = 3.0
    wisp_freq = 14.0
    worley_f1 = 9.0
    worley_f2 = 21.0
    worley_f3 = 43.0
    # Bounds for skipping noise: see the Lipschitz note in _shape_sdf.
    reach_out = _WARP_AMP - _EROSION_LO * _EROSION_TOP
    reach_in = _SHELL + _WARP_AMP + _EROSION_HI * _EROSION_TOP
    for k in prange(nz):
        z = (k + 0.5) / nz
        for j in range(ny):
            y = (j + 0.5) / ny
            for i in range(nx):
                x = (i + 0.5) / nx
                if (
                    x < _FACE_MARGIN or x > 1.0 - _FACE_MARGIN
                    or y < _FACE_MARGIN or y > 1.0 - _FACE_MARGIN
                    or z < _FACE_MARGIN or z > 1.0 - _FACE_MARGIN
                ):
                    out[k, j, i] = 0.0
                    continue
                dc = coarse[min(int(z * g), g - 1), min(int(y * g), g - 1),
                            min(int(x * g), g - 1)]
                if dc > reach_out + slack:
                    out[k, j, i] = 0.0
                    continue
                if dc < -(reach_in + slack):
                    out[k, j, i] = 1.0
                    continue
                d0 = _shape_sdf(core, puffs, base_y, x, y, z)
                if d0 > reach_out:
                    out[k, j, i] = 0.0
                    continue
                if d0 < -reach_in:
                    out[k, j, i] = 1.0
                    continue

                # 0 at the base, 1 once well above it: detail and vertical
                # warp fade in with height so the base stays flat.
                hb = (y - base_y) / _BASE_FADE
                hb = min(1.0, max(0.0, hb))
                hb = hb * hb * (3.0 - 2.0 * hb)
                # Relative height in the cloud: tops billow more than flanks.
                ht = (y - base_y) / (top_y - base_y)
                ht = min(1.0, max(0.0, ht))

                wx = _fbm(perm, x * warp_freq, y * warp_freq, z * warp_freq, 3)
                wy = _fbm(perm, x * warp_freq + 41.3, y * warp_freq + 7.9,
                          z * warp_freq + 23.1, 3)
                wz = _fbm(perm, x * warp_freq + 83.7, y * warp_freq + 59.2,
                          z * warp_freq + 11.6, 3)
                # Scale the vector so its length never exceeds _WARP_AMP.
                wl = math.sqrt(wx * wx + wy * wy * hb * hb + wz * wz)
                ws = _WARP_AMP / max(1.0, wl)
                d = _shape_sdf(core, puffs, base_y, x + wx * ws, y + wy * hb * ws,
                               z + wz * ws)
                # The Worley term below moves d by at most these amounts, so
                # the (costly) cellular noise is often not needed.
                if d > -_EROSION_LO * _EROSION_TOP:
                    out[k, j, i] = 0.0
                    continue
                if d < -(_SHELL + _EROSION_HI * _EROSION_TOP):
                    out[k, j, i] = 1.0
                    continue

                # Cellular billows: nearer a feature point = bulge outwards.
                # Squared F1 makes the bulges round-topped with sharp creases
                # between them, like cauliflower florets.
                c1 = _worley(perm, x * worley_f1 + 3.7, y * worley_f1 + 91.1,
                             z * worley_f1 + 47.5)
                c2 = _worley(perm, x * worley_f2 + 61.3, y * worley_f2 + 13.9,
                             z * worley_f2 + 77.7)
                c3 = _worley(perm, x * worley_f3 + 29.1, y * worley_f3 + 53.3,
                             z * worley_f3 + 7.1)
                cell = 0.5 * c1 * c1 + 0.33 * c2 * c2 + 0.17 * c3 * c3
                e = min(_EROSION_HI, max(_EROSION_LO, cell - 0.3))
                amp = _EROSION_BASE + (_EROSION_TOP - _EROSION_BASE) * hb * (
                    0.6 + 0.4 * ht)
                d += e * amp

                cov = -d / _SHELL
                if cov <= 0.0:
                    out[k, j, i] = 0.0
                    continue
                if cov >= 1.0:
                    out[k, j, i] = 1.0
                    continue
                # Erode low coverage with fBm so the shell breaks into wisps;
                # the base keeps a little more of its edge.
                n = _fbm(perm, x * wisp_freq + 5.5, y * wisp_freq + 19.3,
                         z * wisp_freq + 71.9, 3)
                er = _WISP * (0.35 + 0.4 * hb) * (0.5 + 0.5 * n)
                v = (cov - er) / (1.0 - er)
                if v <= 0.0:
                    out[k, j, i] = 0.0
                    continue
                out[k, j, i] = v * v * (3.0 - 2.0 * v)


# --------------------------------------------------------------------------
# Puff layout (numpy, tiny)
# --------------------------------------------------------------------------

# Puffs (sphere + worst-case outward displacement) stay inside this box so
# the face margin never cuts the cloud.
_LO = _FACE_MARGIN + _WARP_AMP - _EROSION_LO * _EROSION_TOP + 0.01
_HI = 1.0 - _LO


def _layout_puffs(rng: np.random.Generator):
    """Return (core[8], puffs[N, 4], base_y, top_y) for one cloud.

    core = (cx, cy, cz, ax, ay, az, cos, sin): a low, wide dome rotated
    about y; puffs rows = (cx, cy, cz, r).
    """
    base_y = 0.15 + rng.uniform(-0.015, 0.015)
    top_y = min(_HI - 0.04, base_y + rng.uniform(0.66, 0.71))
    height = top_y - base_y
    sx = 0.5 + rng.uniform(-0.03, 0.03)
    sz = 0.5 + rng.uniform(-0.03, 0.03)
    ang = rng.uniform(0.0, np.pi)
    ca, sa = np.cos(ang), np.sin(ang)
    # Footprint ellipse half-axes; the core dome spans it and is low, so the
    # flat base is wide and the height comes from the towers.
    ax = rng.uniform(0.35, 0.39)
    az = rng.uniform(0.31, 0.35)
    # Rotated, the footprint reaches max(ax, az) from its centre: keep it
    # inside the same box as the puffs.
    lim = min(sx - _LO, _HI - sx, sz - _LO, _HI - sz)
    ax, az = min(ax, lim), min(az, lim)
    cy = base_y - 0.06
    ay = 0.65 * height + 0.06
    core = np.array([sx, cy, sz, ax, ay, az, ca, sa])

    def footprint(s, t):
        """Point at polar (s, t) of the footprint ellipse, s in [0, 1]."""
        lx, lz = s * ax * np.cos(t), s * az * np.sin(t)
        return sx + ca * lx - sa * lz, sz + sa * lx + ca * lz

    def fit(c, r):
        """Shrink r so the sphere stays inside the box (minus the margin)."""
        return min(r, c[0] - _LO, _HI - c[0], c[2] - _LO, _HI - c[2], _HI - c[1])

    puffs = []

    # Towers: columns of puffs rising from the body, the main one near the
    # centre and tallest, the others lower; their rounded heads are the big
    # lumps of the cauliflower top.
    n_towers = int(rng.integers(4, 7))
    t0 = rng.uniform(0.0, 2.0 * np.pi)
    for k in range(n_towers):
        if k == 0:
            s, t, frac = rng.uniform(0.0, 0.2), t0, 1.0
            rad = rng.uniform(0.18, 0.21)
        else:
            # Spread the others around the footprint.
            t = t0 + 2.0 * np.pi * k / (n_towers - 1) + rng.uniform(-0.4, 0.4)
            s = rng.uniform(0.35, 0.6)
            frac = rng.uniform(0.5, 0.85)
            rad = rng.uniform(0.13, 0.18)
        px, pz = footprint(s, t)
        head = base_y + frac * height
        lean = rng.normal(size=2) * 0.04
        # Stack puffs 0.7 radii apart from just above the base up to the
        # head, narrowing slightly so the cloud reads as a dome of towers.
        y0 = base_y + 0.3 * rad
        y1 = max(y0, head - 1.05 * rad)
        n_stack = 1 + int(np.ceil((y1 - y0) / (0.7 * rad)))
        for m in range(n_stack):
            f = m / max(n_stack - 1, 1)
            r = rad * (1.0 - 0.15 * f)
            c = np.array([px + lean[0] * f, y0 + (y1 - y0) * f, pz + lean[1] * f])
            c[[0, 2]] += rng.normal(size=2) * 0.15 * r
            r = fit(c, r)
            if r > 0.04:
                puffs.append(np.array([*c, r]))

    # Bulges on the flanks of the low body.
    for _ in range(int(rng.integers(10, 15))):
        t = rng.uniform(0.0, 2.0 * np.pi)
        px, pz = footprint(rng.uniform(0.8, 0.95), t)
        r = rng.uniform(0.06, 0.1)
        c = np.array([px, base_y + rng.uniform(0.2, 1.0) * 0.3 * height, pz])
        r = fit(c, r)
        if r > 0.03:
            puffs.append(np.array([*c, r]))

    def union_dist(c, arr):
        dd = np.linalg.norm(arr[:, :3] - c, axis=1) - arr[:, 3]
        return dd.min()

    # Children on the upper hemisphere of each exposed parent give the
    # smaller billows; children buried inside the cloud add nothing.
    parents = list(puffs)
    for nmin, nmax, (s0, s1) in [(3, 6, (0.45, 0.65)), (2, 4, (0.45, 0.6))]:
        arr = np.array(puffs)
        children = []
        for p in parents:
            for _ in range(int(rng.integers(nmin, nmax + 1))):
                d = rng.normal(size=3)
                d[1] = abs(d[1]) + 0.35
                d /= np.linalg.norm(d)
                c = p[:3] + d * p[3] * rng.uniform(0.6, 0.9)
                want = p[3] * rng.uniform(s0, s1)
                r = fit(c, want)
                # Drop rather than flatten children that hit a limit: many
                # shrunken puffs would line up into a visible flat wall.
                if r < 0.8 * want or r < 0.022 or c[1] < base_y + 0.3 * r:
                    continue
                # Children may crown their parent but not tower over it, so
                # heights stay set by the towers, without a common ceiling.
                if c[1] + r > p[1] + p[3] + 0.4 * r:
                    continue
                # Keep only children that poke out of the cloud by >= 0.3 r.
                if union_dist(c, arr) < -0.7 * r:
                    continue
                children.append(np.array([*c, r]))
        puffs.extend(children)
        parents = children

    puffs = np.ascontiguousarray(np.array(puffs, dtype=np.float64).reshape(-1, 4))
    return core, puffs, base_y, top_y


def _parse_resolution(resolution) -> tuple[int, int, int]:
    if isinstance(resolution, (int, np.integer)):
        n = int(resolution)
        shape = (n, n, n)
    elif isinstance(resolution, Sequence) or isinstance(resolution, np.ndarray):
        if len(resolution) != 3:
            raise ValueError("resolution must be an int or a 3-sequence (nx, ny, nz)")
        shape = tuple(int(v) for v in resolution)
    else:
        raise TypeError("resolution must be an int or a 3-sequence (nx, ny, nz)")
    if min(shape) < 1:
        raise ValueError(f"resolution must be positive, got {shape}")
    return shape


def cloud(resolution, seed: int = 0) -> np.ndarray:
    """Procedural cumulus cloud density on a regular grid.

    Parameters
    ----------
    resolution:
        ``n`` for an n x n x n grid, or ``(nx, ny, nz)``.
    seed:
        Selects the cloud; the same seed always gives the same cloud.

    Returns
    -------
    numpy.ndarray
        float32, C-contiguous, shape ``(nz, ny, nx)`` indexed ``[z, y, x]``
        (x fastest).  Values are dimensionless densities in [0, 1] (scale by
        the medium's extinction coefficient when rendering): about 1 in the
        interior, falling to 0 over a thin wispy shell.  The grid spans the
        unit cube with +y up (flat base at low y, billowing tops at high y);
        voxel (i, j, k) samples the point ((i+0.5)/nx, (j+0.5)/ny,
        (k+0.5)/nz), so grids of any resolution describe the same cloud
        (a non-cubic resolution only changes the sampling density; the
        cloud stretches with whatever box the grid is mapped to).
        Voxels whose centre lies within 5 % of the extent of any face are
        exactly 0.
    """
    nx, ny, nz = _parse_resolution(resolution)
    rng = np.random.default_rng(seed)
    perm = rng.permutation(256).astype(np.int32)
    perm = np.concatenate([perm, perm])
    core, puffs, base_y, top_y = _layout_puffs(rng)
    out = np.empty((nz, ny, nx), dtype=np.float32)
    coarse = _coarse_sdf(core, puffs, float(base_y), _COARSE)
    _cloud_kernel(out, core, puffs, perm, float(base_y), float(top_y), coarse)
    return out


# --------------------------------------------------------------------------
# Plume
# --------------------------------------------------------------------------

# Ambient and peak temperature of the plume, kelvin.
PLUME_T_AMBIENT = 300.0
PLUME_T_CORE = 1800.0
# Height of the source (the plume starts here) and of the plume's end (h = 1):
# the wisps are gone below the top face's margin.
_PLUME_Y0 = 0.08
_PLUME_Y1 = 0.93
# Radius at the source, unit cube (the radius at the top is drawn per seed).
_PLUME_R0 = 0.05
# Horizontal domain warp, in units of the local radius (a hard bound: the warp
# vector's length is clamped to it): small at the source, where the flow is
# still laminar, growing to the full amount by mid-height.  Then the fBm
# frequency of the warp and of the wisps, in local-radius units.
_PLUME_WARP0 = 0.2
_PLUME_WARP = 0.55
_PLUME_WARP_FREQ = 0.7
_PLUME_WISP_FREQ = 2.2
# Bulges of the column: the radius varies by up to this fraction with height.
_PLUME_BULGE = 0.25
# Coverage (radial profile less erosion) over which the density rises from 0
# to full: a soft edge.
_PLUME_SHELL = 0.6
# Distance from the faces over which the plume is faded out (it is exactly 0
# within _FACE_MARGIN).
_PLUME_FADE = 0.07
# The core stays at full heat up to _PLUME_HOT_H, then cools with height
# scale _PLUME_COOL (h units); the hot core's radius is _PLUME_HOT_R of the
# local radius.
_PLUME_HOT_H = 0.1
_PLUME_COOL = 0.15
_PLUME_HOT_R = 0.9


@njit(cache=True, inline="always")
def _smooth(a, b, x):
    t = min(1.0, max(0.0, (x - a) / (b - a)))
    return t * t * (3.0 - 2.0 * t)


@njit(parallel=True, cache=True)
def _plume_kernel(dens, temp, perm, par):
    nz, ny, nx = dens.shape
    cx, cz, lean_x, lean_z, meander, r1, o0, o1 = (par[0], par[1], par[2], par[3], par[4],
                                                   par[5], par[6], par[7])
    height = _PLUME_Y1 - _PLUME_Y0
    spread = (r1 - _PLUME_R0) / height      # dr/dy
    # Beyond this many local radii from the axis nothing is left: the radial
    # profile and the hot core end at q = 1, and the warp moves a point by at
    # most _PLUME_WARP radii.
    q_out = 1.0 + _PLUME_WARP
    for k in prange(nz):
        z = (k + 0.5) / nz
        for j in range(ny):
            y = (j + 0.5) / ny
            for i in range(nx):
                dens[k, j, i] = 0.0
                temp[k, j, i] = PLUME_T_AMBIENT
            h = (y - _PLUME_Y0) / height
            if h <= 0.0 or h >= 1.0:
                continue
            # Window: zero within the face margin, fading in over _PLUME_FADE.
            wz = _smooth(_FACE_MARGIN, _FACE_MARGIN + _PLUME_FADE, min(z, 1.0 - z))
            wy = _smooth(_FACE_MARGIN, _FACE_MARGIN + _PLUME_FADE, min(y, 1.0 - y))
            if wz <= 0.0 or wy <= 0.0:
                continue
            # Axis: a steady drift (lean, growing as h^2) plus a meander whose
            # amplitude grows with height.
            ax = cx + lean_x * h * h + meander * h * _fbm(perm, o0, y * 2.5, o1, 3)
            az = cz + lean_z * h * h + meander * h * _fbm(perm, o1, y * 2.5 + 37.0, o0, 3)
            r = _PLUME_R0 + spread * (y - _PLUME_Y0)
            r *= 1.0 + _PLUME_BULGE * _fbm(perm, o0 + 11.0, y * 6.0, o1 + 5.0, 2)
            # Self-similar height coordinate: integral of dy / r (unbulged),
            # so the eddies are as tall as they are wide.
            s = math.log(1.0 + spread * (y - _PLUME_Y0) / _PLUME_R0) / spread
            # Thinning with height and the top fade.
            amp = 1.0 / (1.0 + 3.0 * max(0.0, h - 0.08))
            top = 1.0 - _smooth(0.75, 1.0, h)
            base = _smooth(0.0, 0.03, h)
            heat_h = math.exp(-max(0.0, h - _PLUME_HOT_H) / _PLUME_COOL)
            warp = _PLUME_WARP0 + (_PLUME_WARP - _PLUME_WARP0) * _smooth(0.0, 0.5, h)
            for i in range(nx):
                x = (i + 0.5) / nx
                wx = _smooth(_FACE_MARGIN, _FACE_MARGIN + _PLUME_FADE, min(x, 1.0 - x))
                if wx <= 0.0:
                    continue
                u = (x - ax) / r
                w = (z - az) / r
                if u * u + w * w >= q_out * q_out:
                    continue
                # Turbulent cross-section: warp the local coordinates.
                fu = _fbm(perm, u * _PLUME_WARP_FREQ + o0, s * _PLUME_WARP_FREQ,
                          w * _PLUME_WARP_FREQ + o1, 4)
                fw = _fbm(perm, u * _PLUME_WARP_FREQ + o1 + 53.0,
                          s * _PLUME_WARP_FREQ + 19.0, w * _PLUME_WARP_FREQ + o0, 4)
                fl = math.sqrt(fu * fu + fw * fw)
                ws = 2.5 * warp / max(1.0, 2.5 * fl)
                uu = u + fu * ws
                ww = w + fw * ws
                q2 = uu * uu + ww * ww
                if q2 >= 1.0:
                    continue
                # Flat-topped radial profile: full inside 0.4 radii, 0 at 1.
                prof = 1.0 - _smooth(0.4, 1.0, math.sqrt(q2))
                window = wx * wy * wz * top * base
                # Wisps: fBm erodes the edge and, higher up, the whole plume:
                # the erosion grows with height, and the height at which the
                # wisps give out varies across the plume (a slow fBm), so the
                # top is ragged, not flat.
                n = _fbm(perm, uu * _PLUME_WISP_FREQ + 71.0, s * _PLUME_WISP_FREQ + o0,
                         ww * _PLUME_WISP_FREQ + 29.0, 4)
                hv = h + 0.5 * _fbm(perm, uu * 0.5 + o1, s * 0.5 + 3.0, ww * 0.5 + o0, 2)
                ero = 0.15 + 0.35 * h + 0.6 * _smooth(0.3, 1.1, hv)
                cov = (prof - ero * (1.0 - n)) / _PLUME_SHELL
                if cov > 0.0:
                    cov = min(1.0, cov)
                    dens[k, j, i] = amp * window * cov * cov * (3.0 - 2.0 * cov)
                # Temperature: a hot core near the base, cooling with height;
                # flickering with the wisp noise.
                qh = q2 / (_PLUME_HOT_R * _PLUME_HOT_R)
                if qh < 1.0:
                    core = (1.0 - qh) * (1.0 - qh)
                    flick = min(1.0, max(0.0, 0.85 + 0.5 * n))
                    heat = core * heat_h * flick * window
                    temp[k, j, i] = PLUME_T_AMBIENT + (PLUME_T_CORE - PLUME_T_AMBIENT) * heat


def plume(resolution, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Procedural rising smoke plume: density and temperature on a regular grid.

    Parameters
    ----------
    resolution:
        ``n`` for an n x n x n grid, or ``(nx, ny, nz)``.
    seed:
        Selects the plume; the same seed always gives the same plume.

    Returns
    -------
    (density, temperature)
        Two float32, C-contiguous arrays of shape ``(nz, ny, nx)`` indexed
        ``[z, y, x]`` (x fastest), spanning the unit cube with +y up; voxel
        (i, j, k) samples the point ((i+0.5)/nx, (j+0.5)/ny, (k+0.5)/nz), so
        every resolution describes the same plume.

        density: dimensionless, in [0, 1] (scale by the medium's extinction
        coefficient when rendering).  About 1 in the core just above the
        source (near the floor, around the centre of the x-z square),
        thinning as the column rises and widens (the source's radius is 5 %
        of the box, the top's 26-30 %), its edge broken into wisps that fade
        out before the top.  Exactly 0 wherever the voxel centre
        lies within 5 % of the extent of a face.

        temperature: kelvin, in [PLUME_T_AMBIENT, PLUME_T_CORE] = [300, 1800].
        Exactly the ambient 300 K outside the plume's hot core (all empty
        space, the 5 % band at the faces, and the cooled upper plume);
        hottest (1600-1700 K at the hottest voxel, at most 1800 K) in the
        dense core just above the source, which keeps its heat over the
        first 10 % of the plume's height and then cools with height
        (e-folding over about 13 % of the box height) and towards the
        plume's edge.  The hot voxels are dense ones: the core glows.
    """
    nx, ny, nz = _parse_resolution(resolution)
    rng = np.random.default_rng(seed)
    perm = rng.permutation(256).astype(np.int32)
    perm = np.concatenate([perm, perm])
    cx, cz = 0.5 + rng.uniform(-0.04, 0.04, size=2)
    lean = rng.normal(size=2)
    lean *= rng.uniform(0.03, 0.08) / np.linalg.norm(lean)
    meander = rng.uniform(0.04, 0.07)
    r1 = rng.uniform(0.26, 0.3)
    o0, o1 = rng.uniform(0.0, 128.0, size=2)
    par = np.array([cx, cz, lean[0], lean[1], meander, r1, o0, o1], dtype=np.float64)
    dens = np.empty((nz, ny, nx), dtype=np.float32)
    temp = np.empty((nz, ny, nx), dtype=np.float32)
    _plume_kernel(dens, temp, perm, par)
    return dens, temp
