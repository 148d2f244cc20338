"""Emission sampling (render.emission_sampling): points drawn in the emitting media, and
their density. Twin of ``kernels/emitters.h``; the distribution is built by volmc/emitters.py,
whose docstring gives the layout.

``sample_emitter`` draws a point from five uniforms: u0 picks the medium (by its
``emitter_prob``, in medium order) and, rescaled to [0, 1) within that medium's share, the
alias table's cell; u1 the alias decision; (u2, u3, u4) the point inside the cell (uniform in
the medium's space, so uniform in the scene frame too: the map is affine). ``emitter_pdf``
is the density per unit volume of the scene frame at a point: the sum over the media whose
distribution holds it, each its ``emitter_density`` times the probability of its cell there,
so that where media overlap a point sampled in one is weighed by all (one-sample MIS over the
media with the balance heuristic; always unbiased). Both backends evaluate the density with
``emitter_pdf`` at the point itself, the sampled point and a collision alike.
"""

import math

from numba import njit

from .medium import in_box, to_medium


@njit(cache=True)
def emitter_cell(m, q):
    """Cell index of point q (medium space) in medium m's distribution, clamped into it."""
    cx, cy, cz = m.emitter_res[0], m.emitter_res[1], m.emitter_res[2]
    ix = min(max(int(math.floor((q[0] - m.bmin[0]) * m.inv_extent[0] * cx)), 0), cx - 1)
    iy = min(max(int(math.floor((q[1] - m.bmin[1]) * m.inv_extent[1] * cy)), 0), cy - 1)
    iz = min(max(int(math.floor((q[2] - m.bmin[2]) * m.inv_extent[2] * cz)), 0), cz - 1)
    return ix + cx * (iy + cy * iz)


@njit(cache=True)
def emitter_pdf(med, p):
    """Density (per unit volume of the scene frame) of ``sample_emitter`` at p."""
    pdf = 0.0
    for i in range(len(med)):
        md = med[i]
        m = md.m
        if not m.emitter_res[0] > 0:
            continue
        q = to_medium(m, p)
        if not in_box(m, q):
            continue
        pdf += m.emitter_density * md.table[m.emitter_row + emitter_cell(m, q), 2]
    return pdf


@njit(cache=True)
def sample_emitter(med, u0, u1, u2, u3, u4):
    """(p, pdf): a point of the scene frame drawn from the emitting media (module docstring),
    and ``emitter_pdf`` there; pdf 0 when no medium has a distribution."""
    acc = 0.0
    j = -1
    lo = 0.0
    share = 0.0
    for i in range(len(med)):
        P = med[i].m.emitter_prob
        if not P > 0.0:
            continue
        if j < 0 or u0 >= acc:   # the last medium whose range starts at or below u0
            j = i
            lo = acc
            share = P
        acc += P
    if j < 0:
        return (0.0, 0.0, 0.0), 0.0
    p = (0.0, 0.0, 0.0)
    for i in range(len(med)):   # (an index Numba can type: see medium.ZERO)
        if i != j:
            continue
        md = med[i]
        m = md.m
        cx, cy, cz = m.emitter_res[0], m.emitter_res[1], m.emitter_res[2]
        n = cx * cy * cz
        v = min(max((u0 - lo) / share, 0.0), 1.0)
        c = min(int(v * n), n - 1)
        if not u1 < md.table[m.emitter_row + c, 0]:
            c = int(md.table[m.emitter_row + c, 1])
        ix = c % cx
        iy = (c // cx) % cy
        iz = c // (cx * cy)
        q = (m.bmin[0] + (ix + u2) / (cx * m.inv_extent[0]),
             m.bmin[1] + (iy + u3) / (cy * m.inv_extent[1]),
             m.bmin[2] + (iz + u4) / (cz * m.inv_extent[2]))
        x = m.emitter_to_scene
        p = (x[0] * q[0] + x[1] * q[1] + x[2] * q[2] + x[3],
             x[4] * q[0] + x[5] * q[1] + x[6] * q[2] + x[7],
             x[8] * q[0] + x[9] * q[1] + x[10] * q[2] + x[11])
    return p, emitter_pdf(med, p)
