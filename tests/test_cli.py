"""The command line end to end: render, convert, errors, Ctrl-C."""

import signal
import subprocess
import time

import numpy as np
import pytest

from volmc.film import read_exr
from volmc.scene.grids import read_vol
from volmc.scene.serialize import dict_to_toml
from cli_subprocess import volmc_cli, volmc_env

TINY = {
    "camera": {"eye": [0.0, 0.0, 4.0], "target": [0.0, 0.0, 0.0], "fov": 40.0,
               "resolution": [10, 8]},
    "medium": {"bounds": [[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]], "density": 1.0,
               "scale": 1.5, "albedo": 0.0},
    "lights": [{"type": "environment", "radiance": 0.5}],
    "render": {"spp": 4, "seed": 1},
}


def run(args, cwd, **kw):
    return subprocess.run(volmc_cli(*args), cwd=cwd, env=volmc_env(),
                          capture_output=True, text=True, timeout=600, **kw)


@pytest.fixture
def tiny(tmp_path):
    p = tmp_path / "tiny.toml"
    p.write_text(dict_to_toml(TINY))
    return p


def test_render_writes_exr_png_and_metadata(tmp_path, tiny):
    r = run(["render", str(tiny), "-o", "out.exr", "--png", "--spp", "3", "--seed", "9",
             "--stats", "--variance", "-D", "medium.scale=1.0"], tmp_path)
    assert r.returncode == 0, r.stderr
    img, meta = read_exr(tmp_path / "out.exr")
    assert img.shape == (8, 10, 3) and img.dtype == np.float32
    assert meta["spp"] == 3 and meta["seed"] == "9" and meta["backend"] == "opencl"
    assert meta["partial"] == 0 and float(meta["render_time_s"]) > 0
    assert "technique.free_flight" in meta and "scale = 1.0" in meta["scene_toml"]
    # Pure absorber, homogeneous: every pixel is exactly 0.5 exp(-tau) along its ray, and
    # its coverage (the A channel) 1 - exp(-tau).
    assert np.all(img > 0) and np.all(img <= 0.5)
    rgba, _ = read_exr(tmp_path / "out.exr", alpha=True)
    assert np.allclose(rgba[..., 3], 1.0 - img[..., 0] / 0.5, atol=1e-6)
    assert (tmp_path / "out.png").stat().st_size > 0
    r2 = run(["render", str(tiny), "-o", "t.exr", "--png", "--spp", "3", "--seed", "9",
              "-D", "render.transparent_background=true", "-D", "medium.scale=1.0"], tmp_path)
    assert r2.returncode == 0, r2.stderr
    t, _ = read_exr(tmp_path / "t.exr", alpha=True)
    assert np.all(t[..., :3] == 0.0) and np.allclose(t[..., 3], rgba[..., 3], atol=1e-6)
    from matplotlib import image as mpimg
    assert mpimg.imread(tmp_path / "t.png").shape == (8, 10, 4)
    var, _ = read_exr(tmp_path / "out.var.exr")
    assert np.all(var >= 0)
    for word in ("samples_per_second", "mean_path_length", "lookups_per_sample", "paths_capped"):
        assert word in r.stdout


def test_medium_out_of_view_is_a_warning(tmp_path, tiny):
    """A camera that sees no medium renders (the background is a legitimate image) with one
    warning line naming the file and key; a camera that sees it gets none."""
    r = run(["render", str(tiny), "--quiet", "--spp", "1", "-D", "camera.target=[0, 0, 8]"],
            tmp_path)
    assert r.returncode == 0, r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("volmc: warning: ")
    assert str(tiny) in lines[0] and "medium" in lines[0]
    # Placed out of view by a transform, and back into view by another.
    r = run(["render", str(tiny), "--quiet", "--spp", "1", "-D",
             "medium.transform={translate=[0, 9, 0]}"], tmp_path)
    assert "no camera ray reaches the medium" in r.stderr
    r = run(["render", str(tiny), "--quiet", "--spp", "1", "-D",
             "medium.transform={translate=[0, 9, 0], rotate=[0, 0, 1, 90]}"], tmp_path)
    assert "no camera ray reaches the medium" in r.stderr
    r = run(["render", str(tiny), "--quiet", "--spp", "1", "-D",
             "medium.transform={rotate=[1, 1, 1, 30]}"], tmp_path)
    assert r.returncode == 0 and r.stderr == ""


