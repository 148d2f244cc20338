"""OpenCL host side: struct layout, program cache, device choice, CLI commands."""

import math
import subprocess
import warnings

import numpy as np
import pyopencl as cl
import pytest

from volmc.cl import build
from volmc.cl.device import compiler_error, select_device
from volmc.cl.structs import c_struct, kernel_light_dtype, kernel_params_dtype
from volmc.params import PARAM_FIELDS, medium_dtype
from volmc.scene import SceneError
from cli_subprocess import volmc_cli, volmc_env


@pytest.mark.parametrize("name,dtype", [("Params", kernel_params_dtype()),
                                        ("Medium", medium_dtype(np.float32)),
                                        ("Light", kernel_light_dtype())])
def test_struct_layout_matches_device(name, dtype):
    """The device compiler lays out the generated C struct exactly as the numpy dtype: the
    kernel writes sizeof and every field's offset, which must equal the dtype's."""
    dev = select_device()
    ctx = cl.Context([dev])
    queue = cl.CommandQueue(ctx)
    lines = [f"out[0] = sizeof({name});"]
    lines += [f"out[{i + 1}] = __builtin_offsetof({name}, {f});" for i, f in enumerate(dtype.names)]
    src = build.params_header() + "kernel void layout(global uint *out) {" + "".join(lines) + "}"
    prg = cl.Program(ctx, src).build()
    host = np.zeros(len(dtype.names) + 1, np.uint32)
    buf = cl.Buffer(ctx, cl.mem_flags.WRITE_ONLY, host.nbytes)
    prg.layout(queue, (1,), None, buf)
    cl.enqueue_copy(queue, host, buf)
    queue.finish()
    assert host[0] == dtype.itemsize
    assert list(host[1:]) == [dtype.fields[f][1] for f in dtype.names]


def test_c_struct_declares_every_field():
    decl = c_struct("Params", PARAM_FIELDS)
    for fname, kind, count, _ in PARAM_FIELDS:
        assert f" {fname}[{count}];" in decl if count > 1 else f" {fname};" in decl


def test_program_cache(tmp_path, monkeypatch):
    monkeypatch.setenv(build.CACHE_ENV, str(tmp_path))
    dev = select_device()
    src = build.assemble("testing.cl")
    build._memory_cache.clear()
    ctx = cl.Context([dev])
    _, how = build.build_program(ctx, dev, src, ["-DFEATURE_MAJORANT_GRID=1"])
    assert how == "compiled" and len(list(tmp_path.glob("*.bin"))) == 1
    _, how = build.build_program(ctx, dev, src, ["-DFEATURE_MAJORANT_GRID=1"])
    assert how == "memory"
    build._memory_cache.clear()
    _, how = build.build_program(cl.Context([dev]), dev, src, ["-DFEATURE_MAJORANT_GRID=1"])
    assert how == "disk"
    # Other options, or another header text, are other programs.
    _, how = build.build_program(ctx, dev, src, ["-DFEATURE_MAJORANT_GRID=0"])
    assert how == "compiled"
    src2 = build.assemble("testing.cl", {"params.h": build.params_header() + "\n/* x */\n"})
    assert build.cache_key(src2, [], dev) != build.cache_key(src, [], dev)
    # A corrupt cached binary is rebuilt, not fatal.
    for f in tmp_path.glob("*.bin"):
        f.write_bytes(b"garbage")
    build._memory_cache.clear()
    _, how = build.build_program(cl.Context([dev]), dev, src, ["-DFEATURE_MAJORANT_GRID=1"])
    assert how == "compiled"
    # So is one cut short (found by an outside test: PoCL aborted or crashed on a truncated
    # binary, on every run until the cache was deleted), whatever the cut; the driver never
    # sees it.
    whole = {f: f.read_bytes() for f in tmp_path.glob("*.bin")}
    for cut in (100, 1000, 50000, -1):
        for f, data in whole.items():
            f.write_bytes(data[:cut])
            assert build.read_cached(f) is None
        build._memory_cache.clear()
        _, how = build.build_program(cl.Context([dev]), dev, src, ["-DFEATURE_MAJORANT_GRID=1"])
        assert how == "compiled"
    key = build.cache_key(src, list(build.BASE_OPTIONS) + ["-DFEATURE_MAJORANT_GRID=1"], dev)
    assert build.read_cached(tmp_path / f"{key}.bin") is not None   # written whole again
    assert not list(tmp_path.glob("*.tmp*"))


