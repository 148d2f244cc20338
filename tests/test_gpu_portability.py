"""GPU portability of the kernels, checked without a GPU (issue 14, item 5).

The kernels run on PoCL here but are meant to run unchanged on GPU OpenCL drivers. This
compiles every program the project builds, with the option sets the renderer, the
benchmarks and the tests build it with, by clang's OpenCL C 1.2 front end for two GPU
targets:

- NVIDIA: ``clang-19 -x cl -cl-std=CL1.2 -target nvptx64-nvidia-nvcl``
- AMD: ``clang-19 -x cl -cl-std=CL1.2 -target amdgcn-amd-amdhsa -mcpu=gfx1030 -nogpulib``
  (RDNA 2; without -mcpu clang targets the 2012 SI generation, whose 104 scalar registers
  the W > 1 kernels' uniform values overflow: "scalar registers (106) exceeds limit (104)")

Each compile runs the full code generator to target assembly (``-S``: PTX, GCN), not just
the front end, so back-end diagnostics (stack frames) and the code the driver would see are
covered (for AMD, the builds at W = 16 and the test kernels at W > 1 stop at optimised LLVM
IR: its code generator takes minutes there, see to_assembly); ``-nogpulib`` only leaves the
device library (ocml) unlinked, so OpenCL builtins stay external calls, which a driver
resolves. The sources are those ``volmc.cl.build.assemble``
gives, with the generated params.h and features.h, written to a temporary folder.

What is checked, per program and target:

- no errors and no warnings under ``-Wall`` (``-Wno-unused-function`` aside: the assembled
  unit carries the whole kernel library as static inline functions, and each program calls
  only part of it);
- no double precision: ``-Xclang -cl-ext=-cl_khr_fp64`` turns the extension off, so any use
  of ``double`` is an error and an unsuffixed literal a warning (GPUs need not support fp64);
- private memory: at most PRIVATE_BUDGET = 16 KiB per work item of up to 8 lanes (paths per
  work item, the W of kernels/lanes.h; 32 KiB at W = 16). ``-Wframe-larger-than`` flags any
  function's frame above 16 KiB (the AMDGPU back end diagnoses it; NVPTX does not), and the
  assembly is read: each AMD kernel's ``.amdhsa_private_segment_fixed_size`` (its scratch
  with its callees) and, for NVIDIA, the sum of every ``__local_depot`` of the module (an
  upper bound of any call chain). The kernels need at most 2 KiB at W = 1 (what a GPU
  runs) and about 1.4 KiB per path at W = 16; the budget is far below the hardware limits
  (512 KiB of local memory per thread on NVIDIA) yet stops a per-work-item array of
  thousands of floats, which would spill to slow memory and starve occupancy on any GPU;

and per program once (the call graph is the target's business only after inlining):

- no recursion (OpenCL C forbids it; clang does not diagnose it and may even turn it into a
  loop): the call graph of the unoptimised LLVM IR (``-O0 -emit-llvm -S``, every call
  still a call) must be acyclic;
- no call to a kernel function without a definition: a C99 ``inline`` function without
  ``static`` has no external definition, so where a GPU compiler does not inline it the
  link fails. This found every kernel function declared plain ``inline`` (clang -O2 left
  trace_path, power_series_segment, unbiased_raymarch_segment and sampler_pair as calls to
  undefined symbols); they are all ``static inline`` now.

The -cl-fast-relaxed-math build also found two uses of INFINITY, undefined under finite
math (-Wnan-infinity-disabled); the kernels use NO_LIMIT (FLT_MAX) there now.

The test skips when clang-19 is absent (``.ci/run`` installs it from Debian).
"""

import functools
import itertools
import math
import os
import re
import shutil
import subprocess
from concurrent.futures import ThreadPoolExecutor

import pytest

from volmc.backends.opencl import render_options
from volmc.bench.fastmath import FAST_MATH
from volmc.bench.sparse import LOOKUPS, lookup_options
from volmc.bench.transmittance_runner import estimator_options
from volmc.cl.build import BASE_OPTIONS, assemble
from volmc.resources import kernels_dir
from volmc.scene.features import FEATURES, TOOL_FEATURES
from volmc.scene.schema import Render
from volmc.techniques import ESTIMATORS