def test_render_default_names_and_quiet(tmp_path, tiny):
    r = run(["render", str(tiny), "--quiet"], tmp_path)
    assert r.returncode == 0 and r.stderr == "" and r.stdout == ""
    assert (tmp_path / "tiny.exr").exists() and not (tmp_path / "tiny.png").exists()


def test_seed_and_batching_reproducible(tmp_path, tiny):
    a = run(["render", str(tiny), "-o", "a.exr", "--quiet", "-D", "medium.albedo=0.9"], tmp_path)
    b = run(["render", str(tiny), "-o", "b.exr", "--quiet", "-D", "medium.albedo=0.9"], tmp_path)
    c = run(["render", str(tiny), "-o", "c.exr", "--quiet", "-D", "medium.albedo=0.9",
             "--seed", "2"], tmp_path)
    assert a.returncode == b.returncode == c.returncode == 0
    ia, ib, ic = (read_exr(tmp_path / f"{n}.exr")[0] for n in "abc")
    assert np.array_equal(ia, ib) and not np.array_equal(ia, ic)


@pytest.mark.parametrize("args,words", [
    (["render", "{tiny}", "--spp", "0"], "--spp"),
    (["render", "{tiny}", "--spp", "many"], "--spp"),
    (["render", "{tiny}", "--seed", "-1"], "--seed"),
    (["render", "{tiny}", "--backend", "gpu"], "--backend"),
    (["render", "{tiny}", "-D", "render.spp"], "section.key=value"),
    (["render", "{tiny}", "-D", "medium.albedo=2"], "medium.albedo"),
    (["render", "{tiny}", "-o", "/nonexistent/dir/x.exr"], "-o"),
    (["render", "{tiny}", "-o", "x.png"], ".exr"),
    (["render", "{tiny}", "-D", "medium.scale=[1, 2]"], "medium.scale"),
    (["render", "{tiny}", "-D", "medium.emission={radiance=1, field={file='nope.vdb'}}"],
     "nope.vdb"),
    (["render", "{tiny}", "-D", "medium.transform={scale=[1, 0, 1]}"], "medium.transform"),
    (["render", "missing.toml"], "missing.toml"),
    # An empty value read as "not given": no checkpoint, no JSON report, the default name.
    (["render", "{tiny}", "--checkpoint", ""], "--checkpoint"),
    (["render", "{tiny}", "-o", ""], "--output"),
    (["bench", "transmittance", "--quick", "--json", ""], "--json"),
    # These failed after the whole benchmark had run.
    (["bench", "render", "{tiny}", "--plot", "figure.foo"], "--plot"),
    (["bench", "render", "{tiny}", "--baseline", "."], "--baseline"),
    (["bench", "workgroup", "{tiny}", "--sizes", "driver,99999999999"], "--sizes"),
    # Before the 512^3 grid is built, not after.
    (["bench", "sparse", "--device", "99"], "--device"),
    # Before the "rendering" line, so that the error is the only line.
    (["render", "{tiny}", "--resume", "missing.ckpt"], "no such checkpoint file"),
    # A 1-spp reference has no noise estimate: every error came out NaN, silently.
    (["bench", "render", "{tiny}", "--reference-spp", "1"], "--reference-spp"),
    (["bench", "lanes", "{tiny}", "--reference-spp", "1"], "--reference-spp"),
    (["peer", "mitsuba", "{tiny}", "--reference-spp", "1"], "--reference-spp"),
    # analytic on a grid rendered the majorant's transmittance under the label "analytic".
    (["bench", "render", "{tiny}", "-D", "medium.density={generator='cloud', resolution=8}",
      "--transmittances", "analytic,ratio"], "analytic is exact in homogeneous media only"),
    (["render", "{tiny}", "--resume", "."], "not a regular file"),
    (["render", "{tiny}", "--resume", "/dev/zero"], "not a regular file"),
    # Before rendering, not after: /proc takes no new file, whatever os.access says to root.
    (["render", "{tiny}", "-o", "/proc/volmc.exr"], "-o"),
    (["render", "{tiny}", "--png", "/proc/volmc.png"], "--png"),
    (["render", "{tiny}", "--checkpoint", "/proc/volmc.npz"], "--checkpoint"),
    (["render", "{tiny}", "-o", "a.exr", "--checkpoint", "a.exr"], "--checkpoint"),
    (["bench", "render", "{tiny}", "--json", "/proc/volmc.json"], "--json"),
    (["convert", "g.npy", "/proc/volmc.vol"], "output"),
    (["convert", "g.npy", "g.vol", "--bounds", "0", "0", "0", "1e39", "1", "1"], "--bounds"),
    (["convert", "g.npy", "g.vol", "--bounds", "1", "1", "1", "0", "0", "0"], "--bounds"),
    # Not empty in float64, empty in the .vol header's float32.
    (["convert", "g.npy", "g.vol", "--bounds", "1", "0", "0", "1.00000001", "1", "1"],
     "--bounds"),
    (["convert", "g.npy", "g.vol", "--bounds", "0", "0", "0", "1e-46", "1", "1"], "--bounds"),
    (["check", "{tiny}", "--spp", "8"], "--spp"),
    # Before the header line, not after it.
    (["check", "{tiny}", "--spp", "16", "--device", "9"], "command line: --device: 9: "),
    (["render", "{tiny}", "--device", ":"], "command line: --device: :"),
    # These waited for Dask's 30 s connect timeout.
    (["render", "{tiny}", "--scheduler", "tcp://127.0.0.1:99999"], "--scheduler"),
    (["render", "{tiny}", "--scheduler", "tcp://256.1.1.1:8786"], "--scheduler"),
    (["render", "{tiny}", "--exposure", "nan"], "--exposure"),
    # An unbounded count started worker processes until memory ran out.
    (["render", "{tiny}", "--workers", "99999999999999999999"], "--workers"),
    (["render", "{tiny}", "--spp", "4294967296"], "--spp"),
    (["bench", "lanes", "{tiny}", "--spp-levels", "4,4294967296"], "--spp-levels"),
    # These allocated a 100000^3 grid and 2^40 / 64 sums: numpy's MemoryError traceback.
    (["bench", "sparse", "--size", "100000"], "--size"),
    (["bench", "sparse", "--lookups", str(2**50)], "--lookups"),
    (["frobnicate"], "invalid choice"),
    # named "-o: not a usable file name" (the default output after the missing scene's name)
    (["render", "a" * 300 + ".toml"], "scene file not found"),
    (["convert", "missing.npy", "x.vol"], "missing.npy"),
])
def test_bad_command_lines_one_line_exit_2(tmp_path, tiny, args, words):
    np.save(tmp_path / "g.npy", np.ones((2, 2, 2), np.float32))   # for convert
    r = run([a.replace("{tiny}", str(tiny)) for a in args], tmp_path)
    assert r.returncode == 2, r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("volmc: error: "), r.stderr
    assert words in lines[0]
    assert "Traceback" not in r.stderr


