"""Benchmarks and comparisons at their edges (found by an outside tester of the commands
other than ``volmc render``): a grid smaller than the Numba warm-up's, an image with no
noise, references of 1 spp or more than any render has, and Ctrl-C during a reference."""

import pytest

from volmc import cli
from volmc.resources import scenes_dir

ABSORBER = str(scenes_dir() / "tests" / "absorber.toml")


def test_sparse_bench_runs_below_its_warm_up_size():
    """bench sparse warmed Numba up on the grid's first 9^3 voxels and read past a smaller
    grid (a segmentation fault at --size 7 and 8)."""
    from volmc.bench.sparse import run
    report = run(size=8, lookups=256, per_item=16, repeats=1, backends=("numba",),
                 log=lambda *a: None)
    assert report


def test_an_exact_image_has_no_time_ratio():
    """volmc's RMSE 0 (an absorber: every sample exact) divided by zero in volmc peer."""
    from volmc.peers.compare import equal_error_time_ratio
    assert equal_error_time_ratio(1.0, 0.0, 2.0, 0.1) is None
    assert equal_error_time_ratio(1.0, 0.1, 2.0, 0.1) == pytest.approx(2.0)


@pytest.mark.parametrize("argv, words", [
    (["peer", "mitsuba", ABSORBER, "--reference-spp", "1"], "at least 2"),
    (["peer", "mitsuba", ABSORBER, "--reference-spp", "4294967296"], "at most 4294967295"),
    (["bench", "denoise", ABSORBER, "--reference-spp", "1"], "at least 2")])
def test_reference_spp_is_checked(argv, words, capsys):
    """volmc peer took any --reference-spp (2^32 rendered without end) and bench denoise took
    1 (a reference with no variance: -inf and Infinity in its report)."""
    assert cli.main(argv) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and "--reference-spp" in lines[0] and words in lines[0], lines


def test_ctrl_c_during_a_reference_stops_the_benchmark(monkeypatch):
    """render() turns Ctrl-C into a partial result; a benchmark's reference used it as if
    whole (exit 0, a report saying 4096 spp over a quarter of them). It stops now."""
    import sys
    from volmc.bench.convergence import reference_image
    from volmc.scene import load_scene
    vr = sys.modules["volmc.render"]   # (volmc.render is the API function)
    real = vr.render

    def interrupted(*args, **kwargs):
        res = real(*args, **kwargs)
        res.partial = True
        return res

    monkeypatch.setattr(vr, "render", interrupted)
    with pytest.raises(KeyboardInterrupt):
        reference_image(load_scene(ABSORBER), 2, log=lambda *a: None)


def _one_line(capsys, *words):
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("volmc: error: "), lines
    for w in words:
        assert w in lines[0], lines[0]


def test_outputs_may_not_be_the_scene_or_each_other(tmp_path, monkeypatch, capsys):
    """--json naming the scene file overwrote it with the report; --json and --plot naming
    one file kept only the figure; a folder's figure or image that is a directory failed
    after the work. Each is the one-line error now, before anything runs."""
    import shutil
    monkeypatch.chdir(tmp_path)
    shutil.copy(ABSORBER, "s.toml")
    before = (tmp_path / "s.toml").read_bytes()
    for argv in (["bench", "render", "s.toml", "--json", "s.toml"],
                 ["bench", "lanes", "s.toml", "--json", "./s.toml"],
                 ["bench", "specialise", "s.toml", "--json", "s.toml"],
                 ["peer", "mitsuba", "s.toml", "--json", "s.toml"]):
        assert cli.main(argv) == 2
        _one_line(capsys, "--json: ", "is the scene file s.toml")
    assert (tmp_path / "s.toml").read_bytes() == before
    assert cli.main(["bench", "variance", "s.toml", "--json", "r.png", "--plot", "r.png"]) == 2
    _one_line(capsys, "--plot: r.png is also the file of --json")
    (tmp_path / "figs" / "estimators_heatmap.png").mkdir(parents=True)
    assert cli.main(["bench", "transmittance", str(scenes_dir() / "tests" /
                                                  "constant_grid.toml"), "--figures",
                     "figs"]) == 2
    _one_line(capsys, "--figures: ", "estimators_heatmap.png")
    (tmp_path / "imgs" / "volmc.exr").mkdir(parents=True)
    assert cli.main(["peer", "mitsuba", "s.toml", "--images", "imgs"]) == 2
    _one_line(capsys, "--images: ", "volmc.exr")


def test_every_scene_is_checked_before_the_first_is_measured(tmp_path, capsys):
    """bench specialise, workgroup and denoise measured the first scene (16 s) before a bad
    second one failed, and wrote nothing."""
    bad = tmp_path / "bad.toml"
    bad.write_text("[camera]\nbogus = 1\n")
    for argv in (["bench", "specialise", ABSORBER, str(bad)],
                 ["bench", "workgroup", ABSORBER, str(bad)]):
        assert cli.main(argv) == 2
        out = capsys.readouterr()
        assert out.out == ""   # nothing measured
        lines = out.err.strip().splitlines()
        assert len(lines) == 1 and "bad.toml: camera.bogus" in lines[0], lines


def test_a_report_whose_folder_went_away_is_kept(tmp_path):
    """write_json after the work, its folder removed meanwhile: a traceback, the report lost.
    Now the one-line error names the copy in the temporary directory."""
    import json
    from volmc.outputs import write_json
    from volmc.scene.errors import SceneError
    with pytest.raises(SceneError, match="--json: cannot write .*the report is in ") as info:
        write_json(str(tmp_path / "gone" / "r.json"), {"a": 1})
    copy = str(info.value).rsplit("the report is in ", 1)[1]
    with open(copy) as f:
        assert json.load(f) == {"a": 1}


@pytest.mark.parametrize("argv, flag", [
    (["bench", "lanes", ABSORBER, "--widths", "4,4"], "--widths"),
    (["bench", "render", ABSORBER, "--backends", "opencl,opencl"], "--backends"),
    (["bench", "transmittance", ABSORBER, "--estimators", "ratio, ratio"], "--estimators"),
    (["bench", "workgroup", ABSORBER, "--sizes", "driver,4,driver"], "--sizes")])
def test_a_configuration_named_twice_is_refused(argv, flag, capsys):
    """--widths 4,4 measured W = 4 twice, as two rows of one name."""
    assert cli.main(argv) == 2
    _one_line(capsys, f"{flag}: ", "is named twice")


def test_a_baseline_without_kernels_is_refused_before_the_work(tmp_path, capsys):
    """A folder with volmc/__init__.py but no kernels passed the check, and failed only when
    its first render was due, after the reference."""
    (tmp_path / "volmc").mkdir()
    (tmp_path / "volmc" / "__init__.py").write_text("")
    assert cli.main(["bench", "render", ABSORBER, "--baseline", str(tmp_path)]) == 2
    _one_line(capsys, "--baseline: ", "no kernels/")