CLANG = shutil.which("clang-19")
needs_clang = pytest.mark.skipif(CLANG is None, reason="clang-19 is not installed (Debian: "
                                 "apt-get install clang-19; .ci/run installs it)")

TARGETS = {
    "nvptx": ["-target", "nvptx64-nvidia-nvcl"],
    "amdgcn": ["-target", "amdgcn-amd-amdhsa", "-mcpu=gfx1030", "-nogpulib"],
}
#: Private memory a work item of up to 8 lanes may use (bytes), and the frame of one function.
PRIVATE_BUDGET = 16 * 1024
FRAME_LIMIT = 16 * 1024
FLAGS = (["-x", "cl"] + list(BASE_OPTIONS)
         + ["-Wall", "-Wno-unused-function", "-Xclang", "-cl-ext=-cl_khr_fp64",
            f"-Wframe-larger-than={FRAME_LIMIT}"])
#: The lane widths compiled beside W = 1 (what GPU drivers report, and so what a GPU runs):
#: the largest builds (every render feature with the default and the "auto" estimators, the
#: test kernels, the estimator benchmark's auto build, the lookup ceiling), to show every width
#: is portable code.
WIDE = (4, 8, 16)
#: Compiles in flight (each one is a single-threaded clang process).
WORKERS = max(1, min(4, os.cpu_count() or 1))


