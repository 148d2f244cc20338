"""C declarations for the kernels, generated from volmc/params.py and volmc/constants.py
(never written by hand).

``params_header()`` is the text of the virtual header ``params.h`` that kernels include:
the Params, Medium and Light structs (float32 reals, the same field order and alignment as
``params_dtype(np.float32)``), the counter indices and every constant of volmc/constants.py.
"""

import numpy as np

from .. import params as P
from ..constants import U32, kernel_constants

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


def c_literal(value):
    """A constant of volmc/constants.py as C source: U32 in hex with a u suffix, int in decimal,
    float with every digit Python keeps and an f suffix (the compiler rounds it to float32
    exactly as numpy.float32 does)."""
    if isinstance(value, U32):
        return f"0x{int(value):X}u"
    if isinstance(value, int):
        return str(value)
    return f"{float(value)!r}f"


def params_header():
    """Text of the generated ``params.h``: every constant of volmc/constants.py, the counter
    indices, and the Params, Medium, Light and Launch structs."""
    out = ["/* Generated from volmc/constants.py and volmc/params.py by volmc/cl/structs.py: "
           "do not edit. */", "#ifndef VOLMC_PARAMS_H", "#define VOLMC_PARAMS_H", ""]
    consts = dict(kernel_constants())
    consts["N_COUNTERS"] = P.N_COUNTERS
    consts.update({k: getattr(P, k) for k in dir(P) if k.startswith("C_")})
    for k, v in consts.items():
        out.append(f"#define {k} {c_literal(v)}")
    out += ["", c_struct("Params", P.PARAM_FIELDS), "", c_struct("Medium", P.MEDIUM_FIELDS), "",
            c_struct("Light", P.LIGHT_FIELDS), "", c_struct("Launch", P.LAUNCH_FIELDS), "",
            "#endif", ""]
    return "\n".join(out)


def kernel_params_dtype():
    """numpy dtype of the kernels' Params struct."""
    return P.params_dtype(np.float32)


def kernel_light_dtype():
    """numpy dtype of the kernels' Light struct."""
    return P.light_dtype(np.float32)
