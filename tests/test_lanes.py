"""Lane-generic kernels (kernels/lanes.h, issue 21): every lane traces exactly the path the
scalar kernel (W = 1) traces for its sample, with the same random numbers.

Where vector and scalar arithmetic can differ, and what is tested here:

* The vector maths library. PoCL evaluates exp, log, log1p, expm1 and atan2 on a vector with
  other code than on a scalar; the results differ by at most 1 ulp (about 1 % of exp's
  arguments, 0.5 % of atan2's, a few in a million of the logarithms' on this machine), and
  the other functions the kernels call (sqrt, rsqrt, sin, cos, sincos, tan, cbrt, pown,
  division) agree bit for bit; sincos equals sin and cos at every width.
  ``test_vector_maths_differs_by_at_most_one_ulp``.
* Contraction into FMA: the source is the same at every width, so the compiler contracts the
  same expressions; a*b + c agrees bit for bit (same test).
* Everything else -- comparisons, selects, integer hashing (Philox, the samplers), the order
  of operations -- is the same code per lane. So the decisions of a path (how far it flies,
  whether it scatters, every counter) are the same at every width, and a sample's value
  differs only by the maths library's ulps, compounded along the path:
  ``test_every_width_traces_the_same_paths``.
"""

import math
import os
import subprocess
import sys

import numpy as np
import pytest

from volmc.backends.opencl import OpenCLBackend
from volmc.cl.lanes import LANE_WIDTHS, check_lanes, device_lanes
from volmc.film import Film
from volmc.params import C_LANE_ACTIVE, C_LANE_ROUNDS, LANE_COUNTERS, COUNTER_NAMES
from volmc.resources import scenes_dir
from volmc.scene import SceneError, load_scene

SCENES = scenes_dir()

#: Functions whose vector and scalar versions may differ, and by how many ulps at most.
MATHS = {"exp(x)": 1, "exp(-x * x)": 1, "log(fabs(x) + 1e-3f)": 1, "log1p(x)": 1,
         "expm1(x)": 1, "atan2(x, y)": 1,
         # ... and those that agree bit for bit (correctly rounded, or one code path).
         "sqrt(fabs(x))": 0, "rsqrt(fabs(x) + 1e-3f)": 0, "cos(x * 7.0f)": 0,
         "sin(x * 7.0f)": 0, "tan(x)": 0, "cbrt(x)": 0, "pown(x, 5)": 0, "x / y": 0,
         "1.0f / y": 0, "x * y + y": 0,
         # sincos (kernels/sampling.h) writes cos to cx, read after the call
         "sincos(x * 7.0f, &cx)": 0, "cx": 0}


def _ulps(a, b):
    """|a - b| in float32 units in the last place (on the monotonic integer line)."""
    ai, bi = (v.view(np.int32).astype(np.int64) for v in (a, b))
    ai = np.where(ai < 0, -2**31 - ai, ai)
    bi = np.where(bi < 0, -2**31 - bi, bi)
    return np.abs(ai - bi)