@pytest.mark.parametrize("scalar", [0, 1])
def test_render_program_builds_without_warnings(scalar):
    """The render kernel of the default scene at W = 16 builds on the default device with an
    empty log of warnings, with either kind of gather (volmc.cl.lanes). On a CPU without
    AVX-512, clang warned once per out-of-line call that passes a 512-bit vector (about 20
    "changes the ABI" warnings and a pyopencl CompilerWarning on every first build) until
    kernels/lanes.h silenced -Wpsabi."""
    from volmc.backends.opencl import render_options
    from volmc.scene import load_scene
    from volmc.resources import default_scene
    from volmc.scene.features import features
    scene = load_scene(default_scene())
    dev = select_device()
    opts = list(build.BASE_OPTIONS) + render_options(features(scene),
                                                     scene.render.transmittance,
                                                     ["-DLANES=16",
                                                      f"-DGATHER_SCALAR={scalar}"])
    prg = cl.Program(cl.Context([dev]), build.assemble("integrator.cl"))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")   # (pyopencl's notice that the log is not empty)
        prg.build(options=opts, devices=[dev])
    log = prg.get_build_info(dev, cl.program_build_info.LOG)
    assert "warning" not in log.lower(), log[:2000]


def test_assemble_expands_each_include_once():
    src = build.assemble("integrator.cl")
    assert '#include "' not in src
    assert src.count("#define VOLMC_RNG_H") == 1
    assert "typedef struct {" in src and "} Params;" in src


def test_device_selection_errors(monkeypatch):
    with pytest.raises(SceneError, match="no such OpenCL platform"):
        select_device("no-such-vendor")
    with pytest.raises(SceneError, match="device"):
        select_device("0:7")
    dev = select_device()
    assert select_device("pocl") == dev and "Portable" in dev.platform.name
    assert compiler_error(dev) is None
    monkeypatch.setenv("VOLMC_CL_DEVICE", "nope")
    with pytest.raises(SceneError, match="VOLMC_CL_DEVICE"):
        select_device()


def test_default_device_skips_a_compiler_that_fails(monkeypatch):
    """A PoCL whose LLVM does not know the CPU ("unknown target CPU 'generic'", the PyPI PoCL
    on AMD Zen 5) is passed over for one that compiles; with none, the one-line error says
    why and what to install."""
    import volmc.cl.device as device
    good = select_device()
    monkeypatch.setattr(device, "compiler_error",
                        lambda d: None if d == good else "error: unknown target CPU 'generic'")
    assert select_device() == good
    monkeypatch.setattr(device, "compiler_error",
                        lambda d: "error: unknown target CPU 'generic'")
    with pytest.raises(SceneError, match="no OpenCL device here can compile kernels.*"
                                         "unknown target CPU.*pocl-opencl-icd"):
        select_device()


def _run(args):
    return subprocess.run(volmc_cli(*args), env=volmc_env(),
                          capture_output=True, text=True, timeout=600)


def test_info_lists_pocl_and_cache():
    r = _run(["info"])
    assert r.returncode == 0
    assert "Portable Computing Language" in r.stdout and "kernel cache:" in r.stdout


def test_info_with_a_bad_default_device_exits_2():
    """The listing, then the device's one-line error and exit status 2 (it exited 0)."""
    r = subprocess.run(volmc_cli("info"), env={**volmc_env(), "VOLMC_CL_DEVICE": "97"},
                       capture_output=True, text=True, timeout=600)
    assert r.returncode == 2 and "kernel cache:" in r.stdout, r.stdout + r.stderr
    assert r.stderr.strip().splitlines() == [r.stderr.strip()]
    assert r.stderr.startswith("volmc: error: environment: VOLMC_CL_DEVICE: 97: ")


def test_check_cli_on_a_test_scene():
    from volmc.resources import scenes_dir
    r = _run(["check", str(scenes_dir() / "tests" / "white_furnace.toml"), "--spp", "32"])
    assert r.returncode == 0, r.stdout + r.stderr
    assert "AGREE" in r.stdout and "standard errors" in r.stdout


def test_check_cli_detects_a_difference(tmp_path):
    """Two backends fed different scenes (via a wrong albedo in one) must DIFFER: run the
    comparison function directly on renders of two different scenes."""
    from volmc.check import compare_images
    from volmc.render import render
    from volmc.resources import scenes_dir
    from volmc.scene import load_scene
    p = scenes_dir() / "tests" / "white_furnace.toml"
    a = render(load_scene(p, ["render.spp=64"]), backend="opencl", progress=False)
    b = render(load_scene(p, ["render.spp=64", "medium.albedo=0.97", "render.seed=5"]),
               backend="numba", progress=False)
    cmp = compare_images(a.image, a.film.variance_of_mean(), b.image,
                         b.film.variance_of_mean())
    assert not cmp.passed