def test_sparse_bench_without_an_active_voxel(tmp_path):
    """A grid too small for its fill has no voxel to look up in ("active" points): the
    one-line error after the progress line, not Numba's ZeroDivisionError."""
    r = run(["bench", "sparse", "--size", "2", "--lookups", "1000"], tmp_path)
    assert r.returncode == 2 and "Traceback" not in r.stderr, r.stderr
    assert r.stderr.strip().splitlines()[-1].startswith("volmc: error: command line: --fill: ")


def test_a_fifo_vdb_is_refused_not_waited_on(tmp_path):
    """A FIFO as the VDB file: open() would wait for a writer forever, and the reader maps
    the file. (A scene may come through a pipe: `volmc render <(...)` reads it.)"""
    import os
    os.mkfifo(tmp_path / "pipe")
    r = run(["info", "pipe"], tmp_path)
    assert r.returncode == 2 and r.stderr.strip() == "volmc: error: pipe: file: not a " \
        "regular file", r.stderr


@pytest.mark.parametrize("kind", ["directory", "fifo"])
def test_an_environment_map_that_is_no_file_is_refused(tmp_path, kind):
    """A directory named like a map failed with a traceback, and a FIFO blocked the read
    forever: one-line errors, as for grid files."""
    import os
    if kind == "fifo":
        os.mkfifo(tmp_path / "sky.exr")
    else:
        (tmp_path / "sky.exr").mkdir()
    raw = dict(TINY, lights=[{"type": "environment", "file": "sky.exr"}])
    (tmp_path / "s.toml").write_text(dict_to_toml(raw))
    r = run(["render", "s.toml", "-o", "o.exr"], tmp_path)
    assert r.returncode == 2 and r.stderr.strip().splitlines() == [
        f"volmc: error: s.toml: lights[0].file: not a regular file: {tmp_path / 'sky.exr'}"
    ], r.stderr