def switch_sets(switches):
    """All on, and a binary covering array of strength 2: every pair of switches meets in
    each of its four on/off combinations, in N + 1 builds where all off, all on, each alone
    and each left out take 2 + 2 n.

    The array has N rows, the first all off. Switch j is on in the rows of S_j, a subset of
    rows 1..N-1 of size w = floor((N - 1) / 2) + 1, distinct for each switch: two such sets
    of one size intersect (2 w > N - 1: both on), and neither holds the other (one on, the
    other off, both ways). N is the least with C(N - 1, w) >= n: 6 rows for up to 10
    switches."""
    n = len(switches)
    rows = 2
    while math.comb(rows - 1, (rows - 1) // 2 + 1) < n:
        rows += 1
    w = (rows - 1) // 2 + 1
    subsets = list(itertools.combinations(range(1, rows), w))[:n]
    out = [tuple(x for x, sub in zip(switches, subsets) if r in sub) for r in range(rows)]
    out.append(tuple(switches))
    return list(dict.fromkeys(out))


def programs():
    """[(label, kernels/ file, options)]: every build the code makes, without repeats.

    integrator.cl (renders): the render FEATURES and the tool switches with the default
    estimator, in the sets of switch_sets, which put every pair of switches in each of its
    four on/off combinations (all off, all on, each alone and each left out took 2 + 2 n
    builds: 18 for eight switches, 50 s of compiling for the AMD target, now 7; every
    subset, 2^n, took 600 s on the AMD target once there were seven); every registry
    estimator with all of them on (auto adds VIEW_ESTIMATOR); the -cl-fast-relaxed-math
    build of `volmc bench fastmath` and test case 20. estimators.cl (estimator benchmark):
    every estimator grey and chromatic, and the shadow-ray functions. bench_sparse.cl:
    every lookup kind. testing.cl, testing_power_series.cl and bench.cl build without
    options. All at W = 1, and WIDE's widths for the largest builds. Returns (label, file,
    options, lanes)."""
    switches = sorted(FEATURES) + sorted(TOOL_FEATURES)
    default = Render().transmittance
    out = []
    for subset in switch_sets(switches):
        out.append((f"{'+'.join(subset) or 'no features'}, {default}", "integrator.cl",
                    render_options(subset, default)))
    for name in ESTIMATORS:
        out.append((f"all features, {name}", "integrator.cl", render_options(switches, name)))
    out.append((f"scene features, {default}, {FAST_MATH}", "integrator.cl",
                render_options(FEATURES, default, (FAST_MATH,))))
    for name, est in ESTIMATORS.items():
        for chromatic in (False, True):
            for shadow in ((False, True) if est.shadow_kernel != est.kernel else (False,)):
                out.append((f"{name}{' shadow' if shadow else ''}"
                            f"{' chromatic' if chromatic else ' grey'}", "estimators.cl",
                            estimator_options(name, chromatic, shadow)))
    for kind, lookup in enumerate(LOOKUPS):
        out.append((lookup, "bench_sparse.cl", list(lookup_options(kind))))
    for name in ("testing.cl", "testing_power_series.cl", "bench.cl"):
        out.append(("no options", name, []))
    out = [(label, name, list(opts), 1) for label, name, opts in out]
    for w in WIDE:
        for est in (default, "auto"):
            out.append((f"all features, {est}", "integrator.cl", render_options(switches, est),
                        w))
        out.append(("auto shadow chromatic", "estimators.cl",
                    estimator_options("auto", True, True), w))
        for name in ("testing.cl", "bench.cl"):
            out.append(("no options", name, [], w))
    seen, unique = set(), []
    for label, name, opts, w in out:
        opts = list(opts) + [f"-DLANES={w}"]
        if (name, tuple(opts)) not in seen:
            seen.add((name, tuple(opts)))
            unique.append((f"{name} [{label}, W = {w}]", name, opts, w))
    return unique


PROGRAMS = programs()


@pytest.fixture(scope="module")
def sources(tmp_path_factory):
    """{kernels/ file: path of its assembled source}."""
    folder = tmp_path_factory.mktemp("gpu_kernels")
    out = {}
    for name in sorted({name for _, name, _, _ in PROGRAMS}):
        out[name] = folder / name
        out[name].write_text(assemble(name))
    return out


def clang(args, source):
    """(return code, diagnostics, output text) of clang-19 on ``source``."""
    out = source.parent / f"{source.stem}.{abs(hash(tuple(args)))}.out"
    p = subprocess.run([CLANG] + FLAGS + list(args) + ["-o", str(out), str(source)],
                       capture_output=True, text=True)
    text = out.read_text() if out.exists() else ""
    out.unlink(missing_ok=True)
    return p.returncode, p.stderr.strip(), text


def private_bytes(target, asm):
    """Private memory per work item the assembly of a module reserves (see the docstring)."""
    if target == "amdgcn":
        sizes = re.findall(r"\.amdhsa_private_segment_fixed_size\s+(\d+)", asm)
        assert sizes, "no AMD kernel descriptor in the assembly"
        return max(int(s) for s in sizes)
    return sum(int(s) for s in re.findall(r"__local_depot\d+\[(\d+)\]", asm))


def call_graph(ir):
    """({defined function: {called functions}}, {declared-only functions}) of LLVM IR text."""
    graph, current = {}, None
    for line in ir.splitlines():
        m = re.match(r"define\b.*?@([\w.$]+)\(", line)
        if m:
            current = graph.setdefault(m.group(1), set())
        elif line.startswith("}"):
            current = None
        elif current is not None:
            current.update(re.findall(r"\bcall\b.*?@([\w.$]+)\(", line))
    declared = set(re.findall(r"^declare\b.*?@([\w.$]+)\(", ir, re.M))
    return graph, declared


def find_cycle(graph):
    """A call cycle [f, g, ..., f] among defined functions, or None."""
    state = {}

    def visit(f, path):
        state[f] = 1
        for g in sorted(graph.get(f, ())):
            if g not in graph:
                continue
            if state.get(g) == 1:
                return path[path.index(g):] + [g]
            if g not in state:
                found = visit(g, path + [g])
                if found:
                    return found
        state[f] = 2
        return None

    for f in sorted(graph):
        if f not in state:
            found = visit(f, [f])
            if found:
                return found
    return None


def undefined_kernel_functions(declared):
    """Declared functions that are no OpenCL builtin (mangled _Z...) or LLVM intrinsic."""
    return sorted(f for f in declared if not f.startswith(("_Z", "llvm.")))


def test_every_kernel_program_is_covered():
    """Each kernels/*.cl is a program the project builds; a new one must join PROGRAMS."""
    built = {name for _, name, _, _ in PROGRAMS}
    assert built == {p.name for p in kernels_dir().glob("*.cl")}
    switches = sorted(FEATURES) + sorted(TOOL_FEATURES)
    sets = [set(s) for s in switch_sets(switches)]
    assert len([p for p in PROGRAMS if p[1] == "integrator.cl" and p[3] == 1]) == (
        len(sets) + len(ESTIMATORS) - 1 + 1)
    assert len(sets) <= 8   # up to 10 switches: six rows, and all on
    for a, b in itertools.combinations(switches, 2):
        assert {(a in s, b in s) for s in sets} == {(False, False), (False, True),
                                                    (True, False), (True, True)}, (a, b)
    assert {p[3] for p in PROGRAMS if p[1] == "integrator.cl"} == {1, *WIDE}
    # Every program reaches assembly for NVIDIA, and at W = 1 (what a GPU runs) for both.
    assert all(to_assembly("nvptx", p) for p in PROGRAMS)
    assert all(to_assembly("amdgcn", p) for p in PROGRAMS if p[3] == 1)


#: AMD's widest lane width, compiled to optimised LLVM IR for the target and not to assembly.
AMD_IR_ONLY_LANES = 16
#: clang's arguments for optimised LLVM IR instead of assembly (to_assembly).
TO_IR = ["-O2", "-emit-llvm", "-S"]


def to_assembly(target, program):
    """Whether ``program`` goes through ``target``'s code generator to assembly; if not, it is
    compiled to optimised LLVM IR for the target (``-O2 -emit-llvm``): the front end's and the
    optimiser's diagnostics, doubles among them, without the back end's (stack frames) and
    without the private-memory count.

    Everything goes to assembly but, for AMD, the builds at W = 16 and the test kernels
    (testing.cl) at W > 1. AMD's code generator (LLVM 19) grows faster than the code: on a
    2-core Zen 3 the render kernel took 18 s at W = 4, 95 s at W = 8 and 400 s at W = 16,
    78 % of them in its "SI Fix SGPR copies" pass, against 3 s to IR at W = 16; the
    estimator benchmark took 28 s at W = 16. GPUs run W = 1 (what their drivers report), and
    NVIDIA's code generator still compiles every program at every W. The test kernels hold
    entry points around the library the render kernel compiles (they took 200 s for AMD at
    W > 1). ``VOLMC_GPU_FULL=1`` sends every program to assembly (about 15 minutes more on
    2 cores), for a check by hand when the kernels change."""
    _, name, _, lanes = program
    if target != "amdgcn" or os.environ.get("VOLMC_GPU_FULL") == "1":
        return True
    return lanes < AMD_IR_ONLY_LANES and not (name == "testing.cl" and lanes > 1)


def compile_problems(target, program, sources):
    """The problems of one program compiled to target assembly (or IR: to_assembly): errors,
    warnings (doubles among them), more than PRIVATE_BUDGET bytes of private memory per work
    item."""
    label, name, opts, lanes = program
    if not to_assembly(target, program):
        rc, diag, _ = clang(TARGETS[target] + opts + TO_IR, sources[name])
        return [f"{label}: clang exit {rc} (to IR)\n{diag[:4000]}"] if rc != 0 or diag else []
    rc, diag, asm = clang(TARGETS[target] + opts + ["-S"], sources[name])
    if rc != 0 or diag:
        return [f"{label}: clang exit {rc}\n{diag[:4000]}"]
    if private_bytes(target, asm) > PRIVATE_BUDGET * max(1, lanes // 8):
        return [f"{label}: {private_bytes(target, asm)} bytes of private memory per work "
                f"item (budget {PRIVATE_BUDGET} per 8 lanes)"]
    return []


def call_graph_problems(program, sources):
    """The problems of one program's unoptimised call graph: recursion, and functions called
    without a definition."""
    label, name, opts, _ = program
    rc, diag, ir = clang(TARGETS["nvptx"] + opts + ["-O0", "-emit-llvm", "-S"], sources[name])
    if rc != 0:
        return [f"{label}: clang exit {rc}\n{diag[:4000]}"]
    graph, declared = call_graph(ir)
    problems = []
    if not graph:
        problems.append(f"{label}: no function in the IR")
    cycle = find_cycle(graph)
    if cycle:
        problems.append(f"{label}: recursion {' -> '.join(cycle)}")
    missing = undefined_kernel_functions(declared)
    if missing:
        problems.append(f"{label}: called without a definition (an inline function "
                        f"without static?): {', '.join(missing)}")
    return problems


def run_checks(check, sources):
    """Every problem check(program, sources) finds over PROGRAMS, in WORKERS threads, the
    widest builds first (then the largest sources), so that the last to finish are short."""
    size = {name: path.stat().st_size for name, path in sources.items()}
    order = sorted(PROGRAMS, key=lambda p: (-p[3], -size[p[1]], p[0]))
    with ThreadPoolExecutor(WORKERS) as pool:
        return [x for found in pool.map(lambda p: check(p, sources), order) for x in found]


@needs_clang
@pytest.mark.parametrize("target", sorted(TARGETS))
def test_kernels_compile_cleanly_for_gpu(target, sources):
    """Every program compiles to target assembly without errors, warnings, doubles or more
    than PRIVATE_BUDGET bytes of private memory per work item."""
    problems = run_checks(functools.partial(compile_problems, target), sources)
    assert not problems, f"{len(problems)} of {len(PROGRAMS)} builds fail on {target}:\n" + \
        "\n\n".join(problems)


@needs_clang
def test_no_recursion_and_no_undefined_functions(sources):
    """The unoptimised call graph of every program is acyclic, and every function a kernel
    calls is defined (or an OpenCL builtin)."""
    problems = run_checks(call_graph_problems, sources)
    assert not problems, "\n".join(problems)


@needs_clang
def test_the_checks_catch_what_they_claim(tmp_path):
    """Each check fails on a small kernel with the problem: double, recursion, a frame over
    the budget (AMD), an inline function without static."""
    def compile_snippet(name, text, args):
        path = tmp_path / f"{name}.cl"
        path.write_text(text)
        return clang(args, path)

    rc, diag, _ = compile_snippet("fp64", "kernel void k(global float *o) {\n"
                                  "    double x = o[0]; o[0] = (float)(x * 2.0); }\n",
                                  TARGETS["nvptx"] + ["-S"])
    assert rc != 0 and "cl_khr_fp64" in diag
    rc, diag, _ = compile_snippet("literal", "kernel void k(global float *o) {\n"
                                  "    o[0] = o[0] * 2.5; }\n", TARGETS["amdgcn"] + ["-S"])
    assert rc == 0 and "double precision constant" in diag
    rc, diag, _ = compile_snippet("literal", "kernel void k(global float *o) {\n"
                                  "    o[0] = o[0] * 2.5; }\n",
                                  TARGETS["amdgcn"] + TO_IR)
    assert rc == 0 and "double precision constant" in diag   # the IR-only builds too
    n = FRAME_LIMIT // 4 + 16
    big = (f"kernel void k(global float *o, int i) {{\n    float a[{n}];\n"
           f"    for (int j = 0; j < {n}; j++) a[j] = o[j];\n    o[0] = a[i]; }}\n")
    rc, diag, asm = compile_snippet("big", big, TARGETS["amdgcn"] + ["-S"])
    assert "-Wframe-larger-than" in diag and private_bytes("amdgcn", asm) > PRIVATE_BUDGET
    rc, diag, asm = compile_snippet("big", big, TARGETS["nvptx"] + ["-S"])
    assert private_bytes("nvptx", asm) > PRIVATE_BUDGET
    rc, diag, ir = compile_snippet("rec", "static int f(int n) { return n ? f(n - 1) + 1 : 0; }\n"
                                   "kernel void k(global int *o) { o[0] = f(o[0]); }\n",
                                   TARGETS["nvptx"] + ["-O0", "-emit-llvm", "-S"])
    assert rc == 0 and find_cycle(call_graph(ir)[0]) == ["f", "f"]
    rc, diag, ir = compile_snippet("c99inline", "inline int g(int n) { return n + 1; }\n"
                                   "kernel void k(global int *o) { o[0] = g(o[0]); }\n",
                                   TARGETS["nvptx"] + ["-O0", "-emit-llvm", "-S"])
    assert rc == 0 and undefined_kernel_functions(call_graph(ir)[1]) == ["g"]
