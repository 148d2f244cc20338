"""Specialised builds: the compiler options that tailor kernels/integrator.cl to one scene.

Feature switches (``-DFEATURE_X=0/1``, volmc/scene/features.py) compile code paths in or
out; bakes (``-DBAKE_X(v)=constant``) replace a record field the kernels read at run time by
the scene's value, so the compiler can fold it. Which of these stay is decided by
``volmc bench specialise``: a specialisation is kept only while it measurably pays.
"""

import numpy as np

from ..scene.features import BAKES

#: The bakes production builds use (measured by `volmc bench specialise`; see the README).
DEFAULT_BAKES = frozenset()


def _f(x):
    """A float32 value as an exact C hexadecimal float literal."""
    return f"{float(np.float32(x)).hex()}f"


def bake_values(packed):
    """{bake name: C expression} of a packed float32 scene (only the bakes that apply)."""
    p, m = packed.params[0], packed.medium[0]
    out = {"N_LIGHTS": str(int(p["n_lights"])),
           "PHASE_KIND": str(int(m["phase_kind"])),
           "PHASE_G": _f(m["g"]),
           "ALBEDO": "((float3)(" + ",".join(_f(a) for a in m["albedo"]) + "))"}
    nx, ny, nz = (int(v) for v in m["dims"])
    out["GRID_DIMS"] = f"((int3)({nx},{ny},{nz}))"
    cz, cy, cx = (int(v) for v in m["maj_res"])
    out["MAJ_RES"] = f"((int3)({cz},{cy},{cx}))"
    assert set(out) == set(BAKES)
    return out


def bake_options(packed, names):
    """``-DBAKE_X(v)=value`` options for the bakes in ``names`` (no spaces: the driver
    splits its option string at them)."""
    values = bake_values(packed)
    return [f"-DBAKE_{n}(v)={values[n]}" for n in sorted(names)]