def test_bench_cli_runs(tmp_path):
    from volmc.resources import scenes_dir
    scene = str(scenes_dir() / "tests" / "absorber.toml")
    out = tmp_path / "b.json"
    r = _run(["bench", "specialise", scene, "--spp", "2", "--repeats", "1"])
    assert r.returncode == 0 and "generic" in r.stdout and "gain of each" in r.stdout
    r = _run(["bench", "workgroup", scene, "--spp", "1", "--repeats", "1", "--sizes", "driver,1",
              "--json", str(out)])
    assert r.returncode == 0 and "driver" in r.stdout and out.exists()
    r = _run(["render", scene, "--device", "nope", "-o", str(tmp_path / "x.exr")])
    assert r.returncode == 2 and "nope" in r.stderr and "Traceback" not in r.stderr


def test_bench_transmittance_cli(tmp_path):
    """The estimator benchmark runs end to end (quick sweep) and writes JSON and figures whose
    figures agree with the estimators' theory (ratio tracking costs mbar L lookups)."""
    import json
    from volmc.resources import scenes_dir
    scene = str(scenes_dir() / "tests" / "white_furnace.toml")
    out = tmp_path / "t.json"
    # A 4^3 majorant grid gives the 8^3 ramp heterogeneous majorant segments for the maps.
    r = _run(["bench", "transmittance", scene, "--quick", "--rays", "64", "--json", str(out),
              "--figures", str(tmp_path), "-D", "render.majorant_resolution=[4, 4, 4]"])
    assert r.returncode == 0, r.stderr
    assert "camera segments" in r.stdout and "1/(MSE*t)" in r.stdout
    assert "guard counters over every case" in r.stdout and "grid majorant" in r.stdout
    rep = json.loads(out.read_text())
    assert len(rep["profiles"]) == 5 * 2 * 2 and len(rep["grids"]) == 2
    # Recorded segments, replayed on the scene's majorant grid: 64 // 4 of each kind.
    assert [g["n_rays"] for g in rep["grids"]] == [16, 16]
    assert all(g["majorant"].startswith("grid majorant") for g in rep["grids"])
    assert rep["maps"]["n_pieces"] > 0 and len(rep["maps"]["bins"]) == 8 * 5
    assert any(b["results"] and b["winner_var_lookups"] for b in rep["maps"]["bins"])
    for row in rep["profiles"] + rep["grids"] + rep["maps"]["bins"]:
        for res in row["results"].values():
            assert res["guards"] == {"capped": 0, "over_majorant": 0, "non_finite": 0}
    for row in rep["profiles"]:
        # Ratio tracking's lookups are Poisson(mbar L) with L = 1 and
        # mbar = mean mu / tightness = tau / effective tightness (2048 estimates per case).
        # Transmittance roulette (robustness case 10) ends a walk early once T = 0 or T < 1e-3
        # (where mu reaches the majorant, e.g. at the peak of a bump), so the count is at
        # most that; on the constant profile under a loose majorant every factor is
        # 1 - tightness and no walk gets there, so the count is exactly Poisson(mbar L).
        expect = -math.log(row["exact"]) / row["effective_tightness"]
        got = row["results"]["ratio"]["lookups"]
        tol = 5 * math.sqrt(expect / 2048) + 1e-9
        assert got < expect + tol, (row["profile"], got)
        if row["profile"] == "constant" and row["effective_tightness"] < 0.5:
            assert abs(got - expect) < tol, (row["profile"], got)
    for name in ("estimators_heatmap.png", "estimators_variance_cost.png",
                 "estimators_error_time.png", "estimators_segment_maps.png",
                 "estimators_winner_map.png"):
        assert (tmp_path / name).stat().st_size > 1000
    r = _run(["bench", "transmittance", scene, "--quick", "--estimators", "ratio,nope"])
    assert r.returncode == 2 and "nope" in r.stderr
    # An empty grid: no shadow ray reaches it, and the report says so instead of dividing by
    # zero; its camera segments are exact for every estimator, which tie (found by an
    # outside check). The profile sweep's tight constant profiles tie the same way.
    np.save(tmp_path / "zero.npy", np.zeros((8, 8, 8), np.float32))
    r = _run(["bench", "transmittance", scene, "--quick", "--rays", "64", "--estimators",
              "track_length,residual_ratio,unbiased_raymarch", "--json", str(out),
              "-D", f"medium.density={{file='{tmp_path / 'zero.npy'}'}}"])
    assert r.returncode == 0 and "Warning" not in r.stderr, r.stderr
    assert "no shadow segments recorded: left out" in r.stdout
    rep = json.loads(out.read_text())
    assert [g["rays"] for g in rep["grids"]] == ["camera segments"]
    assert rep["exact_ties"] >= 1 and "several exact" in r.stdout
    assert rep["summary"]["track_length"]["wins"] == 0