def test_vector_maths_differs_by_at_most_one_ulp():
    """The maths builtins the kernels call, at W = 4, 8 and 16 against W = 1 on the same
    200,000 arguments: within MATHS's ulps, and each function that may differ is exercised
    (the bound would pass vacuously on a library that agrees everywhere, so that is allowed;
    a second ulp is not)."""
    import cl_harness
    from cl_harness import build_source, out_buf, run_kernel, to_dev
    body = "\n".join(f"    store_float(out, i, {len(MATHS)}, {k}, {expr}, on);"
                     for k, expr in enumerate(MATHS))
    src = ('#include "lanes.h"\n#include "lane_io.h"\n'
           "kernel void t_maths(global const float *a, global const float *b, "
           "global float *out, int n) {\n    lmask on;\n    lint i = lane_element(n, &on);\n"
           "    lfloat x = load_float(a, i, 1, 0), y = load_float(b, i, 1, 0), cx;\n"
           f"{body}\n}}\n")
    rng = np.random.default_rng(1)
    n = 200_000
    a = np.concatenate([rng.uniform(-10, 10, n // 2), rng.uniform(-0.99, 3, n // 2)])
    a, b = a.astype(np.float32), rng.uniform(0.1, 5, n).astype(np.float32)
    outs = {}
    old = cl_harness.LANES
    try:
        for w in LANE_WIDTHS:
            cl_harness.LANES = w
            out, ob = out_buf((n, len(MATHS)))
            run_kernel(build_source("t_maths.cl", src), "t_maths", n, to_dev(a), to_dev(b), ob,
                       outs=[(out, ob)])
            outs[w] = out.copy()
    finally:
        cl_harness.LANES = old
    for k, (expr, bound) in enumerate(MATHS.items()):
        for w in LANE_WIDTHS[1:]:
            x, y = outs[1][:, k], outs[w][:, k]
            both = np.isfinite(x) & np.isfinite(y)
            assert np.array_equal(np.isfinite(x), np.isfinite(y)), expr
            assert _ulps(x[both], y[both]).max() <= bound, (expr, w)
    # The kernels call sincos for sin and cos of one angle: the same values at every W.
    names = list(MATHS)
    for w in LANE_WIDTHS:
        for single, pair in (("sin(x * 7.0f)", "sincos(x * 7.0f, &cx)"), ("cos(x * 7.0f)", "cx")):
            assert np.array_equal(outs[w][:, names.index(single)],
                                  outs[w][:, names.index(pair)]), (pair, w)


#: A spot's soft edge amplifies a 1-ulp move of the point it lights: the smoothstep s(x),
#: x = (cos - cos_outer) / (cos_inner - cos_outer), changes by up to 1.5 dcos / (cos_inner -
#: cos_outer), 1e-4 of the spot's full intensity per ulp of cos for the gallery's spot (16
#: degrees, blend 0.35: a band 0.0135 wide in cos), which relative to a sample that the edge
#: lights dimly is many ulps. Equiangular sampling's atan2, 1 ulp apart between the widths'
#: maths libraries for 0.5 % of arguments, moves the point: measured at most 7.9e-6
#: relative with the scene's seed, 1.3e-5 over six seeds. A wrong lane's value would be O(1)
#: off, and every decision (counter) is still compared exactly.
SPOT_EDGE = 5e-5

#: Scenes and overrides that between them take every feature of the kernels: grid and octree
#: majorants, decomposition tracking, the samplers, several light samples, every shadow
#: estimator family, the three spectral modes, emission (and its sampling), equiangular sampling, bricks, the
#: thin lens and the panoramic camera, sun discs, spot and sphere lights.
CONFIGS = [
    ("cloud", None, {}),
    ("octree, ratio", None, {"render.majorant": "octree", "render.transmittance": "ratio"}),
    ("sobol, decomposition, 2 light samples", None,
     {"render.sampler": "sobol", "render.free_flight": "decomposition",
      "render.light_samples": 2}),
    ("stratified, global, next flight", None,
     {"render.sampler": "stratified", "render.majorant": "global",
      "render.transmittance": "next_flight"}),
    ("power series", None, {"render.transmittance": "power_series"}),
    ("telescoping", None, {"render.transmittance": "telescoping"}),
    ("hero", "gallery/sunset.toml", {}),
    ("spectral tracking", "gallery/sunset.toml", {"render.spectral": "tracking"}),
    ("one channel", "gallery/sunset.toml", {"render.spectral": "channel"}),
    ("emission, auto", "gallery/plume.toml", {}),
    ("emission sampling, mis", "gallery/plume.toml", {"render.emission_sampling": "mis"}),
    ("emission sampling alone, three media", "tests/media.toml",
     {"render.emission_sampling": "light"}),
    ("emission sampling alone, glow", "tests/glow.toml", {}),
    ("emission sampling, mis, glow", "tests/glow.toml", {"render.emission_sampling": "mis"}),
    ("equiangular", "gallery/fog.toml", {}),
    ("bricks", "gallery/scan.toml", {}),
    ("absorber (transmittance only)", "tests/absorber.toml", {}),
    ("thin lens, sobol", None, {"camera.aperture": 0.3, "render.sampler": "sobol"}),
    ("panoramic", None, {"camera.type": "panoramic"}),
    ("three media: overlap, placed, emitting", "tests/media.toml", {}),
    ("spot and sphere lights, equiangular, overlap", "gallery/spotlight.toml",
     {"render.equiangular": "true"},
     SPOT_EDGE),
    ("sun disc, sobol, 2 light samples", None,
     {"lights.1.angle": 6.0, "render.sampler": "sobol", "render.light_samples": 2}),
]


#: The share of samples bit for bit equal at W = 16 and W = 1 where it is below 90 %: each of
#: the glow's samples takes a dozen exact transmittances through homogeneous boxes (exp), and
#: the vector exp is 1 ulp off the scalar one for about 1 % of arguments (measured 82-84 %
#: bit for bit; every value still within the relative bound).
BITWISE = {"emission sampling alone, glow": 0.75, "emission sampling, mis, glow": 0.75}


def _samples(scene, lanes, spp, jobs_per_item=None):
    """(every sample of one launch [pixels x spp, 3], the counters) at lane width ``lanes``."""
    w, h = scene.camera.resolution
    be = OpenCLBackend(scene, lanes=lanes, jobs_per_item=jobs_per_item)
    be._reserve(w * h * spp)
    be.render(0, spp, Film(w, h))
    return be.out_host[:w * h * spp].copy(), be.counter_totals()


@pytest.mark.parametrize("name,path,overrides,bound",
                         [c if len(c) == 4 else c + (2e-6,) for c in CONFIGS],
                         ids=[c[0] for c in CONFIGS])
def test_every_width_traces_the_same_paths(name, path, overrides, bound):
    """Per sample, W = 16 against W = 1 (and W = 4 and 8 on the cloud): the same decisions
    (every counter but the lanes' is equal) and the same values up to the maths library's
    ulps, compounded along a path: at most 2e-6 relative (16 ulps; measured at most 7.4e-7
    over 23 configurations; a spot's soft edge: SPOT_EDGE), and most samples bit for bit."""
    ov = dict(overrides)
    ov["camera.resolution"] = [12, 12]
    scene = load_scene(SCENES / (path or "cloud.toml"), [f"{k}={v}" for k, v in ov.items()])
    base, c1 = _samples(scene, 1, 6)
    keep = [i for i, n in enumerate(COUNTER_NAMES) if n not in LANE_COUNTERS]
    assert c1[0] > 0 or "absorber" in name
    for w in ((4, 8, 16) if path is None and not overrides else (16,)):
        out, c = _samples(scene, w, 6)
        np.testing.assert_array_equal(c[keep], c1[keep])
        rel = np.abs(out - base) / np.maximum(np.abs(base), 1e-30)
        assert rel.max() <= bound, (w, rel.max())
        assert np.all(out == base, axis=1).mean() > BITWISE.get(name, 0.9)
        # Occupancy: the lanes active per iteration of the walk loop, at most all of them.
        assert 0 < c[C_LANE_ACTIVE] <= w * c[C_LANE_ROUNDS]


def test_samples_per_work_item_do_not_change_the_samples():
    """However many samples a work-item renders (1 or 3 per lane, or the per-launch default,
    which a launch this small gets at its minimum and a large one at its maximum), every
    sample and every counter but the lanes' are the same, bit for bit."""
    from volmc.backends import opencl
    scene = load_scene(SCENES / "cloud.toml", ["camera.resolution=[12, 12]"])
    base, c0 = _samples(scene, 16, 6)
    keep = [i for i, n in enumerate(COUNTER_NAMES) if n not in LANE_COUNTERS]
    for jobs in (16, 48, 7):
        out, c = _samples(scene, 16, 6, jobs)
        np.testing.assert_array_equal(out, base)
        np.testing.assert_array_equal(c[keep], c0[keep])
    be = OpenCLBackend(scene, lanes=16)
    units = be.device.max_compute_units
    assert be.launch_jobs_per_item(1) == opencl.MIN_JOB_ROUNDS * 16
    assert be.launch_jobs_per_item(10**8) == opencl.JOB_ROUNDS * 16
    n = opencl.ITEMS_PER_UNIT * units * 16 * 8     # 8 rounds give ITEMS_PER_UNIT per unit
    assert be.launch_jobs_per_item(n) == 8 * 16


def test_work_items_dealt_out_of_order_render_every_job_once(monkeypatch):
    """The launch's blocks of jobs dealt to work-items in runs with a stride (item_deal):
    with whole and partial runs, every sample is written once (the output buffer is first
    filled with NaN) and equals the sample rendered with the blocks in order."""
    from volmc.backends import opencl
    scene = load_scene(SCENES / "cloud.toml", ["camera.resolution=[12, 12]"])
    n = 12 * 12 * 6
    for jobs in (5, 7, 16):
        items = -(-n // jobs)
        stride, group = opencl.item_deal(items, jobs)
        runs = items // group
        assert runs >= 3 and items % group and math.gcd(stride, runs) == 1 and stride > 1
    outs = {}
    for deal in ("dealt", "in order"):
        if deal == "in order":
            monkeypatch.setattr(opencl, "item_deal", lambda items, jobs: (1, 1))
        for jobs in (5, 7, 16):
            be = OpenCLBackend(scene, lanes=1, jobs_per_item=jobs)
            be._reserve(n)
            be.clc.cl.enqueue_copy(be.clc.queue, be.out_buf,
                                   np.full(be.out_host.shape, np.nan, np.float32))
            be.render(0, 6, Film(12, 12))
            outs[deal, jobs] = be.out_host[:n].copy()
    for jobs in (5, 7, 16):
        assert np.isfinite(outs["dealt", jobs]).all()
        np.testing.assert_array_equal(outs["dealt", jobs], outs["in order", jobs])
        np.testing.assert_array_equal(outs["dealt", jobs], outs["dealt", 16])


def test_lane_width_choice(monkeypatch):
    """--lanes / lanes= / $VOLMC_LANES take 1, 4, 8 or 16; the default is the device's
    preferred float vector width rounded down to one of them (PoCL on AVX-512: 16)."""
    from volmc.cl.device import select_device
    from volmc.cl.lanes import resolve_lanes
    class Dev:
        def __init__(self, w):
            self.preferred_vector_width_float = w
    assert [device_lanes(Dev(w)) for w in (1, 2, 3, 4, 6, 8, 16, 32)] == [1, 1, 1, 4, 4, 8, 16,
                                                                          16]
    assert check_lanes("8") == 8 and check_lanes(16) == 16
    for bad in ("0", "3", "32", "x", True, 8.5):
        with pytest.raises(SceneError, match="lane width must be one of 1, 4, 8, 16"):
            check_lanes(bad)
    monkeypatch.delenv("VOLMC_LANES", raising=False)
    dev = select_device()
    assert resolve_lanes(None, dev) == device_lanes(dev)
    monkeypatch.setenv("VOLMC_LANES", "4")
    assert resolve_lanes() == 4 and resolve_lanes(8) == 8
    monkeypatch.setenv("VOLMC_LANES", "5")
    with pytest.raises(SceneError, match="environment: VOLMC_LANES: lane width"):
        resolve_lanes()


@pytest.mark.parametrize("lanes", [8, 16])
def test_gather_kinds_trace_the_same_samples(monkeypatch, lanes):
    """$VOLMC_GATHERS: the gather instructions and the scalar loads build different programs
    (the build options differ) that load the same values, so every sample and every counter
    is the same bit for bit: on the cloud (dense grid, grid majorant) and on the plume (bricks,
    emission, octree)."""
    for path, extra in (("cloud.toml", []),
                        ("gallery/plume.toml", ['render.grid_storage="bricks"',
                                                'render.majorant="octree"'])):
        scene = load_scene(SCENES / path, ["camera.resolution=[12, 12]", *extra])
        got, opts = {}, {}
        for kind in ("instructions", "loads"):
            monkeypatch.setenv("VOLMC_GATHERS", kind)
            got[kind] = _samples(scene, lanes, 4)
            opts[kind] = OpenCLBackend(scene, lanes=lanes).options
        assert opts["instructions"] != opts["loads"]
        assert "-DGATHER_SCALAR=1" in opts["loads"]
        assert np.isfinite(got["loads"][0]).all() and got["loads"][0].any()
        np.testing.assert_array_equal(got["instructions"][0], got["loads"][0])
        np.testing.assert_array_equal(got["instructions"][1], got["loads"][1])


def test_gather_kind_choice(monkeypatch, tmp_path):
    """The default gather kind per device (volmc.cl.lanes.device_gathers): CPUs by Intel
    take the instructions unless Linux reports the Gather Data Sampling microcode
    mitigation, other CPUs the scalar loads, other devices the instructions; $VOLMC_GATHERS
    overrides it, and a bad value is the one-line error naming it."""
    import pyopencl as cl
    from volmc.cl.device import select_device
    from volmc.cl.lanes import device_gathers, resolve_gathers
    class Dev:
        def __init__(self, vendor, kind=cl.device_type.CPU):
            self.vendor, self.type = vendor, kind
    gds = tmp_path / "gather_data_sampling"
    missing = tmp_path / "absent"
    intel, amd = Dev("GenuineIntel"), Dev("AuthenticAMD")
    assert device_gathers(amd, missing) == "loads"
    assert device_gathers(intel, missing) == "instructions"
    for status, kind in (("Not affected", "instructions"), ("Mitigation: Microcode", "loads"),
                         ("Vulnerable: No microcode", "instructions"),
                         ("Mitigation: Microcode (locked)", "loads"),
                         ("Mitigation: AVX disabled, no microcode", "instructions")):
        gds.write_text(status + "\n")
        assert device_gathers(intel, gds) == kind, status
        assert device_gathers(amd, gds) == "loads"
    assert device_gathers(Dev("NVIDIA Corporation", cl.device_type.GPU), missing) \
        == "instructions"
    dev = select_device()
    monkeypatch.delenv("VOLMC_GATHERS", raising=False)
    assert resolve_gathers(dev) == device_gathers(dev)
    monkeypatch.setenv("VOLMC_GATHERS", " Loads ")
    assert resolve_gathers(dev) == "loads"
    monkeypatch.setenv("VOLMC_GATHERS", "fast")
    with pytest.raises(SceneError, match="environment: VOLMC_GATHERS: must be one of "
                                         "instructions, loads, got 'fast'"):
        resolve_gathers(dev)


def test_bench_lanes_records_the_gathers(monkeypatch):
    """`volmc bench lanes` names the gather kind its renders were built with, per width in
    the JSON report and once in its table's heading, so a figure says which code it
    measured ($VOLMC_GATHERS set both ways)."""
    from volmc.bench import lanes
    scene = load_scene(SCENES / "tests" / "white_furnace.toml", ["camera.resolution=[8, 8]"])
    for kind in ("loads", "instructions"):
        monkeypatch.setenv("VOLMC_GATHERS", kind)
        lines = []
        report = lanes.run_scene(scene, widths=(1, 4), spp_levels=(1, 2), reference_spp=4,
                                 repeats=1, ceiling=False, log=lambda *a: None)
        lanes.print_summary("wf", report, log=lines.append)
        assert [s["gathers"] for s in report["summary"]] == [kind, kind]
        assert f"reference 4 spp, gathers: {kind})" in lines[0]


def _cli(*args, env=None):
    e = dict(os.environ)
    e.update(env or {})
    return subprocess.run([sys.executable, "-m", "volmc.cli", *args], capture_output=True,
                          text=True, env=e, timeout=600)


def test_cli_lanes(tmp_path):
    """volmc render --lanes W renders at W (the stats say so, with the occupancy); a bad
    --lanes, $VOLMC_LANES or $VOLMC_GATHERS is the one-line error with exit status 2 and no
    file written; volmc info names the width and the gathers, and refuses the same bad
    values after its listing."""
    scene = SCENES / "tests" / "absorber.toml"
    out = tmp_path / "a.exr"
    r = _cli("render", str(scene), "-o", str(out), "--spp", "2", "--lanes", "4", "--stats",
             "-D", "camera.resolution=[8,8]")
    assert r.returncode == 0, r.stderr
    assert "lanes                    4" in r.stdout and "lane_occupancy" in r.stdout
    for args, env, what in ((["--lanes", "3"], None, "command line: --lanes: lane width"),
                            ([], {"VOLMC_LANES": "64"}, "environment: VOLMC_LANES: lane width")):
        bad = tmp_path / "b.exr"
        r = _cli("render", str(scene), "-o", str(bad), *args, env=env)
        assert r.returncode == 2 and "Traceback" not in r.stderr
        assert r.stderr.strip().splitlines() == [f"volmc: error: {what} must be one of 1, 4, 8, "
                                                 f"16, got {'3' if args else '64'!r}"]
        assert not bad.exists()
    # (as the API's lanes=: the numba backend has no lanes, and ignored the flag before)
    r = _cli("render", str(scene), "-o", str(bad), "--backend", "numba", "--lanes", "8")
    assert r.returncode == 2 and not bad.exists()
    assert r.stderr.strip().splitlines() == [
        "volmc: error: command line: --lanes: a lane width applies to the opencl backend only"]
    r = _cli("info")
    assert r.returncode == 0 and "lanes: " in r.stdout and "paths per work-item" in r.stdout
    assert "gathers: " in r.stdout
    for var, value in (("VOLMC_LANES", "5"), ("VOLMC_GATHERS", "fast")):
        r = _cli("info", env={var: value})
        assert r.returncode == 2 and "Traceback" not in r.stderr, r.stderr
        assert r.stderr.strip().splitlines() == [
            f"volmc: error: environment: {var}: "
            + ("lane width must be one of 1, 4, 8, 16, got '5'" if var == "VOLMC_LANES"
               else "must be one of instructions, loads, got 'fast'")]
        assert "default device: none" not in r.stdout
    bad = tmp_path / "g.exr"
    r = _cli("render", str(scene), "-o", str(bad), env={"VOLMC_GATHERS": "fast"})
    assert r.returncode == 2 and not bad.exists()
    assert r.stderr.strip().splitlines() == [
        "volmc: error: environment: VOLMC_GATHERS: must be one of instructions, loads, "
        "got 'fast'"]


def test_resume_with_another_width_is_refused(tmp_path):
    """A checkpoint records W; resuming it at another width is refused before anything is
    compiled (the vector maths library may round differently), at the same width it goes
    on."""
    from volmc.render import render
    scene = load_scene(SCENES / "tests" / "absorber.toml", ["camera.resolution=[8, 8]"])
    ck = tmp_path / "ck.npz"
    render(scene, spp=2, progress=False, checkpoint=str(ck), lanes=8)
    with pytest.raises(SceneError, match="the checkpoint has lane width 8, this render 4"):
        render(scene, spp=4, progress=False, resume=str(ck), lanes=4)
    assert render(scene, spp=4, progress=False, resume=str(ck), lanes=8).film.spp == 4
