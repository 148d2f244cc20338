"""One source of truth for the constants the kernels share with Python (volmc/constants.py).

The kernels' header is generated from that module; these tests fail if a kernel sees a
different value than the reference, if a kernel source defines a shared name by hand, or if
a Python module other than volmc/constants.py assigns one."""

import ast
import re

import numpy as np
import pytest

from volmc import constants, params
from volmc.resources import kernels_dir

SHARED = dict(constants.kernel_constants())
SHARED.update({k: getattr(params, k) for k in dir(params) if k.startswith("C_")})
SHARED["N_COUNTERS"] = params.N_COUNTERS
INTS = [k for k, v in SHARED.items() if isinstance(v, int)]
FLOATS = [k for k, v in SHARED.items() if isinstance(v, float)]


def test_kernels_see_the_reference_values():
    """A generated kernel writes every shared constant into a buffer: integers must equal
    the Python values bit for bit, reals the Python value rounded to float32."""
    from cl_harness import build_source, out_buf, run_kernel
    body = "\n".join([f"    ints[{i}] = (uint)({k});" for i, k in enumerate(INTS)] +
                     [f"    reals[{i}] = (float)({k});" for i, k in enumerate(FLOATS)])
    src = ('#include "params.h"\n'
           "kernel void t_constants(global uint *ints, global float *reals, int n) {\n"
           f"{body}\n}}\n")
    prg = build_source("t_constants.cl", src)
    ints, ib = out_buf(len(INTS), np.uint32)
    reals, rb = out_buf(len(FLOATS), np.float32)
    run_kernel(prg, "t_constants", 1, ib, rb, outs=[(ints, ib), (reals, rb)])
    for i, k in enumerate(INTS):
        assert int(ints[i]) == int(SHARED[k]) % 2**32, k
    for i, k in enumerate(FLOATS):
        assert reals[i] == np.float32(SHARED[k]), (k, reals[i], SHARED[k])


def test_no_kernel_source_defines_a_shared_constant():
    pattern = re.compile(r"^\s*#\s*define\s+(\w+)", re.M)
    for path in sorted(kernels_dir().glob("*.[hc]*")):
        for name in pattern.findall(path.read_text()):
            assert name not in SHARED, f"{path.name} defines {name} by hand"


@pytest.mark.parametrize("module", ["reference", "cl", "bench", "scene", "."])
def test_no_python_module_redefines_a_shared_constant(module):
    """Python modules import the shared constants; only volmc/constants.py (and the counters
    in volmc/params.py) assign them."""
    import volmc
    from pathlib import Path
    root = Path(volmc.__file__).parent / module
    files = sorted(root.glob("*.py"))
    assert files
    for path in files:
        if path.name in ("constants.py", "params.py"):
            continue
        for node in ast.parse(path.read_text()).body:
            targets = node.targets if isinstance(node, ast.Assign) else \
                [node.target] if isinstance(node, ast.AnnAssign) else []
            for t in targets:
                if isinstance(t, ast.Name):
                    assert t.id not in SHARED, f"{path} assigns {t.id}"