def test_bench_render_speed_against_error(tmp_path):
    """`volmc bench render` times every configuration, measures RMSE against a reference and
    the lookup ceiling, and writes a consistent report and the figure."""
    import json
    from volmc.resources import scenes_dir
    scene = str(scenes_dir() / "cloud.toml")
    out, fig = tmp_path / "r.json", tmp_path / "r.png"
    r = _run(["bench", "render", scene, "--backends", "opencl,numba", "--majorants",
              "grid,global", "--free-flights", "delta", "--transmittances", "ratio",
              "--peer", "none", "--spp-levels", "2,32", "--reference-spp", "256",
              "-D", "camera.resolution=[24,24]", "-D", "medium.density.resolution=32",
              "--json", str(out), "--plot", str(fig)])
    assert r.returncode == 0, r.stderr
    assert "time to equal error" in r.stdout and "majorant grid against global" in r.stdout
    rep = json.loads(out.read_text())
    rows = {x["name"]: x for x in rep["results"]}
    assert sorted(rows) == sorted(f"{b} {m} delta ratio" for b in ("opencl", "numba")
                                  for m in ("grid", "global"))
    assert min(x["time_to_equal_error_vs_best_volmc"] for x in rows.values()) == 1.0
    for x in rows.values():
        assert [p["spp"] for p in x["points"]] == [2, 32]
        # Every render's RMSE is positive and falls with spp (16x the samples; the sun's
        # heavy-tailed fireflies keep single-render ratios between about 0.25 and 0.55).
        e2, e32 = (p["rmse"] for p in x["points"])
        assert 0 < e32 < e2
        assert 0 < x["fraction_of_lookup_ceiling"] < 2
        assert x["guards"] == {"capped": 0, "dropped": 0, "over_majorant": 0}
    for b in ("opencl", "numba"):
        assert rows[f"{b} global delta ratio"]["lookups_per_sample"] > \
            rows[f"{b} grid delta ratio"]["lookups_per_sample"]
    assert rep["lookup_ceiling"]["opencl"] > 0 and fig.stat().st_size > 10_000
    r = _run(["bench", "render", scene, "--majorants", "grid,nope"])
    assert r.returncode == 2 and "--majorants" in r.stderr and "Traceback" not in r.stderr


def test_lookup_ceiling_kernels_are_twins():
    """The OpenCL lookup kernel and its Numba twin read the same densities at the same points
    along the scene's pixel rays."""
    import numpy as np
    from volmc.bench.lookups import OpenCLLookups, camera_segments, lookup_sums
    from volmc.resources import scenes_dir
    from volmc.scene import load_scene
    scene = load_scene(scenes_dir() / "tests" / "white_furnace.toml",
                       ["camera.resolution=[12,10]"])
    segs, bmin, bmax = camera_segments(scene)
    # The corner pixels of this view miss the box; every segment is a chord inside it.
    assert 60 < len(segs) < 120 and np.all(segs[:, 7] > segs[:, 6])
    a = OpenCLLookups(scene.grid, bmin, bmax, segs).sums(33, 3, 7)
    b = lookup_sums(np.asarray(scene.grid, np.float64), bmin, bmax, segs, 33, 3, 7)
    assert np.allclose(a, b, rtol=2e-5, atol=1e-4)
    assert np.all(b > 0)


def test_bench_lanes_reports_without_a_ceiling_for_several_media(monkeypatch):
    """`volmc bench lanes` runs over every shipped scene, placed media among them: a scene of
    several media gets its widths compared and no lookup ceiling (which reads one grid),
    instead of stopping the run; a one-grid scene gets its ceiling. The renders are
    replaced by a stand-in that records the ceilings it is given (rendering is tested
    elsewhere; the ceiling is measured for real)."""
    from volmc.bench import convergence, lanes
    from volmc.resources import scenes_dir
    from volmc.scene import load_scene
    given = []

    def fake_run(scene, configs, spp_levels, reference_spp, repeats, device, ceil, log=print):
        given.append(dict(ceil))
        return {"results": [{"lanes": c.lanes, "samples_per_second": 1.0, "mse_seconds": 1.0,
                             "points": [{"rmse": 0.5}]} for c in configs]}

    monkeypatch.setattr(convergence, "run", fake_run)
    lines = []
    scene = load_scene(scenes_dir() / "tests" / "media.toml")
    assert len(scene.spec.media) > 1 and scene.grid is not None
    report = lanes.run_scene(scene, widths=(1, 4), log=lines.append)
    assert any("lookup ceiling: none" in x for x in lines)
    assert given[-1] == {} and [r["lanes"] for r in report["summary"]] == [1, 4]
    one = load_scene(scenes_dir() / "tests" / "white_furnace.toml")
    lanes.run_scene(one, widths=(1,), log=lines.append)
    assert set(given[-1]) == {"opencl W1"} and given[-1]["opencl W1"] > 0