def test_a_section_that_is_not_a_table_is_the_files_error_with_spp(tmp_path):
    # --spp and --seed reach the scene as overrides of render.spp and render.seed; the
    # error is the file's `render`, not a -D the user never typed.
    raw = dict(TINY)
    del raw["render"]
    (tmp_path / "s.toml").write_text("render = [1]\n" + dict_to_toml(raw))
    for flags in ([], ["--spp", "1"], ["--seed", "3"]):
        r = run(["render", "s.toml", "-o", "o.exr"] + flags, tmp_path)
        assert r.returncode == 2 and r.stderr.strip() == \
            "volmc: error: s.toml: render: expected a table, got list [1]", (flags, r.stderr)


def test_bad_grid_via_cli(tmp_path):
    g = np.ones((3, 3, 3), np.float32)
    g[0, 0, 0] = np.nan
    np.save(tmp_path / "g.npy", g)
    raw = dict(TINY, medium=dict(TINY["medium"], density={"file": "g.npy"}))
    (tmp_path / "s.toml").write_text(dict_to_toml(raw))
    r = run(["render", "s.toml"], tmp_path)
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert r.stderr.strip() == f"volmc: error: {tmp_path / 'g.npy'}: medium.density: grid " \
                               "contains 1 NaN value"


def test_convert_round_trip(tmp_path):
    g = np.random.default_rng(1).random((3, 4, 5)).astype(np.float32)
    np.save(tmp_path / "a.npy", g)
    assert run(["convert", "a.npy", "b.vol", "--bounds", "-1", "-2", "-3", "1", "2", "3"],
               tmp_path).returncode == 0
    vol, bbox = read_vol(tmp_path / "b.vol")
    assert np.array_equal(vol, g) and np.allclose(bbox, [-1, -2, -3, 1, 2, 3])
    assert run(["convert", "b.vol", "c.npz"], tmp_path).returncode == 0
    assert run(["convert", "c.npz", "d.npy"], tmp_path).returncode == 0
    assert np.array_equal(np.load(tmp_path / "d.npy"), g)
    assert run(["convert", "d.npy", "e.vol"], tmp_path).returncode == 0
    # A .vol written from a .vol keeps its bounding box.
    assert run(["convert", "b.vol", "f.vol"], tmp_path).returncode == 0
    assert np.allclose(read_vol(tmp_path / "f.vol")[1], [-1, -2, -3, 1, 2, 3])


def test_ctrl_c_writes_partial_image(tmp_path):
    raw = dict(TINY, medium=dict(TINY["medium"], albedo=0.9, scale=3.0),
               render={"spp": 10_000_000, "max_depth": -1})
    (tmp_path / "long.toml").write_text(dict_to_toml(raw))
    p = subprocess.Popen(volmc_cli("render", "long.toml", "-o", "long.exr"), cwd=tmp_path,
                         env=volmc_env(), stderr=subprocess.PIPE, text=True)
    seen = []
    deadline = time.time() + 300
    while time.time() < deadline:
        line = p.stderr.readline()
        seen.append(line)
        if line.startswith("volmc: started") or not line:
            break
    time.sleep(1.5)
    p.send_signal(signal.SIGINT)
    rest = p.communicate(timeout=120)[1]
    assert p.returncode == 130, "".join(seen) + rest
    img, meta = read_exr(tmp_path / "long.exr")
    assert meta["partial"] == 1 and 0 < meta["spp"] < 10_000_000
    assert np.all(np.isfinite(img)) and img.mean() > 0
    assert "partial" in rest and "Traceback" not in rest
