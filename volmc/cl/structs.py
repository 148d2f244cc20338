"""C declarations for the kernels, generated from volmc/params.py (never written by hand).

``params_header()`` is the text of the virtual header ``params.h`` that kernels include:
the Params and Light structs (float32 reals, the same field order and alignment as
``params_dtype(np.float32)``), the counter indices and the enum constants.
"""

import numpy as np

from .. import params as P
from ..reference import phase as phase_mod

_C_TYPES = {"i4": "int", "u4": "uint", "real": "float"}


def c_struct(name, fields):
    """C typedef for a field list of volmc.params."""
    lines = [f"typedef struct {{"]
    for fname, kind, count, meaning in fields:
        ctype = _C_TYPES[kind]
        decl = f"{ctype} {fname}[{count}];" if count > 1 else f"{ctype} {fname};"
        lines.append(f"    {decl:<24s} /* {meaning} */")
    lines.append(f"}} {name};")
    return "\n".join(lines)


def params_header():
    """Text of the generated ``params.h``."""
    out = ["/* Generated from volmc/params.py by volmc/cl/structs.py: do not edit. */",
           "#ifndef VOLMC_PARAMS_H", "#define VOLMC_PARAMS_H", ""]
    consts = {
        "CAMERA_PERSPECTIVE": P.CAMERA_PERSPECTIVE, "CAMERA_ORTHOGRAPHIC": P.CAMERA_ORTHOGRAPHIC,
        "LIGHT_DIRECTIONAL": P.LIGHT_DIRECTIONAL, "LIGHT_POINT": P.LIGHT_POINT,
        "N_COUNTERS": P.N_COUNTERS,
    }
    consts.update({k: getattr(P, k) for k in dir(P) if k.startswith("C_")})
    consts["PHASE_ISOTROPIC"] = phase_mod.PHASE_ISOTROPIC
    consts["PHASE_HG"] = phase_mod.PHASE_HG
    for k, v in consts.items():
        out.append(f"#define {k} {v}")
    out += ["", c_struct("Params", P.PARAM_FIELDS), "", c_struct("Light", P.LIGHT_FIELDS), "",
            "#endif", ""]
    return "\n".join(out)


def kernel_params_dtype():
    """numpy dtype of the kernels' Params struct."""
    return P.params_dtype(np.float32)


def kernel_light_dtype():
    """numpy dtype of the kernels' Light struct."""
    return P.light_dtype(np.float32)
