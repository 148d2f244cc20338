"""The twin rule: every kernel function has a Numba twin of the same name, and the estimator
registry names functions that exist on both sides and dispatch to themselves."""

import math
import re

import numpy as np
import pytest

from volmc.resources import kernels_dir
from volmc.techniques import ESTIMATORS

#: Kernel headers with no Numba counterpart at all: the lane types and helpers (lanes.h: the
#: reference is one lane, so it needs no lane plumbing) and the per-lane loads and stores
#: of the test and benchmark kernels (lane_io.h).
LANE_HEADERS = {"lanes.h", "lane_io.h"}

#: Kernel helpers with no Numba counterpart, and why: float3 from a 3-array (Numba uses
#: tuples throughout), a flat cell index (Numba indexes the 3-D array), and the lerp the
#: reference writes inline in grid_lookup.
C_ONLY = {"vec3", "vec3g", "dda_cell_index", "lerp_ab",
          # grid.h: the cell grid_lookup and sparse_lookup share, per axis (the reference's
          # grid.py writes it in _axis).
          "voxel_cell", "voxel_axis",
          # kernels/spectrum.h: the kernels' per-channel type is float or float3 by build;
          # the reference always carries RGB tuples (vec.py), so it needs no conversions.
          "spec_first", "spec_max", "spec_rgb", "spec_s", "spec_u", "spec_add", "spec_sub",
          "spec_mul", "spec_div", "spec_scale", "spec_sel", "spec_abs", "spec_exp_neg",
          "spec_mul_one_minus", "rgb_times",
          # tracking.h: a walk as a record the lanes' one loop advances an event at a time;
          # track, the reference's twin, is walk_begin then walk_step until the walk ends.
          "walk_begin", "walk_step",
          # The lanes' scheduling in integrator.cl: trace_path (the reference's) cut at its
          # walks, so a lane whose walk ends goes on to its next one, or to a new path,
          # while the others walk; rng_swap lends a shadow ray's stream to the walk loop.
          "path_start", "flight_begin", "flight_end", "nee_next", "shadow_add", "shadow_end",
          "path_bounce", "path_write", "weighted_beta", "rng_swap",
          # Emission sampling: the reference's sample_emitters loops over a vertex's samples
          # and estimates each ray's transmittance in place; nee_next takes one ray per pass
          # (emitter_ray: the loop's body before the transmittance). emis_plain is the
          # reference's EMIS_PLAIN tuple.
          "emitter_ray", "emis_plain"}


#: Twins whose arguments differ, and why: C passes a grid's shape beside its pointer; Numba
#: passes the three channels that C packs in a vector; C reads an environment map's shape
#: from the parameters and finds a row's CDF by its start and length in one flat buffer,
#: where Numba indexes the map's 2-D arrays.
ARGUMENTS_DIFFER = {"grid_lookup", "sample_ok", "env_texel", "cdf_find"}


def _kernel_signatures():
    """{name: [parameter names]} of every (static) inline function of kernels/*.h and
    integrator.cl."""
    out = {}
    for path in sorted(kernels_dir().glob("*.h")) + [kernels_dir() / "integrator.cl"]:
        if path.name in LANE_HEADERS:
            continue
        text = path.read_text()
        for m in re.finditer(r"^(?:static\s+)?inline\s+(?:__attribute__\(\(\w+\)\)\s+)?"
                             r"[\w\s\*]+?\b(\w+)\s*\(([^)]*)\)", text, re.M):
            args = m.group(2).replace(
                "TRANSMITTANCE_ARGS", "const MediumData *med, float3 o, float3 d, float t0, "
                "float t1, Rng *rng, ulong *counters, int max_steps")
            out[m.group(1)] = [re.findall(r"(\w+)\s*(?:\[\w*\])?\s*$", a.strip())[0]
                               for a in args.split(",") if a.strip() not in ("", "void")]
    return out


def _kernel_functions():
    return set(_kernel_signatures())


def _reference_functions():
    from pathlib import Path

    import volmc.reference
    names = set()
    for path in Path(volmc.reference.__file__).parent.glob("*.py"):
        names |= set(re.findall(r"^def (\w+)\(", path.read_text(), re.M))
    return names


def test_every_kernel_function_has_a_numba_twin():
    missing = _kernel_functions() - _reference_functions() - C_ONLY
    assert not missing, f"kernel functions without a Numba twin: {sorted(missing)}"
    assert C_ONLY <= _kernel_functions()


def test_twins_take_the_same_arguments():
    """A Numba twin's parameters are the kernel function's, in order; the kernel may add
    trailing out-parameters (the pdf, a second result) where Numba returns a tuple."""
    import ast
    from pathlib import Path

    import volmc.reference
    ref = {}
    for path in Path(volmc.reference.__file__).parent.glob("*.py"):
        for node in ast.parse(path.read_text()).body:
            if isinstance(node, ast.FunctionDef):
                ref[node.name] = [a.arg for a in node.args.args]
    bad = {name: (c, ref[name]) for name, c in _kernel_signatures().items()
           if name in ref and name not in ARGUMENTS_DIFFER and c[:len(ref[name])] != ref[name]}
    assert not bad, bad


@pytest.mark.parametrize("name", list(ESTIMATORS))
def test_registry_functions_exist_on_both_sides(name):
    est = ESTIMATORS[name]
    assert callable(est.reference) and est.reference.__name__ == est.function
    assert est.kernel in _kernel_functions(), est.kernel


@pytest.mark.parametrize("name", list(ESTIMATORS))
def test_dispatch_runs_the_registered_function(name):
    """reference.estimators.transmittance(id, ...) gives what the registered function gives,
    estimate for estimate, on the same random streams."""
    from volmc.reference.estimators import transmittance
    from volmc.reference.medium import medium_data, make_grid_medium
    from volmc.reference.rng import STREAM_TEST, rng_new
    est = ESTIMATORS[name]
    grid = 0.2 + np.random.default_rng(3).random((4, 5, 6))
    m = make_grid_medium((-1.0, -1.0, -1.0), (1.0, 1.0, 1.0), 2.0, (6, 5, 4))
    m["sigma_maj"] = 2.0 * grid.max()
    m["sigma_min"] = 2.0 * grid.max() if est.homogeneous_only else 2.0 * grid.min()
    med = medium_data(np.atleast_1d(m)[0], grid, grid, grid)
    o, d = (-1.0, 0.1, 0.2), (1.0 / math.sqrt(2.0), 1.0 / math.sqrt(2.0), 0.0)
    for i in range(200):
        c1 = np.zeros(6, np.int64)
        c2 = np.zeros(6, np.int64)
        a = transmittance(est.id, med, o, d, 0.0, 1.2, rng_new(5, 0, i, STREAM_TEST), c1, 10**6)
        b = est.reference(med, o, d, 0.0, 1.2, rng_new(5, 0, i, STREAM_TEST), c2, 10**6)
        b = b if isinstance(b, tuple) else (b, b, b)   # per-segment estimators are grey
        assert a == b and np.array_equal(c1, c2), (name, i)
